"""PokeWorld's named environments: the reference (the default) and the calibrated one that came before it.

An environment is the base layer of physics, behaviour and split settings a generator config is built on
(:func:`pokeworld.sim.generate.make_config`, ``--environment``; docs/design.md, "PokeWorld"). ``reference`` is the environment the paper's authors released (their simulator, behaviour mix and
splits, with one later random draw removed): the dataclass defaults of :class:`~pokeworld.sim.core.PhysicsConfig`,
:class:`~pokeworld.sim.policy.PolicyConfig` and the generator are its values, so its layer is empty. ``calibrated``
is the environment every record before it was made with (its constants calibrated to the paper's reported corpus
statistics, docs/design.md "Calibration"): its layer restores each of those values, and its corpora keep their
contents and content hashes.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from ..errors import ConfigError
from .core import PhysicsConfig
from .policy import PolicyConfig

DEFAULT = "reference"

ENVIRONMENTS: dict[str, dict[str, Any]] = {
    "reference": {},
    "calibrated": {
        "physics": {"force_max": 5.6, "finger_damping": 0.85, "contact_damping": "tangent", "walls": "spring",
                    "speed_cap": 0.0, "drag": "exact", "touch_units": "force_max", "placement": "calibrated",
                    "object_intensity": 255.0, "finger_intensity": 128.0},
        "policy": {"behaviour": "calibrated", "mode_weights": (0.2, 0.65, 0.15), "switch_prob": 0.02,
                   "pursuit_gain": 0.89, "strike_gain": 1.0, "launch_fraction": 0.29, "launch_speed": (2.55, 5.0)},
        "split_fractions": (0.6, 0.2, 0.2),
    },
}
"""environment -> the settings it gives fields left at the reference's value (nested like the generator config)."""

LEGACY = "calibrated"
"""The environment of every store and record whose config names none (all made before environments existed)."""

NEW_PHYSICS_FIELDS = ("walls", "wall_stiffness", "speed_cap", "drag", "touch_units", "placement")
"""PhysicsConfig fields the calibrated environment's configs never had: left out of its content configs."""
NEW_POLICY_FIELDS = ("behaviour", "retreat_gain", "strike_cycle", "mode_noise", "ou_persistence")
"""PolicyConfig fields the calibrated behaviour never had (nor reads): left out of its content configs."""


def check(name: str) -> str:
    if name not in ENVIRONMENTS:
        raise ConfigError(f"unknown environment {name!r}; choose one of {sorted(ENVIRONMENTS)}")
    return name


def layered(cfg, name: str):
    """``cfg`` (a dataclass; the generator's defaults when building a config) with environment ``name``'s layer
    applied to every field still at the reference's value."""
    return _layer(cfg, ENVIRONMENTS[check(name)], type(cfg)())


def _layer(cfg, layer: dict, default):
    changes = {}
    for key, value in layer.items():
        current = getattr(cfg, key)
        if dataclasses.is_dataclass(current):
            changes[key] = _layer(current, value, getattr(default, key))
        elif current == getattr(default, key):
            changes[key] = value
    return dataclasses.replace(cfg, **changes) if changes else cfg


def physics(name: str = DEFAULT) -> PhysicsConfig:
    """The arena constants of environment ``name``."""
    return _layer(PhysicsConfig(), ENVIRONMENTS[check(name)].get("physics", {}), PhysicsConfig())


def policy(name: str = DEFAULT) -> PolicyConfig:
    """The behaviour settings of environment ``name``."""
    return _layer(PolicyConfig(), ENVIRONMENTS[check(name)].get("policy", {}), PolicyConfig())


__all__ = ["DEFAULT", "ENVIRONMENTS", "LEGACY", "NEW_PHYSICS_FIELDS", "NEW_POLICY_FIELDS", "check", "layered",
           "physics", "policy"]
