"""Does a model rank candidate action programs the way the true simulator does?

A CEM planner only ever uses the *order* of its candidates' scores (it keeps the best few as elites), so a
model is useful for planning exactly as far as its scores order candidates like the true cost does. Two
measures per start (one row of candidates), averaged over starts:

* Spearman ρ between the model's and the true costs (average ranks for ties): 1 same order, 0 none, −1 reversed;
* top-k overlap: the share of the truly best k candidates that the model puts among its own k best.

Ties are the rule, not the exception: every candidate that never touches an object at rest leaves it exactly
where it was, so all misses share one true cost, and at a planning start only a few candidates beat it. When the
k-th best true cost is shared by candidates outside the best k, which of them are "the best k" is undecidable,
so the truly best set is then the candidates strictly better than the k-th best (the decidable ones; fewer than
k). Every member of that set lands in a random k-subset with probability k / N, so chance is k / N whatever the
ties; a perfect scorer reads 1. Starts whose true costs are all equal are left out of ρ, and starts with
nothing strictly better than the k-th best out of the overlap (``starts`` and ``topk_starts`` count the rest).
"""

from __future__ import annotations

import numpy as np
from scipy.stats import rankdata


def spearman_rows(model: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(S, N) costs -> (S,) Spearman ρ per row; NaN where ``truth`` is constant, 0 where only ``model`` is
    (a model that cannot tell its candidates apart orders nothing)."""
    rm, rt = rankdata(model, axis=1), rankdata(truth, axis=1)
    rm, rt = rm - rm.mean(1, keepdims=True), rt - rt.mean(1, keepdims=True)
    sm, st = np.sqrt((rm**2).sum(1)), np.sqrt((rt**2).sum(1))
    rho = (rm * rt).sum(1) / np.where(sm * st > 0, sm * st, 1.0)
    return np.where(st > 0, rho, np.nan)


def topk_overlap(model: np.ndarray, truth: np.ndarray, k: int) -> np.ndarray:
    """(S, N) costs -> (S,) share of the truly best k (the decidable ones under ties, see the module docstring)
    among the model's k lowest; NaN where no candidate is strictly better than the k-th best."""
    picked = np.argsort(model, axis=1, kind="stable")[:, :k]
    kth = np.sort(truth, axis=1)[:, k - 1 : k]
    within = truth <= kth
    best = np.where(within.sum(1, keepdims=True) == k, within, truth < kth)
    size = best.sum(1)
    hits = np.take_along_axis(best, picked, 1).sum(1)
    return np.where(size > 0, hits / np.maximum(size, 1), np.nan)


def agreement(model: np.ndarray, truth: np.ndarray, k: int) -> dict:
    """Rank agreement of (S, N) model costs with true costs (lower is better for both).

    Returns ``spearman`` and ``topk_overlap`` (means over the starts each can be read on), ``topk_chance`` k / N
    (a random scorer's expected overlap), ``k``, ``candidates`` N, ``starts`` and ``topk_starts``.
    """
    model, truth = np.asarray(model, float), np.asarray(truth, float)
    if model.shape != truth.shape or model.ndim != 2:
        raise ValueError(f"model and true costs must both be (starts, candidates), got {model.shape} and {truth.shape}")
    if not 1 <= k <= truth.shape[1]:
        raise ValueError(f"k must be in [1, {truth.shape[1]}], got {k}")
    rho, overlap = spearman_rows(model, truth), topk_overlap(model, truth, k)
    mean = lambda x: float(np.nanmean(x)) if np.isfinite(x).any() else float("nan")  # noqa: E731
    return {"spearman": mean(rho), "topk_overlap": mean(overlap), "topk_chance": k / truth.shape[1], "k": int(k),
            "candidates": int(truth.shape[1]), "starts": int(np.isfinite(rho).sum()),
            "topk_starts": int(np.isfinite(overlap).sum())}


__all__ = ["spearman_rows", "topk_overlap", "agreement"]
