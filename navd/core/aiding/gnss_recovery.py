"""Recovery from a GNSS lock-out: when the gate has refused every position (or velocity)
update for longer than ``[filter] max_lockout_s``, the state is reset to GNSS.

A lock-out is timed from the first refused epoch of a run of refusals and ends at the next
accepted one.  A reset at epoch k lets the fix of epoch k+1 in, so the reset comes at the
last epoch k after which waiting for k+1 could end the lock-out beyond ``max_lockout``
(k+1 and k+2 each up to ``_JITTER`` intervals later), so no lock-out lasts longer than that
(f450_glitch's 5 Hz fixes arrive 0.18-0.25 s apart: allowing one interval only, a reset
decided at 4.79 s was followed by a fix 0.22 s later, a 5.01-5.2 s lock-out).

Why.  A chi-square gate trusts the filter's covariance.  When the state has drifted beyond
what the covariance admits (a mis-stated IMU noise spec, an uncalibrated gyro, a vehicle
the model does not describe, a receiver that re-converged somewhere else), every honest fix
looks like an outlier and is refused, and nothing brings the state back: the filter is
locked out for the rest of the run.  An outlier of the receiver lasts a few epochs; a
refusal that lasts seconds says that the *state* is wrong.

What.  Per GNSS epoch, after the aid has tried its updates (the estimator's innovation
record, :mod:`navd.core.aiding.base`):

position  refused for longer than ``max_lockout``: the position moves by minus the last
          position innovation (onto the fix, lever arm included), its covariance becomes
          the fix's accuracy with no correlation to the other states.
velocity  likewise onto the GNSS velocity (horizontal; vertical when the receiver gives
          it).  A velocity the filter could not follow means the attitude or the biases
          that drove it are wrong too: the tilt, heading and bias variances grow by their
          initial (prior) variances, so the next fixes can correct them.  When the vehicle
          is at rest (GNSS speed below ``_REST_SPEED``, and the last 1 s IMU window of
          :mod:`navd.core.aiding.gyro_rest` ended within 1.5 s, turned slower than ``[init]
          static_rate_tol`` and measured gravity within ``_LEVEL_F_TOL``), that window's
          mean specific force is gravity alone and gives roll and pitch directly: they are
          re-levelled from it (yaw kept) with the levelling sigma ``[init] tilt_sd``
          (``reset_level_at_rest``).  A tilt tens of degrees off (a gyro saturated in a crash,
          log171 at 227.5 s: 2000 deg/s, 11 g, then upside down on the ground) is far outside
          what widened variances let a linear update correct: without it the velocity was
          refused for the remaining 15 s of the log despite two resets, each followed within
          a second by horizontal accelerations of g sin(70 deg).

bias limits  a gyro bias estimate beyond ``GYRO_BIAS_LIMIT`` (10 deg/s) or an accelerometer
          bias beyond ``ACCEL_BIAS_LIMIT`` (1.5 m/s^2, ~150 mg) on any axis is no sensor's
          offset (consumer MEMS are specified to a few deg/s and ~100 mg): the filter has
          diverged and is explaining its own error with impossible biases.  Both bias
          estimates go back to the configured (known) biases with their prior variances
          and no correlations, and tilt and heading widen by their priors, as after a
          velocity lock-out (``reset_bias_limit``).

Each reset is counted (``reset_lockout_pos`` / ``reset_lockout_vel``), which the daemon
logs (rate-limited) and the status record shows.  The history ring of past nominal states
is cleared, because a delayed fix must not be linearised about a state from before the
reset.  Zeroing rows/columns of a positive semi-definite P (a projection) and adding a
non-negative diagonal keeps it positive semi-definite.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from navd.config import EstimatorConfig
from navd.core import state as st
from navd.core.aiding.base import ACCEPTED, INNOV_FLAG, INNOV_POS, INNOV_VEL, NOT_TRIED
from navd.core.aiding.gyro_rest import GYRO_BIAS_LIMIT, turning
from navd.core.earth import gravity, radii
from navd.core.level import relevel_cov
from navd.core.rotation import euler_to_mat_into

if TYPE_CHECKING:
    from navd.core.estimator import Estimator

_POS = 6  # error-state index of dlat (then dlon, dh)
_VEL = 3  # error-state index of dv_N
_BG = 9  # error-state index of the gyro bias (then the accelerometer bias at 12)

ACCEL_BIAS_LIMIT = 1.5  # m/s^2: beyond any MEMS accelerometer's offset
_JITTER = 1.25  # a fix may arrive this many nominal intervals after the previous one
_REST_SPEED = 0.5  # m/s: GNSS horizontal speed below which a velocity reset may re-level
_LEVEL_F_TOL = 1.0  # m/s^2: |mean specific force| - g within this to re-level (~100 mg)
_LEVEL_WINDOW_AGE_US = 1_500_000  # the IMU window re-levelled from ended at most this long ago
_RELEVEL_HEADING_DEG = 10.0  # a re-level that moves the tilt further leaves heading unknown


class LockoutRecovery:
    """Watches the GNSS updates' outcomes and resets position/velocity after a lock-out."""

    def __init__(self, cfg: EstimatorConfig) -> None:
        self.cfg = cfg
        self._max_us = cfg.filter.max_lockout * 1e6
        # time of validity of the first refused epoch of the present run of refusals
        # (-1: the last epoch that tried the update accepted it)
        self._pos_refused_us = -1
        self._vel_refused_us = -1
        self._prev_us = -1  # time of validity of the previous epoch
        self._prev_gap = 0  # the interval before it, us

    def reset(self) -> None:
        self._pos_refused_us = -1
        self._vel_refused_us = -1
        self._prev_us = -1
        self._prev_gap = 0

    def refused_s(self, t_us: int) -> tuple[float, float]:
        """How long position and velocity have been refused at ``t_us`` (s; 0 when the
        last epoch that tried them accepted)."""
        return ((t_us - self._pos_refused_us) * 1e-6 if self._pos_refused_us >= 0 else 0.0,
                (t_us - self._vel_refused_us) * 1e-6 if self._vel_refused_us >= 0 else 0.0)

    def after_epoch(self, est: Estimator, t_us: int, h_sd: float, v_sd: float,
                    s_sd: float, vel_d_reported: bool) -> None:
        """Call once per GNSS epoch after its updates; ``*_sd``: the accuracies used (m,
        m/s); ``t_us``: the fix's time of validity."""
        # The next epoch is expected one interval later: reset at the last epoch before the
        # refusal would outlast max_lockout, so that no lock-out lasts longer.  The interval
        # is the shorter of the last two, so the first fix after an outage (a tunnel) does
        # not count its gap as refusal time.
        gap = t_us - self._prev_us if self._prev_us >= 0 else 0
        step = min(gap, self._prev_gap) if self._prev_gap > 0 else gap
        self._prev_us = t_us
        self._prev_gap = gap
        r = est.innov
        self._pos_refused_us = self._watch(r[INNOV_POS, INNOV_FLAG], self._pos_refused_us,
                                           t_us, step)
        if self._pos_refused_us == -2:
            self._reset_position(est, h_sd, v_sd)
            self._pos_refused_us = -1
        self._vel_refused_us = self._watch(r[INNOV_VEL, INNOV_FLAG], self._vel_refused_us,
                                           t_us, step)
        if self._vel_refused_us == -2:
            self._reset_velocity(est, s_sd, vel_d_reported)
            self._vel_refused_us = -1
        check_bias_limits(est)

    def _watch(self, flag: float, refused_us: int, t_us: int, step: int) -> int:
        """The new start of the refusal run after an epoch with outcome ``flag``; -2 when
        the state must be reset now.  Epochs that did not try the update (no velocity in
        the fix, an outage) neither start nor end a run."""
        if flag == ACCEPTED:
            return -1
        if flag == NOT_TRIED:
            return refused_us
        if refused_us < 0:
            # one refused fix is an outlier until the next one agrees with it, however far
            # apart the fixes are
            return t_us
        if self._max_us > 0.0 and t_us - refused_us + 2.0 * _JITTER * step >= self._max_us:
            return -2
        return refused_us

    def _reset_position(self, est: Estimator, h_sd: float, v_sd: float) -> None:
        z = est.innov[INNOV_POS]
        if not (math.isfinite(z[0]) and math.isfinite(z[1]) and math.isfinite(z[2])):
            return
        pos = est.pos
        r_m, r_n = radii(float(pos[0]))
        h = float(pos[2])
        cos_lat = max(math.cos(float(pos[0])), 1e-9)
        # z = D (p_hat - p_gnss) + C l with D = diag(R_M + h, (R_N + h) cos L, -1): move by
        # -D^-1 z so the next innovation is zero
        pos[0] -= z[0] / (r_m + h)
        pos[1] -= z[1] / ((r_n + h) * cos_lat)
        pos[2] += z[2]
        P = est.P
        for k in range(_POS, _POS + 3):
            P[k, :] = 0.0
            P[:, k] = 0.0
        P[_POS, _POS] = (h_sd / (r_m + h)) ** 2
        P[_POS + 1, _POS + 1] = (h_sd / ((r_n + h) * cos_lat)) ** 2
        P[_POS + 2, _POS + 2] = v_sd * v_sd
        st.history_reset(est.buf)
        est.counters["reset_lockout_pos"] += 1

    def _reset_velocity(self, est: Estimator, s_sd: float, vel_d_reported: bool) -> None:
        z = est.innov[INNOV_VEL]
        if not (math.isfinite(z[0]) and math.isfinite(z[1])):
            return
        v = est.vel_n
        v[0] -= z[0]
        v[1] -= z[1]
        n = 3 if vel_d_reported and math.isfinite(z[2]) else 2
        if n == 3:
            v[2] -= z[2]
        P = est.P
        for k in range(_VEL, _VEL + n):
            P[k, :] = 0.0
            P[:, k] = 0.0
            P[k, k] = s_sd * s_sd
        # what drove the velocity away is in doubt as much as at the start
        _widen_attitude_and_biases(est)
        if est.gnss.last_speed_h < _REST_SPEED:
            relevel_at_rest(est)
        st.history_reset(est.buf)
        est.counters["reset_lockout_vel"] += 1


