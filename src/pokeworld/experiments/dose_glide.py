"""Dose-response 1 (paper App. C Table "dose1"): reweighting the loss toward glide frames, the blind
parameter's evidence."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from ..evaluate.tables import dagger, fmt, ours_paper, probe, run_gate_failed
from ..rundir import read_metrics
from ..train.config import field_defaults
from .runs import RunSpec, spec

if TYPE_CHECKING:
    from .config import MapConfig

DOSE_GLIDE = {  # App. C Table "dose1": glide loss weight -> glide loss share and readouts (γ on glide windows)
    1.0: {"share": 0.32, "gamma_glide": 0.08, "glide_model": 0.098, "log_k": 0.42, "object_vel": 0.85},
    4.0: {"share": 0.65, "gamma_glide": 0.15, "glide_model": 0.108, "log_k": 0.34, "object_vel": 0.79},
    16.0: {"share": 0.88, "gamma_glide": 0.21, "glide_model": 0.116, "log_k": 0.20, "object_vel": 0.70},
    64.0: {"share": 0.97, "gamma_glide": 0.27, "glide_model": 0.136, "log_k": 0.10, "object_vel": 0.65},
}

DOSE_GLIDE_MEDIAN_GAMMA = 0.054  # Table "dose1": the functional glide test's median-γ reference


NAME = "dose_glide"


def specs(c: MapConfig) -> list[RunSpec]:
    """Dose-response 1 (paper App. C): glide-frame loss weight 1/4/16/64 (glide loss share 32% -> 97% there)."""
    return [spec("dose_glide", "VFX", c.seeds[0], c.sigreg_weight, glide_loss_weight=w) for w in (1.0, 4.0, 16.0, 64.0)]


def realised_glide_share(results: dict, run: dict) -> float | None:
    """Glide loss share a run's training realised: the mean of the per-step ``glide_loss_share`` in its
    metrics.jsonl (None when the run is not on disk)."""
    name = next((n for n, r in results["runs"].items() if r is run), None)
    shares = []
    if name is not None:
        rows = read_metrics(Path(results.get("map_config", {}).get("out", "")) / "runs" / str(name))
        shares = [r["glide_loss_share"] for r in rows if "glide_loss_share" in r]
    return sum(shares) / len(shares) if shares else None


def dose_glide_table(results: dict) -> list[str]:
    """App. C Table "dose1": glide-frame loss weight -> realised glide loss share, γ on glide windows, the
    functional glide test, log k and velocity (ours / paper)."""
    if "dose_glide" not in results["experiments"]:
        return []
    lines = ["## Dose-response 1: reweighting toward the blind parameter (VFX; glide-frame loss weight)", "",
             "| glide weight | glide loss share | γ, glide windows | γ, contact windows | glide test: model | "
             "glide test: median-γ | log k | velocity |", "|---|---|---|---|---|---|---|---|"]
    default = field_defaults()["glide_loss_weight"]
    for name in results["experiments"]["dose_glide"]:
        r = results["runs"][name]
        w = float(r["train"].get("glide_loss_weight", default))
        p = DOSE_GLIDE.get(w, {})
        share = realised_glide_share(results, r)
        g = r["prediction"].get("glide_test", {})
        gm = dagger(run_gate_failed(results, r, "gamma"))
        share_cell = f"{'—' if share is None else f'{100 * share:.0f}%'} / " + (f"{100 * p['share']:.0f}%" if p else "—")
        lines.append(f"| {w:g} | {share_cell} | {ours_paper(probe(r, 'gamma', 'glide'), p.get('gamma_glide'))}{gm} | "
                     f"{fmt(probe(r, 'gamma'))}{gm} | {ours_paper(g.get('model'), p.get('glide_model'), 3)} | "
                     f"{ours_paper(g.get('median_gamma'), DOSE_GLIDE_MEDIAN_GAMMA if p else None, 3)} | "
                     f"{ours_paper(probe(r, 'log_k'), p.get('log_k'))} | "
                     f"{ours_paper(probe(r, 'object_vel'), p.get('object_vel'))} |")
    lines.append("\nCells read ours / paper (ridge; γ on glide windows as in the paper, log k and velocity on contact "
                 "windows). The glide loss share is the mean per-step share training realised (metrics.jsonl). The "
                 "glide test is decoded: a model uses γ only if its error beats the median-γ reference.")
    return lines + [""]


section = dose_glide_table


__all__ = ['NAME', 'DOSE_GLIDE', 'DOSE_GLIDE_MEDIAN_GAMMA', 'specs', 'section', 'dose_glide_table', 'realised_glide_share']
