"""Tiny RH20T scenes in the real on-disk layout, with known analytic signals (used by the tests).

Layout written under ``<root>/RH20T_cfg<N>/`` (see docs/rh20t.md for where each fact comes from)::

    calib/<calib_ts>/{intrinsics,extrinsics}.npy, tcp.npy
    task_NNNN_user_NNNN_scene_NNNN_cfg_NNNN[_human]/
        metadata.json                       {"calib", "rating", "start_time", "finish_time", ...}
        cam_<serial>/color.mp4 + timestamps.npy   (pickled {'color': [ms], 'depth': [ms]})
        cam_<serial>/color/<13-digit ms>.jpg      (the "extracted" variant)
        transformed/tcp_base.npy            {serial: [{'timestamp', 'tcp' (xyz m + quat wxyz), 'robot_ft'}]}
        transformed/force_torque_base.npy   {serial: [{'timestamp', 'raw' (6), 'zeroed' (6)}]}
        transformed/gripper.npy             {serial: {ts: {'gripper_command': [mm, ..], 'gripper_info': [mm, ..]}}}
        transformed/joint.npy               {serial: {ts: (7,) array}}

Every stream of a camera serial is sampled at that camera's irregular (~10 Hz, ±30 ms jitter)
frame timestamps, so merging serials gives an irregular ~20 Hz stream, as in RH20T. The signals
are functions of time since the scene's ``t0_ms`` (:func:`signals`, :func:`image_level`): piecewise
linear where exactness under linear interpolation matters, so tests can check converted values.
"""

from __future__ import annotations

import io
import json
import os
from pathlib import Path

import numpy as np

from ..io import create_new
from .rh20t import CAMERA_ROLES

T0_MS = 1_690_000_000_000
FT_OFFSET = np.array([5.0, -3.0, 12.0, 0.1, 0.1, 0.1])
"""raw = zeroed + FT_OFFSET, so a converter reading 'raw' instead of 'zeroed' is caught."""
TILT_X = 0.3
"""Fixed tilt about x (rad) composed with the yaw, so a wrong quaternion order is caught."""
IMG_W, IMG_H = 128, 72
"""Fixture image size (16:9 like RH20T's 640x360); columns outside the centred square are black."""

DEFECTS = ("human", "low_rating", "missing_calib", "missing_ft", "nan_ft", "empty_video", "truncated_video",
           "corrupt_video", "unknown_cfg", "missing_camera", "too_short", "mm_units", "nan_ft_isolated",
           "far_fallback")
EXPECTED_REASON: dict[str, str | None] = {
    "human": "human_demo", "low_rating": "low_rating", "missing_calib": "missing_calib",
    "missing_ft": "missing_stream", "nan_ft": "nan_stream", "empty_video": "empty_video",
    "truncated_video": "truncated_video", "corrupt_video": "unreadable_video", "unknown_cfg": "unknown_cfg",
    "missing_camera": "missing_camera", "too_short": "too_short", "mm_units": "bad_units",
    "nan_ft_isolated": None, "far_fallback": None,
}
"""Skip reason per defect; ``None``: the scene is converted anyway (isolated NaN records dropped and counted;
the far camera found under its second serial)."""


def scene_params(k: int) -> dict:
    """Per-scene signal parameters (k = scene counter): y-velocity, yaw rate, contact start time."""
    return {"vy": 0.005 * (1 + k % 3), "yaw_rate": 0.05 + 0.01 * (k % 2), "contact_start": 1.0 + 0.5 * (k % 2)}


def force_z(t: np.ndarray, p: dict) -> np.ndarray:
    """Piecewise-linear press: 0 N, ramp to -30 N over 3 s (|F| crosses 10 N 1 s in), hold 1 s, release over 1.5 s."""
    c = p["contact_start"]
    return np.interp(t, [c, c + 3.0, c + 4.0, c + 5.5], [0.0, -30.0, -30.0, 0.0])


def force_breakpoints(p: dict) -> np.ndarray:
    c = p["contact_start"]
    return np.array([c, c + 3.0, c + 4.0, c + 5.5])


