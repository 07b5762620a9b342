"""``pokeworld swm-certify ENV_ID --factors ...``: what a world model knows about an swm environment's own physics.

stable-worldmodel environments vary physical factors when they are named in ``options={"variation": [...]}``
(``swm/FingerDMControl-v0``: ``spinner.density``, ``spinner.friction``, ``agent.proximal_density``, ...). The command

0. checks that each factor changes the non-pixel observations at all (:mod:`pokeworld.swm.factor_effect`) and
   warns about an inert one (kept as a negative control);
1. collects a corpus with ``swm.World`` and a behaviour policy (swm's ``RandomPolicy``, or actions held for several
   steps: :mod:`pokeworld.swm.behaviour`) under the named variations (HDF5, ``<out>/
   corpus.h5``; reused when collected with the same settings), or takes an existing labelled dataset (``--data``);
2. reads it into a protocol store (:mod:`pokeworld.swm.factors`: factors constant within episodes are the targets,
   the others are dropped and listed);
3. certifies every factor from raw non-pixel observations and actions (:mod:`pokeworld.swm.factor_gate`: GRU oracle,
   linear floor, local dynamics, the gate) before any model is read;
4. trains a small LeWM with its own objective on the train episodes (:mod:`pokeworld.swm.lewm`, as
   ``swm-certify-lewm`` does) and builds its untrained twin;
5. runs :func:`pokeworld.protocol.certify_model` on both with those certificates, and writes the factor table and
   figure (:mod:`pokeworld.swm.factor_report`): ``<out>/swm_certify.{json,md,png}``;
6. with ``--variants``, trains and probes X-JEPA's targets-vs-inputs factorial beside it (:mod:`pokeworld.swm.
   factorial`); ``pokeworld swm-targets`` puts several environments' records side by side.

DeepMind Control environments need ``dm-control`` and ``mujoco`` (not in the swm extra) and a software GL for
headless rendering; when ``MUJOCO_GL`` is unset the command sets it to ``osmesa`` (Debian: ``libosmesa6``).
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import shlex
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from .. import protocol as P
from ..config import config_error, from_preset, to_dict
from ..errors import ConfigError, DataError
from ..evaluate import tables as R
from ..io import (
    atomic_path,
    hash_arrays,
    read_json_if_present,
    read_jsonl,
    save_text,
    write_json,
)
from ..progress import heartbeat
from ..train.config import PRESETS as TRAIN_PRESETS
from . import factorial as X, lewm_config as LC
from .behaviour import POLICIES, check_hold, make_policy
from .factor_effect import factor_effects, inert_words
from .factor_gate import KIND, FactorCertifyConfig, certify_factors
from .factor_report import factor_rows, figure, table_markdown
from .factors import FactorDataConfig, read_factors
from .parallel_collect import collect_in_parallel
from .require import stable_worldmodel

CORPUS = "corpus.h5"
RESULT = "swm_certify"


@dataclass
class SwmCertifyConfig:
    """Certify what a world model knows about an swm environment's physical factors (``pokeworld swm-certify``)."""

    env: str = "swm/FingerDMControl-v0"
    """stable-worldmodel environment id to collect from (ignored with --data)."""
    factors: tuple[str, ...] = ()
    """Variation keys to vary and certify (e.g. spinner.density spinner.friction); with --data, empty takes every
    variation.* column."""
    data: str = ""
    """An existing labelled swm dataset (.h5 or .lance) to certify instead of collecting."""
    out: str = "out/swm/certify"
    """Output directory: corpus.h5, lewm/, protocol/, swm_certify.{json,md,png}."""
    episodes: int = 240
    """Episodes to collect."""
    steps: int = 48
    """Steps per collected episode."""
    num_envs: int = 1
    """Environments World steps side by side (in one process: this batches the policy, not the simulation)."""
    workers: int = 1
    """Processes collecting in parallel, each a share of the episodes, merged in order (pokeworld.swm.
    parallel_collect); 2 uses both cores of a 2-core machine. The corpus depends on it (each worker seeds its own
    resets), so it is fixed, not the machine's core count."""
    policy: str = "random"
    """Behaviour policy of the collection: random (swm's RandomPolicy, a new action every step) or held (each random
    action held for a random number of steps in --hold, which excites the dynamics; pokeworld.swm.behaviour)."""
    hold: tuple[int, int] = (4, 16)
    """--policy held: the fewest and most steps an action is held."""
    image_size: int = 32
    """Side of the collected pixels."""
    observations: tuple[str, ...] = ()
    """Non-pixel observation columns (empty: proprio + touch, observation or state, whichever the data has)."""
    split_fractions: tuple[float, float, float] = (0.5, 0.25, 0.25)
    """Train (LeWM) / probe-fit (certificates and probes) / probe-test fractions of the episodes."""
    seed: int = 0
    """Seed of the collection (resets and behaviour policy), the split, the certificates, LeWM and the probes."""
    certificate: FactorCertifyConfig = field(default_factory=FactorCertifyConfig)
    """The factor certificates (window, GRU oracle size, gate threshold)."""
    lewm_preset: str = "cpu"
    """Preset of the LeWM (pokeworld.swm.lewm.PRESETS)."""
    lewm_steps: int = 0
    """LeWM optimiser steps (0: the preset's)."""
    lewm_overrides: dict[str, Any] = field(default_factory=dict)
    """Other LeWMConfig fields to override, from Python (e.g. {"embed_dim": 32})."""
    protocol_preset: str = "cpu"
    """Preset of pokeworld.protocol.ProtocolConfig (window and stride come from the certificate config)."""
    variants: tuple[str, ...] = ()
    """X-JEPA variants to train beside the LeWM, with the environment's low-dimensional observation in the proprio
    role: V (absent), VF (input only), VX (forecasting target only), VFX (both); empty: the LeWM only."""
    xjepa_preset: str = "cpu"
    """pokeworld train preset of the X-JEPA variants (window and horizons fitted to the episode length)."""
    xjepa_steps: int = 0
    """X-JEPA optimiser steps (0: the preset's)."""
    xjepa_seeds: tuple[int, ...] = (0,)
    """Seeds of the X-JEPA variants (initialisation and window sampling); every variant is trained at each."""

    def __post_init__(self) -> None:
        if self.lewm_steps < 0:
            raise config_error(f"lewm_steps must be >= 0 (0: the preset's), got {self.lewm_steps}")
        for name in ("episodes", "steps", "num_envs", "image_size", "workers"):
            if getattr(self, name) < 1:
                raise config_error(f"{name} must be >= 1, got {getattr(self, name)}")
        if not self.data and self.steps < self.certificate.window:
            raise config_error(f"steps ({self.steps}) must be at least the certificate window "
                               f"({self.certificate.window}): every window lies inside one episode")
        X.check_variants(self.variants)
        if self.policy not in POLICIES:
            raise config_error(f"policy must be one of {list(POLICIES)}, got {self.policy!r}")
        check_hold(self.hold)
        if self.xjepa_steps < 0 or self.xjepa_preset not in TRAIN_PRESETS or not self.xjepa_seeds:
            raise config_error(f"xjepa_steps must be >= 0, xjepa_preset one of {sorted(TRAIN_PRESETS)} and "
                               f"xjepa_seeds not empty, got {self.xjepa_steps}, {self.xjepa_preset!r}, "
                               f"{list(self.xjepa_seeds)}")
        if self.lewm_preset not in LC.PRESETS or self.protocol_preset not in P.PRESETS:
            raise config_error(f"lewm_preset must be one of {sorted(LC.PRESETS)} and protocol_preset one of "
                               f"{sorted(P.PRESETS)}, got {self.lewm_preset!r}, {self.protocol_preset!r}")


