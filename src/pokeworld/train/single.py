"""Training one X-JEPA model into a run directory (``pokeworld train``), optionally data-parallel over GPUs (DDP).

``run(cfg)`` trains (or resumes, or returns at once when finished) and returns the run directory, in the
format :mod:`pokeworld.rundir` owns. An interrupted run resumes from ``ckpt.pt`` and reproduces the
uninterrupted run bit for bit on CPU; SIGINT (Ctrl-C) or SIGTERM (``kill``, SLURM) checkpoints at the step it
arrives in before training stops (:class:`~.loop.StopSignals`), so nothing since the last periodic checkpoint is
lost. The whole training split lives in memory as tensors (on the GPU when there is one), so window sampling never
bottlenecks a step.

Fast path (``fast``; on by default on CUDA): the step's window indices and SIGReg directions are drawn on the
host exactly as on the plain path but uploaded from pinned memory without blocking, AdamW is fused, and nothing
in a step waits for the GPU. ``compile`` ('auto': CUDA graphs on a CUDA device, eager on a CPU) and
``channels_last`` are separate options; ``deadline`` checkpoints and returns early (without ``DONE``) for
time-sliced jobs.
"""

from __future__ import annotations

import os
import random
from pathlib import Path

import numpy as np
import torch

from .. import checkpoint, data as data_mod
from ..config import to_dict
from ..errors import ConfigError
from ..io import run_lock
from ..models.xjepa import XJEPA
from ..run_store import write_run_config
from ..rundir import (
    MetricsLog,
    check_run_dir_writable,
    check_run_files,
    check_state_fits,
    keep_checkpoint,
    load_resume_checkpoint,
    restart_metrics,
    restoring,
    write_final,
)
from .config import (
    TrainConfig,
    auto_threads,
    check_existing,
    compile_mode_for,
    compile_status,
    resolve_device,
    use_fast_path,
    validate,
)
from .loop import LoopSchedule, Progress, past, run_loop
from .optimizer_state import check_optimizer_fits
from .sampler import WindowSampler, data_stats
from .step import compiled, loss_kwargs, lr_lambda, make_optimizer, model_kwargs, train_step


def run(cfg: TrainConfig, status_every: float = 0.0) -> Path:
    """Train (or resume, or skip if finished) one model; returns the run directory. ``status_every`` > 0 prints a
    status line that often (seconds) while training, for runs whose progress bar is off (the map's)."""
    validate(cfg)
    out = Path(cfg.out)
    cfg_dict = to_dict(cfg)
    check_run_files(out)  # before anything reads or writes there: no links, FIFOs, or a file as the folder
    check_existing(cfg)
    if (out / "DONE").exists():
        return out
    if past(cfg.deadline):  # out of time before starting: leave the run as it is
        return out
    # inputs are checked before the run folder and its config.json exist: a config.json left by a command that
    # failed on a mistyped --data would refuse the corrected command as "a different config"
    data_mod.read_manifest(cfg.data)
    check_run_dir_writable(out)

    with run_lock(out, enabled=int(os.environ.get("RANK", "0")) == 0):  # ranks > 0 never write the run dir
        return _train(cfg, out, cfg_dict, status_every)


class _Ranks:
    """This process's place in a data-parallel job (rank 0 of 1 without DDP)."""

    def __init__(self, cfg: TrainConfig):
        self.rank, self.world, self.local_rank = 0, 1, 0
        if not cfg.ddp:
            self.dev = resolve_device(cfg)
            return
        import torch.distributed as dist

        if "RANK" not in os.environ:
            raise ConfigError("ddp=True must be launched with torchrun (RANK/WORLD_SIZE unset)")
        self.rank, self.world = int(os.environ["RANK"]), int(os.environ["WORLD_SIZE"])
        self.local_rank = int(os.environ.get("LOCAL_RANK", 0))
        self.dev = resolve_device(cfg, self.local_rank)
        if self.dev.type == "cuda":
            torch.cuda.set_device(self.dev)
        dist.init_process_group("nccl" if self.dev.type == "cuda" else "gloo")

    @property
    def main(self) -> bool:
        return self.rank == 0


