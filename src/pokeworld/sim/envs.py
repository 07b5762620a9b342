"""Gymnasium front-ends: ``pokeworld/PokeWorld-v0`` and its native vector env (Gymnasium 1.x).

Both wrap :class:`PokeWorldSim`; :class:`PokeWorldEnv` documents the spaces, the action rule, the reward and
the episode length. The vector env uses Gymnasium's default NEXT_STEP autoreset: the step after a truncation
resets that sub-environment and returns its first observation with reward 0.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from ..errors import ConfigError, InputError
from .core import PARAM_NAMES, ParamRanges, PhysicsConfig, PokeWorldSim

_RESET_KEYS = {"params", "finger_pos", "object_pos", "object_vel", "finger_vel"}

EPISODE_STEPS = 64
"""Control steps after which an episode truncates: the corpus's episode length, registered with Gymnasium as the
env's ``max_episode_steps``."""


def episode_steps(value: int | None, required: bool = False) -> int | None:
    """``value`` as an episode length: a positive int, or None (no truncation of the env's own; Gymnasium's
    TimeLimit then truncates) unless ``required``."""
    if value is None and not required:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ConfigError(f"max_episode_steps must be a positive integer, got {value!r}")
    return int(value)



def vision_frames(vision: np.ndarray) -> np.ndarray:
    """Observations' ``vision`` (..., H, W, 1) -> grayscale frames (..., H, W), the layout datasets store and the
    models' encoders read (a view, no copy)."""
    vision = np.asarray(vision)
    if vision.ndim < 3 or vision.shape[-1] != 1:
        raise InputError(f"vision must be (..., H, W, 1) (one channel last), got shape {vision.shape}")
    return vision[..., 0]


def _obs_space(cfg: PhysicsConfig) -> spaces.Dict:
    s, v = cfg.image_size, PokeWorldSim.MAX_VEL
    return spaces.Dict({
        # channel-last with one channel, as Gymnasium's pixel wrappers and image-policy libraries expect
        "vision": spaces.Box(0, 255, (s, s, 1), np.uint8),
        # finger position lies in the unit arena; velocity and force bounds are loose physical caps
        # (reset rejects initial velocities outside this range: PokeWorldSim.MAX_VEL)
        "proprio": spaces.Box(np.array([0, 0, -v, -v], np.float32), np.array([1, 1, v, v], np.float32)),
        "touch": spaces.Box(-1e3, 1e3, (7,), np.float32),
    })


def _check_options(options: dict | None) -> dict:
    options = dict(options or {})
    unknown = set(options) - _RESET_KEYS
    if unknown:
        raise ConfigError(f"unknown reset options {sorted(unknown)}; allowed: {sorted(_RESET_KEYS)}")
    return options


def bounded_actions(actions, n: int) -> np.ndarray:
    """``actions`` as an (n, 2) float array clipped to the action space [-1, 1]² (see :class:`PokeWorldEnv`)."""
    a = np.asarray(actions, dtype=np.float64)
    if a.size != 2 * n:
        raise InputError(f"actions must hold {n} × 2 values (the action space's shape), got shape {a.shape}")
    a = a.reshape(n, 2)
    if not np.all(np.isfinite(a)):
        raise InputError(f"actions must be finite, got {a.tolist()}; pass finite force commands")
    return np.clip(a, -1.0, 1.0)


