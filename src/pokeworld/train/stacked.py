"""Several X-JEPA runs trained in one process as a stacked ensemble (``torch.func`` + ``torch.vmap``).

One small model leaves a GPU mostly idle (``paper`` preset: 2.4 % of the H100's bf16 peak), so runs
that can share every kernel launch are trained together: their parameters are stacked along a new
leading member axis (``torch.func.stack_module_state``) and one ``functional_call`` of the model's
loss runs under ``torch.vmap`` over that axis. A GPU lever: on a CPU the step is compute-bound and
stacking measured slower than separate models (docs/model.md). Every member keeps what its separate run
(:func:`pokeworld.train.run`) would have had:

* its own initialisation (the same ``torch.manual_seed(seed)`` before construction), its own window
  stream (a generator seeded as the separate run's sampler, drawn in the same order; one copy of the
  data serves all members: a step gathers an (M, B) index block at once), its own SIGReg directions
  and, with ``sigreg_pool='pooled'``, its own row subset (both drawn on the host from its seed and the
  step, as ``train.train_step`` draws them, and passed in per member), its own BatchNorm running
  statistics (stacked buffers, updated in place by vmap's batch-norm rule), its own loss weights (λ,
  proprio/touch/sysid weights, the touch contact weight, passed as per-member tensors);
* one AdamW over the stacked parameters (elementwise, so the same update as M optimisers) with
  gradient-norm clipping per member (the norm of each member's gradient, not of the stack's);
* a run directory with the files ``train.run`` writes (``config.json`` = that member's
  :class:`~pokeworld.train.TrainConfig`, ``metrics.jsonl``, ``tb/``, ``ckpt.pt`` in ``train.run``'s
  format — model, optimizer and sampler state in the member's own layout — and ``final.pt`` + ``DONE``),
  so ``pokeworld probe``/``measure`` read it unchanged and ``train.run`` could even resume it alone.

What differs: dropout masks come from one shared generator (``randomness="different"``: independent
masks per member, not the separate run's masks), so with dropout > 0 a member matches its separate
run statistically, not bit-for-bit. With dropout 0 they agree to float rounding
(tests/test_train_stacked.py).

Grouping (:func:`plan_groups`): runs stack when everything that fixes parameter shapes and the step's
graph is equal, i.e. every :class:`TrainConfig` field except :data:`PER_MEMBER_FIELDS`. With
``mix_variants`` the six variants of the factorial also stack: a member whose variant lacks an input
or a target is embedded, exactly, into the smallest variant that contains all of the group's
(:func:`superset_variant`; VFX for the full factorial): missing input MLPs and the projection columns
that read them are zero (a fixed point of the loss and of AdamW: their output and their gradient stay
exactly zero), missing forecasting heads are zero and weighted 0 in the loss. Only the member's own
parameters are saved.

Compilation follows the runs' ``compile`` setting (:func:`~pokeworld.train.config.compile_mode_for`; 'auto': CUDA
graphs on a CUDA device, eager on a CPU): the vmapped loss is compiled as one graph (dynamo traces
``torch.vmap`` with per-member dropout and the math attention kernel without a graph break); the optimizer and
the per-member clipping stay eager.

Not supported (ConfigError): ``ddp``, ``tokens`` (the token SIGReg subsamples rows from a per-run
integer seed, which vmap cannot batch) and ``channels_last``.
"""

from __future__ import annotations

import contextlib
import json
import random
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch
from torch.nn.attention import SDPBackend, sdpa_kernel

from .. import checkpoint, data as data_mod
from ..config import SEED, Limit, check_fields, from_preset, to_dict
from ..errors import ConfigError
from ..io import run_lock
from ..models.xjepa import VARIANTS, XJEPA, check_variant as validate_variant
from ..run_store import write_run_config
from ..rundir import (
    MetricsLog,
    check_run_dir_writable,
    check_run_files,
    check_state_fits,
    load_resume_checkpoint,
    restart_metrics,
    restoring,
    write_final,
)
from .config import (
    PRESETS as TRAIN_PRESETS,
    TrainConfig,
    auto_threads,
    check_existing,
    compile_mode_for,
    compile_status,
    make_config as make_train_config,
    resolve_device,
    use_fast_path,
    validate,
)
from .loop import LoopSchedule, Progress, past, run_loop
from .optimizer_state import check_optimizer_fits
from .sampler import WindowSampler, data_stats
from .step import (
    decay_split,
    loss_kwargs,
    lr_lambda,
    make_optimizer,
    model_kwargs,
    sigreg_directions,
    sigreg_row_index,
    to_device,
)

