"""The ``rh20t-convert`` run: scan, subset, convert (cached) and assemble scenes, then write the store and
its ``conversion_report.json``."""

from __future__ import annotations

import json
import os
from pathlib import Path

from tqdm.auto import tqdm

from ... import __version__
from ...data import Dataset, check_store_destination, save, store_is_current, store_lock
from ...errors import ConfigError, DataError
from ...io import check_owned_dir, check_writable_dir, remove_owned_dir, write_json
from ..npy_child import close_child
from ..regular_files import read_regular
from .assembly import ACTION_COLUMNS, PROPRIO_COLUMNS, TOUCH_COLUMNS, assemble
from .cache import PIPELINE_VERSION, SCENE_CACHE, cache_dir, convert_scene_cached
from .config import ConvertConfig, content_config, out_dir
from .folders import SceneRef, check_scene_name, scan
from .format import ROBOTS
from .skips import SKIP_REASONS, SceneSkip
from .splits import stratified_subset


def corpus_source(root: str | os.PathLike, cfg_id: int) -> dict:
    """Where the scenes under ``root`` come from: a corpus written by ``pokeworld rh20t-synth`` keeps its
    ground truth in ``<corpus>/truth/manifest.json`` beside ``RH20T_cfgN/``; anything else is taken as recorded
    RH20T data. The store carries this so that every report on it can say which of the two it measured."""
    root = Path(root)
    corpus = root.parent if root.name == f"RH20T_cfg{cfg_id}" else root
    man_path = corpus / "truth" / "manifest.json"
    try:  # a regular file only: a FIFO planted here would hang the conversion
        man = json.loads(read_regular(man_path, max_bytes=64 << 20))
    except (OSError, ValueError):
        return {"synthetic": False}
    if not isinstance(man, dict) or man.get("generator") != "pokeworld.real.synthetic":
        return {"synthetic": False}
    return {"synthetic": True, "generator": man["generator"], "generator_version": man.get("version"),
            "seed": man.get("seed"), "truth": str(man_path)}


def _name_checked(refs: list[SceneRef], cfg: ConvertConfig) -> tuple[list[SceneRef], list[dict]]:
    """(candidates, skip records): the folder-name skips (human demos, other / unknown cfg) are decided before
    subsetting, so ``max_scenes`` draws among candidates only."""
    candidates, skips = [], []
    for ref in refs:
        try:
            check_scene_name(ref, cfg)
            candidates.append(ref)
        except SceneSkip as e:
            skips.append({"scene": ref.name, "path": str(ref.path), "reason": e.reason, "message": e.message})
    return candidates, skips


def _subset_record(candidates: list[SceneRef], chosen: list[SceneRef], cfg: ConvertConfig) -> dict | None:
    """What a ``max_scenes`` draw took, per task and by name (``None`` without ``max_scenes``)."""
    if not cfg.max_scenes:
        return None
    per_task: dict[int, list[int]] = {}
    for r in candidates:
        per_task.setdefault(r.task, [0, 0])[0] += 1
    for r in chosen:
        per_task[r.task][1] += 1
    return {"max_scenes": cfg.max_scenes, "subset_seed": cfg.subset_seed, "candidates": len(candidates),
            "sampled": len(chosen), "stratified_by": "task",
            "per_task": {str(t): {"candidates": c, "sampled": k} for t, (c, k) in sorted(per_task.items())},
            "scenes": [r.name for r in chosen]}


def _convert_scenes(chosen: list[SceneRef], cfg: ConvertConfig,
                    cdir: Path) -> tuple[list[tuple[SceneRef, dict]], list[dict]]:
    """(converted (scene, arrays) pairs, skip records) for the chosen scenes, each through the scene cache."""
    converted: list[tuple[SceneRef, dict]] = []
    skips: list[dict] = []
    try:
        for ref in tqdm(chosen, desc=f"rh20t cfg{cfg.cfg}", unit="scene", disable=not cfg.progress):
            arrays, skip = convert_scene_cached(ref, cfg, cdir)
            if arrays is not None:
                converted.append((ref, arrays))
            else:
                skips.append(skip)
    finally:
        close_child()  # the child that unpickled this conversion's files
    return converted, skips


