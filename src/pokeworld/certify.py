"""Recoverability certificates and the certificate gate (paper §3, App. A).

Each hidden parameter must be certified recoverable from raw observation
windows before any model probe is interpreted. Estimators, each fit on
probe-fit episodes and scored by held-out R^2 on probe-test episodes:

* ``gru``     2-layer GRU (width 96) over raw windows: proprio, touch, actions, object state;
* ``linear``  ridge (episode-grouped CV) on the flattened raw window;
* ``mlp``     early-stopped MLP on the flattened raw window;
* ``drag``    physics-informed drag estimator: median log speed ratio over the
              window's glide frames (no fitting; population median where a window has none);
* ``gru_pixel`` / ``drag_pixel``: the same with object state replaced by pixel
              centroids (finger disk masked using proprioception, 3-frame smoothing);
* ``gru_geom``  the GRU with the contact geometry made explicit: the object-minus-finger
              displacement and the disk overlap, computed from the same raw observations.
              Penetration depth under a known contact force is how stiffness shows in
              kinematics (quasi-static d = (F/k)^(2/3)); a GRU fed absolute positions does
              not learn that millimetre-scale difference from a few thousand windows;
* ``gru_notouch`` ``gru_geom`` without the touch channels: what a model whose inputs are
              vision and proprioception could know at best (the bound of the vision-input arms);
* ``gru_pixel_notouch`` the same from pixel-derived object state (optionally at a model's
              smaller ``pixel_size``): the vision-input bound without privileged object state.
* ``linear_logspeed`` the linear certificate in the sensed log-speed coordinate (the coordinate test,
              App. C): ridge from the window's log-speed sequence to γ, on stores that carry a
              ``log_speed`` proprio channel (the ``flow`` corpus); skipped elsewhere.

A parameter's certificate is the best R^2 of any estimator on contact
windows. The gate is the paper's rule (App. A, "The oracle estimator"): the
GRU oracle must reach log m / gamma / log k >= 0.4 / 0.4 / 0.25 on contact
windows. The best-estimator certificate is reported beside it, with a note
whenever the two verdicts disagree; only the paper's rule licenses a claim.
"""

from __future__ import annotations

import functools
import itertools
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import certificate_corpus
from .config import SEED, Limit, check_fields, from_preset, to_dict
from .data import Dataset, load
from .errors import ConfigError, DataError
from .io import adopt_legacy, check_outputs, read_json, read_json_if_present, write_json
from .models.xjepa import area_downsample
from .progress import heartbeat, report, stage
from .regressors import RidgeCV, TorchRegressor, r2_scores
from .windows import Windows, make_windows, wall_contact

GATES = {"log_m": 0.4, "gamma": 0.4, "log_k": 0.25}
GATE_ESTIMATOR = "gru"  # the paper's oracle: the gate reads this estimator, not the best one
ESTIMATORS = ("gru", "gru_geom", "linear", "mlp", "drag", "gru_pixel", "drag_pixel", "gru_notouch",
              "gru_pixel_notouch", "linear_logspeed")
DEFAULT_ESTIMATORS = tuple(e for e in ESTIMATORS if e != "linear_logspeed")  # that one needs a flow corpus
GEOMETRY = ("gru_geom", "gru_notouch", "gru_pixel_notouch")  # estimators fed the contact-geometry channels
# feature columns of window_features: proprio 0-3, touch 4-10, action 11-12, object position 13-14,
# velocity 15-16, and with geometry=True the displacement object - finger 17-18 and the overlap 19
TOUCH_COLUMNS = range(4, 11)
NO_TOUCH = [i for i in range(20) if i not in TOUCH_COLUMNS]