PRESETS: dict[str, dict[str, Any]] = {
    "tiny": {"episodes": 32, "steps": 16, "image_size": 16, "lewm_preset": "tiny", "protocol_preset": "tiny",
             "xjepa_preset": "tiny",
             "certificate": {"window": 8, "stride": 2, "epochs": 4, "patience": 2, "gru_hidden": 16,
                             "max_windows": 400}},
    "cpu": {},
    "paper": {"episodes": 2000, "steps": 100, "image_size": 64, "lewm_preset": "paper", "protocol_preset": "paper"},
}


def make_config(preset: str = "cpu", **overrides) -> SwmCertifyConfig:
    return from_preset(SwmCertifyConfig, PRESETS, preset, **overrides)


# --------------------------------------------------------------------------- collection
def variation_names(env_id: str) -> list[str]:
    """The variation keys of ``env_id`` (ConfigError for an unknown id or an environment without variations)."""
    import gymnasium as gym

    stable_worldmodel()
    from .env import register

    register()  # swm/PokeWorld-v0 beside swm's own environments
    try:
        env = gym.make(env_id)
    except gym.error.Error as e:
        known = sorted(k for k in gym.registry if k.startswith("swm/"))
        raise ConfigError(f"unknown environment {env_id!r} ({e}); stable-worldmodel ids: {known}") from None
    except ImportError as e:  # dm_control / mujoco / a renderer missing
        raise ConfigError(f"{env_id} needs a package that is not installed: {e} (DMControl environments: "
                          "pip install dm-control mujoco, and a software GL such as libosmesa6)") from None
    try:
        space = getattr(env.unwrapped, "variation_space", None)
        if space is None:
            raise ConfigError(f"{env_id} has no variation_space: it varies no physical factor")
        return list(space.names())
    finally:
        env.close()


