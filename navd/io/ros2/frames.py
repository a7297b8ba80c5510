"""navd's frames (NED navigation, FRD body) -> ROS's (ENU world, FLU body; REP-103, REP-145).

Two fixed rotations, each a half turn:

    v_enu = M v_ned,  M = [[0, 1, 0], [1, 0, 0], [0, 0, -1]]   (pi about (N + E)/sqrt 2)
    v_frd = D v_flu,  D = diag(1, -1, -1)                      (pi about the forward axis)

so the body-to-world rotation a ROS consumer wants is ``C_flu^enu = M C_frd^ned D`` and, as
Hamilton quaternions, ``q_enu_flu = q_M * q_nb * q_D`` with ``q_M = (0, 1/sqrt 2, 1/sqrt 2, 0)``
and ``q_D = (0, 1, 0, 0)`` (w, x, y, z).  For the angles this means: roll unchanged, pitch
negated (FLU's y axis points left, so nose-up is a negative rotation), yaw measured
counter-clockwise from east: ``yaw_enu = pi/2 - yaw_ned``.  The variances of the three angles
are unchanged by these sign flips.
"""

from __future__ import annotations

import math

__all__ = ["Q_ENU_NED", "Q_FRD_FLU", "frd_to_flu", "ned_to_enu", "quat_enu_flu", "quat_mul"]

Quat = tuple[float, float, float, float]
Vec3 = tuple[float, float, float]

_H = math.sqrt(0.5)
Q_ENU_NED: Quat = (0.0, _H, _H, 0.0)  # (w, x, y, z) of M
Q_FRD_FLU: Quat = (0.0, 1.0, 0.0, 0.0)  # (w, x, y, z) of D


def quat_mul(a: Quat, b: Quat) -> Quat:
    """Hamilton product a * b, scalar first (the rotation b, then a)."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw)


def quat_enu_flu(quat_nb: Quat) -> Quat:
    """(w, x, y, z) of C_flu^enu (body FLU -> ENU) from navd's C_frd^ned, unit length, w >= 0."""
    q = quat_mul(quat_mul(Q_ENU_NED, quat_nb), Q_FRD_FLU)
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    s = (1.0 if q[0] >= 0.0 else -1.0) / n
    return (q[0] * s, q[1] * s, q[2] * s, q[3] * s)


def ned_to_enu(v_ned: Vec3) -> Vec3:
    """A vector in NED -> the same vector in ENU."""
    return (v_ned[1], v_ned[0], -v_ned[2])


def frd_to_flu(v_frd: Vec3) -> Vec3:
    """A vector in body FRD -> the same vector in body FLU."""
    return (v_frd[0], -v_frd[1], -v_frd[2])
