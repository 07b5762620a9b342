"""The generator's settings (:class:`GenerateConfig`, its presets and corpora) and how a store's manifest is read
back as them (:func:`generator_config`): kept apart from the generator itself so that the store reader
(:mod:`pokeworld.data`) can check a manifest's settings without importing the simulation pipeline."""

from __future__ import annotations

from dataclasses import dataclass, field

from ..config import (
    FRACTION,
    MAX_STORE_BYTES,
    SEED,
    Limit,
    apply_overrides,
    check_fields,
    check_fractions,
    from_dict,
    shown,
    to_dict,
)
from ..errors import ConfigError, DataError
from . import environments
from .core import ParamRanges, PhysicsConfig
from .policy import PolicyConfig


@dataclass
class GenerateConfig:
    """Generate a PokeWorld corpus."""

    out: str = "data/pokeworld"
    """Output directory (written atomically; an existing complete store is kept unless --overwrite). A folder
    holding anything but a pokeworld store is refused, never emptied; ``.<name>.lock`` beside it marks a writer."""
    seed: int = 0
    """Master seed: the same seed and config give byte-identical arrays."""
    environment: str = environments.DEFAULT
    """Named environment (pokeworld.sim.environments): "reference" (the authors' released simulator, behaviour and
    splits; the default) or "calibrated" (the environment of every record made before it). The base every other
    setting is layered on (``--environment calibrated`` builds the config on that environment's physics, behaviour
    and splits; flags given beside it still win); the manifest records it."""
    num_episodes: int = 2400
    """Number of episodes."""
    episode_steps: int = 64
    """Control steps per episode (frames are one more)."""
    split_fractions: tuple[float, float, float] = (0.625, 0.25, 0.125)
    """Fractions of episodes in train / probe-fit / probe-test (disjoint): the reference's 4,000 / 1,600 / 800
    (its 400 validation episodes are never read by its training or probes, so none are generated)."""
    corpus: str = "standard"
    """Named corpus variant applied on top (see CORPORA): standard, contact_poor, frame_averaged, bias0.5, bias1.5,
    bias2.5, gain, drift, drift_fixed_gamma, open_loop."""
    batch_envs: int = 1024
    """Episodes simulated simultaneously."""
    overwrite: bool = False
    """Regenerate even if a complete store exists at ``out``. Replaces only a folder pokeworld verifies as its own
    store of this kind (only files pokeworld writes in a store: data.h5, manifest.json, certificates; the manifest
    readable and of kind "pokeworld"); any other folder is refused, never deleted."""
    physics: PhysicsConfig = field(default_factory=PhysicsConfig)
    """Arena constants."""
    ranges: ParamRanges = field(default_factory=ParamRanges)
    """Hidden-parameter distributions."""
    policy: PolicyConfig = field(default_factory=PolicyConfig)
    """Behaviour-policy knobs."""

    # far above the paper's (8,000 episodes of 64 steps), far below what a machine can hold; the store's size is
    # bounded as a whole below
    LIMITS = {"seed": SEED, "num_episodes": Limit(3, 10**7), "episode_steps": Limit(2, 10**4),
              "split_fractions": FRACTION, "batch_envs": Limit(1, 10**5)}

    def __post_init__(self) -> None:
        check_fields(self)
        check_fractions("GenerateConfig.split_fractions", self.split_fractions)
        environments.check(self.environment)
        if self.corpus not in CORPORA:
            raise ConfigError(f"unknown corpus {self.corpus!r}; choose one of {sorted(CORPORA)}")
        if CORPORA[self.corpus].get("ranges", {}).get("drift", self.ranges.drift) > 0 and \
                self.physics.calibrated_dynamics:
            raise ConfigError(f"corpus {self.corpus!r} draws a drift acceleration, which only the reference "
                              "environment's dynamics have; use --environment reference (the default)")
        size = store_bytes(self.num_episodes, self.episode_steps, self.physics.image_size)
        if size > MAX_STORE_BYTES:
            raise ConfigError(f"{self.num_episodes} episodes of {self.episode_steps} steps at image_size "
                              f"{self.physics.image_size} make a store of {size / 2**30:.0f} GiB; a store may hold at "
                              f"most {MAX_STORE_BYTES >> 30} GiB (data.MAX_STORE_BYTES): use fewer episodes or steps "
                              "or a smaller image_size")


STEP_FLOATS = 4 + 7 + 2 + 9
"""float32 values stored per step besides the frame: proprio, touch, action and the labels."""


def store_bytes(episodes: int, steps: int, image_size: int) -> int:
    """About how many bytes a generated store's arrays hold (all are built in memory before they are written)."""
    return episodes * (steps + 1) * (image_size * image_size + 4 * STEP_FLOATS)


# Named corpora of the paper: each is a set of overrides of the standard generator.
CORPORA: dict[str, dict] = {
    "standard": {},
    "contact_poor": {"policy": {"glide_fraction": 0.95}},
    "frame_averaged": {"physics": {"frame_averaged_touch": True}},
    "bias0.5": {"ranges": {"bias": 0.5}},
    "bias1.5": {"ranges": {"bias": 1.5}},
    "bias2.5": {"ranges": {"bias": 2.5}},
    "gain": {"ranges": {"gain": (0.85, 1.15)}},
    # the paper's rejected constructions of the slow × linear cell (App. C "Constructing the cells"): a drift
    # acceleration of the object, a_d ~ U(-0.15, 0.15)^2 as the release draws it, with drag per episode (i) and with
    # drag fixed at the release's 1.5 (ii)
    "drift": {"ranges": {"drift": 0.15}},
    "drift_fixed_gamma": {"ranges": {"drift": 0.15, "gamma": (1.5, 1.5)}},
    # the standard corpus with a fifth of its program slots running the planner's own two-knot programs open-loop
    # (docs/design.md, "Planning: open-loop behaviour data and the rank test")
    "open_loop": {"policy": {"open_loop_share": 0.2}},
}

