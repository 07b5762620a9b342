"""``pokeworld map`` / ``pokeworld demo``: generate -> certify -> train the runs -> measure -> report, under a lock
on the map folder, resumable and time-sliceable.

Run names are deterministic in their factors and seed, so re-running skips finished runs and resumes
unfinished ones. Runs execute in a local process pool or through submitit (:mod:`.launch`); on a GPU ``stack``
trains the runs that can share a step as stacked ensembles and ``certify_alongside`` computes the certificates
meanwhile. Time-sliced running (``time_budget_min``): every invocation trains until its budget is nearly spent,
checkpoints, writes ``progress.json`` and exits normally; the same command resumes. ``pack`` tars the small
result files for the trip back from a lent machine. A caller may steer the runs one at a time (:class:`RunHooks`):
a GPU allocation (:mod:`pokeworld.remote.run`) orders them, starts one only when it fits the time left and packs each
for the trip back as soon as it is measured.
"""

from __future__ import annotations

import concurrent.futures as cf
import time
from pathlib import Path

from .. import clock, progress
from ..config import to_dict
from ..data import is_complete
from ..errors import PokeworldError
from ..io import adopt_legacy, check_writable_dir, dir_lock, read_json_if_present, remove_stale_temporaries, write_json
from ..train.loop import past
from . import report, stages
from .config import MapConfig
from .factorial import factorial_summary, factorial_table
from .launch import cores, default_workers, launch
from .planning import ensure_planning
from .presets import check_names
from .record import read_record
from .runs import corpus_dir

MAP_LOCK_REFUSAL = ("{path} is in use by another `pokeworld map`: {holder}. Two maps on one --out would overwrite "
                    "each other's results.json; wait for that one to finish and run this command again (its runs "
                    "are merged into the same results.json), or give this one another --out")

def carry_over(previous: dict | None, results: dict) -> dict:
    """``results`` completed with the run records of an earlier ``results.json`` in the same ``out`` that this
    invocation did not measure (each kept under the experiments that listed it, with the certificates of corpora
    only it used and the planning table when this invocation did not plan), so a later invocation with other
    experiments, variants or seeds never drops a finished run's record. Runs measured now replace their earlier
    records; the carried runs and the command that measured them are named in ``provenance["carried_over"]``."""
    if not previous:
        return results
    out = {**results, "experiments": {k: list(v) for k, v in results["experiments"].items()},
           "runs": dict(results["runs"]), "certificates": dict(results["certificates"]),
           "provenance": dict(results["provenance"])}
    carried: list[str] = []
    for exp, names in previous.get("experiments", {}).items():
        now = out["experiments"].setdefault(exp, [])
        extra = [n for n in names if n not in now and n in previous.get("runs", {})]
        now += extra
        for n in extra:
            if n not in out["runs"]:
                out["runs"][n] = previous["runs"][n]
                carried.append(n)
        if not now:
            del out["experiments"][exp]
    if not carried:
        return results
    for corpus, cert in previous.get("certificates", {}).items():
        out["certificates"].setdefault(corpus, cert)
    if "planning" not in out and "planning" in previous:
        out["planning"] = previous["planning"]
    prev = previous.get("provenance", {})
    # a run carried twice keeps the command that measured it, not the one that last carried it
    earlier = [{**e, "runs": [n for n in e["runs"] if n in carried]} for e in prev.get("carried_over", [])]
    already = {n for e in earlier for n in e["runs"]}
    first = {"runs": [n for n in carried if n not in already], "command": prev.get("command", "?"),
             "git": prev.get("git", "?")}
    out["provenance"]["carried_over"] = [e for e in (*earlier, first) if e["runs"]]
    return out

def read_previous_results(path: Path) -> dict | None:
    """The results.json an earlier invocation left in this ``out`` (None when there is none), read when the map
    starts. It is written atomically, so one that is not valid JSON or not shaped like a record pokeworld writes
    (:func:`.record.record_problem`: wrong types, missing keys, NaN where a measured number belongs) was edited or
    damaged: a ConfigError naming it, before any training, rather than a crash in the report after all of it or a
    silent overwrite of someone's file."""
    if not path.exists():
        return None
    return read_record(path, "move it aside (or give this map another --out), then run the same command again")

class RunHooks:
    """What a caller adds to a map that trains its runs one after another, in this process (``pokeworld map``
    passes none and launches its runs as configured). The defaults run every job in the map's order."""

    def order(self, jobs: list[dict]) -> list[dict]:
        """The jobs to run, in the order to run them; a job left out stays pending."""
        return jobs

    def execute(self, job: dict) -> dict:
        """Train and measure one job (:func:`.stages.execute`); a hook may decline it (status 'pending')."""
        return stages.execute(job)

    def measured(self, job: dict, result: dict, prog: dict) -> None:
        """After each job, with the progress.json just written (the job's run finished, partial or pending)."""

    def run_all(self, c: MapConfig, jobs: list[dict], specs: list, started: float) -> None:
        """Run the jobs: by default one at a time (:func:`run_one_by_one`); a GPU allocation may run several at
        once (:mod:`pokeworld.remote.share`)."""
        run_one_by_one(c, jobs, specs, started, self)


