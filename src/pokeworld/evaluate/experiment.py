"""The identifiability map end to end: generate -> certify -> train the runs -> measure -> report.

Experiments are named, runnable definitions (:data:`EXPERIMENTS`), each a
function from the map config to a list of :class:`RunSpec`. Run names are
deterministic in their factors and seed, so re-running skips finished runs
and resumes unfinished ones (``pokeworld.train.run`` and ``measure.run`` both
skip or resume). Runs execute locally in parallel through
``concurrent.futures`` or on SLURM as a submitit job array (``--launcher
slurm``; ``submitit-local`` uses submitit's local executor, as the tests do).

Time-sliced running (``time_budget_min``): on a machine lent for a few minutes at a
time, every invocation trains until its budget is nearly spent, checkpoints, writes
``progress.json`` (finished / partial / pending runs) and exits normally; the same
command resumes. ``pack`` tars the small result files for the trip back.
"""

from __future__ import annotations

import concurrent.futures as cf
import dataclasses
import json
import os
import tarfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from .. import clock
from ..config import from_preset, to_dict
from ..errors import ConfigError
from ..io import write_json

VARIANT_ORDER = ("V", "VF", "VX_p", "VX_t", "VX", "VFX")


@dataclass
class LaunchOptions:
    """Where and how runs execute (:func:`launch`); shared by ``pokeworld map`` and ``pokeworld real``."""

    launcher: str = "local"
    """local (process pool), slurm (submitit job array) or submitit-local (submitit's local executor)."""
    workers: int = 0
    """Parallel local runs (0: one per CPU core on CPU, 1 on a GPU)."""
    slurm_partition: str = ""
    """SLURM partition for --launcher slurm."""
    slurm_timeout_min: int = 180
    """SLURM time limit per run in minutes."""
    slurm_gpus: int = 1
    """GPUs per SLURM job."""

    def __post_init__(self) -> None:
        if self.launcher not in ("local", "slurm", "submitit-local"):
            raise ConfigError(f"launcher must be local, slurm or submitit-local, got {self.launcher!r}")


