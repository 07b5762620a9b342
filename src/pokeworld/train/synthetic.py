"""A tiny synthetic corpus (blobs pushed by a finger blob) for tests and benchmarks that need no simulator."""

from __future__ import annotations

import numpy as np

from ..data import Dataset


def synthetic_dataset(num_episodes: int = 12, steps: int = 24, size: int = 32, seed: int = 0,
                      proprio_dim: int = 4, touch_dim: int = 7, action_dim: int = 2, glide_fraction: float = 0.25):
    """Tiny synthetic :class:`pokeworld.data.Dataset` for tests and smoke runs (no simulator needed).

    A finger blob follows integrated random actions; an object blob drifts and is pushed when the
    finger is close (touch channel 6 = contact flag). Params (log_m, gamma, log_k) are random.
    """
    rng = np.random.default_rng(seed)
    E, T1 = num_episodes, steps + 1
    actions = rng.uniform(-1, 1, (E, steps, action_dim)).astype(np.float32)
    fp = np.zeros((E, T1, 2), np.float32)
    fv = np.zeros((E, T1, 2), np.float32)
    op = np.zeros((E, T1, 2), np.float32)
    touch = np.zeros((E, T1, touch_dim), np.float32)
    fp[:, 0] = rng.uniform(0.2, 0.8, (E, 2))
    op[:, 0] = rng.uniform(0.3, 0.7, (E, 2))
    ov = rng.normal(0, 0.02, (E, 2)).astype(np.float32)
    glide = rng.random(E) < glide_fraction
    for t in range(steps):
        fv[:, t + 1] = 0.8 * fv[:, t] + 0.03 * actions[:, t, :2]
        fp[:, t + 1] = np.clip(fp[:, t] + fv[:, t + 1], 0.05, 0.95)
        d = op[:, t] - fp[:, t + 1]
        dist = np.linalg.norm(d, axis=-1)
        hit = (dist < 0.15) & ~glide
        push = np.where(hit[:, None], d / np.maximum(dist, 1e-3)[:, None] * 0.03, 0)
        ov = 0.9 * ov + push
        op[:, t + 1] = np.clip(op[:, t] + ov, 0.05, 0.95)
        touch[:, t + 1, :2] = -push * 10
        touch[:, t + 1, 2] = np.linalg.norm(push, axis=-1) * 10
        touch[:, t + 1, min(6, touch_dim - 1)] = hit
    yy, xx = np.mgrid[0:size, 0:size] / size
    def blob(p, r):
        return np.exp(-((xx - p[..., 0, None, None]) ** 2 + (yy - p[..., 1, None, None]) ** 2) / (2 * r * r))
    img = np.clip(blob(op, 0.08) + 0.6 * blob(fp, 0.05), 0, 1)
    frames = (img * 255).astype(np.uint8)
    proprio = np.concatenate([fp, fv], -1)[..., :proprio_dim].astype(np.float32)
    if proprio_dim > 4:
        proprio = np.concatenate([proprio, np.zeros((E, T1, proprio_dim - 4), np.float32)], -1)
    split = np.zeros(E, np.int8)
    split[int(0.75 * E):] = 2
    params = {"log_m": rng.normal(size=E).astype(np.float32), "gamma": rng.uniform(0.5, 4, E).astype(np.float32),
              "log_k": rng.normal(size=E).astype(np.float32)}
    return Dataset(frames=frames, proprio=proprio, touch=touch, actions=actions,
                   labels={"object_pos": op, "contact": touch[..., min(6, touch_dim - 1)].copy()},
                   params=params, split=split)


__all__ = ["synthetic_dataset"]
