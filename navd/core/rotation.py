"""SO(3) helpers: Exp/Log, DCM <-> quaternion <-> ZYX Euler (NED/FRD).

``mat`` arguments are 3x3 C_b^n style rotation matrices; quaternions are (w, x, y, z) with
``q`` and ``-q`` the same rotation; Euler angles are (roll, pitch, yaw) in rad for
``C = Rz(yaw) Ry(pitch) Rx(roll)``.  ``*_into`` variants write into caller-owned arrays and
allocate nothing (used in the estimator's hot path); the others return new arrays.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from navd.core._jit import jit

Arr = npt.NDArray[np.float64]


@jit
def skew_into(out: Arr, x: float, y: float, z: float) -> None:
    """out = [v x] (3x3), so that out @ w == cross(v, w)."""
    out[0, 0] = 0.0
    out[0, 1] = -z
    out[0, 2] = y
    out[1, 0] = z
    out[1, 1] = 0.0
    out[1, 2] = -x
    out[2, 0] = -y
    out[2, 1] = x
    out[2, 2] = 0.0


@jit
def exp_into(out: Arr, x: float, y: float, z: float) -> None:
    """out = Exp([x, y, z]) by Rodrigues' formula; series near zero keeps full precision."""
    th2 = x * x + y * y + z * z
    if th2 < 1e-8:
        # Taylor terms to th^4: error below 1e-20 at th^2 = 1e-8.
        a = 1.0 - th2 / 6.0 + th2 * th2 / 120.0
        b = 0.5 - th2 / 24.0 + th2 * th2 / 720.0
    else:
        th = math.sqrt(th2)
        a = math.sin(th) / th
        b = (1.0 - math.cos(th)) / th2
    out[0, 0] = 1.0 - b * (y * y + z * z)
    out[0, 1] = -a * z + b * x * y
    out[0, 2] = a * y + b * x * z
    out[1, 0] = a * z + b * x * y
    out[1, 1] = 1.0 - b * (x * x + z * z)
    out[1, 2] = -a * x + b * y * z
    out[2, 0] = -a * y + b * x * z
    out[2, 1] = a * x + b * y * z
    out[2, 2] = 1.0 - b * (x * x + y * y)


@jit
def mul3_into(out: Arr, a: Arr, b: Arr) -> None:
    """out = a @ b for 3x3 (no BLAS in compiled code; ``out`` must not alias)."""
    for i in range(3):
        for j in range(3):
            out[i, j] = a[i, 0] * b[0, j] + a[i, 1] * b[1, j] + a[i, 2] * b[2, j]


@jit
def mul3t_into(out: Arr, a: Arr, b: Arr) -> None:
    """out = a.T @ b for 3x3."""
    for i in range(3):
        for j in range(3):
            out[i, j] = a[0, i] * b[0, j] + a[1, i] * b[1, j] + a[2, i] * b[2, j]


@jit
def log_so3(m: Arr) -> tuple[float, float, float]:
    """Rotation vector of a rotation matrix (inverse of Exp), angle in [0, pi]."""
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    c = 0.5 * (tr - 1.0)
    c = min(1.0, max(-1.0, c))
    wx = 0.5 * (m[2, 1] - m[1, 2])
    wy = 0.5 * (m[0, 2] - m[2, 0])
    wz = 0.5 * (m[1, 0] - m[0, 1])
    s = math.sqrt(wx * wx + wy * wy + wz * wz)
    th = math.atan2(s, c)
    if th < 1e-6:
        # sin(th)/th ~ 1 - th^2/6: the antisymmetric part already is the vector.
        k = 1.0 + th * th / 6.0
        return wx * k, wy * k, wz * k
    if th < math.pi - 1e-6:
        k = th / s
        return wx * k, wy * k, wz * k
    # Near pi the antisymmetric part vanishes; use the symmetric part (axis up to sign).
    xx = math.sqrt(max(0.0, (m[0, 0] + 1.0) * 0.5))
    yy = math.sqrt(max(0.0, (m[1, 1] + 1.0) * 0.5))
    zz = math.sqrt(max(0.0, (m[2, 2] + 1.0) * 0.5))
    if xx >= yy and xx >= zz:
        yy = math.copysign(yy, m[0, 1] + m[1, 0])
        zz = math.copysign(zz, m[0, 2] + m[2, 0])
    elif yy >= zz:
        xx = math.copysign(xx, m[0, 1] + m[1, 0])
        zz = math.copysign(zz, m[1, 2] + m[2, 1])
    else:
        xx = math.copysign(xx, m[0, 2] + m[2, 0])
        yy = math.copysign(yy, m[1, 2] + m[2, 1])
    n = math.sqrt(xx * xx + yy * yy + zz * zz)
    return th * xx / n, th * yy / n, th * zz / n


