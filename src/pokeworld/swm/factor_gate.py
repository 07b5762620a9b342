"""Recoverability certificates for arbitrary physical factors of an swm dataset (the gate before any model claim).

A factor (``variation.<key>`` of a stable-worldmodel environment, constant within each episode) is certified with
the gate's own instruments (:mod:`pokeworld.certify`, paper App. A), fit per factor on the probe-fit episodes and
scored by held-out R² on the probe-test episodes:

* ``gru``     the recurrent oracle: a GRU over raw windows of the non-pixel observations and the actions;
* ``linear``  the linear floor: ridge (episode-grouped CV) on the same window, flattened;
* ``sysid``   local dynamics (system identification): per window, the least-squares fit of the observation's
              one-step change on the observation, the action and a constant (the window's linearised dynamics),
              whose coefficients and residual scales go to the same ridge. A factor that sets how the state
              responds (gravity the pendulum's restoring term, a mass the gain from force to acceleration, a
              damping the decay of a velocity) is a smooth function of these coefficients, where the flattened
              window holds it only through products of observations that no linear map forms.

All three read exactly what the protocol's probes see of a window (the action after its last observation zeroed, as
the protocol's leak-free readout does), so a certificate and a model probe speak of the same information. swm
datasets carry no contact labels, so windows are of kind "all". The gate is the paper's rule with one threshold
for every factor: the best estimator's R² must reach it, the GRU oracle's verdict is recorded beside it
(:func:`pokeworld.certify.gate`). The result has the shape of :func:`pokeworld.certify.certify`'s, so
:func:`pokeworld.protocol.certify_model` takes it as ``certificates``.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from .. import certify as C
from ..config import to_dict
from ..data import Dataset
from ..errors import ConfigError, DataError
from ..evaluate.measure import neutral_last, padded_actions
from ..io import hash_arrays
from ..progress import heartbeat
from ..regressors import RidgeCV, TorchRegressor, r2_scores
from ..windows import make_windows

ESTIMATORS = ("gru", "linear", "sysid")
KIND = "all"
"""The window kind factors are certified and probed on: swm datasets have no contact labels."""


@dataclass
class FactorCertifyConfig:
    """Certify per-episode factors from raw non-pixel observations and actions."""

    window: int = 16
    """Window length in observations (the protocol's probe window)."""
    stride: int = 4
    """Step between window starts."""
    max_windows: int = 6000
    """Cap on fit windows (episode-preserving random subsample) to bound CPU time."""
    threshold: float = 0.4
    """Gate threshold on held-out R² for every factor (the paper's threshold for mass and drag)."""
    gru_hidden: int = 96
    """GRU oracle width."""
    gru_layers: int = 2
    """GRU oracle depth."""
    epochs: int = 150
    """Maximum GRU epochs (early stopping usually ends sooner)."""
    patience: int = 12
    """Early-stopping patience in epochs."""
    seed: int = 0
    """Seed of the subsample and the GRU's initialisation."""

    def __post_init__(self) -> None:
        if self.window < 3 or self.stride < 1 or self.max_windows < 10:
            raise ConfigError(f"window must be >= 3, stride >= 1 and max_windows >= 10, got {self.window}, "
                              f"{self.stride}, {self.max_windows}")
        if not 0 < self.threshold <= 1:
            raise ConfigError(f"threshold is an R² in (0, 1], got {self.threshold}")


def raw_windows(ds: Dataset, w) -> np.ndarray:
    """(W, L, Dp + Da) float32: the non-pixel observations and actions of each window, the last action zeroed."""
    return np.concatenate([w.gather(ds.proprio), neutral_last(w.gather(padded_actions(ds)))], -1).astype(np.float32)


def local_dynamics(windows: np.ndarray, obs_dim: int, ridge: float = 0.1) -> np.ndarray:
    """(W, P·D + D) per-window linearised dynamics from :func:`raw_windows` output (W, L, D + Da): the ridge
    least-squares coefficients of x[t+1] − x[t] on [x[t], a[t], 1] over the window's L − 1 transitions (the zeroed
    action after the last observation is never used), flattened, and the log residual scale per dimension."""
    x = windows[..., :obs_dim].astype(np.float64)
    a = windows[:, :-1, obs_dim:].astype(np.float64)
    design = np.concatenate([x[:, :-1], a, np.ones(a.shape[:2] + (1,))], -1)  # (W, L-1, P)
    change = x[:, 1:] - x[:, :-1]  # (W, L-1, D)
    gram = design.transpose(0, 2, 1) @ design + ridge * np.eye(design.shape[-1])
    coef = np.linalg.solve(gram, design.transpose(0, 2, 1) @ change)  # (W, P, D)
    residual = change - design @ coef
    scale = np.log(np.sqrt((residual ** 2).mean(1)) + 1e-8)  # (W, D)
    return np.concatenate([coef.reshape(len(coef), -1), scale], -1).astype(np.float32)


def winsorise(fit: np.ndarray, test: np.ndarray, share: float = 0.005) -> tuple[np.ndarray, np.ndarray]:
    """Both feature sets clipped to the fit features' [share, 1 − share] quantiles per column: a window whose local
    fit is ill-conditioned (a pole at rest: the design barely varies) gives extreme coefficients, and one such test
    window would otherwise decide a held-out R²."""
    lo, hi = np.quantile(fit, share, axis=0), np.quantile(fit, 1 - share, axis=0)
    return np.clip(fit, lo, hi), np.clip(test, lo, hi)


def standardise(fit: np.ndarray, test: np.ndarray, obs_dim: int) -> tuple[np.ndarray, np.ndarray]:
    """Observation channels of both window sets scaled by the fit windows' mean and spread (the actions as given),
    so the local-dynamics fit weighs every state dimension alike."""
    flat = fit[..., :obs_dim].reshape(-1, obs_dim)
    mean, std = flat.mean(0), flat.std(0)
    std = np.where(std > 1e-8, std, 1.0)
    scale = lambda w: np.concatenate([(w[..., :obs_dim] - mean) / std, w[..., obs_dim:]], -1)  # noqa: E731
    return scale(fit), scale(test)


def certify_factors(ds: Dataset, factors: tuple[str, ...], cfg: FactorCertifyConfig) -> dict:
    """Certificates of ``factors`` (names under ``ds.params``): estimators, certificate table and gate."""
    missing = [f for f in factors if f not in ds.params]
    if missing or not factors:
        raise DataError(f"factors {missing or '(none)'} are not per-episode factors of this dataset "
                        f"(it has {sorted(ds.params)})")
    fit_eps, test_eps = ds.episodes("probe_fit"), ds.episodes("probe_test")
    if fit_eps.size < 5 or test_eps.size < 5:
        raise DataError(f"{fit_eps.size} probe-fit / {test_eps.size} probe-test episodes; certificates need at least "
                        "5 of each (collect more episodes)")
    rng = np.random.default_rng(cfg.seed)
    w_fit = make_windows(ds, fit_eps, cfg.window, cfg.stride).subsample(cfg.max_windows, rng)
    w_test = make_windows(ds, test_eps, cfg.window, cfg.stride)
    X_fit, X_test = raw_windows(ds, w_fit), raw_windows(ds, w_test)
    Y = np.stack([ds.params[f] for f in factors], 1).astype(np.float64)
    y_fit, y_test = Y[w_fit.episode], Y[w_test.episode]
    gru = functools.partial(TorchRegressor, "gru", hidden=cfg.gru_hidden, layers=cfg.gru_layers, epochs=cfg.epochs,
                            patience=cfg.patience, seed=cfg.seed)
    D = ds.proprio.shape[-1]
    S_fit, S_test = standardise(X_fit, X_test, D)
    estimators: dict = {}
    for est, make, xf, xt in (("gru", gru, X_fit, X_test),
                              ("linear", RidgeCV, X_fit.reshape(len(X_fit), -1), X_test.reshape(len(X_test), -1)),
                              ("sysid", RidgeCV, *winsorise(local_dynamics(S_fit, D), local_dynamics(S_test, D)))):
        with heartbeat("swm-certify", f"{est} certificate of {len(factors)} factors on {len(xf)} fit windows"):
            pred = C.fit_targets(make, xf, y_fit, w_fit.episode, xt, separate=True)
        estimators[est] = {KIND: {f: float(v) for f, v in zip(factors, r2_scores(y_test, pred))}}
        print(f"[swm-certify] {est:7s} " + " ".join(f"{f}={v:+.3f}" for f, v in estimators[est][KIND].items()))
    certificate = C.certificate_table(estimators, factors)
    return {"estimators": estimators, "counts": {KIND: {"fit": len(w_fit), "test": len(w_test)}},
            "certificate": certificate,
            "gate": C.gate(certificate, estimators, gates={f: cfg.threshold for f in factors}, kind=KIND),
            "config": to_dict(cfg), "factors": list(factors),
            "dataset": {"content_sha256": hash_arrays(ds.arrays()), "source": ds.manifest.get("source")}}


__all__ = ["ESTIMATORS", "KIND", "FactorCertifyConfig", "certify_factors", "local_dynamics", "raw_windows",
           "standardise", "winsorise"]
