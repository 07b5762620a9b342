"""RH20T loader: fixture scenes in the real layout -> converted store, values checked against known signals."""

import collections
import json

import numpy as np
import pytest

from pokeworld import data
from pokeworld.errors import ConfigError, DataError
from pokeworld.real import rh20t
from pokeworld.real.fixtures import (FT_OFFSET, force_breakpoints, image_level, make_fixture_root, signals)
from pokeworld.real.rh20t import apply_whiten, contact_onset, make_config, parse_scene_name, run
from pokeworld.real.rh20t import cache as rh20t_cache


@pytest.fixture(scope="module")
def converted(tmp_path_factory):
    base = tmp_path_factory.mktemp("rh20t")
    fx = make_fixture_root(base / "raw", cfg=7)
    cfg = make_config("tiny", root=str(base / "raw"), out=str(base / "store"))
    out = run(cfg)
    return fx, cfg, out, data.load(out)


def _truth(fx, ds, e):
    """Fixture ground truth at the grid times of stored episode ``e``: (scene row, signal dict, t since t0 [s])."""
    row = ds.manifest["scenes"][int(ds.params["scene_index"][e])]
    info = fx["good"][row["name"]]
    t = (row["start_ms"] + 1000.0 * ds.labels["time_s"][e].astype(np.float64) - info["t0_ms"]) / 1000.0
    return row, info, signals(t, info["params"]), t


def test_store_shapes_and_labels(converted):
    fx, cfg, out, ds = converted
    E = ds.num_episodes
    assert ds.frames.shape == (E, 17, 96, 96) and ds.frames.dtype == np.uint8
    assert ds.proprio.shape == (E, 17, 8) and ds.touch.shape == (E, 17, 6) and ds.actions.shape == (E, 16, 7)
    for k in ("force", "tcp_pos"):
        assert ds.labels[k].shape == (E, 17, 3)
    for k in ("force_norm", "contact_onset", "contact"):
        assert ds.labels[k].shape == (E, 17)
    for k in ("task_id", "user_id", "scene_id", "cfg_id", "scene_index", "chunk_index"):
        assert ds.params[k].shape == (E,) and ds.params[k].dtype == np.float32
    assert set(ds.params["cfg_id"]) == {7.0}
    # every good scene converted, chunked into floor(N / 17) chunks of 17 observations at exactly 10 Hz
    assert {r["name"] for r in ds.manifest["scenes"]} == set(fx["good"])
    assert E == sum(r["chunks"] for r in ds.manifest["scenes"]) and all(r["chunks"] == r["grid_steps"] // 17
                                                                         for r in ds.manifest["scenes"])
    np.testing.assert_allclose(np.diff(ds.labels["time_s"], axis=1), 0.1, atol=1e-5)
    for e in range(E):
        row = ds.manifest["scenes"][int(ds.params["scene_index"][e])]
        assert parse_scene_name(row["name"]).task == ds.params["task_id"][e]


def test_interpolated_values_units_and_quaternion_order(converted):
    fx, cfg, out, ds = converted
    for e in range(ds.num_episodes):
        row, info, truth, t = _truth(fx, ds, e)
        np.testing.assert_allclose(ds.labels["tcp_pos"][e], truth["pos"], atol=1e-6)  # metres, exact (linear signal)
        np.testing.assert_allclose(ds.labels["tcp_quat"][e], truth["quat"], atol=1e-5)  # (w, x, y, z)
        np.testing.assert_allclose(ds.labels["gripper_width"][e], truth["gripper_info_mm"] / 1000, atol=1e-6)
        away = np.min(np.abs(t[:, None] - force_breakpoints(info["params"])[None]), axis=1) > 0.15
        assert away.sum() > 8
        np.testing.assert_allclose(ds.labels["force"][e][away], truth["ft_zeroed"][away, :3], atol=1e-5)
        np.testing.assert_allclose(ds.labels["torque"][e], truth["ft_zeroed"][:, 3:], atol=1e-6)  # zeroed, not raw
        assert not np.allclose(ds.labels["torque"][e], truth["ft_raw"][:, 3:], atol=FT_OFFSET[3] / 2)
        np.testing.assert_allclose(ds.labels["force_norm"][e], np.linalg.norm(ds.labels["force"][e], axis=1), rtol=1e-6)


