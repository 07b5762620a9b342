"""A lease landed in the repository (pokeworld.remote.land, scripts/land_lease.py), checked on a tiny
allocation of this CPU: its factorial runs become released model folders whose weights are exactly the returned
ones, the record and the model folders read back as the returned folders do, and damage or a foreign folder is
refused in one line."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from pokeworld import checkpoint
from pokeworld.errors import ConfigError
from pokeworld.model_folder import read_weights
from pokeworld.remote import allocations, land

ROOT = Path(__file__).resolve().parents[1]
V, VFX = (f"{v}-h1-4-16-lam0.02-standard-s0" for v in ("V", "VFX"))


@pytest.fixture(scope="module")
def returned(tmp_path_factory):
    """A tiny allocation's returned folder (V and VFX)."""
    base = tmp_path_factory.mktemp("land")
    env = {**os.environ, "PYTHON": sys.executable, "ALLOC_PRESET": "tiny", "ALLOC_BUDGET_MIN": "5", "ALLOC_TESTS": "0",
           "ALLOC_WORK": str(base / "work"), "ALLOC_COMMIT": "abc1234", "PYTHONPATH": str(ROOT / "src")}
    proc = subprocess.run(["bash", "scripts/gpu_allocation.sh", str(base / "out"), "V", "VFX"], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:]
    return base / "out"


def _weights(a, name):
    return checkpoint.load(a.root / "runs" / name / "final.pt")["model"]


def test_a_landed_lease_reads_back_with_exactly_the_returned_weights(returned, tmp_path):
    record, models = tmp_path / "record", tmp_path / "models"
    index = land.land([returned], record, models, "tiny-lease")
    assert sorted(r["model"] for r in index["runs"].values()) == ["xjepa-V-tiny-s0", "xjepa-VFX-tiny-s0"]
    assert index["parts"] == [] and not list(record.glob("pack.tar.part*"))
    folder = models / "xjepa-VFX-tiny-s0"
    assert {p.name for p in folder.iterdir()} >= {"README.md", "config.json", "model.safetensors", "measure.json",
                                                  "training_metrics.jsonl"}
    config = json.loads((folder / "config.json").read_text())
    assert config["source"]["lease"] == "tiny-lease" and config["train_config"]["data"] == "DIR"
    text = "".join(p.read_text() for p in folder.iterdir() if p.suffix in (".md", ".json"))
    assert str(tmp_path) not in text and "/tmp/" not in text  # no machine's paths on a released model
    # large float32 tensors stored in bfloat16, as they travelled; the rest as they were
    stored = read_weights(folder)
    assert all((t.dtype == torch.bfloat16) == (t.is_floating_point() and t.numel() >= 4096) for t in stored.values())
    (tmp_path / "s1").mkdir(), (tmp_path / "s2").mkdir()
    [raw] = allocations.open_allocations([returned], tmp_path / "s1")
    [landed] = allocations.open_allocations([record], tmp_path / "s2", models)
    assert landed.weights == {V: "returned", VFX: "returned"} and landed.progress == raw.progress
    for name in (V, VFX):
        a, b = _weights(raw, name), _weights(landed, name)
        assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    merged = allocations.merge_allocations([landed])
    assert set(merged["runs"]) == {V, VFX}


def test_changed_weights_or_a_foreign_model_folder_are_refused_in_one_line(returned, tmp_path):
    record, models = tmp_path / "record", tmp_path / "models"
    land.land([returned], record, models, "tiny-lease")
    weights = models / "xjepa-V-tiny-s0" / "model.safetensors"
    data = bytearray(weights.read_bytes())
    data[-1] ^= 1
    weights.write_bytes(bytes(data))
    (tmp_path / "s").mkdir()
    with pytest.raises(ConfigError, match="not the weights its record names"):
        allocations.open_allocations([record], tmp_path / "s", models)
    # a user's folder where a released model would go: refused before anything is written
    mine = tmp_path / "models2" / "xjepa-V-tiny-s0"
    mine.mkdir(parents=True)
    (mine / "notes.txt").write_text("mine")
    with pytest.raises(ConfigError, match="did not write"):
        land.land([returned], tmp_path / "record2", tmp_path / "models2", "tiny-lease")
    assert (mine / "notes.txt").read_text() == "mine" and len(list(mine.iterdir())) == 1


def test_land_lease_script_says_what_it_wrote(returned, tmp_path):
    proc = subprocess.run([sys.executable, "scripts/land_lease.py", str(returned), "--record", str(tmp_path / "rec"),
                           "--models", str(tmp_path / "m")], cwd=ROOT, capture_output=True, text=True, timeout=300,
                          env={**os.environ, "PYTHONPATH": str(ROOT / "src")})
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "2 released models" in proc.stdout and "lease.json" in proc.stdout.splitlines()[-1]
    bad = subprocess.run([sys.executable, "scripts/land_lease.py", str(tmp_path / "nothing"), "--record",
                          str(tmp_path / "rec2")], cwd=ROOT, capture_output=True, text=True, timeout=120,
                         env={**os.environ, "PYTHONPATH": str(ROOT / "src")})
    assert bad.returncode != 0 and bad.stderr.strip().startswith("error:") and len(bad.stderr.strip().splitlines()) == 1


def test_every_released_model_in_the_repository_is_the_weights_its_lease_landed(tmp_path):
    """The committed leases and models/: each landed run's weights file has the digest its lease names, stores its
    large tensors in bfloat16, says on its card where and how it was trained, and the lease reads back whole."""
    leases = sorted((ROOT / "docs" / "results" / "leases").glob("*/lease.json"))
    assert leases, "no landed lease in the repository"
    for i, path in enumerate(leases):
        index = json.loads(path.read_text())
        for name, row in index["runs"].items():
            folder = ROOT / "models" / row["model"]
            stored = read_weights(folder, row["model_sha256"])
            assert any(t.dtype == torch.bfloat16 for t in stored.values())
            card = (folder / "README.md").read_text()
            assert f"GPU lease `{index['lease']}`" in card and "environment `reference`" in card and name in card
        (tmp_path / str(i)).mkdir()
        [a] = allocations.open_allocations([path.parent], tmp_path / str(i), ROOT / "models")
        assert all(a.weights[n] == "returned" for n in index["runs"])
