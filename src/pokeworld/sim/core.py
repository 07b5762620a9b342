"""The vectorised PokeWorld simulator: hidden-parameter sampling, sensors, reset/step."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from ..config import FRACTION, Limit, check_fields, positive
from ..errors import ConfigError
from . import physics

PARAM_NAMES = ("mass", "gamma", "stiffness", "bias_x", "bias_y", "gain")
DRIFT_NAMES = ("drift_x", "drift_y")
"""The per-episode drift acceleration of the object (the paper's rejected attribute construction, App. C
"Constructing the cells"): part of the simulator's parameters, stored in a corpus only when its ranges draw it."""
SIM_PARAM_NAMES = PARAM_NAMES + DRIFT_NAMES
"""The simulator's parameter layout (``PokeWorldSim.params`` columns, the kernels' ``params``)."""


@dataclass(frozen=True)
class PhysicsConfig:
    """Fixed (non-hidden) constants of the PokeWorld arena."""

    dt: float = 0.05
    """Control step in seconds."""
    substeps: int = 20
    """Semi-implicit Euler sub-steps per control step (touch statistics are taken over these)."""
    force_max: float = 6.0
    """F_max: the commanded finger force is F_max * a with a in [-1, 1]^2 (simulator force units). 6.0 is the
    reference's; the calibrated environment's 5.6 was calibrated to the paper's corpus statistics (docs/design.md,
    "Calibration")."""
    finger_mass: float = 1.0
    """Finger mass."""
    finger_damping: float = 2.0
    """Linear damping coefficient on the finger (force -finger_damping * v; terminal speed F_max/damping = 3).
    The calibrated environment's 0.85 was calibrated."""
    finger_radius: float = 0.06
    """Finger disk radius (arena units; the arena is the unit square)."""
    object_radius: float = 0.09
    """Object disk radius."""
    contact_zeta: float = 0.25
    """Finger-object normal damping as a fraction of critical (underdamped keeps impact peaks k-dependent)."""
    contact_damping: str = "hertz"
    """Contact damping law: "hertz" (the reference's and the default: 2 zeta sqrt(k mu) sqrt(d) times the
    separation speed, not clipped; restitution rises with k), "tangent" (the calibrated environment's: zeta of the
    Hertz law's local tangent stiffness, clipped at 0, restitution independent of k) or "constant" (2 zeta
    sqrt(k mu), clipped: restitution falls with k) (docs/design.md, "Contact damping")."""
    walls: str = "hertz"
    """Wall law: "hertz" (the reference's: force wall_stiffness d^1.5 - 2 sqrt(wall_stiffness) sqrt(d) v, the same
    for every mass, so a bounce's acceleration carries 1/m) or "spring" (the calibrated environment's: a
    mass-independent acceleration set by wall_omega and wall_zeta)."""
    wall_stiffness: float = 3000.0
    """K of the Hertz walls (walls "hertz")."""
    speed_cap: float = 3.0
    """Both bodies' speeds are capped at this after every sub-step (the reference's V_CAP); 0: no cap."""
    drag: str = "explicit"
    """How object drag -gamma m v and finger damping are integrated: "explicit" (the reference's: in the force sum
    of each semi-implicit Euler sub-step) or "exact" (the calibrated environment's: exponential factors per
    sub-step, so a free glide decays as exp(-gamma t) to machine precision)."""
    touch_units: str = "raw"
    """Units of the touch force channels (and of touch_noise): "raw" simulator force (the reference's) or
    "force_max" (divided by F_max, the calibrated environment's)."""
    placement: str = "reference"
    """Initial positions: "reference" (finger uniform in [0.15, 0.85]², object in [0.2, 0.8]², redrawn while the
    centres are closer than r_f + r_o + 0.05) or "calibrated" (anywhere inside the walls with a 0.02 margin,
    redrawn while closer than 2.5 (r_f + r_o))."""
    wall_omega: float = 60.0
    """Wall spring natural frequency (rad/s); wall accelerations are independent of m and k."""
    wall_zeta: float = 0.25
    """Wall damping ratio."""
    arena: float = 1.0
    """Side length of the square arena."""
    image_size: int = 64
    """Rendered frames are image_size x image_size grayscale."""
    object_intensity: float = 140.25
    """Gray level of the object disk (the reference's 0.55 of 255; the calibrated environment's 255)."""
    finger_intensity: float = 255.0
    """Gray level of the finger disk (the reference's 1.0 of 255; the calibrated environment's 128)."""
    touch_noise: float = 0.02
    """Std of Gaussian noise on the five force channels of touch (in ``touch_units``)."""
    frame_averaged_touch: bool = False
    """Ablation: replace sub-step statistics by frame averages (peak -> |mean|, end -> mean, fraction -> flag)."""

    # far above the paper's constants, far below what makes one control step cost minutes (substeps) or a frame
    # a megabyte (image_size: a store's frames are E x T x image_size² bytes, built in memory)
    LIMITS = {"dt": positive(1.0), "substeps": Limit(1, 1000), "force_max": positive(1e4), "finger_mass": positive(1e4),
              "finger_damping": Limit(0, 1e4), "finger_radius": positive(1e3), "object_radius": positive(1e3),
              "contact_zeta": FRACTION, "wall_omega": positive(1e5), "wall_zeta": Limit(0, 1e3),
              "arena": positive(1e3), "image_size": Limit(8, 1024), "object_intensity": Limit(0, 255),
              "finger_intensity": Limit(0, 255), "touch_noise": Limit(0, 1e3), "wall_stiffness": positive(1e8),
              "speed_cap": Limit(0, 1e4)}
    #: the choices of each law field (the first of each is the calibrated environment's)
    CHOICES = {"walls": physics.WALL_LAWS, "drag": ("exact", "explicit"), "touch_units": ("force_max", "raw"),
               "placement": ("calibrated", "reference")}

    def __post_init__(self) -> None:
        check_fields(self)
        if not self.contact_zeta < 1:
            raise ConfigError(f"contact_zeta must be in [0, 1) (underdamped), got {self.contact_zeta}")
        if self.contact_damping not in physics.DAMPING_LAWS:
            raise ConfigError(f"contact_damping must be one of {physics.DAMPING_LAWS}, got {self.contact_damping!r}")
        for name, choices in self.CHOICES.items():
            if getattr(self, name) not in choices:
                raise ConfigError(f"{name} must be one of {choices}, got {getattr(self, name)!r}")
        if 2 * (self.finger_radius + self.object_radius) >= self.arena:
            raise ConfigError("finger and object do not fit in the arena")

    @property
    def calibrated_dynamics(self) -> bool:
        """Whether the calibrated environment's kernel steps this arena (:func:`physics.step_kernel`, kept bit for
        bit); any reference law takes :func:`physics.step_kernel_reference`."""
        return (self.contact_damping != "hertz" and self.walls == "spring" and self.speed_cap == 0
                and self.drag == "exact" and self.touch_units == "force_max")

    def constants(self) -> np.ndarray:
        if not self.calibrated_dynamics:
            return self.reference_constants()
        c = np.zeros(physics.NUM_CONSTS)
        c[physics.C_DT] = self.dt
        c[physics.C_NSUB] = self.substeps
        c[physics.C_FMAX] = self.force_max
        c[physics.C_MF] = self.finger_mass
        c[physics.C_CF] = self.finger_damping
        c[physics.C_RF] = self.finger_radius
        c[physics.C_RO] = self.object_radius
        c[physics.C_ZETA] = self.contact_zeta
        c[physics.C_WOMEGA] = self.wall_omega
        c[physics.C_WZETA] = self.wall_zeta
        c[physics.C_ARENA] = self.arena
        c[physics.C_DAMPING_LAW] = physics.DAMPING_LAWS.index(self.contact_damping)
        return c

    def reference_constants(self) -> np.ndarray:
        c = np.zeros(physics.NUM_CONSTS_REFERENCE)
        for i, name in ((physics.C_DT, "dt"), (physics.C_NSUB, "substeps"), (physics.C_FMAX, "force_max"),
                        (physics.C_MF, "finger_mass"), (physics.C_CF, "finger_damping"),
                        (physics.C_RF, "finger_radius"), (physics.C_RO, "object_radius"),
                        (physics.C_ZETA, "contact_zeta"), (physics.C_WOMEGA, "wall_omega"),
                        (physics.C_WZETA, "wall_zeta"), (physics.C_ARENA, "arena"), (physics.C_KWALL, "wall_stiffness"),
                        (physics.C_VCAP, "speed_cap")):
            c[i] = getattr(self, name)
        c[physics.C_DAMPING_LAW] = physics.DAMPING_LAWS.index(self.contact_damping)
        c[physics.C_WALL_LAW] = physics.WALL_LAWS.index(self.walls)
        c[physics.C_TOUCH_RAW] = float(self.touch_units == "raw")
        c[physics.C_DRAG_EXPLICIT] = float(self.drag == "explicit")
        return c


