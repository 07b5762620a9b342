"""PokeWorld as a goal-conditioned stable-worldmodel environment (``swm/PokeWorld-v0``), and World collection.

:class:`PokeWorldGoalEnv` is push-to-goal PokeWorld in swm's conventions (those of its ``PushT`` and
``SimplePointMaze``): a ``variation_space`` (``swm.spaces.Dict``) holds everything an episode may vary — the hidden
physics (mass, drag gamma, contact stiffness k, finger-force bias and actuation gain: :data:`PARAM_NAMES`), the finger
and object starts, and the goal — and ``reset(options={"variation": [...], "variation_values": {...}})`` resamples
or sets them (``swm.spaces.reset_variation_space``). Hidden parameters are drawn as :class:`ParamRanges` draws them
(mass and stiffness log-uniformly), so an swm episode is distributed like a pokeworld corpus episode.

Observation: ``proprio`` (4,) and ``touch`` (7,) (a dict, as PushT's); swm's ``AddPixelsWrapper`` adds ``pixels``
from :meth:`render`, the PokeWorld frame as RGB (the grayscale frame in all three channels, so ``pixels[..., 0]`` is
exactly the frame a pokeworld corpus stores). ``info`` carries the goal image ``goal`` (the arena with the object at
the goal, which swm's goal-conditioned policies read), ``goal_pos``, ``goal_radius``, the object's ``distance`` to
the goal, the true object/finger state and the true hidden parameters (one key each). Success (``terminated``) is the
object's centre within ``goal_radius`` of the goal, the convention of :class:`pokeworld.plan.PlanConfig`; the reward
is minus that distance, dense as PushT's.

:func:`register` adds the id to gymnasium and to swm's ``WORLDS`` the way ``stable_worldmodel.envs`` registers its
own; :func:`run` (``pokeworld swm-collect``) drives ``swm.World`` with an swm policy to record episodes.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import gymnasium as gym
import numpy as np

from ..errors import ConfigError
from ..io import OwnedDir, atomic_path
from ..plan import GOAL_BOX, PlanConfig
from ..sim.core import PARAM_NAMES, ParamRanges, PhysicsConfig, PokeWorldSim
from .require import stable_worldmodel

ENV_ID = "swm/PokeWorld-v0"
"""The gymnasium / stable-worldmodel id (swm's own ids are ``swm/<Name>-v<k>``)."""
ENTRY_POINT = "pokeworld.swm.env:PokeWorldGoalEnv"
EPISODE_STEPS = 64
"""Default episode length (a pokeworld corpus episode); ``swm.World`` passes its own ``max_episode_steps``."""
GOAL_RADIUS = PlanConfig.goal_radius
"""Success radius around the goal: the planner's (``pokeworld.plan.PlanConfig.goal_radius``)."""
START_CLEARANCE = 2.5
"""Object and finger start at least this many (finger + object radii) apart, as :class:`PokeWorldSim` samples them."""
PHYSICS_VARIATIONS = ("physics.mass", "physics.gamma", "physics.stiffness", "physics.bias", "physics.gain")
DEFAULT_VARIATIONS = (*PHYSICS_VARIATIONS, "finger.start_position", "object.start_position", "goal.position")
"""Resampled on every reset unless ``options["variation"]`` says otherwise: hidden physics, starts and goal."""
RESET_OPTIONS = ("variation", "variation_values")


def _swm():
    return stable_worldmodel()


def log_uniform_box(lo: float, hi: float, init: float):
    """An swm variation ``Box`` over [lo, hi] that samples log-uniformly (as :class:`ParamRanges` draws m and k)."""
    swm = _swm()

    class LogUniformBox(swm.spaces.Box):
        def sample(self, mask=None, max_tries=1000, warn_after_s=None, set_value=True, **kwargs):
            low, high = np.log(self.low), np.log(self.high)
            # exp(log(x)) may land one ulp outside; gym's Box.contains wants an ndarray, not a numpy scalar
            value = np.asarray(np.clip(np.exp(self.np_random.uniform(low, high)), self.low, self.high), self.dtype)
            if set_value:
                self._value = value
            return value

    return LogUniformBox(low=lo, high=hi, shape=(), init_value=np.array(init, np.float64), dtype=np.float64)


def _box(lo, hi, init, shape=(), constrain_fn=None):
    swm = _swm()
    return swm.spaces.Box(low=np.full(shape, lo, np.float64), high=np.full(shape, hi, np.float64), shape=shape,
                          init_value=np.array(init, np.float64), dtype=np.float64, constrain_fn=constrain_fn)


class PokeWorldGoalEnv(gym.Env):
    """Push the object to a goal in PokeWorld; hidden physics, starts and goal form the swm variation space."""

    metadata: ClassVar[dict] = {"render_modes": ["rgb_array"], "render_fps": 20}

    def __init__(self, physics: PhysicsConfig | None = None, ranges: ParamRanges | None = None,
                 render_mode: str | None = "rgb_array"):
        if render_mode not in (None, "rgb_array"):
            raise ConfigError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.cfg = physics or PhysicsConfig()
        self.ranges = ranges or ParamRanges()
        self.render_mode = render_mode
        v = PokeWorldSim.MAX_VEL
        self.observation_space = gym.spaces.Dict({
            "proprio": gym.spaces.Box(np.array([0, 0, -v, -v], np.float32), np.array([1, 1, v, v], np.float32)),
            "touch": gym.spaces.Box(-1e3, 1e3, (7,), np.float32),
        })
        self.action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.variation_space = self._variation_space()
        if not self.variation_space.check(debug=True):
            raise ConfigError("the default PokeWorld variation values lie outside the variation space")
        self._sim = PokeWorldSim(1, self.cfg, self.ranges)
        self._goal_sim = PokeWorldSim(1, self.cfg, self.ranges)  # renders the goal image only
        self._goal_image = np.zeros((self.cfg.image_size, self.cfg.image_size, 3), np.uint8)

    def _variation_space(self):
        swm, c, r = _swm(), self.cfg, self.ranges
        geo = lambda lo_hi: float(np.sqrt(lo_hi[0] * lo_hi[1]))  # noqa: E731
        lo_f, hi_f = c.finger_radius + 0.02, c.arena - c.finger_radius - 0.02
        lo_o, hi_o = c.object_radius + 0.02, c.arena - c.object_radius - 0.02
        clearance = START_CLEARANCE * (c.finger_radius + c.object_radius)
        space = None  # the constraints read the space's current values, so they close over it

        def object_clear_of_finger(pos) -> bool:
            finger = space["finger"]["start_position"].value
            return bool(np.linalg.norm(np.asarray(pos) - finger) >= clearance)

        def goal_away_from_object(pos) -> bool:
            obj, radius = space["object"]["start_position"].value, space["goal"]["radius"].value
            return bool(np.linalg.norm(np.asarray(pos) - obj) > radius)

        physics = swm.spaces.Dict({
            "mass": log_uniform_box(*r.mass, geo(r.mass)),
            "gamma": _box(*r.gamma, float(np.mean(r.gamma))),
            "stiffness": log_uniform_box(*r.stiffness, geo(r.stiffness)),
            "bias": _box(-r.bias, r.bias, [0.0, 0.0], (2,)),
            "gain": _box(*r.gain, float(np.mean(r.gain))),
        })
        space = swm.spaces.Dict({
            "physics": physics,
            "finger": swm.spaces.Dict({"start_position": _box(lo_f, hi_f, [0.25, 0.5], (2,))}),
            "object": swm.spaces.Dict({"start_position": _box(lo_o, hi_o, [0.65, 0.5], (2,),
                                                              object_clear_of_finger)}),
            "goal": swm.spaces.Dict({"radius": _box(0.02, 0.3, GOAL_RADIUS),
                                     "position": _box(*GOAL_BOX, [0.5, 0.8], (2,), goal_away_from_object)},
                                    sampling_order=["radius", "position"]),
        }, sampling_order=["physics", "finger", "object", "goal"])
        return space

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        options = dict(options or {})
        unknown = set(options) - set(RESET_OPTIONS)
        if unknown:
            raise ConfigError(f"unknown reset options {sorted(unknown)}; allowed: {list(RESET_OPTIONS)}")
        try:
            _swm().spaces.reset_variation_space(self.variation_space, seed, options, DEFAULT_VARIATIONS)
        except (AssertionError, ValueError) as e:  # swm asserts on values outside the space
            raise ConfigError(f"bad PokeWorld variation options {options}: {e or 'a value lies outside its space'}"
                              ) from None
        values = self.variation_space.value
        phys = values["physics"]
        params = {name: float(phys[name]) for name in ("mass", "gamma", "stiffness", "gain")}
        params["bias"] = np.asarray(phys["bias"], float)
        fp, op = values["finger"]["start_position"], values["object"]["start_position"]
        self._sim.rng = self.np_random  # touch noise follows the env's seed
        obs = self._sim.reset(params=params, finger_pos=fp, object_pos=op)
        self._goal_sim.reset(params=params, finger_pos=fp, object_pos=values["goal"]["position"])
        self._goal_image = np.repeat(self._goal_sim.frames[0][..., None], 3, axis=-1)
        return self._observation(obs), self._info()

    def step(self, action):
        a = np.asarray(action, dtype=np.float64).reshape(1, 2)
        obs = self._sim.step(a)
        info = self._info()
        terminated = bool(info["distance"] < self.goal_radius)
        return self._observation(obs), -float(info["distance"]), terminated, False, info

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        return np.repeat(self._sim.frames[0][..., None], 3, axis=-1)

    # ------------------------------------------------------------------ helpers
    @property
    def goal_pos(self) -> np.ndarray:
        return np.asarray(self.variation_space["goal"]["position"].value, np.float64)

    @property
    def goal_radius(self) -> float:
        return float(self.variation_space["goal"]["radius"].value)

    @staticmethod
    def _observation(obs: dict) -> dict:
        return {"proprio": obs["proprio"][0], "touch": obs["touch"][0]}

    def _info(self) -> dict:
        priv = self._sim.privileged()
        info = {k: priv[k][0].astype(np.float32) for k in ("finger_pos", "finger_vel", "object_pos", "object_vel")}
        info["contact"] = float(priv["contact"][0])
        info.update({name: float(priv[name][0]) for name in PARAM_NAMES})
        info["goal"] = self._goal_image.copy()
        info["goal_pos"] = self.goal_pos.astype(np.float32)
        info["goal_radius"] = self.goal_radius
        info["distance"] = float(np.linalg.norm(priv["object_pos"][0] - self.goal_pos))
        return info


def register() -> str:
    """Register :data:`ENV_ID` with gymnasium and swm's world list (idempotent); returns the id."""
    swm = _swm()
    if ENV_ID not in gym.registry:
        swm.envs.register(id=ENV_ID, entry_point=ENTRY_POINT, max_episode_steps=EPISODE_STEPS)
    swm.envs.WORLDS.add(ENV_ID)
    return ENV_ID


# ---------------------------------------------------------------------- collection
FORMATS = ("lance", "hdf5")
"""swm dataset formats :func:`run` writes: ``lance`` (``World.collect``'s default) and ``hdf5``."""


@dataclass
class CollectConfig:
    """Record PokeWorld episodes with a stable-worldmodel policy through ``swm.World`` (``pokeworld swm-collect``)."""

    out: str = "out/swm/pokeworld.h5"
    """Output: an ``.h5`` file for ``hdf5`` (exact; ``pokeworld swm-import`` reads it), a ``.lance`` path for
    ``lance`` (frames JPEG-compressed, numbers float32)."""
    format: str = "hdf5"
    """swm dataset format: hdf5 or lance."""
    episodes: int = 8
    """Episodes to record."""
    steps: int = EPISODE_STEPS
    """Steps per episode before truncation (episodes that reach the goal end earlier)."""
    num_envs: int = 2
    """Environments ``World`` steps side by side."""
    image_size: int = 64
    """Side of the recorded ``pixels`` (64 = the native PokeWorld frame, stored unresampled)."""
    seed: int = 0
    """Seed of resets (episode i of env j gets swm's seed schedule from this base) and of the random policy."""
    overwrite: bool = False
    """Replace an existing output."""

    def __post_init__(self) -> None:
        if self.format not in FORMATS:
            raise ConfigError(f"format must be one of {FORMATS}, got {self.format!r}")
        for name in ("episodes", "steps", "num_envs", "image_size"):
            if getattr(self, name) < 1:
                raise ConfigError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.format == "hdf5" and Path(self.out).suffix not in (".h5", ".hdf5"):
            raise ConfigError(f"an hdf5 output must end in .h5 or .hdf5, got {self.out!r}")
        if self.format == "lance" and not self.out.rstrip("/").endswith(".lance"):
            raise ConfigError(f"a lance output must end in .lance, got {self.out!r}")


LANCE_TABLE = OwnedDir(files=(), dirs=(
    ("data", OwnedDir(files=(r".+\.lance",))), ("_versions", OwnedDir(files=(r".+\.manifest",))),
    ("_transactions", OwnedDir(files=(r".+\.txn",))), ("_deletions", OwnedDir(files=(r".+",))),
    ("_indices", OwnedDir(files=(r".+",), dirs=((r".+", OwnedDir(files=(r".+",))),)))))
"""What a Lance table folder holds: the only kind of folder swm-collect replaces (``--overwrite``)."""


def make_world(num_envs: int, steps: int, image_size: int, **env_kwargs):
    """An ``swm.World`` over :data:`ENV_ID` recording native-resolution pixels (registers the env first)."""
    swm = _swm()
    register()
    return swm.World(ENV_ID, num_envs=num_envs, image_shape=(image_size, image_size), max_episode_steps=steps,
                     goal_conditioned=True, **env_kwargs)


def run(cfg: CollectConfig) -> Path:
    """Roll swm's ``RandomPolicy`` through ``World.collect`` into ``cfg.out``; returns the output path."""
    swm = _swm()
    out = Path(cfg.out)
    if out.exists() and not cfg.overwrite:
        raise ConfigError(f"{out} exists; pass --overwrite or choose another --out")
    world = make_world(cfg.num_envs, cfg.steps, cfg.image_size)
    try:
        world.set_policy(swm.policy.RandomPolicy(seed=cfg.seed))
        # io's output contract: swm's writer writes inside a private folder (no predictable name for a planted
        # link), renamed to out only when it succeeds; an existing Lance table is replaced only if it is one
        with atomic_path(out, replace=LANCE_TABLE) as staging:
            writer = swm.data.get_format(cfg.format).open_writer(staging, mode="overwrite")
            world.collect(writer=writer, episodes=cfg.episodes, seed=cfg.seed, progress=False)
    finally:
        world.close()
    print(f"[swm-collect] wrote {cfg.episodes} PokeWorld episodes ({cfg.format}) to {out}")
    return out


__all__ = [
    "DEFAULT_VARIATIONS",
    "ENV_ID",
    "GOAL_RADIUS",
    "CollectConfig",
    "PokeWorldGoalEnv",
    "make_world",
    "register",
    "run",
]
