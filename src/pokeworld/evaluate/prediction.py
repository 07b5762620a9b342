"""Prediction quality through a position decoder, and the functional glide test.

From ``context`` observations the direct Δ=``horizon`` head, the autoregressive composition of the Δ=1
head and a static latent are decoded to position units through a ridge decoder fit on encoder latents
of the probe-fit episodes, so every candidate (the static baseline included) carries the decoder's
error. The simulator decodes ``object_pos`` (arena units); real data decodes ``tcp_pos`` (metres).
"""

from __future__ import annotations

import numpy as np
import torch

from ..data import Dataset
from ..regressors import RidgeCV, r2_scores
from ..windows import make_windows, wall_contact
from .state import EpisodeLatents, as_model_input, padded_actions

CONTEXT, HORIZON = 8, 16


def position_decoder(ds: Dataset, lat_fit: EpisodeLatents, fit_eps: np.ndarray, rng,
                      label: str = "object_pos") -> RidgeCV:
    """Ridge decoder from encoder latents of the probe-fit episodes to ``labels/<label>`` (every frame,
    at most 20,000 subsampled)."""
    z = lat_fit.z.reshape(-1, lat_fit.z.shape[-1])
    y = ds.labels[label][fit_eps].reshape(len(z), -1)
    g = np.repeat(fit_eps, lat_fit.z.shape[1])
    keep = rng.choice(len(z), min(len(z), 20000), replace=False)
    return RidgeCV().fit(z[keep], y[keep], g[keep])


def frame_position_r2(ds: Dataset, dec: RidgeCV, lat: EpisodeLatents, episodes: np.ndarray,
                      label: str = "object_pos") -> float:
    """Held-out R² (mean over coordinates) of the position decoder on every frame of ``episodes``: how linearly the
    encoder's per-frame latent holds the position, the release's ``probe_r2_pos_frame`` (the lazy equilibrium's
    position column reads the frame embedding, not the predictor state)."""
    rows = np.array([lat.index[int(e)] for e in episodes])
    z = lat.z[rows].reshape(-1, lat.z.shape[-1])
    y = ds.labels[label][episodes].reshape(len(z), -1)
    return float(np.mean(r2_scores(y, dec.predict(z))))


@torch.no_grad()
def prediction_quality(model, ds: Dataset, lat_fit: EpisodeLatents, lat_test: EpisodeLatents, seed: int,
                       position: str = "object_pos", test_split: str = "probe_test", context: int = CONTEXT,
                       horizon: int = HORIZON, stride: int = 4, glide: bool = True,
                       decoder: RidgeCV | None = None) -> dict:
    """Decoded ``horizon``-step errors (label units) of direct, autoregressive and static predictions.

    Every prediction, the static baseline included, goes through the same position decoder (fit on
    ``lat_fit``, the probe-fit episodes, to ``labels/<position>``), so all candidates carry its error;
    ``probe_error`` is that decoder's error on the true future latent (the floor no decoded prediction
    can beat on average), ``frame_position_r2`` its R² on every test frame (:func:`frame_position_r2`). ``static16_true`` / ``static8_true`` are the undecoded static errors in true
    position space, for reference only. Keys name the horizon (``direct16``, ``rollout8``, ... for the
    default 16 and its half). ``lat_test`` must hold the ``test_split`` episodes. ``glide`` adds the
    simulator's functional glide test. ``decoder``: that position decoder when the caller already fit it
    (``position_decoder(ds, lat_fit, probe-fit episodes, default_rng(seed), position)``, the same fit),
    so evaluating several test splits fits it once.
    """
    if model.objective == "recon":
        return {"note": "reconstruction objective: latent heads receive no gradient"}
    fit_eps, test_eps = ds.episodes("probe_fit"), ds.episodes(test_split)
    dec = decoder or position_decoder(ds, lat_fit, fit_eps, np.random.default_rng(seed), position)
    H, half = horizon, horizon // 2
    w, acts, z, pos = future_windows(ds, lat_test, test_eps, context + H, stride, position)
    truth, truth_half, ctx_pos = pos[:, -1], pos[:, context + half - 1], pos[:, context - 1]
    err = position_error
    static_decoded = dec.predict(z[:, context - 1])
    truth_decoded = dec.predict(z[:, -1])
    out = {"windows": len(w),
           f"static{H}": err(static_decoded, truth), f"static{H}_true": err(ctx_pos, truth),
           f"static{half}": err(static_decoded, truth_half), f"static{half}_true": err(ctx_pos, truth_half),
           "probe_error": err(truth_decoded, truth),
           "frame_position_r2": frame_position_r2(ds, dec, lat_test, test_eps, position)}
    direct = None
    if H in model.horizons:
        direct = dec.predict(direct_latents(model, lat_test, w, acts, H, context))
        out[f"direct{H}"] = err(direct, truth)
    if 1 in model.horizons and not model.tokens:
        rolls = []
        for i in range(0, len(w), 512):
            r = model.rollout(as_model_input(model, z[i:i + 512, :context]), acts[i:i + 512], H)
            rolls.append(r.float().cpu().numpy())
        roll = np.concatenate(rolls)
        out[f"rollout{H}"] = err(dec.predict(roll[:, -1]), truth)
        out[f"rollout{half}"] = err(dec.predict(roll[:, half - 1]), truth_half)
    if glide and direct is not None:
        out["glide_test"] = glide_test(ds, w, direct, fit_eps, residual=truth_decoded - truth, context=context)
    return out


