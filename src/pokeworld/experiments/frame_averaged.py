"""Information bandwidth (paper §4.4): sub-step vs frame-averaged touch, certificates and the VFX model."""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..evaluate.tables import LABELS, fmt, mean_over, probe, variant_runs
from .runs import RunSpec, spec

if TYPE_CHECKING:
    from .config import MapConfig

FRAME_AVERAGED = {"certificate_log_k_substep": 0.87}  # §4.4: frame-averaged touch makes k unrecoverable


NAME = "frame_averaged"


def specs(c: MapConfig) -> list[RunSpec]:
    return [spec("frame_averaged", "VFX", c.seeds[0], c.sigreg_weight, corpus="frame_averaged",
                  measure_corpus="frame_averaged")]


def frame_averaged_lines(results: dict) -> list[str]:
    """§4.4 information bandwidth: certificates on sub-step vs frame-averaged touch, and the VFX model trained
    and probed on the frame-averaged corpus beside the factorial's VFX (same objective, only the sensor differs)."""
    fa = results["certificates"].get("frame_averaged")
    std = results["certificates"].get("standard")
    if not fa or not std:
        return []
    k_fa = fa["certificate"].get("contact", {}).get("log_k", {}).get("r2")
    k_std = std["certificate"].get("contact", {}).get("log_k", {}).get("r2")
    lines = ["## Information bandwidth: frame-averaged touch", "",
             f"log k certificate (best estimator) with sub-step touch: ours {fmt(k_std)} (paper "
             f"{FRAME_AVERAGED['certificate_log_k_substep']}); with frame-averaged touch: ours {fmt(k_fa)} "
             "(paper: unrecoverable).", "",
             "| log k certificate | sub-step touch | frame-averaged touch |", "|---|---|---|"]
    k_of = {name: {e: kinds.get("contact", {}).get("log_k") for e, kinds in c.get("estimators", {}).items()}
            for name, c in (("std", std), ("fa", fa))}
    for e in sorted(e for e in k_of["std"].keys() | k_of["fa"].keys()
                    if k_of["std"].get(e) is not None or k_of["fa"].get(e) is not None):
        lines.append(f"| {e} | {fmt(k_of['std'].get(e))} | {fmt(k_of['fa'].get(e))} |")
    model = [results["runs"][n] for n in results["experiments"].get("frame_averaged", [])]
    base = variant_runs(results, "factorial", "VFX")
    if model:
        qs = ("log_k", "log_m", "gamma", "object_pos", "object_vel")
        lines += ["", "| VFX trained and probed on | " + " | ".join(LABELS.get(q, q) for q in qs) + " | direct-16 |",
                  "|" + "---|" * (len(qs) + 2)]
        for label, runs in (("sub-step touch (factorial)", base), ("frame-averaged touch", model)):
            if runs:
                cells = [fmt(mean_over(runs, lambda r, q=q: probe(r, q))) for q in qs]
                d16 = fmt(mean_over(runs, lambda r: r["prediction"].get("direct16")), 3)
                lines.append(f"| {label} | " + " | ".join(cells) + f" | {d16} |")
        lines.append("\nRidge on held-out contact windows of the corpus the model was trained on; the factorial row "
                     "is the mean over its seeds, the frame-averaged model has one seed.")
    return lines + [""]


section = frame_averaged_lines


__all__ = ['NAME', 'FRAME_AVERAGED', 'specs', 'section', 'frame_averaged_lines']
