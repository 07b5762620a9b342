"""Several runs of one GPU allocation training at once on its one GPU, as many as pay: the allocation's runs each in
a process of its own (spawned, one run per process, so a crash or a CUDA error ends that run only), started in the
queue's order while

* the **ramp** allows it (:class:`Ramp`): one run first, then two, four, eight (at most ``most``), the next level
  only while the steps per second of all runs together, measured at the level reached, grew by at least ``gain``
  over the level before; no accelerator setting is touched (no MPS daemon), so whether runs share the GPU's time
  profitably is measured, never assumed;
* and the run **fits** (:meth:`SharedRuns.admit`): its predicted time (overhead + steps left ÷ the per-run rate at
  one more run) ends before the deadline, and so do those of the runs already training, which the newcomer slows.
  A run that cannot finish even alone is not started; one that could once another ends waits.

The rates come from the runs' own metrics rows (each row's steps/s is timed across a host sync, so it is exact for
the steps it covers), read every ``poll_s`` seconds: a run's rate is the steps of the rows it logged in the last
``window_s`` seconds over their time, counted once the run logged past its first row (the first holds the
compilation). A sample of the total is taken only when every run started is in that steady state, so each level's
number is that of exactly that many runs training together (:class:`Throughput`).
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import statistics
from collections import deque
from dataclasses import dataclass, field
from multiprocessing.connection import wait as mp_wait
from pathlib import Path
from typing import Callable

from .. import clock
from ..errors import PokeworldError
from ..rundir import read_metrics
from ..experiments import stages


@dataclass(frozen=True)
class ShareConfig:
    """How many runs train at once and how that is decided."""

    most: int = 8
    """Most runs at once (1: one after another, the plain allocation)."""
    gain: float = 1.08
    """The next level of the ramp is tried only while the last one raised the total steps/s at least this much."""
    window_s: float = 15.0
    """Seconds of metrics rows a rate is taken over."""
    samples: int = 3
    """Clean samples (every run steady) a level's total needs before the ramp decides."""
    warm_rows: int = 5
    """Metrics rows after its first that a run logs before its rate counts: CUDA-graph warm-up records graphs in
    the first steps after compilation (on an H200 the first run read 97 steps/s over its early rows, 134 later)."""
    poll_s: float = 2.0
    """Seconds between looks at the runs."""
    margin: float = 1.05
    """A run is started only when its predicted time times this fits the time left."""


@dataclass
class RunWatch:
    """One run in training, as read off its metrics rows."""

    name: str
    folder: Path
    steps: int
    """The run's total steps."""
    started: float
    rows: deque = field(default_factory=deque)
    """(time first seen, step, steps/s) of each row after the first this process saw."""
    seen: int = 0
    """Rows of metrics.jsonl read so far."""
    first_step: int | None = None
    warm: int = 0
    """Rows still to skip before the rate counts (:attr:`ShareConfig.warm_rows`)."""

    def read(self, now: float) -> None:
        try:
            rows = read_metrics(self.folder)
        except (PokeworldError, OSError):
            return  # a row being written; the next look reads it
        new, self.seen = rows[self.seen:], max(self.seen, len(rows))
        for r in new:
            if self.first_step is None:
                self.first_step = r["step"]  # the row that holds the compilation (or the resume)
                continue
            if self.warm > 0:
                self.warm -= 1
                continue
            sps = r.get("steps_per_s")
            if isinstance(sps, (int, float)) and sps > 0:
                self.rows.append((now, r["step"], float(sps)))

    def step(self) -> int:
        return self.rows[-1][1] if self.rows else (self.first_step or 0)

    def rate(self, now: float, window_s: float) -> float | None:
        """Steps/s over the rows seen in the last ``window_s`` seconds (None while it has not trained that long
        past its first row, or logged nothing in the window: compiling or measuring)."""
        while self.rows and self.rows[0][0] < now - 4 * window_s:
            self.rows.popleft()
        recent = [(s, sps) for t, s, sps in self.rows if t >= now - window_s]
        if len(recent) < 2 or self.rows[0][0] > now - window_s:
            return None
        steps = [b[0] - a[0] for a, b in zip(recent, recent[1:])]
        seconds = sum(d / sps for d, (_, sps) in zip(steps, recent[1:]))
        return sum(steps) / seconds if seconds > 0 else None


