"""The run directory's format, and its one owner: what training writes there and how everything else reads it.

A run directory holds

* ``config.json`` — the full training config (:class:`pokeworld.train.TrainConfig`);
* ``metrics.jsonl`` — one JSON object per logged step (step, loss terms, lr, frames/s);
* ``tb/`` — TensorBoard events of the same scalars (when enabled);
* ``ckpt.pt`` — the latest checkpoint (model, optimizer, scheduler, RNG states, sampler, step), written
  atomically (:mod:`pokeworld.checkpoint`);
* ``final.pt`` + ``DONE`` — the finished model and the marker that training ended.

Evaluation, planning and the protocol read runs through this module and never import the trainer.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import torch

from . import checkpoint
from .errors import ConfigError
from .io import append_jsonl, read_jsonl
from .models.xjepa import VALUES_BEFORE_THE_FIELD, XJEPA


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

def write_final(out: Path, state: dict, model_kwargs: dict, cfg_dict: dict, step: int, note: str = "") -> None:
    """Write a finished run's ``final.pt`` (weights, model kwargs, config, step) and its ``DONE`` marker."""
    checkpoint.save({"model": state, "model_kwargs": model_kwargs, "config": cfg_dict, "step": step}, out / "final.pt")
    (out / "DONE").write_text(f"finished {step} steps{note}\n")

def restart_metrics(out: Path, step: int, start_row: dict[str, Any] | None = None) -> None:
    """Make ``metrics.jsonl`` match an uninterrupted run: on resume from ``step`` drop rows logged after the
    checkpoint; on a fresh start (``start_row``) replace the file with that step-0 row."""
    path = Path(out) / "metrics.jsonl"
    if start_row is not None:
        path.write_text(json.dumps(start_row, sort_keys=True) + "\n")
        return
    rows = [r for r in read_jsonl(path) if r.get("step", 0) <= step]
    path.write_text("".join(json.dumps(r, sort_keys=True) + "\n" for r in rows))

def finished_run_config(run_dir: str | os.PathLike) -> dict[str, Any]:
    """The config.json of a finished run; ConfigError when ``run_dir`` is not a run or has not finished."""
    run_dir = Path(run_dir)
    if not (run_dir / "config.json").exists():
        raise ConfigError(f"{run_dir} is not a training run (no config.json)")
    if not (run_dir / "DONE").exists():
        raise ConfigError(f"{run_dir} has not finished training; re-run `pokeworld train` to resume it")
    return json.loads((run_dir / "config.json").read_text())

def load_model(run_dir: str | os.PathLike, map_location: str | torch.device = "cpu", final: bool | None = None) -> XJEPA:
    """Load a trained model (eval mode) from a run directory: ``final.pt`` if present, else ``ckpt.pt``."""
    run_dir = Path(run_dir)
    path = run_dir / "final.pt"
    if final is False or not path.exists():
        path = run_dir / "ckpt.pt"
    if not path.exists():
        raise FileNotFoundError(f"{run_dir} holds no final.pt or ckpt.pt; train it with `pokeworld train`")
    ck = checkpoint.load(path, map_location=map_location)
    # a checkpoint written before a kwarg existed means that kwarg's value then, not today's default
    model = XJEPA(**{**VALUES_BEFORE_THE_FIELD, **ck["model_kwargs"]})
    model.load_state_dict(ck["model"])
    return model.to(map_location).eval()


def read_metrics(run_dir: str | os.PathLike) -> list[dict[str, Any]]:
    """The rows of a run's ``metrics.jsonl`` ([] when it has none)."""
    return read_jsonl(Path(run_dir) / "metrics.jsonl")


def last_logged_step(run_dir: str | os.PathLike) -> int:
    """Last logged training step of a run directory (0 when it has none)."""
    return max((int(r.get("step", 0)) for r in read_metrics(run_dir)), default=0)


__all__ = ["MetricsLog", "write_final", "restart_metrics", "finished_run_config", "load_model", "read_metrics",
           "last_logged_step"]
