"""RH20T real-robot scenes -> a pokeworld store (``pokeworld rh20t-convert ROOT --cfg 7``).

Pipeline, one scene at a time (docs/rh20t.md lists every format fact and choice):

1. **scan** ``ROOT`` (an ``RH20T_cfgN`` folder or a folder holding them) for scene folders
   ``task_NNNN_user_NNNN_scene_NNNN_cfg_NNNN``; ``*_human`` demonstration folders, other
   configurations and unknown configurations are skipped with a counted reason.
2. **read** ``metadata.json`` (rating, calibration id, start/finish time), the pickled
   ``transformed/{tcp_base,force_torque_base,gripper}.npy`` dicts and the chosen camera(s)
   (``cam_<serial>/color.mp4`` + ``timestamps.npy``, or extracted ``cam_<serial>/color/<ts>.jpg``).
3. **resample** every numeric stream onto a regular ``hz`` grid by linear interpolation
   (quaternions: hemisphere-aligned lerp + renormalisation) and take the nearest camera frame;
   crop/resize to ``image_size`` grayscale. The result is cached per scene
   (``<out>.cache/<key>/<scene>.npz``, written atomically), so an interrupted run resumes.
4. **assemble**: fixed-length chunks of ``episode_steps`` steps, scene-level and held-out-task
   splits, per-column 0.1/99.9-percentile clipping + whitening with train-only statistics,
   labels (raw force, contact onset, TCP pose), then :func:`pokeworld.data.save`.

Any defect of one scene (missing stream / calibration / camera, NaN, empty or truncated video,
unknown configuration...) skips that scene with a reason code that is counted in
``<out>/conversion_report.json``; a run never stops half-way because of one bad scene and never
writes an array it could not verify.

Streams written to the store (``manifest["columns"]`` names every column):

* ``proprio`` (8): TCP position in the robot base frame [m] (x, y, z), TCP orientation quaternion
  (w, x, y, z), gripper opening width [m];
* ``touch`` (6): zeroed (tared) force [N] and torque [N m] in the robot base frame;
* ``actions`` (7): TCP position delta [m], rotation delta as a rotation vector of
  ``q_{t+1} * conj(q_t)`` (base frame) [rad], gripper width delta [m], between consecutive grid steps.

``proprio``/``touch``/``actions`` are clipped and whitened; the raw physical values stay
available as ``labels`` (``force``, ``torque``, ``tcp_pos``, ``tcp_quat``, ``gripper_width``).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import re
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from tqdm.auto import tqdm

from .. import __version__
from ..config import from_preset, to_dict
from ..data import Dataset, save, store_is_current
from ..errors import ConfigError, DataError
from ..io import atomic_path, write_json

PIPELINE_VERSION = 1
"""Bumped whenever per-scene processing changes, so stale scene caches are never reused."""

ROBOTS: dict[int, str] = {1: "flexiv", 2: "flexiv", 3: "ur5", 4: "ur5", 5: "franka", 6: "kuka", 7: "kuka"}
"""RH20T robot configurations (rh20t_api configs/configs.json, ``conf_num`` -> ``robot``)."""

# Camera serial numbers per configuration and role. "far" is the front third-person camera,
# "close" the in-hand (wrist) camera(s); the first serial of a role found in a scene is used.
# Sources: kpertsch/rh20t_dataset_converter rh20t/cam_definitions.py (overhead/front/side/wrist/
# shoulder per cfg) and rh20t_api configs/configs.json ``in_hand`` (in-hand serials). Override per
# run with ``ConvertConfig.camera_serials``.
_CAM_A = {"overhead": ("035622060973",), "far": ("750612070851",), "side_left": ("039422060546",),
          "side_right": ("750612070853",), "close": ("043322070878",), "shoulder": ("038522063145",)}
_CAM_B = {"overhead": ("104122061850",), "far": ("037522062165",), "side_left": ("104122063678",),
          "side_right": ("105422061350",), "close": ("104422070042",), "shoulder": ("036422060215",)}
_CAM_UR = {"overhead": ("104422070011",), "far": ("038522062288",), "side_left": ("104122062823",),
           "side_right": ("104122062295",), "close": ("045322071843",), "shoulder": ("036422060909",)}
_CAM_KUKA = {"overhead": ("104122060811",), "far": ("104122061018",), "side_left": ("104122064161",),
             "side_right": ("104122063633",), "close": ("135122070361", "135122075425"),
             "shoulder": ("104122061602",)}
CAMERA_ROLES: dict[int, dict[str, tuple[str, ...]]] = {
    1: _CAM_A, 2: _CAM_B, 3: _CAM_UR, 4: _CAM_UR,
    5: {**_CAM_B, "close": ("135122079702", "104422070042")},
    6: _CAM_KUKA, 7: _CAM_KUKA,
}
"""cfg -> role -> candidate serials (first present wins). Roles: far, close, overhead, side_left,
side_right, shoulder; the camera option ``two_view`` means far + close side by side."""

CAMERA_OPTIONS = ("far", "close", "two_view", "overhead", "side_left", "side_right", "shoulder")

SCENE_RE = re.compile(r"^task_(\d{4})_user_(\d{4})_scene_(\d{4})_cfg_(\d{4})(_human)?$")

PROPRIO_COLUMNS = ("tcp_x", "tcp_y", "tcp_z", "quat_w", "quat_x", "quat_y", "quat_z", "gripper_width")
TOUCH_COLUMNS = ("force_x", "force_y", "force_z", "torque_x", "torque_y", "torque_z")
ACTION_COLUMNS = ("d_tcp_x", "d_tcp_y", "d_tcp_z", "d_rot_x", "d_rot_y", "d_rot_z", "d_gripper_width")

SKIP_REASONS = {
    "human_demo": "a *_human demonstration folder (no robot streams)",
    "other_cfg": "scene of a different robot configuration than --cfg",
    "unknown_cfg": "configuration number outside RH20T's cfg1-cfg7",
    "missing_metadata": "metadata.json absent",
    "bad_metadata": "metadata.json unreadable or without an integer rating",
    "low_rating": "rating below min_rating (RH20T: <= 1 marks failed / stopped)",
    "missing_calib": "metadata calib absent or -1 (or calib folder absent when required)",
    "missing_stream": "a required transformed/*.npy or timestamps.npy file is absent",
    "bad_stream": "a stream file cannot be unpickled or has the wrong structure / shape",
    "nan_stream": "non-finite values in a used sensor stream",
    "bad_units": "TCP position beyond max_abs_pos_m or non-unit quaternion (wrong units/order?)",
    "bad_timestamps": "timestamps not 13-digit milliseconds or streams do not overlap in time",
    "stream_gap": "a numeric stream has a gap longer than max_gap_s inside the scene",
    "missing_camera": "no camera folder for the requested role",
    "empty_video": "color video / image folder has no frames",
    "unreadable_video": "color video or image cannot be decoded",
    "truncated_video": "fewer decoded frames than timestamps",
    "frame_count_mismatch": "more decoded frames than timestamps",
    "frame_gap": "no camera frame within frame_tolerance_s of a grid time",
    "too_short": "fewer than episode_steps + 1 grid steps",
    "unexpected_error": "an unanticipated exception while reading the scene (message recorded)",
}
"""Every reason code a scene can be skipped with (reported in conversion_report.json)."""


class SceneSkip(DataError):
    """A scene that cannot be converted; ``reason`` is a key of :data:`SKIP_REASONS`."""

    def __init__(self, reason: str, message: str):
        assert reason in SKIP_REASONS, reason
        super().__init__(f"{reason}: {message}")
        self.reason, self.message = reason, message


@dataclass
class ConvertConfig:
    """Convert RH20T scenes of one robot configuration into a pokeworld store."""

    root: str = ""
    """RH20T root: an ``RH20T_cfgN`` folder or a folder containing ``RH20T_cfg*`` folders."""
    cfg: int = 7
    """Robot configuration to convert (1-2 Flexiv, 3-4 UR5, 5 Franka, 6-7 KUKA iiwa)."""
    out: str = ""
    """Output store directory; empty means ``data/rh20t_cfg<cfg>_<camera>``."""
    camera: str = "far"
    """Camera role: far, close, two_view (far | close side by side), overhead, side_left, side_right, shoulder."""
    camera_serials: tuple[str, ...] = ()
    """Explicit camera serial(s) overriding the role table (1 serial, or 2 for two_view)."""
    image_size: int = 96
    """Output frames are image_size x image_size grayscale uint8."""
    crop: tuple[float, ...] = ()
    """Fractional crop box (top, left, bottom, right) in [0, 1] applied before resizing; empty = centred square."""
    hz: float = 10.0
    """Resampling rate of the regular time grid [Hz]."""
    episode_steps: int = 64
    """Control steps T per stored episode: each scene is cut into chunks of T+1 observations."""
    chunk_stride: int = 0
    """Observations between chunk starts; 0 means episode_steps + 1 (non-overlapping chunks)."""
    clip_percentiles: tuple[float, float] = (0.1, 99.9)
    """Per-column clip range (percentiles of the train split) applied before whitening."""
    onset_threshold_n: float = 10.0
    """Contact threshold on the force norm [N]."""
    onset_horizon: int = 4
    """contact_onset at step t: no contact at t and contact within steps t+1..t+horizon."""
    split_fractions: tuple[float, float, float] = (0.6, 0.2, 0.2)
    """Scene fractions for train / probe-fit / probe-test among non-held-out tasks."""
    num_heldout_tasks: int = 6
    """Tasks held out entirely (split 3), drawn at random with ``seed`` (ignored if heldout_tasks is set)."""
    heldout_tasks: tuple[int, ...] = ()
    """Explicit held-out task ids (overrides num_heldout_tasks)."""
    seed: int = 0
    """Seed for the held-out-task draw and the scene split."""
    min_rating: int = 2
    """Keep scenes with metadata rating >= min_rating (RH20T rates 0-9; <= 1 is failed / stopped)."""
    require_calib_dir: bool = False
    """Also require the calibration folder ``<RH20T_cfgN>/calib/<calib>`` to exist."""
    gripper_field: str = "gripper_info"
    """Key in transformed/gripper.npy whose element 0 is the gripper width [mm]
    (gripper_info = measured, gripper_command = commanded)."""
    max_gap_s: float = 1.0
    """Skip a scene whose numeric streams have a gap longer than this inside the converted span [s]."""
    frame_tolerance_s: float = 0.25
    """Skip a scene if some grid time has no camera frame closer than this [s]."""
    max_abs_pos_m: float = 3.0
    """Sanity bound on |TCP position| [m]; larger values mean mm or a wrong field."""
    max_scenes: int = 0
    """Convert at most this many scenes (sorted by name); 0 = all."""
    progress: bool = True
    """Show a progress bar."""
    overwrite: bool = False
    """Rebuild the store and the scene cache even if they exist."""

    def __post_init__(self) -> None:
        if self.cfg not in ROBOTS:
            raise ConfigError(f"unknown RH20T configuration cfg={self.cfg}; RH20T has cfg 1-7 ({ROBOTS})")
        if self.camera not in CAMERA_OPTIONS:
            raise ConfigError(f"unknown camera role {self.camera!r}; choose one of {CAMERA_OPTIONS}")
        need = 2 if self.camera == "two_view" else 1
        if self.camera_serials and len(self.camera_serials) != need:
            raise ConfigError(f"camera={self.camera} needs {need} serial(s), got {self.camera_serials}")
        if self.image_size < 8 or (self.camera == "two_view" and self.image_size % 2):
            raise ConfigError(f"image_size must be >= 8 (and even for two_view), got {self.image_size}")
        if self.crop and (len(self.crop) != 4 or not (0 <= self.crop[0] < self.crop[2] <= 1
                                                     and 0 <= self.crop[1] < self.crop[3] <= 1)):
            raise ConfigError("crop must be (top, left, bottom, right) fractions with top<bottom, left<right, "
                              f"got {self.crop}")
        if self.hz <= 0 or self.episode_steps < 2 or self.chunk_stride < 0 or self.onset_horizon < 1:
            raise ConfigError("hz must be > 0, episode_steps >= 2, chunk_stride >= 0, onset_horizon >= 1")
        lo, hi = self.clip_percentiles
        if not 0 <= lo < hi <= 100:
            raise ConfigError(f"clip_percentiles must satisfy 0 <= lo < hi <= 100, got {self.clip_percentiles}")
        f = self.split_fractions
        if len(f) != 3 or min(f) < 0 or abs(sum(f) - 1) > 1e-6 or f[0] == 0:
            raise ConfigError(f"split_fractions must be 3 non-negative numbers summing to 1 with train > 0, got {f}")
        if self.gripper_field not in ("gripper_info", "gripper_command"):
            raise ConfigError(f"gripper_field must be gripper_info or gripper_command, got {self.gripper_field!r}")


PRESETS: dict[str, dict] = {
    "tiny": {"episode_steps": 16, "num_heldout_tasks": 1, "progress": False},
    "cpu": {"episode_steps": 64, "max_scenes": 200},
    "paper": {"episode_steps": 64, "num_heldout_tasks": 6},
}


def make_config(preset: str = "cpu", **overrides) -> ConvertConfig:
    return from_preset(ConvertConfig, PRESETS, preset, **overrides)


def out_dir(cfg: ConvertConfig) -> Path:
    return Path(cfg.out or f"data/rh20t_cfg{cfg.cfg}_{cfg.camera}")


# --------------------------------------------------------------------------------------- scan


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


# ------------------------------------------------------------------------------ stream reading


def load_pickled_dict(path: Path, what: str) -> Any:
    """``np.load(path, allow_pickle=True).item()`` with RH20T-specific errors (RH20T stores dicts this way)."""
    if not path.exists():
        raise SceneSkip("missing_stream", f"{what} file {path} is absent")
    try:
        obj = np.load(path, allow_pickle=True)
        obj = obj.item() if isinstance(obj, np.ndarray) and obj.dtype == object and obj.shape == () else obj
    except Exception as e:  # pickle / zip / value errors all mean a damaged file
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


def read_records(obj: dict, key: str, dim: int, what: str) -> tuple[np.ndarray, np.ndarray]:
    """``{serial: [{'timestamp': ms, key: vec}, ...]}`` merged over serials -> (ts (N,), values (N, dim))."""
    ts, vals = [], []
    try:
        for serial, items in obj.items():
            for it in items:
                ts.append(int(it["timestamp"]))
                vals.append(np.asarray(it[key], dtype=np.float64).reshape(-1))
    except (KeyError, TypeError, ValueError) as e:
        raise SceneSkip("bad_stream", f"{what}: expected {{serial: [{{'timestamp', '{key}'}}]}} "
                                      f"({type(e).__name__}: {e})") from None
    bad = [v.shape for v in vals if v.shape != (dim,)]
    if bad:
        raise SceneSkip("bad_stream", f"{what}['{key}'] must have {dim} values, got shape {bad[0]}")
    return _sorted_unique(np.asarray(ts, np.int64), np.asarray(vals, np.float64).reshape(-1, dim), what)


def read_gripper(obj: dict, field: str) -> tuple[np.ndarray, np.ndarray]:
    """``{serial: {ts: {field: [width_mm, ...]}}}`` merged over serials -> (ts (N,), width_mm (N, 1))."""
    ts, vals = [], []
    try:
        for serial, per_ts in obj.items():
            for t, rec in per_ts.items():
                ts.append(int(t))
                vals.append(float(np.asarray(rec[field], dtype=np.float64).reshape(-1)[0]))
    except (KeyError, TypeError, ValueError, IndexError, AttributeError) as e:
        raise SceneSkip("bad_stream", f"gripper.npy: expected {{serial: {{ts: {{'{field}': [width_mm, ...]}}}}}} "
                                      f"({type(e).__name__}: {e})") from None
    return _sorted_unique(np.asarray(ts, np.int64), np.asarray(vals, np.float64).reshape(-1, 1), "gripper.npy")


def align_quaternions(q: np.ndarray) -> np.ndarray:
    """Flip signs so consecutive quaternions lie in the same hemisphere (q and -q are the same rotation)."""
    q = q.copy()
    for i in range(1, len(q)):
        if np.dot(q[i], q[i - 1]) < 0:
            q[i] = -q[i]
    if len(q) and q[0, 0] < 0:
        q = -q
    return q


def interp_columns(t_grid: np.ndarray, ts: np.ndarray, vals: np.ndarray) -> np.ndarray:
    """Linear interpolation of every column of ``vals`` (sampled at ``ts``) at ``t_grid``."""
    return np.stack([np.interp(t_grid, ts, vals[:, j]) for j in range(vals.shape[1])], axis=1)


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of (..., 4) quaternions in (w, x, y, z) order."""
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack([aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw], -1)


