"""Truth trajectory -> error-free IMU increments, exact for navd's own strapdown.

Positions come from :func:`navd.core.strapdown.integrate_positions` (the strapdown's own
position update) and increments from :func:`navd.core.strapdown.invert_trajectory` (its
algebraic inverse, coning/sculling on), so replaying the increments through
:func:`navd.core.strapdown.strapdown_step` reproduces attitude, velocity and position to
round-off.  Any smooth attitude/velocity history is admissible; the profiles only have to be
physically plausible.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from navd.core.strapdown import integrate_positions, invert_trajectory

Arr = npt.NDArray[np.float64]


def euler_to_mats(euler: Arr) -> Arr:
    """C_b^n = Rz(yaw) Ry(pitch) Rx(roll) for (N, 3) Euler angles (rad) -> (N, 3, 3)."""
    cr, sr = np.cos(euler[:, 0]), np.sin(euler[:, 0])
    cp, sp = np.cos(euler[:, 1]), np.sin(euler[:, 1])
    cy, sy = np.cos(euler[:, 2]), np.sin(euler[:, 2])
    m = np.empty((euler.shape[0], 3, 3))
    m[:, 0, 0] = cp * cy
    m[:, 0, 1] = sr * sp * cy - cr * sy
    m[:, 0, 2] = cr * sp * cy + sr * sy
    m[:, 1, 0] = cp * sy
    m[:, 1, 1] = sr * sp * sy + cr * cy
    m[:, 1, 2] = cr * sp * sy - sr * cy
    m[:, 2, 0] = -sp
    m[:, 2, 1] = sr * cp
    m[:, 2, 2] = cr * cp
    return m


def wrap_pi(a: Arr) -> Arr:
    """Wrap angles (rad) to (-pi, pi]."""
    return np.pi - np.mod(np.pi - a, 2.0 * np.pi)


@dataclass(frozen=True)
class Truth:
    """Truth at N + 1 sample times and the N error-free increments between them.

    Attributes:
        mat_nb: (N+1, 3, 3) C_b^n.
        euler: (N+1, 3) roll, pitch, yaw (rad, yaw wrapped to (-pi, pi]).
        vel_n: (N+1, 3) NED velocity, m/s.
        pos: (N+1, 3) lat_rad, lon_rad, alt_m (WGS-84).
        dov: (N+1, 3) xi (rad), eta (rad), dg_D (m/s^2).
        inc: (N, 6) dtheta xyz (rad), dvel xyz (m/s), body FRD; interval k runs k -> k+1.
    """

    mat_nb: Arr
    euler: Arr
    vel_n: Arr
    pos: Arr
    dov: Arr
    inc: Arr


def build_truth(euler: Arr, vel_n: Arr, pos0: Arr, dov: Arr, dt_s: float) -> Truth:
    """Integrate positions and invert the strapdown.

    Args:
        euler: (N+1, 3) roll, pitch, yaw, rad.
        vel_n: (N+1, 3) NED velocity, m/s.
        pos0: (3,) lat_rad, lon_rad, alt_m at the first sample.
        dov: (N+1, 3) gravity disturbance (xi rad, eta rad, dg_D m/s^2) at each sample.
        dt_s: sample interval, s.
    """
    mats = euler_to_mats(euler)
    vel = np.ascontiguousarray(vel_n, dtype=np.float64)
    pos = np.empty_like(vel)
    integrate_positions(vel, np.asarray(pos0, dtype=np.float64), dt_s, pos)
    inc = np.empty((vel.shape[0] - 1, 6))
    invert_trajectory(mats, vel, pos, np.ascontiguousarray(dov, dtype=np.float64), dt_s,
                      True, inc)
    eul = euler.copy()
    eul[:, 2] = wrap_pi(eul[:, 2])
    return Truth(mats, eul, vel, pos, dov, inc)
