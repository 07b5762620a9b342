"""Measure one trained run: probes on the frozen predictor state, prediction quality, functional glide test.

Everything is episode-split: probes are fit on probe-fit episodes and scored by
held-out R^2 on probe-test episodes (paper §3 "Measurement", §4, App. C).

* Probes: ridge (alpha by episode-grouped CV) and an early-stopped MLP, from the
  predictor state at the last observation of 16-step windows, to log m, gamma,
  log k (and b, g when present), object position and velocity, finger position and
  the object-minus-finger position (the composition probes, App. C); on contact,
  glide and all windows.
* Leak-free readout: trunk state t is conditioned on the action taken *after*
  observation t, and the scripted policy computes that action from the privileged
  object state. The primary probes (``probes``) therefore read the state with the
  last window step's action replaced by the neutral action (raw zeros, the padding
  every training episode ends with); the action-conditioned readout is kept as a
  labelled secondary (``probes_action_conditioned``, ridge only).
* Prediction: from ``context`` (8) context observations, the direct Δ=16 head, the
  autoregressive composition of the Δ=1 head and a static latent, all decoded
  to arena units through a ridge position probe fit on encoder latents; the static
  baseline is decoded through the same probe (``static16``; ``static16_true`` is the
  undecoded true-position one).
* Functional glide test: the model's own direct 16-step prediction on pure-glide
  windows against analytic references (true gamma, population-median gamma, static),
  every candidate carrying the same decoder residual so the comparison is in one space.
* Belief objective (``objective='belief'``): the probed state is the causal one, the trunk state
  conditioned on the prior's mean (what the heads predict with from the past alone; ``XJEPA.trunk``).
  ``probes_belief`` adds ridge probes of the prior mean itself (causal) and of the posterior mean on
  the probe window (a leaky diagnostic: it sees the window's future; it says whether the latent carries
  a quantity at all, never what the model knows).
* Untrained bound: the same ridge probes on a randomly initialised model that shares
  only the trained model's input-normalisation statistics.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ..config import from_preset, to_dict
from ..data import Dataset, load
from ..errors import ConfigError, DataError
from ..io import write_json
from ..regressors import RidgeCV, TorchRegressor, r2_scores
from ..windows import make_windows, wall_contact

PARAM_TARGETS = ("log_m", "gamma", "log_k", "bias_x", "bias_y", "gain")
STATE_TARGETS = ("object_pos", "object_vel", "finger_pos", "object_rel")
KINDS = ("contact", "glide", "all")
READOUT = {
    "probes": "state at the window's last observation with the action after it replaced by the neutral "
              "(raw zero) action: leak-free, the primary readout",
    "probes_action_conditioned": "state conditioned on the real action after the last observation, which the "
                                 "scripted policy computed from the object state: an upper, leaky readout",
    "probes_belief": "belief objective only, ridge: 'prior_mean' reads μ_p(h_t) at the window's last observation "
                     "(causal, neutral last action); 'posterior_mean' reads μ_q of the whole probe window, which "
                     "sees the future: a leaky diagnostic of what the latent carries, not of what the model knows",
}
CONTEXT, HORIZON = 8, 16


@dataclass
class MeasureConfig:
    """Probe and evaluate one trained run."""

    run_dir: str = "runs/xjepa"
    """Run directory written by ``pokeworld train``."""
    data: str = ""
    """Dataset to measure on (default: the run's training dataset)."""
    window: int = 16
    """Probe window length (observations); the state at its last observation is probed."""
    stride: int = 4
    """Step between probe windows."""
    kinds: tuple[str, ...] = KINDS
    """Window kinds to probe."""
    action_conditioned_kinds: tuple[str, ...] = ("contact",)
    """Window kinds of the secondary, action-conditioned ridge readout (empty: skip it)."""
    max_windows: int = 6000
    """Cap on fit windows per kind (episode-preserving random subsample)."""
    mlp: bool = True
    """Also fit early-stopped MLP probes (slower)."""
    untrained: bool = True
    """Also probe a randomly initialised model of the same configuration (the untrained bound)."""
    batch_episodes: int = 64
    """Episodes encoded per forward pass."""
    seed: int = 0
    """Seed for subsampling and MLP probes."""
    context: int = CONTEXT
    """Context observations before the 16-step predictions and the glide test (paper: 8)."""
    overwrite: bool = False
    """Recompute even if measure.json is up to date."""

    def __post_init__(self) -> None:
        bad = (set(self.kinds) | set(self.action_conditioned_kinds)) - set(KINDS)
        if bad:
            raise ConfigError(f"unknown window kinds {sorted(bad)}; choose from {list(KINDS)}")
        if self.context < 1 or self.window < 2:
            raise ConfigError(f"context must be ≥ 1 and window ≥ 2, got context={self.context}, window={self.window}")


PRESETS = {"tiny": {"max_windows": 400, "mlp": False}, "cpu": {}, "paper": {"max_windows": 100000}}


def make_config(preset: str = "cpu", **overrides) -> MeasureConfig:
    return from_preset(MeasureConfig, PRESETS, preset, **overrides)


# --------------------------------------------------------------------------- features
@torch.no_grad()
def encode_episodes(model, ds: Dataset, episodes: np.ndarray, batch: int = 64) -> np.ndarray:
    """Encoder latents for whole episodes: (E', T+1, D) float32 (token models: mean over tokens)."""
    out = []
    model.eval()
    for i in range(0, len(episodes), batch):
        e = episodes[i:i + batch]
        z = model.encode(ds.frames[e], ds.proprio[e], ds.touch[e])
        if z.dim() == 4:
            z = z.mean(2)
        out.append(z.float().cpu().numpy())
    return np.concatenate(out)


@torch.no_grad()
def _trunk_at(model, z_win: np.ndarray, a_win: np.ndarray, index: int, batch: int = 512) -> np.ndarray:
    out = []
    for i in range(0, len(z_win), batch):
        zt = torch.as_tensor(z_win[i:i + batch])
        h = model.trunk(zt, a_win[i:i + batch])
        out.append(h[:, index].float().cpu().numpy())
    return np.concatenate(out)


def padded_actions(ds: Dataset) -> np.ndarray:
    """Actions aligned with observations: (E, T+1, Da), the last one zero."""
    return np.concatenate([ds.actions, np.zeros_like(ds.actions[:, :1])], 1)


class EpisodeLatents:
    """Encoder latents of a set of episodes, indexable by global episode id."""

    def __init__(self, model, ds: Dataset, episodes: np.ndarray, batch: int):
        self.index = {int(e): i for i, e in enumerate(episodes)}
        self.z = encode_episodes(model, ds, episodes, batch)

    def gather(self, w) -> np.ndarray:
        rows = np.array([self.index[int(e)] for e in w.episode])
        t = w.start[:, None] + np.arange(w.length)[None, :]
        return self.z[rows[:, None], t]


def window_states(model, ds: Dataset, lat: EpisodeLatents, w, acts: np.ndarray,
                  neutral_last_action: bool = True) -> np.ndarray:
    """Predictor state at the last observation of every window: (W, width).

    ``neutral_last_action`` replaces the action taken after that observation by raw zeros before the
    trunk sees it: the policy chose that action from the privileged object state, so a state conditioned
    on it can expose the object state without the model having inferred anything. Zeros are the padding
    every training episode ends with, so the trunk has seen this input.
    """
    a = w.gather(acts)
    if neutral_last_action:
        a = neutral_last(a)
    return _trunk_at(model, lat.gather(w), a, w.length - 1)


def neutral_last(a_win: np.ndarray) -> np.ndarray:
    """Window actions (W, L, Da) with the last one, taken after the probed observation, set to raw zeros.

    The leak-free readout convention shared by :func:`window_states` and :mod:`pokeworld.protocol`;
    a copy, so the dataset's actions are untouched.
    """
    a = np.array(a_win, copy=True)
    a[:, -1] = 0.0
    return a


# --------------------------------------------------------------------------- probes
def probe_targets(ds: Dataset, w) -> dict[str, np.ndarray]:
    """Targets per window: per-episode parameters and the object / finger state at the last observation.

    ``object_rel`` (object minus finger position) is derived when both positions are labelled.
    """
    out = {}
    for name in PARAM_TARGETS:
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


def fit_probes(X_fit, g_fit, T_fit, X_test, T_test, mlp: bool, seed: int) -> dict:
    """R^2 of ridge (and MLP) probes per target; multi-dimensional targets average their per-dim R^2."""
    res = {"ridge": {}, "mlp": {}}
    for name in T_fit:
        ridge = RidgeCV().fit(X_fit, T_fit[name], g_fit)
        res["ridge"][name] = float(np.mean(r2_scores(T_test[name], ridge.predict(X_test))))
        if mlp:
            m = TorchRegressor("mlp", hidden=256, layers=2, epochs=200, patience=10, seed=seed)
            m.fit(X_fit, T_fit[name], g_fit)
            res["mlp"][name] = float(np.mean(r2_scores(T_test[name], m.predict(X_test))))
    if not mlp:
        del res["mlp"]
    return res


def probe_latents(model, ds: Dataset, cfg: MeasureConfig) -> tuple[EpisodeLatents, EpisodeLatents]:
    """Encoder latents of the probe-fit and probe-test episodes (shared by every readout of one model)."""
    fit_eps, test_eps = ds.episodes("probe_fit"), ds.episodes("probe_test")
    if np.intersect1d(fit_eps, test_eps).size:
        raise DataError("probe-fit and probe-test episodes overlap")
    return (EpisodeLatents(model, ds, fit_eps, cfg.batch_episodes),
            EpisodeLatents(model, ds, test_eps, cfg.batch_episodes))


def probe_model(model, ds: Dataset, cfg: MeasureConfig, mlp: bool, kinds: tuple[str, ...] | None = None,
                neutral_last_action: bool = True, latents=None) -> tuple[dict, tuple]:
    """Probe R^2 per family and window kind: ``({"counts", "ridge", ["mlp"]}, (lat_fit, lat_test))``."""
    kinds = cfg.kinds if kinds is None else kinds
    lat_fit, lat_test = latents if latents is not None else probe_latents(model, ds, cfg)
    acts = padded_actions(ds)
    lat = {"fit": lat_fit, "test": lat_test}
    out = probe_windows(ds, lambda w, part: window_states(model, ds, lat[part], w, acts, neutral_last_action),
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


@torch.no_grad()
def belief_states(model, lat: EpisodeLatents, w, acts: np.ndarray, which: str, batch: int = 512) -> np.ndarray:
    """Belief readout per window: ``prior`` -> μ_p at the last observation (causal, neutral last action);
    ``posterior`` -> μ_q of the whole window (sees its future). (W, K)."""
    z, a = lat.gather(w), neutral_last(w.gather(acts))
    out = []
    for i in range(0, len(z), batch):
        zt, at = torch.as_tensor(z[i:i + batch]), a[i:i + batch]
        mu = model.prior(zt, at)[0][:, -1] if which == "prior" else model.posterior(zt, at)[0]
        out.append(mu.float().cpu().numpy())
    return np.concatenate(out)


def probe_belief(model, ds: Dataset, cfg: MeasureConfig, latents) -> dict:
    """Ridge probes of the belief objective's prior mean (causal) and posterior mean (leaky diagnostic)."""
    acts = padded_actions(ds)
    lat = dict(zip(("fit", "test"), latents))
    return {f"{which}_mean": probe_windows(ds, lambda w, part, which=which: belief_states(model, lat[part], w, acts,
                                                                                         which),
                                           cfg.kinds, cfg.window, cfg.stride, cfg.max_windows, cfg.seed, mlp=False)
            for which in ("prior", "posterior")}


# --------------------------------------------------------------------------- prediction
def _position_decoder(ds: Dataset, lat_fit: EpisodeLatents, fit_eps: np.ndarray, rng) -> RidgeCV:
    z = lat_fit.z.reshape(-1, lat_fit.z.shape[-1])
    y = ds.labels["object_pos"][fit_eps].reshape(-1, 2)
    g = np.repeat(fit_eps, lat_fit.z.shape[1])
    keep = rng.choice(len(z), min(len(z), 20000), replace=False)
    return RidgeCV().fit(z[keep], y[keep], g[keep])


@torch.no_grad()
def prediction_quality(model, ds: Dataset, lat_fit: EpisodeLatents, lat_test: EpisodeLatents, seed: int,
                       context: int = CONTEXT) -> dict:
    """Decoded 16-step errors (arena units) of direct, autoregressive and static predictions; glide test.

    Every prediction, the static baseline included, goes through the same position decoder, so all
    candidates carry its error; ``probe_error`` is that decoder's error on the true future latent (the
    floor no decoded prediction can beat on average). ``static16_true`` / ``static8_true`` are the
    undecoded static errors in true position space, for reference only. ``context`` observations precede
    each prediction (windows of ``context + 16``; an episode too short for one raises DataError).
    """
    if model.objective == "recon":
        return {"note": "reconstruction objective: latent heads receive no gradient"}
    rng = np.random.default_rng(seed)
    fit_eps, test_eps = ds.episodes("probe_fit"), ds.episodes("probe_test")
    dec = _position_decoder(ds, lat_fit, fit_eps, rng)
    L = context + HORIZON
    w = make_windows(ds, test_eps, L, 4)
    acts = w.gather(padded_actions(ds))
    z = lat_test.gather(w)
    pos = w.gather(ds.labels["object_pos"])
    truth, truth8, ctx_pos = pos[:, -1], pos[:, context + 7], pos[:, context - 1]
    err = lambda p, q: float(np.linalg.norm(p - q, axis=-1).mean())  # noqa: E731
    static_decoded = dec.predict(z[:, context - 1])
    truth_decoded = dec.predict(z[:, -1])
    out = {"windows": len(w),
           "static16": err(static_decoded, truth), "static16_true": err(ctx_pos, truth),
           "static8": err(static_decoded, truth8), "static8_true": err(ctx_pos, truth8),
           "probe_error": err(truth_decoded, truth)}
    direct = None
    if HORIZON in model.horizons:
        preds = []
        for i in range(0, len(w), 512):
            zt = torch.as_tensor(z[i:i + 512])
            h = model.trunk(zt, acts[i:i + 512])
            zh = model.predict(h, acts[i:i + 512], HORIZON)
            preds.append(zh[:, context - 1].float().cpu().numpy())
        direct = dec.predict(np.concatenate(preds))
        out["direct16"] = err(direct, truth)
    if 1 in model.horizons and not model.tokens:
        rolls = []
        for i in range(0, len(w), 512):
            r = model.rollout(torch.as_tensor(z[i:i + 512, :context]), acts[i:i + 512], HORIZON)
            rolls.append(r.float().cpu().numpy())
        roll = np.concatenate(rolls)
        out["rollout16"] = err(dec.predict(roll[:, -1]), truth)
        out["rollout8"] = err(dec.predict(roll[:, 7]), truth8)
    if direct is not None:
        out["glide_test"] = glide_test(ds, w, direct, fit_eps, residual=truth_decoded - truth, context=context)
    return out


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


# --------------------------------------------------------------------------- entry
def measure(model, ds: Dataset, cfg: MeasureConfig, untrained_model=None) -> dict:
    """Probes (leak-free primary, action-conditioned secondary), prediction quality and the untrained bound."""
    torch.manual_seed(cfg.seed)
    probes, latents = probe_model(model, ds, cfg, cfg.mlp)
    res = {"readout": {k: v for k, v in READOUT.items() if k != "probes_belief"}, "probes": probes}
    if cfg.action_conditioned_kinds:
        res["probes_action_conditioned"], _ = probe_model(model, ds, cfg, mlp=False, kinds=cfg.action_conditioned_kinds,
                                                          neutral_last_action=False, latents=latents)
    if getattr(model, "belief", None) is not None:
        res["probes_belief"] = probe_belief(model, ds, cfg, latents)
        res["readout"]["probes_belief"] = READOUT["probes_belief"]
    res["prediction"] = prediction_quality(model, ds, *latents, cfg.seed, cfg.context)
    if untrained_model is not None:
        up, _ = probe_model(untrained_model, ds, cfg, mlp=False)
        res["untrained"] = up
    return res


def untrained_copy(trained, seed: int = 12345):
    """A randomly initialised model of ``trained``'s architecture sharing only its input-normalisation buffers.

    Only the model's own top-level ``*_mean`` / ``*_std`` buffers (proprio, touch, action, param statistics,
    registered in ``XJEPA.__init__``) are copied: they describe the data, not learning. Nested buffers such
    as the encoder's BatchNorm running statistics are accumulated during training and stay fresh, or the
    bound would not be untrained.
    """
    from ..models.xjepa import XJEPA

    stats = {k: v.detach().clone() for k, v in trained.named_buffers(recurse=False) if k.endswith(("_mean", "_std"))}
    with torch.random.fork_rng(devices=[]):  # a fixed initialisation without disturbing the caller's stream
        torch.manual_seed(seed)
        fresh = XJEPA(**trained.config)
    fresh.load_state_dict(stats, strict=False)
    return fresh.eval()


def untrained_like(run_dir: Path, ds: Dataset | None = None, seed: int = 12345):
    """:func:`untrained_copy` of the model trained in ``run_dir``."""
    from ..train import load_model

    return untrained_copy(load_model(run_dir, map_location="cpu"), seed)


def run(cfg: MeasureConfig) -> Path:
    """Measure ``cfg.run_dir`` and write ``measure.json`` there (skipped when up to date)."""
    from ..train import load_model

    run_dir = Path(cfg.run_dir)
    if not (run_dir / "config.json").exists():
        raise ConfigError(f"{run_dir} is not a training run (no config.json)")
    if not (run_dir / "DONE").exists():
        raise ConfigError(f"{run_dir} has not finished training; re-run `pokeworld train` to resume it")
    run_cfg = json.loads((run_dir / "config.json").read_text())
    data = cfg.data or run_cfg["data"]
    out = run_dir / ("measure.json" if not cfg.data else f"measure-{Path(cfg.data).name}.json")
    ds = load(data)
    cfg_key = to_dict(cfg)
    if cfg.context == CONTEXT:  # added later: left out at its default so earlier measurements stay up to date
        del cfg_key["context"]
    key = {"config": cfg_key, "data_sha256": ds.manifest.get("content_sha256"),
           "final_mtime": (run_dir / "DONE").stat().st_mtime_ns}
    if out.exists() and not cfg.overwrite:
        prev = json.loads(out.read_text())
        if prev.get("key") == key:
            print(f"[measure] {out} is up to date; skipping")
            return out
    torch.set_num_threads(max(1, torch.get_num_threads()))
    model = load_model(run_dir, map_location="cpu")
    res = measure(model, ds, cfg, untrained_like(run_dir, ds) if cfg.untrained else None)
    res.update(key=key, run=run_cfg, data=data)
    write_json(out, res)
    print(f"[measure] {run_dir.name}: " + summary_line(res))
    return out


def summary_line(res: dict) -> str:
    c = res["probes"].get("ridge", {}).get("contact", {})
    parts = [f"{k}={c[k]:+.2f}" for k in ("log_k", "log_m", "gamma", "object_pos", "object_vel", "object_rel")
             if k in c]
    leaky = res.get("probes_action_conditioned", {}).get("ridge", {}).get("contact", {})
    if "object_pos" in leaky:
        parts.append(f"object_pos(action-conditioned)={leaky['object_pos']:+.2f}")
    p = res.get("prediction", {})
    parts += [f"{k}={p[k]:.3f}" for k in ("direct16", "rollout16", "static16") if k in p]
    return " ".join(parts)
