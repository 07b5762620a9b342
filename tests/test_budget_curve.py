"""The budget curve (scripts/budget_curve.py): a kept checkpoint measured as a snapshot run gives exactly what the
run itself gives at that step (the final checkpoint against the finished run's own measurement), and the record,
table and figure carry every kept step with the paper's value."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

from pokeworld.cli import main as cli

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "budget_curve.py"


def _script():
    spec = importlib.util.spec_from_file_location("budget_curve", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.slow
def test_kept_checkpoints_measure_like_the_run(tmp_path):
    store, run = tmp_path / "store", tmp_path / "run"
    assert cli(["generate", "--preset", "tiny", "--out", str(store)]) == 0
    args = ["train", "--preset", "tiny", "--variant", "VFX", "--steps", "10", "--keep-every", "5", "--data", str(store),
            "--out", str(run)]
    assert cli(args + ["--stop-at", "5"]) == 0 and cli(args) == 0  # kept across a resume, as in sittings
    assert sorted(p.name for p in (run / "kept").iterdir() if p.suffix == ".pt") == ["ckpt-10.pt", "ckpt-5.pt"]
    assert cli(["probe", "--preset", "tiny", str(run), "--data", str(store)]) == 0
    out = tmp_path / "rec" / "budget.json"
    bc = _script()
    assert bc.main([str(run), "--work", str(tmp_path / "work"), "--preset", "tiny", "--plan-episodes", "2",
                    "--out", str(out)]) == 0
    rec = json.loads(out.read_text())
    points = rec["runs"][0]["points"]
    assert sorted(points, key=int) == ["5", "10"]
    own = json.loads(next(run.glob("measure*.json")).read_text())["probes"]
    for q in ("log_k", "log_m", "gamma"):  # the step-10 snapshot holds the finished run's weights: same numbers
        assert points["10"][f"ridge_{q}"] == own["ridge"]["contact"][q]
    assert points["5"]["ridge_log_k"] != points["10"]["ridge_log_k"]  # another checkpoint, another model
    assert rec["runs"][0]["paper"]["ridge"]["log_k"] == pytest.approx(0.495)
    assert rec["runs"][0]["environment"] == "reference"  # the store's manifest names it; the table says so
    assert f"{run.name}: reference, {rec['runs'][0]['objective']}" in out.with_suffix(".md").read_text()
    assert "| run | step |" in out.with_suffix(".md").read_text()
    assert out.with_suffix(".png").stat().st_size > 0
    # re-running measures nothing new and writes the same record
    assert bc.main([str(run), "--work", str(tmp_path / "work"), "--preset", "tiny", "--plan-episodes", "2",
                    "--out", str(out)]) == 0
    assert json.loads(out.read_text())["runs"][0]["points"] == points


def test_a_run_without_kept_checkpoints_is_one_line(tmp_path, capsys):
    (tmp_path / "run").mkdir()
    assert _script().main([str(tmp_path / "run"), "--out", str(tmp_path / "r.json")]) == 2
    assert "no kept/ckpt-<step>.pt checkpoints" in capsys.readouterr().err


def test_the_objective_is_read_from_the_runs_own_config():
    from pokeworld.train.config import make_config, to_dict

    def stored(preset):  # as config.json holds it: tuples as lists
        return json.loads(json.dumps(to_dict(make_config(preset))))

    bc = _script()
    assert bc.objective_of(stored("cpu")) == "reference weighting"
    assert bc.objective_of(stored("cpu_first")) == "first objective"
    assert bc.objective_of({}) == "first objective"  # a config from before the weighting existed