def signals(t: np.ndarray, p: dict) -> dict[str, np.ndarray]:
    """Ground truth at times ``t`` [s since t0_ms]: pos (m), quat (w,x,y,z), gripper mm, zeroed and raw F/T."""
    t = np.asarray(t, np.float64)
    pos = np.stack([0.40 + 0.02 * t, -0.10 + p["vy"] * t, 0.30 - 0.01 * t], -1)
    yaw = 0.1 + p["yaw_rate"] * t
    cz, sz, cx, sx = np.cos(yaw / 2), np.sin(yaw / 2), np.cos(TILT_X / 2), np.sin(TILT_X / 2)
    quat = np.stack([cz * cx, cz * sx, sz * sx, sz * cx], -1)  # q_z(yaw) * q_x(TILT_X), (w, x, y, z)
    ft = np.stack([np.full_like(t, 0.5), np.full_like(t, -0.3), force_z(t, p),
                   0.01 * t, np.full_like(t, 0.02), np.full_like(t, -0.05)], -1)
    return {"pos": pos, "quat": quat, "gripper_info_mm": 80.0 - 6.0 * t, "gripper_command_mm": 75.0 - 6.0 * t,
            "ft_zeroed": ft, "ft_raw": ft + FT_OFFSET}


def image_level(t: np.ndarray, role: str) -> np.ndarray:
    """Uniform gray level of the centred square at time ``t`` [s]: rising for far, falling for close."""
    t = np.asarray(t, np.float64)
    return np.round(20 + 30 * t) if role == "far" else np.round(235 - 30 * t)


def _frame(level: float) -> np.ndarray:
    img = np.zeros((IMG_H, IMG_W, 3), np.uint8)
    x0 = (IMG_W - IMG_H) // 2
    img[:, x0: x0 + IMG_H] = int(np.clip(level, 0, 255))
    return img


def fresh(path: Path) -> Path:
    """``path``, which must not exist yet (not even as a link). Every file these fixtures write is new: they build
    a corpus in a folder of their own (a test's temporary folder, or :func:`pokeworld.io.atomic_path`'s private
    folder in :mod:`pokeworld.real.synthetic`), so an existing name means a caller pointed them at someone else's
    files, and nothing is overwritten or written through a link."""
    if os.path.lexists(path):
        raise FileExistsError(f"{path} exists; the RH20T fixtures write only new files into a folder of their own")
    return path


def write_mp4(path: Path, frames: list[np.ndarray], fps: int = 10, options: dict[str, str] | None = None) -> str:
    """Encode RGB frames with libx264 (falling back to mpeg4) into the new file ``path``; returns the codec used.

    ``options`` are libx264 encoder options (e.g. ``{"preset": "ultrafast"}``), ignored by the mpeg4 fallback.
    """
    import av

    fresh(path)  # checked once: the fallback codec rewrites what a failed first attempt began

    last = None
    for codec in ("libx264", "mpeg4"):
        try:
            with av.open(str(path), "w") as c:
                s = c.add_stream(codec, rate=fps, options=(options or {}) if codec == "libx264" else {})
                s.width, s.height, s.pix_fmt = frames[0].shape[1], frames[0].shape[0], "yuv420p"
                for f in frames:
                    for pkt in s.encode(av.VideoFrame.from_ndarray(f, format="rgb24")):
                        c.mux(pkt)
                for pkt in s.encode():
                    c.mux(pkt)
            return codec
        except Exception as e:  # encoder not built into this FFmpeg
            last = e
    raise RuntimeError(f"no usable mp4 encoder (libx264, mpeg4): {last}")


def save_dict(path: Path, obj) -> None:
    """Write ``obj`` to the new file ``path`` as RH20T does: python dicts as 0-d object arrays (a write; pokeworld
    reads such files back only through its restricted loader)."""
    # RH20T's own pickled-dict format (io writes no pickles of its own): serialised in memory, then created through
    # io.create_new (never an existing file, never through a link)
    buf = io.BytesIO()
    np.save(buf, obj, allow_pickle=True)  # into memory; the file is created by io.create_new below
    create_new(path, buf.getvalue())


