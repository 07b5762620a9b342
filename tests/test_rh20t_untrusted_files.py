"""Files of an untrusted RH20T tree that must not hang, read outside the tree or decode a decompression bomb: a FIFO
or device where a file is expected (special_file), a symlink or metadata calib value leading out of the dataset root
(outside_root), a frame whose header declares a huge image (huge_image). Each is planted in a copy of a fixture scene
and must skip that scene with its reason, within seconds (an alarm turns a hang into a failure)."""

from __future__ import annotations

import json
import os
import shutil
import signal
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from rh20t_hostile import png_header_only

from pokeworld.real import rh20t
from pokeworld.real.fixtures import make_fixture_root, save_dict
from pokeworld.real.rh20t import video
from pokeworld.real.safe_pickle import load_npy_item


def replace_dict(path, obj) -> None:
    """Replace a file of this test's own fixture copy (save_dict writes only new files)."""
    path.unlink(missing_ok=True)
    save_dict(path, obj)


FAR = rh20t.CAMERA_ROLES[7]["far"][0]


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    base = tmp_path_factory.mktemp("untrusted")
    fx = make_fixture_root(base / "raw", cfg=7, n_tasks=1, scenes_per_task=2, defects=(), duration_s=3.0)
    names = sorted(fx["good"])
    by_video = {fx["good"][n]["video"]: n for n in names}
    return {"cfg_dir": fx["cfg_dir"], "mp4": by_video["mp4"], "jpg": by_video["jpg"],
            "calib": next((fx["cfg_dir"] / "calib").iterdir())}


@contextmanager
def alarm(seconds: int = 30):
    """A blocking open() of a FIFO becomes a TimeoutError instead of a test run that never ends."""
    def ring(signum, frame):
        raise TimeoutError(f"still blocked after {seconds} s")

    old = signal.signal(signal.SIGALRM, ring)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def _copy(corpus, video_kind: str, work: Path) -> Path:
    name = corpus[video_kind]
    shutil.copytree(corpus["cfg_dir"] / name, work / "RH20T_cfg7" / name)
    shutil.copytree(corpus["calib"], work / "RH20T_cfg7" / "calib" / corpus["calib"].name)
    return work / "RH20T_cfg7" / name


def _convert(scene: Path, work: Path, **overrides) -> tuple[dict | None, dict | None]:
    ref = rh20t.parse_scene_name(scene.name)
    ref.path = scene
    cfg = rh20t.make_config("tiny", root=str(work), out=str(work / "store"), **overrides)
    with alarm():
        return rh20t.convert_scene_cached(ref, cfg, work / "cache")


def _reason(scene: Path, work: Path, **overrides) -> str | None:
    arrays, skip = _convert(scene, work, **overrides)
    return None if skip is None else skip["reason"]


def _fifo(path: Path) -> None:
    path.unlink()
    os.mkfifo(path)


def _camera_frame_ft(scene: Path) -> None:
    """Only the camera-frame F/T: the conversion must read the calibration folder (given extrinsics for every
    serial, the anchor in-hand camera included)."""
    tr = scene / "transformed"
    (tr / "force_torque_base.npy").rename(tr / "force_torque.npy")
    cal = scene.parent / "calib" / json.loads((scene / "metadata.json").read_text())["calib"].__str__()
    serials = [*load_npy_item(tr / "force_torque.npy"), *rh20t.IN_HAND_CALIB[7]]
    replace_dict(cal / "extrinsics.npy", {s: np.eye(4)[None] for s in serials})


# ----------------------------------------------------------------------------------- special files


@pytest.mark.parametrize("where", ["metadata.json", "transformed/tcp_base.npy", "transformed/gripper.npy",
                                   f"cam_{FAR}/timestamps.npy", f"cam_{FAR}/color.mp4"])
def test_a_fifo_instead_of_a_scene_file_skips_the_scene_without_blocking(corpus, tmp_path, where):
    scene = _copy(corpus, "mp4", tmp_path)
    _fifo(scene / where)
    _, skip = _convert(scene, tmp_path)
    assert skip["reason"] == "special_file" and "FIFO" in skip["message"], skip


def test_fifo_frames_and_a_fifo_calibration_skip_the_scene(corpus, tmp_path):
    scene = _copy(corpus, "jpg", tmp_path)
    for f in (scene / f"cam_{FAR}" / "color").glob("*.jpg"):
        _fifo(f)
    assert _reason(scene, tmp_path) == "special_file"
    shutil.rmtree(tmp_path / "RH20T_cfg7")
    scene = _copy(corpus, "mp4", tmp_path)
    _camera_frame_ft(scene)
    _fifo(tmp_path / "RH20T_cfg7" / "calib" / corpus["calib"].name / "extrinsics.npy")
    assert _reason(scene, tmp_path) == "special_file"


def test_a_symlink_to_a_device_or_out_of_the_tree_is_refused_and_one_inside_is_followed(corpus, tmp_path):
    scene = _copy(corpus, "mp4", tmp_path)
    grip = scene / "transformed" / "gripper.npy"
    baseline, _ = _convert(scene, tmp_path)
    shutil.rmtree(tmp_path / "cache")
    inside = tmp_path / "RH20T_cfg7" / "shared_gripper.npy"
    grip.rename(inside)
    grip.symlink_to(inside)  # inside the root: followed, same result
    arrays, skip = _convert(scene, tmp_path)
    assert skip is None and all(np.array_equal(arrays[k], baseline[k]) for k in baseline)
    grip.unlink()
    grip.symlink_to("/dev/zero")  # never read: a device outside the tree
    shutil.rmtree(tmp_path / "cache")
    assert _reason(scene, tmp_path) == "outside_root"
    outside = tmp_path.parent / f"{tmp_path.name}_outside.npy"
    shutil.copy(inside, outside)
    grip.unlink()
    grip.symlink_to(outside)  # a regular file, but outside the dataset root
    shutil.rmtree(tmp_path / "cache")
    assert _reason(scene, tmp_path) == "outside_root"
    inner_fifo = tmp_path / "RH20T_cfg7" / "fifo.npy"
    os.mkfifo(inner_fifo)
    grip.unlink()
    grip.symlink_to(inner_fifo)  # inside, but a FIFO
    shutil.rmtree(tmp_path / "cache")
    assert _reason(scene, tmp_path) == "special_file"


