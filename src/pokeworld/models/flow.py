"""A small self-supervised optical-flow estimator (the "frozen flow sensor" of paper §4.5 / App. C).

Trained on consecutive frames only — no labels: a CNN maps a frame pair (I0, I1) to a dense displacement
field f (pixels per step, at a quarter of the frame resolution, bilinearly upsampled), and the loss is

* photometric: Charbonnier distance between I0(x) and I1 warped back by f, I1(x + f(x)), summed over three
  scales (frames and flow area-pooled by 1, 2, 4) — a uniform disk on a black background only constrains
  flow at its edges, and the coarse scales widen the basin so displacements of several pixels (a gliding
  object moves up to ≈ 6 px per step) still get a gradient;
* smoothness: mean absolute first differences of f, which fills the textureless interior and background.

After training the estimator is frozen; :func:`object_flow` reads the object's velocity from it as the
intensity-weighted mean flow over the frame with the finger disk masked out (the finger position is known
from proprioception, as for the pixel-derived certificates), converted to arena units per second.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from ..checkpoint import load, save
from ..config import from_preset
from ..errors import ConfigError, DataError


@dataclass
class FlowConfig:
    """Train the self-supervised flow estimator."""

    steps: int = 1500
    """Optimisation steps."""
    batch_size: int = 32
    """Frame pairs per step."""
    lr: float = 2e-3
    """Adam learning rate (cosine-decayed to zero)."""
    width: int = 32
    """Channels of the convolutional trunk."""
    smooth_weight: float = 0.05
    """Weight of the first-order smoothness term against the photometric term."""
    moving_only: bool = True
    """Train on pairs in which some pixel changes (frame difference only, no labels): static pairs carry
    no photometric signal and would only teach the smoothness prior."""
    seed: int = 0
    """Seed of initialisation and pair sampling."""

    def __post_init__(self) -> None:
        if self.steps < 1 or self.batch_size < 1 or self.width < 4:
            raise ConfigError("flow estimator needs steps >= 1, batch_size >= 1 and width >= 4")
        if self.smooth_weight < 0 or self.lr <= 0:
            raise ConfigError("smooth_weight must be >= 0 and lr > 0")


PRESETS = {"tiny": {"steps": 20, "batch_size": 8, "width": 8}, "cpu": {}, "paper": {"steps": 4000, "batch_size": 64}}


def make_config(preset: str = "cpu", **overrides) -> FlowConfig:
    return from_preset(FlowConfig, PRESETS, preset, **overrides)


class FlowNet(nn.Module):
    """(B, 2, H, W) frame pair in [0, 1] -> (B, 2, H, W) displacement (dx, dy) in pixels; H, W divisible by 4."""

    def __init__(self, width: int = 32):
        super().__init__()
        w = width
        act = nn.LeakyReLU(0.1)
        self.body = nn.Sequential(
            nn.Conv2d(3, w, 3, padding=1), act,
            nn.Conv2d(w, w, 3, stride=2, padding=1), act,
            nn.Conv2d(w, 2 * w, 3, stride=2, padding=1), act,
            nn.Conv2d(2 * w, 2 * w, 3, padding=2, dilation=2), act,
            nn.Conv2d(2 * w, 2 * w, 3, padding=4, dilation=4), act,
            nn.Conv2d(2 * w, w, 3, padding=1), act,
            nn.Conv2d(w, 2, 3, padding=1))
        self.config = {"width": width}

    def forward(self, pair: torch.Tensor) -> torch.Tensor:
        H, W = pair.shape[-2:]
        if H % 4 or W % 4:
            raise DataError(f"flow estimator needs frame sides divisible by 4, got {H}x{W}")
        x = torch.cat([pair, pair[:, 1:2] - pair[:, 0:1]], 1)
        coarse = self.body(x)  # quarter resolution, in full-resolution pixels
        return F.interpolate(coarse, size=(H, W), mode="bilinear", align_corners=False)


def warp(img: torch.Tensor, flow: torch.Tensor) -> torch.Tensor:
    """``img`` (B, 1, H, W) sampled at x + flow(x) (bilinear, zeros outside)."""
    B, _, H, W = img.shape
    ys, xs = torch.meshgrid(torch.arange(H, dtype=img.dtype, device=img.device),
                            torch.arange(W, dtype=img.dtype, device=img.device), indexing="ij")
    gx = (xs[None] + flow[:, 0]) * (2.0 / (W - 1)) - 1.0
    gy = (ys[None] + flow[:, 1]) * (2.0 / (H - 1)) - 1.0
    return F.grid_sample(img, torch.stack([gx, gy], -1), mode="bilinear", padding_mode="zeros", align_corners=True)


def flow_loss(net: FlowNet, pair: torch.Tensor, smooth_weight: float) -> tuple[torch.Tensor, dict]:
    """Photometric (three scales) + smoothness loss of ``net`` on frame pairs (B, 2, H, W) in [0, 1]."""
    flow = net(pair)
    photo = pair.new_zeros(())
    for s in (1, 2, 4):
        p = F.avg_pool2d(pair, s) if s > 1 else pair
        f = F.avg_pool2d(flow, s) / s if s > 1 else flow
        diff = p[:, 0:1] - warp(p[:, 1:2], f)
        photo = photo + torch.sqrt(diff.pow(2) + 1e-6).mean() * s  # coarse scales have fewer, blurrier pixels
    smooth = (flow[..., 1:, :] - flow[..., :-1, :]).abs().mean() + (flow[..., 1:] - flow[..., :-1]).abs().mean()
    return photo + smooth_weight * smooth, {"photometric": float(photo.detach()), "smoothness": float(smooth.detach())}


def train_flow(frames: np.ndarray, cfg: FlowConfig, log_every: int = 0) -> FlowNet:
    """Train on consecutive frames of ``frames`` (E, T+1, H, W) uint8 — no labels — and return the frozen net."""
    if frames.ndim != 4 or frames.shape[1] < 2:
        raise DataError(f"frames must be (E, T+1>=2, H, W), got {frames.shape}")
    g = torch.Generator().manual_seed(cfg.seed)
    torch.manual_seed(cfg.seed)
    E, T1 = frames.shape[:2]
    pairs = np.stack(np.meshgrid(np.arange(E), np.arange(T1 - 1), indexing="ij"), -1).reshape(-1, 2)
    if cfg.moving_only:
        moved = np.concatenate([(f[:, 1:] != f[:, :-1]).any((2, 3)) for f in np.array_split(frames, max(1, E // 64))]
                               ).reshape(-1)  # (E, T) in the (episode, step) order of ``pairs``
        if moved.any():
            pairs = pairs[moved]
    net = FlowNet(cfg.width)
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, cfg.steps)
    for step in range(cfg.steps):
        idx = pairs[torch.randint(len(pairs), (cfg.batch_size,), generator=g).numpy()]
        pair = torch.from_numpy(np.stack([frames[idx[:, 0], idx[:, 1]], frames[idx[:, 0], idx[:, 1] + 1]], 1))
        loss, terms = flow_loss(net, pair.float() / 255.0, cfg.smooth_weight)
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        if log_every and (step % log_every == 0 or step == cfg.steps - 1):
            print(f"[flow] step {step:5d} loss {loss.item():.4f} photometric {terms['photometric']:.4f} "
                  f"smoothness {terms['smoothness']:.4f}")
    net.eval()
    for p in net.parameters():
        p.requires_grad_(False)
    return net


@torch.no_grad()
def object_flow(net: FlowNet, frames: np.ndarray, finger_pos: np.ndarray | None = None, finger_radius: float = 0.06,
                arena: float = 1.0, dt: float = 0.05, batch: int = 512) -> np.ndarray:
    """Object velocity read off the frozen flow: (E, T+1, 2) arena units / s (zero at t = 0).

    The estimate at observation t uses frames t-1 and t only (causal, like every other input channel): the
    intensity-weighted mean of the flow from t-1 to t over frame t-1, with the finger disk (``finger_pos``
    (E, T+1, 2) from proprioception; None: no mask) masked out with a one-pixel margin.
    """
    E, T1, H, W = frames.shape
    out = np.zeros((E, T1, 2), np.float32)
    xs = (np.arange(W) + 0.5) * arena / W
    ys = (np.arange(H) + 0.5) * arena / H
    e_idx, t_idx = np.meshgrid(np.arange(E), np.arange(1, T1), indexing="ij")
    e_idx, t_idx = e_idx.ravel(), t_idx.ravel()
    for i in range(0, len(e_idx), batch):
        e, t = e_idx[i:i + batch], t_idx[i:i + batch]
        f0 = frames[e, t - 1].astype(np.float32) / 255.0
        f1 = frames[e, t].astype(np.float32) / 255.0
        flow = net(torch.from_numpy(np.stack([f0, f1], 1))).numpy()  # (B, 2, H, W) pixels
        weight = f0.copy()
        if finger_pos is not None:
            fp = finger_pos[e, t - 1]
            d2 = (xs[None, None, :] - fp[:, 0, None, None]) ** 2 + (ys[None, :, None] - fp[:, 1, None, None]) ** 2
            weight = weight * (d2 > (finger_radius + 1.5 * arena / W) ** 2)
        mass = weight.sum((1, 2))
        v = (flow * weight[:, None]).sum((2, 3)) / np.maximum(mass, 1e-6)[:, None]
        v[mass < 1e-3] = 0.0  # object hidden: no reading
        out[e, t] = v * np.array([arena / W, arena / H], np.float32) / dt
    return out


def log_speed(velocity: np.ndarray, floor: float = 0.01) -> np.ndarray:
    """log max(|v|, floor): the coordinate in which glide decay is linear (Δ log|v| = -γ Δt)."""
    return np.log(np.maximum(np.linalg.norm(velocity, axis=-1), floor)).astype(np.float32)


def save_flow(net: FlowNet, path, meta: dict) -> None:
    save({"state": net.state_dict(), "config": net.config, "meta": meta}, path)


def load_flow(path) -> FlowNet:
    ck = load(path)
    net = FlowNet(**ck["config"])
    net.load_state_dict(ck["state"])
    net.eval()
    return net


__all__ = ["FlowConfig", "FlowNet", "PRESETS", "make_config", "train_flow", "object_flow", "log_speed", "flow_loss",
           "warp", "save_flow", "load_flow"]
