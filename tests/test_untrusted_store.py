"""What a user points pokeworld's store commands at is never destroyed, followed, or allowed to hang them: output
folders pokeworld did not write, links, special files, forged HDF5 headers, non-real dtypes, external links,
two writers of one store, and corrupt stores that a re-run must not silently keep (issue #40, store part).

Cheap by construction: stores are a few episodes of 4x4 frames written with ``data.save``; where ``generate``
runs, its simulator is replaced by that tiny store, so only the checks around it are exercised.
"""

from __future__ import annotations

import json
import os
import threading

import h5py
import numpy as np
import pytest

from pokeworld import data
from pokeworld.errors import ConfigError, DataError
from pokeworld.io import OwnedDir, append_jsonl, atomic_path, dir_lock, open_nofollow
from pokeworld.sim import generate


def tiny_dataset(E: int = 3, T: int = 2, kind: str = "pokeworld") -> data.Dataset:
    rng = np.random.default_rng(0)
    return data.Dataset(
        frames=rng.integers(0, 255, (E, T + 1, 4, 4), dtype=np.uint8),
        proprio=rng.normal(size=(E, T + 1, 4)).astype(np.float32),
        touch=rng.normal(size=(E, T + 1, 7)).astype(np.float32),
        actions=rng.normal(size=(E, T, 2)).astype(np.float32),
        labels={"contact": np.zeros((E, T + 1), np.float32)},
        params={"log_k": np.zeros(E, np.float32)},
        split=np.arange(E, dtype=np.int8) % 3, manifest={"kind": kind})


def tiny_store(path, **kw):
    return data.save(tiny_dataset(**kw), path)


def finishes_within(fn, seconds: float = 10.0):
    """fn()'s outcome (its return value or exception); fails the test instead of hanging when fn blocks."""
    box = {}

    def target():
        try:
            box["value"] = fn()
        except BaseException as e:  # noqa: BLE001 - the outcome is what the test inspects
            box["error"] = e

    t = threading.Thread(target=target, daemon=True)
    t.start()
    t.join(seconds)
    assert not t.is_alive(), f"{fn} did not return within {seconds} s (it blocks)"
    return box


@pytest.fixture
def no_simulation(monkeypatch):
    """generate.run with the simulator replaced by the tiny store: a refusal must come before it is called."""
    calls = []

    def fake_simulate(cfg, progress=True, render=True):
        calls.append(cfg)
        ds = tiny_dataset()
        ds.manifest.update({"config": generate.content_config(cfg), "kind": "pokeworld"})
        return ds

    monkeypatch.setattr(generate, "simulate", fake_simulate)
    return calls


def gen_cfg(out, **kw):
    return generate.make_config("tiny", out=str(out), **kw)


# ---------------------------------------------------------------- 1. output folders are never destroyed
@pytest.mark.parametrize("overwrite", [False, True])
def test_generate_refuses_a_folder_it_did_not_write_and_keeps_it(tmp_path, no_simulation, overwrite):
    out = tmp_path / "thesis"
    out.mkdir()
    (out / "chapter1.tex").write_text("years of work")
    with pytest.raises(ConfigError, match="chapter1.tex.*did not write"):
        generate.run(gen_cfg(out, overwrite=overwrite))
    assert (out / "chapter1.tex").read_text() == "years of work" and not no_simulation


def test_overwrite_replaces_only_an_own_store_of_the_same_kind(tmp_path, no_simulation):
    out = tmp_path / "store"
    tiny_store(out, kind="rh20t")
    with pytest.raises(ConfigError, match="kind 'rh20t', not 'pokeworld'"):
        generate.run(gen_cfg(out, overwrite=True))
    assert data.read_manifest(out)["kind"] == "rh20t" and not no_simulation
    data.save(tiny_dataset(E=4), out)  # an own store of our kind, plus what certify writes beside it
    (out / "certificates.json").write_text("{}")
    generate.run(gen_cfg(out, overwrite=True))
    assert data.load(out).num_episodes == 3 and not (out / "certificates.json").exists()
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".store.")] == [".store.lock"]


def test_certificate_corpora_inside_a_store_are_ours_but_nothing_else_is(tmp_path, no_simulation):
    out = tmp_path / "store"
    tiny_store(out)
    corpus = out / "certificate_corpus"
    tiny_store(corpus / "n8")
    (corpus / ".n8.lock").write_text("")
    (corpus / "n8" / "draft.txt").write_text("mine")
    with pytest.raises(ConfigError, match="'certificate_corpus/n8/draft.txt', which pokeworld did not write"):
        generate.run(gen_cfg(out, overwrite=True))
    (corpus / "n8" / "draft.txt").unlink()
    generate.run(gen_cfg(out, overwrite=True))
    assert not corpus.exists() and data.load(out).num_episodes == 3


def test_rh20t_convert_refuses_a_foreign_out_before_reading_scenes(tmp_path):
    from pokeworld.real.rh20t.config import make_config
    from pokeworld.real.rh20t.convert import run

    out = tmp_path / "mine"
    out.mkdir()
    (out / "photo.jpg").write_bytes(b"\xff\xd8")
    with pytest.raises(ConfigError, match="'photo.jpg', which pokeworld did not write"):
        run(make_config("tiny", root=str(tmp_path / "no_such_root"), out=str(out), overwrite=True))
    assert (out / "photo.jpg").read_bytes() == b"\xff\xd8"


