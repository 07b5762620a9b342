"""Formatting measured results for tables: cells, labels, gates and the accessors every report reads with
(the map's report, the protocol's and the experiments' own tables)."""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np

from ..certify import GATES  # noqa: F401  (re-exported for the tables that mark gated parameters)
from ..published import paper as P

QUANTITIES = ("log_k", "log_m", "gamma", "object_pos", "object_vel")

LABELS = {"log_k": "log k", "log_m": "log m", "gamma": "γ", "object_pos": "obj. position",
          "object_vel": "obj. velocity", "bias_x": "bias b_x", "bias_y": "bias b_y", "gain": "gain g",
          "finger_pos": "finger position", "object_rel": "object − finger"}

def git_commit() -> str:
    """The short commit hash of this checkout ("unknown" outside git)."""
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                              cwd=Path(__file__).parent, timeout=5).stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"

def probe(run: dict, q: str, kind: str = "contact", family: str = "ridge") -> float | None:
    return run.get("probes", {}).get(family, {}).get(kind, {}).get(q)

def mean_over(runs: list[dict], fn) -> float | None:
    vals = [v for v in (fn(r) for r in runs) if v is not None]
    return float(np.mean(vals)) if vals else None

def variant_runs(results: dict, experiment: str, variant: str, horizons=(1, 4, 16)) -> list[dict]:
    names = results["experiments"].get(experiment, [])
    return [results["runs"][n] for n in names
            if results["runs"][n]["train"]["variant"] == variant
            and tuple(results["runs"][n]["train"].get("horizons", ())) == tuple(horizons)]

def gate_failed(results: dict, q: str, corpus: str = "standard") -> bool:
    """True when ``q`` was gated on ``corpus`` and its gate failed (no estimator reached the threshold)."""
    g = results["certificates"].get(corpus, {}).get("gate", {}).get(q)
    return bool(g) and not g["passed"]

def run_gate_failed(results: dict, run: dict, q: str) -> bool:
    """Gate of the corpus a run was probed on (the standard corpus when that one has no certificate)."""
    corpus = run.get("measure_corpus", "standard")
    return gate_failed(results, q, corpus if corpus in results["certificates"] else "standard")

def dagger(failed: bool) -> str:
    return "†" if failed else ""

def no_claim_lines(results: dict) -> list[str]:
    """One explicit sentence per gated parameter whose gate failed: no claim is made about it."""
    lines = []
    for corpus, cert in results["certificates"].items():
        if cert.get("gate_from"):
            continue  # the standard corpus's gate, stated once there
        for q, g in cert.get("gate", {}).items():
            if g["passed"]:
                continue
            best = (f"best estimator {g['estimator']} {g['certificate']:.2f} < {g['threshold']:.2f}"
                    if "certificate" in g else "no certificate")
            oracle = "GRU oracle not run" if g.get("oracle") is None else f"GRU oracle {g['oracle']:.2f}"
            where = "" if corpus == "standard" else f" on the {corpus} corpus"
            lines.append(f"- no claim is made about {LABELS.get(q, q)}{where}: its gate failed ({best}; {oracle}).")
    if not lines:
        return []
    return lines + ["", "Cells marked † report such a parameter; they are measurements, not claims.", ""]

def fmt(v, digits=2) -> str:
    return "—" if v is None else f"{v:+.{digits}f}" if digits == 2 else f"{v:.{digits}f}"

def ours_paper(v, p, digits=2) -> str:
    """A table cell "ours / paper"."""
    return f"{fmt(v, digits)} / {fmt(p, digits)}"

def mlp_cell(v: float | None) -> str:
    """An MLP readout appended to a ridge cell, in parentheses (nothing when it was not fit)."""
    return f" ({fmt(v)})" if v is not None else ""

def simple_table(results: dict, exp: str, title: str, key_fn, paper: dict | None = None,
                 qs=("log_k", "log_m", "gamma", "object_pos", "object_vel")) -> list[str]:
    if exp not in results["experiments"]:
        return []
    lines = [f"## {title}", "", "| run | " + " | ".join(LABELS.get(q, q) for q in qs)
             + " | glide test, decoded (model / median-γ / static / decoder floor) |", "|" + "---|" * (len(qs) + 2)]
    for name in results["experiments"][exp]:
        r = results["runs"][name]
        key = key_fn(r)
        p = (paper or {}).get(key, {})
        g = r["prediction"].get("glide_test", {})
        mlp = {q: probe(r, q, family="mlp") for q in qs}
        cells = [fmt(probe(r, q)) + (f" ({fmt(mlp[q])})" if mlp[q] is not None else "")
                 + dagger(run_gate_failed(results, r, q)) + (f" / {fmt(p[q])}" if q in p else "") for q in qs]
        gt = (f"{fmt(g.get('model'), 3)} / {fmt(g.get('median_gamma'), 3)} / {fmt(g.get('static'), 3)} / "
              f"{fmt(g.get('decoder_floor'), 3)}" + dagger(run_gate_failed(results, r, "gamma"))) if g else "—"
        lines.append(f"| {key} | " + " | ".join(cells) + f" | {gt} |")
    if paper:
        lines.append("\nCells read ours / paper where the paper reports the value (ridge; the MLP probe in "
                     "parentheses where it was fit).")
    if any(r_has_glide(results["runs"][n]) for n in results["experiments"][exp]):
        lines.append("\nGlide test: every candidate carries the position decoder's residual on the true future "
                     "frame, so the model is compared with the references in one space; it uses γ only if it beats "
                     f"the median-γ reference (paper, true positions: true γ {P.GLIDE_TEST['true_gamma']}, "
                     f"median γ {P.GLIDE_TEST['median_gamma']}, static {P.GLIDE_TEST['static']}).")
    return lines + [""]

def r_has_glide(run: dict) -> bool:
    """Whether a run's measurement holds a functional glide test."""
    return "model" in run.get("prediction", {}).get("glide_test", {})

def diff_words(d: float | None, effect: float = 0.1) -> str:
    """A difference in R² with what it amounts to (≥ ``effect`` counts as an effect)."""
    if d is None:
        return "not measured"
    return f"{d:+.2f}" + (" (an effect)" if d >= effect else " (no effect at this budget)" if abs(d) < effect else
                          " (the other way)")

def mean_all(vals) -> float | None:
    """Mean of every component, None unless all are present (a half-measured 2-d parameter is not scored)."""
    vals = list(vals)
    return None if not vals or any(v is None for v in vals) else sum(vals) / len(vals)


__all__ = ["QUANTITIES", "LABELS", "GATES", "git_commit", "probe", "mean_over", "variant_runs", "gate_failed",
           "run_gate_failed", "dagger", "no_claim_lines", "fmt", "ours_paper", "mlp_cell", "simple_table", "r_has_glide",
           "diff_words", "mean_all"]
