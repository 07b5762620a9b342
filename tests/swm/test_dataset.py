"""pokeworld store <-> stable-worldmodel dataset: exact round trip, swm's reader on the export, World data imported,
and untrusted input refused with a DataError."""

import h5py
import numpy as np
import pytest
import stable_worldmodel as swm

from pokeworld.data import load, save
from pokeworld.errors import ConfigError, DataError
from pokeworld.sim.core import PARAM_NAMES
from pokeworld.sim.generate import make_config, simulate
from pokeworld.swm.dataset import ExportConfig, ImportConfig, export_store, import_dataset, run_export, run_import
from pokeworld.swm.env import CollectConfig, run as collect


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    path = tmp_path_factory.mktemp("store") / "standard"
    save(simulate(make_config("tiny", num_episodes=6, batch_envs=6, episode_steps=5), progress=False), path)
    return path


@pytest.fixture(scope="module")
def exported(store, tmp_path_factory):
    return run_export(ExportConfig(store=str(store), out=str(tmp_path_factory.mktemp("swm") / "pw.h5")))


def test_store_to_swm_to_store_is_exact(store, exported, tmp_path):
    back = run_import(ImportConfig(source=str(exported), out=str(tmp_path / "back")))
    a, b = load(store), load(back)  # load re-hashes both stores
    assert a.arrays().keys() == b.arrays().keys()
    for name, arr in a.arrays().items():
        assert arr.dtype == b.arrays()[name].dtype and np.array_equal(arr, b.arrays()[name]), name
    assert b.manifest["content_sha256"] == a.manifest["content_sha256"]
    assert b.manifest["kind"] == "swm-import" and b.manifest["source_manifest"]["seed"] == a.manifest["seed"]
    assert len(b.episodes("train")) == len(a.episodes("train"))


def test_swm_hdf5_dataset_reads_the_export(store, exported):
    ds = load(store)
    reader = swm.data.load_dataset(exported)  # swm's format detection and its own reader class
    assert type(reader).__name__ == "HDF5Dataset"
    assert {"pixels", "proprio", "touch", "action", "split", *PARAM_NAMES, "log_m", "object_pos"} <= set(
        reader.column_names)
    assert list(reader.lengths) == [ds.num_steps + 1] * ds.num_episodes
    ep = reader.load_episode(2)
    assert tuple(ep["pixels"].shape) == (ds.num_steps + 1, 3, 64, 64)  # swm's channel-first tensors
    assert np.array_equal(ep["pixels"][:, 0].numpy(), ds.frames[2])
    assert np.array_equal(ep["touch"].numpy(), ds.touch[2])
    assert np.allclose(ep["mass"].numpy(), ds.params["mass"][2])  # the hidden parameters are columns
    assert np.array_equal(ep["action"][:-1].numpy(), ds.actions[2]) and ep["action"][-1].isnan().all()
    clips = swm.data.HDF5Dataset(path=exported, num_steps=3)  # swm's training view: clips of 3 rows
    assert len(clips) == ds.num_episodes * (ds.num_steps + 1 - 3 + 1)
    assert tuple(clips[0]["proprio"].shape) == (3, 4) and tuple(clips[0]["action"].shape) == (3, 2)


def test_world_collected_pokeworld_imports_into_a_store(tmp_path):
    h5 = collect(CollectConfig(out=str(tmp_path / "w.h5"), episodes=3, steps=6, num_envs=2))
    raw = swm.data.load_dataset(h5)
    ds = load(run_import(ImportConfig(source=str(h5), out=str(tmp_path / "store"), steps=4)))
    assert ds.frames.shape == (3, 5, 64, 64) and ds.actions.shape == (3, 4, 2) and ds.touch.shape == (3, 5, 7)
    first = raw.load_episode(0)
    assert np.array_equal(ds.frames[0], first["pixels"][:5, 0].numpy())
    assert np.array_equal(ds.actions[0], first["action"][:4].numpy())
    assert ds.params["mass"][0] == pytest.approx(float(first["mass"][0]))
    assert np.allclose(ds.params["log_m"], np.log(ds.params["mass"]))
    assert {"object_pos", "goal_pos", "contact"} <= set(ds.labels)
    assert sorted(ds.manifest["split_counts"]) == ["heldout", "probe_fit", "probe_test", "train"]


