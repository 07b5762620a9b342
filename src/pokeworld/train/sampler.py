"""A dataset's training episodes held as (device) tensors, the random windows a step trains on, and the
input-normalisation statistics the model stores."""

from __future__ import annotations

import numpy as np
import torch

from ..errors import ConfigError, DataError
from ..models.xjepa import SYSID_PARAMS, area_downsample
from ..sim.policy import PROGRAM
from ..windows import glide_frames
from .step import to_device


class WindowSampler:
    """Holds a dataset's train episodes as (device) tensors and samples random windows.

    Episodes are drawn uniformly with replacement and the start step is uniform, except for a share
    ``aligned_share`` of the windows (:meth:`draw`), which start where their longest-horizon query reads one whole
    16-step program slot from its first action. Every batch carries
    the per-frame glide mask (``glide``, computed once per episode by :func:`pokeworld.windows.glide_frames`)
    for the glide-frame loss weight. Randomness comes from a dedicated CPU ``torch.Generator`` whose
    state is checkpointed, so resumption is exact. With ``non_blocking`` (the fast path) the two index
    tensors go to the device from pinned memory without making the host wait; the windows are the same.
    """

    def __init__(self, ds, episodes: np.ndarray, image_size: int, window: int, device: torch.device,
                 contact_channel: int = 6, seed: int = 0, with_params: bool = False, non_blocking: bool = False,
                 aligned_share: float = 0.0, horizon: int = PROGRAM):
        ep = np.asarray(episodes)
        if ep.size == 0:
            raise ConfigError("the dataset has no training episodes (split == 0)")
        T1 = ds.frames.shape[1]
        if window > T1:
            raise ConfigError(f"window {window} exceeds the episode length {T1} observations")
        self.window, self.device, self.non_blocking = window, device, non_blocking
        frames = torch.from_numpy(np.ascontiguousarray(ds.frames[ep]))
        chunks = [area_downsample(frames[i:i + 32], image_size) for i in range(0, len(ep), 32)]
        self.frames = torch.cat(chunks).to(device)
        self.proprio = torch.from_numpy(ds.proprio[ep]).float().to(device)
        self.touch = torch.from_numpy(ds.touch[ep]).float().to(device)
        acts = torch.from_numpy(ds.actions[ep]).float()
        self.actions = torch.cat([acts, acts.new_zeros(acts.shape[0], 1, acts.shape[2])], 1).to(device)
        self.params = None
        if with_params:
            missing = [k for k in SYSID_PARAMS if k not in ds.params]
            if missing:
                raise ConfigError(f"sysid control needs params {list(SYSID_PARAMS)}; the dataset lacks {missing}")
            self.params = torch.from_numpy(np.stack([ds.params[k][ep] for k in SYSID_PARAMS], -1)).float().to(device)

        try:
            glide = glide_frames(ds, contact_channel=contact_channel)[ep]
        except DataError:  # no labels and no contact channel: nothing can be called a glide frame
            glide = np.zeros((len(ep), T1), bool)
        self.glide_np = glide
        self.glide = torch.from_numpy(glide).to(device)
        # uniform multinomial (not randint) keeps the sampling stream of runs made before the glide
        # loss weight existed, so they resume exactly
        self.weights = torch.full((len(ep),), 1.0 / len(ep), dtype=torch.float64)
        self.num_starts = T1 - window + 1
        self.gen = torch.Generator(device="cpu")
        self.gen.manual_seed(seed)
        self.offsets = torch.arange(window, device=device)
        self.aligned_share = float(aligned_share)
        self.aligned_starts = program_aligned_starts(T1, window, horizon)
        if self.aligned_share > 0 and self.aligned_starts.numel() == 0:
            raise ConfigError(f"no window of {window} observations in {T1}-observation episodes puts a "
                              f"{horizon}-step query at a program slot start; lower program_aligned_share to 0")

    def sample(self, batch_size: int) -> dict[str, torch.Tensor]:
        """A batch of windows: frames (B, L, S, S) uint8, proprio/touch/actions (B, L, ·), params (B, 3)."""
        e, s = self.draw(batch_size, self.gen)
        return self.gather(to_device(e, self.device, self.non_blocking), to_device(s, self.device, self.non_blocking))

    def draw(self, batch_size: int, gen: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
        """Episode and start indices of ``batch_size`` windows (CPU tensors), drawn from ``gen``."""
        e = torch.multinomial(self.weights, batch_size, replacement=True, generator=gen)
        s = torch.randint(0, self.num_starts, (batch_size,), generator=gen)
        if self.aligned_share > 0:  # drawn only then, so runs without it keep their sampling stream exactly
            aligned = torch.rand(batch_size, generator=gen) < self.aligned_share
            slot = torch.randint(0, self.aligned_starts.numel(), (batch_size,), generator=gen)
            s = torch.where(aligned, self.aligned_starts[slot], s)
        return e, s

    def gather(self, e: torch.Tensor, s: torch.Tensor) -> dict[str, torch.Tensor]:
        """The windows at episode indices ``e`` and start steps ``s`` (any equal leading shape, on the device)."""
        t = s[..., None] + self.offsets
        ee = e[..., None]
        out = {"frames": self.frames[ee, t], "proprio": self.proprio[ee, t], "touch": self.touch[ee, t],
               "actions": self.actions[ee, t], "glide": self.glide[ee, t]}
        if self.params is not None:
            out["params"] = self.params[e]
        return out

    def glide_share(self, horizons, weight: float = 1.0) -> dict[str, float]:
        """Corpus-level glide shares of the prediction loss under this sampler's window distribution.

        ``glide_frame_share``: expected fraction s of target frames (t+Δ, Δ in ``horizons``) that are
        glide frames, i.e. the glide loss share at weight 1; ``glide_loss_share_expected``: the share
        of the loss weight mass at ``weight`` W, W·s_Δ / (W·s_Δ + 1 − s_Δ) averaged over horizons
        (ratio of expected masses, which the per-batch share approaches for large batches).
        """
        g = self.glide_np.astype(np.float64)
        c = np.concatenate([np.zeros((g.shape[0], 1)), np.cumsum(g, 1)], 1)
        st = np.arange(self.num_starts)
        base, share = [], []
        for d in horizons:
            if d >= self.window:
                continue
            s = float((c[:, st + self.window] - c[:, st + d]).mean() / (self.window - d))
            base.append(s)
            mass = weight * s + (1.0 - s)
            share.append(weight * s / mass if mass > 0 else 0.0)
        if not base:
            raise ConfigError(f"no horizon in {tuple(horizons)} is shorter than the window {self.window}")
        return {"glide_frame_share": float(np.mean(base)), "glide_loss_share_expected": float(np.mean(share))}

def program_aligned_starts(num_obs: int, window: int, horizon: int = PROGRAM) -> torch.Tensor:
    """Window starts (int64) whose query position a = window − 1 − ``horizon`` (the last position with a
    ``horizon``-step target: the most context before it, as the planner has) falls on a program slot start 16·j,
    so the Δ = ``horizon`` head reads the slot's whole program from its first action — the planner's query. With
    open-loop slots (``PolicyConfig.open_loop_share``) such windows see one program executed exactly."""
    anchor = window - 1 - horizon
    starts = [PROGRAM * j - anchor for j in range(num_obs // PROGRAM + 1)]
    return torch.tensor([s for s in starts if 0 <= s <= num_obs - window], dtype=torch.int64)


def data_stats(ds, episodes: np.ndarray) -> dict[str, np.ndarray]:
    """Normalisation statistics from the training episodes (model buffers)."""
    ep = np.asarray(episodes)
    st = {}
    for name, arr in (("proprio", ds.proprio[ep]), ("touch", ds.touch[ep]), ("action", ds.actions[ep])):
        flat = arr.reshape(-1, arr.shape[-1]).astype(np.float64) if arr.size else np.zeros((1, arr.shape[-1]))
        st[f"{name}_mean"], st[f"{name}_std"] = flat.mean(0), flat.std(0)
    if all(k in ds.params for k in SYSID_PARAMS):
        p = np.stack([ds.params[k][ep] for k in SYSID_PARAMS], -1).astype(np.float64)
        st["param_mean"], st["param_std"] = p.mean(0), p.std(0)
    return st


__all__ = ["WindowSampler", "data_stats", "program_aligned_starts"]
