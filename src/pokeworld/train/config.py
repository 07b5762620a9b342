"""Training configuration: the :class:`TrainConfig` dataclass, its presets, validation, and the checks that decide
whether an existing run directory may be resumed with a config (paper App. B "Optimization")."""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from ..config import FRACTION, SEED, Limit, check_fields, from_preset, positive, to_dict
from ..devices import pick_device
from ..errors import ConfigError
from ..losses import SIGREG_POOLS
from ..models.encoders import ENCODERS
from ..models.xjepa import (
    CONTACT_WEIGHTINGS,
    GNLL_HEADS,
    HEAD_FORMS,
    MAX_HORIZONS,
    OBJECTIVES,
    VALUES_BEFORE_THE_FIELD,
    check_gnll_variance,
    check_variant,
)
from ..rundir import read_run_config


@dataclass
class TrainConfig:
    """Train one X-JEPA variant (paper §3, App. B).

    The field defaults are the App. B sizes with this project's first objective and model (the ``paper`` preset
    before it was aligned with the authors' released code, :data:`FIRST_PAPER_MODEL`); the ``paper`` preset
    overrides them with the reference's objective and model (:data:`REFERENCE_MODEL`). :func:`make_config` and the
    ``pokeworld train`` command start from the ``cpu`` preset; see :data:`PRESETS` for what each costs.
    """

    variant: str = "VFX"
    """Variant (inputs × targets): one of V, VF, VX_p, VX_t, VX, VFX (paper Table "targets")."""
    data: str = "data/pokeworld"
    """Dataset directory (``pokeworld.data`` format; the default is where ``pokeworld generate`` writes)."""
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
    head_layers: int = 1
    """Hidden layers of every direct Δ head (latent, proprio, touch), each ``width`` wide. The paper gives none;
    1 (the default, every recorded run's). Whether a program touches the object is a gate on the finger's path
    that one hidden layer fits poorly even from the true state (``pokeworld.diagnostics.head_capacity``); 2
    did not lower the phantom pushes of a trained model at the demo budget (docs/design.md, "Planning: head
    depth")."""
    objective: str = "latent"
    """'latent' (MSE to latent targets), 'gnll' (latent heads also predict a log-variance), 'recon'
    (pixel-reconstruction control: shared deconv decoder replaces latent targets, SIGReg omitted) or 'belief'
    (episode-level latent: amortised posterior over the window, learned causal prior, KL term; an ELBO whose
    optimum is not a conditional mean of the future, docs/model.md "belief")."""
    gnll_heads: str = "latent"
    """objective='gnll': which heads are Gaussian NLL — 'latent' (the latent Δ-heads; proprio/touch stay MSE)
    or 'all' (proprio/touch heads also predict a log-variance, so no target gains weight over another through
    its learned precision; docs/model.md "The Gaussian-NLL control")."""
    gnll_variance: str = "bounded"
    """objective='gnll': variance parameterisation of every NLL head (the paper gives none; docs/design.md
    "Gaussian NLL: variance parameterisation"). 'bounded' (the default): a per-element, per-frame log-variance
    output squashed smoothly into (−b, b), b = ``gnll_logvar_bound``, so no precision exceeds e^b; 'free': that
    output clamped to [−8, 8] only, so a precision can reach e^8 ≈ 2,981 (and does: docs/results/deviations_cpu.md
    §5); 'beta': β-NLL (Seitzer et al. 2022),
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
    """Output width of the proprio and touch MLP encoders (also their hidden width with ``encoder='groupnorm'``;
    64 hidden with 'reference'). The reference's: 96."""
    encoder: str = "groupnorm"
    """Per-frame encoder form (docs/model.md "Aligned with the released reference"): 'groupnorm' — 4×4 stride-2
    convolutions with GroupNorm, one Linear from the flattened map and the vector features to the latent;
    'reference' (the ``paper`` preset) — the authors' released encoder: 3×3 stride-2 convolutions without
    normalisation, a ``fuse_dim``-wide GELU bottleneck after the flattened map, and a fusion MLP."""
    fuse_dim: int = 192
    """encoder='reference': width of the vision bottleneck and of the fusion MLP's hidden layer (reference: 192)."""
    head_form: str = "mlp"
    """Direct Δ-head form: 'mlp' — MLP([h_t, actions t..t+Δ−1]) with ``head_layers`` hidden layers ``width``
    wide; 'reference' (the ``paper`` preset) — the released heads: linear in [h_t, GELU(Linear(actions))] (128-wide
    action embedding) for Δ > 1, the state alone at Δ = 1 (Linear for the latent, a 96-wide MLP for proprio /
    touch), latent heads ending in BatchNorm1d (``head_layers`` is then unused)."""
    sensor_horizons: tuple[int, ...] = ()
    """Horizons of the proprio / touch heads: those of ``horizons`` listed here (empty = all of them). Reference:
    (1, 4), no Δ = 16 sensor heads; a single-horizon run (``horizons`` (1,)) then has Δ = 1 sensor heads only."""
    latent_horizon_weights: tuple[float, ...] = ()
    """(weight at Δ = 1, weight at every Δ > 1) of the latent (or recon) horizons' terms, summed; empty = their
    mean. Reference: (1, 0.5), i.e. Δ 1 / 4 / 16 = 1 / 0.5 / 0.5 (the same rule at any horizons)."""
    sensor_horizon_weights: tuple[float, ...] = ()
    """(weight at Δ = 1, weight at every Δ > 1) of the proprio / touch horizons' terms, summed (then times
    ``proprio_weight`` / ``touch_weight``); empty = their mean. Reference: (0.5, 0.25)."""
    contact_weighting: str = "normalised"
    """How ``touch_contact_weight`` enters the touch term: 'normalised' — a weighted mean Σ w·e / Σ w (contact
    frames gain share; the term keeps an MSE's scale); 'frames' (the reference's) — the mean over frames of the
    weighted error Σ w·e / N, so the weight also scales the whole term by its mean (≈ 2 at 1/3 contact frames)."""
    pool: bool = False
    """Average the CNN's last feature map over space instead of flattening it (position then has
    to be learned into the channels; tests whether a latent can discard visible state)."""
    sigreg_weight: float = 0.02
    """SIGReg weight λ."""
    sigreg_dirs: int = 1024
    """Random unit directions per step for SIGReg (resampled every step)."""
    sigreg_knots: int = 17
    """Trapezoid knots on [0, ``sigreg_t_max``] for the Epps–Pulley integral (the integrand is even: the
    integral over [−t_max, t_max] is twice this one)."""
    sigreg_t_max: float = 3.0
    """Upper end of the Epps–Pulley integral's half-range. The reference integrates over [−5, 5] with 17
    trapezoid knots, which is exactly t_max 5 with 9 knots here (the ``paper`` preset)."""
    sigreg_pool: str = "step"
    """Rows of one SIGReg statistic (global-latent models; docs/design.md "SIGReg: per-step or pooled rows"):
    'step' (the runs so far, LeWM's reading) — per time step over the batch's rows, averaged over the window;
    'pooled' — one statistic over all batch × window latents, subsampled to ``sigreg_rows`` (the paper's
    "4096 subsampled rows"). The statistic is N-scaled: its null level is the same, its excess under a
    departure from N(0, I) grows with N (window× at equal λ). Under DDP either is the global statistic over
    all ranks' rows (ECFs all-reduced)."""
    program_aligned_share: float = 0.0
    """Share of each batch's windows drawn to start where the longest direct head's query (the window's last
    position with a Δ = max(horizons) target) falls on a 16-step program slot start, so that head reads a whole
    slot's program from its first action — the planner's exact query (uniform starts give it ~1/16 of the time).
    0 keeps uniform starts and the sampling stream of earlier runs (docs/design.md "Planning: the cost")."""
    sigreg_reference_rows: int = 0
    """The SIGReg statistic at this sample count instead of the rows it is computed on (0: its own rows, the
    statistic as defined). The Epps–Pulley statistic is N-scaled, so at one λ a batch of 32 pulls 4× less than
    the paper's 128; 128 here gives the paper's per-step strength at any batch (per-step pool: N = the batch;
    docs/design.md "SIGReg: strength and the batch")."""
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
    """Global gradient-norm clip (0 = off). Reference (the ``paper`` preset): 5."""
    device: str = "auto"
    """'auto' (cuda if available, else cpu), 'cpu', 'cuda' or 'cuda:N'."""
    amp: bool = True
    """bf16 autocast where supported (CUDA with bf16); ignored on CPU, where bf16 is slower."""
    threads: int = 0
    """CPU threads for torch (0 = auto: half the usable cores, 1 on a 2-core machine; see ``auto_threads``)."""
    ckpt_every: int = 1000
    """Checkpoint every this many steps (and at the end / ``stop_at``)."""
    keep_every: int = 0
    """Also keep a copy of the checkpoint every this many steps, as ``kept/ckpt-<step>.pt`` (a multiple of
    ``ckpt_every``; 0 keeps none): the learning curve over the budget (``scripts/budget_curve.py``)."""
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
    compile: str = "auto"
    """``torch.compile`` of the model's loss (forward + backward graphs): 'auto' (the default: on for a CUDA device,
    off on a CPU and under DDP), 'on' or 'off'. Dropout masks then come from inductor's RNG, so a compiled run
    matches an eager one statistically, not bit-for-bit. Configs written before this was a choice hold
    ``true``/``false``, read as 'on'/'off'."""
    compile_mode: str = "auto"
    """``torch.compile`` mode of a compiled run: 'auto' ('reduce-overhead' on CUDA, 'default' on a CPU), 'default',
    'reduce-overhead' (CUDA graphs: measured on an H200, the ``paper`` preset at 0.0104 s/step against 0.0142 in
    the default mode and 0.0287 eager; CUDA graphs do not apply on a CPU), 'max-autotune-no-cudagraphs' or
    'max-autotune'."""
    channels_last: bool = False
    """Keep conv weights/activations in channels-last layout (faster cuDNN convs on tensor cores).
    Fixed for a run: the optimizer state in the checkpoint inherits the layout."""
    deadline: float = 0.0
    """Unix time after which the loop checkpoints and returns without ``DONE`` (0 = none); a run whose
    deadline has passed before it starts returns at once. For time-sliced jobs (``pokeworld map
    --time-budget-min``); re-running resumes."""

    # :func:`validate` holds every field to these (and the model's sizes to models.xjepa.MODEL_INT_BOUNDS, what a
    # checkpoint may declare): far above the paper's, far below a batch that cannot be allocated
    LIMITS = {"seed": SEED, "steps": Limit(1, 10**9), "stop_at": Limit(0, 10**9), "batch_size": Limit(1, 65536),
              "window": Limit(2, 4096), "horizons": Limit(1, 4095), "head_layers": Limit(1, 16),
              "gnll_beta": FRACTION, "gnll_logvar_bound": positive(1e6), "belief_dim": Limit(1, 65536),
              "belief_kl_weight": Limit(0, 1e6), "sysid_weight": Limit(0, 1e6), "image_size": Limit(16, 1024),
              "channels": Limit(1, 65536), "latent_dim": Limit(1, 65536), "width": Limit(1, 65536),
              "depth": Limit(1, 64), "heads": Limit(1, 1024), "dropout": Limit(0, 1), "vec_dim": Limit(1, 65536),
              "sigreg_weight": Limit(0, 1e6), "sigreg_dirs": Limit(1, 2**20), "sigreg_knots": Limit(2, 10**4),
              "sigreg_t_max": positive(100.0), "fuse_dim": Limit(1, 65536), "sensor_horizons": Limit(1, 4095),
              "latent_horizon_weights": Limit(0, 1e6), "sensor_horizon_weights": Limit(0, 1e6),
              "program_aligned_share": FRACTION, "sigreg_reference_rows": Limit(0, 2**31),
              "sigreg_rows": Limit(1, 2**24), "token_rows": Limit(1, 2**24), "token_dirs": Limit(1, 2**20),
              "touch_contact_weight": Limit(0, 1e6), "contact_channel": Limit(0, 4095),
              "proprio_weight": Limit(0, 1e6), "touch_weight": Limit(0, 1e6), "glide_loss_weight": Limit(0, 1e6),
              "motion_loss_weight": Limit(0, 1e6), "lr": positive(10.0), "warmup": Limit(0, 10**9),
              "weight_decay": Limit(0, 1e3), "grad_clip": Limit(0, 1e9), "threads": Limit(0, 4096),
              "ckpt_every": Limit(1, 10**9), "keep_every": Limit(0, 10**9), "log_every": Limit(1, 10**9),
              "deadline": Limit(0, 2**40)}

    def __post_init__(self) -> None:
        # configs and callers from before 'auto' pass a boolean; the run's config.json then records the setting
        self.compile = legacy_compile(self.compile)

