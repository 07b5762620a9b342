"""Observable corpus statistics that the paper reports, and the calibration of PokeWorld's free constants.

The paper leaves F_max, finger damping, policy gains, mode weights and launch speeds
open, but it reports observables of its default corpus that pin them (docs/design.md,
"Calibration"). All statistics use windows of 8 context + 16 future observations at
stride 4; t is the last context observation (window start + 7):

* ``static16``: mean ‖p(t+16) − p(t)‖ of the object over all windows — the error of
  the static predictor (paper 0.205–0.21: λ-table caption, §4.2);
* ``static8``: the same at 8 steps (paper 0.109, App. C "open-loop 8-step");
* ``glide_static16``: ``static16`` over pure-glide futures — no finger contact and no
  wall contact over t…t+16 and object speed > 0.02 at t (paper 0.144, the ledger);
* ``glide_median_gamma16``: on the same windows, the error of the population-median-γ
  reference p + v(1 − e^{−γ̃T})/γ̃, T = 16·dt (paper 0.049–0.054);
* ``glide_loss_share``: the fraction of prediction targets that are glide frames
  (no finger contact, no wall contact, object speed > 0.02), i.e. the glide loss share
  at glide weight 1 (paper 32 %, Dose–response 1).

``pokeworld stats DATA`` prints them beside the paper's values; the generator writes
them into every simulator manifest.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..config import check_fields
from ..data import Dataset, load
from ..errors import DataError
from ..published.paper import CORPUS_STATS
from ..windows import glide_frames, wall_contact

CONTEXT, HORIZON = 8, 16

#: statistic -> (paper value or (lo, hi) range, where the paper reports it)
PAPER_STATS = CORPUS_STATS
#: relative tolerance of the calibration (issue "Protocol fidelity": within ±15 % of each paper value)
TOLERANCE = 0.15


def corpus_stats(ds: Dataset, stride: int = 4, min_speed: float = 0.02) -> dict[str, float]:
    """The observable statistics of a simulator corpus (needs ``labels/object_pos``, ``object_vel``, ``contact``)."""
    for name in ("object_pos", "object_vel", "contact"):
        if name not in ds.labels:
            raise DataError(f"corpus statistics need labels/{name}; this store has {sorted(ds.labels)} "
                            "(converted real-robot stores have no object labels)")
    T1 = ds.labels["object_pos"].shape[1]
    if T1 < CONTEXT + HORIZON:
        raise DataError(f"episodes of {T1} observations are shorter than the {CONTEXT + HORIZON}-step windows")
    dt = float(ds.manifest.get("config", {}).get("physics", {}).get("dt", 0.05))
    t = np.arange(0, T1 - CONTEXT - HORIZON + 1, stride) + CONTEXT - 1  # last context observation
    pos, vel = ds.labels["object_pos"].astype(np.float64), ds.labels["object_vel"].astype(np.float64)
    p0, v0 = pos[:, t], vel[:, t]
    disp = lambda k: np.linalg.norm(pos[:, t + k] - p0, axis=-1)  # noqa: E731
    out = {"static16": float(disp(HORIZON).mean()), "static8": float(disp(8).mean())}

    # pure-glide futures: no finger or wall contact over t..t+16, moving at t
    span = t[:, None] + np.arange(HORIZON + 1)[None, :]
    touching = (ds.labels["contact"] > 0)[:, span].any(-1) | wall_contact(ds)[:, span].any(-1)
    glide = ~touching & (np.linalg.norm(v0, axis=-1) > min_speed)
    out["glide_windows"] = int(glide.sum())
    out["glide_window_fraction"] = float(glide.mean())
    if glide.sum():
        T = HORIZON * dt
        g_med = float(np.median(ds.params["gamma"]))
        ref = p0[glide] + v0[glide] * (1 - np.exp(-g_med * T)) / g_med
        truth = pos[:, t + HORIZON][glide]
        out["glide_static16"] = float(disp(HORIZON)[glide].mean())
        out["glide_median_gamma16"] = float(np.linalg.norm(ref - truth, axis=-1).mean())
    else:
        out["glide_static16"] = out["glide_median_gamma16"] = float("nan")
    out["glide_loss_share"] = float(glide_frames(ds, min_speed)[:, 1:].mean())
    out["contact_frame_share"] = float((ds.labels["contact"][:, 1:] > 0).mean())
    return out


def paper_range(name: str) -> tuple[float, float]:
    v = PAPER_STATS[name][0]
    return (v, v) if isinstance(v, float) else v


def within_tolerance(name: str, value: float, tol: float = TOLERANCE) -> bool:
    """``value`` lies within ``tol`` (relative) of the paper's value (or of its reported range)."""
    lo, hi = paper_range(name)
    return lo * (1 - tol) <= value <= hi * (1 + tol)


def format_stats(stats: dict[str, float]) -> str:
    rows = [f"{'statistic':24s} {'ours':>8s} {'paper':>13s}  within ±{TOLERANCE:.0%}  source"]
    for name, (_, src) in PAPER_STATS.items():
        lo, hi = paper_range(name)
        paper = f"{lo:.3f}" if lo == hi else f"{lo:.3f}–{hi:.3f}"
        v = stats.get(name, float("nan"))
        ok = "yes" if within_tolerance(name, v) else "NO"
        rows.append(f"{name:24s} {v:8.3f} {paper:>13s}  {ok:^10s}  {src}")
    rows.append(f"(pure-glide windows: {stats.get('glide_windows', 0)}, "
                f"{stats.get('glide_window_fraction', 0):.1%} of all; contact frames "
                f"{stats.get('contact_frame_share', 0):.1%})")
    return "\n".join(rows)


@dataclass
class StatsConfig:
    """Print a corpus's observable statistics beside the paper's."""

    data: str = "data/pokeworld"
    """Store written by ``pokeworld generate``."""

    def __post_init__(self) -> None:
        check_fields(self)


def make_config(preset: str = "cpu", **overrides) -> StatsConfig:
    # one job, no size knobs: every preset is the same
    return StatsConfig(**overrides)


def run(cfg: StatsConfig) -> dict[str, float]:
    ds = load(cfg.data)
    stats = corpus_stats(ds)
    print(f"[stats] {cfg.data} ({ds.num_episodes} episodes)")
    print(format_stats(stats))
    return stats


__all__ = ["PAPER_STATS", "TOLERANCE", "corpus_stats", "within_tolerance", "format_stats", "StatsConfig", "run"]
