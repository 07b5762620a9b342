"""Grouped-CV ridge probe fit: ``pokeworld.regressors.RidgeCV`` against the per-alpha scikit-learn loop it replaced.

Usage:  python benchmarks/ridge_cv.py [--n 6000] [--d 128] [--reps 3] [--out benchmarks/results/ridge_cv.json]

Synthetic probe-shaped data (n windows × d state dims, groups of 12 windows per episode, 2 targets). Both fit 8
alphas × 5 episode-grouped folds plus a final fit; ``RidgeCV`` shares one eigendecomposition per fold across the
alphas (``regressors.ridge_path``). Records the best of ``reps`` timings of each and checks that both pick the
same alpha with the same CV score (tests/test_certify.py checks the predictions against scikit-learn).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import torch
from sklearn.linear_model import Ridge
from sklearn.model_selection import GroupKFold

sys.path.insert(0, str(Path(__file__).resolve().parent))
from train_throughput import write_results  # noqa: E402

from pokeworld.regressors import ALPHAS, RidgeCV, Standardizer, r2_scores  # noqa: E402


def per_alpha_loop(X, Y, groups) -> tuple[float, float]:
    """The previous implementation: one scikit-learn Ridge per alpha and fold. Returns (alpha, CV R²)."""
    Xs = Standardizer.fit(X)(X)
    scores = []
    for a in ALPHAS:
        pred = np.zeros_like(Y)
        for tr, va in GroupKFold(5).split(Xs, Y, groups):
            pred[va] = Ridge(alpha=a).fit(Xs[tr], Y[tr]).predict(Xs[va])
        scores.append(np.mean(r2_scores(Y, pred)))
    best = int(np.argmax(scores))
    Ridge(alpha=ALPHAS[best]).fit(Xs, Y)
    return float(ALPHAS[best]), float(scores[best])


def best_time(fn, reps: int) -> tuple[float, object]:
    times, out = [], None
    for _ in range(reps):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=6000)
    ap.add_argument("--d", type=int, default=128)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--out", default="benchmarks/results/ridge_cv.json")
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    X = rng.normal(size=(args.n, args.d))
    Y = X[:, :3] @ rng.normal(size=(3, 2)) + rng.normal(size=(args.n, 2))
    groups = np.repeat(np.arange(args.n // 12 + 1), 12)[:args.n]
    t_loop, (a_loop, r2_loop) = best_time(lambda: per_alpha_loop(X, Y, groups), args.reps)
    t_new, m = best_time(lambda: RidgeCV().fit(X, Y, groups), args.reps)
    row = {"n": args.n, "d": args.d, "alphas": len(ALPHAS), "folds": 5, "per_alpha_loop_s": round(t_loop, 4),
           "ridgecv_s": round(t_new, 4), "speedup": round(t_loop / t_new, 1),
           "same_alpha": a_loop == m.alpha, "cv_r2_abs_diff": abs(r2_loop - m.cv_r2)}
    print(row)
    write_results(args.out, torch.device("cpu"), [row])


if __name__ == "__main__":
    main()