class _SingleRun:
    """One model, its optimizer, schedule and sampler: the :class:`~.loop.Trainee` of a single run."""

    def __init__(self, cfg: TrainConfig, out: Path, cfg_dict: dict, ranks: _Ranks):
        self.cfg, self.out, self.cfg_dict, self.ranks = cfg, out, cfg_dict, ranks
        dev = self.dev = ranks.dev
        self.fast = use_fast_path(cfg, dev)

        ds = data_mod.load(cfg.data)
        train_ep = ds.episodes("train")
        dims = (ds.proprio.shape[-1], ds.touch.shape[-1], ds.actions.shape[-1])
        self.sampler = WindowSampler(ds, train_ep, cfg.image_size, cfg.window, dev, cfg.contact_channel,
                                     seed=cfg.seed * 1000 + 1 + ranks.rank, with_params=cfg.sysid_weight > 0,
                                     non_blocking=self.fast, aligned_share=cfg.program_aligned_share,
                                     horizon=max(cfg.horizons))
        stats = data_stats(ds, train_ep)
        del ds

        torch.manual_seed(cfg.seed)
        random.seed(cfg.seed)
        np.random.seed(cfg.seed)
        self.mk = model_kwargs(cfg, dims)
        self.model = XJEPA(**self.mk)
        self.model.set_stats(stats)
        self.model.to(dev)
        if cfg.channels_last:
            self.model.to(memory_format=torch.channels_last)
        self.opt = make_optimizer(self.model, cfg, fused=self.fast)
        self.sched = torch.optim.lr_scheduler.LambdaLR(self.opt, lambda s: lr_lambda(s, cfg.warmup, cfg.steps))
        self.loss_kw = loss_kwargs(cfg)
        self.use_amp = cfg.amp and dev.type == "cuda" and torch.cuda.is_bf16_supported()
        self.log: MetricsLog | None = None

    def resume_or_start(self) -> int:
        """Load ``ckpt.pt`` when there is one (returns its step) or start the metrics record; 0 on a fresh start."""
        cfg, ranks = self.cfg, self.ranks
        ckpt_path = self.out / "ckpt.pt"
        if not ckpt_path.exists():
            if ranks.main:  # fresh start: the step-0 row describes the corpus the loss will see
                restart_metrics(self.out, 0, {"step": 0, **self.sampler.glide_share(tuple(cfg.horizons),
                                                                                   cfg.glide_loss_weight)})
            return 0
        ck = load_resume_checkpoint(ckpt_path)
        check_state_fits(self.model, ck["model"], ckpt_path)
        check_optimizer_fits(self.model, ck["optimizer"], ckpt_path)
        with restoring(ckpt_path):
            self.model.load_state_dict(ck["model"])
            self.opt.load_state_dict(ck["optimizer"])
            self.sched.load_state_dict(ck["scheduler"])
            checkpoint.set_rng_state(ck["rng"])
            if ranks.main:
                self.sampler.gen.set_state(ck["sampler"])
            else:
                self.sampler.gen.manual_seed(cfg.seed * 1000 + 1 + ranks.rank + 7919 * ck["step"])
        step = int(ck["step"])
        if ranks.main:
            restart_metrics(self.out, step)
            # an interrupted run that starts again says so, so nobody wonders whether it is starting over
            print(f"[train] resuming {self.out} from step {step}", flush=True)
        return step

    def wrap(self) -> None:
        """DDP around the model, and the (compiled) loss function a step calls."""
        cfg, dev = self.cfg, self.dev
        net: torch.nn.Module = self.model
        if cfg.ddp:
            from torch.nn.parallel import DistributedDataParallel as DDP

            net = DDP(self.model, device_ids=[dev.index] if dev.type == "cuda" else None,
                      find_unused_parameters=cfg.objective == "recon")
        # compile the module call (forward + loss); the optimizer step stays eager, so the lr schedule
        # (a Python float per step) causes no recompiles. On CUDA this is the default, as CUDA graphs
        # (compile_mode_for): the step's inputs are device tensors uploaded ahead and nothing in the global-latent
        # loss reads a value back on the host, so the graphs capture forward and backward whole (the token variant
        # draws its SIGReg row subset on the host inside the loss: that part runs outside the graphs)
        self.mode = compile_mode_for(cfg, dev)
        self.eager_fn = net
        self.loss_fn = compiled(net, mode=self.mode) if self.mode else net
        self.compile_checked = self.mode is None  # a compiled step proves itself once, on the first step

    def fall_back_to_eager(self, error: Exception) -> None:
        """A compilation that fails (it happens at the first call) costs the compiled speed, never the run: the
        same step is taken again eagerly, and the run's metrics say so (``compiled`` 0)."""
        first = (str(error).strip().splitlines() or [""])[0][:200]
        print(f"[train] torch.compile (mode {self.mode}) failed at the first step ({type(error).__name__}: {first}); "
              "training eagerly, recorded as compiled=0 in metrics.jsonl", flush=True)
        self.loss_fn, self.mode, self.compile_checked = self.eager_fn, None, True

    # ------------------------------------------------------------------ Trainee
    def step(self, step: int) -> dict[str, torch.Tensor]:
        batch = self.sampler.sample(self.cfg.batch_size)
        try:
            loss, terms = train_step(self.model, self.opt, self.cfg, batch, step, self.dev, self.loss_kw,
                                     amp=self.use_amp, fast=self.fast, loss_fn=self.loss_fn)
        except Exception as e:  # noqa: BLE001 - only the first compiled step; the eager retry raises a real error
            if self.compile_checked:
                raise
            # nothing was applied: a compile error comes before opt.step(), so the same batch is taken again
            self.fall_back_to_eager(e)
            loss, terms = train_step(self.model, self.opt, self.cfg, batch, step, self.dev, self.loss_kw,
                                     amp=self.use_amp, fast=self.fast, loss_fn=self.loss_fn)
        self.compile_checked = True
        self.sched.step()
        terms["loss"] = loss
        return terms

    def lr(self) -> float:
        return self.sched.get_last_lr()[0]

    def out_of_time(self, step: int) -> bool:
        cfg = self.cfg
        if not cfg.ddp or cfg.deadline <= 0:
            return past(cfg.deadline)
        if step % cfg.log_every:
            return False
        # ranks must stop at the same step (or the others hang in the next all-reduce): rank 0's clock
        # decides, at log steps only, so the broadcast costs one sync per logged row
        import torch.distributed as dist

        flag = torch.tensor(float(past(cfg.deadline)), device=self.dev)
        dist.broadcast(flag, 0)
        return bool(flag)

    def agree_to_stop(self, step: int, signalled: bool) -> bool:
        """Whether to stop for SIGINT / SIGTERM. Under DDP the ranks must stop at the same step (or the others hang
        in the next all-reduce); torchrun passes a signal to every rank, but not at the same instant, so they agree
        at log steps, where a signal to any rank stops all (one more sync per logged row)."""
        if not self.cfg.ddp:
            return signalled
        if step % self.cfg.log_every:
            return False
        import torch.distributed as dist

        flag = torch.tensor(float(signalled), device=self.dev)
        dist.all_reduce(flag, op=dist.ReduceOp.MAX)
        return bool(flag)

    def write_rows(self, row: dict[str, float], sums: dict[str, torch.Tensor], n: int) -> float:
        row.update({k: float(v) / n for k, v in sums.items()})
        row.update(compile_status(self.mode))
        if self.log is not None:
            self.log.write(row)
        return row["loss"]

    def save_checkpoint(self, step: int) -> None:
        if self.ranks.main:
            checkpoint.save({"model": self.model.state_dict(), "optimizer": self.opt.state_dict(),
                             "scheduler": self.sched.state_dict(), "rng": checkpoint.rng_state(),
                             "sampler": self.sampler.gen.get_state(), "step": step, "model_kwargs": self.mk,
                             "config": self.cfg_dict}, self.out / "ckpt.pt")
            if self.cfg.keep_every and step % self.cfg.keep_every == 0:  # a point of the run's learning curve
                keep_checkpoint(self.out, step)