def relevel_at_rest(est: Estimator, w: npt.NDArray[np.float64] | None = None) -> bool:
    """Roll and pitch from the last still IMU window's mean specific force (module doc);
    whether it was done.  ``w``: another still window (mean raw rate (3), mean raw specific
    force (3), end time (us)), the at-rest gyro calibration's run when it finds a gyro bias
    that has been tilting the attitude (aiding/gyro_rest.py)."""
    if w is None:
        w = est.gyro_rest.last_window
    if w[6] < 0.0 or est.t_us - w[6] > _LEVEL_WINDOW_AGE_US:
        return False
    c = est.cfg
    cb = est.gyro_rest.cal_bias
    if turning(w[0], w[1], w[2], w[3], w[4], w[5], float(cb[0]), float(cb[1]), float(cb[2]),
               c.init.static_rate_tol, est.gyro_rest.calibrated):
        return False
    ba = est.bias_a
    fx, fy, fz = w[3] - ba[0], w[4] - ba[1], w[5] - ba[2]
    g = gravity(float(est.pos[0]), float(est.pos[2]))
    if abs(math.sqrt(fx * fx + fy * fy + fz * fz) - g) > _LEVEL_F_TOL:
        return False
    C = est.mat_nb
    yaw = math.atan2(float(C[1, 0]), float(C[0, 0]))
    # the body's down axis in n before the re-level, to tell how far the tilt moved
    d0 = (float(C[2, 0]), float(C[2, 1]), float(C[2, 2]))
    euler_to_mat_into(C, math.atan2(-fy, -fz), math.atan2(fx, math.sqrt(fy * fy + fz * fz)),
                      yaw)
    moved = math.acos(max(-1.0, min(1.0, d0[0] * float(C[2, 0]) + d0[1] * float(C[2, 1])
                                    + d0[2] * float(C[2, 2]))))
    P = est.P
    far = moved > _RELEVEL_HEADING_DEG * math.pi / 180.0
    # the new tilt hides the residual of the estimated accelerometer bias (core/level.py)
    relevel_cov(P, C, c.init.tilt_sd, g, not far)
    if far:
        # a tilt that far off came with a yaw nobody can vouch for
        P[2, :] = 0.0
        P[:, 2] = 0.0
        P[2, 2] = (math.pi / 2.0) ** 2
        est.gnss.course.yaw_known(float(P[2, 2]), yaw, est.t_us * 1e-6, float(P[11, 11]))
    est.counters["reset_level_at_rest"] += 1
    # a delayed fix must not be linearised about the attitude from before
    st.history_reset(est.buf)
    return True


