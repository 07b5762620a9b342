"""The factor table of ``pokeworld swm-certify``: certificate, model R² and gate per physical factor, and its figure.

One row per factor: the certificate (best of the GRU oracle, the linear floor and the local-dynamics fit, held-out
R² from raw non-pixel observations and actions, :mod:`pokeworld.swm.factor_gate`), the model's leak-free probes
(ridge, MLP) and the untrained twin's ridge probe from :func:`pokeworld.protocol.certify_model`'s report, and the
gate. A factor whose gate failed gets † on its model numbers and the status "no claim": the model's R² then says
nothing about whether the model knows it, since the raw observations may not carry it either.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..io import save_figure_as
from .factor_gate import KIND


def factor_rows(report: dict, certificates: dict) -> dict[str, dict]:
    """Per factor: certificate, estimator R², model ridge / MLP / action-conditioned, untrained, gate, status."""
    get = lambda block, fam, q: report.get(block, {}).get(fam, {}).get(KIND, {}).get(q)  # noqa: E731
    rows = {}
    for q, g in certificates["gate"].items():
        est = {e: r[KIND].get(q) for e, r in certificates["estimators"].items() if KIND in r}
        rows[q] = {"certificate": g.get("certificate"), "certificate_estimator": g.get("estimator"),
                   "gru_oracle": est.get("gru"), "linear_floor": est.get("linear"),
                   "local_dynamics": est.get("sysid"), "threshold": g["threshold"],
                   "gate_passed": bool(g["passed"]), "paper_rule_passed": bool(g["paper_rule_passed"]),
                   "ridge": get("probes", "ridge", q), "mlp": get("probes", "mlp", q),
                   "action_conditioned": get("probes_action_conditioned", "ridge", q),
                   "untrained": get("untrained", "ridge", q),
                   "status": "claim" if g["passed"] else "no claim (gate failed)"}
    return rows


def fmt(v: float | None) -> str:
    return "—" if v is None else f"{v:+.2f}"


def table_markdown(rows: dict[str, dict], model: str) -> list[str]:
    """The markdown table: factor | certificate | model R² (ridge, MLP) | untrained | gate."""
    lines = [f"| factor | certificate (GRU oracle / linear floor / local dynamics) | {model} R² ridge / MLP | "
             "untrained ridge | gate |",
             "|---|---|---|---|---|"]
    for q, r in rows.items():
        mark = "" if r["gate_passed"] else "†"
        verdict = "PASS" if r["gate_passed"] else "FAIL: no claim"
        lines.append(f"| {q} | {fmt(r['certificate'])} ({fmt(r['gru_oracle'])} / {fmt(r['linear_floor'])} / "
                     f"{fmt(r.get('local_dynamics'))}) | "
                     f"{fmt(r['ridge'])}{mark} / {fmt(r['mlp'])}{mark} | {fmt(r['untrained'])} | "
                     f"{verdict} (≥ {r['threshold']:.2f}) |")
    return lines


def figure(rows: dict[str, dict], model: str, path: Path) -> Path:
    """Bars per factor: certificate, GRU oracle, linear floor, model ridge / MLP, untrained; gate threshold dashed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    qs = list(rows)
    series = [("certificate (gate)", "certificate", "0.75"), ("GRU oracle", "gru_oracle", "0.45"),
              ("linear floor", "linear_floor", "0.6"), ("local dynamics", "local_dynamics", "0.3"),
              (f"{model} ridge", "ridge", "tab:blue"),
              (f"{model} MLP", "mlp", "tab:cyan"), ("untrained ridge", "untrained", "tab:orange")]
    series = [s for s in series if any(rows[q].get(s[1]) is not None for q in qs)]
    fig, ax = plt.subplots(figsize=(1.6 * len(qs) + 3.0, 3.6))
    width, x = 0.8 / len(series), np.arange(len(qs))
    for i, (label, key, color) in enumerate(series):
        vals = np.clip([np.nan if rows[q].get(key) is None else rows[q][key] for q in qs], -0.1, 1.0)
        # a model bar for a factor whose gate failed is hatched: its height is no claim
        model_bar = key in ("ridge", "mlp", "untrained")
        hatch = ["//" if model_bar and not rows[q]["gate_passed"] else "" for q in qs]
        for j, v in enumerate(vals):
            if np.isfinite(v):
                ax.bar(x[j] + (i - (len(series) - 1) / 2) * width, v, width, color=color, hatch=hatch[j],
                       edgecolor="black" if hatch[j] else color, label=label if j == 0 else None)
    for j, q in enumerate(qs):
        ax.plot([x[j] - 0.4, x[j] + 0.4], [rows[q]["threshold"]] * 2, color="red", lw=1, ls="--")
        if not rows[q]["gate_passed"]:
            ax.text(x[j], 1.03, "gate ✗: no claim", ha="center", fontsize=8, color="red")
    ax.axhline(0, color="black", lw=0.5)
    ax.set_xticks(x, qs, fontsize=8)
    ax.set_ylim(-0.1, 1.12)
    ax.set_ylabel("held-out R² (all windows)")
    ax.set_title(f"{model}: physical factors vs their certificates (dashed: gate threshold)", fontsize=9)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    fig.tight_layout()
    save_figure_as(fig, [path])  # atomically, then closed
    return path


__all__ = ["factor_rows", "figure", "fmt", "table_markdown"]
