"""Seeded scene subsets (task-stratified, nested) and the train / probe / held-out-task split."""

from __future__ import annotations

from typing import Any

import numpy as np

from .config import ConvertConfig
from .folders import SceneRef


def stratified_indices(tasks, keys, n: int, seed: int) -> list[int]:
    """Indices of a seeded random subset of ``n`` items stratified by task (systematic sampling; nested in ``n``).

    Every task's items (in ``keys`` order) are put in a seeded random order and item ``k`` of a task with ``n_t``
    items gets the key ``(k + u_t) / n_t`` (``u_t`` a seeded uniform offset per task); the ``n`` smallest keys are
    kept. So each task contributes ``n * n_t / N`` items up to rounding (at most one off), the draw is random
    within each task, and a smaller ``n`` (same seed) is a subset of a larger one, which keeps scaling curves
    nested. Returns the chosen indices in ``keys`` order; all of them when ``n <= 0`` or ``n >= len(keys)``.
    """
    order_all = sorted(range(len(keys)), key=lambda i: keys[i])
    if n <= 0 or n >= len(keys):
        return order_all
    by_task: dict[int, list[int]] = {}
    for i in order_all:
        by_task.setdefault(int(tasks[i]), []).append(i)
    ranked: list[tuple[float, Any, int]] = []
    for task, group in sorted(by_task.items()):
        rng = np.random.default_rng([seed, 0x5EED, task])  # per task: a task's draw ignores the other tasks
        u_order = rng.permutation(len(group))
        u = rng.random()
        for k, j in enumerate(u_order):
            ranked.append(((k + u) / len(group), keys[group[j]], group[j]))
    ranked.sort(key=lambda x: x[:2])
    return sorted((x[2] for x in ranked[:n]), key=lambda i: keys[i])


def stratified_subset(refs: list[SceneRef], n: int, seed: int) -> list[SceneRef]:
    """A seeded, task-stratified, nested random subset of ``n`` scenes (:func:`stratified_indices`), sorted by name."""
    keys = [(r.name, str(r.path)) for r in refs]
    return [refs[i] for i in stratified_indices([r.task for r in refs], keys, n, seed)]


def split_scenes(tasks: np.ndarray, cfg: ConvertConfig) -> tuple[np.ndarray, list[int]]:
    """Per-scene split codes (0 train, 1 probe-fit, 2 probe-test, 3 held-out task) and the held-out task ids.

    Held-out tasks: ``cfg.heldout_tasks`` or ``num_heldout_tasks`` drawn from the sorted task ids by a
    seeded permutation (at least one task always stays in-distribution). The remaining scenes are
    permuted and split by ``split_fractions`` (rounded; each split gets >= 1 scene when there are >= 3).
    """
    rng = np.random.default_rng(cfg.seed)
    uniq = np.unique(tasks)
    if cfg.heldout_tasks:
        held = sorted(int(t) for t in cfg.heldout_tasks if t in set(uniq.tolist()))
    else:
        n = min(cfg.num_heldout_tasks, max(len(uniq) - 1, 0))
        held = sorted(int(t) for t in rng.permutation(uniq)[:n])
    split = np.full(len(tasks), 3, np.int8)
    rest = np.flatnonzero(~np.isin(tasks, held))
    rest = rest[rng.permutation(len(rest))]
    n = len(rest)
    f = cfg.split_fractions
    n_fit, n_test = int(round(f[1] * n)), int(round(f[2] * n))
    if n >= 3:
        n_fit, n_test = max(n_fit, 1 if f[1] > 0 else 0), max(n_test, 1 if f[2] > 0 else 0)
    while n - n_fit - n_test < 1 and (n_fit or n_test):
        if n_fit >= n_test:
            n_fit -= 1
        else:
            n_test -= 1
    split[rest[:n - n_fit - n_test]] = 0
    split[rest[n - n_fit - n_test: n - n_test]] = 1
    split[rest[n - n_test:]] = 2
    return split, held
