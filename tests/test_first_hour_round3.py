"""Words that say what happened (issue #62, item 4): an interrupted command says whether its rerun resumes or starts
over, a closing line names the files a newcomer wants (not the ownership record), ``certify --preset tiny`` says
its FAIL is a smoke test's, and the worked example says which way a licensed claim goes."""

from __future__ import annotations

import importlib.util
import time
from pathlib import Path
from types import SimpleNamespace

from pokeworld.cli import CERTIFY_SMOKE_NOTE, closing_line, interrupted_exit, run_and_report

ROOT = Path(__file__).resolve().parents[1]


def test_an_interrupted_generate_says_it_starts_over_and_a_map_that_it_resumes(capsys):
    assert interrupted_exit("generate", ["--preset", "cpu", "DIR"], KeyboardInterrupt()) == 130
    err = capsys.readouterr().err.strip()
    assert "to resume" not in err and err.endswith("starts over: run again: pokeworld generate --preset cpu DIR")
    interrupted_exit("map", ["--out", "M"], KeyboardInterrupt())
    assert capsys.readouterr().err.strip().endswith("to resume, run: pokeworld map --out M")


def test_the_closing_line_names_every_output_and_not_the_ownership_record(tmp_path):
    since = time.time() - 1
    for name in (".pokeworld-owned", "plan.json", "plan.md", "distances.npz", "plan_episode.png", "plan_episode.pdf"):
        (tmp_path / name).write_text("x")
    line = closing_line("plan", SimpleNamespace(out=str(tmp_path)), tmp_path, since)
    assert "plan_episode.png" in line and "plan.md" in line and ".pokeworld-owned" not in line and "more" not in line


def test_certify_at_tiny_notes_a_smoke_test_and_still_ends_with_what_it_wrote(tmp_path, capsys):
    out = tmp_path / "certificates.json"

    def runner(cfg):
        out.write_text("{}")
        print(f"[certify] gate log_k: FAIL; wrote {out}")
        return out

    run_and_report("certify", SimpleNamespace(data=str(tmp_path)), runner, preset="tiny")
    lines = capsys.readouterr().out.strip().splitlines()
    assert CERTIFY_SMOKE_NOTE in lines and lines[-1].startswith("[certify] wrote ")
    run_and_report("certify", SimpleNamespace(data=str(tmp_path)), runner, preset="cpu")
    assert CERTIFY_SMOKE_NOTE not in capsys.readouterr().out


def test_the_example_says_which_way_a_licensed_claim_goes():
    spec = importlib.util.spec_from_file_location("certify_example", ROOT / "examples" / "certify_your_model.py")
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    held = example.verdict({"status": "claim", "ridge": 0.45, "untrained": 0.05})
    lacking = example.verdict({"status": "claim", "ridge": -0.12, "untrained": 0.01})
    assert "holds it" in held and "does not hold it" in lacking and lacking != "claim"
    assert example.verdict({"status": "no claim (gate failed)", "ridge": 0.3}) == "no claim (gate failed)"