def _widen_attitude_and_biases(est: Estimator) -> None:
    """Add the prior variances of tilt, heading and both biases to P (a PSD matrix plus a
    non-negative diagonal stays PSD)."""
    c = est.cfg
    P = est.P
    tilt2 = c.init.tilt_sd ** 2
    P[0, 0] += tilt2
    P[1, 1] += tilt2
    P[2, 2] += c.init.heading_sd ** 2
    est.gnss.course.widen(c.init.heading_sd ** 2)
    for k in range(_BG, _BG + 3):
        P[k, k] += c.imu.gyro_bias_sd ** 2
    for k in range(_BG + 3, _BG + 6):
        P[k, k] += c.imu.accel_bias_sd ** 2


def check_bias_limits(est: Estimator) -> bool:
    """Reset both bias estimates to the configured ones when either is beyond its physical
    limit (see the module doc); True when it did."""
    bg = est.bias_g
    ba = est.bias_a
    if (abs(bg[0]) <= GYRO_BIAS_LIMIT and abs(bg[1]) <= GYRO_BIAS_LIMIT
            and abs(bg[2]) <= GYRO_BIAS_LIMIT and abs(ba[0]) <= ACCEL_BIAS_LIMIT
            and abs(ba[1]) <= ACCEL_BIAS_LIMIT and abs(ba[2]) <= ACCEL_BIAS_LIMIT):
        return False
    c = est.cfg
    bg[:] = c.imu.gyro_bias
    ba[:] = c.imu.accel_bias
    P = est.P
    for k in range(_BG, _BG + 6):
        P[k, :] = 0.0
        P[:, k] = 0.0
    _widen_attitude_and_biases(est)
    est.counters["reset_bias_limit"] += 1
    return True
