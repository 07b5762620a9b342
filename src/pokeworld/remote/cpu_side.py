"""The CPU side's numbers in the merged record of GPU allocations, and the paper-budget table that puts every
number of a run beside the paper's and the authors' released run.

``scripts/complete_allocations.py`` (:mod:`.complete`) computes, from what allocations returned, what the
device did not: MLP probes, the untrained bound, the certificates and planning. :func:`attach_cpu_side` reads its
work folder into the merged record (each number with the machine and date that computed it); :func:`record_lines`
writes the per-run table. A run's ridge probes, prediction errors and glide test stay the device's own; the CPU's
ridge readout of the same returned (bfloat16-rounded) weights is kept beside them as a check
(``cpu_measurement.largest_ridge_difference``).
"""

from __future__ import annotations

from pathlib import Path

from ..certify import gate_of
from ..errors import ConfigError, PokeworldError
from ..evaluate.tables import LABELS, fmt
from ..experiments.factorial import FACTORIAL, FACTORIAL_MLP
from ..io import read_json
from ..published import paper as P
from ..published.release import MULTI_HORIZON, RESULTS_COMMIT, SINGLE_HORIZON, SOURCE_REPO, released

CPU_SIDE = "cpu_side"
MAX_JSON_BYTES = 4 << 20
MAX_STAGES = 256
GATED = ("log_m", "gamma", "log_k")


def read_side_json(path: Path, what: str) -> dict:
    try:
        return read_json(path, what, dict, MAX_JSON_BYTES, error=ConfigError)
    except PokeworldError as e:
        raise ConfigError(str(e)) from None


def where(device: dict, date: str | None = None) -> dict:
    return {"device": device.get("device"), "date": date or device.get("date")}


def attach_measurements(merged: dict, work: Path, side: dict) -> list[str]:
    """Each run's CPU measurement (MLP probes, untrained bound, the CPU's ridge beside the device's); returns the
    runs that have one. A measurement of another corpus is refused."""
    sha = merged["provenance"]["corpus_sha256"]
    attached = []
    for name, run in merged["runs"].items():
        stage = side["stages"].get(f"measure {name}", {})
        settings = stage.get("settings", {})
        path = work / "runs" / name / str(settings.get("file", "measure-standard.json"))
        if not stage or not path.exists() or path.parent.parent != work / "runs":
            continue
        m = read_side_json(path, "a CPU-side measurement")
        measured = m.get("key", {}).get("data_sha256")
        # a measurement on a subset of the corpus's probe episodes names the subset and the corpus
        if settings.get("corpus_sha256", measured) != sha or measured != settings.get("data_sha256", measured):
            raise ConfigError(f"{path} measured corpus {str(measured)[:12]}, the allocations trained on {sha[:12]}")
        device_ridge = run["probes"].get("ridge", {}).get("contact", {})
        cpu_ridge = m.get("probes", {}).get("ridge", {}).get("contact", {})
        diffs = [abs(cpu_ridge[q] - device_ridge[q]) for q in cpu_ridge if isinstance(device_ridge.get(q), float)]
        if "mlp" in m.get("probes", {}):
            run["probes"]["mlp"] = m["probes"]["mlp"]
        run["untrained"] = m.get("untrained", {})
        run["cpu_measurement"] = {**where(stage.get("device", side["device"]), stage.get("date")), "stage": stage,
                                  "ridge_contact": cpu_ridge, "prediction": m.get("prediction", {}),
                                  "largest_ridge_difference": max(diffs) if diffs else None,
                                  "probe_episodes": settings.get("probe_episodes") or "all"}
        attached.append(name)
    return attached


