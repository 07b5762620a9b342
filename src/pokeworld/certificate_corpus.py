"""The certificates' own fit corpus: more episodes from the store's generator, on disjoint seeds.

A certificate states what the *data* allow an estimator to recover, so it must not be limited by how many
episodes a store happens to set aside for probe fitting: at the `cpu` budget the 480 probe-fit episodes leave the
GRU oracle at γ R² 0.29 where 1,920 episodes give 0.73 (docs/results/certificate_fit_curve_cpu.md). The
certificate corpus is generated from the store's own recorded generator config, with a seed derived from the
store's so that its episodes are independent of every store episode, and every episode in it is a fit episode;
certificates are still scored on the store's probe-test episodes, the windows model probes are scored on.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .config import apply_overrides
from .data import Dataset, load
from .errors import ConfigError
from .sim import generate

FOLDER = "certificate_corpus"
"""Where, inside the store's folder, the certificate corpora live: one store per size, ``n<episodes>``."""


def fit_seed(store_seed: int) -> int:
    """A seed whose random streams are independent of the store's (numpy SeedSequence with a fixed tag)."""
    return int(np.random.SeedSequence([int(store_seed), 0xCE27]).generate_state(1, np.uint32)[0])


def path(data: str | Path, episodes: int) -> Path:
    return Path(data) / FOLDER / f"n{int(episodes)}"


def ensure(store: Dataset, data: str | Path, episodes: int) -> Dataset:
    """The certificate corpus of the store at ``data``: ``episodes`` episodes, all in the probe-fit split,
    generated (or found up to date) in ``data/certificate_corpus/n<episodes>``. One folder per size keeps every
    size reproducible on its own (a generator's last batch depends on the total count, so the first n episodes
    of a larger corpus are not an n-episode corpus); fit-size curves fit prefixes of one large corpus instead."""
    if store.manifest.get("generator") != "pokeworld.sim.generate":
        raise ConfigError(f"fit_episodes > 0 needs a store written by `pokeworld generate` (its generator config "
                          f"makes the certificate corpus); {data} was written by "
                          f"{store.manifest.get('generator', 'an unknown generator')}: use fit_episodes=0")
    cfg = generate.generator_config(store.manifest, f"{data}/manifest.json")  # checked: data, not configuration
    cfg = apply_overrides(cfg, {"out": str(path(data, episodes)), "seed": fit_seed(cfg.seed),
                                         "num_episodes": int(episodes), "split_fractions": (0.0, 1.0, 0.0)})
    print(f"[certify] certificate corpus: {episodes} episodes from the store's generator (seed {cfg.seed})")
    return load(generate.run(cfg))


__all__ = ["FOLDER", "fit_seed", "path", "ensure"]
