"""A protocol report in numbers, and the same protocol on trained X-JEPA runs beside another model's report.

:func:`summarize` turns a :func:`pokeworld.protocol.certify_model` report into its raw numbers (per window kind and
quantity: ridge / MLP / untrained-bound R², the certificate, the gate verdict). :func:`certify_run` certifies an
X-JEPA run directory through the same protocol — its state is the one ``pokeworld probe`` reads
(``XJEPA.features``: encoder and trunk, the leak-free readout zeroing the action after the window) and its
untrained bound is :func:`pokeworld.evaluate.measure.untrained_copy` — so a stable-worldmodel model and our
variants are read by the same probes on the same corpus; :func:`comparison_markdown` puts them side by side.
"""

from __future__ import annotations

from pathlib import Path

from .. import protocol as P
from ..evaluate.measure import untrained_copy
from ..io import write_json
from ..rundir import load_model

TABLE_QUANTITIES = ("log_m", "gamma", "log_k", "object_pos", "object_vel", "finger_pos", "object_rel")
"""Rows of the comparison table, in this order (those a report lacks are left out)."""


def summarize(report: dict) -> dict:
    """Raw numbers of a protocol report: per window kind and quantity ridge / MLP / untrained R², the
    certificate (best estimator, contact windows) and the gate verdict."""
    probes, unt = report["probes"], report.get("untrained", {})
    cert = report["certificates"]["certificate"].get("contact", {})
    table: dict = {}
    for kind, per_q in probes.get("ridge", {}).items():
        table[kind] = {q: {"ridge": r2, "mlp": probes.get("mlp", {}).get(kind, {}).get(q),
                           "untrained_ridge": unt.get("ridge", {}).get(kind, {}).get(q),
                           "certificate": (cert.get(q) or {}).get("r2") if kind == "contact" else None}
                       for q, r2 in per_q.items()}
    gate = {q: {"passed": g["passed"], "certificate": g.get("certificate"), "threshold": g["threshold"]}
            for q, g in report["certificates"]["gate"].items()}
    return {"model": report["model"], "r2": table, "gate": gate,
            "claims": {q: c["status"] for q, c in report["claims"].items()},
            "action_conditioned_ridge": report.get("probes_action_conditioned", {}).get("ridge", {}),
            "seconds": report["provenance"]["seconds"]}


def certify_run(run_dir: str, data: str, out: Path, config: P.ProtocolConfig) -> dict:
    """Certify the trained X-JEPA run ``run_dir`` on ``data`` with ``config``; writes ``out``/summary.json."""
    model = load_model(run_dir).eval()
    name = f"X-JEPA {Path(run_dir).name}"
    report = P.certify_model(model.features, data, out, untrained=untrained_copy(model).features, name=name,
                             config=config)
    summary = {"run_dir": str(run_dir), **summarize(report)}
    write_json(Path(out) / "summary.json", summary)
    return summary


def comparison_markdown(summaries: dict[str, dict], kind: str = "contact") -> list[str]:
    """Markdown rows: quantity, certificate, then per model 'ridge / MLP / untrained ridge' on ``kind`` windows."""
    names = list(summaries)
    first = summaries[names[0]]["r2"].get(kind, {})
    fmt = lambda x: "—" if x is None else f"{x:+.2f}"  # noqa: E731
    lines = [f"| quantity ({kind} windows) | certificate | " + " | ".join(names) + " |",
             "|---|---|" + "---|" * len(names)]
    for q in (q for q in TABLE_QUANTITIES if q in first):
        cells = []
        for n in names:
            c = summaries[n]["r2"].get(kind, {}).get(q, {})
            cells.append(f"{fmt(c.get('ridge'))} / {fmt(c.get('mlp'))} / {fmt(c.get('untrained_ridge'))}")
        lines.append(f"| {q} | {fmt(first[q].get('certificate'))} | " + " | ".join(cells) + " |")
    return lines


__all__ = ["TABLE_QUANTITIES", "summarize", "certify_run", "comparison_markdown"]