#: TrainConfig fields that may differ between members of one stacked group (everything else is shared).
PER_MEMBER_FIELDS = ("seed", "out", "sigreg_weight", "touch_contact_weight", "proprio_weight", "touch_weight",
                     "sysid_weight", "tensorboard")
#: XJEPA.loss keyword arguments that may be per-member tensors under vmap (used only in arithmetic).
TENSOR_LOSS_KWARGS = ("sigreg_weight", "touch_contact_weight", "proprio_weight", "touch_weight", "sysid_weight")


@dataclass
class StackedConfig:
    """Train a grid of X-JEPA runs (variants × seeds × λ) stacked in one process (``pokeworld train-stacked``).

    Each run is the :class:`pokeworld.train.TrainConfig` of the preset with its variant, seed and λ;
    runs that can share a step (see ``mix_variants``) train as one stacked ensemble.
    """

    data: str = "data/pokeworld"
    """Dataset directory (``pokeworld.data`` format), shared by all runs."""
    out: str = "runs/stacked"
    """Parent directory; each run trains into ``out/<variant>_s<seed>`` (``_lam<λ>`` appended when sweeping λ)."""
    variants: tuple[str, ...] = ("VFX",)
    """Variants to train (V, VF, VX_p, VX_t, VX, VFX)."""
    seeds: tuple[int, ...] = (0,)
    """Seeds per variant."""
    sigreg_weights: tuple[float, ...] = ()
    """SIGReg weights λ to sweep; empty = the preset's λ only."""
    mix_variants: bool = True
    """Stack variants with different inputs/targets in one group (zero-embedded into the smallest variant
    containing them all; exact); off = one group per variant."""
    max_members: int = 0
    """Most members per stacked group (0 = no limit); larger groups are split in order."""
    preset: str = "cpu"
    """TrainConfig preset of every run (set by ``--preset``)."""
    steps: int = 0
    """Optimisation steps per run (0 = the preset's)."""
    device: str = "auto"
    """'auto', 'cpu', 'cuda' or 'cuda:N'."""
    threads: int = 0
    """CPU threads (0 = ``train.auto_threads()``)."""
    fast: str = "auto"
    """TrainConfig ``fast`` (non-blocking uploads, fused AdamW; 'auto' = on for CUDA)."""
    progress: bool = True
    """Show a progress bar per group."""

    LIMITS = {"seeds": SEED, "sigreg_weights": Limit(0, 1e6), "max_members": Limit(0, 10**4),
              "steps": Limit(0, 10**9), "threads": Limit(0, 4096)}

    def __post_init__(self) -> None:
        check_fields(self)


#: Each TrainConfig preset by name (``tiny`` also silences the progress bar, as its TrainConfig preset does).
PRESETS: dict[str, dict[str, Any]] = {name: {"preset": name, **({"progress": False} if name == "tiny" else {})}
                                      for name in TRAIN_PRESETS}


def make_config(preset: str = "cpu", **overrides: Any) -> StackedConfig:
    """``StackedConfig`` for a TrainConfig preset plus field overrides."""
    if preset not in TRAIN_PRESETS:
        raise ConfigError(f"unknown preset {preset!r}; choose one of {sorted(TRAIN_PRESETS)}")
    return from_preset(StackedConfig, PRESETS, preset, **overrides)


def train_configs(scfg: StackedConfig) -> list[TrainConfig]:
    """The grid's TrainConfigs (variant-major, then λ, then seed)."""
    if not scfg.variants or not scfg.seeds:
        raise ConfigError("variants and seeds must each list at least one value")
    lams = tuple(scfg.sigreg_weights) or (None,)
    cfgs = []
    for v in scfg.variants:
        for lam in lams:
            for s in scfg.seeds:
                name = f"{v}_s{s}" + ("" if lam is None else f"_lam{lam:g}")
                kw: dict[str, Any] = dict(variant=v, seed=s, data=scfg.data, out=str(Path(scfg.out) / name),
                                          device=scfg.device, threads=scfg.threads, fast=scfg.fast,
                                          progress=scfg.progress)
                if lam is not None:
                    kw["sigreg_weight"] = lam
                if scfg.steps:
                    kw["steps"] = scfg.steps
                cfgs.append(make_train_config(scfg.preset, **kw))
    return cfgs


