"""This machine's training speed for a given config, timed in a few seconds: what a map's up-front time estimate
is made from (machines differ 2–3× in speed, so a table of another machine's numbers would mislead)."""

from __future__ import annotations

import time

import torch

from ..models.xjepa import XJEPA
from .config import TrainConfig
from .sampler import WindowSampler
from .step import loss_kwargs, make_optimizer, model_kwargs, train_step
from .synthetic import synthetic_dataset


def seconds_per_step(cfg: TrainConfig, threads: int, steps: int = 3, warmup: int = 1) -> float:
    """Seconds per full optimisation step of a ``cfg`` model on the CPU with ``threads`` threads, on synthetic
    windows at ``cfg``'s sizes, after ``warmup`` steps (the first step pays one-time allocations)."""
    ds = synthetic_dataset(num_episodes=4, steps=max(2 * cfg.window, 24), size=cfg.image_size, seed=0)
    dev = torch.device("cpu")
    sampler = WindowSampler(ds, ds.episodes("train"), cfg.image_size, cfg.window, dev, cfg.contact_channel, seed=0,
                            with_params=cfg.sysid_weight > 0, horizon=max(cfg.horizons))
    before_threads, rng = torch.get_num_threads(), torch.random.get_rng_state()
    torch.set_num_threads(max(1, threads))
    try:
        model = XJEPA(**model_kwargs(cfg, (4, 7, 2))).train()
        opt, kw = make_optimizer(model, cfg), loss_kwargs(cfg)
        for s in range(warmup):
            train_step(model, opt, cfg, sampler.sample(cfg.batch_size), s, dev, kw)
        start = time.perf_counter()
        for s in range(steps):
            train_step(model, opt, cfg, sampler.sample(cfg.batch_size), warmup + s, dev, kw)
        return (time.perf_counter() - start) / steps
    finally:  # the caller's process goes on as it was: its threads and its random stream
        torch.set_num_threads(before_threads)
        torch.random.set_rng_state(rng)


__all__ = ["seconds_per_step"]
