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

Pickled ``.npy`` files are read by :mod:`pokeworld.real.safe_pickle`'s restricted unpickler (a pickle naming
anything but numpy arrays and python containers skips the scene as ``unsafe_pickle`` before it runs).
Isolated bad records (NaN, overflowed ~1e36, all-zero TCP, out-of-range values) are dropped and
counted; a camera role falls back along its ordered serial list, then (external roles only) to another
external camera present in the scene; a missing base-frame F/T file is
replaced by the camera-frame one rotated through the calibration. Any other defect of one scene
(missing stream / calibration / camera, an unusable stream, empty or truncated video, unknown
configuration...) skips that scene with a reason code that is counted in
``<out>/conversion_report.json`` (with the cameras used, the dropped records and the F/T sources);
a run never stops half-way because of one bad scene and never writes an array it could not verify.
``max_scenes`` draws a seeded, task-stratified, nested random subset for scaling studies.

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
from scipy.spatial.transform import Rotation
from tqdm.auto import tqdm

from .. import __version__
from ..config import from_preset, to_dict
from ..data import Dataset, save, store_is_current
from ..errors import ConfigError, DataError
from ..io import atomic_path, write_json
from .safe_pickle import UnsafePickleError, load_npy, load_npy_item

PIPELINE_VERSION = 3
"""Bumped whenever per-scene processing changes, so stale scene caches are never reused. 3: a scene without any
of its role's serials falls back to another external camera (cached ``missing_camera`` skips are stale), camera
rows carry ``fallback_kind``, pickles are read by the restricted unpickler (``unsafe_pickle``)."""

ROBOTS: dict[int, str] = {1: "flexiv", 2: "flexiv", 3: "ur5", 4: "ur5", 5: "franka", 6: "kuka", 7: "kuka"}
"""RH20T robot configurations (rh20t_api configs/configs.json, ``conf_num`` -> ``robot``)."""

# Camera serial numbers per configuration and role, each an ORDERED list: the first serial present in a
# scene is used, the next ones are fallbacks (the serial each scene used is recorded in the manifest and
# counted in the report). Roles follow the RH20T authors' own loader (cage-policy/CAGE utils/dataset.py:
# FRONT_CAM / IN_HAND_CAMS / SIDE_CAM / BACK_CAM per cfg); the first "far" serial of each cfg is the "front"
# camera of kpertsch/rh20t_dataset_converter rh20t/cam_definitions.py, whose "overhead" cfg6/7 serial
# 104122060811 the authors list as a BACK camera. In-hand serials also agree with rh20t_api
# configs/configs.json ``in_hand``. docs/rh20t.md has the provenance table. Override per run with
# ``ConvertConfig.camera_serials`` (an explicit list never falls back).
_FRONT_FLEXIV_B = ("037522062165", "104122061850", "f0461559")
_FRONT_UR = ("038522062288", "104122062295", "104422070011", "f0172289")
_FRONT_KUKA = ("104122061018", "104122061330", "f0271510")
_SIDE_B = ("104122063678", "105422061350")
_BACK_B = ("036422060215", "104422070044")
_BACK_UR = ("036422060909", "104122062823")
_SIDE_KUKA = ("037522061512", "104122063633", "104122064161")
_BACK_KUKA = ("104122060811", "104122061602")
CAMERA_ROLES: dict[int, dict[str, tuple[str, ...]]] = {
    1: {"far": ("750612070851", "035622060973", "039422060546", "750612070853"), "close": ("043322070878",),
        "side": ("038522062547",), "back": ("819112070044",)},
    2: {"far": _FRONT_FLEXIV_B, "close": ("104422070042",), "side": _SIDE_B, "back": _BACK_B},
    3: {"far": _FRONT_UR, "close": ("045322071843",), "side": ("104122063550",), "back": _BACK_UR},
    4: {"far": _FRONT_UR, "close": ("045322071843",), "side": ("104122063550",), "back": _BACK_UR},
    5: {"far": _FRONT_FLEXIV_B, "close": ("135122079702", "104422070042"), "side": _SIDE_B, "back": _BACK_B},
    6: {"far": _FRONT_KUKA, "close": ("135122070361", "135122075425"), "side": _SIDE_KUKA, "back": _BACK_KUKA},
    7: {"far": _FRONT_KUKA, "close": ("135122070361", "135122075425"), "side": _SIDE_KUKA, "back": _BACK_KUKA},
}
"""cfg -> role -> ordered candidate serials (first present wins, later ones are fallbacks). Roles: far (front
third-person / global view), close (in-hand wrist camera), side, back; the camera option ``two_view`` means
far + close side by side."""

