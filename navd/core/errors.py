"""Continuous-time 15-state error model ``dx/dt = F x + G w`` in NED (docs/design.md §3).

State order and sign conventions are those of :mod:`navd`.  With ``RMh = R_M + h``,
``RNh = R_N + h``, ``w_in = w_ie + w_en`` and ``f^n = C f^b``::

    dphi/dt = -[w_in x] phi + dw_in(dv, dp) - C dbg
    ddv/dt  = [f^n x] phi - (2 w_ie + w_en) x dv - (2 dw_ie + dw_en) x v + dg(dp) + C dba
    ddp/dt  = d(lat_dot, lon_dot, h_dot)/d(v, p)

The seed papers print this matrix in ENU with several wrong entries (docs/design.md §3 lists them);
this one is derived from the mechanization and tested against its numerical Jacobian, so
the derivatives of the radii of curvature and of normal gravity are kept rather than
neglected (they cost nothing and make the test tight).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from navd.core._jit import jit
from navd.core.earth import OMEGA_IE, gravity_derivs, radii, radii_dlat

Arr = npt.NDArray[np.float64]

N_STATES = 15
I_ATT = 0
I_VEL = 3
I_POS = 6
I_BG = 9
I_BA = 12


@jit
def build_f(F: Arr, mat_nb: Arr, vel_n: Arr, pos: Arr, f_n: Arr) -> None:
    """Fill ``F`` (15, 15) at the nominal state.

    Args:
        F: output, overwritten entirely.
        mat_nb: C_b^n (3, 3).
        vel_n: NED velocity (3,), m/s.
        pos: (lat_rad, lon_rad, alt_m).
        f_n: specific force in NED (3,), m/s^2 (mean over the propagation interval).
    """
    F[:, :] = 0.0
    lat = pos[0]
    h = pos[2]
    vn, ve, vd = vel_n[0], vel_n[1], vel_n[2]
    sl, cl = math.sin(lat), math.cos(lat)
    tl = sl / cl
    r_m, r_n = radii(lat)
    drm, drn = radii_dlat(lat)
    rmh = r_m + h
    rnh = r_n + h
    om = OMEGA_IE
    # w_in and its partials
    wx = om * cl + ve / rnh
    wy = -vn / rmh
    wz = -om * sl - ve * tl / rnh
    # d w_in / d lat (radii derivatives included)
    dwx_dl = -om * sl - ve * drn / (rnh * rnh)
    dwy_dl = vn * drm / (rmh * rmh)
    dwz_dl = -om * cl - ve / (rnh * cl * cl) + ve * tl * drn / (rnh * rnh)
    # d w_in / d h
    dwx_dh = -ve / (rnh * rnh)
    dwy_dh = vn / (rmh * rmh)
    dwz_dh = ve * tl / (rnh * rnh)

    # attitude rows
    F[0, 1] = wz
    F[0, 2] = -wy
    F[1, 0] = -wz
    F[1, 2] = wx
    F[2, 0] = wy
    F[2, 1] = -wx
    F[0, 4] = 1.0 / rnh
    F[1, 3] = -1.0 / rmh
    F[2, 4] = -tl / rnh
    F[0, 6] = dwx_dl
    F[1, 6] = dwy_dl
    F[2, 6] = dwz_dl
    F[0, 8] = dwx_dh
    F[1, 8] = dwy_dh
    F[2, 8] = dwz_dh
    for i in range(3):
        for j in range(3):
            F[i, 9 + j] = -mat_nb[i, j]
            F[3 + i, 12 + j] = mat_nb[i, j]

    # velocity rows: vdot = f^n - (2 w_ie + w_en) x v + g
    F[3, 1] = -f_n[2]
    F[3, 2] = f_n[1]
    F[4, 0] = f_n[2]
    F[4, 2] = -f_n[0]
    F[5, 0] = -f_n[1]
    F[5, 1] = f_n[0]
    # o = 2 w_ie + w_en as a function of (v, lat, h)
    ox = 2.0 * om * cl + ve / rnh
    oy = -vn / rmh
    oz = -2.0 * om * sl - ve * tl / rnh
    # -(o x v) = [-(oy vd - oz ve), -(oz vn - ox vd), -(ox ve - oy vn)]
    # partials of o wrt vn, ve
    do_dvn = (0.0, -1.0 / rmh, 0.0)
    do_dve = (1.0 / rnh, 0.0, -tl / rnh)
    # d(-(o x v))/dv = [v x] do/dv - [o x]
    F[3, 3] = -(do_dvn[1] * vd - do_dvn[2] * ve)
    F[4, 3] = -(do_dvn[2] * vn - do_dvn[0] * vd) - oz
    F[5, 3] = -(do_dvn[0] * ve - do_dvn[1] * vn) + oy
    F[3, 4] = -(do_dve[1] * vd - do_dve[2] * ve) + oz
    F[4, 4] = -(do_dve[2] * vn - do_dve[0] * vd)
    F[5, 4] = -(do_dve[0] * ve - do_dve[1] * vn) - ox
    F[3, 5] = -oy
    F[4, 5] = ox
    F[5, 5] = 0.0
    # partials of o wrt lat and h
    dox_dl = -2.0 * om * sl - ve * drn / (rnh * rnh)
    doy_dl = vn * drm / (rmh * rmh)
    doz_dl = -2.0 * om * cl - ve / (rnh * cl * cl) + ve * tl * drn / (rnh * rnh)
    dox_dh = -ve / (rnh * rnh)
    doy_dh = vn / (rmh * rmh)
    doz_dh = ve * tl / (rnh * rnh)
    dg_dl, dg_dh = gravity_derivs(lat, h)
    F[3, 6] = -(doy_dl * vd - doz_dl * ve)
    F[4, 6] = -(doz_dl * vn - dox_dl * vd)
    F[5, 6] = -(dox_dl * ve - doy_dl * vn) + dg_dl
    F[3, 8] = -(doy_dh * vd - doz_dh * ve)
    F[4, 8] = -(doz_dh * vn - dox_dh * vd)
    F[5, 8] = -(dox_dh * ve - doy_dh * vn) + dg_dh

    # position rows: lat' = vn/RMh, lon' = ve/(RNh cos L), h' = -vd
    F[6, 3] = 1.0 / rmh
    F[6, 6] = -vn * drm / (rmh * rmh)
    F[6, 8] = -vn / (rmh * rmh)
    F[7, 4] = 1.0 / (rnh * cl)
    F[7, 6] = ve * tl / (rnh * cl) - ve * drn / (rnh * rnh * cl)
    F[7, 8] = -ve / (rnh * rnh * cl)
    F[8, 5] = -1.0
