"""One optimisation step and what it is built from: the model's constructor arguments, the optimizer and its
schedule, the loss's fixed arguments, and the per-step SIGReg directions and row subsets drawn on the host."""

from __future__ import annotations

import math
import warnings
from typing import Any

import torch

from ..losses import random_directions, subsample_index
from .config import TrainConfig


def to_device(x: torch.Tensor, dev: torch.device, non_blocking: bool = False) -> torch.Tensor:
    """Host tensor -> ``dev``. A plain copy from pageable memory makes the host wait for the GPU
    stream; from pinned memory with ``non_blocking`` it is queued and the host runs ahead."""
    if non_blocking and dev.type == "cuda":
        return x.pin_memory().to(dev, non_blocking=True)
    return x.to(dev)

def compiled(fn, mode: str | None = None):
    """``torch.compile(fn, mode=mode)`` without the warnings torch's own compiler stack raises as it loads:
    inductor imports ``torch.utils.mkldnn``, whose classes are built with torch's deprecated
    ``torch.jit.script_method`` (a DeprecationWarning for each of its 14 methods, about nothing pokeworld does).
    That module is imported first with exactly that warning ignored; anything else still warns."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r"`torch\.jit\.script_method` is deprecated",
                                category=DeprecationWarning)
        import torch.utils.mkldnn  # noqa: F401 - loaded here, quietly, before torch.compile loads it
    return torch.compile(fn, mode=mode)

def sigreg_seed(cfg: TrainConfig, step: int) -> int:
    """Seed of the step's SIGReg directions: a function of (seed, step) only, so identical on every
    rank and after resume."""
    return cfg.seed * 1_000_003 + step

def sigreg_directions(cfg: TrainConfig, step: int, dev: torch.device, non_blocking: bool = False) -> torch.Tensor:
    """The step's SIGReg directions (D, K), drawn on the host exactly as :func:`pokeworld.losses.sigreg`
    draws them from :func:`sigreg_seed`, so both paths regularise along the same directions."""
    k = cfg.token_dirs if cfg.tokens else cfg.sigreg_dirs
    return to_device(random_directions(cfg.latent_dim, k, sigreg_seed(cfg, step)), dev, non_blocking)

def sigreg_row_index(cfg: TrainConfig, step: int, dev: torch.device, non_blocking: bool = False) -> torch.Tensor | None:
    """The step's pooled-SIGReg row subset ((sigreg_rows,) int64 indices into the batch × window rows), drawn
    on the host exactly as :func:`pokeworld.losses.sigreg` draws it from :func:`sigreg_seed`; None when
    nothing is subsampled (sigreg_pool='step', or batch × window ≤ sigreg_rows)."""
    if cfg.sigreg_pool != "pooled" or cfg.tokens:
        return None
    idx = subsample_index(cfg.batch_size * cfg.window, cfg.sigreg_rows, sigreg_seed(cfg, step))
    return None if idx is None else to_device(idx, dev, non_blocking)

def decay_split(named_ndims) -> tuple[list[str], list[str]]:
    """Parameter names with weight decay (matrices and kernels) and without (biases, norms, positional
    embeddings), from ``(name, ndim)`` pairs in order. The single rule, so stacked training maps optimizer
    moments onto the same indices as :func:`make_optimizer`."""
    decay, no_decay = [], []
    for n, ndim in named_ndims:
        (decay if ndim >= 2 and "pos" not in n else no_decay).append(n)
    return decay, no_decay

def make_optimizer(model: torch.nn.Module, cfg: TrainConfig, fused: bool = False) -> torch.optim.AdamW:
    """AdamW without weight decay on biases, norms and positional embeddings; ``fused`` = one kernel
    for the whole update instead of a few per parameter group."""
    named = dict(model.named_parameters())
    decay, no_decay = ([named[n] for n in names] for names in decay_split((n, p.ndim) for n, p in named.items()))
    return torch.optim.AdamW([{"params": decay, "weight_decay": cfg.weight_decay},
                              {"params": no_decay, "weight_decay": 0.0}], lr=cfg.lr, betas=(0.9, 0.999),
                             fused=True if fused else None)

def loss_kwargs(cfg: TrainConfig) -> dict[str, Any]:
    """Keyword arguments of :meth:`XJEPA.loss` fixed by the config (the per-step ones are added by the loop)."""
    return dict(sigreg_weight=cfg.sigreg_weight, sigreg_dirs=cfg.sigreg_dirs, sigreg_knots=cfg.sigreg_knots,
                token_rows=cfg.token_rows, token_dirs=cfg.token_dirs, touch_contact_weight=cfg.touch_contact_weight,
                proprio_weight=cfg.proprio_weight, touch_weight=cfg.touch_weight, sysid_weight=cfg.sysid_weight,
                glide_loss_weight=cfg.glide_loss_weight, belief_kl_weight=cfg.belief_kl_weight,
                motion_loss_weight=cfg.motion_loss_weight, sigreg_pool=cfg.sigreg_pool, sigreg_rows=cfg.sigreg_rows,
                gnll_beta=cfg.gnll_beta, sigreg_reference_rows=cfg.sigreg_reference_rows, sigreg_t_max=cfg.sigreg_t_max,
                latent_horizon_weights=tuple(cfg.latent_horizon_weights),
                sensor_horizon_weights=tuple(cfg.sensor_horizon_weights), contact_weighting=cfg.contact_weighting)

def train_step(model: torch.nn.Module, opt: torch.optim.Optimizer, cfg: TrainConfig, batch: dict, step: int,
               dev: torch.device, loss_kw: dict[str, Any], amp: bool = False, fast: bool = False,
               loss_fn=None) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """One optimisation step: loss (bf16 autocast when ``amp``), backward, gradient clipping, AdamW.

    ``loss_fn`` defaults to ``model`` (pass a compiled wrapper to time ``torch.compile``). Returns the
    detached loss and the loss terms, with ``grad_norm`` when clipping is on; nothing is read on the host.
    """
    dirs = sigreg_directions(cfg, step, dev, non_blocking=fast)
    rows = sigreg_row_index(cfg, step, dev, non_blocking=fast)
    extra = {} if rows is None else {"sigreg_row_index": rows}  # the subset uploaded ahead, like the directions
    with torch.autocast(dev.type, dtype=torch.bfloat16, enabled=amp):
        loss, terms = (model if loss_fn is None else loss_fn)(batch, sigreg_seed=sigreg_seed(cfg, step),
                                                              sigreg_directions=dirs, **extra, **loss_kw)
    opt.zero_grad(set_to_none=True)
    loss.backward()
    if cfg.grad_clip > 0:
        terms["grad_norm"] = torch.nn.utils.clip_grad_norm_(model.parameters(), cfg.grad_clip).detach()
    opt.step()
    return loss.detach(), terms

def model_kwargs(cfg: TrainConfig, dims: tuple[int, int, int]) -> dict[str, Any]:
    """XJEPA constructor arguments for ``cfg`` and data dims (Dp, Dt, Da)."""
    return dict(variant=cfg.variant, proprio_dim=dims[0], touch_dim=dims[1], action_dim=dims[2],
                image_size=cfg.image_size, channels=tuple(cfg.channels), latent_dim=cfg.latent_dim, width=cfg.width,
                depth=cfg.depth, heads=cfg.heads, dropout=cfg.dropout,
                horizons=tuple(cfg.horizons), objective=cfg.objective, tokens=cfg.tokens,
                sysid=cfg.sysid_weight > 0, max_len=max(128, cfg.window), vec_dim=cfg.vec_dim,
                contact_channel=cfg.contact_channel, pool=cfg.pool, belief_dim=cfg.belief_dim,
                motion_channel=cfg.motion_channel, gnll_heads=cfg.gnll_heads, gnll_variance=cfg.gnll_variance,
                gnll_logvar_bound=cfg.gnll_logvar_bound, head_layers=cfg.head_layers, encoder=cfg.encoder,
                fuse_dim=cfg.fuse_dim, head_form=cfg.head_form, sensor_horizons=tuple(cfg.sensor_horizons))

def lr_lambda(step: int, warmup: int, total: int) -> float:
    """Linear warm-up to 1, then cosine decay to 0 at ``total``."""
    if step < warmup:
        return (step + 1) / warmup
    p = min(1.0, (step - warmup) / max(1, total - warmup))
    return 0.5 * (1 + math.cos(math.pi * p))


__all__ = ["to_device", "sigreg_seed", "sigreg_directions", "sigreg_row_index", "decay_split", "make_optimizer",
           "loss_kwargs", "train_step", "model_kwargs", "lr_lambda"]