CAMERA_ROTATION: dict[tuple[int, str], int] = {
    (3, "f0172289"): 90, (4, "f0172289"): 90, (5, "f0461559"): 270, (6, "f0271510"): 270, (7, "f0271510"): 270,
}
"""(cfg, serial) -> image rotation [degrees, PIL convention: counter-clockwise] for cameras mounted sideways, as the
RH20T authors' loader corrects them (cage-policy/CAGE utils/preprocessings.py ``camera_orientation_correction``),
followed by a bottom square crop unless ``crop`` is given. cfg2's f0461559 is rotated only for some users/tasks
there and is left unrotated here (it is the last far fallback of cfg2)."""

CAMERA_OPTIONS = ("far", "close", "two_view", "side", "back")

IN_HAND_CALIB: dict[int, tuple[str, ...]] = {1: ("043322070878",), 2: ("104422070042",), 3: ("045322071843",),
                                            4: ("045322071843",), 5: ("104422070042", "135122079702"),
                                            6: ("135122075425", "135122070361"), 7: ("135122075425", "135122070361")}
"""rh20t_api configs/configs.json ``in_hand`` in its order: the API anchors the base-to-world transform on
``in_hand[0]``'s extrinsics (scene.extrinsics_base_aligned), so the camera-frame F/T fallback does too."""

TCP_CAMERA_ROT: dict[int, tuple[tuple[float, ...], ...]] = {
    1: ((0, -1, 0), (1, 0, 0), (0, 0, 1)), 2: ((0, -1, 0), (1, 0, 0), (0, 0, 1)),
    3: ((1, 0, 0), (0, 1, 0), (0, 0, 1)), 4: ((1, 0, 0), (0, 1, 0), (0, 0, 1)),
    5: ((0, 1, 0), (-1, 0, 0), (0, 0, 1)), 6: ((0, -1, 0), (1, 0, 0), (0, 0, 1)), 7: ((0, -1, 0), (1, 0, 0), (0, 0, 1)),
}
"""Rotation part of rh20t_api configs.json ``tc_mat`` (TCP -> in-hand camera) per cfg (translations are irrelevant
for rotating force/torque vectors)."""

ALIGN_BASE_ROT: dict[int, tuple[tuple[float, ...], ...]] = {
    c: (((-1, 0, 0), (0, -1, 0), (0, 0, 1)) if c in (3, 4) else ((1, 0, 0), (0, 1, 0), (0, 0, 1))) for c in range(1, 8)}