@dataclass(frozen=True)
class ParamRanges:
    """Per-episode hidden-parameter distributions."""

    mass: tuple[float, float] = (0.5, 3.0)
    """Object mass m, sampled log-uniformly."""
    gamma: tuple[float, float] = (0.5, 4.0)
    """Drag decay rate gamma (1/s), sampled uniformly; drag force is -gamma*m*v."""
    stiffness: tuple[float, float] = (500.0, 6000.0)
    """Contact stiffness k, sampled log-uniformly."""
    bias: float = 0.0
    """Half-width B of the per-episode additive finger force bias b ~ U(-B, B)^2 (0 disables it)."""
    gain: tuple[float, float] = (1.0, 1.0)
    """Actuation gain g ~ U(lo, hi) multiplying the commanded force ((1, 1) disables it)."""
    drift: float = 0.0
    """Half-width A of the per-episode drift acceleration of the object a_d ~ U(-A, A)^2 (arena units/s², added to
    its dynamics on every sub-step as a force m a_d; 0 disables it). The reference environment's kernel only."""

    LIMITS = {"mass": positive(1e6), "gamma": positive(1e4), "stiffness": positive(1e8), "bias": Limit(0, 1e3),
              "gain": positive(1e3), "drift": Limit(0, 1e3)}

    def __post_init__(self) -> None:
        check_fields(self)
        for name in ("mass", "gamma", "stiffness", "gain"):
            lo, hi = getattr(self, name)
            if not hi >= lo:
                raise ConfigError(f"ParamRanges.{name} must satisfy 0 < lo <= hi, got {(lo, hi)}")

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        p = np.zeros((n, len(SIM_PARAM_NAMES)))
        p[:, 0] = np.exp(rng.uniform(np.log(self.mass[0]), np.log(self.mass[1]), n))
        p[:, 1] = rng.uniform(*self.gamma, n)
        p[:, 2] = np.exp(rng.uniform(np.log(self.stiffness[0]), np.log(self.stiffness[1]), n))
        p[:, 3:5] = rng.uniform(-self.bias, self.bias, (n, 2)) if self.bias > 0 else 0.0
        p[:, 5] = rng.uniform(*self.gain, n) if self.gain[1] > self.gain[0] else self.gain[0]
        if self.drift > 0:  # drawn last and only when on, so every corpus without drift keeps its random stream
            p[:, 6:8] = rng.uniform(-self.drift, self.drift, (n, 2))
        return p


