"""Scripted behaviour policies: pursuit, strike-retreat and Ornstein-Uhlenbeck drift, randomly switched.

Two behaviours (``PolicyConfig.behaviour``). The *reference* behaviour (the default; :class:`ReferencePolicy`) is
the authors' released simulator's: modes drawn uniformly and redrawn with probability 0.03 per step, pursuit
``1.2 u + 0.4 ε``, a periodic strike (6 steps approaching at ``1.4 u``, 4 retreating at ``-u``, ``+ 0.3 ε``, phase
random per episode) and an AR(1) drift ``0.85 a + 0.45 ε`` of the previous action, u the unit vector to the object.
The *calibrated* behaviour (:class:`MixedPolicy`, the calibrated environment's) is described below.

Vectorised over episodes. A fraction of episodes are *glide* episodes in which
the finger avoids the object after it has been launched, giving contact-free
decays (the contact-poor corpus sets this fraction to 0.95). Optionally a share
of the 16-step program slots of every other episode is *open-loop*: one random
two-knot action program, the planner's own action family (:func:`programs`),
executed without re-aiming, so the corpus holds programs that miss as well as
programs that hit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..config import FRACTION, Limit, check_fields
from ..errors import ConfigError

PURSUIT, STRIKE, DRIFT, AVOID = 0, 1, 2, 3

PROGRAM = 16
"""Actions in one two-knot action program: the planner's horizon (its Δ=16 head) and an open-loop slot's length."""
KNOT_SD = 0.8
"""Std of a random knot coordinate: the CEM planner's first proposal and the open-loop slots' spread."""


def programs(knots: np.ndarray) -> np.ndarray:
    """(..., 4) knots -> (..., 16, 2) actions interpolated from knot 1 to knot 2, clipped to [-1, 1].

    The one definition of the smooth two-knot action family, shared by the CEM planner (pokeworld.plan) and the
    open-loop behaviour slots, so the programs a model is trained on and those it must rank cannot drift apart.
    """
    w = np.linspace(0.0, 1.0, PROGRAM)[:, None]
    a = knots[..., None, 0:2] * (1 - w) + knots[..., None, 2:4] * w
    return np.clip(a, -1.0, 1.0)


def aimed_knots(direction: np.ndarray, aim, rng: np.random.Generator) -> np.ndarray:
    """(n, 2) unit directions -> (n, 4) knots N(aim · direction, KNOT_SD²) per coordinate (both knots aimed the
    same way): the open-loop slots' programs; ``aim`` a scalar or per row ((n, 1); 0 gives the planner's first
    CEM proposal)."""
    return aim * np.concatenate([direction, direction], -1) + rng.normal(0.0, KNOT_SD, (len(direction), 4))


@dataclass(frozen=True)
class PolicyConfig:
    """Knobs of the mixed behaviour policy.

    The defaults are the reference behaviour's (module docstring). The calibrated environment's values
    (docs/design.md, "Calibration"; :data:`pokeworld.sim.environments.ENVIRONMENTS`) were calibrated with F_max and
    finger damping so that its corpus matched the paper's observable statistics, every mode at weight >= 0.15.
    Fields marked "calibrated behaviour" are read by that behaviour only, "reference behaviour" by the other.
    """

    behaviour: str = "reference"
    """Which scripted behaviour acts: "reference" (:class:`ReferencePolicy`) or "calibrated" (:class:`MixedPolicy`)."""
    mode_weights: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """Relative probabilities of pursuit / strike(-retreat) / drift when a mode is (re)drawn."""
    switch_prob: float = 0.03
    """Per-step probability of redrawing the mode (the reference behaviour may redraw the same mode)."""
    pursuit_gain: float = 1.2
    """Action magnitude of sustained pushes (pursuit; the reference's 1.2 saturates at the [-1, 1] clip)."""
    strike_gain: float = 1.4
    """Action magnitude while striking (approaching)."""
    retreat_gain: float = 1.0
    """Reference behaviour: action magnitude of the strike cycle's retreat (away from the object)."""
    strike_cycle: tuple[int, int] = (6, 4)
    """Reference behaviour: steps approaching, then steps retreating, of the periodic strike."""
    mode_noise: tuple[float, float, float] = (0.4, 0.3, 0.45)
    """Reference behaviour: std of the Gaussian noise of pursuit / strike / drift actions (one draw per step)."""
    ou_persistence: float = 0.85
    """Reference behaviour: the drift's action is ou_persistence times the previous action plus its noise."""
    retreat_steps: tuple[int, int] = (4, 7)
    """Calibrated behaviour: range of steps spent retreating after an impact (the object glides meanwhile)."""
    ou_theta: float = 1.5
    """Calibrated behaviour: mean-reversion rate of the OU drift (1/s)."""
    ou_sigma: float = 2.8
    """Calibrated behaviour: diffusion of the OU drift."""
    action_noise: float = 0.1
    """Calibrated behaviour: std of Gaussian noise added to scripted actions."""
    launch_fraction: float = 0.6
    """Fraction of episodes whose object starts with a random velocity."""
    launch_speed: tuple[float, float] = (0.15, 0.9)
    """Launch speed range (arena units/s)."""
    glide_fraction: float = 0.0
    """Fraction of episodes that are contact-free glides (object launched, finger avoids it)."""
    open_loop_share: float = 0.0
    """Probability that a program slot (steps 16j..16j+15) of a non-glide episode executes one random two-knot
    program (:func:`programs`, no action noise, no re-aiming) instead of the closed-loop modes. 0 draws nothing,
    so corpora stay byte-identical to those made before the field existed (docs/design.md, "Planning: open-loop
    behaviour data and the rank test")."""
    open_loop_aim: float = 0.89
    """Mean of both knots of an open-loop program along the finger-to-object direction at the slot's start
    (spread KNOT_SD per coordinate around it); 0 gives exactly the planner's first CEM proposal, N(0, KNOT_SD²).
    Aimed programs still miss often, and keep ``static16`` in band at a share of 0.2 where unaimed ones do not."""

    LIMITS = {"retreat_gain": Limit(0, 100), "strike_cycle": Limit(1, 10**4), "mode_noise": Limit(0, 1e3),
              "ou_persistence": Limit(0, 1), "mode_weights": Limit(0, 1e6), "switch_prob": FRACTION, "pursuit_gain": Limit(0, 100),
              "strike_gain": Limit(0, 100), "retreat_steps": Limit(1, 10**4), "ou_theta": Limit(0, 1e4),
              "ou_sigma": Limit(0, 1e4), "action_noise": Limit(0, 1e3), "launch_fraction": FRACTION,
              "launch_speed": Limit(0, 1e3), "glide_fraction": FRACTION, "open_loop_share": FRACTION,
              "open_loop_aim": FRACTION}  # the aim is an action magnitude

    def __post_init__(self) -> None:
        check_fields(self)
        if sum(self.mode_weights) <= 0:
            raise ConfigError(f"mode_weights must be three non-negative numbers, not all 0, got {self.mode_weights}")
        if self.retreat_steps[1] < self.retreat_steps[0]:
            raise ConfigError(f"retreat_steps must be 1 <= lo <= hi, got {self.retreat_steps}")
        if self.behaviour not in BEHAVIOURS:
            raise ConfigError(f"behaviour must be one of {BEHAVIOURS}, got {self.behaviour!r}")


BEHAVIOURS = ("reference", "calibrated")


def make_policy(cfg: PolicyConfig, num_envs: int, rng: np.random.Generator, dt: float = 0.05):
    """The behaviour ``cfg.behaviour`` names, for ``num_envs`` episodes."""
    cls = ReferencePolicy if cfg.behaviour == "reference" else MixedPolicy
    return cls(cfg, num_envs, rng, dt)


class MixedPolicy:
    """Stateful vectorised policy; call :meth:`reset` at episode start and :meth:`act` every step."""

    def __init__(self, cfg: PolicyConfig, num_envs: int, rng: np.random.Generator, dt: float = 0.05):
        self.cfg, self.n, self.rng, self.dt = cfg, num_envs, rng, dt
        w = np.asarray(cfg.mode_weights, float)
        self._p = w / w.sum()
        self.mode = np.zeros(num_envs, int)
        self.glide = np.zeros(num_envs, bool)
        self.open_loop = np.zeros(num_envs, bool)  # this slot runs a program
        self.knots = np.zeros((num_envs, 4))  # the slot's program knots (where open_loop)
        self.t = 0  # steps since reset: program slots start at multiples of PROGRAM
        self.ou = np.zeros((num_envs, 2))
        self.retreat = np.zeros(num_envs, int)

    def reset(self) -> tuple[np.ndarray, np.ndarray]:
        """Draw per-episode modes; returns (launch mask, launch velocities) for the simulator reset."""
        n, c, rng = self.n, self.cfg, self.rng
        self.glide = rng.random(n) < c.glide_fraction
        self.mode = np.where(self.glide, AVOID, rng.choice(3, n, p=self._p))
        self.ou = rng.normal(0, 0.3, (n, 2))
        self.retreat = np.zeros(n, int)
        self.open_loop = np.zeros(n, bool)
        self.t = 0
        launch = self.glide | (rng.random(n) < c.launch_fraction)
        ang = rng.uniform(0, 2 * np.pi, n)
        speed = rng.uniform(*c.launch_speed, n)
        vel = np.stack([np.cos(ang), np.sin(ang)], 1) * (speed * launch)[:, None]
        return launch, vel

    def act(self, proprio: np.ndarray, object_pos: np.ndarray, contact: np.ndarray) -> np.ndarray:
        """Actions (N, 2) in [-1, 1] from finger state, object position and last-step contact flag."""
        c, rng, n = self.cfg, self.rng, self.n
        switch = (~self.glide) & (rng.random(n) < c.switch_prob)
        if switch.any():
            self.mode[switch] = rng.choice(3, int(switch.sum()), p=self._p)
            self.retreat[switch] = 0
        fp, fv = proprio[:, 0:2], proprio[:, 2:4]
        rel = object_pos - fp
        dist = np.linalg.norm(rel, axis=1, keepdims=True)
        u = rel / np.maximum(dist, 1e-6)
        self.ou += -c.ou_theta * self.ou * self.dt + c.ou_sigma * np.sqrt(self.dt) * rng.normal(size=(n, 2))
        a = np.zeros((n, 2))
        m = self.mode
        a[m == PURSUIT] = c.pursuit_gain * u[m == PURSUIT]
        a[m == DRIFT] = self.ou[m == DRIFT]
        # strike-retreat: charge until an impact, then back off for a few steps while the object glides
        strike = m == STRIKE
        hit = strike & (contact > 0.5) & (self.retreat == 0)
        self.retreat[hit] = rng.integers(c.retreat_steps[0], c.retreat_steps[1] + 1, int(hit.sum()))
        retreating = strike & (self.retreat > 0)
        charging = strike & ~retreating
        a[charging] = c.strike_gain * u[charging]
        a[retreating] = -0.7 * u[retreating] - 0.3 * fv[retreating]
        self.retreat[retreating] -= 1
        avoid = m == AVOID
        near = avoid & (dist[:, 0] < 0.4)
        a[avoid] = 0.5 * self.ou[avoid]
        a[near] = -0.8 * u[near]
        a += c.action_noise * rng.normal(size=(n, 2))
        a = np.clip(a, -1.0, 1.0)
        # open-loop slots draw last and only when asked for, so the closed-loop stream of a corpus without them is
        # unchanged; the closed-loop state above keeps evolving underneath and takes over when the slot ends
        step = self.t % PROGRAM
        self.t += 1
        if c.open_loop_share > 0 and step == 0:
            self.open_loop = ~self.glide & (rng.random(n) < c.open_loop_share)
            self.knots[self.open_loop] = aimed_knots(u[self.open_loop], c.open_loop_aim, rng)
        if self.open_loop.any():  # the program exactly, as the planner executes it
            a[self.open_loop] = programs(self.knots[self.open_loop])[:, step]
        return a


class ReferencePolicy(MixedPolicy):
    """The reference behaviour (module docstring), with the calibrated behaviour's glide episodes (the finger
    drifts at 0.15 ε, the object launched) and open-loop program slots, both off by default."""

    def reset(self) -> tuple[np.ndarray, np.ndarray]:
        n, c, rng = self.n, self.cfg, self.rng
        self.glide = rng.random(n) < c.glide_fraction if c.glide_fraction > 0 else np.zeros(n, bool)
        self.mode = np.where(self.glide, AVOID, rng.choice(3, n, p=self._p))
        self.phase = rng.integers(0, sum(c.strike_cycle), n)
        self.last = np.zeros((n, 2))
        self.open_loop = np.zeros(n, bool)
        self.t = 0
        launch = self.glide | (rng.random(n) < c.launch_fraction)
        ang = rng.uniform(0, 2 * np.pi, n)
        speed = rng.uniform(*c.launch_speed, n)
        return launch, np.stack([np.cos(ang), np.sin(ang)], 1) * (speed * launch)[:, None]

    def act(self, proprio: np.ndarray, object_pos: np.ndarray, contact: np.ndarray) -> np.ndarray:
        c, rng, n = self.cfg, self.rng, self.n
        switch = ~self.glide & (rng.random(n) < c.switch_prob)
        if switch.any():
            self.mode[switch] = rng.choice(3, int(switch.sum()), p=self._p)
        rel = object_pos - proprio[:, 0:2]
        u = rel / np.maximum(np.linalg.norm(rel, axis=1, keepdims=True), 1e-8)
        eps = rng.normal(size=(n, 2))
        approach = ((self.t + self.phase) % sum(c.strike_cycle)) < c.strike_cycle[0]
        strike = np.where(approach[:, None], c.strike_gain * u, -c.retreat_gain * u)
        m = self.mode[:, None]
        a = np.where(m == PURSUIT, c.pursuit_gain * u + c.mode_noise[0] * eps,
                     np.where(m == STRIKE, strike + c.mode_noise[1] * eps,
                              np.where(m == DRIFT, c.ou_persistence * self.last + c.mode_noise[2] * eps, 0.15 * eps)))
        a = np.clip(a, -1.0, 1.0)
        step = self.t % PROGRAM
        self.t += 1
        if c.open_loop_share > 0 and step == 0:
            self.open_loop = ~self.glide & (rng.random(n) < c.open_loop_share)
            self.knots[self.open_loop] = aimed_knots(u[self.open_loop], c.open_loop_aim, rng)
        if self.open_loop.any():
            a[self.open_loop] = programs(self.knots[self.open_loop])[:, step]
        self.last = a
        return a
