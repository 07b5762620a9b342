"""LeWM, stable-worldmodel's LeJEPA world model, trained on a PokeWorld store and certified by the protocol.

What comes from stable-worldmodel (``stable_worldmodel.wm``): the ``LeWM`` model (encode / predict / rollout),
its autoregressive ``Predictor`` (causal transformer with AdaLN-zero action conditioning), the action
``Embedder``, the projector / predictor-projector ``MLP`` (BatchNorm1d, as LeWM's model config sets it), the
``SIGReg`` objective and the ``Transformer`` / ``Block`` the encoder is assembled from. The training objective is
LeWM's ``lejepa_forward`` (le-wm ``train.py``): encode ``history_size + num_preds`` frames, predict frames
``num_preds..`` from the first ``history_size`` frames and their actions, loss = MSE(pred, target) +
``sigreg_weight`` · SIGReg(embeddings as (T, B, D)), both terms back-propagating into the encoder (no
stop-gradient, no EMA target: that is LeWM).

What PokeWorld supplies because stable-worldmodel 0.1.1 does not ship it:

* the encoder. LeWM calls ``encoder(pixels, interpolate_pos_encoding=True).last_hidden_state[:, 0]``, a Hugging
  Face ViT from stable-pretraining (the ``train`` extra, not installed by ``pokeworld[swm]``). :class:`PatchViT`
  is a ViT-tiny-shaped encoder built from swm's own ``Transformer`` with the same call interface. swm's attention
  is causal, so the readout (CLS) token is appended *last*, where it attends to every patch, and is returned at
  index 0 where LeWM reads it. Frames are fixed-size, so there are no positions to interpolate.
* the training loop (le-wm trains through Lightning + stable-pretraining, neither a dependency here):
  :func:`train`, with LeWM's loss, AdamW, linear warmup + cosine decay and gradient clipping at 1.0.
* inputs. LeWM encodes pixels only. PokeWorld frames are (H, W) uint8 grayscale; they are scaled to [-1, 1],
  area-resized to ``image_size`` and fed as one channel (a 3-channel repeat would only sum the patch filters).
  ``inputs`` may add proprioception and/or touch: each goes through its own swm ``Embedder`` and is added to the
  CLS embedding before the projector (:class:`PokeLeWM` overrides ``encode`` for that and nothing else).
  Actions, proprio and touch are standardised with train-split statistics, as le-wm's column normalisers do.

The state handed to the protocol (:class:`LeWMStates`) is, by default, the predictor's state at each
observation: the transformer output at t given the last ``history_size`` embeddings and actions (the context
LeWM's own rollout uses), before ``pred_proj``. That is the analogue of X-JEPA's trunk state, which the paper
probes; the protocol zeroes the action after the probed observation, as it does for X-JEPA. ``readout =
"embedding"`` probes the projected CLS embedding of the single frame instead (no history, so it cannot hold
dynamics parameters except through one frame); ``"both"`` concatenates the two.
"""

from __future__ import annotations

import importlib
import json
import math
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from .. import checkpoint as CK, protocol as P
from ..config import to_dict
from ..data import Dataset, load
from ..errors import ConfigError, DataError
from ..evaluate.measure import padded_actions
from ..io import append_jsonl, read_json_if_present, read_jsonl, save_text, write_json
from ..windows import make_windows
from .compare import certify_run, comparison_markdown, summarize
from .lewm_config import INPUTS, NOT_TRAINING, PRESETS, READOUTS, LeWMConfig, make_config
from .require import stable_worldmodel

CKPT = "ckpt.pt"
PROTOCOL_DIR = "protocol"


