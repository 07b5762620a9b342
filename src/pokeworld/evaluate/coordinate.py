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

import os
from pathlib import Path

import numpy as np

from ..config import to_dict
from ..data import (
    MAX_MANIFEST_BYTES,
    STORE_FILES,
    Dataset,
    check_store_destination,
    is_complete,
    load,
    read_manifest,
    save,
)
from ..errors import ConfigError, DataError
from ..io import OwnedDir, check_writable_dir, read_json, remove_own_file
from ..models.flow import FlowConfig, log_speed, object_flow, save_flow, train_flow
from ..regressors import r2_scores
from ..windows import glide_frames

CHANNELS = ("finger_x", "finger_y", "finger_vx", "finger_vy", "flow_vx", "flow_vy", "log_speed")
"""Proprio channels of the flow corpus: the source's four, then the sensor's three."""
VELOCITY_CHANNELS = CHANNELS[:6]
"""Proprio channels of the ``flow_velocity`` corpus: the flow corpus's without the log speed (the γ ledger's "frozen
flow velocity sensor", where the coordinate test adds the log-speed coordinate)."""


def _verify_flow_corpus(out: Path) -> None:
    """What :func:`~pokeworld.data.save` verifies of a store folder before replacing it: data only beside a
    manifest that parses."""
    if not os.path.lexists(out / "manifest.json"):
        if os.path.lexists(out / "data.h5"):
            raise ConfigError(f"{out} holds data.h5 without manifest.json, so pokeworld cannot tell that it wrote it; "
                              "move or delete it yourself, or choose another folder")
        return
    try:
        read_json(out / "manifest.json", "a store manifest", dict, MAX_MANIFEST_BYTES)
    except DataError as e:
        raise ConfigError(f"{out} cannot be verified as a pokeworld store ({e}); pokeworld replaces only stores it "
                          "can verify: move or delete it yourself, or choose another folder") from None


FLOW_CORPUS = OwnedDir(
    files=(*STORE_FILES, r"flow_sensor\.pt"),
    # certify's certificate corpora, as a store folder holds them (pokeworld.certificate_corpus.FOLDER)
    dirs=(("certificate_corpus", OwnedDir(files=(r"\.n\d+\.lock",), dirs=((r"n\d+", OwnedDir(files=STORE_FILES)),))),),
    verify=_verify_flow_corpus)
"""What a flow corpus folder holds: a store (its files, certificate corpora, a manifest that parses) and the
frozen sensor beside it."""


def _key(source_manifest: dict, cfg: FlowConfig) -> dict:
    return {"source_sha256": source_manifest.get("content_sha256"), "flow": to_dict(cfg)}


def check_flow_destination(out: Path) -> None:
    """Raise ConfigError, before the source is read or the sensor trained, unless the flow corpus may be written at
    ``out``: absent, an empty folder or one holding only a flow corpus's files (:data:`FLOW_CORPUS`), in a
    writable folder. Links, files and any other folder are refused, as :func:`~pokeworld.data.save` would refuse
    them after the whole computation."""
    check_store_destination(out, None, owned=FLOW_CORPUS, what="flow corpus path")
    check_writable_dir(out.parent)


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
                    flow={**_key(src.manifest, cfg), "sensor": sensor_quality(src, vel, src.episodes("probe_test"))})
    ds = Dataset(frames=src.frames, proprio=proprio, touch=src.touch, actions=src.actions, labels=src.labels,
                 params=src.params, split=src.split, manifest=manifest)
    return ds, net


def velocity_only(flow_ds: Dataset) -> Dataset:
    """The ``flow_velocity`` corpus of a flow corpus: the same episodes and frozen sensor's velocity, without the
    log-speed channel, so the two runs differ by the log-speed coordinate alone."""
    names = flow_ds.manifest.get("proprio_channels")
    if tuple(names or ()) != CHANNELS:
        raise DataError(f"the flow_velocity corpus derives from a flow corpus (proprio channels {list(CHANNELS)}), "
                        f"got {names}")
    manifest = {k: v for k, v in flow_ds.manifest.items() if k not in ("content_sha256", "stats")}
    manifest.update(corpus="flow_velocity", proprio_channels=list(VELOCITY_CHANNELS),
                    flow={**flow_ds.manifest.get("flow", {}), "flow_sha256": flow_ds.manifest.get("content_sha256")})
    return Dataset(frames=flow_ds.frames, proprio=np.ascontiguousarray(flow_ds.proprio[..., :len(VELOCITY_CHANNELS)]),
                   touch=flow_ds.touch, actions=flow_ds.actions, labels=flow_ds.labels, params=flow_ds.params,
                   split=flow_ds.split, manifest=manifest)


def build_flow_velocity_corpus(flow_dir: str | Path, out: str | Path) -> Path:
    """Write the ``flow_velocity`` corpus (:func:`velocity_only`) of the flow corpus at ``flow_dir`` to ``out``;
    skipped when ``out`` already holds it for that flow corpus (its content hash), refused when it holds another."""
    out = Path(out)
    check_flow_destination(out)
    source_hash = read_manifest(flow_dir).get("content_sha256")
    if is_complete(out):
        prev = read_manifest(out).get("flow")
        if isinstance(prev, dict) and prev.get("flow_sha256") == source_hash:
            print(f"[flow] {out} already holds the velocity-only corpus of {flow_dir}; skipping")
            return out
        raise ConfigError(f"{out} holds a different store; move it away or choose another directory")
    save(velocity_only(load(flow_dir)), out)
    print(f"[flow] wrote {out}: the flow corpus's velocity channels without the log speed")
    return out


def build_flow_corpus(source: str | Path, out: str | Path, cfg: FlowConfig, overwrite: bool = False) -> Path:
    """Write the ``flow`` corpus derived from the store at ``source`` to ``out`` (and the frozen sensor to
    ``out/flow_sensor.pt``); skipped when ``out`` already holds it for the same source and sensor config."""
    out = Path(out)
    check_flow_destination(out)
    if is_complete(out) and not overwrite:  # decided from the two manifests, before the source is loaded
        prev = read_manifest(out).get("flow")
        prev = prev if isinstance(prev, dict) else {}
        if {k: prev.get(k) for k in ("source_sha256", "flow")} == _key(read_manifest(source), cfg):
            print(f"[flow] {out} already holds this flow corpus; skipping")
            return out
        raise ConfigError(f"{out} holds a different store; pass overwrite or choose another directory")
    src = load(source)
    ds, net = flow_dataset(src, cfg, log_every=max(1, cfg.steps // 5))
    remove_own_file(out / "flow_sensor.pt")  # checked as ours above; save replaces only a folder holding a store
    save(ds, out)
    save_flow(net, out / "flow_sensor.pt", ds.manifest["flow"])
    s = ds.manifest["flow"]["sensor"]
    print(f"[flow] wrote {out}: sensed velocity R² {s.get('velocity_r2', float('nan')):.3f} "
          f"(glide frames {s.get('glide_velocity_r2', float('nan')):.3f}, glide log speed "
          f"{s.get('glide_log_speed_r2', float('nan')):.3f}) on probe-test episodes")
    return out


__all__ = ["CHANNELS", "VELOCITY_CHANNELS", "FLOW_CORPUS", "build_flow_corpus", "build_flow_velocity_corpus",
           "velocity_only", "check_flow_destination", "flow_dataset", "sensor_quality"]
