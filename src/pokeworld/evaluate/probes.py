"""Probes from frozen states: targets, ridge / early-stopped MLP fits, and the episode-split probe loop.

Every fit is episode-grouped (ridge alpha by grouped CV, MLP early stopping on held-out episodes) and
scored on episodes the fit never saw. :func:`fit_predict` is the one place probes are fitted; the
simulator's R^2 tables (:func:`fit_probes`, :func:`probe_windows`) and the real-data metrics
(:mod:`pokeworld.real.evaluate`: force / position R^2, onset AUC, force forecasting) all read its
predictions. States given as tensors are probed on their device (:mod:`pokeworld.regressors`); only the R^2
numbers come to the host.
"""

from __future__ import annotations

import numpy as np
import torch

from ..data import Dataset
from ..errors import DataError
from ..regressors import RidgeCV, TorchRegressor, r2_scores
from ..windows import make_windows
from .state import EpisodeLatents, padded_actions, probes_on_device, window_states

PARAM_TARGETS = ("log_m", "gamma", "log_k", "bias_x", "bias_y", "gain")
STATE_TARGETS = ("object_pos", "object_vel", "finger_pos", "object_rel")
KINDS = ("contact", "glide", "all")


def probe_targets(ds: Dataset, w) -> dict[str, np.ndarray]:
    """Targets per window: per-episode parameters and the object / finger state at the last observation.

    ``object_rel`` (object minus finger position) is derived when both positions are labelled. A store whose
    manifest lists ``probe_params`` (an swm factor dataset: :mod:`pokeworld.swm.factors`) has those probed too.
    """
    out = {}
    for name in (*PARAM_TARGETS, *ds.manifest.get("probe_params", ())):
        if name in ds.params and np.ptp(ds.params[name]) > 0:
            out[name] = ds.params[name][w.episode][:, None].astype(np.float64)
    for name in STATE_TARGETS:
        if name == "object_rel":
            if {"object_pos", "finger_pos"} <= set(ds.labels):
                out[name] = (w.last(ds.labels["object_pos"]) - w.last(ds.labels["finger_pos"])).reshape(
                    len(w), -1).astype(np.float64)
        elif name in ds.labels:
            out[name] = w.last(ds.labels[name]).reshape(len(w), -1).astype(np.float64)
    return out


def fit_predict(X_fit, g_fit, T_fit: dict, X_tests: dict, mlp: bool, seed: int) -> dict:
    """Fit a ridge (and an MLP) probe per target on ``X_fit`` and predict every test set.

    Returns ``{family: {target: {test_name: (W_test, D) prediction}}}``; ``g_fit`` are episode ids
    (grouped CV / early stopping). Targets are fitted in order, ridge before MLP, so seeds and results
    do not depend on how many test sets are scored.
    """
    res: dict = {"ridge": {}, "mlp": {}}
    for name in T_fit:
        ridge = RidgeCV().fit(X_fit, T_fit[name], g_fit)
        res["ridge"][name] = {k: ridge.predict(X) for k, X in X_tests.items()}
        if mlp:
            m = TorchRegressor("mlp", hidden=256, layers=2, epochs=200, patience=10, seed=seed)
            m.fit(X_fit, T_fit[name], g_fit)
            res["mlp"][name] = {k: m.predict(X) for k, X in X_tests.items()}
    if not mlp:
        del res["mlp"]
    return res


def fit_probes(X_fit, g_fit, T_fit, X_test, T_test, mlp: bool, seed: int) -> dict:
    """R^2 of ridge (and MLP) probes per target; multi-dimensional targets average their per-dim R^2.
    Tensor states: fit and scored on their device, each R^2 the one number copied to the host."""
    preds = fit_predict(X_fit, g_fit, T_fit, {"test": X_test}, mlp, seed)
    return {fam: {name: mean_r2(T_test[name], p["test"]) for name, p in per.items()} for fam, per in preds.items()}


def mean_r2(y_true, y_pred) -> float:
    """The mean over columns of :func:`~pokeworld.regressors.r2_scores`, as a float (tensors: on their device)."""
    r2 = r2_scores(y_true, y_pred)
    return float(r2.mean()) if isinstance(r2, torch.Tensor) else float(np.mean(r2))


