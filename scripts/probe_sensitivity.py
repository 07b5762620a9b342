"""What a leak-free ridge probe can resolve at a given number of windows (docs/results/frontier_cpu.md).

Planted check: 128-d isotropic Gaussian states plus one direction carrying an episode-level parameter, so
the best linear readout explains exactly R²_true of its variance; 2 windows per episode, grouped-CV
``RidgeCV`` fit on the fit windows, R² on disjoint test episodes; mean and s.d. over seeds. Run at our
glide-window counts (156 fit / 152 test) and the paper's (696 / 351).

    python scripts/probe_sensitivity.py [--seeds 20] [--out docs/results/glide_probe_sensitivity.json]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from pokeworld.io import write_json
from pokeworld.regressors import RidgeCV


def planted_r2(r2_true: float, n_fit: int, n_test: int, dim: int = 128, per_episode: int = 2, seed: int = 0) -> float:
    rng = np.random.default_rng(seed)
    n = n_fit + n_test
    episode = np.arange(n) // per_episode
    y = rng.normal(size=episode[-1] + 1)[episode]
    u = rng.normal(size=dim)
    u /= np.linalg.norm(u)
    X = rng.normal(size=(n, dim)) + np.outer(np.sqrt(r2_true / (1 - r2_true)) * y, u)
    fit, test = slice(0, n_fit), slice(n_fit, n)  # episodes never straddle: n_fit is even
    pred = np.asarray(RidgeCV().fit(X[fit], y[fit], episode[fit]).predict(X[test])).reshape(-1)
    return float(1 - ((y[test] - pred) ** 2).sum() / ((y[test] - y[test].mean()) ** 2).sum())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--out", default="")
    a = ap.parse_args()
    rows = []
    for r2 in (0.1, 0.2, 0.3, 0.5):
        for n_fit, n_test in ((156, 152), (696, 351)):
            v = [planted_r2(r2, n_fit, n_test, seed=s) for s in range(a.seeds)]
            rows.append({"r2_true": r2, "fit": n_fit, "test": n_test, "mean": float(np.mean(v)), "sd": float(np.std(v))})
            print(f"planted R² {r2}: {n_fit} fit / {n_test} test windows -> read {np.mean(v):+.2f} (s.d. {np.std(v):.2f})")
    if a.out:
        write_json(Path(a.out), {"seeds": a.seeds, "dim": 128, "windows_per_episode": 2, "rows": rows})


if __name__ == "__main__":
    main()
