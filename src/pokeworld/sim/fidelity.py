"""How close a PokeWorld corpus is to the authors' released reference: the statistics of a side-by-side table.

Every window statistic follows the reference's evaluation code (``exp/e003_motion/train.py`` of
``tantansir/latent-world-model-identifiability``): its episodes record 64 states, each *after* a control step, so
its frame j is our observation j + 1 (our observation 0 is the reset state). Its probe windows start at frames
0, 8, …, 40 and hold 16 frames; a window is a *contact* window with ≥ 2 contact frames, a *glide* window with none
and a mean object speed above 0.15. Static-16 is ‖p(31) − p(15)‖ of its frames, averaged over episodes (its
``static_baseline_err["16"]``). The raw-state ridge is its ``raw_lin+obj`` control (``probe_controls.py``): ridge
on the flattened 16-frame window of finger state, object state, touch and action (17 numbers a frame), α chosen on
an 80 / 20 split of the fit windows, fit on probe-fit contact windows and scored on probe-test ones.

Head-on restitution is :func:`pokeworld.sim.contact.restitution` of the contact law alone under the corpus's physics
(no finger damping, no drag, no command): the finger at 1.3 into an object of mass 1.22 at rest.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..data import Dataset
from ..errors import DataError
from . import contact
from .core import PhysicsConfig

WINDOW, STARTS = 16, (0, 8, 16, 24, 32, 40)
"""The reference's probe windows: 16 frames from each of these starts (its frames: our observations + 1)."""
MIN_WINDOWS = 20
"""Fewer contact windows than this in either split: no ridge number (NaN)."""
RESTITUTION_K, RESTITUTION_M, RESTITUTION_V = (500.0, 1732.0, 6000.0), 1.22, 1.3
TARGETS = ("log_m", "gamma", "log_k")

#: statistic -> (reference value, tolerance): the released simulator's numbers, measured outside the project
REFERENCE: dict[str, tuple[float, float]] = {
    "restitution_k500": (0.74, 0.05), "restitution_k1732": (0.77, 0.05), "restitution_k6000": (0.79, 0.05),
    "static16": (0.205, 0.015), "contact_step_fraction": (0.32, 0.04), "contact_window_fraction": (0.67, 0.04),
    "glide_window_fraction": (0.073, 0.02), "impact_speed_median": (0.79, 0.12), "object_speed_p99": (1.32, 0.2),
    "first_frame_moving": (0.62, 0.04), "ridge_log_m": (0.79, 0.08), "ridge_gamma": (0.30, 0.08),
    "ridge_log_k": (0.95, 0.03),
}
#: the same statistics of the calibrated environment's paper corpus, measured outside the project beside the
#: reference's (the outside measurement's calibrated column; scripts/reference_fidelity.py checks ours against it)
CALIBRATED_ISSUE: dict[str, float] = {
    "restitution_k500": 0.48, "restitution_k1732": 0.48, "restitution_k6000": 0.48, "static16": 0.168,
    "contact_step_fraction": 0.29, "contact_window_fraction": 0.85, "glide_window_fraction": 0.034,
    "impact_speed_median": 1.31, "object_speed_p99": 2.10, "first_frame_moving": 0.29, "ridge_log_m": 0.68,
    "ridge_gamma": 0.48, "ridge_log_k": 0.95,
}


