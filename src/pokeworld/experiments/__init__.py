"""The identifiability map and its experiments (``pokeworld map``, ``pokeworld demo``).

* :mod:`.map` — the driver: generate -> certify -> train -> measure -> report, locked, resumable, time-sliceable;
* :mod:`.config` — :class:`MapConfig`; :mod:`.presets` — its presets and the demo's;
* :mod:`.stages` — corpora, certificates, the per-run jobs, progress and the results pack;
* :mod:`.launch` — local process pool or submitit;
* :mod:`.runs` — run specs, run names and paths in a map folder;
* :mod:`.report` — results.json, results.md and the figure; :mod:`.merge` — fold a later map's runs into a
  record (``scripts/merge_map_results.py``);
* :mod:`.registry` — every experiment, one module each (its run specs, its report section, its paper values):
  :mod:`.factorial`, :mod:`.lazy`, :mod:`.lambda_sweep`, :mod:`.lambda_factorial`, :mod:`.coverage`,
  :mod:`.frame_averaged`, :mod:`.controls`, :mod:`.dose_touch`, :mod:`.dose_glide`, :mod:`.attributes`,
  :mod:`.belief`, :mod:`.planning`, :mod:`.coordinate`, :mod:`.ledger`, :mod:`.tokens`.

Adding an experiment: a module with ``NAME``, ``specs(c)`` and ``section(results)``, listed in the registry.

The map's runs carried to a GPU and back (the paper-budget map in short device leases) are :mod:`pokeworld.remote`,
which imports this package; nothing here imports it.
"""

from .config import MapConfig
from .launch import LaunchOptions, launch
from .map import carry_over, run
from .presets import DEMO, PRESETS, make_config, make_demo_config
from .registry import EXPERIMENTS
from .stages import all_specs, experiment_specs, spec_experiments

__all__ = ["MapConfig", "PRESETS", "DEMO", "make_config", "make_demo_config", "run", "carry_over", "EXPERIMENTS",
           "all_specs", "experiment_specs", "spec_experiments", "LaunchOptions", "launch"]