@dataclass
class MapConfig(LaunchOptions):
    """Run the identifiability map (or the small demo)."""

    out: str = "out/map"
    """Output directory: data/, runs/, results.json, tables and figures land here."""
    preset: str = "cpu"
    """Preset used for every stage (generate, certify, train, measure): tiny (seconds, tests), cpu (2 CPU
    cores, ≈ 20 min per 4,000-step model, two side by side) or paper (GPU, ≈ 14 min per 20k-step model on
    one H100, 0.027 s per model-step with ``stack``); see ``pokeworld --help``."""
    experiments: tuple[str, ...] = ("factorial", "lazy", "lambda", "coverage", "frame_averaged")
    """Named experiments to run (see EXPERIMENTS)."""
    variants: tuple[str, ...] = VARIANT_ORDER
    """Variants of the input x target factorial."""
    seeds: tuple[int, ...] = (0, 1)
    """Training seeds of the factorial."""
    lambdas: tuple[float, ...] = (0.3, 0.1, 0.02, 0.01, 0.005)
    """SIGReg weights of the lambda sweep."""
    planning_variants: tuple[str, ...] = ("V", "VX_t", "VX_p", "VFX")
    """Variants planned with in the planning experiment (their factorial runs, seeds ``seeds``; paper Table
    "planning"), beside a random controller."""
    planning_corpus: str = "standard"
    """Training corpus of the planning experiment's runs: 'standard' (the factorial's own runs) or 'open_loop'
    (the standard behaviour with 20 % of 16-step slots spent on the planner's own open-loop programs,
    docs/design.md "Planning: open-loop behaviour data"); probes read the standard corpus either way."""
    belief_histories: tuple[str, ...] = ("window", "episode")
    """History lengths of the ``belief`` experiment: 'window' (the standard training windows) and/or 'episode'
    (whole 64-step episodes, trained at the batch size that keeps the standard runs' frames per step)."""
    attribute_corpora: tuple[str, ...] = ("bias0.5", "bias1.5", "bias2.5", "gain")
    """Corpora of the attribute matrix (``attributes``): persistent force bias ±0.5 / ±1.5 / ±2.5 and the
    actuator gain; a subset re-runs some cells (e.g. to add MLP probes) without re-training the others."""
    lazy_variants: tuple[str, ...] = ("V", "VX_p", "VX_t", "VX", "VFX")
    """Variants trained single-horizon (Δ = 1 only) in the lazy-equilibrium experiment."""
    sigreg_weight: float = 0.02
    """Operating-point SIGReg weight for every other experiment."""
    sigreg_pool: str = "step"
    """SIGReg rows of every global-latent run (``pokeworld train --sigreg-pool``): 'step' or 'pooled'; runs it
    does not apply to (token, reconstruction) keep theirs. A non-default value is part of each run's name."""
    gnll_variance: str = "free"
    """Variance parameterisation of every Gaussian-NLL run (``pokeworld train --gnll-variance``: free, bounded,
    beta, per_head); part of those runs' names when not 'free'."""
    train_preset: str = ""
    """Training preset of every run (empty: ``preset``); the demo trains with ``pokeworld train``'s ``demo``
    preset (the cpu model at batch 8 with 64-wide vector encoders) and measures as ``preset``."""
    train_steps: int = 0
    """Override of training steps per run (0 keeps the preset's)."""
    train_batch_size: int = 0
    """Override of windows per training step (0 keeps the preset's); the whole-episode belief runs keep the
    frames per step of this batch size."""
    num_episodes: int = 0
    """Override of episodes per corpus (0 keeps the preset's)."""
    data_seed: int = 0
    """Seed of the generated corpora."""
    split_fractions: tuple[float, ...] = ()
    """Train / probe-fit / probe-test shares of every generated corpus (empty keeps the generator's 0.6 / 0.2 /
    0.2); the demo gives the probe-fit split 0.4 (its models see fewer windows than 960 episodes hold)."""
    certify_estimators: tuple[str, ...] = ("gru", "gru_geom", "linear", "mlp", "drag", "gru_pixel", "drag_pixel",
                                           "gru_notouch", "gru_pixel_notouch")
    """Certificate estimators to run."""
    certify_kinds: tuple[str, ...] = ("contact", "glide")
    """Window kinds the certificates are computed on (the gate reads contact windows; glide windows
    give the drag certificate on pure glides)."""
    certify_max_windows: int = 0
    """Cap on certificate fit windows per kind (0 keeps the certify preset's; the demo lowers it to fit its budget)."""
    certify_epochs: int = 0
    """Maximum epochs of the neural certificate estimators (0 keeps the certify preset's)."""
    certify_fit_episodes: int = -1
    """Episodes of the certificates' own fit corpus (``pokeworld certify --fit-episodes``; -1 keeps the certify
    preset's, 0 fits on the corpus's probe-fit split)."""
    certify_separate_targets: bool = True
    """One certificate fit per target (certify's default); the demo fits its three targets jointly to keep
    its budget (on the standard corpus joint fits read at most 0.07 less, docs/design.md "Certificates")."""
    mlp_probes: bool = True
    """Fit early-stopped MLP probes besides ridge."""
    measure_max_windows: int = 0
    """Cap on probe-fit windows per kind (0 keeps the measurement preset's, 6,000 at cpu)."""
    measure_kinds: tuple[str, ...] = ()
    """Window kinds every run's probes read (empty: the measurement's default, contact, glide and all windows);
    the demo probes contact windows only, the ones its tables show."""
    untrained: bool = True
    """Probe randomly initialised models too (the untrained bound)."""
    time_budget_min: float = 0.0
    """Wall-clock budget of this invocation in minutes (0 = none). Training stops with a checkpoint
    ``time_reserve_min`` before it ends, unfinished runs are reported in progress.json, the command
    exits 0, and running it again resumes. Corpus generation and certification are not interrupted."""
    time_reserve_min: float = 1.0
    """Minutes of ``time_budget_min`` kept for checkpointing, measuring a run that just finished,
    the report and the pack; no stage starts inside it."""
    stack: bool = False
    """Train the runs that can share a step as stacked ensembles in this process (``pokeworld.train.stacked``:
    one vmapped step for every member of a group, the factorial's six variants in one VFX-shaped group; a GPU
    lever, slower than separate runs on a CPU), then measure each run as usual; runs that cannot stack (tokens)
    train alone. Each member's run directory is the one ``train.run`` would write. Local launcher only."""
    certify_alongside: bool = False
    """Compute the certificates in a background process while the runs train, instead of before training: on a GPU
    machine training leaves the CPU cores idle. Certification is not interrupted by ``time_budget_min``: the map
    waits for it after training stops. The certificates are the same either way (same configs, same seeds)."""
    stack_max_members: int = 0
    """With ``stack``: most members per stacked group (0 = no limit; lower it when a group does not fit in memory)."""
    pack: str = ""
    """Write the small results to this .tar.gz (paths relative to ``out``): every run's config.json,
    metrics.jsonl and measure*.json, each corpus's certificates.json and manifest.json, map_config.json,
    progress.json, results.json/.md and the figure; never checkpoints, TensorBoard events or data."""

    def __post_init__(self) -> None:
        super().__post_init__()
        bad = set(self.experiments) - set(EXPERIMENTS)
        if bad:
            raise ConfigError(f"unknown experiments {sorted(bad)}; choose from {sorted(EXPERIMENTS)}")
        from ..models.xjepa import VARIANTS

        bad_corpora = set(self.attribute_corpora) - set(CORPUS_TARGETS)
        if bad_corpora:
            raise ConfigError(f"unknown attribute corpora {sorted(bad_corpora)}; choose from {sorted(CORPUS_TARGETS)}")
        badv = (set(self.variants) | set(self.lazy_variants) | set(self.planning_variants)) - set(VARIANTS)
        if badv:
            raise ConfigError(f"unknown variants {sorted(badv)}; choose from {list(VARIANTS)}")
        if not self.belief_histories or set(self.belief_histories) - {"window", "episode"}:
            raise ConfigError(f"belief_histories must name 'window' and/or 'episode', got {self.belief_histories}")
        if self.planning_corpus not in ("standard", "open_loop"):
            raise ConfigError(f"planning_corpus must be standard or open_loop, got {self.planning_corpus!r}")
        if self.split_fractions and (len(self.split_fractions) != 3 or min(self.split_fractions) <= 0):
            raise ConfigError(f"split_fractions must be three positive shares (train, probe-fit, probe-test), "
                              f"got {self.split_fractions}")
        from .probes import KINDS

        if set(self.measure_kinds) - set(KINDS):
            raise ConfigError(f"unknown measure_kinds {sorted(set(self.measure_kinds) - set(KINDS))}; choose from {list(KINDS)}")
        if self.preset not in ("tiny", "cpu", "paper"):
            raise ConfigError(f"unknown preset {self.preset!r}; choose tiny, cpu or paper")
        from ..train import PRESETS as TRAIN_PRESETS

        if self.train_preset and self.train_preset not in TRAIN_PRESETS:
            raise ConfigError(f"unknown train_preset {self.train_preset!r}; choose one of {sorted(TRAIN_PRESETS)}")
        from ..losses import SIGREG_POOLS
        from ..models.xjepa import check_gnll_variance

        if self.sigreg_pool not in SIGREG_POOLS:
            raise ConfigError(f"unknown sigreg_pool {self.sigreg_pool!r}; choose one of {list(SIGREG_POOLS)}")
        check_gnll_variance(self.gnll_variance, "gnll", 2.0)
        if self.time_budget_min < 0 or self.time_reserve_min < 0:
            raise ConfigError("time_budget_min and time_reserve_min must be non-negative")
        if 0 < self.time_budget_min <= self.time_reserve_min:
            raise ConfigError(f"time_budget_min ({self.time_budget_min}) must exceed time_reserve_min "
                              f"({self.time_reserve_min}), or nothing can be trained")
        if self.stack and self.launcher != "local":
            raise ConfigError("stack trains in the map's own process: use it with --launcher local")
        if self.stack_max_members < 0:
            raise ConfigError(f"stack_max_members must be ≥ 0, got {self.stack_max_members}")
        if self.pack and not self.pack.endswith((".tar.gz", ".tgz")):
            raise ConfigError(f"pack must name a .tar.gz file, got {self.pack!r}")


