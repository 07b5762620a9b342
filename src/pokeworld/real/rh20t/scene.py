"""One scene end to end: metadata checks, streams and cameras read, resampled onto the regular time grid."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from .cameras import camera_serials
from .config import ConvertConfig
from .files import calibration_folder, dataset_file, read_dataset_file, scene_root
from .folders import SceneRef, check_scene_name
from .format import CAMERA_ROTATION
from .records import (
    clean_records,
    load_pickled_dict,
    read_ft,
    read_gripper,
    read_records,
)
from .rotations import align_quaternions
from .skips import SceneSkip
from .video import read_camera


def interp_columns(t_grid: np.ndarray, ts: np.ndarray, vals: np.ndarray) -> np.ndarray:
    """Linear interpolation of every column of ``vals`` (sampled at ``ts``) at ``t_grid``."""
    return np.stack([np.interp(t_grid, ts, vals[:, j]) for j in range(vals.shape[1])], axis=1)


def _metadata_time(meta: dict, keys: tuple[str, ...]) -> int | None:
    for k in keys:
        v = meta.get(k)
        if isinstance(v, (int, float)) and 1e12 < v < 1e13:
            return int(v)
    return None


MAX_METADATA_BYTES = 1 << 20
"""Largest metadata.json read (RH20T's are a few hundred bytes)."""


def read_metadata(d: Path, root: Path, cfg: ConvertConfig) -> tuple[dict, int]:
    """(metadata, rating) of scene folder ``d``, after the checks metadata alone decides: present, a regular file
    inside ``root``, valid JSON with an integer rating >= ``min_rating``, a calibration id that names a folder
    under ``calib/`` (never outside the root), and that folder present if ``require_calib_dir``."""
    mpath = d / "metadata.json"
    if dataset_file(mpath, root, "metadata.json") is None:
        raise SceneSkip("missing_metadata", f"{mpath} is absent")
    try:
        meta = json.loads(read_dataset_file(mpath, root, "metadata.json", MAX_METADATA_BYTES).decode("utf-8"))
        rating = int(meta["rating"])
    except SceneSkip:  # a DataError, hence a ValueError: the file's kind, not its content
        raise
    # OverflowError: json reads Infinity as a float, and int(inf) overflows; OSError: vanished meanwhile
    except (json.JSONDecodeError, KeyError, TypeError, ValueError, UnicodeDecodeError, OverflowError, OSError) as e:
        raise SceneSkip("bad_metadata", f"{mpath}: {type(e).__name__}: {e}") from None
    if rating < cfg.min_rating:
        raise SceneSkip("low_rating", f"rating {rating} < min_rating {cfg.min_rating}")
    calib = meta.get("calib")
    if calib is None or calib == -1 or calib == "-1":
        raise SceneSkip("missing_calib", f"metadata calib is {calib!r}")
    folder = calibration_folder(d, calib, root)
    if cfg.require_calib_dir and not folder.is_dir():
        raise SceneSkip("missing_calib", f"calibration folder {folder} is absent")
    return meta, rating


def process_scene(ref: SceneRef, cfg: ConvertConfig) -> dict[str, np.ndarray]:
    """Read, check and resample one scene; raise :class:`SceneSkip` with a reason on any defect."""
    d = ref.path
    check_scene_name(ref, cfg)
    root = scene_root(cfg.root, d)
    meta, rating = read_metadata(d, root, cfg)
    # numeric streams (robot base frame, SI units per rh20t_api's transformed/ folder); isolated bad records
    # (NaN, overflow, all-zero TCP...) are dropped and counted, an unusable stream skips the scene
    tr = d / "transformed"
    dropped: dict[str, dict[str, int]] = {}
    raw_tcp = read_records(load_pickled_dict(tr / "tcp_base.npy", "transformed/tcp_base.npy", root), "tcp", 7,
                           "tcp_base.npy")
    tcp_ts, tcp, dropped["tcp_base"] = clean_records(*raw_tcp, "tcp", "tcp_base.npy", cfg)
    ft_raw_ts, ft_raw, ft_source, uncalibrated = read_ft(d, meta, cfg, root)
    ft_name = "force_torque_base" if ft_source == "base" else "force_torque"
    ft_ts, ft, dropped[ft_name] = clean_records(ft_raw_ts, ft_raw, "ft", f"{ft_name}.npy zeroed", cfg)
    if uncalibrated:  # records of serials without extrinsics cannot be rotated into the base frame
        dropped[ft_name] = {**dropped[ft_name], "no_extrinsics": uncalibrated}
    raw_gr = read_gripper(load_pickled_dict(tr / "gripper.npy", "transformed/gripper.npy", root), cfg.gripper_field)
    gr_ts, grip, dropped["gripper"] = clean_records(*raw_gr, "gripper", "gripper.npy", cfg)
    dropped = {k: v for k, v in dropped.items() if v}
    cams = camera_serials(d, cfg)
    serials = [c[1] for c in cams]
    half = cfg.camera == "two_view"
    out_hw = (cfg.image_size, cfg.image_size // 2 if half else cfg.image_size)
    cam_ts = [read_camera(d / f"cam_{s}", None, cfg, out_hw, root=root)[0] for s in serials]
    # only the span every stream and camera covers (within the metadata's start / finish) is interpolated,
    # never extrapolated
    starts = [tcp_ts[0], ft_ts[0], gr_ts[0], *(c[0] for c in cam_ts)]
    ends = [tcp_ts[-1], ft_ts[-1], gr_ts[-1], *(c[-1] for c in cam_ts)]
    t0, t1 = max(starts), min(ends)
    ms, mf = _metadata_time(meta, ("start_time",)), _metadata_time(meta, ("finish_time", "end_time"))
    if ms is not None:
        t0 = max(t0, ms)
    if mf is not None:
        t1 = min(t1, mf)
    if t1 <= t0:
        raise SceneSkip("bad_timestamps", f"streams / metadata times do not overlap ({t0} >= {t1})")
    step_ms = 1000.0 / cfg.hz
    t_grid = t0 + step_ms * np.arange(int(math.floor((t1 - t0) / step_ms + 1e-9)) + 1)
    for name, ts in (("tcp_base", tcp_ts), (ft_name, ft_ts), ("gripper", gr_ts)):
        inside = ts[(ts >= t0) & (ts <= t1)]
        edges = np.concatenate([[t0], inside, [t1]])
        gap = np.diff(edges).max() / 1000.0
        if gap > cfg.max_gap_s:
            raise SceneSkip("stream_gap", f"{name} has a {gap:.2f} s gap (> max_gap_s={cfg.max_gap_s}) "
                                          f"after dropping {dropped.get(name, {})} bad records")
    views = [read_camera(d / f"cam_{s}", t_grid, cfg, out_hw, CAMERA_ROTATION.get((cfg.cfg, s), 0), root)[1]
             for s in serials]
    frames = np.concatenate(views, axis=2) if half else views[0]
    pos = interp_columns(t_grid, tcp_ts, tcp[:, :3])
    quat = interp_columns(t_grid, tcp_ts, align_quaternions(tcp[:, 3:]))
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    ft_g = interp_columns(t_grid, ft_ts, ft)
    grip_m = interp_columns(t_grid, gr_ts, grip)[:, 0] / 1000.0
    info = {"cameras": [{"role": r, "serial": sn, "rank": k, "fallback": k > 0, "fallback_kind": kind,
                         "rotation": CAMERA_ROTATION.get((cfg.cfg, sn), 0)} for r, sn, k, kind in cams],
            "dropped_records": dropped, "ft_source": ft_source}
    return {
        "frames": frames.astype(np.uint8), "pos": pos, "quat": quat, "ft": ft_g, "grip": grip_m,
        "t_s": (t_grid - t0) / 1000.0, "t0_ms": np.asarray(t0, np.int64),
        "rating": np.asarray(rating), "serials": np.asarray(",".join(serials)), "info": np.asarray(json.dumps(info)),
    }
