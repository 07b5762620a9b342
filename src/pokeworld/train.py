"""Training X-JEPA models (paper App. B "Optimization"): one readable file.

``run(cfg)`` trains one model into ``cfg.out`` and returns that directory:

* ``config.json`` — the full :class:`TrainConfig`; re-running with a conflicting config
  (anything but the bookkeeping fields in :data:`RESUMABLE_FIELDS`) raises ConfigError;
* ``metrics.jsonl`` — one JSON object per ``log_every`` steps (step, loss terms, lr, frames/s);
* ``tb/`` — TensorBoard events (``tensorboard=True``);
* ``ckpt.pt`` — written atomically every ``ckpt_every`` steps: model, optimizer, scheduler,
  python/numpy/torch(/cuda) RNG states, the window sampler's generator, step;
* ``final.pt`` + ``DONE`` — at the end. A finished run returns immediately; an interrupted
  one resumes from ``ckpt.pt`` and reproduces the uninterrupted run bit-for-bit on CPU.

The whole dataset lives in memory as tensors (on the GPU when there is one); a batch
is gathered with two index tensors, so window sampling never bottlenecks a step.

Fast path (``fast``; on by default on CUDA, off on CPU): the per-step window indices and SIGReg
directions are drawn on the host exactly as in the plain path but uploaded from pinned memory
without blocking, AdamW is fused, and nothing in a step waits for the GPU — loss terms are
summed on the device and read (with the NaN check) only when a row is logged or a checkpoint
written. ``compile`` and ``channels_last`` are separate options. ``deadline`` checkpoints and
returns early (without ``DONE``) for time-sliced jobs.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import random
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from . import checkpoint
from .config import from_preset, to_dict
from .errors import ConfigError, DataError
from .faults import crash_point
from .losses import SIGREG_POOLS, random_directions, subsample_index
from .models.xjepa import (GNLL_HEADS, OBJECTIVES, SYSID_PARAMS, XJEPA, area_downsample, check_gnll_variance,
                           check_variant)


@dataclass
class TrainConfig:
    """Train one X-JEPA variant (paper §3, App. B).

    The field defaults are the ``paper`` preset (App. B sizes; needs a GPU). :func:`make_config` and the
    ``pokeworld train`` command start from the ``cpu`` preset instead; see :data:`PRESETS` for what each costs.
    """

    variant: str = "VFX"
    """Variant (inputs × targets): one of V, VF, VX_p, VX_t, VX, VFX (paper Table "targets")."""
    data: str = "data/sim"
    """Dataset directory (``pokeworld.data`` format)."""
    out: str = "runs/xjepa"
    """Run directory: config, metrics, TensorBoard, checkpoints. Re-running resumes or returns."""
    seed: int = 0
    """Seed for initialisation, window sampling, dropout and SIGReg directions."""
    steps: int = 20000
    """Total optimisation steps (also sets the cosine schedule length)."""
    stop_at: int = 0
    """Stop (checkpointed, not finished) after this global step; 0 = run to ``steps``. For time-sliced jobs."""
    batch_size: int = 128
    """Windows per step (paper: 96–128)."""
    window: int = 24
    """Observations per training window; must exceed the largest horizon."""
    horizons: tuple[int, ...] = (1, 4, 16)
    """Direct prediction horizons Δ; (1,) is the single-horizon mode."""
    objective: str = "latent"
    """'latent' (MSE to latent targets), 'gnll' (latent heads also predict a log-variance), 'recon'
    (pixel-reconstruction control: shared deconv decoder replaces latent targets, SIGReg omitted) or 'belief'
    (episode-level latent: amortised posterior over the window, learned causal prior, KL term; an ELBO whose
    optimum is not a conditional mean of the future, docs/model.md "belief")."""
    gnll_heads: str = "latent"
    """objective='gnll': which heads are Gaussian NLL — 'latent' (the latent Δ-heads; proprio/touch stay MSE)
    or 'all' (proprio/touch heads also predict a log-variance, so no target gains weight over another through
    its learned precision; docs/model.md "The Gaussian-NLL control")."""
    gnll_variance: str = "free"
    """objective='gnll': variance parameterisation of every NLL head (the paper gives none; docs/design.md
    "Gaussian NLL: variance parameterisation"). 'free' (the runs so far): a per-element, per-frame log-variance
    output clamped to [−8, 8], so a precision can reach e^8 ≈ 2,981; 'bounded': that output squashed smoothly
    into (−b, b), b = ``gnll_logvar_bound``, so no precision exceeds e^b; 'beta': β-NLL (Seitzer et al. 2022),
    each element's NLL times stop_gradient(σ^{2β}), β = ``gnll_beta``; 'per_head': heads output the mean only
    and each head (horizon; proprio/touch too with gnll_heads='all') learns one log-variance scalar, so heads are
    rescaled against each other but no frame is reweighted against another (adds parameters)."""
    gnll_beta: float = 0.5
    """gnll_variance='beta': β in [0, 1] of β-NLL; 0 is the plain NLL, 1 gives the mean the MSE gradient."""
    gnll_logvar_bound: float = 2.0
    """gnll_variance='bounded': bound b of the squashed log-variance b·tanh(s/b) (precision ≤ e^b ≈ 7.4 at 2)."""
    belief_dim: int = 8
    """objective='belief': dimension K of the episode-level latent u."""
    belief_kl_weight: float = 0.01
    """objective='belief': weight β of the mean-over-steps KL(q(u | window) ‖ p(u | h_t)) against the per-dim
    MSE prediction terms (β = 2σ²/D for a Gaussian likelihood of variance σ² on D latent dims)."""
    tokens: bool = False
    """Token-based control: spatial tokens from the last CNN map, dense aligned Δ=1 token prediction on top of the
    shared heads (the Δ > 1 latent heads predict the token-mean latent from the token-mean state, the touch /
    proprio heads keep every horizon), token-level SIGReg on subsampled rows (paper §3, App. B)."""
    sysid_weight: float = 0.0
    """Weight of the system-ID control head (trunk -> whitened (log m, γ, log k)); paper control: 0.5; 0 = off."""
    image_size: int = 64
    """Encoder input side; stored frames are area-pooled down to it on load (must divide evenly by 16)."""
    channels: tuple[int, ...] = (32, 64, 128, 256)
    """CNN channels of the four stride-2 stages."""
    latent_dim: int = 128
    """Latent (embedding) dimension."""
    width: int = 192
    """Predictor transformer width."""
    depth: int = 4
    """Predictor transformer layers."""
    heads: int = 8
    """Attention heads."""
    dropout: float = 0.1
    """Dropout in the predictor."""
    vec_dim: int = 64
    """Hidden/output width of the proprio and touch MLP encoders."""
    pool: bool = False
    """Average the CNN's last feature map over space instead of flattening it (position then has
    to be learned into the channels; tests whether a latent can discard visible state)."""
    sigreg_weight: float = 0.02
    """SIGReg weight λ."""
    sigreg_dirs: int = 1024
    """Random unit directions per step for SIGReg (resampled every step)."""
    sigreg_knots: int = 17
    """Trapezoid knots on [0, 3] for the Epps–Pulley integral."""
    sigreg_pool: str = "step"
    """Rows of one SIGReg statistic (global-latent models; docs/design.md "SIGReg: per-step or pooled rows"):
    'step' (the runs so far, LeWM's reading) — per time step over the batch's rows, averaged over the window;
    'pooled' — one statistic over all batch × window latents, subsampled to ``sigreg_rows`` (the paper's
    "4096 subsampled rows"). The statistic is N-scaled: its null level is the same, its excess under a
    departure from N(0, I) grows with N (window× at equal λ). Under DDP either is the global statistic over
    all ranks' rows (ECFs all-reduced)."""
    sigreg_rows: int = 4096
    """sigreg_pool='pooled': latent rows per step (per rank under DDP) the pooled statistic is computed on, a
    seeded random subset when batch × window exceeds it (paper: 4096); all rows otherwise."""
    token_rows: int = 4096
    """Token variant: token rows subsampled per step for SIGReg."""
    token_dirs: int = 256
    """Token variant: SIGReg directions per step."""
    touch_contact_weight: float = 4.0
    """Touch-loss weight on frames whose target contact flag is set (1 elsewhere)."""
    contact_channel: int = 6
    """Touch channel holding the contact flag (used for the contact weight and glide detection)."""
    proprio_weight: float = 1.0
    """Weight of the proprio forecasting loss (variants with a proprio target)."""
    touch_weight: float = 1.0
    """Weight of the touch forecasting loss (variants with a touch target)."""
    glide_loss_weight: float = 1.0
    """Weight W of glide target frames in every prediction-loss term (latent/recon Δ-heads, proprio and
    touch heads; not SIGReg), 1 on other frames; each term stays a weighted mean. Raises the glide share
    of the loss from s to W·s / (W·s + 1 − s) without changing the data (paper App. C dose–response 1:
    s ≈ 0.32 -> 0.65 / 0.88 / 0.97 at W = 4 / 16 / 64). Glide frame: no finger contact, object speed >
    0.02 and no wall contact (simulator labels; ``windows.glide_frames``), else touch contact flag off."""
    motion_channel: bool = True
    """Feed the encoder the temporal-difference channel x_t − x_{t−1} beside the frame (paper App. B); off =
    that channel is zero (the γ ledger's "motion channel off", same architecture)."""
    motion_loss_weight: float = 0.0
    """α of magnitude-weighted motion-forecast targets (the γ ledger): every latent Δ-head term weights its
    target frame by 1 + α·m/mean(m), m = the frame's mean absolute temporal difference; 0 = off."""
    lr: float = 3e-4
    """Peak AdamW learning rate."""
    warmup: int = 500
    """Linear warm-up steps before cosine decay to zero."""
    weight_decay: float = 0.05
    """AdamW weight decay."""
    grad_clip: float = 1.0
    """Global gradient-norm clip (0 = off)."""
    device: str = "auto"
    """'auto' (cuda if available, else cpu), 'cpu', 'cuda' or 'cuda:N'."""
    amp: bool = True
    """bf16 autocast where supported (CUDA with bf16); ignored on CPU, where bf16 is slower."""
    threads: int = 0
    """CPU threads for torch (0 = auto: half the usable cores, 1 on a 2-core machine; see ``auto_threads``)."""
    ckpt_every: int = 1000
    """Checkpoint every this many steps (and at the end / ``stop_at``)."""
    log_every: int = 100
    """Write metrics every this many steps."""
    tensorboard: bool = True
    """Also write TensorBoard events under ``out/tb``."""
    progress: bool = True
    """Show a tqdm progress bar."""
    ddp: bool = False
    """Opt-in multi-GPU DistributedDataParallel; launch with ``torchrun --nproc_per_node=N``."""
    fast: str = "auto"
    """Fast path: 'auto' (on for CUDA devices, off on CPU), 'on' or 'off'. Non-blocking pinned uploads of
    the step's window indices and SIGReg directions, fused AdamW, no host sync between log/checkpoint
    steps. Samples the same windows and directions as the plain path."""
    compile: bool = False
    """``torch.compile`` the model's loss (forward + backward graphs). Dropout masks then come from
    inductor's RNG, so a compiled run matches an eager one statistically, not bit-for-bit."""
    channels_last: bool = False
    """Keep conv weights/activations in channels-last layout (faster cuDNN convs on tensor cores).
    Fixed for a run: the optimizer state in the checkpoint inherits the layout."""
    deadline: float = 0.0
    """Unix time after which the loop checkpoints and returns without ``DONE`` (0 = none); a run whose
    deadline has passed before it starts returns at once. For time-sliced jobs (``pokeworld map
    --time-budget-min``); re-running resumes."""


#: Field overrides per preset (costs as in ``cli.PRESET_COSTS``).
#: ``paper`` = App. B; needs a GPU: on one H100 0.041 s/step on the fast path (≈ 14 min per 20k-step model), 0.030
#: compiled, 0.027 s per model-step for six models stacked (docs/model.md "Fast path", "Several models").
#: ``cpu``: 32×32 frames, narrower CNN/predictor, batch 32, 256 SIGReg directions, 4,000 steps (stiffness
#: enters the VFX latent only after ~2,000 steps at this size, docs/model.md); ≈ 0.26 s/step on one
#: core, ≈ 20 min per model with two models side by side on 2 cores. ``tiny``: unit tests, seconds.
PRESETS: dict[str, dict[str, Any]] = {
    "paper": {},
    "cpu": dict(image_size=32, channels=(16, 32, 64, 64), width=128, depth=2, heads=4, vec_dim=32,
                batch_size=32, steps=4000, warmup=100, lr=1e-3, sigreg_dirs=256, token_rows=1024,
                token_dirs=128, ckpt_every=500, log_every=50),
    "tiny": dict(image_size=16, channels=(4, 8, 8, 8), latent_dim=16, width=16, depth=1, heads=2, vec_dim=8,
                 batch_size=4, window=18, steps=10, warmup=2, sigreg_dirs=16, token_rows=64, token_dirs=16,
                 ckpt_every=5, log_every=5, tensorboard=False, progress=False, device="cpu"),
}
# the demo's model: the cpu preset with the paper's 64-wide proprio/touch encoders, at a quarter of its batch for
# more updates per CPU-second; stiffness enters VFX faster per frame seen (docs/model.md "Learning speed")
PRESETS["demo"] = {**PRESETS["cpu"], "vec_dim": 64, "batch_size": 8, "steps": 2200, "ckpt_every": 1000,
                   "log_every": 100}

#: Fields that may differ when re-running into an existing run directory.
RESUMABLE_FIELDS = ("steps", "stop_at", "ckpt_every", "log_every", "tensorboard", "progress", "threads", "device",
                    "fast", "compile", "deadline")

#: Fields removed from TrainConfig -> the value with which a run made before the removal behaves
#: exactly like the current code; a run that set anything else conflicts. (Fields added later are
#: compared at their default, which by convention reproduces the behaviour before they existed.)
RETIRED_FIELDS: dict[str, Any] = {"glide_episode_weight": 1.0}


def field_defaults() -> dict[str, Any]:
    """TrainConfig field -> its default (the value a run gets when nothing overrides it)."""
    return {f.name: f.default for f in dataclasses.fields(TrainConfig)}


def make_config(preset: str = "cpu", **overrides: Any) -> TrainConfig:
    """``TrainConfig`` from a named preset plus field overrides; validated."""
    cfg = from_preset(TrainConfig, PRESETS, preset, **overrides)
    validate(cfg)
    return cfg


def validate(cfg: TrainConfig) -> None:
    """Raise ConfigError on inconsistent settings."""
    check_variant(cfg.variant)
    if cfg.objective not in OBJECTIVES:
        raise ConfigError(f"unknown objective {cfg.objective!r}; choose one of {list(OBJECTIVES)}")
    hs = tuple(cfg.horizons)
    if not hs or min(hs) < 1 or 1 not in hs:
        raise ConfigError(f"horizons must be positive and include 1, got {hs}")
    if max(hs) >= cfg.window:
        raise ConfigError(f"window {cfg.window} must exceed the largest horizon {max(hs)}")
    if cfg.tokens and cfg.objective != "latent":
        raise ConfigError("tokens=True supports objective='latent' only")
    if cfg.objective == "belief" and cfg.belief_dim < 1:
        raise ConfigError(f"belief_dim must be ≥ 1, got {cfg.belief_dim}")
    if cfg.gnll_heads not in GNLL_HEADS:
        raise ConfigError(f"unknown gnll_heads {cfg.gnll_heads!r}; choose one of {list(GNLL_HEADS)}")
    if cfg.gnll_heads != "latent" and cfg.objective != "gnll":
        raise ConfigError(f"gnll_heads={cfg.gnll_heads!r} needs objective='gnll'")
    check_gnll_variance(cfg.gnll_variance, cfg.objective, cfg.gnll_logvar_bound)
    if not 0.0 <= cfg.gnll_beta <= 1.0:
        raise ConfigError(f"gnll_beta must lie in [0, 1], got {cfg.gnll_beta}")
    # an option that the chosen parameterisation ignores would only make the run's config lie about it
    if cfg.gnll_beta != 0.5 and cfg.gnll_variance != "beta":
        raise ConfigError(f"gnll_beta={cfg.gnll_beta} applies to gnll_variance='beta' only")
    if cfg.gnll_logvar_bound != 2.0 and cfg.gnll_variance != "bounded":
        raise ConfigError(f"gnll_logvar_bound={cfg.gnll_logvar_bound} applies to gnll_variance='bounded' only")
    if cfg.sigreg_pool not in SIGREG_POOLS:
        raise ConfigError(f"unknown sigreg_pool {cfg.sigreg_pool!r}; choose one of {list(SIGREG_POOLS)}")
    if cfg.sigreg_rows < 1:
        raise ConfigError(f"sigreg_rows must be ≥ 1, got {cfg.sigreg_rows}")
    if cfg.sigreg_pool != "step":
        if cfg.tokens:
            raise ConfigError("sigreg_pool applies to global latents; tokens=True always pools token rows "
                              "(token_rows)")
        if cfg.objective == "recon":
            raise ConfigError("objective='recon' has no SIGReg to pool")
    elif cfg.sigreg_rows != 4096:
        raise ConfigError(f"sigreg_rows={cfg.sigreg_rows} applies to sigreg_pool='pooled' only")
    if cfg.image_size % 16 or cfg.image_size < 16:
        raise ConfigError(f"image_size must be a multiple of 16 (4 stride-2 stages), got {cfg.image_size}")
    if len(cfg.channels) != 4:
        raise ConfigError(f"channels must list the 4 CNN stages, got {cfg.channels}")
    for name in ("steps", "batch_size", "log_every", "ckpt_every"):
        if getattr(cfg, name) < 1:
            raise ConfigError(f"{name} must be ≥ 1, got {getattr(cfg, name)}")
    if cfg.motion_loss_weight > 0 and cfg.objective == "recon":
        raise ConfigError("motion_loss_weight weights latent targets; objective='recon' has none")
    if min(cfg.glide_loss_weight, cfg.sysid_weight, cfg.sigreg_weight, cfg.belief_kl_weight,
           cfg.motion_loss_weight) < 0:
        raise ConfigError("weights must be non-negative")
    if not math.isfinite(cfg.glide_loss_weight):
        raise ConfigError(f"glide_loss_weight must be finite, got {cfg.glide_loss_weight}")
    if cfg.fast not in ("auto", "on", "off"):
        raise ConfigError(f"fast must be 'auto', 'on' or 'off', got {cfg.fast!r}")


def use_fast_path(cfg: TrainConfig, dev: torch.device) -> bool:
    """Whether ``cfg.fast`` selects the fast path on ``dev`` ('auto': CUDA only)."""
    return cfg.fast == "on" or (cfg.fast == "auto" and dev.type == "cuda")


def wall_clock() -> float:
    """Unix time for ``deadline`` checks (a module function so tests can fast-forward time)."""
    return time.time()


def to_device(x: torch.Tensor, dev: torch.device, non_blocking: bool = False) -> torch.Tensor:
    """Host tensor -> ``dev``. A plain copy from pageable memory makes the host wait for the GPU
    stream; from pinned memory with ``non_blocking`` it is queued and the host runs ahead."""
    if non_blocking and dev.type == "cuda":
        return x.pin_memory().to(dev, non_blocking=True)
    return x.to(dev)


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
                gnll_beta=cfg.gnll_beta)


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