# --------------------------------------------------------------------------- the model
class PatchViT(nn.Module):
    """A ViT encoder from swm's Transformer with the Hugging Face call LeWM.encode makes (see module docstring)."""

    def __init__(self, image_size: int, patch_size: int, dim: int, depth: int, heads: int, dim_head: int,
                 mlp_dim: int):
        super().__init__()
        wm = swm_module("wm.lewm.module")
        self.patch = nn.Conv2d(1, dim, patch_size, patch_size)
        self.pos = nn.Parameter(0.02 * torch.randn(1, (image_size // patch_size) ** 2, dim))
        self.cls = nn.Parameter(0.02 * torch.randn(1, 1, dim))
        self.transformer = wm.Transformer(dim, dim, dim, depth, heads, dim_head, mlp_dim, 0.0, block_class=wm.Block)

    def forward(self, pixels: torch.Tensor, interpolate_pos_encoding: bool = True) -> SimpleNamespace:
        x = self.patch(pixels).flatten(2).transpose(1, 2) + self.pos
        h = self.transformer(torch.cat([x, self.cls.expand(x.shape[0], -1, -1)], 1))
        # the causal attention lets only the last token see every patch; LeWM reads the CLS at index 0
        return SimpleNamespace(last_hidden_state=torch.cat([h[:, -1:], h[:, :-1]], 1))


def swm_module(name: str):
    """A stable-worldmodel submodule (``wm.lewm.module``, ``wm.lewm.lewm``, ``wm.loss``), via require's clear error."""
    stable_worldmodel()
    return importlib.import_module(f"stable_worldmodel.{name}")


def _lewm_base():
    return swm_module("wm.lewm.lewm").LeWM


class PokeLeWM(_lewm_base()):  # the base class comes through require, so a missing extra is one clear error
    """swm's LeWM with PokeWorld input preparation and optional proprio / touch added to the CLS embedding."""

    def __init__(self, cfg: LeWMConfig, dims: dict[str, int], stats: dict[str, np.ndarray]):
        wm = swm_module("wm.lewm.module")
        D = cfg.embed_dim
        extra = sum(dims[k] for k in cfg.inputs if k != "vision")
        super().__init__(
            encoder=PatchViT(cfg.image_size, cfg.patch_size, D, cfg.encoder_depth, cfg.encoder_heads, cfg.dim_head,
                             cfg.mlp_dim),
            predictor=wm.Predictor(num_frames=cfg.history_size, depth=cfg.predictor_depth, heads=cfg.predictor_heads,
                                   mlp_dim=cfg.mlp_dim, input_dim=D, hidden_dim=D, output_dim=D,
                                   dim_head=cfg.dim_head, dropout=cfg.dropout),
            action_encoder=wm.Embedder(input_dim=dims["actions"], emb_dim=D),
            projector=wm.MLP(D, cfg.projector_hidden, D, norm_fn=nn.BatchNorm1d),
            pred_proj=wm.MLP(D, cfg.projector_hidden, D, norm_fn=nn.BatchNorm1d))
        self.extra_encoder = wm.Embedder(input_dim=extra, emb_dim=D) if extra else None
        self.streams = tuple(k for k in cfg.inputs if k != "vision")
        self.image_size = cfg.image_size
        for name, value in stats.items():
            self.register_buffer(name, torch.as_tensor(value, dtype=torch.float32))

    def observe(self, frames, proprio, touch, actions) -> dict[str, torch.Tensor]:
        """Raw PokeWorld windows (B, T, ...) -> LeWM's info dict: pixels (B, T, 1, S, S), action, extra."""
        dev = self.actions_mean.device
        frames = torch.as_tensor(frames, device=dev)
        B, T, H, W = frames.shape
        x = frames.reshape(B * T, 1, H, W).float().div(127.5).sub(1.0)
        if (H, W) != (self.image_size, self.image_size):
            x = F.interpolate(x, size=(self.image_size, self.image_size), mode="area")
        info = {"pixels": x.reshape(B, T, 1, self.image_size, self.image_size),
                "action": self._standardise("actions", actions)}
        raw = {"proprio": proprio, "touch": touch}
        if self.streams:
            info["extra"] = torch.cat([self._standardise(k, raw[k]) for k in self.streams], -1)
        return info

    def _standardise(self, name: str, x) -> torch.Tensor:
        x = torch.as_tensor(x, device=self.actions_mean.device).float()
        return (x - getattr(self, f"{name}_mean")) / getattr(self, f"{name}_std")

    def encode(self, info: dict) -> dict:
        if self.extra_encoder is None:
            return super().encode(info)
        pixels = info["pixels"].float()
        B = pixels.size(0)
        cls = self.encoder(pixels.flatten(0, 1), interpolate_pos_encoding=True).last_hidden_state[:, 0]
        cls = cls + self.extra_encoder(info["extra"]).flatten(0, 1)
        info["emb"] = self.projector(cls).unflatten(0, (B, -1))
        if "action" in info:
            info["act_emb"] = self.action_encoder(info["action"])
        return info


def data_stats(ds: Dataset, inputs: tuple[str, ...]) -> dict[str, np.ndarray]:
    """Train-split mean / std of actions and the extra streams (le-wm standardises every non-pixel column)."""
    eps = ds.episodes("train")
    if eps.size == 0:
        raise DataError("the store has no train episodes (split == 0) to train LeWM on")
    out = {}
    for name in ("actions", *(k for k in inputs if k != "vision")):
        x = getattr(ds, name)[eps].reshape(-1, getattr(ds, name).shape[-1]).astype(np.float64)
        out[f"{name}_mean"] = x.mean(0).astype(np.float32)
        out[f"{name}_std"] = np.maximum(x.std(0), 1e-6).astype(np.float32)
    return out


def build_model(cfg: LeWMConfig, ds: Dataset) -> PokeLeWM:
    """LeWM for ``ds``'s streams, initialised from ``cfg.seed`` without touching the caller's RNG streams."""
    dims = {k: int(getattr(ds, k).shape[-1]) for k in ("proprio", "touch", "actions")}
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(cfg.seed)
        return PokeLeWM(cfg, dims, data_stats(ds, cfg.inputs))


class LeWMStates(nn.Module):
    """The protocol's state function: ``(frames, proprio, touch, actions) -> (B, L, D)`` LeWM states."""

    def __init__(self, model: PokeLeWM, readout: str = "predictor"):
        super().__init__()
        if readout not in READOUTS:
            raise ConfigError(f"readout must be one of {list(READOUTS)}, got {readout!r}")
        self.model, self.readout = model, readout

    def forward(self, frames, proprio, touch, actions) -> torch.Tensor:
        info = self.model.encode(self.model.observe(frames, proprio, touch, actions))
        emb, act = info["emb"], info["act_emb"]
        if self.readout == "embedding":
            return emb
        H = self.model.predictor.num_frames
        # the predictor state at t sees the last H embeddings and actions, as in LeWM's rollout
        states = torch.stack([self.model.predictor(emb[:, max(0, t - H + 1):t + 1], act[:, max(0, t - H + 1):t + 1])
                              [:, -1] for t in range(emb.shape[1])], 1)
        return states if self.readout == "predictor" else torch.cat([emb, states], -1)


# --------------------------------------------------------------------------- LeWM's objective
def lewm_loss(model: PokeLeWM, sigreg: nn.Module, info: dict, cfg: LeWMConfig) -> dict[str, torch.Tensor]:
    """le-wm's ``lejepa_forward``: prediction MSE on the shifted embeddings + λ · SIGReg of all embeddings."""
    out = model.encode(info)
    emb, act_emb = out["emb"], out["act_emb"]
    pred = model.predict(emb[:, :cfg.history_size], act_emb[:, :cfg.history_size])
    pred_loss = (pred - emb[:, cfg.num_preds:]).pow(2).mean()
    sigreg_loss = sigreg(emb.transpose(0, 1))
    return {"loss": pred_loss + cfg.sigreg_weight * sigreg_loss, "pred_loss": pred_loss, "sigreg_loss": sigreg_loss}


def learning_rate(cfg: LeWMConfig, step: int) -> float:
    """Linear warmup then cosine decay to zero (stable-pretraining's LinearWarmupCosineAnnealingLR shape)."""
    warm = max(1, int(cfg.warmup_frac * cfg.steps))
    if step < warm:
        return cfg.lr * (step + 1) / warm
    return 0.5 * cfg.lr * (1 + math.cos(math.pi * (step - warm) / max(1, cfg.steps - warm)))


# --------------------------------------------------------------------------- training
def training_config(cfg: LeWMConfig) -> dict:
    return {k: v for k, v in to_dict(cfg).items() if k not in NOT_TRAINING}


def _check_run_dir(cfg: LeWMConfig, out: Path) -> None:
    stored = out / "config.json"
    stored_cfg = read_json_if_present(stored, "a LeWM run's config.json")
    if stored_cfg is not None:
        prev = {k: v for k, v in stored_cfg.items() if k not in NOT_TRAINING}
        if prev != training_config(cfg):
            now = training_config(cfg)
            diff = sorted(k for k in set(prev) | set(now) if prev.get(k) != now.get(k))
            raise ConfigError(f"{out} holds a LeWM trained with another config (differs in {diff}); choose another "
                              "out or delete the directory")
    write_json(stored, to_dict(cfg))


def _resume(out: Path, model: nn.Module, opt: torch.optim.Optimizer, sampler: torch.Generator) -> int:
    path = out / CKPT
    if not path.exists():
        return 0
    ck = CK.load(path)
    model.load_state_dict(ck["model"])
    opt.load_state_dict(ck["optimizer"])
    sampler.set_state(ck["sampler"])
    CK.set_rng_state(ck["rng"])
    step = int(ck["step"])
    # rows logged after the checkpoint are replayed by the resumed run, so they are dropped
    rows = [r for r in read_jsonl(out / "metrics.jsonl") if r["step"] <= step]
    save_text(out / "metrics.jsonl", "".join(json.dumps(r, sort_keys=True) + "\n" for r in rows))
    print(f"[lewm] resuming {out} at step {step}")
    return step


def _save(out: Path, model, opt, sampler: torch.Generator, step: int, cfg: LeWMConfig) -> None:
    CK.save({"model": model.state_dict(), "optimizer": opt.state_dict(), "sampler": sampler.get_state(),
             "rng": CK.rng_state(), "step": step, "done": step >= cfg.steps, "config": to_dict(cfg)}, out / CKPT)


def is_trained(out: str | Path, cfg: LeWMConfig) -> bool:
    """True when ``out`` holds a finished LeWM trained with ``cfg``'s training fields."""
    path = Path(out) / CKPT
    if not path.exists():
        return False
    ck = CK.load(path)
    stored = {k: v for k, v in ck.get("config", {}).items() if k not in NOT_TRAINING}
    return bool(ck.get("done")) and stored == training_config(cfg)


def _batch(ds: Dataset, acts: np.ndarray, w, idx: np.ndarray) -> tuple:
    sel = w.select(idx)
    return sel.gather(ds.frames), sel.gather(ds.proprio), sel.gather(ds.touch), sel.gather(acts)


def train(cfg: LeWMConfig, ds: Dataset | None = None) -> Path:
    """Train LeWM with its own objective on the store's train split; resume from ckpt.pt, skip when finished."""
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    _check_run_dir(cfg, out)
    if is_trained(out, cfg):
        print(f"[lewm] {out} is trained ({cfg.steps} steps); reusing it")
        return out
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    ds = ds if ds is not None else load(cfg.data)
    length = cfg.history_size + cfg.num_preds
    windows = make_windows(ds, ds.episodes("train"), length=length, stride=1)
    acts = padded_actions(ds)
    model = build_model(cfg, ds).train()
    sigreg = swm_module("wm.loss").SIGReg(knots=cfg.sigreg_knots, num_proj=cfg.sigreg_proj)
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    sampler = torch.Generator().manual_seed(cfg.seed)
    torch.manual_seed(cfg.seed)  # dropout and SIGReg's projections draw from the global stream
    step = _resume(out, model, opt, sampler)
    t0, sums = time.time(), {}
    while step < cfg.steps:
        idx = torch.randint(len(windows), (cfg.batch_size,), generator=sampler).numpy()
        info = model.observe(*_batch(ds, acts, windows, idx))
        for g in opt.param_groups:
            g["lr"] = learning_rate(cfg, step)
        losses = lewm_loss(model, sigreg, info, cfg)
        if not torch.isfinite(losses["loss"]):
            values = {k: round(float(v), 4) for k, v in losses.items()}
            raise DataError(f"LeWM's loss became non-finite at step {step} ({values}); lower lr")
        opt.zero_grad(set_to_none=True)
        losses["loss"].backward()
        grad = nn.utils.clip_grad_norm_(model.parameters(), cfg.grad_clip)
        opt.step()
        step += 1
        for k, v in {**losses, "grad_norm": grad}.items():
            sums[k] = sums.get(k, 0.0) + float(v.detach())
        if step % cfg.log_every == 0 or step == cfg.steps:
            n = step % cfg.log_every or cfg.log_every
            append_jsonl(out / "metrics.jsonl", {"step": step, "lr": learning_rate(cfg, step - 1),
                                                 "seconds": round(time.time() - t0, 2),
                                                 **{k: v / n for k, v in sums.items()}})
            sums = {}
        if step % cfg.ckpt_every == 0 or step == cfg.steps:
            _save(out, model, opt, sampler, step, cfg)
    print(f"[lewm] trained {out} ({cfg.steps} steps, {time.time() - t0:.0f}s this session)")
    return out


def load_trained(out: str | Path, cfg: LeWMConfig, ds: Dataset) -> PokeLeWM:
    """The finished LeWM in ``out`` (weights-only load), in eval mode."""
    if not is_trained(out, cfg):
        raise DataError(f"{out} holds no finished LeWM trained with this config; run train(cfg) first")
    model = build_model(cfg, ds)
    model.load_state_dict(CK.load(Path(out) / CKPT)["model"])
    return model.eval()


# --------------------------------------------------------------------------- certification
def protocol_config(cfg: LeWMConfig) -> P.ProtocolConfig:
    return P.make_config(cfg.protocol_preset, **cfg.protocol_overrides)


def run(cfg: LeWMConfig) -> dict:
    """Train (or reuse) LeWM on ``cfg.data``, then certify it beside its untrained twin; returns the summary."""
    ds = load(cfg.data)
    out = train(cfg, ds)
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    model = LeWMStates(load_trained(out, cfg, ds), cfg.readout)
    twin = LeWMStates(build_model(cfg, ds).eval(), cfg.readout)  # same seed, same data statistics, no training
    report = P.certify_model(model, cfg.data, out / PROTOCOL_DIR, untrained=twin, name=f"LeWM ({cfg.readout})",
                             config=protocol_config(cfg))
    summary = {"config": to_dict(cfg), "training": read_jsonl(out / "metrics.jsonl")[-1:], **summarize(report)}
    write_json(out / "summary.json", summary)
    if cfg.compare_runs:
        write_comparison(cfg, out, summary)
    return summary


def write_comparison(cfg: LeWMConfig, out: Path, lewm_summary: dict) -> Path:
    """Certify ``cfg.compare_runs`` like the LeWM and write the side-by-side tables (comparison.md / .json)."""
    summaries = {f"LeWM ({cfg.readout})": lewm_summary}
    for run_dir in cfg.compare_runs:
        name = Path(run_dir).name
        summaries[f"X-JEPA {name}"] = certify_run(run_dir, cfg.data, out / "compare" / name, protocol_config(cfg))
    write_json(out / "comparison.json", {"data": cfg.data, "protocol": to_dict(protocol_config(cfg)),
                                         "models": summaries})
    lines = ["# LeWM beside X-JEPA: the certificate-gated protocol on one store", "",
             f"Store `{cfg.data}`; every model read by the same probes (ProtocolConfig preset "
             f"`{cfg.protocol_preset}`); cells are held-out R² ridge / MLP / untrained-bound ridge.", ""]
    for kind in ("contact", "all"):
        lines += [*comparison_markdown(summaries, kind), ""]
    save_text(out / "comparison.md", "\n".join(lines))
    print("\n".join(lines))
    return out / "comparison.md"


__all__ = [
    "INPUTS",
    "PRESETS",
    "READOUTS",
    "LeWMConfig",
    "LeWMStates",
    "PatchViT",
    "PokeLeWM",
    "build_model",
    "data_stats",
    "is_trained",
    "learning_rate",
    "lewm_loss",
    "load_trained",
    "make_config",
    "protocol_config",
    "run",
    "train",
    "write_comparison",
]
