"""Gyro offset at rest: what autopilots do at boot, done as a measurement of the gyro bias.

Why.  A consumer MEMS gyro out of the box is off by 0.3-1 deg/s (hundreds to thousands of
deg/h), far beyond what a filter prior of a few deg/h admits; the filter then takes the
offset for rotation, the tilt runs away and every honest GNSS fix is refused (issue 14).
At rest the mean gyro output is known up to noise: offset + earth rate.  Averaging it is the
cheapest and best gyro calibration there is, and it observes the vertical gyro axis too,
which GNSS fixes at rest cannot.

Stillness.  "At rest" is decided from the IMU itself, over windows of ``_WINDOW_S``:

* every window's mean rate is below ``[init] static_rate_tol_dps`` and its mean specific
  force is within ``_F_TOL`` of gravity (no turning, no acceleration);
* across ``_WINDOWS`` consecutive windows, the window means of rate *and* specific force
  scatter no more than the noise inside the windows allows (an Allan-variance test at one
  window length: sum over axes and windows of (mean_k - grand mean)^2 / (s^2 / n), which is
  chi-square with 3 (K - 1) degrees of freedom for a still sensor; refused above its
  ``_STILL_PROB`` quantile).  A platform that sways (a boat at anchor, a vehicle rocked by
  wind or by people stepping in) turns back and forth: its window mean rates and its tilt
  (hence mean specific force) change from window to window far more than white noise does,
  so it fails the test even when each window looks quiet.  Vibration much faster than a
  window raises the noise inside the windows as much as it moves their means, so an idling
  engine still counts as rest;
* while navigating, the filter's horizontal speed is below ``_MAX_SPEED_MPS`` (a steady turn
  at constant speed has constant rate and specific force: it would pass the IMU tests).

Not caught: a platform turning in place at a steady rate below ``static_rate_tol_dps`` with
no other motion (a robot spinning slowly on the spot).  Its rate is taken for offset; the
chi-square gate below refuses it once the bias is known better than that rate.

Measurement.  The mean raw rate over the K windows, r (body FRD, rad/s), is offset plus the
earth rate seen in the body, ``r = b_g + C^T w_ie^n + noise``.  Computed - measured, with the
error conventions of docs/design.md §2 (``C_hat = Exp(-phi) C``, ``db = b - b_hat``)::

    z = b_hat + C_hat^T w_ie^n - r = -db - C_hat^T [w_ie^n x] phi - noise
    H = [ -C_hat^T [w_ie^n x] | 0 | 0 | -I | 0 ]

so the heading uncertainty of an unaligned filter (the horizontal earth rate, ~12 deg/h,
depends on it) enters through P rather than by hand, and repeated updates at rest keep the
heading/bias correlation exact.  R is diagonal: the windows' own sample variance over the
number of samples (floored at a quarter of the configured ARW, and at ``_R_FLOOR`` for what
white noise does not describe: temperature, g-sensitivity).  The heading is held as a
consider state when the GNSS hold is enabled (docs/design.md §3.7), so the earth rate does
not become a gyrocompass a MEMS gyro cannot be.  Each update uses fresh windows only.

Gated like any update.  Refused (the filter's bias is further off than its covariance
admits: an uncalibrated gyro under a tight prior), the bias is *set* to the measurement
instead: its covariance becomes R plus the earth rate squared (heading unknown), with no
correlations, and the tilt variance grows by its prior (the wrong bias has been tilting the
attitude).  Counted ``gyro_rest_accepted`` / ``gyro_rest_rejected`` / ``reset_gyro_rest``.
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

_WINDOW_S = 1.0  # one stillness window
_WINDOWS = 5  # windows per test and per bias measurement (5 s at rest)
_STILL_PROB = 0.999  # quantile of the Allan-type chi-square test
_F_TOL = 1.5  # |mean specific force| within this of gravity, m/s^2 (covers 150 mg offsets)
_MAX_SPEED_MPS = 0.5  # filter's horizontal speed below this while navigating
_R_FLOOR = (1.0 * math.pi / 180.0 / 3600.0) ** 2  # (1 deg/h)^2: temperature, g-sensitivity

# accumulator layout (one window): sum rate (3), sum specific force (3), sums of squares of
# both (6), sample count, time (s)
_ACC_W = 14
_BG = 9  # error-state index of the gyro bias


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
    a[13] += dt
    return bool(a[13] >= window_s)


@jit
def slide_out(win: Arr, n: Arr) -> None:
    """Drop the oldest of the ``n[0]`` windows in ``win``."""
    k = int(n[0])
    for i in range(k - 1):
        for j in range(win.shape[1]):
            win[i, j] = win[i + 1, j]
    n[0] = k - 1


@jit
def close_window(a: Arr, win: Arr, n: Arr, rate_tol: float, f_tol: float, g: float,
                 arw: float, vrw: float, still_gate: float) -> int:
    """Close the window accumulated in ``a`` into the run ``win`` (K, 13) holding ``n[0]``
    windows; -1: moving (run cleared), 0: collecting, 1: the K windows are still.

    Per window: mean rate (3), mean specific force (3), sample variances of both (6), count.
    The still test is the module doc's: gross limits per window, then per sensor the
    chi-square scatter of the window means against the in-window noise, with the observed
    variance floored at a quarter of the configured white noise (``arw``, ``vrw``:
    densities) so a near-noiseless sensor is not judged by zero.
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
    dt = a[13] / cnt
    for i in range(a.shape[0]):
        a[i] = 0.0
    rate = math.sqrt(win[k, 0] ** 2 + win[k, 1] ** 2 + win[k, 2] ** 2)
    f = math.sqrt(win[k, 3] ** 2 + win[k, 4] ** 2 + win[k, 5] ** 2)
    if rate > rate_tol or abs(f - g) > f_tol:
        n[0] = 0.0
        return -1
    k += 1
    n[0] = k
    if k < K:
        return 0
    for s in range(2):
        floor = 0.25 * (arw * arw if s == 0 else vrw * vrw) / dt + (1e-14 if s == 0 else 1e-10)
        stat = 0.0
        for ax in range(3 * s, 3 * s + 3):
            mean = 0.0
            var = 0.0
            for j in range(K):
                mean += win[j, ax]
                var += win[j, 6 + ax]
            mean /= K
            var = max(var / K, floor)
            for j in range(K):
                d = win[j, ax] - mean
                stat += d * d * win[j, 12] / var
        if stat > still_gate:
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
        # per sensor: chi-square with 3 (K - 1) dof for a still one
        self._still_gate = chi2_quantile(_STILL_PROB, 3 * (_WINDOWS - 1))
        self._gate3 = chi2_quantile(cfg.filter.gate_prob, 3)
        self.updates = 0
        self.still = False

    def reset(self) -> None:
        self.acc[:] = 0.0
        self._n[0] = 0.0
        self.still = False

    @property
    def windows(self) -> int:
        """Windows of the present still-candidate run (at most ``_WINDOWS``)."""
        return int(self._n[0])

    def window_done(self, est: Estimator) -> None:
        """The present window is complete (:func:`rest_push` returned True)."""
        g = gravity(float(est.pos[0]), float(est.pos[2])) if est.initialized else 9.80665
        imu = self.cfg.imu
        res = close_window(self.acc, self._win, self._n, self.cfg.init.static_rate_tol,
                           _F_TOL, g, imu.gyro_arw, imu.accel_vrw, self._still_gate)
        self.still = res == 1
        if res != 1:
            return
        if not (self.enabled and est.initialized):
            # before navigation: keep the newest windows for the first measurement
            slide_out(self._win, self._n)
            return
        self._n[0] = 0  # each measurement uses fresh windows only
        vn = est.vel_n
        if math.hypot(float(vn[0]), float(vn[1])) < _MAX_SPEED_MPS:
            self._measure(est)

    def _measure(self, est: Estimator) -> None:
        W = self._win
        n_tot = float(np.sum(W[:, 12]))
        imu = self.cfg.imu
        dt = self.window_s * _WINDOWS / n_tot
        lat = float(est.pos[0])
        w_ie = (OMEGA_IE * math.cos(lat), 0.0, -OMEGA_IE * math.sin(lat))
        C = est.mat_nb
        H, z, R = est.meas_H, est.meas_z, est.meas_R
        H[:, :] = 0.0
        R[:, :] = 0.0
        # [w x] for w = w_ie^n
        wx = ((0.0, -w_ie[2], w_ie[1]), (w_ie[2], 0.0, -w_ie[0]), (-w_ie[1], w_ie[0], 0.0))
        bg = est.bias_g
        r_meas = [0.0, 0.0, 0.0]
        for i in range(3):
            e_b = C[0, i] * w_ie[0] + C[1, i] * w_ie[1] + C[2, i] * w_ie[2]  # (C^T w)_i
            r_meas[i] = float(np.sum(W[:, i] * W[:, 12])) / n_tot
            z[i] = float(bg[i]) + e_b - r_meas[i]
            # -(C^T [w x])_i,j = -sum_k C[k, i] wx[k][j]
            for j in range(3):
                H[i, j] = -(C[0, i] * wx[0][j] + C[1, i] * wx[1][j] + C[2, i] * wx[2][j])
            H[i, _BG + i] = -1.0
            var = max(float(np.mean(W[:, 6 + i])), 0.25 * imu.gyro_arw ** 2 / dt)
            R[i, i] = var / n_tot + _R_FLOOR
        hold = 2 if est.gnss.hold_enabled else -1
        self.updates += 1
        nis = est.fuse_block(3, self._gate3, "gyro_rest", hold)
        if nis >= 0.0 or nis == -math.inf:
            return
        # the filter's bias is further off than its covariance admits: take the measurement
        P = est.P
        earth2 = OMEGA_IE * OMEGA_IE
        for i in range(3):
            e_b = C[0, i] * w_ie[0] + C[1, i] * w_ie[1] + C[2, i] * w_ie[2]
            bg[i] = r_meas[i] - e_b
            k = _BG + i
            P[k, :] = 0.0
            P[:, k] = 0.0
            P[k, k] = R[i, i] + earth2
        tilt2 = self.cfg.init.tilt_sd ** 2
        P[0, 0] += tilt2
        P[1, 1] += tilt2
        est.counters["reset_gyro_rest"] += 1