def run_one_by_one(c: MapConfig, jobs: list[dict], specs: list, started: float, hooks: RunHooks) -> None:
    """The jobs in ``hooks``' order, one at a time, progress.json written after each so that a hook can pack it."""
    for job in hooks.order(jobs):
        result = hooks.execute(job)
        hooks.measured(job, result, stages.write_progress(c, specs, started))


MAP_FILES = ("results.json", "results.md", "map_config.json", "progress.json", "device.json",
             "identifiability_map.png", "identifiability_map.pdf")
"""The files a map writes at the top of its folder."""


def adopt_legacy_map(out: Path) -> None:
    """A map folder written before ownership records existed (recognised by its map_config.json, a JSON object)
    gets its record, so that re-running the map replaces its own results as it always did."""
    try:
        ok = isinstance(read_json_if_present(out / "map_config.json", "a map's map_config.json"), dict)
    except PokeworldError:
        ok = False
    if ok:
        adopt_legacy(out, MAP_FILES)


def run(c: MapConfig, hooks: RunHooks | None = None) -> Path:
    """Run every stage of the map and write results.json, results.md and the figure into ``c.out``.

    With ``time_budget_min`` the invocation may stop early (progress.json says where); with ``pack``
    the small results are tarred at the end either way; with ``hooks`` the runs train one at a time in this
    process, as the hooks order and admit them (:class:`RunHooks`). The whole invocation holds ``out/.map.lock``: a
    second map on the same ``out`` is refused with a message naming this one (a killed map's lock is released with its
    process), and the experiments of an earlier invocation are carried into results.json (:func:`carry_over`).
    """
    check_names(c)
    progress.quiet(c.quiet)
    out = Path(c.out)
    check_writable_dir(out)
    print(stages.plan_line(c), flush=True)
    with dir_lock(out, ".map.lock", MAP_LOCK_REFUSAL) as stale:
        if stale:
            print(f"[map] the previous holder of {out} ({stale}) is gone; taking over its lock and resuming")
        # temporary copies a killed map left of its top-level files (results, report, figures): only the lock's
        # holder writes these, so none of them is in use
        remove_stale_temporaries(out)
        adopt_legacy_map(out)
        return _run_locked(c, hooks)