def quat_to_rotvec(q: np.ndarray) -> np.ndarray:
    """(..., 4) unit quaternions (w, x, y, z) -> (..., 3) rotation vectors (shortest rotation)."""
    q = np.where(q[..., :1] < 0, -q, q)
    v = q[..., 1:]
    s = np.linalg.norm(v, axis=-1, keepdims=True)
    angle = 2 * np.arctan2(s, q[..., :1])
    scale = np.where(s > 1e-12, angle / np.maximum(s, 1e-12), 2.0)  # small-angle limit: 2 v
    return v * scale


def tcp_actions(quat: np.ndarray, pos: np.ndarray, grip: np.ndarray) -> np.ndarray:
    """(N,) poses -> (N-1, 7) actions: position delta, base-frame rotation vector of q_{t+1} q_t^*, gripper delta."""
    conj = quat[:-1] * np.array([1, -1, -1, -1])
    drot = quat_to_rotvec(quat_mul(quat[1:], conj))
    return np.concatenate([pos[1:] - pos[:-1], drot, grip[1:] - grip[:-1]], axis=1)


def contact_onset(force_norm: np.ndarray, threshold: float, horizon: int) -> tuple[np.ndarray, np.ndarray]:
    """(contact, onset) for one scene: contact_t = |F_t| > thr; onset_t = not contact_t and any contact in t+1..t+h."""
    contact = force_norm > threshold
    n = len(contact)
    future = np.zeros(n, bool)
    for k in range(1, horizon + 1):
        future[: n - k] |= contact[k:]
    return contact.astype(np.float32), (~contact & future).astype(np.float32)