PRESETS: dict[str, dict] = {
    "tiny": {"num_episodes": 48, "batch_envs": 48},
    "cpu": {"num_episodes": 2400},
    "paper": {"num_episodes": 6400},  # 4,000 / 1,600 / 800, the reference's
}
CALIBRATED_PRESETS = {"paper": {"num_episodes": 8000}}
"""The calibrated environment's preset sizes where they differ (its paper corpus: 4,800 / 1,600 / 1,600)."""


def make_config(preset: str = "cpu", **overrides) -> GenerateConfig:
    """The generator config of ``preset`` built on the environment ``overrides`` names (default the reference):
    the environment's layer first, then the preset, then the overrides, so an explicit value always wins."""
    env = environments.check(overrides.get("environment", environments.DEFAULT))
    if preset not in PRESETS:
        raise ConfigError(f"unknown preset {preset!r} for GenerateConfig; choose one of {sorted(PRESETS)}")
    sizes = {**PRESETS[preset], **(CALIBRATED_PRESETS.get(preset, {}) if env == "calibrated" else {})}
    cfg = apply_overrides(environments.layered(GenerateConfig(), env), {**sizes, "environment": env})
    return apply_overrides(cfg, overrides) if overrides else cfg


def resolved(cfg: GenerateConfig) -> GenerateConfig:
    """``cfg`` with its named corpus overrides applied."""
    return apply_overrides(cfg, CORPORA[cfg.corpus])


def content_config(cfg: GenerateConfig) -> dict:
    """The resolved config minus fields that do not affect the arrays (output path, overwrite).

    Without open-loop slots (``policy.open_loop_share`` 0) both open-loop fields are left out too: nothing is
    drawn for them, so the arrays are those of the generator before the fields existed, and stores written then
    must stay current rather than be refused as built from another config.
    """
    d = to_dict(resolved(cfg))
    for k in ("out", "overwrite"):
        d.pop(k)
    if d["policy"]["open_loop_share"] == 0:
        for k in ("open_loop_share", "open_loop_aim"):
            del d["policy"][k]
    for k, v in LEGACY_PHYSICS.items():  # the values every store had before the field existed: they stay current
        if d["physics"][k] == v:
            del d["physics"][k]
    if d["physics"].get("walls", "spring") != "hertz":
        d["physics"].pop("wall_stiffness")  # read by the Hertz walls only
    if d["policy"]["behaviour"] == LEGACY_POLICY["behaviour"]:
        for k in environments.NEW_POLICY_FIELDS:  # the calibrated behaviour reads none of them
            del d["policy"][k]
    if d["environment"] == environments.LEGACY:
        del d["environment"]
    if d["ranges"].get("drift") == 0:  # no drift is what every store had before the field existed
        del d["ranges"]["drift"]
    return d


LEGACY_PHYSICS = {"contact_damping": "tangent", "walls": "spring", "speed_cap": 0.0, "drag": "exact",
                  "touch_units": "force_max", "placement": "calibrated"}
"""Physics fields a store's manifest may lack, with the value every store written before the field existed had."""
LEGACY_POLICY = {"behaviour": "calibrated"}
"""Policy fields a store's manifest may lack, with the value every store written before the field existed had."""


def generator_config(manifest: dict, where: str = "the store's manifest") -> GenerateConfig:
    """The generator config a store of ``pokeworld generate`` was made with, from its manifest: a field the
    manifest lacks takes the value stores had before the field existed (:data:`LEGACY_PHYSICS`, the open-loop
    share 0), never today's default, so an old store is re-made, extended or simulated as what it is.

    The manifest is data, not configuration (its config is not covered by the content hash), so every field goes
    through the config's own checks (types, finite, ranges) and its seed through :data:`~pokeworld.config.SEED`:
    anything else is one DataError naming ``where`` and the field, before anything is simulated."""
    config, seed = manifest.get("config", {}), manifest.get("seed", 0)
    try:
        if not isinstance(config, dict) or not isinstance(config.get("physics", {}), dict):
            raise ConfigError(f"its config {shown(config)} is not a JSON object of generator settings")
        if not (isinstance(seed, int) and not isinstance(seed, bool) and SEED.admits(seed)):
            raise ConfigError(f"its seed must be an integer {SEED}, got {shown(seed)}")
        if not isinstance(config.get("policy", {}), dict):
            raise ConfigError(f"its config's policy {shown(config.get('policy'))} is not a JSON object")
        config = {"environment": environments.LEGACY, **config}
        config["physics"] = {**LEGACY_PHYSICS, **config.get("physics", {})}
        config["policy"] = {**LEGACY_POLICY, **config.get("policy", {})}
        return from_dict(GenerateConfig, config)
    except ConfigError as e:
        problem = str(e)
        for cls, field in MANIFEST_FIELDS.items():  # name the field as the manifest spells it
            problem = problem.replace(f"{cls}.", f"config.{field}", 1) if problem.startswith(cls) else problem
        raise DataError(f"{where}: {problem}; the store's manifest is damaged or not pokeworld's: regenerate the "
                        "store") from None


MANIFEST_FIELDS = {"GenerateConfig": "", "PhysicsConfig": "physics.", "ParamRanges": "ranges.",
                   "PolicyConfig": "policy."}
"""Where each config's fields sit in a store manifest's ``config``."""


__all__ = ["GenerateConfig", "STEP_FLOATS", "store_bytes", "CORPORA", "PRESETS", "make_config", "resolved", "content_config", "LEGACY_PHYSICS", "LEGACY_POLICY", "generator_config", "MANIFEST_FIELDS"]
