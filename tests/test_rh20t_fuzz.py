"""Property-based corruption of RH20T fixture scenes: the converter never crashes, repairs (and counts) or skips
every corrupted scene with a specific reason, and leaves untouched scenes byte-identical.

Cheap by construction: the fixture corpus and each scene's uncorrupted conversion are built once per module;
an example copies only the scene it corrupts (plus the calibration folder) and converts it through
``convert_scene_cached`` (the per-scene path ``run`` uses); a few whole-run examples corrupt scenes of a copied
corpus and check the report and the untouched scenes' cached arrays. Deterministic (``derandomize``) for CI.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, Phase, event, given, settings, strategies as st
from rh20t_hostile import MEMORY_PRIMITIVES, planted_npy, png_header_only, shared_reference_bomb

from pokeworld.errors import DataError
from pokeworld.real import rh20t
from pokeworld.real.fixtures import make_fixture_root, save_dict
from pokeworld.real.safe_pickle import load_npy_item


def replace_dict(path, obj) -> None:
    """Replace a file of this test's own fixture copy (save_dict writes only new files)."""
    path.unlink(missing_ok=True)
    save_dict(path, obj)


ROLES = rh20t.CAMERA_ROLES[7]
FAR, CLOSE = ROLES["far"][0], ROLES["close"][0]
N_TASKS, SCENES_PER_TASK = 3, 2
CAMERAS = ("far", "two_view")
MARKER = "fuzz_payload_ran"


class Payload:
    """Writes a marker file beside the scene if unpickled by an unrestricted loader."""

    def __init__(self, marker: Path):
        self.marker = str(marker)

    def __reduce__(self):
        return os.system, (f"touch {self.marker}",)


def _ref(scene_dir: Path) -> rh20t.SceneRef:
    ref = rh20t.parse_scene_name(scene_dir.name)
    ref.path = scene_dir
    return ref


def _save_object(path: Path, obj) -> None:
    """np.save a python object the way RH20T stores one: a 0-d object array (a list would become an array)."""
    if isinstance(obj, np.ndarray):
        np.save(path, obj)
        return
    arr = np.empty((), object)
    arr[()] = obj
    np.save(path, arr, allow_pickle=True)


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    base = tmp_path_factory.mktemp("fuzz")
    fx = make_fixture_root(base / "raw", cfg=7, n_tasks=N_TASKS, scenes_per_task=SCENES_PER_TASK, defects=(),
                           duration_s=3.0)
    cfg_dir = fx["cfg_dir"]
    calib = next((cfg_dir / "calib").iterdir())
    names = sorted(fx["good"])
    baseline = {}
    for cam in CAMERAS:
        cfg = rh20t.make_config("tiny", root=str(base / "raw"), camera=cam)
        for name in names:
            baseline[cam, name] = rh20t.process_scene(_ref(cfg_dir / name), cfg)
    return Corpus(base=base, cfg_dir=cfg_dir, calib=calib, names=names, baseline=baseline,
                  video={n: fx["good"][n]["video"] for n in names})


class Corpus(dict):
    """The module's fixture corpus; a short repr keeps hypothesis' failure reports readable."""

    def __init__(self, **kw):
        super().__init__(**kw)

    def __repr__(self) -> str:
        return f"Corpus({self['cfg_dir']})"


# ----------------------------------------------------------------------------------- mutations
# A mutation is (kind, *params) drawn by hypothesis. apply() returns its tag and the skip reasons it may cause:
#   "same"       the converter must give byte-identical arrays (the change is normalised away: record order,
#                exact duplicate records, a timestamp given as an equal float or digit string, an unread file);
#   "normalised" a documented rule may change the output without counting it (duplicate timestamps with
#                different values keep the first; dropped frames use the nearest one within frame_tolerance_s;
#                without start/finish_time the grid spans the streams' common span);
#   "defect"     the scene must be skipped with one of the reasons, or converted with the repair counted
#                (dropped_records, a camera fallback, the F/T source), or converted identically (the damage was
#                in a part the converter does not read).

