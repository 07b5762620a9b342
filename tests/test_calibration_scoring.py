"""The behaviour-mix search scores points correctly: its loss on planted statistics, and a committed grid point
re-scored from scratch (docs/design.md, "Behaviour mix under the constant law")."""

import json
import math
from pathlib import Path

import numpy as np
import pytest

from pokeworld.sim.calibration import TARGETS, evaluate_corpus, loss
from pokeworld.sim.stats import within_tolerance

GRID = Path(__file__).resolve().parents[1] / "docs" / "results" / "mix_grid_constant.json"


def test_loss_is_zero_at_the_papers_statistics_and_counts_log_ratios():
    assert loss(dict(TARGETS)) == pytest.approx(0.0, abs=1e-12)
    name = next(iter(TARGETS))
    # a factor e too high in one statistic costs exactly 1, and a factor e too low the same (log-symmetric)
    for factor in (math.e, 1 / math.e):
        off = dict(TARGETS) | {name: TARGETS[name] * factor}
        assert loss(off) == pytest.approx(1.0)
    # two statistics off add up; a point further off scores worse
    two = dict(TARGETS) | {k: v * math.e for k, v in list(TARGETS.items())[:2]}
    assert loss(two) == pytest.approx(2.0)
    assert loss(dict(TARGETS) | {name: TARGETS[name] * 1.1}) < loss(dict(TARGETS) | {name: TARGETS[name] * 1.5})


def test_tolerance_band_is_the_papers_value_plus_minus_15_percent():
    name = "static8"
    assert within_tolerance(name, TARGETS[name] * 1.14)
    assert not within_tolerance(name, TARGETS[name] * 1.2)
    assert not within_tolerance(name, TARGETS[name] * 0.8)


def test_a_committed_grid_point_rescored_from_scratch_matches_its_record():
    """The grid's first point (the default mix under the constant law, strike gain 0.7) simulated again with the
    grid's seed and episode count gives the statistics and the loss the committed grid holds: the scoring is a
    function of the point alone, so the grid can be checked and extended."""
    grid = json.loads(GRID.read_text())
    row = grid["rows"][0]
    episodes = int(grid["command"].split("--episodes ")[1].split()[0])
    point = {"physics": dict(row["point"]["physics"]),
             "policy": {k: tuple(v) if isinstance(v, list) else v for k, v in row["point"]["policy"].items()}}
    _, stats = evaluate_corpus(point, episodes, seed=0)
    for k, v in row["stats"].items():
        assert stats[k] == pytest.approx(v, rel=1e-9, abs=1e-12), k
    assert loss(stats) == pytest.approx(row["stats_loss"], rel=1e-9)
    # and a different point scores differently (the check can fail)
    other = {"physics": dict(point["physics"]), "policy": dict(point["policy"]) | {"launch_fraction": 0.6}}
    _, other_stats = evaluate_corpus(other, episodes, seed=0)
    assert not np.isclose(loss(other_stats), row["stats_loss"], rtol=1e-3)
