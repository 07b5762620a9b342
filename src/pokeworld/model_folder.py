"""The exported model folder's format (``pokeworld export``), in the model-hub layout, and its safe reading.

An exported folder holds

* ``README.md`` — the model card: YAML front matter (library, tags, licence, dataset, the measured metrics) and
  the text (what the model is, how it was trained and measured, the command that reproduces it);
* ``config.json`` — ``{"format": FORMAT, "model_kwargs": ..., "train_config": ..., "step": ...}``: the
  architecture the weights fit and the training config of the run they come from;
* ``model.safetensors`` — the weights, one named float tensor per entry of the model's state dict.

The card is written last (atomically): a folder without it is an export that did not finish, and every reader
refuses it (:func:`check_complete`), so weights and a config without their card never pass for a model.

``probe``, ``plan`` and the protocol read such a folder wherever they read a finished run
(:mod:`pokeworld.rundir` recognises it by ``config.json``'s ``format``). Nothing in it is trusted: the
safetensors format holds tensors only (loading it cannot run code), its size is bounded before it is read, and
:func:`pokeworld.rundir.model_from_checkpoint` checks the declared kwargs and every tensor's shape against the
model before any weight is loaded into it, as for a checkpoint.
"""

from __future__ import annotations

import hashlib
import os
import struct
from pathlib import Path
from typing import Any

import torch

from .checkpoint import CheckpointError, first_line
from .errors import ConfigError, DataError
from .io import OwnedDir, parse_json, read_json, read_regular_bytes
from .run_fields import check_run_fields

FORMAT = "pokeworld-xjepa-1"
"""``config.json``'s ``format`` in an exported folder (a training run's config.json has none)."""
CONFIG, WEIGHTS, CARD = "config.json", "model.safetensors", "README.md"
MAX_CONFIG_BYTES = 1 << 20
#: Largest weights file read: 100 M float32 elements (rundir.MAX_MODEL_ELEMENTS) and a header.
MAX_WEIGHT_BYTES = 400_000_000 + (16 << 20)
#: The most bytes the safetensors header (a JSON table of names, dtypes, shapes and offsets) may take.
MAX_HEADER_BYTES = 16 << 20
#: Element types the weights may hold (what torch.save would have stored for an X-JEPA state dict).
DTYPES = {"F32", "F16", "BF16", "F64", "I64", "BOOL"}


def _verify_exported(folder: Path) -> None:
    """What makes an owned folder an export: its config.json, if any, is an exported model's (not a run's)."""
    if os.path.lexists(folder / CONFIG) and folder_config(folder) is None:
        raise ConfigError(f"{folder} holds a training run's {CONFIG}, not an exported model's; pokeworld writes an "
                          "export only into a new folder or over an earlier export: name another --out")


EXPORTED_FOLDER = OwnedDir(files=(r"README\.md", r"config\.json", r"model\.safetensors",
                                  r"measure(-.+)?(\.previous)?\.json", r"training_metrics\.jsonl"),
                           verify=_verify_exported)
"""What an exported folder holds (the card, config, weights, the measurements ``pokeworld probe`` adds, and a
released model's training log): an export replaces only such a folder (:func:`pokeworld.io.check_owned_dir`)."""


def folder_config(run_dir: str | os.PathLike) -> dict[str, Any] | None:
    """An exported folder's ``config.json`` (checked), or None when ``run_dir``'s config.json is not one (a
    training run's, or none)."""
    path = Path(run_dir) / CONFIG
    if not os.path.lexists(path):
        return None
    cfg = read_json(path, "a run's config.json", dict, MAX_CONFIG_BYTES,
                    remedy="restore the file or train the run again into a new folder")
    return exported_config(cfg, path)


