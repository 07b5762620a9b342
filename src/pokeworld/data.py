"""The on-disk dataset format shared by simulator corpora and converted RH20T data.

A dataset is a directory holding ``data.h5`` (chunked HDF5) and
``manifest.json``. Arrays, with E episodes of T control steps:

=================  =====================  ===========================================
name               shape / dtype          meaning
=================  =====================  ===========================================
frames             (E, T+1, H, W) uint8   grayscale observation before each step
proprio            (E, T+1, Dp) float32   proprioception at each observation
touch              (E, T+1, Dt) float32   touch / force summarising the step that ended
                                          at this observation (zeros at t = 0)
actions            (E, T, Da) float32     action applied between obs t and t+1
labels/<name>      (E, T+1, ...) float32  privileged per-step labels (object state...)
params/<name>      (E,) float32           per-episode hidden parameters / metadata
split              (E,) int8              0 train, 1 probe-fit, 2 probe-test, 3 held-out
=================  =====================  ===========================================

The manifest records the generator config, seed, format version and a content
hash over all arrays; :func:`load` re-hashes and refuses a store whose bytes do
not match, so a truncated or edited file is never silently used.
"""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from .errors import ConfigError, DataError
from .io import atomic_path, hash_arrays, write_json

FORMAT_VERSION = 1
SPLITS = {"train": 0, "probe_fit": 1, "probe_test": 2, "heldout": 3}
STREAMS = ("frames", "proprio", "touch", "actions")


@dataclasses.dataclass
class Dataset:
    """In-memory dataset; see module docstring for the array layout."""

    frames: np.ndarray
    proprio: np.ndarray
    touch: np.ndarray
    actions: np.ndarray
    labels: dict[str, np.ndarray]
    params: dict[str, np.ndarray]
    split: np.ndarray
    manifest: dict[str, Any] = dataclasses.field(default_factory=dict)

    def __post_init__(self) -> None:
        validate(self)

    @property
    def num_episodes(self) -> int:
        return int(self.frames.shape[0])

    @property
    def num_steps(self) -> int:
        """Control steps per episode (observations are one more)."""
        return int(self.actions.shape[1])

    def episodes(self, split: str) -> np.ndarray:
        """Indices of the episodes in ``split`` (a key of :data:`SPLITS`)."""
        if split not in SPLITS:
            raise DataError(f"unknown split {split!r}; known: {sorted(SPLITS)}")
        return np.flatnonzero(self.split == SPLITS[split])

    def subset(self, idx: np.ndarray) -> "Dataset":
        """Episodes ``idx`` as a new Dataset (arrays are copies)."""
        idx = np.asarray(idx)
        return Dataset(
            frames=self.frames[idx], proprio=self.proprio[idx], touch=self.touch[idx],
            actions=self.actions[idx],
            labels={k: v[idx] for k, v in self.labels.items()},
            params={k: v[idx] for k, v in self.params.items()},
            split=self.split[idx], manifest=dict(self.manifest),
        )

    def arrays(self) -> dict[str, np.ndarray]:
        out = {name: getattr(self, name) for name in STREAMS}
        out.update({f"labels/{k}": v for k, v in self.labels.items()})
        out.update({f"params/{k}": v for k, v in self.params.items()})
        out["split"] = self.split
        return out


def validate(ds: Dataset) -> None:
    """Raise :class:`DataError` on inconsistent shapes, wrong dtypes or non-finite values."""
    if ds.frames.ndim != 4 or ds.frames.dtype != np.uint8:
        raise DataError(f"frames must be (E, T+1, H, W) uint8, got {ds.frames.shape} {ds.frames.dtype}")
    E, T1 = ds.frames.shape[:2]
    if E == 0:
        raise DataError("dataset has no episodes")
    for name in ("proprio", "touch"):
        a = getattr(ds, name)
        if a.ndim != 3 or a.shape[:2] != (E, T1):
            raise DataError(f"{name} must be (E={E}, T+1={T1}, D), got {a.shape}")
    if ds.actions.ndim != 3 or ds.actions.shape[:2] != (E, T1 - 1):
        raise DataError(f"actions must be (E={E}, T={T1 - 1}, Da), got {ds.actions.shape}")
    for name, a in ds.labels.items():
        if a.shape[:2] != (E, T1):
            raise DataError(f"labels/{name} must start with (E={E}, T+1={T1}), got {a.shape}")
    for name, a in ds.params.items():
        if a.shape != (E,):
            raise DataError(f"params/{name} must be (E={E},), got {a.shape}")
    if ds.split.shape != (E,):
        raise DataError(f"split must be (E={E},), got {ds.split.shape}")
    for name, a in ds.arrays().items():
        if a.dtype.kind == "f" and not np.isfinite(a).all():
            bad = int((~np.isfinite(a)).sum())
            raise DataError(f"{name} contains {bad} non-finite values (NaN/inf); refusing to use it")


