"""X-JEPA: action-conditioned latent world models with cross-modal forecasting targets (paper §3, App. B).

Shapes: B batch, L sequence length, H×W frame, D latent (128), W predictor width,
Dp/Dt/Da proprio/touch/action dims (read from the data), S spatial tokens (token mode).

The model owns all preprocessing (buffers): frame area-downsampling to ``image_size``,
the temporal-difference channel, proprio/touch/action normalisation statistics and the
whitening of hidden parameters (sysid control). A loaded model therefore takes *raw*
dataset arrays.

Variants (inputs × targets, paper Table "targets"); see :data:`VARIANTS`.
Objectives: ``latent`` (MSE to jointly learned encoder targets, no stop-gradient),
``gnll`` (latent heads also output a log-variance; Gaussian NLL; with ``gnll_heads='all'`` the
proprio/touch heads too, so every target keeps its relative weight; ``gnll_variance`` picks the variance
parameterisation, :data:`~pokeworld.losses.GNLL_VARIANCES`), ``recon`` (a shared
deconvolutional decoder reconstructs future frames instead of latent targets; SIGReg off),
``belief`` (an episode-level latent u: amortised posterior q(u | whole window), learned causal prior
p(u | trunk state h_t), every head reads h_t + W·u; MSE + β·KL(q ‖ p_t), an ELBO; docs/model.md "belief").
Controls: ``sysid`` head (trunk -> whitened (log m, γ, log k)), ``tokens`` (spatial tokens,
dense aligned Δ=1 token prediction, token-level SIGReg subsampling).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from ..errors import ConfigError
from ..losses import (
    DEFAULT_GNLL_VARIANCE,
    GNLL_VARIANCES,
    LOGVAR_RANGE,
    beta_nll,
    beta_nll_weight,
    bounded_logvar,
    gaussian_kl,
    gaussian_nll,
    glide_loss_share,
    glide_weights,
    head_logvar_nll,
    masked_mse,
    motion_weights,
    nll_precision,
    sigreg,
    sigreg_rows_of,
)
from .encoders import ENCODERS, FusedEncoder
from .predictor import CausalPredictor, KVCache

#: variant name -> (input modalities, target modalities). "latent" is the visual/fused latent target.
VARIANTS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "V": (("vision",), ("latent",)),
    "VF": (("vision", "proprio", "touch"), ("latent",)),
    "VX_p": (("vision",), ("latent", "proprio")),
    "VX_t": (("vision",), ("latent", "touch")),
    "VX": (("vision",), ("latent", "proprio", "touch")),
    "VFX": (("vision", "proprio", "touch"), ("latent", "proprio", "touch")),
}
OBJECTIVES = ("latent", "gnll", "recon", "belief")
GNLL_HEADS = ("latent", "all")
SYSID_PARAMS = ("log_m", "gamma", "log_k")


VALUES_BEFORE_THE_FIELD = {"gnll_variance": "free"}
"""Model kwargs / TrainConfig fields whose default changed after runs were recorded without them -> the value such
a record means (it was the default then). Every other field added later is read at its default, which reproduces
the behaviour before it existed."""


def check_variant(variant: str) -> None:
    if variant not in VARIANTS:
        raise ConfigError(f"unknown variant {variant!r}; choose one of {list(VARIANTS)}")


def check_gnll_variance(variance: str, objective: str, bound: float) -> None:
    """ConfigError unless ``variance`` is one of :data:`~pokeworld.losses.GNLL_VARIANCES`, one that is neither the
    default nor 'free' comes with objective='gnll', and the 'bounded' log-variance bound is positive and finite.
    ('free' was the default before 'bounded': every config and checkpoint written then records it, NLL or not.)"""
    if variance not in GNLL_VARIANCES:
        raise ConfigError(f"unknown gnll_variance {variance!r}; choose one of {list(GNLL_VARIANCES)}")
    if variance not in (DEFAULT_GNLL_VARIANCE, "free") and objective != "gnll":
        raise ConfigError(f"gnll_variance={variance!r} needs objective='gnll'")
    if not (0.0 < float(bound) < float("inf")):
        raise ConfigError(f"gnll_logvar_bound must be positive and finite, got {bound}")


#: Integer model kwargs -> (least, greatest) value a checkpoint may declare. Generous (the paper's model sits far
#: inside every range); they exist so that a checkpoint from elsewhere cannot make the constructor build
#: millions of modules before its weights are compared (the parameter count is bounded separately).
MODEL_INT_BOUNDS: dict[str, tuple[int, int]] = {
    "proprio_dim": (0, 4096), "touch_dim": (0, 4096), "action_dim": (1, 4096), "image_size": (16, 4096),
    "latent_dim": (1, 65536), "width": (1, 65536), "depth": (1, 64), "heads": (1, 1024), "max_len": (1, 65536),
    "vec_dim": (1, 65536), "contact_channel": (0, 4095), "recon_positions": (1, 65536), "belief_dim": (1, 65536),
    "head_layers": (1, 16), "fuse_dim": (1, 65536)}
MODEL_BOOL_KWARGS = ("tokens", "sysid", "pool", "motion_channel")
MODEL_STR_KWARGS = ("variant", "objective", "gnll_heads", "gnll_variance", "encoder", "head_form")
MODEL_FLOAT_KWARGS = {"dropout": (0.0, 1.0), "gnll_logvar_bound": (0.0, 1e6)}
MAX_CHANNEL, MAX_HORIZONS = 65536, 64
#: Every kwarg :class:`XJEPA` takes.
MODEL_KWARGS = frozenset({*MODEL_INT_BOUNDS, *MODEL_BOOL_KWARGS, *MODEL_STR_KWARGS, *MODEL_FLOAT_KWARGS, "channels",
                          "horizons", "sensor_horizons"})


def _shown(value: Any) -> str:
    """``repr`` cut to a readable length: a declared value may be a megabyte of list."""
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _int_in(name: str, value: Any, least: int, greatest: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ConfigError(f"model kwarg {name}={_shown(value)} must be an integer")
    if not least <= value <= greatest:
        raise ConfigError(f"model kwarg {name}={value} is outside the allowed {least}..{greatest}")
    return value


def check_model_kwargs(kwargs: Any) -> dict[str, Any]:
    """The kwargs of :class:`XJEPA` as a checkpoint declares them, checked for name, type and range before any
    module is built (ConfigError saying what was declared and what is allowed); ``channels`` and ``horizons``
    come back as tuples."""
    if not isinstance(kwargs, dict):
        raise ConfigError(f"model kwargs must be a dict, got {type(kwargs).__name__}")
    out: dict[str, Any] = {}
    for name, value in kwargs.items():
        if name in MODEL_INT_BOUNDS:
            out[name] = _int_in(name, value, *MODEL_INT_BOUNDS[name])
        elif name in MODEL_BOOL_KWARGS or name in MODEL_STR_KWARGS:
            kind = bool if name in MODEL_BOOL_KWARGS else str
            if not isinstance(value, kind):
                raise ConfigError(f"model kwarg {name}={_shown(value)} must be a {kind.__name__}")
            out[name] = value
        elif name in MODEL_FLOAT_KWARGS:
            least, greatest = MODEL_FLOAT_KWARGS[name]
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not least <= value <= greatest:
                raise ConfigError(f"model kwarg {name}={_shown(value)} must be a number in [{least}, {greatest}]")
            out[name] = float(value)
        elif name in ("channels", "horizons", "sensor_horizons"):
            size = {"channels": (4, 4), "horizons": (1, MAX_HORIZONS), "sensor_horizons": (0, MAX_HORIZONS)}[name]
            if not isinstance(value, (list, tuple)) or not size[0] <= len(value) <= size[1]:
                raise ConfigError(f"model kwarg {name}={_shown(value)} must list {size[0]}..{size[1]} integers")
            top = MAX_CHANNEL if name == "channels" else MODEL_INT_BOUNDS["max_len"][1]
            out[name] = tuple(_int_in(name, v, 1, top) for v in value)
        else:
            raise ConfigError(f"unknown model kwarg {_shown(name)}; XJEPA takes {sorted(MODEL_KWARGS)}")
    return out


def area_downsample(frames: torch.Tensor, size: int) -> torch.Tensor:
    """(..., H, W) -> (..., size, size) by area pooling; uint8 in -> uint8 out (rounded), float -> float."""
    h, w = frames.shape[-2:]
    if h == size and w == size:
        return frames
    if h < size or w < size:
        raise ValueError(f"frames {h}x{w} are smaller than image_size {size}; only downsampling is supported")
    lead = frames.shape[:-2]
    x = frames.reshape(-1, 1, h, w).float()
    y = F.interpolate(x, size=(size, size), mode="area")
    if frames.dtype == torch.uint8:
        y = y.round_().clamp_(0, 255).to(torch.uint8)
    return y.reshape(*lead, size, size)


class DeltaHead(nn.Module):
    """Direct Δ-step head: MLP([h_t, flattened actions t..t+Δ-1]) -> out_dim, ``layers`` hidden GELU layers."""

    def __init__(self, width: int, act_in: int, out_dim: int, hidden: int | None = None, layers: int = 1):
        super().__init__()
        if layers < 1:
            raise ConfigError(f"a Δ head needs at least one hidden layer, got head_layers={layers}")
        hidden = hidden or width
        mods: list[nn.Module] = [nn.Linear(width + act_in, hidden), nn.GELU()]
        for _ in range(layers - 1):
            mods += [nn.Linear(hidden, hidden), nn.GELU()]
        self.net = nn.Sequential(*mods, nn.Linear(hidden, out_dim))

    def forward(self, h: torch.Tensor, a: torch.Tensor) -> torch.Tensor:
        return self.net(torch.cat([h, a], -1) if a.shape[-1] else h)


HEAD_FORMS = ("mlp", "reference")
"""Forms of the direct Δ heads (``XJEPA(head_form=...)``, docs/model.md "Aligned with the released reference"): 'mlp' —
:class:`DeltaHead` everywhere; 'reference' — :class:`ReferenceDeltaHead`, the released reference's heads."""

