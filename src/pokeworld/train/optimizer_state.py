"""A resumed optimizer state checked like a resumed model, before ``load_state_dict``.

``torch.optim.Optimizer.load_state_dict`` copies whatever a checkpoint's ``optimizer`` holds: moments of another
shape, a NaN moment, a zero-stride view (one stored number standing for a whole matrix, which an in-place update
cannot write) or a learning rate given as a string all load silently, and the first step then dies with a raw
traceback or trains on garbage. :func:`check_optimizer_fits` compares the state with the AdamW that
:func:`.step.make_optimizer` builds for the model (its two parameter groups, in :func:`.step.decay_split`'s order)
and says in one line what does not fit.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import torch

from ..checkpoint import CheckpointError
from .step import decay_split

MOMENTS = ("exp_avg", "exp_avg_sq")
"""AdamW's per-parameter moments (``max_exp_avg_sq`` too with amsgrad, which pokeworld does not use)."""
NUMBERS = ("lr", "eps", "weight_decay", "initial_lr")
"""A parameter group's numeric settings (load_state_dict takes them from the checkpoint)."""


def unfit(path: Path | str, text: str) -> CheckpointError:
    return CheckpointError(f"{path} does not fit this run: {text}")


def optimizer_params(model: torch.nn.Module) -> list[list[torch.Tensor]]:
    """The model's parameters in :func:`.step.make_optimizer`'s groups (with decay, without), in its order."""
    named = dict(model.named_parameters())
    return [[named[n] for n in names] for names in decay_split((n, p.ndim) for n, p in named.items())]


def check_optimizer_fits(model: torch.nn.Module, state: Any, path: Path | str) -> None:
    """CheckpointError (one line naming ``path``) unless ``state`` is an AdamW state of ``model``'s parameters as
    :func:`.step.make_optimizer` groups them: the groups' sizes and numeric settings, every moment of its
    parameter's shape, floating, finite and stored densely (no zero stride, no more elements than its storage),
    every step a finite number ≥ 0."""
    groups = optimizer_params(model)
    if not (isinstance(state, dict) and isinstance(state.get("state"), dict)
            and isinstance(state.get("param_groups"), list)):
        raise unfit(path, "its 'optimizer' is not an optimizer state (a 'state' mapping and "
                              "'param_groups' list); the checkpoint is damaged or was edited")
    saved = state["param_groups"]
    sizes = [len(g.get("params", ())) if isinstance(g, dict) and isinstance(g.get("params"), list) else None
             for g in saved]
    if sizes != [len(g) for g in groups]:
        raise unfit(path, f"its optimizer has parameter groups of sizes {sizes[:4]}, the model "
                              f"{[len(g) for g in groups]}; the checkpoint is from another model or was edited")
    by_index = {}
    for g, params in zip(saved, groups):
        check_group(g, path)
        if not all(isinstance(i, int) and not isinstance(i, bool) for i in g["params"]):
            raise unfit(path, "its optimizer's parameter indices are not integers; it is damaged")
        by_index.update(zip(g["params"], params))
    for index, entry in state["state"].items():
        if index not in by_index or not isinstance(entry, dict):
            raise unfit(path, f"its optimizer holds a state for parameter {str(index)[:20]!r}, which "
                                  "its groups do not list; the checkpoint is damaged or was edited")
        check_entry(entry, by_index[index], f"{path} does not fit this run: optimizer state of parameter {index}")


def check_group(group: dict, path: Path | str) -> None:
    """A parameter group's settings: finite numbers (lr, eps, weight decay ≥ 0) and two betas in [0, 1)."""
    for key in NUMBERS:
        value = group.get(key, 0.0)
        if isinstance(value, torch.Tensor) and value.numel() == 1:
            value = value.item()
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
            raise unfit(path, f"its optimizer's {key} is {str(value)[:40]!r}, not a finite number ≥ 0; "
                                  "the checkpoint is damaged or was edited")
    betas = group.get("betas", (0.9, 0.999))
    if not (isinstance(betas, (list, tuple)) and len(betas) == 2
            and all(isinstance(b, (int, float)) and not isinstance(b, bool) and 0 <= b < 1 for b in betas)):
        raise unfit(path, f"its optimizer's betas are {str(betas)[:40]!r}, not two numbers in [0, 1); "
                              "the checkpoint is damaged or was edited")


def check_entry(entry: dict, param: torch.Tensor, where: str) -> None:
    """One parameter's AdamW state: its step and both moments (see :func:`check_optimizer_fits`)."""
    step = entry.get("step")
    if isinstance(step, torch.Tensor):
        step = step.item() if step.numel() == 1 and not step.is_complex() and step.dtype != torch.bool else None
    if isinstance(step, bool) or not isinstance(step, (int, float)) or not math.isfinite(step) or step < 0:
        raise CheckpointError(f"{where}: its step is {str(entry.get('step'))[:40]!r}, not a finite number ≥ 0")
    unknown = sorted(set(entry) - {"step", *MOMENTS, "max_exp_avg_sq"})
    missing = [k for k in MOMENTS if k not in entry]
    if unknown or missing:
        raise CheckpointError(f"{where}: it holds {sorted(map(str, entry))[:5]}, AdamW's are step and {MOMENTS}")
    for key in (k for k in entry if k != "step"):
        m = entry[key]
        if not isinstance(m, torch.Tensor) or not m.is_floating_point():
            raise CheckpointError(f"{where}: {key} is not a floating-point tensor")
        if tuple(m.shape) != tuple(param.shape):
            raise CheckpointError(f"{where}: {key} has shape {list(m.shape)}, its parameter {list(param.shape)}; the "
                                  "checkpoint is from another model or was edited")
        if any(s == 0 and n > 1 for s, n in zip(m.stride(), m.shape)) or \
                m.numel() * m.element_size() > m.untyped_storage().nbytes():
            raise CheckpointError(f"{where}: {key} is a view repeating stored numbers (stride {list(m.stride())}); "
                                  "an optimizer update cannot write it: the checkpoint was crafted")
        if not bool(torch.isfinite(m).all()):
            raise CheckpointError(f"{where}: {key} holds NaN or infinite values; the run diverged or the "
                                  "checkpoint is damaged: resume from an earlier one or restart it")


__all__ = ["MOMENTS", "NUMBERS", "optimizer_params", "check_optimizer_fits", "check_group", "check_entry", "unfit"]
