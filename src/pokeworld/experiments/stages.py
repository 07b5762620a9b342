"""The map's stages: corpora, certificates, the jobs that train and measure each run, stacked training on a GPU,
progress and the pack of small results that travels back from a lent machine."""

from __future__ import annotations

import os
import tarfile
from pathlib import Path
from typing import Any

from .. import certify, clock, train
from ..config import to_dict
from ..data import read_manifest
from ..errors import PokeworldError
from ..evaluate import measure
from ..evaluate.coordinate import build_flow_corpus, build_flow_velocity_corpus
from ..io import atomic_path, read_json, write_json
from ..models import flow
from ..progress import HEARTBEAT_S, duration
from ..rundir import last_logged_step
from ..sim import generate
from ..train import stacked as train_stacked
from ..train.loop import past, status_every
from .attributes import CORPUS_TARGETS
from .config import MapConfig
from .launch import TRAINING_STAGE, cores, default_workers
from .registry import EXPERIMENTS
from .runs import RunSpec, corpus_dir, run_dir, spec_measure_path, with_map_training

CERTIFICATES = "a certificate record (certificates.json)"


def experiment_specs(c: MapConfig, exp: str) -> list[RunSpec]:
    """The runs of experiment ``exp`` under ``c`` (its own specs with the map-wide training choices)."""
    return [with_map_training(c, s) for s in EXPERIMENTS[exp](c)]

def all_specs(c: MapConfig) -> list[RunSpec]:
    """Every run of the map's experiments, once (a run shared by two experiments trains once)."""
    seen: dict[str, RunSpec] = {}
    for exp in c.experiments:
        for spec in experiment_specs(c, exp):
            seen.setdefault(spec.name, spec)  # a run shared by two experiments trains once
    return list(seen.values())

def spec_experiments(c: MapConfig) -> dict[str, list[str]]:
    """experiment -> run names (including runs shared with other experiments)."""
    return {exp: [s.name for s in experiment_specs(c, exp)] for exp in c.experiments}

def corpus_config(c: MapConfig, corpus: str) -> generate.GenerateConfig:
    """The generator config of the map's corpus ``corpus`` (not the derived flow corpus)."""
    overrides: dict[str, Any] = {"out": str(corpus_dir(c, corpus)), "corpus": corpus, "seed": c.data_seed}
    if c.num_episodes:
        overrides["num_episodes"] = c.num_episodes
    if c.split_fractions:
        overrides["split_fractions"] = tuple(c.split_fractions)
    overrides["environment"] = c.environment
    if c.contact_damping:  # empty: the environment's own law
        overrides["physics"] = {"contact_damping": c.contact_damping}
    return generate.make_config(c.preset, **overrides)

def ensure_corpus(c: MapConfig, corpus: str) -> Path:
    """Generate corpus ``corpus`` into the map folder (skipped when it is there and current)."""
    if corpus == "flow":  # derived from the standard corpus by the frozen flow sensor
        return build_flow_corpus(ensure_corpus(c, "standard"), corpus_dir(c, "flow"), flow.make_config(c.preset))
    if corpus == "flow_velocity":  # the flow corpus without its log-speed channel
        return build_flow_velocity_corpus(ensure_corpus(c, "flow"), corpus_dir(c, corpus))

    try:
        return generate.run(corpus_config(c, corpus))
    except PokeworldError as e:
        if "--overwrite" not in str(e):
            raise
        # generate's remedy names its own --overwrite, which map and demo do not have
        raise type(e)(f"{corpus_dir(c, corpus)} holds a corpus this map cannot use ({str(e).split(';')[0]}); give "
                      "this map another --out, or move that corpus folder away to have it generated again") from None

GATED = ("log_m", "gamma", "log_k")