STREAMS = ("tcp_base", "force_torque_base", "gripper")
FILES = ("tcp_base", "force_torque_base", "gripper", "joint", "metadata", "far_timestamps", "far_video",
         "close_timestamps", "close_video", "extrinsics", "calib_tcp")
VALUE_KINDS = ("nan", "inf", "-inf", "1e36", "-9.432e36", "zero")
DTYPE_VARIANTS = ("value_str", "value_none", "value_dict", "ts_digits", "ts_float", "ts_garbage", "ts_none",
                  "ts_nan", "ts_inf", "ts_huge", "records_not_list", "top_list", "top_float_array", "missing_key")
TS_VARIANTS = ("shuffle", "dup_exact", "dup_conflict", "seconds", "shift_day")
CAM_TS_VARIANTS = ("swap", "dup", "drop_last", "append", "no_color_key", "strings")
META_VARIANTS = ("drop_rating", "rating_str", "rating_inf", "rating_none", "rating_list", "rating_low",
                 "rating_digits", "rating_float", "drop_calib", "calib_minus1", "calib_missing_dir", "drop_start",
                 "drop_finish", "start_str", "start_after_finish", "not_dict_list", "not_dict_str", "null",
                 "bad_json", "not_utf8")
CALIB_VARIANTS = ("delete_dir", "delete_extrinsics", "delete_tcp", "drop_anchor", "drop_far", "nan_extrinsics",
                  "huge_extrinsics", "tcp_wrong_size")

ESCAPES = ("outside_copy", "device")
PICKLED = ("tcp_base", "force_torque_base", "gripper", "far_timestamps", "close_timestamps", "extrinsics", "joint")
HOSTILE_PICKLES = (*sorted(MEMORY_PRIMITIVES), "shared_reference_bomb")

mutation = st.one_of(
    st.tuples(st.just("truncate"), st.sampled_from(FILES), st.floats(0, 0.99)),
    st.tuples(st.just("garbage"), st.sampled_from(FILES), st.integers(0, 2**16),
              st.sampled_from((b"", b"\x93NUMPY", b"\xff\xd8\xff", b"\x00\x00\x00\x18ftypisom", b"\x80\x04"))),
    st.tuples(st.just("delete"), st.sampled_from(FILES + ("far_dir", "close_dir"))),
    st.tuples(st.just("values"), st.sampled_from(STREAMS), st.sampled_from(VALUE_KINDS), st.floats(0.01, 1.0),
              st.integers(0, 2**16)),
    st.tuples(st.just("shape"), st.sampled_from(STREAMS), st.sampled_from((0, 1, 5, 8)), st.floats(0.01, 1.0),
              st.integers(0, 2**16)),
    st.tuples(st.just("dtype"), st.sampled_from(STREAMS), st.sampled_from(DTYPE_VARIANTS), st.integers(0, 2**16)),
    st.tuples(st.just("timestamps"), st.sampled_from(STREAMS), st.sampled_from(TS_VARIANTS), st.integers(0, 2**16)),
    st.tuples(st.just("camera_ts"), st.sampled_from(("far", "close")), st.sampled_from(CAM_TS_VARIANTS),
              st.integers(0, 2**16)),
    st.tuples(st.just("metadata"), st.sampled_from(META_VARIANTS)),
    st.tuples(st.just("camera_frame_ft")),
    st.tuples(st.just("calib"), st.sampled_from(CALIB_VARIANTS)),
    st.tuples(st.just("drop_frames"), st.sampled_from(("far", "close")), st.floats(0.05, 1.0), st.integers(0, 2**16)),
    st.tuples(st.just("payload"), st.sampled_from(("tcp_base", "force_torque_base", "gripper", "far_timestamps",
                                                   "extrinsics", "joint"))),
    # untrusted-input cases (issue #40): special files, links out of the tree, huge declared frames, hostile pickles
    st.tuples(st.just("special"), st.sampled_from(FILES)),
    st.tuples(st.just("escape"), st.sampled_from(FILES + ("far_dir", "close_dir")), st.sampled_from(ESCAPES)),
    st.tuples(st.just("calib_value"), st.sampled_from(("../../..", "/etc", "1/../../../..", "../calib/.."))),
    st.tuples(st.just("huge_frame"), st.sampled_from(("far", "close")), st.sampled_from((16384, 8192))),
    st.tuples(st.just("hostile_pickle"), st.sampled_from(PICKLED), st.sampled_from(HOSTILE_PICKLES)),
)

