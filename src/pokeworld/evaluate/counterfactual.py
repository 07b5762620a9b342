"""Does a model predict *where* each candidate action program sends the object?

The rank test (:mod:`pokeworld.evaluate.ranking`) says whether a model orders candidate programs like the true
simulator; when it does not, these two numbers say why. Both compare the model's predicted object positions after
the programs with the true ones, *within* a start (every candidate shares the start, so what differs between them
is only what the actions do):

* ``spread_ratio``: the spread of the model's predicted end positions across a start's candidates over the true
  spread (median over starts). Near 0: the predictions hardly depend on the action program (the heads read the
  state, not the actions); near 1: they vary as much as the outcomes do.
* ``within_r2``: R² of the predicted end positions against the true ones after removing each start's mean from
  both (pooled over starts and the two coordinates). 1: the model predicts every program's counterfactual
  outcome; 0: no better than predicting the start's average outcome for all; below 0: worse than that.

Given the start positions, two more split the candidates by what truly happens (planning starts put the object
at rest, so a program that never touches it leaves it exactly where it was):

* ``miss_displacement``: the mean predicted displacement (end − start) over candidates that truly miss (truth: 0);
* ``hit_displacement`` / ``hit_true_displacement``: the same over candidates that truly move the object, and
  their true mean displacement. A model that has only seen aimed pushes succeed predicts phantom pushes: a
  ``miss_displacement`` near ``hit_true_displacement``.
"""

from __future__ import annotations

import numpy as np


def counterfactual_fit(model_end: np.ndarray, true_end: np.ndarray, start: np.ndarray | None = None,
                       min_spread: float = 1e-6) -> dict:
    """(S, N, 2) predicted and true object positions after N candidate programs from S starts -> metrics;
    ``start`` (S, 2), the object's position at each start, adds the miss / hit displacements.

    Starts whose true outcomes do not vary (every candidate misses an object at rest) say nothing about
    counterfactuals and are left out; ``starts`` counts the rest.
    """
    model_end, true_end = np.asarray(model_end, float), np.asarray(true_end, float)
    if model_end.shape != true_end.shape or model_end.ndim != 3 or model_end.shape[-1] != 2:
        raise ValueError(f"predicted and true end positions must both be (starts, candidates, 2), "
                         f"got {model_end.shape} and {true_end.shape}")
    dm = model_end - model_end.mean(1, keepdims=True)
    dt = true_end - true_end.mean(1, keepdims=True)
    spread_true = np.sqrt((dt**2).sum(-1).mean(1))
    keep = spread_true > min_spread
    out = {"spread_ratio": float("nan"), "within_r2": float("nan"), "starts": 0}
    if keep.any():
        spread_model = np.sqrt((dm**2).sum(-1).mean(1))
        resid = ((dm[keep] - dt[keep]) ** 2).sum()
        out = {"spread_ratio": float(np.median(spread_model[keep] / spread_true[keep])),
               "within_r2": float(1.0 - resid / (dt[keep] ** 2).sum()), "starts": int(keep.sum())}
    if start is not None:
        start = np.asarray(start, float)
        if start.shape != (true_end.shape[0], 2):
            raise ValueError(f"start must be (starts, 2) = {(true_end.shape[0], 2)}, got {start.shape}")
        moved_by = np.linalg.norm(model_end - start[:, None], axis=-1)
        true_by = np.linalg.norm(true_end - start[:, None], axis=-1)
        hit = true_by > min_spread
        mean = lambda x: float(x.mean()) if x.size else float("nan")  # noqa: E731
        out |= {"miss_displacement": mean(moved_by[~hit]), "hit_displacement": mean(moved_by[hit]),
                "hit_true_displacement": mean(true_by[hit]), "hit_share": float(hit.mean())}
    return out


__all__ = ["counterfactual_fit"]
