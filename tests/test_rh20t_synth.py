"""Synthetic RH20T-layout corpus (PokeWorld episodes with known force) -> the real converter -> planted truth."""

import collections
import hashlib
import json

import numpy as np
import pytest

from pokeworld import cli, data
from pokeworld.errors import ConfigError
from pokeworld.real import rh20t, synthetic
from pokeworld.real.rh20t import make_config, run
from pokeworld.real.synthetic import DEFECTS, check_conversion, load_truth, store_chunks


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    base = tmp_path_factory.mktemp("synth")
    root = synthetic.run(synthetic.make_config("tiny", root=str(base / "raw")))
    man = json.loads((root / "truth" / "manifest.json").read_text())
    out = run(make_config("tiny", root=str(root), out=str(base / "store")))
    return root, man, out, data.load(out)


def test_layout_is_rh20t(corpus):
    root, man, out, ds = corpus
    cfg_dir = root / "RH20T_cfg7"
    assert (cfg_dir / "calib" / str(synthetic.CALIB_MS) / "extrinsics.npy").exists()
    scenes = [r for r in man["scenes"] if r["defect"] is None]
    assert len(scenes) == 12 and {r["task"] for r in scenes} == {1, 2, 3}
    kinds = collections.Counter(r["video"] for r in man["scenes"])
    assert kinds["mp4"] and kinds["jpg"]  # both camera storage variants
    d = cfg_dir / scenes[0]["name"]
    meta = json.loads((d / "metadata.json").read_text())
    assert {"calib", "rating", "start_time", "finish_time"} <= set(meta) and len(str(meta["start_time"])) == 13
    for f in ("tcp_base", "force_torque_base", "force_torque", "gripper", "joint"):
        obj = np.load(d / "transformed" / f"{f}.npy", allow_pickle=True).item()
        assert set(obj) == {scenes[0]["far_serial"], scenes[0]["close_serial"]}
    tcp = np.load(d / "transformed" / "tcp_base.npy", allow_pickle=True).item()[scenes[0]["far_serial"]]
    ts = np.sort([r["timestamp"] for r in tcp])
    assert 70 <= np.diff(ts).min() and np.diff(ts).max() <= 130 and np.diff(ts).std() > 5  # irregular ~10 Hz
    assert all(r["tcp"].shape == (7,) for r in tcp)


def test_store_records_that_it_came_from_a_synthetic_corpus(corpus, tmp_path):
    root, man, out, ds = corpus
    src = ds.manifest["source"]
    assert src["synthetic"] is True and src["seed"] == man["seed"] and src["generator"] == "pokeworld.real.synthetic"
    assert rh20t.corpus_source(root / "RH20T_cfg7", 7)["synthetic"]  # the cfg folder given as root
    (tmp_path / "truth").mkdir()  # a truth folder some other tool wrote is not ours
    (tmp_path / "truth" / "manifest.json").write_text(json.dumps({"generator": "someone.else"}))
    assert rh20t.corpus_source(tmp_path, 7) == {"synthetic": False}
    (tmp_path / "truth" / "manifest.json").write_text("{not json")
    assert rh20t.corpus_source(tmp_path, 7) == {"synthetic": False}


def test_conversion_reproduces_the_recorded_signals_exactly(corpus):
    """expected_* = linear interpolation of the recorded samples after the drop rules: float precision."""
    root, man, out, ds = corpus
    n = 0
    for e, row, tr, sl in store_chunks(ds, root):
        assert row["start_ms"] == int(tr["start_ms"])  # the converter's grid is the truth's grid
        np.testing.assert_allclose(ds.labels["time_s"][e], tr["time_s"][sl], atol=1e-5)
        np.testing.assert_allclose(ds.labels["force"][e], tr["expected_force"][sl], atol=1e-4)
        np.testing.assert_allclose(ds.labels["torque"][e], tr["expected_torque"][sl], atol=1e-5)
        np.testing.assert_allclose(ds.labels["tcp_pos"][e], tr["expected_tcp_pos"][sl], atol=1e-6)
        np.testing.assert_allclose(ds.labels["gripper_width"][e], tr["gripper_width"][sl], atol=1e-6)
        assert (np.abs(ds.labels["tcp_quat"][e] @ tr["tcp_quat"]) > 1 - 1e-3).all()  # small per-record noise
        n += 1
    assert n == ds.num_episodes > 0


