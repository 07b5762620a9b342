"""Named presets layered over dataclass defaults (dreamerv3 style).

Every experiment config is a ``@dataclass`` whose fields carry docstrings (tyro
shows them as ``--help``). A module declares ``PRESETS = {"tiny": {...},
"cpu": {...}, "paper": {...}}``: each preset is a dict of field overrides
applied on top of the dataclass defaults. Nested dataclasses are overridden
with nested dicts.
"""

from __future__ import annotations

import dataclasses
import json
from typing import Any, Mapping, TypeVar

from .errors import ConfigError

PRESET_NAMES = ("tiny", "cpu", "paper")
T = TypeVar("T")


def apply_overrides(cfg: T, overrides: Mapping[str, Any]) -> T:
    """Return a copy of ``cfg`` with ``overrides`` applied (recursively for nested dataclasses)."""
    fields = {f.name: f for f in dataclasses.fields(cfg)}
    changes: dict[str, Any] = {}
    for key, value in overrides.items():
        if key not in fields:
            raise ConfigError(f"{type(cfg).__name__} has no field {key!r}; known fields: {sorted(fields)}")
        current = getattr(cfg, key)
        if dataclasses.is_dataclass(current) and isinstance(value, Mapping):
            changes[key] = apply_overrides(current, value)
        else:
            changes[key] = value
    return dataclasses.replace(cfg, **changes)


def from_preset(cls: type[T], presets: Mapping[str, Mapping[str, Any]], preset: str, **overrides: Any) -> T:
    """Build ``cls()`` with the named preset and then ``overrides`` applied."""
    if preset not in presets:
        raise ConfigError(f"unknown preset {preset!r} for {cls.__name__}; choose one of {sorted(presets)}")
    cfg = apply_overrides(cls(), presets[preset])
    if overrides:
        cfg = apply_overrides(cfg, overrides)
    return cfg


def to_dict(cfg: Any) -> dict:
    """JSON-serialisable dict of a (possibly nested) dataclass config."""
    return json.loads(json.dumps(dataclasses.asdict(cfg), default=str))


def from_dict(cls: type[T], data: Mapping[str, Any]) -> T:
    """Inverse of :func:`to_dict` for our flat-or-nested dataclass configs."""
    return apply_overrides(cls(), data)
