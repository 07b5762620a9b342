"""Open-loop replay: the simulator continued from a recorded state under a given action program.

The forecast-dependence measurement (:mod:`pokeworld.evaluate.dependence`) needs the simulator's own answer to
"what happens from this state, with these parameters, under these actions": the truth its slopes are computed on,
and the reference forecasters (the simulator itself and its planted corruptions) that check the measurement.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..errors import ConfigError
from .core import DRIFT_NAMES, PARAM_NAMES, SIM_PARAM_NAMES, PhysicsConfig, PokeWorldSim
from .generate_config import generator_config, resolved

STATE_LABELS = ("finger_pos", "finger_vel", "object_pos", "object_vel")
"""The store labels that make up the simulator's state vector, in its order (:mod:`pokeworld.sim.physics`)."""


def physics_of(manifest: dict) -> PhysicsConfig:
    """The physics a store was generated with, read as the generator reads its manifest
    (:func:`~pokeworld.sim.generate_config.generator_config`: a field the manifest lacks takes the value stores had
    before it existed, never today's default), so an old store is replayed as what it is."""
    return resolved(generator_config(manifest)).physics


def state_at(labels: dict, episodes: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(N, 8) simulator states of ``episodes`` at observation ``t`` from the store's labels."""
    return np.concatenate([np.asarray(labels[k][episodes, t], float) for k in STATE_LABELS], -1)


def params_of(params: dict, episodes: np.ndarray) -> np.ndarray:
    """(N, len(SIM_PARAM_NAMES)) hidden parameters of ``episodes`` in the simulator's layout (a store without a drift
    acceleration, every store but a drift corpus, has none: zeros)."""
    base = [np.asarray(params[k], float)[episodes] for k in PARAM_NAMES]
    drift = [np.asarray(params[k], float)[episodes] if k in params else np.zeros(len(base[0])) for k in DRIFT_NAMES]
    return np.stack(base + drift, -1)


def replay(physics: PhysicsConfig, state: np.ndarray, params: np.ndarray, actions: np.ndarray) -> dict:
    """Continue N episodes from ``state`` (N, 8) with ``params`` (N, 8) under ``actions`` (N, H, 2).

    Returns noise-free ``object_pos`` / ``object_vel`` (N, H, 2) and ``touch`` (N, H, 7) after each of the H steps
    (``touch[:, j]`` summarises step j, as the observation after it does). Nothing is rendered.
    """
    state, params, actions = (np.asarray(x, float) for x in (state, params, actions))
    n = len(state)
    if state.shape != (n, 8) or params.shape != (n, len(SIM_PARAM_NAMES)) or actions.ndim != 3 or len(actions) != n:
        raise ConfigError(f"replay needs state (N, 8), params (N, {len(SIM_PARAM_NAMES)}) and actions (N, H, 2), got "
                          f"{state.shape}, {params.shape} and {actions.shape}")
    sim = PokeWorldSim(n, dataclasses.replace(physics, touch_noise=0.0))
    sim.state[:] = state
    sim.params[:] = params
    pos, vel, touch = [], [], []
    for j in range(actions.shape[1]):
        sim.step(actions[:, j], render=False)
        pos.append(sim.state[:, 4:6].copy())
        vel.append(sim.state[:, 6:8].copy())
        touch.append(sim.touch_clean.copy())
    return {"object_pos": np.stack(pos, 1), "object_vel": np.stack(vel, 1), "touch": np.stack(touch, 1)}


__all__ = ["STATE_LABELS", "params_of", "physics_of", "replay", "state_at"]