# ----------------------------------------------------------------------------------- calibration outside the root


@pytest.mark.parametrize("calib", ["../../../../../etc", "/etc", "1/../../../..", "../task_0001"])
def test_a_metadata_calib_leading_out_of_the_calib_folder_is_refused(corpus, tmp_path, calib):
    scene = _copy(corpus, "mp4", tmp_path)
    meta = json.loads((scene / "metadata.json").read_text())
    meta["calib"] = calib
    (scene / "metadata.json").write_text(json.dumps(meta))
    _, skip = _convert(scene, tmp_path)
    assert skip["reason"] == "outside_root", skip


def test_a_calibration_folder_symlinked_out_of_the_root_is_not_read(corpus, tmp_path):
    scene = _copy(corpus, "mp4", tmp_path)
    _camera_frame_ft(scene)
    assert _reason(scene, tmp_path) is None  # converted through the calibration inside the tree
    cal = tmp_path / "RH20T_cfg7" / "calib" / corpus["calib"].name
    outside = tmp_path.parent / f"{tmp_path.name}_calib"
    shutil.move(cal, outside)
    cal.symlink_to(outside, target_is_directory=True)
    shutil.rmtree(tmp_path / "cache")
    assert _reason(scene, tmp_path) == "outside_root"


# ----------------------------------------------------------------------------------- huge frames


def test_frames_declaring_a_huge_image_are_refused_before_decoding(corpus, tmp_path):
    scene = _copy(corpus, "jpg", tmp_path)
    bomb = png_header_only(16384, 16384)
    for f in (scene / f"cam_{FAR}" / "color").glob("*.jpg"):
        f.unlink()
        f.with_suffix(".png").write_bytes(bomb)
    _, skip = _convert(scene, tmp_path)
    # PIL's own limit (2 x Image.MAX_IMAGE_PIXELS) or ours, whichever speaks first: both before decoding
    assert skip["reason"] == "huge_image" and ("16384 x 16384" in skip["message"]
                                               or f"{16384 ** 2} pixels" in skip["message"]), skip
    bomb = png_header_only(8192, 4096)  # 33.5 Mpx: under PIL's limit, over MAX_FRAME_PIXELS
    for f in (scene / f"cam_{FAR}" / "color").glob("*.png"):
        f.write_bytes(bomb)
    shutil.rmtree(tmp_path / "cache")
    _, skip = _convert(scene, tmp_path)
    assert skip["reason"] == "huge_image" and "8192 x 4096" in skip["message"], skip


@pytest.mark.parametrize("video_kind", ["mp4", "jpg"])
def test_the_frame_size_limit_applies_to_video_streams_and_images(corpus, tmp_path, monkeypatch, video_kind):
    """The fixture's frames are 128 x 72: at that limit they convert, one pixel below it the video stream's declared
    size (mp4) or the image header (jpg) refuses them."""
    scene = _copy(corpus, video_kind, tmp_path)
    monkeypatch.setattr(video, "MAX_FRAME_PIXELS", 128 * 72)
    assert _reason(scene, tmp_path) is None
    monkeypatch.setattr(video, "MAX_FRAME_PIXELS", 128 * 72 - 1)
    shutil.rmtree(tmp_path / "cache")
    assert _reason(scene, tmp_path) == "huge_image"


# ----------------------------------------------------------------------------------- the whole run


def test_a_run_counts_each_new_reason_and_converts_the_rest(tmp_path):
    fx = make_fixture_root(tmp_path / "raw", cfg=7, n_tasks=2, scenes_per_task=3, defects=(), duration_s=3.0)
    cfg_dir, names = fx["cfg_dir"], sorted(fx["good"])
    _fifo(cfg_dir / names[0] / "metadata.json")
    meta = json.loads((cfg_dir / names[1] / "metadata.json").read_text())
    (cfg_dir / names[1] / "metadata.json").write_text(json.dumps({**meta, "calib": "../../.."}))
    jpg_scene = next(n for n in names[2:] if fx["good"][n]["video"] == "jpg")
    for f in (cfg_dir / jpg_scene / f"cam_{FAR}" / "color").glob("*.jpg"):
        f.unlink()
        f.with_suffix(".png").write_bytes(png_header_only(16384, 16384))
    (tmp_path / "raw" / "truth").mkdir()
    os.mkfifo(tmp_path / "raw" / "truth" / "manifest.json")  # where a synthetic corpus keeps its truth
    with alarm(120):
        out = rh20t.run(rh20t.make_config("tiny", root=str(tmp_path / "raw"), out=str(tmp_path / "store")))
    rep = json.loads((out / "conversion_report.json").read_text())
    assert rep["skip_counts"] == {"huge_image": 1, "outside_root": 1, "special_file": 1}
    assert set(rep["skip_reason_meaning"]) == {"huge_image", "outside_root", "special_file"}
    assert {s["scene"]: s["reason"] for s in rep["skipped"]} == {
        names[0]: "special_file", names[1]: "outside_root", jpg_scene: "huge_image"}
    assert rep["scenes_converted"] == len(names) - 3 and rep["source"] == {"synthetic": False}