def exported_config(cfg: dict[str, Any], path: Path) -> dict[str, Any] | None:
    """``cfg`` (a parsed config.json at ``path``) when it is an exported folder's, its entries checked; None when
    it is a training run's (no :data:`FORMAT`)."""
    if cfg.get("format") != FORMAT:
        return None
    for key, kind in (("model_kwargs", dict), ("train_config", dict), ("step", int)):
        if not isinstance(cfg.get(key), kind) or isinstance(cfg.get(key), bool):
            raise CheckpointError(f"{path}: an exported model's config.json needs {key!r} as a {kind.__name__}, "
                                  f"got {type(cfg.get(key)).__name__}; the folder is damaged: export the run again")
    if cfg["step"] < 0:
        raise CheckpointError(f"{path}: its 'step' is {cfg['step']}, below 0; the folder is damaged: export the run "
                              "again")
    check_run_fields(cfg["train_config"], path, "train_config.")
    return cfg


def check_complete(run_dir: str | os.PathLike) -> None:
    """ConfigError unless the exported folder ``run_dir`` holds its card, a regular file: the card is written last,
    so a folder without it is an export that stopped before it finished."""
    card = Path(run_dir) / CARD
    if not os.path.isfile(card) or os.path.islink(card):
        raise ConfigError(f"{run_dir} is an export that did not finish (no model card {CARD}, which is written "
                          "last): export the run again (pokeworld export RUN --out FOLDER)")


def is_model_folder(run_dir: str | os.PathLike) -> bool:
    """Whether ``run_dir`` is an exported model folder (its config.json says :data:`FORMAT`)."""
    return folder_config(run_dir) is not None


def read_weights(run_dir: str | os.PathLike, sha256: str = "") -> dict[str, torch.Tensor]:
    """The tensors of ``run_dir/model.safetensors``: a regular file of at most :data:`MAX_WEIGHT_BYTES` (with
    ``sha256``, bytes of that digest: the weights a record names), whose header names only tensors of
    :data:`DTYPES` (checked before any tensor is decoded); CheckpointError naming the file otherwise."""
    path = Path(run_dir) / WEIGHTS
    if not os.path.lexists(path):
        raise CheckpointError(f"{run_dir} holds no {WEIGHTS}; export the run again (pokeworld export)")
    try:
        raw = read_regular_bytes(path, "a model's weights", MAX_WEIGHT_BYTES)
    except DataError as e:
        raise CheckpointError(str(e)) from None
    if sha256 and hashlib.sha256(raw).hexdigest() != sha256:
        raise CheckpointError(f"{path} is not the weights its record names (sha256 {sha256[:12]}…): it was changed "
                              "or replaced; restore it from the repository (git checkout -- the file)")
    check_header(raw, path)
    from safetensors import SafetensorError
    from safetensors.torch import load

    try:
        return load(raw)
    except (SafetensorError, ValueError, RuntimeError) as e:
        raise CheckpointError(f"cannot read {path} ({first_line(e)}); it is damaged or not a safetensors "
                              "file") from None


def check_header(raw: bytes, path: Path) -> None:
    """CheckpointError unless ``raw`` starts with a safetensors header (an 8-byte length, then a JSON table)
    whose entries are tensors of :data:`DTYPES`."""
    if len(raw) < 8:
        raise CheckpointError(f"{path} is {len(raw)} bytes, too short for a safetensors file; it is damaged")
    (size,) = struct.unpack("<Q", raw[:8])
    if size > min(MAX_HEADER_BYTES, len(raw) - 8):
        raise CheckpointError(f"{path} declares a {size}-byte header in a {len(raw)}-byte file; it is damaged or "
                              "not a safetensors file")
    header = parse_json(raw[8:8 + size], path, "a safetensors header", "it is damaged or not a safetensors file",
                        error=CheckpointError)
    if not isinstance(header, dict):
        raise CheckpointError(f"{path}: its header is not a table of tensors; it is damaged")
    odd = sorted(f"{k[:40]}: {v.get('dtype') if isinstance(v, dict) else type(v).__name__}"
                 for k, v in header.items() if k != "__metadata__"
                 and not (isinstance(v, dict) and v.get("dtype") in DTYPES))
    if odd:
        raise CheckpointError(f"{path} holds entries that are not weights of a known type ({odd[:3]}); allowed "
                              f"element types: {sorted(DTYPES)}")


__all__ = ["FORMAT", "CONFIG", "WEIGHTS", "CARD", "MAX_WEIGHT_BYTES", "EXPORTED_FOLDER", "folder_config",
           "exported_config", "is_model_folder", "check_complete", "read_weights", "check_header"]