PRESETS: dict[str, dict] = {
    "tiny": {"preset": "tiny", "experiments": ("factorial",), "variants": ("V", "VX_t"), "seeds": (0,),
             "mlp_probes": False, "certify_estimators": ("linear", "drag"), "untrained": False},
    "cpu": {"preset": "cpu", "seeds": (0,)},
    "paper": {"preset": "paper"},
}

DEMO = {  # the newcomer's first run: four variants, one seed; 8 min 55 s measured on 2 idle cores (README)
    "experiments": ("factorial",), "variants": ("V", "VF", "VX_t", "VFX"), "seeds": (0,),
    # the cpu map's corpus: a 1,200-episode one halves the probe-fit split, and a ridge readout fit on 240 episodes
    # under-reads a weak signal (VFX log k 0.06 vs 0.10 for one checkpoint, docs/model.md "Learning speed")
    # the model: train's "demo" preset (cpu sizes, 64-wide vector encoders, batch 8, 2,200 steps); probes read
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
}


def make_config(preset: str = "cpu", **overrides) -> MapConfig:
    return from_preset(MapConfig, PRESETS, preset, **overrides)


def make_demo_config(preset: str = "cpu", **overrides) -> MapConfig:
    cfg = from_preset(MapConfig, PRESETS, preset)
    demo = {k: v for k, v in DEMO.items() if preset != "tiny" or k in ("experiments",)}
    return dataclasses.replace(cfg, out="out/demo", **{**demo, **overrides})


# --------------------------------------------------------------------------- run specs
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


def _h(horizons) -> str:
    return "h" + "-".join(map(str, horizons))


def _spec(exp, variant, seed, lam, horizons=(1, 4, 16), corpus="standard", measure_corpus="standard",
          measure: dict | None = None, **extra):
    # an override equal to the training default is the default run itself: it keeps the plain name, so a
    # dose level that equals the operating point (touch contact weight 4, glide weight 1) shares the factorial's run
    from ..train import field_defaults

    defaults = field_defaults()
    extra = {k: v for k, v in extra.items() if not (k in defaults and defaults[k] == v)}
    tag = "".join(f"-{k}{v}" for k, v in sorted(extra.items()))
    name = f"{variant}-{_h(horizons)}-lam{lam:g}-{corpus}{tag}-s{seed}"
    train = dict(variant=variant, horizons=tuple(horizons), sigreg_weight=lam, seed=seed, **extra)
    return RunSpec(name, exp, corpus, measure_corpus, train, seed, dict(measure or {}))


def exp_factorial(c: MapConfig) -> list[RunSpec]:
    return [_spec("factorial", v, s, c.sigreg_weight) for v in c.variants for s in c.seeds]


def exp_lazy(c: MapConfig) -> list[RunSpec]:
    """Single-step vs multi-horizon x vision-only vs cross-modal targets (single-horizon factorial column)."""
    runs = [_spec("lazy", v, c.seeds[0], c.sigreg_weight, horizons=(1,)) for v in c.lazy_variants]
    runs += [_spec("lazy", v, c.seeds[0], c.sigreg_weight) for v in ("V", "VX", "VFX") if v in c.variants]
    return runs


def exp_lambda(c: MapConfig) -> list[RunSpec]:
    # every seed (the sweep's steps 0.02 -> 0.01 -> 0.005 are within seed-to-seed spread on `cpu`), the first
    # seed's sweep first, so a time-budgeted map that stops early leaves a whole sweep rather than half of one
    return [_spec("lambda", "VFX", seed, lam) for seed in c.seeds for lam in c.lambdas]


def exp_coverage(c: MapConfig) -> list[RunSpec]:
    return [_spec("coverage", "VFX", c.seeds[0], c.sigreg_weight, corpus=corp) for corp in ("standard", "contact_poor")]


def exp_frame_averaged(c: MapConfig) -> list[RunSpec]:
    return [_spec("frame_averaged", "VFX", c.seeds[0], c.sigreg_weight, corpus="frame_averaged",
                  measure_corpus="frame_averaged")]


def exp_controls(c: MapConfig) -> list[RunSpec]:
    s, lam = c.seeds[0], c.sigreg_weight
    return [_spec("controls", "VFX", s, lam, sysid_weight=0.5), _spec("controls", "VFX", s, lam, objective="gnll"),
            _spec("controls", "VFX", s, lam, objective="gnll", gnll_heads="all"),
            _spec("controls", "V", s, lam, objective="recon"), _spec("controls", "VFX", s, lam, objective="recon"),
            _spec("controls", "VFX", s, lam, tokens=True)]


#: Whole-episode training window (64 control steps -> 65 observations) of the belief experiment's
#: long-history runs, and how they are measured: every probe / prediction window is an episode prefix
#: (stride past the episode end), the only windows whole-episode training ever shows the model, with 48
#: observations of history at the probed state and before the 16-step predictions.
LONG_WINDOW = 65
LONG_MEASURE = {"window": 48, "stride": 64, "context": 48}


def long_batch_size(preset: str, batch_size: int = 0) -> int:
    """Whole-episode batch size that keeps the frames per step of the standard runs (``batch_size``, 0 = the
    preset's; cpu: 32 × 24 -> 12 × 65): the long-history runs then differ from the standard ones in history
    length only, not in compute or in frames seen (docs/design.md, "The belief experiment")."""
    from ..train import PRESETS as TRAIN_PRESETS, TrainConfig

    t = from_preset(TrainConfig, TRAIN_PRESETS, preset)
    return max(2, round((batch_size or t.batch_size) * t.window / LONG_WINDOW))


def exp_tokens(c: MapConfig) -> list[RunSpec]:
    """The factorial ordering under a spatial-token encoder (paper §4.1 / App. C: "unchanged under a token-based
    encoder", VFX stiffness 0.62): every factorial variant with ``tokens=True``, first seed (VFX is the controls'
    token run)."""
    return [_spec("tokens", v, c.seeds[0], c.sigreg_weight, tokens=True) for v in c.variants]


