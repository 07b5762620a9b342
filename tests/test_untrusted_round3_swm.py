"""Untrusted inputs, round 3 (issue #50): an swm HDF5 episode index that overlaps or points outside the stored rows,
a malformed export record, shared-reference tuple pickles that made the checked unpickler exponential, a timeout
verdict that was paid again on every load, and outputs refused only after all the work was done.

Everything here runs in the core environment (h5py, no stable-worldmodel): swm-import of an HDF5 file needs only
h5py."""

from __future__ import annotations

import os
import pickle
import shutil
import sys
import tempfile
from pathlib import Path

import h5py
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pokeworld.data import Dataset, save
from pokeworld.errors import ConfigError, DataError
from pokeworld.evaluate import coordinate
from pokeworld.models import flow
from pokeworld.real import npy_child, rh20t
from pokeworld.real.safe_pickle import UnsafePickleError, load_npy
from pokeworld.swm import dataset
from pokeworld.swm.dataset import ExportConfig, ImportConfig, export_store, import_dataset, read_swm, to_store

sys.path.insert(0, str(Path(__file__).parent))
from rh20t_hostile import OBJECT_FLAGS, dtype_ops, global_op, object_array_ops, planted_npy  # noqa: E402


# ------------------------------------------------------------------------------------------------ swm fixtures
def tiny_store(E: int = 3, T1: int = 4, side: int = 8) -> Dataset:
    """A small store whose pixel rows are numbered (row r of the export holds r everywhere) and whose params and
    split are the same in every episode, so any grouping of the rows into episodes is a consistent dataset."""
    frames = np.arange(E * T1, dtype=np.uint8).reshape(E, T1, 1, 1) * np.ones((1, 1, side, side), np.uint8)
    rows = np.arange(E * T1, dtype=np.float32).reshape(E, T1, 1)
    return Dataset(frames=frames, proprio=np.repeat(rows, 4, -1), touch=rows.copy(),
                   actions=np.repeat(rows[:, :-1], 2, -1), labels={"object_pos": np.repeat(rows, 2, -1)},
                   params={"mass": np.ones(E, np.float32)}, split=np.zeros(E, np.int8), manifest={"kind": "pokeworld"})


@pytest.fixture(scope="module")
def exported(tmp_path_factory) -> Path:
    path = export_store(tiny_store(), tmp_path_factory.mktemp("swm") / "pw.h5")
    with h5py.File(path, "a") as f:  # finite actions in every row, so that any grouping of rows is a valid store
        f["action"][...] = np.nan_to_num(f["action"][()], nan=-1.0)
    return path


def with_index(src: Path, out: Path, lengths, offsets) -> Path:
    """A copy of ``src`` whose episode index is replaced (gzip-compressed, as a hostile file would be)."""
    shutil.copy(src, out)
    with h5py.File(out, "a") as f:
        for name, values in (("ep_len", lengths), ("ep_offset", offsets)):
            del f[name]
            values = np.asarray(values)
            f.create_dataset(name, data=values, **({"compression": "gzip"} if values.size > 1000 else {}))
    return out


def with_record(src: Path, out: Path, record) -> Path:
    shutil.copy(src, out)
    with h5py.File(out, "a") as f:
        f.attrs["pokeworld"] = record
    return out


def never(what: str):
    def refuse(*args, **kwargs):
        raise AssertionError(f"{what} ran before the input or output was checked")
    return refuse


