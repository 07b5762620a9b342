"""The γ intervention ledger (paper App. C): every prediction-side mechanism against drag, one VFX run each."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..evaluate.tables import fmt, probe
from ..io import save_figure
from .runs import RunSpec, spec

if TYPE_CHECKING:
    from .config import MapConfig

LEDGER = {  # App. C, the γ intervention ledger (text): mechanism -> the paper's best γ readout. The paper adds
    # mechanisms in sequence (single horizon -> multi-horizon heads -> + motion input channel); our default trunk
    # has the motion channel, so its multi-horizon run is the paper's "+ motion channel" stage and the
    # motion-off run its "multi-horizon heads" stage.
    "single-horizon head": "0.00",
    "no motion input channel": "0.05",
    "multi-horizon heads": "0.12 (plateau)",
    "spatial tokens": "no gain",
    "magnitude-weighted motion targets": "no gain",
    "frozen flow velocity sensor": "plateau unchanged",
    "flow sensor with the log-speed coordinate": "0.33 on glide windows",
    "glide-enriched loss": "no gain",
}


NAME = "ledger"


#: γ ledger rows: mechanism -> the run that deploys it (train overrides on VFX beside the horizons and corpus);
#: every run except the two ledger-only ones is shared with the experiment named in its spec.
LEDGER_MOTION_ALPHA = 4.0


def specs(c: MapConfig) -> list[RunSpec]:
    """The γ intervention ledger (App. C): every prediction-side mechanism against drag, one VFX run each —
    single- vs multi-horizon heads, the temporal-difference input channel off, spatial tokens, magnitude-weighted
    motion-forecast targets, the frozen flow sensor's velocity as input (then with its log-speed coordinate, the
    coordinate test's run: the figure's "linearizing sensed coordinate"), and a glide-enriched loss (weight 16).
    Runs shared with factorial / controls / coordinate / dose_glide keep those experiments' names."""
    s, lam = c.seeds[0], c.sigreg_weight
    return [spec("ledger", "VFX", s, lam, horizons=(1,)), spec("factorial", "VFX", s, lam),
            spec("ledger", "VFX", s, lam, motion_channel=False), spec("controls", "VFX", s, lam, tokens=True),
            spec("ledger", "VFX", s, lam, motion_loss_weight=LEDGER_MOTION_ALPHA),
            spec("ledger", "VFX", s, lam, corpus="flow_velocity", measure_corpus="flow_velocity"),
            spec("coordinate", "VFX", s, lam, corpus="flow", measure_corpus="flow"),
            spec("dose_glide", "VFX", s, lam, glide_loss_weight=16.0)]


def ledger_mechanism(run: dict) -> str:
    """Ledger row label of a run (the mechanism it deploys), from its corpus and train overrides."""
    t = run["train"]
    if run.get("corpus") == "flow_velocity":
        return "frozen flow velocity sensor"
    if run.get("corpus") == "flow":
        return "flow sensor with the log-speed coordinate"
    if t.get("tokens"):
        return "spatial tokens"
    if t.get("motion_loss_weight", 0.0) > 0:
        return "magnitude-weighted motion targets"
    if t.get("motion_channel", True) is False:
        return "no motion input channel"
    if t.get("glide_loss_weight", 1.0) != 1.0:
        return "glide-enriched loss"
    return "single-horizon head" if tuple(t.get("horizons", (1, 4, 16))) == (1,) else "multi-horizon heads"


def ledger_rows(results: dict) -> list[tuple[str, dict]]:
    """(mechanism, run) per ledger run, in the ledger's order."""
    return [(ledger_mechanism(results["runs"][n]), results["runs"][n]) for n in results["experiments"].get("ledger", [])]

def best_gamma(run: dict) -> float | None:
    """Best γ readout of a run over probe families (ridge, MLP) and window kinds (contact, glide)."""
    vals = [probe(run, "gamma", kind, fam) for fam in ("ridge", "mlp") for kind in ("contact", "glide")]
    vals = [v for v in vals if v is not None]
    return max(vals) if vals else None

