"""Attitude series as arrays: vectorised quaternion and Euler maths for logs and reports.

The estimator's own rotation kernels (:mod:`navd.core.rotation`) work on one attitude at a
time inside numba; offline code (flight-log readers, the evaluation report) handles whole
series at once.  Quaternions are scalar-first ``(w, x, y, z)`` rows of shape (K, 4) for
C_b^n; Euler angles are ZYX ``(roll, pitch, yaw)`` rows of shape (K, 3), rad.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]


def euler_to_quat(euler_rad: F64) -> F64:
    """(K, 3) roll, pitch, yaw, rad -> (K, 4) quaternion of C = Rz Ry Rx."""
    h = euler_rad * 0.5
    cr, sr = np.cos(h[:, 0]), np.sin(h[:, 0])
    cp, sp = np.cos(h[:, 1]), np.sin(h[:, 1])
    cy, sy = np.cos(h[:, 2]), np.sin(h[:, 2])
    return np.stack([cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
                     cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy], 1)


def quat_to_euler(q: F64) -> F64:
    """(K, 4) quaternion (normalised here: logs store rounded ones) -> (K, 3) ZYX Euler, rad."""
    n = np.linalg.norm(q, axis=1)
    q = q / np.where(n > 0.0, n, 1.0)[:, None]
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    roll = np.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2.0 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return np.stack([roll, pitch, yaw], 1)


def quat_mul(a: F64, b: F64) -> F64:
    """Hamilton product of (K, 4) quaternions (or (1, 4) broadcast against (K, 4))."""
    w1, x1, y1, z1 = a[:, 0], a[:, 1], a[:, 2], a[:, 3]
    w2, x2, y2, z2 = b[:, 0], b[:, 1], b[:, 2], b[:, 3]
    return np.stack([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2],
                    1)


def quat_conj(q: F64) -> F64:
    """The inverse rotation of unit quaternions (K, 4)."""
    return np.asarray(q * np.array([1.0, -1.0, -1.0, -1.0]), dtype=np.float64)


def rotation_angle(q_a: F64, q_b: F64) -> F64:
    """(K,) angle of the rotation between two unit-quaternion series, rad (NaN where either
    is NaN)."""
    dot = np.abs(np.sum(q_a * q_b, axis=1))
    return np.asarray(2.0 * np.arccos(np.clip(dot, 0.0, 1.0)), dtype=np.float64)
