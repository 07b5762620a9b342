"""Rank agreement of model and true costs: exact on planted orders, chance-level on random ones, ties handled."""

import numpy as np
import pytest

from pokeworld.evaluate.ranking import agreement, spearman_rows, topk_overlap


def test_same_order_reads_one_reversed_minus_one_any_monotone_map_the_same():
    truth = np.random.default_rng(0).normal(size=(20, 64))
    assert agreement(truth, truth, 8)["spearman"] == pytest.approx(1.0)
    assert agreement(np.exp(3 * truth), truth, 8)["topk_overlap"] == 1.0  # only the order counts
    r = agreement(-truth, truth, 8)
    assert r["spearman"] == pytest.approx(-1.0) and r["topk_overlap"] == 0.0


def test_random_scores_read_chance():
    rng = np.random.default_rng(1)
    truth = rng.normal(size=(4000, 64))
    r = agreement(rng.normal(size=truth.shape), truth, 8)
    assert abs(r["spearman"]) < 0.01
    assert r["topk_chance"] == 8 / 64 and abs(r["topk_overlap"] - 8 / 64) < 0.01


def test_partial_knowledge_lands_between_chance_and_one():
    rng = np.random.default_rng(2)
    truth = rng.normal(size=(500, 64))
    r = agreement(truth + rng.normal(size=truth.shape), truth, 8)
    assert 0.5 < r["spearman"] < 0.9 and 0.2 < r["topk_overlap"] < 0.8


def test_spearman_matches_scipy_with_ties():
    from scipy.stats import spearmanr

    rng = np.random.default_rng(3)
    truth = rng.integers(0, 4, (6, 30)).astype(float)  # heavy ties
    model = rng.normal(size=truth.shape) + truth
    expected = [spearmanr(m, t).statistic for m, t in zip(model, truth)]
    np.testing.assert_allclose(spearman_rows(model, truth), expected, atol=1e-12)


def test_tied_misses_cannot_dilute_or_inflate_the_top_k():
    # 2 candidates improve (costs 0, 1), 60 misses tie at 5, 2 make it worse: only the two improvers are decidable
    truth = np.array([[0.0, 1.0] + [5.0] * 60 + [9.0, 9.0]])
    assert topk_overlap(truth, truth, 8)[0] == 1.0
    one = np.arange(64.0)[None].copy()
    one[0, 1] = 100.0  # the model finds the best improver, misses the second
    assert topk_overlap(one, truth, 8)[0] == 0.5
    # a model that ranks the misses first (in whatever order) finds none of what matters
    assert topk_overlap(-np.arange(64.0)[None] + 0 * truth, truth, 8)[0] == 0.0
    # nothing beats the tie at the k-th place: no decidable top k, the start is left out
    flat = np.array([[5.0] * 60 + [7.0] * 4])
    assert np.isnan(topk_overlap(flat, flat, 8)[0])


def test_undecidable_starts_are_left_out_and_constant_models_order_nothing():
    truth = np.vstack([np.full(16, 2.0), np.arange(16.0)])
    r = agreement(np.arange(16.0)[None].repeat(2, 0), truth, 4)
    assert r["starts"] == 1 and r["spearman"] == pytest.approx(1.0)  # the all-tied start is left out
    assert spearman_rows(np.zeros((1, 16)), truth[1:])[0] == 0.0


def test_bad_shapes_and_k_raise():
    with pytest.raises(ValueError):
        agreement(np.zeros((2, 8)), np.zeros((2, 9)), 2)
    with pytest.raises(ValueError):
        agreement(np.zeros((2, 8)), np.zeros((2, 8)), 9)