def reference_frames(ds: Dataset) -> dict[str, np.ndarray]:
    """The store's states on the reference's frame grid (observations 1 …): finger and object (E, T, 4) as
    position + velocity, touch (E, T, 7), actions (E, T, 2) (action j drives frame j), contact flags (E, T)."""
    lab = ds.labels
    for name in ("finger_pos", "finger_vel", "object_pos", "object_vel", "contact"):
        if name not in lab:
            raise DataError(f"the fidelity statistics need labels/{name}; this store has {sorted(lab)}")
    if ds.actions.shape[1] < STARTS[-1] + WINDOW:
        raise DataError(f"episodes of {ds.actions.shape[1]} steps are shorter than the reference's "
                        f"{STARTS[-1] + WINDOW}-frame probe grid")
    cat = lambda *a: np.concatenate([x[:, 1:] for x in a], -1).astype(np.float64)  # noqa: E731
    return {"finger": cat(lab["finger_pos"], lab["finger_vel"]), "obj": cat(lab["object_pos"], lab["object_vel"]),
            "touch": ds.touch[:, 1:].astype(np.float64), "act": ds.actions.astype(np.float64),
            "contact": lab["contact"][:, 1:] > 0}


def windows(f: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Per (episode, start) window of the reference's grid: contact-frame count, mean object speed, raw features."""
    E = f["contact"].shape[0]
    ep, t0 = np.repeat(np.arange(E), len(STARTS)), np.tile(STARTS, E)
    span = t0[:, None] + np.arange(WINDOW)[None]
    speed = np.linalg.norm(f["obj"][..., 2:], axis=-1)
    raw = np.concatenate([f["finger"][ep[:, None], span], f["obj"][ep[:, None], span],
                          f["touch"][ep[:, None], span], f["act"][ep[:, None], span]], -1)
    return {"episode": ep, "contacts": f["contact"][ep[:, None], span].sum(1), "speed": speed[ep[:, None], span].mean(1),
            "raw": raw.reshape(len(ep), -1)}


HAND_FEATURES = ("log peak force max", "log peak force mean", "contact fraction mean", "log contact fraction mean",
                 "contact frames", "log impulse", "log force / acceleration", "log object speed mean",
                 "log object speed max", "log object speed first", "log object speed last", "glide decay rate",
                 "glide pair share", "log finger speed mean", "log overlap max", "log peak / overlap^1.5",
                 "action magnitude mean", "log end force mean", "log closing speed")
"""The 19 hand features of a window (:func:`hand_features`): what a physicist reads off a poke."""


def hand_features(f: dict[str, np.ndarray], ep: np.ndarray, t0: np.ndarray, radii: float, dt: float) -> np.ndarray:
    """(W, 19) :data:`HAND_FEATURES` of the 16-frame windows (``ep``, ``t0``) of reference frames ``f``: peak force,
    contact fraction and their contact-frame means (stiffness: Hertz peak force and contact time), impulse and
    force over acceleration (mass: :func:`inertia`), speeds, the median glide decay rate log(|v_t| / |v_t+1|) / dt over
    contact-free frame pairs (drag; 0 and share 0 where there is none), finger speed, the largest disk overlap
    (``radii`` = r_f + r_o) and peak force over overlap^1.5 (Hertz k), action magnitude, end-of-step force and the
    closing speed at the window's first contact."""
    span = t0[:, None] + np.arange(WINDOW)[None]
    g = lambda a: a[ep[:, None], span]  # noqa: E731
    tou, obj, fin, c = g(f["touch"]), g(f["obj"]), g(f["finger"]), g(f["contact"])
    n = np.maximum(c.sum(1), 1)
    lg = lambda x: np.log(np.maximum(x, 1e-6))  # noqa: E731
    cmean = lambda x: (x * c).sum(1) / n  # noqa: E731
    peak, frac = np.maximum(tou[..., 2], 0), tou[..., 5]
    so, sf = np.linalg.norm(obj[..., 2:], axis=-1), np.linalg.norm(fin[..., 2:], axis=-1)
    overlap = np.maximum(radii - np.linalg.norm(obj[..., :2] - fin[..., :2], axis=-1), 0).max(1)
    pairs = ~c[:, :-1] & ~c[:, 1:] & (so[:, :-1] > 0.02) & (so[:, 1:] > 0.02)
    rate = np.where(pairs, np.log(np.maximum(so[:, :-1], 1e-9) / np.maximum(so[:, 1:], 1e-9)) / dt, np.nan)
    has = pairs.any(1)
    decay = np.zeros(len(ep))
    decay[has] = np.nanmedian(rate[has], axis=1)
    first = np.argmax(c, 1)
    before = np.maximum(first - 1, 0)
    rows = np.arange(len(ep))
    closing = np.linalg.norm(fin[rows, before, 2:] - obj[rows, before, 2:], axis=-1)
    cols = [lg(peak.max(1)), lg(cmean(peak)), cmean(frac), lg(cmean(frac)), c.sum(1) / WINDOW,
            lg(np.linalg.norm(tou[..., 0:2].sum(1) * dt, axis=-1)), inertia(tou, obj, c, dt),
            lg(so.mean(1)), lg(so.max(1)), lg(so[:, 0] + 0.01), lg(so[:, -1] + 0.01), decay, pairs.mean(1),
            lg(sf.mean(1)), lg(overlap), lg(peak.max(1)) - 1.5 * lg(overlap),
            np.linalg.norm(g(f["act"]), axis=-1).mean(1), lg(cmean(np.linalg.norm(tou[..., 3:5], axis=-1))), lg(closing)]
    return np.stack(cols, 1)


def inertia(tou: np.ndarray, obj: np.ndarray, c: np.ndarray, dt: float) -> np.ndarray:
    """Median over a window's contact frames after its first of log |mean contact force over the step| − log |the
    object's velocity change over it| / dt: log m up to drag and walls (Newton's second law on each step); 0 where
    the window has no such frame."""
    dv = np.linalg.norm(np.diff(obj[..., 2:], axis=1), axis=-1) / dt
    f = np.linalg.norm(tou[:, 1:, 0:2], axis=-1)
    est = np.where(c[:, 1:], np.log(np.maximum(f, 1e-6)) - np.log(np.maximum(dv, 1e-6)), np.nan)
    has = c[:, 1:].any(1)
    out = np.zeros(len(c))
    out[has] = np.nanmedian(est[has], axis=1)
    return out


def ridge_r2(X_fit: np.ndarray, y_fit: np.ndarray, X_test: np.ndarray, y_test: np.ndarray) -> np.ndarray:
    """Held-out R² per target column: standardised ridge, α from (0.01, 0.1, 1, 10, 100) by the mean R² of the last
    20 % of the fit rows, refit on all of them (the reference's ``ridge_fit_eval``)."""
    mu, sd = X_fit.mean(0), X_fit.std(0) + 1e-6
    A, B = (X_fit - mu) / sd, (X_test - mu) / sd
    ymu, ysd = y_fit.mean(0), y_fit.std(0) + 1e-6
    Y = (y_fit - ymu) / ysd
    cut = int(0.8 * len(A))
    solve = lambda X, y, a: np.linalg.solve(X.T @ X + a * np.eye(X.shape[1]), X.T @ y)  # noqa: E731
    alpha = max((0.01, 0.1, 1.0, 10.0, 100.0),
                key=lambda a: r2(Y[cut:], A[cut:] @ solve(A[:cut], Y[:cut], a)).mean())
    pred = B @ solve(A, Y, alpha) * ysd + ymu
    return r2(y_test, pred)


def r2(y: np.ndarray, pred: np.ndarray) -> np.ndarray:
    return 1 - ((y - pred) ** 2).sum(0) / (((y - y.mean(0)) ** 2).sum(0) + 1e-12)


def labels(ds: Dataset, episodes: np.ndarray) -> np.ndarray:
    return np.stack([ds.params[t][episodes] for t in TARGETS], 1).astype(np.float64)


def corpus_statistics(ds: Dataset) -> dict[str, float]:
    """Every corpus statistic of the side-by-side table, on the store's probe-test split (the ridge fit on its
    probe-fit split): the reference measured its numbers on its 800 probe-test episodes."""
    test, fit = ds.episodes("probe_test"), ds.episodes("probe_fit")
    if len(test) == 0 or len(fit) == 0:
        raise DataError("the fidelity statistics need probe-fit and probe-test episodes; this store has "
                        f"{ds.manifest.get('split_counts')}")
    f = reference_frames(ds)
    ft = {k: v[test] for k, v in f.items()}
    w = windows(ft)
    speed = np.linalg.norm(ft["obj"][..., 2:], axis=-1)
    out = {"static16": float(np.linalg.norm(ft["obj"][:, 31, :2] - ft["obj"][:, 15, :2], axis=-1).mean()),
           "contact_step_fraction": float(ft["contact"].mean()),
           "contact_window_fraction": float((w["contacts"] >= 2).mean()),
           "glide_window_fraction": float(((w["contacts"] == 0) & (w["speed"] > 0.15)).mean()),
           "object_speed_p99": float(np.percentile(speed, 99)),
           "first_frame_moving": float((speed[:, 0] > 0.01).mean()),
           "contact_windows": int((w["contacts"] >= 2).sum()), "moving_windows": int((w["speed"] > 0.15).sum())}
    onsets = contact.impact_speeds({k: v[test] for k, v in ds.labels.items()})
    out["impact_speed_median"] = float(np.median(onsets)) if onsets.size else float("nan")
    out.update(ridges(ds, f, fit, test))
    return out


def ridges(ds: Dataset, f: dict[str, np.ndarray], fit: np.ndarray, test: np.ndarray) -> dict[str, float]:
    """Ridge R² of log m, γ, log k on contact windows, fit on ``fit`` episodes and scored on ``test`` ones, from the
    19 hand features (``ridge_*``) and from the reference's flattened raw window (``raw_ridge_*``)."""
    phys = ds.manifest.get("config", {}).get("physics", {})
    radii = phys.get("finger_radius", 0.06) + phys.get("object_radius", 0.09)
    sets = {}
    for name, eps in (("fit", fit), ("test", test)):
        sub = {k: v[eps] for k, v in f.items()}
        w = windows(sub)
        keep = w["contacts"] >= 2
        hand = hand_features(sub, w["episode"][keep], np.tile(STARTS, len(eps))[keep], radii, phys.get("dt", 0.05))
        sets[name] = (hand, w["raw"][keep], labels(ds, eps[w["episode"][keep]]))
    out = {}
    for prefix, col in (("ridge", 0), ("raw_ridge", 1)):
        if min(len(sets["fit"][2]), len(sets["test"][2])) < MIN_WINDOWS:
            out.update({f"{prefix}_{t}": float("nan") for t in TARGETS})
            continue
        r = ridge_r2(sets["fit"][col], sets["fit"][2], sets["test"][col], sets["test"][2])
        out.update({f"{prefix}_{t}": float(v) for t, v in zip(TARGETS, r)})
    return out


def restitutions(physics: PhysicsConfig) -> dict[str, float]:
    """Head-on restitution of ``physics``'s contact law alone at the three stiffnesses (module docstring)."""
    law_alone = dataclasses.replace(physics, finger_damping=0.0)
    e = contact.restitution(law_alone, np.array(RESTITUTION_K), RESTITUTION_M, RESTITUTION_V, gamma=0.0)
    return {f"restitution_k{int(k)}": float(v) for k, v in zip(RESTITUTION_K, e)}


def verdicts(stats: dict[str, float]) -> dict[str, dict]:
    """Each statistic beside the reference's value and whether it lies within its tolerance."""
    return {name: {"ours": stats[name], "reference": ref, "tolerance": tol,
                   "pass": bool(abs(stats[name] - ref) <= tol + 1e-12)}
            for name, (ref, tol) in REFERENCE.items() if name in stats}


__all__ = ["WINDOW", "STARTS", "REFERENCE", "CALIBRATED_ISSUE", "HAND_FEATURES", "hand_features", "ridges",
           "reference_frames", "windows", "ridge_r2",
           "corpus_statistics", "restitutions", "verdicts"]