def test_proprio_touch_actions_are_clipped_whitened_physical_streams(converted):
    fx, cfg, out, ds = converted
    st = ds.manifest["normalization"]
    for e in range(ds.num_episodes):
        row, info, truth, t = _truth(fx, ds, e)
        raw_p = np.concatenate([truth["pos"], truth["quat"], truth["gripper_info_mm"][:, None] / 1000], 1)
        np.testing.assert_allclose(ds.proprio[e], apply_whiten(raw_p, st["proprio"]), atol=2e-3)
        # action = (d position, rotation vector of q_{t+1} q_t^*, d gripper): the yaw-only motion gives (0, 0, d yaw)
        dyaw = info["params"]["yaw_rate"] * np.diff(t)
        raw_a = np.concatenate([np.diff(truth["pos"], axis=0), np.zeros((16, 2)), dyaw[:, None],
                                np.diff(truth["gripper_info_mm"])[:, None] / 1000], 1)
        np.testing.assert_allclose(ds.actions[e], apply_whiten(raw_a, st["actions"]), atol=2e-3)
        away = np.min(np.abs(t[:, None] - force_breakpoints(info["params"])[None]), axis=1) > 0.15
        np.testing.assert_allclose(ds.touch[e][away], apply_whiten(truth["ft_zeroed"], st["touch"])[away], atol=1e-4)