# ------------------------------------------------------------------------------------------------ 1. swm-import
def test_two_rows_declaring_two_million_episodes_are_refused_before_the_gather(tmp_path, monkeypatch):
    """The reproduced file: 2 stored rows of 64 x 64 pixels, 2 million episodes all on those rows (about 46 GiB
    gathered before); refused by the episode index check, with no gather at all."""
    two_rows = export_store(tiny_store(E=1, T1=2, side=64), tmp_path / "two.h5")
    n = 2_000_000
    bomb = with_index(two_rows, tmp_path / "bomb.h5", np.full(n, 2, np.int64), np.zeros(n, np.int64))
    assert bomb.stat().st_size < 200_000
    monkeypatch.setattr(dataset, "_gather", never("the gather"))
    with pytest.raises(DataError, match=r"episodes 0 and 1 share stored rows") as e:
        import_dataset(ImportConfig(source=str(bomb)))
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("lengths, offsets", [
    ([4, 4, 4], [0, 4, 9]),  # the last one runs past the 12 rows
    ([4, -4, 4], [0, 4, 8]),  # a negative length
    ([4, 4, 4], [0, -4, 8]),  # a negative offset
    ([4, 4, 2**62], [0, 4, 2**62]),  # offset + length wraps around int64
    ([4, 4, 4], [0, 2, 8]),  # overlapping episodes
    ([4, 4, 4], [0, 0, 0]),  # the same rows three times
    (np.array([4, 4, 2**63 + 4], np.uint64), [0, 4, 8]),  # a uint64 past int64
], ids=["past-end", "negative-length", "negative-offset", "wrapping", "overlap", "repeated", "uint64"])
def test_an_episode_index_outside_or_overlapping_the_stored_rows_is_one_data_error(exported, tmp_path, monkeypatch,
                                                                                     lengths, offsets):
    bad = with_index(exported, tmp_path / "bad.h5", np.asarray(lengths), np.asarray(offsets, np.int64))
    monkeypatch.setattr(dataset, "_gather", never("the gather"))
    with pytest.raises(DataError, match=r"stored rows") as e:
        import_dataset(ImportConfig(source=str(bad)))
    assert "\n" not in str(e.value)


def test_the_gather_is_checked_against_max_gib_before_it_allocates(exported, monkeypatch):
    """to_store on its own (columns read by another reader): the bytes the gather would allocate are checked first."""
    cols, lengths, offsets, meta = read_swm(exported)
    monkeypatch.setattr(dataset, "_gather", never("the gather"))
    n = 100_000  # overlapping rows, never checked by read_swm here
    with pytest.raises(DataError, match=r"gathering 100000 episodes x 4 rows needs .* GiB, over the allowed "
                                        r"0\.001 GiB.*--max-gib"):
        to_store(cols, np.full(n, 4, np.int64), np.zeros(n, np.int64), meta,
                 ImportConfig(source=str(exported), max_gib=0.001))


@pytest.mark.parametrize("record", [
    "[" * 5_000 + "]" * 5_000,  # past Python's recursion limit: json.loads raised RecursionError
    '{"a":' * 5_000 + "1" + "}" * 5_000,
    '["pokeworld-swm-hdf5"]',
    '"pokeworld-swm-hdf5"',
    "5",
    '{"format": "pokeworld-swm-hdf5", "labels": [], "params": [], "source_manifest": ["not", "an", "object"]}',
], ids=["deep-list", "deep-object", "list", "string", "number", "manifest-list"])
def test_a_malformed_export_record_is_one_data_error(exported, tmp_path, record):
    bad = with_record(exported, tmp_path / "bad.h5", record)
    with pytest.raises(DataError, match=r"attribute 'pokeworld' is not a pokeworld-swm-hdf5 record") as e:
        import_dataset(ImportConfig(source=str(bad)))
    assert "\n" not in str(e.value)


def expected_outcome(lengths: list[int], offsets: list[int], rows: int) -> np.ndarray | None:
    """The rows an import must gather (episodes x T1), or None where it must refuse the index."""
    if any(n < 1 for n in lengths) or any(o < 0 or o + n > rows for n, o in zip(lengths, offsets)):
        return None
    spans = sorted(zip(offsets, lengths))
    if any(o2 < o1 + n1 for (o1, n1), (o2, _) in zip(spans, spans[1:])):
        return None
    T1 = max(set(lengths), key=lambda n: (lengths.count(n), n))
    if T1 < 2:
        return None
    return np.array([[o + t for t in range(T1)] for n, o in zip(lengths, offsets) if n >= T1])


REAL_GATHER = dataset._gather
HUGE = st.sampled_from([2**31, 2**62, 2**63 - 1, -(2**63), -(2**31), -1])
INDEX_VALUE = st.one_of(st.integers(-3, 14), HUGE)


