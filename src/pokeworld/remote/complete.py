"""What a GPU allocation leaves to the CPU side, computed from what it returned: the certificates of the same seeded
corpus, the MLP probes and the untrained bound of each returned run, and planning with the returned runs.

A device allocation trains and measures with ridge probes only (``scripts/gpu_allocation.sh``: its minutes go to
training), so every other number of the paper's tables for those runs is computed here, from the returned weights:

1. the seeded corpus the allocations trained on is generated here (the same map settings, so the same bytes) and
   refused unless its content hash is the allocations' (:func:`ensure_same_corpus`);
2. each finished run with its returned weights is written as a run folder (:func:`.allocations.export_runs`; a
   folder already holding the same weights is kept, so its measurement stays up to date);
3. each is measured at the ``paper`` measurement preset (every window, ridge and MLP probes, the untrained bound,
   the prediction errors and the glide test) by :func:`pokeworld.evaluate.measure.run`, on this machine;
4. the certificates (:func:`pokeworld.certify.run`; the instruments, window cap, fit set and epochs are options,
   recorded, because the paper's full set takes hours on a small CPU);
5. planning with the runs and a random controller (:func:`pokeworld.plan.plan_runs`, the paper's CEM by default;
   ``--plan-episodes`` below the paper's 100 is recorded as such).

Every stage writes its output under ``--work`` and is skipped when its output is up to date, so the command can be
run again after an interruption (or stages and runs split over concurrent invocations); ``cpu_side/`` names this
machine and holds one record per stage: its settings, its UTC date and its wall time, and
``scripts/merge_allocations.py --cpu-side WORK``
puts these numbers beside the device's.
"""

from __future__ import annotations

import argparse
import hashlib

import numpy as np
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

from .. import certify, plan
from ..config import from_dict, to_dict
from ..data import load, read_manifest, save
from ..errors import ConfigError, PokeworldError
from ..evaluate import measure
from ..io import read_json_if_present, read_regular_bytes, write_json
from ..experiments import stages
from ..experiments.config import MapConfig
from . import allocations

CPU_SIDE = "cpu_side"
"""The folder of the CPU side's records in its work folder: ``machine.json`` (this machine, the corpus) and one
JSON per stage (so that stages run by concurrent invocations never overwrite each other's record)."""
GATE_ESTIMATORS = ("gru", "linear", "drag")
"""The gate's instruments (the GRU oracle, the linear floor, the drag fit): the default certificate set."""


def now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def ensure_same_corpus(allocs: list[allocations.Allocation], work: Path) -> Path:
    """The allocations' seeded corpus generated under ``work/map`` from their own map settings; ConfigError when its
    content differs from what they trained on (another environment in this checkout)."""
    allocations.check_agreement(allocs)
    c = from_dict(MapConfig, {**allocs[0].map_config, "out": str(work / "map")})
    corpus = stages.ensure_corpus(c, "standard")
    sha = read_manifest(corpus).get("content_sha256")
    if sha != allocs[0].corpus_sha256:
        raise ConfigError(f"the corpus generated here ({str(sha)[:12]}) is not the one the allocations trained on "
                          f"({allocs[0].corpus_sha256[:12]}): this checkout generates another environment; run this "
                          "from the commit the allocations ran (device.json 'git')")
    return corpus


MAX_WEIGHTS_BYTES = 256 << 20
"""Largest final.pt read to compare or key (a paper-preset run's is 17 MiB)."""


def weights_sha256(path: Path) -> str:
    return hashlib.sha256(read_regular_bytes(path, "a run's final weights", MAX_WEIGHTS_BYTES)).hexdigest()


def same_weights(a: Path, b: Path) -> bool:
    return a.exists() and b.exists() and weights_sha256(a) == weights_sha256(b)