def test_percentile_clipping_uses_train_statistics_only(converted):
    fx, cfg, out, ds = converted
    raw = np.concatenate([ds.labels["force"], ds.labels["torque"]], -1).astype(np.float64)
    train = raw[ds.split == 0].reshape(-1, 6)
    st = ds.manifest["normalization"]["touch"]
    lo, hi = np.percentile(train, [0.1, 99.9], axis=0)
    np.testing.assert_allclose(st["lo"], lo, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(st["hi"], hi, rtol=1e-5, atol=1e-5)
    clipped = np.clip(train, lo, hi)
    np.testing.assert_allclose(st["mean"], clipped.mean(0), atol=1e-5)
    # the clip is active (torque_x = 0.01 t rises past its 99.9th train percentile) and applies to every split
    assert (raw[..., 3] > hi[3] + 1e-7).any()
    z_hi = (hi[3] - st["mean"][3]) / st["std"][3]
    assert ds.touch[..., 3].max() <= z_hi + 1e-5 and np.isclose(ds.touch[..., 3].max(), z_hi, atol=1e-5)
    # statistics are not those of all episodes
    assert not np.allclose(st["mean"], np.clip(raw.reshape(-1, 6), lo, hi).mean(0), atol=1e-3)
    # train split is (approximately) whitened
    tz = ds.touch[ds.split == 0].reshape(-1, 6)
    np.testing.assert_allclose(tz[:, 2].mean(), 0, atol=1e-4)
    np.testing.assert_allclose(tz[:, 2].std(), 1, atol=1e-3)


def test_contact_onset_labels_match_analytic_force(converted):
    fx, cfg, out, ds = converted
    assert ds.manifest["onset_base_rate"] > 0
    n_onset = 0
    for e in range(ds.num_episodes):
        row, info, truth, t = _truth(fx, ds, e)
        fn = lambda tt: np.linalg.norm(signals(tt, info["params"])["ft_zeroed"][..., :3], axis=-1)  # noqa: E731
        future = np.stack([fn(t + 0.1 * k) > 10 for k in range(1, 5)]).any(0)
        expected = (fn(t) <= 10) & future
        np.testing.assert_array_equal(ds.labels["contact_onset"][e], expected.astype(np.float32))
        np.testing.assert_array_equal(ds.labels["contact"][e], (fn(t) > 10).astype(np.float32))
        n_onset += int(expected.sum())
    assert n_onset >= len(fx["good"]) * 3  # every scene presses once: ~4 onset steps each (unless cut at a chunk edge)


def test_contact_onset_definition():
    fn = np.array([0, 0, 0, 0, 0, 0, 12, 15, 3, 0, 0, 11.0])
    contact, onset = contact_onset(fn, 10.0, 4)
    np.testing.assert_array_equal(contact, [0, 0, 0, 0, 0, 0, 1, 1, 0, 0, 0, 1])
    np.testing.assert_array_equal(onset, [0, 0, 1, 1, 1, 1, 0, 0, 1, 1, 1, 0])


def test_frames_use_nearest_frame_of_the_far_camera_cropped(converted):
    fx, cfg, out, ds = converted
    for e in range(ds.num_episodes):
        row, info, truth, t = _truth(fx, ds, e)
        assert row["serials"] == [info["serials"]["far"]]
        grid_ms = row["start_ms"] + np.round(ds.labels["time_s"][e].astype(np.float64) * 1000).astype(np.int64)
        cam_ms = info["cam_ts"]["far"]
        nearest = cam_ms[np.abs(cam_ms[None] - grid_ms[:, None]).argmin(1)]  # ties -> the earlier frame
        level = image_level((nearest - info["t0_ms"]) / 1000.0, "far")
        got = ds.frames[e][:, 8:-8, 8:-8].reshape(17, -1).astype(float)
        tol = 3.0 if info["video"] == "mp4" else 2.0
        np.testing.assert_allclose(got.mean(1), level, atol=tol)
        assert (got.std(1) < 2.5).all()  # centred square crop: the black side bands are gone


def test_bad_scenes_are_skipped_with_counted_reasons(converted):
    fx, cfg, out, ds = converted
    rep = json.loads((out / "conversion_report.json").read_text())
    assert rep["skip_counts"] == dict(collections.Counter(fx["bad"].values()))
    assert rep["scenes_found"] == len(fx["good"]) + len(fx["bad"]) and rep["scenes_converted"] == len(fx["good"])
    got = {s["scene"]: s["reason"] for s in rep["skipped"]}
    assert got == fx["bad"]
    assert all(s["message"] for s in rep["skipped"]) and set(rep["skip_reason_meaning"]) == set(got.values())
    assert ds.manifest["skip_counts"] == rep["skip_counts"]
    assert ds.manifest["source"] == rep["source"] == {"synthetic": False}  # no rh20t-synth truth beside the scenes


def test_splits_are_scene_level_disjoint_and_heldout_tasks(converted):
    fx, cfg, out, ds = converted
    scene_split = collections.defaultdict(set)
    for e in range(ds.num_episodes):
        scene_split[int(ds.params["scene_index"][e])].add(int(ds.split[e]))
    assert all(len(v) == 1 for v in scene_split.values())  # all chunks of a scene share its split
    held = ds.manifest["heldout_tasks"]
    assert len(held) == 1
    tasks = ds.params["task_id"]
    assert set(tasks[ds.split == 3]) == set(map(float, held))
    assert not set(tasks[ds.split != 3]) & set(map(float, held))
    per = {s: {int(i) for i in ds.params["scene_index"][ds.split == s]} for s in range(4)}
    assert all(per[s] for s in range(4))
    for a in range(4):
        for b in range(a + 1, 4):
            assert not per[a] & per[b]


def test_split_scenes_counts_and_explicit_heldout():
    cfg = make_config("tiny", root="x", num_heldout_tasks=2)
    tasks = np.repeat(np.arange(1, 11), 5)
    split, held = rh20t.split_scenes(tasks, cfg)
    assert len(held) == 2 and set(tasks[split == 3]) == set(held)
    assert np.bincount(split, minlength=4).tolist() == [24, 8, 8, 10]
    split2, held2 = rh20t.split_scenes(tasks, make_config("tiny", root="x", heldout_tasks=(3, 7)))
    assert held2 == [3, 7] and set(np.flatnonzero(split2 == 3) // 5 + 1) == {3, 7}


def test_rerun_skips_and_resume_uses_scene_cache(converted, monkeypatch, tmp_path):
    fx, cfg, out, ds = converted
    mtime = (out / "data.h5").stat().st_mtime_ns
    assert run(cfg) == out and (out / "data.h5").stat().st_mtime_ns == mtime
    with pytest.raises(ConfigError, match="different config"):
        run(make_config("tiny", root=cfg.root, out=cfg.out, seed=3))
    # a new output over the same cache key: every scene comes from the cache, nothing is re-read
    cache = rh20t.cache_dir(cfg)
    n_short = list(fx["bad"].values()).count("too_short")  # too_short is decided at assembly, after caching
    assert len(list(cache.glob("*.npz"))) == len(fx["good"]) + n_short

    def boom(*a, **k):
        raise AssertionError("scene re-processed although cached")

    monkeypatch.setattr(rh20t_cache, "process_scene", boom)  # where convert_scene_cached looks it up
    import shutil
    shutil.rmtree(out)
    out2 = run(cfg)
    ds2 = data.load(out2)
    assert ds2.manifest["content_sha256"] == ds.manifest["content_sha256"]
    rep = json.loads((out2 / "conversion_report.json").read_text())
    assert rep["skip_counts"] == dict(collections.Counter(fx["bad"].values()))


def test_two_view_and_close_camera(converted, tmp_path):
    fx, cfg, out, ds = converted
    two = data.load(run(make_config("tiny", root=cfg.root, out=str(tmp_path / "two"), camera="two_view")))
    close = data.load(run(make_config("tiny", root=cfg.root, out=str(tmp_path / "close"), camera="close")))
    assert two.frames.shape[2:] == (96, 96) and two.num_episodes == ds.num_episodes
    for e in range(0, two.num_episodes, 5):
        row, info, truth, t = _truth(fx, two, e)
        assert row["serials"] == [info["serials"]["far"], info["serials"]["close"]]
        left, right = two.frames[e][:, 8:-8, 6:42].mean((1, 2)), two.frames[e][:, 8:-8, 54:90].mean((1, 2))
        np.testing.assert_allclose(left, image_level(t, "far"), atol=5)
        np.testing.assert_allclose(right, image_level(t, "close"), atol=5)
        np.testing.assert_allclose(close.frames[e][:, 8:-8, 8:-8].mean((1, 2)), image_level(t, "close"), atol=5)


def test_config_and_input_errors(tmp_path):
    with pytest.raises(ConfigError, match="cfg"):
        make_config("tiny", root="x", cfg=9)
    with pytest.raises(ConfigError, match="camera"):
        make_config("tiny", root="x", camera="left_eye")
    with pytest.raises(ConfigError, match="root"):
        run(make_config("tiny", out=str(tmp_path / "o")))
    with pytest.raises(DataError, match="does not exist"):
        run(make_config("tiny", root=str(tmp_path / "nope"), out=str(tmp_path / "o")))
    (tmp_path / "empty" / "RH20T_cfg7").mkdir(parents=True)
    with pytest.raises(DataError, match="no RH20T cfg7 scene"):
        run(make_config("tiny", root=str(tmp_path / "empty"), out=str(tmp_path / "o")))
    assert (tmp_path / "o" / "conversion_report.json").exists() and not data.is_complete(tmp_path / "o")


def test_scene_name_parsing():
    r = parse_scene_name("task_0012_user_0003_scene_0004_cfg_0007")
    assert (r.task, r.user, r.scene, r.cfg, r.human) == (12, 3, 4, 7, False)
    assert parse_scene_name("task_0012_user_0003_scene_0004_cfg_0007_human").human
    assert parse_scene_name("calib") is None and parse_scene_name("task_12_user_3") is None


def test_isolated_bad_records_are_dropped_and_counted_and_far_falls_back(converted):
    fx, cfg, out, ds = converted
    rep = json.loads((out / "conversion_report.json").read_text())
    rows = {r["name"]: r for r in ds.manifest["scenes"]}
    assert set(fx["repaired"]) <= set(rows)
    iso = next(n for n, d in fx["repaired"].items() if d == "nan_ft_isolated")
    fb = next(n for n, d in fx["repaired"].items() if d == "far_fallback")
    assert rows[iso]["dropped_records"] == {"force_torque_base": {"non_finite": 3}}
    assert rep["dropped_records"] == {"force_torque_base": {"non_finite": 3}}
    assert rep["scenes_with_dropped_records"] == 1
    assert rows[fb]["serials"] == [rh20t.CAMERA_ROLES[7]["far"][1]] and rows[fb]["cameras"][0]["fallback"]
    assert rep["camera_counts"] == {"far": {rh20t.CAMERA_ROLES[7]["far"][0]: len(rows) - 1,
                                            rh20t.CAMERA_ROLES[7]["far"][1]: 1}}
    assert rep["camera_fallback_scenes"] == 1 and ds.manifest["camera_counts"] == rep["camera_counts"]


def test_camera_roles_are_ordered_lists_with_the_documented_cfg7_serials():
    r = rh20t.CAMERA_ROLES[7]
    assert r["far"] == ("104122061018", "104122061330", "f0271510")  # the authors' FRONT_CAM list
    assert "104122060811" in r["back"] and all("104122060811" not in r[k] for k in ("far", "close", "side"))
    assert set(r["close"]) == {"135122070361", "135122075425"}
    assert all(set(roles) == {"far", "close", "side", "back"} for roles in rh20t.CAMERA_ROLES.values())
    with pytest.raises(ConfigError, match="camera"):
        make_config("tiny", root="x", camera="overhead")


def test_clean_records_drops_isolated_and_skips_unusable_streams():
    cfg = make_config("tiny", root="x")
    n = 50
    ts = 1_690_000_000_000 + 100 * np.arange(n)
    tcp = np.tile([0.4, 0.1, 0.3, 1.0, 0.0, 0.0, 0.0], (n, 1))
    bad = tcp.copy()
    bad[3, 0] = np.nan
    bad[7, 1] = -9.432e36
    bad[9] = 0.0
    bad[11, 2] = 5.0  # a 5 m glitch
    bad[13, 3:] = [2.0, 0, 0, 0]
    t2, v2, dropped = rh20t.clean_records(ts, bad, "tcp", "tcp", cfg)
    assert dropped == {"non_finite": 1, "overflow": 1, "zero": 1, "out_of_range": 1, "bad_quaternion": 1}
    assert len(t2) == n - 5 and np.isfinite(v2).all()
    for mutate, reason, words in [
        (lambda v: v.__setitem__(slice(None), 0.0), "zero_tcp", "not logged"),
        (lambda v: v.__setitem__((slice(None), slice(0, 3)), v[:, :3] * 1000), "bad_units", "millimetres"),
        (lambda v: v.__setitem__((slice(0, 20), 1), -9.4e36), "overflow_stream", "overflowed"),
        (lambda v: v.__setitem__((slice(0, 30), 0), np.nan), "nan_stream", "non-finite"),
    ]:
        v = tcp.copy()
        mutate(v)
        with pytest.raises(rh20t.SceneSkip) as e:
            rh20t.clean_records(ts, v, "tcp", "tcp", cfg)
        assert e.value.reason == reason and words in e.value.message
    ft = np.zeros((n, 6))
    ft[5, 2] = 3e38
    assert rh20t.clean_records(ts, ft, "ft", "ft", cfg)[2] == {"overflow": 1}


def test_stratified_subset_is_seeded_proportional_and_nested():
    refs = [parse_scene_name(f"task_{t:04d}_user_0001_scene_{s:04d}_cfg_0007")
            for t, k in ((1, 40), (2, 20), (3, 10), (4, 30)) for s in range(1, k + 1)]
    a = rh20t.stratified_subset(refs, 30, seed=0)
    counts = collections.Counter(r.task for r in a)
    for t, k in ((1, 40), (2, 20), (3, 10), (4, 30)):
        assert abs(counts[t] - 30 * k / 100) <= 1
    assert [r.name for r in rh20t.stratified_subset(refs, 30, seed=0)] == [r.name for r in a]
    assert {r.name for r in rh20t.stratified_subset(refs, 30, seed=1)} != {r.name for r in a}
    prev: set = set()
    for n in (5, 10, 30, 60, 99):
        cur = {r.name for r in rh20t.stratified_subset(refs, n, seed=0)}
        assert len(cur) == n and prev <= cur
        prev = cur
    # not the first scenes by name: scene ids within a task are drawn at random
    assert sorted(r.scene for r in a if r.task == 1) != list(range(1, counts[1] + 1))
    assert len(rh20t.stratified_subset(refs, 0, seed=0)) == len(refs)


def test_camera_frame_force_torque_rotation_chain(tmp_path):
    """The fallback inverts rh20t_api's base -> camera projection (Euler convention checked against scipy)."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(0)
    angles = rng.uniform(0, 2 * np.pi, 3)
    np.testing.assert_allclose(rh20t.euler_sxyz_to_mat(*angles), Rotation.from_euler("xyz", angles).as_matrix(),
                               atol=1e-12)  # transforms3d 'sxyz' = scipy extrinsic 'xyz'
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    np.testing.assert_allclose(rh20t.quat_to_mat(q), Rotation.from_quat(np.roll(q, -1)).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(rh20t.rotvec_to_mat(angles), Rotation.from_rotvec(angles).as_matrix(), atol=1e-12)

    def homog(r, t):
        m = np.eye(4)
        m[:3, :3], m[:3, 3] = r, t
        return m

    cal = tmp_path / "calib" / "1"
    cal.mkdir(parents=True)
    ext = {s: homog(Rotation.random(random_state=i).as_matrix(), rng.normal(size=3))[None]
           for i, s in enumerate(["104122061018", "135122075425", "135122070361"])}
    np.save(cal / "extrinsics.npy", ext, allow_pickle=True)
    tcp = np.concatenate([[400.0, -120.0, 300.0], angles])  # kuka: mm + Euler
    np.save(cal / "tcp.npy", tcp)
    rots = rh20t.base_to_camera_rotations(cal, 7)
    tc = homog(np.array(rh20t.TCP_CAMERA_ROT[7], float), [0.035, 0.055, 0.2])
    tcp_mat = homog(Rotation.from_euler("xyz", angles).as_matrix(), tcp[:3] / 1000)
    base_world = np.linalg.inv(ext["135122075425"][0]) @ tc @ np.linalg.inv(tcp_mat)
    for s in ext:
        full = ext[s][0] @ base_world @ np.eye(4)
        np.testing.assert_allclose(rots[s], full[:3, :3], atol=1e-10)
    (tmp_path / "calib" / "2").mkdir()
    with pytest.raises(rh20t.SceneSkip, match="extrinsics.npy"):
        rh20t.base_to_camera_rotations(tmp_path / "calib" / "2", 7)


def test_sideways_camera_is_rotated_then_bottom_cropped():
    img = np.zeros((36, 64), np.uint8)  # landscape sensor; after a 270 degree turn the image is 64 tall, 36 wide
    img[:, -20:] = 200  # right columns become the bottom rows after a clockwise quarter turn (PIL ROTATE_270)
    out = rh20t.crop_resize(img, (), (18, 18), rotate=270)
    assert out.shape == (18, 18)
    assert out[-5:].mean() > 150 and out[:5].mean() < 50  # bottom square kept, bright band at its bottom
    assert rh20t.CAMERA_ROTATION[(7, "f0271510")] == 270


def test_external_role_falls_back_to_any_other_external_camera_but_never_to_a_wrist_camera(tmp_path):
    fx = make_fixture_root(tmp_path / "raw", cfg=7, n_tasks=2, scenes_per_task=2, defects=())
    cfg_dir, names, roles = fx["cfg_dir"], sorted(fx["good"]), rh20t.CAMERA_ROLES[7]
    far0, unlisted = roles["far"][0], "999000111222"
    cfg = make_config("tiny", root=str(tmp_path / "raw"), out=str(tmp_path / "far"))
    before = rh20t.process_scene(rh20t.scan(cfg_dir)[0], cfg)
    assert rh20t.scan(cfg_dir)[0].name == names[0]
    renames = {names[0]: (far0, unlisted),  # a third-person camera under a serial no role lists
               names[1]: (far0, roles["back"][0]),  # only a camera of another external role
               names[2]: (far0, roles["close"][1]),  # only wrist cameras: nothing external to fall back to
               names[3]: (roles["close"][0], "888000111222")}  # the wrist camera under an unlisted serial
    for name, (old, new) in renames.items():
        (cfg_dir / name / f"cam_{old}").rename(cfg_dir / name / f"cam_{new}")
    after = rh20t.process_scene(rh20t.scan(cfg_dir)[0], cfg)
    for k in before:  # the renamed folder's data is used unchanged
        if k not in ("serials", "info"):
            np.testing.assert_array_equal(after[k], before[k])
    cam = json.loads(str(after["info"]))["cameras"][0]
    assert cam == {"role": "far", "serial": unlisted, "rank": len(roles["far"]), "fallback": True,
                   "fallback_kind": "other_external", "rotation": 0}

    ds = data.load(run(cfg))
    rep = json.loads((tmp_path / "far" / "conversion_report.json").read_text())
    rows = {r["name"]: r for r in ds.manifest["scenes"]}
    assert rows[names[0]]["serials"] == [unlisted] and rows[names[1]]["serials"] == [roles["back"][0]]
    assert rows[names[1]]["cameras"][0]["fallback_kind"] == "other_external"
    assert rows[names[3]]["cameras"][0] == {"role": "far", "serial": far0, "rank": 0, "fallback": False,
                                            "fallback_kind": None, "rotation": 0}
    assert rep["skip_counts"] == {"missing_camera": 1} and rep["skipped"][0]["scene"] == names[2]
    assert "no other external camera" in rep["skipped"][0]["message"]
    assert rep["camera_other_external_scenes"] == 2 and rep["camera_fallback_scenes"] == 2
    assert rep["camera_counts"]["far"] == {far0: 1, unlisted: 1, roles["back"][0]: 1}

    # an explicit serial never falls back
    rep = json.loads((run(make_config("tiny", root=cfg.root, out=str(tmp_path / "explicit"), camera_serials=(far0,)))
                      / "conversion_report.json").read_text())
    assert rep["skip_counts"] == {"missing_camera": 3} and rep["camera_other_external_scenes"] == 0
    # the wrist role falls back along its own list only, never to an external or unlisted camera
    rep = json.loads((run(make_config("tiny", root=cfg.root, out=str(tmp_path / "close"), camera="close"))
                      / "conversion_report.json").read_text())
    assert rep["skip_counts"] == {"missing_camera": 1} and rep["skipped"][0]["scene"] == names[3]
    assert rep["camera_other_external_scenes"] == 0


def test_other_external_serials_order_and_wrist_exclusion():
    roles = rh20t.CAMERA_ROLES[7]
    present = {"zzz9", "aaa1", roles["back"][1], roles["side"][2], roles["close"][0], roles["far"][1],
               "104422070042"}  # the last: cfg2's / cfg5's wrist camera, a wrist camera in any cfg
    assert rh20t.other_external_serials(present, "far", 7) == [roles["side"][2], roles["back"][1], "aaa1", "zzz9"]
    assert rh20t.other_external_serials(present, "side", 7) == [roles["far"][1], roles["back"][1], "aaa1", "zzz9"]
    external = {s for r in rh20t.CAMERA_ROLES.values() for k in rh20t.EXTERNAL_ROLES for s in r[k]}
    assert not external & rh20t.IN_HAND_SERIALS  # no serial is both a wrist and an external camera
