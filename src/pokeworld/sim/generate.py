"""Dataset generation: roll the mixed policy in PokeWorld and write a pokeworld store."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from .. import __version__
from ..data import Dataset, assign_splits, check_store_destination, save, store_is_current, store_lock
from ..io import check_writable_dir, remove_stale_temporaries
from .core import PARAM_NAMES, SIM_PARAM_NAMES, PokeWorldSim
from .generate_config import (  # the settings live there (the store reader checks manifests with them)
    CORPORA,
    LEGACY_PHYSICS,
    PRESETS,
    GenerateConfig,
    content_config,
    generator_config,
    make_config,
    resolved,
    store_bytes,
)
from .policy import make_policy
from .stats import CONTEXT, HORIZON, corpus_stats


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
    params = np.zeros((E, len(SIM_PARAM_NAMES)))
    ss = np.random.SeedSequence(cfg.seed)
    split_rng, *batch_seeds = [np.random.default_rng(s) for s in ss.spawn(1 + -(-E // cfg.batch_envs))]
    bar = tqdm(total=E * T, desc="simulate", unit="step", disable=not progress, unit_scale=True)
    for b, start in enumerate(range(0, E, cfg.batch_envs)):
        stop = min(start + cfg.batch_envs, E)
        n = stop - start
        rng = batch_seeds[b]
        sim = PokeWorldSim(n, cfg.physics, cfg.ranges, seed=int(rng.integers(2**63)))
        pol = make_policy(cfg.policy, n, rng, cfg.physics.dt)
        launch, vel = pol.reset()
        obs = sim.reset(object_vel=vel)
        params[start:stop] = sim.params
        for t in range(T + 1):
            priv = sim.privileged()
            sl = (slice(start, stop), t)
            frames[sl], proprio[sl], touch[sl] = obs["vision"][..., 0], obs["proprio"], obs["touch"]
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
    # the drift acceleration is stored only where it is drawn: every other store keeps the layout (and hash) it had
    stored = SIM_PARAM_NAMES if cfg.ranges.drift > 0 else PARAM_NAMES
    par = {name: params[:, i].astype(np.float32) for i, name in enumerate(SIM_PARAM_NAMES) if name in stored}
    par["log_m"] = np.log(params[:, 0]).astype(np.float32)
    par["log_k"] = np.log(params[:, 2]).astype(np.float32)
    manifest = {"generator": "pokeworld.sim.generate", "version": __version__, "seed": cfg.seed,
                "config": content_config(raw_cfg), "corpus": cfg.corpus, "kind": "pokeworld",
                "environment": cfg.environment}
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
        if out.parent.is_dir():  # a killed writer's half-written store (we hold its lock: no writer is left)
            remove_stale_temporaries(out.parent, out.name)
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


__all__ = ["GenerateConfig", "CORPORA", "PRESETS", "LEGACY_PHYSICS", "make_config", "resolved", "content_config",
           "generator_config", "store_bytes", "simulate", "run"]
