"""The map's presets (tiny, cpu, paper) and the demo's, and the check of a config's experiment and corpus names
against the registry."""

from __future__ import annotations

import dataclasses

from ..config import from_preset
from ..errors import ConfigError
from .attributes import CORPUS_TARGETS
from .config import MapConfig
from .controls import CONTROL_RUNS
from .registry import EXPERIMENTS

PRESETS: dict[str, dict] = {
    "tiny": {"preset": "tiny", "experiments": ("factorial",), "variants": ("V", "VX_t"), "seeds": (0,),
             "mlp_probes": False, "certify_estimators": ("linear", "drag"), "untrained": False},
    "cpu": {"preset": "cpu", "seeds": (0,)},
    "paper": {"preset": "paper"},
}

DEMO = {  # the newcomer's first run: four variants, one seed; 7 min 02 s measured on 2 idle cores (docs/results/demo.md)
    "experiments": ("factorial",), "variants": ("V", "VF", "VX_t", "VFX"), "seeds": (0,),
    # the cpu map's corpus: a 1,200-episode one halves the probe-fit split, and a ridge readout fit on 240 episodes
    # under-reads a weak signal (VFX log k 0.06 vs 0.10 for one checkpoint, docs/model.md "Learning speed")
    # the model: train's "demo" preset (cpu sizes, 64-wide vector encoders, batch 8, 2,200 steps, the reference's
    # loss weighting: VFX − VF +0.32 against +0.22 with the first objective, docs/results/demo_levers_cpu.md); probes read
    # contact windows only, the ones the demo's tables show
    "train_preset": "demo", "measure_kinds": ("contact",),
    # a ridge readout of a 128-d state at R² ≈ 0.25 is fit-set limited (the same checkpoint reads 0.27 from 5.4k
    # probe-fit windows and 0.29 from 10.7k, docs/model.md "Learning speed"), and 2,200 steps × 8 windows
    # sample fewer windows than 960 training episodes hold: 40 % of the episodes go to the probe-fit split
    "split_fractions": (0.4, 0.4, 0.2), "measure_max_windows": 12000,
    "num_episodes": 2400, "mlp_probes": False, "untrained": False,
    # certificates for the demo only: the paper's GRU oracle, the geometry GRU that certifies log k, the
    # linear floor and the drag estimator, on contact windows, with a smaller fit set and fewer epochs
    "certify_estimators": ("gru", "gru_geom", "linear", "drag"), "certify_kinds": ("contact",),
    "certify_max_windows": 3000, "certify_epochs": 60, "certify_separate_targets": False,
    # ... on the corpus's own probe-fit split: a certificate corpus would add its generation to the demo's budget
    # and its 3,000-window cap would leave it fit-set limited all the same
    "certify_fit_episodes": 0,
    # one whole-job time estimate from the start, kept current from each stage's measured rate (DEMO_STAGE_SECONDS)
    "whole_job_estimate": True,
}

#: What the demo's stages cost on the reference machine (2 idle cores; `python benchmarks/train_cpu.py` 8.03–8.35
#: model-steps/s for two `cpu` models side by side), in seconds: the priors of the demo's whole-job estimate
#: (:func:`.stages.whole_job_costs`), scaled by a training step timed on this machine at the start; a stage that
#: reports its progress (a certificate's epochs, training's steps) is then estimated from its own measured rate.
#: With the timed training (4 runs x 2,200 steps, two at a time, ~5 min) they add up to the measured idle demo on
#: the reference environment (7 min 02 s, docs/results/demo.md): its two GRU certificates took 20 and 18 s on a
#: machine whose training step was 1.2x the reference's.
DEMO_STAGE_SECONDS = {"corpus": 10.0, "certificate gru": 17.0, "certificate gru_geom": 15.0, "certificate": 1.0,
                      "measure per run": 12.0, "report": 5.0}
#: One demo model's step on one thread of the reference machine (benchmarks/results/train_cpu_demo.json, "one
#: model, 1 thread"): a step timed now over this is how much slower this machine is now (its load included).
DEMO_REFERENCE_S_PER_STEP = 0.0677

def make_config(preset: str = "cpu", **overrides) -> MapConfig:
    """The map config of a preset (tiny, cpu, paper) with field overrides."""
    return check_names(from_preset(MapConfig, PRESETS, preset, **overrides))

def make_demo_config(preset: str = "cpu", **overrides) -> MapConfig:
    """The demo's map config (:data:`DEMO` over the preset; at tiny only its experiment list)."""
    cfg = from_preset(MapConfig, PRESETS, preset)
    demo = {k: v for k, v in DEMO.items() if preset != "tiny" or k in ("experiments",)}
    return check_names(dataclasses.replace(cfg, **{"out": "out/demo", **demo, **overrides}))


def check_names(c: MapConfig) -> MapConfig:
    """``c``, after checking its experiment, attribute-corpus and control-run names (ConfigError)."""
    bad = set(c.experiments) - set(EXPERIMENTS)
    if bad:
        raise ConfigError(f"unknown experiments {sorted(bad)}; choose from {sorted(EXPERIMENTS)}")
    bad_corpora = set(c.attribute_corpora) - set(CORPUS_TARGETS)
    if bad_corpora:
        raise ConfigError(f"unknown attribute corpora {sorted(bad_corpora)}; choose from {sorted(CORPUS_TARGETS)}")
    bad_controls = set(c.control_runs) - set(CONTROL_RUNS)
    if bad_controls:
        raise ConfigError(f"unknown control runs {sorted(bad_controls)}; choose from {list(CONTROL_RUNS)}")
    return c


__all__ = ["PRESETS", "DEMO", "DEMO_STAGE_SECONDS", "DEMO_REFERENCE_S_PER_STEP", "make_config", "make_demo_config", "check_names"]
