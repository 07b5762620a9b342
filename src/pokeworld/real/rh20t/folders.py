"""Scene folders: parsing their names, finding them under a root, and the skips a name alone decides."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from ...errors import DataError
from .config import ConvertConfig
from .format import ROBOTS, SCENE_RE
from .skips import SceneSkip


@dataclass
class SceneRef:
    """One scene folder found by :func:`scan`."""

    path: Path
    name: str
    task: int
    user: int
    scene: int
    cfg: int
    human: bool


def parse_scene_name(name: str) -> SceneRef | None:
    """Parse ``task_0001_user_0002_scene_0003_cfg_0007[_human]``; ``None`` if it is not a scene name."""
    m = SCENE_RE.match(name)
    if not m:
        return None
    t, u, s, c = (int(g) for g in m.groups()[:4])
    return SceneRef(Path(name), name, t, u, s, c, m.group(5) is not None)


def scan(root: str | os.PathLike) -> list[SceneRef]:
    """All scene folders under ``root`` (itself an ``RH20T_cfgN`` folder, or up to two levels above scenes)."""
    root = Path(root)
    if not root.is_dir():
        raise DataError(f"RH20T root {root} does not exist or is not a directory")
    found: dict[Path, SceneRef] = {}
    for parent in [root, *sorted(p for p in root.iterdir() if p.is_dir())]:
        for d in sorted(parent.iterdir()) if parent.is_dir() else []:
            ref = parse_scene_name(d.name) if d.is_dir() else None
            if ref is not None:
                ref.path = d
                found[d.resolve()] = ref
    return sorted(found.values(), key=lambda r: (r.name, str(r.path)))


def check_scene_name(ref: SceneRef, cfg: ConvertConfig) -> None:
    """Skips decided by the folder name alone: human demonstrations, unknown or other configurations."""
    if ref.human:
        raise SceneSkip("human_demo", f"{ref.name} is a human demonstration folder")
    if ref.cfg not in ROBOTS:
        raise SceneSkip("unknown_cfg", f"{ref.name}: cfg {ref.cfg} is not an RH20T configuration (1-7)")
    if ref.cfg != cfg.cfg:
        raise SceneSkip("other_cfg", f"{ref.name} is cfg {ref.cfg}, converting cfg {cfg.cfg}")