def exp_belief(c: MapConfig) -> list[RunSpec]:
    """Objective × history length on the VFX trunk, every seed: latent (the factorial's VFX run) and belief
    objectives, each on the standard windows and on whole episodes at equal frames per step (docs/model.md
    "belief"), beside the system-ID head (the controls' run): what a supervised readout of the same trunk reaches."""
    lam, runs = c.sigreg_weight, []
    for s in c.seeds:
        if "window" in c.belief_histories:
            runs += [_spec("belief", "VFX", s, lam), _spec("belief", "VFX", s, lam, objective="belief")]
        if "episode" in c.belief_histories:
            long = dict(measure=LONG_MEASURE, window=LONG_WINDOW,
                        batch_size=long_batch_size(c.train_preset or c.preset, c.train_batch_size))
            runs += [_spec("belief", "VFX", s, lam, **long), _spec("belief", "VFX", s, lam, objective="belief", **long)]
    return runs + [_spec("controls", "VFX", c.seeds[0], lam, sysid_weight=0.5)]


def exp_dose_touch(c: MapConfig) -> list[RunSpec]:
    return [_spec("dose_touch", "VFX", c.seeds[0], c.sigreg_weight, touch_contact_weight=w) for w in (4.0, 1.0, 0.25, 0.0)]


def exp_dose_glide(c: MapConfig) -> list[RunSpec]:
    """Dose-response 1 (paper App. C): glide-frame loss weight 1/4/16/64 (glide loss share 32% -> 97% there)."""
    return [_spec("dose_glide", "VFX", c.seeds[0], c.sigreg_weight, glide_loss_weight=w) for w in (1.0, 4.0, 16.0, 64.0)]


def realised_glide_share(results: dict, run: dict) -> float | None:
    """Glide loss share a run's training realised: the mean of the per-step ``glide_loss_share`` in its
    metrics.jsonl (None when the run is not on disk)."""
    name = next((n for n, r in results["runs"].items() if r is run), None)
    path = Path(results.get("map_config", {}).get("out", "")) / "runs" / str(name) / "metrics.jsonl"
    shares = []
    if name is not None and path.exists():
        shares = [r["glide_loss_share"] for r in map(json.loads, path.read_text().splitlines()) if "glide_loss_share" in r]
    return sum(shares) / len(shares) if shares else None


def exp_planning(c: MapConfig) -> list[RunSpec]:
    """Closed-loop planning (App. C): the factorial's own multi-horizon runs (same names, so a map that runs the
    factorial trains each once); the planner itself runs after training (:func:`ensure_planning`)."""
    return [_spec("factorial", v, s, c.sigreg_weight, corpus=c.planning_corpus) for v in c.planning_variants
            for s in c.seeds]


def exp_coordinate(c: MapConfig) -> list[RunSpec]:
    """The coordinate test (App. C): VFX on the ``flow`` corpus (a frozen self-supervised flow sensor's velocity
    and log speed appended to proprioception) beside the factorial's VFX on the standard corpus."""
    s, lam = c.seeds[0], c.sigreg_weight
    return [_spec("factorial", "VFX", s, lam), _spec("coordinate", "VFX", s, lam, corpus="flow", measure_corpus="flow")]


def exp_attributes(c: MapConfig) -> list[RunSpec]:
    return [_spec("attributes", "VFX", c.seeds[0], c.sigreg_weight, corpus=corp, measure_corpus=corp)
            for corp in c.attribute_corpora]


#: γ ledger rows: mechanism -> the run that deploys it (train overrides on VFX beside the horizons and corpus);
#: every run except the two ledger-only ones is shared with the experiment named in its spec.
LEDGER_MOTION_ALPHA = 4.0
"""α of the ledger's magnitude-weighted motion-forecast run: a frame with the batch's mean motion weighs 5, a still one 1."""


def exp_ledger(c: MapConfig) -> list[RunSpec]:
    """The γ intervention ledger (App. C): every prediction-side mechanism against drag, one VFX run each —
    single- vs multi-horizon heads, the temporal-difference input channel off, spatial tokens, magnitude-weighted
    motion-forecast targets, the frozen flow sensor's input channel, and a glide-enriched loss (glide weight 16).
    Runs shared with lazy / factorial / controls / coordinate / dose_glide keep those experiments' names."""
    s, lam = c.seeds[0], c.sigreg_weight
    return [_spec("lazy", "VFX", s, lam, horizons=(1,)), _spec("factorial", "VFX", s, lam),
            _spec("ledger", "VFX", s, lam, motion_channel=False), _spec("controls", "VFX", s, lam, tokens=True),
            _spec("ledger", "VFX", s, lam, motion_loss_weight=LEDGER_MOTION_ALPHA),
            _spec("coordinate", "VFX", s, lam, corpus="flow", measure_corpus="flow"),
            _spec("dose_glide", "VFX", s, lam, glide_loss_weight=16.0)]


def ledger_mechanism(run: dict) -> str:
    """Ledger row label of a run (the mechanism it deploys), from its corpus and train overrides."""
    t = run["train"]
    if run.get("corpus") == "flow":
        return "frozen flow velocity sensor"
    if t.get("tokens"):
        return "spatial tokens"
    if t.get("motion_loss_weight", 0.0) > 0:
        return "magnitude-weighted motion targets"
    if t.get("motion_channel", True) is False:
        return "no motion input channel"
    if t.get("glide_loss_weight", 1.0) != 1.0:
        return "glide-enriched loss"
    return "single-horizon head" if tuple(t.get("horizons", (1, 4, 16))) == (1,) else "multi-horizon heads"


EXPERIMENTS: dict[str, Callable[[MapConfig], list[RunSpec]]] = {
    "factorial": exp_factorial, "lazy": exp_lazy, "lambda": exp_lambda, "coverage": exp_coverage,
    "frame_averaged": exp_frame_averaged, "controls": exp_controls, "dose_touch": exp_dose_touch,
    "dose_glide": exp_dose_glide, "attributes": exp_attributes, "belief": exp_belief, "planning": exp_planning,
    "coordinate": exp_coordinate, "ledger": exp_ledger, "tokens": exp_tokens,
}
CORPUS_TARGETS = {"bias0.5": ("bias_x", "bias_y"), "bias1.5": ("bias_x", "bias_y"), "bias2.5": ("bias_x", "bias_y"),
                  "gain": ("gain",)}


