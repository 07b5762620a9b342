"""A run's measurement record (``measure.json``, written by ``pokeworld probe``) read back for the numbers other
commands quote: the model card of ``pokeworld export`` and the readout column of ``forecast-dependence``.

The record lies in a run or model folder that may come from someone else, so every field those readers take is
checked before any of it is used: ``probes.ridge`` a table of window kinds, each a table of quantities holding a
number or null; ``prediction`` a table whose entries are numbers, null or tables (the glide test); ``key`` a
table whose ``data_sha256`` is a string or null. A string or a list where a number or a table belongs is one line
naming the file and the field, before the reader writes anything.
"""

from __future__ import annotations

import numbers
import os
from pathlib import Path
from typing import Any

from ..errors import DataError
from ..io import read_json_if_present

MAX_MEASUREMENT_BYTES = 64 << 20
"""Largest measure.json read back (a measurement with every readout is tens of kilobytes)."""


def _is_number(value: Any) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def _kind(value: Any) -> str:
    return {dict: "a table", list: "a list", str: "a string", bool: "true/false"}.get(
        type(value), "null" if value is None else "a number" if _is_number(value) else type(value).__name__)


def _refuse(path: Path, field: str, value: Any, expected: str) -> DataError:
    return DataError(f"{path}: its {field} is {_kind(value)}, not {expected}; the measurement is damaged or was "
                     "edited: measure the run again (pokeworld probe RUN --overwrite)")


def _table(value: Any, path: Path, field: str) -> dict:
    """``value`` when it is a table (an absent one is empty), else DataError naming ``field``."""
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise _refuse(path, field, value, "a table")
    return value


def read_readout(path: str | os.PathLike) -> dict | None:
    """The probe's ridge R² per window kind and quantity, the prediction errors (numbers only) and the store's
    content hash from the measurement at ``path``, every field checked (see the module docstring); None when there
    is no measurement."""
    path = Path(path)
    res = read_json_if_present(path, "a measurement record (measure.json)", dict, MAX_MEASUREMENT_BYTES)
    if res is None:
        return None
    probes = _table(res.get("probes"), path, "probes")
    ridge = _table(probes.get("ridge"), path, "probes.ridge")
    for kind, row in ridge.items():
        for quantity, r2 in _table(row, path, f"probes.ridge.{kind}").items():
            if r2 is not None and not _is_number(r2):
                raise _refuse(path, f"probes.ridge.{kind}.{quantity}", r2, "a number (an R²) or null")
    prediction = _table(res.get("prediction"), path, "prediction")
    for name, value in prediction.items():
        if value is not None and not _is_number(value) and not isinstance(value, dict):
            raise _refuse(path, f"prediction.{name}", value, "a number, null or a table")
    digest = _table(res.get("key"), path, "key").get("data_sha256")
    if digest is not None and not isinstance(digest, str):
        raise _refuse(path, "key.data_sha256", digest, "a string (the store's content hash)")
    return {"ridge": {kind: dict(row or {}) for kind, row in ridge.items()},
            "prediction": {k: v for k, v in prediction.items() if _is_number(v)}, "data_sha256": digest}


__all__ = ["MAX_MEASUREMENT_BYTES", "read_readout"]