"""Rotation part of rh20t_api configs.json ``align_mat_base`` per cfg (UR5: a 180 degree turn about z)."""

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
    "camera_frame_ft": "force_torque_base.npy absent; the camera-frame force_torque.npy is present but could not be "
                       "rotated into the base frame (ft_camera_fallback off, or calibration extrinsics / tcp absent)",
    "bad_stream": "a stream file cannot be unpickled or has the wrong structure / shape",
    "unsafe_pickle": "a pickled .npy file (stream, camera timestamps or calibration) references a global the "
                     "restricted unpickler does not admit (e.g. os.system); refused before anything in it ran",
    "nan_stream": "more than max_bad_record_fraction of a stream's records are non-finite (isolated ones are dropped "
                  "and counted instead)",
    "zero_tcp": "more than max_bad_record_fraction of the TCP records are all zeros (pose not logged)",
    "overflow_stream": "more than max_bad_record_fraction of a stream's records hold overflowed values (|x| > 1e6)",
    "bad_units": "most TCP positions beyond max_abs_pos_m (millimetres instead of metres?) or most quaternions "
                 "non-unit (wrong order / units?)",
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
    """Camera role: far (front / global view), close (in-hand wrist camera), two_view (far | close side by side),
    side, back. Each role is an ordered serial list per cfg (CAMERA_ROLES): the first present serial is used."""
    camera_serials: tuple[str, ...] = ()
    """Explicit camera serial(s) overriding the role table (1 serial, or 2 for two_view); no fallback."""
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
    """Sanity bound on |TCP position| [m]: a record beyond it is dropped; most records beyond it mean mm."""
    max_abs_ft: float = 1e4
    """Sanity bound on |force| [N] / |torque| [N m]: a record beyond it is dropped as overflowed."""
    max_bad_record_fraction: float = 0.2
    """Isolated bad records (non-finite, overflowed ~1e36, all-zero TCP, non-unit quaternion, out of range) are
    dropped and counted; a stream with a larger fraction of bad records skips the scene."""
    ft_camera_fallback: bool = True
    """If transformed/force_torque_base.npy is absent but the camera-frame transformed/force_torque.npy is present,
    rotate it into the base frame through the scene's calibration (extrinsics.npy, tcp.npy); otherwise the scene is
    skipped as camera_frame_ft."""
    max_scenes: int = 0
    """Convert a seeded random subset of at most this many scenes, stratified by task (0 = all candidate scenes).
    Subsets of one subset_seed are nested: the first N of a larger draw are the smaller draw."""
    subset_seed: int = 0
    """Seed of the scene subset draw (independent of ``seed``, which draws held-out tasks and splits)."""
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
        if not 0 <= self.max_bad_record_fraction < 1 or self.max_scenes < 0:
            raise ConfigError("max_bad_record_fraction must be in [0, 1) and max_scenes >= 0")
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
    """The dict pickled in an RH20T ``.npy`` file (a 0-d object array), read by the restricted unpickler of
    :mod:`pokeworld.real.safe_pickle` (never numpy's unrestricted pickle loading)."""
    if not path.exists():
        raise SceneSkip("missing_stream", f"{what} file {path} is absent")
    try:
        obj = load_npy_item(path)
    except UnsafePickleError as e:
        raise SceneSkip("unsafe_pickle", f"{path}: {e}") from None
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


# ------------------------------------------------------------- camera-frame F/T -> base frame


# Rotations through scipy (conventions pinned by tests/test_rh20t.py): quaternions here are (w, x, y, z),
# scipy's are (x, y, z, w); transforms3d's default Euler axes ``sxyz`` are scipy's static "xyz".
def euler_sxyz_to_mat(ai: float, aj: float, ak: float) -> np.ndarray:
    """Static-axes x-y-z Euler angles (transforms3d's default ``sxyz``, used by rh20t_api) -> rotation matrix."""
    return Rotation.from_euler("xyz", [ai, aj, ak]).as_matrix()


def quat_to_mat(q: np.ndarray) -> np.ndarray:
    """Quaternion (w, x, y, z), normalised first -> rotation matrix."""
    return Rotation.from_quat(np.roll(np.asarray(q, np.float64), -1)).as_matrix()


def rotvec_to_mat(v: np.ndarray) -> np.ndarray:
    """Rotation vector (axis * angle) -> rotation matrix."""
    return Rotation.from_rotvec(np.asarray(v, np.float64)).as_matrix()


def calib_tcp_rotation(tcp: np.ndarray, cfg_num: int) -> np.ndarray:
    """Rotation of the calibration-time TCP pose ``calib/<calib>/tcp.npy`` as rh20t_api reads it.

    kuka: (x, y, z [mm], Euler sxyz [rad]); franka: (x, y, z, rotation vector), then a flip diag(1, -1, -1);
    flexiv / ur5: (x, y, z, quaternion w, x, y, z), or Euler sxyz when it has 6 values.
    """
    t = np.asarray(tcp, np.float64).reshape(-1)
    robot = ROBOTS[cfg_num]
    if robot == "franka" and t.size == 6:
        return rotvec_to_mat(t[3:6]) @ np.diag([1.0, -1.0, -1.0])
    if t.size == 6:
        return euler_sxyz_to_mat(*t[3:6])
    if t.size == 7:
        return quat_to_mat(t[3:7])
    raise ValueError(f"calibration tcp must have 6 or 7 values, got {t.size}")