def _scene_tallies(rows: list[dict]) -> tuple[dict[str, dict[str, int]], dict[str, dict[str, int]], dict[str, int]]:
    """Over the converted scenes' rows: serials used per camera role, dropped records per stream and kind, and
    scenes per F/T source."""
    camera_counts: dict[str, dict[str, int]] = {}
    dropped_total: dict[str, dict[str, int]] = {}
    ft_sources: dict[str, int] = {}
    for r in rows:
        for c in r["cameras"]:
            per = camera_counts.setdefault(c["role"], {})
            per[c["serial"]] = per.get(c["serial"], 0) + 1
        for stream, kinds in r["dropped_records"].items():
            for k, v in kinds.items():
                dropped_total.setdefault(stream, {})[k] = dropped_total.setdefault(stream, {}).get(k, 0) + v
        ft_sources[r["ft_source"]] = ft_sources.get(r["ft_source"], 0) + 1
    return camera_counts, dropped_total, ft_sources


def _conversion_report(cfg: ConvertConfig, root: Path, *, found: int, candidates: int, chosen: int,
                       subset: dict | None, skips: list[dict], ds: Dataset | None, info: dict, cdir: Path) -> dict:
    """``conversion_report.json`` (before the store's split counts and content hash are known)."""
    counts: dict[str, int] = {}
    for s in skips:
        counts[s["reason"]] = counts.get(s["reason"], 0) + 1
    rows = info.get("scenes", [])
    camera_counts, dropped_total, ft_sources = _scene_tallies(rows)
    return {
        "root": str(cfg.root), "cfg": cfg.cfg, "robot": ROBOTS[cfg.cfg], "camera": cfg.camera,
        "source": corpus_source(root, cfg.cfg), "scenes_found": found, "scenes_candidate": candidates,
        "scenes_sampled": chosen,
        "subset": subset, "scenes_converted": len(rows),
        "camera_counts": {role: dict(sorted(v.items())) for role, v in sorted(camera_counts.items())},
        "camera_fallback_scenes": sum(any(c["fallback"] for c in r["cameras"]) for r in rows),
        "camera_other_external_scenes": sum(any(c.get("fallback_kind") == "other_external" for c in r["cameras"])
                                            for r in rows),
        "ft_source_counts": dict(sorted(ft_sources.items())),
        "scenes_with_dropped_records": sum(bool(r["dropped_records"]) for r in rows),
        "dropped_records": {k: dict(sorted(v.items())) for k, v in sorted(dropped_total.items())},
        "scenes_skipped": len(skips), "skip_counts": dict(sorted(counts.items())),
        "skip_reason_meaning": {k: SKIP_REASONS[k] for k in sorted(counts)},
        "skipped": skips, "episodes": 0 if ds is None else ds.num_episodes,
        "dropped_tail_steps": info.get("dropped_tail_steps", 0), "cache": str(cdir),
    }


def _store_manifest(cfg: ConvertConfig, info: dict, report: dict, subset: dict | None) -> dict:
    """The store's manifest: provenance, column names, normalisation and label notes, and the report's counts."""
    return {
        "generator": "pokeworld.real.rh20t", "version": __version__, "pipeline_version": PIPELINE_VERSION,
        "kind": "rh20t", "seed": cfg.seed, "config": content_config(cfg), "robot": ROBOTS[cfg.cfg],
        "hz": cfg.hz, "columns": {"proprio": list(PROPRIO_COLUMNS), "touch": list(TOUCH_COLUMNS),
                                  "actions": list(ACTION_COLUMNS)},
        "normalization": info["normalization"],
        "normalization_note": "proprio/touch/actions = (clip(x, lo, hi) - mean) / std; lo/hi = "
                              f"{list(cfg.clip_percentiles)} percentiles, all statistics from split 0 (train) only",
        "labels_note": "force/torque: zeroed base-frame F/T [N, N m], raw; contact: |F| > "
                       f"{cfg.onset_threshold_n} N; contact_onset: no contact at t and contact within the next "
                       f"{cfg.onset_horizon} steps (computed on the whole scene before chunking); tcp_pos [m]; "
                       "tcp_quat (w,x,y,z); gripper_width [m]; time_s since scene start",
        "heldout_tasks": info["heldout_tasks"], "onset_base_rate": info["onset_base_rate"],
        "chunk_stride": info["chunk_stride"], "scenes": info["scenes"],
        "skip_counts": report["skip_counts"], "camera_counts": report["camera_counts"],
        "ft_source_counts": report["ft_source_counts"], "dropped_records": report["dropped_records"],
        "subset": subset, "source": report["source"],
    }