def test_conversion_matches_the_physical_truth_within_interpolation_error(corpus):
    """Against the noise-free simulator signal: sampling at ~20 Hz and re-interpolating loses only impact peaks."""
    root, man, out, ds = corpus
    f_true, f_conv, c_true, c_conv, pos_err = [], [], [], [], []
    for e, row, tr, sl in store_chunks(ds, root):
        f_true.append(tr["force"][sl])
        f_conv.append(ds.labels["force"][e])
        c_true.append(tr["contact"][sl])
        c_conv.append(ds.labels["contact"][e])
        pos_err.append(np.abs(ds.labels["tcp_pos"][e] - tr["tcp_pos"][sl]).max())
    ft, fc = np.concatenate(f_true), np.concatenate(f_conv)
    r2 = 1 - ((fc - ft) ** 2).sum() / ((ft - ft.mean(0)) ** 2).sum()
    assert r2 > 0.9
    assert max(pos_err) < 0.03  # [m]: 20 Hz piecewise-linear motion re-sampled at ~20 Hz
    ct, cc = np.concatenate(c_true), np.concatenate(c_conv)
    assert 0.05 < ct.mean() < 0.6 and (ct == cc).mean() > 0.95  # contacts exceed 10 N, and are found
    assert (np.concatenate([tr["force_norm"] for *_, tr, _ in store_chunks(ds, root)]) > 10).any()


def test_contact_labels_follow_the_converter_definition(corpus):
    root, man, out, ds = corpus
    for e, row, tr, sl in store_chunks(ds, root):
        whole = rh20t.contact_onset(np.linalg.norm(tr["expected_force"], axis=1), 10.0, 4)
        np.testing.assert_array_equal(ds.labels["contact"][e], whole[0][sl])
        np.testing.assert_array_equal(ds.labels["contact_onset"][e], whole[1][sl])


def test_bad_scenes_skipped_or_repaired_and_counted(corpus):
    root, man, out, ds = corpus
    rep = json.loads((out / "conversion_report.json").read_text())
    assert rep["skip_counts"] == man["expected_skip_counts"]
    assert {s["scene"]: s["reason"] for s in rep["skipped"]} == {
        r["name"]: r["expected"] for r in man["scenes"] if r["expected"] != "converted"}
    assert rep["scenes_converted"] == man["expected_converted"]
    assert rep["camera_counts"]["far"] == man["expected_camera_counts"]
    assert rep["ft_source_counts"] == man["expected_ft_source_counts"] == {"base": 16, "camera_via_calib": 1}
    rows = {r["name"]: r for r in ds.manifest["scenes"]}
    for r in man["scenes"]:
        if r["expected"] == "converted":
            assert rows[r["name"]]["dropped_records"] == r["dropped_records"], r["name"]
            assert rows[r["name"]]["serials"] == [r["far_serial"]]
            assert rows[r["name"]]["cameras"][0]["fallback"] == (r["defect"] == "far_fallback")
            assert rows[r["name"]]["ft_source"] == r["ft_source"]
    assert rep["dropped_records"] == {"force_torque_base": {"non_finite": 3}, "tcp_base": {"overflow": 3, "zero": 3}}
    assert rep["scenes_with_dropped_records"] == 3 and rep["camera_fallback_scenes"] == 1
    msg = {s["reason"]: s["message"] for s in rep["skipped"]}
    assert "millimetres" in msg["bad_units"] and "millimetres" not in msg["zero_tcp"]
    assert "not logged" in msg["zero_tcp"]
    assert set(DEFECTS.values()) - {None} == set(rep["skip_counts"])


def test_two_view_sees_the_arena_and_the_finger(corpus, tmp_path):
    root, man, out, ds = corpus
    two = data.load(run(make_config("tiny", root=str(root), out=str(tmp_path / "two"), camera="two_view")))
    assert two.frames.shape[2:] == (96, 96)
    # close (right half): the finger (gray 128) always sits at the centre of the wrist view
    centre = two.frames[:, :, 44:52, 68:76].astype(float)
    assert np.abs(np.median(centre) - 128) < 15
    # far (left half): the finger moves across the arena
    assert two.frames[:, :, :, :48].std() > 10
    assert two.num_episodes == ds.num_episodes  # every far-convertible scene also has its wrist camera


def test_generation_is_deterministic(tmp_path):
    cfg = dict(tasks=(2,), users_per_task=1, scenes_per_user=2, defect_repeats=0, duration_s=(3.0, 3.0))
    digests = []
    for i in range(2):
        root = synthetic.run(synthetic.make_config("tiny", root=str(tmp_path / f"r{i}"), **cfg))
        h = hashlib.sha256()
        for f in sorted((root / "RH20T_cfg7").rglob("*")):
            if f.is_file() and f.suffix in (".npy", ".json"):
                h.update(f.relative_to(root).as_posix().encode() + f.read_bytes())
        for f in sorted((root / "truth").glob("*.npz")):
            for k, v in sorted(load_truth(root, f.stem).items()):
                h.update(k.encode() + np.ascontiguousarray(v).tobytes())
        digests.append(h.hexdigest())
    assert digests[0] == digests[1]
    # a scene does not depend on what else the corpus holds
    one = synthetic.run(synthetic.make_config("tiny", root=str(tmp_path / "one"), **{**cfg, "scenes_per_user": 1}))
    name = "task_0002_user_0001_scene_0001_cfg_0007"
    np.testing.assert_array_equal(load_truth(one, name)["knots_ft"],
                                  load_truth(tmp_path / "r0", name)["knots_ft"])
    other = synthetic.run(synthetic.make_config("tiny", root=str(tmp_path / "s1"), seed=1, **cfg))
    assert not np.array_equal(load_truth(other, name)["knots_ft"], load_truth(one, name)["knots_ft"])


