"""The torch device a config names: one rule for training, measurement and the benchmarks."""

from __future__ import annotations

import torch

from .errors import ConfigError


def pick_device(name: str, local_rank: int = 0) -> torch.device:
    """'auto' -> the GPU of ``local_rank`` when CUDA is available, else the CPU; any other name as torch reads it.
    A name torch does not know, or a CUDA device on a machine without one, is a ConfigError."""
    if name == "auto":
        return torch.device(f"cuda:{local_rank}" if torch.cuda.is_available() else "cpu")
    try:
        dev = torch.device(name)
    except RuntimeError as e:
        raise ConfigError(f"unknown device {name!r}: use auto, cpu, cuda or cuda:N") from e
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise ConfigError(f"device {name!r} requested but CUDA is not available")
    return dev


__all__ = ["pick_device"]
