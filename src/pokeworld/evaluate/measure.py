"""Measure one trained run: probes on the frozen predictor state, prediction quality, functional glide test.

Everything is episode-split: probes are fit on probe-fit episodes and scored by
held-out R^2 on probe-test episodes (paper §3 "Measurement", §4, App. C).

* Probes: ridge (alpha by episode-grouped CV) and an early-stopped MLP, from the
  predictor state at the last observation of 16-step windows, to log m, gamma,
  log k (and b, g when present), object position and object velocity; on contact,
  glide and all windows.
* Prediction: from 8 context observations, the direct Δ=16 head, the
  autoregressive composition of the Δ=1 head and a static latent, all decoded
  to arena units through a ridge position probe fit on encoder latents.
* Functional glide test: the model's own direct 16-step prediction on pure-glide
  windows against analytic references (true gamma, population-median gamma, static).
* Untrained bound: the same ridge probes on a randomly initialised model.
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
STATE_TARGETS = ("object_pos", "object_vel")
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
    kinds: tuple[str, ...] = ("contact", "glide", "all")
    """Window kinds to probe."""
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
    overwrite: bool = False
    """Recompute even if measure.json is up to date."""


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


def window_states(model, ds: Dataset, lat: EpisodeLatents, w, acts: np.ndarray) -> np.ndarray:
    """Predictor state at the last observation of every window: (W, width)."""
    return _trunk_at(model, lat.gather(w), w.gather(acts), w.length - 1)


# --------------------------------------------------------------------------- probes
def probe_targets(ds: Dataset, w) -> dict[str, np.ndarray]:
    """Targets per window: per-episode parameters and the object state at the last observation."""
    out = {}
    for name in PARAM_TARGETS:
        if name in ds.params and np.ptp(ds.params[name]) > 0:
            out[name] = ds.params[name][w.episode][:, None].astype(np.float64)
    for name in STATE_TARGETS:
        if name in ds.labels:
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


def probe_model(model, ds: Dataset, cfg: MeasureConfig, mlp: bool) -> dict:
    rng = np.random.default_rng(cfg.seed)
    fit_eps, test_eps = ds.episodes("probe_fit"), ds.episodes("probe_test")
    if np.intersect1d(fit_eps, test_eps).size:
        raise DataError("probe-fit and probe-test episodes overlap")
    acts = padded_actions(ds)
    lat_fit = EpisodeLatents(model, ds, fit_eps, cfg.batch_episodes)
    lat_test = EpisodeLatents(model, ds, test_eps, cfg.batch_episodes)
    out = {"counts": {}}
    for kind in cfg.kinds:
        wf = make_windows(ds, fit_eps, cfg.window, cfg.stride).kind(kind).subsample(cfg.max_windows, rng)
        wt = make_windows(ds, test_eps, cfg.window, cfg.stride).kind(kind)
        out["counts"][kind] = {"fit": len(wf), "test": len(wt)}
        if len(wf) < 10 or len(wt) < 10 or np.unique(wf.episode).size < 5:
            continue
        assert not np.intersect1d(wf.episode, wt.episode).size
        Xf = window_states(model, ds, lat_fit, wf, acts)
        Xt = window_states(model, ds, lat_test, wt, acts)
        res = fit_probes(Xf, wf.episode, probe_targets(ds, wf), Xt, probe_targets(ds, wt), mlp, cfg.seed)
        for fam, r in res.items():
            out.setdefault(fam, {})[kind] = r
    return out, (lat_fit, lat_test)


# --------------------------------------------------------------------------- prediction
def _position_decoder(ds: Dataset, lat_fit: EpisodeLatents, fit_eps: np.ndarray, rng) -> RidgeCV:
    z = lat_fit.z.reshape(-1, lat_fit.z.shape[-1])
    y = ds.labels["object_pos"][fit_eps].reshape(-1, 2)
    g = np.repeat(fit_eps, lat_fit.z.shape[1])
    keep = rng.choice(len(z), min(len(z), 20000), replace=False)
    return RidgeCV().fit(z[keep], y[keep], g[keep])


@torch.no_grad()
def prediction_quality(model, ds: Dataset, lat_fit: EpisodeLatents, lat_test: EpisodeLatents, seed: int) -> dict:
    """Decoded 16-step errors (arena units) of direct, autoregressive and static predictions; glide test."""
    if model.objective == "recon":
        return {"note": "reconstruction objective: latent heads receive no gradient"}
    rng = np.random.default_rng(seed)
    fit_eps, test_eps = ds.episodes("probe_fit"), ds.episodes("probe_test")
    dec = _position_decoder(ds, lat_fit, fit_eps, rng)
    L = CONTEXT + HORIZON
    w = make_windows(ds, test_eps, L, 4)
    acts = w.gather(padded_actions(ds))
    z = lat_test.gather(w)
    pos = w.gather(ds.labels["object_pos"])
    truth, ctx_pos = pos[:, -1], pos[:, CONTEXT - 1]
    out = {"windows": len(w), "static16": float(np.linalg.norm(ctx_pos - truth, axis=-1).mean())}
    dist = lambda zz, p: float(np.linalg.norm(dec.predict(zz) - p, axis=-1).mean())  # noqa: E731
    out["static16_decoded"] = dist(z[:, CONTEXT - 1], truth)
    out["probe_error"] = dist(z[:, -1], truth)  # decoder floor: true latent at t+16
    direct = None
    if HORIZON in model.horizons:
        preds = []
        for i in range(0, len(w), 512):
            zt = torch.as_tensor(z[i:i + 512])
            h = model.trunk(zt, acts[i:i + 512])
            zh = model.predict(h, acts[i:i + 512], HORIZON)
            preds.append(zh[:, CONTEXT - 1].float().cpu().numpy())
        direct = np.concatenate(preds)
        out["direct16"] = dist(direct, truth)
    if 1 in model.horizons and not model.tokens:
        rolls = []
        for i in range(0, len(w), 512):
            r = model.rollout(torch.as_tensor(z[i:i + 512, :CONTEXT]), acts[i:i + 512], HORIZON)
            rolls.append(r.float().cpu().numpy())
        roll = np.concatenate(rolls)
        out["rollout16"] = dist(roll[:, -1], truth)
        out["rollout8"] = dist(roll[:, 7], pos[:, CONTEXT + 7])
        out["static8"] = float(np.linalg.norm(ctx_pos - pos[:, CONTEXT + 7], axis=-1).mean())
    if direct is not None:
        out["glide_test"] = glide_test(ds, w, dec.predict(direct), fit_eps)
    return out


def glide_test(ds: Dataset, w, predicted_pos: np.ndarray, fit_eps: np.ndarray) -> dict:
    """Errors of the model's direct 16-step positions on pure-glide futures vs analytic references."""
    dt = ds.manifest.get("config", {}).get("physics", {}).get("dt", 0.05)
    contact = w.gather(ds.labels["contact"])[:, CONTEXT - 1:] > 0
    walls = w.gather(wall_contact(ds))[:, CONTEXT - 1:]
    vel = w.gather(ds.labels["object_vel"])
    speed = np.linalg.norm(vel[:, CONTEXT - 1:], axis=-1)
    ok = ~contact.any(1) & ~walls.any(1) & (speed > 0.02).all(1)
    if ok.sum() < 5:
        return {"windows": int(ok.sum())}
    pos = w.gather(ds.labels["object_pos"])
    p0, v0, truth = pos[ok, CONTEXT - 1], vel[ok, CONTEXT - 1], pos[ok, -1]
    T = HORIZON * dt
    gamma = ds.params["gamma"][w.episode[ok]][:, None]
    g_med = float(np.median(ds.params["gamma"][fit_eps]))
    ref = lambda g: p0 + v0 * (1 - np.exp(-g * T)) / g  # noqa: E731
    err = lambda p: float(np.linalg.norm(p - truth, axis=-1).mean())  # noqa: E731
    return {"windows": int(ok.sum()), "model": err(predicted_pos[ok]), "true_gamma": err(ref(gamma)),
            "median_gamma": err(ref(g_med)), "static": err(p0)}


