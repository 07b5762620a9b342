"""A map's runs and where they live: :class:`RunSpec` (one training run and how to measure it), the naming rule
that makes a run's directory a function of its factors (so runs shared by experiments train once), and the paths
of corpora, run directories and measurements inside a map folder."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from ..evaluate.measure import measure_path
from ..losses import DEFAULT_GNLL_VARIANCE
from ..train.config import field_defaults

if TYPE_CHECKING:
    from .config import MapConfig

@dataclass(frozen=True)
class RunSpec:
    """One training run and how to measure it."""

    name: str
    experiment: str
    corpus: str = "standard"
    """Training corpus."""
    measure_corpus: str = "standard"
    """Corpus the probes are fit and tested on."""
    train: dict = field(default_factory=dict)
    """TrainConfig overrides (variant, horizons, sigreg_weight, ...)."""
    seed: int = 0
    measure: dict = field(default_factory=dict)
    """MeasureConfig overrides (probe window, stride, prediction context); empty for the paper's protocol."""

def horizon_tag(horizons) -> str:
    """A run name's horizon field: h1-4-16."""
    return "h" + "-".join(map(str, horizons))

def spec(exp, variant, seed, lam, horizons=(1, 4, 16), corpus="standard", measure_corpus="standard",
         measure: dict | None = None, **extra) -> RunSpec:
    """The run of ``exp`` with these factors; ``extra`` are TrainConfig overrides, named in the run's name."""
    # an override equal to the training default is the default run itself: it keeps the plain name, so a
    # dose level that equals the operating point (touch contact weight 4, glide weight 1) shares the factorial's run
    defaults = field_defaults()
    extra = {k: v for k, v in extra.items() if not (k in defaults and defaults[k] == v)}
    tag = "".join(f"-{k}{v}" for k, v in sorted(extra.items()))
    name = f"{variant}-{horizon_tag(horizons)}-lam{lam:g}-{corpus}{tag}-s{seed}"
    train = dict(variant=variant, horizons=tuple(horizons), sigreg_weight=lam, seed=seed, **extra)
    return RunSpec(name, exp, corpus, measure_corpus, train, seed, dict(measure or {}))

def with_map_training(c: MapConfig, run: RunSpec) -> RunSpec:
    """``run`` with the map-wide training choices (``sigreg_pool``, ``sigreg_reference_rows``, ``gnll_variance``)
    applied where they apply;
    a changed run is renamed through :func:`spec`, so it never shares a directory with the default run."""
    t = run.train
    extra = {}
    if c.sigreg_pool != "step" and not t.get("tokens") and t.get("objective", "latent") != "recon":
        extra["sigreg_pool"] = c.sigreg_pool
    if c.sigreg_reference_rows and not t.get("tokens") and t.get("objective", "latent") != "recon":
        extra["sigreg_reference_rows"] = c.sigreg_reference_rows
    if c.gnll_variance != DEFAULT_GNLL_VARIANCE and t.get("objective") == "gnll":
        extra["gnll_variance"] = c.gnll_variance
    if not extra:
        return run
    rest = {k: v for k, v in t.items() if k not in ("variant", "horizons", "sigreg_weight", "seed")}
    return spec(run.experiment, t["variant"], t["seed"], t["sigreg_weight"], t["horizons"], run.corpus,
                run.measure_corpus, run.measure, **rest, **extra)

def corpus_dir(c: MapConfig, corpus: str) -> Path:
    """Where the map keeps corpus ``corpus``."""
    return Path(c.out) / "data" / corpus

def spec_measure_path(c: MapConfig, s: RunSpec) -> Path:
    """The measure.json the map writes for run ``s`` (on its measure corpus when that differs from its training one)."""
    data = str(corpus_dir(c, s.measure_corpus)) if s.measure_corpus != s.corpus else ""
    return measure_path(run_dir(c, s.name), data)


def run_dir(c: MapConfig, name: str) -> Path:
    """The directory of run ``name`` in the map folder."""
    return Path(c.out) / "runs" / name


__all__ = ["RunSpec", "horizon_tag", "spec", "with_map_training", "corpus_dir", "run_dir",
           "spec_measure_path"]
