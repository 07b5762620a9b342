"""Whether a trained model can take what a command will feed it: a store's streams and the command's options, checked
before any work.

A model's sizes are fixed when it is trained: the frame size it downsamples to (``image_size``), the proprio, touch
and action widths its encoder and heads read, the longest sequence its predictor has positions for (``max_len``)
and the Δ heads it has. A model from someone else's folder, a store of another generator or an option such as
``plan --context 200`` can each ask for more; torch then fails with a shape error only after the encoding, the
random controller or a simulated corpus. :func:`check_model_takes` compares them first and says in one line which
input does not fit and what to do; :func:`checked_model` reads the model (its weights checked by
:func:`pokeworld.rundir.load_model`: kwargs, shapes, finite values) and makes that comparison.
"""

from __future__ import annotations

import os
from pathlib import Path

from .data import STREAMS, Dataset, stream_shapes
from .errors import ConfigError
from .models.xjepa import XJEPA
from .rundir import load_model

#: The per-step width each stream's last axis holds, and the model attribute that must equal it.
STREAM_WIDTHS = {"proprio": "proprio_dim", "touch": "touch_dim", "actions": "action_dim"}


def store_streams(data: str | os.PathLike | Dataset) -> dict[str, tuple[int, ...]]:
    """The shapes of a store's streams: from the file's header for a store folder (no array read), from the arrays
    of an in-memory :class:`~pokeworld.data.Dataset`."""
    if isinstance(data, Dataset):
        return {n: tuple(getattr(data, n).shape) for n in STREAMS}
    return stream_shapes(data)


def check_model_takes(model: XJEPA, streams: dict[str, tuple[int, ...]], where: str | os.PathLike, store: str,
                      sequence: int = 0, option: str = "", horizons: tuple[int, ...] = (),
                      remedy: str = "lower them to fit") -> None:
    """ConfigError, one line naming the model's folder ``where`` and the input, unless ``model`` takes the store's
    frames (at least ``image_size`` pixels a side) and its proprio, touch and action widths, ``sequence``
    observations at once through its predictor (``option``: what asks for them; ``remedy``: what to do when it
    cannot) and has the Δ heads ``horizons``."""
    cfg = model.config
    H, W = streams["frames"][-2:]
    if min(H, W) < cfg["image_size"]:
        raise ConfigError(f"{where}: the model reads frames of {cfg['image_size']}x{cfg['image_size']} pixels "
                          f"(image_size), but {store} holds {H}x{W} frames; it only downsamples: use it on a store "
                          "of its own frame size (the one it was trained on)")
    for stream, attr in STREAM_WIDTHS.items():
        if streams[stream][-1] != cfg[attr]:
            raise ConfigError(f"{where}: the model reads {cfg[attr]} {stream} values a step ({attr}), but {store} "
                              f"holds {streams[stream][-1]}; use it on a store of the generator it was trained on")
    if sequence > cfg["max_len"]:
        raise ConfigError(f"{where}: {option} feed the model {sequence} observations at once, but its predictor "
                          f"takes at most {cfg['max_len']} (its max_len): {remedy}")
    missing = sorted(set(horizons) - set(model.horizons))
    if missing:
        raise ConfigError(f"{where}: this needs the model's Δ={', '.join(map(str, missing))} heads, but it has Δ in "
                          f"{list(model.horizons)}; use a model trained with those horizons")


def checked_model(run_dir: str | os.PathLike, data: str | os.PathLike | Dataset, sequence: int = 0,
                  option: str = "", horizons: tuple[int, ...] = (), device: str = "cpu",
                  remedy: str = "lower them to fit") -> XJEPA:
    """The model of ``run_dir`` (:func:`~pokeworld.rundir.load_model`: its kwargs, shapes and finite weights
    checked) after :func:`check_model_takes` against the store ``data``."""
    model = load_model(run_dir, map_location=device)
    store = "the given store" if isinstance(data, Dataset) else str(Path(data))
    check_model_takes(model, store_streams(data), run_dir, store, sequence, option, horizons, remedy)
    return model


__all__ = ["STREAM_WIDTHS", "store_streams", "check_model_takes", "checked_model"]