class Throughput:
    """Total steps/s of n runs training together, R(n), learned from clean samples."""

    def __init__(self, prior_s_per_step: float):
        self.prior = 1.0 / prior_s_per_step
        self.samples: dict[int, list[float]] = {}

    def add(self, n: int, total: float) -> None:
        self.samples.setdefault(n, []).append(total)

    def measured(self, n: int, at_least: int = 1) -> float | None:
        s = self.samples.get(n, [])
        return statistics.median(s[-8:]) if len(s) >= at_least else None

    def total(self, n: int) -> float:
        """R(n), pessimistic where not measured: the best total of at most n runs measured (no further gain), the
        prior's one run before anything was measured."""
        if self.measured(n) is not None:
            return self.measured(n)
        below = [self.measured(m) for m in self.samples if m <= n]
        return max(below) if below else self.prior

    def per_run(self, n: int) -> float:
        return self.total(n) / max(n, 1)

    def table(self) -> dict[str, float]:
        return {str(n): round(self.measured(n), 2) for n in sorted(self.samples)}


class Ramp:
    """The number of runs allowed at once: 1, 2, 4, 8 (capped at ``most``), the next level only while the last
    raised the total by ``gain``; settled at the best level measured otherwise."""

    def __init__(self, cfg: ShareConfig):
        self.cfg = cfg
        self.target = 1
        self.previous: int | None = None
        self.settled = cfg.most <= 1
        self.decisions: list[str] = []

    def update(self, tp: Throughput) -> str:
        """Move on when the current level is measured; returns what was decided ('' when nothing)."""
        if self.settled:
            return ""
        now = tp.measured(self.target, self.cfg.samples)
        if now is None:
            return ""
        before = tp.measured(self.previous) if self.previous else None
        if before is None or now >= self.cfg.gain * before:
            if self.target >= self.cfg.most:
                self.settled = True
                line = f"{self.target} runs at once: {now:.0f} steps/s in all; the most allowed"
            else:
                self.previous, self.target = self.target, min(2 * self.target, self.cfg.most)
                line = f"{self.previous} at once: {now:.0f} steps/s in all; trying {self.target}"
        else:
            self.settled = True
            best = self.target if now >= before else self.previous
            line = (f"{self.target} at once: {now:.0f} steps/s in all against {before:.0f} with {self.previous} "
                    f"(gain {now / before:.2f} < {self.cfg.gain}); keeping {best}")
            self.target = best
        self.decisions.append(line)
        return line


def finish_times(work: list[tuple[int, float]], tp: Throughput, most: int) -> list[float]:
    """Seconds until each run of ``work`` (steps left, overhead seconds left) ends, played out as a fluid: the
    runs with work share the total rate of as many runs at once (at most ``most`` train, the rest wait), equally;
    a run's overhead (start-up and compilation, or its measurement) counts as time it holds its place without
    stepping. Pessimistic where R(n) is not measured (:meth:`Throughput.total`)."""
    # each run as seconds of overhead then steps; a run in overhead still takes its share of places (a compiling or
    # measuring run holds the GPU lightly, so its share of the steps goes to the others)
    left = [[float(o), float(n)] for n, o in work]
    ends = [0.0] * len(work)
    t = 0.0
    active = [i for i in range(len(work))]
    while active:
        run = active[:max(most, 1)]
        for i in [i for i in run if left[i][0] <= 1e-9 and left[i][1] <= 1e-6]:  # nothing left: ended now
            ends[i] = t
            active.remove(i)
        run = active[:max(most, 1)]
        if not run:
            break
        stepping = [i for i in run if left[i][0] <= 0 and left[i][1] > 0]
        rate = tp.total(len(stepping)) / len(stepping) if stepping else 0.0
        # the next event: an overhead ends, or a stepping run's steps end
        dt = min([left[i][0] for i in run if left[i][0] > 0] + [left[i][1] / rate for i in stepping if rate > 0])
        t += dt
        for i in run:
            if left[i][0] > 0:
                left[i][0] -= dt
            elif i in stepping:
                left[i][1] -= rate * dt
    return ends


