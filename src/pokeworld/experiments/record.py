"""The shape of a map's ``results.json`` (:func:`pokeworld.experiments.report.collect`), checked when one is read
back from disk: by ``pokeworld map`` before it carries an earlier invocation's runs over, and by
``scripts/merge_map_results.py`` before it folds one record into another.

A record is read back from a file anyone may have edited or damaged. Checked when it is read, a wrong type, a
missing key or a NaN where a measured number belongs is one line naming the file; used as it is, it is a traceback
in the report at the very end of a map, after all its training.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from ..errors import ConfigError
from ..io import read_json

TOP_LEVEL = ("experiments", "runs", "certificates", "map_config", "provenance")
"""Keys every record holds, each a JSON object."""
RUN_KEYS = {"experiment": str, "corpus": str, "train": dict, "probes": dict, "prediction": dict}
"""Keys every run record holds, with their types (the report reads each)."""
MAX_RECORD_BYTES = 256 << 20
"""Largest results.json read back (the 38-run frontier record is about 0.3 MB)."""
MEASURED = ("probes", "prediction", "untrained", "probes_action_conditioned", "probes_belief", "trained")
"""A run record's measured sections (and its training summary): every leaf a finite number or a string (notes), never
null or NaN."""


def leaf_problem(value: Any, where: str, finite: bool = True) -> str | None:
    """The first leaf of a measured section that is not a number (finite, when ``finite``) or a string, or None."""
    if isinstance(value, dict):
        items = value.items()
    elif isinstance(value, list):
        items = enumerate(value)
    elif isinstance(value, str) or (isinstance(value, (int, float)) and (math.isfinite(value) or not finite)):
        return None
    else:
        return f"{where} is {value!r}, not a {'finite ' * finite}number"
    for k, v in items:
        problem = leaf_problem(v, f"{where}.{k}", finite)
        if problem:
            return problem
    return None


def run_problem(run: Any, finite: bool = True) -> str | None:
    """What makes one run record unlike those :func:`~pokeworld.experiments.report.collect` writes, or None;
    ``finite=False`` lets NaN and infinities stand in the measured sections (a merge judges those itself)."""
    if not isinstance(run, dict):
        return f"is a {type(run).__name__}, not an object"
    for key, kind in RUN_KEYS.items():
        if not isinstance(run.get(key), kind):
            return f"'{key}' is missing or not a {kind.__name__}"
    for section in MEASURED:
        if section in run:
            if not isinstance(run[section], dict):
                return f"'{section}' is not an object"
            problem = leaf_problem(run[section], section, finite)
            if problem:
                return problem
    return None


def record_problem(record: Any, finite: bool = True) -> str | None:
    """What makes ``record`` unlike a results.json pokeworld writes (the first problem found), or None
    (``finite`` as in :func:`run_problem`)."""
    if not isinstance(record, dict):
        return f"it is a JSON {type(record).__name__}, not an object"
    for key in TOP_LEVEL:
        if not isinstance(record.get(key), dict):
            return f"'{key}' is missing or not an object"
    if not isinstance(record["map_config"].get("experiments"), list):
        return "map_config.experiments is missing or not a list"
    for exp, names in record["experiments"].items():
        if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
            return f"experiments.{exp} is not a list of run names"
    for name, run in record["runs"].items():
        problem = run_problem(run, finite)
        if problem:
            return f"run {name}: {problem}"
    carried = record["provenance"].get("carried_over", [])
    if not isinstance(carried, list) or not all(isinstance(e, dict) and isinstance(e.get("runs"), list)
                                                for e in carried):
        return "provenance.carried_over is not a list of {'runs': [...]} entries"
    for corpus, cert in record["certificates"].items():
        if not (isinstance(cert, dict) and isinstance(cert.get("estimators"), dict)
                and isinstance(cert.get("gate"), dict)):
            return f"certificates.{corpus} is not an object with 'estimators' and 'gate' objects"
    planning = record.get("planning", {})
    if not (isinstance(planning, dict) and all(isinstance(planning.get(k, {}), dict) for k in ("config", "summary"))):
        return "'planning' is not an object with 'config' and 'summary' objects"
    return None


def read_record(path: str | Path, remedy: str, finite: bool = True) -> dict:
    """The results record at ``path``; a ConfigError naming the file, its first problem and ``remedy`` (what to
    do) when it is not valid JSON or not shaped like one pokeworld writes (``finite`` as in :func:`run_problem`)."""
    record = read_json(path, "a results record", None, MAX_RECORD_BYTES, remedy, ConfigError)
    problem = record_problem(record, finite)
    if problem:
        raise ConfigError(f"{path} is not a results record pokeworld wrote ({problem}); {remedy}")
    return record


__all__ = ["MAX_RECORD_BYTES", "TOP_LEVEL", "RUN_KEYS", "MEASURED", "leaf_problem", "run_problem", "record_problem", "read_record"]