def base_to_camera_rotations(calib_dir: Path, cfg_num: int) -> dict[str, np.ndarray]:
    """serial -> 3x3 rotation R with v_camera = R v_base, from a calibration folder (rh20t_api's chain).

    The API projects base-frame F/T into camera ``s`` with ``extrinsics[s] @ base_world @ align_mat_base``,
    ``base_world = inv(extrinsics[in_hand[0]]) @ tc_mat @ inv(calib_tcp)``; only the rotations matter for
    vectors. Raises SceneSkip(camera_frame_ft) when a needed file or the anchor in-hand camera is absent.
    """
    ext_path, tcp_path = calib_dir / "extrinsics.npy", calib_dir / "tcp.npy"
    if not ext_path.exists() or not tcp_path.exists():
        raise SceneSkip("camera_frame_ft", f"force_torque_base.npy absent and calibration {calib_dir} lacks "
                                           "extrinsics.npy / tcp.npy to rotate the camera-frame force_torque.npy")
    try:
        ext = load_npy_item(ext_path)
        mats = {str(k): np.asarray(v, np.float64).reshape(-1, 4, 4)[0][:3, :3] for k, v in dict(ext).items()}
        r_tcp = calib_tcp_rotation(load_npy(tcp_path), cfg_num)
    except UnsafePickleError as e:
        raise SceneSkip("unsafe_pickle", f"calibration {calib_dir}: {e}") from None
    except Exception as e:  # damaged calibration files
        raise SceneSkip("camera_frame_ft", f"cannot read calibration {calib_dir}: {type(e).__name__}: {e}") from None
    anchor = IN_HAND_CALIB[cfg_num][0]
    if anchor not in mats:
        raise SceneSkip("camera_frame_ft", f"calibration {calib_dir} has no extrinsics for the anchor in-hand camera "
                                           f"{anchor} (has {sorted(mats)})")
    world_from_base = (mats[anchor].T @ np.asarray(TCP_CAMERA_ROT[cfg_num], np.float64) @ r_tcp.T
                       @ np.asarray(ALIGN_BASE_ROT[cfg_num], np.float64))
    return {s: m @ world_from_base for s, m in mats.items()}


def read_ft(d: Path, meta: dict, cfg: ConvertConfig) -> tuple[np.ndarray, np.ndarray, str, int]:
    """Zeroed base-frame F/T records (raw ts, values), their source (``base`` or ``camera_via_calib``) and the
    number of camera-frame records left out because their serial has no calibration extrinsics."""
    tr = d / "transformed"
    base, cam = tr / "force_torque_base.npy", tr / "force_torque.npy"
    if base.exists() or not cam.exists():
        ts, v = read_records(load_pickled_dict(base, "transformed/force_torque_base.npy"), "zeroed", 6,
                             "force_torque_base.npy")
        return ts, v, "base", 0
    if not cfg.ft_camera_fallback:
        raise SceneSkip("camera_frame_ft", "force_torque_base.npy absent, only the camera-frame force_torque.npy is "
                                           "present and ft_camera_fallback is off")
    rots = base_to_camera_rotations(d.parent / "calib" / str(meta.get("calib")), cfg.cfg)
    to_base = {s: np.kron(np.eye(2), r.T) for s, r in rots.items()}  # force and torque rotate alike
    obj = load_pickled_dict(cam, "transformed/force_torque.npy")
    missing = sorted(str(s) for s in obj if str(s) not in to_base)
    ts, v = read_records(obj, "zeroed", 6, "force_torque.npy (camera frame)", transform=to_base)
    if len(ts) == 0:
        raise SceneSkip("camera_frame_ft", f"no serial of force_torque.npy ({missing}) has calibration extrinsics")
    return ts, v, "camera_via_calib", sum(len(obj[s]) for s in obj if str(s) not in to_base)


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


