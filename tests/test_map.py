"""The identifiability map end to end on the tiny preset, run naming, skipping, and submitit launching."""

import json

import numpy as np
import pytest

from pokeworld.errors import ConfigError
from pokeworld.evaluate import experiment
from pokeworld.evaluate.measure import CONTEXT, HORIZON, glide_test
from pokeworld.windows import make_windows


def test_run_names_are_deterministic_and_unique():
    c = experiment.make_config("cpu", experiments=tuple(experiment.EXPERIMENTS))
    a = [s.name for s in experiment.all_specs(c)]
    b = [s.name for s in experiment.all_specs(c)]
    assert a == b and len(a) == len(set(a))
    assert "VFX-h1-4-16-lam0.02-standard-s0" in a  # shared by factorial, lambda and coverage: trained once
    assert "V-h1-lam0.02-standard-s0" in a


def test_bad_map_configs_raise():
    with pytest.raises(ConfigError, match="unknown experiments"):
        experiment.make_config("tiny", experiments=("alchemy",))
    with pytest.raises(ConfigError, match="unknown variants"):
        experiment.make_config("tiny", variants=("VZ",))
    with pytest.raises(ConfigError, match="launcher"):
        experiment.make_config("tiny", launcher="kubernetes")


def test_glide_test_references(tiny_dataset):
    ds = tiny_dataset
    w = make_windows(ds, np.arange(ds.num_episodes), CONTEXT + HORIZON, 2)
    truth = w.gather(ds.labels["object_pos"])[:, -1]
    res = glide_test(ds, w, truth, np.arange(ds.num_episodes))
    assert res["windows"] >= 5
    assert res["model"] == 0.0
    assert res["true_gamma"] < 1e-3 < res["median_gamma"] < res["static"]


@pytest.mark.slow
def test_tiny_map_writes_every_artifact_and_skips_on_rerun(tmp_path, capsys):
    out = tmp_path / "map"
    c = experiment.make_config("tiny", out=str(out), workers=1)
    experiment.run(c)
    for name in ("results.json", "results.md", "identifiability_map.png", "identifiability_map.pdf", "map_config.json",
                 "data/standard/manifest.json", "data/standard/certificates.json"):
        assert (out / name).exists(), name
    res = json.loads((out / "results.json").read_text())
    assert set(res["runs"]) == {"V-h1-4-16-lam0.02-standard-s0", "VX_t-h1-4-16-lam0.02-standard-s0"}
    for r in res["runs"].values():
        assert "contact" in r["probes"]["ridge"] and "log_k" in r["probes"]["ridge"]["contact"]
        assert r["prediction"]["static16"] > 0
    for run in (out / "runs").iterdir():
        for f in ("config.json", "metrics.jsonl", "DONE", "measure.json"):
            assert (run / f).exists(), (run, f)
    md = (out / "results.md").read_text()
    assert "| V |" in md and "paper" in md
    capsys.readouterr()
    experiment.run(c)  # second run: everything is skipped
    log = capsys.readouterr().out
    assert "already holds this corpus" in log and "up to date" in log


@pytest.mark.slow
def test_submitit_local_launcher_runs_jobs(tmp_path):
    out = tmp_path / "map"
    c = experiment.make_config("tiny", out=str(out), variants=("V",), launcher="submitit-local")
    experiment.run(c)
    assert (out / "runs" / "V-h1-4-16-lam0.02-standard-s0" / "measure.json").exists()
    assert list((out / "submitit").iterdir())