#: Field overrides per preset (costs as in ``cli.PRESET_COSTS``).
#: ``paper`` = App. B with the released reference's objective and model (:data:`REFERENCE_MODEL`); needs a GPU
#: (the timings are the first model's, :data:`FIRST_PAPER_MODEL`): on one H100 0.041 s/step on the fast path (≈ 14 min per 20k-step model), 0.030
#: compiled, 0.027 s per model-step for six models stacked (docs/model.md "Fast path", "Several models").
#: ``cpu``: 32×32 frames, narrower CNN/predictor, batch 32, 256 SIGReg directions, 4,000 steps, the reference's loss
#: weighting (:data:`REFERENCE_OBJECTIVE`; ``cpu_first``: the same with the first objective) (stiffness
#: enters the VFX latent only after ~2,000 steps at this size, docs/model.md); ≈ 0.26 s/step on one
#: core, ≈ 20 min per model with two models side by side on 2 cores. ``tiny``: unit tests, seconds.
#: The reference's loss weighting alone: proprio / touch heads at Δ 1 and 4 only, latent Δ1 : Δ>1 = 1 : 0.5, sensor
#: 0.5 : 0.25, contact frames weighted 1 + 3c. The ``cpu`` and ``demo`` presets take it (at the demo's budget it
#: lifts VFX log k 0.22 → 0.32 on the reference environment; the reference's pooled SIGReg and encoder lower it
#: there: docs/model.md "The reference's objective at CPU budgets").
REFERENCE_OBJECTIVE: dict[str, Any] = dict(
    sensor_horizons=(1, 4), latent_horizon_weights=(1.0, 0.5), sensor_horizon_weights=(0.5, 0.25),
    contact_weighting="frames")
