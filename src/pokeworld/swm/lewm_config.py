"""The configuration of ``pokeworld swm-certify-lewm``: :class:`LeWMConfig` and its presets.

Kept apart from :mod:`.lewm`, whose model classes derive from stable-worldmodel's, so that the command's
``--help`` shows its options (and the CLI its one line on installing the extra) where the extra is missing.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from ..config import from_preset
from ..errors import ConfigError

INPUTS = ("vision", "proprio", "touch")
READOUTS = ("predictor", "embedding", "both")


@dataclass
class LeWMConfig:
    """Train stable-worldmodel's LeWM on a PokeWorld store and certify it (``pokeworld swm-certify-lewm``)."""

    data: str = "out/data/standard"
    """PokeWorld store (``pokeworld generate`` output); LeWM trains on its train split."""
    out: str = "out/swm/lewm"
    """Run directory: config.json, metrics.jsonl, ckpt.pt, protocol/ (the certify_model report)."""
    inputs: tuple[str, ...] = ("vision", "proprio")
    """Observation streams: "vision" (LeWM's own, required), "proprio", "touch" (added to the CLS embedding)."""
    image_size: int = 32
    """Side the frames are area-resized to before the encoder."""
    patch_size: int = 8
    """ViT patch side (image_size must be a multiple of it)."""
    embed_dim: int = 64
    """LeWM's embed_dim: encoder width, embedding and predictor width (192 in le-wm)."""
    encoder_depth: int = 2
    """Encoder transformer blocks (12 in ViT-tiny)."""
    encoder_heads: int = 4
    """Encoder attention heads."""
    predictor_depth: int = 2
    """Predictor blocks (6 in le-wm)."""
    predictor_heads: int = 4
    """Predictor attention heads (16 in le-wm)."""
    dim_head: int = 16
    """Width per attention head (64 in le-wm)."""
    mlp_dim: int = 256
    """Transformer MLP width of encoder and predictor (2048 in le-wm's predictor)."""
    projector_hidden: int = 256
    """Hidden width of the projector and pred_proj MLPs (2048 in le-wm)."""
    history_size: int = 3
    """Context frames of the predictor (le-wm: 3)."""
    num_preds: int = 1
    """Prediction shift (le-wm: 1); a training window holds history_size + num_preds observations."""
    dropout: float = 0.1
    """Predictor dropout (le-wm: 0.1)."""
    sigreg_weight: float = 0.09
    """λ of LeWM's loss, pred_loss + λ·SIGReg (le-wm: 0.09)."""
    sigreg_knots: int = 17
    """SIGReg integration knots (le-wm: 17)."""
    sigreg_proj: int = 1024
    """SIGReg random projections per step (le-wm: 1024)."""
    steps: int = 1500
    """Optimiser steps."""
    batch_size: int = 64
    """Windows per step (le-wm: 128)."""
    lr: float = 5e-4
    """AdamW peak learning rate (le-wm: 5e-5 over 100 GPU epochs; too slow for a CPU budget of minutes)."""
    weight_decay: float = 1e-3
    """AdamW weight decay (le-wm: 1e-3)."""
    warmup_frac: float = 0.05
    """Fraction of steps of linear warmup before the cosine decay."""
    grad_clip: float = 1.0
    """Gradient-norm clip (le-wm: 1.0)."""
    log_every: int = 50
    """Steps between metrics.jsonl rows."""
    ckpt_every: int = 250
    """Steps between checkpoints (training resumes from the last one)."""
    threads: int = 1
    """torch CPU threads (0: leave torch's default)."""
    seed: int = 0
    """Seed of the initialisation (shared by the untrained twin), window sampling, dropout and SIGReg."""
    readout: str = "predictor"
    """State handed to the protocol: "predictor" (the paper's choice for X-JEPA), "embedding" or "both"."""
    protocol_preset: str = "cpu"
    """Preset of pokeworld.protocol.ProtocolConfig for certify_model."""
    protocol_overrides: dict[str, Any] = field(default_factory=dict)
    """ProtocolConfig fields to override (e.g. {"max_windows": 3000})."""
    compare_runs: tuple[str, ...] = ()
    """Trained X-JEPA run directories certified beside the LeWM on the same store with the same ProtocolConfig
    (``out``/compare/<run>/); the side-by-side table goes to ``out``/comparison.md and .json."""

    def __post_init__(self) -> None:
        self.inputs = tuple(self.inputs)
        if "vision" not in self.inputs or set(self.inputs) - set(INPUTS) or len(set(self.inputs)) != len(self.inputs):
            raise ConfigError(f"inputs must include 'vision' and be distinct names from {list(INPUTS)}, got "
                              f"{list(self.inputs)}")
        if self.image_size < self.patch_size or self.image_size % self.patch_size:
            raise ConfigError(f"image_size {self.image_size} must be a positive multiple of patch_size "
                              f"{self.patch_size}")
        if min(self.embed_dim, self.encoder_depth, self.predictor_depth, self.history_size, self.num_preds,
               self.steps, self.batch_size, self.log_every, self.ckpt_every) < 1:
            raise ConfigError("widths, depths, history_size, num_preds, steps, batch_size, log_every and ckpt_every "
                              "must be >= 1")
        if self.batch_size < 2:
            raise ConfigError("batch_size must be >= 2: SIGReg and BatchNorm need several embeddings per step")
        if self.readout not in READOUTS:
            raise ConfigError(f"readout must be one of {list(READOUTS)}, got {self.readout!r}")
        if not 0 <= self.warmup_frac < 1 or self.lr <= 0:
            raise ConfigError("warmup_frac must be in [0, 1) and lr > 0")


PRESETS: dict[str, dict[str, Any]] = {
    "tiny": {"image_size": 16, "patch_size": 4, "embed_dim": 32, "encoder_depth": 1, "predictor_depth": 1,
             "encoder_heads": 2, "predictor_heads": 2, "mlp_dim": 64, "projector_hidden": 64, "steps": 60,
             "batch_size": 32, "lr": 2e-3, "sigreg_proj": 256, "log_every": 5, "ckpt_every": 20,
             "protocol_preset": "tiny"},
    "cpu": {},
    "paper": {"image_size": 64, "patch_size": 8, "embed_dim": 192, "encoder_depth": 12, "encoder_heads": 3,
              "predictor_depth": 6, "predictor_heads": 16, "dim_head": 64, "mlp_dim": 2048, "projector_hidden": 2048,
              "batch_size": 128, "steps": 50000, "lr": 5e-5, "threads": 0, "protocol_preset": "paper"},
}
# training-irrelevant fields: changing them reuses a trained model instead of refusing the run directory
NOT_TRAINING = ("out", "log_every", "threads", "readout", "protocol_preset", "protocol_overrides", "compare_runs")


def make_config(preset: str = "cpu", **overrides) -> LeWMConfig:
    return from_preset(LeWMConfig, PRESETS, preset, **overrides)


__all__ = ["INPUTS", "READOUTS", "LeWMConfig", "PRESETS", "NOT_TRAINING", "make_config"]