@contextlib.contextmanager
def counted(policy: Any) -> Iterator[list[int]]:
    """While the block runs, ``policy``'s ``get_action`` calls are counted in the yielded one-element list (for
    progress lines)."""
    calls, get_action = [0], policy.get_action

    def counting(*args: Any, **kwargs: Any) -> Any:
        calls[0] += 1
        return get_action(*args, **kwargs)

    policy.get_action = counting
    try:
        yield calls
    finally:  # the closure holds the policy, which holds swm's environments: left in place, that cycle keeps their
        del policy.get_action  # renderers alive until interpreter exit, where freeing them fails loudly


def check_factor_names(cfg: SwmCertifyConfig) -> None:
    """One line for a factor ``cfg.env`` does not vary (or an unknown environment)."""
    names = variation_names(cfg.env)
    unknown = [f for f in cfg.factors if f not in names]
    if unknown:
        raise ConfigError(f"{cfg.env} has no variation {unknown}; its variations: {names}")


def collect(cfg: SwmCertifyConfig, path: Path) -> Path:
    """Record ``cfg.episodes`` episodes of ``cfg.env`` under the variations ``cfg.factors`` with the behaviour policy
    ``cfg.policy`` (HDF5)."""
    swm = stable_worldmodel()
    check_factor_names(cfg)
    # staged inside a private folder (atomic_path: created exclusively, mode 0700, a random name): swm's writer opens
    # its file following links, and a predictable staging name beside the corpus could be planted; only a finished
    # collection is renamed to the final name, and a failed one's folder is removed
    if cfg.workers > 1 and cfg.episodes > 1:
        with atomic_path(path) as staging:
            collect_in_parallel(dataclasses.replace(cfg, workers=1), staging, cfg.workers, collect)
        return path
    world = swm.World(cfg.env, num_envs=cfg.num_envs, image_shape=(cfg.image_size, cfg.image_size),
                      max_episode_steps=cfg.steps, goal_conditioned=False)
    try:
        with atomic_path(path) as staging:
            policy = make_policy(cfg.policy, cfg.seed, cfg.hold)
            world.set_policy(policy)
            writer = swm.data.get_format("hdf5").open_writer(staging, mode="overwrite")
            with counted(policy) as calls:
                def status() -> str:  # one policy call steps every environment once
                    return (f"collecting {cfg.env}: about {min(cfg.episodes, calls[0] * cfg.num_envs // cfg.steps)}"
                            f" of {cfg.episodes} episodes")

                with heartbeat("swm-certify", status):  # swm's tqdm bar is off: it floods redirected logs
                    world.collect(writer=writer, episodes=cfg.episodes, seed=cfg.seed,
                                  options={"variation": list(cfg.factors)}, progress=False)
    finally:
        world.close()
    return path