#: The objective and model of the authors' released code (``exp/e003_motion``: model.py, train.py) that App. B
#: leaves open; the ``paper`` preset's overrides (docs/model.md "Aligned with the released reference").
REFERENCE_MODEL: dict[str, Any] = dict(
    encoder="reference", fuse_dim=192, vec_dim=96, head_form="reference", **REFERENCE_OBJECTIVE,
    sigreg_pool="pooled", sigreg_knots=9, sigreg_t_max=5.0, grad_clip=5.0)
#: Overrides that give the ``paper`` preset this project's first objective and model (the field defaults), with
#: which the first paper-budget runs were trained: ``make_config("paper", **FIRST_PAPER_MODEL)``.
FIRST_PAPER_MODEL: dict[str, Any] = dict(
    encoder="groupnorm", fuse_dim=192, vec_dim=64, head_form="mlp", sensor_horizons=(), latent_horizon_weights=(),
    sensor_horizon_weights=(), contact_weighting="normalised", sigreg_pool="step", sigreg_knots=17, sigreg_t_max=3.0,
    grad_clip=1.0)

#: The ``cpu`` preset's sizes and schedule (what ``cpu`` and ``cpu_first`` share).
CPU_SIZES: dict[str, Any] = dict(
    image_size=32, channels=(16, 32, 64, 64), width=128, depth=2, heads=4, vec_dim=32, batch_size=32, steps=4000,
    warmup=100, lr=1e-3, sigreg_dirs=256, token_rows=1024, token_dirs=128, ckpt_every=500, log_every=50)
