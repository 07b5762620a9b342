"""A synthetic corpus in the exact RH20T on-disk layout, from PokeWorld episodes whose force is known.

``pokeworld rh20t-synth ROOT --preset cpu`` simulates PokeWorld episodes (:mod:`pokeworld.sim`) and writes each
as an RH20T scene under ``ROOT/RH20T_cfg7/`` (the layout :mod:`pokeworld.real.fixtures` writes for analytic
scenes: pickled ``transformed/`` dicts, ``cam_<serial>/color.mp4`` + ``timestamps.npy`` or extracted
``cam_<serial>/color/<ms>.jpg``, irregular ~10 Hz timestamps with jitter, ``metadata.json``, ``calib/``), plus
the ground truth beside it in ``ROOT/truth/`` (one ``<scene>.npz`` per scene and ``manifest.json``), so the §5
pipeline (convert -> train -> probe) can be checked against planted answers. docs/rh20t.md, "Synthetic
RH20T-layout corpus", describes every mapping; in short:

* **robot**: the PokeWorld finger is the TCP. Position [m] = ``tcp_offset_m + metres_per_unit * (x, y, 0)``
  (arena x, y -> base x, y); orientation a fixed gripper-down quaternion with a small random rotation per
  record; gripper width constant.
* **force**: the finger-object contact force is the F/T reading in the base frame: the reaction force on the
  finger averaged over each 50 ms control step, times ``newtons_per_unit`` (a sustained push at half F_max is
  ~26 N, so contacts exceed the paper's 10 N threshold), F_z = 0; torque = r x F with the contact point
  ``lever_arm_m`` below the sensor. The continuous-time truth is piecewise linear through the per-step means
  (placed at step mid-times); recorded ``zeroed`` values add bounded uniform noise (``ft_noise_n``).
* **tasks** = behaviour-policy mixtures / parameter ranges (:data:`TASKS`); **users** = seeds; every scene is
  simulated from its own ``SeedSequence([seed, task, user, scene])``, so generation is deterministic per seed
  and a scene does not depend on the preset that wrote it.
* **cameras**: a far (global) camera that sees the whole arena in the centred square of a 16:9 frame, and a
  close (wrist) camera, a window of ``close_window`` arena units centred on the finger; each at its own
  irregular ~10 Hz timestamps. Every numeric stream of a serial is sampled at that serial's frame times (as in
  RH20T), so merged streams are irregular ~20 Hz.
* **defects** (:data:`DEFECTS`): scenes the converter must repair (isolated NaN / overflowed / all-zero records,
  only the camera-frame F/T, the far camera under a fallback serial) or skip with a known reason.

The truth of a scene is given on the exact 10 Hz grid the converter builds (``start_time + 100 k`` ms: every
stream starts before ``metadata.start_time`` and ends after ``finish_time``), as both the true physical signal
(``force``, ``tcp_pos``, ...) and ``expected_*``: the linear interpolation of the recorded samples after the
converter's documented drop rules, which a correct conversion reproduces to float precision.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from .. import __version__
from ..config import from_preset, to_dict
from ..data import load
from ..errors import ConfigError, DataError
from ..io import (
    OwnedDir,
    atomic_path,
    check_owned_dir,
    create_new,
    read_json,
    read_json_if_present,
    remove_owned_dir,
    save_npz,
    write_json,
)
from ..sim import environments
from ..sim.core import PARAM_NAMES, ParamRanges, PokeWorldSim
from ..sim.physics import render_kernel
from ..sim.policy import make_policy
from .evaluate import r2
from .fixtures import save_array, save_dict, write_mp4
from .rh20t import (
    ALIGN_BASE_ROT,
    CAMERA_ROLES,
    IN_HAND_CALIB,
    ROBOTS,
    SKIP_REASONS,
    TCP_CAMERA_ROT,
    contact_onset,
    euler_sxyz_to_mat,
    quat_mul,
    quat_to_mat,
)

T0_MS = 1_700_000_000_000
"""First scene's start (13-digit ms); scene i starts one hour after scene i-1."""
CALIB_MS = T0_MS - 86_400_000
"""The calibration every synthetic scene uses (``calib/<CALIB_MS>/``)."""
EMPTY_CALIB_MS = CALIB_MS - 86_400_000
"""A calibration folder with intrinsics only (no extrinsics / tcp): the camera-frame F/T cannot be rotated."""
FT_RAW_OFFSET = np.array([4.0, -2.5, 9.0, 0.08, -0.05, 0.11])
"""raw = zeroed + FT_RAW_OFFSET: a converter reading 'raw' would be off by this."""
QUAT_DOWN = np.array([0.0, 1.0, 0.0, 0.0])
"""Base TCP orientation (w, x, y, z): 180 degrees about x, gripper pointing down."""
OVERFLOW_VALUE = -9.432e36
"""An overflowed TCP value as seen in RH20T (cage-policy/CAGE utils/dataset.py mentions -9.432e+36)."""

TASKS: dict[int, dict] = {
    1: {"name": "push", "policy": {"mode_weights": (0.85, 0.05, 0.10), "launch_fraction": 0.3}},
    2: {"name": "strike", "policy": {"mode_weights": (0.15, 0.70, 0.15), "launch_fraction": 0.3}},
    3: {"name": "wander", "policy": {"mode_weights": (0.20, 0.10, 0.70)}},
    4: {"name": "heavy", "ranges": {"mass": (1.5, 3.0)}},
    5: {"name": "light_slippery", "ranges": {"mass": (0.5, 1.0), "gamma": (0.5, 1.5)}},
    6: {"name": "stiff", "ranges": {"stiffness": (3000.0, 6000.0)}},
}
"""Synthetic task id -> behaviour-policy / hidden-parameter overrides of the PokeWorld defaults."""

