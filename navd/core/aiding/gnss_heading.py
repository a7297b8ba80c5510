"""Completed heading update: heading from GNSS course (seed 001), docs/design.md §4.

With chi = atan2(vE, vN) the course of the lever-arm-corrected GNSS velocity, and psi_hat
the INS yaw, the innovation and its linear model are::

    z = wrap(psi_hat - chi)
    z = -tan(theta) (cos(psi) phiN + sin(psi) phiE) - phiD + J ([(C u) x] phi - C [l x] dbg)
        + v_chi

(from C_hat = Exp(-phi) C; the seed's eq. 21 coefficient mapped to NED and to our error
sign; the J terms come from removing the lever-arm velocity C_hat (w_hat x l), u = w x l,
from the GNSS velocity before taking its course).
chi shares its noise with the velocity measurement: with ``J = [-vE, vN, 0]/|v_h|^2``
the joint covariance of (velocity, course) innovations is ``[[R_v, R_v J^T], [J R_v,
J R_v J^T + s_beta^2]]``, where s_beta models sideslip/crab.  The block is appended to the
velocity block (row 3) and whitened jointly in :func:`navd.core.kalman.gated_update`.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from navd.core._jit import jit

Arr = npt.NDArray[np.float64]


@jit
def course_row(H: Arr, z: Arr, R: Arr, row: int, mat_nb: Arr, rate_b: Arr, lever_b: Arr,
               vn: float, ve: float, sd_h: float, sd_beta: float) -> None:
    """Write the course row at ``row`` of H/z and its (co)variances into R.

    R[0:row, 0:row] must already hold the velocity covariance R_v when row == 3 (joint);
    with row == 0 only the course variance ``sd_h^2/|v_h|^2 + sd_beta^2`` is written
    (course-only update; sd_h is the per-axis horizontal speed sigma, m/s).
    """
    yaw = math.atan2(mat_nb[1, 0], mat_nb[0, 0])
    sp = -mat_nb[2, 0]
    cp = math.sqrt(max(0.0, 1.0 - sp * sp))
    tp = sp / max(cp, 1e-9)
    chi = math.atan2(ve, vn)
    d = yaw - chi
    z[row] = (d + math.pi) % (2.0 * math.pi) - math.pi
    for k in range(H.shape[1]):
        H[row, k] = 0.0
    vh2 = vn * vn + ve * ve
    jn = -ve / vh2
    je = vn / vh2
    # (vn, ve) had C_hat (w_hat x l) removed, which depends on phi and dbg:
    # d(course) = J d(v_c),  d(v_c) = -[(C u) x] phi + C [l x] dbg,  u = w x l
    ux = rate_b[1] * lever_b[2] - rate_b[2] * lever_b[1]
    uy = rate_b[2] * lever_b[0] - rate_b[0] * lever_b[2]
    uz = rate_b[0] * lever_b[1] - rate_b[1] * lever_b[0]
    cu0 = mat_nb[0, 0] * ux + mat_nb[0, 1] * uy + mat_nb[0, 2] * uz
    cu1 = mat_nb[1, 0] * ux + mat_nb[1, 1] * uy + mat_nb[1, 2] * uz
    cu2 = mat_nb[2, 0] * ux + mat_nb[2, 1] * uy + mat_nb[2, 2] * uz
    # J [(Cu) x] = [jn, je, 0] [[0, -cu2, cu1], [cu2, 0, -cu0], [-cu1, cu0, 0]]
    H[row, 0] = -tp * math.cos(yaw) + je * cu2
    H[row, 1] = -tp * math.sin(yaw) - jn * cu2
    H[row, 2] = -1.0 + jn * cu1 - je * cu0
    lx, ly, lz = lever_b[0], lever_b[1], lever_b[2]
    for i in range(2):
        ji = jn if i == 0 else je
        c0, c1, c2 = mat_nb[i, 0], mat_nb[i, 1], mat_nb[i, 2]
        # - J C [l x]: row i of C [l x] is (c1 lz - c2 ly, c2 lx - c0 lz, c0 ly - c1 lx)
        H[row, 9] -= ji * (c1 * lz - c2 * ly)
        H[row, 10] -= ji * (c2 * lx - c0 * lz)
        H[row, 11] -= ji * (c0 * ly - c1 * lx)
    if row == 3:
        c0 = jn * R[0, 0] + je * R[1, 0]
        c1 = jn * R[0, 1] + je * R[1, 1]
        c2 = jn * R[0, 2] + je * R[1, 2]
        R[3, 0] = c0
        R[3, 1] = c1
        R[3, 2] = c2
        R[0, 3] = c0
        R[1, 3] = c1
        R[2, 3] = c2
        R[3, 3] = jn * c0 + je * c1 + sd_beta * sd_beta
    else:
        R[row, row] = sd_h * sd_h / vh2 + sd_beta * sd_beta


def course_sd(speed_sd_mps: float, speed_h_mps: float) -> float:
    """1-sigma of the course from a per-axis speed accuracy, rad (sigma_v / |v_h|)."""
    return speed_sd_mps / speed_h_mps
