"""A labelled stable-worldmodel dataset as a protocol store: observations, actions and per-episode physical factors.

stable-worldmodel environments vary physical factors (densities, friction, gravity, ...) when they are named in
``reset(options={"variation": [...]})``, and swm's info wrapper writes each one's value at every step as the
column ``variation.<key>``, so ``World.collect`` stores them beside the observations. :func:`read_factors` turns
such a dataset (HDF5, or Lance through swm's reader) into an in-memory :class:`pokeworld.data.Dataset`:

* ``frames``: the ``pixels`` column in luma grayscale (optionally area-resized to ``image_size``);
* ``proprio``: the raw non-pixel observation columns, flattened and concatenated (by default the first of
  ``proprio`` + ``touch`` / ``observation`` / ``state`` the dataset has; any numeric columns can be named);
* ``touch``: empty (width 0): a generic swm environment has no separate touch stream;
* ``actions``: the ``action`` column (a row holds the action taken after its observation; the last row of an
  episode is no transition of it, so an episode of L rows gives L observations and L - 1 actions);
* ``params``: the factors. A factor constant within every episode is a target; one that changes within an
  episode is no per-episode property and one with the same value in every episode was not varied: both are
  dropped and listed under ``manifest["dropped_factors"]`` with the reason. A vector factor (e.g. a colour)
  gives one target per component (``name[i]``). ``manifest["probe_params"]`` lists the targets, which is how
  the protocol's probes (:func:`pokeworld.evaluate.probes.probe_targets`) know to probe them.

The file is read by :func:`pokeworld.swm.dataset.read_swm`, with ``swm-import``'s refusals: no links or external
storage, no pickle (h5py and arrow run no code), bounded column sizes, a checked episode index; anything
malformed is a :class:`DataError`. Episodes get a random train / probe-fit / probe-test split.
"""

from __future__ import annotations

import os
from collections import Counter
from dataclasses import dataclass

import numpy as np

from ..data import Dataset, assign_splits
from ..errors import ConfigError, DataError
from .dataset import DEFAULT_MAX_GIB, INDEX, read_swm

VARIATION_PREFIX = "variation."
DEFAULT_OBSERVATIONS = (("proprio", "touch"), ("proprio",), ("observation",), ("state",))
"""Observation columns read when none are named: the first group the dataset holds entirely."""


@dataclass
class FactorDataConfig:
    """How an swm dataset maps to a protocol store."""

    factors: tuple[str, ...] = ()
    """Factors to certify: variation keys (``spinner.density``) or column names; empty: every ``variation.*``."""
    observations: tuple[str, ...] = ()
    """Non-pixel observation columns the certificates and the model read (empty: :data:`DEFAULT_OBSERVATIONS`)."""
    steps: int = 0
    """Control steps per episode (longer episodes are cut, shorter dropped); 0: the commonest episode length."""
    image_size: int = 0
    """Side the frames are area-resized to (0: as stored)."""
    split_fractions: tuple[float, float, float] = (0.5, 0.25, 0.25)
    """Train / probe-fit / probe-test fractions (the certificates and probes fit on probe-fit episodes)."""
    seed: int = 0
    """Seed of the split."""
    max_gib: float = DEFAULT_MAX_GIB
    """Budget for the bytes the read columns declare, checked before reading (as ``swm-import --max-gib``)."""

    def __post_init__(self) -> None:
        if not self.max_gib > 0:
            raise ConfigError(f"max_gib must be > 0, got {self.max_gib}")
        if self.steps < 0 or self.image_size < 0:
            raise ConfigError(f"steps and image_size must be >= 0, got {self.steps}, {self.image_size}")
        f = self.split_fractions
        if len(f) != 3 or min(f) <= 0 or abs(sum(f) - 1) > 1e-6:
            raise ConfigError(f"split_fractions must be three positive fractions summing to 1, got {f}")


def factor_column(name: str, columns) -> str:
    """The column of factor ``name``: ``variation.<name>`` when the dataset has it, else ``name`` itself."""
    for col in (VARIATION_PREFIX + name, name):
        if col in columns:
            return col
    found = sorted(c[len(VARIATION_PREFIX):] for c in columns if c.startswith(VARIATION_PREFIX))
    hint = found or "none (collect with reset options {'variation': [...]})"
    raise DataError(f"no factor {name!r} in the dataset (no column {VARIATION_PREFIX + name!r} or {name!r}); its "
                    f"variation columns: {hint}")


def observation_columns(cfg: FactorDataConfig, columns) -> tuple[str, ...]:
    if cfg.observations:
        missing = [c for c in cfg.observations if c not in columns]
        if missing:
            raise DataError(f"observation columns {missing} are not in the dataset (its columns: {sorted(columns)})")
        return tuple(cfg.observations)
    for group in DEFAULT_OBSERVATIONS:
        if all(c in columns for c in group):
            return group
    raise DataError(f"the dataset has none of the observation columns {[g[0] for g in DEFAULT_OBSERVATIONS]}; "
                    f"name them with --observations (its columns: {sorted(columns)})")