DEFECTS: dict[str, str | None] = {
    # repaired: converted, with the defect counted
    "nan_ft_isolated": None, "overflow_tcp": None, "zero_tcp_records": None, "camera_frame_ft": None,
    "far_fallback": None,
    # skipped with a reason
    "nan_ft": "nan_stream", "zero_tcp": "zero_tcp", "mm_units": "bad_units", "overflow_ft": "overflow_stream",
    "camera_frame_ft_no_calib": "camera_frame_ft", "low_rating": "low_rating", "human": "human_demo",
    "truncated_video": "truncated_video", "missing_camera": "missing_camera", "too_short": "too_short",
}
"""Defect kind -> the converter's skip reason (``None``: the scene converts, the defect is repaired / counted)."""
assert all(r is None or r in SKIP_REASONS for r in DEFECTS.values())


@dataclass
class SynthConfig:
    """Write a synthetic RH20T-layout corpus (PokeWorld episodes with known force) and its ground truth."""

    root: str = "data/rh20t_synth"
    """Output root: scenes go to ROOT/RH20T_cfg<cfg>/, ground truth to ROOT/truth/."""
    seed: int = 0
    """Master seed; the same seed and config give the same corpus (scene by scene)."""
    cfg: int = 7
    """RH20T configuration the scenes claim (its camera serials and calibration conventions are used)."""
    tasks: tuple[int, ...] = (1, 2, 3, 4, 5, 6)
    """Synthetic task ids (keys of TASKS)."""
    users_per_task: int = 8
    """Users (seeds) per task."""
    scenes_per_user: int = 6
    """Scenes per (task, user)."""
    duration_s: tuple[float, float] = (13.5, 16.0)
    """Scene duration range [s] (uniform); >= 13 s fits two 65-step chunks at 10 Hz."""
    defect_repeats: int = 2
    """Scenes written per defect kind (DEFECTS), on top of the good scenes; 0 disables defects."""
    jpg_every: int = 5
    """Every n-th scene stores extracted jpg frames instead of color.mp4 (0: all mp4)."""
    frame_size: tuple[int, int] = (192, 108)
    """Camera frame (width, height), 16:9 like RH20T's 640x360."""
    close_window: float = 0.5
    """Side of the close (wrist) camera's view, in arena units, centred on the finger."""
    metres_per_unit: float = 0.5
    """TCP metres per arena unit (the unit-square arena is 0.5 m wide)."""
    tcp_offset_m: tuple[float, float, float] = (0.35, -0.25, 0.12)
    """TCP position of the arena origin in the robot base frame [m]."""
    newtons_per_unit: float = 10.0
    """Newtons per simulator force unit (F_max = 5.6 units at the default calibration)."""
    lever_arm_m: float = 0.15
    """Contact point below the F/T sensor [m]: torque = (0, 0, -lever) x F."""
    ft_noise_n: float = 0.3
    """Half-width of the uniform noise on recorded zeroed force [N] (torque: times lever_arm_m)."""
    quat_noise_rad: float = 0.005
    """Std of the random rotation angle per TCP record [rad]."""
    gripper_mm: float = 40.0
    """Constant gripper width [mm]."""
    overwrite: bool = False
    """Rewrite ROOT even if it holds a complete corpus of this config."""
    progress: bool = True
    """Show a progress bar."""

    def __post_init__(self) -> None:
        if self.cfg not in ROBOTS or len(CAMERA_ROLES[self.cfg]["far"]) < 2:
            raise ConfigError(f"cfg must be an RH20T configuration with a far fallback serial, got {self.cfg}")
        bad = [t for t in self.tasks if t not in TASKS]
        if bad or not self.tasks:
            raise ConfigError(f"tasks must be a non-empty subset of {sorted(TASKS)}, got {self.tasks}")
        if self.users_per_task < 1 or self.scenes_per_user < 1 or self.defect_repeats < 0:
            raise ConfigError("users_per_task and scenes_per_user must be >= 1, defect_repeats >= 0")
        lo, hi = self.duration_s
        if not 1.5 <= lo <= hi:
            raise ConfigError(f"duration_s must satisfy 1.5 <= lo <= hi, got {self.duration_s}")
        w, h = self.frame_size
        if w < h or w % 2 or h % 2 or h < 16:
            raise ConfigError(f"frame_size must be (width >= height >= 16), both even, got {self.frame_size}")
        if not 0 < self.close_window <= 1:
            raise ConfigError(f"close_window must be in (0, 1], got {self.close_window}")


PRESETS: dict[str, dict] = {
    "tiny": {"tasks": (1, 2, 3), "users_per_task": 2, "scenes_per_user": 2, "duration_s": (4.0, 5.0),
             "defect_repeats": 1, "jpg_every": 3, "progress": False},
    "cpu": {},
    "paper": {"users_per_task": 20, "scenes_per_user": 8},
}
"""tiny: 12 short scenes + one per defect (seconds, for tests); cpu: 288 scenes of 13.5-16 s + 2 per defect
(converts and trains on 2 cores); paper: 960 scenes (about cfg7's 896)."""


def make_config(preset: str = "cpu", **overrides) -> SynthConfig:
    return from_preset(SynthConfig, PRESETS, preset, **overrides)


def content_config(cfg: SynthConfig) -> dict:
    d = to_dict(cfg)
    for k in ("root", "overwrite", "progress"):
        d.pop(k)
    return d


# ----------------------------------------------------------------------------- scene plan


@dataclass
class ScenePlan:
    """One scene to write: its ids, defect (or None), index (start time) and seed material."""

    task: int
    user: int
    scene: int
    index: int
    defect: str | None = None
    human: bool = False
    extra: dict = field(default_factory=dict)

    def name(self, cfg_num: int) -> str:
        return (f"task_{self.task:04d}_user_{self.user:04d}_scene_{self.scene:04d}_cfg_{cfg_num:04d}"
                + ("_human" if self.human else ""))


