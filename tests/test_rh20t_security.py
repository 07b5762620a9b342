"""RH20T's pickled .npy files are read by a restricted unpickler: a planted payload is refused before it runs, the
scene holding it is skipped as unsafe_pickle, and every legitimate file loads exactly as np.load would load it."""

import builtins
import collections
import io
import json
import os
import pickle
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from numpy.lib import format as npy_format
from rh20t_hostile import (
    FORGED_OBJECT_DTYPE,
    MEMORY_PRIMITIVES,
    OBJECT_FLAGS,
    dtype_ops,
    global_op,
    int_op,
    object_array_ops,
    planted_npy,
    shared_reference_bomb,
)

from pokeworld.real import npy_child, rh20t, synthetic
from pokeworld.real.fixtures import make_fixture_root
from pokeworld.real.safe_pickle import ADMITTED_GLOBALS, RestrictedUnpickler, UnsafePickleError, load_npy, load_npy_item


class SystemPayload:
    def __init__(self, marker: Path):
        self.marker = str(marker)

    def __reduce__(self):
        return os.system, (f"touch {self.marker}",)


class EvalPayload(SystemPayload):
    def __reduce__(self):
        return builtins.eval, (f"open({self.marker!r}, 'w').close()",)


class PopenPayload(SystemPayload):
    def __reduce__(self):
        return subprocess.Popen, ([sys.executable, "-c", f"open({self.marker!r}, 'w').close()"],)