def test_a_store_folder_without_a_readable_manifest_is_not_replaced(tmp_path, no_simulation):
    out = tmp_path / "store"
    tiny_store(out)
    (out / "manifest.json").write_text("{broken")
    with pytest.raises(ConfigError, match="cannot be verified as a pokeworld store"):
        generate.run(gen_cfg(out, overwrite=True))
    assert (out / "data.h5").exists() and not no_simulation


def test_out_that_is_a_file_or_unwritable_is_refused_before_simulating(tmp_path, no_simulation):
    (tmp_path / "notes.txt").write_text("keep")
    with pytest.raises(ConfigError, match="existing file, not a folder"):
        generate.run(gen_cfg(tmp_path / "notes.txt"))
    with pytest.raises(ConfigError, match="cannot create output folder"):
        generate.run(gen_cfg(tmp_path / "notes.txt" / "store"))
    assert (tmp_path / "notes.txt").read_text() == "keep" and not no_simulation


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="permissions do not bind root")
def test_read_only_parent_is_refused_before_simulating(tmp_path, no_simulation):
    parent = tmp_path / "ro"
    parent.mkdir()
    parent.chmod(0o555)
    try:
        with pytest.raises(ConfigError, match="not writable"):
            generate.run(gen_cfg(parent / "store"))
    finally:
        parent.chmod(0o755)
    assert not no_simulation


def test_atomic_path_never_removes_a_folder_it_did_not_verify(tmp_path):
    final = tmp_path / "out"
    final.mkdir()
    (final / "mine.txt").write_text("x")
    for replace in (None, OwnedDir(files=(r"data\.h5",))):
        with pytest.raises(ConfigError, match="non-empty folder|did not write"):
            with atomic_path(final, replace=replace) as tmp:
                tmp.mkdir()
        assert (final / "mine.txt").read_text() == "x" and not list(tmp_path.glob(".out.*"))
    (final / "mine.txt").unlink()
    (final / "data.h5").write_text("old")
    with atomic_path(final, replace=OwnedDir(files=(r"data\.h5",))) as tmp:
        tmp.mkdir()
        (tmp / "data.h5").write_text("new")
    assert (final / "data.h5").read_text() == "new" and sorted(p.name for p in tmp_path.iterdir()) == [".pokeworld-owned", "out"]


# ---------------------------------------------------------------- 2. links are never written through
def test_links_are_refused_for_locks_metrics_and_atomic_outputs(tmp_path):
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    run = tmp_path / "run"
    run.mkdir()
    (run / ".lock").symlink_to(victim)
    with pytest.raises(ConfigError, match=r"\.lock is a symbolic link"):
        with dir_lock(run, ".lock", "{path} {holder}"):
            pass
    (run / "metrics.jsonl").symlink_to(victim)
    with pytest.raises(ConfigError, match="metrics.jsonl is a symbolic link"):
        append_jsonl(run / "metrics.jsonl", {"step": 1})
    os.link(victim, run / "hard.jsonl")
    with pytest.raises(ConfigError, match="2 hard links"):
        append_jsonl(run / "hard.jsonl", {"step": 1})
    (tmp_path / "target_dir").mkdir()
    (tmp_path / "target_dir" / "keep").write_text("k")
    (tmp_path / "store").symlink_to(tmp_path / "target_dir")
    with pytest.raises(ConfigError, match="is a symbolic link"):
        tiny_store(tmp_path / "store")
    assert victim.read_text() == "precious" and (tmp_path / "target_dir" / "keep").exists()


def test_a_fifo_under_a_written_name_is_refused_not_blocked_on(tmp_path):
    fifo = tmp_path / "metrics.jsonl"
    os.mkfifo(fifo)
    outcome = finishes_within(lambda: append_jsonl(fifo, {"step": 1}))
    assert isinstance(outcome.get("error"), ConfigError) and "FIFO" in str(outcome["error"])
    with open_nofollow(tmp_path / "fresh.jsonl", "w") as fh:  # an ordinary new file still opens
        fh.write("ok\n")
    assert (tmp_path / "fresh.jsonl").read_text() == "ok\n"


# ---------------------------------------------------------------- 3. one writer per store
def test_a_second_writer_of_a_store_is_refused_naming_the_holder(tmp_path, no_simulation):
    out = tmp_path / "store"
    with data.store_lock(out):
        with pytest.raises(ConfigError, match=rf"store is being written by pid {os.getpid()}"):
            generate.run(gen_cfg(out))
    assert not out.exists() and (tmp_path / ".store.lock").is_file() and not no_simulation
    generate.run(gen_cfg(out))  # released: the next writer gets it
    assert data.load(out).num_episodes == 3


# ---------------------------------------------------------------- 5. declared shapes checked before reading
def _replace_dataset(store, name, **create):
    with h5py.File(store / "data.h5", "r+") as f:
        del f[name]
        f.create_dataset(name, **create)


