"""Behaviour policies for collecting swm corpora whose physical factors show in the observations.

swm's ``RandomPolicy`` draws a fresh uniform action every step. Under it the action's effect averages out within a few
steps: Cartpole's cart barely leaves the centre and the pole barely swings, Finger's spinner turns in 10 % of the steps
(docs/results/swm_finger_cpu.md), so a factor that acts through those motions (a mass through the acceleration a
held force gives, a density through a swing, friction through a spin) leaves little trace. System identification
excites a plant with piecewise-constant inputs instead (pseudo-random step sequences); :func:`held_random_policy`
does that: every environment holds a uniform random action for a random number of steps in
``[hold_min, hold_max]``, then draws the next. With ``hold_min = hold_max = 1`` it is swm's random policy. The
hold runs on across an episode's end (the next episode starts mid-hold), which changes nothing a window sees.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..config import config_error
from ..errors import ConfigError
from .require import stable_worldmodel

POLICIES = ("random", "held")
"""``random``: swm's RandomPolicy; ``held``: :func:`held_random_policy`."""


def check_hold(hold: tuple[int, int]) -> None:
    if len(hold) != 2 or not 1 <= hold[0] <= hold[1] <= 1000:
        raise config_error(f"hold must be two step counts 1 <= min <= max <= 1000, got {list(hold)}")


class HeldActions:
    """The policy's state without swm: per environment the action held and the steps it has left."""

    def __init__(self, low: np.ndarray, high: np.ndarray, hold: tuple[int, int], seed: int | None):
        check_hold(hold)
        self.low, self.high, self.hold = np.asarray(low, np.float64), np.asarray(high, np.float64), hold
        self.rng = np.random.default_rng(seed)
        self.current = np.zeros(self.low.shape, np.float64)
        self.left = np.zeros(self.low.shape[:1], np.int64)

    def next(self) -> np.ndarray:
        """The actions of every environment for this step, (num_envs, *action shape)."""
        expired = self.left <= 0
        if expired.any():
            self.current[expired] = self.rng.uniform(self.low[expired], self.high[expired])
            self.left[expired] = self.rng.integers(self.hold[0], self.hold[1] + 1, int(expired.sum()))
        self.left -= 1
        return self.current.copy()


def held_random_policy(seed: int | None, hold: tuple[int, int]) -> Any:
    """An swm policy holding each uniform random action for ``hold[0]``..``hold[1]`` steps (see the module)."""
    swm = stable_worldmodel()
    check_hold(hold)

    class HeldRandomPolicy(swm.policy.BasePolicy):
        def __init__(self) -> None:
            super().__init__()
            self.type, self.seed, self.state = "held_random", seed, None

        def set_seed(self, value: int) -> None:
            self.seed, self.state = value, None

        def get_action(self, obs: Any, **kwargs: Any) -> np.ndarray:
            if self.state is None:  # the vector env's batched Box: (num_envs, *shape)
                space = self.env.action_space
                low, high = np.broadcast_arrays(space.low, space.high)
                if not (np.isfinite(low).all() and np.isfinite(high).all()):
                    raise ConfigError("the held random policy needs a bounded action space; this environment's "
                                      "is unbounded: use --policy random")
                self.state = HeldActions(low, high, hold, self.seed)
            return self.state.next().astype(self.env.action_space.dtype)

    return HeldRandomPolicy()


def make_policy(name: str, seed: int, hold: tuple[int, int]) -> Any:
    """The swm policy ``name`` (:data:`POLICIES`), seeded."""
    swm = stable_worldmodel()
    if name == "random":
        return swm.policy.RandomPolicy(seed=seed)
    if name == "held":
        return held_random_policy(seed, hold)
    raise ConfigError(f"unknown policy {name!r}; choose one of {list(POLICIES)}")


__all__ = ["POLICIES", "HeldActions", "check_hold", "held_random_policy", "make_policy"]