def run(cfg: ConvertConfig) -> Path:
    """Convert ``cfg.root`` into a store at ``out_dir(cfg)``; write ``conversion_report.json`` inside it.

    Re-running with the same config returns the existing store; an interrupted run resumes from the
    per-scene cache. Raises :class:`DataError` if no scene could be converted (the report is still written).
    Before any scene is read, the output must be free or hold a pokeworld RH20T store, its folder writable, and
    no other writer at work on it (:func:`~pokeworld.data.store_lock`, held to the end).
    """
    if not cfg.root:
        raise ConfigError("root is required: the RH20T folder (RH20T_cfgN or its parent)")
    out = out_dir(cfg)
    check_store_destination(out, "rh20t")
    check_writable_dir(out.parent)
    with store_lock(out):
        return _convert_into(cfg, out)


def _convert_into(cfg: ConvertConfig, out: Path) -> Path:
    """:func:`run` under the store lock: keep an intact identical store, else convert and write it at ``out``."""
    report_path = out / "conversion_report.json"
    if store_is_current(out, content_config(cfg), cfg.overwrite):
        print(f"[rh20t] {out} already holds this conversion; skipping")
        return out
    cdir = cache_dir(cfg)
    if cfg.overwrite and cdir.exists():  # only the cache entries pokeworld wrote, checked first
        check_owned_dir(cdir, SCENE_CACHE)
        remove_owned_dir(cdir, SCENE_CACHE)
    cdir.mkdir(parents=True, exist_ok=True)
    root = Path(cfg.root)
    refs = scan(root / f"RH20T_cfg{cfg.cfg}" if (root / f"RH20T_cfg{cfg.cfg}").is_dir() else root)
    candidates, name_skips = _name_checked(refs, cfg)
    chosen = stratified_subset(candidates, cfg.max_scenes, cfg.subset_seed)
    subset = _subset_record(candidates, chosen, cfg)
    converted, scene_skips = _convert_scenes(chosen, cfg, cdir)
    ds, more_skips, info = assemble(converted, cfg)
    skips = name_skips + scene_skips + more_skips
    report = _conversion_report(cfg, root, found=len(refs), candidates=len(candidates), chosen=len(chosen),
                                subset=subset, skips=skips, ds=ds, info=info, cdir=cdir)
    if ds is None:
        out.mkdir(parents=True, exist_ok=True)
        write_json(report_path, report)
        raise DataError(f"no RH20T cfg{cfg.cfg} scene under {cfg.root} could be converted "
                        f"(skips: {report['skip_counts'] or 'no scene folders found'}); see {report_path}")
    save(ds, out, _store_manifest(cfg, info, report, subset))
    report["split_counts"] = ds.manifest["split_counts"]
    report["content_sha256"] = ds.manifest["content_sha256"]
    write_json(report_path, report)
    print(f"[rh20t] wrote {ds.num_episodes} episodes from {len(info['scenes'])} scenes to {out} "
          f"({report['scenes_skipped']} scenes skipped: {report['skip_counts']}; cameras {report['camera_counts']}; "
          f"{report['scenes_with_dropped_records']} scenes with dropped records: {report['dropped_records']})")
    return out
