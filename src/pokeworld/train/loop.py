"""The training loop every run goes through, one model (:mod:`.single`) or a stacked group (:mod:`.stacked`).

The loop owns the cadence: a step, the sum of its loss terms on the device, a metrics row every ``log_every``
steps, a checkpoint every ``ckpt_every``, the non-finite check before either (the only host syncs: reading a
loss every step would make the host wait for the GPU), the deadline, SIGINT / SIGTERM (:class:`StopSignals`: a
checkpoint at the step they arrive in, then :class:`TrainingInterrupted`), and the progress display. What a step
is, what a row holds and what a checkpoint stores belong to the :class:`Trainee` it drives.
"""

from __future__ import annotations

import math
import signal
import sys
import threading
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

    # Optional (read with getattr, so a trainee without it stops on its own process's signal):
    # def agree_to_stop(self, step: int, signalled: bool) -> bool:
    #     """Whether to stop at ``step`` for a signal, ``signalled`` saying whether this process received one; a
    #     data-parallel trainee returns the same answer on every rank (or the others hang in the next all-reduce)."""


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

    def expect(self, step: int, seconds: float, timed: int) -> None:
        """Say once, early, how long the run will take from its first timed steps (``timed`` steps after the first,
        which holds any compilation, took ``seconds``) and how to stop and resume: a preset meant for a GPU takes
        hours a step on a CPU, and that should be known before the hours start. Said when an hour or more is left."""
        if timed <= 0 or seconds <= 0:
            return
        per_step = seconds / timed
        left = (self.sched.end - step) * per_step
        if left < 3600:
            return
        line = (f"[train {self.label}] expected: {self.sched.end - step} more steps at {per_step:.2f} s/step (the "
                f"first {timed} timed) ≈ {left / 3600:.1f} h on this machine; Ctrl-C stops it with a checkpoint at "
                "the step in progress and the same command resumes from there")
        if self.pbar is not None:
            self.pbar.write(line)
        else:
            print(line, flush=True)

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
    """How far the loop got: steps done, the step of the last checkpoint (None: none written yet), and the signal
    that stopped it (None: it ran to its end or deadline)."""

    done: int
    saved: int | None
    stopped_by: str | None = None


class TrainingInterrupted(KeyboardInterrupt):
    """Training stopped by SIGINT (Ctrl-C) or SIGTERM. ``checkpointed``: a checkpoint at the step it stopped was
    written and the message says so in full (the CLI prints it as it is); otherwise (a second Ctrl-C, or one outside
    the loop's handlers) the message says which earlier checkpoint a re-run resumes from, and the CLI adds the
    command. ``exit_code``: the shell's convention for a process ended by that signal (128 + its number)."""

    def __init__(self, message: str, checkpointed: bool = False, signum: int = signal.SIGINT):
        super().__init__(message)
        self.checkpointed, self.exit_code = checkpointed, 128 + int(signum)


def interrupted_line(step: int, total: int, saved: int | None, checkpoints: str) -> str:
    """What a person who pressed Ctrl-C at ``step`` needs: where it stopped, and which checkpoint (``saved``: its
    step; None: none written yet) a re-run resumes from."""
    resume = (f"re-running resumes from {checkpoints} at step {saved}" if saved is not None else
              "no checkpoint was written yet, so re-running starts again from step 0")
    return f"training stopped at step {step} of {total}; {resume}"


def signalled_line(step: int, signal_name: str) -> str:
    """What a person (or a job log) needs after a signal stopped training with a checkpoint at ``step``."""
    return f"interrupted at step {step} by {signal_name}; checkpoint saved: the same command resumes from step {step}"


#: Signals that stop training with a checkpoint at the current step: Ctrl-C, and what ``kill``, SLURM (at a job's
#: time limit or on preemption) and torchrun send to end a job.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class StopSignals:
    """While training: the first SIGINT / SIGTERM only records its name in ``received``, which the loop reads after
    the step in progress, so the step ends cleanly and everything is checkpointed at it; a second one raises
    KeyboardInterrupt at once, so a step or a write that hangs can still be left (the last checkpoint then stands).

    Handlers go in only in the main thread (Python allows no other; a run trained in a worker thread keeps the
    old behaviour), only for the duration of the ``with`` block, and the previous handlers come back after it. A
    signal its previous owner ignores (SIG_IGN, e.g. SIGINT of a job started in the background) stays ignored.
    """

    def __init__(self) -> None:
        self.received: str | None = None
        self._previous: dict[int, object] = {}

    def __enter__(self) -> StopSignals:
        if threading.current_thread() is not threading.main_thread():
            return self
        for sig in STOP_SIGNALS:
            if signal.getsignal(sig) is not signal.SIG_IGN:
                self._previous[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, *exc) -> None:
        for sig, handler in self._previous.items():
            # None: a handler installed outside Python, which cannot be put back; the default is the nearest
            signal.signal(sig, signal.SIG_DFL if handler is None else handler)
        self._previous.clear()

    def _handle(self, signum: int, frame) -> None:
        if self.received is not None:
            raise KeyboardInterrupt
        self.received = signal.Signals(signum).name

    def stop_now(self, t: Trainee, step: int) -> bool:
        """Whether the loop stops after ``step`` for a signal (agreed across ranks by trainees that need it)."""
        agree = getattr(t, "agree_to_stop", None)
        return agree(step, self.received is not None) if agree else self.received is not None


