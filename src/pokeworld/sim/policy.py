"""Scripted behaviour policies: pursuit, strike-retreat and Ornstein-Uhlenbeck drift, randomly switched.

Vectorised over episodes. A fraction of episodes are *glide* episodes in which
the finger avoids the object after it has been launched, giving contact-free
decays (the contact-poor corpus sets this fraction to 0.95).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError

PURSUIT, STRIKE, DRIFT, AVOID = 0, 1, 2, 3


@dataclass(frozen=True)
class PolicyConfig:
    """Knobs of the mixed behaviour policy.

    The defaults are calibrated (with F_max and finger damping) so that the default corpus matches
    the paper's observable statistics (``pokeworld stats``; docs/design.md, "Calibration";
    ``scripts/calibrate_env.py``), with every mode kept at a weight of at least 0.15.
    """

    mode_weights: tuple[float, float, float] = (0.2, 0.65, 0.15)
    """Relative probabilities of pursuit / strike-retreat / OU drift when a mode is (re)drawn."""
    switch_prob: float = 0.02
    """Per-step probability of redrawing the mode."""
    pursuit_gain: float = 0.89
    """Action magnitude of sustained pushes (pursuit)."""
    strike_gain: float = 1.0
    """Action magnitude while striking."""
    retreat_steps: tuple[int, int] = (4, 7)
    """Range of steps spent retreating after an impact (the object glides meanwhile)."""
    ou_theta: float = 1.5
    """Mean-reversion rate of the OU drift (1/s)."""
    ou_sigma: float = 2.8
    """Diffusion of the OU drift."""
    action_noise: float = 0.1
    """Std of Gaussian noise added to scripted actions."""
    launch_fraction: float = 0.29
    """Fraction of episodes whose object starts with a random velocity."""
    launch_speed: tuple[float, float] = (2.55, 5.0)
    """Launch speed range (arena units/s)."""
    glide_fraction: float = 0.0
    """Fraction of episodes that are contact-free glides (object launched, finger avoids it)."""

    def __post_init__(self) -> None:
        if len(self.mode_weights) != 3 or min(self.mode_weights) < 0 or sum(self.mode_weights) <= 0:
            raise ConfigError(f"mode_weights must be three non-negative numbers, got {self.mode_weights}")
        for name in ("switch_prob", "launch_fraction", "glide_fraction"):
            v = getattr(self, name)
            if not 0 <= v <= 1:
                raise ConfigError(f"PolicyConfig.{name} must be in [0, 1], got {v}")
        if self.retreat_steps[0] < 1 or self.retreat_steps[1] < self.retreat_steps[0]:
            raise ConfigError(f"retreat_steps must be 1 <= lo <= hi, got {self.retreat_steps}")


class MixedPolicy:
    """Stateful vectorised policy; call :meth:`reset` at episode start and :meth:`act` every step."""

    def __init__(self, cfg: PolicyConfig, num_envs: int, rng: np.random.Generator, dt: float = 0.05):
        self.cfg, self.n, self.rng, self.dt = cfg, num_envs, rng, dt
        w = np.asarray(cfg.mode_weights, float)
        self._p = w / w.sum()
        self.mode = np.zeros(num_envs, int)
        self.glide = np.zeros(num_envs, bool)
        self.ou = np.zeros((num_envs, 2))
        self.retreat = np.zeros(num_envs, int)

    def reset(self) -> tuple[np.ndarray, np.ndarray]:
        """Draw per-episode modes; returns (launch mask, launch velocities) for the simulator reset."""
        n, c, rng = self.n, self.cfg, self.rng
        self.glide = rng.random(n) < c.glide_fraction
        self.mode = np.where(self.glide, AVOID, rng.choice(3, n, p=self._p))
        self.ou = rng.normal(0, 0.3, (n, 2))
        self.retreat = np.zeros(n, int)
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
        return np.clip(a, -1.0, 1.0)
