"""The SIGReg weight sweep (paper Table "lambda"): VFX at each λ, every seed."""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..evaluate.tables import dagger, fmt, mean_over, probe, run_gate_failed
from .runs import RunSpec, spec

if TYPE_CHECKING:
    from .config import MapConfig

LAMBDA = {  # Table "lambda" (VFX)
    0.3: {"log_k": 0.12, "log_m": 0.12, "object_vel": 0.54, "direct16": 0.128},
    0.1: {"log_k": 0.24, "log_m": 0.18, "object_vel": 0.62, "direct16": 0.111},
    0.02: {"log_k": 0.50, "log_m": 0.29, "object_vel": 0.79, "direct16": 0.099},
    0.01: {"log_k": 0.54, "log_m": 0.32, "object_vel": 0.79, "direct16": 0.096},
    0.005: {"log_k": 0.57, "log_m": 0.32, "object_vel": 0.80, "direct16": 0.095},
}


NAME = "lambda"


def specs(c: MapConfig) -> list[RunSpec]:
    # every seed (the sweep's steps 0.02 -> 0.01 -> 0.005 are within seed-to-seed spread on `cpu`), the first
    # seed's sweep first, so a time-budgeted map that stops early leaves a whole sweep rather than half of one
    return [spec("lambda", "VFX", seed, lam) for seed in c.seeds for lam in c.lambdas]


def lambda_table(results: dict) -> list[str]:
    if "lambda" not in results["experiments"]:
        return []
    lines = ["## SIGReg weight λ (VFX, contact windows; mean over seeds)", "",
             "| λ | seeds | log k (ours / paper) | log m (ours / paper) | velocity (ours / paper) "
             "| direct-16 (ours / paper) |", "|---|---|---|---|---|---|"]
    by_lam: dict[float, list[dict]] = {}
    for name in results["experiments"]["lambda"]:
        r = results["runs"][name]
        by_lam.setdefault(r["train"]["sigreg_weight"], []).append(r)
    for lam in sorted(by_lam, reverse=True):
        runs, p = by_lam[lam], LAMBDA.get(lam, {})
        k, m = (fmt(mean_over(runs, lambda r, q=q: probe(r, q)))
                + dagger(any(run_gate_failed(results, r, q) for r in runs)) for q in ("log_k", "log_m"))
        vel = mean_over(runs, lambda r: probe(r, "object_vel"))
        d16 = mean_over(runs, lambda r: r["prediction"].get("direct16"))
        lines.append(f"| {lam:g} | {len(runs)} | {k} / {fmt(p.get('log_k'))} | {m} / {fmt(p.get('log_m'))} | "
                     f"{fmt(vel)} / {fmt(p.get('object_vel'))} | {fmt(d16, 3)} / {fmt(p.get('direct16'), 3)} |")
    return lines + [""]


section = lambda_table


__all__ = ['NAME', 'LAMBDA', 'specs', 'section', 'lambda_table']