def with_map_training(c: MapConfig, spec: RunSpec) -> RunSpec:
    """``spec`` with the map-wide training choices (``sigreg_pool``, ``gnll_variance``) applied where they apply;
    a changed run is renamed through :func:`_spec`, so it never shares a directory with the default run."""
    t = spec.train
    extra = {}
    if c.sigreg_pool != "step" and not t.get("tokens") and t.get("objective", "latent") != "recon":
        extra["sigreg_pool"] = c.sigreg_pool
    if c.gnll_variance != "free" and t.get("objective") == "gnll":
        extra["gnll_variance"] = c.gnll_variance
    if not extra:
        return spec
    rest = {k: v for k, v in t.items() if k not in ("variant", "horizons", "sigreg_weight", "seed")}
    return _spec(spec.experiment, t["variant"], t["seed"], t["sigreg_weight"], t["horizons"], spec.corpus,
                 spec.measure_corpus, spec.measure, **rest, **extra)


def experiment_specs(c: MapConfig, exp: str) -> list[RunSpec]:
    """The runs of experiment ``exp`` under ``c`` (its own specs with the map-wide training choices)."""
    return [with_map_training(c, s) for s in EXPERIMENTS[exp](c)]


def all_specs(c: MapConfig) -> list[RunSpec]:
    seen: dict[str, RunSpec] = {}
    for exp in c.experiments:
        for spec in experiment_specs(c, exp):
            seen.setdefault(spec.name, spec)  # a run shared by two experiments trains once
    return list(seen.values())


def spec_experiments(c: MapConfig) -> dict[str, list[str]]:
    """experiment -> run names (including runs shared with other experiments)."""
    return {exp: [s.name for s in experiment_specs(c, exp)] for exp in c.experiments}


# --------------------------------------------------------------------------- stages
def corpus_dir(c: MapConfig, corpus: str) -> Path:
    return Path(c.out) / "data" / corpus


def ensure_corpus(c: MapConfig, corpus: str) -> Path:
    from ..sim import generate

    if corpus == "flow":  # derived from the standard corpus by the frozen flow sensor
        from ..models import flow
        from .coordinate import build_flow_corpus

        return build_flow_corpus(ensure_corpus(c, "standard"), corpus_dir(c, "flow"), flow.make_config(c.preset))

    overrides: dict[str, Any] = {"out": str(corpus_dir(c, corpus)), "corpus": corpus, "seed": c.data_seed}
    if c.num_episodes:
        overrides["num_episodes"] = c.num_episodes
    if c.split_fractions:
        overrides["split_fractions"] = tuple(c.split_fractions)
    return generate.run(generate.make_config(c.preset, **overrides))


GATED = ("log_m", "gamma", "log_k")


def with_standard_gate(std: dict, own: dict) -> dict:
    """``own`` certificates (a derived or attribute corpus, certified for its new targets only) completed with
    the standard corpus's estimators for the gated parameters; the gate is then the standard's, and
    ``gate_from`` says so (reports state it once, on the standard corpus)."""
    from .. import certify

    est: dict = {}
    for source in (std.get("estimators", {}), own.get("estimators", {})):
        for e, kinds in source.items():
            for kind, r2 in kinds.items():
                est.setdefault(e, {}).setdefault(kind, {}).update(r2)
    targets = tuple(dict.fromkeys(GATED + tuple(own.get("config", {}).get("targets", ()))))
    cert = certify.certificate_table(est, targets)
    return {**own, "estimators": est, "certificate": cert, "gate": certify.gate(cert, est), "gate_from": "standard",
            "counts": {**std.get("counts", {}), **{f"{k} ({'/'.join(own['config']['targets'])})": v
                                                   for k, v in own.get("counts", {}).items()}}}


def ensure_certificates(c: MapConfig, corpus: str) -> dict:
    """Certificates of ``corpus`` (``certify.run``, skipped when up to date).

    The flow corpus certifies its log-speed channel, an attribute corpus (bias, gain) its attribute: their
    other parameters have the standard corpus's distributions and (flow) episodes, so their gated-parameter
    certificates and gate are the standard corpus's (:func:`with_standard_gate`). One recurrent fit per target
    costs ~20 CPU-minutes on a 2-core machine; not repeating the standard targets on four more corpora saves
    about four CPU-hours of the `cpu` preset.
    """
    from .. import certify

    cost = {k: v for k, v in (("max_windows", c.certify_max_windows), ("epochs", c.certify_epochs)) if v}
    if c.certify_fit_episodes >= 0:
        cost["fit_episodes"] = c.certify_fit_episodes
    cost["separate_targets"] = c.certify_separate_targets
    if corpus == "flow":
        # the state-based estimators do not read the appended channels: only the log-speed certificate is new
        path = certify.run(certify.make_config(c.preset, data=str(corpus_dir(c, corpus)), targets=("gamma",),
                                               estimators=("linear_logspeed",), kinds=c.certify_kinds))
        manifest = json.loads((corpus_dir(c, corpus) / "manifest.json").read_text())
        return {**with_standard_gate(ensure_certificates(c, "standard"), json.loads(Path(path).read_text())),
                "flow_sensor": manifest.get("flow", {}).get("sensor", {})}
    if corpus in CORPUS_TARGETS:
        path = certify.run(certify.make_config(c.preset, data=str(corpus_dir(c, corpus)),
                                               targets=CORPUS_TARGETS[corpus],
                                               estimators=c.certify_estimators, kinds=c.certify_kinds, **cost))
        return with_standard_gate(ensure_certificates(c, "standard"), json.loads(Path(path).read_text()))
    path = certify.run(certify.make_config(c.preset, data=str(corpus_dir(c, corpus)), targets=GATED,
                                           estimators=c.certify_estimators, kinds=c.certify_kinds, **cost))
    return json.loads(Path(path).read_text())