def export_new_runs(allocs: list[allocations.Allocation], merged: dict, runs: Path, scratch: Path) -> list[str]:
    """The runs with returned weights as run folders under ``runs``; a folder that already holds the same
    final.pt is left as it is (its DONE, and so its measurement's key, unchanged)."""
    fresh = scratch / "export"
    names = allocations.export_runs(allocs, merged, fresh)
    for name in names:
        if not same_weights(fresh / name / "final.pt", runs / name / "final.pt"):
            allocations.export_runs(allocs, {"runs": {name: merged["runs"][name]}}, runs)
    return names


def stage_path(work: Path, stage: str) -> Path:
    return work / CPU_SIDE / (stage.replace(" ", "_").replace("/", "_") + ".json")


def timed(work: Path, stage: str, settings: dict, fn, up_to_date: bool) -> object:
    """Run ``fn`` and record the stage in its own file (this machine, settings, date and wall time; or that its
    output was up to date, in which case the earlier record is kept)."""
    t0 = time.monotonic()
    result = fn()
    if up_to_date and stage_path(work, stage).exists():
        return result
    entry = {"stage": stage, "device": allocations.device_record(), "settings": settings, "date": now()}
    entry.update({"computed": "earlier (output up to date)"} if up_to_date
                 else {"wall_s": round(time.monotonic() - t0, 1)})
    write_json(stage_path(work, stage), entry)
    return result


def probe_subset(corpus: Path, n: int, work: Path) -> Path:
    """A store of ``n`` probe-fit and ``n`` probe-test episodes of ``corpus`` (a seeded draw, kept in corpus order;
    no training episodes, which a measurement does not read), its manifest naming the corpus and the episodes;
    reused when it is there."""
    out = work / f"probe-subset-{n}"
    parent = read_manifest(corpus).get("content_sha256")
    if out.exists() and (read_manifest(out).get("subset_of") or {}).get("content_sha256") == parent:
        return out
    ds = load(corpus)
    rng = np.random.default_rng(0)
    parts = []
    for split in ("probe_fit", "probe_test"):
        eps = ds.episodes(split)
        if n > len(eps):
            raise ConfigError(f"--probe-episodes {n}: the corpus has {len(eps)} {split} episodes")
        parts.append(rng.choice(eps, n, replace=False))
    idx = np.sort(np.concatenate(parts))
    save(ds.subset(idx), out, manifest={"subset_of": {"content_sha256": parent, "episodes": idx.tolist(),
                                                      "what": f"{n} probe-fit and {n} probe-test episodes"}})
    return out


def measure_runs(a: argparse.Namespace, names: list[str], work: Path, corpus: Path) -> None:
    kinds = {"kinds": tuple(a.measure_kinds), "action_conditioned_kinds": ()} if a.measure_kinds else {}
    data = probe_subset(corpus, a.probe_episodes, work) if a.probe_episodes else corpus
    subset = {"probe_episodes": a.probe_episodes, "data_sha256": read_manifest(data).get("content_sha256"),
              "corpus_sha256": read_manifest(corpus).get("content_sha256")}
    for name in names:
        cfg = measure.make_config(a.preset, run_dir=str(work / "runs" / name), data=str(data), device="cpu", **kinds)
        out = measure.measure_path(cfg.run_dir, cfg.data)
        prev = read_json_if_present(out, "a run's measurement")
        fresh = prev is not None and prev.get("key", {}).get("config", {}).get("mlp") and \
            prev.get("key", {}).get("data_sha256") == subset["data_sha256"]
        print(f"[cpu-side] measuring {name} ({a.preset} preset: ridge{' and MLP' if cfg.mlp else ''} probes, "
              "untrained bound; "
              f"{', '.join(cfg.kinds)} windows)", flush=True)
        timed(work, f"measure {name}", {"preset": a.preset, "mlp": cfg.mlp, "untrained": cfg.untrained,
                                        "max_windows": cfg.max_windows, "kinds": list(cfg.kinds),
                                        "action_conditioned_kinds": list(cfg.action_conditioned_kinds),
                                        "file": out.name, **subset}, lambda: measure.run(cfg), bool(fresh))


