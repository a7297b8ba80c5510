"""Strapdown mechanization on IMU increments (WGS-84, NED), and its exact inverse.

One step from t_k to t_k+1 = t_k + T, with bias-compensated increments (dtheta, dv) in
body FRD and the previous step's increments (dtheta', dv')::

    alpha  = dtheta + dtheta' x dtheta / 12                         (coning)
    dv_c   = dv + dtheta x dv / 2 + (dtheta' x dv + dv' x dtheta) / 12   (rotation + sculling)
    zeta   = omega_in^n(p_k, v_k) T
    v_k+1  = v_k + (I - [zeta x]/2) C_k dv_c + (g^n(p_k) - (2 omega_ie + omega_en) x v_k) T
    C_k+1  = Exp(-zeta) C_k Exp(alpha)
    p_k+1  : trapezoidal velocity, radii at L_k, mid-height and mid-latitude

g^n = [-xi gamma, -eta gamma, gamma + dg_D] carries the deflection of the vertical when a DOV
model is active (``dov`` = (xi, eta, dg_D) in rad, rad, m/s^2; zeros otherwise).

The simulator generates IMU increments with :func:`invert_trajectory`, the algebraic
inverse of the step above, so an error-free IMU replays its truth to round-off.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from navd.core._jit import jit
from navd.core.earth import OMEGA_IE, gravity, radii
from navd.core.rotation import exp_into, log_so3, mul3_into, mul3t_into

Arr = npt.NDArray[np.float64]


@jit
def position_step(pos: Arr, vn0: float, ve0: float, vd0: float,
                  vn1: float, ve1: float, vd1: float, dt: float) -> None:
    """Advance pos = (lat_rad, lon_rad, alt_m) in place with trapezoidal velocity."""
    lat = pos[0]
    h = pos[2]
    r_m, r_n = radii(lat)
    h1 = h - 0.5 * (vd0 + vd1) * dt
    hm = 0.5 * (h + h1)
    lat1 = lat + 0.5 * (vn0 + vn1) * dt / (r_m + hm)
    lm = 0.5 * (lat + lat1)
    pos[1] = pos[1] + 0.5 * (ve0 + ve1) * dt / ((r_n + hm) * math.cos(lm))
    pos[0] = lat1
    pos[2] = h1


@jit
def nav_rates(pos: Arr, vel_n: Arr, w_ie: Arr, w_en: Arr) -> None:
    """Write earth rate and transport rate (NED, rad/s) at (pos, vel_n) into w_ie, w_en."""
    lat = pos[0]
    h = pos[2]
    r_m, r_n = radii(lat)
    w_ie[0] = OMEGA_IE * math.cos(lat)
    w_ie[1] = 0.0
    w_ie[2] = -OMEGA_IE * math.sin(lat)
    w_en[0] = vel_n[1] / (r_n + h)
    w_en[1] = -vel_n[0] / (r_m + h)
    w_en[2] = -vel_n[1] * math.tan(lat) / (r_n + h)


@jit
def gravity_n(pos: Arr, dov: Arr, g_n: Arr) -> None:
    """Gravity vector in NED including the deflection of the vertical, m/s^2."""
    gam = gravity(pos[0], pos[2])
    g_n[0] = -dov[0] * gam
    g_n[1] = -dov[1] * gam
    g_n[2] = gam + dov[2]


@jit
def strapdown_step(mat_nb: Arr, vel_n: Arr, pos: Arr, dov: Arr,
                   inc: Arr, prev_inc: Arr, dt: float, coning: bool, work: Arr) -> None:
    """Advance (mat_nb, vel_n, pos) by one IMU interval, in place.

    Args:
        mat_nb: C_b^n (3, 3), updated.
        vel_n: NED velocity (3,), m/s, updated.
        pos: (lat_rad, lon_rad, alt_m), updated.
        dov: (xi_rad, eta_rad, dg_d_mps2) gravity disturbance.
        inc: bias-compensated (dtheta_xyz rad, dv_xyz m/s) of this interval (6,).
        prev_inc: the same for the previous interval (6,), zeros at start.
        dt: interval, s.
        coning: apply coning and sculling corrections.
        work: scratch, shape (8, 3, 3).
    """
    w_ie = work[0, 0]
    w_en = work[0, 1]
    g_n = work[0, 2]
    nav_rates(pos, vel_n, w_ie, w_en)
    gravity_n(pos, dov, g_n)
    zx = (w_ie[0] + w_en[0]) * dt
    zy = (w_ie[1] + w_en[1]) * dt
    zz = (w_ie[2] + w_en[2]) * dt
    tx, ty, tz = inc[0], inc[1], inc[2]
    vx, vy, vz = inc[3], inc[4], inc[5]
    ax, ay, az = tx, ty, tz
    cx = vx + 0.5 * (ty * vz - tz * vy)
    cy = vy + 0.5 * (tz * vx - tx * vz)
    cz = vz + 0.5 * (tx * vy - ty * vx)
    if coning:
        px, py, pz = prev_inc[0], prev_inc[1], prev_inc[2]
        qx, qy, qz = prev_inc[3], prev_inc[4], prev_inc[5]
        ax += (py * tz - pz * ty) / 12.0
        ay += (pz * tx - px * tz) / 12.0
        az += (px * ty - py * tx) / 12.0
        cx += ((py * vz - pz * vy) + (qy * tz - qz * ty)) / 12.0
        cy += ((pz * vx - px * vz) + (qz * tx - qx * tz)) / 12.0
        cz += ((px * vy - py * vx) + (qx * ty - qy * tx)) / 12.0
    c = mat_nb
    # specific-force increment in n(k), then rotated half a step for the n-frame motion
    sx = c[0, 0] * cx + c[0, 1] * cy + c[0, 2] * cz
    sy = c[1, 0] * cx + c[1, 1] * cy + c[1, 2] * cz
    sz = c[2, 0] * cx + c[2, 1] * cy + c[2, 2] * cz
    dnx = sx - 0.5 * (zy * sz - zz * sy)
    dny = sy - 0.5 * (zz * sx - zx * sz)
    dnz = sz - 0.5 * (zx * sy - zy * sx)
    v0n, v0e, v0d = vel_n[0], vel_n[1], vel_n[2]
    ox = 2.0 * w_ie[0] + w_en[0]
    oy = 2.0 * w_ie[1] + w_en[1]
    oz = 2.0 * w_ie[2] + w_en[2]
    vel_n[0] = v0n + dnx + (g_n[0] - (oy * v0d - oz * v0e)) * dt
    vel_n[1] = v0e + dny + (g_n[1] - (oz * v0n - ox * v0d)) * dt
    vel_n[2] = v0d + dnz + (g_n[2] - (ox * v0e - oy * v0n)) * dt
    # attitude: C <- Exp(-zeta) C Exp(alpha)
    e_n = work[1]
    e_b = work[2]
    tmp = work[3]
    exp_into(e_n, -zx, -zy, -zz)
    exp_into(e_b, ax, ay, az)
    mul3_into(tmp, c, e_b)
    mul3_into(c, e_n, tmp)
    position_step(pos, v0n, v0e, v0d, vel_n[0], vel_n[1], vel_n[2], dt)


@jit
def integrate_positions(vel_n: Arr, pos0: Arr, dt: float, out: Arr) -> None:
    """Integrate positions (N, 3) from velocities (N, 3) exactly as the strapdown does."""
    p = pos0.copy()
    out[0] = p
    for k in range(vel_n.shape[0] - 1):
        position_step(p, vel_n[k, 0], vel_n[k, 1], vel_n[k, 2],
                      vel_n[k + 1, 0], vel_n[k + 1, 1], vel_n[k + 1, 2], dt)
        out[k + 1] = p


@jit
def _solve3(a: Arr, b: Arr, x: Arr) -> None:
    """x = a^-1 b for a 3x3 system (Cramer's rule; the systems here are near-identity)."""
    det = (a[0, 0] * (a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1])
           - a[0, 1] * (a[1, 0] * a[2, 2] - a[1, 2] * a[2, 0])
           + a[0, 2] * (a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]))
    for col in range(3):
        m = a.copy()
        for r in range(3):
            m[r, col] = b[r]
        x[col] = (m[0, 0] * (m[1, 1] * m[2, 2] - m[1, 2] * m[2, 1])
                  - m[0, 1] * (m[1, 0] * m[2, 2] - m[1, 2] * m[2, 0])
                  + m[0, 2] * (m[1, 0] * m[2, 1] - m[1, 1] * m[2, 0])) / det


