"""Fixed-length episode windows and their contact / pure-glide classification.

A window of length L starting at step s covers observations s..s+L-1 and the
actions taken after each of them (actions s..s+L-1; the last one leads out of
the window). Definitions (docs/design.md, "Windows"):

* contact window: the finger touches the object at some observation in the window
  (``labels/contact`` > 0, the noise-free flag of the step ending there);
* pure-glide window: no finger contact at any observation, the object is
  moving (speed > ``min_speed``) at every observation, and it touches no wall.

Windows are always built from an explicit episode set, so fit / test
disjointness is inherited from the episode split.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .data import Dataset
from .errors import DataError


@dataclass
class Windows:
    """Window index: episode id and start step per window, plus kind masks."""

    episode: np.ndarray
    start: np.ndarray
    length: int
    contact: np.ndarray
    glide: np.ndarray

    def __len__(self) -> int:
        return int(self.episode.size)

    def select(self, mask: np.ndarray) -> "Windows":
        return Windows(self.episode[mask], self.start[mask], self.length, self.contact[mask], self.glide[mask])

    def subsample(self, cap: int, rng: np.random.Generator) -> "Windows":
        """At most ``cap`` windows drawn without replacement (order kept); bounds CPU time of fits."""
        if len(self) <= cap:
            return self
        return self.select(np.sort(rng.choice(len(self), cap, replace=False)))

    def kind(self, kind: str) -> "Windows":
        """Subset of ``kind`` 'contact', 'glide' or 'all'."""
        if kind == "all":
            return self
        if kind not in ("contact", "glide"):
            raise DataError(f"unknown window kind {kind!r}; use 'contact', 'glide' or 'all'")
        return self.select(getattr(self, kind))

    def gather(self, array: np.ndarray, offset: int = 0, length: int | None = None) -> np.ndarray:
        """``array[e, s+offset : s+offset+length]`` for every window, stacked: (W, length, ...)."""
        length = self.length if length is None else length
        t = self.start[:, None] + offset + np.arange(length)[None, :]
        if t.max(initial=0) >= array.shape[1] or t.min(initial=0) < 0:
            raise DataError(f"window steps {t.min()}..{t.max()} exceed the episode length {array.shape[1]}")
        return array[self.episode[:, None], t]

    def last(self, array: np.ndarray) -> np.ndarray:
        """Value at the window's last observation: (W, ...)."""
        return array[self.episode, self.start + self.length - 1]


def wall_contact(ds: Dataset, margin: float = 0.005) -> np.ndarray:
    """(E, T+1) bool: object within ``margin`` of a wall contact (simulator corpora only)."""
    cfg = ds.manifest.get("config", {}).get("physics", {})
    r = cfg.get("object_radius", 0.09)
    arena = cfg.get("arena", 1.0)
    p = ds.labels["object_pos"]
    return ((p < r + margin) | (p > arena - r - margin)).any(-1)


def glide_frames(ds: Dataset, min_speed: float = 0.02, contact_channel: int = 6) -> np.ndarray:
    """(E, T+1) bool: observations at which the object glides freely.

    Simulator stores: no finger contact (``labels/contact``), object speed > ``min_speed`` and no
    wall contact — the frame-level version of the pure-glide window. Stores without object labels
    (real data) fall back to "no contact" from the touch stream's contact flag.
    """
    if {"contact", "object_vel", "object_pos"} <= set(ds.labels):
        speed = np.linalg.norm(ds.labels["object_vel"], axis=-1)
        return (ds.labels["contact"] <= 0) & (speed > min_speed) & ~wall_contact(ds)
    if not 0 <= contact_channel < ds.touch.shape[-1]:
        raise DataError(f"no object labels and no touch contact channel {contact_channel} to find glide frames")
    return ds.touch[..., contact_channel] <= 0.5


def make_windows(ds: Dataset, episodes: np.ndarray, length: int = 16, stride: int = 4,
                 min_speed: float = 0.02) -> Windows:
    """All windows of ``length`` at ``stride`` in ``episodes``, classified as contact / glide."""
    episodes = np.asarray(episodes)
    if episodes.size == 0:
        raise DataError("no episodes to cut windows from (is the split empty?)")
    T1 = ds.frames.shape[1]
    if length < 2 or length > T1:
        raise DataError(f"window length {length} must be in [2, {T1}]")
    starts = np.arange(0, T1 - length + 1, stride)
    ep = np.repeat(episodes, starts.size)
    st = np.tile(starts, episodes.size)
    w = Windows(ep, st, length, np.zeros(ep.size, bool), np.zeros(ep.size, bool))
    if "contact" in ds.labels:
        contact = w.gather(ds.labels["contact"]) > 0
        w.contact = contact.any(1)
        if "object_vel" in ds.labels:
            speed = np.linalg.norm(w.gather(ds.labels["object_vel"]), axis=-1)
            walls = w.gather(wall_contact(ds))
            w.glide = (~contact.any(1)) & (speed > min_speed).all(1) & (~walls.any(1))
    return w
