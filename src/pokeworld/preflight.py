"""Checks a command makes on the runs it is pointed at before its long computation, so that a path that is not a
run, a run that has not finished or a run whose store now holds other content is one clear line at the start
rather than a traceback after minutes of probing or planning with the others."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from .errors import ConfigError
from .run_store import trained_store
from .rundir import finished_run_config, has_final_weights, read_run_config


def finished_run(run_dir: str | os.PathLike) -> dict[str, Any]:
    """:func:`pokeworld.rundir.finished_run_config`, and ``final.pt`` there too: a run with ``DONE`` but no
    ``final.pt`` would otherwise be read from its last ``ckpt.pt``, an unfinished model, under the finished run's
    name. The refusal is the same line either way."""
    cfg = finished_run_config(run_dir)
    if not has_final_weights(run_dir):
        raise ConfigError(f"{run_dir} has not finished training; re-run `pokeworld train` to resume it")
    return cfg


def require_finished_runs(runs: Sequence[str], command: str, usage: str, data: str = "") -> None:
    """Refuse, before any run is read for work: a path that is not a training run (``usage`` says how the command
    is called: the usual cause is an output path given among the runs), a run that has not finished
    (:func:`finished_run`) and, unless ``data`` names another corpus, a run whose training store is not found with
    its recorded content (:func:`pokeworld.run_store.trained_store`)."""
    for r in runs:
        if not Path(r).is_dir() or read_run_config(r) is None:
            what = "does not exist" if not os.path.lexists(r) else "is not a training run (no config.json in it)"
            raise ConfigError(f"{r} {what}; {usage}")
    for r in runs:
        finished_run(r)
    if not data:
        for r in runs:
            trained_store(r, command)


__all__ = ["finished_run", "require_finished_runs"]
