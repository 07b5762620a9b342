"""Converted scenes -> one dataset: chunks, actions, contact labels, splits and train-only whitening."""

from __future__ import annotations

import json

import numpy as np

from ...data import Dataset
from ...errors import DataError
from .config import ConvertConfig
from .folders import SceneRef
from .rotations import quat_mul, quat_to_rotvec
from .splits import split_scenes

PROPRIO_COLUMNS = ("tcp_x", "tcp_y", "tcp_z", "quat_w", "quat_x", "quat_y", "quat_z", "gripper_width")
TOUCH_COLUMNS = ("force_x", "force_y", "force_z", "torque_x", "torque_y", "torque_z")
ACTION_COLUMNS = ("d_tcp_x", "d_tcp_y", "d_tcp_z", "d_rot_x", "d_rot_y", "d_rot_z", "d_gripper_width")


def tcp_actions(quat: np.ndarray, pos: np.ndarray, grip: np.ndarray) -> np.ndarray:
    """(N,) poses -> (N-1, 7) actions: position delta, base-frame rotation vector of q_{t+1} q_t^*, gripper delta."""
    conj = quat[:-1] * np.array([1, -1, -1, -1])
    drot = quat_to_rotvec(quat_mul(quat[1:], conj))
    return np.concatenate([pos[1:] - pos[:-1], drot, grip[1:] - grip[:-1]], axis=1)


def contact_onset(force_norm: np.ndarray, threshold: float, horizon: int) -> tuple[np.ndarray, np.ndarray]:
    """(contact, onset) for one scene: contact_t = |F_t| > thr; onset_t = not contact_t and any contact in t+1..t+h."""
    contact = force_norm > threshold
    n = len(contact)
    future = np.zeros(n, bool)
    for k in range(1, horizon + 1):
        future[: n - k] |= contact[k:]
    return contact.astype(np.float32), (~contact & future).astype(np.float32)


def robust_whiten_stats(x: np.ndarray, percentiles: tuple[float, float]) -> dict[str, list[float]]:
    """Per-column clip bounds (percentiles of ``x``) and mean/std of the clipped ``x``; x is (N, D)."""
    lo, hi = np.percentile(x, percentiles, axis=0)
    xc = np.clip(x, lo, hi)
    mean, std = xc.mean(0), xc.std(0)
    std = np.where(std > 1e-8, std, 1.0)  # constant column: centre only
    return {"lo": lo.tolist(), "hi": hi.tolist(), "mean": mean.tolist(), "std": std.tolist()}


def apply_whiten(x: np.ndarray, st: dict[str, list[float]]) -> np.ndarray:
    lo, hi, mean, std = (np.asarray(st[k], np.float64) for k in ("lo", "hi", "mean", "std"))
    return ((np.clip(x, lo, hi) - mean) / std).astype(np.float32)