def test_a_forged_frame_header_is_refused_before_reading(tmp_path):
    out = tiny_store(tmp_path / "s")
    # 3 x 3 x 4096 x 4096 uint8 = 151 MB declared, no chunk written: a few KB of file
    _replace_dataset(out, "frames", shape=(3, 3, 4096, 4096), dtype=np.uint8, chunks=(1, 1, 4096, 4096),
                     compression="gzip")
    with pytest.raises(DataError, match=r"'frames' declares shape \(3, 3, 4096, 4096\), the manifest implies "
                                        r"\(3, 3, 4, 4\)"):
        data.load(out)
    man = json.loads((out / "manifest.json").read_text())
    (out / "manifest.json").write_text(json.dumps({**man, "frame_shape": [4096, 4096]}))
    with pytest.raises(DataError, match="declares .* but the file stores only 0 bytes"):
        data.load(out)


def test_the_byte_budget_is_stated_and_enforced(tmp_path, monkeypatch):
    out = tiny_store(tmp_path / "s")
    monkeypatch.setattr(data, "MAX_STORE_BYTES", 1 << 8)
    with pytest.raises(DataError, match=r"declare 639 bytes in all .* at most 256 bytes \(data.MAX_STORE_BYTES\)"):
        data.load(out)


# ---------------------------------------------------------------- 6. special files are not opened
@pytest.mark.parametrize("member", ["data.h5", "manifest.json"])
def test_a_fifo_or_link_in_a_store_is_refused_not_read(tmp_path, member):
    out = tiny_store(tmp_path / "s")
    (out / member).unlink()
    os.mkfifo(out / member)
    outcome = finishes_within(lambda: data.load(out))
    assert isinstance(outcome.get("error"), DataError) and "FIFO" in str(outcome["error"])
    (out / member).unlink()
    (out / member).symlink_to("/dev/zero")
    with pytest.raises(DataError, match="is a symbolic link"):
        data.load(out)


# ---------------------------------------------------------------- 12. dtypes and links out of the file
def test_complex_streams_are_refused_even_when_in_memory():
    ds = tiny_dataset()
    with pytest.raises(DataError, match="proprio has dtype complex64"):
        data.Dataset(**{**ds.__dict__, "proprio": ds.proprio.astype(np.complex64) * np.nan})


def test_non_real_dtypes_in_a_store_are_refused(tmp_path):
    out = tiny_store(tmp_path / "s")
    _replace_dataset(out, "touch", data=np.full((3, 3, 7), np.nan, np.complex64))
    with pytest.raises(DataError, match="'touch' declares dtype complex64"):
        data.load(out)
    out = tiny_store(tmp_path / "t")
    with h5py.File(out / "data.h5", "r+") as f:
        f["labels"].create_dataset("note", data=np.array([[b"a"] * 3] * 3))
    with pytest.raises(DataError, match="'labels/note' declares dtype"):
        data.load(out)


def test_links_and_storage_outside_the_store_file_are_refused(tmp_path):
    outside = tmp_path / "outside.h5"
    with h5py.File(outside, "w") as f:
        f["secret"] = np.zeros((3, 3), np.float32)
    out = tiny_store(tmp_path / "ext_link")
    with h5py.File(out / "data.h5", "r+") as f:
        f["labels/leak"] = h5py.ExternalLink(str(outside), "secret")
    with pytest.raises(DataError, match="'labels/leak' is a link to elsewhere"):
        data.load(out)
    raw = tmp_path / "raw.bin"
    raw.write_bytes(np.zeros((3, 3), np.float32).tobytes())
    out = tiny_store(tmp_path / "ext_storage")
    with h5py.File(out / "data.h5", "r+") as f:
        f["params"].create_dataset("leak", shape=(3,), dtype=np.float32, external=[(str(raw), 0, 12)])
    with pytest.raises(DataError, match="keeps its data outside the file"):
        data.load(out)
    out = tiny_store(tmp_path / "virtual")
    layout = h5py.VirtualLayout(shape=(3,), dtype=np.float32)
    layout[:] = h5py.VirtualSource(str(outside), "secret", shape=(3, 3))[:, 0]
    with h5py.File(out / "data.h5", "r+") as f:
        f["params"].create_virtual_dataset("leak", layout)
    with pytest.raises(DataError, match="keeps its data outside the file"):
        data.load(out)


# ---------------------------------------------------------------- 14. a corrupt store is not kept by a re-run
def test_a_rerun_verifies_the_store_before_skipping_and_names_overwrite(tmp_path, no_simulation):
    out = tmp_path / "store"
    generate.run(gen_cfg(out))
    generate.run(gen_cfg(out))  # intact: skipped
    assert len(no_simulation) == 1
    with h5py.File(out / "data.h5", "r+") as f:
        f["actions"][0, 0, 0] += 0.5
    with pytest.raises(DataError, match="damaged .*hash mismatch.*pass --overwrite"):
        generate.run(gen_cfg(out))
    generate.run(gen_cfg(out, overwrite=True))
    assert data.load(out).num_episodes == 3 and len(no_simulation) == 2
