"""A forecast-dependence record (``<name>.json`` of ``pokeworld forecast-dependence``) read back to be merged, every
field checked before anything is measured.

``--merge`` joins earlier records' rows to a new measurement; the table, the markdown and the figure then read
each row's run, variant, seed, steps, store, S cells and readout, and each planted row's cells. A record that was
edited or damaged (a row without its ``dependence``, a ``config`` that is a list, a string where S belongs) is one
line naming the file and the field here, at the start, instead of a KeyError after the measurement and the JSON
were written.
"""

from __future__ import annotations

import numbers
import os
from pathlib import Path
from typing import Any

from ..errors import ConfigError, DataError
from ..io import read_json
from .dependence import PARAMETERS
from .forecasters import PLANTS

#: A cell's entries that hold a number when present (``S`` and its slopes only where S was measured).
CELL_NUMBERS = ("S", "slope_model", "slope_simulator", "forecast_error")
#: The readout's window kinds, each a number (an R²) or null per parameter.
READOUT_KINDS = ("contact", "glide")


def _is_number(value: Any) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


class Fields:
    """Checks of one record's fields, each failure one DataError naming the file and the field."""

    def __init__(self, path: Path):
        self.path = path

    def fail(self, field: str, expected: str, value: Any) -> DataError:
        shown = repr(value)
        return DataError(f"{self.path}: its {field} must be {expected}, got {shown[:60]}; the record is damaged or "
                         "was edited: measure its runs again, or leave it out of --merge")

    def table(self, value: Any, field: str) -> dict:
        if not isinstance(value, dict):
            raise self.fail(field, "a table", value)
        return value

    def cell(self, value: Any, field: str) -> None:
        """One S cell: its numbers numbers, its interval two numbers, its windows an integer, its note a string."""
        cell = self.table(value, field)
        for name in CELL_NUMBERS:
            if (name in cell or (name != "forecast_error" and "S" in cell)) and not _is_number(cell.get(name)):
                raise self.fail(f"{field}.{name}", "a number", cell.get(name))
        interval = cell.get("S_interval")
        if "S" in cell and not (isinstance(interval, list) and len(interval) == 2 and all(map(_is_number, interval))):
            raise self.fail(f"{field}.S_interval", "a list of two numbers", interval)
        windows = cell.get("windows", 0)
        if not isinstance(windows, int) or isinstance(windows, bool):
            raise self.fail(f"{field}.windows", "an integer", windows)
        if not isinstance(cell.get("note", ""), str):
            raise self.fail(f"{field}.note", "a string", cell.get("note"))

    def row(self, value: Any, field: str) -> None:
        """One run's row: its words, its S cell and readout per parameter."""
        row = self.table(value, field)
        for name in ("run", "variant", "store"):
            if not isinstance(row.get(name), str):
                raise self.fail(f"{field}.{name}", "a string", row.get(name))
        for name in ("seed", "steps"):
            if row.get(name) is not None and (not isinstance(row[name], int) or isinstance(row[name], bool)):
                raise self.fail(f"{field}.{name}", "an integer or null", row[name])
        dependence = self.table(row.get("dependence"), f"{field}.dependence")
        readout = self.table(row.get("readout"), f"{field}.readout")
        for p in PARAMETERS:
            self.cell(dependence.get(p), f"{field}.dependence.{p}")
            self.readout(readout.get(p), f"{field}.readout.{p}")

    def readout(self, value: Any, field: str) -> None:
        kinds = self.table(value, field)
        for kind in READOUT_KINDS:
            r2 = kinds.get(kind)
            if r2 is not None and not _is_number(r2):
                raise self.fail(f"{field}.{kind}", "a number (an R²) or null", r2)

    def planted(self, value: Any) -> None:
        """Per store, per planted forecaster, per parameter: one S cell (a record without planted rows has none)."""
        for store, plants in self.table({} if value is None else value, "planted").items():
            plants = self.table(plants, f"planted.{store}")
            for plant in PLANTS:
                params = self.table(plants.get(plant), f"planted.{store}.{plant}")
                for p in PARAMETERS:
                    self.cell(params.get(p), f"planted.{store}.{plant}.{p}")


def same_store(got: dict, store: Any, store_sha256: str | None) -> bool:
    """Whether a record's ``config`` names the store of this measurement: by the store's content hash when both
    carry one (a committed record names its store by a placeholder, not by a path of the machine it was made on),
    else by the path as given."""
    if store_sha256 and isinstance(got.get("store_sha256"), str):
        return got["store_sha256"] == store_sha256
    return got.get("store") == store


def read_record(path: str | os.PathLike, settings: dict[str, Any], store_sha256: str | None = None) -> dict:
    """The record at ``path``, every field its merge reads checked (DataError naming the field), measured with
    ``settings`` (ConfigError otherwise: its numbers are not comparable with this measurement's); ``settings``'
    ``store`` is matched by ``store_sha256`` where the record carries one (:func:`same_store`)."""
    path = Path(path)
    rec = read_json(path, "a forecast-dependence record", dict)
    check = Fields(path)
    got = check.table(rec.get("config"), "config")
    if any(got.get(k) != v for k, v in settings.items() if k != "store") or (
            "store" in settings and not same_store(got, settings["store"], store_sha256)):
        raise ConfigError(f"{path} was measured with other settings ({str(got)[:200]}); merge only records of the "
                          f"same settings ({settings})")
    runs = rec.get("runs")
    if not isinstance(runs, list):
        raise check.fail("runs", "a list of rows", runs)
    for i, row in enumerate(runs):
        check.row(row, f"runs[{i}]")
    check.planted(rec.get("planted"))
    return rec


__all__ = ["CELL_NUMBERS", "READOUT_KINDS", "read_record", "same_store"]
