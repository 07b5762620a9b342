"""Progress of long work, so that slow never reads as hung: a heartbeat line at least every 30 s while a stage runs
(on a terminal and in a redirected log alike), the training progress of runs that other processes train, read
from their ``metrics.jsonl`` (steps, steps/s, time left), and one whole-job estimate (:class:`JobEstimate`),
kept current from each stage's own measured rate (a certificate fit's epochs, training's steps).

``quiet(True)`` (``--quiet`` on ``map`` / ``demo``) silences the heartbeats; the stage lines stay.
"""

from __future__ import annotations

import contextlib
import statistics
import sys
import threading
import time
from pathlib import Path
from typing import Callable, Iterator

from .errors import PokeworldError
from .rundir import read_metrics

HEARTBEAT_S = 30.0
"""Longest silence while a stage runs."""

_QUIET = threading.Event()


def quiet(on: bool = True) -> None:
    """Silence (or restore) the heartbeats of this process."""
    if on:
        _QUIET.set()
    else:
        _QUIET.clear()


def duration(seconds: float) -> str:
    """``42 s``, ``3 min 05 s``, ``1 h 02 min``."""
    s = int(round(max(0.0, seconds)))
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60:02d} s"
    return f"{s // 3600} h {s % 3600 // 60:02d} min"


@contextlib.contextmanager
def heartbeat(tag: str, status: Callable[[], str] | str, every: float = HEARTBEAT_S) -> Iterator[None]:
    """While the block runs, print ``[tag] still working: <status> (<elapsed>)`` every ``every`` seconds from a
    daemon thread (``status`` a string or a callable giving the current one; a failing callable prints what it
    can). Nothing is printed for a block shorter than ``every``."""
    done = threading.Event()
    start = time.monotonic()

    def beat() -> None:
        while not done.wait(every):
            if _QUIET.is_set():
                continue
            try:
                now = status() if callable(status) else status
            except Exception as e:  # noqa: BLE001 - a heartbeat must never end the work it reports on
                now = f"(status unavailable: {type(e).__name__})"
            whole = f"; {_JOB[-1].status()}" if _JOB else ""  # the whole job's estimate, when one is kept
            print(f"[{tag}] still working: {now} ({duration(time.monotonic() - start)} so far){whole}", flush=True)
            sys.stdout.flush()

    thread = threading.Thread(target=beat, name=f"{tag}-heartbeat", daemon=True)
    thread.start()
    try:
        yield
    finally:
        done.set()
        thread.join(timeout=1.0)


def run_progress(name: str, run_dir: str | Path, steps: int) -> str:
    """One run's training progress from its metrics: ``VFX-… 1200/2200 steps, 2.1 steps/s, ~8 min left``;
    ``waiting`` before its first row, ``trained, being measured`` once ``DONE`` is there, ``finished`` once its
    measurement is written too."""
    run_dir = Path(run_dir)
    if (run_dir / "DONE").exists():  # trained; the map's worker measures it next
        return f"{name} finished" if any(run_dir.glob("measure*.json")) else f"{name} trained, being measured"
    try:
        rows = read_metrics(run_dir) if run_dir.is_dir() else []
    except PokeworldError:
        rows = []
    if not rows:
        return f"{name} waiting"
    last = rows[-1]
    step = int(last.get("step", 0))
    rate = last.get("steps_per_s")
    line = f"{name} {step}/{steps} steps"
    if isinstance(rate, (int, float)) and rate > 0:
        line += f", {rate:.2g} steps/s, ~{duration((steps - step) / rate)} left"
    return line


def runs_fraction(runs: dict[str, tuple[Path, int]]) -> float:
    """The share of all the runs' training steps done (a trained run counts whole), from their metrics."""
    done = total = 0
    for run_dir, steps in runs.values():
        total += steps
        if (Path(run_dir) / "DONE").exists():
            done += steps
            continue
        try:
            rows = read_metrics(run_dir) if Path(run_dir).is_dir() else []
        except PokeworldError:
            rows = []
        done += min(steps, int(rows[-1].get("step", 0))) if rows else 0
    return done / total if total else 0.0


