"""The training loop every run goes through, one model (:mod:`.single`) or a stacked group (:mod:`.stacked`).

The loop owns the cadence: a step, the sum of its loss terms on the device, a metrics row every ``log_every``
steps, a checkpoint every ``ckpt_every``, the non-finite check before either (the only host syncs: reading a
loss every step would make the host wait for the GPU), the deadline, and the progress display. What a step is,
what a row holds and what a checkpoint stores belong to the :class:`Trainee` it drives.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass
from typing import Protocol

import torch

from .. import clock
from ..faults import crash_point


class Trainee(Protocol):
    """What the loop drives."""

    def step(self, step: int) -> dict[str, torch.Tensor]:
        """One optimisation step from global step ``step``; its loss terms, ``loss`` among them (0-d for one
        model, (M,) for M stacked members), left on the device."""

    def lr(self) -> float:
        """The learning rate the last step used."""

    def out_of_time(self, step: int) -> bool:
        """Whether the deadline has passed (checked after every step; the loop then checkpoints and stops)."""

    def write_rows(self, row: dict[str, float], sums: dict[str, torch.Tensor], n: int) -> float:
        """Write the metrics row(s) of the ``n`` steps since the last one: ``row`` holds the timing fields, ``sums``
        the loss terms summed over those steps; returns the loss to show in the progress display."""

    def save_checkpoint(self, step: int) -> None:
        """Checkpoint everything needed to resume at ``step``."""


@dataclass
class LoopSchedule:
    """When the loop writes: steps [start, end), a row every ``log_every``, a checkpoint every ``ckpt_every``."""

    start: int
    end: int
    total: int
    """The run's total steps (``end`` is earlier for a run stopped at ``stop_at``)."""
    log_every: int
    ckpt_every: int
    frames_per_step: int
    """Frames one step trains on (per member), for the frames/s field."""


def speed_row(step: int, lr: float, n_steps: int, frames_per_step: int, seconds: float) -> dict[str, float]:
    """The timing fields of a metrics.jsonl row covering ``n_steps`` steps that took ``seconds``."""
    return {"step": step, "lr": lr, "frames_per_s": n_steps * frames_per_step / max(seconds, 1e-9),
            "steps_per_s": n_steps / max(seconds, 1e-9)}


def check_finite(first_bad: torch.Tensor, acc: dict[str, torch.Tensor], step: int,
                 members: list[str] | None = None) -> None:
    """Raise if any step since the last check had a non-finite loss. Called only before a metrics row or a
    checkpoint is written (one host sync there instead of one per step), so no checkpoint holds NaNs.
    ``first_bad`` is 0-d for one model, (M,) for stacked members (named by ``members``)."""
    if first_bad.dim() == 0:
        bad_step = int(first_bad)
        if bad_step >= 0:
            bad = {k: float(v) for k, v in acc.items() if not math.isfinite(float(v))}
            raise FloatingPointError(
                f"non-finite training loss at step {bad_step} (detected at step {step}); terms non-finite since "
                f"the last log {bad or '(none: overflow in sum)'}. "
                "Lower the learning rate or check the data; the last good checkpoint is kept.")
        return
    bad = first_bad.cpu()
    for i in range(len(bad)):
        if bad[i] >= 0:
            raise FloatingPointError(
                f"non-finite training loss of stacked member {members[i] if members else i} at step {int(bad[i])} "
                f"(detected at step {step}). Lower the learning rate or check the data; the last "
                "good checkpoints are kept.")


class Progress:
    """What a person watching sees: a tqdm bar (``bar``), or one status line every ``every`` seconds (step, loss,
    steps/s, time left; for runs launched by the map, whose parallel workers would tear a bar), or nothing."""

    def __init__(self, sched: LoopSchedule, label: str, bar: bool = False, every: float = 0.0):
        self.sched, self.label, self.every = sched, label, every
        self.pbar = None
        self.last_loss: float | None = None
        self.t_start = self.t_last = time.perf_counter()
        self.step0 = sched.start
        if bar:
            from tqdm.auto import tqdm

            self.pbar = tqdm(total=sched.total, initial=sched.start, desc=label, dynamic_ncols=True)

    def update(self, step: int) -> None:
        if self.pbar is not None:
            self.pbar.update(1)
        elif self.every > 0 and time.perf_counter() - self.t_last >= self.every:
            self.t_last = time.perf_counter()
            print(self.status(step, None), flush=True)

    def row(self, step: int, loss: float, frames_per_s: float) -> None:
        self.last_loss = loss
        if self.pbar is not None:
            self.pbar.set_postfix(loss=f"{loss:.4f}", fps=f"{frames_per_s:.0f}")

    def status(self, step: int, loss: float | None) -> str:
        loss = self.last_loss if loss is None else loss
        rate = (step - self.step0) / max(time.perf_counter() - self.t_start, 1e-9)
        left = (self.sched.end - step) / rate if rate > 0 else float("inf")
        return (f"[train {self.label}] step {step}/{self.sched.total}"
                + (f" loss {loss:.4f}" if loss is not None else "")
                + f" {rate:.2f} steps/s, {left / 60:.1f} min left")

    def close(self) -> None:
        if self.pbar is not None:
            self.pbar.close()


