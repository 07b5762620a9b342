"""The map's configuration, :class:`MapConfig`: which experiments, at which budget, launched how. Its presets
and the demo's are :mod:`.presets`; the names of experiments are checked against :mod:`.registry` there."""

from __future__ import annotations

from dataclasses import dataclass

from ..config import FRACTION, SEED, Limit, check_fractions
from ..errors import ConfigError
from ..evaluate.probes import KINDS
from ..losses import SIGREG_POOLS
from ..models.xjepa import VARIANTS, check_gnll_variance
from ..sim import environments
from ..sim.physics import DAMPING_LAWS
from ..train.config import PRESETS as TRAIN_PRESETS
from .launch import LaunchOptions

#: The factorial's variants in the paper's order (inputs, then targets).
VARIANT_ORDER = ("V", "VF", "VX_p", "VX_t", "VX", "VFX")


@dataclass
class MapConfig(LaunchOptions):
    """Run the identifiability map (or the small demo)."""

    out: str = "out/map"
    """Output directory: data/, runs/, results.json, tables and figures land here."""
    quiet: bool = False
    """No heartbeat lines (every 30 s, what is running and how far the runs are); the stage lines stay."""
    whole_job_estimate: bool = False
    """Keep one estimate of the whole job's time from the start (the demo's stage costs on the reference machine,
    scaled by a training step timed on this machine), kept current from each stage's own measured rate as it runs
    (a certificate fit's epochs, training's steps); the demo turns it on (its stage costs are the demo's)."""
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
    control_runs: tuple[str, ...] = ("sysid", "gnll", "gnll_every_head", "V_recon", "VFX_recon", "tokens")
    """Runs of the objective-attribution controls (``controls``): the system-ID head, Gaussian NLL on the latent
    heads / on every head, V and VFX with reconstruction, spatial tokens; a subset re-runs some cells (e.g. the
    NLL rows after a change of its variance) without re-training the others."""
    lazy_variants: tuple[str, ...] = ("V", "VX_p", "VX_t", "VX", "VFX")
    """Variants trained single-horizon (Δ = 1 only) in the lazy-equilibrium experiment."""
    sigreg_weight: float = 0.02
    """Operating-point SIGReg weight for every other experiment."""
    ordering_sigreg_weight: float = 0.1
    """SIGReg weight of ``lambda_factorial``, the factorial's variants (first seed) re-trained to check that Table
    "targets"' ordering holds at a stronger weight (paper App. C: "unchanged at λ = 0.1")."""
    sigreg_pool: str = "step"
    """SIGReg rows of every global-latent run (``pokeworld train --sigreg-pool``): 'step' or 'pooled'; runs it
    does not apply to (token, reconstruction) keep theirs. A non-default value is part of each run's name."""
    environment: str = "reference"
    """Environment of every corpus the map generates (``pokeworld generate --environment``): 'reference' (the
    authors' released simulator, the default) or 'calibrated' (every record made before it; docs/design.md,
    "PokeWorld")."""
    contact_damping: str = ""
    """Contact-damping law of every corpus the map generates (``PhysicsConfig.contact_damping``): empty for the
    environment's own ('hertz' in the reference, 'tangent' in the calibrated one), or 'hertz', 'tangent',
    'constant' (docs/design.md, "Contact damping")."""
    sigreg_reference_rows: int = 0
    """SIGReg statistic of every global-latent run at this sample count (``pokeworld train
    --sigreg-reference-rows``; 0: each run's own rows). 128 gives the paper's batch-128 strength at any batch; a
    non-default value is part of each run's name."""
    gnll_variance: str = "bounded"
    """Variance parameterisation of every Gaussian-NLL run (``pokeworld train --gnll-variance``: bounded, free,
    beta, per_head); part of those runs' names when not the training default ('bounded')."""
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
    measure_device: str = "auto"
    """Where each finished run is measured: 'auto' (on the device it trained on, the GPU when there is one, its
    probes there too) or 'cpu' (the machine's CPU cores, probes on the host: on a GPU allocation the device's own
    cores). Not part of a measurement's key: both read the same numbers to float rounding (tests/test_cuda.py)."""
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
    certify: bool = True
    """Compute the corpora's certificates. Off (``--no-certify``): none are computed, and the record's certificates
    and gates stay empty. A GPU allocation (``scripts/gpu_allocation.sh``) spends its minutes on training and leaves
    them to the CPU side, where ``pokeworld certify`` runs on the same seeded corpus and
    ``scripts/merge_allocations.py --certificates`` adds them to the merged record (checked against its corpus
    hash)."""
    stack_max_members: int = 0
    """With ``stack``: most members per stacked group (0 = no limit; lower it when a group does not fit in memory)."""
    pack: str = ""
    """Write the small results to this .tar.gz (paths relative to ``out``): every run's config.json,
    metrics.jsonl and measure*.json, each corpus's certificates.json and manifest.json, map_config.json,
    progress.json, results.json/.md and the figure; never checkpoints, TensorBoard events or data."""

    LIMITS = {"seeds": SEED, "lambdas": Limit(0, 1e6), "sigreg_weight": Limit(0, 1e6),
              "ordering_sigreg_weight": Limit(0, 1e6),
              "sigreg_reference_rows": Limit(0, 2**31), "train_steps": Limit(0, 10**9),
              "train_batch_size": Limit(0, 65536), "num_episodes": Limit(0, 10**7), "data_seed": SEED,
              "split_fractions": FRACTION, "certify_max_windows": Limit(0, 10**8), "certify_epochs": Limit(0, 10**5),
              "certify_fit_episodes": Limit(-1, 10**6), "measure_max_windows": Limit(0, 10**8),
              "time_budget_min": Limit(0, 1e7), "time_reserve_min": Limit(0, 1e7), "stack_max_members": Limit(0, 10**4)}

    def __post_init__(self) -> None:
        super().__post_init__()  # checks every field's type and range (LaunchOptions.__post_init__)

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
        if self.split_fractions:
            check_fractions("MapConfig.split_fractions", self.split_fractions)
        if self.measure_device not in ("auto", "cpu"):
            raise ConfigError(f"measure_device must be 'auto' or 'cpu', got {self.measure_device!r}")
        if set(self.measure_kinds) - set(KINDS):
            raise ConfigError(f"unknown measure_kinds {sorted(set(self.measure_kinds) - set(KINDS))}; choose from {list(KINDS)}")
        if self.preset not in ("tiny", "cpu", "paper"):
            raise ConfigError(f"unknown preset {self.preset!r}; choose tiny, cpu or paper")
        if self.train_preset and self.train_preset not in TRAIN_PRESETS:
            raise ConfigError(f"unknown train_preset {self.train_preset!r}; choose one of {sorted(TRAIN_PRESETS)}")
        environments.check(self.environment)
        if self.contact_damping and self.contact_damping not in DAMPING_LAWS:
            raise ConfigError(f"contact_damping must be one of {list(DAMPING_LAWS)}, got {self.contact_damping!r}")
        if self.sigreg_reference_rows < 0:
            raise ConfigError(f"sigreg_reference_rows must be ≥ 0, got {self.sigreg_reference_rows}")
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
        if self.certify_alongside and not self.certify:
            raise ConfigError("certify_alongside computes the certificates, which --no-certify leaves out; drop one")
        if self.stack_max_members < 0:
            raise ConfigError(f"stack_max_members must be ≥ 0, got {self.stack_max_members}")
        if self.pack and not self.pack.endswith((".tar.gz", ".tgz")):
            raise ConfigError(f"pack must name a .tar.gz file, got {self.pack!r}")


def recorded_map_config(recorded: dict) -> dict:
    """A map config as a record wrote it, with the environment of a record made before environments existed
    (``calibrated``, its corpora's) where it names none, so an old record is read back as what it ran."""
    return {"environment": environments.LEGACY, **recorded}


__all__ = ["MapConfig", "VARIANT_ORDER", "recorded_map_config"]
