"""An swm collection on several cores: worker processes each collect a share of the episodes into a part file, and
the parts are merged, in worker order, into one HDF5 dataset through swm's own writer.

stable-worldmodel's ``World`` steps its environments one after another in one process (``EnvPool``), so
``--num-envs`` batches the policy but not the simulation. Measured on a 2-core machine (120 Pendulum episodes of 48
steps at 32 px): 112.8 s in one process, 85.5 s with two workers (1.3×; the software renderer, OSMesa's llvmpipe,
may already spread one process's rendering over both cores — not measured). ``concurrent.futures``' process pool (an existing
engine, ``spawn`` so no worker inherits torch's threads) runs ``collect`` once per worker: worker ``w`` collects
episodes ``w::workers``'s share with its resets seeded from ``seed + w * SEED_STRIDE`` (swm seeds an episode's reset
with the base seed plus its index, so the workers' reset seeds never overlap), and its behaviour policy seeded the
same way. The merged corpus is therefore a different (equally valid) sample from a one-process collection with the
same seed, which is why the worker count is part of the corpus cache key.

Part files are our own (``part-<w>.h5``), in a private folder beside the corpus that
:func:`pokeworld.io.temporary_folder` creates (exclusively, mode 0700, a random name: nobody can predict it or plant a link in it, where swm's writer
would follow one), read back with h5py (no pickle, only the writer's top-level datasets, episode index checked) and
removed with the folder after the merge or a failure; a killed run leaves the folder under a name the next run's
stale-temporary cleanup recognises.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import DataError
from ..io import remove_temporary, temporary_folder

SEED_STRIDE = 1_000_003
"""Seed offset between workers (larger than any episode count, so reset seeds never overlap)."""


def shares(episodes: int, workers: int) -> list[int]:
    """Episodes per worker: as even as possible, no empty worker."""
    workers = max(1, min(workers, episodes))
    return [episodes // workers + (1 if w < episodes % workers else 0) for w in range(workers)]


def part_path(folder: Path, w: int, suffix: str = ".h5") -> Path:
    """Worker ``w``'s part file in the private ``folder`` (:func:`pokeworld.io.temporary_folder`)."""
    return folder / f"part-{w}{suffix}"


def read_episodes(part: Path) -> list[dict[str, np.ndarray]]:
    """The episodes of one part file (swm's HDF5 layout: one dataset per column, ``ep_len`` / ``ep_offset``)."""
    import h5py

    with h5py.File(part, "r") as f:
        lengths, offsets = np.asarray(f["ep_len"][:], np.int64), np.asarray(f["ep_offset"][:], np.int64)
        cols = [k for k in f if k not in ("ep_len", "ep_offset") and isinstance(f[k], h5py.Dataset)]
        total = min(int(f[c].shape[0]) for c in cols) if cols else 0
        if lengths.shape != offsets.shape or (lengths < 1).any() or (offsets < 0).any() or \
                (offsets + lengths > total).any():
            raise DataError(f"{part}: its episode index does not match its columns; collect again")
        return [{c: np.asarray(f[c][o:o + n]) for c in cols} for o, n in zip(offsets.tolist(), lengths.tolist())]


def merge(parts: list[Path], path: Path) -> int:
    """Write every part's episodes, in order, to ``path`` through swm's HDF5 writer; the episode count."""
    from .require import stable_worldmodel

    n = 0
    with stable_worldmodel().data.get_format("hdf5").open_writer(path, mode="overwrite") as writer:
        for part in parts:
            for ep in read_episodes(part):
                writer.write_episode(ep)
                n += 1
    return n


def collect_in_parallel(cfg: Any, path: Path, workers: int, collect: Callable[[Any, Path], Path]) -> Path:
    """Collect ``cfg.episodes`` episodes with ``collect(cfg_share, part)`` in ``workers`` processes and merge the
    parts into ``path`` (``collect`` must be importable by name: it runs in the workers; ``cfg`` a dataclass with
    ``episodes`` and ``seed``, which each worker's share replaces)."""
    counts = shares(cfg.episodes, workers)
    private = temporary_folder(path)
    parts = [part_path(private, w, path.suffix) for w in range(len(counts))]
    cfgs = [dataclasses.replace(cfg, episodes=k, seed=cfg.seed + w * SEED_STRIDE) for w, k in enumerate(counts)]
    try:
        with ProcessPoolExecutor(len(counts), mp_context=get_context("spawn")) as pool:
            try:
                for done in pool.map(collect, cfgs, parts):
                    print(f"[swm-certify] worker part {done.name} collected", flush=True)
            except BrokenProcessPool as e:  # a worker killed (memory) or unable to start (a script read from stdin)
                raise DataError(f"a collection worker died ({e}); collect with --workers 1, or run from a file or "
                                "the pokeworld command") from None
        n = merge(parts, path)
        if n != cfg.episodes:
            raise DataError(f"the workers collected {n} episodes, not {cfg.episodes}; collect again")
    finally:
        remove_temporary(private)  # the parts and anything a killed worker left in the private folder
    return path


__all__ = ["SEED_STRIDE", "collect_in_parallel", "merge", "part_path", "read_episodes", "shares"]
