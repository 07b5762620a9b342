"""The fields of a run's training config that its readers use, checked before they use them.

``probe``, ``plan``, ``forecast-dependence``, ``export`` and the protocol read a run's ``config.json`` (or, for an
exported model folder, its ``train_config``) for the run's variant, seed, steps, training store and model sizes: a
label, a key of a table, a path, a number in a command line. The file may come from someone else, so each of those
fields is held to the type and range ``pokeworld train`` writes (the annotations and limits of
``pokeworld.train.TrainConfig``, restated here because the run folder's readers never import the trainer) and a
wrong one is one line naming the file and the field, before any work, never a TypeError after it. Fields a run
written by an earlier version lacks are left out of the check (their readers have defaults); fields no reader
uses are not checked, nor is ``data``, which :func:`pokeworld.rundir.finished_run_config` and
:func:`pokeworld.run_store.trained_store` refuse themselves with the line that says where the store went.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Optional

from .config import SEED, Limit, field_problem, shown
from .errors import DataError
from .models.xjepa import VARIANTS

SIZE = Limit(1, 65536)
#: Field -> (annotated type, range) of what the readers take from a run's training config.
READ_FIELDS: dict[str, tuple[Any, Limit | None]] = {
    "variant": (str, None), "seed": (int, SEED), "steps": (int, Limit(1, 10**9)),
    "data_path": (Optional[str], None), "data_sha256": (Optional[str], None),
    "out": (Optional[str], None), "image_size": (int, Limit(16, 4096)), "channels": (tuple[int, ...], SIZE),
    "latent_dim": (int, SIZE), "width": (int, SIZE), "depth": (int, Limit(1, 64)), "heads": (int, Limit(1, 1024)),
    "vec_dim": (int, SIZE), "window": (int, Limit(2, 4096)), "horizons": (tuple[int, ...], Limit(1, 4095)),
}


def check_run_fields(cfg: dict[str, Any], path: str | Path, prefix: str = "") -> None:
    """DataError, one line naming ``path`` and the field (``prefix`` + its name, as the file spells it), unless every
    field of :data:`READ_FIELDS` present in ``cfg`` has its type and range and ``variant`` is a known one."""
    for name, (tp, limit) in READ_FIELDS.items():
        if name not in cfg:
            continue
        value = cfg[name]
        problem = field_problem(value, tp, limit)
        if problem is None and name == "variant" and value not in VARIANTS:
            problem = f"must be one of {list(VARIANTS)}"
        if problem:
            raise DataError(f"{path}: its {prefix}{name} {problem}, got {shown(value)}; the run's config is damaged "
                            "or was edited: restore it, or train (or export) the run again")


__all__ = ["READ_FIELDS", "check_run_fields"]
