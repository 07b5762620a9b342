"""Dose-response 2 (paper App. C Table "dose2"): starving an acquired parameter by scaling the contact-frame
touch loss."""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..evaluate.tables import dagger, fmt, ours_paper, probe, run_gate_failed
from ..train.config import field_defaults
from .runs import RunSpec, spec

if TYPE_CHECKING:
    from .config import MapConfig

DOSE_TOUCH = {  # App. C Table "dose2": contact-frame touch-loss weight -> ridge readouts (4 is the default)
    4.0: {"log_k": 0.50, "log_m": 0.29, "gamma": 0.12},
    1.0: {"log_k": 0.37, "log_m": 0.28, "gamma": 0.14},
    0.25: {"log_k": 0.12, "log_m": 0.26, "gamma": 0.13},
    0.0: {"log_k": -0.005, "log_m": 0.21, "gamma": 0.14},
}


NAME = "dose_touch"


def specs(c: MapConfig) -> list[RunSpec]:
    return [spec("dose_touch", "VFX", c.seeds[0], c.sigreg_weight, touch_contact_weight=w) for w in (4.0, 1.0, 0.25, 0.0)]


def dose_touch_table(results: dict) -> list[str]:
    """App. C Table "dose2": contact-frame touch-loss weight -> log k, log m, γ (ours / paper)."""
    if "dose_touch" not in results["experiments"]:
        return []
    lines = ["## Dose-response 2: starving an acquired parameter (VFX; contact-frame touch-loss weight)", "",
             "| touch weight | log k | log m | γ | obj. position |", "|---|---|---|---|---|"]
    default = field_defaults()["touch_contact_weight"]
    for name in results["experiments"]["dose_touch"]:
        r = results["runs"][name]
        w = float(r["train"].get("touch_contact_weight", default))
        p = DOSE_TOUCH.get(w, {})
        cells = [ours_paper(probe(r, q), p.get(q)) + dagger(run_gate_failed(results, r, q))
                 for q in ("log_k", "log_m", "gamma")]
        label = f"{w:g}" + (" (default)" if w == default else "")
        lines.append(f"| {label} | " + " | ".join(cells) + f" | {fmt(probe(r, 'object_pos'))} |")
    lines.append("\nCells read ours / paper (ridge, contact windows). Data, probe sets and certificates are the "
                 "same in every row; only the touch loss on contact frames is scaled.")
    return lines + [""]


section = dose_touch_table


__all__ = ['NAME', 'DOSE_TOUCH', 'specs', 'section', 'dose_touch_table']