def headless_gl() -> None:
    """Headless DMControl rendering: dm_control reads ``MUJOCO_GL`` once, when it is first imported, so this runs
    before anything makes an environment."""
    os.environ.setdefault("MUJOCO_GL", "osmesa")


def corpus(cfg: SwmCertifyConfig, out: Path) -> tuple[Path, float]:
    """The dataset to certify and the seconds spent collecting it (0 when given or reused)."""
    if cfg.data:
        if not (Path(cfg.data).suffix in (".h5", ".hdf5") or cfg.data.rstrip("/").endswith(".lance")):
            raise ConfigError(f"--data must be an swm .h5/.hdf5 file or .lance table, got {cfg.data!r}")
        if not Path(cfg.data).exists():
            raise DataError(f"--data {cfg.data} does not exist")
        return Path(cfg.data), 0.0
    headless_gl()
    path, key_path = out / CORPUS, out / "corpus.json"
    key = {k: getattr(cfg, k) for k in ("env", "factors", "episodes", "steps", "num_envs", "image_size", "seed")}
    if cfg.policy != "random":  # corpora collected before the option existed keep their key
        key.update(policy=cfg.policy, hold=cfg.hold)
    if cfg.workers > 1:  # likewise
        key.update(workers=cfg.workers)
    key = json.loads(json.dumps(key))
    if path.exists() and read_json_if_present(key_path, "a cached corpus's key (corpus.json)") == key:
        print(f"[swm-certify] reusing {path}")
        return path, 0.0
    t0 = time.time()
    collect(cfg, path)
    write_json(key_path, key)
    print(f"[swm-certify] collected {cfg.episodes} episodes of {cfg.env} in {time.time() - t0:.0f}s")
    return path, time.time() - t0


def check_effects(cfg: SwmCertifyConfig) -> dict[str, dict]:
    """Whether each factor changes the observations at all (:mod:`pokeworld.swm.factor_effect`), said before the
    collection; {} with --data (no environment to run)."""
    if cfg.data:
        return {}
    headless_gl()
    check_factor_names(cfg)  # registers the environments; one line for an unknown id or factor
    effects = factor_effects(cfg.env, tuple(cfg.factors), steps=cfg.steps)
    for line in inert_words(effects):
        print(f"[swm-certify] warning: {line}", flush=True)
    return effects