def work(job: dict, conn) -> None:
    """A run's process: train and measure ``job`` (:func:`pokeworld.experiments.stages.execute`) and send back its
    result; any error is sent as the run's, so that it ends this run only."""
    try:
        result = stages.execute(job)
    except BaseException as e:  # noqa: BLE001  (a CUDA error, a full memory: this run's end, not the allocation's)
        result = {"name": job["name"], "status": "partial", "error": f"{type(e).__name__}: {e}"[:500]}
    conn.send(result)
    conn.close()


@dataclass
class Slot:
    job: dict
    watch: RunWatch
    process: multiprocessing.process.BaseProcess
    conn: object
    started_at_step: int
    paused: bool = False


class SharedRuns:
    """Train and measure the jobs (in order) on one GPU, as many at once as the ramp and the deadline allow;
    ``finished(job, result, training)`` is called in this process after each one, ``training`` the runs still
    training (the allocation packs there). When the ramp settles below the runs it started (more runs did not
    pay), the newest are paused (SIGSTOP: a stopped process submits no GPU work, its memory stays) and resumed
    (SIGCONT) one by one as the others end, before any new run starts."""

    def __init__(self, cfg: ShareConfig, deadline: float, overhead_s: float, prior_s_per_step: float,
                 start_step: Callable[[dict], int], finished: Callable[[dict, dict, frozenset[str]], None]):
        self.cfg, self.deadline, self.overhead_s = cfg, deadline, overhead_s
        self.start_step, self.finished = start_step, finished
        self.tp, self.ramp = Throughput(prior_s_per_step), Ramp(cfg)
        self.slots: list[Slot] = []
        self.overheads: list[float] = []
        self.declined: dict[str, str] = {}
        self.last_status = 0.0
        self.t0 = clock.wall_clock()

    def say(self, line: str) -> None:
        """A line of the allocation's log, with the seconds since the runs began (the lease's record times them)."""
        print(f"[share +{clock.wall_clock() - self.t0:.0f}s] {line}", flush=True)

    def active(self) -> list[Slot]:
        return [s for s in self.slots if not s.paused]

    def run(self, jobs: list[dict]) -> None:
        queue = list(jobs)
        while queue or self.slots:
            now = clock.wall_clock()
            self.observe(now)
            line = self.ramp.update(self.tp)
            if line:
                self.say(line)
            self.balance()
            while queue and len(self.slots) < self.ramp.target:
                verdict = self.admit(queue[0], now)
                if verdict == "wait":
                    break
                job = queue.pop(0)
                if verdict == "go":
                    self.start(job, now)
                else:
                    self.declined[job["name"]] = verdict
                    self.say(f"{job['name']}: not started, {verdict}")
            if not self.slots:
                continue
            ready = mp_wait([s.process.sentinel for s in self.slots], timeout=self.cfg.poll_s)
            for slot in [s for s in self.slots if s.process.sentinel in ready]:
                self.end(slot)

    def balance(self) -> None:
        """Pause the newest runs beyond the ramp's target; resume the oldest paused one while fewer train."""
        active = self.active()
        for slot in active[self.ramp.target:]:
            self.signal(slot, signal.SIGSTOP, True)
        paused = [s for s in self.slots if s.paused]
        while paused and len(self.active()) < self.ramp.target:
            self.signal(paused.pop(0), signal.SIGCONT, False)

    def signal(self, slot: Slot, sig: int, paused: bool) -> None:
        try:
            os.kill(slot.process.pid, sig)
        except ProcessLookupError:
            return
        slot.paused = paused
        slot.watch.rows.clear()  # its rate is measured afresh once it trains again
        self.say(f"{slot.job['name']}: {'paused' if paused else 'resumed'} ({len(self.active())} training)")

    def start(self, job: dict, now: float) -> None:
        ctx = multiprocessing.get_context("spawn")  # no CUDA state is inherited: each run makes its own context
        receive, send = ctx.Pipe(duplex=False)
        process = ctx.Process(target=work, args=(job, send), name=f"run-{job['name']}", daemon=False)
        step = self.start_step(job)
        watch = RunWatch(job["name"], Path(job["train"]["out"]), stages.job_train_config(job).steps, now,
                         warm=self.cfg.warm_rows)
        watch.seen = len(read_metrics(watch.folder)) if (watch.folder / "metrics.jsonl").exists() else 0
        process.start()
        send.close()
        self.slots.append(Slot(job, watch, process, receive, step))
        self.say(f"{job['name']}: started ({len(self.slots)} at once, ramp target {self.ramp.target}), "
                 f"{watch.steps - step} steps")

    def end(self, slot: Slot) -> None:
        self.slots.remove(slot)
        result = None
        try:
            if slot.conn.poll(1.0):
                result = slot.conn.recv()
        except (EOFError, OSError):
            pass
        slot.process.join(5)
        if not isinstance(result, dict):
            result = {"name": slot.job["name"], "status": "partial",
                      "error": f"its process ended with exit code {slot.process.exitcode} and no result"}
        if result.get("error"):
            self.say(f"{slot.job['name']}: failed ({result['error'][:300]})")
        wall = clock.wall_clock() - slot.watch.started
        if result.get("status") == "finished":
            self.learn_overhead(slot, wall)
        result["wall_s"] = round(wall, 1)
        self.say(f"{slot.job['name']}: {result.get('status')} after {wall:.0f} s ({len(self.slots)} still running)")
        self.finished(slot.job, result, frozenset(s.job["name"] for s in self.slots))
    def learn_overhead(self, slot: Slot, wall: float) -> None:
        """The run's wall time less the time its rows account for: start-up, compilation and measurement."""
        try:
            rows = [r for r in read_metrics(slot.watch.folder) if r["step"] > slot.started_at_step]
        except (PokeworldError, OSError):
            return
        timed = sum((b["step"] - a["step"]) / b["steps_per_s"] for a, b in zip(rows, rows[1:])
                    if isinstance(b.get("steps_per_s"), (int, float)) and b["steps_per_s"] > 0)
        if rows:
            self.overheads.append(max(0.0, wall - timed))
            self.overhead_s = statistics.median(self.overheads[-4:])

    def observe(self, now: float) -> None:
        """Read every run's new rows; a clean sample of the total when every run training is steady."""
        rates = []
        for slot in self.slots:
            slot.watch.read(now)
            if not slot.paused:
                rates.append(slot.watch.rate(now, self.cfg.window_s))
        if rates and all(r is not None for r in rates):
            self.tp.add(len(rates), sum(rates))
        if now - self.last_status >= 30 and self.slots:
            self.last_status = now
            each = ", ".join(f"{s.watch.name} {s.watch.step()}/{s.watch.steps}{' (paused)' if s.paused else ''}"
                             for s in self.slots)
            self.say(f"{len(self.active())} training: {each}; steps/s in all by runs at once "
                     f"{self.tp.table() or '(not measured yet)'}")

    def admit(self, job: dict, now: float) -> str:
        """'go', 'wait' (it would fit once fewer runs share the GPU) or why it cannot finish before the deadline.
        The work left, the newcomer's included, is played out at the measured total rates (:func:`finish_times`:
        n runs training share R(n) equally, each run's overhead before its last step): the newcomer goes when every
        run then ends before the deadline."""
        left = self.deadline - now
        steps_left = max(0, stages.job_train_config(job).steps - self.start_step(job))
        alone = self.overhead_s + steps_left / self.tp.per_run(1)
        if self.cfg.margin * alone > left:
            return f"{steps_left} steps predicted to take {alone:.0f} s even alone but {max(left, 0):.0f} s are left"
        if any(s.paused for s in self.slots):
            return "wait"
        # a run still to compile is charged the whole overhead, one already training its measurement (about half)
        work = [(max(0, s.watch.steps - s.watch.step()),
                 self.overhead_s / 2 if s.watch.rows else self.overhead_s) for s in self.slots]
        ends = finish_times(work + [(steps_left, self.overhead_s)], self.tp, self.ramp.target)
        return "go" if self.cfg.margin * max(ends) <= left else "wait"

    def record(self) -> dict:
        """What the sharing measured, for the allocation's index."""
        return {"most": self.cfg.most, "settled_at": self.ramp.target, "steps_per_s_by_runs_at_once":
                self.tp.table(), "decisions": self.ramp.decisions, "overhead_s": round(self.overhead_s, 1),
                "declined": dict(self.declined)}


__all__ = ["ShareConfig", "RunWatch", "Throughput", "Ramp", "finish_times", "work", "Slot", "SharedRuns"]