def attach_certificates(merged: dict, work: Path, side: dict) -> bool:
    path = work / "certificates.json"
    if not path.exists():
        return False
    cert = read_side_json(path, "a certify JSON")
    if (cert.get("dataset") or {}).get("content_sha256") != merged["provenance"]["corpus_sha256"]:
        raise ConfigError(f"{path} certifies another corpus than the allocations trained on")
    merged["certificates"]["standard"] = {"certificate": cert.get("certificate", {}), "gate": gate_of(cert),
                                          "estimators": cert.get("estimators", {}), "counts": cert.get("counts", {}),
                                          **where(side["stages"].get("certify", {}).get("device", side["device"]),
                                                  side["stages"].get("certify", {}).get("date")),
                                          "settings": side.get("stages", {}).get("certify", {}).get("settings", {})}
    return True


def attach_planning(merged: dict, work: Path, side: dict) -> bool:
    path = work / "planning" / "planning.json"
    if not path.exists():
        return False
    pl = read_side_json(path, "the CPU side's planning record")
    stage = side.get("stages", {}).get("planning", {})
    merged["planning"] = {"config": pl["config"], "summary": pl["summary"], "runs": pl.get("runs", {}),
                          "figure": [], "paper_budget": bool(pl.get("paper_budget")),
                          **where(stage.get("device", side["device"]), stage.get("date")), "stage": stage}
    return True


def read_side(work: Path) -> dict:
    """The CPU side's records under ``work`` (:mod:`.complete`): ``{"device", "corpus", "stages"}``."""
    folder = work / CPU_SIDE
    machine = read_side_json(folder / "machine.json", "the CPU side's machine record")
    if not isinstance(machine.get("device"), dict) or not isinstance(machine.get("corpus"), dict):
        raise ConfigError(f"{folder / 'machine.json'} names no machine and corpus; it is not a record "
                          "complete_allocations.py wrote")
    files = sorted(p for p in folder.glob("*.json") if p.name != "machine.json")
    if len(files) > MAX_STAGES:
        raise ConfigError(f"{folder} holds {len(files)} stage records; complete_allocations.py writes a few")
    stages = {}
    for p in files:
        entry = read_side_json(p, "a CPU-side stage record")
        if isinstance(entry.get("stage"), str) and isinstance(entry.get("device"), dict):
            stages[entry["stage"]] = entry
    return {**machine, "stages": stages}


def attach_cpu_side(merged: dict, work: Path) -> dict:
    """``merged`` completed with the CPU side computed under ``work`` (:mod:`.complete`) and each run's
    released values (:mod:`pokeworld.published.release`); returns what was attached."""
    side = read_side(work)
    if side.get("corpus", {}).get("content_sha256") != merged["provenance"]["corpus_sha256"]:
        raise ConfigError(f"{work} holds the CPU side of another corpus than the allocations trained on")
    done = {"measured": attach_measurements(merged, work, side),
            "certificates": attach_certificates(merged, work, side), "planning": attach_planning(merged, work, side)}
    merged["provenance"]["cpu_side"] = {**where(side["device"]), "work": str(work), **done}
    for run in merged["runs"].values():
        key = (run["train"]["variant"], int(run["train"]["seed"]))
        run["released"] = {k: v for k, v in {"multi_horizon": released(*key), "single_horizon":
                                             released(*key, table=SINGLE_HORIZON)}.items() if v}
    return done


# ---------------------------------------------------------------------- the per-run table


def cell(v, digits: int = 2) -> str:
    """A number as the tables write it; text as it is (a share already in %); '—' for none."""
    return v if isinstance(v, str) else fmt(v, digits) if isinstance(v, (int, float)) else "—"


def share(v) -> str | None:
    return f"{v:.0%}" if isinstance(v, (int, float)) else None


def short(d: dict) -> str:
    """'H100, 2026-11-27' for a device and date; 'not computed' without one."""
    if not d.get("device"):
        return "not computed"
    return f"{str(d['device']).replace('NVIDIA ', '').split(' 80GB')[0]}, {str(d.get('date') or '—')[:10]}"


