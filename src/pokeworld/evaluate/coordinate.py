"""The coordinate test (paper §4.5, App. C): a sensed log-speed channel that makes drag's trace linear.

:func:`build_flow_corpus` derives the ``flow`` corpus from a simulator store: it trains the self-supervised
flow sensor (:mod:`pokeworld.models.flow`) on the store's train-split frames (no labels), freezes it, and
appends three channels to every observation's proprioception — the object's sensed velocity (vx, vy; arena
units / s, from frames t-1 and t) and its log speed. Everything else (frames, touch, actions, labels,
parameters, splits) is the source's, so a model trained on it differs from one trained on the source only by
the extra input channel. Appending to proprioception needs no model change: the encoder reads the proprio
width from the data. The price, recorded in docs/design.md, is that variants with a proprio target (VFX)
also forecast the three channels.

The map's ``coordinate`` experiment trains VFX on ``flow`` beside the factorial's VFX and reports the linear
γ certificate on log-speed sequences over glide windows (``certify``'s ``linear_logspeed`` estimator), the
glide-window γ readout, the velocity readout and the functional glide test, before and after.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..config import to_dict
from ..data import Dataset, is_complete, load, save
from ..errors import ConfigError, DataError
from ..models.flow import FlowConfig, log_speed, object_flow, save_flow, train_flow
from ..regressors import r2_scores
from ..windows import glide_frames

CHANNELS = ("finger_x", "finger_y", "finger_vx", "finger_vy", "flow_vx", "flow_vy", "log_speed")
"""Proprio channels of the flow corpus: the source's four, then the sensor's three."""


def _key(src: Dataset, cfg: FlowConfig) -> dict:
    return {"source_sha256": src.manifest.get("content_sha256"), "flow": to_dict(cfg)}


def sensor_quality(ds: Dataset, velocity: np.ndarray, episodes: np.ndarray) -> dict:
    """How well the frozen sensor reads the object's velocity on ``episodes`` (labels used to score only).

    R^2 of the sensed velocity against ``labels/object_vel`` over all observations after the first and over
    glide frames, and of the sensed log speed against the true one on glide frames.
    """
    if "object_vel" not in ds.labels:
        return {}
    true, est = ds.labels["object_vel"][episodes, 1:], velocity[episodes, 1:]
    glide = glide_frames(ds)[episodes, 1:]
    out = {"velocity_r2": float(np.mean(r2_scores(true.reshape(-1, 2), est.reshape(-1, 2))))}
    if glide.sum() > 10:
        out["glide_velocity_r2"] = float(np.mean(r2_scores(true[glide], est[glide])))
        out["glide_log_speed_r2"] = float(r2_scores(log_speed(true[glide])[:, None], log_speed(est[glide])[:, None])[0])
    return out


def flow_dataset(src: Dataset, cfg: FlowConfig, log_every: int = 0) -> tuple[Dataset, object]:
    """The derived dataset (proprio extended by the sensor's channels) and the frozen sensor."""
    if src.proprio.shape[-1] != 4:
        raise DataError(f"the flow corpus derives from a 4-d proprio store, got {src.proprio.shape[-1]}-d")
    phys = src.manifest.get("config", {}).get("physics", {})
    net = train_flow(src.frames[src.episodes("train")], cfg, log_every)
    vel = object_flow(net, src.frames, src.proprio[..., 0:2], phys.get("finger_radius", 0.06),
                      phys.get("arena", 1.0), phys.get("dt", 0.05))
    proprio = np.concatenate([src.proprio, vel, log_speed(vel)[..., None]], -1).astype(np.float32)
    manifest = {k: v for k, v in src.manifest.items() if k not in ("content_sha256", "stats")}
    manifest.update(corpus="flow", proprio_channels=list(CHANNELS),
                    flow={**_key(src, cfg), "sensor": sensor_quality(src, vel, src.episodes("probe_test"))})
    ds = Dataset(frames=src.frames, proprio=proprio, touch=src.touch, actions=src.actions, labels=src.labels,
                 params=src.params, split=src.split, manifest=manifest)
    return ds, net


def build_flow_corpus(source: str | Path, out: str | Path, cfg: FlowConfig, overwrite: bool = False) -> Path:
    """Write the ``flow`` corpus derived from the store at ``source`` to ``out`` (and the frozen sensor to
    ``out/flow_sensor.pt``); skipped when ``out`` already holds it for the same source and sensor config."""
    out = Path(out)
    src = load(source)
    if is_complete(out) and not overwrite:
        prev = json.loads((out / "manifest.json").read_text())
        if {k: prev.get("flow", {}).get(k) for k in ("source_sha256", "flow")} == _key(src, cfg):
            print(f"[flow] {out} already holds this flow corpus; skipping")
            return out
        raise ConfigError(f"{out} holds a different store; pass overwrite or choose another directory")
    ds, net = flow_dataset(src, cfg, log_every=max(1, cfg.steps // 5))
    save(ds, out)
    save_flow(net, out / "flow_sensor.pt", ds.manifest["flow"])
    s = ds.manifest["flow"]["sensor"]
    print(f"[flow] wrote {out}: sensed velocity R² {s.get('velocity_r2', float('nan')):.3f} "
          f"(glide frames {s.get('glide_velocity_r2', float('nan')):.3f}, glide log speed "
          f"{s.get('glide_log_speed_r2', float('nan')):.3f}) on probe-test episodes")
    return out


__all__ = ["CHANNELS", "build_flow_corpus", "flow_dataset", "sensor_quality"]
