"""The paper-budget queue of GPU allocations: which runs come first, and how a run is named on the command line
(``VARIANT@SEED``). Shared by the allocation driver (:mod:`.allocation_run`) and the plan of the next allocation
(:func:`.allocations.plan`)."""

from __future__ import annotations

from ..errors import ConfigError
from ..models.xjepa import VARIANTS

PRIORITY = ("VFX@0", "VF@0", "V@0", "VX_t@0", "VX_p@0", "VX@0", "VFX@1", "VF@1", "V@1", "VX_t@1", "VX_p@1", "VX@1")
"""The paper-budget queue: every factorial variant at seed 0 (the central comparison VFX against VF first), then the
same at seed 1 (the paper's tables are means of two seeds)."""

def parse_token(token: str) -> tuple[str, int]:
    """(variant, seed) of ``VARIANT`` or ``VARIANT@SEED``; ConfigError otherwise."""
    variant, at, seed = token.partition("@")
    if variant not in VARIANTS or (at and not seed.isdigit()):
        raise ConfigError(f"{token!r} is not a run (VARIANT or VARIANT@SEED, a variant of {list(VARIANTS)})")
    return variant, int(seed or 0)


def token(key: tuple[str, int]) -> str:
    return f"{key[0]}@{key[1]}"


def order_queue(requested: list[tuple[str, int]], finished: set[tuple[str, int]],
                resumable: set[tuple[str, int]]) -> list[tuple[str, int]]:
    """``requested`` without the finished runs, those with a checkpoint first, each group in the requested order."""
    todo = [r for r in dict.fromkeys(requested) if r not in finished]
    return [r for r in todo if r in resumable] + [r for r in todo if r not in resumable]


__all__ = ["PRIORITY", "parse_token", "token", "order_queue"]
