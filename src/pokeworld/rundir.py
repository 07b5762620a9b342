"""The run directory's format, and its one owner: what training writes there and how everything else reads it.

A run directory holds

* ``config.json`` — the full training config (:class:`pokeworld.train.TrainConfig`);
* ``metrics.jsonl`` — one JSON object per logged step (step, loss terms, lr, frames/s);
* ``tb/`` — TensorBoard events of the same scalars (when enabled);
* ``ckpt.pt`` — the latest checkpoint (model, optimizer, scheduler, RNG states, sampler, step), written
  atomically (:mod:`pokeworld.checkpoint`);
* ``final.pt`` + ``DONE`` — the finished model and the marker that training ended.

Evaluation, planning and the protocol read runs through this module and never import the trainer.

A run directory may come from someone else (a shared cluster folder, a colleague's archive), so nothing in it is
trusted: its own files must be regular files, never links (writing would follow a link and overwrite its target)
nor FIFOs or devices (reading would hang); ``config.json`` and ``metrics.jsonl`` are parsed with one-line errors
for damage (a final ``metrics.jsonl`` line cut off by a crash is dropped); checkpoints are read weights-only and
their model kwargs are checked against the stored tensors' shapes, on the ``meta`` device, before a model is
built.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import shutil
import stat
from pathlib import Path
from typing import Any, Iterator

import torch

from . import checkpoint
from .checkpoint import CheckpointError, file_kind, first_line
from .errors import ConfigError, DataError, PokeworldError
from .io import (
    OWNED_RECORD,
    adopt_legacy,
    append_jsonl,
    atomic_path,
    check_outputs,
    parse_json,
    read_json,
    read_regular_bytes,
    save_text,
)
from .model_folder import CARD, WEIGHTS, check_complete, exported_config, folder_config, read_weights
from .models.xjepa import VALUES_BEFORE_THE_FIELD, XJEPA, check_model_kwargs
from .run_fields import check_run_fields

#: The names training writes in a run directory (``tb`` a folder, the rest regular files).
RUN_FILES = ("config.json", "metrics.jsonl", "ckpt.pt", "final.pt", "DONE", ".lock", "tb")
#: Largest config.json / metrics.jsonl read (a 20k-step run logs a few hundred kilobytes of metrics).
MAX_CONFIG_BYTES, MAX_METRICS_BYTES = 1 << 20, 256 << 20
#: Largest model (parameters and buffers) a checkpoint may declare: ~20x the paper's 4.4 M, 400 MB in float32.
MAX_MODEL_ELEMENTS = 100_000_000
#: What a resumable ``ckpt.pt`` holds besides the model, and the type each entry must have.
RESUME_ENTRIES: dict[str, type] = {"model": dict, "optimizer": dict, "scheduler": dict, "rng": dict,
                                   "sampler": torch.Tensor, "step": int, "model_kwargs": dict}


def not_a_run(run_dir: str | os.PathLike) -> str:
    """Why ``run_dir`` is not a training run, and what to name instead."""
    what = "does not exist" if not os.path.lexists(run_dir) else "is not a training run (no config.json)"
    return (f"{run_dir} {what}: name a run folder that `pokeworld train` wrote (its --out; the default is "
            "runs/xjepa)")


def check_run_files(run_dir: str | os.PathLike) -> None:
    """ConfigError (naming the file) when ``run_dir`` is not a folder or one of its :data:`RUN_FILES` is a link or
    a special file: writing would follow the link and overwrite its target, reading a FIFO would hang."""
    run_dir = Path(run_dir)
    if run_dir.exists() and not run_dir.is_dir():
        raise ConfigError(f"{run_dir} is a file, not a run folder: name a folder instead")
    for name in RUN_FILES:
        path = run_dir / name
        try:
            mode = os.lstat(path).st_mode
        except (FileNotFoundError, NotADirectoryError):
            continue
        if stat.S_ISLNK(mode):
            raise ConfigError(f"{path} is a symbolic link (to {os.readlink(path)}); pokeworld refuses run folders "
                              "whose own files are links (writing them would overwrite the target): remove the link")
        if not (stat.S_ISDIR(mode) if name == "tb" else stat.S_ISREG(mode)):
            want = "a folder" if name == "tb" else "a regular file"
            raise ConfigError(f"{path} is {file_kind(mode)}, not {want}; pokeworld reads and writes only "
                              f"{want} there: remove it")


def adopt_legacy_run(run_dir: str | os.PathLike) -> None:
    """A run folder written before ownership records (``.pokeworld-owned``) existed, recognised by its config.json
    (a JSON object naming a variant and a step count), gets its record, so that it resumes and is measured as
    before; a folder without such a config.json (a user's files) gets none and stays refused."""
    run_dir = Path(run_dir)
    if os.path.lexists(run_dir / OWNED_RECORD) or not (run_dir / "config.json").is_file():
        return
    try:
        cfg = read_run_config(run_dir)
    except PokeworldError:
        return
    if isinstance(cfg, dict) and isinstance(cfg.get("variant"), str) and isinstance(cfg.get("steps"), int):
        measured = sorted(p.name for p in run_dir.glob("measure*.json"))
        adopt_legacy(run_dir, [n for n in RUN_FILES if n != "tb"] + measured)


def check_run_dir_writable(out: str | os.PathLike) -> None:
    """Before training into ``out``: :func:`check_run_files`, then prove the folder can be created and written
    (ConfigError in one line, before any data is loaded or any step is trained)."""
    check_run_files(out)
    adopt_legacy_run(out)
    check_outputs(out, *(n for n in RUN_FILES if n != "tb"))  # a user's metrics.jsonl is refused, not appended to


def read_run_config(run_dir: str | os.PathLike) -> dict[str, Any] | None:
    """A run's ``config.json`` as a dict (None when it has none); DataError when it is not a JSON object or a field
    its readers use has the wrong type (:func:`pokeworld.run_fields.check_run_fields`). For an exported model folder
    (:mod:`pokeworld.model_folder`), the training config of the run it was exported from, checked alike."""
    path = Path(run_dir) / "config.json"
    check_run_files(run_dir)
    if not path.exists():
        return None
    cfg = read_json(path, "a run's config.json", dict, MAX_CONFIG_BYTES,
                    remedy="restore the file or train the run again into a new folder")
    exported = exported_config(cfg, path)
    if exported is not None:
        return exported["train_config"]
    check_run_fields(cfg, path)
    return cfg


class MetricsLog:
    """A run's metrics record: one JSON line per row in ``metrics.jsonl`` and, when ``tensorboard``, the same
    scalars under ``tb/`` (``purge_step`` drops events a resumed run will write again)."""

    def __init__(self, out: Path, tensorboard: bool, step: int):
        self.path = Path(out) / "metrics.jsonl"
        self.writer = None
        if tensorboard:
            from torch.utils.tensorboard import SummaryWriter

            self.writer = SummaryWriter(str(Path(out) / "tb"), purge_step=step or None)

    def write(self, row: dict[str, Any]) -> None:
        append_jsonl(self.path, row)
        if self.writer is not None:
            for k, v in row.items():
                if k != "step":
                    self.writer.add_scalar(f"train/{k}", v, row["step"])

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()


def keep_checkpoint(out: Path, step: int) -> Path:
    """Copy ``out/ckpt.pt`` (just written at ``step``) to ``out/kept/ckpt-<step>.pt``, a point of the run's learning
    curve (``TrainConfig.keep_every``; read by ``scripts/budget_curve.py``)."""
    dest = Path(out) / "kept" / f"ckpt-{step}.pt"
    with atomic_path(dest) as tmp:
        shutil.copyfile(Path(out) / "ckpt.pt", tmp)
    return dest


def write_final(out: Path, state: dict, model_kwargs: dict, cfg_dict: dict, step: int, note: str = "") -> None:
    """Write a finished run's ``final.pt`` (weights, model kwargs, config, step) and its ``DONE`` marker."""
    checkpoint.save({"model": state, "model_kwargs": model_kwargs, "config": cfg_dict, "step": step}, out / "final.pt")
    save_text(out / "DONE", f"finished {step} steps{note}\n")


def restart_metrics(out: Path, step: int, start_row: dict[str, Any] | None = None) -> None:
    """Make ``metrics.jsonl`` match an uninterrupted run: on resume from ``step`` drop rows logged after the
    checkpoint (and a last line a crash cut off); on a fresh start (``start_row``) replace the file with that
    step-0 row."""
    path = Path(out) / "metrics.jsonl"
    rows = [start_row] if start_row is not None else [r for r in read_metrics(out) if r["step"] <= step]
    save_text(path, "".join(json.dumps(r, sort_keys=True) + "\n" for r in rows))


def finished_run_config(run_dir: str | os.PathLike) -> dict[str, Any]:
    """The config.json of a finished run; ConfigError when ``run_dir`` is not a run or has not finished,
    DataError when its config.json is damaged."""
    run_dir = Path(run_dir)
    cfg = read_run_config(run_dir)
    if cfg is None:
        raise ConfigError(not_a_run(run_dir))
    if folder_config(run_dir) is not None:
        check_complete(run_dir)
    elif not finished_marker(run_dir).exists():
        raise ConfigError(f"{run_dir} has not finished training; re-run `pokeworld train` to resume it")
    if not isinstance(cfg.get("data"), str) or not cfg["data"]:
        raise DataError(f"{run_dir / 'config.json'} names no dataset (its 'data' is {cfg.get('data')!r:.60}, not a "
                        "path); the run folder is damaged: pass the corpus with --data")
    return cfg


def finished_marker(run_dir: str | os.PathLike) -> Path:
    """The file whose presence (and modification time) says a run finished: ``DONE`` in a training run, the
    model card in an exported model folder (written last, after the weights)."""
    run_dir = Path(run_dir)
    return run_dir / (CARD if folder_config(run_dir) is not None else "DONE")


def has_final_weights(run_dir: str | os.PathLike) -> bool:
    """Whether ``run_dir`` holds a finished model: ``final.pt`` in a training run, the weights and the card (written
    after them) in an exported model folder."""
    run_dir = Path(run_dir)
    if folder_config(run_dir) is not None:
        return (run_dir / WEIGHTS).is_file() and (run_dir / CARD).is_file()
    return (run_dir / "final.pt").is_file()


def read_metrics(run_dir: str | os.PathLike) -> list[dict[str, Any]]:
    """The rows of a run's ``metrics.jsonl`` ([] when it has none). A last line without its newline that does not
    parse was cut off by a crash while being written and is dropped; any other damage is a DataError naming the
    line."""
    path = Path(run_dir) / "metrics.jsonl"
    check_run_files(run_dir)
    if not path.exists():
        return []
    raw = read_regular_bytes(path, "a run's metrics.jsonl", MAX_METRICS_BYTES)
    lines = raw.split(b"\n")
    rows = []
    for number, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            row = parse_json(line, f"{path} line {number}", "a run's metrics.jsonl",
                             "delete that line (or the file) and re-run")
        except DataError:
            if number == len(lines):  # the file ends inside this line: a torn final write
                break
            raise
        step = row.get("step") if isinstance(row, dict) else None
        if isinstance(step, bool) or not isinstance(step, int) or step < 0:
            raise DataError(f"{path} line {number} is not a metrics row (a JSON object with a non-negative integer "
                            "'step'); the file is damaged: delete that line (or the file) and re-run")
        rows.append(row)
    return rows


def training_summary(run_dir: str | os.PathLike) -> dict[str, Any]:
    """What a run's ``metrics.jsonl`` says about its training as a whole: the last logged step and, for a run whose
    objective logs it, the mean glide loss share over every logged row (the dose–response's realised share). {} when
    the folder holds no metrics (a run measured from a model folder)."""
    rows = read_metrics(run_dir) if Path(run_dir).is_dir() else []
    if not rows:
        return {}
    shares = [r["glide_loss_share"] for r in rows
              if isinstance(r.get("glide_loss_share"), (int, float)) and not isinstance(r["glide_loss_share"], bool)
              and math.isfinite(r["glide_loss_share"])]
    return {"last_logged_step": max(r["step"] for r in rows),
            **({"glide_loss_share": sum(shares) / len(shares)} if shares else {})}


def last_logged_step(run_dir: str | os.PathLike) -> int:
    """Last logged training step of a run directory (0 when it has none)."""
    return max((r["step"] for r in read_metrics(run_dir)), default=0)


def load_resume_checkpoint(path: Path) -> dict[str, Any]:
    """A ``ckpt.pt`` to resume from, with every entry :data:`RESUME_ENTRIES` names of the right type
    (CheckpointError naming the file and the entry otherwise)."""
    ck = checkpoint.load(path)
    for key, kind in RESUME_ENTRIES.items():
        value = ck.get(key)
        if not isinstance(value, kind) or isinstance(value, bool):
            raise CheckpointError(f"{path} is not a resumable checkpoint: its {key!r} is "
                                  f"{type(value).__name__}, expected {kind.__name__}; it is damaged: move it away "
                                  "to restart the run from step 0")
    if ck["step"] < 0:
        raise CheckpointError(f"{path} is not a resumable checkpoint: step {ck['step']} < 0")
    return ck


@contextlib.contextmanager
def restoring(path: Path) -> Iterator[None]:
    """Loading a checkpoint's states into a model, optimizer, scheduler, RNGs and sampler: whatever does not fit
    becomes one CheckpointError naming the file instead of a torch traceback."""
    try:
        yield
    except (RuntimeError, KeyError, ValueError, TypeError, IndexError, AttributeError) as e:
        if isinstance(e, CheckpointError):
            raise
        raise CheckpointError(f"{path} does not fit this run ({type(e).__name__}: {first_line(e)}); it is damaged "
                              "or from another config: move it away to restart the run from step 0") from None


def check_state_fits(model: torch.nn.Module, state: Any, path: Path) -> None:
    """CheckpointError unless ``state`` holds exactly ``model``'s tensors, each of its shape, each stored densely
    (a stride-0 view would declare more elements than the file holds)."""
    if not isinstance(state, dict) or not all(isinstance(k, str) and isinstance(v, torch.Tensor)
                                              for k, v in state.items()):
        raise CheckpointError(f"{path}: its 'model' is not a dict of named tensors; the checkpoint is damaged")
    expected = {k: tuple(v.shape) for k, v in model.state_dict().items()}
    missing, unexpected = sorted(set(expected) - set(state)), sorted(set(state) - set(expected))
    if missing or unexpected:
        raise CheckpointError(f"{path}: the weights do not match the model its kwargs declare (missing "
                              f"{missing[:3]}, unexpected {[k[:60] for k in unexpected[:3]]}); the checkpoint is "
                              "damaged or was edited")
    for name, tensor in state.items():
        if tuple(tensor.shape) != expected[name]:
            raise CheckpointError(f"{path}: the model kwargs declare {name} of shape {list(expected[name])} but the "
                                  f"weights hold {list(tensor.shape)}; the checkpoint is damaged or was edited")
        if tensor.numel() * tensor.element_size() > tensor.untyped_storage().nbytes():
            raise CheckpointError(f"{path}: {name} declares {tensor.numel()} elements but stores "
                                  f"{tensor.untyped_storage().nbytes()} bytes; the checkpoint was crafted")
        # a NaN or inf weight makes every state it touches NaN: the probes' fit would refuse it only after the
        # whole encoding, and a plan would rank candidates by NaN
        if tensor.is_floating_point() and not bool(torch.isfinite(tensor).all()):
            raise CheckpointError(f"{path}: {name} holds NaN or infinite values; the weights are damaged (or come "
                                  "from a diverged run): restore them, or train (or export) the run again")


def model_from_checkpoint(ck: dict[str, Any], path: Path) -> XJEPA:
    """The model a checkpoint's ``model_kwargs`` and ``model`` weights describe, validated before any weight is
    allocated: the kwargs' names, types and ranges (:func:`~pokeworld.models.xjepa.check_model_kwargs`), then
    the model built on the ``meta`` device (no memory) and bounded to :data:`MAX_MODEL_ELEMENTS`, and every
    shape compared with the stored weights."""
    declared = ck.get("model_kwargs")
    try:
        # a checkpoint written before a kwarg existed means that kwarg's value then, not today's default
        kwargs = check_model_kwargs({**VALUES_BEFORE_THE_FIELD, **declared} if isinstance(declared, dict) else declared)
    except ConfigError as e:
        raise CheckpointError(f"{path}: {e}") from None
    try:
        with torch.device("meta"):
            skeleton = XJEPA(**kwargs)
    except ConfigError as e:
        raise CheckpointError(f"{path}: its model kwargs are invalid ({e})") from None
    except (ValueError, TypeError, RuntimeError, AssertionError, ZeroDivisionError) as e:  # e.g. width % heads
        raise CheckpointError(f"{path}: its model kwargs describe no buildable model ({type(e).__name__}: "
                              f"{first_line(e)})") from None
    size = sum(t.numel() for t in skeleton.state_dict().values())
    if size > MAX_MODEL_ELEMENTS:
        raise CheckpointError(f"{path}: its model kwargs declare a model of {size:,} parameters and buffers; at "
                              f"most {MAX_MODEL_ELEMENTS:,} are allowed (the paper's model has 4.4 M)")
    check_state_fits(skeleton, ck.get("model"), path)
    model = XJEPA(**kwargs)
    with restoring(path):
        model.load_state_dict(ck["model"])
    return model


def load_model(run_dir: str | os.PathLike, map_location: str | torch.device = "cpu",
               final: bool | None = None) -> XJEPA:
    """Load a trained model (eval mode) from a run directory: ``final.pt`` if present, else ``ckpt.pt``; or from
    an exported model folder (its ``model.safetensors``, checked as a checkpoint is)."""
    run_dir = Path(run_dir)
    check_run_files(run_dir)
    exported = folder_config(run_dir)
    if exported is not None:
        check_complete(run_dir)
        ck = {"model": read_weights(run_dir), "model_kwargs": exported["model_kwargs"]}
        return model_from_checkpoint(ck, run_dir / WEIGHTS).to(map_location).eval()
    path = run_dir / "final.pt"
    if final is False or not path.exists():
        path = run_dir / "ckpt.pt"
    if not path.exists():
        raise ConfigError(f"{run_dir} holds no final.pt or ckpt.pt; train it with `pokeworld train`")
    ck = checkpoint.load(path, map_location=map_location)
    return model_from_checkpoint(ck, path).to(map_location).eval()


__all__ = ["RUN_FILES", "adopt_legacy_run", "MAX_MODEL_ELEMENTS", "RESUME_ENTRIES", "MetricsLog", "check_run_files",
           "check_run_dir_writable", "read_run_config", "write_final", "restart_metrics", "finished_run_config",
           "load_model", "model_from_checkpoint", "check_state_fits", "load_resume_checkpoint", "restoring",
           "read_metrics", "training_summary", "last_logged_step", "finished_marker", "has_final_weights"]