# ---------------------------------------------------------------------- data in memory


class WindowSampler:
    """Holds a dataset's train episodes as (device) tensors and samples random windows.

    Episodes are drawn uniformly with replacement and the start step is uniform. Every batch carries
    the per-frame glide mask (``glide``, computed once per episode by :func:`pokeworld.windows.glide_frames`)
    for the glide-frame loss weight. Randomness comes from a dedicated CPU ``torch.Generator`` whose
    state is checkpointed, so resumption is exact. With ``non_blocking`` (the fast path) the two index
    tensors go to the device from pinned memory without making the host wait; the windows are the same.
    """

    def __init__(self, ds, episodes: np.ndarray, image_size: int, window: int, device: torch.device,
                 contact_channel: int = 6, seed: int = 0, with_params: bool = False, non_blocking: bool = False):
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
        from .windows import glide_frames

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

    def sample(self, batch_size: int) -> dict[str, torch.Tensor]:
        """A batch of windows: frames (B, L, S, S) uint8, proprio/touch/actions (B, L, ·), params (B, 3)."""
        e, s = self.draw(batch_size, self.gen)
        return self.gather(to_device(e, self.device, self.non_blocking), to_device(s, self.device, self.non_blocking))

    def draw(self, batch_size: int, gen: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
        """Episode and start indices of ``batch_size`` windows (CPU tensors), drawn from ``gen``."""
        e = torch.multinomial(self.weights, batch_size, replacement=True, generator=gen)
        return e, torch.randint(0, self.num_starts, (batch_size,), generator=gen)

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


def data_stats(ds, episodes: np.ndarray) -> dict[str, np.ndarray]:
    """Normalisation statistics from the training episodes (model buffers)."""
    ep = np.asarray(episodes)
    st = {}
    for name, arr in (("proprio", ds.proprio[ep]), ("touch", ds.touch[ep]), ("action", ds.actions[ep])):
        flat = arr.reshape(-1, arr.shape[-1]).astype(np.float64)
        st[f"{name}_mean"], st[f"{name}_std"] = flat.mean(0), flat.std(0)
    if all(k in ds.params for k in SYSID_PARAMS):
        p = np.stack([ds.params[k][ep] for k in SYSID_PARAMS], -1).astype(np.float64)
        st["param_mean"], st["param_std"] = p.mean(0), p.std(0)
    return st


def synthetic_dataset(num_episodes: int = 12, steps: int = 24, size: int = 32, seed: int = 0,
                      proprio_dim: int = 4, touch_dim: int = 7, action_dim: int = 2, glide_fraction: float = 0.25):
    """Tiny synthetic :class:`pokeworld.data.Dataset` for tests and smoke runs (no simulator needed).

    A finger blob follows integrated random actions; an object blob drifts and is pushed when the
    finger is close (touch channel 6 = contact flag). Params (log_m, gamma, log_k) are random.
    """
    from .data import Dataset

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


# ---------------------------------------------------------------------- model / checkpoint helpers


def model_kwargs(cfg: TrainConfig, dims: tuple[int, int, int]) -> dict[str, Any]:
    """XJEPA constructor arguments for ``cfg`` and data dims (Dp, Dt, Da)."""
    return dict(variant=cfg.variant, proprio_dim=dims[0], touch_dim=dims[1], action_dim=dims[2],
                image_size=cfg.image_size, channels=tuple(cfg.channels), latent_dim=cfg.latent_dim, width=cfg.width,
                depth=cfg.depth, heads=cfg.heads, dropout=cfg.dropout,
                horizons=tuple(cfg.horizons), objective=cfg.objective, tokens=cfg.tokens,
                sysid=cfg.sysid_weight > 0, max_len=max(128, cfg.window), vec_dim=cfg.vec_dim,
                contact_channel=cfg.contact_channel, pool=cfg.pool, belief_dim=cfg.belief_dim,
                motion_channel=cfg.motion_channel, gnll_heads=cfg.gnll_heads, gnll_variance=cfg.gnll_variance,
                gnll_logvar_bound=cfg.gnll_logvar_bound)


def lr_lambda(step: int, warmup: int, total: int) -> float:
    """Linear warm-up to 1, then cosine decay to 0 at ``total``."""
    if step < warmup:
        return (step + 1) / warmup
    p = min(1.0, (step - warmup) / max(1, total - warmup))
    return 0.5 * (1 + math.cos(math.pi * p))


class MetricsLog:
    """A run's metrics record: one JSON line per row in ``metrics.jsonl`` and, when ``tensorboard``, the same
    scalars under ``tb/`` (``purge_step`` drops events a resumed run will write again)."""

    def __init__(self, out: Path, tensorboard: bool, step: int):
        self.path = Path(out) / "metrics.jsonl"
        self.writer = None
        if tensorboard:
            from torch.utils.tensorboard import SummaryWriter

            self.writer = SummaryWriter(str(Path(out) / "tb"), purge_step=step or None)

    def write(self, row: dict[str, Any]) -> None:
        from .io import append_jsonl

        append_jsonl(self.path, row)
        if self.writer is not None:
            for k, v in row.items():
                if k != "step":
                    self.writer.add_scalar(f"train/{k}", v, row["step"])

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()


def write_final(out: Path, state: dict, model_kwargs: dict, cfg_dict: dict, step: int, note: str = "") -> None:
    """Write a finished run's ``final.pt`` (weights, model kwargs, config, step) and its ``DONE`` marker."""
    checkpoint.save({"model": state, "model_kwargs": model_kwargs, "config": cfg_dict, "step": step}, out / "final.pt")
    (out / "DONE").write_text(f"finished {step} steps{note}\n")


def speed_row(step: int, lr: float, n_steps: int, frames_per_step: int, seconds: float) -> dict[str, float]:
    """The timing fields of a metrics.jsonl row covering ``n_steps`` steps that took ``seconds``."""
    return {"step": step, "lr": lr, "frames_per_s": n_steps * frames_per_step / max(seconds, 1e-9),
            "steps_per_s": n_steps / max(seconds, 1e-9)}


def check_existing(cfg: TrainConfig) -> None:
    """Raise ConfigError if ``cfg.out`` holds a run whose config differs in anything but :data:`RESUMABLE_FIELDS`
    (fields added since are compared at their default, retired ones at :data:`RETIRED_FIELDS`)."""
    out = Path(cfg.out)
    if not (out / "config.json").exists():
        return
    old = json.loads((out / "config.json").read_text())
    default = to_dict(TrainConfig())
    diff = {k: (old.get(k, default[k]), v) for k, v in to_dict(cfg).items()
            if k not in RESUMABLE_FIELDS and old.get(k, default[k]) != v}
    diff.update({k: (old[k], "(removed)") for k, same in RETIRED_FIELDS.items() if old.get(k, same) != same})
    if diff:
        raise ConfigError(f"{out} already holds a run with a different config {diff} (old, new); "
                          "use another --out or delete the directory")


def restart_metrics(out: Path, step: int, start_row: dict[str, Any] | None = None) -> None:
    """Make ``metrics.jsonl`` match an uninterrupted run: on resume from ``step`` drop rows logged after the
    checkpoint; on a fresh start (``start_row``) replace the file with that step-0 row."""
    path = Path(out) / "metrics.jsonl"
    if start_row is not None:
        path.write_text(json.dumps(start_row, sort_keys=True) + "\n")
        return
    from .io import read_jsonl

    rows = [r for r in read_jsonl(path) if r.get("step", 0) <= step]
    path.write_text("".join(json.dumps(r, sort_keys=True) + "\n" for r in rows))


def finished_run_config(run_dir: str | os.PathLike) -> dict[str, Any]:
    """The config.json of a finished run; ConfigError when ``run_dir`` is not a run or has not finished."""
    run_dir = Path(run_dir)
    if not (run_dir / "config.json").exists():
        raise ConfigError(f"{run_dir} is not a training run (no config.json)")
    if not (run_dir / "DONE").exists():
        raise ConfigError(f"{run_dir} has not finished training; re-run `pokeworld train` to resume it")
    return json.loads((run_dir / "config.json").read_text())


def load_model(run_dir: str | os.PathLike, map_location: str | torch.device = "cpu", final: bool | None = None) -> XJEPA:
    """Load a trained model (eval mode) from a run directory: ``final.pt`` if present, else ``ckpt.pt``."""
    run_dir = Path(run_dir)
    path = run_dir / "final.pt"
    if final is False or not path.exists():
        path = run_dir / "ckpt.pt"
    if not path.exists():
        raise FileNotFoundError(f"{run_dir} holds no final.pt or ckpt.pt; train it with `pokeworld train`")
    ck = checkpoint.load(path, map_location=map_location)
    model = XJEPA(**ck["model_kwargs"])
    model.load_state_dict(ck["model"])
    return model.to(map_location).eval()


def auto_threads() -> int:
    """Half the usable cores (≥ 1, ≤ 8). On a shared 2-core machine one thread per process is ~4× faster
    than two (measured: oversubscription with other workers dominates small-matrix CPU training)."""
    n = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, min(8, n // 2))


def _device(cfg: TrainConfig, local_rank: int = 0) -> torch.device:
    if cfg.device == "auto":
        return torch.device(f"cuda:{local_rank}" if torch.cuda.is_available() else "cpu")
    dev = torch.device(cfg.device)
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise ConfigError(f"device {cfg.device!r} requested but CUDA is not available")
    return dev


def _check_finite(first_bad: torch.Tensor, acc: dict[str, torch.Tensor], step: int) -> None:
    """Raise if any step since the last check had a non-finite loss. Called only before a metrics row or a
    checkpoint is written (one host sync there instead of one per step), so no checkpoint holds NaNs."""
    bad_step = int(first_bad)
    if bad_step >= 0:
        bad = {k: float(v) for k, v in acc.items() if not math.isfinite(float(v))}
        raise FloatingPointError(
            f"non-finite training loss at step {bad_step} (detected at step {step}); terms non-finite since the "
            f"last log {bad or '(none: overflow in sum)'}. "
            "Lower the learning rate or check the data; the last good checkpoint is kept.")


def _out_of_time(cfg: TrainConfig, step: int, dev: torch.device) -> bool:
    if cfg.deadline <= 0:
        return False
    if not cfg.ddp:
        return wall_clock() >= cfg.deadline
    if step % cfg.log_every:
        return False
    # ranks must stop at the same step (or the others hang in the next all-reduce): rank 0's clock
    # decides, at log steps only, so the broadcast costs one sync per logged row
    import torch.distributed as dist

    flag = torch.tensor(float(wall_clock() >= cfg.deadline), device=dev)
    dist.broadcast(flag, 0)
    return bool(flag)


# ---------------------------------------------------------------------- training


def run(cfg: TrainConfig) -> Path:
    """Train (or resume, or skip if finished) one model; returns the run directory."""
    validate(cfg)
    out = Path(cfg.out)
    cfg_dict = to_dict(cfg)
    check_existing(cfg)
    if (out / "DONE").exists():
        return out
    if cfg.deadline > 0 and wall_clock() >= cfg.deadline:  # out of time before starting: leave the run as it is
        return out
    from .io import run_lock

    with run_lock(out, enabled=int(os.environ.get("RANK", "0")) == 0):  # ranks > 0 never write the run dir
        return _train(cfg, out, cfg_dict)


def _train(cfg: TrainConfig, out: Path, cfg_dict: dict) -> Path:
    """The body of :func:`run`, under the run directory's lock."""
    rank, world, local_rank = 0, 1, 0
    if cfg.ddp:
        import torch.distributed as dist

        if "RANK" not in os.environ:
            raise ConfigError("ddp=True must be launched with torchrun (RANK/WORLD_SIZE unset)")
        rank, world, local_rank = int(os.environ["RANK"]), int(os.environ["WORLD_SIZE"]), int(os.environ.get("LOCAL_RANK", 0))
        dev = _device(cfg, local_rank)
        if dev.type == "cuda":
            torch.cuda.set_device(dev)
        dist.init_process_group("nccl" if dev.type == "cuda" else "gloo")
    else:
        dev = _device(cfg)
    if dev.type == "cpu":
        torch.set_num_threads(cfg.threads or auto_threads())
    main = rank == 0
    fast = use_fast_path(cfg, dev)

    if main:
        from .io import write_json

        out.mkdir(parents=True, exist_ok=True)
        write_json(out / "config.json", cfg_dict)

    from . import data as data_mod

    ds = data_mod.load(cfg.data)
    train_ep = ds.episodes("train")
    dims = (ds.proprio.shape[-1], ds.touch.shape[-1], ds.actions.shape[-1])
    sampler = WindowSampler(ds, train_ep, cfg.image_size, cfg.window, dev, cfg.contact_channel,
                            seed=cfg.seed * 1000 + 1 + rank, with_params=cfg.sysid_weight > 0, non_blocking=fast)
    train_horizons = tuple(cfg.horizons)
    stats = data_stats(ds, train_ep)
    del ds

    torch.manual_seed(cfg.seed)
    random.seed(cfg.seed)
    np.random.seed(cfg.seed)
    mk = model_kwargs(cfg, dims)
    model = XJEPA(**mk)
    model.set_stats(stats)
    model.to(dev)
    if cfg.channels_last:
        model.to(memory_format=torch.channels_last)
    opt = make_optimizer(model, cfg, fused=fast)
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda s: lr_lambda(s, cfg.warmup, cfg.steps))

    step = 0
    ckpt_path = out / "ckpt.pt"
    if ckpt_path.exists():
        ck = checkpoint.load(ckpt_path)
        model.load_state_dict(ck["model"])
        opt.load_state_dict(ck["optimizer"])
        sched.load_state_dict(ck["scheduler"])
        checkpoint.set_rng_state(ck["rng"])
        if rank == 0:
            sampler.gen.set_state(ck["sampler"])
        else:
            sampler.gen.manual_seed(cfg.seed * 1000 + 1 + rank + 7919 * ck["step"])
        step = int(ck["step"])
        if main:
            restart_metrics(out, step)
    elif main:  # fresh start: the step-0 row describes the corpus the loss will see
        restart_metrics(out, 0, {"step": 0, **sampler.glide_share(train_horizons, cfg.glide_loss_weight)})

    net: torch.nn.Module = model
    if cfg.ddp:
        from torch.nn.parallel import DistributedDataParallel as DDP

        net = DDP(model, device_ids=[dev.index] if dev.type == "cuda" else None,
                  find_unused_parameters=cfg.objective == "recon")
    use_amp = cfg.amp and dev.type == "cuda" and torch.cuda.is_bf16_supported()
    # compile the module call (forward + loss); the optimizer step stays eager, so the lr schedule
    # (a Python float per step) causes no recompiles
    loss_fn = torch.compile(net) if cfg.compile else net

    def save_ckpt(s: int) -> None:
        if main:
            checkpoint.save({"model": model.state_dict(), "optimizer": opt.state_dict(), "scheduler": sched.state_dict(),
                          "rng": checkpoint.rng_state(), "sampler": sampler.gen.get_state(), "step": s, "model_kwargs": mk,
                          "config": cfg_dict}, ckpt_path)

    log = MetricsLog(out, cfg.tensorboard, step) if main else None
    pbar = None
    if main and cfg.progress:
        from tqdm.auto import tqdm

        pbar = tqdm(total=cfg.steps, initial=step, desc=f"train {cfg.variant}", dynamic_ncols=True)

    end = min(cfg.steps, cfg.stop_at) if cfg.stop_at > 0 else cfg.steps
    loss_kw = loss_kwargs(cfg)
    # loss terms are summed on the device and read only when a row is logged: a per-step .item() or
    # isfinite check would make the host wait for the GPU every step
    acc: dict[str, torch.Tensor] = {}
    first_bad = torch.full((), -1, dtype=torch.long, device=dev)  # first step with a non-finite loss
    n_acc, t0 = 0, time.perf_counter()
    model.train()
    try:
        while step < end:
            loss, terms = train_step(model, opt, cfg, sampler.sample(cfg.batch_size), step, dev, loss_kw,
                                     amp=use_amp, fast=fast, loss_fn=loss_fn)
            sched.step()
            crash_point("train_step")
            terms["loss"] = loss
            first_bad = torch.where((first_bad < 0) & ~torch.isfinite(terms["loss"]), step, first_bad)
            step += 1
            for k, v in terms.items():
                acc[k] = acc.get(k, 0.0) + v.float()
            n_acc += 1
            if pbar is not None:
                pbar.update(1)
            out_of_time = _out_of_time(cfg, step, dev)
            log_now = step % cfg.log_every == 0 or step == end or out_of_time
            ckpt_now = step % cfg.ckpt_every == 0 or step == end or out_of_time
            if log_now or ckpt_now:
                _check_finite(first_bad, acc, step)
            if log_now:
                if dev.type == "cuda":
                    torch.cuda.synchronize(dev)
                dt = time.perf_counter() - t0
                row = speed_row(step, sched.get_last_lr()[0], n_acc, cfg.batch_size * cfg.window * world, dt)
                row.update({k: float(v) / n_acc for k, v in acc.items()})
                if main:
                    log.write(row)
                    if pbar is not None:
                        pbar.set_postfix(loss=f"{row['loss']:.4f}", fps=f"{row['frames_per_s']:.0f}")
                acc, n_acc, t0 = {}, 0, time.perf_counter()
            if ckpt_now:
                save_ckpt(step)
            if out_of_time:
                break
    finally:
        if pbar is not None:
            pbar.close()
        if log is not None:
            log.close()
    if step >= cfg.steps and main:
        write_final(out, model.state_dict(), mk, cfg_dict, step)
    if cfg.ddp:
        import torch.distributed as dist

        dist.barrier()
        dist.destroy_process_group()
    return out


__all__ = ["TrainConfig", "PRESETS", "make_config", "validate", "run", "load_model", "WindowSampler",
           "data_stats", "synthetic_dataset", "model_kwargs", "lr_lambda", "use_fast_path", "make_optimizer",
           "loss_kwargs", "sigreg_directions", "sigreg_row_index", "sigreg_seed", "to_device", "wall_clock"]