#: What turns the ``demo`` preset's model out of the ``cpu`` one: the paper's 64-wide proprio / touch encoders, a
#: quarter of the batch for more updates per CPU-second (docs/model.md "Learning speed"), 2,200 steps.
DEMO_OVER_CPU: dict[str, Any] = dict(vec_dim=64, batch_size=8, steps=2200, ckpt_every=1000, log_every=100)

PRESETS: dict[str, dict[str, Any]] = {
    "paper": dict(REFERENCE_MODEL),
    "cpu": {**CPU_SIZES, **REFERENCE_OBJECTIVE},
    "tiny": dict(image_size=16, channels=(4, 8, 8, 8), latent_dim=16, width=16, depth=1, heads=2, vec_dim=8,
                 batch_size=4, window=18, steps=10, warmup=2, sigreg_dirs=16, token_rows=64, token_dirs=16,
                 ckpt_every=5, log_every=5, tensorboard=False, progress=False, device="cpu"),
}

PRESETS["demo"] = {**PRESETS["cpu"], **DEMO_OVER_CPU}
# the cpu and demo models with the first objective (the field defaults), with which every cpu / demo record made
# before REFERENCE_OBJECTIVE was trained: they reproduce those records
PRESETS["cpu_first"] = dict(CPU_SIZES)
PRESETS["demo_first"] = {**CPU_SIZES, **DEMO_OVER_CPU}