def with_standard_gate(std: dict, own: dict) -> dict:
    """``own`` certificates (a derived or attribute corpus, certified for its new targets only) completed with
    the standard corpus's estimators for the gated parameters; the gate is then the standard's, and
    ``gate_from`` says so (reports state it once, on the standard corpus)."""
    est: dict = {}
    for source in (std.get("estimators", {}), own.get("estimators", {})):
        for e, kinds in source.items():
            for kind, r2 in kinds.items():
                est.setdefault(e, {}).setdefault(kind, {}).update(r2)
    targets = tuple(dict.fromkeys(GATED + tuple(own.get("config", {}).get("targets", ()))))
    cert = certify.certificate_table(est, targets)
    return {**own, "estimators": est, "certificate": cert, "gate": certify.gate(cert, est), "gate_from": "standard",
            "counts": {**std.get("counts", {}), **{f"{k} ({'/'.join(own['config']['targets'])})": v
                                                   for k, v in own.get("counts", {}).items()}}}

def ensure_certificates(c: MapConfig, corpus: str) -> dict:
    """Certificates of ``corpus`` (``certify.run``, skipped when up to date).

    The flow corpus certifies its log-speed channel, an attribute corpus (bias, gain) its attribute: their
    other parameters have the standard corpus's distributions and (flow) episodes, so their gated-parameter
    certificates and gate are the standard corpus's (:func:`with_standard_gate`). One recurrent fit per target
    costs ~20 CPU-minutes on a 2-core machine; not repeating the standard targets on four more corpora saves
    about four CPU-hours of the `cpu` preset.
    """
    cost = {k: v for k, v in (("max_windows", c.certify_max_windows), ("epochs", c.certify_epochs)) if v}
    if c.certify_fit_episodes >= 0:
        cost["fit_episodes"] = c.certify_fit_episodes
    cost["separate_targets"] = c.certify_separate_targets
    if corpus == "flow_velocity":  # the standard episodes, no channel a certificate reads: the standard's
        return {**ensure_certificates(c, "standard"), "gate_from": "standard"}
    if corpus == "flow":
        # the state-based estimators do not read the appended channels: only the log-speed certificate is new
        path = certify.run(certify.make_config(c.preset, data=str(corpus_dir(c, corpus)), targets=("gamma",),
                                               estimators=("linear_logspeed",), kinds=c.certify_kinds))
        manifest = read_manifest(corpus_dir(c, corpus))
        return {**with_standard_gate(ensure_certificates(c, "standard"), read_json(path, CERTIFICATES)),
                "flow_sensor": manifest.get("flow", {}).get("sensor", {})}
    if corpus in CORPUS_TARGETS:
        path = certify.run(certify.make_config(c.preset, data=str(corpus_dir(c, corpus)),
                                               targets=CORPUS_TARGETS[corpus],
                                               estimators=c.certify_estimators, kinds=c.certify_kinds, **cost))
        return with_standard_gate(ensure_certificates(c, "standard"), read_json(path, CERTIFICATES))
    path = certify.run(certify.make_config(c.preset, data=str(corpus_dir(c, corpus)), targets=GATED,
                                           estimators=c.certify_estimators, kinds=c.certify_kinds, **cost))
    return read_json(path, CERTIFICATES)

def certify_corpora(c: MapConfig, corpora: list[str], threads: int = 0) -> dict[str, dict]:
    """:func:`ensure_certificates` of each corpus in order, on ``threads`` CPU threads (0: torch's default); top-level
    because ``certify_alongside`` runs it in a spawned process."""
    if threads:
        import torch

        torch.set_num_threads(threads)
    return {corpus: ensure_certificates(c, corpus) for corpus in corpora}

def execute(job: dict) -> dict:
    """Train (resume / skip) and measure one run. Top-level and picklable for process pools and submitit.

    Returns ``{"name", "status"}`` with status ``finished`` (trained and measured; also ``measure``:
    the path), ``partial`` (stopped at ``job["deadline"]``, or trained but not yet measured) or
    ``pending`` (the deadline had passed before it started).
    """
    import torch

    deadline = job.get("deadline", 0.0)
    if past(deadline):
        return {"name": job["name"], "status": "pending"}
    if job.get("threads"):
        torch.set_num_threads(job["threads"])
    tcfg = job_train_config(job)
    done = train.run(tcfg, status_every=status_every())
    if not (done / "DONE").exists() or past(deadline):
        return {"name": job["name"], "status": "partial"}
    # the thread count training sets (CPU reductions round by it): a run measured in a later invocation, whose
    # training was skipped, then reads the same numbers as one measured right after training
    torch.set_num_threads(tcfg.threads or train.auto_threads())
    mcfg = measure.make_config(job["preset"], run_dir=job["train"]["out"], data=job["measure_data"],
                               mlp=job["mlp"], untrained=job["untrained"], **job.get("measure", {}))
    path = measure.run(mcfg)
    return {"name": job["name"], "status": "finished", "measure": str(path)}