def certify_corpus(a: argparse.Namespace, corpus: Path, work: Path) -> Path:
    overrides = {"data": str(corpus), "out": str(work / "certificates.json"), "estimators": tuple(a.certify_estimators),
                 "kinds": ("contact",)}
    for field, value in (("max_windows", a.certify_max_windows), ("fit_episodes", a.certify_fit_episodes),
                         ("epochs", a.certify_epochs)):
        if value is not None:
            overrides[field] = value
    cfg = certify.make_config(a.preset, **overrides)
    prev = read_json_if_present(Path(cfg.out), "a certificate record (certificates.json)")
    print(f"[cpu-side] certificates: {', '.join(cfg.estimators)}, contact windows, at most {cfg.max_windows} "
          f"windows, {cfg.epochs} epochs, fit on {cfg.fit_episodes or 'the probe-fit split'}", flush=True)
    up = isinstance(prev, dict) and prev.get("config") == to_dict(cfg)
    return timed(work, "certify", {k: v for k, v in to_dict(cfg).items() if k not in ("data", "out")},
                 lambda: certify.run(cfg), up)


def plan_with_runs(a: argparse.Namespace, names: list[str], merged: dict, corpus: Path, work: Path) -> None:
    runs = work / "runs"
    cfg = plan.make_config(a.preset, out=str(work / "planning"), seed=0, runs=(), device="cpu",
                           **({"episodes": a.plan_episodes} if a.plan_episodes else {}))
    by_variant: dict[str, list[str]] = {}
    for name in names:
        by_variant.setdefault(merged["runs"][name]["train"]["variant"], []).append(str(runs / name))
    key = {"config": to_dict(cfg), "decoder_probe_episodes": a.probe_episodes,
           "runs": {v: [Path(d).name for d in ds] for v, ds in by_variant.items()},
           "weights": {n: weights_sha256(runs / n / "final.pt")[:16] for n in names}}
    path = Path(cfg.out) / "planning.json"
    prev = read_json_if_present(path, "the CPU side's planning record")
    if isinstance(prev, dict) and prev.get("key") == key:
        print(f"[cpu-side] {path} is up to date; skipping planning")
        return
    paper = plan.make_config("paper")
    print(f"[cpu-side] planning: {cfg.episodes} episodes (the paper's {paper.episodes}), population "
          f"{cfg.population}, {cfg.iterations} iterations; {', '.join(by_variant)} and random", flush=True)

    # the position decoder is fit on the corpus the runs trained on, or on the same probe subset as the measurement
    decoder_data = probe_subset(corpus, a.probe_episodes, work) if a.probe_episodes else corpus

    def run_planner():
        planned = plan.plan_runs(cfg, by_variant, data=str(decoder_data))
        plan.write_outputs(planned, Path(cfg.out), cfg.goal_radius)
        write_json(path, {"key": key, "config": to_dict(cfg), "summary": planned["summary"], "runs": by_variant,
                          "paper_budget": all(getattr(cfg, k) == getattr(paper, k) for k in plan.RELEASED_PLANNER)})

    timed(work, "planning", {"episodes": cfg.episodes, "paper_episodes": paper.episodes,
                               "population": cfg.population, "iterations": cfg.iterations, "steps": cfg.steps,
                               "decoder_probe_episodes": a.probe_episodes or "all"},
          run_planner, False)