#: Fields of a run's config.json that say where and how it ran, not what it trained: left out of :func:`changes_from`.
BOOKKEEPING_FIELDS = frozenset({"data", "out", "ckpt_every", "keep_every", "log_every", "tensorboard", "progress",
                                "threads", "stop_at", "deadline", "device", "fast", "compile", "compile_mode"})


def changes_from(run_config: dict, preset: str, ignore: frozenset[str] | set[str] = frozenset()) -> dict:
    """What a run's config.json (a JSON dict) changes against ``preset``: every field whose value differs, bookkeeping
    fields and ``ignore`` left out; the preset's tuples compare as the JSON lists a config.json holds."""
    def as_stored(v: Any) -> Any:  # config.json holds tuples as lists
        return [as_stored(x) for x in v] if isinstance(v, (tuple, list)) else v

    base = {k: as_stored(v) for k, v in to_dict(make_config(preset)).items()}
    skip = BOOKKEEPING_FIELDS | set(ignore)
    return {k: v for k, v in run_config.items() if k not in skip and k in base and base[k] != v}


COMPILE_SETTINGS = ("auto", "on", "off")
"""Values of ``TrainConfig.compile``."""
COMPILE_MODES = ("auto", "default", "reduce-overhead", "max-autotune-no-cudagraphs", "max-autotune")
"""``torch.compile`` modes a run may name (``TrainConfig.compile_mode``; 'auto' is resolved per device)."""

#: Fields that may differ when re-running into an existing run directory.
RESUMABLE_FIELDS = ("steps", "stop_at", "ckpt_every", "keep_every", "log_every", "tensorboard", "progress", "threads", "device",
                    "fast", "compile", "compile_mode", "deadline")