# --------------------------------------------------------------------------- the run
def run(cfg: SwmCertifyConfig) -> dict:
    """Collect (or read), certify, train LeWM and its twin, probe, and write the factor table and figure."""
    if not cfg.data and not cfg.factors:
        raise ConfigError("name the factors to vary (e.g. --factors spinner.density spinner.friction), or give "
                          "a labelled dataset with --data")
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    cost: dict[str, float] = {}
    t_all = time.time()
    effects = check_effects(cfg)
    source, cost["collect_s"] = corpus(cfg, out)
    ds = read_factors(source, FactorDataConfig(factors=cfg.factors, observations=cfg.observations,
                                               split_fractions=cfg.split_fractions, seed=cfg.seed))
    digest = hash_arrays(ds.arrays())
    factors = tuple(ds.manifest["probe_params"])
    print(f"[swm-certify] {ds.num_episodes} episodes x {ds.num_steps} steps; factors {list(factors)}; dropped "
          f"{ds.manifest['dropped_factors'] or 'none'}")
    t0 = time.time()
    certificate = dataclasses.replace(cfg.certificate, seed=cfg.seed)
    certs = certify_factors(ds, factors, certificate)
    cost["certify_s"] = time.time() - t0

    from . import lewm as L  # its model classes derive from swm's: imported only when a model is trained

    lcfg = LC.make_config(cfg.lewm_preset, data=f"{source} (content {digest[:16]})", out=str(out / "lewm"),
                         seed=cfg.seed, **({"steps": cfg.lewm_steps} if cfg.lewm_steps else {}), **cfg.lewm_overrides)
    t0 = time.time()
    L.train(lcfg, ds)
    cost["train_s"] = time.time() - t0
    if lcfg.threads:
        torch.set_num_threads(lcfg.threads)
    model = L.LeWMStates(L.load_trained(lcfg.out, lcfg, ds), lcfg.readout)
    twin = L.LeWMStates(L.build_model(lcfg, ds).eval(), lcfg.readout)  # same seed and data statistics, untrained
    pcfg = P.make_config(cfg.protocol_preset, kinds=(KIND,), action_conditioned_kinds=(KIND,),
                         window=certificate.window, stride=certificate.stride, seed=cfg.seed)
    t0 = time.time()
    name = f"LeWM ({lcfg.readout})"
    report = P.certify_model(model, ds, out / "protocol", untrained=twin, certificates=certs, name=name, config=pcfg)
    cost["protocol_s"] = time.time() - t0
    t0 = time.time()
    xjepa = (X.run_factorial(ds, certs, pcfg, out, digest, cfg.variants, cfg.xjepa_seeds, cfg.xjepa_preset,
                             cfg.xjepa_steps) if cfg.variants else None)
    cost["xjepa_s"] = time.time() - t0
    cost["total_s"] = time.time() - t_all
    rows = factor_rows(report, certs)
    result = {"env": None if cfg.data else cfg.env, "source": str(source), "command": command_line(),
              "config": to_dict(cfg), "lewm": to_dict(lcfg), "protocol": to_dict(pcfg),
              "corpus": {"episodes": ds.num_episodes, "steps": ds.num_steps, "content_sha256": digest,
                         "split_counts": {s: int(ds.episodes(s).size) for s in ("train", "probe_fit", "probe_test")},
                         "observations": ds.manifest["observations"], "observation_width": int(ds.proprio.shape[-1]),
                         "frame_shape": list(ds.frames.shape[2:])},
              "factors": rows, "dropped_factors": ds.manifest["dropped_factors"], "factor_effects": effects,
              "certificates": {k: certs[k] for k in ("estimators", "counts", "gate")},
              "training": read_jsonl(out / "lewm" / "metrics.jsonl")[-1:], "xjepa": xjepa,
              "cost_seconds": {k: round(v, 1) for k, v in cost.items()},
              "provenance": {"git": R.git_commit(), "torch_threads": torch.get_num_threads()}}
    write_json(out / f"{RESULT}.json", result)
    figure(rows, name, out / f"{RESULT}.png")
    if xjepa:
        X.figure(xjepa["summary"], cfg.variants, f"{result['env'] or source}: X-JEPA variants (state absent / "
                 "input / target / both) vs the certificate", out / f"{RESULT}_variants.png")
    save_text(out / f"{RESULT}.md", markdown(result, name))
    print("\n".join(table_markdown(rows, name)))
    print(f"[swm-certify] wrote {out / RESULT}.{{json,md,png}} ({cost['total_s']:.0f}s)")
    return result


def policy_words(result: dict) -> str:
    """The collection's behaviour policy in words (a given dataset's is unknown)."""
    cfg = result["config"]
    if cfg["data"]:
        return "given dataset"
    if cfg.get("policy", "random") == "held":
        return f"random actions held {cfg['hold'][0]}–{cfg['hold'][1]} steps"
    return "random policy"