def complete(a: argparse.Namespace) -> Path:
    """Every stage of the module docstring asked for; returns the folder of the records."""
    work = a.work.resolve()
    work.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="pokeworld-cpu-side-") as scratch:
        allocs = allocations.open_allocations(a.allocations, Path(scratch), a.models)
        merged = allocations.merge_allocations(allocs)
        returned = {n for al in allocs for n, w in al.weights.items()
                    if w == "returned" and (not a.runs or n in a.runs)}
        if not returned and {"measure", "planning"} & set(a.stages):
            # planning with no run would record the random controller alone as if it were the stage's result
            raise ConfigError(f"{', '.join(map(str, a.allocations))}: no finished run with returned weights to "
                              "measure or plan with (a folder without its pack.tar.part files, or an unpacked map "
                              "folder?); give the folders as the device returned them")
        t0 = time.monotonic()
        corpus = given_corpus(allocs, a.corpus) if a.corpus else ensure_same_corpus(allocs, work)
        seconds = round(time.monotonic() - t0, 1)
        write_json(work / CPU_SIDE / "machine.json", {
            "device": allocations.device_record(),
            "corpus": {"path": str(corpus), "content_sha256": allocs[0].corpus_sha256,
                       "seconds_to_generate_or_check": seconds}})
        names = export_new_runs(allocs, merged, work / "runs", Path(scratch))
    unknown = [r for r in a.runs if r not in names]
    if unknown:
        raise ConfigError(f"--runs {unknown}: not a finished run with returned weights ({names})")
    names = [n for n in names if not a.runs or n in a.runs]
    if "measure" in a.stages:
        measure_runs(a, names, work, corpus)
    if "certify" in a.stages:
        certify_corpus(a, corpus, work)
    if "planning" in a.stages:
        plan_with_runs(a, names, merged, corpus, work)
    return work / CPU_SIDE


def given_corpus(allocs: list[allocations.Allocation], corpus: Path) -> Path:
    """An existing store of the allocations' corpus (--corpus), refused unless its content hash is theirs."""
    sha = read_manifest(corpus).get("content_sha256")
    if sha != allocs[0].corpus_sha256:
        raise ConfigError(f"{corpus} holds corpus {str(sha)[:12]}, the allocations trained on "
                          f"{allocs[0].corpus_sha256[:12]}")
    return corpus.resolve()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="The CPU side of GPU allocations: the same seeded corpus, its "
                                             "certificates, MLP probes and the untrained bound of the returned runs, "
                                             "and planning with them.")
    ap.add_argument("allocations", nargs="+", type=Path, help="allocation folders as returned")
    ap.add_argument("--work", type=Path, required=True, help="where the corpus, the runs and the outputs go")
    ap.add_argument("--models", type=Path, default=Path("models"),
                    help="where a landed lease's model folders are (default models/, the repository's)")
    ap.add_argument("--stages", nargs="+", default=["measure", "certify", "planning"],
                    choices=["measure", "certify", "planning"], help="which stages to run (default: all)")
    ap.add_argument("--certify-estimators", nargs="+", default=list(GATE_ESTIMATORS),
                    help="certificate instruments (default: the gate's)")
    ap.add_argument("--certify-max-windows", type=int, help="cap on fit windows (default: the paper preset's)")
    ap.add_argument("--certify-fit-episodes", type=int, help="certificate-corpus episodes to fit on; 0 = the "
                                                            "probe-fit split (default: the paper preset's)")
    ap.add_argument("--certify-epochs", type=int, help="maximum epochs (default: the paper preset's)")
    ap.add_argument("--plan-episodes", type=int, default=0, help="planning episodes (default: the paper's)")
    ap.add_argument("--preset", default="paper", choices=["tiny", "cpu", "paper"],
                    help="measurement, certificate and planning preset (default paper, the paper's budgets; the "
                         "others check the command on small allocations)")
    ap.add_argument("--corpus", type=Path, help="an existing store of the allocations' corpus (checked by its content "
                                                "hash) instead of generating it under --work")
    ap.add_argument("--probe-episodes", type=int, default=0,
                    help="measure on this many probe-fit and as many probe-test episodes of the corpus (a seeded "
                         "draw, recorded; default 0: all of them)")
    ap.add_argument("--runs", nargs="+", default=[], help="only these runs (default: every returned run)")
    ap.add_argument("--measure-kinds", nargs="+", choices=["contact", "glide", "all"],
                    help="window kinds the CPU measurement probes (default: the paper preset's: all three and the "
                         "action-conditioned contact readout)")
    a = ap.parse_args(argv)
    try:
        path = complete(a)
    except PokeworldError as e:
        raise SystemExit(f"error: {e}") from None
    print(f"[cpu-side] -> {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
