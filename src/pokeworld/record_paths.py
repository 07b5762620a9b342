"""Records name no machine's paths: an absolute path in a record becomes a placeholder.

A record is written on the machine that computed it, and its provenance (commands, run folders, stores) holds that
machine's paths, which mean nothing elsewhere. Each absolute path becomes ``<machine>/`` followed by what locates
it in the map's own layout: from the last ``runs/``, ``data/``, ``models/``, ``out/`` or ``map/`` folder on (a
run's or a store's name), else the file or folder's own name; inside a longer string (a command line) each path is
replaced the same way. Numbers are never touched. Used by the merge of GPU allocations before it writes, and by
``scripts/record_paths.py`` over the committed records.
"""

from __future__ import annotations

import re
from typing import Any

PATH = re.compile(r"(?<![\w.<>-])/(?:work|tmp|root|home|opt|mnt|scratch|var|data)/[^\s'\"`,;:)\]}]*")
ANCHORS = ("runs", "data", "models", "out", "map")


def placeholder(path: str) -> str:
    """``<machine>/`` and what locates ``path`` in the map's layout (see the module docstring)."""
    parts = [p for p in path.split("/") if p]
    for i in range(len(parts) - 1, -1, -1):
        if parts[i] in ANCHORS and i < len(parts) - 1:
            return "<machine>/" + "/".join(parts[i:])
    return "<machine>/" + (parts[-1] if parts else "")


def without_machine_paths(value: Any) -> Any:
    """``value`` (a parsed record) with every absolute path in its strings, keys included, replaced by
    :func:`placeholder`; two keys of one table that would become one are a ValueError (nothing is dropped)."""
    if isinstance(value, dict):
        out: dict = {}
        for k, v in value.items():
            key = without_machine_paths(k) if isinstance(k, str) else k
            if key in out:
                raise ValueError(f"two keys become {key!r} without their machine paths; rename one by hand")
            out[key] = without_machine_paths(v)
        return out
    if isinstance(value, list):
        return [without_machine_paths(v) for v in value]
    if isinstance(value, str):
        return PATH.sub(lambda m: placeholder(m.group(0)), value)
    return value


__all__ = ["PATH", "ANCHORS", "placeholder", "without_machine_paths"]
