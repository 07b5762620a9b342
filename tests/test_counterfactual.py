"""The counterfactual fit reads what it should on planted predictions: the truth, an action-blind model, a
model with shuffled outcomes, and a model that moves the right way but too little."""

import numpy as np
import pytest

from pokeworld.evaluate.counterfactual import counterfactual_fit


def _true_ends(seed=0, starts=20, cands=32):
    rng = np.random.default_rng(seed)
    return rng.normal(0.5, 0.1, (starts, 1, 2)) + rng.normal(0, 0.05, (starts, cands, 2))


def test_the_true_outcomes_fit_perfectly():
    t = _true_ends()
    r = counterfactual_fit(t.copy(), t)
    assert r["spread_ratio"] == pytest.approx(1.0) and r["within_r2"] == pytest.approx(1.0) and r["starts"] == 20


def test_an_action_blind_model_has_no_spread_and_explains_nothing():
    t = _true_ends()
    blind = np.repeat(t.mean(1, keepdims=True) + 0.03, t.shape[1], 1)  # the start's mean outcome, offset
    r = counterfactual_fit(blind, t)
    assert r["spread_ratio"] == pytest.approx(0.0, abs=1e-12) and r["within_r2"] == pytest.approx(0.0, abs=1e-12)


def test_shuffled_outcomes_spread_right_but_fit_worse_than_the_mean():
    t = _true_ends(1)
    rng = np.random.default_rng(2)
    shuffled = rng.permuted(t, axis=1)
    r = counterfactual_fit(shuffled, t)
    assert r["spread_ratio"] == pytest.approx(1.0) and -1.3 < r["within_r2"] < -0.7


def test_a_timid_model_is_seen_in_its_spread():
    t = _true_ends(3)
    timid = t.mean(1, keepdims=True) + 0.2 * (t - t.mean(1, keepdims=True))
    r = counterfactual_fit(timid, t)
    assert r["spread_ratio"] == pytest.approx(0.2) and r["within_r2"] == pytest.approx(1 - 0.8**2)


def test_starts_where_nothing_moves_are_left_out_and_bad_shapes_raise():
    t = _true_ends(4, starts=5)
    t[:2] = 0.4  # every candidate misses: no counterfactual to read
    r = counterfactual_fit(t + 0.0, t)
    assert r["starts"] == 3
    assert np.isnan(counterfactual_fit(np.zeros((2, 4, 2)), np.zeros((2, 4, 2)))["within_r2"])
    with pytest.raises(ValueError, match="starts, candidates, 2"):
        counterfactual_fit(np.zeros((2, 4, 2)), np.zeros((2, 4, 3)))


def test_phantom_pushes_show_as_displacement_on_the_misses():
    """Half the candidates truly move the object 0.2, half miss it (it stays at the start): a faithful model reads
    0 on the misses and 0.2 on the hits; a model that predicts every candidate pushes reads 0.2 on both."""
    rng = np.random.default_rng(5)
    start = rng.uniform(0.3, 0.7, (10, 2))
    ang = rng.uniform(0, 2 * np.pi, (10, 16))
    push = 0.2 * np.stack([np.cos(ang), np.sin(ang)], -1)
    hit = np.arange(16) < 8
    truth = start[:, None] + np.where(hit[None, :, None], push, 0.0)
    faithful = counterfactual_fit(truth.copy(), truth, start)
    assert faithful["miss_displacement"] == pytest.approx(0.0) and faithful["hit_displacement"] == pytest.approx(0.2)
    assert faithful["hit_true_displacement"] == pytest.approx(0.2) and faithful["hit_share"] == 0.5
    phantom = counterfactual_fit(start[:, None] + push, truth, start)
    assert phantom["miss_displacement"] == pytest.approx(0.2) and phantom["spread_ratio"] > 1.2
    assert phantom["within_r2"] < 0.5
    with pytest.raises(ValueError, match="start must be"):
        counterfactual_fit(truth, truth, start[:3])