def save_array(path: Path, array) -> None:
    """Write the plain array ``array`` (no pickle) to the new file ``path`` as RH20T's ``.npy`` files are."""
    # a file of RH20T's own layout in a folder being built (a test fixture's, or the synthetic corpus's private
    # temporary under io.atomic_path): io.create_new, as save_dict
    buf = io.BytesIO()
    np.save(buf, np.asarray(array))  # into memory; the file is created by io.create_new below
    create_new(path, buf.getvalue())


def write_scene(cfg_dir: Path, name: str, k: int, *, cfg: int = 7, duration_s: float = 7.5, video: str = "mp4",
                rating: int = 5, defect: str | None = None, seed: int = 0) -> dict:
    """Write one scene folder; returns {'t0_ms', 'params', 'cam_ts': {role: ms array}, 'serials': {role: serial}}."""
    rng = np.random.default_rng(seed + 1000 * k)
    d = cfg_dir / name
    (d / "transformed").mkdir(parents=True, exist_ok=True)
    t0 = T0_MS + 3_600_000 * k
    p = scene_params(k)
    roles = CAMERA_ROLES[cfg] if cfg in CAMERA_ROLES else CAMERA_ROLES[7]
    serials = {"far": roles["far"][1 if defect == "far_fallback" else 0], "close": roles["close"][0]}
    if defect == "missing_camera":
        serials.pop("far")
    cam_ts: dict[str, np.ndarray] = {}
    tcp_d, ft_d, gr_d, jt_d = {}, {}, {}, {}
    for role, serial in serials.items():
        n = int(duration_s * 10) + 3
        steps = 100 + rng.integers(-30, 31, n - 1)
        ts = t0 + int(rng.integers(0, 25)) + np.concatenate([[0], np.cumsum(steps)])
        cam_ts[role] = ts
        t = (ts - t0) / 1000.0
        sig = signals(t, p)
        pos = sig["pos"] * (1000.0 if defect == "mm_units" else 1.0)
        zero = sig["ft_zeroed"].copy()
        if defect == "nan_ft" and role == "far":  # half the merged records: the stream is unusable
            zero[:, 2] = np.nan
        if defect == "nan_ft_isolated" and role == "far":  # 3 isolated records: dropped and counted
            zero[5:8, 2] = np.nan
        tcp_recs = [{"timestamp": int(ts[i]), "tcp": np.concatenate([pos[i], sig["quat"][i]]),
                     "robot_ft": sig["ft_zeroed"][i] * 0.9} for i in range(n)]
        ft_recs = [{"timestamp": int(ts[i]), "raw": sig["ft_raw"][i], "zeroed": zero[i]} for i in range(n)]
        order = rng.permutation(n)  # RH20T lists are not guaranteed sorted: the loader must sort
        tcp_d[serial] = [tcp_recs[i] for i in order]
        ft_d[serial] = [ft_recs[i] for i in order]
        gr_d[serial] = {int(ts[i]): {"gripper_command": [float(sig["gripper_command_mm"][i]), 0.0, 0.0],
                                     "gripper_info": [float(sig["gripper_info_mm"][i]), 0.0, 0.0]} for i in range(n)}
        jt_d[serial] = {int(ts[i]): np.linspace(0, 1, 7) * t[i] for i in range(n)}
        cam = d / f"cam_{serial}"
        cam.mkdir(exist_ok=True)
        frames = [_frame(v) for v in image_level(t, role)]
        if video == "jpg":
            import cv2

            (cam / "color").mkdir(exist_ok=True)
            for ti, f in zip(ts, frames):
                jpg = fresh(cam / "color" / f"{int(ti)}.jpg")
                cv2.imwrite(str(jpg), f[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, 95])
        else:
            save_dict(cam / "timestamps.npy", {"color": [int(x) for x in ts], "depth": [int(x) for x in ts]})
            mp4 = cam / "color.mp4"
            if defect == "empty_video" and role == "far":
                create_new(mp4, b"")  # an empty video, created as save_dict creates
            elif defect == "truncated_video" and role == "far":
                write_mp4(mp4, frames[: n - 10])
            else:
                write_mp4(mp4, frames)
                if defect == "corrupt_video" and role == "far":
                    with open(mp4, "r+b") as fh:  # the file write_mp4 has just created
                        fh.truncate(os.fstat(fh.fileno()).st_size * 2 // 5)
    tr = d / "transformed"
    save_dict(tr / "tcp_base.npy", tcp_d)
    if defect != "missing_ft":
        save_dict(tr / "force_torque_base.npy", ft_d)
    save_dict(tr / "gripper.npy", gr_d)
    save_dict(tr / "joint.npy", jt_d)
    all_ts = np.concatenate(list(cam_ts.values()))
    calib = -1 if defect == "missing_calib" else T0_MS - 86_400_000
    meta = {"calib": calib, "rating": 1 if defect == "low_rating" else rating, "bad_calib_view": [],
            "start_time": int(all_ts.min()), "finish_time": int(all_ts.max())}
    create_new(d / "metadata.json", json.dumps(meta).encode())
    return {"t0_ms": t0, "params": p, "cam_ts": cam_ts, "serials": serials, "video": video}


def write_calib(cfg_dir: Path, cfg: int) -> None:
    c = cfg_dir / "calib" / str(T0_MS - 86_400_000)
    c.mkdir(parents=True, exist_ok=True)
    roles = CAMERA_ROLES[cfg]
    eye = {roles[r][0]: np.eye(4)[None] for r in ("far", "close")}
    save_dict(c / "extrinsics.npy", eye)
    save_dict(c / "intrinsics.npy", {s: np.eye(3, 4) for s in eye})
    save_array(c / "tcp.npy", [0.4, -0.1, 0.3, 1.0, 0.0, 0.0, 0.0])


def make_fixture_root(root: str | Path, cfg: int = 7, n_tasks: int = 3, scenes_per_task: int = 2,
                      defects: tuple[str, ...] = DEFECTS, duration_s: float = 7.5, seed: int = 0) -> dict:
    """Write good scenes (tasks 1..n_tasks, mp4 and jpg alternating) plus one scene per defect.

    Returns ``{"root", "cfg_dir", "good": {name: info}, "bad": {name: expected_reason}, "repaired": {name: defect}}``;
    defect scenes that convert anyway (``EXPECTED_REASON[defect] is None``) are in ``good`` and ``repaired``.
    """
    root = Path(root)
    cfg_dir = root / f"RH20T_cfg{cfg}"
    cfg_dir.mkdir(parents=True, exist_ok=True)
    write_calib(cfg_dir, cfg)
    good, bad, repaired, k = {}, {}, {}, 0
    for task in range(1, n_tasks + 1):
        for s in range(1, scenes_per_task + 1):
            name = f"task_{task:04d}_user_{s:04d}_scene_{s:04d}_cfg_{cfg:04d}"
            good[name] = write_scene(cfg_dir, name, k, cfg=cfg, duration_s=duration_s,
                                     video="jpg" if k % 2 else "mp4", seed=seed)
            k += 1
    for i, defect in enumerate(defects):
        task = 50 + i
        cfg_tag = 9 if defect == "unknown_cfg" else cfg
        name = f"task_{task:04d}_user_0001_scene_0001_cfg_{cfg_tag:04d}" + ("_human" if defect == "human" else "")
        info = write_scene(cfg_dir, name, k, cfg=cfg, duration_s=1.0 if defect == "too_short" else duration_s,
                           defect=defect, seed=seed)
        if EXPECTED_REASON[defect] is None:
            good[name], repaired[name] = info, defect
        else:
            bad[name] = EXPECTED_REASON[defect]
        k += 1
    return {"root": root, "cfg_dir": cfg_dir, "good": good, "bad": bad, "repaired": repaired}


__all__ = ["fresh", "make_fixture_root", "write_scene", "signals", "image_level", "force_z", "force_breakpoints",
           "scene_params", "DEFECTS", "EXPECTED_REASON", "FT_OFFSET", "T0_MS"]