def luma_frames(pixels: np.ndarray, image_size: int) -> np.ndarray:
    """(N, H, W, 3) uint8 RGB -> (N, S, S) uint8 luma, area-resized to ``image_size`` when set."""
    if pixels.dtype != np.uint8 or pixels.ndim != 4 or pixels.shape[-1] != 3:
        raise DataError(f"pixels must be (rows, H, W, 3) uint8, got {pixels.shape} {pixels.dtype}")
    luma = pixels.astype(np.float32) @ np.array([0.299, 0.587, 0.114], np.float32)
    if image_size and image_size != luma.shape[-1]:
        import torch

        from ..models.xjepa import area_downsample

        if luma.shape[1] != luma.shape[2] or luma.shape[1] % image_size:
            raise ConfigError(f"image_size {image_size} must divide the stored square frames {luma.shape[1:]}")
        luma = area_downsample(torch.from_numpy(luma), image_size).numpy()
    return np.clip(np.rint(luma), 0, 255).astype(np.uint8)


def per_episode_factors(values: dict[str, np.ndarray]) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """Per-episode targets from factor columns gathered as (E, T1, ...); the rest with the reason dropped."""
    kept, dropped = {}, {}
    for name, v in values.items():
        v = v.reshape(*v.shape[:2], -1).astype(np.float64)
        for i in range(v.shape[-1]):
            comp = v[..., i]
            label = name if v.shape[-1] == 1 else f"{name}[{i}]"
            if not np.isfinite(comp).all():
                dropped[label] = "non-finite values"
            elif not (comp == comp[:, :1]).all():
                dropped[label] = "changes within episodes (not a per-episode property)"
            elif np.ptp(comp[:, 0]) == 0:
                dropped[label] = f"the same value ({comp[0, 0]:g}) in every episode (not varied)"
            else:
                kept[label] = comp[:, 0].astype(np.float32)
    return kept, dropped


def episode_rows(lengths: np.ndarray, offsets: np.ndarray, steps: int) -> tuple[np.ndarray, int]:
    """Row indices (E, T1) of the episodes with at least T1 = steps + 1 rows (the commonest length when 0)."""
    if steps:
        T1 = steps + 1
    else:
        counts = Counter(lengths.tolist())
        T1 = max(counts, key=lambda n: (counts[n], n))
    keep = np.flatnonzero(lengths >= T1)
    if T1 < 2 or keep.size == 0:
        raise DataError(f"no episode has {T1} observations; episode lengths {sorted(set(lengths.tolist()))}")
    return offsets[keep][:, None] + np.arange(T1)[None], T1


def read_factors(path: str | os.PathLike, cfg: FactorDataConfig) -> Dataset:
    """An swm dataset with ``variation.*`` columns as a protocol store (see the module docstring)."""
    chosen: dict = {}

    def select(names, meta) -> list[str]:
        # only these columns are read, and their declared sizes are checked against max_gib first
        names = list(names)
        factors = cfg.factors or tuple(c[len(VARIATION_PREFIX):] for c in names if c.startswith(VARIATION_PREFIX))
        if not factors:
            raise DataError(f"{path} has no variation.* columns: collect it with reset options {{'variation': [...]}} "
                            "or name factor columns with --factors")
        chosen["factors"] = {n: factor_column(n, names) for n in factors}
        chosen["observations"] = observation_columns(cfg, names)
        return [c for c in dict.fromkeys([*INDEX, "pixels", "action", *chosen["observations"],
                                          *chosen["factors"].values()]) if c in names]

    cols, lengths, offsets, _ = read_swm(path, cfg.max_gib, select=select)
    for need in ("pixels", "action", *chosen["observations"], *chosen["factors"].values()):
        if need not in cols:
            raise DataError(f"{path}: no numeric {need!r} column; the protocol needs pixels, actions, the observations "
                            "and the factors")
    factor_cols, obs = chosen["factors"], chosen["observations"]
    rows, T1 = episode_rows(lengths, offsets, cfg.steps)
    E = rows.shape[0]
    gather = lambda c: cols[c][rows.reshape(-1)].reshape(E, T1, *cols[c].shape[1:])  # noqa: E731
    params, dropped = per_episode_factors({n: gather(c) for n, c in factor_cols.items()})
    if not params:
        raise DataError(f"{path}: no factor varies across episodes while constant within them: {dropped}")
    frames = luma_frames(cols["pixels"][rows.reshape(-1)], cfg.image_size)
    proprio = np.concatenate([gather(c).reshape(E, T1, -1) for c in obs], -1).astype(np.float32)
    actions = gather("action").reshape(E, T1, -1)[:, :-1].astype(np.float32)
    split = assign_splits(E, tuple(cfg.split_fractions), np.random.default_rng(cfg.seed))
    manifest = {"kind": "swm-factors", "source": str(path), "observations": list(obs),
                "factors": {n: factor_cols[n.split("[")[0]] for n in params}, "dropped_factors": dropped,
                "probe_params": sorted(params), "frames_from_pixels": "luma", "swm_episodes": int(lengths.size),
                "dropped_short_episodes": int(lengths.size - E)}
    return Dataset(frames=frames.reshape(E, T1, *frames.shape[1:]), proprio=proprio,
                   touch=np.zeros((E, T1, 0), np.float32), actions=actions, labels={}, params=params, split=split,
                   manifest=manifest)


__all__ = ["DEFAULT_OBSERVATIONS", "VARIATION_PREFIX", "FactorDataConfig", "factor_column", "luma_frames",
           "observation_columns", "per_episode_factors", "read_factors"]
