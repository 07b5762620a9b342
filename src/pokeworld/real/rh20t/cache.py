"""The per-scene conversion cache, keyed by every setting that changes per-scene processing, so runs resume."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

from ...errors import DataError
from ...io import OwnedDir, read_json, remove_own_file, save_npz, write_json
from .config import ConvertConfig, out_dir
from .folders import SceneRef, check_scene_name
from .scene import process_scene
from .skips import SceneSkip

PIPELINE_VERSION = 4
"""Bumped whenever per-scene processing changes, so stale scene caches are never reused. 3: a scene without any
of its role's serials falls back to another external camera (cached ``missing_camera`` skips are stale), camera
rows carry ``fallback_kind``, pickles are read by the restricted unpickler (``unsafe_pickle``). 4: pickles are
unpickled in a child process and dtype / array BUILDs are checked (``unsafe_pickle``), special files
(``special_file``), paths leading outside the root (``outside_root``) and oversized frames (``huge_image``) skip."""

_CACHE_FIELDS = ("cfg", "camera", "camera_serials", "image_size", "crop", "hz", "min_rating", "require_calib_dir",
                 "gripper_field", "max_gap_s", "frame_tolerance_s", "max_abs_pos_m", "max_abs_ft",
                 "max_bad_record_fraction", "ft_camera_fallback")


SCENE_CACHE = OwnedDir(files=(r".+\.npz", r".+\.skip\.json"))
"""What a conversion's scene cache folder holds: one ``.npz`` per converted scene or a ``.skip.json`` per skip."""


def cache_dir(cfg: ConvertConfig) -> Path:
    """``<out>.cache/<key>``: the key hashes every config field that changes per-scene processing."""
    key = {f: getattr(cfg, f) for f in _CACHE_FIELDS}
    key["pipeline_version"] = PIPELINE_VERSION
    digest = hashlib.sha256(json.dumps(key, sort_keys=True, default=list).encode()).hexdigest()[:12]
    o = out_dir(cfg)
    return o.with_name(o.name + ".cache") / digest


def _cache_file(cdir: Path, ref: SceneRef) -> Path:
    tag = hashlib.sha256(str(ref.path.resolve()).encode()).hexdigest()[:8]  # same name in two roots
    return cdir / f"{ref.name}-{tag}"


def convert_scene_cached(ref: SceneRef, cfg: ConvertConfig, cdir: Path) -> tuple[dict | None, dict | None]:
    """(arrays, None) for a converted scene or (None, skip record); results are cached atomically."""
    try:  # decided by the folder name alone: nothing to cache
        check_scene_name(ref, cfg)
    except SceneSkip as e:
        return None, {"scene": ref.name, "path": str(ref.path), "reason": e.reason, "message": e.message}
    base = _cache_file(cdir, ref)
    ok, skip = base.with_suffix(".npz"), base.with_suffix(".skip.json")
    if ok.exists():
        try:
            with np.load(ok, allow_pickle=False) as z:
                return {k: z[k] for k in z.files}, None
        except Exception:
            remove_own_file(ok)  # damaged cache entry: recompute
    if skip.exists():
        try:
            return None, read_json(skip, "a cached skip record")
        except DataError:
            remove_own_file(skip)  # damaged cache entry: recompute
    try:
        arrays = process_scene(ref, cfg)
    except SceneSkip as e:
        rec = {"scene": ref.name, "path": str(ref.path), "reason": e.reason, "message": e.message}
        if e.cacheable:
            write_json(skip, rec)
        return None, rec
    except (KeyboardInterrupt, SystemExit):
        raise
    except Exception as e:  # never stop a long run for one scene; not cached so a fixed bug re-runs it
        return None, {"scene": ref.name, "path": str(ref.path), "reason": "unexpected_error",
                      "message": f"{type(e).__name__}: {e}"}
    save_npz(ok, arrays)
    return arrays, None