class PokeWorldEnv(gym.Env):
    """Single-episode PokeWorld: a force-controlled finger pokes an object whose mass, drag and contact stiffness
    are hidden and resampled at every reset.

    Action: a 2-d force command in the action space Box(-1, 1, (2,)); the finger is pushed with
    ``gain · F_max · action + bias`` (gain and bias are hidden per-episode parameters). A component outside
    [-1, 1] is clipped to it (the force saturates at F_max, the Gymnasium convention of most control envs):
    ``[5, 0]`` acts exactly as ``[1, 0]``. A non-finite action raises :class:`~pokeworld.errors.InputError` (a
    ValueError).

    Observation (a dict):

    * ``vision``: (image_size, image_size, 1) uint8 grayscale frame of the arena (64 px by default), channel
      last as Gymnasium's image convention has it (stable-baselines3's ``CnnPolicy`` reads it as an image;
      :func:`vision_frames` drops the channel axis);
    * ``proprio``: (4,) finger position x, y in the unit arena and velocity vx, vy (within ±50);
    * ``touch``: (7,) statistics of the contact force on the finger over the control step's physics sub-steps,
      forces in ``PhysicsConfig.touch_units`` (raw simulator force by default, the reference environment's; F_max
      units in the calibrated one): 0-1 mean force x, y; 2 peak force magnitude; 3-4 force x, y at the step's end;
      5 fraction of sub-steps in contact; 6 contact flag (1 when in contact at any sub-step). Channels 0-4 carry
      Gaussian noise (``PhysicsConfig.touch_noise``).

    Reward: always 0, and the episode never terminates: PokeWorld has no task; it is a data source for world
    models (tasks such as push-to-goal are scored outside the env, :mod:`pokeworld.plan`). Episodes truncate
    after ``max_episode_steps`` control steps (64, the corpus's episode length): ``gymnasium.make`` registers it
    as the env's ``spec.max_episode_steps`` and truncates through Gymnasium's TimeLimit wrapper
    (``gymnasium.make(ENV_ID, max_episode_steps=N)`` for another length); an env constructed directly truncates
    itself after its own ``max_episode_steps``. ``info`` carries the true parameters (``mass``, ``gamma``,
    ``stiffness``, ``bias_x``, ``bias_y``, ``gain``) and the finger and object states.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 20}

    def __init__(self, physics: PhysicsConfig | None = None, ranges: ParamRanges | None = None,
                 max_episode_steps: int | None = EPISODE_STEPS, render_mode: str | None = None):
        if render_mode not in (None, "rgb_array"):
            raise ConfigError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.cfg = physics or PhysicsConfig()
        self.ranges = ranges or ParamRanges()
        self.max_episode_steps = episode_steps(max_episode_steps)
        self.render_mode = render_mode
        self.observation_space = _obs_space(self.cfg)
        self.action_space = spaces.Box(-1.0, 1.0, (2,), np.float32)
        self._sim = PokeWorldSim(1, self.cfg, self.ranges)
        self._t = 0

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        opts = _check_options(options)
        self._sim.rng = self.np_random
        obs = self._sim.reset(**opts)
        self._t = 0
        return self._single(obs), self._info()

    def step(self, action):
        obs = self._sim.step(bounded_actions(action, 1))
        self._t += 1
        truncated = self.max_episode_steps is not None and self._t >= self.max_episode_steps
        return self._single(obs), 0.0, False, truncated, self._info()

    def render(self):
        if self.render_mode == "rgb_array":
            return np.repeat(self._sim.frames[0][..., None], 3, axis=-1)
        return None

    @staticmethod
    def _single(obs: dict) -> dict:
        return {k: v[0] for k, v in obs.items()}

    def _info(self) -> dict:
        priv = self._sim.privileged()
        return {k: (float(v[0]) if v.ndim == 1 else v[0]) for k, v in priv.items()}


class PokeWorldVectorEnv(VectorEnv):
    """Natively vectorised PokeWorld (one numba kernel steps every sub-environment); spaces, action clipping,
    reward and truncation as in :class:`PokeWorldEnv`, per sub-environment. It truncates itself after
    ``max_episode_steps`` (``gymnasium.make_vec`` passes the registered 64, or the length it is given)."""

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": []}

    def __init__(self, num_envs: int = 1, physics: PhysicsConfig | None = None,
                 ranges: ParamRanges | None = None, max_episode_steps: int = EPISODE_STEPS):
        self.num_envs = int(num_envs)
        self.cfg = physics or PhysicsConfig()
        self.max_episode_steps = episode_steps(max_episode_steps, required=True)
        self._sim = PokeWorldSim(self.num_envs, self.cfg, ranges)
        self.single_observation_space = _obs_space(self.cfg)
        self.single_action_space = spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._t = np.zeros(self.num_envs, int)
        self._needs_reset = np.zeros(self.num_envs, bool)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if seed is not None:
            self._sim.rng = np.random.default_rng(seed)
        obs = self._sim.reset(**_check_options(options))
        self._t[:] = 0
        self._needs_reset[:] = False
        return obs, self._sim.privileged()

    def step(self, actions):
        resetting = self._needs_reset.copy()
        obs = self._sim.step(bounded_actions(actions, self.num_envs))
        if resetting.any():
            obs = self._sim.reset(mask=resetting)
            self._t[resetting] = 0
        self._t[~resetting] += 1
        truncated = (self._t >= self.max_episode_steps) & ~resetting
        self._needs_reset = truncated.copy()
        reward = np.zeros(self.num_envs)
        terminated = np.zeros(self.num_envs, bool)
        return obs, reward, terminated, truncated, self._sim.privileged()


def registered_env(**kwargs) -> PokeWorldEnv:
    """The entry point ``gymnasium.make`` calls: a :class:`PokeWorldEnv` that leaves truncation to the TimeLimit
    wrapper Gymnasium adds from the registered (or given) ``max_episode_steps``, so that one length rules."""
    return PokeWorldEnv(**{"max_episode_steps": None, **kwargs})


def register() -> None:
    """Register the env ids with gymnasium (idempotent; ``import pokeworld`` already does it)."""
    from .. import register_envs

    register_envs()


__all__ = ["EPISODE_STEPS", "PokeWorldEnv", "PokeWorldVectorEnv", "episode_steps", "register", "registered_env",
           "vision_frames", "PARAM_NAMES"]
