"""The map's record and report: results.json (collected from the runs' measurements), results.md (the
certificate table, then each experiment's own section in :data:`~.registry.REPORT_ORDER`, then the readout check)
and the identifiability-map figure."""

from __future__ import annotations

import json
import platform
import sys
from pathlib import Path

import numpy as np

from .. import __version__, paper_values as P
from ..certify import GATES, gate_of
from ..config import to_dict
from ..evaluate.tables import (
    LABELS,
    QUANTITIES,
    dagger,
    fmt,
    gate_failed,
    git_commit,
    mean_over,
    no_claim_lines,
    probe,
    run_gate_failed,
    variant_runs,
)
from ..io import atomic_path, save_figure
from .registry import REPORT_ORDER
from .runs import spec_measure_path
from .stages import spec_experiments


def collect(c, specs, certificates: dict) -> dict:
    """results.json: every run's measurement, the certificates and gates, the experiments' run lists, the map
    config and where the record came from."""
    runs = {}
    for s in specs:
        path = spec_measure_path(c, s)
        m = json.loads(path.read_text()) if path.exists() else {}
        runs[s.name] = {"experiment": s.experiment, "corpus": s.corpus, "measure_corpus": s.measure_corpus,
                        "train": s.train, "probes": m.get("probes", {}), "prediction": m.get("prediction", {}),
                        "untrained": m.get("untrained", {}),
                        "probes_action_conditioned": m.get("probes_action_conditioned", {}),
                        "probes_belief": m.get("probes_belief", {}), "measure": dict(s.measure)}
    # gate_of: certificates stored before the paper-rule gate are re-gated on the GRU oracle
    certs = {k: {"certificate": v.get("certificate", {}), "gate": gate_of(v),
                 "estimators": v.get("estimators", {}), "counts": v.get("counts", {}),
                 **({"flow_sensor": v["flow_sensor"]} if "flow_sensor" in v else {})}
             for k, v in certificates.items()}
    return {"runs": runs, "certificates": certs, "experiments": spec_experiments(c), "map_config": to_dict(c),
            "provenance": {"command": "pokeworld " + " ".join(sys.argv[1:]) if sys.argv and "pokeworld" in sys.argv[0]
                           else " ".join(sys.argv), "preset": c.preset, "pokeworld": __version__,
                           "git": git_commit(), "python": platform.python_version()}}

def certificate_table(results: dict) -> list[str]:
    """The standard corpus's certificates beside the paper's, and the gate."""
    std = results["certificates"].get("standard")
    if not std:
        return []
    est = std["estimators"]
    lines = ["## Recoverability certificates (contact windows, held-out R²)", "",
             "| estimator | log m (ours / paper) | γ (ours / paper) | log k (ours / paper) |", "|---|---|---|---|"]
    for name, kinds in est.items():
        r = kinds.get("contact", {})
        p = P.CERTIFICATES.get(name, {})
        lines.append(f"| {name} | " + " | ".join(f"{fmt(r.get(q))} / {fmt(p.get(q))}"
                                               for q in ("log_m", "gamma", "log_k")) + " |")
    lines.append("")
    thresholds = "/".join(str(GATES[q]) for q in ("log_m", "gamma", "log_k"))
    verdicts = [f"{LABELS.get(q, q)} {'PASS' if g['passed'] else 'FAIL'} ({gate_cell(g)})"
                for q, g in std["gate"].items()]
    lines.append(f"Gate (best estimator m/γ/k ≥ {thresholds}; the paper's GRU-oracle rule beside it): "
                 + ", ".join(verdicts))
    notes = [f"- {LABELS.get(q, q)}: {g['note']}" for q, g in std["gate"].items() if not g.get("agree", True)]
    if notes:
        lines += ["", "Where the paper's rule (the GRU oracle alone) disagrees:"] + notes
    return lines + [""]

def gate_cell(g: dict) -> str:
    oracle = "GRU not run" if g.get("oracle") is None else f"GRU {g['oracle']:.2f}"
    return (f"{g['estimator']} {g['certificate']:.2f}; " if "certificate" in g else "") + oracle

def readout_table(results: dict) -> list[str]:
    """The action-leak check, once: leak-free (primary) vs action-conditioned readout per run."""
    qs = ("object_pos", "object_vel", "object_rel", "log_k")
    rows = []
    for name, r in results["runs"].items():
        leaky = r.get("probes_action_conditioned", {}).get("ridge", {}).get("contact", {})
        if not leaky:
            continue
        rows.append(f"| {name} | " + " | ".join(
            f"{fmt(probe(r, q))} / {fmt(leaky.get(q))}" + dagger(q in GATES and run_gate_failed(results, r, q))
            for q in qs) + " |")
    if not rows:
        return []
    return ["## Readout: leak-free vs action-conditioned (ridge R², contact windows)", "",
            "Every probe in this report reads the predictor state at a window's last observation with the action "
            "taken after it replaced by the neutral (zero) action: the scripted policy computed that action from the "
            "object state, so a state conditioned on it could expose the object without any inference. Cells read "
            "leak-free / action-conditioned.", "",
            "| run | " + " | ".join(LABELS[q] for q in qs) + " |", "|" + "---|" * (len(qs) + 1), *rows, ""]

