"""Reading the pickled numeric streams (TCP, F/T, gripper) and dropping or rejecting their bad records."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from ..npy_child import load_npy_item_isolated
from ..regular_files import NotRegularFileError
from ..safe_pickle import UnsafePickleError
from .calibration import base_to_camera_rotations
from .config import ConvertConfig
from .files import calibration_folder, dataset_file
from .skips import SceneSkip


def load_untrusted_npy(path: Path, root: Path | None, what: str) -> Any:
    """An ``.npy`` file of the dataset, checked by :func:`~.files.dataset_file` and read by the restricted unpickler
    in the child process of :mod:`pokeworld.real.npy_child` (0-d object arrays unwrapped). Raises SceneSkip
    ``missing_stream`` / ``special_file`` / ``outside_root`` / ``unsafe_pickle``; other exceptions mean a damaged
    file."""
    real = dataset_file(path, root, what)
    if real is None:
        raise SceneSkip("missing_stream", f"{what} file {path} is absent")
    try:
        return load_npy_item_isolated(real)
    except UnsafePickleError as e:
        raise SceneSkip("unsafe_pickle", f"{path}: {e}") from None
    except NotRegularFileError as e:  # swapped for a FIFO after the check
        raise SceneSkip("special_file", f"{what}: {e}") from None


def load_pickled_dict(path: Path, what: str, root: Path | None = None) -> Any:
    """The dict pickled in an RH20T ``.npy`` file (a 0-d object array), read by :func:`load_untrusted_npy` (never
    numpy's unrestricted pickle loading, never in this process). ``root``: the dataset root no file may resolve
    outside of (``None``: the file's own folder)."""
    try:
        obj = load_untrusted_npy(path, root, what)
    except SceneSkip:
        raise
    except Exception as e:  # pickle / header / value errors all mean a damaged file
        raise SceneSkip("bad_stream", f"cannot read {path}: {type(e).__name__}: {e}") from None
    if not isinstance(obj, dict):
        raise SceneSkip("bad_stream", f"{path} holds {type(obj).__name__}, expected a pickled dict")
    return obj


def _sorted_unique(ts: np.ndarray, vals: np.ndarray, what: str) -> tuple[np.ndarray, np.ndarray]:
    if ts.size == 0:
        raise SceneSkip("bad_stream", f"{what} has no samples")
    if not np.all((ts > 1e12) & (ts < 1e13)):
        raise SceneSkip("bad_timestamps", f"{what} timestamps are not 13-digit milliseconds (e.g. {ts.flat[0]})")
    order = np.argsort(ts, kind="stable")
    ts, vals = ts[order], vals[order]
    keep = np.concatenate([[True], np.diff(ts) > 0])  # merged serials can repeat a timestamp: keep the first
    return ts[keep], vals[keep]


def read_records(obj: dict, key: str, dim: int, what: str,
                 transform: dict[str, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``{serial: [{'timestamp': ms, key: vec}, ...]}`` merged over serials -> raw (ts (N,), values (N, dim)).

    Unsorted and unchecked (see :func:`clean_records`). ``transform`` maps serial -> (dim, dim) matrix applied to
    that serial's vectors (used to rotate camera-frame F/T into the base frame); serials missing from it are left out.
    """
    ts, vals = [], []
    try:
        for serial, items in obj.items():
            if transform is not None and str(serial) not in transform:
                continue
            m = None if transform is None else transform[str(serial)]
            for it in items:
                v = np.asarray(it[key], dtype=np.float64).reshape(-1)
                ts.append(int(it["timestamp"]))
                vals.append(v if m is None or v.shape != (dim,) else m @ v)
        ts_arr = np.asarray(ts, np.int64)
    # OverflowError: an infinite timestamp (int(inf)) or one beyond int64
    except (KeyError, TypeError, ValueError, OverflowError) as e:
        raise SceneSkip("bad_stream", f"{what}: expected {{serial: [{{'timestamp', '{key}'}}]}} "
                                      f"({type(e).__name__}: {e})") from None
    bad = [v.shape for v in vals if v.shape != (dim,)]
    if bad:
        raise SceneSkip("bad_stream", f"{what}['{key}'] must have {dim} values, got shape {bad[0]}")
    return ts_arr, np.asarray(vals, np.float64).reshape(-1, dim)


def read_gripper(obj: dict, field: str) -> tuple[np.ndarray, np.ndarray]:
    """``{serial: {ts: {field: [width_mm, ...]}}}`` merged over serials -> raw (ts (N,), width_mm (N, 1))."""
    ts, vals = [], []
    try:
        for serial, per_ts in obj.items():
            for t, rec in per_ts.items():
                ts.append(int(t))
                vals.append(float(np.asarray(rec[field], dtype=np.float64).reshape(-1)[0]))
        ts_arr = np.asarray(ts, np.int64)
    except (KeyError, TypeError, ValueError, IndexError, AttributeError, OverflowError) as e:
        raise SceneSkip("bad_stream", f"gripper.npy: expected {{serial: {{ts: {{'{field}': [width_mm, ...]}}}}}} "
                                      f"({type(e).__name__}: {e})") from None
    return ts_arr, np.asarray(vals, np.float64).reshape(-1, 1)


BAD_RECORD_KINDS = ("non_finite", "zero", "overflow", "out_of_range", "bad_quaternion")
"""Kinds of isolated bad records that are dropped (and counted per stream) instead of skipping the scene."""
OVERFLOW_ABS = 1e6
"""A value beyond this magnitude is an overflowed reading (RH20T has TCP values like -9.4e36)."""


def classify_records(vals: np.ndarray, stream: str, cfg: ConvertConfig) -> np.ndarray:
    """Per-record code: 0 good, else 1 + index into :data:`BAD_RECORD_KINDS` (first matching kind wins).

    ``stream`` is ``tcp`` (xyz m + quaternion), ``ft`` (force N, torque N m) or ``gripper`` (width mm).
    """
    code = np.zeros(len(vals), np.int8)

    def mark(mask, kind):
        code[mask & (code == 0)] = 1 + BAD_RECORD_KINDS.index(kind)

    with np.errstate(invalid="ignore", over="ignore"):
        mark(~np.isfinite(vals).all(1), "non_finite")
        if stream == "tcp":
            mark((vals == 0).all(1), "zero")
        mark((np.abs(vals) > OVERFLOW_ABS).any(1), "overflow")
        if stream == "tcp":
            mark(np.abs(vals[:, :3]).max(1) > cfg.max_abs_pos_m, "out_of_range")
            mark(np.abs(np.linalg.norm(vals[:, 3:], axis=1) - 1) > 0.05, "bad_quaternion")
        elif stream == "ft":
            mark((np.abs(vals) > cfg.max_abs_ft).any(1), "out_of_range")
    return code


def clean_records(ts: np.ndarray, vals: np.ndarray, stream: str, what: str,
                  cfg: ConvertConfig) -> tuple[np.ndarray, np.ndarray, dict[str, int]]:
    """Drop (and count) isolated bad records, then sort and de-duplicate; skip the scene if the stream is unusable.

    Returns (ts, vals, {kind: n_dropped}). More than ``cfg.max_bad_record_fraction`` bad records, or fewer than 2
    good ones, raise :class:`SceneSkip` with a reason named after the dominant kind of defect.
    """
    if len(ts) == 0:
        raise SceneSkip("bad_stream", f"{what} has no samples")
    code = classify_records(vals, stream, cfg)
    bad = code > 0
    counts = {k: int((code == i + 1).sum()) for i, k in enumerate(BAD_RECORD_KINDS) if (code == i + 1).any()}
    frac = float(bad.mean())
    if frac > cfg.max_bad_record_fraction or (~bad).sum() < 2:
        kind = max(counts, key=counts.get)
        share = f"{int(bad.sum())} of {len(bad)} records bad ({counts})"
        if kind == "non_finite":
            raise SceneSkip("nan_stream", f"{what}: {share}, non-finite values")
        if kind == "zero":
            raise SceneSkip("zero_tcp", f"{what}: {share}; all-zero TCP records mean the pose was not logged")
        if kind == "overflow" or (kind == "out_of_range" and stream != "tcp"):
            raise SceneSkip("overflow_stream", f"{what}: {share}; overflowed / out-of-range values "
                                               f"(e.g. {vals[bad][0].tolist()})")
        if kind == "out_of_range":
            big = np.abs(vals[code == 1 + BAD_RECORD_KINDS.index("out_of_range"), :3]).max(1)
            hint = (" (millimetres instead of metres?)" if np.median(big) < 1000 * cfg.max_abs_pos_m else "")
            raise SceneSkip("bad_units", f"{what}: {share}; |tcp position| reaches {big.max():.3g} > "
                                         f"{cfg.max_abs_pos_m} m{hint}")
        raise SceneSkip("bad_units", f"{what}: {share}; tcp quaternion norms deviate from 1 (wrong order / units?)")
    ts, vals = _sorted_unique(ts[~bad], vals[~bad], what)
    return ts, vals, counts


def read_ft(d: Path, meta: dict, cfg: ConvertConfig,
            root: Path | None = None) -> tuple[np.ndarray, np.ndarray, str, int]:
    """Zeroed base-frame F/T records (raw ts, values), their source (``base`` or ``camera_via_calib``) and the
    number of camera-frame records left out because their serial has no calibration extrinsics."""
    tr = d / "transformed"
    base, cam = tr / "force_torque_base.npy", tr / "force_torque.npy"
    if os.path.lexists(base) or not os.path.lexists(cam):
        ts, v = read_records(load_pickled_dict(base, "transformed/force_torque_base.npy", root), "zeroed", 6,
                             "force_torque_base.npy")
        return ts, v, "base", 0
    if not cfg.ft_camera_fallback:
        raise SceneSkip("camera_frame_ft", "force_torque_base.npy absent, only the camera-frame force_torque.npy is "
                                           "present and ft_camera_fallback is off")
    rots = base_to_camera_rotations(calibration_folder(d, meta.get("calib"), root), cfg.cfg, root)
    to_base = {s: np.kron(np.eye(2), r.T) for s, r in rots.items()}  # force and torque rotate alike
    obj = load_pickled_dict(cam, "transformed/force_torque.npy", root)
    missing = sorted(str(s) for s in obj if str(s) not in to_base)
    ts, v = read_records(obj, "zeroed", 6, "force_torque.npy (camera frame)", transform=to_base)
    if len(ts) == 0:
        raise SceneSkip("camera_frame_ft", f"no serial of force_torque.npy ({missing}) has calibration extrinsics")
    return ts, v, "camera_via_calib", sum(len(obj[s]) for s in obj if str(s) not in to_base)
