"""Does a factor change the dynamics at all? The swm variation's effect on the non-pixel observations.

A variation space names what an environment *can* vary; it does not promise that the physics reads it. In MuJoCo a
geom's ``density`` is ignored when the geom also sets an explicit ``mass``, and DMControl's XML does that for the
Pendulum's bob and pole and Cartpole's pole, so swm's ``agent.mass_density`` / ``agent.pole_density`` there change
the colour of nothing and the mass of nothing. No estimator can certify such a factor, and reporting it as merely
"not certified" would hide why. :func:`factor_effects` measures it directly: for each factor, the same reset seed
and the same action sequence are run with only that factor at the low and at the high end of its range (every other
variation at its default), and the two non-pixel observation trajectories are compared, beside the same run
repeated at the low end (the simulator's own run-to-run difference). A factor whose two ends give trajectories no
further apart than the repeat is *inert*: it is kept in the certificates as a negative control, and the record says
that it is inert and why it cannot pass. The check is as strong as its episodes: a factor that acts only through a
contact the random actions never make (PokeWorld's object start position under 48 random steps) reads inert too,
which is what it is for the certificates on such episodes.
"""

from __future__ import annotations

from typing import Any

import numpy as np

LOW_DIM_MAX = 256
"""Largest per-step array read as a non-pixel observation (pixels are far larger)."""

REL_TOL = 1e-6
"""An effect at or below this (relative to the observations' spread) reads as none, whatever the repeat gave."""


def low_dim(obs: Any) -> np.ndarray:
    """The non-pixel observation of one step, flattened: the array itself, or a dict's small numeric arrays."""
    if isinstance(obs, dict):
        parts = [np.ravel(np.asarray(v, np.float64)) for _, v in sorted(obs.items())
                 if np.asarray(v).dtype.kind in "fiub" and np.asarray(v).size <= LOW_DIM_MAX]
        return np.concatenate(parts) if parts else np.zeros(0)
    return np.ravel(np.asarray(obs, np.float64))


def subspace(space: Any, key: str) -> Any:
    """The variation subspace at dotted ``key``."""
    for part in key.split("."):
        space = space[part]
    return space


def rollout(env: Any, key: str, value: np.ndarray, seed: int, actions: np.ndarray) -> np.ndarray:
    """Non-pixel observations of one episode: reset at ``seed`` with ``key`` set to ``value``, then ``actions``."""
    obs, _ = env.reset(seed=seed, options={"variation": [key], "variation_values": {key: value}})
    traj = [low_dim(obs)]
    for a in actions:
        obs, *_ = env.step(a)
        traj.append(low_dim(obs))
    return np.stack(traj)


def effect_of(env: Any, key: str, seed: int, steps: int) -> dict:
    """One factor's effect at one seed: the largest low-vs-high and low-vs-low differences, relative to the spread."""
    sub = subspace(env.unwrapped.variation_space, key)
    low, high = np.asarray(sub.low, dtype=sub.dtype), np.asarray(sub.high, dtype=sub.dtype)
    rng = np.random.default_rng(seed)
    space = env.action_space
    actions = rng.uniform(np.broadcast_to(space.low, space.shape), np.broadcast_to(space.high, space.shape),
                          (steps, *space.shape)).astype(space.dtype)
    a, b, c = (rollout(env, key, v, seed, actions) for v in (low, high, low))
    scale = float(np.std(a)) + 1e-12
    return {"effect": float(np.max(np.abs(b - a))) / scale, "repeat": float(np.max(np.abs(c - a))) / scale}


def factor_effects(env_id: str, factors: tuple[str, ...], steps: int = 48, seeds: tuple[int, ...] = (0, 1, 2)
                   ) -> dict[str, dict]:
    """Per factor: the largest relative effect over ``seeds`` of moving it across its range, the largest repeat
    difference, and whether it is inert (module docstring). Factors without a numeric range (a shape, a colour
    space without bounds) are reported as unmeasured."""
    import gymnasium as gym

    env = gym.make(env_id)
    try:
        return effects_in(env, factors, steps, seeds)
    finally:
        env.close()


def effects_in(env: Any, factors: tuple[str, ...], steps: int, seeds: tuple[int, ...]) -> dict[str, dict]:
    """:func:`factor_effects` on an environment already made."""
    out = {}
    for key in factors:
        sub = subspace(env.unwrapped.variation_space, key)
        if getattr(sub, "low", None) is None or getattr(sub, "high", None) is None:
            out[key] = {"effect": None, "repeat": None, "inert": None, "steps": steps, "seeds": list(seeds),
                        "unmeasured": "no numeric range"}
            continue
        if np.array_equal(np.asarray(sub.low), np.asarray(sub.high)):
            out[key] = {"effect": None, "repeat": None, "inert": None, "steps": steps, "seeds": list(seeds),
                        "unmeasured": "its range is a single value: nothing varies"}
            continue
        try:
            runs = [effect_of(env, key, s, steps) for s in seeds]
        except Exception as e:  # noqa: BLE001 - an end of the range the environment refuses (a constraint): unmeasured
            out[key] = {"effect": None, "repeat": None, "inert": None, "steps": steps, "seeds": list(seeds),
                        "unmeasured": f"{type(e).__name__}: {str(e).splitlines()[0][:200] if str(e) else ''}"}
            continue
        effect, repeat = max(r["effect"] for r in runs), max(r["repeat"] for r in runs)
        out[key] = {"effect": effect, "repeat": repeat, "inert": bool(effect <= max(REL_TOL, 10.0 * repeat)),
                    "steps": steps, "seeds": list(seeds)}
    return out


def inert_words(effects: dict[str, dict]) -> list[str]:
    """One line per inert factor, for logs and records."""
    return [f"{k} changed none of the non-pixel observations the certificates read in {v['steps']} steps of "
            f"random actions at seeds {v['seeds']} (its range's two ends, same seed and actions: largest difference "
            f"{v['effect']:.1e} of the observations' spread, repeat {v['repeat']:.1e}); a certificate cannot pass on "
            "such episodes, so it stays in as a negative control" for k, v in effects.items() if v.get("inert")]


__all__ = ["LOW_DIM_MAX", "REL_TOL", "effect_of", "effects_in", "factor_effects", "inert_words", "low_dim", "rollout", "subspace"]
