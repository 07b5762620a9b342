"""One GPU allocation's training, as ``scripts/gpu_allocation.sh`` runs it after its smoke check: the runs of a
queue one at a time in one ``pokeworld map`` (:class:`pokeworld.experiments.map.RunHooks`), each started only when
its predicted time fits what is left, each packed for the trip back as soon as it is measured and while it trains
(:mod:`.pack`), checkpoints that earlier allocations returned resumed first.

* The queue: run tokens ``VARIANT`` or ``VARIANT@SEED`` (``VFX``, ``VF@1``) for the factorial, the map's run name
  for any other experiment's run (:func:`.queue.paper_queue`), in priority order (default
  :data:`PRIORITY`). A run of another experiment is measured completely where it trains (MLP probes and the
  untrained bound too), so its record needs no weights afterwards. Runs an earlier allocation given with ``--resume`` finished are dropped, runs with a checkpoint
  (returned by an earlier allocation, or left in the work folder) move to the front (:func:`order_queue`);
  ``python scripts/merge_allocations.py --plan`` prints the same order from what earlier allocations returned.
* The time: a run starts (or resumes) only when ``overhead + steps left × s/step`` fits the time left before the
  budget's reserve (:class:`Pace`): the s/step and overhead (compilation, measurement) this allocation measured on
  its last finished run, or the preset's prior (:data:`PRIORS`) before one finished. A run the prediction lets in
  but the budget still cuts stops at the map's deadline with a checkpoint, which comes back.
* Resuming: a returned checkpoint is restored into the work folder's run (its config.json pointed at this
  machine's corpus and folder, its metrics, ``resumed.json`` naming where and at which step it came from); training
  refuses it if this machine's corpus has other content. Allocations with other map settings are not resumed from.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import tempfile
from dataclasses import dataclass
from pathlib import Path

from .. import clock
from ..config import to_dict
from ..errors import ConfigError, PokeworldError
from ..io import read_regular_bytes, save_bytes, write_json
from ..rundir import last_logged_step, load_resume_checkpoint, read_metrics
from ..models.xjepa import VARIANTS
from ..experiments import stages
from ..experiments.config import VARIANT_ORDER, MapConfig
from ..experiments.launch import cores
from ..experiments.map import RunHooks, run as run_map
from ..experiments.presets import make_config
from ..experiments.registry import EXPERIMENTS
from ..experiments.runs import RunSpec, run_dir
from . import allocations
from .pack import Packer, ReturnLimits, Snapshots
from .queue import PRIORITY, catalog, factorial_key, order_queue, parse_token, split_folder_list, token_of
from .share import SharedRuns, ShareConfig

#: preset -> (s/step, overhead s) a run is predicted with until this allocation has timed one. paper: the aligned
#: configuration's VFX (the queue's first run, and its slowest variant) as the H200 lease of 2026-11-28 timed it,
#: 0.0081 s/step with CUDA graphs and 56 s of compilation and measurement (V 0.0062 / 40 s, VF 0.0066 / 45 s;
#: docs/model.md "GPU allocations"), rounded up. tiny and cpu: this repository's CPUs.
PRIORS = {"paper": (0.0081, 60.0), "cpu": (0.3, 60.0), "tiny": (0.05, 10.0)}


@dataclass
class Pace:
    """The time a run is predicted to take: ``overhead_s + steps × s_per_step``."""

    s_per_step: float
    overhead_s: float
    source: str = "prior"

    def predict(self, steps: int) -> float:
        return self.overhead_s + steps * self.s_per_step

    def learn(self, run: Path, from_step: int, wall_s: float) -> None:
        """Take the s/step of the rows ``run`` logged past ``from_step`` (the first left out: it holds the
        compilation) and the rest of ``wall_s`` as the overhead."""
        rows = [r for r in read_metrics(run) if r["step"] > from_step and r.get("steps_per_s", 0) > 0][1:]
        steps = last_logged_step(run) - from_step
        if rows:
            self.s_per_step = statistics.median(1 / r["steps_per_s"] for r in rows)
        elif steps > 0:
            self.s_per_step = wall_s / steps
        self.overhead_s = max(0.0, wall_s - steps * self.s_per_step)
        self.source = "measured"


def checkpoint_step(run: Path) -> int:
    """The step an unfinished run resumes from: its ckpt.pt's (0 without one)."""
    if not (run / "ckpt.pt").exists():
        return 0
    return load_resume_checkpoint(run / "ckpt.pt")["step"]  # an integer ≥ 0, or one CheckpointError line


