"""Training X-JEPA models (paper App. B "Optimization").

* :mod:`.config` — :class:`TrainConfig`, its presets and validation;
* :mod:`.sampler` — the training split in memory and the random windows of a step;
* :mod:`.step` — one optimisation step and the pieces it is built from;
* :mod:`.loop` — the loop every run goes through (metrics rows, checkpoints, finite checks, deadline, progress);
* :mod:`.single` — one model into one run directory (``pokeworld train``, optionally DDP);
* :mod:`.stacked` — several runs in one process as a stacked ensemble (``pokeworld train-stacked``);
* :mod:`.synthetic` — a tiny synthetic corpus for tests and benchmarks.

The run directory's format is :mod:`pokeworld.rundir`'s. This package's names below are its public API
(``from pokeworld.train import make_config, run``).
"""

from ..rundir import finished_run_config, load_model
from .config import (
                     PRESETS,
                     RESUMABLE_FIELDS,
                     RETIRED_FIELDS,
                     TrainConfig,
                     auto_threads,
                     check_existing,
                     compile_mode_for,
                     field_defaults,
                     make_config,
                     resolve_device,
                     use_fast_path,
                     validate,
)
from .sampler import WindowSampler, data_stats
from .single import run
from .step import (
                     compiled,
                     decay_split,
                     loss_kwargs,
                     lr_lambda,
                     make_optimizer,
                     model_kwargs,
                     sigreg_directions,
                     sigreg_row_index,
                     sigreg_seed,
                     to_device,
                     train_step,
)
from .synthetic import synthetic_dataset

__all__ = ["TrainConfig", "PRESETS", "RESUMABLE_FIELDS", "RETIRED_FIELDS", "make_config", "validate", "field_defaults",
           "check_existing", "auto_threads", "resolve_device", "use_fast_path", "compile_mode_for", "run", "load_model",
           "finished_run_config", "WindowSampler", "data_stats", "synthetic_dataset", "model_kwargs", "lr_lambda",
           "make_optimizer", "decay_split", "loss_kwargs", "train_step", "sigreg_directions", "sigreg_row_index",
           "sigreg_seed", "to_device", "compiled"]
