"""Which camera serial(s) a scene uses for the requested role, with the fallbacks along and beyond its list."""

from __future__ import annotations

from pathlib import Path

from .config import ConvertConfig
from .format import CAMERA_ROLES, IN_HAND_CALIB
from .skips import SceneSkip

IN_HAND_SERIALS: frozenset[str] = frozenset(
    [s for v in IN_HAND_CALIB.values() for s in v] + [s for r in CAMERA_ROLES.values() for s in r["close"]])
"""Every wrist (in-hand) camera serial of any configuration; never used as an external camera. The union over
cfgs, not the scene's cfg alone: the same physical cameras move between configurations (104422070042 is cfg2's
and cfg5's wrist camera), and a wrist view in place of a third-person one would silently change the viewpoint."""

EXTERNAL_ROLES = ("far", "side", "back")


def other_external_serials(present: set[str], role: str, cfg_num: int) -> list[str]:
    """External (non-wrist) camera serials present in a scene that are not on ``role``'s own list, in fallback
    order: serials listed under the cfg's other external roles first (role order far, side, back; list order
    within a role), then unlisted serials in sorted order."""
    roles = CAMERA_ROLES[cfg_num]
    own = set(roles[role])
    listed = [s for r in EXTERNAL_ROLES if r != role for s in roles[r]]
    order = list(dict.fromkeys(s for s in listed if s in present))
    order += sorted(present - set(order))
    return [s for s in order if s not in own and s not in IN_HAND_SERIALS]


def camera_serials(scene_dir: Path, cfg: ConvertConfig) -> list[tuple[str, str, int, str | None]]:
    """(role, serial, rank, fallback_kind) of the camera(s) used for ``cfg.camera`` in this scene.

    rank 0 is the role's first choice; ``0 < rank < len(list)`` a fallback down the role's own list
    (fallback_kind ``role_list``); an external role (far, side, back) none of whose serials is present falls back
    to another external camera of the scene (:func:`other_external_serials`, fallback_kind ``other_external``,
    rank ``len(list) + i``), so a recording is not dropped because its third-person camera has an unlisted serial.
    The wrist role (close) never falls back to an external camera; an explicit ``camera_serials`` override never
    falls back (rank -1). fallback_kind is None when no fallback was needed.
    """
    present = {d.name[4:] for d in scene_dir.iterdir() if d.is_dir() and d.name.startswith("cam_")}
    roles = ["far", "close"] if cfg.camera == "two_view" else [cfg.camera]
    if cfg.camera_serials:
        chosen = list(cfg.camera_serials)
        missing = [s for s in chosen if s not in present]
        if missing:
            raise SceneSkip("missing_camera", f"camera folder(s) cam_{missing[0]} absent (present: {sorted(present)})")
        return [(r, s, -1, None) for r, s in zip(roles, chosen)]
    out = []
    for role in roles:
        cands = CAMERA_ROLES[cfg.cfg][role]
        rank = next((i for i, s in enumerate(cands) if s in present), None)
        if rank is not None:
            out.append((role, cands[rank], rank, "role_list" if rank else None))
            continue
        others = other_external_serials(present, role, cfg.cfg) if role in EXTERNAL_ROLES else []
        if not others:
            kind = "external" if role in EXTERNAL_ROLES else "wrist"
            raise SceneSkip("missing_camera", f"no '{role}' camera (serials {list(cands)}) and no other {kind} "
                                              f"camera among {sorted(present)}")
        out.append((role, others[0], len(cands), "other_external"))
    return out