#: Fields removed from TrainConfig -> the value with which a run made before the removal behaves
#: exactly like the current code; a run that set anything else conflicts. (Fields added later are
#: compared at their default, which by convention reproduces the behaviour before they existed, except
#: those in models.xjepa.VALUES_BEFORE_THE_FIELD, whose default changed since.)
RETIRED_FIELDS: dict[str, Any] = {"glide_episode_weight": 1.0}

def field_defaults() -> dict[str, Any]:
    """TrainConfig field -> its default (the value a run gets when nothing overrides it)."""
    return {f.name: f.default for f in dataclasses.fields(TrainConfig)}

def make_config(preset: str = "cpu", **overrides: Any) -> TrainConfig:
    """``TrainConfig`` from a named preset plus field overrides; validated."""
    cfg = from_preset(TrainConfig, PRESETS, preset, **overrides)
    validate(cfg)
    return cfg

MAX_BATCH_FRAME_BYTES = 16 << 30
"""Most bytes one step's input frames may take (batch × window × image_size², float32, the frame and its motion
channel): the paper's batch takes 50 MB; this is beyond any one accelerator's memory."""


def validate(cfg: TrainConfig) -> None:
    """Raise ConfigError on inconsistent settings: every field's type and range first (:data:`TrainConfig.LIMITS`),
    before anything is created on disk, then how the fields fit together."""
    check_fields(cfg)
    frame_bytes = cfg.batch_size * cfg.window * cfg.image_size**2 * 4 * 2
    if frame_bytes > MAX_BATCH_FRAME_BYTES:
        raise ConfigError(f"batch_size {cfg.batch_size} × window {cfg.window} at image_size {cfg.image_size} needs "
                          f"{frame_bytes / 2**30:.0f} GiB of frames per step (at most {MAX_BATCH_FRAME_BYTES >> 30}); "
                          "lower batch_size, window or image_size")
    check_variant(cfg.variant)
    if cfg.keep_every < 0 or (cfg.keep_every and cfg.keep_every % cfg.ckpt_every):
        raise ConfigError(f"keep_every {cfg.keep_every} must be 0 or a multiple of ckpt_every {cfg.ckpt_every}: only "
                          "steps that write a checkpoint can keep one")
    if cfg.objective not in OBJECTIVES:
        raise ConfigError(f"unknown objective {cfg.objective!r}; choose one of {list(OBJECTIVES)}")
    hs = tuple(cfg.horizons)
    if not hs or min(hs) < 1 or 1 not in hs or len(hs) > MAX_HORIZONS:
        raise ConfigError(f"horizons must be positive, include 1 and number at most {MAX_HORIZONS}, got {hs!r:.80}")
    if max(hs) >= cfg.window:
        raise ConfigError(f"window {cfg.window} must exceed the largest horizon {max(hs)}")
    if cfg.tokens and cfg.objective != "latent":
        raise ConfigError("tokens=True supports objective='latent' only")
    if cfg.gnll_heads not in GNLL_HEADS:
        raise ConfigError(f"unknown gnll_heads {cfg.gnll_heads!r}; choose one of {list(GNLL_HEADS)}")
    if cfg.gnll_heads != "latent" and cfg.objective != "gnll":
        raise ConfigError(f"gnll_heads={cfg.gnll_heads!r} needs objective='gnll'")
    check_gnll_variance(cfg.gnll_variance, cfg.objective, cfg.gnll_logvar_bound)
    # an option that the chosen parameterisation ignores would only make the run's config lie about it
    if cfg.gnll_beta != 0.5 and cfg.gnll_variance != "beta":
        raise ConfigError(f"gnll_beta={cfg.gnll_beta} applies to gnll_variance='beta' only")
    if cfg.gnll_logvar_bound != 2.0 and cfg.gnll_variance != "bounded":
        raise ConfigError(f"gnll_logvar_bound={cfg.gnll_logvar_bound} applies to gnll_variance='bounded' only")
    if cfg.sigreg_pool not in SIGREG_POOLS:
        raise ConfigError(f"unknown sigreg_pool {cfg.sigreg_pool!r}; choose one of {list(SIGREG_POOLS)}")
    if cfg.compile not in COMPILE_SETTINGS:
        raise ConfigError(f"compile must be one of {list(COMPILE_SETTINGS)}, got {cfg.compile!r}")
    if cfg.compile_mode not in COMPILE_MODES:
        raise ConfigError(f"compile_mode must be one of {list(COMPILE_MODES)}, got {cfg.compile_mode!r}")
    # 'default' is what every config written before 'auto' existed holds, compiled or not
    if cfg.compile == "off" and cfg.compile_mode not in ("auto", "default"):
        raise ConfigError(f"compile_mode={cfg.compile_mode!r} applies to a compiled run; --compile off trains eagerly")
    # a token run always pools its token rows (token_rows) and a recon run has no SIGReg: either reading of the
    # global-latent pool leaves them as they are (the paper preset's 'pooled' reaches them through the map's
    # controls), but a row budget they would ignore is refused
    if cfg.sigreg_rows != 4096 and (cfg.sigreg_pool != "pooled" or cfg.tokens or cfg.objective == "recon"):
        raise ConfigError(f"sigreg_rows={cfg.sigreg_rows} applies to sigreg_pool='pooled' with global latents "
                          "and a SIGReg (not tokens=True, not objective='recon') only")
    if cfg.image_size % 16 or cfg.image_size < 16:
        raise ConfigError(f"image_size must be a multiple of 16 (4 stride-2 stages), got {cfg.image_size}")
    if len(cfg.channels) != 4:
        raise ConfigError(f"channels must list the 4 CNN stages, got {cfg.channels}")
    if cfg.motion_loss_weight > 0 and cfg.objective == "recon":
        raise ConfigError("motion_loss_weight weights latent targets; objective='recon' has none")
    if cfg.fast not in ("auto", "on", "off"):
        raise ConfigError(f"fast must be 'auto', 'on' or 'off', got {cfg.fast!r}")
    check_model_form(cfg)