@jit
def invert_trajectory(mats: Arr, vels: Arr, poss: Arr, dovs: Arr, dt: float,
                      coning: bool, incs: Arr) -> None:
    """IMU increments that make :func:`strapdown_step` reproduce a trajectory exactly.

    Args:
        mats: C_b^n at each sample (N, 3, 3).
        vels: NED velocity (N, 3), m/s.
        poss: positions (N, 3) integrated by :func:`integrate_positions`.
        dovs: gravity disturbance (xi, eta, dg_D) at each sample (N, 3).
        dt: sample interval, s.
        coning: whether the replaying strapdown applies coning/sculling.
        incs: output (N - 1, 6): dtheta (rad), dv (m/s) over each interval, body FRD.
    """
    w_ie = np.zeros(3)
    w_en = np.zeros(3)
    g_n = np.zeros(3)
    e_n = np.zeros((3, 3))
    tmp = np.zeros((3, 3))
    m = np.zeros((3, 3))
    a = np.zeros((3, 3))
    rhs = np.zeros(3)
    dth = np.zeros(3)
    dv = np.zeros(3)
    prev = np.zeros(6)
    for k in range(mats.shape[0] - 1):
        c0 = mats[k]
        c1 = mats[k + 1]
        nav_rates(poss[k], vels[k], w_ie, w_en)
        gravity_n(poss[k], dovs[k], g_n)
        zx = (w_ie[0] + w_en[0]) * dt
        zy = (w_ie[1] + w_en[1]) * dt
        zz = (w_ie[2] + w_en[2]) * dt
        exp_into(e_n, zx, zy, zz)
        mul3t_into(tmp, c0, e_n)
        mul3_into(m, tmp, c1)
        alpha = log_so3(m)
        px, py, pz = prev[0], prev[1], prev[2]
        if coning:
            # (I + [dtheta' x]/12) dtheta = alpha
            a[:, :] = 0.0
            a[0, 0] = 1.0
            a[1, 1] = 1.0
            a[2, 2] = 1.0
            a[0, 1] = -pz / 12.0
            a[0, 2] = py / 12.0
            a[1, 0] = pz / 12.0
            a[1, 2] = -px / 12.0
            a[2, 0] = -py / 12.0
            a[2, 1] = px / 12.0
            rhs[0], rhs[1], rhs[2] = alpha
            _solve3(a, rhs, dth)
        else:
            dth[0], dth[1], dth[2] = alpha
        v0 = vels[k]
        o = 2.0 * w_ie + w_en
        cor = np.cross(o, v0)
        dvn = vels[k + 1] - v0 - (g_n - cor) * dt
        # (I - [zeta x]/2) s = dvn  ->  s
        a[:, :] = 0.0
        a[0, 0] = 1.0
        a[1, 1] = 1.0
        a[2, 2] = 1.0
        a[0, 1] = 0.5 * zz
        a[0, 2] = -0.5 * zy
        a[1, 0] = -0.5 * zz
        a[1, 2] = 0.5 * zx
        a[2, 0] = 0.5 * zy
        a[2, 1] = -0.5 * zx
        s = np.zeros(3)
        _solve3(a, dvn, s)
        y = np.zeros(3)
        for i in range(3):
            y[i] = c0[0, i] * s[0] + c0[1, i] * s[1] + c0[2, i] * s[2]
        tx, ty, tz = dth[0], dth[1], dth[2]
        # (I + [dtheta x]/2 + [dtheta' x]/12) dv = y - dv' x dtheta / 12
        kx = 0.5 * tx
        ky = 0.5 * ty
        kz = 0.5 * tz
        if coning:
            kx += px / 12.0
            ky += py / 12.0
            kz += pz / 12.0
            qx, qy, qz = prev[3], prev[4], prev[5]
            y[0] -= (qy * tz - qz * ty) / 12.0
            y[1] -= (qz * tx - qx * tz) / 12.0
            y[2] -= (qx * ty - qy * tx) / 12.0
        a[0, 0] = 1.0
        a[1, 1] = 1.0
        a[2, 2] = 1.0
        a[0, 1] = -kz
        a[0, 2] = ky
        a[1, 0] = kz
        a[1, 2] = -kx
        a[2, 0] = -ky
        a[2, 1] = kx
        _solve3(a, y, dv)
        incs[k, 0:3] = dth
        incs[k, 3:6] = dv
        prev[0:3] = dth
        prev[3:6] = dv
