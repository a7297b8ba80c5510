"""Gyro offset at rest: what autopilots do at boot, done as a measurement of the gyro bias.

Why.  A consumer MEMS gyro out of the box is off by 0.3-1 deg/s (hundreds to thousands of
deg/h), far beyond what a filter prior of a few deg/h admits; the filter then takes the
offset for rotation, the tilt runs away and every honest GNSS fix is refused (issue 14).
At rest the mean gyro output is known up to noise: offset + earth rate.  Averaging it is the
cheapest and best gyro calibration there is, and it observes the vertical gyro axis too,
which GNSS fixes at rest cannot.

Stillness.  "At rest" is decided from the IMU itself, over windows of ``_WINDOW_S``:

* every window's mean rate less the bias is below ``[init] static_rate_tol_dps`` (before
  the first measurement: its part about the vertical, see :func:`turning`) and its mean
  specific force within ``_F_TOL`` of gravity (no turning, no acceleration);
* across ``_WINDOWS`` consecutive windows, the window means of rate *and* specific force
  scatter no more than the noise inside the windows allows (an Allan-variance test at one
  window length: sum over axes and windows of (mean_k - grand mean)^2 / (s^2 / n), which is
  chi-square with 3 (K - 1) degrees of freedom for a still sensor; refused above its
  ``_STILL_PROB`` quantile), and no axis shows a trend across the windows (squared
  least-squares slope over its variance, chi-square with 1 dof).  s^2 is the windows' own
  sample variance, never the configured noise: a config that overstates the accelerometer
  noise, as vibration allowances do, would blind the test.  A platform that sways (a boat
  at anchor, a vehicle rocked by wind or by people stepping in) turns back and forth: its
  window mean rates and its tilt (hence mean specific force) drift from window to window
  far more than white noise does, so it fails even when each window looks quiet.  Vibration
  much faster than a window raises the noise inside the windows as much as it moves their
  means, so an idling engine still counts as rest;
* while navigating, the last GNSS fix's or the filter's horizontal speed is below
  ``_MAX_SPEED_MPS`` (a steady turn at constant speed has constant rate and specific force:
  it would pass the IMU tests; the fix counts alone because a filter that an uncalibrated
  gyro has already driven off is the one that needs the calibration).

A measurement is made from every ``_WINDOWS`` still windows (10 s), and from a shorter still
run of at least ``_MIN_WINDOWS`` + 1 that motion ends (a stop at traffic lights, a quad
carried between short rests), less its last window, in which the motion may have begun.
While navigating, a window that closes with both the fix and the filter above
``_MAX_SPEED_MPS`` is motion too, whatever the IMU shows: a car that backs out of its space
at 0.7 m/s^2 5 s after power-on passed the still test (a consumer accelerometer's noise
hides so gentle a start), so the run went on into the motion and no measurement was made;
the filter then set off with the 0.5 deg/s gyro prior, a tilt sigma of 2 deg, and let the
velocity fixes bend its pitch by 6-14 deg (issue 14, robustness case ``reverse_start``).  A
sway never ends a run that way: it stays within the gross limits.

Not caught: a platform turning in place at a steady rate below ``static_rate_tol_dps`` with
no other motion (a robot spinning slowly on the spot).  Its rate is taken for offset; the
chi-square gate below refuses it once the bias is known better than that rate.

Still, a sway much slower than the 10 s test looks like an offset near its rate extremum when
the accelerometer is too noisy to see the tilt change; the gate below refuses such a reading
once the bias is known, and the reset needs two refusals in a row that agree.

Measurement.  The mean raw rate over the K windows, r (body FRD, rad/s), is offset plus the
earth rate seen in the body, ``r = b_g + C^T w_ie^n + noise``.  Computed - measured, with the
error conventions of docs/design.md §2 (``C_hat = Exp(-phi) C``, ``db = b - b_hat``)::

    z = b_hat + C_hat^T w_ie^n - r = -db - C_hat^T [w_ie^n x] phi - noise
    H = [ -C_hat^T [w_ie^n x] | 0 | 0 | -I | 0 ]

so the heading uncertainty of an unaligned filter (the horizontal earth rate, ~12 deg/h,
depends on it) enters through P rather than by hand, and repeated updates at rest keep the
heading/bias correlation exact.  R is diagonal: the windows' own sample variance over the
number of samples (plus ``_R_FLOOR`` for what white noise does not describe: temperature,
g-sensitivity).  The heading is held as a
consider state when the GNSS hold is enabled (docs/design.md §3.7), so the earth rate does
not become a gyrocompass a MEMS gyro cannot be.  Each update uses fresh windows only.

Gated like any update.  Refused ``_RESET_AFTER`` (2) times in a row by measurements that agree
with each other (chi-square of their scatter; the filter's bias is further off than its
covariance admits: an uncalibrated gyro under a tight prior; a slow sway changes its rate
between them), the bias is *set* to their mean instead: its covariance becomes their R plus
the earth rate squared (heading unknown), with no correlations, and the tilt variance grows
by its prior (the wrong bias has been tilting the attitude).  Counted ``gyro_rest_accepted``
/ ``gyro_rest_rejected`` / ``reset_gyro_rest``.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from navd.config import EstimatorConfig
from navd.core._jit import jit
from navd.core.chi2 import chi2_quantile
from navd.core.earth import OMEGA_IE, gravity

if TYPE_CHECKING:
    from navd.core.estimator import Estimator

Arr = npt.NDArray[np.float64]

# rad/s: beyond any MEMS gyro's offset (consumer parts are specified to a few deg/s); also
# the lock-out recovery's limit on the bias estimate (aiding/gnss_recovery.py)
GYRO_BIAS_LIMIT = 10.0 * math.pi / 180.0
_WINDOW_S = 1.0  # one stillness window
_WINDOWS = 10  # windows per test and per bias measurement (10 s at rest)
_MIN_WINDOWS = 5  # a shorter still run that motion ends is measured from this many on
_STILL_PROB = 0.999  # quantile of the Allan-type chi-square test
_F_TOL = 1.5  # |mean specific force| within this of gravity, m/s^2 (covers 150 mg offsets)
_MAX_SPEED_MPS = 0.5  # filter's horizontal speed below this while navigating
_R_FLOOR = (1.0 * math.pi / 180.0 / 3600.0) ** 2  # (1 deg/h)^2: temperature, g-sensitivity
_RESET_AFTER = 2  # refused measurements in a row, agreeing with each other, before a reset
# per-sample variance floors of the still test (a noiseless simulated sensor): (rad/s)^2, (m/s^2)^2
_VAR_FLOOR_GYRO = 1e-12
_VAR_FLOOR_ACCEL = 1e-10

# accumulator layout (one window): sum rate (3), sum specific force (3), sums of squares of
# both (6), sample count, time (s)
_ACC_W = 14
_ACC_T = 13
_BG = 9  # error-state index of the gyro bias


@jit
def turning(rx: float, ry: float, rz: float, fx: float, fy: float, fz: float, bx: float,
            by: float, bz: float, rate_tol: float, calibrated: bool) -> bool:
    """Whether a mean raw rate ``r`` (rad/s) with mean specific force ``f`` (m/s^2, the same
    body axes) says the IMU turns.  Once the gyro has been calibrated at rest: the rate less
    that calibration ``b`` (rad/s) above ``rate_tol``.  Before: only its component about
    the vertical (along f) above ``rate_tol``; and in either case a rate beyond
    :data:`GYRO_BIAS_LIMIT`.

    Before calibration only the vertical part is ambiguous: a turn about a horizontal axis
    turns gravity in the body (3 deg/s for one 1-s window tilts f by 3 deg, 0.5 m/s^2),
    which the still test's trend and scatter of f refuse, while a steady yaw looks like an
    offset.  A consumer gyro's offset is up to a few deg/s per axis (MPU-6000 class), so a
    limit on the whole raw rate took such an IMU for turning: a multirotor whose offsets
    were +3/-2.5/+2 deg/s (4.4 deg/s together, 2 about its vertical) at rest for 15 s was
    never calibrated and its tilt ran 40-50 deg off (docs/results.md, "A consumer gyro's
    offset beyond the stillness limit").  Afterwards the whole rate counts again: a
    multirotor's specific force is its thrust, along the body whatever its tilt, so the f
    tests do not see it tilt in a hover (log171 at 84 s: the window in which it began to
    move went into a measurement, 0.03 deg/s off)."""
    r2 = rx * rx + ry * ry + rz * rz
    if r2 > GYRO_BIAS_LIMIT * GYRO_BIAS_LIMIT:
        return True
    if calibrated:
        dx, dy, dz = rx - bx, ry - by, rz - bz
        return dx * dx + dy * dy + dz * dz > rate_tol * rate_tol
    f = math.sqrt(fx * fx + fy * fy + fz * fz)
    if f <= 0.0:
        return r2 > rate_tol * rate_tol
    return abs(rx * fx + ry * fy + rz * fz) / f > rate_tol


@jit
def rest_push(a: Arr, dtx: float, dty: float, dtz: float, dvx: float, dvy: float, dvz: float,
              dt: float, window_s: float) -> bool:
    """Add one raw IMU sample (increments, rad and m/s, over dt s) to the window
    accumulators ``a`` (_ACC_W,); True when the window is complete."""
    rx, ry, rz = dtx / dt, dty / dt, dtz / dt
    fx, fy, fz = dvx / dt, dvy / dt, dvz / dt
    a[0] += rx
    a[1] += ry
    a[2] += rz
    a[3] += fx
    a[4] += fy
    a[5] += fz
    a[6] += rx * rx
    a[7] += ry * ry
    a[8] += rz * rz
    a[9] += fx * fx
    a[10] += fy * fy
    a[11] += fz * fz
    a[12] += 1.0
    a[_ACC_T] += dt
    return bool(a[_ACC_T] >= window_s)


@jit
def rest_completes(a: Arr, dt: float, window_s: float) -> bool:
    """Whether :func:`rest_push` of a sample of ``dt`` s would complete the window (the same
    sum and test: decided before pushing, by a caller that must close it first)."""
    return bool(a[_ACC_T] + dt >= window_s)


@jit
def slide_out(win: Arr, n: Arr) -> None:
    """Drop the oldest of the ``n[0]`` windows in ``win``."""
    k = int(n[0])
    for i in range(k - 1):
        for j in range(win.shape[1]):
            win[i, j] = win[i + 1, j]
    n[0] = k - 1


@jit
def _still(win: Arr, K: int, still_gate: float, trend_gate: float) -> bool:
    """The module doc's still test over the first K windows of ``win``."""
    kc = 0.5 * (K - 1)
    sxx = 0.0
    for j in range(K):
        sxx += (j - kc) ** 2
    for s in range(2):
        floor = _VAR_FLOOR_GYRO if s == 0 else _VAR_FLOOR_ACCEL
        stat = 0.0
        for ax in range(3 * s, 3 * s + 3):
            mean = 0.0
            var = 0.0
            for j in range(K):
                mean += win[j, ax]
                var += win[j, 6 + ax]
            mean /= K
            var = max(var / K, floor)
            sxy = 0.0
            for j in range(K):
                d = win[j, ax] - mean
                stat += d * d * win[j, 12] / var
                sxy += (j - kc) * d
            # a slow sway is a trend across the windows first: its least-squares slope,
            # 1 dof per axis, is far more sensitive to it than the omnibus scatter
            if sxy * sxy / sxx * win[0, 12] / var > trend_gate:
                return False
        if stat > still_gate:
            return False
    return True


@jit
def close_window(a: Arr, win: Arr, n: Arr, rate_tol: float, f_tol: float, g: float,
                 still_gates: Arr, trend_gate: float, k_min: int, moving: bool,
                 bias: Arr, calibrated: bool) -> int:
    """Close the window accumulated in ``a`` into the run ``win`` (K, 13) holding ``n[0]``
    windows.  Returns -1: moving (run cleared), 0: collecting, 1: the K windows are still,
    2: motion ended a run whose first ``n[0]`` (>= k_min) windows are still (the last one
    before the motion is left out: the motion may have begun inside it).

    Per window: mean rate (3), mean specific force (3), sample variances of both (6), count.
    ``still_gates[k]``: the omnibus gate for k windows; ``moving``: another sensor (GNSS)
    says this window ends in motion, whatever the IMU shows; ``bias`` (3,) rad/s and
    ``calibrated``: the gyro offset last measured at rest and whether there is one
    (:func:`turning`).
    """
    cnt = a[12]
    if cnt < 2.0:
        for i in range(a.shape[0]):
            a[i] = 0.0
        return 0
    k = int(n[0])
    K = win.shape[0]
    for i in range(6):
        mean = a[i] / cnt
        win[k, i] = mean
        win[k, 6 + i] = max((a[6 + i] - cnt * mean * mean) / (cnt - 1.0), 0.0)
    win[k, 12] = cnt
    for i in range(a.shape[0]):
        a[i] = 0.0
    f = math.sqrt(win[k, 3] ** 2 + win[k, 4] ** 2 + win[k, 5] ** 2)
    if (moving or turning(win[k, 0], win[k, 1], win[k, 2], win[k, 3], win[k, 4], win[k, 5],
                          bias[0], bias[1], bias[2], rate_tol, calibrated)
            or abs(f - g) > f_tol):
        if k - 1 >= k_min and _still(win, k - 1, float(still_gates[k - 1]), trend_gate):
            n[0] = k - 1
            return 2
        n[0] = 0.0
        return -1
    k += 1
    n[0] = k
    if k < K:
        return 0
    if not _still(win, K, float(still_gates[K]), trend_gate):
        slide_out(win, n)
        return 0
    return 1


class GyroRest:
    """Stillness detection and the at-rest gyro bias measurement (see the module doc).

    Attributes:
        acc: the present window's accumulators (``_ACC_W``,), fed by :func:`rest_push`.
        window_s: window length, s.
        updates: bias measurements applied (accepted or reset) so far.
    """

    def __init__(self, cfg: EstimatorConfig) -> None:
        self.cfg = cfg
        self.enabled = cfg.imu.rest_calibration
        self.window_s = _WINDOW_S
        self.acc = np.zeros(_ACC_W)
        # finished windows of the present still run: mean rate (3), mean specific force (3),
        # sample variance of rate (3) and of specific force (3), sample count
        self._win = np.zeros((_WINDOWS, 13))
        self._n = np.zeros(1)  # windows in self._win (a float, kept in an array for the kernel)
        # per sensor and number of windows k: chi-square with 3 (k - 1) dof for a still one
        self._still_gates = np.array([chi2_quantile(_STILL_PROB, 3 * max(k - 1, 1))
                                      for k in range(_WINDOWS + 1)])
        self._trend_gate = chi2_quantile(_STILL_PROB, 1)  # per axis
        self._gate3 = chi2_quantile(cfg.filter.gate_prob, 3)
        # refused measurements in a row (mean raw rate (3), R diagonal (3)) and their count;
        # they agree when their scatter is within chi-square 3 (n - 1) dof
        self._rej = np.zeros((_RESET_AFTER, 6))
        self._n_rej = 0
        self._agree_gate = chi2_quantile(_STILL_PROB, 3 * (_RESET_AFTER - 1))
        self.updates = 0
        self.still = False
        # the last closed window: mean raw rate (3, rad/s, body FRD), mean raw specific force
        # (3, m/s^2, body FRD), its end time (us; -1: none yet).  The lock-out recovery
        # re-levels from it (navd/core/aiding/gnss_recovery.py).
        self.last_window = np.zeros(7)
        self.last_window[6] = -1.0
        # the same for the whole run of the present measurement (its re-level, below)
        self._run_window = np.zeros(7)
        # sensor time (us) since which the gyro bias has been as the filter believes: the
        # start of the first run measured, then the last measurement accepted or reset
        # (-1: none yet)
        self._bias_ok_us = -1
        # the gyro offset last measured at rest (rad/s, body FRD) and whether there is one:
        # the stillness test's (:func:`turning`).  The sensor's, not the state's, so a
        # restart of the filter keeps it
        self.cal_bias = np.zeros(3)
        self.calibrated = False

    def reset(self) -> None:
        self.acc[:] = 0.0
        self._n[0] = 0.0
        self._n_rej = 0
        self.still = False
        self.last_window[6] = -1.0
        self._bias_ok_us = -1

    @property
    def windows(self) -> int:
        """Windows of the present still-candidate run (at most ``_WINDOWS``)."""
        return int(self._n[0])

    def window_done(self, est: Estimator) -> None:
        """The present window is complete (:func:`rest_push` returned True)."""
        g = gravity(float(est.pos[0]), float(est.pos[2])) if est.initialized else 9.80665
        a, lw = self.acc, self.last_window
        if a[12] >= 2.0:
            for i in range(6):
                lw[i] = a[i] / a[12]
            lw[6] = float(est.t_us)
        # a gentle start (a car backing out at 0.7 m/s^2) passes the IMU's tests when the
        # accelerometer is noisy: then only the fixes say that the run has ended, and the
        # windows still before it are the boot calibration that the start needs
        res = close_window(self.acc, self._win, self._n, self.cfg.init.static_rate_tol,
                           _F_TOL, g, self._still_gates, self._trend_gate, _MIN_WINDOWS,
                           est.initialized and not self._at_rest(est), self.cal_bias,
                           self.calibrated)
        self.still = res == 1
        if res <= 0:
            return
        if not (self.enabled and est.initialized):
            if res == 1:
                # before navigation: keep the newest windows for the first measurement
                slide_out(self._win, self._n)
            else:
                self._n[0] = 0.0
            return
        k = int(self._n[0])
        self._n[0] = 0.0  # each measurement uses fresh windows only
        # every window of the run closed at rest by the fixes or the filter (else the run
        # would have ended there)
        self._measure(est, k)

    @staticmethod
    def _at_rest(est: Estimator) -> bool:
        """At rest by GNSS or by the filter's speed (while navigating): a filter that an
        uncalibrated gyro has already driven off must still get its calibration."""
        vn = est.vel_n
        return bool(est.gnss.last_speed_h < _MAX_SPEED_MPS
                    or math.hypot(float(vn[0]), float(vn[1])) < _MAX_SPEED_MPS)

    def _measure(self, est: Estimator, k: int) -> None:
        """The bias measurement from the first ``k`` windows of the run."""
        W = self._win[:k]
        n_tot = float(np.sum(W[:, 12]))
        lat = float(est.pos[0])
        w_ie = (OMEGA_IE * math.cos(lat), 0.0, -OMEGA_IE * math.sin(lat))
        C = est.mat_nb
        H, z, R = est.meas_H, est.meas_z, est.meas_R
        H[:, :] = 0.0
        R[:, :] = 0.0
        # [w x] for w = w_ie^n
        wx = ((0.0, -w_ie[2], w_ie[1]), (w_ie[2], 0.0, -w_ie[0]), (-w_ie[1], w_ie[0], 0.0))
        bg = est.bias_g
        rec = self._rej[self._n_rej]  # this measurement: mean raw rate (3), R diagonal (3)
        rw = self._run_window  # the run's mean raw rate and specific force (re-levels)
        for i in range(6):
            rw[i] = float(np.sum(W[:, i] * W[:, 12])) / n_tot
        rw[6] = float(est.t_us)
        for i in range(3):
            e_b = C[0, i] * w_ie[0] + C[1, i] * w_ie[1] + C[2, i] * w_ie[2]  # (C^T w)_i
            rec[i] = float(rw[i])
            z[i] = float(bg[i]) + e_b - rec[i]
            # -(C^T [w x])_i,j = -sum_k C[k, i] wx[k][j]
            for j in range(3):
                H[i, j] = -(C[0, i] * wx[0][j] + C[1, i] * wx[1][j] + C[2, i] * wx[2][j])
            H[i, _BG + i] = -1.0
            var = max(float(np.mean(W[:, 6 + i])), _VAR_FLOOR_GYRO)
            R[i, i] = var / n_tot + _R_FLOOR
            rec[3 + i] = R[i, i]
        if self._bias_ok_us < 0:
            self._bias_ok_us = est.t_us - int(1e6 * k * self.window_s)
        hold = 2 if est.gnss.hold_enabled else -1
        self.updates += 1
        nis = est.fuse_block(3, self._gate3, "gyro_rest", hold)
        if nis >= 0.0 or nis == -math.inf:
            self._n_rej = 0
            self._bias_ok_us = est.t_us
            self.cal_bias[:] = bg
            self.calibrated = True
            return
        self._n_rej += 1
        self._refused(est, w_ie)
        if self._n_rej < _RESET_AFTER:
            return
        # refused _RESET_AFTER times in a row: if the refused readings agree with each other
        # the filter's bias is further off than its covariance admits; take their mean
        J = self._rej
        stat = 0.0
        mean = [float(np.mean(J[:, i])) for i in range(3)]
        for k in range(_RESET_AFTER):
            for i in range(3):
                stat += (J[k, i] - mean[i]) ** 2 / J[k, 3 + i]
        if stat > self._agree_gate:
            # they disagree (a sway, not an offset): forget the oldest
            J[:-1] = J[1:].copy()
            self._n_rej -= 1
            return
        self._n_rej = 0
        P = est.P
        earth2 = OMEGA_IE * OMEGA_IE
        for i in range(3):
            e_b = C[0, i] * w_ie[0] + C[1, i] * w_ie[1] + C[2, i] * w_ie[2]
            bg[i] = mean[i] - e_b
            k = _BG + i
            P[k, :] = 0.0
            P[:, k] = 0.0
            P[k, k] = float(np.mean(J[:, 3 + i])) / _RESET_AFTER + earth2
        est.counters["reset_gyro_rest"] += 1
        self.cal_bias[:] = bg
        self.calibrated = True
        # the wrong bias has been tilting the attitude since the start, by its horizontal
        # part times the time (4.4 deg/s for 20 s: a tilt 40-50 deg off at a sigma of
        # 5-10, velocity fixes accepted because the yaw bank held the tilt as a consider
        # state, the unknown heading's acceleration being the tilt error's gravity); at
        # rest the windows' specific force gives it again (the lock-out recovery's re-level)
        self._bias_ok_us = est.t_us
        if not self._relevel(est):
            tilt2 = self.cfg.init.tilt_sd ** 2
            P[0, 0] += tilt2
            P[1, 1] += tilt2

    def _relevel(self, est: Estimator) -> bool:
        """Roll and pitch from the run's mean specific force (10 s of it: 0.5 deg of noise
        at a consumer VRW, against 1.7 deg from the last 1-s window)."""
        from navd.core.aiding.gnss_recovery import relevel_at_rest  # it imports this module
        return relevel_at_rest(est, self._run_window)

    def _refused(self, est: Estimator, w_ie: tuple[float, float, float]) -> None:
        """A measurement refused: the bias is off by about z, the run's mean rate less bias
        and earth rate ``w_ie`` (rad/s, NED) per body axis.  Where the horizontal part of z,
        acting since the bias was last confirmed, has tilted the attitude by more than three
        tilt sigmas, the state cannot wait for the second refusal: the gyro offset of 4.4
        deg/s above had tilted it 20 deg by the first, 10 s in, and the velocity fixes,
        with the yaw bank holding the tilt, would not bring it back.  Then the tilt is
        re-levelled now and the bias variance widens by z^2, so that the fixes and the next
        measurement may move it.  A smaller refusal (log171 on the ground before take-off:
        0.03 deg/s at sigma 0.005, 0.4 deg of drift at a tilt sigma of 0.65) waits, as
        before, for a second that agrees."""
        P = est.P
        C = est.mat_nb
        bg, rw = est.bias_g, self._run_window
        z = [float(bg[i]) + C[0, i] * w_ie[0] + C[1, i] * w_ie[1] + C[2, i] * w_ie[2]
             - float(rw[i]) for i in range(3)]
        zn = C[0, 0] * z[0] + C[0, 1] * z[1] + C[0, 2] * z[2]
        ze = C[1, 0] * z[0] + C[1, 1] * z[1] + C[1, 2] * z[2]
        drift = math.hypot(zn, ze) * max(est.t_us - self._bias_ok_us, 0) * 1e-6
        if drift <= 3.0 * math.sqrt(max(float(P[0, 0]), float(P[1, 1]))):
            return
        if self._relevel(est):
            for i in range(3):
                P[_BG + i, _BG + i] += z[i] * z[i]
            est.counters["gyro_rest_relevel"] += 1