@st.composite
def episode_indexes(draw):
    """Back-to-back episodes (what swm writes) or arbitrary values (negative, huge, overlapping)."""
    if draw(st.booleans()):
        lengths = draw(st.lists(st.integers(1, 6), min_size=1, max_size=6).filter(lambda v: sum(v) <= 12))
        gap = draw(st.integers(0, 12 - sum(lengths)))
        offsets = list(np.cumsum([gap, *lengths[:-1]]))
        order = draw(st.permutations(range(len(lengths))))
        return [lengths[i] for i in order], [int(offsets[i]) for i in order]
    n = draw(st.integers(1, 6))
    return draw(st.lists(INDEX_VALUE, min_size=n, max_size=n)), draw(st.lists(INDEX_VALUE, min_size=n, max_size=n))


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(index=episode_indexes())
def test_fuzzed_episode_indexes_import_exactly_or_raise_one_data_error(exported, monkeypatch, index):
    lengths, offsets = index
    budget = 2**-12  # GiB: 256 KiB, far above the 12 rows the file stores
    gathered = []

    def counting_gather(cols, ln, off, keep, T1):
        need = keep.size * T1 * sum(v[:1].nbytes for v in cols.values())
        assert need <= budget * 2**30, f"gathered {need} bytes past the budget"
        gathered.append(need)
        return REAL_GATHER(cols, ln, off, keep, T1)

    monkeypatch.setattr(dataset, "_gather", counting_gather)
    expected = expected_outcome(lengths, offsets, rows=12)
    with tempfile.TemporaryDirectory() as tmp:
        src = with_index(exported, Path(tmp) / "fuzz.h5", np.array(lengths, np.int64), np.array(offsets, np.int64))
        try:
            ds = import_dataset(ImportConfig(source=str(src), max_gib=budget))
        except DataError as e:
            assert "\n" not in str(e)
            assert expected is None, f"a valid index {index} was refused: {e}"
            return
    assert expected is not None, f"an invalid index {index} was imported"
    np.testing.assert_array_equal(ds.frames[:, :, 0, 0], expected)  # pixel rows hold their row number
    np.testing.assert_array_equal(ds.proprio[..., 0], expected.astype(np.float32))
    assert ds.num_episodes == len(expected) and gathered


# ------------------------------------------------------------------------------------------------ 2. pickles
def tuple_chain(levels: int) -> bytes:
    """Opcodes leaving on the stack a tuple that holds the previous one twice, ``levels`` deep: 8 bytes of pickle a
    level, 2**levels leaves as a tree. Memo slots 0..levels."""
    ops = pickle.EMPTY_TUPLE + pickle.BINPUT + b"\x00" + pickle.POP
    for i in range(levels):
        ops += (pickle.BINGET + bytes([i])) * 2 + pickle.TUPLE2 + pickle.BINPUT + bytes([i + 1]) + pickle.POP
    return ops + pickle.BINGET + bytes([levels])


def in_object_array(element_ops: bytes) -> bytes:
    return object_array_ops(dtype_ops("O8", OBJECT_FLAGS), pickle.EMPTY_LIST + element_ops + pickle.APPEND)


DEPTH = 60  # an exponential walk of 2**60 nodes never returns: the test returning is the check
SHARED_TUPLE_PICKLES = {
    # a refused dtype spec / _reconstruct shape: the error message used to repr the whole tree
    "dtype_spec": global_op("numpy", "dtype") + tuple_chain(DEPTH) + pickle.TUPLE1 + pickle.REDUCE,
    "reconstruct_shape": global_op("numpy._core.multiarray", "_reconstruct") + global_op("numpy", "ndarray")
    + tuple_chain(DEPTH) + pickle.SHORT_BINBYTES + b"\x01b" + pickle.TUPLE3 + pickle.REDUCE,
    # hashing a dict key / set element walks the tuple as a tree
    "dict_key": in_object_array(pickle.EMPTY_DICT + tuple_chain(DEPTH) + pickle.NONE + pickle.SETITEM),
    "dict_keys": in_object_array(pickle.EMPTY_DICT + pickle.MARK + tuple_chain(DEPTH) + pickle.NONE
                                 + pickle.SETITEMS),
    "set_global": in_object_array(global_op("builtins", "set") + pickle.EMPTY_LIST + tuple_chain(DEPTH)
                                  + pickle.APPEND + pickle.TUPLE1 + pickle.REDUCE),
    "frozenset_global_over_the_tuple": in_object_array(global_op("builtins", "frozenset") + tuple_chain(DEPTH)
                                                       + pickle.TUPLE1 + pickle.REDUCE),
    "additems": in_object_array(pickle.EMPTY_SET + pickle.MARK + tuple_chain(DEPTH) + pickle.ADDITEMS),
    "frozenset_opcode": in_object_array(pickle.MARK + tuple_chain(DEPTH) + pickle.FROZENSET),
    # many keys sharing one big (but each hashable in reasonable time) tuple: charged in total, not per key
    "many_keys": in_object_array(pickle.EMPTY_DICT + pickle.MARK + tuple_chain(16) + pickle.POP + b"".join(
        pickle.BININT + i.to_bytes(4, "little") + pickle.BINGET + bytes([16]) + pickle.TUPLE2 + pickle.NONE
        for i in range(20)) + pickle.SETITEMS),
}


