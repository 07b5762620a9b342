"""Dataset generation, the store format, manifests and corruption handling."""

import hashlib
import json

import h5py
import numpy as np
import pytest

from pokeworld import data
from pokeworld.errors import ConfigError, DataError
from pokeworld.sim.generate import episode_contact_fraction, make_config, run, simulate


def _gen(tmp_path, name="ds", **kw):
    cfg = make_config("tiny", out=str(tmp_path / name), **kw)
    return run(cfg), cfg


def test_generate_writes_store_with_manifest_and_disjoint_splits(tmp_path):
    out, cfg = _gen(tmp_path)
    man = json.loads((out / "manifest.json").read_text())
    assert man["seed"] == cfg.seed and man["version"] and man["content_sha256"]
    assert man["config"]["num_episodes"] == 48
    ds = data.load(out)
    assert ds.frames.shape == (48, 65, 64, 64) and ds.frames.dtype == np.uint8
    assert ds.proprio.shape == (48, 65, 4) and ds.touch.shape == (48, 65, 7) and ds.actions.shape == (48, 64, 2)
    for k in ("log_m", "gamma", "log_k"):
        assert ds.params[k].shape == (48,)
    sets = [set(ds.episodes(s)) for s in ("train", "probe_fit", "probe_test")]
    assert sum(map(len, sets)) == 48
    assert not (sets[0] & sets[1]) and not (sets[0] & sets[2]) and not (sets[1] & sets[2])
    assert all(len(s) > 0 for s in sets)
    assert not list(tmp_path.glob(".*tmp*"))  # nothing half-written left behind


def test_same_seed_gives_identical_bytes(tmp_path):
    a, _ = _gen(tmp_path, "a")
    b, _ = _gen(tmp_path, "b")
    c, _ = _gen(tmp_path, "c", seed=1)
    h = lambda p: hashlib.sha256((p / "data.h5").read_bytes()).hexdigest()  # noqa: E731
    assert h(a) == h(b)
    assert (a / "manifest.json").read_text() == (b / "manifest.json").read_text()
    assert h(a) != h(c)


def test_rerun_skips_and_conflicting_config_is_refused(tmp_path):
    out, cfg = _gen(tmp_path)
    mtime = (out / "data.h5").stat().st_mtime_ns
    run(cfg)
    assert (out / "data.h5").stat().st_mtime_ns == mtime
    with pytest.raises(ConfigError, match="different config"):
        run(make_config("tiny", out=str(out), seed=5))


def test_truncated_and_tampered_stores_are_refused(tmp_path):
    out, _ = _gen(tmp_path)
    raw = (out / "data.h5").read_bytes()
    (out / "data.h5").write_bytes(raw[: len(raw) // 2])
    with pytest.raises(DataError, match="truncated or corrupt"):
        data.load(out)
    (out / "data.h5").write_bytes(raw)
    with h5py.File(out / "data.h5", "r+") as f:
        f["actions"][0, 0, 0] += 0.5
    with pytest.raises(DataError, match="hash mismatch"):
        data.load(out)
    with pytest.raises(DataError, match="does not exist"):
        data.load(tmp_path / "nope")
    (out / "manifest.json").write_text("{not json")
    with pytest.raises(DataError, match="not valid JSON"):
        data.load(out)


def test_nan_in_sensor_stream_is_refused(tiny_dataset):
    ds = tiny_dataset.subset(np.arange(4))
    ds.touch[1, 3, 2] = np.nan
    with pytest.raises(DataError, match="touch contains 1 non-finite"):
        data.validate(ds)


def test_corpora_change_what_they_should():
    std = simulate(make_config("tiny", num_episodes=64, batch_envs=64), progress=False)
    poor = simulate(make_config("tiny", num_episodes=64, batch_envs=64, corpus="contact_poor"), progress=False)
    assert episode_contact_fraction(poor) < 0.5 < episode_contact_fraction(std)
    bias = simulate(make_config("tiny", num_episodes=16, batch_envs=16, corpus="bias1.5"), progress=False)
    assert 0 < np.abs(bias.params["bias_x"]).max() <= 1.5
    assert np.all(std.params["bias_x"] == 0) and np.all(std.params["gain"] == 1)
    with pytest.raises(ConfigError, match="unknown corpus"):
        make_config("tiny", corpus="mud")


def test_parameter_ranges_respected(tiny_dataset):
    p = tiny_dataset.params
    assert p["mass"].min() >= 0.5 and p["mass"].max() <= 3.0
    assert p["gamma"].min() >= 0.5 and p["gamma"].max() <= 4.0
    assert p["stiffness"].min() >= 500 and p["stiffness"].max() <= 6000
    np.testing.assert_allclose(p["log_m"], np.log(p["mass"]), atol=1e-6)


def test_policy_produces_contacts_impacts_and_glides(tiny_dataset):
    contact = tiny_dataset.labels["contact"]
    speed = np.linalg.norm(tiny_dataset.labels["object_vel"], axis=-1)
    assert 0.1 < contact.mean() < 0.7
    glide = (contact == 0) & (speed > 0.1)
    assert glide.mean() > 0.05
    assert tiny_dataset.touch[..., 2].max() > 1.0  # sharp impact peaks exist
