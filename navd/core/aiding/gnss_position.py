"""GNSS position update (antenna lever arm in body FRD).

Innovation in NED metres, computed minus measured::

    z = D (p_hat - p_gnss) + C_hat l_b,      D = diag(R_M + h, (R_N + h) cos L, -1)
    z = [(C l_b) x] phi + D dp + v,          v ~ N(0, diag(sh^2, sh^2, sv^2))

(``C_hat l = (I - [phi x]) C l`` gives the attitude column.)
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from navd.core._jit import jit
from navd.core.earth import radii

Arr = npt.NDArray[np.float64]


@jit
def fill(H: Arr, z: Arr, R: Arr, mat_nb: Arr, pos: Arr, lever_b: Arr,
         lat_g: float, lon_g: float, alt_g: float, sd_h: float, sd_v: float) -> int:
    """Write the 3-row position block into H (4,15), z (4,), R (4,4); return m = 3."""
    lat = pos[0]
    h = pos[2]
    r_m, r_n = radii(lat)
    dn = r_m + h
    de = (r_n + h) * math.cos(lat)
    H[:, :] = 0.0
    R[:, :] = 0.0
    lx = mat_nb[0, 0] * lever_b[0] + mat_nb[0, 1] * lever_b[1] + mat_nb[0, 2] * lever_b[2]
    ly = mat_nb[1, 0] * lever_b[0] + mat_nb[1, 1] * lever_b[1] + mat_nb[1, 2] * lever_b[2]
    lz = mat_nb[2, 0] * lever_b[0] + mat_nb[2, 1] * lever_b[1] + mat_nb[2, 2] * lever_b[2]
    dlon = lon_g - pos[1]
    # wrap the longitude difference so the antimeridian is not a 360 degree jump
    dlon = (dlon + math.pi) % (2.0 * math.pi) - math.pi
    z[0] = (lat - lat_g) * dn + lx
    z[1] = -dlon * de + ly
    z[2] = -(h - alt_g) + lz
    H[0, 1] = -lz
    H[0, 2] = ly
    H[1, 0] = lz
    H[1, 2] = -lx
    H[2, 0] = -ly
    H[2, 1] = lx
    H[0, 6] = dn
    H[1, 7] = de
    H[2, 8] = -1.0
    R[0, 0] = sd_h * sd_h
    R[1, 1] = sd_h * sd_h
    R[2, 2] = sd_v * sd_v
    return 3


@jit
def delay_noise(R: Arr, vel_n: Arr, delay_var: float) -> None:
    """R[0:3, 0:3] += delay_var v v^T: the covariance of the position error v dt of a fix
    whose time of validity is off by dt ~ N(0, delay_var) (s^2), v = ``vel_n`` (3,) NED m/s
    (:func:`navd.core.aiding.gnss_velocity.delay_noise`)."""
    for i in range(3):
        for j in range(3):
            R[i, j] += delay_var * vel_n[i] * vel_n[j]