def variants_markdown(xjepa: dict, variants: list[str]) -> list[str]:
    """The X-JEPA factorial's section of the record: what was trained, the factor × variant table, its costs."""
    runs = [r for per_seed in xjepa["variants"].values() for r in per_seed.values()]
    return ["## Targets, not inputs? X-JEPA with the state absent, an input, a target, both", "",
            (f"X-JEPA at the `{xjepa['preset']}` train preset, {runs[0]['steps']} steps, seeds {xjepa['seeds']}, the "
             "environment's low-dimensional observation in the proprio role (no touch stream); cells: predictor-state "
             "R² ridge / MLP (untrained twin's ridge), the mean over seeds; † and \"no claim\": the factor's gate "
             f"failed. Cost: training {sum(r['train_s'] for r in runs):.0f} s, probes "
             f"{sum(r['protocol_s'] for r in runs):.0f} s in all."), "",
            *X.table_markdown(xjepa["summary"], tuple(variants))]


def command_line() -> str:
    """The command as typed when run through the CLI, else a note that it was called from Python."""
    if len(sys.argv) > 1 and sys.argv[1] == "swm-certify":
        return "pokeworld " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    return "pokeworld.swm.certify_env.run (Python)"


def markdown(result: dict, name: str) -> str:
    """The record: what was run, what it cost, the factor table and what was dropped."""
    c, cost = result["corpus"], result["cost_seconds"]
    lines = [f"# What {name} knows about {result['env'] or result['source']}'s physical factors", "",
             f"Command: `{result['command']}`", "",
             (f"Corpus: {c['episodes']} episodes × {c['steps']} steps ({policy_words(result)}; split train / "
              f"probe-fit / probe-test {c['split_counts']['train']} / {c['split_counts']['probe_fit']} / "
              f"{c['split_counts']['probe_test']}), frames {c['frame_shape']}, observations {c['observations']} "
              f"(width {c['observation_width']}), content {c['content_sha256'][:12]}."), "",
             (f"Cost of this invocation (wall seconds; 0: reused from an earlier one or given): collect "
              f"{cost['collect_s']:.0f}, certificates {cost['certify_s']:.0f}, LeWM training {cost['train_s']:.0f}, "
              f"protocol {cost['protocol_s']:.0f}, X-JEPA variants {cost.get('xjepa_s', 0.0):.0f}, total "
              f"{cost['total_s']:.0f}."), "",
             *table_markdown(result["factors"], name), "",
             ("Certificate: held-out R² on probe-test episodes, best of the GRU oracle, the linear floor and the "
              "local-dynamics fit, all reading the raw non-pixel observations and actions of the same windows the "
              "probes read (all windows; the action after the last observation zeroed). Model: leak-free ridge / MLP "
              "probes of the LeWM predictor state; untrained: the same ridge probe of the untrained twin. † and "
              "\"no claim\": the gate failed, so the model's number says nothing about what it knows.")]
    if result.get("xjepa"):
        lines += ["", *variants_markdown(result["xjepa"], result["config"]["variants"])]
    inert = inert_words(result.get("factor_effects") or {})
    if inert:
        lines += ["", "Inert factors (pokeworld.swm.factor_effect): " + "; ".join(inert) + "."]
    if result["dropped_factors"]:
        lines += ["", "Dropped factors (not per-episode targets): "
                  + "; ".join(f"{k}: {v}" for k, v in result["dropped_factors"].items()) + "."]
    return "\n".join(lines) + "\n"


__all__ = ["PRESETS", "SwmCertifyConfig", "check_effects", "check_factor_names", "collect", "command_line", "corpus",
           "counted", "make_config", "markdown", "policy_words", "run", "variants_markdown", "variation_names"]