@dataclass
class CertifyConfig:
    """Certify hidden parameters recoverable from raw observations."""

    data: str = "data/pokeworld"
    """Dataset directory (``pokeworld generate`` output)."""
    out: str = ""
    """Where to write certificates.json (default: <data>/certificates.json)."""
    targets: tuple[str, ...] = ("log_m", "gamma", "log_k")
    """Per-episode parameters to certify (names under params/ in the store)."""
    estimators: tuple[str, ...] = DEFAULT_ESTIMATORS
    """Estimators to run (subset of ESTIMATORS: gru, gru_geom, linear, mlp, drag, gru_pixel, drag_pixel,
    gru_notouch, gru_pixel_notouch, linear_logspeed; the last only on stores with a log-speed channel)."""
    pixel_size: int = 0
    """Frame side the pixel-derived estimators read (frames area-pooled to it first; 0 = stored size).
    Set it to a model's ``image_size`` to bound what that model's input resolution reveals."""
    kinds: tuple[str, ...] = ("contact", "glide")
    """Window kinds to evaluate on (the gate reads contact windows)."""
    window: int = 16
    """Window length in observations."""
    stride: int = 4
    """Step between window starts."""
    max_windows: int = 6000
    """Cap on fit windows per kind (random episode-preserving subsample) to bound CPU time."""
    fit_episodes: int = 0
    """Fit the estimators on a certificate corpus of this many episodes of the store's own generator on disjoint
    seeds (``<data>/certificate_corpus/n<fit_episodes>``, generated once; pokeworld.certificate_corpus) instead of the store's
    probe-fit split (0); scored on the store's probe-test episodes either way."""
    gru_hidden: int = 96
    """GRU width."""
    gru_layers: int = 2
    """GRU depth."""
    epochs: int = 150
    """Maximum epochs for the neural estimators (early stopping usually ends sooner)."""
    patience: int = 12
    """Early-stopping patience in epochs."""
    seed: int = 0
    """Seed for estimator initialisation and subsampling."""
    separate_targets: bool = True
    """Fit each estimator once per target (as the model probes are fit) rather than once for all targets.
    A joint fit shares one early stop (neural) or one ridge penalty (linear) across targets, which cuts a
    slow, low-variance target short: on the ±0.5 bias corpus the joint GRU reads bias 0.06, per-target 0.8."""

    LIMITS = {"pixel_size": Limit(0, 1024), "window": Limit(3, 4096), "stride": Limit(1, 4096),
              "max_windows": Limit(1, 10**8), "fit_episodes": Limit(0, 10**6), "gru_hidden": Limit(1, 8192),
              "gru_layers": Limit(1, 64), "epochs": Limit(1, 10**5), "patience": Limit(1, 10**5), "seed": SEED}

    def __post_init__(self) -> None:
        check_fields(self)
        bad = set(self.estimators) - set(ESTIMATORS)
        if bad:
            raise ConfigError(f"unknown estimators {sorted(bad)}; choose from {list(ESTIMATORS)}")
        if not set(self.kinds) <= {"contact", "glide", "all"}:
            raise ConfigError(f"kinds must be among contact, glide, all; got {self.kinds}")
        if self.window < 3 or self.stride < 1:
            raise ConfigError("window must be >= 3 and stride >= 1")
        if self.fit_episodes < 0 or self.max_windows < 1:
            raise ConfigError(f"fit_episodes must be >= 0 and max_windows >= 1, got {self.fit_episodes}, "
                              f"{self.max_windows}")
        if self.pixel_size < 0 or 0 < self.pixel_size < 8:
            raise ConfigError(f"pixel_size must be 0 (stored size) or >= 8, got {self.pixel_size}")


PRESETS = {
    # the cpu preset's three estimators at smoke-test sizes: a newcomer's tiny run should show what cpu will
    "tiny": {"epochs": 4, "patience": 2, "max_windows": 400, "gru_hidden": 32, "estimators": ("gru", "linear", "drag")},
    # the gate's instruments (GRU oracle, linear floor, drag) on contact windows, fit on a 1,920-episode
    # certificate corpus with every window kept: where the GRU oracle's γ stops being fit-set limited
    # (docs/results/certificate_fit_curve_cpu.md); the other estimators are one --estimators away
    "cpu": {"fit_episodes": 1920, "max_windows": 30000, "estimators": ("gru", "linear", "drag"),
            "kinds": ("contact",)},
    "paper": {"fit_episodes": 3840, "max_windows": 100000, "epochs": 300, "patience": 20},
}


def make_config(preset: str = "cpu", **overrides) -> CertifyConfig:
    return from_preset(CertifyConfig, PRESETS, preset, **overrides)