# ------------------------------------------------------------------------------------ frames


def _crop_resize(gray: np.ndarray, crop: tuple[float, ...], out_hw: tuple[int, int]) -> np.ndarray:
    import cv2

    h, w = gray.shape
    if crop:
        t, l, b, r = crop
        box = gray[int(round(t * h)): max(int(round(b * h)), int(round(t * h)) + 1),
                   int(round(l * w)): max(int(round(r * w)), int(round(l * w)) + 1)]
    else:
        s = min(h, w)
        y0, x0 = (h - s) // 2, (w - s) // 2
        box = gray[y0: y0 + s, x0: x0 + s]
    return cv2.resize(box, (out_hw[1], out_hw[0]), interpolation=cv2.INTER_AREA)


def read_camera(cam_dir: Path, t_grid: np.ndarray, cfg: ConvertConfig, out_hw: tuple[int, int],
                t_range: tuple[int, int] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Camera timestamps (ms, sorted) and, if ``t_grid`` is given, the nearest frame for each grid time.

    ``color.mp4`` + ``timestamps.npy`` is used when present, else extracted ``color/<ts>.jpg``.
    With ``t_grid=None`` only the timestamps are returned (frames empty).
    """
    mp4, tsf, jpg_dir = cam_dir / "color.mp4", cam_dir / "timestamps.npy", cam_dir / "color"
    if mp4.exists():
        meta = load_pickled_dict(tsf, "camera timestamps.npy")
        if "color" not in meta:
            raise SceneSkip("bad_stream", f"{tsf} has no 'color' key (keys: {sorted(meta)})")
        ts = np.asarray(meta["color"], np.int64).reshape(-1)
        if ts.size == 0:
            raise SceneSkip("empty_video", f"{tsf} lists no color frames")
        if not np.all((ts > 1e12) & (ts < 1e13)) or np.any(np.diff(ts) <= 0):
            raise SceneSkip("bad_timestamps", f"{tsf} color timestamps are not increasing 13-digit milliseconds")
        if t_grid is None:
            return ts, np.zeros((0, *out_hw), np.uint8)
        idx = _nearest(ts, t_grid, cfg.frame_tolerance_s, cam_dir.name)
        frames = _decode_mp4(mp4, len(ts), np.unique(idx), cfg.crop, out_hw)
        return ts, np.stack([frames[i] for i in idx])
    if jpg_dir.is_dir():
        files = {}
        for f in jpg_dir.iterdir():
            if f.suffix.lower() in (".jpg", ".jpeg", ".png") and f.stem[:13].isdigit():
                files[int(f.stem[:13])] = f
        if not files:
            raise SceneSkip("empty_video", f"{jpg_dir} holds no <timestamp>.jpg frames")
        ts = np.asarray(sorted(files), np.int64)
        if not np.all(ts > 1e12):
            raise SceneSkip("bad_timestamps", f"{jpg_dir} image names are not 13-digit millisecond timestamps")
        if t_grid is None:
            return ts, np.zeros((0, *out_hw), np.uint8)
        import cv2

        idx = _nearest(ts, t_grid, cfg.frame_tolerance_s, cam_dir.name)
        cache: dict[int, np.ndarray] = {}
        for i in np.unique(idx):
            img = cv2.imread(str(files[int(ts[i])]), cv2.IMREAD_GRAYSCALE)
            if img is None:
                raise SceneSkip("unreadable_video", f"cannot decode image {files[int(ts[i])]}")
            cache[int(i)] = _crop_resize(img, cfg.crop, out_hw)
        return ts, np.stack([cache[int(i)] for i in idx])
    raise SceneSkip("missing_stream", f"{cam_dir} has neither color.mp4 nor a color/ image folder")


def _nearest(ts: np.ndarray, t_grid: np.ndarray, tol_s: float, what: str) -> np.ndarray:
    j = np.clip(np.searchsorted(ts, t_grid), 1, len(ts) - 1) if len(ts) > 1 else np.zeros(len(t_grid), int)
    if len(ts) > 1:
        j = np.where(np.abs(ts[j - 1] - t_grid) <= np.abs(ts[j] - t_grid), j - 1, j)
    off = np.abs(ts[j] - t_grid) / 1000.0
    if off.max() > tol_s:
        k = int(off.argmax())
        raise SceneSkip("frame_gap", f"{what}: nearest frame to grid time {t_grid[k]:.0f} is {off[k]:.3f} s away "
                                     f"(> frame_tolerance_s={tol_s})")
    return j


def _decode_mp4(path: Path, n_expected: int, wanted: np.ndarray, crop, out_hw) -> dict[int, np.ndarray]:
    import av

    if path.stat().st_size == 0:
        raise SceneSkip("empty_video", f"{path} is an empty file")
    wanted_set = set(int(i) for i in wanted)
    out: dict[int, np.ndarray] = {}
    n = 0
    try:
        with av.open(str(path)) as container:
            if not container.streams.video:
                raise SceneSkip("empty_video", f"{path} has no video stream")
            for frame in container.decode(video=0):
                if n in wanted_set:
                    out[n] = _crop_resize(frame.to_ndarray(format="gray"), crop, out_hw)
                n += 1
    except SceneSkip:
        raise
    except Exception as e:  # av.error.* (invalid data, EOF...) for damaged containers
        if n == 0:
            raise SceneSkip("unreadable_video", f"cannot decode {path}: {type(e).__name__}: {e}") from None
        raise SceneSkip("truncated_video", f"{path}: decoding stopped after {n} of {n_expected} frames "
                                           f"({type(e).__name__}: {e})") from None
    if n == 0:
        raise SceneSkip("empty_video", f"{path} decodes to 0 frames")
    if n < n_expected:
        raise SceneSkip("truncated_video", f"{path} has {n} frames but timestamps.npy lists {n_expected}")
    if n > n_expected:
        raise SceneSkip("frame_count_mismatch", f"{path} has {n} frames but timestamps.npy lists only {n_expected}")
    return out


def camera_serials(scene_dir: Path, cfg: ConvertConfig) -> list[str]:
    """Serials of the camera(s) used for ``cfg.camera`` in this scene (explicit override or role table)."""
    present = {d.name[4:] for d in scene_dir.iterdir() if d.is_dir() and d.name.startswith("cam_")}
    roles = ["far", "close"] if cfg.camera == "two_view" else [cfg.camera]
    if cfg.camera_serials:
        chosen = list(cfg.camera_serials)
        missing = [s for s in chosen if s not in present]
        if missing:
            raise SceneSkip("missing_camera", f"camera folder(s) cam_{missing[0]} absent (present: {sorted(present)})")
        return chosen
    chosen = []
    for role in roles:
        cands = CAMERA_ROLES[cfg.cfg][role]
        hit = next((s for s in cands if s in present), None)
        if hit is None:
            raise SceneSkip("missing_camera", f"no '{role}' camera (serials {list(cands)}) among {sorted(present)}")
        chosen.append(hit)
    return chosen


# ----------------------------------------------------------------------------- one scene


def _metadata_time(meta: dict, keys: tuple[str, ...]) -> int | None:
    for k in keys:
        v = meta.get(k)
        if isinstance(v, (int, float)) and 1e12 < v < 1e13:
            return int(v)
    return None


def check_scene_name(ref: SceneRef, cfg: ConvertConfig) -> None:
    """Skips decided by the folder name alone: human demonstrations, unknown or other configurations."""
    if ref.human:
        raise SceneSkip("human_demo", f"{ref.name} is a human demonstration folder")
    if ref.cfg not in ROBOTS:
        raise SceneSkip("unknown_cfg", f"{ref.name}: cfg {ref.cfg} is not an RH20T configuration (1-7)")
    if ref.cfg != cfg.cfg:
        raise SceneSkip("other_cfg", f"{ref.name} is cfg {ref.cfg}, converting cfg {cfg.cfg}")


def process_scene(ref: SceneRef, cfg: ConvertConfig) -> dict[str, np.ndarray]:
    """Read, check and resample one scene; raise :class:`SceneSkip` with a reason on any defect."""
    d = ref.path
    check_scene_name(ref, cfg)
    # metadata
    mpath = d / "metadata.json"
    if not mpath.exists():
        raise SceneSkip("missing_metadata", f"{mpath} is absent")
    try:
        meta = json.loads(mpath.read_text())
        rating = int(meta["rating"])
    except (json.JSONDecodeError, KeyError, TypeError, ValueError, UnicodeDecodeError) as e:
        raise SceneSkip("bad_metadata", f"{mpath}: {type(e).__name__}: {e}") from None
    if rating < cfg.min_rating:
        raise SceneSkip("low_rating", f"rating {rating} < min_rating {cfg.min_rating}")
    calib = meta.get("calib")
    if calib is None or calib == -1 or calib == "-1":
        raise SceneSkip("missing_calib", f"metadata calib is {calib!r}")
    if cfg.require_calib_dir and not (d.parent / "calib" / str(calib)).is_dir():
        raise SceneSkip("missing_calib", f"calibration folder {d.parent / 'calib' / str(calib)} is absent")
    # numeric streams (robot base frame, SI units per rh20t_api's transformed/ folder)
    tr = d / "transformed"
    tcp_ts, tcp = read_records(load_pickled_dict(tr / "tcp_base.npy", "transformed/tcp_base.npy"), "tcp", 7,
                               "tcp_base.npy")
    ft_ts, ft = read_records(load_pickled_dict(tr / "force_torque_base.npy", "transformed/force_torque_base.npy"),
                             "zeroed", 6, "force_torque_base.npy")
    gr_ts, grip = read_gripper(load_pickled_dict(tr / "gripper.npy", "transformed/gripper.npy"), cfg.gripper_field)
    for name, v in (("tcp_base.npy", tcp), ("force_torque_base.npy zeroed", ft), ("gripper.npy", grip)):
        if not np.isfinite(v).all():
            raise SceneSkip("nan_stream", f"{name} has {int((~np.isfinite(v)).sum())} non-finite values")
    if np.abs(tcp[:, :3]).max() > cfg.max_abs_pos_m:
        raise SceneSkip("bad_units", f"|tcp position| reaches {np.abs(tcp[:, :3]).max():.3g} > {cfg.max_abs_pos_m} m "
                                     "(millimetres instead of metres?)")
    qn = np.linalg.norm(tcp[:, 3:], axis=1)
    if np.abs(qn - 1).max() > 0.05:
        raise SceneSkip("bad_units", f"tcp quaternion norm deviates from 1 by {np.abs(qn - 1).max():.3g}")
    # cameras
    serials = camera_serials(d, cfg)
    half = cfg.camera == "two_view"
    out_hw = (cfg.image_size, cfg.image_size // 2 if half else cfg.image_size)
    cam_ts = [read_camera(d / f"cam_{s}", None, cfg, out_hw)[0] for s in serials]
    # common time span and regular grid
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
    for name, ts in (("tcp_base", tcp_ts), ("force_torque_base", ft_ts), ("gripper", gr_ts)):
        inside = ts[(ts >= t0) & (ts <= t1)]
        edges = np.concatenate([[t0], inside, [t1]])
        gap = np.diff(edges).max() / 1000.0
        if gap > cfg.max_gap_s:
            raise SceneSkip("stream_gap", f"{name} has a {gap:.2f} s gap (> max_gap_s={cfg.max_gap_s})")
    views = [read_camera(d / f"cam_{s}", t_grid, cfg, out_hw)[1] for s in serials]
    frames = np.concatenate(views, axis=2) if half else views[0]
    # resample numeric streams
    pos = interp_columns(t_grid, tcp_ts, tcp[:, :3])
    quat = interp_columns(t_grid, tcp_ts, align_quaternions(tcp[:, 3:]))
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    ft_g = interp_columns(t_grid, ft_ts, ft)
    grip_m = interp_columns(t_grid, gr_ts, grip)[:, 0] / 1000.0
    return {
        "frames": frames.astype(np.uint8), "pos": pos, "quat": quat, "ft": ft_g, "grip": grip_m,
        "t_s": (t_grid - t0) / 1000.0, "t0_ms": np.asarray(t0, np.int64),
        "rating": np.asarray(rating), "serials": np.asarray(",".join(serials)),
    }


# ----------------------------------------------------------------------------------- caching


_CACHE_FIELDS = ("cfg", "camera", "camera_serials", "image_size", "crop", "hz", "min_rating", "require_calib_dir",
                 "gripper_field", "max_gap_s", "frame_tolerance_s", "max_abs_pos_m")


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
            ok.unlink()  # damaged cache entry: recompute
    if skip.exists():
        try:
            return None, json.loads(skip.read_text())
        except json.JSONDecodeError:
            skip.unlink()
    try:
        arrays = process_scene(ref, cfg)
    except SceneSkip as e:
        rec = {"scene": ref.name, "path": str(ref.path), "reason": e.reason, "message": e.message}
        write_json(skip, rec)
        return None, rec
    except (KeyboardInterrupt, SystemExit):
        raise
    except Exception as e:  # never stop a long run for one scene; not cached so a fixed bug re-runs it
        return None, {"scene": ref.name, "path": str(ref.path), "reason": "unexpected_error",
                      "message": f"{type(e).__name__}: {e}"}
    with atomic_path(ok) as tmp, open(tmp, "wb") as fh:
        np.savez(fh, **arrays)
    return arrays, None


# ------------------------------------------------------------------------------- assembling


def split_scenes(tasks: np.ndarray, cfg: ConvertConfig) -> tuple[np.ndarray, list[int]]:
    """Per-scene split codes (0 train, 1 probe-fit, 2 probe-test, 3 held-out task) and the held-out task ids.

    Held-out tasks: ``cfg.heldout_tasks`` or ``num_heldout_tasks`` drawn from the sorted task ids by a
    seeded permutation (at least one task always stays in-distribution). The remaining scenes are
    permuted and split by ``split_fractions`` (rounded; each split gets >= 1 scene when there are >= 3).
    """
    rng = np.random.default_rng(cfg.seed)
    uniq = np.unique(tasks)
    if cfg.heldout_tasks:
        held = sorted(int(t) for t in cfg.heldout_tasks if t in set(uniq.tolist()))
    else:
        n = min(cfg.num_heldout_tasks, max(len(uniq) - 1, 0))
        held = sorted(int(t) for t in rng.permutation(uniq)[:n])
    split = np.full(len(tasks), 3, np.int8)
    rest = np.flatnonzero(~np.isin(tasks, held))
    rest = rest[rng.permutation(len(rest))]
    n = len(rest)
    f = cfg.split_fractions
    n_fit, n_test = int(round(f[1] * n)), int(round(f[2] * n))
    if n >= 3:
        n_fit, n_test = max(n_fit, 1 if f[1] > 0 else 0), max(n_test, 1 if f[2] > 0 else 0)
    while n - n_fit - n_test < 1 and (n_fit or n_test):
        if n_fit >= n_test:
            n_fit -= 1
        else:
            n_test -= 1
    split[rest[:n - n_fit - n_test]] = 0
    split[rest[n - n_fit - n_test: n - n_test]] = 1
    split[rest[n - n_test:]] = 2
    return split, held


def robust_whiten_stats(x: np.ndarray, percentiles: tuple[float, float]) -> dict[str, list[float]]:
    """Per-column clip bounds (percentiles of ``x``) and mean/std of the clipped ``x``; x is (N, D)."""
    lo, hi = np.percentile(x, percentiles, axis=0)
    xc = np.clip(x, lo, hi)
    mean, std = xc.mean(0), xc.std(0)
    std = np.where(std > 1e-8, std, 1.0)  # constant column: centre only
    return {"lo": lo.tolist(), "hi": hi.tolist(), "mean": mean.tolist(), "std": std.tolist()}


def apply_whiten(x: np.ndarray, st: dict[str, list[float]]) -> np.ndarray:
    lo, hi, mean, std = (np.asarray(st[k], np.float64) for k in ("lo", "hi", "mean", "std"))
    return ((np.clip(x, lo, hi) - mean) / std).astype(np.float32)


def content_config(cfg: ConvertConfig) -> dict:
    d = to_dict(cfg)
    for k in ("out", "overwrite", "progress"):
        d.pop(k)
    return d


def assemble(scenes: list[tuple[SceneRef, dict]], cfg: ConvertConfig) -> tuple[Dataset | None, list[dict], dict]:
    """Chunk converted scenes, split, preprocess; returns (dataset or None, extra skip records, info)."""
    T1 = cfg.episode_steps + 1
    stride = cfg.chunk_stride or T1
    skips, kept = [], []
    for ref, a in scenes:
        if len(a["t_s"]) < T1:
            skips.append({"scene": ref.name, "path": str(ref.path), "reason": "too_short",
                          "message": f"{len(a['t_s'])} grid steps < episode_steps + 1 = {T1}"})
        else:
            kept.append((ref, a))
    if not kept:
        return None, skips, {}
    tasks = np.array([r.task for r, _ in kept])
    scene_split, held = split_scenes(tasks, cfg)
    if not (scene_split == 0).any():
        raise DataError("no scene landed in the train split (too few scenes / tasks for the requested held-out "
                        "tasks); cannot compute train-only normalisation statistics")
    cols: dict[str, list] = {k: [] for k in ("frames", "proprio", "touch", "actions", "split")}
    lab: dict[str, list] = {k: [] for k in ("force", "torque", "force_norm", "contact", "contact_onset", "tcp_pos",
                                            "tcp_quat", "gripper_width", "time_s")}
    par: dict[str, list] = {k: [] for k in ("task_id", "user_id", "scene_id", "cfg_id", "rating", "scene_index",
                                            "chunk_index", "t_start_s")}
    scene_rows, dropped_tail, onset_scene = [], 0, []
    for si, ((ref, a), sp) in enumerate(zip(kept, scene_split)):
        n = len(a["t_s"])
        fn = np.linalg.norm(a["ft"][:, :3], axis=1)
        contact, onset = contact_onset(fn, cfg.onset_threshold_n, cfg.onset_horizon)
        onset_scene.append(onset)
        proprio = np.concatenate([a["pos"], a["quat"], a["grip"][:, None]], 1)
        actions = tcp_actions(a["quat"], a["pos"], a["grip"][:, None])
        starts = list(range(0, n - T1 + 1, stride))
        dropped_tail += n - (starts[-1] + T1)
        for ci, s in enumerate(starts):
            sl = slice(s, s + T1)
            cols["frames"].append(a["frames"][sl])
            cols["proprio"].append(proprio[sl])
            cols["touch"].append(a["ft"][sl])
            cols["actions"].append(actions[s: s + T1 - 1])
            cols["split"].append(sp)
            for k, v in (("force", a["ft"][sl, :3]), ("torque", a["ft"][sl, 3:]), ("force_norm", fn[sl]),
                         ("contact", contact[sl]), ("contact_onset", onset[sl]), ("tcp_pos", a["pos"][sl]),
                         ("tcp_quat", a["quat"][sl]), ("gripper_width", a["grip"][sl]), ("time_s", a["t_s"][sl])):
                lab[k].append(v)
            for k, v in (("task_id", ref.task), ("user_id", ref.user), ("scene_id", ref.scene), ("cfg_id", ref.cfg),
                         ("rating", float(a["rating"])), ("scene_index", si), ("chunk_index", ci),
                         ("t_start_s", a["t_s"][s])):
                par[k].append(v)
        scene_rows.append({"name": ref.name, "path": str(ref.path), "task": ref.task, "user": ref.user,
                           "scene": ref.scene, "rating": int(a["rating"]), "serials": str(a["serials"]).split(","),
                           "start_ms": int(a["t0_ms"]), "grid_steps": n, "chunks": len(starts),
                           "split": int(sp)})
    split = np.asarray(cols["split"], np.int8)
    raw = {k: np.stack(cols[k]).astype(np.float64) for k in ("proprio", "touch", "actions")}
    train = split == 0
    stats = {k: robust_whiten_stats(v[train].reshape(-1, v.shape[-1]), cfg.clip_percentiles) for k, v in raw.items()}
    ds = Dataset(
        frames=np.stack(cols["frames"]).astype(np.uint8),
        proprio=apply_whiten(raw["proprio"], stats["proprio"]),
        touch=apply_whiten(raw["touch"], stats["touch"]),
        actions=apply_whiten(raw["actions"], stats["actions"]),
        labels={k: np.stack(v).astype(np.float32) for k, v in lab.items()},
        params={k: np.asarray(v, np.float32) for k, v in par.items()},
        split=split,
    )
    onset_all = np.concatenate(onset_scene)
    info = {"scenes": scene_rows, "heldout_tasks": held, "normalization": stats, "dropped_tail_steps": dropped_tail,
            "onset_base_rate": float(onset_all.mean()),
            "chunk_stride": stride}
    return ds, skips, info


# ------------------------------------------------------------------------------------- run


def run(cfg: ConvertConfig) -> Path:
    """Convert ``cfg.root`` into a store at ``out_dir(cfg)``; write ``conversion_report.json`` inside it.

    Re-running with the same config returns the existing store; an interrupted run resumes from the
    per-scene cache. Raises :class:`DataError` if no scene could be converted (the report is still written).
    """
    if not cfg.root:
        raise ConfigError("root is required: the RH20T folder (RH20T_cfgN or its parent)")
    out = out_dir(cfg)
    report_path = out / "conversion_report.json"
    if store_is_current(out, content_config(cfg), cfg.overwrite):
        print(f"[rh20t] {out} already holds this conversion; skipping")
        return out
    cdir = cache_dir(cfg)
    if cfg.overwrite and cdir.exists():
        shutil.rmtree(cdir)
    cdir.mkdir(parents=True, exist_ok=True)
    root = Path(cfg.root)
    refs = scan(root / f"RH20T_cfg{cfg.cfg}" if (root / f"RH20T_cfg{cfg.cfg}").is_dir() else root)
    if cfg.max_scenes:
        refs = refs[: cfg.max_scenes]
    converted: list[tuple[SceneRef, dict]] = []
    skips: list[dict] = []
    for ref in tqdm(refs, desc=f"rh20t cfg{cfg.cfg}", unit="scene", disable=not cfg.progress):
        arrays, skip = convert_scene_cached(ref, cfg, cdir)
        if arrays is not None:
            converted.append((ref, arrays))
        else:
            skips.append(skip)
    ds, more_skips, info = assemble(converted, cfg)
    skips += more_skips
    counts: dict[str, int] = {}
    for s in skips:
        counts[s["reason"]] = counts.get(s["reason"], 0) + 1
    report = {
        "root": str(cfg.root), "cfg": cfg.cfg, "robot": ROBOTS[cfg.cfg], "camera": cfg.camera,
        "scenes_found": len(refs), "scenes_converted": len(info.get("scenes", [])),
        "scenes_skipped": len(skips), "skip_counts": dict(sorted(counts.items())),
        "skip_reason_meaning": {k: SKIP_REASONS[k] for k in sorted(counts)},
        "skipped": skips, "episodes": 0 if ds is None else ds.num_episodes,
        "dropped_tail_steps": info.get("dropped_tail_steps", 0), "cache": str(cdir),
    }
    if ds is None:
        out.mkdir(parents=True, exist_ok=True)
        write_json(report_path, report)
        raise DataError(f"no RH20T cfg{cfg.cfg} scene under {cfg.root} could be converted "
                        f"(skips: {report['skip_counts'] or 'no scene folders found'}); see {report_path}")
    manifest = {
        "generator": "pokeworld.real.rh20t", "version": __version__, "pipeline_version": PIPELINE_VERSION,
        "kind": "rh20t", "seed": cfg.seed, "config": content_config(cfg), "robot": ROBOTS[cfg.cfg],
        "hz": cfg.hz, "columns": {"proprio": list(PROPRIO_COLUMNS), "touch": list(TOUCH_COLUMNS),
                                  "actions": list(ACTION_COLUMNS)},
        "normalization": info["normalization"],
        "normalization_note": "proprio/touch/actions = (clip(x, lo, hi) - mean) / std; lo/hi = "
                              f"{list(cfg.clip_percentiles)} percentiles, all statistics from split 0 (train) only",
        "labels_note": "force/torque: zeroed base-frame F/T [N, N m], raw; contact: |F| > "
                       f"{cfg.onset_threshold_n} N; contact_onset: no contact at t and contact within the next "
                       f"{cfg.onset_horizon} steps (computed on the whole scene before chunking); tcp_pos [m]; "
                       "tcp_quat (w,x,y,z); gripper_width [m]; time_s since scene start",
        "heldout_tasks": info["heldout_tasks"], "onset_base_rate": info["onset_base_rate"],
        "chunk_stride": info["chunk_stride"], "scenes": info["scenes"],
        "skip_counts": report["skip_counts"],
    }
    save(ds, out, manifest)
    report["split_counts"] = ds.manifest["split_counts"]
    report["content_sha256"] = ds.manifest["content_sha256"]
    write_json(report_path, report)
    print(f"[rh20t] wrote {ds.num_episodes} episodes from {len(info['scenes'])} scenes to {out} "
          f"({report['scenes_skipped']} scenes skipped: {report['skip_counts']})")
    return out


__all__ = ["ConvertConfig", "PRESETS", "make_config", "run", "scan", "parse_scene_name", "process_scene",
           "SceneSkip", "SKIP_REASONS", "CAMERA_ROLES", "ROBOTS", "contact_onset", "split_scenes", "dataclasses"]