def run_config(scfg: StackedConfig) -> list[Path]:
    """CLI entry: train the grid of ``scfg``; returns the run directories."""
    return run(train_configs(scfg), mix_variants=scfg.mix_variants, max_members=scfg.max_members)


# ---------------------------------------------------------------------- grouping and embedding


def superset_variant(variants: Sequence[str]) -> str:
    """The variant with the fewest inputs+targets that contains every input and target of ``variants``."""
    for v in variants:
        validate_variant(v)
    ins = set().union(*(VARIANTS[v][0] for v in variants))
    outs = set().union(*(VARIANTS[v][1] for v in variants))
    fits = [v for v, (i, o) in VARIANTS.items() if ins <= set(i) and outs <= set(o)]
    return min(fits, key=lambda v: len(VARIANTS[v][0]) + len(VARIANTS[v][1]))


#: TrainConfig flags no stacked group supports, and why.
UNSTACKABLE = (("ddp", "train multi-GPU runs with `pokeworld train --ddp`"),
               ("tokens", "the token SIGReg draws its row subset from a per-run integer seed"),
               ("channels_last", "stacked conv weights have no channels-last layout"))


def stackable(cfg: TrainConfig) -> bool:
    """Whether ``cfg`` can train as a member of a stacked group (else it trains alone with ``train.run``)."""
    return not any(getattr(cfg, name) for name, _ in UNSTACKABLE)


def _check_stackable(cfg: TrainConfig) -> None:
    for name, why in UNSTACKABLE:
        if getattr(cfg, name):
            raise ConfigError(f"stacked training does not support {name}=True ({why}); {cfg.out}")


def group_key(cfg: TrainConfig, mix_variants: bool) -> str:
    """Runs with equal keys can be stacked: all fields but :data:`PER_MEMBER_FIELDS` (and the variant
    when mixing), plus whether the sysid head exists (its weight's sign fixes the parameter set)."""
    d = to_dict(cfg)
    for k in PER_MEMBER_FIELDS + (("variant",) if mix_variants else ()):
        d.pop(k, None)
    d["_sysid_head"] = cfg.sysid_weight > 0
    return json.dumps(d, sort_keys=True)


def plan_groups(cfgs: Sequence[TrainConfig], mix_variants: bool = True, max_members: int = 0) -> list[list[int]]:
    """Indices of ``cfgs`` per stacked group, in first-appearance order; each group ≤ ``max_members``."""
    outs = [str(Path(c.out).resolve()) for c in cfgs]
    if len(set(outs)) != len(outs):
        raise ConfigError("two runs share an output directory; give each its own `out`")
    groups: dict[str, list[int]] = {}
    for i, c in enumerate(cfgs):
        validate(c)
        _check_stackable(c)
        groups.setdefault(group_key(c, mix_variants), []).append(i)
    out = []
    for g in groups.values():
        n = max_members if max_members > 0 else len(g)
        out += [g[i:i + n] for i in range(0, len(g), n)]
    return out