def future_windows(ds: Dataset, lat: EpisodeLatents, episodes: np.ndarray, length: int, stride: int = 4,
                   position: str = "object_pos"):
    """The prediction test's windows of ``length`` observations over ``episodes``: ``(windows, their actions, their
    latents (W, length, D), their positions (W, length, P))``."""
    w = make_windows(ds, episodes, length, stride)
    pos = w.gather(ds.labels[position])
    return w, w.gather(padded_actions(ds)), lat.gather(w), pos.reshape(*pos.shape[:2], -1)


def position_error(p: np.ndarray, q: np.ndarray) -> float:
    """Mean Euclidean distance between two (W, P) position arrays: every error of the prediction table."""
    return float(np.linalg.norm(p - q, axis=-1).mean())


@torch.no_grad()
def direct_latents(model, lat: EpisodeLatents, w, acts: np.ndarray, horizon: int, context: int = CONTEXT,
                   batch: int = 512) -> np.ndarray:
    """The direct Δ=``horizon`` head's prediction from the state at window position ``context`` − 1: (W, D), the
    latent the position decoder reads. The trunk reads its own input (every token of a token model); a token
    model's direct head predicts the token-mean latent from the token-mean state."""
    z_in = lat.gather(w, trunk=True)
    preds = []
    for i in range(0, len(w), batch):
        h = model.trunk(as_model_input(model, z_in[i:i + batch]), acts[i:i + batch])
        preds.append(model.predict(h, acts[i:i + batch], horizon)[:, context - 1].float().cpu().numpy())
    return np.concatenate(preds)


def glide_test(ds: Dataset, w, predicted_pos: np.ndarray, fit_eps: np.ndarray,
               residual: np.ndarray | None = None, context: int = CONTEXT) -> dict:
    """The model's direct 16-step positions on pure-glide futures against analytic references.

    ``w`` are (context + HORIZON)-observation windows; a window qualifies when the object glides freely
    (no finger or wall contact, moving) from the last context observation to the end. ``residual`` is
    the position decoder's error on the true future latent, per window (None: predictions are in true
    position space already). See :func:`glide_comparison` for the keys.
    """
    if "gamma" not in ds.params:
        return {"windows": 0, "note": "no gamma parameter in this dataset"}
    dt = ds.manifest.get("config", {}).get("physics", {}).get("dt", 0.05)
    contact = w.gather(ds.labels["contact"])[:, context - 1:] > 0
    walls = w.gather(wall_contact(ds))[:, context - 1:]
    vel = w.gather(ds.labels["object_vel"])
    speed = np.linalg.norm(vel[:, context - 1:], axis=-1)
    ok = ~contact.any(1) & ~walls.any(1) & (speed > 0.02).all(1)
    if ok.sum() < 5:
        return {"windows": int(ok.sum())}
    pos = w.gather(ds.labels["object_pos"])
    residual = np.zeros_like(predicted_pos) if residual is None else residual
    res = glide_comparison(predicted_pos[ok], residual[ok], pos[ok, -1], pos[ok, context - 1], vel[ok, context - 1],
                           ds.params["gamma"][w.episode[ok]], float(np.median(ds.params["gamma"][fit_eps])),
                           HORIZON * dt)
    return {"windows": int(ok.sum()), **res}


def glide_reference(p0: np.ndarray, v0: np.ndarray, gamma, horizon_time: float) -> np.ndarray:
    """Exponential-drag glide from (p0, v0) after ``horizon_time``: p0 + v0 (1 - e^(-γT)) / γ."""
    g = np.broadcast_to(np.asarray(gamma, float).reshape(-1), (len(p0),))[:, None]  # scalar or per window
    safe = np.maximum(g, 1e-9)
    travel = np.where(g > 1e-9, -np.expm1(-safe * horizon_time) / safe, horizon_time)  # γ → 0: free flight
    return p0 + v0 * travel


def glide_comparison(predicted: np.ndarray, residual: np.ndarray, truth: np.ndarray, p0: np.ndarray,
                     v0: np.ndarray, gamma: np.ndarray, gamma_median: float, horizon_time: float) -> dict:
    """Mean position errors of the model and of analytic references, compared in one (decoded) space.

    The model's prediction is read through a position decoder whose own error on the true future frame
    is ``residual`` = dec(z_true) - truth. Each analytic reference is displaced by the same residual, so
    every candidate carries the decoder's error and the comparison cannot be decided by it:

    * ``model``: |predicted - truth|;  ``decoder_floor``: |residual| (the decoded truth);
    * ``true_gamma`` / ``median_gamma`` / ``static``: |reference + residual - truth| for the glide with the
      episode's γ, with the population-median γ, and the position at the last context observation;
    * ``undecoded``: the same references' errors in true position space (no decoder involved);
    * ``uses_gamma``: the model beats the decoded median-γ reference, i.e. its predictions carry
      episode-specific drag; ``beats_static``: it beats the decoded static reference.
    """
    refs = {"true_gamma": glide_reference(p0, v0, gamma, horizon_time),
            "median_gamma": glide_reference(p0, v0, gamma_median, horizon_time),
            "static": p0}
    err = lambda p: float(np.linalg.norm(p - truth, axis=-1).mean())  # noqa: E731
    out = {"model": err(predicted), "decoder_floor": float(np.linalg.norm(residual, axis=-1).mean())}
    out.update({name: err(ref + residual) for name, ref in refs.items()})
    out["undecoded"] = {name: err(ref) for name, ref in refs.items()}
    out["uses_gamma"] = bool(out["model"] < out["median_gamma"])
    out["beats_static"] = bool(out["model"] < out["static"])
    return out