REFERENCE_ACTION_DIM, REFERENCE_SENSOR_HIDDEN = 128, 96
"""The reference heads' action-window embedding width and its Δ = 1 proprio / touch MLP's hidden width."""


class ReferenceDeltaHead(nn.Module):
    """A direct Δ-step head in the released reference's form (``exp/e003_motion/model.py``).

    Δ > 1: ``Linear([h, GELU(Linear(actions t..t+Δ−1))])`` — linear in the trunk state, the action window
    embedded to 128; Δ = 1: the state alone (the trunk at t has already read the action after observation t),
    through one Linear for a latent head or a ``width -> 96 -> out`` GELU MLP for a proprio / touch head. A latent
    head ends in BatchNorm1d over its first ``bn_features`` outputs (its mean: a Gaussian-NLL head's
    log-variance half is left as it is); 0 = none (proprio / touch heads)."""

    def __init__(self, width: int, act_in: int, out_dim: int, delta: int, sensor: bool, bn_features: int = 0):
        super().__init__()
        self.act = None
        if delta > 1:
            self.act = nn.Sequential(nn.Linear(act_in, REFERENCE_ACTION_DIM), nn.GELU())
            self.out = nn.Linear(width + REFERENCE_ACTION_DIM, out_dim)
        elif sensor:
            self.out = nn.Sequential(nn.Linear(width, REFERENCE_SENSOR_HIDDEN), nn.GELU(),
                                     nn.Linear(REFERENCE_SENSOR_HIDDEN, out_dim))
        else:
            self.out = nn.Linear(width, out_dim)
        self.bn = nn.BatchNorm1d(bn_features) if bn_features else None

    def forward(self, h: torch.Tensor, a: torch.Tensor) -> torch.Tensor:
        y = self.out(h if self.act is None else torch.cat([h, self.act(a)], -1))
        if self.bn is None:
            return y
        k = self.bn.num_features
        mean = self.bn(y[..., :k].reshape(-1, k)).reshape(*y.shape[:-1], k)
        return mean if y.shape[-1] == k else torch.cat([mean, y[..., k:]], -1)


def delta_head(form: str, width: int, delta: int, action_dim: int, out_dim: int, layers: int, sensor: bool,
               bn_features: int = 0) -> nn.Module:
    """The direct Δ head of ``form`` (:data:`HEAD_FORMS`); ``bn_features`` applies to the reference form only."""
    if form == "reference":
        return ReferenceDeltaHead(width, delta * action_dim, out_dim, delta, sensor, bn_features)
    return DeltaHead(width, delta * action_dim, out_dim, layers=layers)


