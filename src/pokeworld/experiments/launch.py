"""Where a map's (or the real-robot experiments') runs execute: a local process pool or submitit (SLURM, or its
local executor). No scheduler of our own."""

from __future__ import annotations

import concurrent.futures as cf
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from ..config import Limit, check_fields
from ..errors import ConfigError
from ..progress import heartbeat, report, runs_fraction, runs_progress

TRAINING_STAGE = "training and measurement"
"""The map's stage that trains and measures its runs (a whole-job estimate hears how far its training is)."""


@dataclass
class LaunchOptions:
    """Where and how runs execute (:func:`launch`); shared by ``pokeworld map`` and ``pokeworld real``."""

    launcher: str = "local"
    """local (process pool), slurm (submitit job array) or submitit-local (submitit's local executor)."""
    workers: int = 0
    """Parallel local runs (0: one per CPU core on CPU, 1 on a GPU)."""
    slurm_partition: str = ""
    """SLURM partition for --launcher slurm."""
    slurm_timeout_min: int = 180
    """SLURM time limit per run in minutes."""
    slurm_gpus: int = 1
    """GPUs per SLURM job."""

    LIMITS = {"workers": Limit(0, 4096), "slurm_timeout_min": Limit(1, 10**6), "slurm_gpus": Limit(0, 1024)}

    def __post_init__(self) -> None:
        check_fields(self)  # every field of the subclass too (MapConfig, RealConfig), with its own LIMITS
        if self.launcher not in ("local", "slurm", "submitit-local"):
            raise ConfigError(f"launcher must be local, slurm or submitit-local, got {self.launcher!r}")

def launch(c: LaunchOptions, jobs: list[dict], fn: Callable[[dict], dict], name: str = "pokeworld-map") -> list[dict]:
    """Execute jobs locally (process pool) or through submitit; returns their result dicts.

    ``fn`` is the top-level, picklable job function (the map's :func:`~.stages.execute`; ``pokeworld real``
    passes its own), ``name`` the SLURM job name. ``c`` needs ``launcher``, ``workers``, ``out`` and the
    ``slurm_*`` fields.
    """
    if not jobs:
        return []
    # the workers train out of sight: their metrics, read here every 30 s, say how far each run is
    with heartbeat("map", training_status(jobs)):
        return _execute(c, jobs, fn, name)


def training_status(jobs: list[dict]):
    """A callable giving the training progress of the jobs' runs (:func:`pokeworld.progress.runs_progress`)."""
    from ..train import make_config

    runs = {}
    for j in jobs:
        tr = j.get("train", {})
        if "out" in tr:
            steps = tr.get("steps") or make_config(j.get("train_preset", "cpu")).steps
            runs[j.get("name", Path(tr["out"]).name)] = (Path(tr["out"]), int(steps))
    def status() -> str:
        if not runs:
            return f"{len(jobs)} jobs running"
        report(TRAINING_STAGE, runs_fraction(runs))  # the whole job's estimate follows the runs' own rate
        return runs_progress(runs)

    return status


def _execute(c: LaunchOptions, jobs: list[dict], fn: Callable[[dict], dict], name: str) -> list[dict]:
    if c.launcher == "local":
        workers = c.workers or default_workers(len(jobs))
        if workers == 1:
            return [fn(j) for j in jobs]
        ctx = __import__("multiprocessing").get_context("spawn")
        with cf.ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
            return list(pool.map(fn, jobs))
    import submitit

    folder = Path(c.out) / "submitit"
    if c.launcher == "slurm":
        ex = submitit.AutoExecutor(folder=folder, cluster="slurm")
        params: dict[str, Any] = {"timeout_min": c.slurm_timeout_min, "gpus_per_node": c.slurm_gpus,
                                  "cpus_per_task": 8, "name": name}
        if c.slurm_partition:
            params["slurm_partition"] = c.slurm_partition
        ex.update_parameters(**params)
    else:
        ex = submitit.AutoExecutor(folder=folder, cluster="local")
        ex.update_parameters(timeout_min=c.slurm_timeout_min)
    handles = ex.map_array(fn, jobs)
    print(f"[map] submitted {len(handles)} jobs to {c.launcher}: {[h.job_id for h in handles][:4]}...")
    return [h.result() for h in handles]

def cores() -> int:
    """CPU cores this process may use."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)

def default_workers(n_jobs: int) -> int:
    """One run per core on CPU (small models scale badly across threads); one per GPU otherwise."""
    import torch

    if torch.cuda.is_available():
        return 1
    return max(1, min(n_jobs, cores()))


__all__ = ["LaunchOptions", "TRAINING_STAGE", "launch", "cores", "default_workers"]