def _run_locked(c: MapConfig, hooks: RunHooks | None = None) -> Path:
    """The body of :func:`run`, under the out directory's lock."""
    started = clock.wall_clock()
    # training must stop early enough to leave the reserve for measuring, reporting and packing
    deadline = started + 60 * (c.time_budget_min - c.time_reserve_min) if c.time_budget_min > 0 else 0.0
    out = Path(c.out)
    out.mkdir(parents=True, exist_ok=True)
    # checked now, before any training: the earlier record is only merged in at the very end (carry_over)
    previous = read_previous_results(out / "results.json")
    write_json(out / "map_config.json", to_dict(c))
    specs = stages.all_specs(c)
    corpora = sorted({s.corpus for s in specs} | {s.measure_corpus for s in specs} | {"standard"})
    # flow's certificates build on the standard's; with certify off none are computed (an allocation's record takes
    # them from the CPU side later)
    certify_order = [k for k in sorted(corpora, key=lambda k: k == "flow") if k != "contact_poor"] if c.certify else []
    workers = c.workers or default_workers(len(specs))
    threads = max(1, cores() // workers) if (c.launcher == "local" and workers > 1) else 0
    # a time-sliced or steered invocation spends its budget on the work, not on timing it
    job = whole_job(c, specs, corpora, certify_order, workers, threads) if hooks is None and not deadline else None
    with progress.whole_job(job):
        prepared, certificates, background = prepare(c, corpora, certify_order, deadline, job)
        if prepared:
            print(f"[map] {len(specs)} runs, launcher={c.launcher}, workers={workers}"
                  + (f", training until {c.time_budget_min - c.time_reserve_min:g} min" if deadline else ""))
            jobs = stages.jobs(c, specs, threads, deadline)
            estimate = (stages.training_estimate(c, specs, workers, threads)
                        if hooks is None and not deadline and job is None and not c.whole_job_estimate else None)
            if estimate:
                print(estimate, flush=True)
            with progress.stage(stages.TRAINING_STAGE, "map"):
                if hooks is not None:
                    hooks.run_all(c, jobs, specs, started)
                else:
                    if c.stack:
                        stages.train_stacked_jobs(c, jobs)
                    launch(c, jobs, stages.execute)
        if background is not None:
            with background[0]:
                print("[map] waiting for the background certificates")
                certificates = background[1].result()
        finish(c, specs, certificates, previous, prepared, deadline, started, job)
    if c.pack:
        stages.pack_results(c, c.pack)
    return out


def whole_job(c: MapConfig, specs: list, corpora: list[str], certify_order: list[str], workers: int,
              threads: int) -> progress.JobEstimate | None:
    """The whole job's estimate (``whole_job_estimate``), said at the start: None when off, on a GPU or when every
    run is trained already (what is left is the report)."""
    if not c.whole_job_estimate:
        return None
    wall, cpu = time.monotonic(), time.process_time()
    timed = stages.timed_training(c, specs, workers, threads)
    if timed is None:
        return None
    # the share of a core the timing got: a later stage here that gets less runs on a machine others came to share
    share = progress.Contention.share_between(time.monotonic() - wall, time.process_time() - cpu, timed["threads"])
    costs, slow = stages.whole_job_costs(c, corpora, certify_order, timed)
    job = progress.JobEstimate(costs, contention=progress.Contention(share or 1.0, elsewhere=(stages.TRAINING_STAGE,)))
    job.covers[stages.TRAINING_STAGE] = timed["seconds"] / costs[stages.TRAINING_STAGE]  # training, then measuring
    print(stages.whole_job_line(job, timed, slow), flush=True)
    return job


def prepare(c: MapConfig, corpora: list[str], certify_order: list[str], deadline: float,
            job: progress.JobEstimate | None) -> tuple[bool, dict, tuple | None]:
    """Every corpus, then the certificates (here, or in a background process with ``certify_alongside``): whether
    all is in place for training (False when the deadline came first), the certificates, and the background
    (executor, future) if any. Stages found done already count as done in ``job`` without setting its pace."""
    certificates: dict[str, dict] = {}
    for corpus in corpora:
        if past(deadline):
            return False, certificates, None
        if job is not None and is_complete(corpus_dir(c, corpus)):
            job.skip(stages.corpus_stage(corpus))
        with progress.stage(stages.corpus_stage(corpus), "map"):
            stages.ensure_corpus(c, corpus)
    if c.certify_alongside:
        # certificates are CPU work, training on a GPU leaves the cores idle: one spawned process computes them while
        # the runs train (spawned, not forked, so it inherits no CUDA state)
        ctx = __import__("multiprocessing").get_context("spawn")
        background = cf.ProcessPoolExecutor(max_workers=1, mp_context=ctx)
        # two cores stay with the training process, whose GPU step is bound by its host-side launches
        pending = background.submit(stages.certify_corpora, c, certify_order, max(1, cores() - 2))
        print(f"[map] certifying {certify_order} in a background process while the runs train")
        return True, certificates, (background, pending)
    for corpus in certify_order:
        if past(deadline):
            return False, certificates, None
        certificates[corpus] = stages.ensure_certificates(c, corpus)
    if job is not None:  # certificates found up to date: their stages were never begun
        for name in [n for n in job.costs if n.startswith("certificate ") and n not in job.taken]:
            job.skip(name)
    return True, certificates, None


def finish(c: MapConfig, specs: list, certificates: dict, previous: dict | None, prepared: bool, deadline: float,
           started: float, job: progress.JobEstimate | None) -> None:
    """progress.json, then the report when every run is measured (or why not, and how to resume); the closing line
    gives the job's total time."""
    out = Path(c.out)
    prog = stages.write_progress(c, specs, started)
    planning_late = "planning" in c.experiments and past(deadline)  # planning takes minutes: never start it late
    if prog["complete"] and prepared and not planning_late:
        with progress.stage(stages.REPORT_STAGE, "map"):
            results = report.collect(c, specs, certificates)
            if "planning" in c.experiments:
                results["planning"] = ensure_planning(c)
            results = carry_over(previous, results)  # only this invocation, holding the lock, writes results.json
            write_json(out / "results.json", results)
            report.write_all(c, results)
            table = report.certificate_table(results) + factorial_table(results)
            print("\n".join(table + factorial_summary(results)))
        total = job.total() if job is not None else f"in {progress.duration(clock.wall_clock() - started)}"
        print(f"\n[map] wrote {out / 'results.json'}, {out / 'results.md'} (every table) and the figure "
              f"{out / 'identifiability_map.png'} {total}")
    elif planning_late and prog["complete"] and prepared:
        print("[map] time budget reached before planning: every run is trained and measured; run the same "
              "command again to plan and write the report")
    else:
        print(f"[map] time budget reached: {len(prog['finished'])} runs finished, {len(prog['partial'])} partial "
              f"{prog['partial']}, {len(prog['pending'])} pending; run the same command again to resume "
              f"({out / 'progress.json'})")


__all__ = ["run", "RunHooks", "run_one_by_one", "carry_over", "read_previous_results", "MAP_LOCK_REFUSAL"]
