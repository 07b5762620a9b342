"""Property-based damage to a pokeworld store: every truncated, bit-flipped, re-declared, linked or special-file
store ends in a DataError / ConfigError or loads exactly the original arrays — never a hang, another exception,
or an allocation beyond what the store really holds.

Cheap by construction: one 3-episode store of 4x4 frames is written once per module; an example copies its two
files, damages the copy and loads it (in a thread with a time limit, under ``tracemalloc``). Deterministic
(``derandomize``) for CI.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import threading
import tracemalloc
from pathlib import Path

import h5py
import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from pokeworld import data
from pokeworld.errors import ConfigError, DataError
from pokeworld.io import hash_arrays

ARRAYS = ("frames", "proprio", "touch", "actions", "split", "labels/contact", "params/log_k")
PEAK_BYTES = 32 << 20  # the store's arrays are under 1 KB: anything near this is an unchecked allocation
SETTINGS = settings(max_examples=80, deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    rng = np.random.default_rng(0)
    E, T = 3, 2
    ds = data.Dataset(frames=rng.integers(0, 255, (E, T + 1, 4, 4), dtype=np.uint8),
                      proprio=rng.normal(size=(E, T + 1, 4)).astype(np.float32),
                      touch=rng.normal(size=(E, T + 1, 7)).astype(np.float32),
                      actions=rng.normal(size=(E, T, 2)).astype(np.float32),
                      labels={"contact": np.zeros((E, T + 1), np.float32)}, params={"log_k": np.ones(E, np.float32)},
                      split=np.arange(E, dtype=np.int8) % 3, manifest={"kind": "pokeworld"})
    path = data.save(ds, tmp_path_factory.mktemp("fuzz") / "base")
    return path, hash_arrays(ds.arrays())


def outcome_of(path: Path) -> BaseException | data.Dataset:
    """data.load(path)'s result or exception, failing the example if it blocks or allocates without bound."""
    box = {}

    def target():
        tracemalloc.start()
        try:
            box["result"] = data.load(path)
        except BaseException as e:  # noqa: BLE001 - the outcome is what the property inspects
            box["result"] = e
        finally:
            box["peak"] = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()

    t = threading.Thread(target=target, daemon=True)
    t.start()
    t.join(10)
    assert not t.is_alive(), f"data.load({path}) blocked"
    assert box["peak"] < PEAK_BYTES, f"data.load allocated {box['peak']} bytes for a store of under 1 KB of arrays"
    return box["result"]


def check(path: Path, base_hash: str) -> None:
    result = outcome_of(path)
    if isinstance(result, data.Dataset):
        event("loaded")
        assert hash_arrays(result.arrays()) == base_hash  # a load that succeeds returns the original arrays
    else:
        event(type(result).__name__)
        assert isinstance(result, (DataError, ConfigError)), repr(result)
        assert "\n" not in str(result)
    try:  # deciding whether a store may be written there must not hang or crash either
        data.check_store_destination(path, "pokeworld")
    except ConfigError:
        pass


@pytest.fixture
def copy(base):
    root = Path(tempfile.mkdtemp(prefix="pokeworld-fuzz-"))
    counter = iter(range(10**9))

    def fresh() -> Path:
        out = root / f"s{next(counter)}"
        shutil.copytree(base[0], out)
        return out

    yield fresh
    shutil.rmtree(root, ignore_errors=True)


@SETTINGS
@given(member=st.sampled_from(["data.h5", "manifest.json"]), keep=st.floats(0, 1),
       flips=st.lists(st.tuples(st.floats(0, 1), st.integers(1, 255)), max_size=4))
def test_truncated_or_flipped_bytes(base, copy, member, keep, flips):
    path = copy()
    raw = bytearray((path / member).read_bytes())
    for where, xor in flips:
        raw[int(where * (len(raw) - 1))] ^= xor
    (path / member).write_bytes(bytes(raw[: int(keep * len(raw))]) if keep < 1 else bytes(raw))
    check(path, base[1])


MANIFEST_VALUES = st.one_of(st.none(), st.booleans(), st.integers(-3, 2**62), st.floats(allow_nan=True),
                            st.text(max_size=5), st.lists(st.integers(-3, 2**40), max_size=3))


@SETTINGS
@given(field=st.sampled_from(["num_episodes", "num_steps", "frame_shape", "format_version", "kind",
                              "content_sha256", "config"]), value=MANIFEST_VALUES, whole=st.booleans())
def test_manifest_fields_of_any_type(base, copy, field, value, whole):
    path = copy()
    man = json.loads((path / "manifest.json").read_text())
    (path / "manifest.json").write_text(json.dumps(value if whole else {**man, field: value}))
    check(path, base[1])


DTYPES = ["uint8", "int8", "bool", "float16", "float32", "float64", "complex64", "S3", "int64"]


@SETTINGS
@given(name=st.sampled_from(ARRAYS), shape=st.lists(st.sampled_from([0, 1, 2, 3, 4, 7, 4096, 2**20]), max_size=4),
       dtype=st.sampled_from(DTYPES), written=st.booleans(), frame_shape=st.sampled_from([None, [4096, 4096]]))
def test_redeclared_datasets(base, copy, name, shape, dtype, written, frame_shape):
    path = copy()
    shape = tuple(shape)
    small = int(np.prod(shape, dtype=np.int64)) <= 4096
    try:
        with h5py.File(path / "data.h5", "r+") as f:
            del f[name]
            if written and small:
                f.create_dataset(name, data=np.zeros(shape, dtype))
            else:  # declared only: no chunk written, as a forged header would be
                f.create_dataset(name, shape=shape, dtype=dtype, chunks=True if shape and all(shape) else None)
    except (ValueError, TypeError, OSError):
        return  # HDF5 cannot declare this shape at all
    if frame_shape is not None:  # a manifest that agrees with a forged frame header
        man = json.loads((path / "manifest.json").read_text())
        (path / "manifest.json").write_text(json.dumps({**man, "frame_shape": frame_shape}))
    check(path, base[1])


@SETTINGS
@given(name=st.sampled_from(ARRAYS), link=st.sampled_from(["external", "external_missing", "soft", "soft_dangling"]))
def test_links_inside_the_file(base, copy, name, link):
    path = copy()
    outside = path.parent / f"{path.name}-outside.h5"
    shutil.copy(path / "data.h5", outside)
    with h5py.File(path / "data.h5", "r+") as f:
        del f[name]
        f[name] = {"external": h5py.ExternalLink(str(outside), name),
                   "external_missing": h5py.ExternalLink(str(path / "nope.h5"), name),
                   "soft": h5py.SoftLink("/frames"), "soft_dangling": h5py.SoftLink("/nothing")}[link]
    check(path, base[1])


@SETTINGS
@given(member=st.sampled_from(["data.h5", "manifest.json"]),
       special=st.sampled_from(["fifo", "dev_zero", "link_to_copy", "folder", "missing", "link_to_folder"]))
def test_special_files_in_place_of_store_files(base, copy, member, special):
    path = copy()
    target = path / member
    twin = path.parent / f"{path.name}-{member}"
    shutil.copy(target, twin)
    target.unlink()
    if special == "fifo":
        os.mkfifo(target)
    elif special == "dev_zero":
        target.symlink_to("/dev/zero")
    elif special == "link_to_copy":
        target.symlink_to(twin)
    elif special == "folder":
        target.mkdir()
    elif special == "link_to_folder":
        target.symlink_to(path.parent)
    check(path, base[1])
