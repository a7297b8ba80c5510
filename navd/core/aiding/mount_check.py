"""Is the IMU pitched on the vehicle?  A check from a ground vehicle's own motion (issue 14).

navd reports the attitude of the body its increments are in: the vehicle's once ``[imu]
mount_*_deg`` says how the IMU sits on it, else the IMU's.  A board a few degrees off level
makes roll and pitch that far from the vehicle's at a sigma of tenths of a degree (docs/
results.md, "The IMU's mounting").  Roll cannot be told from the motion, but pitch can on a
ground vehicle: it rolls along its road, so its velocity has no vertical component in its
own axes, whatever the grade.  In the IMU's axes, with the IMU pitched by theta_m on it, the
velocity rises above the IMU's x axis by theta_m: v_s = |v| (cos theta_m, 0, sin theta_m),
so ``theta_k = atan2(v_z, v_x)`` of the GNSS velocity in the estimator's body axes observes
theta_m (plus the estimator's own pitch error, which it knows the variance of).

Each epoch of straight forward driving (course update active, >= ``_MIN_SPEED``, turning
slower than ``_MAX_RATE``: a turn's lever-arm velocity and sideslip are not pitch) adds
theta_k to a mean forgetting over ``_TAU_S``, weighted by the inverse of its variance:
the estimator's rotation variance about the body y axis plus the GNSS speed noise's
(sigma_v / v)^2, so the first minutes, while the estimator's own pitch is still uncertain,
do not bias it (drive_long seed 2: +1.8 deg at sigma 1.3 deg in the first minute).  The
mean's sigma takes the estimator's part as fully correlated (the weighted mean of its
sigmas: a pitch error does not average away) and the speed noise's as white.  When after
``_MIN_DRIVEN_S`` of such driving the mean is beyond 3 sigma and ``_MIN_DEG``, it is counted
once, ``imu_pitch_mount_suspect`` (the daemon warns on it), and the status shows the mean
and sigma (``imu_pitch_on_vehicle_deg``): the value to write into ``[imu]
mount_pitch_deg``.  Nothing is corrected: suspension pitch under braking and a loaded boot
move the mean too, which a user, not a filter, can tell from a mounting.  Only the ground
profile (fixed-wing and multirotor velocities are not along their noses).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from navd.config import EstimatorConfig
from navd.types import GnssSample

if TYPE_CHECKING:
    from navd.core.estimator import Estimator

_MIN_SPEED = 5.0  # m/s
_MAX_RATE = math.radians(3.0)  # rad/s
_TAU_S = 600.0
_MIN_DRIVEN_S = 60.0
_MIN_DEG = 0.5
# state (an array: the epoch loop rebinds no Python objects): sum of weights, weighted sums
# of theta, of the white variance (weights squared) and of the attitude sigma about the body
# y axis, seconds driven, flagged (0/1), previous epoch time (us; -1 none)
_W, _WT, _WV, _WS, _DRIVEN, _FLAG, _T_PREV = range(7)


class PitchMountCheck:
    """The IMU's pitch on a ground vehicle, from its velocity in the body axes."""

    def __init__(self, cfg: EstimatorConfig) -> None:
        self.enabled = cfg.filter.profile == "ground"
        self._s = np.zeros(7)
        self.reset()

    def reset(self) -> None:
        self._s[:] = 0.0
        self._s[_T_PREV] = -1.0

    @property
    def estimate(self) -> tuple[float, float] | None:
        """The mean pitch of the velocity above the body x axis and its 1-sigma, rad (None
        before any straight driving)."""
        s = self._s
        if s[_W] <= 0.0:
            return None
        return float(s[_WT] / s[_W]), self._sd()

    def _sd(self) -> float:
        s = self._s
        return math.sqrt(float(s[_WV] / (s[_W] * s[_W]) + (s[_WS] / s[_W]) ** 2))

    def on_epoch(self, est: Estimator, g: GnssSample, s_sd: float) -> None:
        """After an epoch whose course update was active: add its velocity direction
        (``s_sd``: the per-axis GNSS speed sigma, m/s)."""
        if not self.enabled:
            return
        s = self._s
        m = est.mat_nb
        r = est.rate_b
        if abs(m[2, 0] * r[0] + m[2, 1] * r[1] + m[2, 2] * r[2]) > _MAX_RATE:
            return
        if not math.isfinite(g.vel_d):
            return
        vx = m[0, 0] * g.vel_n + m[1, 0] * g.vel_e + m[2, 0] * g.vel_d
        vz = m[0, 2] * g.vel_n + m[1, 2] * g.vel_e + m[2, 2] * g.vel_d
        if vx < _MIN_SPEED:
            return
        t_prev = s[_T_PREV]
        s[_T_PREV] = g.t_us
        dt = (g.t_us - t_prev) * 1e-6 if t_prev >= 0.0 else 0.0
        if not 0.0 < dt < 5.0:
            dt = 0.0
        # rotation variance about the body y axis: c^T P_att c, c = C_b^n e_y
        P = est.P
        c0, c1, c2 = m[0, 1], m[1, 1], m[2, 1]
        v_att = (c0 * (P[0, 0] * c0 + P[0, 1] * c1 + P[0, 2] * c2)
                 + c1 * (P[1, 0] * c0 + P[1, 1] * c1 + P[1, 2] * c2)
                 + c2 * (P[2, 0] * c0 + P[2, 1] * c1 + P[2, 2] * c2))
        v_white = s_sd * s_sd / (vx * vx)
        w = 1.0 / max(v_att + v_white, 1e-12)  # a receiver may report 0 m/s of noise
        lam = math.exp(-dt / _TAU_S)
        s[_W] = lam * s[_W] + w
        s[_WT] = lam * s[_WT] + w * math.atan2(vz, vx)
        s[_WV] = lam * lam * s[_WV] + w * w * v_white
        s[_WS] = lam * s[_WS] + w * math.sqrt(max(v_att, 0.0))
        s[_DRIVEN] += dt
        if (s[_FLAG] == 0.0 and s[_DRIVEN] >= _MIN_DRIVEN_S
                and abs(s[_WT] / s[_W]) > max(math.radians(_MIN_DEG), 3.0 * self._sd())):
            s[_FLAG] = 1.0
            est.counters["imu_pitch_mount_suspect"] += 1
