"""Attitude outputs from the nominal state: Euler, quaternion and Euler-angle sigmas."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from navd.core._jit import jit
from navd.core.rotation import mat_to_euler, mat_to_quat

Arr = npt.NDArray[np.float64]


@jit
def euler_error_map(mat_nb: Arr, M: Arr) -> None:
    """M (3,3) with d(roll, pitch, yaw) = M phi for C_hat = Exp(-phi) C.

    C_hat = C Exp(-C^T phi): a body-frame rotation -C^T phi, mapped to Euler increments by
    the inverse of the ZYX rate kinematics.
    """
    roll, pitch, _ = mat_to_euler(mat_nb)
    sr, cr = math.sin(roll), math.cos(roll)
    cp = max(math.cos(pitch), 1e-9)
    tp = math.sin(pitch) / cp
    e00, e01, e02 = 1.0, sr * tp, cr * tp
    e10, e11, e12 = 0.0, cr, -sr
    e20, e21, e22 = 0.0, sr / cp, cr / cp
    for j in range(3):
        # (C^T)[:, j] = C[j, :]
        bx, by, bz = mat_nb[j, 0], mat_nb[j, 1], mat_nb[j, 2]
        M[0, j] = -(e00 * bx + e01 * by + e02 * bz)
        M[1, j] = -(e10 * bx + e11 * by + e12 * bz)
        M[2, j] = -(e20 * bx + e21 * by + e22 * bz)


@jit
def attitude_outputs(mat_nb: Arr, P: Arr, M: Arr) -> tuple[float, float, float, float, float,
                                                            float, float, float, float, float]:
    """(roll, pitch, yaw, qw, qx, qy, qz, sd_roll, sd_pitch, sd_yaw), rad."""
    roll, pitch, yaw = mat_to_euler(mat_nb)
    qw, qx, qy, qz = mat_to_quat(mat_nb)
    euler_error_map(mat_nb, M)
    v0 = 0.0
    v1 = 0.0
    v2 = 0.0
    for a in range(3):
        s = 0.0
        for i in range(3):
            for j in range(3):
                s += M[a, i] * P[i, j] * M[a, j]
        if a == 0:
            v0 = s
        elif a == 1:
            v1 = s
        else:
            v2 = s
    return (roll, pitch, yaw, qw, qx, qy, qz,
            math.sqrt(max(v0, 0.0)), math.sqrt(max(v1, 0.0)), math.sqrt(max(v2, 0.0)))
