"""The map's record and report: results.json (collected from the runs' measurements), results.md (the
certificate table, then each experiment's own section in :data:`~.registry.REPORT_ORDER`, then the readout check)
and the identifiability-map figure."""

from __future__ import annotations

import platform
import sys
from pathlib import Path

import numpy as np

from .. import __version__
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
from ..errors import DataError
from ..io import read_json_if_present, save_figure, save_text
from ..published import paper as P
from ..rundir import training_summary
from .config import recorded_map_config
from .registry import REPORT_ORDER
from .runs import run_dir, spec_measure_path
from .stages import spec_experiments


def collect(c, specs, certificates: dict) -> dict:
    """results.json: every run's measurement, the certificates and gates, the experiments' run lists, the map
    config and where the record came from."""
    runs = {}
    for s in specs:
        try:
            trained = training_summary(run_dir(c, s.name))
        except DataError as e:  # a damaged metrics.jsonl costs its summary, not the report
            trained = {"unreadable": str(e)}
        path = spec_measure_path(c, s)
        m = read_json_if_present(path, "a run's measure.json") or {}
        runs[s.name] = {"experiment": s.experiment, "corpus": s.corpus, "measure_corpus": s.measure_corpus,
                        "train": s.train, "trained": trained,
                        "probes": m.get("probes", {}), "prediction": m.get("prediction", {}),
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
    environment = recorded_map_config(results.get("map_config", {}))["environment"]
    out = ["# Identifiability map: results", "",
           f"Produced by `{prov['command']}` (preset `{prov['preset']}`, environment `{environment}`, pokeworld "
           f"{prov['pokeworld']}, git {prov['git']}). "
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

VARIANT_KEY = {  # the README's table: X-JEPA inputs -> forecasting targets
    "V": "vision in, vision target",
    "VF": "+ proprio, touch in",
    "VX_p": "vision in, proprio target",
    "VX_t": "vision in, touch target",
    "VX": "vision in, proprio and touch targets",
    "VFX": "proprio, touch in and as targets",
}
"""The variant names, explained in the figure's key."""

OBSERVED = ("object_pos", "object_vel")
"""Quantities the certificate estimators observe directly in their input: certified by construction (1.00)."""


def map_matrix(results: dict) -> tuple[np.ndarray, list[str], list[str], np.ndarray]:
    """(quantities x [certificate, variants...]) R^2 matrix with a gate-failed mask."""
    variants = [v for v in results["map_config"]["variants"] if variant_runs(results, "factorial", v)]
    cols = ["certificate"] + variants
    cert = results["certificates"].get("standard", {}).get("certificate", {}).get("contact", {})
    M = np.full((len(QUANTITIES), len(cols)), np.nan)
    failed = np.zeros_like(M, bool)
    for i, q in enumerate(QUANTITIES):
        if q in cert:  # like with like: the GRU oracle, as the paper's column (the best estimator is named apart)
            oracle = oracle_r2(results, q)
            M[i, 0] = cert[q]["r2"] if oracle is None else oracle
        elif q in OBSERVED:
            M[i, 0] = 1.0  # object state is observed directly by the certificate estimators
        for j, v in enumerate(variants, 1):
            val = mean_over(variant_runs(results, "factorial", v), lambda r: probe(r, q))
            M[i, j] = np.nan if val is None else val
        failed[i, :] = gate_failed(results, q)
    return M, [LABELS[q] for q in QUANTITIES], cols, failed


def oracle_r2(results: dict, q: str) -> float | None:
    """Our GRU oracle's certificate R² for ``q`` on the standard corpus's contact windows (the estimator the paper's
    certificate column reports); None when it was not fit (the tiny preset's estimators)."""
    est = results["certificates"].get("standard", {}).get("estimators", {}).get("gru", {})
    val = est.get("contact", {}).get(q)
    return None if val is None else float(val)


def map_conclusion(results: dict) -> str | None:
    """The map's conclusion in one sentence, computed from its numbers: whether stiffness (log k) enters the latent
    when touch is a forecasting target (VFX − VF) and when it is only an input (VF − V); a difference of ≥ 0.1 R²
    counts as an effect (as in :func:`.factorial.factorial_summary`). None without VFX and VF."""
    from .factorial import FACTORIAL

    k = {v: mean_over(variant_runs(results, "factorial", v), lambda r: probe(r, "log_k")) for v in ("V", "VF", "VFX")}
    if k["VFX"] is None or k["VF"] is None:
        return None
    target = k["VFX"] - k["VF"]
    paper = FACTORIAL["VFX"]["log_k"] - FACTORIAL["VF"]["log_k"]
    inputs = None if k["V"] is None else k["VF"] - k["V"]
    said = f"log k ridge R²: VFX − VF = {target:+.2f}, paper {paper:+.2f}"
    as_input = "" if inputs is None else f"; touch as an input only, VF − V = {inputs:+.2f}"
    if target >= 0.1 and (inputs is None or inputs < 0.1):
        text = f"Stiffness enters the latent only when touch is a forecasting target ({said}{as_input})."
    elif target >= 0.1:
        text = f"Stiffness enters the latent with touch as a target and as an input ({said}{as_input})."
    else:
        text = f"At this budget touch as a target does not put stiffness in the latent ({said}{as_input})."
    return text + (" († the log k gate failed: no claim is made.)" if gate_failed(results, "log_k") else "")


def paper_matrix(cols: list[str]) -> np.ndarray:
    """The paper's values for :func:`map_matrix`'s cells (NaN where the paper reports none): the certificate
    column is its GRU oracle (App. A), the variants its Table "targets" (log k, log m; mean of two seeds), and
    VFX's γ, position and velocity its Table "controls" VFX row."""
    from .controls import CONTROLS
    from .factorial import FACTORIAL

    P_ = np.full((len(QUANTITIES), len(cols)), np.nan)
    for i, q in enumerate(QUANTITIES):
        for j, col in enumerate(cols):
            if col == "certificate":
                val = P.CERTIFICATES["gru"].get(q)
            else:
                val = FACTORIAL.get(col, {}).get(q)
                if val is None and col == "VFX":
                    val = CONTROLS["VFX"].get(q)
            if val is not None:
                P_[i, j] = val
    return P_


def _r2(x: float) -> str:
    s = f"{x:.2f}"
    return "0.00" if s == "-0.00" else s


def map_title(results: dict) -> str:
    """The figure's title: what is shown and which presets produced it (the demo's training preset included)."""
    prov, mc = results.get("provenance", {}), results.get("map_config", {})
    preset, train_preset = prov.get("preset") or mc.get("preset", "?"), mc.get("train_preset") or ""
    command = str(prov.get("command", "")).split()
    words = [f"preset {preset}"]
    if command[:1] == ["pokeworld"] and len(command) > 1:  # the command that made it: pokeworld map / demo
        words = [f"pokeworld {command[1]}", f"{'map ' * (command[1] == 'demo')}preset {preset}"]
    if train_preset and train_preset != preset:
        words.append(f"training preset {train_preset}")
    if mc.get("train_steps"):
        words.append(f"{mc['train_steps']:,} training steps")
    return ("Identifiability map: what a frozen latent holds (held-out R², contact windows)\n"
            + "; ".join(words))


def variant_seeds(results: dict, variant: str) -> list:
    """The seeds of a factorial variant's runs, sorted."""
    return sorted({r["train"].get("seed") for r in variant_runs(results, "factorial", variant)}, key=str)


def map_key(results: dict, cols: list[str], failed_rows: list[str]) -> list[str]:
    """The figure's footnote, one entry per item, so the figure reads without the docs."""
    seeds = {v: variant_seeds(results, v) for v in cols if v != "certificate"}
    every = sorted({s for ss in seeds.values() for s in ss}, key=str)
    counts = {len(ss) for ss in seeds.values()}
    if len(counts) > 1:
        seed_words = "mean over the variant's seeds, counted under its name"
    elif len({tuple(ss) for ss in seeds.values()}) == 1:  # the same seeds for every variant
        seed_words = f"seed {every[0]}" if len(every) == 1 else f"mean over seeds {', '.join(map(str, every))}"
    else:
        n = counts.pop() if counts else 0
        seed_words = "one seed per variant" if n == 1 else f"mean over {n} seeds per variant"
    est = {q: v.get("estimator") for q, v in results["certificates"].get("standard", {}).get("certificate", {})
           .get("contact", {}).items()}
    items = [(f"Variant cells: a ridge probe of the frozen predictor state ({seed_words}); "
              "italic \"paper\": the paper's value (Table \"targets\"; VFX's γ, position and velocity from Table "
              "\"controls\"); — : not measured."),
             (("Certificate: our GRU oracle fit on the raw observation streams, beside the paper's GRU oracle; "
               "\"best\": the estimator the gate reads, where another does better"
               if any(oracle_r2(results, q) is not None for q in est) else
               "Certificate: the best estimator fit on the raw observation streams"
               + (f" ({', '.join(sorted(set(filter(None, est.values()))))})" if any(est.values()) else "")
               + "; paper: its GRU oracle")
              + ". Object position and velocity read 1.00 by construction: they are observed "
              "directly in the estimators' input (certified, not fit).")]
    if failed_rows:
        items.append(f"gate ✗ ({', '.join(failed_rows)}): no estimator reached the certificate threshold "
                     f"(log k ≥ {GATES['log_k']}, log m and γ ≥ {GATES['log_m']}); no claim is made for that row.")
    variants = [c for c in cols if c != "certificate"]
    items.append("Variants (X-JEPA inputs → forecasting targets): "
                 + "; ".join(f"{v} = {VARIANT_KEY[v]}" for v in variants if v in VARIANT_KEY) + ".")
    return items


def certificate_note(results: dict, q: str, paper: float) -> tuple[str, str]:
    """The certificate cell's second line and its artist label: the paper's GRU oracle beside ours, and the best
    estimator (the one the gate reads) named apart when it is another; without our GRU oracle, the estimator."""
    best = results["certificates"]["standard"]["certificate"]["contact"][q]
    paper_words = "" if np.isnan(paper) else f"paper {_r2(paper)}"
    if oracle_r2(results, q) is None:  # the cell shows the best estimator: name it
        return best["estimator"] + (f" · {paper_words}" if paper_words else ""), "paper" if paper_words else "estimator"
    apart = "" if best["estimator"] == "gru" else f"best: {best['estimator']} {_r2(best['r2'])}"
    return "\n".join(w for w in (paper_words, apart) if w), "paper" if paper_words else "estimator"


def figure(results: dict, out: Path, stem: str = "identifiability_map") -> list[Path]:
    """The identifiability map: certificate and factorial variants × quantities, as ``out/stem.png`` and ``.pdf``.

    Each cell holds our value (its colour) and, beneath it in italics, the paper's (its Text artists carry the
    label "paper"); a footnote explains the certificate column, the gate and the variant names."""
    import textwrap

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    M, rows, cols, failed = map_matrix(results)
    paper = paper_matrix(cols)
    qs = list(QUANTITIES)
    cert = results["certificates"].get("standard", {}).get("certificate", {}).get("contact", {})
    failed_rows = [rows[i] for i in range(len(rows)) if failed[i].any()]
    row_labels = [r + ("\ngate ✗" if failed[i].any() else "") for i, r in enumerate(rows)]
    n_seeds = {v: len(variant_seeds(results, v)) for v in cols[1:]}
    oracle = any(oracle_r2(results, q) is not None for q in cert)
    col_labels = [("certificate\n(GRU oracle)" if oracle else c) if c == "certificate"
                  else c if len(set(n_seeds.values())) == 1 else f"{c}\n{n_seeds[c]} seed{'s' * (n_seeds[c] != 1)}"
                  for c in cols]
    width = max(1.15 * len(cols) + 3.0, 8.0)
    chars = int(width * 16)  # footnote characters per line at 7.5 pt
    key = [textwrap.fill(item, chars, subsequent_indent="   ") for item in map_key(results, cols, failed_rows)]
    key_lines = sum(k.count("\n") + 1 for k in key)
    map_h, key_h = 0.75 * len(rows) + 2.2, 0.14 * key_lines + 0.15
    fig, ax = plt.subplots(figsize=(width, map_h + key_h))
    im = ax.imshow(np.clip(np.nan_to_num(M, nan=0.0), 0, 1), cmap="viridis", vmin=0, vmax=1, aspect="auto")
    for i in range(M.shape[0]):
        for j in range(M.shape[1]):
            dark = np.isnan(M[i, j]) or M[i, j] < 0.5
            color = "white" if dark else "black"
            observed = j == 0 and qs[i] not in cert and qs[i] in OBSERVED
            main = "—" if np.isnan(M[i, j]) else _r2(M[i, j])
            ax.text(j, i - 0.12, main, ha="center", va="center", fontsize=10, color=color)
            if observed:
                sub, label = "observed", "observed"
            elif j == 0 and qs[i] in cert and cert[qs[i]].get("estimator"):
                sub, label = certificate_note(results, qs[i], paper[i, j])
            elif not np.isnan(paper[i, j]):
                sub, label = f"paper {_r2(paper[i, j])}", "paper"
            else:
                continue
            two = "\n" in sub  # the certificate cell's paper value and best estimator: one line each
            ax.text(j, i + (0.27 if two else 0.22), sub, ha="center", va="center", fontsize=7 if two else 7.5,
                    style="italic", color=color, label=label)
    ax.axvline(0.5, color="white", lw=3)
    ax.set_xticks(range(len(cols)), col_labels)
    ax.set_yticks(range(len(rows)), row_labels)
    ax.set_xlabel("certificate (raw observations)  |  X-JEPA variant (frozen predictor state)", fontsize=9)
    ax.set_ylabel("probed quantity", fontsize=9)
    conclusion = map_conclusion(results)
    # the conclusion on its own line, its numbers on the next
    title = map_title(results) + ("\n" + conclusion.replace(" (", "\n(", 1) if conclusion else "")
    ax.set_title(title, fontsize=10)
    fig.colorbar(im, ax=ax, fraction=0.04, label="held-out R² (ridge, contact windows; clipped to 0–1)")
    fig.text(0.01, 0.01, "\n".join(key), ha="left", va="bottom", fontsize=7.5, linespacing=1.3)
    fig.tight_layout(rect=(0, key_h / (map_h + key_h), 1, 1))
    return save_figure(fig, out, stem)

def write_all(c, results: dict) -> None:
    """results.md and every figure, into the map folder."""
    out = Path(c.out)
    save_text(out / "results.md", markdown(results))
    figure(results, out)
    for experiment in REPORT_ORDER:
        if hasattr(experiment, "figures"):
            experiment.figures(results, out)


__all__ = ["collect", "certificate_table", "gate_cell", "readout_table", "markdown", "merged_lines", "map_matrix",
           "paper_matrix", "map_title", "map_key", "map_conclusion", "oracle_r2", "certificate_note", "variant_seeds", "VARIANT_KEY", "figure", "write_all"]
