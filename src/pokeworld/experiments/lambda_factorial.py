"""The factorial at a stronger SIGReg weight (paper App. C, after Table "targets": "the ordering is unchanged at
λ = 0.1"): the six variants at one seed, their log k ordering checked against Table "targets"' and put beside the
release's runs at that weight (exp/e003_motion's files without a λ suffix)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING

from ..evaluate.tables import fmt, mean_over, probe, variant_runs
from ..published.release import LAMBDA_0_1
from .factorial import FACTORIAL
from .runs import RunSpec, spec

if TYPE_CHECKING:
    from .config import MapConfig

NAME = "lambda_factorial"

TARGETS_ORDER = ("VFX", "VX", "VX_t", "VX_p", "VF", "V")
"""Table "targets"' variants by log k, highest first (0.50, 0.46, 0.40; then the three near zero)."""
TOUCH_READERS = ("VX_t", "VX", "VFX")
"""The variants with touch as an input or a target: the ones Table "targets" finds reading stiffness."""
ORDERING_TOLERANCE = 0.1
"""R²: a gap or a reversal smaller than this is not called (the ledger's tolerance for an R² readout)."""


def ordering_holds(log_k: Mapping[str, float | None], variants: tuple[str, ...] = TARGETS_ORDER,
                   tolerance: float = ORDERING_TOLERANCE) -> bool | None:
    """Whether ``log_k`` (variant -> log k R²) keeps Table "targets"' ordering among ``variants``: every variant with
    touch reads log k more than ``tolerance`` above every variant without, and no pair in :data:`TARGETS_ORDER`'s
    order is reversed by more than ``tolerance``. None when one of ``variants`` has no value, or when ``variants``
    lack a side of the comparison (an ordering of some variants is not the table's)."""
    order = [v for v in TARGETS_ORDER if v in variants]
    if any(log_k.get(v) is None for v in order):
        return None
    readers = [log_k[v] for v in order if v in TOUCH_READERS]
    others = [log_k[v] for v in order if v not in TOUCH_READERS]
    if not readers or not others:
        return None
    gap = min(readers) - max(others) > tolerance
    kept = all(log_k[a] >= log_k[b] - tolerance for i, a in enumerate(order) for b in order[i + 1:])
    return gap and kept


def specs(c: MapConfig) -> list[RunSpec]:
    # one seed, as the release has it; VFX at this weight is also the λ sweep's run (trained once)
    return [spec(NAME, v, c.seeds[0], c.ordering_sigreg_weight) for v in c.variants]


RELEASED_VARIANTS = tuple(v for v in TARGETS_ORDER if (v, 0) in LAMBDA_0_1)
"""The variants the release trained at λ 0.1 (V, VX_t, VX, VFX: no VF or VX_p)."""


def released_log_k() -> dict[str, float]:
    """The release's log k (ridge, contact windows) per variant at λ 0.1, the mean of its seeds."""
    by_variant: dict[str, list[float]] = {}
    for (v, _), r in LAMBDA_0_1.items():
        by_variant.setdefault(v, []).append(r["ridge"]["log_k"])
    return {v: sum(x) / len(x) for v, x in by_variant.items()}


def lambda_factorial_table(results: dict) -> list[str]:
    """Per variant ours at the stronger weight beside the operating point's (the factorial's runs, when this map
    has them) and the release's runs at λ 0.1, then whether each keeps Table "targets"' ordering."""
    names = results["experiments"].get(NAME)
    if not names:
        return []
    lam = results["runs"][names[0]]["train"]["sigreg_weight"]
    lines = [f"## The factorial at λ = {lam:g} (ridge R², contact windows)", "",
             "The paper states only that Table \"targets\"' ordering is unchanged at λ = 0.1; the release's run "
             "of the same seed at that weight is beside ours (it has no VF or VX_p there), and the operating "
             "point's paper values for reference.", "",
             f"| variant | log k at λ {lam:g} (ours / release) | log m at λ {lam:g} (ours / release) | "
             "log k at the operating point (ours / paper) | position |", "|---|---|---|---|---|"]
    ours = {}
    for v in results["map_config"]["variants"]:
        runs = [results["runs"][n] for n in names if results["runs"][n]["train"]["variant"] == v]
        if not runs:
            continue
        seed = runs[0]["train"]["seed"]
        rel = LAMBDA_0_1.get((v, seed), {}).get("ridge", {}) if lam == 0.1 else {}
        ours[v] = mean_over(runs, lambda r: probe(r, "log_k"))
        base = mean_over(variant_runs(results, "factorial", v), lambda r: probe(r, "log_k"))
        lines.append(f"| {v} | {fmt(ours[v])} / {fmt(rel.get('log_k'))} | "
                     f"{fmt(mean_over(runs, lambda r: probe(r, 'log_m')))} / {fmt(rel.get('log_m'))} | "
                     f"{fmt(base)} / {fmt(FACTORIAL.get(v, {}).get('log_k'))} | "
                     f"{fmt(mean_over(runs, lambda r: probe(r, 'object_pos')))} |")
    verdict = {True: "holds", False: "does not hold", None: "cannot be judged (a variant is missing)"}
    lines.append(f"\nTable \"targets\"' ordering (every variant with touch more than {ORDERING_TOLERANCE:g} above "
                 f"every variant without; no pair reversed by more than {ORDERING_TOLERANCE:g}): ours "
                 f"{verdict[ordering_holds(ours)]}"
                 + (f"; the release's runs (its {', '.join(RELEASED_VARIANTS)}; seed means) "
                    f"{verdict[ordering_holds(released_log_k(), RELEASED_VARIANTS)]}" if lam == 0.1 else "") + ".")
    return lines + [""]


section = lambda_factorial_table


__all__ = ["NAME", "TARGETS_ORDER", "TOUCH_READERS", "ORDERING_TOLERANCE", "ordering_holds", "specs",
           "RELEASED_VARIANTS", "released_log_k", "section", "lambda_factorial_table"]