def certify_corpora(c: MapConfig, corpora: list[str], threads: int = 0) -> dict[str, dict]:
    """:func:`ensure_certificates` of each corpus in order, on ``threads`` CPU threads (0: torch's default); top-level
    because ``certify_alongside`` runs it in a spawned process."""
    if threads:
        import torch

        torch.set_num_threads(threads)
    return {corpus: ensure_certificates(c, corpus) for corpus in corpora}


def planning_dir(c: MapConfig) -> Path:
    return Path(c.out) / "planning"


def ensure_planning(c: MapConfig) -> dict:
    """Plan with the planning variants' finished runs and a random controller (same planner, budget, starts
    and goals for all); writes ``planning/planning.json``, ``distances.npz`` and the episode figure.

    Skipped when ``planning.json`` was computed with the same planner config from the same finished runs.
    Returns ``{"config", "summary", "runs", "figure"}`` (summary: controller -> reach, median improvement).
    """
    from .. import plan

    pcfg = plan.make_config(c.preset, out=str(planning_dir(c)), seed=c.data_seed)
    runs: dict[str, list[str]] = {}
    for spec in experiment_specs(c, "planning"):
        runs.setdefault(spec.train["variant"], []).append(str(Path(c.out) / "runs" / spec.name))
    key = {"config": to_dict(pcfg), "runs": {v: [[Path(d).name, (Path(d) / "DONE").stat().st_mtime_ns]
                                                  for d in dirs] for v, dirs in runs.items()}}
    out = planning_dir(c)
    path = out / "planning.json"
    if path.exists():
        prev = json.loads(path.read_text())
        if prev.get("key") == key:
            print(f"[map] {path} is up to date; skipping planning")
            return prev["result"]
    out.mkdir(parents=True, exist_ok=True)
    # the position decoder is fit on the corpus the planned runs were trained on
    planned = plan.plan_runs(pcfg, runs, data=str(corpus_dir(c, c.planning_corpus)))
    figs = plan.write_outputs(planned, out, pcfg.goal_radius)
    result = {"config": to_dict(pcfg), "summary": planned["summary"], "runs": runs,
              "figure": [str(p.relative_to(Path(c.out))) for p in figs]}
    write_json(path, {"key": key, "result": result})
    return result


def spec_measure_path(c: MapConfig, s: RunSpec) -> Path:
    """The measure.json the map writes for run ``s`` (on its measure corpus when that differs from its training one)."""
    from .measure import measure_path

    data = str(corpus_dir(c, s.measure_corpus)) if s.measure_corpus != s.corpus else ""
    return measure_path(Path(c.out) / "runs" / s.name, data)


def _past(deadline: float) -> bool:
    return deadline > 0 and clock.wall_clock() >= deadline


def execute(job: dict) -> dict:
    """Train (resume / skip) and measure one run. Top-level and picklable for process pools and submitit.

    Returns ``{"name", "status"}`` with status ``finished`` (trained and measured; also ``measure``:
    the path), ``partial`` (stopped at ``job["deadline"]``, or trained but not yet measured) or
    ``pending`` (the deadline had passed before it started).
    """
    import torch

    from .. import train
    from . import measure

    deadline = job.get("deadline", 0.0)
    if _past(deadline):
        return {"name": job["name"], "status": "pending"}
    if job.get("threads"):
        torch.set_num_threads(job["threads"])
    tcfg = job_train_config(job)
    run_dir = train.run(tcfg)
    if not (run_dir / "DONE").exists() or _past(deadline):
        return {"name": job["name"], "status": "partial"}
    # the thread count training sets (CPU reductions round by it): a run measured in a later invocation, whose
    # training was skipped, then reads the same numbers as one measured right after training
    torch.set_num_threads(tcfg.threads or train.auto_threads())
    mcfg = measure.make_config(job["preset"], run_dir=job["train"]["out"], data=job["measure_data"],
                               mlp=job["mlp"], untrained=job["untrained"], **job.get("measure", {}))
    path = measure.run(mcfg)
    return {"name": job["name"], "status": "finished", "measure": str(path)}


def job_train_config(job: dict):
    """The TrainConfig a map job trains (with its deadline): the same for a separate and a stacked run."""
    from .. import train

    return train.make_config(job["train_preset"], **job["train"], deadline=job.get("deadline", 0.0))


def train_stacked_jobs(c: MapConfig, jobs: list[dict]) -> None:
    """``stack``: train every unfinished job that can stack with :func:`pokeworld.train.stacked.run` (grouped by
    what fixes the step's shapes; members resume together from a common checkpoint step), before :func:`launch`
    measures them (and trains alone the jobs that cannot stack). Stops at the jobs' deadline like ``train.run``."""
    from ..train import stacked as train_stacked

    cfgs = [job_train_config(j) for j in jobs]
    todo = [cfg for cfg in cfgs if train_stacked.stackable(cfg) and not (Path(cfg.out) / "DONE").exists()]
    if not todo:
        return
    groups = train_stacked.plan_groups(todo, mix_variants=True, max_members=c.stack_max_members)
    print(f"[map] training {len(todo)} runs as {len(groups)} stacked group(s) of {[len(g) for g in groups]} members")
    train_stacked.run(todo, mix_variants=True, max_members=c.stack_max_members)


def _jobs(c: MapConfig, specs: list[RunSpec], threads: int, deadline: float = 0.0) -> list[dict]:
    jobs = []
    for s in specs:
        tr = dict(s.train, data=str(corpus_dir(c, s.corpus)), out=str(Path(c.out) / "runs" / s.name),
                  progress=False)
        if c.train_steps:
            tr["steps"] = c.train_steps
        if c.train_batch_size and "batch_size" not in s.train:
            tr["batch_size"] = c.train_batch_size
        if threads:
            tr["threads"] = threads
        measure_data = str(corpus_dir(c, s.measure_corpus)) if s.measure_corpus != s.corpus else ""
        measure = ({"kinds": tuple(c.measure_kinds)} if c.measure_kinds else {}) | (
            {"max_windows": c.measure_max_windows} if c.measure_max_windows else {}) | dict(s.measure)
        jobs.append({"name": s.name, "preset": c.preset, "train_preset": c.train_preset or c.preset, "train": tr,
                     "measure_data": measure_data,
                     "mlp": c.mlp_probes, "untrained": c.untrained, "threads": threads, "deadline": deadline,
                     "measure": measure})
    return jobs