class AllocationHooks(RunHooks):
    """The map's runs in queue order, each admitted when it fits the time left, snapshotted while it trains and
    packed once measured; with ``share.most`` > 1 several at once (:mod:`.share`)."""

    def __init__(self, queue: list[str], packer: Packer, deadline: float, pace: Pace, snapshot_s: float,
                 share: ShareConfig = ShareConfig(most=1), complete: set[str] | frozenset[str] = frozenset()):
        self.queue, self.packer, self.deadline, self.pace, self.snapshot_s = queue, packer, deadline, pace, snapshot_s
        self.share, self.complete = share, complete

    def order(self, jobs: list[dict]) -> list[dict]:
        """The queue's jobs in its order; those in ``complete`` measured with MLP probes and the untrained bound."""
        by_name = {j["name"]: j for j in jobs}
        return [{**by_name[n], "mlp": True, "untrained": True} if n in self.complete else by_name[n]
                for n in self.queue if n in by_name]

    def run_all(self, c: MapConfig, jobs: list[dict], specs: list, started: float) -> None:
        if self.share.most <= 1:
            return super().run_all(c, jobs, specs, started)
        def finished(job: dict, result: dict, training: frozenset[str]) -> None:
            facts = {"wall_s": result.get("wall_s"), "status": result.get("status")}
            if result.get("error"):
                facts["error"] = result["error"]
            self.packer.facts[job["name"]] = facts
            self.packer.share = shared.record()
            self.packer.pack(training=training)

        # each run in a process of its own, the machine's cores shared among the most that may run at once (more
        # threads than cores stall every run: on 2 cores two tiny runs of 2 threads each ran 30x slower in all)
        threads = max(1, cores() // self.share.most)
        ordered = [{**j, "threads": threads, "train": {**j["train"], "threads": threads}} for j in self.order(jobs)]
        shared = SharedRuns(self.share, self.deadline, self.pace.overhead_s, self.pace.s_per_step,
                            lambda j: checkpoint_step(Path(j["train"]["out"])), finished)
        shared.run(ordered)
        self.packer.share = shared.record()
        print(f"[allocation] shared the GPU: {shared.record()}", flush=True)

    def execute(self, job: dict) -> dict:
        name, run = job["name"], Path(job["train"]["out"])
        if (run / "DONE").exists():  # trained by an earlier invocation in this work folder: measured, if not yet
            return stages.execute(job)
        done = checkpoint_step(run)
        steps = stages.job_train_config(job).steps
        need, left = self.pace.predict(steps - done), self.deadline - clock.wall_clock()
        if need > left:
            print(f"[allocation] {name}: not started, {steps - done} steps predicted to take {need:.0f} s "
                  f"({self.pace.source} pace) but {max(left, 0):.0f} s are left", flush=True)
            return {"name": name, "status": "pending"}
        print(f"[allocation] {name}: {'resuming at step ' + str(done) if done else 'starting'}, {steps - done} steps "
              f"predicted {need:.0f} s ({self.pace.source} pace), {left:.0f} s left", flush=True)
        t0 = clock.wall_clock()
        with Snapshots(self.packer, name, self.snapshot_s):
            result = stages.execute(job)
        wall = clock.wall_clock() - t0
        if result["status"] == "finished":
            self.pace.learn(run, done, wall)
            self.packer.facts[name] = {"wall_s": round(wall, 1), "from_step": done,
                                       "sec_per_step": self.pace.s_per_step, "overhead_s": self.pace.overhead_s}
        return result

    def measured(self, job: dict, result: dict, prog: dict) -> None:
        if result["status"] != "pending":
            self.packer.pack()


# ---------------------------------------------------------------------- resuming earlier allocations


def restore(c: MapConfig, specs: dict[str, RunSpec], folders: list[Path], scratch: Path) -> set[str]:
    """Read the allocations returned in ``folders``: restore each checkpoint they hold (the furthest one of a run)
    into the run's folder under ``c.out`` unless that run already has one; returns the runs they finished."""
    finished: set[str] = set()
    best: dict[str, tuple[int, allocations.Allocation]] = {}
    by_name = {s.name: s for s in specs.values()}
    for a in allocations.open_allocations(folders, scratch):
        folder = a.source
        mine = to_dict(c)  # tuples as the JSON lists map_config.json holds
        differ = [k for k in allocations.AGREE if a.map_config.get(k) != mine.get(k)]
        if differ:
            print(f"[allocation] {folder}: not resumed from, it ran the map with other settings ({differ})")
            continue
        finished |= {token_of(by_name[n]) for n in a.progress.get("finished", []) if n in by_name}
        for name, step in a.checkpoints.items():
            if name in by_name and step > best.get(name, (-1, None))[0]:
                best[name] = (step, a)
    for name, (step, a) in best.items():
        if token_of(by_name[name]) not in finished:
            restore_run(c, by_name[name], a, step)
    return finished


def restore_run(c: MapConfig, spec: RunSpec, a: allocations.Allocation, step: int) -> None:
    """Put allocation ``a``'s checkpoint of ``spec`` (step ``step``) into this map's run folder, with its config
    (pointed at this machine's corpus and folder), its metrics and resumed.json; a run folder that already holds a
    checkpoint or a finished run is left as it is."""
    dest, src = run_dir(c, spec.name), a.root / "runs" / spec.name
    if (dest / "ckpt.pt").exists() or (dest / "DONE").exists():
        print(f"[allocation] {spec.name}: its folder already holds a checkpoint; not restored from {a.source}")
        return
    job = stages.jobs(c, [spec], 0)[0]
    cfg = {**allocations.read_json(src / "config.json", "a returned run's config.json"), "data": job["train"]["data"],
           "out": job["train"]["out"]}
    dest.mkdir(parents=True, exist_ok=True)
    write_json(dest / "config.json", cfg)
    # the parts are written before the records, so a kill between the two returns a checkpoint whose metrics the
    # records do not hold yet: the run resumes all the same, its earlier rows missing (said in resumed.json)
    names = ("metrics.jsonl", "ckpt.pt") if (src / "metrics.jsonl").exists() else ("ckpt.pt",)
    for name in names:
        data = read_regular_bytes(src / name, f"a returned run's {name}", 1 << 30)
        save_bytes(dest / name, data)
    write_json(dest / "resumed.json", {"step": step, "from": a.source, "device": a.device.get("device"),
                                       "metrics_before_resume": "returned" if len(names) == 2 else "not returned",
                                       "date": a.device.get("date"), "git": a.device.get("git"),
                                       "checkpoint": "returned compacted: float32 tensors of at least 4096 elements "
                                                     "(weights and AdamW moments) rounded to bfloat16"})
    print(f"[allocation] {spec.name}: restored the checkpoint at step {step} from {a.source}", flush=True)


# ---------------------------------------------------------------------- the allocation


def allocation_config(a: argparse.Namespace, requested: list[str]) -> MapConfig:
    """The map that trains ``requested`` (queue tokens): the experiments and seeds they belong to (a run of the
    factorial alone keeps the map to its variants, so its progress names only the queue's runs); ConfigError for a
    token that is none of the map's runs at this preset."""
    seeds = {0, 1, 2} | {k[1] for t in requested if (k := factorial_key(t))}
    known = catalog(a.preset, tuple(seeds))
    unknown = [t for t in requested if t not in known]
    if unknown:
        raise ConfigError(f"{unknown[:3]} are not runs of the map at preset {a.preset!r} (VARIANT@SEED, or a run "
                          "name that merge_allocations.py --plan prints)")
    exps = [e for e in EXPERIMENTS if any(known[t].experiment == e for t in requested)]
    only_factorial = exps == ["factorial"]
    base = dict(out=str(a.work / "map"), experiments=tuple(exps), certify=False, mlp_probes=False,
                untrained=False, workers=1, train_steps=a.steps, measure_device=a.measure_device,
                seeds=tuple(sorted({known[t].seed for t in requested})))
    # the factorial alone: its queued variants; with other experiments, every variant (their runs are the map's
    # for the whole factorial, as the catalog's are)
    base["variants"] = (tuple(dict.fromkeys(known[t].train["variant"] for t in requested)) if only_factorial
                        else tuple(v for v in VARIANT_ORDER if v in VARIANTS))
    c = make_config(a.preset, **base)
    missing = sorted(set(requested) - {token_of(s) for s in stages.all_specs(c)})
    if missing:
        raise ConfigError(f"{missing[:3]} are not among the runs of the map this allocation builds; name them "
                          "as merge_allocations.py --plan prints them")
    return c


def allocate(a: argparse.Namespace) -> int:
    """Restore, plan, train and pack one allocation (see the module docstring); returns the exit status."""
    started = a.started or clock.wall_clock()
    deadline = started + 60 * a.budget_min - 60 * a.reserve_min
    requested = list(dict.fromkeys(parse_token(t) for t in a.runs))
    c = allocation_config(a, requested)
    specs = {token_of(s): s for s in stages.all_specs(c)}
    with tempfile.TemporaryDirectory(prefix="pokeworld-resume-") as scratch:
        finished = restore(c, specs, a.resume, Path(scratch))
    resumable = {k for k, s in specs.items() if (run_dir(c, s.name) / "ckpt.pt").exists()
                 and not (run_dir(c, s.name) / "DONE").exists()}
    queue = order_queue(requested, finished, resumable)
    print(f"[allocation] queue: {' '.join(queue) or 'nothing'}"
          + (f" (finished earlier: {' '.join(sorted(finished))})" if finished else ""), flush=True)
    left_min = (deadline - clock.wall_clock()) / 60
    if queue and all(factorial_key(t) for t in queue):  # the map's progress then names the queue's runs
        c = dataclasses.replace(c, variants=tuple(dict.fromkeys(specs[t].train["variant"] for t in queue)),
                                seeds=tuple(sorted({specs[t].seed for t in queue})))
    limits = ReturnLimits(parts=a.return_parts, **({"part_bytes": a.part_bytes} if a.part_bytes else {}))
    packer = Packer(c, stages.all_specs(c), a.out, clock.wall_clock(), limits)
    packer.pack()  # the device record and any restored checkpoint come back even if nothing else does
    if not queue or left_min <= 0.25:
        print(f"[allocation] {'nothing to train' if not queue else f'only {left_min:.2f} min left'}; no map started")
        return 0 if not queue else 4
    prior = PRIORS.get(a.preset, PRIORS["paper"])
    pace = Pace(a.prior_s_per_step or prior[0], a.prior_overhead_s if a.prior_overhead_s >= 0 else prior[1])
    # runs of experiments other than the factorial are measured completely where they train (MLP probes and the
    # untrained bound too): their records then need no weights on the CPU side
    complete = {specs[t].name for t in queue if specs[t].experiment != "factorial"}
    hooks = AllocationHooks([specs[t].name for t in queue], packer, deadline, pace, a.snapshot_s,
                            ShareConfig(most=a.concurrency), complete)
    run_map(dataclasses.replace(c, time_budget_min=left_min + a.reserve_min, time_reserve_min=a.reserve_min), hooks)
    packer.pack()
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="One GPU allocation's training (scripts/gpu_allocation.sh runs it).")
    ap.add_argument("out", type=Path, help="the folder the device machine returns")
    ap.add_argument("--work", type=Path, required=True, help="the map's working folder (corpus, checkpoints)")
    ap.add_argument("--runs", nargs="*", default=list(PRIORITY),
                    help="VARIANT@SEED (the factorial) or a run name of any experiment (merge_allocations.py --plan "
                         "prints the paper's queue), in priority order")
    ap.add_argument("--preset", default="paper")
    ap.add_argument("--steps", type=int, default=0, help="training steps per run (0: the preset's)")
    ap.add_argument("--budget-min", type=float, default=8.5, help="minutes from --started to the end")
    ap.add_argument("--reserve-min", type=float, default=0.5, help="minutes kept at the end for the last pack")
    ap.add_argument("--started", type=float, default=0.0, help="unix time the allocation started (default: now)")
    ap.add_argument("--resume", nargs="*", type=Path, default=[], help="folders earlier allocations returned")
    ap.add_argument("--resume-list", default="", help="the same as one shell-quoted list (ALLOC_RESUME as "
                                                      "merge_allocations.py --plan prints it)")
    ap.add_argument("--snapshot-s", type=float, default=30.0, help="seconds between checkpoint snapshots")
    ap.add_argument("--prior-s-per-step", type=float, default=0.0, help="s/step before one is measured")
    ap.add_argument("--prior-overhead-s", type=float, default=-1.0, help="seconds per run beside its steps")
    ap.add_argument("--measure-device", choices=("auto", "cpu"), default="auto",
                    help="measure each finished run on its device (auto: the GPU) or on the machine's CPU cores")
    ap.add_argument("--concurrency", type=int, default=1,
                    help="most runs training at once on the GPU (1: one after another; more: a ramp from one "
                         "that goes on while the total steps/s grows, pokeworld.remote.share)")
    ap.add_argument("--return-parts", type=int, default=0,
                    help="parts the weights may take in all when several returns carry them (a lease's commands; "
                         "0: what one return folder holds)")
    ap.add_argument("--part-bytes", type=int, default=0, help=argparse.SUPPRESS)  # tests: small parts
    a = ap.parse_args(argv)
    if not 1 <= a.concurrency <= 64 or not 0 <= a.return_parts <= 64 or a.part_bytes < 0:
        ap.error("--concurrency must be in [1, 64], --return-parts in [0, 64], --part-bytes ≥ 0")
    try:
        a.resume = [*a.resume, *map(Path, split_folder_list(a.resume_list))]
        return allocate(a)
    except PokeworldError as e:
        raise SystemExit(f"error: {e}") from None


__all__ = ["PRIORITY", "PRIORS", "parse_token", "token_of", "order_queue", "allocation_config", "Pace", "checkpoint_step",
           "AllocationHooks", "restore", "restore_run", "allocate", "main"]

if __name__ == "__main__":
    raise SystemExit(main())