def _train(cfg: TrainConfig, out: Path, cfg_dict: dict, status_every: float) -> Path:
    """The body of :func:`run`, under the run directory's lock."""
    ranks = _Ranks(cfg)
    if ranks.dev.type == "cpu":
        torch.set_num_threads(cfg.threads or auto_threads())
    t = _SingleRun(cfg, out, cfg_dict, ranks)  # loads the data: a corpus that fails to load leaves no config.json
    if ranks.main:
        out.mkdir(parents=True, exist_ok=True)
        write_run_config(out, cfg_dict)  # records the store's path and content hash; refuses a changed store
    step = t.resume_or_start()
    t.wrap()
    t.log = MetricsLog(out, cfg.tensorboard, step) if ranks.main else None
    end = min(cfg.steps, cfg.stop_at) if cfg.stop_at > 0 else cfg.steps
    sched = LoopSchedule(step, end, cfg.steps, cfg.log_every, cfg.ckpt_every, cfg.batch_size * cfg.window * ranks.world)
    progress = Progress(sched, Path(cfg.out).name if status_every else f"train {cfg.variant}",
                        bar=ranks.main and cfg.progress, every=status_every if ranks.main else 0.0)
    t.model.train()
    try:
        step = run_loop(t, sched, ranks.dev, progress, checkpoints=str(out / "ckpt.pt"))
    finally:
        progress.close()
        if t.log is not None:
            t.log.close()
    if step >= cfg.steps and ranks.main:
        write_final(out, t.model.state_dict(), t.mk, cfg_dict, step)
    if cfg.ddp:
        import torch.distributed as dist

        dist.barrier()
        dist.destroy_process_group()
    return out


__all__ = ["run"]