def launch(c: MapConfig, jobs: list[dict], fn: Callable[[dict], dict] | None = None) -> list[dict]:
    """Execute jobs locally (process pool) or through submitit; returns their result dicts.

    ``fn`` is the top-level, picklable job function (default :func:`execute`; ``pokeworld real``
    passes its own). ``c`` needs ``launcher``, ``workers``, ``out`` and the ``slurm_*`` fields.
    """
    fn = execute if fn is None else fn
    if not jobs:
        return []
    if c.launcher == "local":
        workers = c.workers or _default_workers(len(jobs))
        if workers == 1:
            return [fn(j) for j in jobs]
        ctx = __import__("multiprocessing").get_context("spawn")
        with cf.ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
            return list(pool.map(fn, jobs))
    import submitit

    folder = Path(c.out) / "submitit"
    if c.launcher == "slurm":
        ex = submitit.AutoExecutor(folder=folder, cluster="slurm")
        params: dict[str, Any] = {"timeout_min": c.slurm_timeout_min, "gpus_per_node": c.slurm_gpus,
                                  "cpus_per_task": 8, "name": "pokeworld-map" if fn is execute else f"pokeworld-{fn.__name__}"}
        if c.slurm_partition:
            params["slurm_partition"] = c.slurm_partition
        ex.update_parameters(**params)
    else:
        ex = submitit.AutoExecutor(folder=folder, cluster="local")
        ex.update_parameters(timeout_min=c.slurm_timeout_min)
    handles = ex.map_array(fn, jobs)
    print(f"[map] submitted {len(handles)} jobs to {c.launcher}: {[h.job_id for h in handles][:4]}...")
    return [h.result() for h in handles]


def _cores() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def _default_workers(n_jobs: int) -> int:
    """One run per core on CPU (small models scale badly across threads); one per GPU otherwise."""
    import torch

    if torch.cuda.is_available():
        return 1
    return max(1, min(n_jobs, _cores()))


def _last_step(run_dir: Path) -> int:
    """Last logged training step of a run directory (0 when it has none)."""
    path = run_dir / "metrics.jsonl"
    rows = [json.loads(x) for x in path.read_text().splitlines() if x.strip()] if path.exists() else []
    return max((int(r.get("step", 0)) for r in rows), default=0)


def write_progress(c: MapConfig, specs: list[RunSpec], started: float) -> dict:
    """``progress.json``, read off the run directories (so earlier invocations' work counts): runs
    ``finished`` (trained and measured), ``partial`` (name -> last logged step: stopped at a deadline,
    or trained but not measured yet) and ``pending`` (not started)."""
    prog: dict[str, Any] = {"finished": [], "partial": {}, "pending": []}
    for s in specs:
        run_dir = Path(c.out) / "runs" / s.name
        if (run_dir / "DONE").exists() and spec_measure_path(c, s).exists():
            prog["finished"].append(s.name)
        elif (run_dir / "ckpt.pt").exists() or (run_dir / "DONE").exists():
            prog["partial"][s.name] = _last_step(run_dir)
        else:
            prog["pending"].append(s.name)
    prog["complete"] = len(prog["finished"]) == len(specs)
    prog["elapsed_min"] = (clock.wall_clock() - started) / 60
    prog["time_budget_min"] = c.time_budget_min
    write_json(Path(c.out) / "progress.json", prog)
    return prog


#: Files ``pack`` takes, as globs relative to the map directory (all small: JSON, markdown, figures).
PACK_GLOBS = ("map_config.json", "progress.json", "results.json", "results.md", "identifiability_map.png",
              "identifiability_map.pdf", "planning/planning.json", "planning/plan_episode.png", "data/*/certificates.json", "data/*/manifest.json",
              "runs/*/config.json", "runs/*/metrics.jsonl", "runs/*/measure*.json")


def pack_results(c: MapConfig, dest: str | os.PathLike) -> Path:
    """Tar+gzip the small result files of ``c.out`` (:data:`PACK_GLOBS`) into ``dest``; returns it."""
    out, dest = Path(c.out), Path(dest)
    dest.parent.mkdir(parents=True, exist_ok=True)
    tmp = dest.with_name(f".{dest.name}.tmp-{os.getpid()}")
    with tarfile.open(tmp, "w:gz") as tar:
        for pattern in PACK_GLOBS:
            for path in sorted(out.glob(pattern)):
                tar.add(path, arcname=str(path.relative_to(out)))
    os.replace(tmp, dest)
    size = dest.stat().st_size
    # the device machine returns files of at most 16 MiB each
    print(f"[map] packed results into {dest} ({size / 2 ** 20:.2f} MiB)"
          + (" — over 16 MiB, too large to come back from the device" if size > 16 * 2 ** 20 else ""))
    return dest


MAP_LOCK_REFUSAL = ("{path} is in use by another `pokeworld map`: {holder}. Two maps on one --out would overwrite "
                    "each other's results.json; wait for that one to finish and run this command again (its runs "
                    "are merged into the same results.json), or give this one another --out")


