"""Dataset generation: roll the mixed policy in PokeWorld and write a pokeworld store."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from .. import __version__
from ..config import apply_overrides, from_dict, from_preset, to_dict
from ..data import Dataset, assign_splits, check_store_destination, save, store_is_current, store_lock
from ..errors import ConfigError
from ..io import check_writable_dir
from .core import PARAM_NAMES, ParamRanges, PhysicsConfig, PokeWorldSim
from .policy import MixedPolicy, PolicyConfig
from .stats import CONTEXT, HORIZON, corpus_stats


@dataclass
class GenerateConfig:
    """Generate a PokeWorld corpus."""

    out: str = "data/pokeworld"
    """Output directory (written atomically; an existing complete store is kept unless --overwrite). A folder
    holding anything but a pokeworld store is refused, never emptied; ``.<name>.lock`` beside it marks a writer."""
    seed: int = 0
    """Master seed: the same seed and config give byte-identical arrays."""
    num_episodes: int = 2400
    """Number of episodes."""
    episode_steps: int = 64
    """Control steps per episode (frames are one more)."""
    split_fractions: tuple[float, float, float] = (0.6, 0.2, 0.2)
    """Fractions of episodes in train / probe-fit / probe-test (disjoint)."""
    corpus: str = "standard"
    """Named corpus variant applied on top (see CORPORA): standard, contact_poor, frame_averaged, bias0.5, bias1.5,
    bias2.5, gain, open_loop."""
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

    def __post_init__(self) -> None:
        if self.num_episodes < 3:
            raise ConfigError(f"num_episodes must be >= 3 (one per split), got {self.num_episodes}")
        if self.episode_steps < 2:
            raise ConfigError(f"episode_steps must be >= 2, got {self.episode_steps}")
        if self.batch_envs < 1:
            raise ConfigError(f"batch_envs must be >= 1, got {self.batch_envs}")
        if self.corpus not in CORPORA:
            raise ConfigError(f"unknown corpus {self.corpus!r}; choose one of {sorted(CORPORA)}")


# Named corpora of the paper: each is a set of overrides of the standard generator.
CORPORA: dict[str, dict] = {
    "standard": {},
    "contact_poor": {"policy": {"glide_fraction": 0.95}},
    "frame_averaged": {"physics": {"frame_averaged_touch": True}},
    "bias0.5": {"ranges": {"bias": 0.5}},
    "bias1.5": {"ranges": {"bias": 1.5}},
    "bias2.5": {"ranges": {"bias": 2.5}},
    "gain": {"ranges": {"gain": (0.85, 1.15)}},
    # the standard corpus with a fifth of its program slots running the planner's own two-knot programs open-loop
    # (docs/design.md, "Planning: open-loop behaviour data and the rank test")
    "open_loop": {"policy": {"open_loop_share": 0.2}},
}

PRESETS: dict[str, dict] = {
    "tiny": {"num_episodes": 48, "batch_envs": 48},
    "cpu": {"num_episodes": 2400},
    "paper": {"num_episodes": 8000},
}


def make_config(preset: str = "cpu", **overrides) -> GenerateConfig:
    return from_preset(GenerateConfig, PRESETS, preset, **overrides)


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
    if d["physics"]["contact_damping"] == LEGACY_PHYSICS["contact_damping"]:
        del d["physics"]["contact_damping"]  # the law every store had before the field existed: they stay current
    return d


LEGACY_PHYSICS = {"contact_damping": "tangent"}
"""Physics fields a store's manifest may lack, with the value every store written before the field existed had."""


def generator_config(manifest: dict) -> GenerateConfig:
    """The generator config a store of ``pokeworld generate`` was made with, from its manifest: a field the
    manifest lacks takes the value stores had before the field existed (:data:`LEGACY_PHYSICS`, the open-loop
    share 0), never today's default, so an old store is re-made, extended or simulated as what it is."""
    config = dict(manifest.get("config", {}))
    config["physics"] = {**LEGACY_PHYSICS, **config.get("physics", {})}
    return from_dict(GenerateConfig, config)