def test_rerun_keeps_and_config_guard(tmp_path):
    cfg = synthetic.make_config("tiny", root=str(tmp_path / "r"), tasks=(1,), users_per_task=1, scenes_per_user=1,
                                defect_repeats=0, duration_s=(2.0, 2.0))
    root = synthetic.run(cfg)
    stamp = (root / "truth" / "manifest.json").stat().st_mtime_ns
    assert synthetic.run(cfg) == root and (root / "truth" / "manifest.json").stat().st_mtime_ns == stamp
    with pytest.raises(ConfigError, match="different synthetic corpus"):
        synthetic.run(synthetic.make_config("tiny", root=str(root), tasks=(2,), users_per_task=1))
    with pytest.raises(ConfigError, match="tasks"):
        synthetic.make_config("tiny", root="x", tasks=(99,))


def test_cli_command(tmp_path):
    rc = cli.main(["rh20t-synth", str(tmp_path / "c"), "--preset", "tiny", "--tasks", "3", "--users-per-task", "1",
                   "--scenes-per-user", "1", "--defect-repeats", "0"])
    assert rc == 0
    man = json.loads((tmp_path / "c" / "truth" / "manifest.json").read_text())
    assert [r["name"] for r in man["scenes"]] == ["task_0003_user_0001_scene_0001_cfg_0007"]


def test_scaling_subset_is_seeded_and_stratified(corpus, tmp_path):
    root, man, out, ds = corpus
    a = run(make_config("tiny", root=str(root), out=str(tmp_path / "a"), max_scenes=9, subset_seed=1))
    sub = json.loads((a / "manifest.json").read_text())["subset"]
    assert sub["sampled"] == 9 and len(sub["scenes"]) == 9
    per = sub["per_task"]
    for t, c in per.items():  # proportional to the task's candidates, at most one off
        assert abs(c["sampled"] - 9 * c["candidates"] / sub["candidates"]) < 1 + 1e-9
    rep = json.loads((a / "conversion_report.json").read_text())
    assert rep["scenes_sampled"] == 9 and rep["scenes_converted"] + sum(
        v for k, v in rep["skip_counts"].items() if k != "human_demo") == 9
    b = json.loads((run(make_config("tiny", root=str(root), out=str(tmp_path / "b"), max_scenes=9, subset_seed=1))
                    / "manifest.json").read_text())["subset"]
    c = json.loads((run(make_config("tiny", root=str(root), out=str(tmp_path / "c"), max_scenes=9, subset_seed=2))
                    / "manifest.json").read_text())["subset"]
    assert b["scenes"] == sub["scenes"] and c["scenes"] != sub["scenes"]
    small = json.loads((run(make_config("tiny", root=str(root), out=str(tmp_path / "s"), max_scenes=5,
                                        subset_seed=1)) / "manifest.json").read_text())["subset"]
    assert set(small["scenes"]) < set(sub["scenes"])  # nested: scaling curves reuse the smaller draws


def test_conversion_check_script_passes_a_correct_store_and_catches_a_corrupted_one(corpus, tmp_path):
    """check_conversion (and its script): float-precision errors and planted counts on the converted store; a
    store whose force was scaled (a units slip) must show up as a large error against expected_force."""
    import shutil

    root, man, out, ds = corpus
    from pokeworld.real import conversion_check as script

    good = check_conversion(out, root)
    assert all(good["counts_match_planted"].values())
    assert good["max_abs_error_vs_expected"]["force_n"] < 1e-4 and good["force_r2_vs_noise_free_truth"] > 0.9
    bad = tmp_path / "bad"
    force = ds.labels["force"]
    ds.labels["force"] = force * 1.1  # a units slip; the fixture's array is put back below
    try:
        data.save(ds, bad)
    finally:
        ds.labels["force"] = force
    shutil.copy(out / "conversion_report.json", bad / "conversion_report.json")
    worse = check_conversion(bad, root)
    assert worse["max_abs_error_vs_expected"]["force_n"] > 1.0
    assert script.main([str(tmp_path / "missing"), str(root)]) == 2