def report(stage: str, fraction: float) -> None:
    """Tell the whole job being estimated, if any, how far its running ``stage`` is (:meth:`JobEstimate.report`)."""
    if _JOB:
        _JOB[-1].report(stage, fraction)


def runs_progress(runs: dict[str, tuple[Path, int]]) -> str:
    """The progress of several runs (name -> (run folder, total steps)): how many are trained and how many of those
    measured too, then the unfinished ones."""
    lines = [run_progress(n, d, s) for n, (d, s) in runs.items()]
    measured = sum(line.endswith(" finished") for line in lines)
    trained = measured + sum(line.endswith(" being measured") for line in lines)
    busy = [line for line in lines if not line.endswith(" finished")]
    return (f"runs: {trained} of {len(lines)} trained, {measured} of {len(lines)} measured"
            + ("; " + " | ".join(busy) if busy else ""))


RATE_WINDOW = 5
"""How many of a stage's latest report intervals set its rate (their median): one stalled interval among them does
not move the estimate, a lasting change of speed does within a few reports."""


class StageRate:
    """A running stage's own measured rate, from the share of its work it reports done (a fit's epochs, training's
    steps): seconds per unit of share, the median over its latest intervals between reports. The first interval,
    which also holds the stage's set-up, counts only until another exists."""

    def __init__(self, begun: float):
        self.share, self.last = 0.0, begun
        self.intervals: list[float] = []  # seconds per unit of share, one per interval between two reports

    def report(self, now: float, share: float) -> None:
        """``share`` of the stage is done at ``now``; a report without progress waits for the next (a stall's time
        joins one interval, which the median then outvotes)."""
        if share <= self.share:
            return
        self.intervals.append((now - self.last) / (share - self.share))
        self.share, self.last = share, now

    def left(self, now: float) -> float | None:
        """Seconds the rest of the stage takes at its measured rate, counted down since its last report as
        :func:`predicted_left` counts down a prediction (a stall's time is not taken for progress past half of
        what was left); None before its first report."""
        if not self.intervals:
            return None
        latest = self.intervals[1:][-RATE_WINDOW:] or self.intervals
        return predicted_left(statistics.median(latest) * (1.0 - self.share), now - self.last)


def predicted_left(cost: float, elapsed: float) -> float:
    """What remains of work predicted to take ``cost`` seconds, ``elapsed`` seconds later with no news of it: the
    prediction's remainder within half of it; past that a remainder that shrinks more slowly and never reaches zero
    (a quarter of the prediction in the limit), so that overrunning work still reads as not done and the job's
    total grows with its overrun, without the overrun being extrapolated to anything else."""
    if cost <= 0:
        return 0.0
    x = elapsed / cost
    return cost * (1.0 - x) if x <= 0.5 else cost * x / (4.0 * x - 1.0)