@pytest.mark.parametrize("name", sorted(SHARED_TUPLE_PICKLES))
def test_shared_reference_tuples_are_refused_without_walking_them_as_trees(tmp_path, name):
    path = planted_npy(tmp_path / f"{name}.npy", SHARED_TUPLE_PICKLES[name])
    assert path.stat().st_size < 1000
    with pytest.raises(UnsafePickleError) as e:
        load_npy(path)
    assert len(str(e.value)) < 400 and "\n" not in str(e.value)
    with pytest.raises(rh20t.SceneSkip) as skip:  # the conversion's path: the child refuses it at once
        rh20t.load_pickled_dict(path, "transformed/gripper.npy")
    assert skip.value.reason == "unsafe_pickle" and skip.value.cacheable


def test_a_key_nested_a_million_tuples_deep_is_refused_before_python_hashes_it(tmp_path):
    """Python hashes nested tuples by C recursion without a depth guard: this key crashed the unpickling child with
    SIGSEGV (a skip, but by a crash); now its depth is measured first, without recursion."""
    ops = pickle.EMPTY_DICT + pickle.EMPTY_TUPLE + pickle.TUPLE1 * 1_000_000 + pickle.NONE + pickle.SETITEM
    path = planted_npy(tmp_path / "deep_key.npy", in_object_array(ops))
    with pytest.raises(rh20t.SceneSkip, match="nests tuples 1000001 deep") as e:  # in the child, as a conversion
        rh20t.load_pickled_dict(path, "transformed/gripper.npy")
    assert e.value.reason == "unsafe_pickle"


def test_a_shared_reference_tuple_in_the_reply_is_refused_after_one_walk_per_level(tmp_path):
    """A tuple tree that is never hashed reaches the JSON reply: each shared object is encoded once and its repeats
    charged, so the budget refuses it at once instead of after walking the whole budget."""
    path = planted_npy(tmp_path / "reply.npy", in_object_array(tuple_chain(DEPTH)))
    arr = load_npy(path)
    with pytest.raises(npy_child.NpyReadError, match="too large"):
        npy_child.encode(arr, npy_child._Budget(1 << 40))  # a budget no tree walk would exhaust in a test's time
    with pytest.raises(rh20t.SceneSkip, match="too large"):
        rh20t.load_pickled_dict(path, "transformed/gripper.npy")


def test_tuple_keys_sets_and_shared_values_still_load_as_np_load_does(tmp_path):
    shared = (1, "a", (2.5, None))
    obj = {(1, 2): [shared, shared], frozenset({(3, 4), 5}): {"k": shared}, "s": {(6, 7), (8, (9,))},
           "nested": np.array([{(1,): 2}], object)}
    for protocol in (2, 4):
        path = tmp_path / f"p{protocol}.npy"
        arr = np.empty((), object)
        arr[()] = obj
        with open(path, "wb") as fh:  # np.save's layout with the protocol an older numpy wrote
            np.lib.format.write_array_header_1_0(fh, np.lib.format.header_data_from_array_1_0(arr))
            pickle.dump(arr, fh, protocol=protocol)
        expected = np.load(path, allow_pickle=True).item()
        got = load_npy(path).item()
        assert got.keys() == expected.keys() and got["s"] == expected["s"]
        assert npy_child.load_npy_item_isolated(path)[(1, 2)] == [shared, shared]