STREAM_REASONS = {"bad_stream", "nan_stream", "zero_tcp", "overflow_stream", "bad_units", "bad_timestamps",
                  "stream_gap", "missing_stream", "camera_frame_ft"}
VIDEO_REASONS = {"empty_video", "unreadable_video", "truncated_video", "frame_count_mismatch", "frame_gap",
                 "bad_timestamps", "bad_stream", "missing_stream"}


def _path(scene: Path, calib: Path, role: str, video: str) -> Path | None:
    """The file a role names in this scene (None: the scene has no such file, e.g. timestamps of a jpg camera)."""
    tr = scene / "transformed"
    if role in ("tcp_base", "gripper", "joint"):
        return tr / f"{role}.npy"
    if role == "force_torque_base":  # after a camera_frame_ft mutation the camera-frame file holds the F/T
        base = tr / "force_torque_base.npy"
        return base if base.exists() or not (tr / "force_torque.npy").exists() else tr / "force_torque.npy"
    if role == "metadata":
        return scene / "metadata.json"
    if role in ("extrinsics", "calib_tcp"):
        return calib / ("extrinsics.npy" if role == "extrinsics" else "tcp.npy")
    cam = scene / f"cam_{FAR if role.startswith('far') else CLOSE}"
    if role.endswith("_dir"):
        return cam
    if role.endswith("_timestamps"):
        return cam / "timestamps.npy" if video == "mp4" else None
    if video == "mp4":
        return cam / "color.mp4"
    jpgs = sorted((cam / "color").glob("*.jpg")) if (cam / "color").is_dir() else []
    return jpgs[len(jpgs) // 2] if jpgs else None


def _file_reasons(role: str) -> set[str]:
    if role == "metadata":
        return {"bad_metadata", "missing_metadata"}
    if role in ("extrinsics", "calib_tcp"):
        return {"camera_frame_ft"}
    if role in ("far_video", "close_video", "far_timestamps", "close_timestamps", "far_dir", "close_dir"):
        return VIDEO_REASONS | {"missing_camera"}
    return STREAM_REASONS


def _load(path: Path | None):
    """A stream / calibration dict to mutate further; None when an earlier mutation already deleted, damaged or
    replaced the file by a payload (then there is nothing left to mutate). Read with the restricted loader so
    that the test itself never unpickles a planted payload."""
    try:
        obj = load_npy_item(path)
    except Exception:
        return None
    return obj if isinstance(obj, dict) else None


def _records(obj: dict) -> list[dict]:
    return [r for items in obj.values() for r in items]


def _regular(path: Path | None) -> bool:
    """A plain file the test may read or write: an earlier mutation may have left a FIFO (opening it would block the
    test itself) or a link out of the tree in its place."""
    return path is not None and path.is_file() and not path.is_symlink()


def apply(m: tuple, scene: Path, calib: Path, video: str) -> tuple[str, set[str]]:
    kind = m[0]
    if kind in ("truncate", "garbage", "delete"):
        path = _path(scene, calib, m[1], video)
        if path is None or not os.path.lexists(path) or (kind != "delete" and not _regular(path)):
            return "same", set()
        if kind == "truncate":
            raw = path.read_bytes()
            path.write_bytes(raw[: int(len(raw) * m[2])])
        elif kind == "garbage":
            rng = np.random.default_rng(m[2])
            path.write_bytes(m[3] + rng.integers(0, 256, int(rng.integers(0, 2000)), dtype=np.uint8).tobytes())
        elif path.is_dir() and not path.is_symlink():
            shutil.rmtree(path)
        else:
            path.unlink()
        if kind == "delete" and path.suffix == ".jpg":  # one extracted frame missing: the nearest other one is used
            return "normalised", {"frame_gap"}
        return ("same" if m[1] == "joint" else "defect"), _file_reasons(m[1])
    if kind in ("values", "shape", "dtype", "timestamps"):
        return _mutate_stream(m, scene, calib, video)
    if kind == "camera_ts":
        return _mutate_camera_ts(m, scene, video)
    if kind == "metadata":
        return _mutate_metadata(m[1], scene, calib)
    if kind == "camera_frame_ft":
        tr = scene / "transformed"
        if (tr / "force_torque_base.npy").exists():
            (tr / "force_torque_base.npy").rename(tr / "force_torque.npy")  # identity extrinsics: same values
        return "defect", {"camera_frame_ft", "missing_stream"}
    if kind == "calib":
        return _mutate_calib(m[1], calib)
    if kind == "drop_frames":
        cam = scene / f"cam_{FAR if m[1] == 'far' else CLOSE}" / "color"
        if video != "jpg" or not cam.is_dir():
            return "same", set()
        jpgs = sorted(cam.glob("*.jpg"))
        rng = np.random.default_rng(m[3])
        for f in rng.permutation(jpgs)[: int(round(m[2] * len(jpgs)))]:
            f.unlink()
        return "normalised", {"frame_gap", "empty_video", "bad_timestamps"}
    if kind in ("special", "escape", "calib_value", "huge_frame", "hostile_pickle"):
        return _untrusted(m, scene, calib, video)
    if kind == "payload":
        path = _path(scene, calib, m[1], video)
        if not _regular(path):
            return "same", set()
        replace_dict(path, {FAR: [Payload(scene.parent / MARKER)]})
        return ("same" if m[1] == "joint" else "defect"), {"unsafe_pickle"}
    raise AssertionError(m)


def _untrusted(m: tuple, scene: Path, calib: Path, video: str) -> tuple[str, set[str]]:
    """A FIFO where a file is expected, a symlink out of the root, a metadata calib leading out, frames declaring a
    huge image, a hostile pickle (a memory primitive, or shared references that expand exponentially)."""
    kind = m[0]
    if kind == "calib_value":
        path = scene / "metadata.json"
        if not _regular(path):
            return "same", set()
        try:
            meta = json.loads(path.read_text())
        except (OSError, ValueError):  # deleted, damaged or already a FIFO
            return "same", set()
        if not isinstance(meta, dict) or "rating" not in meta or "calib" not in meta:
            return "same", set()
        path.write_text(json.dumps({**meta, "calib": m[1]}))
        return "defect", {"outside_root", "bad_metadata", "low_rating"}
    if kind == "huge_frame":
        cam = scene / f"cam_{FAR if m[1] == 'far' else CLOSE}" / "color"
        frames = sorted(cam.glob("*.jpg")) if video == "jpg" and cam.is_dir() else []
        for f in frames:
            f.unlink()
            f.with_suffix(".png").write_bytes(png_header_only(m[2], m[2]))
        return ("defect", {"huge_image"} | VIDEO_REASONS) if frames else ("same", set())
    path = _path(scene, calib, m[1], video)
    if path is None or not os.path.lexists(path):
        return "same", set()
    unread = m[1] == "joint"  # never read by the converter: whatever it holds changes nothing
    if kind == "hostile_pickle":
        if not _regular(path):
            return "same", set()
        ops = shared_reference_bomb() if m[2] == "shared_reference_bomb" else MEMORY_PRIMITIVES[m[2]]
        planted_npy(path, ops)
        return ("same", set()) if unread else ("defect", {"unsafe_pickle", "bad_stream", "camera_frame_ft"})
    if kind == "special":
        if path.is_dir() and not path.is_symlink():
            return "same", set()
        path.unlink()
        os.mkfifo(path)
        return ("same", set()) if unread else ("defect", {"special_file"})
    outside = scene.parents[2] / f"outside_{scene.parents[1].name}_{scene.name}_{m[1]}"  # beside the root
    if m[2] == "device":
        target = Path("/dev/zero")
    elif path.is_symlink() or not (path.is_file() or path.is_dir()):
        return "same", set()
    else:
        (shutil.copytree if path.is_dir() else shutil.copy)(path, outside)
        target = outside
    shutil.rmtree(path) if path.is_dir() and not path.is_symlink() else path.unlink()
    path.symlink_to(target)
    return ("same", set()) if unread else ("defect", {"outside_root"} | _file_reasons(m[1]))


def _mutate_stream(m: tuple, scene: Path, calib: Path, video: str) -> tuple[str, set[str]]:
    kind, stream, variant = m[0], m[1], m[2]
    path = _path(scene, calib, stream, video)
    obj = _load(path)
    key = {"tcp_base": "tcp", "force_torque_base": "zeroed", "gripper": "gripper_info"}[stream]
    if not _well_formed(obj, stream, key):
        return "same", set()  # an earlier mutation already broke its structure
    rng = np.random.default_rng(m[-1])
    if stream == "gripper":  # {serial: {ts: {field: [mm, 0, 0]}}} -> a list view of the same records
        recs = [(s, t, r) for s, per in obj.items() for t, r in per.items()]
    else:
        recs = [(s, None, r) for s in obj for r in obj[s]]

    def pick(frac: float) -> list:
        return [recs[i] for i in rng.permutation(len(recs))[: max(1, int(round(frac * len(recs))))]]

    tag, reasons = "defect", set(STREAM_REASONS)
    if kind == "values":
        if variant == "zero" and stream != "tcp_base":
            return "same", set()  # zero force / a closed gripper are valid readings, not corruption
        value = {"nan": np.nan, "inf": np.inf, "-inf": -np.inf, "1e36": 1e36, "-9.432e36": -9.432e36, "zero": 0.0}
        for _, _, r in pick(m[3]):
            v = np.array(r[key], np.float64)
            if variant == "zero":
                v[:] = 0.0
            else:
                v[rng.integers(0, v.size)] = value[variant]
            r[key] = v if stream != "gripper" else v.tolist()
    elif kind == "shape":
        size = variant
        for _, _, r in pick(m[3]):
            v = np.resize(np.asarray(r[key], np.float64), size)
            r[key] = v if stream != "gripper" else v.tolist()
        if stream == "gripper" and size > 0:  # only element 0 (the width) is read: a longer/shorter list is fine
            tag = "same"
    elif kind == "dtype":
        serial = next(iter(obj))
        if variant in ("top_list", "top_float_array"):
            obj = list(obj.values()) if variant == "top_list" else np.zeros(7)
        elif variant == "records_not_list":
            obj[serial] = "not records" if stream == "gripper" else {"a": 1}
        elif variant.startswith("value_") or variant == "missing_key":
            _, _, r = recs[int(rng.integers(0, len(recs)))]
            if variant == "missing_key":
                del r[key]
            else:
                r[key] = {"value_str": "abc", "value_none": None, "value_dict": {"x": 1}}[variant]
            if variant == "value_none" and stream == "gripper":
                tag = "defect"  # asarray(None, float) is NaN: a dropped, counted record
        else:  # timestamp types
            new = {"ts_digits": str, "ts_float": float, "ts_garbage": lambda t: "not a time", "ts_none": lambda t: None,
                   "ts_nan": lambda t: float("nan"), "ts_inf": lambda t: float("inf"),
                   "ts_huge": lambda t: 10**20}[variant]
            if stream == "gripper":
                s, t, r = recs[int(rng.integers(0, len(recs)))]
                del obj[s][t]
                obj[s][new(t)] = r
            else:
                _, _, r = recs[int(rng.integers(0, len(recs)))]
                r["timestamp"] = new(r["timestamp"])
            if variant in ("ts_digits", "ts_float"):
                tag = "same"
    elif kind == "timestamps":
        if variant == "shuffle":
            tag = "same"
            if stream != "gripper":
                for s in obj:
                    obj[s] = [obj[s][i] for i in rng.permutation(len(obj[s]))]
            else:
                for s in obj:
                    items = list(obj[s].items())
                    obj[s] = dict(items[i] for i in rng.permutation(len(items)))
        elif variant in ("dup_exact", "dup_conflict"):
            tag = "same" if variant == "dup_exact" else "normalised"
            s, t, r = recs[int(rng.integers(0, len(recs)))]
            other = [x for x in obj if x != s][0]
            dup = {k: (np.array(v, np.float64) * (1.0 if variant == "dup_exact" else 1.01) if k == key else v)
                   for k, v in r.items()}
            if stream == "gripper":
                dup[key] = dup[key].tolist()
                obj[other][t] = dup  # the same time logged by the other serial
            else:
                obj[other].append(dup)
        else:
            scale = {"seconds": lambda t: t // 1000, "shift_day": lambda t: t + 86_400_000}[variant]
            for s, t, r in recs:
                if stream == "gripper":
                    obj[s][scale(t)] = obj[s].pop(t)
                else:
                    r["timestamp"] = scale(r["timestamp"])
    _save_object(path, obj)
    return tag, reasons


def _well_formed(obj, stream: str, key: str) -> bool:
    if not isinstance(obj, dict) or len(obj) < 2:
        return False
    if stream == "gripper":
        return all(isinstance(per, dict) and all(isinstance(t, int) and isinstance(r, dict) and
                                                 isinstance(r.get(key), list) for t, r in per.items())
                   for per in obj.values())
    return all(isinstance(items, list) and all(isinstance(r, dict) and isinstance(r.get("timestamp"), int)
                                               and isinstance(r.get(key), np.ndarray) for r in items)
               for items in obj.values())


def _mutate_camera_ts(m: tuple, scene: Path, video: str) -> tuple[str, set[str]]:
    path = scene / f"cam_{FAR if m[1] == 'far' else CLOSE}" / "timestamps.npy"
    obj = _load(path) if video == "mp4" else None
    if obj is None or not isinstance(obj.get("color"), list) or len(obj["color"]) < 3:
        return "same", set()
    ts = list(obj["color"])
    i = int(np.random.default_rng(m[3]).integers(1, len(ts) - 1))
    variant = m[2]
    if variant == "swap":
        ts[i - 1], ts[i] = ts[i], ts[i - 1]
    elif variant == "dup":
        ts.insert(i, ts[i])
    elif variant == "drop_last":
        ts = ts[:-1]
    elif variant == "append":
        ts.append(ts[-1] + 100)
    elif variant == "strings":
        ts[i] = "soon"
    if variant == "no_color_key":
        obj = {"depth": obj["depth"]}
    else:
        obj["color"] = ts
    replace_dict(path, obj)
    return "defect", VIDEO_REASONS


def _mutate_metadata(variant: str, scene: Path, calib: Path) -> tuple[str, set[str]]:
    path = scene / "metadata.json"
    if not _regular(path):
        return "same", set()
    try:
        meta = json.loads(path.read_text())
    except (ValueError, UnicodeDecodeError):
        return "same", set()
    if not isinstance(meta, dict):
        return "same", set()
    tag, reasons = "defect", {"bad_metadata"}
    if variant == "drop_rating":
        meta.pop("rating", None)
    elif variant.startswith("rating_"):
        new = {"rating_str": "five", "rating_inf": float("inf"), "rating_none": None, "rating_list": [5],
               "rating_low": 1, "rating_digits": str(meta.get("rating")), "rating_float": 5.7}[variant]
        if variant in ("rating_digits", "rating_float") and meta.get("rating") != 5:
            return "same", set()
        meta["rating"] = new
        tag = "same" if variant in ("rating_digits", "rating_float") else "defect"
        reasons = {"low_rating"} if variant == "rating_low" else {"bad_metadata"}
    elif variant in ("drop_calib", "calib_minus1"):
        meta.pop("calib", None) if variant == "drop_calib" else meta.update(calib=-1)
        reasons = {"missing_calib"}
    elif variant == "calib_missing_dir":
        meta["calib"] = 1  # a calibration that does not exist: only the camera-frame F/T needs one
        reasons = {"camera_frame_ft"}
    elif variant in ("drop_start", "drop_finish", "start_str"):
        if variant == "start_str":
            meta["start_time"] = "early"
        else:
            meta.pop("start_time" if variant == "drop_start" else "finish_time", None)
        tag, reasons = "normalised", set()
    elif variant == "start_after_finish":
        if "finish_time" not in meta:
            return "same", set()
        meta["start_time"] = meta["finish_time"] + 1000
        reasons = {"bad_timestamps"}
    elif variant in ("not_dict_list", "not_dict_str", "null"):
        meta = {"not_dict_list": [meta], "not_dict_str": "metadata", "null": None}[variant]
    if variant == "bad_json":
        path.write_text(json.dumps(meta)[:-1] + ",}")
    elif variant == "not_utf8":
        path.write_bytes(b"\xff\xfe" + json.dumps(meta).encode("utf-16-le"))
    else:
        path.write_text(json.dumps(meta))
    return tag, reasons


def _mutate_calib(variant: str, calib: Path) -> tuple[str, set[str]]:
    ext, tcp = calib / "extrinsics.npy", calib / "tcp.npy"
    if variant == "delete_dir":
        shutil.rmtree(calib, ignore_errors=True)
    elif variant in ("delete_extrinsics", "delete_tcp"):
        (ext if variant == "delete_extrinsics" else tcp).unlink(missing_ok=True)
    elif variant == "tcp_wrong_size" and (_regular(tcp) or not os.path.lexists(tcp)):
        np.save(tcp, np.zeros(5))
    elif (mats := _load(ext)) is not None:
        if variant in ("drop_anchor", "drop_far"):
            mats.pop(rh20t.IN_HAND_CALIB[7][0] if variant == "drop_anchor" else FAR, None)
        else:
            for k in mats:
                mats[k] = np.array(mats[k], np.float64)
                mats[k][0, 0, 0] = np.nan if variant == "nan_extrinsics" else 1e36
        replace_dict(ext, mats)
    # the calibration matters only when the scene's F/T is camera-frame (then it skips or converts counted)
    return "defect", {"camera_frame_ft", "nan_stream", "overflow_stream"}


# ----------------------------------------------------------------------------------- checks


def _identical(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)


def _counted_repair(arrays: dict) -> bool:
    info = json.loads(str(arrays["info"]))
    return bool(info["dropped_records"]) or any(c["fallback"] for c in info["cameras"]) or info["ft_source"] != "base"


def _check_valid(arrays: dict, cfg: rh20t.ConvertConfig) -> None:
    n = len(arrays["t_s"])
    assert n >= 1 and arrays["frames"].shape == (n, cfg.image_size, cfg.image_size)
    assert arrays["frames"].dtype == np.uint8
    np.testing.assert_allclose(np.diff(arrays["t_s"]), 1 / cfg.hz, atol=1e-9)
    for k, dim in (("pos", 3), ("quat", 4), ("ft", 6)):
        assert arrays[k].shape == (n, dim) and np.isfinite(arrays[k]).all(), k
    assert np.isfinite(arrays["grip"]).all() and np.abs(arrays["pos"]).max() <= cfg.max_abs_pos_m
    assert np.abs(arrays["ft"]).max() <= cfg.max_abs_ft
    np.testing.assert_allclose(np.linalg.norm(arrays["quat"], axis=1), 1, atol=1e-9)


def _check_outcome(arrays, skip, cfg, baseline, outcomes) -> None:
    tags = [t for t, _ in outcomes]
    allowed = set().union(*(r for _, r in outcomes))
    if arrays is None:
        event(f"skipped: {skip['reason']}")  # --hypothesis-show-statistics lists what the examples exercised
        assert skip["reason"] in rh20t.SKIP_REASONS and skip["reason"] != "unexpected_error", skip
        assert skip["reason"] in allowed, (skip, outcomes)
        assert any(t != "same" for t in tags), (skip, outcomes)  # a normalised-away change must not skip
        return
    _check_valid(arrays, cfg)
    event("converted: " + ("identical" if _identical(arrays, baseline) else
                           "repair counted" if _counted_repair(arrays) else "normalised"))
    if all(t == "same" for t in tags):
        assert _identical(arrays, baseline), outcomes
    elif "normalised" not in tags:
        assert _identical(arrays, baseline) or _counted_repair(arrays), (outcomes, json.loads(str(arrays["info"])))


def _copy_scene(corpus, name: str, work: Path) -> tuple[Path, Path]:
    cfg_dir = work / "RH20T_cfg7"
    shutil.copytree(corpus["cfg_dir"] / name, cfg_dir / name)
    calib = cfg_dir / "calib" / corpus["calib"].name
    shutil.copytree(corpus["calib"], calib)
    return cfg_dir / name, calib


# Deterministic for CI (derandomize, no example database). No shrink phase: an example is a scene number and at
# most three mutation tuples, readable as generated, while shrinking re-copies and re-converts scenes for minutes.
FUZZ = dict(deadline=None, derandomize=True, database=None, report_multiple_bugs=True,
            phases=[Phase.explicit, Phase.generate], suppress_health_check=[HealthCheck.too_slow,
                                                                            HealthCheck.data_too_large])


@settings(max_examples=400, **FUZZ)
@given(scene=st.integers(0, N_TASKS * SCENES_PER_TASK - 1), camera=st.sampled_from(CAMERAS),
       mutations=st.lists(mutation, min_size=1, max_size=3))
def test_a_corrupted_scene_is_repaired_and_counted_or_skipped_with_a_specific_reason(corpus, scene, camera,
                                                                                     mutations):
    name = corpus["names"][scene]
    with tempfile.TemporaryDirectory(dir=corpus["base"]) as tmp:
        work = Path(tmp)
        scene_dir, calib = _copy_scene(corpus, name, work)
        outcomes = [apply(m, scene_dir, calib, corpus["video"][name]) for m in mutations]
        cfg = rh20t.make_config("tiny", root=str(work), out=str(work / "store"), camera=camera)
        ref = _ref(scene_dir)
        arrays, skip = rh20t.convert_scene_cached(ref, cfg, work / "cache")
        assert not (work / "RH20T_cfg7" / MARKER).exists()
        _check_outcome(arrays, skip, cfg, corpus["baseline"][camera, name], outcomes)


@settings(max_examples=8, **FUZZ)
@given(corrupt=st.dictionaries(st.integers(0, N_TASKS * SCENES_PER_TASK - 1),
                               st.lists(mutation, min_size=1, max_size=2), min_size=1, max_size=3))
def test_a_run_over_corrupted_scenes_completes_and_untouched_scenes_are_byte_identical(corpus, corrupt):
    with tempfile.TemporaryDirectory(dir=corpus["base"]) as tmp:
        work = Path(tmp)
        shutil.copytree(corpus["cfg_dir"], work / "RH20T_cfg7")
        cal = work / "RH20T_cfg7" / "calib" / corpus["calib"].name
        outcomes = {}
        for i, muts in corrupt.items():
            name = corpus["names"][i]
            outcomes[name] = [apply(m, work / "RH20T_cfg7" / name, cal, corpus["video"][name]) for m in muts]
        # the calibration folder is shared: a calibration defect planted with one scene may skip another scene
        # whose F/T is camera-frame (untouched scenes have base-frame F/T and never read it)
        calib_reasons = {"camera_frame_ft", "nan_stream", "overflow_stream", "unsafe_pickle", "bad_stream",
                         "special_file", "outside_root"}
        cfg = rh20t.make_config("tiny", root=str(work), out=str(work / "store"))
        try:
            rh20t.run(cfg)
            converted = True
        except DataError:
            converted = False
        rep = json.loads((work / "store" / "conversion_report.json").read_text())
        assert converted == (rep["scenes_converted"] > 0)  # DataError only when no scene converted
        assert rep["scenes_found"] == len(corpus["names"]) == rep["scenes_converted"] + rep["scenes_skipped"]
        assert "unexpected_error" not in rep["skip_counts"]
        assert not (work / "RH20T_cfg7" / MARKER).exists()
        skips = {s["scene"]: s for s in rep["skipped"]}
        cache = rh20t.cache_dir(cfg)
        for name in corpus["names"]:
            cached = list(cache.glob(f"{name}-*.npz"))
            arrays = None
            if cached:
                with np.load(cached[0]) as z:
                    arrays = {k: z[k] for k in z.files}
            baseline = corpus["baseline"]["far", name]
            if name in outcomes:
                skip = skips.get(name) if arrays is None else None
                _check_outcome(arrays, skip, cfg, baseline, [*outcomes[name], ("defect", calib_reasons)])
            else:
                assert name not in skips and len(cached) == 1, name
                assert _identical(arrays, baseline), name
