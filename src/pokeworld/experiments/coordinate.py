"""The coordinate test (paper App. C): VFX with a frozen self-supervised flow sensor's velocity and log speed
as input, beside the factorial's VFX."""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..evaluate.tables import fmt, probe
from .runs import RunSpec, spec

if TYPE_CHECKING:
    from .config import MapConfig

COORDINATE = {  # App. C "The coordinate test" and the γ ledger (frozen flow velocity sensor)
    "gamma_linear_certificate_logspeed": 0.52,  # ridge on log-speed sequences over glide windows (696/351)
    "gamma_linear_certificate_standard": 0.0,  # Table "matrix": ≈ 0 in the standard coordinates
    "gamma_glide_readout": (0.08, 0.33),  # model readout on glide windows, before / after (ridge)
    "object_vel": (0.79, 0.88),  # velocity readout before / after the frozen flow sensor (ledger)
    "glide_test_model_after": 0.114,  # functional glide test with the log-speed channel
    "glide_test_median_gamma": 0.054,  # its median-γ reference
}


NAME = "coordinate"


def specs(c: MapConfig) -> list[RunSpec]:
    """The coordinate test (App. C): VFX on the ``flow`` corpus (a frozen self-supervised flow sensor's velocity
    and log speed appended to proprioception) beside the factorial's VFX on the standard corpus."""
    s, lam = c.seeds[0], c.sigreg_weight
    return [spec("factorial", "VFX", s, lam), spec("coordinate", "VFX", s, lam, corpus="flow", measure_corpus="flow")]


def coordinate_table(results: dict) -> list[str]:
    """App. C "The coordinate test": VFX without and with the sensed log-speed channel."""
    if "coordinate" not in results["experiments"]:
        return []
    runs = {results["runs"][n]["corpus"]: results["runs"][n] for n in results["experiments"]["coordinate"]}
    before, after = runs.get("standard"), runs.get("flow")
    certs = results["certificates"]
    lin = lambda corpus, est: certs.get(corpus, {}).get("estimators", {}).get(est, {}).get("glide", {}).get("gamma")  # noqa: E731
    C = COORDINATE
    gl = lambda r, k: None if r is None else r["prediction"].get("glide_test", {}).get(k)  # noqa: E731
    pr = lambda r, q, kind: None if r is None else probe(r, q, kind)  # noqa: E731
    rows = [("linear γ certificate, glide windows (standard coordinates / log-speed sequence)",
             lin("standard", "linear"), lin("flow", "linear_logspeed"),
             (C["gamma_linear_certificate_standard"], C["gamma_linear_certificate_logspeed"]), 2),
            ("model γ readout, glide windows (ridge)", pr(before, "gamma", "glide"), pr(after, "gamma", "glide"),
             C["gamma_glide_readout"], 2),
            ("object-velocity readout, contact windows (ridge)", pr(before, "object_vel", "contact"),
             pr(after, "object_vel", "contact"), C["object_vel"], 2),
            ("γ readout, contact windows (ridge)", pr(before, "gamma", "contact"), pr(after, "gamma", "contact"),
             (None, None), 2),
            ("log k readout, contact windows (ridge)", pr(before, "log_k", "contact"), pr(after, "log_k", "contact"),
             (None, None), 2),
            ("functional glide test: model error (decoded)", gl(before, "model"), gl(after, "model"),
             (None, C["glide_test_model_after"]), 3),
            ("functional glide test: median-γ reference", gl(before, "median_gamma"), gl(after, "median_gamma"),
             (None, C["glide_test_median_gamma"]), 3)]
    lines = ["## The coordinate test (VFX; a frozen self-supervised flow sensor's velocity and log speed as input)", "",
             "| quantity | before (ours / paper) | with the log-speed channel (ours / paper) |", "|---|---|---|"]
    for label, b, a, (pb, pa), d in rows:
        lines.append(f"| {label} | {fmt(b, d)} / {fmt(pb, d)} | {fmt(a, d)} / {fmt(pa, d)} |")
    sensor = certs.get("flow", {}).get("flow_sensor", {})
    if sensor:
        lines.append("\nFlow sensor on probe-test episodes (trained on frames only, labels used to score): "
                     f"velocity R² {fmt(sensor.get('velocity_r2'))}, on glide frames "
                     f"{fmt(sensor.get('glide_velocity_r2'))}, glide log speed {fmt(sensor.get('glide_log_speed_r2'))}.")
    lines.append("\nThe model uses γ functionally only if its glide-test error beats the median-γ reference; the "
                 "paper's γ readout and certificate here are on glide windows, the velocity pair is the γ ledger's "
                 "frozen flow velocity sensor.")
    return lines + [""]


section = coordinate_table


__all__ = ['NAME', 'COORDINATE', 'specs', 'section', 'coordinate_table']
