"""What the contact law leaves in the observations: restitution and post-contact displacement against stiffness.

The paper's matched pairs (Fig. pairs (c)) say a stiffness change alters "the impact transient, and with it the
post-contact trajectory". Whether it does depends on how "normal damping at zeta of critical" is read
(:func:`pokeworld.sim.physics.hertz_normal_force`). This module measures it in the simulator itself, for either
reading, and integrates the same one-dimensional contact independently (``scipy``) as the reference a test checks
the simulator against. ``scripts/contact_law.py`` writes the record (docs/results/contact_law_*.{json,md}).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from .core import PhysicsConfig, PokeWorldSim

HEAD_ON_Y = 0.5
"""Height of the head-on collisions (the arena's middle: no wall within reach)."""


def _sim(physics: PhysicsConfig, n: int, k, m, v, gamma) -> PokeWorldSim:
    """``n`` head-on collisions: the finger moving at ``v`` along +x just before touching an object at rest."""
    sim = PokeWorldSim(n, physics, seed=0)
    gap = 1e-4
    x_f = 0.25
    x_o = x_f + physics.finger_radius + physics.object_radius + gap
    sim.reset(params={"mass": m, "gamma": gamma, "stiffness": k},
              finger_pos=np.tile([x_f, HEAD_ON_Y], (n, 1)), object_pos=np.tile([x_o, HEAD_ON_Y], (n, 1)),
              finger_vel=np.stack([v, np.zeros(n)], 1), object_vel=np.zeros((n, 2)))
    return sim


def restitution(physics: PhysicsConfig, k, m, v, gamma=0.0, max_steps: int = 20000) -> np.ndarray:
    """Coefficient of restitution of head-on impacts at relative speed ``v`` (arrays broadcast together).

    Simulated at the physics' own sub-step (one sub-step per call, so separation is caught to within a sub-step),
    zero commanded force; e = (v_object − v_finger after separation) / v. Finger damping and drag act during the
    contact as they do in the corpus; set them to zero for the two-body law alone.
    """
    k, m, v, gamma = np.broadcast_arrays(*(np.asarray(a, float).ravel() for a in (k, m, v, gamma)))
    h = physics.dt / physics.substeps
    fine = dataclasses.replace(physics, dt=h, substeps=1, touch_noise=0.0)
    sim = _sim(fine, k.size, k, m, v, gamma)
    touched = np.zeros(k.size, bool)
    out = np.full(k.size, np.nan)
    zero = np.zeros((k.size, 2))
    for _ in range(max_steps):
        sim.step(zero, render=False)
        contact = sim.touch_clean[:, 6] > 0
        done = touched & ~contact & np.isnan(out)
        out[done] = (sim.state[done, 6] - sim.state[done, 2]) / v[done]
        touched |= contact
        if not np.isnan(out).any():
            break
    return out


def displacement_after(physics: PhysicsConfig, k, m, v, gamma, steps: int = 16) -> np.ndarray:
    """Object displacement along the impact direction ``steps`` control steps after a head-on impact at ``v``,
    the finger retreating at full force from the first control step after it separated (as strike–retreat does;
    no commanded force before): the post-contact trajectory a model sees."""
    k, m, v, gamma = np.broadcast_arrays(*(np.asarray(a, float).ravel() for a in (k, m, v, gamma)))
    sim = _sim(dataclasses.replace(physics, touch_noise=0.0), k.size, k, m, v, gamma)
    x0 = sim.state[:, 4].copy()
    touched = np.zeros(k.size, bool)
    retreat = np.zeros(k.size, bool)
    for _ in range(steps):
        sim.step(np.stack([-retreat.astype(float), np.zeros(k.size)], 1), render=False)
        contact = sim.touch_clean[:, 6] > 0
        retreat |= touched & ~contact
        touched |= contact
    return sim.state[:, 4] - x0


def restitution_reference(law: str, k: float, mu: float, v: float, zeta: float) -> float:
    """The same two-body Hertz contact with damping integrated by ``scipy`` (no drag, no finger damping):
    mu d'' = −k d^1.5 − c d', from d = 0, d' = v, until the force vanishes; e = −d'(end) / v.

    ``c = 2 zeta sqrt(k mu)`` (law "constant") or ``2 zeta sqrt(1.5 k sqrt(d) mu)`` (law "tangent"); the
    separation is where the clipped force reaches zero (the penalty contact cannot pull), as in the simulator.
    Law "hertz" (the reference environment's): ``c = 2 zeta sqrt(k mu) sqrt(d)``, not clipped, so the contact
    lasts until the overlap is gone.
    """
    from scipy.integrate import solve_ivp

    def force(d: float, dd: float) -> float:
        stiffness = k if law in ("constant", "hertz") else 1.5 * k * math.sqrt(max(d, 0.0))
        c = 2 * zeta * math.sqrt(stiffness * mu) * (math.sqrt(max(d, 0.0)) if law == "hertz" else 1.0)
        return k * max(d, 0.0) ** 1.5 + c * dd

    def rhs(_t, y):
        f = force(y[0], y[1])
        return [y[1], -(f if law == "hertz" else max(f, 0.0)) / mu]

    def released(_t, y):  # the force has fallen to zero (hertz: the overlap is gone) while the bodies separate
        if law == "hertz":
            return y[0] if y[1] < 0 else 1.0
        return force(y[0], y[1]) if y[1] < 0 else 1.0

    released.terminal, released.direction = True, -1
    delta = (5 * mu * v * v / (4 * k)) ** 0.4  # undamped maximum overlap: sets the time scale
    sol = solve_ivp(rhs, (0.0, 50 * delta / v), [0.0, v], events=released, rtol=1e-10, atol=1e-13,
                    max_step=delta / v / 200)
    return float(-sol.y_events[0][0][1] / v) if sol.t_events[0].size else float(-sol.y[1, -1] / v)


def impact_speeds(labels: dict) -> np.ndarray:
    """Relative normal speeds at every contact onset of a corpus (its ``labels``): the step before contact starts,
    the finger's velocity minus the object's, projected on the line of centres. The speeds a model sees impacts at.
    """
    contact = labels["contact"] > 0
    onset = contact[:, 1:] & ~contact[:, :-1]
    e, t = np.nonzero(onset)
    normal = labels["object_pos"][e, t] - labels["finger_pos"][e, t]
    normal = normal / np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    return np.einsum("ij,ij->i", labels["finger_vel"][e, t] - labels["object_vel"][e, t], normal)


def law_table(physics: PhysicsConfig, stiffness, speeds, mass: float = 1.0, gamma: float = 1.0,
              steps: int = 16) -> dict:
    """Restitution and +``steps`` displacement over a stiffness × impact-speed grid for both damping laws, with
    the soft / stiff ratios a reader compares (1.00 means stiffness leaves no trace after contact)."""
    kk, vv = np.meshgrid(np.asarray(stiffness, float), np.asarray(speeds, float), indexing="ij")
    out = {"stiffness": list(map(float, stiffness)), "speeds": list(map(float, speeds)), "mass": mass, "gamma": gamma,
           "steps": steps, "laws": {}}
    for law in ("constant", "tangent"):
        ph = dataclasses.replace(physics, contact_damping=law)
        e = restitution(ph, kk, mass, vv, gamma).reshape(kk.shape)
        disp = displacement_after(ph, kk, mass, vv, gamma, steps).reshape(kk.shape)
        out["laws"][law] = {"restitution": e.tolist(), "displacement": disp.tolist(),
                            "restitution_ratio_soft_to_stiff": (e[0] / e[-1]).tolist(),
                            "displacement_ratio_soft_to_stiff": (disp[0] / disp[-1]).tolist()}
    return out


__all__ = ["restitution", "displacement_after", "restitution_reference", "impact_speeds", "law_table"]