def status_every() -> float:
    """Seconds between status lines of a run the map launches: 30 on a terminal, none otherwise (a log file
    or CI gets the map's own lines only)."""
    return 30.0 if sys.stdout.isatty() else 0.0


@dataclass
class LoopPosition:
    """How far the loop got: steps done, and the step of the last checkpoint (None: none written yet)."""

    done: int
    saved: int | None


class TrainingInterrupted(KeyboardInterrupt):
    """Ctrl-C during training; its message says at which step training stopped and what a re-run resumes from
    (the CLI adds the command and exits with 130)."""


def interrupted_line(step: int, total: int, saved: int | None, checkpoints: str) -> str:
    """What a person who pressed Ctrl-C at ``step`` needs: where it stopped, and which checkpoint (``saved``: its
    step; None: none written yet) a re-run resumes from."""
    resume = (f"re-running resumes from {checkpoints} at step {saved}" if saved is not None else
              "no checkpoint was written yet, so re-running starts again from step 0")
    return f"training stopped at step {step} of {total}; {resume}"


def run_loop(t: Trainee, sched: LoopSchedule, dev: torch.device, progress: Progress,
             loss_shape: tuple[int, ...] = (), members: list[str] | None = None, checkpoints: str = "ckpt.pt") -> int:
    """Train ``t`` from ``sched.start`` until ``sched.end`` or its deadline; returns the step reached. Ctrl-C
    becomes :class:`TrainingInterrupted` naming the step and the checkpoint (``checkpoints``, in words) that a
    re-run resumes from."""
    # a run that starts past step 0 was resumed from a checkpoint at that step
    pos = LoopPosition(sched.start, sched.start if sched.start > 0 else None)
    try:
        return _loop(t, sched, dev, progress, loss_shape, members, pos)
    except KeyboardInterrupt:
        raise TrainingInterrupted(interrupted_line(pos.done, sched.total, pos.saved, checkpoints)) from None


def _loop(t: Trainee, sched: LoopSchedule, dev: torch.device, progress: Progress, loss_shape: tuple[int, ...],
          members: list[str] | None, pos: LoopPosition) -> int:
    """The body of :func:`run_loop`, keeping ``pos`` current."""
    step = sched.start
    # loss terms are summed on the device and read only when a row is logged: a per-step .item() or
    # isfinite check would make the host wait for the GPU every step
    acc: dict[str, torch.Tensor] = {}
    first_bad = torch.full(loss_shape, -1, dtype=torch.long, device=dev)  # first step with a non-finite loss
    n_acc, t0 = 0, time.perf_counter()
    while step < sched.end:
        terms = t.step(step)
        crash_point("train_step")
        first_bad = torch.where((first_bad < 0) & ~torch.isfinite(terms["loss"]), step, first_bad)
        step += 1
        pos.done = step
        for k, v in terms.items():
            acc[k] = acc.get(k, 0.0) + v.float()
        n_acc += 1
        progress.update(step)
        out_of_time = t.out_of_time(step)
        log_now = step % sched.log_every == 0 or step == sched.end or out_of_time
        ckpt_now = step % sched.ckpt_every == 0 or step == sched.end or out_of_time
        if log_now or ckpt_now:
            check_finite(first_bad, acc, step, members)
        if log_now:
            if dev.type == "cuda":
                torch.cuda.synchronize(dev)
            row = speed_row(step, t.lr(), n_acc, sched.frames_per_step, time.perf_counter() - t0)
            loss = t.write_rows(row, acc, n_acc)
            progress.row(step, loss, row["frames_per_s"])
            acc, n_acc, t0 = {}, 0, time.perf_counter()
        if ckpt_now:
            t.save_checkpoint(step)
            pos.saved = step
        if out_of_time:
            break
    return step


def past(deadline: float) -> bool:
    """Whether a deadline (unix time; 0 = none) has passed."""
    return deadline > 0 and clock.wall_clock() >= deadline


__all__ = ["Trainee", "LoopSchedule", "LoopPosition", "Progress", "TrainingInterrupted", "interrupted_line", "run_loop",
           "speed_row", "check_finite", "status_every", "past"]