def save(ds: Dataset, out_dir: str | os.PathLike, manifest: dict[str, Any] | None = None) -> Path:
    """Write ``ds`` to ``out_dir`` atomically (temporary directory, then rename)."""
    out_dir = Path(out_dir)
    arrays = ds.arrays()
    man = dict(ds.manifest)
    man.update(manifest or {})
    man["format_version"] = FORMAT_VERSION
    man["content_sha256"] = hash_arrays(arrays)
    man["num_episodes"] = ds.num_episodes
    man["num_steps"] = ds.num_steps
    man["frame_shape"] = list(ds.frames.shape[2:])
    man["split_counts"] = {k: int((ds.split == v).sum()) for k, v in SPLITS.items()}
    with atomic_path(out_dir) as tmp:
        tmp.mkdir(parents=True)
        with h5py.File(tmp / "data.h5", "w", track_order=True) as f:
            for name, a in arrays.items():
                # one chunk per episode, deflate level 1; not LZF: h5py's LZF leaves its hash table
                # uninitialised, so the same array can compress to different bytes from run to run
                per_episode = {"chunks": (1,) + a.shape[1:], "compression": "gzip", "compression_opts": 1}
                f.create_dataset(name, data=a, track_times=False, **(per_episode if a.ndim >= 2 else {}))
        write_json(tmp / "manifest.json", man)
    ds.manifest = man
    return out_dir


def read_manifest(path: str | os.PathLike) -> dict[str, Any]:
    """A dataset directory's manifest (content hash, config, splits) without reading the arrays: what a
    cache check needs before deciding whether to load the store at all."""
    path = Path(path)
    h5, mf = path / "data.h5", path / "manifest.json"
    if not path.is_dir():
        raise DataError(f"dataset directory {path} does not exist (generate it with `pokeworld generate`)")
    if not h5.exists() or not mf.exists():
        raise DataError(f"{path} is not a pokeworld dataset: expected data.h5 and manifest.json")
    try:
        manifest = json.loads(mf.read_text())
    except json.JSONDecodeError as e:
        raise DataError(f"{mf} is not valid JSON ({e}); the dataset is corrupt") from None
    if manifest.get("format_version") != FORMAT_VERSION:
        raise DataError(f"{path}: format version {manifest.get('format_version')} != supported {FORMAT_VERSION}")
    return manifest


def load(path: str | os.PathLike, verify: bool = True) -> Dataset:
    """Load a dataset directory, checking presence, structure and (by default) the content hash."""
    path = Path(path)
    h5 = path / "data.h5"
    manifest = read_manifest(path)
    try:
        with h5py.File(h5, "r") as f:
            missing = [n for n in (*STREAMS, "split") if n not in f]
            if missing:
                raise DataError(f"{h5} lacks datasets {missing}; the store is incomplete")
            arrays = {n: f[n][()] for n in (*STREAMS, "split")}
            labels = {k: f["labels"][k][()] for k in f.get("labels", {})}
            params = {k: f["params"][k][()] for k in f.get("params", {})}
    except DataError:
        raise
    except (OSError, KeyError, ValueError) as e:
        raise DataError(f"cannot read {h5}: {e}. The file is truncated or corrupt; regenerate it") from None
    ds = Dataset(labels=labels, params=params, manifest=manifest, **arrays)
    if verify:
        digest = hash_arrays(ds.arrays())
        if digest != manifest.get("content_sha256"):
            raise DataError(f"{path}: content hash mismatch (manifest {manifest.get('content_sha256')!s:.12}, "
                            f"data {digest:.12}); the store was modified or is corrupt")
    return ds