def run_loop(t: Trainee, sched: LoopSchedule, dev: torch.device, progress: Progress,
             loss_shape: tuple[int, ...] = (), members: list[str] | None = None, checkpoints: str = "ckpt.pt") -> int:
    """Train ``t`` from ``sched.start`` until ``sched.end`` or its deadline; returns the step reached.

    SIGINT or SIGTERM ends the step in progress, checkpoints at it as the periodic checkpoint does, and raises
    :class:`TrainingInterrupted` (``checkpointed``); a KeyboardInterrupt that bypasses that (a second Ctrl-C)
    becomes one naming the step and the earlier checkpoint (``checkpoints``, in words) that a re-run resumes from.
    """
    # a run that starts past step 0 was resumed from a checkpoint at that step
    pos = LoopPosition(sched.start, sched.start if sched.start > 0 else None)
    try:
        with StopSignals() as stop:
            step = _loop(t, sched, dev, progress, loss_shape, members, pos, stop)
    except KeyboardInterrupt:
        raise TrainingInterrupted(interrupted_line(pos.done, sched.total, pos.saved, checkpoints)) from None
    if pos.stopped_by is not None:
        signum = getattr(signal, pos.stopped_by, signal.SIGTERM)
        raise TrainingInterrupted(signalled_line(step, pos.stopped_by), checkpointed=True, signum=signum)
    return step


def _loop(t: Trainee, sched: LoopSchedule, dev: torch.device, progress: Progress, loss_shape: tuple[int, ...],
          members: list[str] | None, pos: LoopPosition, stop: StopSignals) -> int:
    """The body of :func:`run_loop`, keeping ``pos`` current."""
    step = sched.start
    # loss terms are summed on the device and read only when a row is logged: a per-step .item() or
    # isfinite check would make the host wait for the GPU every step
    acc: dict[str, torch.Tensor] = {}
    first_bad = torch.full(loss_shape, -1, dtype=torch.long, device=dev)  # first step with a non-finite loss
    n_acc, t0 = 0, time.perf_counter()
    # the expected time, from the steps after the first (which holds any compilation); on a CPU only, where a step
    # is done when it returns (a GPU's are queued)
    timing = {"from": None, "said": dev.type != "cpu"}
    while step < sched.end:
        if not timing["said"] and step == sched.start + 1:
            timing["from"] = time.perf_counter()
        elif not timing["said"] and timing["from"] is not None and step == sched.start + 1 + EXPECT_AFTER:
            progress.expect(step, time.perf_counter() - timing["from"], EXPECT_AFTER)
            timing["said"] = True
        terms = t.step(step)
        crash_point("train_step")
        first_bad = torch.where((first_bad < 0) & ~torch.isfinite(terms["loss"]), step, first_bad)
        step += 1
        pos.done = step
        for k, v in terms.items():
            acc[k] = acc.get(k, 0.0) + v.float()
        n_acc += 1
        progress.update(step)
        # both are asked every step, in this order, on every rank: under DDP each may be a collective
        out_of_time = t.out_of_time(step)
        signalled = stop.stop_now(t, step) and step < sched.end  # a signal in the last step: training is done
        stopping = out_of_time or signalled
        log_now = step % sched.log_every == 0 or step == sched.end or stopping
        ckpt_now = step % sched.ckpt_every == 0 or step == sched.end or stopping
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
        if signalled:
            # under DDP a rank may stop for another rank's signal
            pos.stopped_by = stop.received or "a signal to another process"
        if stopping:
            break
    return step


EXPECT_AFTER = 3
"""Steps timed (after the first) before training says how long the whole run will take."""


def past(deadline: float) -> bool:
    """Whether a deadline (unix time; 0 = none) has passed."""
    return deadline > 0 and clock.wall_clock() >= deadline


__all__ = ["Trainee", "LoopSchedule", "LoopPosition", "Progress", "TrainingInterrupted", "StopSignals", "STOP_SIGNALS",
           "interrupted_line", "signalled_line", "run_loop", "speed_row", "check_finite", "status_every", "past"]