def job_train_config(job: dict):
    """The TrainConfig a map job trains (with its deadline): the same for a separate and a stacked run."""
    return train.make_config(job["train_preset"], **job["train"], deadline=job.get("deadline", 0.0))

def train_stacked_jobs(c: MapConfig, jobs: list[dict]) -> None:
    """``stack``: train every unfinished job that can stack with :func:`pokeworld.train.stacked.run` (grouped by
    what fixes the step's shapes; members resume together from a common checkpoint step), before :func:`launch`
    measures them (and trains alone the jobs that cannot stack). Stops at the jobs' deadline like ``train.run``."""
    cfgs = [job_train_config(j) for j in jobs]
    todo = [cfg for cfg in cfgs if train_stacked.stackable(cfg) and not (Path(cfg.out) / "DONE").exists()]
    if not todo:
        return
    groups = train_stacked.plan_groups(todo, mix_variants=True, max_members=c.stack_max_members)
    print(f"[map] training {len(todo)} runs as {len(groups)} stacked group(s) of {[len(g) for g in groups]} members")
    train_stacked.run(todo, mix_variants=True, max_members=c.stack_max_members)

def jobs(c: MapConfig, specs: list[RunSpec], threads: int, deadline: float = 0.0) -> list[dict]:
    """One picklable job per run: its TrainConfig overrides and how to measure it."""
    out = []
    for s in specs:
        tr = dict(s.train, data=str(corpus_dir(c, s.corpus)), out=str(run_dir(c, s.name)),
                  progress=False)
        if c.train_steps:
            tr["steps"] = c.train_steps
        if c.train_batch_size and "batch_size" not in s.train:
            tr["batch_size"] = c.train_batch_size
        if threads:
            tr["threads"] = threads
        measure_data = str(corpus_dir(c, s.measure_corpus)) if s.measure_corpus != s.corpus else ""
        measure = ({"kinds": tuple(c.measure_kinds)} if c.measure_kinds else {}) | (
            {"max_windows": c.measure_max_windows} if c.measure_max_windows else {}) | (
            {"device": "cpu", "probe_device": "host"} if c.measure_device == "cpu" else {}) | dict(s.measure)
        out.append({"name": s.name, "preset": c.preset, "train_preset": c.train_preset or c.preset, "train": tr,
                     "measure_data": measure_data,
                     "mlp": c.mlp_probes, "untrained": c.untrained, "threads": threads, "deadline": deadline,
                     "measure": measure})
    return out

def write_progress(c: MapConfig, specs: list[RunSpec], started: float) -> dict:
    """``progress.json``, read off the run directories (so earlier invocations' work counts): runs
    ``finished`` (trained and measured), ``partial`` (name -> last logged step: stopped at a deadline,
    or trained but not measured yet) and ``pending`` (not started)."""
    prog: dict[str, Any] = {"finished": [], "partial": {}, "pending": []}
    for s in specs:
        rd = run_dir(c, s.name)
        if (rd / "DONE").exists() and spec_measure_path(c, s).exists():
            prog["finished"].append(s.name)
        elif (rd / "ckpt.pt").exists() or (rd / "DONE").exists():
            prog["partial"][s.name] = last_logged_step(rd)
        else:
            prog["pending"].append(s.name)
    prog["complete"] = len(prog["finished"]) == len(specs)
    prog["elapsed_min"] = (clock.wall_clock() - started) / 60
    prog["time_budget_min"] = c.time_budget_min
    write_json(Path(c.out) / "progress.json", prog)
    return prog

