"""The conversion config (:class:`ConvertConfig`), its presets, and the output path and identity it implies."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from ...config import from_preset, to_dict
from ...errors import ConfigError
from .format import CAMERA_OPTIONS, ROBOTS


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
    """Rebuild the store and the scene cache even if they exist. Replaces only a folder pokeworld verifies as its
    own RH20T store (only files pokeworld writes in a store: data.h5, manifest.json, conversion_report.json,
    certificates; the manifest readable and of kind "rh20t"); any other folder is refused, never deleted."""

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


def content_config(cfg: ConvertConfig) -> dict:
    d = to_dict(cfg)
    for k in ("out", "overwrite", "progress"):
        d.pop(k)
    return d