def check_model_form(cfg: TrainConfig) -> None:
    """ConfigError unless the encoder / head forms, the sensor horizons and the per-horizon weights fit together
    (each weight tuple empty or one weight per horizon it weights)."""
    for name, allowed in (("encoder", ENCODERS), ("head_form", HEAD_FORMS), ("contact_weighting", CONTACT_WEIGHTINGS)):
        if getattr(cfg, name) not in allowed:
            raise ConfigError(f"unknown {name} {getattr(cfg, name)!r}; choose one of {list(allowed)}")
    if cfg.fuse_dim != 192 and cfg.encoder != "reference":
        raise ConfigError(f"fuse_dim={cfg.fuse_dim} applies to encoder='reference' only")
    if cfg.head_layers != 1 and cfg.head_form == "reference":
        raise ConfigError(f"head_layers={cfg.head_layers} applies to head_form='mlp' only (the reference's heads are "
                          "linear in the state)")
    hs, sensor = tuple(cfg.horizons), tuple(cfg.sensor_horizons)
    if len(set(sensor)) != len(sensor) or (sensor and not set(sensor) & set(hs)):
        raise ConfigError(f"sensor_horizons {sensor!r:.80} must be distinct and share a horizon with {hs!r:.80}")
    for name in ("latent_horizon_weights", "sensor_horizon_weights"):
        n = len(getattr(cfg, name))
        if n not in (0, 2):
            raise ConfigError(f"{name} lists {n} weights: give two (the weight at Δ = 1, the weight at every "
                              "Δ > 1), or none for the mean over the horizons")

def use_fast_path(cfg: TrainConfig, dev: torch.device) -> bool:
    """Whether ``cfg.fast`` selects the fast path on ``dev`` ('auto': CUDA only)."""
    return cfg.fast == "on" or (cfg.fast == "auto" and dev.type == "cuda")