class JobEstimate:
    """One estimate of a whole job's time, from its start to its last line, kept current as the job runs.

    ``costs`` maps each stage, in order, to its predicted seconds on this machine (a timing made at the start, or a
    reference cost scaled by it). The time left is the predictions of the stages ahead plus what remains of the
    running stage: at its own measured rate once it reports its progress (:meth:`report`: a certificate's fit by
    its epochs, training by its steps), else by its prediction (:func:`predicted_left`). A stage that runs slower
    than predicted therefore lengthens the estimate by its own overrun only: a stalled certificate does not scale
    the training ahead, whose cost was timed on this machine and which measures its own rate once it runs. The
    share done is the job's elapsed time over its estimated total (stages found done already counted at their
    predicted cost), so it advances within a stage, and it never goes back when the estimate grows
    (:meth:`fraction`). Stages found done already (a resumed job) cost nothing here. ``now`` is the clock (a test
    passes a fake one). With a ``contention`` (:class:`Contention`) every prediction is scaled by how much less of
    the CPU this process gets than when the costs were timed: a machine that other work came to share after the
    timing lengthens the stages ahead, a stall does not.
    """

    def __init__(self, costs: dict[str, float], now: Callable[[], float] = time.monotonic,
                 contention: "Contention | None" = None):
        self.costs = {k: max(0.0, float(v)) for k, v in costs.items()}
        self.now = now
        self.contention = contention  # how much of the CPU this process gets now against the timing's share
        self.started = now()
        self.initial = sum(self.costs.values())
        self.taken: dict[str, float] = {}
        self.skipped: set[str] = set()
        self.running: tuple[str, float] | None = None
        self.rate: StageRate | None = None  # the running stage's own rate, from its reports
        self.covers: dict[str, float] = {}  # the share of a stage's cost its reported work stands for
        self.shown, self.shown_at = 0.0, self.started  # the share done said last, and when

    def report(self, stage: str, fraction: float) -> None:
        """The running ``stage``'s work is ``fraction`` done (a fit's epochs, training steps over all the runs'
        steps): what remains of it then follows its own measured rate instead of its prediction. The part of the
        stage that work stands for is ``covers[stage]`` (training, of a stage that measures the runs too)."""
        if self.running and self.running[0] == stage and self.rate is not None:
            self.rate.report(self.now(), min(1.0, max(0.0, fraction)) * self.covers.get(stage, 1.0))

    def begin(self, stage: str) -> None:
        self.running = (stage, self.now())
        self.rate = StageRate(self.running[1])
        if self.contention is not None:
            self.contention.begin(stage)

    def end(self, stage: str) -> str:
        """Close ``stage`` (begun with :meth:`begin`); the line saying what it took and the re-estimate."""
        begun = self.running[1] if self.running and self.running[0] == stage else self.now()
        self.taken[stage] = self.now() - begun
        self.running, self.rate = None, None
        if self.contention is not None:
            self.contention.end(stage)
        return (f"{stage} took {duration(self.taken[stage])} (predicted {duration(self.costs.get(stage, 0))}); "
                + self.status())

    def skip(self, stage: str) -> None:
        """``stage`` was done already: it counts as done and costs nothing."""
        self.skipped.add(stage)
        if self.running and self.running[0] == stage:
            self.running, self.rate = None, None

    def _ahead(self) -> list[str]:
        done = set(self.taken) | self.skipped | ({self.running[0]} if self.running else set())
        return [s for s in self.costs if s not in done]

    def running_left(self) -> float:
        """Seconds still to go in the running stage (0 when none runs)."""
        if not self.running:
            return 0.0
        name, begun = self.running
        own = self.rate.left(self.now()) if self.rate is not None else None
        return own if own is not None else predicted_left(self.costs.get(name, 0.0) * self.slowdown(),
                                                          self.now() - begun)

    def left(self) -> float:
        """Seconds still to go: the stages ahead at their predictions and what remains of the running one; every
        prediction times the machine's slowdown since the timing, when one is measured (:class:`Contention`)."""
        return sum(self.costs[s] for s in self._ahead()) * self.slowdown() + self.running_left()

    def slowdown(self) -> float:
        return self.contention.slowdown() if self.contention is not None else 1.0

    def fraction(self) -> float:
        """The share of the job done: its elapsed time (and the predicted cost of stages found done) over its
        estimated total. It never goes back nor stands still: when the estimate grows past what was said, the share
        said advances at half its pace (the time since over the estimated total, halved) until the elapsed time's
        share catches up with it."""
        now, left = self.now(), self.left()
        done = now - self.started + sum(self.costs.get(s, 0.0) for s in self.skipped)
        if left <= 0:
            share = 1.0
        else:
            creep = self.shown + 0.5 * (now - self.shown_at) / (done + left)
            share = min(0.99, max(done / (done + left), creep))
        self.shown, self.shown_at = max(self.shown, share), now
        return self.shown

    def status(self) -> str:
        """``whole job 42% done, ~12 min 30 s left of about 21 min 10 s``."""
        elapsed, left = self.now() - self.started, self.left()
        return f"whole job {self.fraction():.0%} done, ~{duration(left)} left of about {duration(elapsed + left)}"

    def total(self) -> str:
        """``in 43 min 10 s (estimated at the start: 21 min 05 s)``, for the job's closing line."""
        return f"in {duration(self.now() - self.started)} (estimated at the start: {duration(self.initial)})"