# --------------------------------------------------------------------------- observables
def pixel_object_state(ds: Dataset, episodes: np.ndarray, smooth: int = 3,
                       size: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Object position and velocity estimated from pixels for whole episodes: (E', T+1, 2) each.

    The finger disk (known from proprioception) is masked out with a one-pixel
    margin; the object is the intensity-weighted centroid of what remains (on frames area-pooled
    to ``size`` × ``size`` when ``size`` is set);
    positions are smoothed with a centred moving average of ``smooth`` frames
    and velocities are central differences of the smoothed track.
    """
    cfg = ds.manifest.get("config", {}).get("physics", {})
    arena, rf = cfg.get("arena", 1.0), cfg.get("finger_radius", 0.06)
    dt = cfg.get("dt", 0.05)
    frames = ds.frames[episodes]
    if size and size != frames.shape[-1]:

        import torch

        frames = area_downsample(torch.from_numpy(np.ascontiguousarray(frames)), size).numpy()
    frames = frames.astype(np.float32)
    E, T1, H, W = frames.shape
    xs = (np.arange(W) + 0.5) * arena / W
    ys = (np.arange(H) + 0.5) * arena / H
    fp = ds.proprio[episodes, :, 0:2]
    dx = xs[None, None, None, :] - fp[..., 0, None, None]
    dy = ys[None, None, :, None] - fp[..., 1, None, None]
    mask = dx**2 + dy**2 > (rf + 1.5 * arena / W) ** 2
    img = frames * mask
    mass = img.sum((2, 3))
    pos = np.stack([(img * xs[None, None, None, :]).sum((2, 3)), (img * ys[None, None, :, None]).sum((2, 3))], -1)
    pos = pos / np.maximum(mass, 1e-6)[..., None]
    # frames where the finger hides the object entirely: carry the last estimate forward
    for t in range(1, T1):
        lost = mass[:, t] < 1e-3
        pos[lost, t] = pos[lost, t - 1]
    if smooth > 1:
        k = np.ones(smooth) / smooth
        pad = np.pad(pos, ((0, 0), (smooth // 2, smooth // 2), (0, 0)), mode="edge")
        pos = np.stack([np.apply_along_axis(np.convolve, 1, pad[..., i], k, "valid") for i in range(2)], -1)
    vel = np.gradient(pos, dt, axis=1)
    return pos.astype(np.float32), vel.astype(np.float32)


def window_features(ds: Dataset, w: Windows, object_pos: np.ndarray, object_vel: np.ndarray,
                    geometry: bool = False) -> np.ndarray:
    """Raw per-step features (W, L, 17): proprio 4, touch 7, action 2, object position 2, velocity 2.

    ``geometry=True`` appends the contact geometry (W, L, 3): displacement object - finger (2) and the
    disk overlap max(0, r_f + r_o - distance) in units of the object radius (1).
    """
    actions = np.concatenate([ds.actions, np.zeros_like(ds.actions[:, :1])], 1)
    # finger position and velocity only: derived corpora (flow) append sensed channels after them, and the
    # column layout below (TOUCH_COLUMNS, NO_TOUCH) must not shift
    proprio, obj = w.gather(ds.proprio[..., :4]), w.gather(object_pos)
    cols = [proprio, w.gather(ds.touch), w.gather(actions), obj, w.gather(object_vel)]
    if geometry:
        cfg = ds.manifest.get("config", {}).get("physics", {})
        rf, ro = cfg.get("finger_radius", 0.06), cfg.get("object_radius", 0.09)
        rel = obj - proprio[..., 0:2]
        overlap = np.maximum(rf + ro - np.linalg.norm(rel, axis=-1, keepdims=True), 0.0) / ro
        cols += [rel, overlap]
    return np.concatenate(cols, -1).astype(np.float32)


def drag_estimates(speed: np.ndarray, glide: np.ndarray, dt: float, fallback: float,
                   min_speed: float = 0.02) -> np.ndarray:
    """Median over glide frame pairs of log(|v_t| / |v_t+1|) / dt, per window.

    ``speed`` (W, L) object speeds and ``glide`` (W, L-1) marks frame pairs with no
    finger or wall contact. Windows without a usable pair get ``fallback``.
    """
    ok = usable_glide_pairs(speed, glide, min_speed)
    rate = np.log(np.maximum(speed[:, :-1], 1e-9) / np.maximum(speed[:, 1:], 1e-9)) / dt
    rate = np.where(ok, rate, np.nan)
    out = np.full(len(speed), fallback, dtype=float)
    has = ok.any(1)
    if has.any():
        out[has] = np.nanmedian(rate[has], axis=1)
    return out


def usable_glide_pairs(speed: np.ndarray, glide: np.ndarray, min_speed: float = 0.02) -> np.ndarray:
    """The frame pairs (W, L-1) the drag estimator reads: glide pairs (``glide``: no finger or wall contact at either
    end) with both speeds above ``min_speed``, where the log-ratio of speeds is not noise."""
    if speed.ndim != 2 or glide.shape != (speed.shape[0], speed.shape[1] - 1):
        raise DataError(f"speed (W, L) and glide (W, L-1) expected, got {speed.shape}, {glide.shape}")
    return glide & (speed[:, :-1] > min_speed) & (speed[:, 1:] > min_speed)


def drag_prediction(ds: Dataset, w: Windows, vel: np.ndarray, y_fit: np.ndarray, dt: float
                    ) -> tuple[np.ndarray, np.ndarray]:
    """The drag estimator's γ for each window of ``w`` (object velocities ``vel`` (E, T+1, 2)) and which windows
    hold a usable glide pair. The only thing it learns from the fit windows' γ (``y_fit``) is their median, the
    estimate of a window without a usable pair, and their support, which bounds wild ratios from noisy (pixel)
    speeds."""
    speed = np.linalg.norm(w.gather(vel), axis=-1)
    glide = glide_pairs(ds, w)
    pred = drag_estimates(speed, glide, dt, float(np.median(y_fit)))
    return np.clip(pred, y_fit.min(), y_fit.max()), usable_glide_pairs(speed, glide).any(1)


def drag_coverage(pred: np.ndarray, has_pair: np.ndarray, y: np.ndarray) -> dict:
    """Where the drag certificate's R² comes from: the share of windows with a usable glide pair, the R² on those
    and on the rest (each against its own spread; None with fewer than two windows), and ``r2_lost_without``, the
    part of 1 − R² (of the whole) that the windows without a pair account for."""
    var = float(np.sum((y - y.mean()) ** 2))

    def part(mask: np.ndarray) -> float | None:
        if mask.sum() < 2 or np.ptp(y[mask]) == 0:
            return None
        return float(1.0 - np.sum((y[mask] - pred[mask]) ** 2) / np.sum((y[mask] - y[mask].mean()) ** 2))

    lost = float(np.sum((y[~has_pair] - pred[~has_pair]) ** 2) / var) if var > 0 else None
    return {"windows": int(len(y)), "with_glide_pair": float(has_pair.mean()) if len(y) else 0.0,
            "r2_with_glide_pair": part(has_pair), "r2_without": part(~has_pair), "r2_lost_without": lost}


def linear_sequence_r2(X_fit: np.ndarray, y_fit: np.ndarray, groups: np.ndarray, X_test: np.ndarray,
                       y_test: np.ndarray) -> float:
    """Held-out R^2 of ridge (episode-grouped CV) from a per-window sequence (W, L[, D]) to a scalar target.

    The linear certificate of a coordinate: on pure glides log|v_t| = log|v_0| - γ t dt, so γ is a linear
    functional of the log-speed sequence (its negated least-squares slope) and this certificate can read it,
    while in plain speed the same trace is a ratio.
    """
    model = RidgeCV().fit(X_fit.reshape(len(X_fit), -1), np.asarray(y_fit, float).reshape(-1, 1), groups)
    pred = model.predict(X_test.reshape(len(X_test), -1))
    return float(r2_scores(np.asarray(y_test, float).reshape(-1, 1), pred)[0])


def log_speed_channel(ds: Dataset) -> np.ndarray | None:
    """The store's sensed log-speed channel (E, T+1), when it has one (``manifest["proprio_channels"]``
    names ``log_speed``: a derived corpus such as ``flow``), else None."""
    names = ds.manifest.get("proprio_channels", [])
    if "log_speed" not in names:
        return None
    return ds.proprio[..., names.index("log_speed")]


def glide_pairs(ds: Dataset, w: Windows) -> np.ndarray:
    """Frame pairs (W, L-1) of ``w`` with no finger or wall contact at either end."""
    contact = w.gather(ds.labels["contact"]) > 0
    walls = w.gather(wall_contact(ds))
    free = ~(contact | walls)
    return free[:, :-1] & free[:, 1:]


# --------------------------------------------------------------------------- main
def fit_targets(make, X_fit: np.ndarray, Y_fit: np.ndarray, groups: np.ndarray, X_test: np.ndarray,
                separate: bool) -> np.ndarray:
    """Fit ``make()`` on (X_fit, Y_fit) and predict X_test: one model for all columns of Y_fit, or one per
    column when ``separate``. Returns (len(X_test), Y_fit.shape[1])."""
    if not separate or Y_fit.shape[1] == 1:
        return make().fit(X_fit, Y_fit, groups).predict(X_test).reshape(len(X_test), -1)
    return np.column_stack([make().fit(X_fit, Y_fit[:, [j]], groups).predict(X_test).reshape(-1)
                            for j in range(Y_fit.shape[1])])


def observed_state(ds: Dataset, episodes: np.ndarray, pixels: bool, pixel_size: int) -> dict:
    """Object position and velocity the estimators read: ``state`` (the simulator's labels) and, when
    ``pixels``, ``pixel`` (:func:`pixel_object_state`, filled for ``episodes`` only)."""
    state = {"state": (ds.labels["object_pos"], ds.labels["object_vel"])}
    if pixels:
        pos = np.zeros_like(ds.labels["object_pos"])
        vel = np.zeros_like(ds.labels["object_vel"])
        for i in range(0, episodes.size, 256):
            chunk = episodes[i:i + 256]
            pos[chunk], vel[chunk] = pixel_object_state(ds, chunk, size=pixel_size)
        state["pixel"] = (pos, vel)
    return state


def epoch_reporting(make, stage_name: str, fits: int, cfg: CertifyConfig):
    """``make`` with its regressors reporting their epochs as ``stage_name``'s progress to a whole job's estimate
    (:func:`pokeworld.progress.report`), so the estimate times the stage by its own epochs: the ``i``-th of ``fits``
    fits is done by its epochs over the fewest it can still take (early stopping ends it no sooner than
    ``patience`` epochs after its best validation loss, and no later than ``cfg.epochs``)."""
    made = itertools.count()

    def reporting():
        i = next(made)

        def on_epoch(epoch: int, stale: int) -> None:
            fewest = min(cfg.epochs, epoch + cfg.patience - stale)
            report(stage_name, (i + epoch / fewest) / fits)

        return make(on_epoch=on_epoch)

    return reporting


def _estimator_r2(est: str, ds: Dataset, fit_ds: Dataset, cfg: CertifyConfig, windows, targets, states,
                  dt: float, stage_name: str = "", extras: dict | None = None) -> dict[str, float] | None:
    """One estimator's held-out R² per target on one window kind (None when it does not apply to this store);
    a neural estimator reports its epochs as ``stage_name``'s progress (:func:`epoch_reporting`). A drag
    estimator also puts its :func:`drag_coverage` into ``extras["drag_coverage"]`` (from the same prediction)."""
    w_fit, w_test = windows
    y_fit, y_test = targets
    fit_state, test_state = states
    source = "pixel" if "_pixel" in est else "state"
    (pos_fit, vel_fit), (pos, vel) = fit_state[source], test_state[source]
    if est == "linear_logspeed":
        channel, fit_channel = log_speed_channel(ds), log_speed_channel(fit_ds)
        if channel is None or fit_channel is None or "gamma" not in cfg.targets:
            print(f"[certify] {est}: this store has no log_speed channel (or gamma is not a target); skipping")
            return None
        g_idx = cfg.targets.index("gamma")
        r2 = {"gamma": linear_sequence_r2(w_fit.gather(fit_channel), y_fit[:, g_idx], w_fit.episode,
                                          w_test.gather(channel), y_test[:, g_idx])}
    elif est.startswith("drag"):
        if "gamma" not in cfg.targets:
            return None
        g_idx = cfg.targets.index("gamma")
        pred, has_pair = drag_prediction(ds, w_test, vel, y_fit[:, g_idx], dt)
        r2 = {"gamma": float(r2_scores(y_test[:, g_idx], pred)[0])}
        if extras is not None:
            extras["drag_coverage"] = drag_coverage(pred, has_pair, y_test[:, g_idx])
    else:
        geometry = est in GEOMETRY
        X_fit = window_features(fit_ds, w_fit, pos_fit, vel_fit, geometry)
        X_test = window_features(ds, w_test, pos, vel, geometry)
        if est.endswith("_notouch"):
            X_fit, X_test = X_fit[..., NO_TOUCH], X_test[..., NO_TOUCH]
        if est == "linear":
            X_fit, X_test = X_fit.reshape(len(X_fit), -1), X_test.reshape(len(X_test), -1)
            make = RidgeCV
        else:
            arch = "mlp" if est == "mlp" else "gru"
            kw = dict(hidden=cfg.gru_hidden, layers=cfg.gru_layers) if arch == "gru" else {}
            make = functools.partial(TorchRegressor, arch, epochs=cfg.epochs, patience=cfg.patience,
                                     seed=cfg.seed, **kw)
            make = epoch_reporting(make, stage_name, len(cfg.targets) if cfg.separate_targets else 1, cfg)
        pred = fit_targets(make, X_fit, y_fit, w_fit.episode, X_test, cfg.separate_targets)
        r2 = {t: float(v) for t, v in zip(cfg.targets, r2_scores(y_test, pred))}
    return r2


def _certify_kinds(ds: Dataset, fit_ds: Dataset, cfg: CertifyConfig, episodes, states, params, dt: float,
                   rng: np.random.Generator, results: dict, now: dict) -> None:
    """Every estimator on every window kind, into ``results`` (``now["what"]``: what is being fit, for the
    heartbeat)."""
    fit_eps, test_eps = episodes
    fit_state, test_state = states
    Y_fit_all, Y_test_all = params
    own = fit_ds is ds
    for kind in cfg.kinds:
        available = make_windows(fit_ds, fit_eps, cfg.window, cfg.stride).kind(kind)
        w_fit = available.subsample(cfg.max_windows, rng)
        w_test = make_windows(ds, test_eps, cfg.window, cfg.stride).kind(kind)
        results["counts"][kind] = {"fit": len(w_fit), "fit_available": len(available), "test": len(w_test)}
        if cfg.fit_episodes and len(w_fit) < len(available):
            results["warnings"].append(capped_corpus_warning(kind, len(w_fit), len(available), cfg))
            print(f"[certify] warning: {results['warnings'][-1]}")
        if len(w_fit) < 10 or len(w_test) < 10:
            print(f"[certify] too few {kind} windows ({len(w_fit)} fit / {len(w_test)} test); skipping")
            continue
        assert not own or not np.intersect1d(w_fit.episode, w_test.episode).size
        y_fit, y_test = Y_fit_all[w_fit.episode], Y_test_all[w_test.episode]
        for i, est in enumerate(cfg.estimators):
            now["what"] = f"{est} on {kind} windows ({len(w_fit)} fit / {len(w_test)} test; estimator {i + 1} of " \
                          f"{len(cfg.estimators)})"
            name = certify_stage(cfg.data, kind, est)
            extras: dict = {}
            with stage(name, "certify"):  # a whole job's estimate hears of it
                r2 = _estimator_r2(est, ds, fit_ds, cfg, (w_fit, w_test), (y_fit, y_test), (fit_state, test_state),
                                   dt, name, extras)
            if r2 is None:
                continue
            results["estimators"].setdefault(est, {})[kind] = r2
            print(f"[certify] {kind:8s} {est:11s} " + " ".join(f"{t}={v:+.3f}" for t, v in r2.items()), flush=True)
            if "drag_coverage" in extras:  # what its R² is made of: the windows that hold a glide, and the rest
                cov = results.setdefault("drag_coverage", {}).setdefault(est, {})[kind] = extras["drag_coverage"]
                print(f"[certify] {kind:8s} {est:11s} {drag_coverage_line(cov)}", flush=True)


def drag_coverage_line(cov: dict) -> str:
    """:func:`drag_coverage` in words."""
    def num(v: float | None) -> str:
        return "—" if v is None else f"{v:.2f}"

    return (f"{cov['with_glide_pair']:.0%} of {cov['windows']} windows hold a usable glide pair (R² "
            f"{num(cov['r2_with_glide_pair'])} there); the rest take the fit windows' median (R² "
            f"{num(cov['r2_without'])}, {num(cov['r2_lost_without'])} of the whole's 1 − R²)")


def certify_stage(data: str, kind: str, estimator: str) -> str:
    """The name of one estimator's fit as a stage of a whole job (:func:`pokeworld.progress.stage`)."""
    return f"certificate {estimator} ({Path(data).name}, {kind} windows)"


def certify(ds: Dataset, cfg: CertifyConfig, fit_ds: Dataset | None = None) -> dict:
    """Run every requested estimator; return the certificates dictionary.

    Estimators are fit on ``fit_ds``'s probe-fit episodes (the store's own when None; the first
    ``cfg.fit_episodes`` of them when set) and scored on ``ds``'s probe-test episodes.
    """
    missing = [t for t in cfg.targets if t not in ds.params]
    if missing:
        raise DataError(f"targets {missing} are not in this dataset's params ({sorted(ds.params)})")
    for lab in ("contact", "object_pos", "object_vel"):
        if lab not in ds.labels:
            raise DataError(f"certificates need labels/{lab} (a simulator corpus)")
    own = fit_ds is None
    fit_ds = ds if own else fit_ds
    fit_eps, test_eps = fit_ds.episodes("probe_fit"), ds.episodes("probe_test")
    if cfg.fit_episodes:
        if fit_eps.size < cfg.fit_episodes:
            raise DataError(f"fit_episodes={cfg.fit_episodes} but the fit corpus holds only {fit_eps.size} "
                            "probe-fit episodes")
        fit_eps = fit_eps[:cfg.fit_episodes]
    if own and np.intersect1d(fit_eps, test_eps).size:
        raise DataError("probe-fit and probe-test episodes overlap")
    rng = np.random.default_rng(cfg.seed)
    dt = ds.manifest.get("config", {}).get("physics", {}).get("dt", 0.05)
    pixels = any("_pixel" in e for e in cfg.estimators)
    if own:  # one pass over the store's probe episodes, as before the certificate corpus existed
        fit_state = test_state = observed_state(ds, np.concatenate([fit_eps, test_eps]), pixels, cfg.pixel_size)
    else:
        fit_state = observed_state(fit_ds, fit_eps, pixels, cfg.pixel_size)
        test_state = observed_state(ds, test_eps, pixels, cfg.pixel_size)
    Y_fit_all = np.stack([fit_ds.params[t] for t in cfg.targets], 1).astype(np.float64)
    Y_test_all = np.stack([ds.params[t] for t in cfg.targets], 1).astype(np.float64)
    results: dict = {"estimators": {}, "counts": {}, "warnings": []}
    now = {"what": "preparing windows"}
    with heartbeat("certify", lambda: now["what"]):
        _certify_kinds(ds, fit_ds, cfg, (fit_eps, test_eps), (fit_state, test_state), (Y_fit_all, Y_test_all), dt,
                       rng, results, now)
    results["certificate"] = certificate_table(results["estimators"], cfg.targets)
    results["gate"] = gate(results["certificate"], results["estimators"])
    results["config"] = to_dict(cfg)
    results["dataset"] = {"path": cfg.data, "content_sha256": ds.manifest.get("content_sha256"),
                          "corpus": ds.manifest.get("corpus")}
    results["fit_corpus"] = ({"source": "store probe-fit split", "episodes": int(fit_eps.size)} if own else
                             {"source": "certificate corpus", "episodes": int(fit_eps.size),
                              "seed": fit_ds.manifest.get("seed"),
                              "content_sha256": fit_ds.manifest.get("content_sha256")})
    return results


def capped_corpus_warning(kind: str, kept: int, available: int, cfg: CertifyConfig) -> str:
    """Why a window cap on a certificate corpus matters: the corpus exists so that the GRU oracle is not fit-set
    limited, and a cap below its window count brings that limit back (docs/design.md, "Certificates")."""
    return (f"max_windows={cfg.max_windows} keeps {kept} of the {cfg.fit_episodes}-episode certificate corpus's "
            f"{available} {kind} windows: the certificate may be fit-set limited again (the GRU oracle's gamma "
            f"rises with the fit windows); raise --max-windows to at least {available} for a certificate at the "
            "plateau")


def certificate_table(estimators: dict, targets) -> dict:
    """Best R^2 per target and window kind over all estimators, with the winning estimator's name."""
    out: dict = {}
    for est, kinds in estimators.items():
        for kind, r2 in kinds.items():
            for t, v in r2.items():
                cur = out.setdefault(kind, {}).get(t)
                if cur is None or v > cur["r2"]:
                    out[kind][t] = {"r2": v, "estimator": est}
    return out


def gate(certificate: dict, estimators: dict | None = None, gates: dict[str, float] | None = None,
         kind: str = "contact") -> dict:
    """Gate verdict per gated parameter on ``kind`` windows (contact: the paper's gate).

    ``gates`` maps each gated quantity to its threshold (default :data:`GATES`, PokeWorld's three parameters);
    a store without contact labels (an swm factor dataset, :mod:`pokeworld.swm.factor_gate`) gates on "all".

    ``passed``: the best-estimator certificate (``certificate`` R^2, from ``estimator``) reaches
    ``threshold``: some estimator recovers the parameter from raw observations, which is what the gate
    must establish before a model null can be read. Beside it the paper's rule, ``paper_rule_passed``:
    the ``gru`` oracle's contact-window R^2 (``oracle``; None when it was not run) reaches the threshold.
    ``agree`` is False when the two verdicts differ and ``note`` says so in words.
    """
    contact = certificate.get(kind, {})
    oracle_r2 = (estimators or {}).get(GATE_ESTIMATOR, {}).get(kind, {})
    out = {}
    for t, thr in (GATES if gates is None else gates).items():
        best, oracle = contact.get(t), oracle_r2.get(t)
        if best is None and oracle is None:
            continue
        paper = oracle is not None and oracle >= thr
        entry = {"threshold": thr, "rule": f"best estimator R^2 on {kind} windows >= {thr}",
                 "paper_rule": f"{GATE_ESTIMATOR} oracle R^2 on {kind} windows >= {thr}",
                 "oracle": oracle, "paper_rule_passed": paper}
        if best is not None:
            entry.update(certificate=best["r2"], estimator=best["estimator"], passed=best["r2"] >= thr)
        else:
            entry["passed"] = paper
        entry["agree"] = entry["passed"] == paper
        entry["note"] = gate_note(entry)
        out[t] = entry
    return out


def gate_note(g: dict) -> str:
    """One sentence on a gate entry: the verdict, its basis, and the paper's rule when it disagrees."""
    thr = g["threshold"]
    oracle = ("the GRU oracle was not run" if g.get("oracle") is None else
              f"GRU oracle {g['oracle']:.2f} {'>=' if g['paper_rule_passed'] else '<'} {thr:.2f}")
    best = (f"best estimator {g['estimator']} {g['certificate']:.2f} {'>=' if g['passed'] else '<'} {thr:.2f}"
            if "certificate" in g else "no certificate")
    if g["passed"] and g["paper_rule_passed"]:
        return f"passes: {best}; the paper's rule passes too ({oracle})"
    if g["passed"]:
        return f"certified only through the {g['estimator']} estimator ({g['certificate']:.2f}); " \
               f"the paper's GRU-oracle rule fails ({oracle})"
    return f"fails: {best}; {oracle}"


def gate_of(results: dict) -> dict:
    """The gate of a certificates dict, recomputed when it was stored by an older version of :func:`gate`
    (entries without ``paper_rule_passed``)."""
    stored = results.get("gate", {})
    if stored and all("paper_rule_passed" in g for g in stored.values()):
        return stored
    if "certificate" not in results:
        return stored
    return gate(results["certificate"], results.get("estimators", {}))


def format_table(results: dict) -> str:
    """Plain-text table of estimator x (kind, target) R^2 with the gate rows (paper rule and best estimator)."""
    lines = []
    for kind in ("contact", "glide", "all"):
        rows = {e: k[kind] for e, k in results["estimators"].items() if kind in k}
        if not rows:
            continue
        targets = sorted({t for r in rows.values() for t in r})
        lines.append(f"{kind} windows ({results['counts'][kind]['fit']} fit / {results['counts'][kind]['test']} test)")
        lines.append(f"  {'estimator':12s}" + "".join(f"{t:>10s}" for t in targets))
        for est, r2 in rows.items():
            lines.append(f"  {est:12s}" + "".join(f"{r2[t]:>10.3f}" if t in r2 else f"{'-':>10s}" for t in targets))
    for est, kinds in results.get("drag_coverage", {}).items():
        for kind, cov in kinds.items():
            lines.append(f"{est} on {kind} windows: {drag_coverage_line(cov)}")
    for t, g in gate_of(results).items():
        # print the comparison that holds (0.2 < 0.4 -> FAIL), as the protocol report does
        best = (f"{g['estimator']} {g['certificate']:.3f} {'>=' if g['passed'] else '<'} {g['threshold']}"
                if "certificate" in g else f"none < {g['threshold']}")
        oracle = ("not run" if g["oracle"] is None else
                  f"{g['oracle']:.3f} {'>=' if g['paper_rule_passed'] else '<'} {g['threshold']}")
        line = (f"gate {t}: best estimator {best} -> {'PASS' if g['passed'] else 'FAIL'} "
                f"(paper's rule: GRU oracle {oracle} -> {'PASS' if g['paper_rule_passed'] else 'FAIL'})")
        if not g["agree"]:
            line += f"; NOTE: {g['note']}"
        lines.append(line)
    return "\n".join(lines)


def run(cfg: CertifyConfig) -> Path:
    """Certify the dataset at ``cfg.data`` and write ``certificates.json``; skip if already done."""
    out = Path(cfg.out) if cfg.out else Path(cfg.data) / "certificates.json"
    ds = load(cfg.data)
    prev = read_json_if_present(out, "a certificate record (certificates.json)")
    if isinstance(prev, dict) and "certificate" in prev:  # ours, from before ownership records: replaceable
        adopt_legacy(out.parent, [out.name])
    check_outputs(out.parent, out.name)  # a user's file under that name is refused before hours of fitting
    if prev is not None:
        if prev.get("config") == to_dict(cfg) and prev.get("dataset", {}).get("content_sha256") == \
                ds.manifest.get("content_sha256"):
            print(format_table(prev))
            print(f"[certify] {out} is up to date; skipping")
            return out
    fit_ds = certificate_corpus.ensure(ds, cfg.data, cfg.fit_episodes) if cfg.fit_episodes else None
    results = certify(ds, cfg, fit_ds)
    write_json(out, results)
    print(format_table(results))
    print(f"[certify] wrote {out}")
    return out


def load_gate(path: str | Path) -> dict:
    """Read the gate verdicts from a certificates.json (raises DataError when absent)."""
    path = Path(path)
    if not os.path.lexists(path):
        raise DataError(f"no certificates at {path}; run `pokeworld certify` first")
    return gate_of(read_json(path, "a certificate record (certificates.json)"))


__all__ = ["CertifyConfig", "PRESETS", "GATES", "GATE_ESTIMATOR", "certify", "gate", "gate_of", "load_gate", "run",
           "make_config", "fit_targets", "drag_estimates", "drag_prediction", "drag_coverage", "glide_pairs",
           "usable_glide_pairs", "pixel_object_state", "window_features", "certify_stage",
           "epoch_reporting"]
