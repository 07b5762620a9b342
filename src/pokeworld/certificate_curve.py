"""Fit-size curve of the recoverability certificates: held-out R² of each estimator against the number of
certificate-fit episodes, to find where each estimator plateaus and to read the gate there.

Every size is a prefix of one certificate corpus (pokeworld.certificate_corpus) of the largest size, so the curve
is nested: a larger fit set contains every smaller one. Scores are on the store's probe-test episodes throughout.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

from . import certificate_corpus, certify
from .config import Limit, check_fields, from_preset, to_dict
from .data import load
from .errors import ConfigError
from .io import write_json


@dataclass
class CurveConfig:
    """Certificate R² against certificate-fit episodes."""

    data: str = "data/pokeworld"
    """Store to certify (``pokeworld generate`` output); its probe-test split scores every point."""
    out: str = ""
    """JSON record to write (default: <data>/certificate_fit_curve.json)."""
    sizes: tuple[int, ...] = (240, 480, 960, 1920, 3840)
    """Certificate-fit episode counts (prefixes of one corpus of the largest size)."""
    preset: str = "cpu"
    """Certify preset of every point (estimator widths, epochs, patience)."""
    estimators: tuple[str, ...] = ("gru", "linear", "drag")
    """Estimators to trace."""
    kinds: tuple[str, ...] = ("contact",)
    """Window kinds (the gate reads contact windows)."""
    max_windows: int = 1_000_000
    """Cap on fit windows per point; the default leaves every size uncapped, so the curve measures data."""
    plateau_tol: float = 0.02
    """A curve has plateaued at the first size whose R² is within this of the largest size's."""

    LIMITS = {"sizes": Limit(1, 10**6), "max_windows": Limit(1, 10**9), "plateau_tol": Limit(0, 1)}

    def __post_init__(self) -> None:
        check_fields(self)
        if not self.sizes or min(self.sizes) < 1 or list(self.sizes) != sorted(set(self.sizes)):
            raise ConfigError(f"sizes must be increasing positive episode counts, got {self.sizes}")


PRESETS: dict[str, dict] = {
    "tiny": {"preset": "tiny", "sizes": (8, 16, 32)},
    "cpu": {},
    "paper": {"preset": "paper", "sizes": (240, 480, 960, 1920, 3840, 7680)},
}


def make_config(preset: str = "cpu", **overrides) -> CurveConfig:
    return from_preset(CurveConfig, PRESETS, preset, **overrides)


def plateau(points: list[tuple[int, float]], tol: float) -> int | None:
    """The first size whose R² is within ``tol`` of the largest size's (where more data stops helping), or None
    when only the largest size is: the curve is still rising at the end of the range."""
    last = points[-1][1]
    first = next(n for n, r2 in points if r2 >= last - tol)
    return None if first == points[-1][0] and len(points) > 1 else first


def run(cfg: CurveConfig) -> Path:
    """Certify ``cfg.data`` at every size; write the curve, each estimator's plateau and the gate read there."""
    ds = load(cfg.data)
    fit_ds = certificate_corpus.ensure(ds, cfg.data, max(cfg.sizes))
    points: dict[str, list] = {}
    for n in cfg.sizes:
        ccfg = certify.make_config(cfg.preset, data=cfg.data, estimators=cfg.estimators, kinds=cfg.kinds,
                                   fit_episodes=n, max_windows=cfg.max_windows)
        t0 = time.perf_counter()
        res = certify.certify(ds, ccfg, fit_ds)
        points[str(n)] = {"estimators": res["estimators"], "counts": res["counts"],
                          "seconds": time.perf_counter() - t0}
        print(f"[certificate-curve] {n} episodes: {res['counts']} in {points[str(n)]['seconds']:.0f} s")
    curves: dict = {}
    for est in cfg.estimators:
        for kind in cfg.kinds:
            by_target: dict[str, list] = {}
            for n in cfg.sizes:
                for t, r2 in points[str(n)]["estimators"].get(est, {}).get(kind, {}).items():
                    by_target.setdefault(t, []).append((n, r2))
            for t, pts in by_target.items():
                curves.setdefault(est, {}).setdefault(kind, {})[t] = {
                    "points": pts, "plateau_episodes": plateau(pts, cfg.plateau_tol)}
    largest = points[str(max(cfg.sizes))]["estimators"]
    gate = certify.gate(certify.certificate_table(largest, ("log_m", "gamma", "log_k")), largest)
    record = {"config": to_dict(cfg), "points": points, "curves": curves,
              "gate_at_largest": gate, "fit_corpus_seed": fit_ds.manifest.get("seed"),
              "dataset": {"path": cfg.data, "content_sha256": ds.manifest.get("content_sha256")}}
    out = Path(cfg.out) if cfg.out else Path(cfg.data) / "certificate_fit_curve.json"
    write_json(out, record)
    print(markdown(record))
    return out


def markdown(record: dict) -> str:
    """The curve as a table: one row per estimator and target, one column per size, and the plateau."""
    sizes = record["config"]["sizes"]
    lines = ["| estimator | window kind | target | " + " | ".join(f"{n} ep." for n in sizes) + " | plateau from |",
             "|---|---|---|" + "---|" * (len(sizes) + 1)]
    for est, kinds in record["curves"].items():
        for kind, targets in kinds.items():
            for t, c in targets.items():
                vals = dict(c["points"])
                lines.append(f"| {est} | {kind} | {t} | " + " | ".join(
                    f"{vals[n]:+.2f}" if n in vals else "—" for n in sizes) + f" | {c['plateau_episodes'] or 'still rising'} |")
    return "\n".join(lines)


__all__ = ["CurveConfig", "PRESETS", "make_config", "plateau", "run", "markdown"]