class Contention:
    """How much slower the machine runs now than when a job's costs were timed, from the share of the CPU this
    process gets: its CPU seconds per wall second per thread it runs (``threads()``), over the stage running here
    (once it has run ``min_seconds``) or else the last one that ran here, against ``timed_share``, the same share
    while the costs were timed. Work that takes a core's whole time runs at that share, so the ratio is the
    slowdown of every stage ahead when other processes came to share the cores after the timing (or the speed-up
    when they left), and 1 when the machine is as it was: a stage slow for its own reasons (more epochs, a stall)
    keeps its share and scales nothing. Stages in ``elsewhere`` run in other processes (training in workers) and are
    not sampled. Clamped to [1/4, 4]: a multi-threaded fit's share under load can fall further than the
    single-threaded training ahead slows, and the training corrects itself by its own rate once it runs."""

    def __init__(self, timed_share: float, elsewhere: tuple[str, ...] = (), cpu: Callable[[], float] = time.process_time,
                 now: Callable[[], float] = time.monotonic, threads: Callable[[], int] | None = None,
                 min_seconds: float = 10.0):
        self.timed_share, self.elsewhere = max(1e-3, float(timed_share)), set(elsewhere)
        self.cpu, self.now, self.min_seconds = cpu, now, min_seconds
        self.threads = threads or _torch_threads
        self.mark: tuple[float, float, int] | None = None  # (wall, cpu, threads) when the running stage began here
        self.share: float | None = None  # the last stage's that ran here

    @staticmethod
    def share_between(wall: float, cpu: float, threads: int) -> float | None:
        return cpu / wall / max(1, threads) if wall > 0 else None

    def begin(self, stage: str) -> None:
        self.mark = None if stage in self.elsewhere else (self.now(), self.cpu(), self.threads())

    def end(self, stage: str) -> None:
        if self.mark is not None and self.now() - self.mark[0] >= self.min_seconds:
            self.share = self.running_share()
        self.mark = None

    def running_share(self) -> float | None:
        if self.mark is None:
            return None
        wall0, cpu0, threads = self.mark
        return self.share_between(self.now() - wall0, self.cpu() - cpu0, threads)

    def slowdown(self) -> float:
        running = self.running_share() if self.mark and self.now() - self.mark[0] >= self.min_seconds else None
        share = running if running is not None else self.share
        if share is None:
            return 1.0
        return min(4.0, max(0.25, self.timed_share / max(share, 1e-3)))


def _torch_threads() -> int:
    import torch  # the threads a stage here computes on; torch is what runs its work

    return torch.get_num_threads()


_JOB: list[JobEstimate] = []


@contextlib.contextmanager
def whole_job(estimate: JobEstimate | None) -> Iterator[JobEstimate | None]:
    """While the block runs, heartbeats end with ``estimate``'s status and :func:`stage` blocks report to it."""
    if estimate is None:
        yield None
        return
    _JOB.append(estimate)
    try:
        yield estimate
    finally:
        _JOB.remove(estimate)


@contextlib.contextmanager
def stage(name: str, tag: str) -> Iterator[None]:
    """A stage of the whole job, when one is being estimated and has a stage called ``name``: begun here, and at its
    end a line ``[tag] <name> took …; whole job … done, ~… left``. Nothing otherwise (a command run on its own)."""
    job = _JOB[-1] if _JOB and name in _JOB[-1].costs else None
    if job is not None and (name in job.skipped or name in job.taken):  # found done already: not timed again
        job = None
    if job is not None:
        job.begin(name)
    yield
    if job is not None:
        print(f"[{tag}] {job.end(name)}", flush=True)


__all__ = ["HEARTBEAT_S", "quiet", "duration", "heartbeat", "run_progress", "runs_progress", "runs_fraction",
           "report", "RATE_WINDOW", "StageRate", "predicted_left", "JobEstimate", "Contention",
           "whole_job", "stage"]