def _crop_resize(gray: np.ndarray, crop: tuple[float, ...], out_hw: tuple[int, int], rotate: int = 0) -> np.ndarray:
    """Rotate (degrees counter-clockwise, multiple of 90), crop (fractions, or a square: centred, or bottom for a
    rotated camera) and area-resize one grayscale image."""
    import cv2

    if rotate % 360:
        code = {90: cv2.ROTATE_90_COUNTERCLOCKWISE, 180: cv2.ROTATE_180, 270: cv2.ROTATE_90_CLOCKWISE}[rotate % 360]
        gray = cv2.rotate(gray, code)
    h, w = gray.shape
    if rotate % 360 and not crop:  # sideways camera: bottom square, as the RH20T authors' loader crops it
        s = min(h, w)
        box = gray[h - s:, (w - s) // 2: (w - s) // 2 + s]
    elif crop:
        t, l, b, r = crop
        box = gray[int(round(t * h)): max(int(round(b * h)), int(round(t * h)) + 1),
                   int(round(l * w)): max(int(round(r * w)), int(round(l * w)) + 1)]
    else:
        s = min(h, w)
        y0, x0 = (h - s) // 2, (w - s) // 2
        box = gray[y0: y0 + s, x0: x0 + s]
    return cv2.resize(box, (out_hw[1], out_hw[0]), interpolation=cv2.INTER_AREA)


def read_camera(cam_dir: Path, t_grid: np.ndarray, cfg: ConvertConfig, out_hw: tuple[int, int],
                rotate: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Camera timestamps (ms, sorted) and, if ``t_grid`` is given, the nearest frame for each grid time.

    ``color.mp4`` + ``timestamps.npy`` is used when present, else extracted ``color/<ts>.jpg``.
    With ``t_grid=None`` only the timestamps are returned (frames empty).
    """
    mp4, tsf, jpg_dir = cam_dir / "color.mp4", cam_dir / "timestamps.npy", cam_dir / "color"
    if mp4.exists():
        meta = load_pickled_dict(tsf, "camera timestamps.npy")
        if "color" not in meta:
            raise SceneSkip("bad_stream", f"{tsf} has no 'color' key (keys: {sorted(meta)})")
        try:
            ts = np.asarray(meta["color"], np.int64).reshape(-1)
        except (TypeError, ValueError, OverflowError) as e:
            raise SceneSkip("bad_stream", f"{tsf} 'color' is not a list of integer timestamps "
                                          f"({type(e).__name__}: {e})") from None
        if ts.size == 0:
            raise SceneSkip("empty_video", f"{tsf} lists no color frames")
        if not np.all((ts > 1e12) & (ts < 1e13)) or np.any(np.diff(ts) <= 0):
            raise SceneSkip("bad_timestamps", f"{tsf} color timestamps are not increasing 13-digit milliseconds")
        if t_grid is None:
            return ts, np.zeros((0, *out_hw), np.uint8)
        idx = _nearest(ts, t_grid, cfg.frame_tolerance_s, cam_dir.name)
        frames = _decode_mp4(mp4, len(ts), np.unique(idx), cfg.crop, out_hw, rotate)
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
        idx = _nearest(ts, t_grid, cfg.frame_tolerance_s, cam_dir.name)
        cache: dict[int, np.ndarray] = {}
        for i in np.unique(idx):
            img = _read_gray_image(files[int(ts[i])])
            cache[int(i)] = _crop_resize(img, cfg.crop, out_hw, rotate)
        return ts, np.stack([cache[int(i)] for i in idx])
    raise SceneSkip("missing_stream", f"{cam_dir} has neither color.mp4 nor a color/ image folder")


def _read_gray_image(path: Path) -> np.ndarray:
    """Decode one extracted frame to grayscale; a truncated file skips the scene.

    OpenCV decodes a JPEG cut short without an error (libjpeg only warns and fills the missing rows with gray),
    so a frame must end with its end-of-image marker (JPEG ``FFD9``, PNG ``IEND`` chunk) before it is decoded.
    """
    import cv2

    data = path.read_bytes()
    end = data.rstrip(b"\x00")  # zero padding after the end marker is harmless
    complete = end.endswith(b"IEND\xaeB`\x82") if path.suffix.lower() == ".png" else end.endswith(b"\xff\xd9")
    if not complete:
        raise SceneSkip("unreadable_video", f"image {path} is truncated (no end-of-image marker, {len(data)} bytes)")
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise SceneSkip("unreadable_video", f"cannot decode image {path}")
    return img


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


def _decode_mp4(path: Path, n_expected: int, wanted: np.ndarray, crop, out_hw,
                rotate: int = 0) -> dict[int, np.ndarray]:
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
                    out[n] = _crop_resize(frame.to_ndarray(format="gray"), crop, out_hw, rotate)
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
    # OverflowError: json reads Infinity as a float, and int(inf) overflows
    except (json.JSONDecodeError, KeyError, TypeError, ValueError, UnicodeDecodeError, OverflowError) as e:
        raise SceneSkip("bad_metadata", f"{mpath}: {type(e).__name__}: {e}") from None
    if rating < cfg.min_rating:
        raise SceneSkip("low_rating", f"rating {rating} < min_rating {cfg.min_rating}")
    calib = meta.get("calib")
    if calib is None or calib == -1 or calib == "-1":
        raise SceneSkip("missing_calib", f"metadata calib is {calib!r}")
    if cfg.require_calib_dir and not (d.parent / "calib" / str(calib)).is_dir():
        raise SceneSkip("missing_calib", f"calibration folder {d.parent / 'calib' / str(calib)} is absent")
    # numeric streams (robot base frame, SI units per rh20t_api's transformed/ folder); isolated bad records
    # (NaN, overflow, all-zero TCP...) are dropped and counted, an unusable stream skips the scene
    tr = d / "transformed"
    dropped: dict[str, dict[str, int]] = {}
    raw_tcp = read_records(load_pickled_dict(tr / "tcp_base.npy", "transformed/tcp_base.npy"), "tcp", 7,
                           "tcp_base.npy")
    tcp_ts, tcp, dropped["tcp_base"] = clean_records(*raw_tcp, "tcp", "tcp_base.npy", cfg)
    ft_raw_ts, ft_raw, ft_source, uncalibrated = read_ft(d, meta, cfg)
    ft_name = "force_torque_base" if ft_source == "base" else "force_torque"
    ft_ts, ft, dropped[ft_name] = clean_records(ft_raw_ts, ft_raw, "ft", f"{ft_name}.npy zeroed", cfg)
    if uncalibrated:  # records of serials without extrinsics cannot be rotated into the base frame
        dropped[ft_name] = {**dropped[ft_name], "no_extrinsics": uncalibrated}
    raw_gr = read_gripper(load_pickled_dict(tr / "gripper.npy", "transformed/gripper.npy"), cfg.gripper_field)
    gr_ts, grip, dropped["gripper"] = clean_records(*raw_gr, "gripper", "gripper.npy", cfg)
    dropped = {k: v for k, v in dropped.items() if v}
    # cameras
    cams = camera_serials(d, cfg)
    serials = [c[1] for c in cams]
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
    for name, ts in (("tcp_base", tcp_ts), (ft_name, ft_ts), ("gripper", gr_ts)):
        inside = ts[(ts >= t0) & (ts <= t1)]
        edges = np.concatenate([[t0], inside, [t1]])
        gap = np.diff(edges).max() / 1000.0
        if gap > cfg.max_gap_s:
            raise SceneSkip("stream_gap", f"{name} has a {gap:.2f} s gap (> max_gap_s={cfg.max_gap_s}) "
                                          f"after dropping {dropped.get(name, {})} bad records")
    views = [read_camera(d / f"cam_{s}", t_grid, cfg, out_hw, CAMERA_ROTATION.get((cfg.cfg, s), 0))[1]
             for s in serials]
    frames = np.concatenate(views, axis=2) if half else views[0]
    # resample numeric streams
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


# ----------------------------------------------------------------------------------- caching


_CACHE_FIELDS = ("cfg", "camera", "camera_serials", "image_size", "crop", "hz", "min_rating", "require_calib_dir",
                 "gripper_field", "max_gap_s", "frame_tolerance_s", "max_abs_pos_m", "max_abs_ft",
                 "max_bad_record_fraction", "ft_camera_fallback")


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


# ------------------------------------------------------------------------------- subsets


def stratified_indices(tasks, keys, n: int, seed: int) -> list[int]:
    """Indices of a seeded random subset of ``n`` items stratified by task (systematic sampling; nested in ``n``).

    Every task's items (in ``keys`` order) are put in a seeded random order and item ``k`` of a task with ``n_t``
    items gets the key ``(k + u_t) / n_t`` (``u_t`` a seeded uniform offset per task); the ``n`` smallest keys are
    kept. So each task contributes ``n * n_t / N`` items up to rounding (at most one off), the draw is random
    within each task, and a smaller ``n`` (same seed) is a subset of a larger one, which keeps scaling curves
    nested. Returns the chosen indices in ``keys`` order; all of them when ``n <= 0`` or ``n >= len(keys)``.
    """
    order_all = sorted(range(len(keys)), key=lambda i: keys[i])
    if n <= 0 or n >= len(keys):
        return order_all
    by_task: dict[int, list[int]] = {}
    for i in order_all:
        by_task.setdefault(int(tasks[i]), []).append(i)
    ranked: list[tuple[float, Any, int]] = []
    for task, group in sorted(by_task.items()):
        rng = np.random.default_rng([seed, 0x5EED, task])  # per task: a task's draw ignores the other tasks
        u_order = rng.permutation(len(group))
        u = rng.random()
        for k, j in enumerate(u_order):
            ranked.append(((k + u) / len(group), keys[group[j]], group[j]))
    ranked.sort(key=lambda x: x[:2])
    return sorted((x[2] for x in ranked[:n]), key=lambda i: keys[i])


def stratified_subset(refs: list[SceneRef], n: int, seed: int) -> list[SceneRef]:
    """A seeded, task-stratified, nested random subset of ``n`` scenes (:func:`stratified_indices`), sorted by name."""
    keys = [(r.name, str(r.path)) for r in refs]
    return [refs[i] for i in stratified_indices([r.task for r in refs], keys, n, seed)]


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
        extra = json.loads(str(a["info"])) if "info" in a else {}
        scene_rows.append({"name": ref.name, "path": str(ref.path), "task": ref.task, "user": ref.user,
                           "scene": ref.scene, "rating": int(a["rating"]), "serials": str(a["serials"]).split(","),
                           "cameras": extra.get("cameras", []), "ft_source": extra.get("ft_source", "base"),
                           "dropped_records": extra.get("dropped_records", {}),
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


def corpus_source(root: str | os.PathLike, cfg_id: int) -> dict:
    """Where the scenes under ``root`` come from: a corpus written by ``pokeworld rh20t-synth`` keeps its
    ground truth in ``<corpus>/truth/manifest.json`` beside ``RH20T_cfgN/``; anything else is taken as recorded
    RH20T data. The store carries this so that every report on it can say which of the two it measured."""
    root = Path(root)
    corpus = root.parent if root.name == f"RH20T_cfg{cfg_id}" else root
    man_path = corpus / "truth" / "manifest.json"
    try:
        man = json.loads(man_path.read_text())
    except (OSError, ValueError):
        return {"synthetic": False}
    if not isinstance(man, dict) or man.get("generator") != "pokeworld.real.synthetic":
        return {"synthetic": False}
    return {"synthetic": True, "generator": man["generator"], "generator_version": man.get("version"),
            "seed": man.get("seed"), "truth": str(man_path)}


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
    converted: list[tuple[SceneRef, dict]] = []
    skips: list[dict] = []
    candidates = []
    for ref in refs:  # name-level skips (human demos, other / unknown cfg) are decided before subsetting
        try:
            check_scene_name(ref, cfg)
            candidates.append(ref)
        except SceneSkip as e:
            skips.append({"scene": ref.name, "path": str(ref.path), "reason": e.reason, "message": e.message})
    chosen = stratified_subset(candidates, cfg.max_scenes, cfg.subset_seed)
    subset = None
    if cfg.max_scenes:
        per_task: dict[int, list[int]] = {}
        for r in candidates:
            per_task.setdefault(r.task, [0, 0])[0] += 1
        for r in chosen:
            per_task[r.task][1] += 1
        subset = {"max_scenes": cfg.max_scenes, "subset_seed": cfg.subset_seed, "candidates": len(candidates),
                  "sampled": len(chosen), "stratified_by": "task",
                  "per_task": {str(t): {"candidates": c, "sampled": k} for t, (c, k) in sorted(per_task.items())},
                  "scenes": [r.name for r in chosen]}
    for ref in tqdm(chosen, desc=f"rh20t cfg{cfg.cfg}", unit="scene", disable=not cfg.progress):
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
    rows = info.get("scenes", [])
    camera_counts: dict[str, dict[str, int]] = {}
    dropped_total: dict[str, dict[str, int]] = {}
    ft_sources: dict[str, int] = {}
    for r in rows:
        for c in r["cameras"]:
            per = camera_counts.setdefault(c["role"], {})
            per[c["serial"]] = per.get(c["serial"], 0) + 1
        for stream, kinds in r["dropped_records"].items():
            for k, v in kinds.items():
                dropped_total.setdefault(stream, {})[k] = dropped_total.setdefault(stream, {}).get(k, 0) + v
        ft_sources[r["ft_source"]] = ft_sources.get(r["ft_source"], 0) + 1
    report = {
        "root": str(cfg.root), "cfg": cfg.cfg, "robot": ROBOTS[cfg.cfg], "camera": cfg.camera,
        "source": corpus_source(root, cfg.cfg), "scenes_found": len(refs), "scenes_candidate": len(candidates),
        "scenes_sampled": len(chosen),
        "subset": subset, "scenes_converted": len(rows),
        "camera_counts": {role: dict(sorted(v.items())) for role, v in sorted(camera_counts.items())},
        "camera_fallback_scenes": sum(any(c["fallback"] for c in r["cameras"]) for r in rows),
        "camera_other_external_scenes": sum(any(c.get("fallback_kind") == "other_external" for c in r["cameras"])
                                            for r in rows),
        "ft_source_counts": dict(sorted(ft_sources.items())),
        "scenes_with_dropped_records": sum(bool(r["dropped_records"]) for r in rows),
        "dropped_records": {k: dict(sorted(v.items())) for k, v in sorted(dropped_total.items())},
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
        "skip_counts": report["skip_counts"], "camera_counts": report["camera_counts"],
        "ft_source_counts": report["ft_source_counts"], "dropped_records": report["dropped_records"],
        "subset": subset, "source": report["source"],
    }
    save(ds, out, manifest)
    report["split_counts"] = ds.manifest["split_counts"]
    report["content_sha256"] = ds.manifest["content_sha256"]
    write_json(report_path, report)
    print(f"[rh20t] wrote {ds.num_episodes} episodes from {len(info['scenes'])} scenes to {out} "
          f"({report['scenes_skipped']} scenes skipped: {report['skip_counts']}; cameras {report['camera_counts']}; "
          f"{report['scenes_with_dropped_records']} scenes with dropped records: {report['dropped_records']})")
    return out


__all__ = ["ConvertConfig", "PRESETS", "make_config", "run", "scan", "parse_scene_name", "process_scene",
           "SceneSkip", "SKIP_REASONS", "CAMERA_ROLES", "CAMERA_ROTATION", "ROBOTS", "contact_onset", "split_scenes",
           "stratified_subset", "clean_records", "base_to_camera_rotations", "BAD_RECORD_KINDS", "dataclasses"]