def gamma_certificates(results: dict) -> dict[str, float]:
    """γ certificates on the standard corpus: the best estimator's R² per window kind."""
    est = results["certificates"].get("standard", {}).get("estimators", {})
    out = {}
    for kind in ("contact", "glide"):
        vals = {name: e.get(kind, {}).get("gamma") for name, e in est.items()}
        vals = {k: v for k, v in vals.items() if v is not None}
        if vals:
            best = max(vals, key=vals.get)
            out[f"{kind} ({best})"] = vals[best]
    return out

def ledger_table(results: dict) -> list[str]:
    """App. C, the γ intervention ledger: best γ readout under each prediction-side mechanism."""
    rows = ledger_rows(results)
    if not rows:
        return []
    lines = ["## The γ intervention ledger (VFX; every prediction-side mechanism against drag)", "",
             "| mechanism | γ contact | γ glide | best γ (ours / paper) | velocity | glide test: model / median-γ | uses γ |",
             "|---|---|---|---|---|---|---|"]
    for label, r in rows:
        g = r["prediction"].get("glide_test", {})
        gt = f"{fmt(g.get('model'), 3)} / {fmt(g.get('median_gamma'), 3)}" if g else "—"
        uses = {True: "yes", False: "no"}.get(g.get("uses_gamma"), "—")
        lines.append(f"| {label} | {fmt(probe(r, 'gamma', 'contact'))} | {fmt(probe(r, 'gamma', 'glide'))} | "
                     f"{fmt(best_gamma(r))} / {LEDGER.get(label, '—')} | {fmt(probe(r, 'object_vel'))} | {gt} | {uses} |")
    certs = gamma_certificates(results)
    if certs:
        lines.append("\nγ certificates on the same corpus (best estimator per window kind): "
                     + ", ".join(f"{k} {fmt(v)}" for k, v in certs.items()) + ".")
    lines.append("\nBest γ = the largest of the ridge/MLP readouts on contact and glide windows that were run. "
                 "The paper adds mechanisms in sequence (single horizon → multi-horizon heads → motion channel); "
                 "our trunk has the temporal-difference channel by default, so its multi-horizon row is the "
                 "paper's \"+ motion channel\" stage and the motion-off row its \"multi-horizon heads\" stage. "
                 "Figure: `gamma_ledger.png`.")
    return lines + [""]

def ledger_figure(results: dict, out: Path) -> list[Path]:
    rows = ledger_rows(results)
    if not rows:
        return []
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    vals = [best_gamma(r) for _, r in rows]
    fig, ax = plt.subplots(figsize=(7.5, 0.45 * len(rows) + 1.4))
    y = np.arange(len(rows))
    ax.barh(y, [0.0 if v is None else v for v in vals], color="0.6")
    for yi, v in zip(y, vals):
        ax.text(max(v or 0.0, 0.0) + 0.01, yi, "—" if v is None else f"{v:.2f}", va="center", fontsize=8)
    for (label, v), ls in zip(gamma_certificates(results).items(), ("--", ":")):
        ax.axvline(v, color="k", ls=ls, lw=1, label=f"certificate, {label}: {v:.2f}")
    ax.set_yticks(y, [label for label, _ in rows])
    ax.invert_yaxis()
    ax.set_xlim(min(-0.05, min((v for v in vals if v is not None), default=0.0)), 1.0)
    ax.set_xlabel("best γ readout (held-out R²)")
    ax.set_title(f"γ intervention ledger (preset {results['provenance']['preset']})", fontsize=10)
    if gamma_certificates(results):
        ax.legend(fontsize=7, loc="lower right")
    else:  # a map run with --no-certify: say so rather than draw an empty key
        ax.text(0.99, 0.02, "no γ certificate in this map", transform=ax.transAxes, ha="right", fontsize=7)
    fig.tight_layout()
    return save_figure(fig, out, "gamma_ledger")


section = ledger_table


def figures(results: dict, out: Path) -> list[Path]:
    """The ledger's figure (nothing when the ledger did not run)."""
    return ledger_figure(results, out)


__all__ = ['NAME', 'LEDGER', 'LEDGER_MOTION_ALPHA', 'specs', 'section', 'figures', 'ledger_mechanism', 'ledger_rows', 'best_gamma', 'gamma_certificates', 'ledger_table', 'ledger_figure']
