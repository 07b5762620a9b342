"""Base-to-camera rotations from a calibration folder, which carry camera-frame F/T into the base frame."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..npy_child import load_npy_isolated, load_npy_item_isolated
from ..safe_pickle import UnsafePickleError
from .files import dataset_file
from .format import ALIGN_BASE_ROT, IN_HAND_CALIB, ROBOTS, TCP_CAMERA_ROT
from .rotations import euler_sxyz_to_mat, quat_to_mat, rotvec_to_mat
from .skips import SceneSkip


def calib_tcp_rotation(tcp: np.ndarray, cfg_num: int) -> np.ndarray:
    """Rotation of the calibration-time TCP pose ``calib/<calib>/tcp.npy`` as rh20t_api reads it.

    kuka: (x, y, z [mm], Euler sxyz [rad]); franka: (x, y, z, rotation vector), then a flip diag(1, -1, -1);
    flexiv / ur5: (x, y, z, quaternion w, x, y, z), or Euler sxyz when it has 6 values.
    """
    t = np.asarray(tcp, np.float64).reshape(-1)
    robot = ROBOTS[cfg_num]
    if robot == "franka" and t.size == 6:
        return rotvec_to_mat(t[3:6]) @ np.diag([1.0, -1.0, -1.0])
    if t.size == 6:
        return euler_sxyz_to_mat(*t[3:6])
    if t.size == 7:
        return quat_to_mat(t[3:7])
    raise ValueError(f"calibration tcp must have 6 or 7 values, got {t.size}")


def base_to_camera_rotations(calib_dir: Path, cfg_num: int, root: Path | None = None) -> dict[str, np.ndarray]:
    """serial -> 3x3 rotation R with v_camera = R v_base, from a calibration folder (rh20t_api's chain).

    The API projects base-frame F/T into camera ``s`` with ``extrinsics[s] @ base_world @ align_mat_base``,
    ``base_world = inv(extrinsics[in_hand[0]]) @ tc_mat @ inv(calib_tcp)``; only the rotations matter for
    vectors. Raises SceneSkip(camera_frame_ft) when a needed file or the anchor in-hand camera is absent. The
    files are checked (regular, inside ``root``; ``None``: inside ``calib_dir``) and unpickled in the child process.
    """
    ext_path = dataset_file(calib_dir / "extrinsics.npy", root or calib_dir, "calibration extrinsics.npy")
    tcp_path = dataset_file(calib_dir / "tcp.npy", root or calib_dir, "calibration tcp.npy")
    if ext_path is None or tcp_path is None:
        raise SceneSkip("camera_frame_ft", f"force_torque_base.npy absent and calibration {calib_dir} lacks "
                                           "extrinsics.npy / tcp.npy to rotate the camera-frame force_torque.npy")
    try:
        ext = load_npy_item_isolated(ext_path)
        mats = {str(k): np.asarray(v, np.float64).reshape(-1, 4, 4)[0][:3, :3] for k, v in dict(ext).items()}
        r_tcp = calib_tcp_rotation(load_npy_isolated(tcp_path), cfg_num)
    except UnsafePickleError as e:
        raise SceneSkip("unsafe_pickle", f"calibration {calib_dir}: {e}") from None
    except Exception as e:  # damaged calibration files
        raise SceneSkip("camera_frame_ft", f"cannot read calibration {calib_dir}: {type(e).__name__}: {e}") from None
    anchor = IN_HAND_CALIB[cfg_num][0]
    if anchor not in mats:
        raise SceneSkip("camera_frame_ft", f"calibration {calib_dir} has no extrinsics for the anchor in-hand camera "
                                           f"{anchor} (has {sorted(mats)})")
    world_from_base = (mats[anchor].T @ np.asarray(TCP_CAMERA_ROT[cfg_num], np.float64) @ r_tcp.T
                       @ np.asarray(ALIGN_BASE_ROT[cfg_num], np.float64))
    return {s: m @ world_from_base for s, m in mats.items()}