@jit
def euler_to_mat_into(out: Arr, roll: float, pitch: float, yaw: float) -> None:
    """out = Rz(yaw) Ry(pitch) Rx(roll)."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    out[0, 0] = cp * cy
    out[0, 1] = sr * sp * cy - cr * sy
    out[0, 2] = cr * sp * cy + sr * sy
    out[1, 0] = cp * sy
    out[1, 1] = sr * sp * sy + cr * cy
    out[1, 2] = cr * sp * sy - sr * cy
    out[2, 0] = -sp
    out[2, 1] = sr * cp
    out[2, 2] = cr * cp


@jit
def mat_to_euler(m: Arr) -> tuple[float, float, float]:
    """(roll, pitch, yaw) of a C_b^n matrix; pitch in [-pi/2, pi/2], yaw in (-pi, pi]."""
    pitch = -math.asin(min(1.0, max(-1.0, m[2, 0])))
    roll = math.atan2(m[2, 1], m[2, 2])
    yaw = math.atan2(m[1, 0], m[0, 0])
    return roll, pitch, yaw


@jit
def mat_to_quat(m: Arr) -> tuple[float, float, float, float]:
    """Quaternion (w, x, y, z), w >= 0, by Shepperd's branch on the largest component."""
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0.0:
        s = 2.0 * math.sqrt(1.0 + tr)
        w = 0.25 * s
        x = (m[2, 1] - m[1, 2]) / s
        y = (m[0, 2] - m[2, 0]) / s
        z = (m[1, 0] - m[0, 1]) / s
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        w = (m[2, 1] - m[1, 2]) / s
        x = 0.25 * s
        y = (m[0, 1] + m[1, 0]) / s
        z = (m[0, 2] + m[2, 0]) / s
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        w = (m[0, 2] - m[2, 0]) / s
        x = (m[0, 1] + m[1, 0]) / s
        y = 0.25 * s
        z = (m[1, 2] + m[2, 1]) / s
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        w = (m[1, 0] - m[0, 1]) / s
        x = (m[0, 2] + m[2, 0]) / s
        y = (m[1, 2] + m[2, 1]) / s
        z = 0.25 * s
    if w < 0.0:
        w, x, y, z = -w, -x, -y, -z
    n = math.sqrt(w * w + x * x + y * y + z * z)
    return w / n, x / n, y / n, z / n


@jit
def quat_to_mat_into(out: Arr, w: float, x: float, y: float, z: float) -> None:
    """out = rotation matrix of the (normalised) quaternion (w, x, y, z)."""
    n = math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    out[0, 0] = 1.0 - 2.0 * (y * y + z * z)
    out[0, 1] = 2.0 * (x * y - w * z)
    out[0, 2] = 2.0 * (x * z + w * y)
    out[1, 0] = 2.0 * (x * y + w * z)
    out[1, 1] = 1.0 - 2.0 * (x * x + z * z)
    out[1, 2] = 2.0 * (y * z - w * x)
    out[2, 0] = 2.0 * (x * z - w * y)
    out[2, 1] = 2.0 * (y * z + w * x)
    out[2, 2] = 1.0 - 2.0 * (x * x + y * y)


@jit
def orthonormalize(m: Arr, a: Arr, r: Arr) -> None:
    """Remove accumulated non-orthogonality of ``m`` in place; ``a``, ``r`` are 3x3 scratch."""
    # C <- C (3I - C^T C)/2: converges quadratically, error ~ (C^T C - I)^2.
    mul3t_into(a, m, m)
    for i in range(3):
        for j in range(3):
            a[i, j] *= -0.5
        a[i, i] += 1.5
    mul3_into(r, m, a)
    for i in range(3):
        for j in range(3):
            m[i, j] = r[i, j]


# ---- convenience (allocating) wrappers for tests, simulator and I/O ----

def skew(v: Arr) -> Arr:
    out = np.empty((3, 3))
    skew_into(out, float(v[0]), float(v[1]), float(v[2]))
    return out


def exp_so3(v: Arr) -> Arr:
    out = np.empty((3, 3))
    exp_into(out, float(v[0]), float(v[1]), float(v[2]))
    return out


def log_vec(m: Arr) -> Arr:
    return np.array(log_so3(m))


def euler_to_mat(roll: float, pitch: float, yaw: float) -> Arr:
    out = np.empty((3, 3))
    euler_to_mat_into(out, roll, pitch, yaw)
    return out


def quat_to_mat(q: tuple[float, float, float, float] | Arr) -> Arr:
    out = np.empty((3, 3))
    quat_to_mat_into(out, float(q[0]), float(q[1]), float(q[2]), float(q[3]))
    return out


def wrap_pi(a: float) -> float:
    """Wrap an angle to (-pi, pi]."""
    r = math.fmod(a + math.pi, 2.0 * math.pi)
    if r <= 0.0:
        r += 2.0 * math.pi
    return r - math.pi