# --------------------------------------------------------------------------- entry
def measure(model, ds: Dataset, cfg: MeasureConfig, untrained_model=None) -> dict:
    torch.manual_seed(cfg.seed)
    probes, (lat_fit, lat_test) = probe_model(model, ds, cfg, cfg.mlp)
    res = {"probes": probes, "prediction": prediction_quality(model, ds, lat_fit, lat_test, cfg.seed)}
    if untrained_model is not None:
        up, _ = probe_model(untrained_model, ds, cfg, mlp=False)
        res["untrained"] = up
    return res


def untrained_like(run_dir: Path, ds: Dataset, seed: int = 12345):
    """A randomly initialised model with the run's architecture and the run's normalisation statistics."""
    from ..models.xjepa import XJEPA
    from ..train import load_model

    trained = load_model(run_dir, map_location="cpu")
    torch.manual_seed(seed)
    fresh = XJEPA(**trained.config)
    stats = {k: v for k, v in trained.state_dict().items() if k.endswith(("_mean", "_std"))}
    fresh.load_state_dict(stats, strict=False)
    return fresh.eval()


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
    key = {"config": to_dict(cfg), "data_sha256": ds.manifest.get("content_sha256"),
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
    parts = [f"{k}={c[k]:+.2f}" for k in ("log_k", "log_m", "gamma", "object_pos", "object_vel") if k in c]
    p = res.get("prediction", {})
    parts += [f"{k}={p[k]:.3f}" for k in ("direct16", "rollout16", "static16") if k in p]
    return " ".join(parts)