def run_rows(run: dict) -> list[tuple[str, object, object, object, str, int]]:
    """(quantity, ours, paper, released, computed on, digits) for one run."""
    v, seed = run["train"]["variant"], int(run["train"]["seed"])
    rel = released(v, seed, MULTI_HORIZON)
    gpu, cpu = short(run.get("allocation", {})), short(run.get("cpu_measurement", {}))
    n = run.get("cpu_measurement", {}).get("probe_episodes")
    if isinstance(n, int):  # measured on a seeded subset of the probe splits
        cpu += f", {n} + {n} of the probe-fit + probe-test episodes"
    ridge = run["probes"].get("ridge", {}).get("contact", {})
    mlp = run["probes"].get("mlp", {}).get("contact", {})
    unt = run.get("untrained", {}).get("ridge", {}).get("contact", {})
    pred, glide = run.get("prediction", {}), run.get("prediction", {}).get("glide_test", {})
    rows = [(f"{LABELS[q]} ridge", ridge.get(q), FACTORIAL.get(v, {}).get(q) if q != "gamma" else None,
             rel.get("ridge", {}).get(q), gpu, 2) for q in ("log_k", "log_m", "gamma")]
    rows += [(f"{LABELS[q]} MLP", mlp.get(q), FACTORIAL_MLP.get(v, {}).get(q), rel.get("mlp", {}).get(q),
              cpu, 2) for q in ("log_k", "log_m", "gamma")]
    rows += [(f"{LABELS[q]} untrained bound (ridge)", unt.get(q), None, None, cpu, 2) for q in GATED]
    rows += [("object position ridge", ridge.get("object_pos"), None, rel.get("object_pos_frame"), gpu, 2),
             ("direct-16 (arena units)", pred.get("direct16"), P.PREDICTION["direct16"], rel.get("direct16"), gpu, 3),
             ("rollout-16", pred.get("rollout16"), P.PREDICTION["rollout16"], rel.get("rollout16"), gpu, 3),
             ("static-16", pred.get("static16"), P.PREDICTION["static16"], rel.get("static16"), gpu, 3),
             # like for like: decoded references beside the paper's decoded one, true-position ones beside its own
             ("glide test, decoded: model", glide.get("model"), None, None, gpu, 3),
             ("glide test, decoded: median-γ reference", glide.get("median_gamma"),
              P.GLIDE_TEST_DECODED["median_gamma"], None, gpu, 3),
             ("glide test, decoded: static", glide.get("static"), None, None, gpu, 3)]
    true = glide.get("undecoded", {}) if isinstance(glide.get("undecoded"), dict) else {}
    rows += [(f"glide test, true positions: {label}", true.get(q), P.GLIDE_TEST[q], None, gpu, 4 if q == "true_gamma"
              else 3) for q, label in (("true_gamma", "true-γ reference"), ("median_gamma", "median-γ reference"),
                                       ("static", "static"))]
    return rows


def planning_rows(merged: dict, variant: str) -> list[tuple[str, object, object, object, str, int]]:
    pl = merged.get("planning")
    if not pl or variant not in pl["summary"]:
        return []
    s, p = pl["summary"][variant], P.PLANNING.get(variant, (None, None))
    on = short(pl) + ("" if pl.get("paper_budget") else f", {pl['config']['episodes']} episodes")
    n = pl.get("stage", {}).get("settings", {}).get("decoder_probe_episodes")
    if isinstance(n, int):
        on += f", decoder fit on {n} probe-fit episodes"
    # the paper's improvement is the released planner's start − closest distance (records from before that metric
    # show "—" there); start − final is ours alone
    return [("planning: goal-region reach", share(s.get("reach")), share(p[0]), None, on, 2),
            ("planning: median improvement, start − closest", s.get("median_closest_improvement"), p[1], None, on, 3),
            ("planning: median improvement, start − final", s.get("median_improvement"), None, None, on, 3)]


