"""The planning experiment inside the map: it reuses the factorial's runs, writes the table, figure and results."""

import json

import pytest

from pokeworld import experiments as experiment
from pokeworld.experiments import factorial, planning


def test_planning_reuses_the_factorial_runs():
    c = experiment.make_config("cpu", experiments=("factorial", "planning"))
    names = [s.name for s in experiment.all_specs(c)]
    factorial_runs = {s.name for s in factorial.specs(c)}
    assert {s.name for s in planning.specs(c)} <= factorial_runs  # no extra training
    assert len(names) == len(set(names)) == len(factorial_runs)
    alone = experiment.make_config("cpu", experiments=("planning",))
    assert {s.name for s in experiment.all_specs(alone)} == {
        f"{v}-h1-4-16-lam0.02-standard-s0" for v in ("V", "VX_t", "VX_p", "VFX")}


@pytest.mark.slow
def test_tiny_map_with_planning_writes_the_table(tmp_path, capsys):
    out = tmp_path / "map"
    c = experiment.make_config("tiny", out=str(out), workers=1, experiments=("factorial", "planning"),
                               planning_variants=("V", "VX_t"))
    experiment.run(c)
    res = json.loads((out / "results.json").read_text())
    summary = res["planning"]["summary"]
    assert set(summary) == {"random", "V", "VX_t"}
    for v in summary.values():
        assert 0.0 <= v["reach"] <= 1.0 and isinstance(v["median_improvement"], float)
    assert set(summary["V"]["per_run"]) == {"V-h1-4-16-lam0.02-standard-s0"}
    assert set(res["runs"]) == {"V-h1-4-16-lam0.02-standard-s0", "VX_t-h1-4-16-lam0.02-standard-s0"}
    assert (out / "planning" / "plan_episode.png").exists()
    md = (out / "results.md").read_text()
    assert "## Closed-loop planning" in md
    assert "| VX_t |" in md and "/ 38% |" in md and "| random |" in md  # paper beside ours
    capsys.readouterr()
    experiment.run(c)
    assert "skipping planning" in capsys.readouterr().out
