"""``pokeworld real``: the paper's real-robot experiments (§5, App. C) over converted RH20T stores.

Experiments (:data:`EXPERIMENTS`), each a list of :class:`RealRun` built from the config:

* ``kuka``: the pilot configuration (cfg7, far camera), every variant (Table "kuka");
* ``viewpoint``: the same variants on the far, close-up and two-view cfg7 stores (Table "viewpoint");
* ``scaling``: the four-arm factorial (V, VX, VF, VFX) on cfg1 at several training-set sizes and
  fixed compute, plus a +50 %-compute control at full scale (Table "cfg1", Fig. "scissors",
  the future-force and untrained-bound tables);
* ``joint``: one configuration-blind VFX trained on cfg7 + cfg1 concatenated, evaluated on each,
  beside the two specialists (Table "joint", "cross-embodiment").

Every run trains with ``pokeworld train`` on a store (the given ones, a training-scene subset for
the scaling points, or the concatenation for the joint model) and is evaluated by
:mod:`pokeworld.real.evaluate` on its evaluation store(s). Runs execute through the identifiability
map's launcher (:func:`pokeworld.experiments.launch.launch`: local process pool or submitit), and
re-running skips finished runs and resumes unfinished ones. Results land in ``out/results.json``,
``out/results.md`` (tables with the paper's numbers beside ours) and, when the scaling experiment ran, ``out/scissors.png``.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from .. import train
from ..config import from_preset, to_dict
from ..data import (
    Dataset,
    concatenate,
    is_complete,
    load,
    read_manifest,
    save,
    store_is_current,
)
from ..errors import ConfigError, DataError
from ..experiments.launch import LaunchOptions, cores, default_workers, launch
from ..io import read_json_if_present, write_json
from ..models.xjepa import VARIANTS
from . import evaluate, report
from .rh20t import stratified_indices

STORES = ("kuka", "kuka_close", "kuka_two_view", "flexiv")
"""Store fields of :class:`RealConfig`: cfg7 far / close-up / two-view, cfg1 far."""


@dataclass
class RealConfig(LaunchOptions):
    """Run the real-robot experiments over converted RH20T stores."""

    out: str = "out/real"
    """Output directory: derived stores, runs/, results.json, results.md, scissors.png (scaling experiment only)."""
    preset: str = "cpu"
    """Preset of every stage (train, evaluate): tiny (seconds, tests), cpu (2 CPU cores) or paper (GPU)."""
    kuka: str = ""
    """Converted cfg7 (KUKA) store, far camera (``pokeworld rh20t-convert ROOT --cfg 7``)."""
    kuka_close: str = ""
    """Converted cfg7 store, close-up (wrist) camera (``--camera close``), for the viewpoint study."""
    kuka_two_view: str = ""
    """Converted cfg7 store, far | close side by side (``--camera two_view``), for the viewpoint study."""
    flexiv: str = ""
    """Converted cfg1 (Flexiv) store, far camera, for the scaling factorial and the joint model."""
    experiments: tuple[str, ...] = ()
    """Experiments to run (kuka, viewpoint, scaling, joint); empty = every one whose stores are given."""
    variants: tuple[str, ...] = ("V", "VX", "VX_t", "VFX")
    """Variants of the kuka and viewpoint experiments (paper Table "kuka")."""
    arms: tuple[str, ...] = ("V", "VX", "VF", "VFX")
    """The four arms (inputs x targets) of the scaling factorial."""
    scales: tuple[float, ...] = (800, 2000, 1.0)
    """Training-set sizes of the scaling factorial: a value > 1 is a number of corpus scenes (the paper's
    "episodes"), a value in (0, 1] a fraction of the corpus; the training split is subsampled by scene
    to that share, probe and held-out splits stay whole, so every scale is measured on the same episodes."""
    compute_control: float = 1.5
    """Step multiplier of the compute control at full scale (paper: +50 %); 0 = no control runs."""
    joint_variant: str = "VFX"
    """Variant of the configuration-blind joint model."""
    train_steps: int = 0
    """Training steps per run at fixed compute (0 keeps the train preset's)."""
    image_size: int = 0
    """Encoder input side (0 keeps the train preset's; the paper preset uses the stores' 96)."""
    seed: int = 0
    """Training seed of every run (also the scene-subset seed)."""
    mlp_probes: bool = False
    """Also fit MLP probes (tables report ridge)."""
    untrained: bool = True
    """Evaluate untrained copies too (the untrained-encoder bounds)."""

    def __post_init__(self) -> None:
        super().__post_init__()

        bad = set(self.experiments) - set(EXPERIMENTS)
        if bad:
            raise ConfigError(f"unknown experiments {sorted(bad)}; choose from {list(EXPERIMENTS)}")
        badv = (set(self.variants) | set(self.arms) | {self.joint_variant}) - set(VARIANTS)
        if badv:
            raise ConfigError(f"unknown variants {sorted(badv)}; choose from {list(VARIANTS)}")
        if self.preset not in ("tiny", "cpu", "paper"):
            raise ConfigError(f"unknown preset {self.preset!r}; choose tiny, cpu or paper")
        if not self.scales or min(self.scales) <= 0:
            raise ConfigError(f"scales must be positive (scene counts > 1 or fractions <= 1), got {self.scales}")
        if self.compute_control < 0:
            raise ConfigError("compute_control must be >= 0")


PRESETS: dict[str, dict] = {
    # tests: two variants / arms, two scales, fixture-sized stores
    "tiny": {"preset": "tiny", "variants": ("V", "VFX"), "arms": ("VX", "VFX"), "scales": (0.5, 1.0)},
    # 2 CPU cores: fractions (synthetic corpora are small), 1,500 steps per run at 32x32
    "cpu": {"preset": "cpu", "scales": (0.2, 0.5, 1.0), "train_steps": 1500},
    # App. B/C: 20k steps, 96x96 frames, 800 / 2,000 / 4,258 scenes
    "paper": {"preset": "paper", "image_size": 96, "mlp_probes": True},
}


def make_config(preset: str = "cpu", **overrides) -> RealConfig:
    return from_preset(RealConfig, PRESETS, preset, **overrides)


# --------------------------------------------------------------------------- runs
@dataclass(frozen=True)
class RealRun:
    """One training run and the stores it is evaluated on."""

    name: str
    experiment: str
    store: str
    """Training store key: a :data:`STORES` field, ``flexiv@<scale>`` (a scene subset) or ``joint``."""
    variant: str
    evals: tuple[str, ...]
    """Evaluation store keys (given stores only)."""
    steps_factor: float = 1.0
    """Training steps relative to the fixed-compute budget."""
    scale: float = 1.0


def _run(exp, store, variant, evals=None, steps_factor=1.0, scale=1.0, seed=0) -> RealRun:
    tag = "" if steps_factor == 1.0 else f"-x{steps_factor:g}"
    return RealRun(f"{store.replace('@', '-n')}-{variant}{tag}-s{seed}", exp, store, variant,
                   tuple(evals or (store,)), steps_factor, scale)


def exp_kuka(c: RealConfig) -> list[RealRun]:
    return [_run("kuka", "kuka", v, seed=c.seed) for v in c.variants]


def exp_viewpoint(c: RealConfig) -> list[RealRun]:
    return [_run("viewpoint", st, v, seed=c.seed) for st in ("kuka", "kuka_close", "kuka_two_view") for v in c.variants]


def exp_scaling(c: RealConfig) -> list[RealRun]:
    runs = []
    for arm in c.arms:
        for s in c.scales:
            store = "flexiv" if s == 1.0 else f"flexiv@{s:g}"
            runs.append(_run("scaling", store, arm, evals=("flexiv",), scale=s, seed=c.seed))
        if c.compute_control:
            runs.append(_run("scaling", "flexiv", arm, steps_factor=c.compute_control, seed=c.seed))
    return runs


def exp_joint(c: RealConfig) -> list[RealRun]:
    v = c.joint_variant
    return [_run("joint", "joint", v, evals=("kuka", "flexiv"), seed=c.seed),
            _run("joint", "kuka", v, seed=c.seed), _run("joint", "flexiv", v, seed=c.seed)]


EXPERIMENTS: dict[str, Callable[[RealConfig], list[RealRun]]] = {
    "kuka": exp_kuka, "viewpoint": exp_viewpoint, "scaling": exp_scaling, "joint": exp_joint}
NEEDS = {"kuka": ("kuka",), "viewpoint": ("kuka", "kuka_close", "kuka_two_view"), "scaling": ("flexiv",),
         "joint": ("kuka", "flexiv")}
"""Stores each experiment needs."""


def experiments(c: RealConfig) -> tuple[str, ...]:
    """The experiments to run: ``c.experiments``, or every one whose stores are all given."""
    given = {k for k in STORES if getattr(c, k)}
    if not c.experiments:
        chosen = tuple(e for e in EXPERIMENTS if set(NEEDS[e]) <= given)
        if not chosen:
            raise ConfigError("no store given: pass at least --kuka (cfg7 far) or --flexiv (cfg1 far), "
                              "converted with `pokeworld rh20t-convert`")
        return chosen
    for e in c.experiments:
        missing = [k for k in NEEDS[e] if k not in given]
        if missing:
            raise ConfigError(f"experiment {e} needs the stores {['--' + m.replace('_', '-') for m in missing]}")
    return tuple(c.experiments)


def all_runs(c: RealConfig) -> list[RealRun]:
    seen: dict[str, RealRun] = {}
    for exp in experiments(c):
        for r in EXPERIMENTS[exp](c):
            if r.name in seen:  # a run shared by two experiments trains once, evaluated on the union
                old = seen[r.name]
                seen[r.name] = dataclasses.replace(old, evals=tuple(dict.fromkeys(old.evals + r.evals)))
            else:
                seen[r.name] = r
    return list(seen.values())


def run_experiments(c: RealConfig) -> dict[str, list[str]]:
    return {exp: [r.name for r in EXPERIMENTS[exp](c)] for exp in experiments(c)}


# --------------------------------------------------------------------------- stores
def subset_train_scenes(ds: Dataset, scale: float, seed: int) -> tuple[Dataset, dict]:
    """``ds`` with its training split reduced to a seeded, task-stratified, nested share of its training scenes
    (the converter's ``--max-scenes`` sampling, :func:`pokeworld.real.rh20t.stratified_indices`).

    ``scale`` > 1 is a number of corpus scenes (all splits), mapped to the same share of training
    scenes; ``scale`` <= 1 is that share directly. Probe-fit, probe-test and held-out episodes stay.
    """
    scene = ds.params["scene_index"].astype(int) if "scene_index" in ds.params else np.arange(ds.num_episodes)
    task = ds.params["task_id"].astype(int) if "task_id" in ds.params else np.zeros(ds.num_episodes, int)
    total = np.unique(scene).size
    train_scenes, first = np.unique(scene[ds.split == 0], return_index=True)
    if scale > 1 and scale > total:
        raise ConfigError(f"scale {scale:g} scenes exceeds the corpus's {total} scenes")
    frac = scale / total if scale > 1 else scale
    keep_n = max(1, int(round(frac * train_scenes.size)))
    chosen = stratified_indices(task[ds.split == 0][first], [int(x) for x in train_scenes], keep_n, seed)
    keep = train_scenes[chosen]
    idx = np.flatnonzero((ds.split != 0) | np.isin(scene, keep))
    sub = ds.subset(idx)
    info = {"scale": scale, "corpus_scenes": int(total), "train_scenes": int(keep_n),
            "train_scenes_full": int(train_scenes.size), "train_episodes": int((sub.split == 0).sum())}
    return sub, info


def _store_dir(c: RealConfig, key: str) -> Path:
    if key in STORES:
        return Path(getattr(c, key))
    return Path(c.out) / "data" / key.replace("@", "-n")


def _content_sha(store: str) -> str:
    return read_manifest(store)["content_sha256"]


def ensure_stores(c: RealConfig, runs: list[RealRun]) -> dict[str, str]:
    """Paths of every store the runs use, building the scene subsets and the concatenation once."""
    paths: dict[str, str] = {}
    for key in dict.fromkeys(k for r in runs for k in (r.store, *r.evals)):
        path = _store_dir(c, key)
        if key in STORES:
            if not is_complete(path):
                raise DataError(f"--{key.replace('_', '-')} {path} is not a converted store (no data.h5/manifest.json)")
        else:
            # a derived store is reused only if it was built from these inputs (else ConfigError: its runs
            # were trained on other data, so a fresh --out is needed)
            if key == "joint":
                derived = {"kind": "joint", "sources": [_content_sha(c.kuka), _content_sha(c.flexiv)]}
            else:
                scale = next(r.scale for r in runs if r.store == key)
                derived = {"kind": "subset", "source": _content_sha(c.flexiv), "scale": scale, "seed": c.seed}
            if not store_is_current(path, derived):
                if key == "joint":
                    ds, extra = concatenate([load(c.kuka), load(c.flexiv)], names=["kuka", "flexiv"]), {}
                else:
                    src = load(c.flexiv)
                    ds, info = subset_train_scenes(src, scale, c.seed)
                    extra = {"subset_of": str(c.flexiv), "subset": info, "source_config": src.manifest.get("config")}
                save(ds, path, {"config": derived, **extra})
                print(f"[real] wrote {path}")
        paths[key] = str(path)
    return paths


# --------------------------------------------------------------------------- jobs
def execute(job: dict) -> dict:
    """Train (resume / skip) one run and evaluate it on each store. Top-level and picklable."""
    import torch

    if job.get("threads"):
        torch.set_num_threads(job["threads"])
    run_dir = train.run(train.make_config(job["preset"], **job["train"]))
    paths = {}
    for key, data in job["evals"].items():
        ecfg = evaluate.make_config(job["preset"], run_dir=str(run_dir), data=data, mlp=job["mlp"],
                                    untrained=job["untrained"])
        paths[key] = str(evaluate.run(ecfg))
    return {"name": job["name"], "evals": paths}


def jobs(c: RealConfig, runs: list[RealRun], stores: dict[str, str], threads: int) -> list[dict]:
    base_steps = c.train_steps or train.make_config(c.preset).steps
    out = []
    for r in runs:
        tr: dict[str, Any] = dict(variant=r.variant, data=stores[r.store], out=str(Path(c.out) / "runs" / r.name),
                                  seed=c.seed, steps=int(math.ceil(base_steps * r.steps_factor)), progress=False)
        if c.image_size:
            tr["image_size"] = c.image_size
        if threads:
            tr["threads"] = threads
        out.append({"name": r.name, "preset": c.preset, "train": tr, "mlp": c.mlp_probes, "untrained": c.untrained,
                    "threads": threads, "evals": {k: stores[k] for k in r.evals}})
    return out


def run(c: RealConfig) -> Path:
    """Build derived stores, train and evaluate every run, write results.json, results.md (and scissors.png after scaling)."""
    out = Path(c.out)
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "real_config.json", to_dict(c))
    runs = all_runs(c)
    stores = ensure_stores(c, runs)
    workers = c.workers or default_workers(len(runs))
    threads = max(1, cores() // workers) if (c.launcher == "local" and workers > 1) else 0
    print(f"[real] {len(runs)} runs ({', '.join(experiments(c))}), launcher={c.launcher}, workers={workers}")
    launch(dataclasses.replace(c, workers=workers), jobs(c, runs, stores, threads), fn=execute, name="pokeworld-real")
    results = collect(c, runs, stores)
    write_json(out / "results.json", results)
    written = report.write_all(out, results)
    print(f"[real] wrote {', '.join(str(p) for p in [out / 'results.json', *written])}")
    return out


def collect(c: RealConfig, runs: list[RealRun], stores: dict[str, str]) -> dict:
    """Every run's evaluation results, keyed by run name and evaluation store."""
    res: dict[str, Any] = {"config": to_dict(c), "experiments": run_experiments(c), "stores": stores, "runs": {}}
    for r in runs:
        run_dir = Path(c.out) / "runs" / r.name
        evals = {}
        for key in r.evals:
            path = evaluate.result_path(run_dir, stores[key])
            d = read_json_if_present(path, "a real-data evaluation record")
            if d is not None:
                evals[key] = {k: d[k] for k in ("trained", "untrained") if k in d}
        res["runs"][r.name] = {"experiment": r.experiment, "store": r.store, "variant": r.variant,
                               "scale": r.scale, "steps_factor": r.steps_factor, "evals": evals}
    for key, path in stores.items():
        man = read_manifest(path)
        res.setdefault("store_info", {})[key] = {
            "episodes": man.get("num_episodes"), "split_counts": man.get("split_counts"),
            "scenes": len(man.get("scenes", [])) or None, "onset_base_rate": man.get("onset_base_rate"),
            "subset": man.get("subset"), "synthetic": bool((man.get("source") or {}).get("synthetic"))}
    return res