def carry_over(previous: dict | None, results: dict) -> dict:
    """``results`` completed with the run records of an earlier ``results.json`` in the same ``out`` that this
    invocation did not measure (each kept under the experiments that listed it, with the certificates of corpora
    only it used and the planning table when this invocation did not plan), so a later invocation with other
    experiments, variants or seeds never drops a finished run's record. Runs measured now replace their earlier
    records; the carried runs and the command that measured them are named in ``provenance["carried_over"]``."""
    if not previous:
        return results
    out = {**results, "experiments": {k: list(v) for k, v in results["experiments"].items()},
           "runs": dict(results["runs"]), "certificates": dict(results["certificates"]),
           "provenance": dict(results["provenance"])}
    carried: list[str] = []
    for exp, names in previous.get("experiments", {}).items():
        now = out["experiments"].setdefault(exp, [])
        extra = [n for n in names if n not in now and n in previous.get("runs", {})]
        now += extra
        for n in extra:
            if n not in out["runs"]:
                out["runs"][n] = previous["runs"][n]
                carried.append(n)
        if not now:
            del out["experiments"][exp]
    if not carried:
        return results
    for corpus, cert in previous.get("certificates", {}).items():
        out["certificates"].setdefault(corpus, cert)
    if "planning" not in out and "planning" in previous:
        out["planning"] = previous["planning"]
    prev = previous.get("provenance", {})
    # a run carried twice keeps the command that measured it, not the one that last carried it
    earlier = [{**e, "runs": [n for n in e["runs"] if n in carried]} for e in prev.get("carried_over", [])]
    already = {n for e in earlier for n in e["runs"]}
    first = {"runs": [n for n in carried if n not in already], "command": prev.get("command", "?"),
             "git": prev.get("git", "?")}
    out["provenance"]["carried_over"] = [e for e in (*earlier, first) if e["runs"]]
    return out


def read_previous_results(path: Path) -> dict | None:
    """The results.json an earlier invocation left in this ``out`` (None when there is none or it is unreadable:
    it is written atomically, so an unreadable one was edited by hand and is not merged)."""
    if not path.exists():
        return None
    try:
        prev = json.loads(path.read_text())
        if isinstance(prev, dict) and isinstance(prev.get("experiments"), dict) and isinstance(prev.get("runs"), dict):
            return prev
    except (ValueError, UnicodeDecodeError):
        pass
    print(f"[map] warning: {path} is not a results record pokeworld wrote; it is replaced, not merged")
    return None


def run(c: MapConfig) -> Path:
    """Run every stage of the map and write results.json, results.md and the figure into ``c.out``.

    With ``time_budget_min`` the invocation may stop early (progress.json says where); with ``pack``
    the small results are tarred at the end either way. The whole invocation holds ``out/.map.lock``: a second
    map on the same ``out`` is refused with a message naming this one (a killed map's lock is released with its
    process), and the experiments of an earlier invocation are carried into results.json (:func:`carry_over`).
    """
    from ..io import dir_lock

    out = Path(c.out)
    with dir_lock(out, ".map.lock", MAP_LOCK_REFUSAL) as stale:
        if stale:
            print(f"[map] the previous holder of {out} ({stale}) is gone; taking over its lock and resuming")
        # temporary copies a killed map left of its top-level files (results, report, figures): only the lock's
        # holder writes these, so none of them is in use
        for tmp in out.glob(".*.tmp-*"):
            if tmp.is_file():
                tmp.unlink()
        return _run_locked(c)


def _run_locked(c: MapConfig) -> Path:
    """The body of :func:`run`, under the out directory's lock."""
    from . import report

    started = clock.wall_clock()
    # training must stop early enough to leave the reserve for measuring, reporting and packing
    deadline = started + 60 * (c.time_budget_min - c.time_reserve_min) if c.time_budget_min > 0 else 0.0
    out = Path(c.out)
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "map_config.json", to_dict(c))
    specs = all_specs(c)
    corpora = sorted({s.corpus for s in specs} | {s.measure_corpus for s in specs} | {"standard"})
    certificates: dict[str, dict] = {}
    prepared = True  # every corpus (and, unless certify_alongside, certificate) in place: training may start
    for corpus in corpora:
        if _past(deadline):
            prepared = False
            break
        ensure_corpus(c, corpus)
    certify_order = [k for k in sorted(corpora, key=lambda k: k == "flow") if k != "contact_poor"]  # flow's build on the standard's
    background = None
    if prepared and c.certify_alongside:
        # certificates are CPU work, training on a GPU leaves the cores idle: one spawned process computes them while
        # the runs train (spawned, not forked, so it inherits no CUDA state)
        ctx = __import__("multiprocessing").get_context("spawn")
        background = cf.ProcessPoolExecutor(max_workers=1, mp_context=ctx)
        # two cores stay with the training process, whose GPU step is bound by its host-side launches
        pending = background.submit(certify_corpora, c, certify_order, max(1, _cores() - 2))
        print(f"[map] certifying {certify_order} in a background process while the runs train")
    else:
        for corpus in certify_order:
            if not prepared:
                break
            if _past(deadline):
                prepared = False
                break
            certificates[corpus] = ensure_certificates(c, corpus)
    if prepared:
        workers = c.workers or _default_workers(len(specs))
        threads = max(1, _cores() // workers) if (c.launcher == "local" and workers > 1) else 0
        print(f"[map] {len(specs)} runs, launcher={c.launcher}, workers={workers}"
              + (f", training until {c.time_budget_min - c.time_reserve_min:g} min" if deadline else ""))
        jobs = _jobs(c, specs, threads, deadline)
        if c.stack:
            train_stacked_jobs(c, jobs)
        launch(c, jobs)
    if background is not None:
        with background:
            print("[map] waiting for the background certificates")
            certificates = pending.result()
    prog = write_progress(c, specs, started)
    planning_late = "planning" in c.experiments and _past(deadline)  # planning takes minutes: never start it late
    if prog["complete"] and prepared and not planning_late:
        results = report.collect(c, specs, certificates)
        if "planning" in c.experiments:
            results["planning"] = ensure_planning(c)
        results = carry_over(read_previous_results(out / "results.json"), results)
        write_json(out / "results.json", results)
        report.write_all(c, results)
        table = report.certificate_table(results) + report.factorial_table(results)
        print("\n".join(table + report.factorial_summary(results)))
        print(f"\n[map] wrote {out / 'results.json'}, {out / 'results.md'} (every table) and the figure "
              f"{out / 'identifiability_map.png'}")
    elif planning_late and prog["complete"] and prepared:
        print("[map] time budget reached before planning: every run is trained and measured; run the same "
              "command again to plan and write the report")
    else:
        print(f"[map] time budget reached: {len(prog['finished'])} runs finished, {len(prog['partial'])} partial "
              f"{prog['partial']}, {len(prog['pending'])} pending; run the same command again to resume "
              f"({out / 'progress.json'})")
    if c.pack:
        pack_results(c, c.pack)
    return out