class PokeWorldSim:
    """N independent PokeWorld episodes stepped together.

    Observations (dict of arrays, leading dim N): ``vision`` (H, W) uint8,
    ``proprio`` (4,) finger position and velocity, ``touch`` (7,) sub-step
    statistics of the reaction force on the finger (see :mod:`.physics`).
    """

    def __init__(self, num_envs: int, physics_cfg: PhysicsConfig | None = None,
                 ranges: ParamRanges | None = None, seed: int | None = None):
        if num_envs < 1:
            raise ConfigError(f"num_envs must be >= 1, got {num_envs}")
        self.n = int(num_envs)
        self.cfg = physics_cfg or PhysicsConfig()
        self.ranges = ranges or ParamRanges()
        if self.ranges.drift > 0 and self.cfg.calibrated_dynamics:
            raise ConfigError("a drift acceleration (ParamRanges.drift > 0) needs the reference environment's dynamics; "
                              "the calibrated environment's kernel is kept bit for bit and has none")
        self.rng = np.random.default_rng(seed)
        self._consts = self.cfg.constants()
        self.state = np.zeros((self.n, 8))
        self.params = np.zeros((self.n, len(SIM_PARAM_NAMES)))
        self.touch_clean = np.zeros((self.n, physics.TOUCH_DIM))
        self.touch = np.zeros((self.n, physics.TOUCH_DIM), dtype=np.float32)
        s = self.cfg.image_size
        self.frames = np.zeros((self.n, s, s), dtype=np.uint8)

    # ------------------------------------------------------------------ reset
    #: Largest initial velocity component (arena units/s) ``reset`` accepts for the finger and the object:
    #: the velocity range of the proprio observation space (the finger's terminal speed is 2, the policy
    #: launches the object at ≤ 2), so no episode starts outside what the env declares it observes.
    MAX_VEL: float = 50.0
    #: The paper's short parameter names, accepted by ``reset(params=...)`` beside the long ones.
    PARAM_ALIASES: dict[str, str] = {"m": "mass", "k": "stiffness"}

    def reset(self, mask: np.ndarray | None = None, params: Mapping[str, object] | None = None,
              finger_pos=None, object_pos=None, object_vel=None, finger_vel=None) -> dict:
        """Resample episodes where ``mask`` is True (all by default); explicit values override sampling.

        ``params`` maps names in :data:`SIM_PARAM_NAMES` (or the paper's ``m`` / ``k`` for mass /
        stiffness, ``bias`` / ``drift`` for both components) to scalars or per-reset arrays. Initial
        velocities must lie in ±:attr:`MAX_VEL` per component.
        """
        idx = np.arange(self.n) if mask is None else np.flatnonzero(np.asarray(mask, bool))
        n = idx.size
        if n == 0:
            return self.observe()
        p = self.ranges.sample(self.rng, n)
        given: dict[str, str] = {}
        for alias, value in (params or {}).items():
            key = self.PARAM_ALIASES.get(alias, alias)
            if key in given:
                raise ConfigError(f"parameter {key!r} given twice (as {given[key]!r} and {alias!r})")
            given[key] = alias
            cols = {"bias": [3, 4], "drift": [6, 7]}.get(
                key, [SIM_PARAM_NAMES.index(key)] if key in SIM_PARAM_NAMES else None)
            if cols is None:
                raise ConfigError(f"unknown parameter {alias!r}; known: {list(SIM_PARAM_NAMES) + ['bias', 'drift']} "
                                  f"(or the paper's {', '.join(self.PARAM_ALIASES)})")
            v = np.asarray(value, dtype=float)
            if not np.all(np.isfinite(v)):
                raise ConfigError(f"parameter {key!r} must be finite, got {value}")
            if key in ("mass", "stiffness", "gain") and np.any(v <= 0):
                raise ConfigError(f"parameter {key!r} must be > 0, got {value}")
            if key == "gamma" and np.any(v < 0):
                raise ConfigError(f"parameter 'gamma' must be >= 0, got {value}")
            if 6 in cols and np.any(v != 0) and self.cfg.calibrated_dynamics:
                raise ConfigError("a drift acceleration needs the reference environment's dynamics (the calibrated "
                                  "kernel has none)")
            p[:, cols] = v.reshape(-1, len(cols)) if v.ndim and v.size == n * len(cols) else v
        self.params[idx] = p
        c = self.cfg
        lo_f, hi_f = c.finger_radius, c.arena - c.finger_radius
        fp, op = self._placements(n)
        fp = self._override(fp, finger_pos, "finger_pos", n, (lo_f, hi_f))
        op = self._override(op, object_pos, "object_pos", n, (c.object_radius, c.arena - c.object_radius))
        vmax, why = self.MAX_VEL, "per component (the velocity range of the proprio observation space)"
        fv = self._override(np.zeros((n, 2)), finger_vel, "finger_vel", n, (-vmax, vmax), why)
        ov = self._override(np.zeros((n, 2)), object_vel, "object_vel", n, (-vmax, vmax), why)
        self.state[idx, 0:2], self.state[idx, 2:4] = fp, fv
        self.state[idx, 4:6], self.state[idx, 6:8] = op, ov
        self.touch_clean[idx] = 0.0
        self.touch[idx] = 0.0
        self._render()
        return self.observe()

    def _placements(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """Initial finger and object positions under ``placement`` (field doc); object placements that overlap
        (or nearly touch) the finger are redrawn."""
        c = self.cfg
        if c.placement == "reference":
            a = c.arena
            fp = self.rng.uniform(0.15 * a, 0.85 * a, (n, 2))
            lo_o, hi_o, gap = 0.2 * a, 0.8 * a, c.finger_radius + c.object_radius + 0.05 * a
        else:
            fp = self.rng.uniform(c.finger_radius + 0.02, c.arena - c.finger_radius - 0.02, (n, 2))
            lo_o, hi_o = c.object_radius + 0.02, c.arena - c.object_radius - 0.02
            gap = 2.5 * (c.finger_radius + c.object_radius)
        op = self.rng.uniform(lo_o, hi_o, (n, 2))
        for _ in range(100):
            bad = np.linalg.norm(op - fp, axis=1) < gap
            if not bad.any():
                break
            op[bad] = self.rng.uniform(lo_o, hi_o, (int(bad.sum()), 2))
        return fp, op

    @staticmethod
    def _override(default: np.ndarray, value, name: str, n: int, bounds,
                  why: str = "(inside the walls)") -> np.ndarray:
        if value is None:
            return default
        v = np.asarray(value, dtype=float)
        if v.shape not in ((2,), (n, 2)):
            raise ConfigError(f"{name} must have shape (2,) or ({n}, 2), got {v.shape}")
        if not np.all(np.isfinite(v)):
            raise ConfigError(f"{name} must be finite, got {value}")
        if bounds is not None and (np.any(v < bounds[0]) or np.any(v > bounds[1])):
            raise ConfigError(f"{name} must lie in [{bounds[0]:.3f}, {bounds[1]:.3f}] {why}, got {value}")
        return np.broadcast_to(v, (n, 2)).copy()

    # ------------------------------------------------------------------- step
    def step(self, actions: np.ndarray, render: bool = True) -> dict:
        """Apply ``actions`` (N, 2) in [-1, 1] for one control step and return observations."""
        a = np.asarray(actions, dtype=np.float64)
        if a.shape != (self.n, 2):
            raise ConfigError(f"actions must have shape ({self.n}, 2), got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ConfigError("actions contain NaN or inf")
        a = np.clip(a, -1.0, 1.0)
        kernel = physics.step_kernel if self.cfg.calibrated_dynamics else physics.step_kernel_reference
        kernel(self.state, self.params, a, self._consts, self.touch_clean)
        self._sense()
        if render:
            self._render()
        return self.observe()

    def _sense(self) -> None:
        t = self.touch_clean
        if self.cfg.frame_averaged_touch:
            mean = t[:, 0:2]
            t = np.concatenate([mean, np.linalg.norm(mean, axis=1, keepdims=True), mean,
                                t[:, 6:7], t[:, 6:7]], axis=1)
        out = t.astype(np.float32)
        if self.cfg.touch_noise > 0:
            out[:, :5] += self.rng.normal(0.0, self.cfg.touch_noise, (self.n, 5)).astype(np.float32)
        self.touch = out

    def _render(self) -> None:
        c = self.cfg
        physics.render_kernel(self.state, self.frames, c.finger_radius, c.object_radius, c.arena,
                              c.object_intensity, c.finger_intensity)

    def observe(self) -> dict:
        return {"vision": self.frames[..., None].copy(), "proprio": self.state[:, 0:4].astype(np.float32),
                "touch": self.touch.copy()}

    def privileged(self) -> dict:
        """Ground-truth state and parameters (for labels and ``info``)."""
        return {"finger_pos": self.state[:, 0:2].copy(), "finger_vel": self.state[:, 2:4].copy(),
                "object_pos": self.state[:, 4:6].copy(), "object_vel": self.state[:, 6:8].copy(),
                "contact": self.touch_clean[:, 6].copy(),
                **{name: self.params[:, i].copy() for i, name in enumerate(SIM_PARAM_NAMES)}}

    def replace_config(self, **changes) -> None:
        self.cfg = dataclasses.replace(self.cfg, **changes)
        self._consts = self.cfg.constants()
