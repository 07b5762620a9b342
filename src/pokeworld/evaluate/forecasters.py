"""Forecasters for the forecast-dependence measurement (:mod:`pokeworld.evaluate.dependence`).

* :class:`SimulatorForecaster` — the reference: the simulator replayed from the true state. Given the true
  parameters it is the truth (S = 1 by construction of the measurement); told to ``ignore`` one parameter it
  forecasts with that parameter fixed at the middle of its range (S ≈ 0); told to ``reverse`` it, with the value
  mirrored through that middle (S < 0). These are the planted cases the measurement is checked on.
* :class:`XJEPAForecaster` — a trained X-JEPA: context encoded, the direct Δ = horizon head's latent forecast
  under the program, and the Δ = 1 head's autoregressive rollout for touch, every latent decoded by ridge decoders
  fit on encoder latents of the probe-fit episodes (as the decoded prediction test reads positions).
"""

from __future__ import annotations

import numpy as np
import torch

from ..data import Dataset
from ..errors import ConfigError
from ..regressors import RidgeCV
from ..sim.core import PARAM_NAMES, ParamRanges, PhysicsConfig
from ..sim.replay import replay
from .dependence import Forecast, ForecastQuery
from .prediction import position_decoder
from .state import EpisodeLatents, as_model_input

PLANTS = ("true", "ignore", "reverse")
"""What a :class:`SimulatorForecaster` does with its parameter: use it, fix it at mid-range, mirror it."""
LOG_SCALE = {"mass", "stiffness", "gain"}
"""Parameters sampled log-uniformly: their middle and mirror are taken in logs."""


class SimulatorForecaster:
    """The simulator as a forecaster, optionally with one parameter ignored or reversed (a planted model)."""

    def __init__(self, physics: PhysicsConfig, param: str = "gamma", plant: str = "true",
                 ranges: ParamRanges | None = None):
        if plant not in PLANTS:
            raise ConfigError(f"plant must be one of {PLANTS}, got {plant!r}")
        if param not in PARAM_NAMES:
            raise ConfigError(f"unknown parameter {param!r}; choose from {list(PARAM_NAMES)}")
        self.physics, self.param, self.plant = physics, param, plant
        lo, hi = getattr(ranges or ParamRanges(), param)
        self.scale = (np.log, np.exp) if param in LOG_SCALE else (lambda v: v, lambda v: v)
        self.lo, self.hi = self.scale[0](lo), self.scale[0](hi)

    def planted(self, params: np.ndarray) -> np.ndarray:
        """``params`` with this forecaster's parameter replaced as its plant says."""
        p = np.array(params, float, copy=True)
        col = PARAM_NAMES.index(self.param)
        forward, back = self.scale
        if self.plant == "ignore":
            p[:, col] = back((self.lo + self.hi) / 2)
        elif self.plant == "reverse":
            p[:, col] = back(self.lo + self.hi - forward(p[:, col]))
        return p

    def forecast(self, query: ForecastQuery) -> Forecast:
        program = query.actions[:, -query.horizon:]
        out = replay(self.physics, query.state, self.planted(query.params), program)
        return Forecast(start=query.state[:, 4:6].copy(), end=out["object_pos"][:, -1],
                        touch_peak=out["touch"][:, :, 2])


def touch_decoder(ds: Dataset, lat_fit: EpisodeLatents, fit_eps: np.ndarray, rng, channel: int = 2) -> RidgeCV:
    """Ridge decoder from encoder latents of the probe-fit episodes to touch channel ``channel`` (the peak force) of
    the same observation; contact frames are kept whole and the rest subsampled to as many (at most 20,000 in all),
    so the decoder is fit where the peak varies."""
    z = lat_fit.z.reshape(-1, lat_fit.z.shape[-1])
    y = ds.touch[fit_eps][..., channel].reshape(-1)
    g = np.repeat(fit_eps, lat_fit.z.shape[1])
    hit, rest = np.flatnonzero(y > 0), np.flatnonzero(y <= 0)
    hit = rng.choice(hit, min(hit.size, 10000), replace=False) if hit.size else hit
    rest = rng.choice(rest, min(rest.size, max(hit.size, 2000), 20000 - hit.size), replace=False)
    keep = np.concatenate([hit, rest])
    return RidgeCV().fit(z[keep], y[keep], g[keep])


class XJEPAForecaster:
    """A trained X-JEPA's forecasts, decoded to object positions and the touch peak."""

    def __init__(self, model, ds: Dataset, seed: int = 0, batch: int = 256, batch_episodes: int = 64,
                 fit_episodes: int = 400):
        if model.objective == "recon":
            raise ConfigError("a reconstruction-objective model has no latent forecast heads to measure")
        self.model, self.batch = model, batch
        # the decoders subsample 20,000 frames: 400 episodes (26,000 frames) hold them, and encoding more is waste
        fit_eps = ds.episodes("probe_fit")[:fit_episodes]
        lat_fit = EpisodeLatents(model, ds, fit_eps, batch_episodes)
        rng = np.random.default_rng(seed)
        self.position = position_decoder(ds, lat_fit, fit_eps, rng)
        self.touch = touch_decoder(ds, lat_fit, fit_eps, rng)

    @torch.no_grad()
    def _one_batch(self, q: ForecastQuery, lo: int, hi: int, touch_steps: int) -> tuple[np.ndarray, ...]:
        m, C, H = self.model, q.frames.shape[1], q.horizon
        z_full = m.encode(q.frames[lo:hi], q.proprio[lo:hi], q.touch[lo:hi])
        z = z_full.mean(2) if z_full.dim() == 4 else z_full
        # the trunk is causal: steps after the context only pad the sequence to the head's action window
        pad = z_full[:, -1:].expand(-1, H, *z_full.shape[2:])
        acts = np.concatenate([q.actions[lo:hi], np.zeros_like(q.actions[lo:hi, :1])], 1)
        h = m.trunk(as_model_input(m, torch.cat([z_full, pad], 1)), acts)
        end = m.predict(h, acts, H)[:, C - 1].float().cpu().numpy()
        roll = None
        if touch_steps and 1 in m.horizons and not m.tokens:
            roll = m.rollout(as_model_input(m, z), acts, touch_steps).float().cpu().numpy()
        return z[:, C - 1].float().cpu().numpy(), end, roll

    def forecast(self, query: ForecastQuery) -> Forecast:
        if query.horizon not in self.model.horizons:
            raise ConfigError(f"the model has no Δ={query.horizon} head (horizons {self.model.horizons})")
        parts = [self._one_batch(query, i, i + self.batch, query.touch_steps)
                 for i in range(0, len(query.frames), self.batch)]
        start, end = (np.concatenate([p[k] for p in parts]) for k in (0, 1))
        peak = None
        if parts and parts[0][2] is not None:
            roll = np.concatenate([p[2] for p in parts])
            peak = self.touch.predict(roll.reshape(-1, roll.shape[-1])).reshape(roll.shape[:2])
        return Forecast(start=self.position.predict(start), end=self.position.predict(end), touch_peak=peak)


__all__ = ["LOG_SCALE", "PLANTS", "SimulatorForecaster", "XJEPAForecaster", "touch_decoder"]
