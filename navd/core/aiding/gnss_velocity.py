"""GNSS velocity update (antenna lever arm in body FRD, rate-induced velocity removed).

Innovation, computed minus measured, NED m/s::

    z = v_hat + C_hat (w_hat x l_b) - v_gnss
    z = [(C (w x l)) x] phi + dv - C [l x] dbg + v,     v ~ N(0, R_v)

where ``w_hat = w + dbg`` is the bias-compensated body rate (bias errors are residuals).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from navd.core._jit import jit

Arr = npt.NDArray[np.float64]


@jit
def fill(H: Arr, z: Arr, R: Arr, mat_nb: Arr, vel_n: Arr, rate_b: Arr, lever_b: Arr,
         vn: float, ve: float, vd: float, sd_h: float, sd_v: float,
         lever_var: float = 0.0) -> int:
    """Write the 3-row velocity block into rows 0..2 of H, z, R; return m = 3.

    ``lever_var``: variance per axis of the lever arm's error dl (m^2); the velocity it makes,
    C (w x dl), adds ``lever_var C [w x][w x]^T C^T`` to R (full 3x3), which the course row
    inherits through R (:func:`navd.core.aiding.gnss_heading.course_row`).
    """
    H[:, :] = 0.0
    R[:, :] = 0.0
    # w x l in body
    wx = rate_b[1] * lever_b[2] - rate_b[2] * lever_b[1]
    wy = rate_b[2] * lever_b[0] - rate_b[0] * lever_b[2]
    wz = rate_b[0] * lever_b[1] - rate_b[1] * lever_b[0]
    ux = mat_nb[0, 0] * wx + mat_nb[0, 1] * wy + mat_nb[0, 2] * wz
    uy = mat_nb[1, 0] * wx + mat_nb[1, 1] * wy + mat_nb[1, 2] * wz
    uz = mat_nb[2, 0] * wx + mat_nb[2, 1] * wy + mat_nb[2, 2] * wz
    z[0] = vel_n[0] + ux - vn
    z[1] = vel_n[1] + uy - ve
    z[2] = vel_n[2] + uz - vd
    H[0, 1] = -uz
    H[0, 2] = uy
    H[1, 0] = uz
    H[1, 2] = -ux
    H[2, 0] = -uy
    H[2, 1] = ux
    H[0, 3] = 1.0
    H[1, 4] = 1.0
    H[2, 5] = 1.0
    # -C [l x]
    lx, ly, lz = lever_b[0], lever_b[1], lever_b[2]
    for i in range(3):
        c0, c1, c2 = mat_nb[i, 0], mat_nb[i, 1], mat_nb[i, 2]
        H[i, 9] = -(c1 * lz - c2 * ly)
        H[i, 10] = -(-c0 * lz + c2 * lx)
        H[i, 11] = -(c0 * ly - c1 * lx)
    R[0, 0] = sd_h * sd_h
    R[1, 1] = sd_h * sd_h
    R[2, 2] = sd_v * sd_v
    if lever_var > 0.0:
        lever_noise(R, mat_nb, rate_b, lever_var)
    return 3


@jit
def lever_noise(R: Arr, mat_nb: Arr, rate_b: Arr, lever_var: float) -> None:
    """R[0:3, 0:3] += lever_var C ([w x][w x]^T) C^T, [w x][w x]^T = |w|^2 I - w w^T: the
    covariance of C (w x dl) for dl ~ N(0, lever_var I).  A lever arm is one fixed error, so
    the velocity it makes persists through a turn; taken as white noise it only keeps the
    update from trusting those velocities more than they deserve (docs/results.md)."""
    w0, w1, w2 = rate_b[0], rate_b[1], rate_b[2]
    ww = w0 * w0 + w1 * w1 + w2 * w2
    # M = C (|w|^2 I - w w^T) C^T = |w|^2 I - (C w)(C w)^T  (C orthonormal)
    c0 = mat_nb[0, 0] * w0 + mat_nb[0, 1] * w1 + mat_nb[0, 2] * w2
    c1 = mat_nb[1, 0] * w0 + mat_nb[1, 1] * w1 + mat_nb[1, 2] * w2
    c2 = mat_nb[2, 0] * w0 + mat_nb[2, 1] * w1 + mat_nb[2, 2] * w2
    cw = (c0, c1, c2)
    for i in range(3):
        for j in range(3):
            m = (ww if i == j else 0.0) - cw[i] * cw[j]
            R[i, j] += lever_var * m


@jit
def delay_noise(R: Arr, ax: float, ay: float, az: float, delay_var: float) -> None:
    """R[0:3, 0:3] += delay_var a a^T: the covariance of the velocity error a dt of a fix
    whose time of validity is off by dt ~ N(0, delay_var) (s^2), a the vehicle's NED
    acceleration (m/s^2).  Like the lever arm's, the error is one fixed latency taken as
    white: it keeps a lagging receiver's velocities from being trusted while the vehicle
    accelerates or turns (a turn's lag looks like a yaw error of yaw rate x dt)."""
    a = (ax, ay, az)
    for i in range(3):
        for j in range(3):
            R[i, j] += delay_var * a[i] * a[j]
