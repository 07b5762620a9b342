"""The store a run was trained on: recorded in its ``config.json`` when training starts, and found again by content
by every command that reads the run later (``pokeworld probe``, ``pokeworld plan``, a resumed ``pokeworld train``).

A run's ``data`` is the path as it was typed, relative to the folder training ran in; read from another folder it
names another store, or none, and probing it would measure another corpus under the run's name. So training records
beside it ``data_path`` (the resolved, absolute path) and ``data_sha256`` (the store manifest's ``content_sha256``,
which :func:`pokeworld.data.load` verifies against the arrays), and :func:`trained_store` answers only with a store
holding that content: ``data`` as typed (relative to the current folder), then ``data`` relative to the folder
training ran in (:func:`training_folder`), then ``data_path``; the first whose hash is the recorded one. A store
found with other content is refused, naming both hashes; a resumed run refuses a store whose content changed.

Runs trained before these fields existed carry no hash, so their content cannot be checked: an absolute ``data`` is
used as it is, a relative one relative to the folder training ran in when that folder can be told from the run's
recorded ``out`` and it holds the store, else relative to the current folder with a warning (printed once per run
and process).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from .data import read_manifest
from .errors import ConfigError, DataError
from .io import write_json
from .rundir import not_a_run, read_run_config

RECORDED = ("data_path", "data_sha256")
"""The fields :func:`write_run_config` adds to a run's config.json beside the training config."""

warned_runs: set[str] = set()
"""Runs whose store was resolved against the current folder without a hash to check (warned once each)."""


def store_identity(data: str | os.PathLike) -> dict[str, str]:
    """``{"data_path", "data_sha256"}`` of the store at ``data`` (DataError when it is not a store)."""
    path = Path(data).resolve()
    return {"data_path": str(path), "data_sha256": read_manifest(path).get("content_sha256")}


def write_run_config(out: Path, cfg_dict: dict[str, Any]) -> None:
    """Write ``out/config.json``: the training config and the :func:`store_identity` of its ``data``.

    A resumed run (``config.json`` already records a hash) whose store now holds other content is refused with a
    DataError naming both hashes, before anything is trained on it.
    """
    now = store_identity(cfg_dict["data"])
    path = Path(out) / "config.json"
    before = (read_run_config(out) or {}).get("data_sha256")
    if before and before != now["data_sha256"]:
        raise DataError(f"{out} was trained on a store with content sha256 {str(before)[:12]}, but {cfg_dict['data']} "
                        f"({now['data_path']}) holds {str(now['data_sha256'])[:12]}: resuming would train one model on "
                        "two corpora; restore that store, or train on this one into another --out")
    write_json(path, {**cfg_dict, **now})


def training_folder(run_dir: str | os.PathLike, recorded_out: str) -> Path | None:
    """The folder training ran in, when the run folder still sits at its recorded (relative) ``out`` below it:
    ``/home/u/proj`` for the run ``/home/u/proj/runs/a`` trained with ``out='runs/a'``; None when it cannot be told."""
    out = Path(os.path.normpath(recorded_out)) if recorded_out else None
    if out is None or out.is_absolute() or ".." in out.parts:
        return None
    here = Path(run_dir).resolve()
    n = len(out.parts)
    if here.parts[-n:] != out.parts:
        return None
    return here.parents[n - 1]


def content_of(path: Path) -> str | None:
    """The recorded content hash of the store at ``path``; None when no store is there."""
    try:
        return read_manifest(path).get("content_sha256")
    except DataError:
        return None


def trained_store(run_dir: str | os.PathLike, command: str) -> str:
    """The path of the store ``run_dir`` was trained on, as ``command`` (a log prefix) should read it.

    Checked by content when the run recorded its store's hash (DataError naming both hashes when only other
    content is found, or none); see the module docstring for runs recorded before the hash.
    """
    cfg = read_run_config(run_dir)
    if cfg is None:
        raise ConfigError(not_a_run(run_dir))
    data = cfg.get("data")
    if not isinstance(data, str) or not data:
        raise DataError(f"{run_dir}/config.json names no training store ('data'); the run folder is damaged")
    out = cfg.get("out")
    base = training_folder(run_dir, out if isinstance(out, str) else "")
    anchored = str(base / data) if base is not None and not Path(data).is_absolute() else None
    recorded = cfg.get("data_sha256")
    if not isinstance(recorded, str) or not recorded:
        return unchecked_store(run_dir, data, anchored, command)
    candidates = [p for p in dict.fromkeys([data, anchored, cfg.get("data_path")]) if isinstance(p, str) and p]
    found = {p: content_of(Path(p)) for p in candidates}
    for p, digest in found.items():
        if digest == recorded:
            return p
    other = {p: d for p, d in found.items() if d is not None}
    where = f"{cfg.get('data_path', data)} (content sha256 {recorded[:12]})"
    if other:
        # one path under several names (relative, absolute, recorded) is said once
        seen = "; ".join(f"{p} holds {str(d)[:12]}" for p, d in {Path(p).resolve(): d for p, d in other.items()}.items())
        raise DataError(f"{run_dir} was trained on {where}, but {seen}: {command} would read another corpus under "
                        "this run's name; restore the store it was trained on (or pass --data to name another "
                        "corpus deliberately)")
    raise DataError(f"{run_dir} was trained on {where}, which is no longer there (looked at "
                    f"{', '.join(candidates)}); restore that store, or pass --data to name another corpus")


def unchecked_store(run_dir: str | os.PathLike, data: str, anchored: str | None, command: str) -> str:
    """The store of a run recorded before its hash was: ``data`` if absolute, relative to the training folder when
    a store is there, else relative to the current folder with a warning (once per run)."""
    if Path(data).is_absolute():
        return data
    if anchored is not None and content_of(Path(anchored)) is not None:
        return anchored
    key = str(Path(run_dir).resolve())
    if key not in warned_runs:
        warned_runs.add(key)
        print(f"[{command}] warning: {run_dir} records no store hash (trained before pokeworld recorded one) and "
              f"no store at data={data!r} was found from the folder it was trained in; reading that path relative "
              "to the current folder, unchecked")
    return data


__all__ = ["RECORDED", "store_identity", "write_run_config", "training_folder", "trained_store", "unchecked_store",
           "content_of"]