#: Files ``pack`` takes, as globs relative to the map directory (all small: JSON, markdown, figures). A GPU
#: allocation (:mod:`pokeworld.remote.run`) adds three: device.json (where its map ran), returned.json (the index of the
#: weights and checkpoints it brings back beside the pack) and a resumed run's resumed.json (from which allocation's
#: checkpoint, at which step).
PACK_GLOBS = ("map_config.json", "progress.json", "device.json", "returned.json", "results.json", "results.md",
              "identifiability_map.png", "identifiability_map.pdf", "planning/planning.json",
              "planning/plan_episode.png", "data/*/certificates.json", "data/*/manifest.json",
              "runs/*/config.json", "runs/*/metrics.jsonl", "runs/*/measure*.json", "runs/*/resumed.json")

def pack_results(c: MapConfig, dest: str | os.PathLike, quiet: bool = False) -> Path:
    """Tar+gzip the small result files of ``c.out`` (:data:`PACK_GLOBS`) into ``dest``; returns it. ``quiet``: no
    line printed (an allocation re-packs after every run and while one trains, and says so itself)."""
    out, dest = Path(c.out), Path(dest)
    dest.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(dest) as tmp, tarfile.open(tmp, "w:gz") as tar:  # no half-written pack under its name
        for pattern in PACK_GLOBS:
            for path in sorted(out.glob(pattern)):
                tar.add(path, arcname=str(path.relative_to(out)))
    size = dest.stat().st_size
    # the device machine returns files of at most 16 MiB each
    if not quiet or size > 16 * 2 ** 20:
        print(f"[map] packed results into {dest} ({size / 2 ** 20:.2f} MiB)"
              + (" — over 16 MiB, too large to come back from the device" if size > 16 * 2 ** 20 else ""))
    return dest


__all__ = ["experiment_specs", "all_specs", "spec_experiments", "corpus_config", "ensure_corpus", "GATED",
           "with_standard_gate", "ensure_certificates", "certify_corpora", "execute", "job_train_config",
           "train_stacked_jobs", "jobs", "write_progress", "PACK_GLOBS", "pack_results", "plan_line", "timed_training",
           "training_estimate", "whole_job_costs", "relative_speed", "whole_job_line", "corpus_stage", "TRAINING_STAGE",
           "REPORT_STAGE"]


def plan_line(c: MapConfig) -> str:
    """What this map will do, said before it starts: corpora, certificates, runs and their steps, workers."""
    specs = all_specs(c)
    corpora = sorted({s.corpus for s in specs} | {s.measure_corpus for s in specs} | {"standard"})
    steps = c.train_steps or train.make_config(c.train_preset or c.preset).steps
    workers = c.workers or default_workers(len(specs))
    certs = (f"certificates ({', '.join(c.certify_estimators)}) for {len(corpora)} corpora" if c.certify
             else "no certificates")
    return (f"[map] plan: {len(corpora)} corpora ({', '.join(corpora)}; generated or reused) -> {certs} -> "
            f"{len(specs)} runs x {steps} steps on {workers} worker(s) -> probes -> report; progress every "
            f"{int(HEARTBEAT_S)} s (--quiet silences it)")