def markdown(results: dict) -> str:
    """results.md."""
    prov = results["provenance"]
    out = ["# Identifiability map: results", "",
           f"Produced by `{prov['command']}` (preset `{prov['preset']}`, pokeworld {prov['pokeworld']}, git {prov['git']}). "
           "Paper values are the paper's own numbers, shown beside ours for comparison; they are never used as ours.", ""]
    out += merged_lines(prov)
    out += certificate_table(results)
    out += no_claim_lines(results)
    for experiment in REPORT_ORDER:
        out += experiment.section(results)
    out += readout_table(results)
    return "\n".join(out) + "\n"

def merged_lines(prov: dict) -> list[str]:
    """What earlier invocations left in this record (experiment.carry_over) and what later ones folded into it
    (``scripts/merge_map_results.py``), one line each."""
    out = [f"Carried over from an earlier invocation on the same output folder, `{m['command']}` (git {m['git']}): "
           f"{len(m['runs'])} run{'s' * (len(m['runs']) != 1)} ({', '.join(m['runs'])})." for m in prov.get("carried_over", [])]
    out += [""] if out else []
    for m in prov.get("merged", []):
        n_rep, n_add = len(m["runs_replaced_reproduced"]), len(m["runs_added"])
        out += [f"Merged in from `{m['command']}` (git {m['git']}), experiments {', '.join(m['experiments'])}: "
                f"{n_rep} re-trained run{'s' * (n_rep != 1)} reproduced this record's ridge numbers (to "
                f"{m['tol']:g}) and replaced the record's, adding what that invocation measured besides (e.g. MLP "
                f"probes); {n_add} run{'s' * (n_add != 1)} added."
                + "".join(f" `{n}` did not reproduce (largest ridge difference {d:.4f}) and was replaced by its re-trained "
                          "run: every number of its row is the re-trained run's." for n, d in
                          m.get("runs_replaced_differing", {}).items()), ""]
    return out

def map_matrix(results: dict) -> tuple[np.ndarray, list[str], list[str], np.ndarray]:
    """(quantities x [certificate, variants...]) R^2 matrix with a gate-failed mask."""
    variants = [v for v in results["map_config"]["variants"] if variant_runs(results, "factorial", v)]
    cols = ["certificate"] + variants
    cert = results["certificates"].get("standard", {}).get("certificate", {}).get("contact", {})
    M = np.full((len(QUANTITIES), len(cols)), np.nan)
    failed = np.zeros_like(M, bool)
    for i, q in enumerate(QUANTITIES):
        if q in cert:
            M[i, 0] = cert[q]["r2"]
        elif q in ("object_pos", "object_vel"):
            M[i, 0] = 1.0  # object state is observed directly by the certificate estimators
        for j, v in enumerate(variants, 1):
            val = mean_over(variant_runs(results, "factorial", v), lambda r: probe(r, q))
            M[i, j] = np.nan if val is None else val
        failed[i, :] = gate_failed(results, q)
    return M, [LABELS[q] for q in QUANTITIES], cols, failed

def figure(results: dict, out: Path, stem: str = "identifiability_map") -> list[Path]:
    """The identifiability map: certificate and factorial variants × quantities, as ``out/stem.png`` and ``.pdf``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    M, rows, cols, failed = map_matrix(results)
    fig, ax = plt.subplots(figsize=(1.2 * len(cols) + 2, 0.7 * len(rows) + 1.6))
    im = ax.imshow(np.clip(M, 0, 1), cmap="viridis", vmin=0, vmax=1, aspect="auto")
    for i in range(M.shape[0]):
        for j in range(M.shape[1]):
            if np.isnan(M[i, j]):
                txt = "—"
            else:
                txt = f"{M[i, j]:.2f}" + ("\ngate ✗" if failed[i, j] else "")
            ax.text(j, i, txt, ha="center", va="center", fontsize=9,
                    color="white" if (np.isnan(M[i, j]) or M[i, j] < 0.5) else "black")
    ax.axvline(0.5, color="white", lw=3)
    ax.set_xticks(range(len(cols)), cols)
    ax.set_yticks(range(len(rows)), rows)
    prov = results["provenance"]
    ax.set_title(f"Identifiability map (ridge R², contact windows; preset {prov['preset']})", fontsize=10)
    fig.colorbar(im, ax=ax, fraction=0.04, label="held-out R²")
    fig.tight_layout()
    return save_figure(fig, out, stem)

def write_all(c, results: dict) -> None:
    """results.md and every figure, into the map folder."""
    out = Path(c.out)
    with atomic_path(out / "results.md") as tmp:
        tmp.write_text(markdown(results))
    figure(results, out)
    for experiment in REPORT_ORDER:
        if hasattr(experiment, "figures"):
            experiment.figures(results, out)


__all__ = ["collect", "certificate_table", "gate_cell", "readout_table", "markdown", "merged_lines", "map_matrix",
           "figure", "write_all"]