def assemble(scenes: list[tuple[SceneRef, dict]], cfg: ConvertConfig) -> tuple[Dataset | None, list[dict], dict]:
    """Chunk converted scenes, split, preprocess; returns (dataset or None, extra skip records, info)."""
    T1 = cfg.episode_steps + 1
    stride = cfg.chunk_stride or T1
    skips, kept = [], []
    for ref, a in scenes:
        if len(a["t_s"]) < T1:
            skips.append({"scene": ref.name, "path": str(ref.path), "reason": "too_short",
                          "message": f"{len(a['t_s'])} grid steps < episode_steps + 1 = {T1}"})
        else:
            kept.append((ref, a))
    if not kept:
        return None, skips, {}
    tasks = np.array([r.task for r, _ in kept])
    scene_split, held = split_scenes(tasks, cfg)
    if not (scene_split == 0).any():
        raise DataError("no scene landed in the train split (too few scenes / tasks for the requested held-out "
                        "tasks); cannot compute train-only normalisation statistics")
    cols: dict[str, list] = {k: [] for k in ("frames", "proprio", "touch", "actions", "split")}
    lab: dict[str, list] = {k: [] for k in ("force", "torque", "force_norm", "contact", "contact_onset", "tcp_pos",
                                            "tcp_quat", "gripper_width", "time_s")}
    par: dict[str, list] = {k: [] for k in ("task_id", "user_id", "scene_id", "cfg_id", "rating", "scene_index",
                                            "chunk_index", "t_start_s")}
    scene_rows, dropped_tail, onset_scene = [], 0, []
    for si, ((ref, a), sp) in enumerate(zip(kept, scene_split)):
        n = len(a["t_s"])
        fn = np.linalg.norm(a["ft"][:, :3], axis=1)
        contact, onset = contact_onset(fn, cfg.onset_threshold_n, cfg.onset_horizon)
        onset_scene.append(onset)
        proprio = np.concatenate([a["pos"], a["quat"], a["grip"][:, None]], 1)
        actions = tcp_actions(a["quat"], a["pos"], a["grip"][:, None])
        starts = list(range(0, n - T1 + 1, stride))
        dropped_tail += n - (starts[-1] + T1)
        for ci, s in enumerate(starts):
            sl = slice(s, s + T1)
            cols["frames"].append(a["frames"][sl])
            cols["proprio"].append(proprio[sl])
            cols["touch"].append(a["ft"][sl])
            cols["actions"].append(actions[s: s + T1 - 1])
            cols["split"].append(sp)
            for k, v in (("force", a["ft"][sl, :3]), ("torque", a["ft"][sl, 3:]), ("force_norm", fn[sl]),
                         ("contact", contact[sl]), ("contact_onset", onset[sl]), ("tcp_pos", a["pos"][sl]),
                         ("tcp_quat", a["quat"][sl]), ("gripper_width", a["grip"][sl]), ("time_s", a["t_s"][sl])):
                lab[k].append(v)
            for k, v in (("task_id", ref.task), ("user_id", ref.user), ("scene_id", ref.scene), ("cfg_id", ref.cfg),
                         ("rating", float(a["rating"])), ("scene_index", si), ("chunk_index", ci),
                         ("t_start_s", a["t_s"][s])):
                par[k].append(v)
        extra = json.loads(str(a["info"])) if "info" in a else {}
        scene_rows.append({"name": ref.name, "path": str(ref.path), "task": ref.task, "user": ref.user,
                           "scene": ref.scene, "rating": int(a["rating"]), "serials": str(a["serials"]).split(","),
                           "cameras": extra.get("cameras", []), "ft_source": extra.get("ft_source", "base"),
                           "dropped_records": extra.get("dropped_records", {}),
                           "start_ms": int(a["t0_ms"]), "grid_steps": n, "chunks": len(starts),
                           "split": int(sp)})
    split = np.asarray(cols["split"], np.int8)
    raw = {k: np.stack(cols[k]).astype(np.float64) for k in ("proprio", "touch", "actions")}
    train = split == 0
    stats = {k: robust_whiten_stats(v[train].reshape(-1, v.shape[-1]), cfg.clip_percentiles) for k, v in raw.items()}
    ds = Dataset(
        frames=np.stack(cols["frames"]).astype(np.uint8),
        proprio=apply_whiten(raw["proprio"], stats["proprio"]),
        touch=apply_whiten(raw["touch"], stats["touch"]),
        actions=apply_whiten(raw["actions"], stats["actions"]),
        labels={k: np.stack(v).astype(np.float32) for k, v in lab.items()},
        params={k: np.asarray(v, np.float32) for k, v in par.items()},
        split=split,
    )
    onset_all = np.concatenate(onset_scene)
    info = {"scenes": scene_rows, "heldout_tasks": held, "normalization": stats, "dropped_tail_steps": dropped_tail,
            "onset_base_rate": float(onset_all.mean()),
            "chunk_stride": stride}
    return ds, skips, info