def record_lines(merged: dict) -> list[str]:
    """Per run: every number the paper reports for its variant, ours beside the paper's and the released run's,
    with the machine and date that computed ours."""
    lines = ["## Every number of each run, beside the paper's and the authors' released run", "",
             f"Released: the authors' per-run JSON of the same variant and seed ({SOURCE_REPO} at "
             f"{RESULTS_COMMIT[:7]}, exp/e003_motion/results, λ 0.02, 20,000 steps); paper: its tables (mean of two "
             "seeds). Ridge, prediction and glide numbers are the device's measurement; MLP probes, the untrained "
             "bound and planning were computed on the CPU from the returned weights (float32 tensors of at least "
             "4,096 elements rounded to bfloat16 for the trip).", ""]
    for name, run in sorted(merged["runs"].items()):
        lines += [f"### {name}", "", "| quantity | ours | paper | released | computed on |", "|---|---|---|---|---|"]
        for q, ours, paper, rel, on, d in run_rows(run) + planning_rows(merged, run["train"]["variant"]):
            lines.append(f"| {q} | {cell(ours, d)} | {cell(paper, d)} | {cell(rel, d)} | {on} |")
        single = released(run["train"]["variant"], int(run["train"]["seed"]), SINGLE_HORIZON)
        if single:
            r = single["ridge"]
            lines.append(f"\nThe authors' single-horizon run of the same variant ({single['source']}: Δ = 1 only, "
                         f"not the configuration of Table \"targets\"): ridge log k {cell(r['log_k'])}, log m "
                         f"{cell(r['log_m'])}, γ {cell(r['gamma'])}.")
        check = run.get("cpu_measurement", {}).get("largest_ridge_difference")
        if isinstance(check, float):
            lines.append(f"\nThe CPU's ridge readout of the returned weights differs from the device's by at most "
                         f"{check:.3f} (contact windows).")
        lines.append("")
    pl = merged.get("planning")
    if pl and "random" in pl["summary"]:
        r = pl["summary"]["random"]
        c = pl["config"]
        budget = ("the released planner's settings (the `paper` preset)" if pl.get("paper_budget") else
                  f"NOT the released planner's settings: {c['episodes']} episodes of {c['steps']} steps, population "
                  f"{c['population']}, {c['iterations']} iterations, approach weight {c.get('approach_weight', 0.0)}")
        lines += [f"Random controller (same starts and goals; {budget}; {short(pl)}): reach {share(r.get('reach'))} "
                  f"(paper {share(P.PLANNING['random'][0])}), median improvement to the closest approach "
                  f"{cell(r.get('median_closest_improvement'), 3)} (paper {P.PLANNING['random'][1]}), to the end "
                  f"{cell(r.get('median_improvement'), 3)}.", ""]
    return lines + headline_lines(merged)


def headline_lines(merged: dict) -> list[str]:
    """VFX − VF per seed where both were trained: ours, the paper's and the released runs'."""
    by = {(r["train"]["variant"], int(r["train"]["seed"])): r for r in merged["runs"].values()}
    lines = []
    for seed in sorted({s for _, s in by}):
        a, b = by.get(("VFX", seed)), by.get(("VF", seed))
        if not (a and b):
            continue
        for fam, table in (("ridge", FACTORIAL), ("mlp", FACTORIAL_MLP)):
            ours = [r["probes"].get(fam, {}).get("contact", {}).get("log_k") for r in (a, b)]
            paper = [table.get(v, {}).get("log_k") for v in ("VFX", "VF")]
            rel = [released(v, seed).get(fam, {}).get("log_k") for v in ("VFX", "VF")]
            diff = lambda xs: cell(xs[0] - xs[1]) if None not in xs else "—"  # noqa: E731
            lines.append(f"VFX − VF log k ({fam}, seed {seed}): ours {diff(ours)}, paper {diff(paper)}, "
                         f"released {diff(rel)}.")
    return lines + ([""] if lines else [])


__all__ = ["CPU_SIDE", "read_side", "attach_cpu_side", "attach_measurements", "attach_certificates", "attach_planning",
           "record_lines", "headline_lines", "run_rows", "planning_rows"]