def embed_state(member: dict[str, torch.Tensor], template: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """A member's state in the superset model's layout: equal-shaped entries copied, an entry the superset
    widens (the encoder projection that also reads the fused proprio/touch features) copied into its
    leading slice, everything the member lacks zero."""
    out = {}
    for k, t in template.items():
        z = torch.zeros_like(t)
        if k in member:
            m = member[k]
            if m.dim() != t.dim() or any(a > b for a, b in zip(m.shape, t.shape)):
                raise ConfigError(f"cannot embed {k} of shape {tuple(m.shape)} into {tuple(t.shape)}")
            z[tuple(slice(0, n) for n in m.shape)] = m
        out[k] = z
    return out


def _leading(t: torch.Tensor, shape: torch.Size) -> torch.Tensor:
    return t[tuple(slice(0, n) for n in shape)]


# ---------------------------------------------------------------------- the stacked group


class StackedGroup:
    """M runs of one group: the superset model, the stacked state, the optimizer and the samplers."""

    def __init__(self, cfgs: list[TrainConfig], dev: torch.device, fast: bool, ds=None):
        from torch.func import stack_module_state

        self.cfgs, self.dev, self.fast, self.M = cfgs, dev, fast, len(cfgs)
        c0 = cfgs[0]
        ds = data_mod.load(c0.data) if ds is None else ds
        train_ep = ds.episodes("train")
        dims = (ds.proprio.shape[-1], ds.touch.shape[-1], ds.actions.shape[-1])
        # one copy of the data; member i draws from a generator seeded like its separate run's sampler
        self.sampler = WindowSampler(ds, train_ep, c0.image_size, c0.window, dev, c0.contact_channel,
                                       seed=c0.seed * 1000 + 1, with_params=c0.sysid_weight > 0, non_blocking=fast,
                                       aligned_share=c0.program_aligned_share, horizon=max(c0.horizons))
        self.gens = []
        for c in cfgs:
            g = torch.Generator(device="cpu")
            g.manual_seed(c.seed * 1000 + 1)
            self.gens.append(g)
        stats = data_stats(ds, train_ep)
        del ds

        self.mks = [model_kwargs(c, dims) for c in cfgs]
        self.super_variant = superset_variant([c.variant for c in cfgs])
        self.members: list[XJEPA] = []
        for c, mk in zip(cfgs, self.mks):
            torch.manual_seed(c.seed)  # as train.run, so the initialisation equals the separate run's
            random.seed(c.seed)
            np.random.seed(c.seed)
            m = XJEPA(**mk)
            m.set_stats(stats)
            self.members.append(m)
        base = XJEPA(**{**self.mks[0], "variant": self.super_variant})
        self.template = {k: v.detach().clone() for k, v in base.state_dict().items()}  # shapes/dtypes (CPU)
        template = self.template
        self.param_names = [n for n, _ in base.named_parameters()]
        embedded = []
        for m in self.members:
            st = embed_state(m.state_dict(), template)
            e = XJEPA(**{**self.mks[0], "variant": self.super_variant})
            e.load_state_dict(st)
            embedded.append(e)
        params, buffers = stack_module_state(embedded)
        self.params = {k: v.detach().to(dev).requires_grad_(True) for k, v in params.items()}
        self.buffers = {k: v.to(dev) for k, v in buffers.items()}
        del embedded
        self.base = base.to("meta").train()  # structure only; the stacked tensors are passed in

        # decay / no-decay split as train.make_optimizer, judged on the per-member parameter
        decay, no_decay = decay_split((n, self.params[n].dim() - 1) for n in self.param_names)
        self.opt = torch.optim.AdamW([{"params": [self.params[n] for n in decay], "weight_decay": c0.weight_decay},
                                      {"params": [self.params[n] for n in no_decay], "weight_decay": 0.0}],
                                     lr=c0.lr, betas=(0.9, 0.999), fused=True if fast else None)
        self.opt_names = decay + no_decay
        self.sched = torch.optim.lr_scheduler.LambdaLR(self.opt, lambda s: lr_lambda(s, c0.warmup, c0.steps))

        # loss kwargs: shared Python values, or per-member tensors where members differ
        kws = [loss_kwargs(c) for c in cfgs]
        self.shared_kw: dict[str, Any] = {}
        self.member_kw: dict[str, torch.Tensor] = {}
        targets = [VARIANTS[c.variant][1] for c in cfgs]
        for k in kws[0]:
            vals = [kw[k] for kw in kws]
            if k in ("proprio_weight", "touch_weight"):  # a target the member lacks weighs 0 in the superset
                m = k.split("_")[0]
                vals = [v if m in tg else 0.0 for v, tg in zip(vals, targets)]
            if k in TENSOR_LOSS_KWARGS and len(set(vals)) > 1:
                self.member_kw[k] = torch.tensor(vals, dtype=torch.float32, device=dev)
            elif len(set(vals)) == 1:
                self.shared_kw[k] = vals[0]
            else:  # unreachable when grouped by group_key
                raise ConfigError(f"loss argument {k} differs within a stacked group: {vals}")
        self.own_terms = [set(VARIANTS[c.variant][1]) for c in cfgs]

        def member_loss(p, b, batch, dirs, mkw):
            from torch.func import functional_call

            # the math attention kernel: CUDA's fused kernels batch under vmap in the forward, but the
            # memory-efficient backward rejects the batched logsumexp's strides ("LSE is not correctly aligned
            # (strideH)", seen on an H100 with torch 2.11); the CPU flash kernel has no batching rule at all
            with sdpa_kernel(SDPBackend.MATH):
                return functional_call(self.base, (p, b), (batch,),
                                       dict(sigreg_directions=dirs, **mkw, **self.shared_kw))

        self.vloss = torch.vmap(member_loss, randomness="different")
        mode = self.mode = compile_mode_for(c0, dev)  # compile is a group-key field: one setting for the whole group
        if mode:
            # the stacked state is updated in place and never moves: marked static, CUDA graphs read it where it
            # lives (a plain tensor argument would be copied in before every replay, and its in-place BatchNorm
            # update would keep the graph from being recorded at all)
            for t in (*self.params.values(), *self.buffers.values()):
                torch._dynamo.mark_static_address(t)
            self.vloss = torch.compile(self.vloss, mode=mode)
        self.use_amp = c0.amp and dev.type == "cuda" and torch.cuda.is_bf16_supported()

    def step(self, step: int) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """One optimisation step of every member; returns the (M,) losses and (M,) terms (on the device)."""
        c0 = self.cfgs[0]
        batch = self.sample(c0.batch_size)
        dirs = self.directions(step)
        with torch.autocast(self.dev.type, dtype=torch.bfloat16, enabled=self.use_amp):
            loss, terms = self.vloss(self.params, self.buffers, batch, dirs, self.step_kw(step))
        self.opt.zero_grad(set_to_none=True)
        loss.sum().backward()  # members share no parameters: each gets its own loss's gradient
        if c0.grad_clip > 0:
            terms["grad_norm"] = self.clip_(c0.grad_clip).detach()
        self.opt.step()
        self.sched.step()
        terms["loss"] = loss.detach()
        return loss.detach(), terms

    # ------------------------------------------------------------------ per step
    def sample(self, batch_size: int) -> dict[str, torch.Tensor]:
        """(M, B, ...) windows; member i's draws equal ``WindowSampler.sample`` with its own generator."""
        draws = [self.sampler.draw(batch_size, g) for g in self.gens]
        e = to_device(torch.stack([d[0] for d in draws]), self.dev, self.fast)
        st = to_device(torch.stack([d[1] for d in draws]), self.dev, self.fast)
        return self.sampler.gather(e, st)

    def directions(self, step: int) -> torch.Tensor:
        dirs = torch.stack([sigreg_directions(c, step, torch.device("cpu")) for c in self.cfgs])
        return to_device(dirs, self.dev, self.fast)

    def step_kw(self, step: int) -> dict[str, torch.Tensor]:
        """The per-member loss tensors of ``step``: the fixed ones, plus (M, sigreg_rows) pooled-SIGReg row
        subsets when the group subsamples. Inside vmap the loss sees no per-member integer seed, so a subset
        drawn there from ``sigreg_seed`` would be one subset for every member and step; drawn here, member i's
        is the one its separate run draws."""
        rows = [sigreg_row_index(c, step, torch.device("cpu")) for c in self.cfgs]
        if rows[0] is None:  # same pool, rows, batch and window across the group: all None or none
            return self.member_kw
        return {**self.member_kw, "sigreg_row_index": to_device(torch.stack(rows), self.dev, self.fast)}

    def clip_(self, max_norm: float) -> torch.Tensor:
        """Per-member gradient-norm clipping as ``clip_grad_norm_`` on each member; returns the (M,) norms."""
        grads = [p.grad for p in self.params.values() if p.grad is not None]
        norms = torch.stack([g.reshape(g.shape[0], -1).norm(dim=1) for g in grads])  # (P, M)
        total = norms.norm(dim=0)
        coef = (max_norm / (total + 1e-6)).clamp(max=1.0)
        for g in grads:
            g.mul_(coef.view(-1, *([1] * (g.dim() - 1))).to(g.dtype))
        return total

    # ------------------------------------------------------------------ member views
    def member_state(self, i: int) -> dict[str, torch.Tensor]:
        """Member i's model state_dict in its own variant's layout (on the CPU)."""
        own = self.members[i].state_dict()
        full = {**self.params, **self.buffers}
        return {k: _leading(full[k][i].detach(), v.shape).cpu().clone() for k, v in own.items()}

    def _member_opt_names(self, i: int) -> list[str]:
        """Member i's parameter names in ``train.make_optimizer``'s index order (decay group first)."""
        decay, no_decay = decay_split((n, p.ndim) for n, p in self.members[i].named_parameters())
        return decay + no_decay

    def member_optimizer_state(self, i: int) -> dict[str, Any]:
        """Member i's AdamW state_dict as ``train.make_optimizer(member)`` would hold it."""
        ref = make_optimizer(self.members[i], self.cfgs[i]).state_dict()
        shapes = {n: p.shape for n, p in self.members[i].named_parameters()}
        state = {}
        for idx, n in enumerate(self._member_opt_names(i)):
            st = self.opt.state.get(self.params[n])
            if st:
                state[idx] = {k: v.detach().cpu().clone() if k == "step" else
                              _leading(v[i].detach(), shapes[n]).cpu().clone() for k, v in st.items()}
        groups = [dict(sg, params=rg["params"])
                  for rg, sg in zip(ref["param_groups"], self.opt.state_dict()["param_groups"])]
        return {"state": state, "param_groups": groups}

    def load(self, cks: list[dict[str, Any]]) -> None:
        """Restore every member from its ``train.run``-format checkpoint (model, optimizer, sampler)."""
        with torch.no_grad():
            states = [embed_state(ck["model"], self.template) for ck in cks]
            for k, t in {**self.params, **self.buffers}.items():
                t.copy_(torch.stack([st[k] for st in states]).to(t.device))
        # optimizer: each member's moments embedded into the superset layout and stacked
        per_member = []
        for i, ck in enumerate(cks):
            src = ck["optimizer"]["state"]
            per_member.append({n: src[idx] for idx, n in enumerate(self._member_opt_names(i)) if idx in src})
        state = {}
        for j, n in enumerate(self.opt_names):
            have = [pm[n] for pm in per_member if n in pm]
            if not have:
                continue
            entry = {"step": have[0]["step"]}
            for k in have[0]:
                if k != "step":
                    tmpl = {n: self.template[n]}
                    entry[k] = torch.stack([embed_state({n: pm[n][k]} if n in pm else {}, tmpl)[n]
                                            for pm in per_member])
            state[j] = entry
        groups = [dict(mg, params=sg["params"])
                  for mg, sg in zip(cks[0]["optimizer"]["param_groups"], self.opt.state_dict()["param_groups"])]
        self.opt.load_state_dict({"state": state, "param_groups": groups})
        self.sched.load_state_dict(cks[0]["scheduler"])
        for gen, ck in zip(self.gens, cks):
            gen.set_state(ck["sampler"])


# ---------------------------------------------------------------------- training


def _ckpt_step(cfg: TrainConfig) -> int:
    p = Path(cfg.out) / "ckpt.pt"
    if not p.exists():
        return 0
    return load_resume_checkpoint(p)["step"]


def run(cfgs: Sequence[TrainConfig], *, mix_variants: bool = True, max_members: int = 0) -> list[Path]:
    """Train (or resume, or skip if finished) every run of ``cfgs``, stacking those that can share a step
    (:func:`plan_groups`); returns the run directories in the order of ``cfgs``."""
    cfgs = list(cfgs)
    plan_groups(cfgs, mix_variants, max_members)  # validates all runs (stackable, distinct outs) up front
    for c in cfgs:
        check_run_files(c.out)  # as train.run: no links, FIFOs, or a file where a run folder goes
        check_existing(c)
    todo = [i for i, c in enumerate(cfgs) if not (Path(c.out) / "DONE").exists()]
    if todo:  # as train.run: inputs checked before any run folder or config.json is written
        data_mod.read_manifest(cfgs[todo[0]].data)
        for i in todo:
            check_run_dir_writable(cfgs[i].out)
    # members resume together only from the same step: the checkpoint step joins the group key
    by_step: dict[int, list[int]] = {}
    for i in todo:
        by_step.setdefault(_ckpt_step(cfgs[i]), []).append(i)
    for idx in by_step.values():
        for g in plan_groups([cfgs[i] for i in idx], mix_variants, max_members):
            _run_group([cfgs[idx[j]] for j in g])
    return [Path(c.out) for c in cfgs]


def _run_group(cfgs: list[TrainConfig]) -> None:
    c0 = cfgs[0]
    if past(c0.deadline):
        return
    with contextlib.ExitStack() as locks:  # every member's run directory, as train.run locks its own
        for c in cfgs:
            locks.enter_context(run_lock(c.out))
        _train_group(cfgs)


class _StackedRun:
    """A stacked group and its members' run directories: the :class:`~.loop.Trainee` of a stacked run."""

    def __init__(self, cfgs: list[TrainConfig], g: StackedGroup, outs: list[Path]):
        self.cfgs, self.g, self.outs = cfgs, g, outs
        self.logs: list[MetricsLog] = []

    def resume_or_start(self) -> int:
        g, outs, c0 = self.g, self.outs, self.cfgs[0]
        if (outs[0] / "ckpt.pt").exists():
            cks = [load_resume_checkpoint(out / "ckpt.pt") for out in outs]
            for member, ck, out in zip(g.members, cks, outs):
                check_state_fits(member, ck["model"], out / "ckpt.pt")
                check_optimizer_fits(member, ck["optimizer"], out / "ckpt.pt")
            with restoring(outs[0] / "ckpt.pt"):
                g.load(cks)
                checkpoint.set_rng_state(cks[0]["rng"])
            step = int(cks[0]["step"])
            for out in outs:
                restart_metrics(out, step)
            return step
        # dropout masks: one generator for the group (vmap draws independent masks per member)
        torch.manual_seed(c0.seed)
        start_row = {"step": 0, **g.sampler.glide_share(tuple(c0.horizons), c0.glide_loss_weight)}
        for out in outs:
            restart_metrics(out, 0, start_row)
        return 0

    # ------------------------------------------------------------------ Trainee
    def step(self, step: int) -> dict[str, torch.Tensor]:
        return self.g.step(step)[1]

    def lr(self) -> float:
        return self.g.sched.get_last_lr()[0]

    def out_of_time(self, step: int) -> bool:
        return past(self.cfgs[0].deadline)

    def write_rows(self, row: dict[str, float], sums: dict[str, torch.Tensor], n: int) -> float:
        vals = {k: (v / n).cpu() for k, v in sums.items()}
        for i, log in enumerate(self.logs):
            member = dict(row, stacked_members=self.g.M, **compile_status(self.g.mode))
            member.update({k: float(v[i]) for k, v in vals.items()
                           if k not in ("proprio", "touch") or k in self.g.own_terms[i]})
            log.write(member)
        return float(vals["loss"].mean())

    def save_checkpoint(self, step: int) -> None:
        g, rng = self.g, checkpoint.rng_state()
        for i, (c, out) in enumerate(zip(self.cfgs, self.outs)):
            checkpoint.save({"model": g.member_state(i), "optimizer": g.member_optimizer_state(i),
                             "scheduler": g.sched.state_dict(), "rng": rng, "sampler": g.gens[i].get_state(),
                             "step": step, "model_kwargs": g.mks[i], "config": to_dict(c)}, out / "ckpt.pt")


def _train_group(cfgs: list[TrainConfig]) -> None:
    """The body of :func:`_run_group`, under the members' run-directory locks."""
    c0 = cfgs[0]
    dev = resolve_device(c0)
    if dev.type == "cpu":
        torch.set_num_threads(c0.threads or auto_threads())
    fast = use_fast_path(c0, dev)
    outs = [Path(c.out) for c in cfgs]
    g = StackedGroup(cfgs, dev, fast)  # loads the data: a corpus that fails to load leaves no config.json
    for c, out in zip(cfgs, outs):
        out.mkdir(parents=True, exist_ok=True)
        write_run_config(out, to_dict(c))  # as train.run: the store's path and content hash beside the config
    t = _StackedRun(cfgs, g, outs)
    step = t.resume_or_start()
    t.logs = [MetricsLog(out, c.tensorboard, step) for c, out in zip(cfgs, outs)]
    end = min(c0.steps, c0.stop_at) if c0.stop_at > 0 else c0.steps
    sched = LoopSchedule(step, end, c0.steps, c0.log_every, c0.ckpt_every, c0.batch_size * c0.window)
    progress = Progress(sched, f"train stacked ×{g.M} ({g.super_variant})", bar=c0.progress)
    try:
        step = run_loop(t, sched, dev, progress, loss_shape=(g.M,), members=[str(o) for o in outs],
                        checkpoints=f"the ckpt.pt of its {g.M} runs")
    finally:
        progress.close()
        for log in t.logs:
            log.close()
    if step >= c0.steps:
        for i, (c, out) in enumerate(zip(cfgs, outs)):
            write_final(out, g.member_state(i), g.mks[i], to_dict(c), step, note=f" (stacked ×{g.M})")


__all__ = ["StackedConfig", "make_config", "train_configs", "run_config", "run", "plan_groups", "group_key",
           "superset_variant", "embed_state", "stackable", "StackedGroup", "PER_MEMBER_FIELDS", "UNSTACKABLE"]