def test_a_timeout_verdict_is_cached_by_content_and_the_child_is_not_started_again(tmp_path, monkeypatch):
    path = tmp_path / "gripper.npy"
    np.save(path, {"slow": 1}, allow_pickle=True)
    twin = tmp_path / "other_scene_gripper.npy"
    shutil.copy(path, twin)
    monkeypatch.setattr(npy_child._CHILD, "timed_out", {})  # this test's verdicts only
    npy_child.close_child()
    monkeypatch.setenv("POKEWORLD_PAUSE_AT", f"unpickle:{path.resolve()}:60")  # the slow checker
    monkeypatch.setattr(npy_child, "PICKLE_TIMEOUT_S", 1.0)
    real_start = npy_child.NpyChild._start
    try:
        with pytest.raises(rh20t.SceneSkip) as first:
            rh20t.load_pickled_dict(path, "transformed/gripper.npy")
        assert first.value.reason == "unsafe_pickle" and "within 1 s" in first.value.message
        assert first.value.cacheable  # the scene cache keeps it across conversions
        monkeypatch.setattr(npy_child.NpyChild, "_start", never("a new unpickling child"))
        for again in (path, twin):  # the same bytes under any name: refused at once
            with pytest.raises(npy_child.UnpicklerTimeout, match="refused without retrying"):
                npy_child.load_npy_isolated(again)
            with pytest.raises(rh20t.SceneSkip) as cached:
                rh20t.load_pickled_dict(again, "transformed/gripper.npy")
            assert cached.value.reason == "unsafe_pickle" and cached.value.cacheable
        # a verdict at 1 s says nothing about a longer timeout: that load runs (unpaused, it succeeds)
        monkeypatch.setattr(npy_child.NpyChild, "_start", real_start)
        monkeypatch.delenv("POKEWORLD_PAUSE_AT")
        assert npy_child.load_npy_item_isolated(path, timeout_s=30.0) == {"slow": 1}
    finally:
        npy_child.close_child()


def test_the_scene_cache_keeps_a_timeout_skip(tmp_path, monkeypatch):
    """A scene skipped because its file timed out is cached like any unsafe_pickle verdict: the next conversion
    reads the skip record instead of paying the timeout again."""
    from pokeworld.real.rh20t import cache as scene_cache
    from pokeworld.real.rh20t import records

    stream = tmp_path / "scene" / "gripper.npy"
    stream.parent.mkdir()
    np.save(stream, {"a": 1}, allow_pickle=True)
    loads = []

    def timing_out(path, timeout_s=None):
        loads.append(path)
        raise npy_child.UnpicklerTimeout(f"unpickling {path} did not finish within 120 s; the child was killed")

    monkeypatch.setattr(records, "load_npy_item_isolated", timing_out)
    monkeypatch.setattr(scene_cache, "process_scene", lambda ref, cfg: records.load_pickled_dict(stream, "gripper"))
    monkeypatch.setattr(scene_cache, "check_scene_name", lambda ref, cfg: None)
    ref = type("Ref", (), {"name": "task_0001_user_0001_scene_0001_cfg_0001", "path": stream.parent})()
    for _ in range(2):
        arrays, skip = scene_cache.convert_scene_cached(ref, None, tmp_path)
        assert arrays is None and skip["reason"] == "unsafe_pickle" and "within 120 s" in skip["message"]
    assert len(loads) == 1