def simulate(cfg: GenerateConfig, progress: bool = True, render: bool = True) -> Dataset:
    """Roll out ``cfg.num_episodes`` episodes and return them as an in-memory :class:`Dataset`.

    ``render=False`` leaves the frames black (labels, proprio, touch and actions are unchanged,
    since nothing in the dynamics reads the frames): the fast path for corpus statistics.
    """
    raw_cfg, cfg = cfg, resolved(cfg)
    E, T, S = cfg.num_episodes, cfg.episode_steps, cfg.physics.image_size
    frames = np.zeros((E, T + 1, S, S), np.uint8)
    proprio = np.zeros((E, T + 1, 4), np.float32)
    touch = np.zeros((E, T + 1, 7), np.float32)
    actions = np.zeros((E, T, 2), np.float32)
    lab = {k: np.zeros((E, T + 1, 2), np.float32) for k in ("object_pos", "object_vel", "finger_pos", "finger_vel")}
    lab["contact"] = np.zeros((E, T + 1), np.float32)
    params = np.zeros((E, len(PARAM_NAMES)))
    ss = np.random.SeedSequence(cfg.seed)
    split_rng, *batch_seeds = [np.random.default_rng(s) for s in ss.spawn(1 + -(-E // cfg.batch_envs))]
    bar = tqdm(total=E * T, desc="simulate", unit="step", disable=not progress, unit_scale=True)
    for b, start in enumerate(range(0, E, cfg.batch_envs)):
        stop = min(start + cfg.batch_envs, E)
        n = stop - start
        rng = batch_seeds[b]
        sim = PokeWorldSim(n, cfg.physics, cfg.ranges, seed=int(rng.integers(2**63)))
        pol = MixedPolicy(cfg.policy, n, rng, cfg.physics.dt)
        launch, vel = pol.reset()
        obs = sim.reset(object_vel=vel)
        params[start:stop] = sim.params
        for t in range(T + 1):
            priv = sim.privileged()
            sl = (slice(start, stop), t)
            frames[sl], proprio[sl], touch[sl] = obs["vision"], obs["proprio"], obs["touch"]
            for k in ("object_pos", "object_vel", "finger_pos", "finger_vel"):
                lab[k][sl] = priv[k]
            lab["contact"][sl] = priv["contact"]
            if t == T:
                break
            a = pol.act(obs["proprio"], priv["object_pos"], priv["contact"])
            actions[sl] = a
            obs = sim.step(a, render=render)
            bar.update(n)
    bar.close()
    split = assign_splits(E, cfg.split_fractions, split_rng)
    par = {name: params[:, i].astype(np.float32) for i, name in enumerate(PARAM_NAMES)}
    par["log_m"] = np.log(params[:, 0]).astype(np.float32)
    par["log_k"] = np.log(params[:, 2]).astype(np.float32)
    manifest = {"generator": "pokeworld.sim.generate", "version": __version__, "seed": cfg.seed,
                "config": content_config(raw_cfg), "corpus": cfg.corpus, "kind": "pokeworld"}
    ds = Dataset(frames=frames, proprio=proprio, touch=touch, actions=actions, labels=lab,
                 params=par, split=split, manifest=manifest)
    if T + 1 >= CONTEXT + HORIZON:
        ds.manifest["stats"] = corpus_stats(ds)  # the observables the calibration targets (pokeworld stats)
    return ds


def run(cfg: GenerateConfig) -> Path:
    """Generate and write the corpus described by ``cfg``; skip if an identical, intact one already exists.

    Before simulating: ``out`` must be free or hold a pokeworld store (:func:`~pokeworld.data.check_store_destination`),
    its folder writable, and no other writer at work on it (:func:`~pokeworld.data.store_lock`, held to the end).
    """
    out = Path(cfg.out)
    check_store_destination(out, "pokeworld")
    check_writable_dir(out.parent)
    with store_lock(out):
        if store_is_current(out, content_config(cfg), cfg.overwrite):
            print(f"[generate] {out} already holds this corpus; skipping")
            return out
        ds = simulate(cfg)
        save(ds, out)
    counts = ds.manifest["split_counts"]
    print(f"[generate] wrote {ds.num_episodes} episodes ({counts}) to {out}")
    return out


def episode_contact_fraction(ds: Dataset) -> float:
    """Fraction of episodes that contain any finger-object contact."""
    return float((ds.labels["contact"].max(axis=1) > 0).mean())


__all__ = ["GenerateConfig", "CORPORA", "PRESETS", "make_config", "simulate", "run"]
