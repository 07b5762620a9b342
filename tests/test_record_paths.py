"""The committed records name no machine's paths (scripts/record_paths.py), and the rewriting keeps every number."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_no_record_holds_a_machines_path():
    proc = subprocess.run([sys.executable, "scripts/record_paths.py", "--check"], cwd=ROOT, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout


def test_paths_become_placeholders_and_nothing_else_changes(tmp_path):
    import json

    record = tmp_path / "r.json"
    record.write_text(json.dumps({"command": "pokeworld map --out /work/scratch/s8/map --data /tmp/x/data/standard",
                                  "runs": ["/home/u/out/runs/VFX-h1-4-16-lam0.02-standard-s0"], "r2": 0.123456789,
                                  "note": "a ratio 3/4 and docs/results/x.md stay",
                                  "planted": {"/work/scratch/s8/map/data/standard": {"S": 1.0}}}))
    proc = subprocess.run([sys.executable, "scripts/record_paths.py", str(record)], cwd=ROOT, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    out = json.loads(record.read_text())
    assert out == {"command": "pokeworld map --out <machine>/map --data <machine>/data/standard",
                   "runs": ["<machine>/runs/VFX-h1-4-16-lam0.02-standard-s0"], "r2": 0.123456789,
                   "note": "a ratio 3/4 and docs/results/x.md stay",
                   "planted": {"<machine>/data/standard": {"S": 1.0}}}


def test_two_keys_that_would_become_one_are_refused():
    import pytest

    from pokeworld.record_paths import without_machine_paths

    with pytest.raises(ValueError, match="two keys"):
        without_machine_paths({"/work/a/data/standard": 1, "/tmp/b/data/standard": 2})


def test_a_markdown_report_is_rewritten_in_place_and_keeps_its_table(tmp_path):
    report = tmp_path / "r.md"
    report.write_text("| run | R² |\n|---|---|\n| /work/scratch/s8/map/runs/VFX-s0 | 0.51 |\n\n"
                      "Produced by `pokeworld map --out /tmp/x/map` (a ratio 3/4 stays).\n")
    proc = subprocess.run([sys.executable, "scripts/record_paths.py", "--check", str(report)], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1 and "1 of 1" in proc.stdout
    proc = subprocess.run([sys.executable, "scripts/record_paths.py", str(report)], cwd=ROOT, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert report.read_text() == ("| run | R² |\n|---|---|\n| <machine>/runs/VFX-s0 | 0.51 |\n\n"
                                  "Produced by `pokeworld map --out <machine>/map` (a ratio 3/4 stays).\n")
