"""Rotation and quaternion arithmetic through scipy. Quaternions are (w, x, y, z) here, (x, y, z, w) in scipy;
transforms3d's default Euler axes ``sxyz`` are scipy's static "xyz" (conventions pinned by tests/test_rh20t.py)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def euler_sxyz_to_mat(ai: float, aj: float, ak: float) -> np.ndarray:
    """Static-axes x-y-z Euler angles (transforms3d's default ``sxyz``, used by rh20t_api) -> rotation matrix."""
    return Rotation.from_euler("xyz", [ai, aj, ak]).as_matrix()


def quat_to_mat(q: np.ndarray) -> np.ndarray:
    """Quaternion (w, x, y, z), normalised first -> rotation matrix."""
    return Rotation.from_quat(np.roll(np.asarray(q, np.float64), -1)).as_matrix()


def rotvec_to_mat(v: np.ndarray) -> np.ndarray:
    """Rotation vector (axis * angle) -> rotation matrix."""
    return Rotation.from_rotvec(np.asarray(v, np.float64)).as_matrix()


def align_quaternions(q: np.ndarray) -> np.ndarray:
    """Flip signs so consecutive quaternions lie in the same hemisphere (q and -q are the same rotation)."""
    q = q.copy()
    for i in range(1, len(q)):
        if np.dot(q[i], q[i - 1]) < 0:
            q[i] = -q[i]
    if len(q) and q[0, 0] < 0:
        q = -q
    return q


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of (..., 4) quaternions in (w, x, y, z) order."""
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack([aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw], -1)


def quat_to_rotvec(q: np.ndarray) -> np.ndarray:
    """(..., 4) unit quaternions (w, x, y, z) -> (..., 3) rotation vectors (shortest rotation)."""
    q = np.where(q[..., :1] < 0, -q, q)
    v = q[..., 1:]
    s = np.linalg.norm(v, axis=-1, keepdims=True)
    angle = 2 * np.arctan2(s, q[..., :1])
    scale = np.where(s > 1e-12, angle / np.maximum(s, 1e-12), 2.0)  # small-angle limit: 2 v
    return v * scale
