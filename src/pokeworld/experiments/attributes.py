"""The attribute matrix (paper App. C Table "matrixfull"): stiffness, force bias at three ranges, drag and
actuator gain, each against its linear and recurrent certificates."""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..evaluate.tables import (
    dagger,
    fmt,
    gate_failed,
    mean_all,
    mean_over,
    probe,
    variant_runs,
)
from .runs import RunSpec, spec

if TYPE_CHECKING:
    from .config import MapConfig

ATTRIBUTES = {  # App. C Table "matrixfull": cell -> linear cert., recurrent cert., model readout, model / recurrent
    # ("≈0" cells are stored as 0.0; a range is stored as a (low, high) pair)
    "stiffness": {"linear": 0.0, "recurrent": 0.87, "model": (0.50, 0.62), "ratio": (0.6, 0.7)},
    "bias0.5": {"linear": 0.13, "recurrent": 0.92, "model": 0.13, "ratio": 0.14},
    "bias1.5": {"linear": 0.51, "recurrent": 0.96, "model": 0.39, "ratio": 0.41},
    "bias2.5": {"linear": 0.65, "recurrent": 0.96, "model": 0.65, "ratio": 0.68},
    "drag": {"linear": 0.0, "recurrent": 0.89, "model": 0.13, "ratio": 0.15},
    "gain": {"linear": -0.01, "recurrent": 0.69, "model": -0.01, "ratio": 0.0},
}


NAME = "attributes"


def specs(c: MapConfig) -> list[RunSpec]:
    return [spec("attributes", "VFX", c.seeds[0], c.sigreg_weight, corpus=corp, measure_corpus=corp)
            for corp in c.attribute_corpora]


CORPUS_TARGETS = {"bias0.5": ("bias_x", "bias_y"), "bias1.5": ("bias_x", "bias_y"), "bias2.5": ("bias_x", "bias_y"),
                  "gain": ("gain",)}


#: Attribute-matrix cells: (row key of ATTRIBUTES, cell, parameter, corpus, probed quantities). A parameter
#: probed as several components (the 2-d force bias) scores the mean R² of its components.
ATTRIBUTE_CELLS = (("stiffness", "fast × ratio", "stiffness k", "standard", ("log_k",)),
                   ("bias0.5", "slow × linear, b ∈ ±0.5", "force bias", "bias0.5", ("bias_x", "bias_y")),
                   ("bias1.5", "slow × linear, b ∈ ±1.5", "force bias", "bias1.5", ("bias_x", "bias_y")),
                   ("bias2.5", "slow × linear, b ∈ ±2.5", "force bias", "bias2.5", ("bias_x", "bias_y")),
                   ("drag", "slow × ratio, gated", "drag γ", "standard", ("gamma",)),
                   ("gain", "slow × ratio, ungated", "actuation gain g", "gain", ("gain",)))

RECURRENT_ESTIMATORS = ("gru", "gru_geom")

def attribute_matrix_table(results: dict) -> list[str]:
    """App. C Table "matrixfull": per cell the linear and recurrent certificates, the model's readout (ridge,
    MLP in parentheses) and readout / recurrent certificate. Stiffness and drag come from the standard corpus
    and the factorial's VFX runs, the bias and gain cells from the attributes corpora and their VFX runs."""
    if "attributes" not in results["experiments"]:
        return []
    certs = results["certificates"]
    vfx_std = variant_runs(results, "factorial", "VFX")
    by_corpus = {results["runs"][n]["corpus"]: results["runs"][n] for n in results["experiments"]["attributes"]}

    def cert(corpus, estimators, qs):
        est = certs.get(corpus, {}).get("estimators", {})
        per = {e: mean_all([est.get(e, {}).get("contact", {}).get(q) for q in qs]) for e in estimators}
        per = {e: v for e, v in per.items() if v is not None}
        return (max(per.values()), max(per, key=per.get)) if per else (None, None)

    def model(corpus, qs, family):
        runs = vfx_std if corpus == "standard" else [by_corpus[corpus]] if corpus in by_corpus else []
        return mean_over(runs, lambda r: mean_all([probe(r, q, "contact", family) for q in qs]))

    lines = ["## The attribute matrix (VFX; contact windows; ours / paper)", "",
             "| cell | parameter | linear cert. | recurrent cert. | model: ridge (MLP) | model / recurrent cert. |",
             "|---|---|---|---|---|---|"]
    paper_cell = lambda v: "—" if v is None else f"{v[0]:.2f}–{v[1]:.2f}" if isinstance(v, tuple) else f"{v:+.2f}"  # noqa: E731
    for key, cell, param, corpus, qs in ATTRIBUTE_CELLS:
        p = ATTRIBUTES[key]
        lin, _ = cert(corpus, ("linear",), qs)
        rec, rec_est = cert(corpus, RECURRENT_ESTIMATORS, qs)
        ridge, mlp = model(corpus, qs, "ridge"), model(corpus, qs, "mlp")
        ratio = ridge / rec if ridge is not None and rec else None
        mark = dagger(any(gate_failed(results, q, corpus) for q in qs if q in ("log_m", "gamma", "log_k")))
        lines.append(f"| {cell} | {param} | {fmt(lin)} / {paper_cell(p['linear'])} | {fmt(rec)}"
                     f"{f' ({rec_est})' if rec_est else ''} / {paper_cell(p['recurrent'])} | {fmt(ridge)}"
                     f"{f' ({fmt(mlp)})' if mlp is not None else ''}{mark} / {paper_cell(p['model'])} | "
                     f"{fmt(ratio)} / {paper_cell(p['ratio'])} |")
    drag = certs.get("standard", {}).get("estimators", {}).get("drag", {}).get("contact", {}).get("gamma")
    lines.append("\nRecurrent certificate = the best of the GRU estimators (named); a 2-d force bias scores the mean "
                 "of its two components' R². Certificates are lower bounds, so model / recurrent certificate is a "
                 "comparison with the best simple estimator, not a fraction of the truth."
                 + (f" Drag's physics-informed certificate: {fmt(drag)} (paper 0.89, the instrument the paper's gate "
                    "reads for drag)." if drag is not None else ""))
    return lines + [""]


section = attribute_matrix_table


__all__ = ['NAME', 'ATTRIBUTES', 'CORPUS_TARGETS', 'ATTRIBUTE_CELLS', 'RECURRENT_ESTIMATORS', 'specs', 'section', 'attribute_matrix_table']