def compile_mode_for(cfg: TrainConfig, dev: torch.device) -> str | None:
    """The ``torch.compile`` mode a run of ``cfg`` uses on ``dev``, or None when it trains eagerly.

    'auto' compiles only on a CUDA device outside DDP: there CUDA graphs ('reduce-overhead') remove the host
    dispatch that bounds a step, while on a CPU compilation costs minutes for a few per cent (docs/model.md), so CPU
    runs stay eager and bit-identical to earlier ones. Under DDP the gradient all-reduce runs in DDP's hooks, which
    CUDA graphs have not been checked with here. A mode of 'auto' is 'reduce-overhead' on CUDA, 'default' elsewhere.
    """
    if cfg.compile == "off" or (cfg.compile == "auto" and (dev.type != "cuda" or cfg.ddp)):
        return None
    if cfg.compile_mode != "auto":
        return cfg.compile_mode
    return "reduce-overhead" if dev.type == "cuda" else "default"

def legacy_compile(value: Any) -> Any:
    """``compile`` as the current setting: the booleans of configs written before 'auto' existed map to 'on'/'off'
    (anything else is returned as it is, for :func:`validate` to judge)."""
    if isinstance(value, bool):
        return "on" if value else "off"
    return value

def check_existing(cfg: TrainConfig) -> None:
    """Raise ConfigError if ``cfg.out`` holds a run whose config differs in anything but :data:`RESUMABLE_FIELDS`
    (fields added since are compared at their default, retired ones at :data:`RETIRED_FIELDS`)."""
    out = Path(cfg.out)
    old = read_run_config(out)  # refuses links, FIFOs and damaged JSON in one line
    if old is None:
        return
    default = {**to_dict(TrainConfig()), **VALUES_BEFORE_THE_FIELD}  # what a config.json without a field means
    diff = {k: (old.get(k, default[k]), v) for k, v in to_dict(cfg).items()
            if k not in RESUMABLE_FIELDS and old.get(k, default[k]) != v}
    diff.update({k: (old[k], "(removed)") for k, same in RETIRED_FIELDS.items() if old.get(k, same) != same})
    if diff:
        raise ConfigError(f"{out} already holds a run with a different config {diff} (old, new); "
                          "use another --out or delete the directory")

def auto_threads() -> int:
    """Half the usable cores (≥ 1, ≤ 8). On a shared 2-core machine one thread per process is ~4× faster
    than two (measured: oversubscription with other workers dominates small-matrix CPU training)."""
    n = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, min(8, n // 2))

def compile_status(mode: str | None) -> dict[str, float]:
    """What a metrics row records of compilation, never assumed: ``compiled`` (1: the compiled loss is in use, 0:
    eager) and, for CUDA graphs ('reduce-overhead'), ``cudagraph_skips``: how many graphs inductor declined to
    capture so far in this process (it does so silently, e.g. for a host read; 0 means every graph was captured)."""
    status = {"compiled": float(mode is not None)}
    if mode == "reduce-overhead":
        from torch._dynamo.utils import counters  # inductor's own tally, the one its logs report

        status["cudagraph_skips"] = float(counters["inductor"].get("cudagraph_skips", 0))
    return status


def resolve_device(cfg: TrainConfig, local_rank: int = 0) -> torch.device:
    """The device ``cfg.device`` names ('auto': the GPU of ``local_rank`` when CUDA is available, else the CPU)."""
    return pick_device(cfg.device, local_rank)


__all__ = ["TrainConfig", "PRESETS", "BOOKKEEPING_FIELDS", "changes_from", "REFERENCE_OBJECTIVE", "REFERENCE_MODEL", "FIRST_PAPER_MODEL", "check_model_form", "RESUMABLE_FIELDS", "RETIRED_FIELDS", "COMPILE_SETTINGS", "COMPILE_MODES",
           "field_defaults", "make_config", "validate", "use_fast_path", "compile_mode_for", "legacy_compile",
           "check_existing", "auto_threads", "resolve_device", "compile_status"]