def probe_latents(model, ds: Dataset, cfg, on_device: bool = False) -> tuple[EpisodeLatents, EpisodeLatents]:
    """Encoder latents of the probe-fit and probe-test episodes (shared by every readout of one model); with
    ``on_device`` the predictor's inputs stay on the model's device (:class:`EpisodeLatents`).

    ``cfg`` needs ``batch_episodes`` (a MeasureConfig or any config carrying it)."""
    fit_eps, test_eps = ds.episodes("probe_fit"), ds.episodes("probe_test")
    if np.intersect1d(fit_eps, test_eps).size:
        raise DataError("probe-fit and probe-test episodes overlap")
    return (EpisodeLatents(model, ds, fit_eps, cfg.batch_episodes, on_device),
            EpisodeLatents(model, ds, test_eps, cfg.batch_episodes, on_device))


def probe_model(model, ds: Dataset, cfg, mlp: bool, kinds: tuple[str, ...] | None = None,
                neutral_last_action: bool = True, latents=None) -> tuple[dict, tuple]:
    """Probe R^2 per family and window kind: ``({"counts", "ridge", ["mlp"]}, (lat_fit, lat_test))``.

    ``cfg`` carries ``kinds``, ``window``, ``stride``, ``max_windows``, ``seed``, ``batch_episodes`` and
    ``probe_device`` (:class:`pokeworld.evaluate.measure.MeasureConfig`); the latter says whether the states stay
    on the model's device and are probed there (:func:`~pokeworld.evaluate.state.probes_on_device`)."""
    kinds = cfg.kinds if kinds is None else kinds
    on_device = probes_on_device(cfg.probe_device, model)
    lat_fit, lat_test = latents if latents is not None else probe_latents(model, ds, cfg, on_device)
    acts = padded_actions(ds)
    lat = {"fit": lat_fit, "test": lat_test}
    out = probe_windows(ds, lambda w, part: window_states(model, ds, lat[part], w, acts, neutral_last_action,
                                                          on_device=on_device),
                        kinds, cfg.window, cfg.stride, cfg.max_windows, cfg.seed, mlp)
    return out, (lat_fit, lat_test)


def probe_windows(ds: Dataset, states, kinds: tuple[str, ...], window: int, stride: int, max_windows: int,
                  seed: int, mlp: bool, targets: tuple[str, ...] | None = None) -> dict:
    """Probe R^2 per family and window kind from any state reader: ``{"counts", "ridge", ["mlp"]}``.

    ``states(windows, part) -> (W, D)`` returns the state probed for each window (``part`` is "fit" for
    probe-fit windows, "test" for probe-test ones). Trained runs (:func:`probe_model`) and user models
    (:mod:`pokeworld.protocol`) both go through this loop, so their window selection, subsampling,
    episode split and probes are the same by construction. ``targets`` restricts the probed quantities
    (None: every one :func:`probe_targets` finds).
    """
    fit_eps, test_eps = ds.episodes("probe_fit"), ds.episodes("probe_test")
    out: dict = {"counts": {}}
    for kind in kinds:
        # one generator per kind, so readouts that probe different kind sets use identical windows
        rng = np.random.default_rng([seed, KINDS.index(kind)])
        wf = make_windows(ds, fit_eps, window, stride).kind(kind).subsample(max_windows, rng)
        wt = make_windows(ds, test_eps, window, stride).kind(kind)
        out["counts"][kind] = {"fit": len(wf), "test": len(wt)}
        if len(wf) < 10 or len(wt) < 10 or np.unique(wf.episode).size < 5:
            continue
        assert not np.intersect1d(wf.episode, wt.episode).size
        Xf, Xt = states(wf, "fit"), states(wt, "test")
        Tf, Tt = probe_targets(ds, wf), probe_targets(ds, wt)
        if targets is not None:
            Tf, Tt = ({k: v for k, v in T.items() if k in targets} for T in (Tf, Tt))
        res = fit_probes(Xf, wf.episode, Tf, Xt, Tt, mlp, seed)
        for fam, r in res.items():
            out.setdefault(fam, {})[kind] = r
    return out