def is_complete(path: str | os.PathLike) -> bool:
    """True when ``path`` holds a finished dataset (used to skip regeneration)."""
    path = Path(path)
    return (path / "data.h5").exists() and (path / "manifest.json").exists()


def store_is_current(path: str | os.PathLike, content_config: dict, overwrite: bool = False) -> bool:
    """True when ``path`` already holds a store built from ``content_config`` (so the caller skips work).

    False when there is no complete store or ``overwrite`` is set; raises ConfigError when a store
    built from a *different* config is there, so nothing is silently replaced.
    """
    if overwrite or not is_complete(path):
        return False
    if read_manifest(path).get("config") == content_config:
        return True
    raise ConfigError(f"{path} holds a store built with a different config; pass --overwrite or choose another --out")


def concatenate(datasets: list[Dataset], names: list[str] | None = None) -> Dataset:
    """One store from several with the same episode length, frame size and stream widths (e.g. two
    RH20T configurations for a configuration-blind model).

    Episodes keep their split. Labels and params present in every input (with equal trailing shapes)
    are kept, the rest dropped (``scene_index`` offset per input so scenes of different inputs stay distinct); ``params/source`` records the input index of every episode (for
    evaluation and bookkeeping only: the model never reads params). Streams are concatenated as stored,
    so each input keeps its own normalisation (converted RH20T stores are whitened with their own
    train statistics).
    """
    if len(datasets) < 2:
        raise DataError("concatenate needs at least two datasets")
    first = datasets[0]
    for i, ds in enumerate(datasets[1:], 1):
        for name in STREAMS:
            a, b = getattr(first, name), getattr(ds, name)
            if a.shape[1:] != b.shape[1:]:
                raise DataError(f"cannot concatenate: {name} of dataset {i} is {b.shape[1:]} per episode, "
                                f"dataset 0 has {a.shape[1:]} (same episode length, frame size and widths needed)")
    common = lambda attr: [k for k in getattr(first, attr)  # noqa: E731
                           if all(k in getattr(d, attr) and getattr(d, attr)[k].shape[1:] == getattr(first, attr)[k].shape[1:]
                                  for d in datasets)]
    cat = lambda arrs: np.concatenate(arrs, 0)  # noqa: E731
    params = {k: cat([d.params[k] for d in datasets]) for k in common("params") if k != "source"}
    params["source"] = cat([np.full(d.num_episodes, i, np.float32) for i, d in enumerate(datasets)])
    if "scene_index" in params:  # each input numbers its scenes from 0: offset them so scenes stay distinct
        offsets = np.cumsum([0] + [d.params["scene_index"].max() + 1 for d in datasets[:-1]])
        params["scene_index"] = cat([d.params["scene_index"] + o for d, o in zip(datasets, offsets)]).astype(
            params["scene_index"].dtype)
    manifest = {"kind": "concat", "sources": names or [str(i) for i in range(len(datasets))],
                "source_manifests": [{k: d.manifest.get(k) for k in ("kind", "robot", "content_sha256", "hz")}
                                     for d in datasets]}
    hz = {d.manifest.get("hz") for d in datasets}
    if len(hz) == 1:
        manifest["hz"] = hz.pop()
    return Dataset(frames=cat([d.frames for d in datasets]), proprio=cat([d.proprio for d in datasets]),
                   touch=cat([d.touch for d in datasets]), actions=cat([d.actions for d in datasets]),
                   labels={k: cat([d.labels[k] for d in datasets]) for k in common("labels")},
                   params=params, split=cat([d.split for d in datasets]), manifest=manifest)


def assign_splits(num_episodes: int, fractions: tuple[float, float, float], rng: np.random.Generator) -> np.ndarray:
    """Random disjoint train / probe-fit / probe-test assignment with the given fractions."""
    if len(fractions) != 3 or min(fractions) < 0 or abs(sum(fractions) - 1) > 1e-6:
        raise DataError(f"split fractions must be three non-negative numbers summing to 1, got {fractions}")
    counts = np.floor(np.asarray(fractions) * num_episodes).astype(int)
    counts[0] += num_episodes - counts.sum()
    split = np.repeat(np.arange(3, dtype=np.int8), counts)
    rng.shuffle(split)
    return split