# ------------------------------------------------------------------------------------------------ 3. outputs first
def test_swm_export_checks_its_output_before_loading_the_store(tmp_path, monkeypatch):
    monkeypatch.setattr(dataset, "load", never("loading the store"))
    (tmp_path / "a_file").write_text("not a folder")
    user = tmp_path / "user.h5"
    user.write_text("a user's file")
    (tmp_path / "folder.h5").mkdir()
    for out, overwrite, match in ((tmp_path / "a_file" / "x.h5", False, "a_file"),
                                  (user, True, "pokeworld did not write it"),
                                  (tmp_path / "folder.h5", True, "not a regular file"),
                                  (tmp_path / "x.npz", False, r"\.h5 or \.hdf5")):
        with pytest.raises(ConfigError, match=match) as e:
            dataset.run_export(ExportConfig(store=str(tmp_path / "store"), out=str(out), overwrite=overwrite))
        assert "\n" not in str(e.value)
    assert user.read_text() == "a user's file"


def test_swm_import_checks_its_output_before_reading_the_file(exported, tmp_path, monkeypatch):
    monkeypatch.setattr(dataset, "import_dataset", never("the import"))
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("keep me")
    (tmp_path / "a_file").write_text("not a folder")
    for out in (foreign, tmp_path / "a_file" / "store"):
        with pytest.raises(ConfigError):
            dataset.run_import(ImportConfig(source=str(exported), out=str(out), overwrite=True))
    assert (foreign / "notes.txt").read_text() == "keep me"


@pytest.fixture
def no_flow_work(monkeypatch):
    for name in ("load", "flow_dataset", "train_flow", "save", "save_flow"):
        monkeypatch.setattr(coordinate, name, never(f"coordinate.{name}"))


def test_coordinate_checks_the_flow_corpus_folder_before_any_work(tmp_path, no_flow_work, monkeypatch):
    monkeypatch.setattr(coordinate, "read_manifest", never("reading the source"))
    foreign = tmp_path / "flow"
    foreign.mkdir()
    (foreign / "results.csv").write_text("a user's table")
    (tmp_path / "a_file").write_text("not a folder")
    os.symlink(foreign, tmp_path / "link")
    cfg = flow.make_config("tiny")
    for out, match in ((foreign, "results.csv"), (tmp_path / "a_file" / "flow", "a_file"),
                       (tmp_path / "a_file", "existing file"), (tmp_path / "link", "symbolic link")):
        for overwrite in (False, True):
            with pytest.raises(ConfigError, match=match):
                coordinate.build_flow_corpus(tmp_path / "standard", out, cfg, overwrite=overwrite)
    assert (foreign / "results.csv").read_text() == "a user's table"


def flow_corpus(tmp_path: Path, cfg) -> tuple[Path, Path]:
    """A source store and a flow corpus folder derived from it (store files, the sensor, the ownership record)."""
    source = save(tiny_store(), tmp_path / "standard")
    src_manifest = coordinate.read_manifest(source)
    ds = tiny_store()
    ds.manifest = {"kind": "pokeworld", "corpus": "flow", "flow": coordinate._key(src_manifest, cfg)}
    out = save(ds, tmp_path / "flow")
    from pokeworld.checkpoint import save as save_checkpoint

    save_checkpoint({"sensor": 1}, out / "flow_sensor.pt")
    return source, out


def test_an_existing_flow_corpus_is_kept_without_loading_and_replaced_with_overwrite(tmp_path, monkeypatch):
    cfg = flow.make_config("tiny")
    source, out = flow_corpus(tmp_path, cfg)
    monkeypatch.setattr(coordinate, "load", never("loading the source"))
    assert coordinate.build_flow_corpus(source, out, cfg) == out  # same source and sensor config: skipped
    other = flow.make_config("tiny", steps=3)
    with pytest.raises(ConfigError, match="holds a different store"):
        coordinate.build_flow_corpus(source, out, other)
    monkeypatch.undo()
    replacement = tiny_store()
    replacement.manifest = {"kind": "pokeworld", "corpus": "flow", "flow": {"replaced": True, "sensor": {}}}
    monkeypatch.setattr(coordinate, "flow_dataset", lambda src, c, log_every=0: (replacement, None))
    from pokeworld.checkpoint import save as save_checkpoint

    monkeypatch.setattr(coordinate, "save_flow", lambda net, path, meta: save_checkpoint({"sensor": 2}, path))
    coordinate.build_flow_corpus(source, out, other, overwrite=True)  # its own sensor file does not block it
    assert coordinate.read_manifest(out)["flow"]["replaced"] and (out / "flow_sensor.pt").exists()