def timed_training(c: MapConfig, specs: list[RunSpec], workers: int, threads: int) -> dict | None:
    """The runs still to train, timed on this machine now: two steps of each distinct model
    (:func:`pokeworld.train.speed.seconds_per_step`); ``seconds`` is their training time on ``workers``. None on a
    GPU (its speed is not the CPU's) or when every run is trained already."""
    from ..train.speed import seconds_per_step

    todo = [s for s in specs if not (run_dir(c, s.name) / "DONE").exists()]
    if not todo:
        return None
    steps = {"steps": c.train_steps} if c.train_steps else {}
    cfgs = [train.make_config(c.train_preset or c.preset, **{**s.train, **steps}) for s in todo]
    if train.resolve_device(cfgs[0]).type != "cpu":
        return None
    threads = threads or max(1, cores() // workers)

    def key(cfg) -> str:  # one timing per distinct model (the seed does not change a step's cost)
        return repr({k: v for k, v in to_dict(cfg).items() if k not in ("seed", "out", "data")})

    timed: dict[str, float] = {}
    for cfg in cfgs:
        if key(cfg) not in timed:
            timed[key(cfg)] = seconds_per_step(cfg, threads, steps=2)
    total = sum(timed[key(cfg)] * cfg.steps for cfg in cfgs) / min(workers, len(cfgs))
    return {"seconds": total, "rates": sorted(set(timed.values())), "runs": len(todo), "threads": threads,
            "workers": workers}


def training_estimate(c: MapConfig, specs: list[RunSpec], workers: int, threads: int) -> str | None:
    """The time the runs still to train will take on this machine (:func:`timed_training`), as a line; None on a
    GPU or when every run is trained already."""
    t = timed_training(c, specs, workers, threads)
    if t is None:
        return None
    rates = ", ".join(f"{s:.2f}" for s in t["rates"])
    return (f"[map] this machine: {rates} s/step per model on {t['threads']} thread(s) (timed now): the {t['runs']} "
            f"runs to train take about {duration(t['seconds'])} on {workers} worker(s), certificates and measurement "
            "on top")


REPORT_STAGE = "report"


def corpus_stage(corpus: str) -> str:
    return f"corpus {corpus}"


def whole_job_costs(c: MapConfig, corpora: list[str], certify_order: list[str], t: dict) -> tuple[dict, float]:
    """Each stage of the job -> its predicted seconds on this machine, in order, and the slowdown they were scaled
    by: the demo's reference costs (:data:`.presets.DEMO_STAGE_SECONDS`) times this machine's timed step over the
    reference step (``t``: :func:`timed_training`), the training itself as timed, measurement inside it. These are
    the predictions until a stage runs: a certificate fit and the training then report their own progress, and
    the estimate follows their measured rate (:class:`pokeworld.progress.JobEstimate`)."""
    from .presets import DEMO_REFERENCE_S_PER_STEP, DEMO_STAGE_SECONDS as REF

    slow = max(t["rates"]) / DEMO_REFERENCE_S_PER_STEP
    costs = {corpus_stage(k): REF["corpus"] * slow for k in corpora}
    for corpus in certify_order:
        for kind in c.certify_kinds:
            for est in c.certify_estimators:
                name = certify.certify_stage(str(corpus_dir(c, corpus)), kind, est)
                costs[name] = REF.get(f"certificate {est}", REF["certificate"]) * slow
    rounds = -(-t["runs"] // t["workers"])  # runs measured side by side, like they train
    costs[TRAINING_STAGE] = t["seconds"] + REF["measure per run"] * rounds * slow
    costs[REPORT_STAGE] = REF["report"] * slow
    return costs, slow


def relative_speed(slow: float) -> str:
    """``2.6× slower than the reference machine`` for a step that takes 2.6 times the reference's (``1.5× faster``
    below 1, ``as fast as`` within 5 %)."""
    if slow >= 1.05:
        return f"{slow:.1f}× slower than the reference machine"
    if slow <= 1 / 1.05:
        return f"{1 / slow:.1f}× faster than the reference machine"
    return "as fast as the reference machine"


def whole_job_line(job, t: dict, slow: float) -> str:
    """The estimate said at the start: the timing behind it and each stage's share."""
    groups: dict[str, float] = {}
    for name, cost in job.costs.items():
        group = name.split(" ")[0] if not name.startswith(TRAINING_STAGE) else TRAINING_STAGE
        groups[group] = groups.get(group, 0.0) + cost
    shares = ", ".join(f"{g} {duration(v)}" for g, v in groups.items())
    rates = ", ".join(f"{s:.3f}" for s in t["rates"])
    return (f"[map] this machine, timed now: {rates} s/step per model on {t['threads']} thread(s), "
            f"{relative_speed(slow)}; the whole job takes about {duration(job.initial)} ({shares}), kept current "
            "from each stage's own rate as it runs (certificate epochs, training steps)")