def test_lance_import_matches_hdf5_import_up_to_jpeg(tmp_path):
    common = {"episodes": 2, "steps": 4, "num_envs": 1, "seed": 5}
    h5 = import_dataset(ImportConfig(source=str(collect(CollectConfig(out=str(tmp_path / "a.h5"), **common)))))
    lance = collect(CollectConfig(out=str(tmp_path / "a.lance"), format="lance", **common))
    ln = import_dataset(ImportConfig(source=str(lance)))
    assert np.array_equal(ln.proprio, h5.proprio) and np.array_equal(ln.params["mass"], h5.params["mass"])
    assert np.abs(ln.frames.astype(int) - h5.frames).max() <= 16  # Lance stores pixels as JPEG


def test_export_refuses_an_existing_output_and_clashing_names(store, exported):
    with pytest.raises(ConfigError, match="exists"):
        run_export(ExportConfig(store=str(store), out=str(exported)))
    ds = load(store)
    ds.labels["action"] = ds.labels["contact"]
    with pytest.raises(DataError, match="collide"):
        export_store(ds, exported.with_name("clash.h5"))


def copy_with(exported, out, edit):
    """A copy of the export with ``edit(h5py.File)`` applied."""
    with h5py.File(exported, "r") as src, h5py.File(out, "w") as dst:
        for name in src:
            src.copy(name, dst)
        for k, v in src.attrs.items():
            dst.attrs[k] = v
        edit(dst)
    return out


def replace(name, value):
    def edit(f):
        del f[name]
        f[name] = value
    return edit


@pytest.mark.parametrize("case, edit, message", [
    ("no_index", lambda f: f.__delitem__("ep_len"), "episode index"),
    ("offset_out_of_range", replace("ep_offset", np.array([0, 6, 12, 18, 24, 999])), "outside"),
    ("no_pixels", lambda f: f.__delitem__("pixels"), "missing"),
    ("string_proprio", replace("proprio", np.array([b"x"] * 36, dtype="S1")), "missing"),
    ("ragged_column", replace("touch", np.zeros((5, 7), np.float32)), "different numbers of rows"),
    ("mass_varies", replace("mass", np.linspace(1, 2, 36).astype(np.float32)), "not constant"),
    ("nan_proprio", replace("proprio", np.full((36, 4), np.nan, np.float32)), "non-finite"),
    ("bad_record", lambda f: f.attrs.__setitem__("pokeworld", "{not json"), "is not a pokeworld-swm-hdf5 record"),
    ("external_link", lambda f: f.__setitem__("sneaky", h5py.ExternalLink("/etc/passwd", "/x")), "link"),
])
def test_malformed_swm_files_are_data_errors(exported, tmp_path, case, edit, message):
    bad = copy_with(exported, tmp_path / f"{case}.h5", edit)
    with pytest.raises(DataError, match=message):
        import_dataset(ImportConfig(source=str(bad)))


def test_non_hdf5_and_unknown_paths_are_data_errors(tmp_path):
    junk = tmp_path / "junk.h5"
    junk.write_bytes(b"\x80\x04\x95not an hdf5 file, and not unpickled either")
    with pytest.raises(DataError, match="cannot read"):
        import_dataset(ImportConfig(source=str(junk)))
    with pytest.raises(DataError, match="expected an swm"):
        import_dataset(ImportConfig(source=str(tmp_path)))
    with pytest.raises(DataError, match="does not exist"):
        import_dataset(ImportConfig(source=str(tmp_path / "absent.h5")))
