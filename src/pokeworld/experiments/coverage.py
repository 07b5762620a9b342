"""Data coverage (paper App. C): VFX trained on a contact-poor corpus, probed on the standard one."""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..evaluate.tables import simple_table
from .runs import RunSpec, spec

if TYPE_CHECKING:
    from .config import MapConfig

COVERAGE = {  # App. C: VFX on contact-poor data vs standard
    "standard": {"log_k": 0.50, "log_m": 0.29, "object_pos": 0.98, "object_vel": 0.79},
    "contact_poor": {"log_k": 0.05, "log_m": 0.11, "object_pos": 0.87, "object_vel": 0.58},
}


NAME = "coverage"


def specs(c: MapConfig) -> list[RunSpec]:
    return [spec("coverage", "VFX", c.seeds[0], c.sigreg_weight, corpus=corp) for corp in ("standard", "contact_poor")]


def section(results: dict) -> list[str]:
    """VFX trained on the contact-poor corpus beside the standard one, both probed on the standard corpus."""
    return simple_table(results, NAME, "Data coverage (VFX; probes on the standard corpus)", lambda r: r["corpus"], COVERAGE)


__all__ = ['NAME', 'COVERAGE', 'specs', 'section']