def _wait_for(marker: Path, seconds: float = 10.0) -> bool:
    """Popen's child writes the marker asynchronously."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if marker.exists():
            return True
        time.sleep(0.05)
    return marker.exists()


def _payload_files(tmp_path: Path) -> dict[str, tuple[Path, Path]]:
    """name -> (.npy file holding a payload the way an RH20T stream would, its marker file)."""
    out = {}
    for kind, cls in (("system", SystemPayload), ("eval", EvalPayload), ("popen", PopenPayload)):
        marker = tmp_path / f"{kind}.marker"
        out[f"{kind}_top_level"] = (cls(marker), marker)
        out[f"{kind}_dict_value"] = ({"104122061018": cls(marker)}, marker)
        out[f"{kind}_nested_object_array"] = (
            {"104122061018": [{"timestamp": 1_690_000_000_000, "tcp": np.array([0.1, cls(marker)], dtype=object)}]},
            marker)
    files = {}
    for name, (obj, marker) in out.items():
        path = tmp_path / f"{name}.npy"
        np.save(path, obj, allow_pickle=True)
        files[name] = (path, marker)
    return files


PAYLOADS = [f"{k}_{w}" for k in ("system", "eval", "popen") for w in ("top_level", "dict_value", "nested_object_array")]


@pytest.mark.parametrize("name", PAYLOADS)
def test_planted_payloads_are_refused_without_running(tmp_path, name):
    path, marker = _payload_files(tmp_path)[name]
    with pytest.raises(UnsafePickleError, match="not admitted"):
        load_npy_item(path)
    time.sleep(0.2 if "popen" in name else 0)  # a child process would have had time to write it
    assert not marker.exists()
    with pytest.raises(rh20t.SceneSkip) as e:
        rh20t.load_pickled_dict(path, "transformed/gripper.npy")
    assert e.value.reason == "unsafe_pickle" and not marker.exists()


@pytest.mark.parametrize("name", ["system_dict_value", "eval_nested_object_array", "popen_top_level"])
def test_the_planted_payloads_are_live_under_np_load(tmp_path, name):
    """Control: the same files run their payload under np.load(allow_pickle=True), so the refusal above is real."""
    path, marker = _payload_files(tmp_path)[name]
    proc = None
    try:
        obj = np.load(path, allow_pickle=True)
        proc = next((x for x in _walk(obj) if isinstance(x, subprocess.Popen)), None)
        assert _wait_for(marker)
    finally:
        if proc is not None:
            proc.wait()


def _walk(obj):
    if isinstance(obj, np.ndarray) and obj.dtype == object:
        for x in obj.reshape(-1):
            yield from _walk(x)
    elif isinstance(obj, dict):
        for x in obj.values():
            yield from _walk(x)
    elif isinstance(obj, (list, tuple)):
        for x in obj:
            yield from _walk(x)
    else:
        yield obj


class NdarrayFromBuffer:
    """np.ndarray called directly can turn raw bytes into object pointers."""

    def __reduce__(self):
        return np.ndarray, ((1,), object, b"\0" * 8)


class RotCodec:
    def __reduce__(self):
        import codecs

        return codecs.encode, ("abc", "rot13")


def test_other_refusals_ndarray_call_structured_dtype_codecs_persistent_id_and_bare_pickle(tmp_path):
    cases = {
        "ndarray_call": {"a": NdarrayFromBuffer()},
        "structured_dtype": {"a": np.zeros(2, dtype=[("x", "f8"), ("y", "i4")])},
        "datetime_dtype": {"a": np.array(["2024-01-01"], dtype="datetime64[D]")},
        "codecs_rot13": {"a": RotCodec()},
    }
    for name, obj in cases.items():
        np.save(tmp_path / f"{name}.npy", obj, allow_pickle=True)
        with pytest.raises(UnsafePickleError):
            load_npy_item(tmp_path / f"{name}.npy")

    class WithPersistentId(pickle.Pickler):
        def persistent_id(self, obj):
            return "ext" if obj == "x" else None

    arr = np.empty((), object)
    arr[()] = {"a": "x"}
    buf = io.BytesIO()
    npy_format.write_array_header_1_0(buf, npy_format.header_data_from_array_1_0(arr))
    WithPersistentId(buf, protocol=3).dump(arr)
    (tmp_path / "pid.npy").write_bytes(buf.getvalue())
    with pytest.raises(UnsafePickleError, match="persistent id"):
        load_npy_item(tmp_path / "pid.npy")
    # a bare pickle (np.load(allow_pickle=True) falls back to pickle.load for it) is not an .npy file at all
    marker = tmp_path / "bare.marker"
    (tmp_path / "bare.npy").write_bytes(pickle.dumps({"a": SystemPayload(marker)}))
    with pytest.raises(ValueError, match="magic"):
        load_npy_item(tmp_path / "bare.npy")
    with pytest.raises(rh20t.SceneSkip) as e:
        rh20t.load_pickled_dict(tmp_path / "bare.npy", "gripper.npy")
    assert e.value.reason == "bad_stream" and not marker.exists()


def test_admitted_names_are_only_numpy_reconstruction_and_inert_builtins():
    names = {f"{m}.{n}" for m, n in ADMITTED_GLOBALS}
    assert names == {"numpy.core.multiarray._reconstruct", "numpy._core.multiarray._reconstruct",
                     "numpy.core.multiarray.scalar", "numpy._core.multiarray.scalar", "numpy.ndarray", "numpy.dtype",
                     "builtins.set", "builtins.frozenset", "builtins.complex", "__builtin__.set",
                     "__builtin__.frozenset", "__builtin__.complex", "_codecs.encode"}
    assert not callable(ADMITTED_GLOBALS[("numpy", "ndarray")])


def _write_object_npy(path: Path, obj, protocol: int, old_numpy_names: bool = False) -> None:
    arr = np.empty((), object)
    arr[()] = obj
    buf = io.BytesIO()
    npy_format.write_array_header_1_0(buf, npy_format.header_data_from_array_1_0(arr))
    data = pickle.dumps(arr, protocol=protocol)
    if old_numpy_names:  # protocol 2 spells globals as text lines: write numpy 1.x's module name
        assert b"numpy._core.multiarray\n" in data
        data = data.replace(b"numpy._core.multiarray\n", b"numpy.core.multiarray\n")
    path.write_bytes(buf.getvalue() + data)


def _deep_equal(a, b) -> bool:
    if type(a) is not type(b):
        return False
    if isinstance(a, np.ndarray):
        if a.dtype != b.dtype or a.shape != b.shape:
            return False
        if a.dtype == object:
            return all(_deep_equal(x, y) for x, y in zip(a.reshape(-1), b.reshape(-1)))
        return bool(np.array_equal(a, b, equal_nan=a.dtype.kind in "fc"))
    if isinstance(a, dict):
        return list(a) == list(b) and all(_deep_equal(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(_deep_equal(x, y) for x, y in zip(a, b))
    if isinstance(a, (float, np.floating)) and np.isnan(a):
        return bool(np.isnan(b))
    return bool(a == b)


@pytest.mark.parametrize("protocol,old_names", [(2, False), (2, True), (3, False), (4, False)])
def test_np_save_pickle_protocols_and_numpy_1_module_names_load(tmp_path, protocol, old_names):
    """np.save pickles with protocol 2 (numpy < 1.17), 3 (numpy 1.x) or 4 (numpy 2); numpy < 2 names its
    reconstruction helpers numpy.core.multiarray."""
    obj = {"104122061018": [{"timestamp": 1_690_000_000_000, "tcp": np.arange(7.0), "n": np.int64(3),
                             "f": np.float32(0.5), "ok": np.bool_(True), "s": np.str_("x")}],
           "gripper": {1_690_000_000_000: {"gripper_info": [80.0, 0.0, 0.0]}}, "ids": {1, 2}, "z": 1 + 2j,
           "names": np.array(["ab", "c"]), "raw": b"\x00\xff", "nested": np.array([{"k": np.arange(3)}, None], object),
           "nan": float("nan"), "frozen": frozenset({3})}
    path = tmp_path / "x.npy"
    _write_object_npy(path, obj, protocol, old_names)
    expected = np.load(path, allow_pickle=True).item()
    assert _deep_equal(load_npy_item(path), expected) and _deep_equal(expected, obj)


def test_non_object_npy_loads_without_pickle_and_header_mismatch_is_refused(tmp_path):
    np.save(tmp_path / "tcp.npy", np.array([0.4, -0.1, 0.3, 1.0, 0.0, 0.0, 0.0]))
    got = load_npy(tmp_path / "tcp.npy")
    assert got.dtype == np.float64 and np.array_equal(got, np.load(tmp_path / "tcp.npy"))
    np.save(tmp_path / "f.npy", np.asfortranarray(np.arange(6.0).reshape(2, 3)))
    assert np.array_equal(load_npy(tmp_path / "f.npy"), np.arange(6.0).reshape(2, 3))
    # an object header whose pickle holds a float array: not what the header promises
    arr = np.empty((), object)
    buf = io.BytesIO()
    npy_format.write_array_header_1_0(buf, npy_format.header_data_from_array_1_0(arr))
    (tmp_path / "lie.npy").write_bytes(buf.getvalue() + pickle.dumps(np.zeros(3), protocol=4))
    with pytest.raises(ValueError, match="header says"):
        load_npy(tmp_path / "lie.npy")


def test_calibration_and_camera_timestamps_payloads_skip_as_unsafe_pickle(tmp_path):
    marker = tmp_path / "calib.marker"
    cal = tmp_path / "calib" / "1"
    cal.mkdir(parents=True)
    np.save(cal / "extrinsics.npy", {"135122075425": SystemPayload(marker)}, allow_pickle=True)
    np.save(cal / "tcp.npy", np.zeros(6))
    with pytest.raises(rh20t.SceneSkip) as e:
        rh20t.base_to_camera_rotations(cal, 7)
    assert e.value.reason == "unsafe_pickle"
    np.save(cal / "extrinsics.npy", {"135122075425": np.eye(4)[None]}, allow_pickle=True)
    np.save(cal / "tcp.npy", np.array(EvalPayload(marker), dtype=object), allow_pickle=True)
    with pytest.raises(rh20t.SceneSkip) as e:
        rh20t.base_to_camera_rotations(cal, 7)
    assert e.value.reason == "unsafe_pickle"
    cam = tmp_path / "cam_104122061018"
    cam.mkdir()
    (cam / "color.mp4").write_bytes(b"\0")
    np.save(cam / "timestamps.npy", {"color": PopenPayload(marker)}, allow_pickle=True)
    cfg = rh20t.make_config("tiny", root="x")
    with pytest.raises(rh20t.SceneSkip) as e:
        rh20t.read_camera(cam, None, cfg, (96, 96))
    assert e.value.reason == "unsafe_pickle"
    time.sleep(0.2)
    assert not marker.exists()


def test_conversion_skips_exactly_the_scene_with_a_payload(tmp_path):
    fx = make_fixture_root(tmp_path / "raw", cfg=7, defects=("nan_ft_isolated",))
    victim = sorted(fx["good"])[2]
    marker = tmp_path / "gripper.marker"
    np.save(fx["cfg_dir"] / victim / "transformed" / "gripper.npy", {"104122061018": SystemPayload(marker)},
            allow_pickle=True)
    out = rh20t.run(rh20t.make_config("tiny", root=str(tmp_path / "raw"), out=str(tmp_path / "store")))
    rep = json.loads((out / "conversion_report.json").read_text())
    assert not marker.exists()
    assert rep["skip_counts"] == {"unsafe_pickle": 1}
    assert [(s["scene"], s["reason"]) for s in rep["skipped"]] == [(victim, "unsafe_pickle")]
    assert ".system, which is not admitted" in rep["skipped"][0]["message"]
    assert "unsafe_pickle" in rep["skip_reason_meaning"]
    assert rep["scenes_converted"] == len(fx["good"]) - 1


def _npy_files(root: Path) -> list[Path]:
    return sorted(root.rglob("*.npy"))


def test_safe_loader_returns_what_np_load_returns_on_fixture_and_synthetic_corpora(tmp_path):
    """Every .npy the converter reads is loaded identically (deep equality, arrays included), so converting these
    corpora gives the same arrays as the np.load(allow_pickle=True) loader did."""
    fx = make_fixture_root(tmp_path / "fx", cfg=7, n_tasks=1, scenes_per_task=2, defects=("far_fallback",))
    syn = synthetic.run(synthetic.make_config("tiny", root=str(tmp_path / "syn"), tasks=(1,), users_per_task=1,
                                              scenes_per_user=1, defect_repeats=0, duration_s=(2.0, 2.0)))
    kinds = collections.Counter()
    for root in (fx["root"], syn):
        files = _npy_files(root)
        assert any(f.name == "extrinsics.npy" for f in files) and any(f.name == "gripper.npy" for f in files)
        for f in files:
            ref = np.load(f, allow_pickle=True)
            ref = ref.item() if ref.dtype == object and ref.shape == () else ref
            got = load_npy_item(f)
            assert _deep_equal(got, ref), f
            kinds[type(got).__name__] += 1
    assert kinds["dict"] >= 10 and kinds["ndarray"] >= 2  # pickled dicts and plain arrays (calibration tcp.npy)


# ----------------------------------------------------------------------------------- memory primitives (issue #40)
# (the planted pickles are in rh20t_hostile.py)


def test_a_dtype_build_that_rewrites_flags_is_refused():
    """The step the exploits rest on. numpy's own unpickling accepts it (the control below), and so did this loader
    before BUILD was checked: it returned an 'object' dtype whose flags no longer say it holds objects."""
    forged = pickle.loads(FORGED_OBJECT_DTYPE)
    assert forged == np.dtype("O") and forged.flags == 0 and not forged.hasobject  # the primitive is live in numpy
    with pytest.raises(UnsafePickleError, match="would change numpy dtype"):
        RestrictedUnpickler(io.BytesIO(FORGED_OBJECT_DTYPE)).load()
    # the states numpy itself writes still load: native and swapped byte order, str with its size
    for dt in (np.dtype("O"), np.dtype(">f8"), np.dtype("<U5"), np.dtype("b1"), np.dtype(">c16")):
        got = RestrictedUnpickler(io.BytesIO(pickle.dumps(dt, protocol=2))).load()
        assert got == dt and got.__reduce__() == dt.__reduce__()


@pytest.mark.parametrize("name", sorted(MEMORY_PRIMITIVES))
def test_memory_primitives_are_refused_before_numpy_reads_a_pointer(tmp_path, name):
    path = planted_npy(tmp_path / "gripper.npy", MEMORY_PRIMITIVES[name])
    with pytest.raises(UnsafePickleError, match="would change numpy dtype|object dtypes|plain non-object"):
        load_npy_item(path)
    with pytest.raises(rh20t.SceneSkip) as e:  # the converter's path: the child refuses it, nothing crashes
        rh20t.load_pickled_dict(path, "transformed/gripper.npy")
    assert e.value.reason == "unsafe_pickle" and "killed by signal" not in e.value.message


def test_the_planted_memory_primitive_crashes_numpys_own_loader(tmp_path):
    """Control: under np.load(allow_pickle=True) the same file kills the process with SIGSEGV (in a child here)."""
    path = planted_npy(tmp_path / "gripper.npy", MEMORY_PRIMITIVES["object_scalar_from_forged_dtype"])
    proc = subprocess.run([sys.executable, "-c", f"import numpy as np; np.load({str(path)!r}, allow_pickle=True)"],
                          capture_output=True, timeout=60)
    assert proc.returncode < 0, proc  # killed by a signal: SIGSEGV (-11) here


def test_reconstruct_is_admitted_only_as_numpy_pickles_it(tmp_path):
    big_shape = (global_op("numpy._core.multiarray", "_reconstruct") + global_op("numpy", "ndarray") + int_op(1 << 30)
                 + pickle.TUPLE1 + pickle.SHORT_BINBYTES + b"\x01b" + pickle.TUPLE3 + pickle.REDUCE)
    with pytest.raises(UnsafePickleError, match="shape \\(0,\\)"):
        load_npy_item(planted_npy(tmp_path / "a.npy", big_shape))
    # an array BUILD whose data is shorter than its shape needs is refused before numpy allocates it
    short = object_array_ops(dtype_ops("O8", OBJECT_FLAGS), pickle.EMPTY_LIST)
    with pytest.raises(UnsafePickleError, match="list of 1 items"):
        load_npy_item(planted_npy(tmp_path / "b.npy", short))


# ----------------------------------------------------------------------------------- the unpickling child


def test_a_child_killed_while_unpickling_skips_that_scene_and_the_conversion_completes(tmp_path, monkeypatch):
    """A crash nobody has found yet (simulated by killing the child with SIGKILL at the fault point
    ``unpickle:<file>``) costs one scene, counted as unsafe_pickle, instead of ending the conversion."""
    fx = make_fixture_root(tmp_path / "raw", cfg=7, n_tasks=2, scenes_per_task=2, defects=())
    victim = sorted(fx["good"])[1]
    target = (fx["cfg_dir"] / victim / "transformed" / "gripper.npy").resolve()
    npy_child.close_child()  # the next child starts with the fault point set
    monkeypatch.setenv("POKEWORLD_KILL_AT", f"unpickle:{target}")
    try:
        out = rh20t.run(rh20t.make_config("tiny", root=str(tmp_path / "raw"), out=str(tmp_path / "store")))
    finally:
        npy_child.close_child()
    rep = json.loads((out / "conversion_report.json").read_text())
    assert rep["skip_counts"] == {"unsafe_pickle": 1}
    assert [s["scene"] for s in rep["skipped"]] == [victim]
    assert "killed by signal 9" in rep["skipped"][0]["message"]
    assert rep["scenes_converted"] == len(fx["good"]) - 1


def test_a_child_that_hangs_is_killed_after_the_timeout_and_the_verdict_is_cached(tmp_path, monkeypatch):
    path = tmp_path / "gripper.npy"
    np.save(path, {"a": 1}, allow_pickle=True)
    other = tmp_path / "tcp.npy"
    np.save(other, {"b": 2}, allow_pickle=True)
    monkeypatch.setattr(npy_child._CHILD, "timed_out", {})  # this test's verdicts only
    npy_child.close_child()
    monkeypatch.setenv("POKEWORLD_PAUSE_AT", f"unpickle:{path.resolve()}:60")
    monkeypatch.setattr(npy_child, "PICKLE_TIMEOUT_S", 2.0)
    start = time.monotonic()
    try:
        with pytest.raises(rh20t.SceneSkip) as e:
            rh20t.load_pickled_dict(path, "transformed/gripper.npy")
    finally:
        monkeypatch.delenv("POKEWORLD_PAUSE_AT")
        npy_child.close_child()
    assert time.monotonic() - start < 30
    # cached like any unsafe_pickle verdict (issue #50): N such files must not cost N x the timeout every conversion
    assert e.value.reason == "unsafe_pickle" and e.value.cacheable and "within 2 s" in e.value.message
    with pytest.raises(rh20t.SceneSkip, match="refused without retrying"):  # the same content: refused at once
        rh20t.load_pickled_dict(path, "transformed/gripper.npy")
    assert rh20t.load_pickled_dict(other, "transformed/tcp.npy") == {"b": 2}  # a fresh child serves the next


def test_the_child_returns_what_np_load_returns(tmp_path):
    obj = {"104122061018": [{"timestamp": 1_690_000_000_000, "tcp": np.arange(7.0), "n": np.int64(3),
                             "f": np.float32(0.5), "ok": np.bool_(True), "s": np.str_("x")}],
           "gripper": {1_690_000_000_000: {"gripper_info": [80.0, 0.0, 0.0]}}, "ids": {1, 2}, "z": 1 + 2j,
           "t": (1, "a"), "raw": b"\x00\xff", "nested": np.array([{"k": np.arange(3)}, None], object),
           "nan": float("nan"), "frozen": frozenset({3}), "big_endian": np.arange(3, dtype=">i4"),
           "fortran": np.asfortranarray(np.arange(6.0).reshape(2, 3)), "huge_int": 10**30}
    for protocol in (2, 4):
        _write_object_npy(tmp_path / "x.npy", obj, protocol)
        expected = np.load(tmp_path / "x.npy", allow_pickle=True).item()
        assert _deep_equal(npy_child.load_npy_item_isolated(tmp_path / "x.npy"), expected)


def test_a_reply_that_would_expand_shared_references_is_refused(tmp_path):
    path = planted_npy(tmp_path / "bomb.npy", shared_reference_bomb())
    with pytest.raises(rh20t.SceneSkip) as e:
        rh20t.load_pickled_dict(path, "transformed/gripper.npy")
    assert e.value.reason == "bad_stream" and "too large" in e.value.message
