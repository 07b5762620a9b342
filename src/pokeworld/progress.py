"""Progress of long work, so that slow never reads as hung: a heartbeat line at least every 30 s while a stage runs
(on a terminal and in a redirected log alike), and the training progress of runs that other processes train, read
from their ``metrics.jsonl`` (steps, steps/s, time left).

``quiet(True)`` (``--quiet`` on ``map`` / ``demo``) silences the heartbeats; the stage lines stay.
"""

from __future__ import annotations

import contextlib
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
            print(f"[{tag}] still working: {now} ({duration(time.monotonic() - start)} so far)", flush=True)
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


def runs_progress(runs: dict[str, tuple[Path, int]]) -> str:
    """The progress of several runs (name -> (run folder, total steps)), the unfinished ones first."""
    lines = [run_progress(n, d, s) for n, (d, s) in runs.items()]
    done = sum(line.endswith(" finished") for line in lines)
    busy = [line for line in lines if not line.endswith(" finished")]
    return f"training {done}/{len(lines)} runs finished" + ("; " + " | ".join(busy) if busy else "")


__all__ = ["HEARTBEAT_S", "quiet", "duration", "heartbeat", "run_progress", "runs_progress"]