class Decoder(nn.Module):
    """Shared deconvolutional decoder: vector -> (C0, s0, s0) map -> 4 stride-2 upconvs -> (1, S, S) in [0,1]."""

    def __init__(self, channels: tuple[int, ...], image_size: int):
        super().__init__()
        rev = tuple(reversed(channels))  # e.g. 256/128/64/32
        self.c0, self.s0 = rev[0], max(1, image_size // 2 ** len(channels))
        self.in_dim = self.c0 * self.s0 * self.s0
        layers: list[nn.Module] = []
        for i, c in enumerate(rev):
            c_out = rev[i + 1] if i + 1 < len(rev) else 1
            layers.append(nn.ConvTranspose2d(c, c_out, 4, 2, 1))
            if i + 1 < len(rev):
                layers += [nn.GroupNorm(min(8, c_out), c_out), nn.GELU()]
        self.net = nn.Sequential(*layers)

    def forward(self, v: torch.Tensor) -> torch.Tensor:
        return torch.sigmoid(self.net(v.reshape(-1, self.c0, self.s0, self.s0)))


class BeliefModule(nn.Module):
    """Episode-level latent u ∈ R^K for the ``belief`` objective: posterior, causal prior, conditioning.

    * posterior q(u | window): a set encoder over the window's transitions (z_t, z_{t+1}, a_t), mean-pooled
      over t, then Linear -> (μ_q, log σ²_q). A permutation-invariant summary of transitions can hold what
      is constant over the window (an episode parameter is) far more easily than time-specific events;
    * prior p(u | h_t): MLP on each causal trunk state -> (μ_p, log σ²_p) per step t;
    * conditioning: ``h + Linear(u)``, so every head keeps its input width and form.
    """

    def __init__(self, latent_dim: int, action_dim: int, width: int, belief_dim: int):
        super().__init__()
        self.dim = belief_dim
        self.transition = nn.Sequential(nn.Linear(2 * latent_dim + action_dim, width), nn.GELU(),
                                        nn.Linear(width, width), nn.GELU())
        self.post_out = nn.Linear(width, 2 * belief_dim)
        self.prior = nn.Sequential(nn.Linear(width, width), nn.GELU(), nn.Linear(width, 2 * belief_dim))
        self.inp = nn.Linear(belief_dim, width)

    def posterior(self, z: torch.Tensor, a: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """z (B, L, D), normalised actions a (B, L, Da) -> μ_q, log σ²_q (B, K) from the L−1 transitions."""
        x = torch.cat([z[:, :-1], z[:, 1:], a[:, :-1]], -1)
        return self.post_out(self.transition(x).mean(1)).chunk(2, -1)

    def prior_of(self, h: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(B, L, width) causal states -> μ_p, log σ²_p (B, L, K)."""
        return self.prior(h).chunk(2, -1)


CONTACT_WEIGHTINGS = ("normalised", "frames")
"""How the touch term's contact weights enter (``XJEPA.loss(contact_weighting=...)``)."""


def combine_horizons(losses: list[torch.Tensor], valid: list[int], weights: tuple[float, ...] = ()) -> torch.Tensor:
    """One term from the per-horizon ``losses`` (one per horizon in ``valid``): their mean when ``weights`` is empty,
    else Σ w_d · loss_d with ``weights`` = (w at Δ = 1, w at every Δ > 1) — the reference's rule (latent 1 / 0.5,
    proprio and touch 0.5 / 0.25), which reads the same for any set of horizons."""
    if not weights:
        return torch.stack(losses).mean()
    if len(weights) != 2:
        raise ValueError(f"horizon weights are (w at Δ = 1, w at Δ > 1), got {len(weights)} numbers")
    return sum(float(weights[0] if d == 1 else weights[1]) * l_d for d, l_d in zip(valid, losses))


def _horizon_weights(w: torch.Tensor | None):
    """``at(d, pos=None)``: the (B, L) target-frame weights ``w`` read at horizon d (at window positions ``pos``);
    None when there are no weights."""

    def at(d: int, pos=None):
        if w is None:
            return None
        return w[:, d:] if pos is None else w[:, pos + d]

    return at


class XJEPA(nn.Module):
    """The X-JEPA model. Construct with :meth:`__init__` kwargs (stored in ``self.config`` for checkpoints).

    Public API (shapes in each docstring): :meth:`encode`, :meth:`trunk`, :meth:`predict`,
    :meth:`forecast`, :meth:`rollout`, :meth:`features`, :meth:`loss`; attributes
    ``variant``, ``horizons``, ``latent_dim``, ``width``, ``inputs``, ``targets``.
    """

    def __init__(self, variant: str = "VFX", proprio_dim: int = 4, touch_dim: int = 7, action_dim: int = 2,
                 image_size: int = 64, channels: tuple[int, ...] = (32, 64, 128, 256), latent_dim: int = 128,
                 width: int = 192, depth: int = 4, heads: int = 8, dropout: float = 0.1,
                 horizons: tuple[int, ...] = (1, 4, 16), objective: str = "latent", tokens: bool = False,
                 sysid: bool = False, max_len: int = 128, vec_dim: int = 64, contact_channel: int = 6,
                 recon_positions: int = 8, pool: bool = False, belief_dim: int = 8, motion_channel: bool = True,
                 gnll_heads: str = "latent", gnll_variance: str = DEFAULT_GNLL_VARIANCE, gnll_logvar_bound: float = 2.0,
                 head_layers: int = 1, encoder: str = "groupnorm", fuse_dim: int = 192, head_form: str = "mlp",
                 sensor_horizons: tuple[int, ...] = ()):
        super().__init__()
        check_variant(variant)
        if encoder not in ENCODERS:
            raise ConfigError(f"unknown encoder {encoder!r}; choose one of {list(ENCODERS)}")
        if head_form not in HEAD_FORMS:
            raise ConfigError(f"unknown head_form {head_form!r}; choose one of {list(HEAD_FORMS)}")
        if objective not in OBJECTIVES:
            raise ConfigError(f"unknown objective {objective!r}; choose one of {list(OBJECTIVES)}")
        horizons = tuple(sorted(int(d) for d in horizons))
        if not horizons or horizons[0] < 1:
            raise ConfigError(f"horizons must be positive integers, got {horizons}")
        sensor_horizons = tuple(sorted(int(d) for d in sensor_horizons))
        if sensor_horizons and not set(sensor_horizons) & set(horizons):
            raise ConfigError(f"sensor_horizons {sensor_horizons} share no horizon with {horizons}")
        if tokens and objective != "latent":
            raise ConfigError("the token variant supports objective='latent' only")
        if gnll_heads not in GNLL_HEADS:
            raise ConfigError(f"unknown gnll_heads {gnll_heads!r}; choose one of {list(GNLL_HEADS)}")
        if gnll_heads != "latent" and objective != "gnll":
            raise ConfigError(f"gnll_heads={gnll_heads!r} needs objective='gnll'")
        check_gnll_variance(gnll_variance, objective, gnll_logvar_bound)
        if objective == "belief" and belief_dim < 1:
            raise ConfigError(f"belief_dim must be ≥ 1 for objective='belief', got {belief_dim}")
        self.config: dict[str, Any] = dict(
            variant=variant, proprio_dim=proprio_dim, touch_dim=touch_dim, action_dim=action_dim,
            image_size=image_size, channels=tuple(channels), latent_dim=latent_dim, width=width, depth=depth,
            heads=heads, dropout=dropout, horizons=horizons, objective=objective, tokens=tokens, sysid=sysid,
            max_len=max_len, vec_dim=vec_dim, contact_channel=contact_channel, recon_positions=recon_positions,
            pool=pool, belief_dim=belief_dim, motion_channel=motion_channel, gnll_heads=gnll_heads,
            gnll_variance=gnll_variance, gnll_logvar_bound=gnll_logvar_bound, head_layers=head_layers,
            encoder=encoder, fuse_dim=fuse_dim, head_form=head_form, sensor_horizons=sensor_horizons)
        self.motion_channel = motion_channel
        self.modal_gnll = objective == "gnll" and gnll_heads == "all"  # proprio/touch heads output (mean, log σ²)
        self.gnll_variance, self.gnll_logvar_bound = gnll_variance, float(gnll_logvar_bound)
        # 'per_head': the heads output the mean only and each owns one log-variance scalar (parameters that
        # exist only with this option, so every other model keeps its state_dict)
        per_head = objective == "gnll" and gnll_variance == "per_head"
        lv_out = 2 if objective == "gnll" and not per_head else 1
        self.variant, self.horizons, self.latent_dim, self.width = variant, horizons, latent_dim, width
        # the proprio / touch heads' horizons: those of the latent heads listed in sensor_horizons (empty: all), so a
        # single-horizon run of a preset with sensor heads at (1, 4) is single-horizon throughout
        self.sensor_horizons = tuple(d for d in horizons if d in sensor_horizons) if sensor_horizons else horizons
        self.objective, self.tokens, self.image_size = objective, tokens, image_size
        self.contact_channel, self.recon_positions = contact_channel, recon_positions
        self.dims = {"proprio": proprio_dim, "touch": touch_dim}
        # a stream of width 0 (a store without touch, as an swm environment's) is neither read nor forecast, so
        # on such a store VX is VX_p and VFX reads and forecasts proprio only
        present = lambda streams: tuple(m for m in streams if self.dims.get(m, 1) > 0)  # noqa: E731
        self.inputs, self.targets = (present(streams) for streams in VARIANTS[variant])
        self.action_dim = action_dim

        self.encoder = FusedEncoder(image_size, tuple(channels), proprio_dim, touch_dim,
                                    "proprio" in self.inputs, "touch" in self.inputs, latent_dim, vec_dim, tokens,
                                    pool=pool, style=encoder, fuse_dim=fuse_dim)
        self.num_tokens = self.encoder.num_tokens if tokens else 1
        self.predictor = CausalPredictor(latent_dim, action_dim, width, depth, heads, dropout, max_len,
                                         self.num_tokens)
        self.latent_heads = nn.ModuleDict({str(d): delta_head(head_form, width, d, action_dim, latent_dim * lv_out,
                                                              head_layers, sensor=False, bn_features=latent_dim)
                                           for d in horizons})
        self.modal_heads = nn.ModuleDict()
        for m in ("proprio", "touch"):
            if m in self.targets:
                self.modal_heads[m] = nn.ModuleDict(
                    {str(d): delta_head(head_form, width, d, action_dim,
                                        self.dims[m] * (lv_out if self.modal_gnll else 1), head_layers, sensor=True)
                     for d in self.sensor_horizons})
        self.latent_logvar = self.modal_logvar = None
        if per_head:  # log σ² = 0 at init: the NLL starts as ½·MSE, near where the free heads' initial outputs sit
            self.latent_logvar = nn.ParameterDict({str(d): nn.Parameter(torch.zeros(())) for d in horizons})
            if self.modal_gnll:
                self.modal_logvar = nn.ModuleDict({m: nn.ParameterDict({str(d): nn.Parameter(torch.zeros(()))
                                                                        for d in self.sensor_horizons})
                                                   for m in self.modal_heads})
        sid_hidden = REFERENCE_SENSOR_HIDDEN if head_form == "reference" else width  # the reference's head_sid: 96
        self.sysid_head = (nn.Sequential(nn.Linear(width, sid_hidden), nn.GELU(),
                                         nn.Linear(sid_hidden, len(SYSID_PARAMS))) if sysid else None)
        self.belief = (BeliefModule(latent_dim, action_dim, width, belief_dim) if objective == "belief" else None)
        if objective == "recon":
            self.decoder = Decoder(tuple(channels), image_size)
            self.adapters = nn.ModuleDict({str(d): nn.Linear(width + (d * action_dim if d > 1 else 0),
                                                             self.decoder.in_dim) for d in horizons})
        # preprocessing statistics (set from the train split by set_stats)
        for name, dim in (("proprio", proprio_dim), ("touch", touch_dim), ("action", action_dim),
                          ("param", len(SYSID_PARAMS))):
            self.register_buffer(f"{name}_mean", torch.zeros(dim))
            self.register_buffer(f"{name}_std", torch.ones(dim))

    # ------------------------------------------------------------------ preprocessing
    @torch.no_grad()
    def set_stats(self, stats: dict[str, np.ndarray | torch.Tensor]) -> None:
        """Set normalisation buffers from ``{"proprio_mean": (Dp,), "proprio_std": ..., "touch_*", "action_*",
        "param_*"}`` (any subset). Standard deviations are floored to avoid division by ~0."""
        for k, v in stats.items():
            buf = getattr(self, k)
            v = torch.as_tensor(np.asarray(v), dtype=torch.float32)
            if k.endswith("_std"):
                v = torch.where(v > 1e-6, v, torch.ones_like(v))
            buf.copy_(v.to(buf.device))

    def _dev(self) -> torch.device:
        return self.proprio_mean.device

    def _t(self, x) -> torch.Tensor:
        return torch.as_tensor(x, device=self._dev())

    def norm(self, name: str, x) -> torch.Tensor:
        """Normalise raw ``proprio`` / ``touch`` / ``action`` / ``param`` values with the train-split stats."""
        x = self._t(x).float()
        return (x - getattr(self, f"{name}_mean")) / getattr(self, f"{name}_std")

    def denorm(self, name: str, x: torch.Tensor) -> torch.Tensor:
        return x * getattr(self, f"{name}_std") + getattr(self, f"{name}_mean")

    def prep_frames(self, frames) -> torch.Tensor:
        """(B, L, H, W) uint8 or float in [0,1] -> (B, L, 2, S, S) float: frame and temporal difference.

        The difference channel is ``x_t − x_{t−1}`` inside the given sequence and zero at its first frame
        (matching t = 0 of an episode, which has no previous frame). With ``motion_channel=False`` it is
        zero everywhere (the γ ledger's "motion channel off"; same architecture, no motion input)."""
        f = area_downsample(self._t(frames), self.image_size)
        f = f.float() / 255.0 if f.dtype == torch.uint8 else f.float()
        diff = torch.cat([torch.zeros_like(f[:, :1]), f[:, 1:] - f[:, :-1]], dim=1)
        if not self.motion_channel:
            diff = torch.zeros_like(diff)
        return torch.stack([f, diff], dim=2)

    # ------------------------------------------------------------------ public API
    def encode(self, frames, proprio=None, touch=None) -> torch.Tensor:
        """Per-frame latents.

        Args:
            frames: (B, L, H, W) uint8 or float in [0,1] (any H ≥ image_size; area-downsampled inside).
            proprio: (B, L, Dp) raw proprioception (ignored unless the variant inputs it).
            touch: (B, L, Dt) raw touch (ignored unless the variant inputs it).
        Returns:
            z: (B, L, latent_dim); in token mode (B, L, S, latent_dim).
        """
        return self._encode_prepped(self.prep_frames(frames), proprio, touch)

    def _encode_prepped(self, x: torch.Tensor, proprio, touch) -> torch.Tensor:
        """:meth:`encode` from frames already through :meth:`prep_frames` ((B, L, 2, S, S))."""
        b, L = x.shape[:2]
        p = self.norm("proprio", proprio).reshape(b * L, -1) if "proprio" in self.inputs else None
        t = self.norm("touch", touch).reshape(b * L, -1) if "touch" in self.inputs else None
        z = self.encoder(x.reshape(b * L, *x.shape[2:]), p, t)
        return z.reshape(b, L, *z.shape[1:])

    def trunk_tokens(self, z: torch.Tensor, actions, cache: KVCache | None = None) -> torch.Tensor:
        """(B, L, D) or (B, L, S, D) latents + (B, L, Da) raw actions -> (B, L, S, width) causal states.
        ``cache``: these steps continue the ones fed before with the same cache (incremental decoding)."""
        if z.dim() == 3:
            z = z[:, :, None, :]
        return self.predictor(z, self.norm("action", actions), cache)

    def trunk(self, z: torch.Tensor, actions, cache: KVCache | None = None) -> torch.Tensor:
        """Causal predictor states: the state every head reads when only the past is known.

        Args:
            z: (B, L, latent_dim) from :meth:`encode` (token mode: (B, L, S, latent_dim)).
            actions: (B, L, Da) raw actions; ``actions[:, t]`` is the action taken after observation t
                (pad the last one with zeros when it is unknown). State t depends on z[:, :t+1] and
                actions[:, :t+1] only.
        Returns:
            h: (B, L, width) (token mode: mean over the S token states). For ``objective='belief'`` the
            transformer state conditioned on the causal prior's mean, h_t + W·μ_p(h_t) (still causal;
            :meth:`trunk_raw` gives the unconditioned state).
            With ``cache`` (a :class:`~pokeworld.models.predictor.KVCache`), z and actions are the steps that
            follow those fed before with the same cache, and only their states are returned.
        """
        h = self.trunk_raw(z, actions, cache)
        if self.belief is not None:
            h = self.condition(h, self.belief.prior_of(h)[0])
        return h

    def trunk_raw(self, z: torch.Tensor, actions, cache: KVCache | None = None) -> torch.Tensor:
        """Transformer states (B, L, width) before any belief conditioning (equal to :meth:`trunk` otherwise)."""
        return self.trunk_tokens(z, actions, cache).mean(2)

    def _need_belief(self) -> "BeliefModule":
        if self.belief is None:
            raise ValueError(f"objective {self.objective!r} has no episode-level latent (objective='belief' has)")
        return self.belief

    def condition(self, h: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """Heads' input given belief sample / mean u: (B, L, width) + (B, K) or (B, L, K) -> (B, L, width)."""
        if u.dim() == h.dim() - 1:
            u = u[:, None]
        return h + self._need_belief().inp(u)

    def prior(self, z: torch.Tensor, actions) -> tuple[torch.Tensor, torch.Tensor]:
        """Causal prior p(u | history ≤ t): μ_p, log σ²_p (B, L, K) from latents (B, L, D) and raw actions."""
        return self._need_belief().prior_of(self.trunk_raw(z, actions))

    def posterior(self, z: torch.Tensor, actions) -> tuple[torch.Tensor, torch.Tensor]:
        """Amortised posterior q(u | window): μ_q, log σ²_q (B, K) from all of the window's transitions. In training
        the window extends past every step t but the first, so for those steps q sees their future: a training
        device, never the probed state. On a probe window that ends at the probed observation it sees exactly
        the history the prior sees, so there it measures what the posterior encodes from that evidence."""
        return self._need_belief().posterior(z, self.norm("action", actions))

    def action_window(self, actions, delta: int) -> torch.Tensor:
        """(B, L, Da) raw -> (B, L, delta·Da): normalised actions[t:t+delta] flattened, zero past the end."""
        a = self.norm("action", actions)
        b, L, da = a.shape
        a = torch.cat([a, a.new_zeros(b, delta, da)], 1)
        return a.unfold(1, delta, 1)[:, :L].transpose(-1, -2).reshape(b, L, delta * da)

    def _head_out(self, h, actions, delta: int, head: nn.Module) -> torch.Tensor:
        # states may cover fewer steps than the actions (a planner's one state and a whole program): step t's
        # window is actions[t:t+Δ] either way
        aw = self.action_window(actions, delta)[:, :h.shape[1]]
        if h.dim() == 4:  # token states: same action window for every token of the step
            aw = aw[:, :, None, :].expand(*h.shape[:3], aw.shape[-1])
        return head(h, aw)

    def _check_delta(self, delta: int) -> None:
        if delta not in self.horizons:
            raise ValueError(f"no direct head for delta={delta}; this model has horizons {self.horizons}")

    def predict(self, h: torch.Tensor, actions, delta: int, return_logvar: bool = False):
        """Direct Δ-step latent prediction.

        Args:
            h: (B, L, width) trunk states (token mode: (B, L, S, width) from :meth:`trunk_tokens`).
            actions: (B, L, Da) raw actions aligned as in :meth:`trunk`; the head at t sees actions[t:t+Δ]
                flattened (zero-padded past the window end). ``h`` may cover fewer steps than the actions
                (e.g. one state and the Δ actions that follow it: (B, 1, width) and (B, ≥Δ, Da)).
            delta: one of ``self.horizons``.
        Returns:
            z_hat: (B, L, latent_dim) (token mode (B, L, S, latent_dim)): prediction of z at t+Δ for every t
            (positions t+Δ ≥ L use padded actions). With ``return_logvar`` (gnll objective) also the log-variance.
        """
        self._check_delta(delta)
        out = self._head_out(h, actions, delta, self.latent_heads[str(delta)])
        if self.objective == "gnll":
            mean, logvar = self._mean_logvar(out, self.latent_logvar, delta)
            return (mean, logvar) if return_logvar else mean
        return (out, None) if return_logvar else out

    def _mean_logvar(self, out: torch.Tensor, head_logvars, delta: int) -> tuple[torch.Tensor, torch.Tensor]:
        """A gnll head's output -> (mean, the log-variance the NLL uses), per ``gnll_variance``: 'free' / 'beta'
        the raw second half, 'bounded' that half squashed into (−b, b), 'per_head' the head's scalar broadcast
        to the mean's shape (so every reader of log-variances sees the variance the loss used)."""
        if self.gnll_variance == "per_head":
            return out, head_logvars[str(delta)].expand_as(out)
        mean, logvar = out.chunk(2, -1)
        if self.gnll_variance == "bounded":
            logvar = bounded_logvar(logvar, self.gnll_logvar_bound)
        return mean, logvar

    def _nll(self, mean: torch.Tensor, logvar: torch.Tensor, target: torch.Tensor, weight: torch.Tensor | None,
             beta: float) -> torch.Tensor:
        """The gnll objective's per-head term for this model's ``gnll_variance`` (log-variances from
        :meth:`_mean_logvar`)."""
        if self.gnll_variance == "beta":
            return beta_nll(mean, logvar, target, weight, beta)
        if self.gnll_variance == "per_head":
            return head_logvar_nll(mean, logvar, target, weight)
        return gaussian_nll(mean, logvar, target, weight)

    def forecast(self, h: torch.Tensor, actions, delta: int, modality: str, raw: bool = True,
                 return_logvar: bool = False):
        """Cross-modal forecast of ``modality`` ('touch' / 'proprio') at t+Δ: (B, L, Dm), raw units by default.
        With ``return_logvar`` also its log-variance in normalised units (``gnll_heads='all'``; None otherwise)."""
        if modality not in self.modal_heads:
            raise ValueError(f"variant {self.variant} has no {modality!r} forecasting head")
        if delta not in self.sensor_horizons:
            raise ValueError(f"no direct {modality} head for delta={delta}; this model has {self.sensor_horizons}")
        y = self._head_out(h, actions, delta, self.modal_heads[modality][str(delta)])
        logvar = None
        if self.modal_gnll:
            y, logvar = self._mean_logvar(y, None if self.modal_logvar is None else self.modal_logvar[modality],
                                          delta)
        y = self.denorm(modality, y) if raw else y
        return (y, logvar) if return_logvar else y

    def sysid(self, h: torch.Tensor, raw: bool = True) -> torch.Tensor:
        """System-ID control head: (B, L, width) -> (B, L, 3) estimates of (log m, γ, log k)."""
        if self.sysid_head is None:
            raise ValueError("this model was built without the sysid head")
        y = self.sysid_head(h)
        return self.denorm("param", y) if raw else y

    @torch.no_grad()
    def rollout(self, z_context: torch.Tensor, actions_future, steps: int, actions_context=None) -> torch.Tensor:
        """Autoregressive rollout composing the Δ=1 head, feeding each prediction back into the predictor.

        Args:
            z_context: (B, C, latent_dim) encoded context observations 0..C-1 (global-latent models only).
            actions_future: raw actions, either (B, C+steps-1, Da) aligned with the context start
                (``actions[:, t]`` after observation t, the usual window layout; longer is fine), or
                (B, steps, Da) = the actions after observations C-1 .. C+steps-2, in which case
                ``actions_context`` (B, C-1, Da) must give the actions after observations 0..C-2.
            steps: number of future latents to produce.
        Returns:
            z_hat: (B, steps, latent_dim) predictions of z at C, C+1, ..., C+steps-1.
        """
        if self.tokens:
            raise ValueError("rollout is defined for global-latent models")
        self._check_delta(1)
        C = z_context.shape[1]
        acts = self._t(actions_future).float()
        if actions_context is not None:
            acts = torch.cat([self._t(actions_context).float()[:, :C - 1], acts], 1)
        if acts.shape[1] < C + steps - 1:
            raise ValueError(f"rollout needs actions for {C + steps - 1} steps from the context start "
                             f"(or pass actions_context), got {acts.shape[1]}")
        outs = []
        if C + steps - 1 <= self.predictor.max_len:
            # every step's state is that of the whole grown sequence (causal, absolute time): feed each
            # prediction alone against cached keys/values instead of re-running the sequence
            cache = KVCache()
            h = self.trunk(z_context, acts[:, :C], cache)
            for L in range(C, C + steps):
                z_next = self.predict(h[:, -1:], acts[:, L - 1:L], 1)
                outs.append(z_next)
                if L < C + steps - 1:
                    h = self.trunk(z_next, acts[:, L:L + 1], cache)
            return torch.cat(outs, 1)
        seq = z_context  # longer than the predictor's context: slide a max_len window (times shift every step)
        for _ in range(steps):
            L = seq.shape[1]
            ctx = seq[:, -self.predictor.max_len:]
            a = acts[:, L - ctx.shape[1]:L]
            h = self.trunk(ctx, a)
            z_next = self.predict(h[:, -1:], a[:, -1:], 1)
            outs.append(z_next)
            seq = torch.cat([seq, z_next], 1)
        return torch.cat(outs, 1)

    @torch.no_grad()
    def features(self, frames, proprio, touch, actions) -> torch.Tensor:
        """Frozen predictor state for probes: encode + trunk in eval mode, no grad. Returns (B, L, width)."""
        was = self.training
        self.eval()
        try:
            return self.trunk(self.encode(frames, proprio, touch), actions)
        finally:
            self.train(was)

    # ------------------------------------------------------------------ training objective
    def forward(self, batch: dict[str, torch.Tensor], **kw) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """Same as :meth:`loss` (so DistributedDataParallel hooks see a forward call)."""
        return self.loss(batch, **kw)

    def loss(self, batch: dict[str, torch.Tensor], *, sigreg_weight: float = 0.02, sigreg_dirs: int = 1024,
             sigreg_seed: int = 0, sigreg_knots: int = 17, token_rows: int = 4096, token_dirs: int = 256,
             touch_contact_weight: float = 4.0, proprio_weight: float = 1.0, touch_weight: float = 1.0,
             sysid_weight: float = 0.5, glide_loss_weight: float = 1.0, belief_kl_weight: float = 0.01,
             motion_loss_weight: float = 0.0, sigreg_directions: torch.Tensor | None = None,
             sigreg_pool: str = "step", sigreg_rows: int = 4096, sigreg_row_index: torch.Tensor | None = None,
             gnll_beta: float = 0.5, sigreg_reference_rows: int = 0, sigreg_t_max: float = 3.0,
             latent_horizon_weights: tuple[float, ...] = (), sensor_horizon_weights: tuple[float, ...] = (),
             contact_weighting: str = "normalised") -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """Training loss on a batch of windows.

        Args:
            batch: ``frames`` (B, L, H, W) uint8, ``proprio`` (B, L, Dp), ``touch`` (B, L, Dt), ``actions``
                (B, L, Da) raw (last action of an episode zero-padded), optional ``params`` (B, 3) raw
                (log m, γ, log k) for the sysid control, optional ``glide`` (B, L) bool glide-frame mask.
            glide_loss_weight: weight W of a prediction-loss term (latent/recon, proprio, touch; not SIGReg,
                not sysid) whose target frame t+Δ is a glide frame, 1 otherwise; each term stays a weighted
                mean. Needs ``batch["glide"]``; with it the term ``glide_loss_share`` (Σ w·glide / Σ w over
                target frames) is reported.
            motion_loss_weight: α of the magnitude-weighted motion-forecast targets (the γ ledger): each latent
                Δ-head term (latent/gnll/belief objectives, the token term) weights its target frame t+Δ by
                ``1 + α · m / mean(m)``, m = the frame's mean absolute temporal difference (labels-free),
                composed with the glide weights; 0 = off. Not applied to the proprio/touch heads.
            sigreg_directions: optional (latent_dim, K) SIGReg directions replacing the ones drawn from
                ``sigreg_seed`` (K = ``sigreg_dirs``, or ``token_dirs`` in token mode); the trainer draws the
                same ones on the host and uploads them without a sync.
            belief_kl_weight: β of the ``belief`` objective: the loss adds β · mean_t KL(q(u | window) ‖
                p(u | h_t)), reported as ``kl`` (and ``kl_last``, the KL at the window's last step).
            sigreg_pool: global-latent SIGReg rows (:data:`~pokeworld.losses.SIGREG_POOLS`): 'step' = one
                statistic per time step over the B batch rows, averaged over time; 'pooled' = one statistic over
                the B·L rows, subsampled to ``sigreg_rows`` (from ``sigreg_seed``, or ``sigreg_row_index`` when
                given: the trainers draw it on the host). Not used by the token path (always pooled over
                ``token_rows``) or ``recon`` (no SIGReg).
            sigreg_reference_rows: global-latent SIGReg statistic at this sample count instead of its rows' own
                (:func:`~pokeworld.losses.epps_pulley`; 0 = the rows' own): λ then means one strength at any batch.
            gnll_beta: β of ``gnll_variance='beta'`` (β-NLL); the effective weight on latent errors is then also
                reported as ``latent_weight`` (mean e^{(β−1)s}; the other variants' weight is
                ``latent_precision``).
            sigreg_t_max: the Epps–Pulley integral's half-range [0, t_max] (``sigreg_knots`` trapezoid knots on it;
                the integrand is even, so this is the integral over [−t_max, t_max]).
            latent_horizon_weights: (w at Δ = 1, w at every Δ > 1) of the latent (or recon) horizons' terms, summed
                (:func:`combine_horizons`); empty: the mean over the horizons.
            sensor_horizon_weights: the same for the proprio / touch heads, each modality's sum then times
                ``proprio_weight`` / ``touch_weight``; empty: their mean.
            contact_weighting: how the touch term's contact weights enter (:data:`CONTACT_WEIGHTINGS`):
                'normalised' — a weighted mean Σ w·e / Σ w (contact frames gain share, the term's scale stays
                that of an MSE); 'frames' — Σ w·e / N, the mean over frames of the weighted error (the reference's;
                the weight also scales the term up by the mean weight).
        Returns:
            (total loss, {term name: detached scalar}).
        """
        frames, proprio, touch, actions = batch["frames"], batch["proprio"], batch["touch"], batch["actions"]
        L = frames.shape[1]
        x = self.prep_frames(frames)  # (B, L, 2, S, S): shared by the encoder and the motion weights
        z = self._encode_prepped(x, proprio, touch)
        hs = self.trunk_tokens(z, actions)  # (B, L, S, W)
        h = hs.mean(2)
        terms: dict[str, torch.Tensor] = {}
        total = z.new_zeros((), dtype=torch.float32)
        h_causal = h
        if self.belief is not None:
            h, h_causal, kl_term = self._belief_terms(z, h, actions, terms)
            total = total + belief_kl_weight * kl_term
        valid = [d for d in self.horizons if d < L]
        gw, lw = self._target_weights(batch, x, valid, glide_loss_weight, motion_loss_weight, terms)
        at = _horizon_weights(gw)  # target-frame weights of horizon d (at window positions ``pos``)
        at_latent = _horizon_weights(lw)
        if self.tokens:
            total = total + self._token_terms(z, hs, h, actions, valid, at_latent, terms, latent_horizon_weights)
            terms["sigreg"] = sigreg(z.reshape(-1, z.shape[-1]), token_dirs, sigreg_seed, sigreg_knots,
                                     max_rows=token_rows, directions=sigreg_directions, t_max=sigreg_t_max)
        elif self.objective in ("latent", "gnll", "belief"):
            total = total + self._latent_terms(z, h, actions, valid, at_latent, gnll_beta, terms,
                                               latent_horizon_weights)
            # 'step': per time step over the batch (LeWM), then averaged over time and directions; 'pooled': one
            # statistic over the batch × time rows (subsampled), so its N — and the statistic's excess over the
            # null under any departure from N(0, I) — is L times the per-step one (docs/design.md)
            terms["sigreg"] = sigreg(sigreg_rows_of(z, sigreg_pool), sigreg_dirs, sigreg_seed, sigreg_knots,
                                     max_rows=sigreg_rows if sigreg_pool == "pooled" else None,
                                     directions=sigreg_directions,
                                     rows=sigreg_row_index if sigreg_pool == "pooled" else None,
                                     reference_rows=sigreg_reference_rows, t_max=sigreg_t_max)
        else:  # recon: shared decoder on per-horizon adapters; SIGReg omitted (pixels anchor the latent)
            total = total + self._recon_terms(frames, h, actions, valid, gw, at, terms, latent_horizon_weights)
        if "sigreg" in terms:
            total = total + sigreg_weight * terms["sigreg"]
        for m, w in (("proprio", proprio_weight), ("touch", touch_weight)):
            if m in self.modal_heads:
                terms[m] = self._modal_term(m, batch, h, actions, at, touch_contact_weight, gnll_beta,
                                            sensor_horizon_weights, contact_weighting)
                total = total + w * terms[m]
        if self.sysid_head is not None:
            if "params" not in batch:
                raise ValueError("sysid control needs batch['params'] (log_m, gamma, log_k)")
            tgt = self.norm("param", batch["params"])[:, None, :].expand(-1, L, -1)
            terms["sysid"] = masked_mse(self.sysid_head(h_causal), tgt)
            total = total + sysid_weight * terms["sysid"]
        return total, {k: v.detach() for k, v in terms.items()}

    # ------------------------------------------------------------------ loss terms, one per objective
    def _belief_terms(self, z, h, actions, terms):
        """The belief objective's ELBO pieces: (h conditioned on a posterior sample, the causal h, the KL term)."""
        # one ELBO per step t with a shared variational posterior: q may depend on anything (here the
        # whole window), the bound holds for each t; prediction terms read h_t + W·u, u ~ q
        mu_q, lv_q = self.posterior(z, actions)
        mu_p, lv_p = self.belief.prior_of(h)
        kl = gaussian_kl(mu_q[:, None], lv_q[:, None], mu_p, lv_p)  # (B, L)
        terms["kl"], terms["kl_last"] = kl.mean(), kl[:, -1].mean()
        u = mu_q + torch.exp(0.5 * lv_q.float().clamp(*LOGVAR_RANGE)).to(mu_q.dtype) * torch.randn_like(mu_q)
        # the sysid control reads the causal state the probes read (prior mean), never the posterior sample:
        # labels flowing into u would make the episode latent a supervised parameter code
        return self.condition(h, u), self.condition(h, mu_p), terms["kl"]

    def _target_weights(self, batch, x, valid, glide_loss_weight, motion_loss_weight, terms):
        """(B, L) target-frame weights: the glide weights (None at W = 1, which keeps the unweighted losses bit for
        bit) and the latent targets' weights (glide times motion magnitude when ``motion_loss_weight`` > 0)."""
        gw = None
        if "glide" in batch:
            if glide_loss_weight != 1.0:
                gw = glide_weights(batch["glide"], glide_loss_weight)
            terms["glide_loss_share"] = glide_loss_share(batch["glide"], glide_loss_weight, valid)
        elif glide_loss_weight != 1.0:
            raise ValueError("glide_loss_weight != 1 needs batch['glide'] (the glide-frame mask)")
        lw = gw
        if motion_loss_weight > 0:
            if self.objective == "recon":
                raise ValueError("motion_loss_weight weights latent targets; the recon objective has none")
            mw = motion_weights(x[:, :, 0], motion_loss_weight)  # the frame channel, as the encoder sees it
            lw = mw if gw is None else gw * mw
        return gw, lw

    def _token_terms(self, z, hs, h, actions, valid, at_latent, terms, weights=()) -> torch.Tensor:
        """The token variant's prediction terms (combined over horizons by :func:`combine_horizons`)."""
        # the paper's token variant keeps the shared Δ ∈ {1, 4, 16} heads and adds dense prediction: Δ = 1 is
        # predicted per token, spatially aligned; the longer horizons predict the token-mean latent from the
        # token-mean state, as the global model does
        L = z.shape[1]
        z_mean, losses = z.mean(2), []
        for d in valid:
            if d == 1:
                pred = self._head_out(hs, actions, 1, self.latent_heads["1"])
                w1 = at_latent(1)
                l_d = masked_mse(pred[:, :-1], z[:, 1:],
                                 None if w1 is None else w1[..., None].expand(z[:, 1:].shape[:-1]))
            else:
                l_d = masked_mse(self.predict(h, actions, d)[:, :L - d], z_mean[:, d:], at_latent(d))
            terms[f"pred_{d}"] = l_d
            losses.append(l_d)
        return combine_horizons(losses, valid, weights)

    def _latent_terms(self, z, h, actions, valid, at_latent, gnll_beta, terms, weights=()) -> torch.Tensor:
        """The latent Δ-heads' terms (MSE, or Gaussian NLL for ``gnll``; combined over horizons by
        :func:`combine_horizons`)."""
        L = z.shape[1]
        losses, precisions, beta_weights = [], [], []
        for d in valid:
            mean, logvar = self.predict(h, actions, d, return_logvar=True)
            if self.objective == "gnll":
                l_d = self._nll(mean[:, :L - d], logvar[:, :L - d], z[:, d:], at_latent(d), gnll_beta)
                # the NLL weighs a latent error by exp(-s): its mean is the latent terms' effective weight
                # (β-NLL multiplies it by sg(e^{βs}); that product is reported as latent_weight)
                precisions.append(nll_precision(logvar.detach()).mean())
                if self.gnll_variance == "beta":
                    beta_weights.append(beta_nll_weight(logvar.detach(), gnll_beta).mean())
            else:
                l_d = masked_mse(mean[:, :L - d], z[:, d:], at_latent(d))
            terms[f"pred_{d}"] = l_d
            losses.append(l_d)
        if precisions:
            terms["latent_precision"] = torch.stack(precisions).mean()
        if beta_weights:
            terms["latent_weight"] = torch.stack(beta_weights).mean()
        return combine_horizons(losses, valid, weights)

    def _recon_terms(self, frames, h, actions, valid, gw, at, terms, weights=()) -> torch.Tensor:
        """The reconstruction control's pixel terms (combined over horizons by :func:`combine_horizons`)."""
        L = frames.shape[1]
        img = area_downsample(frames, self.image_size).float() / 255.0
        losses = []
        for d in valid:
            pos = torch.linspace(0, L - 1 - d, min(self.recon_positions, L - d), device=h.device).round().long()
            inp = h[:, pos]
            if d > 1:
                inp = torch.cat([inp, self.action_window(actions, d)[:, pos]], -1)
            rec = self.decoder(self.adapters[str(d)](inp)).reshape(h.shape[0], len(pos), *img.shape[-2:])
            if gw is None:
                l_d = (rec - img[:, pos + d]).pow(2).mean()
            else:
                l_d = masked_mse(rec.flatten(2), img[:, pos + d].flatten(2), at(d, pos))
            terms[f"recon_{d}"] = l_d
            losses.append(l_d)
        return combine_horizons(losses, valid, weights)

    def _modal_term(self, m, batch, h, actions, at, touch_contact_weight, gnll_beta, weights=(),
                    contact_weighting="normalised") -> torch.Tensor:
        """The proprio or touch forecasting term over the sensor horizons (combined by :func:`combine_horizons`;
        contact frames weighted for touch, per ``contact_weighting``)."""
        L = h.shape[1]
        target = self.norm(m, batch[m])
        valid = [d for d in self.sensor_horizons if d < L]
        losses = []
        for d in valid:
            pred, logvar = self.forecast(h, actions, d, m, raw=False, return_logvar=True)
            weight, scale = at(d), None
            if m == "touch" and 0 <= self.contact_channel < batch[m].shape[-1]:
                contact = batch[m][:, d:, self.contact_channel] > 0.5
                cw = 1.0 + (touch_contact_weight - 1.0) * contact.float()
                if contact_weighting == "frames":
                    # Σ cw·g·e / Σ g instead of Σ cw·g·e / Σ cw·g: the weighted mean times Σ cw·g / Σ g (data only)
                    scale = cw.mean() if weight is None else (cw * weight).sum() / weight.sum().clamp_min(1e-8)
                weight = cw if weight is None else cw * weight  # the two reweightings compose
            if logvar is None:
                term = masked_mse(pred[:, :L - d], target[:, d:], weight)
            else:
                term = self._nll(pred[:, :L - d], logvar[:, :L - d], target[:, d:], weight, gnll_beta)
            losses.append(term if scale is None else term * scale)
        return combine_horizons(losses, valid, weights)