def plan_scenes(cfg: SynthConfig) -> list[ScenePlan]:
    """Good scenes (task x user x scene) then defect scenes (scene ids 90+, spread over tasks and users)."""
    plans: list[ScenePlan] = []
    for t in cfg.tasks:
        for u in range(1, cfg.users_per_task + 1):
            for s in range(1, cfg.scenes_per_user + 1):
                plans.append(ScenePlan(t, u, s, len(plans)))
    k = 0
    for defect in DEFECTS:
        for r in range(cfg.defect_repeats):
            t = cfg.tasks[k % len(cfg.tasks)]
            u = 1 + (k // len(cfg.tasks)) % cfg.users_per_task
            plans.append(ScenePlan(t, u, 90 + k, len(plans), defect=defect, human=defect == "human"))
            k += 1
    return plans


# ----------------------------------------------------------------------------- simulation

SCENE_ENVIRONMENT = "calibrated"
"""The PokeWorld environment the synthetic RH20T scenes are rolled in: the one they were built on (forces in F_max
units), so the fixtures and their recorded checks stay as they were."""
SCENE_PHYSICS = environments.physics(SCENE_ENVIRONMENT)


def _override(obj, changes: dict):
    import dataclasses

    return dataclasses.replace(obj, **changes) if changes else obj


def simulate_scene(task: int, duration_s: float, rng_seed: np.random.SeedSequence) -> dict:
    """Roll one PokeWorld episode long enough to cover ``duration_s``; positions / forces per control step."""
    spec = TASKS[task]
    phys = SCENE_PHYSICS
    ranges = _override(ParamRanges(), spec.get("ranges", {}))
    pol_cfg = _override(environments.policy(SCENE_ENVIRONMENT), spec.get("policy", {}))
    n_steps = int(math.ceil(duration_s / phys.dt)) + 2
    sim_seed, pol_seed = rng_seed.spawn(2)
    sim = PokeWorldSim(1, phys, ranges, seed=np.random.default_rng(sim_seed).integers(2**63))
    pol = make_policy(pol_cfg, 1, np.random.default_rng(pol_seed), phys.dt)
    _, vel = pol.reset()
    obs = sim.reset(object_vel=vel)
    finger = np.zeros((n_steps + 1, 2))
    obj = np.zeros((n_steps + 1, 2))
    obj_vel = np.zeros((n_steps + 1, 2))
    force = np.zeros((n_steps + 1, 2))  # mean reaction force on the finger over step k (k >= 1), F_max units
    contact = np.zeros(n_steps + 1, bool)
    for k in range(n_steps + 1):
        priv = sim.privileged()
        finger[k], obj[k], obj_vel[k] = priv["finger_pos"][0], priv["object_pos"][0], priv["object_vel"][0]
        if k == n_steps:
            break
        a = pol.act(obs["proprio"], priv["object_pos"], priv["contact"])
        obs = sim.step(a, render=False)
        force[k + 1] = sim.touch_clean[0, 0:2]
        contact[k + 1] = sim.touch_clean[0, 6] > 0
    params = {name: float(sim.params[0, i]) for i, name in enumerate(PARAM_NAMES)}
    return {"dt": phys.dt, "finger": finger, "object": obj, "object_vel": obj_vel,
            "force_units": force * phys.force_max, "contact": contact, "params": params, "physics": phys}


# ---------------------------------------------------------------------------------- helpers


def _camera_times(rng: np.random.Generator, t0_ms: int, span_ms: float) -> np.ndarray:
    """Irregular ~10 Hz frame times (100 +- 30 ms steps) from t0 + [0, 25) ms until t0 + span."""
    ts = [t0_ms + int(rng.integers(0, 25))]
    while ts[-1] < t0_ms + span_ms:
        ts.append(ts[-1] + 100 + int(rng.integers(-30, 31)))
    return np.asarray(ts[:-1], np.int64)


def _small_rotations(rng: np.random.Generator, n: int, sigma: float) -> np.ndarray:
    v = rng.normal(0, sigma, (n, 3))
    ang = np.linalg.norm(v, axis=1, keepdims=True)
    axis = v / np.maximum(ang, 1e-12)
    return np.concatenate([np.cos(ang / 2), axis * np.sin(ang / 2)], 1)


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    return quat_to_mat(q / np.linalg.norm(q))


def _homog(r: np.ndarray, t) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = r, t
    return m


def _render(pos_f: np.ndarray, pos_o: np.ndarray, view: str, cfg: SynthConfig) -> np.ndarray:
    """(n, H, W) grayscale frames: the arena (far) or a finger-centred window (close) in the centred square."""
    w, h = cfg.frame_size
    phys = SCENE_PHYSICS
    n = len(pos_f)
    state = np.zeros((n, 8))
    square = np.zeros((n, h, h), np.uint8)
    if view == "far":
        state[:, 0:2], state[:, 4:6] = pos_f, pos_o
        render_kernel(state, square, phys.finger_radius, phys.object_radius, phys.arena,
                      phys.object_intensity, phys.finger_intensity)
    else:
        half = cfg.close_window / 2
        state[:, 0:2] = half
        state[:, 4:6] = pos_o - pos_f + half
        render_kernel(state, square, phys.finger_radius, phys.object_radius, cfg.close_window,
                      phys.object_intensity, phys.finger_intensity)
        # outside the arena (beyond the walls) is a dim gray: the wrist camera sees the wall edge
        c = (np.arange(h) + 0.5) / h * cfg.close_window - half
        xs = pos_f[:, 0:1, None] + c[None, None, :]
        ys = pos_f[:, 1:2, None] + c[None, :, None]
        outside = (xs < 0) | (xs > phys.arena) | (ys < 0) | (ys > phys.arena)
        square = np.where(outside & (square == 0), np.uint8(40), square)
    frames = np.full((n, h, w), 70, np.uint8)  # side bands: flat gray the converter's centred crop removes
    x0 = (w - h) // 2
    frames[:, :, x0: x0 + h] = square
    return frames


def _interp(t: np.ndarray, tk: np.ndarray, vk: np.ndarray) -> np.ndarray:
    return np.stack([np.interp(t, tk, vk[:, j]) for j in range(vk.shape[1])], 1)


def _expected(grid_ms: np.ndarray, samples: list[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> np.ndarray:
    """What a correct conversion yields: merge the serials' good records (serial order), sort (stable), keep the
    first of repeated timestamps, interpolate linearly at the grid."""
    ts = np.concatenate([s[0] for s in samples])
    vals = np.concatenate([s[1] for s in samples])
    ok = np.concatenate([s[2] for s in samples])
    ts, vals = ts[ok], vals[ok]
    order = np.argsort(ts, kind="stable")
    ts, vals = ts[order], vals[order]
    keep = np.concatenate([[True], np.diff(ts) > 0])
    return _interp(grid_ms.astype(np.float64), ts[keep].astype(np.float64), vals[keep])


# ----------------------------------------------------------------------------- calibration


def calibration(cfg: SynthConfig, serials: list[str]) -> dict:
    """Seeded extrinsics for every serial (+ the anchor in-hand cameras) and a calibration TCP pose (kuka format)."""
    rng = np.random.default_rng([cfg.seed, 0xCA11B])
    names = list(dict.fromkeys([*serials, *IN_HAND_CALIB[cfg.cfg]]))
    ext = {s: _homog(_random_rotation(rng), rng.uniform(-0.5, 0.5, 3))[None] for s in names}
    robot = ROBOTS[cfg.cfg]
    if robot == "kuka":  # mm + Euler sxyz (rad), bounded to [0, 2 pi) as rh20t_api's kuka preprocessor does
        angles = rng.uniform(0, 2 * np.pi, 3)
        tcp = np.concatenate([rng.uniform(200, 600, 3), angles])
        r_tcp = euler_sxyz_to_mat(*angles)
        t_tcp = tcp[:3] / 1000.0
    else:
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        tcp = np.concatenate([rng.uniform(0.2, 0.6, 3), q])
        r_tcp, t_tcp = quat_to_mat(q), tcp[:3]
    return {"extrinsics": ext, "tcp": tcp, "tcp_mat": _homog(r_tcp, t_tcp)}


def base_to_camera(cal: dict, serial: str, cfg_num: int) -> np.ndarray:
    """4x4 base -> camera transform as rh20t_api composes it (extrinsics[s] @ base_world @ align_mat_base)."""
    ext = {s: m[0] for s, m in cal["extrinsics"].items()}
    tc = _homog(np.asarray(TCP_CAMERA_ROT[cfg_num], float), [0.03, 0.05, 0.2])  # translation is irrelevant
    base_world = np.linalg.inv(ext[IN_HAND_CALIB[cfg_num][0]]) @ tc @ np.linalg.inv(cal["tcp_mat"])
    return ext[serial] @ base_world @ _homog(np.asarray(ALIGN_BASE_ROT[cfg_num], float), [0, 0, 0])


def write_calib(cfg_dir: Path, cal: dict) -> None:
    """The ``calib/`` folder, written in a private temporary and renamed in (an earlier one of ours replaced)."""
    with atomic_path(cfg_dir / "calib", replace=SYNTHETIC_CALIB) as calib:
        c = calib / str(CALIB_MS)
        c.mkdir(parents=True)
        save_dict(c / "extrinsics.npy", cal["extrinsics"])
        save_dict(c / "intrinsics.npy", {s: np.eye(3, 4) for s in cal["extrinsics"]})
        save_array(c / "tcp.npy", cal["tcp"])
        e = calib / str(EMPTY_CALIB_MS)  # intrinsics only: the camera-frame F/T fallback cannot work
        e.mkdir()
        save_dict(e / "intrinsics.npy", {s: np.eye(3, 4) for s in cal["extrinsics"]})


# --------------------------------------------------------------------------------- one scene


@dataclass
class _SceneDraw:
    """One scene's simulation and its seeded draws (duration, camera frame times), shared by the writers of its
    folder and of its truth; ``rng`` is the scene's record generator, drawn from in a fixed order."""

    name: str
    rng: np.random.Generator
    duration: float
    sim: dict
    t0: int
    serial: dict[str, str]
    cams: list[str]
    cam_ts: dict[str, np.ndarray]
    t_pos: np.ndarray
    t_f: np.ndarray
    ft_knots: np.ndarray
    start_ms: int
    finish_ms: int
    grid_ms: np.ndarray


def _force_knots(sim: dict, cfg: SynthConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Knots of the continuous truth: (position times, F/T times, (n, 6) F/T values) [s since t0, N, N m].

    Positions are known at step boundaries and forces as per-step means, placed at step mid-times, so the truth
    between knots is piecewise linear."""
    dt = sim["dt"]
    k = np.arange(len(sim["finger"]))
    t_pos = k * dt
    t_f = np.concatenate([[0.0], (k[1:] - 0.5) * dt, [k[-1] * dt]])
    f_units = np.concatenate([sim["force_units"][:1] * 0, sim["force_units"][1:], sim["force_units"][-1:]])
    f_xy = f_units * cfg.newtons_per_unit
    ft_knots = np.zeros((len(t_f), 6))
    ft_knots[:, 0:2] = f_xy
    ft_knots[:, 3] = cfg.lever_arm_m * f_xy[:, 1]  # (0, 0, -h) x (Fx, Fy, 0) = (h Fy, -h Fx, 0)
    ft_knots[:, 4] = -cfg.lever_arm_m * f_xy[:, 0]
    return t_pos, t_f, ft_knots


def _draw_scene(plan: ScenePlan, cfg: SynthConfig) -> _SceneDraw:
    """Simulate one scene and draw its duration and camera frame times, all from the scene's own seed."""
    ss = np.random.SeedSequence([cfg.seed, plan.task, plan.user, plan.scene, int(plan.human)])
    sim_ss, rec_ss = ss.spawn(2)
    rng = np.random.default_rng(rec_ss)
    lo, hi = cfg.duration_s
    duration = 1.0 if plan.defect == "too_short" else float(rng.uniform(lo, hi))
    sim = simulate_scene(plan.task, duration + 0.6, sim_ss)
    t0 = T0_MS + 3_600_000 * plan.index
    roles = CAMERA_ROLES[cfg.cfg]
    serial = {"far": roles["far"][1 if plan.defect == "far_fallback" else 0], "close": roles["close"][0]}
    # missing_camera keeps only the wrist camera, so the converter has no external camera to fall back to
    cams = ["far", "close"] if plan.defect != "missing_camera" else ["close"]
    t_pos, t_f, ft_knots = _force_knots(sim, cfg)
    span_ms = (duration + 0.5) * 1000.0
    cam_ts = {role: _camera_times(rng, t0, span_ms) for role in cams}
    start_ms, finish_ms = t0 + 300, t0 + int(round(duration * 1000)) - 200
    grid_ms = start_ms + 100 * np.arange((finish_ms - start_ms) // 100 + 1, dtype=np.int64)
    return _SceneDraw(plan.name(cfg.cfg), rng, duration, sim, t0, serial, cams, cam_ts, t_pos, t_f, ft_knots,
                      start_ms, finish_ms, grid_ms)


def _tcp_at(t_s: np.ndarray, sc: _SceneDraw, cfg: SynthConfig) -> np.ndarray:
    """TCP position [m] at ``t_s`` [s since t0]: the finger's arena position placed in the robot base frame."""
    off = np.asarray(cfg.tcp_offset_m, float)
    xy = _interp(t_s, sc.t_pos, sc.sim["finger"])
    return off + cfg.metres_per_unit * np.concatenate([xy, np.zeros((len(t_s), 1))], 1)


def _plant_record_defects(defect: str | None, first: bool, tcp: np.ndarray, zeroed: np.ndarray, ok_tcp: np.ndarray,
                          ok_ft: np.ndarray, dropped: dict[str, dict[str, int]]) -> None:
    """Damage one serial's records in place as ``defect`` asks; the isolated (repairable) defects go into the first
    serial only and mark their records as not ``ok`` and counted in ``dropped``, as the converter must."""
    if first and defect in ("overflow_tcp", "zero_tcp_records", "nan_ft_isolated"):
        n = len(tcp)
        bad_idx = np.array([n // 3, n // 3 + 4, 2 * n // 3])
        if defect == "overflow_tcp":
            tcp[bad_idx, 1] = OVERFLOW_VALUE
            ok_tcp[bad_idx] = False
            dropped["tcp_base"] = {"overflow": len(bad_idx)}
        elif defect == "zero_tcp_records":
            tcp[bad_idx] = 0.0
            ok_tcp[bad_idx] = False
            dropped["tcp_base"] = {"zero": len(bad_idx)}
        else:
            zeroed[bad_idx, 2] = np.nan
            ok_ft[bad_idx] = False
            dropped["force_torque_base"] = {"non_finite": len(bad_idx)}
    if defect == "nan_ft":
        zeroed[::2, 0] = np.nan
    if defect == "overflow_ft":
        zeroed[1::2, 1] = 3.0e38
    if defect == "zero_tcp":
        tcp[:] = 0.0
    if defect == "mm_units":
        tcp[:, :3] *= 1000.0


def _record_streams(sc: _SceneDraw, plan: ScenePlan, cfg: SynthConfig,
                    cal: dict) -> tuple[dict[str, dict], dict[str, list], dict[str, dict[str, int]]]:
    """Each camera serial's records of every numeric stream, sampled at that serial's frame times (as in RH20T).

    Returns the ``transformed/<stem>.npy`` dicts by stem, the recorded (ts, values, good) samples per stream that
    the expected conversion is built from, and the dropped-record counts the planted defects imply."""
    files: dict[str, dict] = {"tcp_base": {}, "force_torque_base": {}, "force_torque": {}, "gripper": {},
                              "joint": {}}
    samples: dict[str, list] = {"tcp": [], "ft": []}
    dropped: dict[str, dict[str, int]] = {}
    for role in sc.cams:
        sn = sc.serial[role]
        ts = sc.cam_ts[role]
        n = len(ts)
        t_s = (ts - sc.t0) / 1000.0
        pos = _tcp_at(t_s, sc, cfg)
        quat = quat_mul(_small_rotations(sc.rng, n, cfg.quat_noise_rad), QUAT_DOWN[None])
        ft_true = _interp(t_s, sc.t_f, sc.ft_knots)
        noise = sc.rng.uniform(-cfg.ft_noise_n, cfg.ft_noise_n, (n, 6))
        noise[:, 2:] = 0.0
        noise[:, 3] = cfg.lever_arm_m * noise[:, 1]
        noise[:, 4] = -cfg.lever_arm_m * noise[:, 0]
        zeroed = ft_true + noise
        tcp = np.concatenate([pos, quat], 1)
        ok_tcp, ok_ft = np.ones(n, bool), np.ones(n, bool)
        _plant_record_defects(plan.defect, role == sc.cams[0], tcp, zeroed, ok_tcp, ok_ft, dropped)
        samples["tcp"].append((ts, pos, ok_tcp))
        samples["ft"].append((ts, zeroed, ok_ft))
        order = sc.rng.permutation(n)  # RH20T lists are not guaranteed sorted
        files["tcp_base"][sn] = [{"timestamp": int(ts[i]), "tcp": tcp[i], "robot_ft": ft_true[i] * 0.9}
                                 for i in order]
        files["force_torque_base"][sn] = [{"timestamp": int(ts[i]), "raw": zeroed[i] + FT_RAW_OFFSET,
                                           "zeroed": zeroed[i]} for i in order]
        rot6 = np.kron(np.eye(2), base_to_camera(cal, sn, cfg.cfg)[:3, :3])
        files["force_torque"][sn] = [{"timestamp": int(ts[i]), "raw": rot6 @ (zeroed[i] + FT_RAW_OFFSET),
                                      "zeroed": rot6 @ zeroed[i]} for i in order]
        files["gripper"][sn] = {int(ts[i]): {"gripper_command": [cfg.gripper_mm, 0.0, 0.0],
                                             "gripper_info": [cfg.gripper_mm, 0.0, 0.0]} for i in range(n)}
        files["joint"][sn] = {int(ts[i]): np.zeros(7) for i in range(n)}
    return files, samples, dropped


def _write_cameras(d: Path, sc: _SceneDraw, plan: ScenePlan, cfg: SynthConfig) -> str:
    """Render and write every camera folder of the scene; returns the storage variant used (``mp4`` or ``jpg``)."""
    video = "jpg" if cfg.jpg_every and plan.index % cfg.jpg_every == cfg.jpg_every - 1 else "mp4"
    for role in sc.cams:
        sn = sc.serial[role]
        ts = sc.cam_ts[role]
        t_s = (ts - sc.t0) / 1000.0
        frames = _render(_interp(t_s, sc.t_pos, sc.sim["finger"]), _interp(t_s, sc.t_pos, sc.sim["object"]),
                         "far" if role in ("far", "side") else "close", cfg)
        cam = d / f"cam_{sn}"
        cam.mkdir()
        if video == "jpg":
            import cv2

            (cam / "color").mkdir()
            for ti, f in zip(ts, frames):
                cv2.imwrite(str(cam / "color" / f"{int(ti)}.jpg"), f, [cv2.IMWRITE_JPEG_QUALITY, 95])
        else:
            save_dict(cam / "timestamps.npy", {"color": [int(x) for x in ts], "depth": [int(x) for x in ts]})
            rgb = [np.repeat(f[..., None], 3, axis=2) for f in frames]
            if plan.defect == "truncated_video" and role == "far":
                rgb = rgb[: len(rgb) - 10]
            write_mp4(cam / "color.mp4", rgb, options={"preset": "ultrafast", "crf": "18"})
    return video


def _write_streams(d: Path, plan: ScenePlan, files: dict[str, dict]) -> None:
    """The ``transformed/`` stream files (none for a human demonstration; no base-frame F/T for the camera-frame
    defects)."""
    if not plan.human:
        tr = d / "transformed"
        save_dict(tr / "tcp_base.npy", files["tcp_base"])
        if plan.defect not in ("camera_frame_ft", "camera_frame_ft_no_calib"):
            save_dict(tr / "force_torque_base.npy", files["force_torque_base"])
        save_dict(tr / "force_torque.npy", files["force_torque"])
        save_dict(tr / "gripper.npy", files["gripper"])
        save_dict(tr / "joint.npy", files["joint"])


def _write_metadata(d: Path, sc: _SceneDraw, plan: ScenePlan) -> dict:
    """``metadata.json`` (calibration, rating, start / finish time); returns what it wrote."""
    calib = EMPTY_CALIB_MS if plan.defect == "camera_frame_ft_no_calib" else CALIB_MS
    meta = {"calib": calib, "rating": 1 if plan.defect == "low_rating" else int(sc.rng.integers(3, 10)),
            "bad_calib_view": [], "start_time": int(sc.start_ms), "finish_time": int(sc.finish_ms)}
    # d is the scene folder being built inside io.atomic_path's private temporary (write_scene): the output contract
    # covers the folder as a whole, and each file in it is an exclusive create (RH20T's layout has no ownership record)
    create_new(d / "metadata.json", json.dumps(meta).encode())
    return meta


def _scene_truth(sc: _SceneDraw, cfg: SynthConfig, samples: dict[str, list]) -> dict[str, np.ndarray]:
    """The scene's truth on the converter's grid: the noise-free signals and the labels the converter derives from
    them, ``expected_*`` from the recorded samples, the simulator's positions and contact intervals, and the hidden
    parameters."""
    dt = sc.sim["dt"]
    t0, start_ms, grid_ms = sc.t0, sc.start_ms, sc.grid_ms
    g_s = (grid_ms - t0) / 1000.0
    ft_grid = _interp(g_s, sc.t_f, sc.ft_knots)
    force, torque = ft_grid[:, :3], ft_grid[:, 3:]
    fn = np.linalg.norm(force, axis=1)
    contact, onset = contact_onset(fn, 10.0, 4)
    exp_ft = _expected(grid_ms, samples["ft"])
    exp_pos = _expected(grid_ms, samples["tcp"])
    step_contact = sc.sim["contact"]
    edges = np.flatnonzero(np.diff(np.concatenate([[0], step_contact.astype(int), [0]])))
    intervals = np.stack([(edges[0::2] - 1) * dt, (edges[1::2] - 1) * dt], 1) - (start_ms - t0) / 1000.0
    return {
        "grid_ms": grid_ms, "time_s": (grid_ms - start_ms) / 1000.0, "start_ms": np.int64(start_ms),
        "t0_ms": np.int64(t0),
        "force": force, "torque": torque, "force_norm": fn, "contact": contact, "contact_onset": onset,
        "tcp_pos": _tcp_at(g_s, sc, cfg), "tcp_quat": QUAT_DOWN.copy(),
        "gripper_width": np.full(len(grid_ms), cfg.gripper_mm / 1000.0),
        "expected_force": exp_ft[:, :3], "expected_torque": exp_ft[:, 3:], "expected_tcp_pos": exp_pos,
        "finger_pos": _interp(g_s, sc.t_pos, sc.sim["finger"]), "object_pos": _interp(g_s, sc.t_pos, sc.sim["object"]),
        "object_vel": _interp(g_s, sc.t_pos, sc.sim["object_vel"]),
        "contact_intervals_s": intervals, "knots_t_s": sc.t_f - (start_ms - t0) / 1000.0, "knots_ft": sc.ft_knots,
        **{f"param_{k_}": np.float64(v) for k_, v in sc.sim["params"].items()},
    }


SYNTHETIC_SCENE = OwnedDir(
    files=(r"metadata\.json",),
    dirs=((r"transformed", OwnedDir(files=(r"[a-z_]+\.npy",))),
          (r"cam_\w+", OwnedDir(files=(r"timestamps\.npy", r"color\.mp4"),
                                dirs=((r"color", OwnedDir(files=(r"\d+\.jpg",))),)))))
"""What :func:`write_scene` writes in a scene folder: metadata, the transformed streams and one folder a camera."""
SYNTHETIC_CALIB = OwnedDir(files=(), dirs=((r"\d+", OwnedDir(files=(r"(extrinsics|intrinsics|tcp)\.npy",))),))
"""A synthetic corpus's ``calib`` folder: one folder a calibration time, its matrices."""
SYNTHETIC_CFG_DIR = OwnedDir(files=(), dirs=((r"calib", SYNTHETIC_CALIB), (r"task_\w+", SYNTHETIC_SCENE)))
"""A synthetic corpus's ``RH20T_cfg<N>`` folder: its calibration folders and its scene folders."""
SYNTHETIC_TRUTH = OwnedDir(files=(r"manifest\.json", r"task_\w+\.npz"))
"""A synthetic corpus's ``truth`` folder: the manifest and one ground-truth file a scene."""


def write_scene(cfg_dir: Path, truth_dir: Path, plan: ScenePlan, cfg: SynthConfig, cal: dict) -> dict:
    """Simulate and write one scene folder and its truth file; returns the scene's manifest row."""
    sc = _draw_scene(plan, cfg)
    files, samples, dropped = _record_streams(sc, plan, cfg, cal)
    # written in a private temporary folder and renamed in: an earlier write of this scene is replaced only if it
    # holds nothing but what we write (SYNTHETIC_SCENE), and no link planted in the scene folder is followed
    with atomic_path(cfg_dir / sc.name, replace=SYNTHETIC_SCENE) as d:
        (d / "transformed").mkdir(parents=True)
        video = _write_cameras(d, sc, plan, cfg)
        _write_streams(d, plan, files)
        meta = _write_metadata(d, sc, plan)
    truth = _scene_truth(sc, cfg, samples)
    save_npz(truth_dir / f"{sc.name}.npz", truth)
    far_cam = "far" if "far" in sc.cams else None
    expected = DEFECTS[plan.defect] if plan.defect else None
    return {"name": sc.name, "task": plan.task, "task_name": TASKS[plan.task]["name"], "user": plan.user,
            "scene": plan.scene, "defect": plan.defect, "expected": expected or "converted",
            "duration_s": sc.duration, "video": video, "far_serial": sc.serial["far"] if far_cam else None,
            "close_serial": sc.serial["close"], "ft_source": ("camera_via_calib" if plan.defect == "camera_frame_ft"
                                                              else "base"),
            "dropped_records": dropped, "grid_steps": int(len(sc.grid_ms)),
            "contact_steps": int(truth["contact"].sum()), "params": sc.sim["params"], "rating": meta["rating"]}


# ------------------------------------------------------------------------------------- run


def _holds_this_corpus(root: Path, cfg: SynthConfig) -> bool:
    """Whether ``root`` already holds the corpus ``cfg`` asks for (so there is nothing to write)."""
    if cfg.overwrite:
        return False
    try:
        old = read_json_if_present(root / "truth" / "manifest.json", "a synthetic corpus's truth manifest")
    except DataError:
        return False
    return old is not None and old.get("config") == content_config(cfg)


SYNTHETIC_ROOT = OwnedDir(files=(), dirs=((r"RH20T_cfg\d+", SYNTHETIC_CFG_DIR), (r"truth", SYNTHETIC_TRUTH)))
"""A synthetic corpus's root: its ``RH20T_cfg<N>`` folders and ``truth``, nothing else."""


def _check_root(root: Path, cfg: SynthConfig) -> None:
    """Refuse, before anything is simulated, a root this run may not write into: a real RH20T folder (or anything
    but an empty folder or a synthetic corpus of ours, recognised by its truth manifest), and without
    ``--overwrite`` any corpus of ours with other settings. Scene names collide with real ones, so writing into a
    real folder would overwrite real scenes' files."""
    if root.is_symlink() or (root.exists() and not root.is_dir()):
        raise ConfigError(f"{root} is not a folder; choose a new folder as --root")
    if not root.exists() or not any(root.iterdir()):
        return
    try:
        man = read_json_if_present(root / "truth" / "manifest.json", "a synthetic corpus's truth manifest")
    except DataError:
        man = None
    if not (isinstance(man, dict) and man.get("generator") == "pokeworld.real.synthetic"):
        raise ConfigError(f"{root} is not empty and holds no synthetic corpus of pokeworld's (no valid "
                          "truth/manifest.json): it may be a real RH20T folder, whose scenes share these names; choose "
                          "a new folder as --root (--overwrite replaces only a synthetic corpus pokeworld wrote)")
    check_owned_dir(root, SYNTHETIC_ROOT)
    if not cfg.overwrite:
        raise ConfigError(f"{root} holds a different synthetic corpus (other settings); pass --overwrite to replace it (only "
                          "its own files are removed) or choose another --root")


def run(cfg: SynthConfig) -> Path:
    """Write the corpus and ``ROOT/truth/``; a root that already holds this config is kept (unless overwrite)."""
    root = Path(cfg.root)
    if _holds_this_corpus(root, cfg):
        print(f"[rh20t-synth] {root} already holds this corpus; skipping")
        return root
    _check_root(root, cfg)
    if cfg.overwrite:  # a synthetic corpus of ours only (checked above): a real RH20T folder is refused, not deleted
        for sub, spec in ((root / f"RH20T_cfg{cfg.cfg}", SYNTHETIC_CFG_DIR), (root / "truth", SYNTHETIC_TRUTH)):
            if sub.exists():
                remove_owned_dir(sub, spec)
    cfg_dir, truth_dir = root / f"RH20T_cfg{cfg.cfg}", root / "truth"
    cfg_dir.mkdir(parents=True, exist_ok=True)
    truth_dir.mkdir(parents=True, exist_ok=True)
    plans = plan_scenes(cfg)
    roles = CAMERA_ROLES[cfg.cfg]
    cal = calibration(cfg, [roles["far"][0], roles["far"][1], roles["close"][0], roles["side"][0]])
    write_calib(cfg_dir, cal)
    t_start = time.perf_counter()
    import numba

    threads = numba.get_num_threads()
    numba.set_num_threads(1)  # one episode at a time: thread start-up would dominate the tiny kernels
    try:
        rows = [write_scene(cfg_dir, truth_dir, p, cfg, cal)
                for p in tqdm(plans, desc="rh20t-synth", unit="scene", disable=not cfg.progress)]
    finally:
        numba.set_num_threads(threads)
    counts: dict[str, int] = {}
    for r in rows:
        if r["expected"] != "converted":
            counts[r["expected"]] = counts.get(r["expected"], 0) + 1
    manifest = {
        "generator": "pokeworld.real.synthetic", "version": __version__, "seed": cfg.seed,
        "config": content_config(cfg), "cfg": cfg.cfg, "robot": ROBOTS[cfg.cfg],
        "tasks": {str(t): TASKS[t] for t in cfg.tasks}, "defects": DEFECTS,
        "constants": {"metres_per_unit": cfg.metres_per_unit, "tcp_offset_m": list(cfg.tcp_offset_m),
                      "newtons_per_unit": cfg.newtons_per_unit, "force_max_units": SCENE_PHYSICS.force_max,
                      "lever_arm_m": cfg.lever_arm_m, "tcp_quat": QUAT_DOWN.tolist(), "ft_raw_offset":
                      FT_RAW_OFFSET.tolist(), "dt_s": SCENE_PHYSICS.dt, "calib": CALIB_MS},
        "truth_note": "truth/<scene>.npz on the converter's 10 Hz grid (grid_ms = start_time + 100 k): force/torque "
                      "[N, N m] base frame (noise-free), contact = |F| > 10 N, contact_onset as the converter "
                      "defines it, tcp_pos [m], expected_* = linear interpolation of the recorded samples after the "
                      "converter's drop rules (what a correct conversion yields), finger/object positions [arena "
                      "units], contact_intervals_s (simulator contact, s since start_time), param_* (PokeWorld "
                      "hidden parameters)",
        "scenes": rows, "expected_converted": sum(r["expected"] == "converted" for r in rows),
        "expected_skip_counts": dict(sorted(counts.items())),
        "expected_camera_counts": _camera_counts(rows),
        "expected_ft_source_counts": _count(r["ft_source"] for r in rows if r["expected"] == "converted"),
        "seconds": round(time.perf_counter() - t_start, 2),
    }
    write_json(truth_dir / "manifest.json", manifest)
    print(f"[rh20t-synth] wrote {len(rows)} scenes ({manifest['expected_converted']} convertible, skips expected "
          f"{manifest['expected_skip_counts']}) to {cfg_dir} and truth to {truth_dir} in {manifest['seconds']} s")
    return root


def _count(items) -> dict[str, int]:
    out: dict[str, int] = {}
    for x in items:
        out[x] = out.get(x, 0) + 1
    return dict(sorted(out.items()))


def _camera_counts(rows: list[dict]) -> dict[str, int]:
    """Far-camera serial per converted scene (what the converter's report counts for camera=far)."""
    return _count(r["far_serial"] for r in rows if r["expected"] == "converted")


def load_truth(root: str | Path, scene: str) -> dict[str, np.ndarray]:
    """The ground truth of one scene (``ROOT/truth/<scene>.npz``) as a dict of arrays."""
    with np.load(Path(root) / "truth" / f"{scene}.npz", allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def store_chunks(ds, root: str | Path):
    """(episode, manifest scene row, truth, grid slice of the episode) for every episode of a store converted
    from the synthetic corpus at ``root``: the truth of an episode is its scene's truth over that slice."""
    T1 = ds.labels["force"].shape[1]
    for e in range(ds.num_episodes):
        row = ds.manifest["scenes"][int(ds.params["scene_index"][e])]
        ci = int(ds.params["chunk_index"][e])
        yield e, row, load_truth(root, row["name"]), slice(ci * T1, (ci + 1) * T1)


def check_conversion(store: str | Path, root: str | Path) -> dict:
    """A converted store against the corpus's ground truth (docs/rh20t.md, "What conversion gives").

    Two separate things: conversion mechanics (stored signals against ``expected_*``, the linear interpolation of
    the recorded samples after the drop rules: float precision when the converter is right) and sampling loss
    (against the noise-free simulator signal), plus whether the skip / F/T-source counts are the planted ones."""
    ds = load(store)
    man = read_json(Path(root) / "truth" / "manifest.json", "a synthetic corpus's truth manifest", max_bytes=64 << 20)
    rep = read_json(Path(store) / "conversion_report.json", "a conversion report", max_bytes=64 << 20)
    err = {"force_n": 0.0, "torque_nm": 0.0, "tcp_pos_m": 0.0}
    f_true, f_conv, c_true, c_conv, pos_err = [], [], [], [], []
    for e, _, tr, sl in store_chunks(ds, root):
        for key, label in (("force_n", "force"), ("torque_nm", "torque"), ("tcp_pos_m", "tcp_pos")):
            err[key] = max(err[key], float(np.abs(ds.labels[label][e] - tr[f"expected_{label}"][sl]).max()))
        f_true.append(tr["force"][sl])
        f_conv.append(ds.labels["force"][e])
        c_true.append(tr["contact"][sl])
        c_conv.append(ds.labels["contact"][e])
        pos_err.append(float(np.abs(ds.labels["tcp_pos"][e] - tr["tcp_pos"][sl]).max()))
    ft, fc = np.concatenate(f_true), np.concatenate(f_conv)
    ct, cc = np.concatenate(c_true), np.concatenate(c_conv)
    return {
        "store": str(store), "root": str(root), "episodes": int(ds.num_episodes),
        "scenes_converted": rep["scenes_converted"], "skip_counts": rep["skip_counts"],
        "camera_counts": rep["camera_counts"], "ft_source_counts": rep["ft_source_counts"],
        "counts_match_planted": {
            "skip_counts": rep["skip_counts"] == man["expected_skip_counts"],
            "scenes_converted": rep["scenes_converted"] == man["expected_converted"],
            "ft_source_counts": rep["ft_source_counts"] == man["expected_ft_source_counts"]},
        "max_abs_error_vs_expected": err,
        "force_r2_vs_noise_free_truth": r2(ft, fc),
        "force_max_abs_error_vs_truth_n": float(np.abs(fc - ft).max()),
        "tcp_max_abs_error_vs_truth_m": max(pos_err),
        "contact_label_agreement": float((ct == cc).mean()),
        "contact_share": float(cc.mean()),
        "onset_base_rate": ds.manifest.get("onset_base_rate"),
    }


__all__ = ["SynthConfig", "PRESETS", "TASKS", "DEFECTS", "make_config", "run", "plan_scenes", "simulate_scene",
           "load_truth", "store_chunks", "check_conversion", "content_config"]
