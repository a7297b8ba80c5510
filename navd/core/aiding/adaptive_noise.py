"""Process and GNSS velocity noise adapted online from the velocity innovations (docs/design.md
§3.3).

Why.  A user who states the IMU's noise too low (or whose vehicle vibrates more than the
datasheet) gets a filter that trusts its own propagation too much: the velocity
innovations outgrow their predicted covariance, the gate refuses honest fixes, and the
lock-out recovery has to reset the state again and again (issue 14: 3x the configured ARW
and VRW gave 4 deg of tilt with 61 resets).  The innovations themselves say so.

Test.  For a consistent filter the velocity NIS of an epoch is chi-square with m degrees
of freedom (m = 3, 2 without a reported vertical velocity, +1 when the course row joined),
so it exceeds the chi-square median with probability 1/2.  Over ``_WINDOW`` epochs that
tried the velocity update (accepted or refused; the refused count as high), the number k
above the median is Binomial(N, 1/2) for a consistent filter: a sign test, which does not
care how heavy the tail of the innovations is (one wild fix counts once, unlike a mean of
NIS).  z = (k - N/2) / (sqrt(N)/2): above ``_Z_UP`` the white-noise densities (ARW, VRW) are
scaled up by the window's median NIS ratio (NIS over the chi-square median; between
``_STEP`` and ``_MAX_STEP``); below ``_Z_DOWN`` they come back down by ``_STEP``, never below
the configured values and never above ``[filter] max_q_scale`` times them (variance scale;
25 = 5x sigma).

Which noise.  Too large an innovation has two causes with opposite signatures (Mehra's
classic argument): a filter that trusts its propagation too much (IMU noise understated)
under-corrects, so its innovations stay correlated from one epoch to the next; one that
trusts the fixes too much (a receiver that understates its velocity noise) chases their
noise and over-corrects, so consecutive innovations anti-correlate.  The window's lag-1
correlation of the horizontal velocity innovations, rho = sum z_k z_k-1 / sum z_k^2, picks
the one to scale up: rho > 0 the IMU white noise (Q), else the reported GNSS velocity
variance (R, applied to the following epochs' velocity sigma).  Measured on car480 with the
adaptation off: 3x IMU noise rho = +0.14 (window 10-90 %: +0.03..+0.28), 3x GNSS velocity
noise rho = -0.18 (-0.29..-0.05), clean -0.02 (-0.17..+0.14).  Too small an innovation
brings down the one that over-corrects (rho < 0: Q), else R, never below 1.

Not fighting the bias estimation.  An uncalibrated gyro also makes velocity innovations
large, and inflating the white noise then only widens every sigma while the bias stays
wrong (an earlier version of this took an uncalibrated-gyro car from 11.6 to 83.6 deg of
tilt).  So a window counts only while the bias estimates have settled: every gyro-bias
sigma below ``_SETTLED`` times its prior, the specific-force error the accelerometer bias and
the tilt make together (per NED axis, ``[f^n×] φ + C δb_a`` with gravity for f^n) below
``_SETTLED`` times the accelerometer-bias prior sigma, and both estimates within the physical
limits of :mod:`navd.core.aiding.gnss_recovery`.  Until then the bias states, not the noise,
are what must move.  (The accelerometer bias's own sigma is no test: on a straight road it
stays near its prior, honestly, since only turns tell it from tilt (core/level.py), while the
combination that moves the velocity is known within seconds.)  The gyro side is judged in
the same currency: the tilt the gyro-bias uncertainty can build within one window, times g,
must be below the specific-force error's sigma.  And the first window after the biases
settle is skipped: its innovations still carry the convergence that just ended.

Gyro-bias walk.  Innovations that persist say the filter lags a slow error it believes it
knows: a window with lag-1 correlation above ``_RHO_UP``, or whose innovations keep a mean
(``_MR_UP``: a drift the filter half-follows keeps rho low), scales the gyro-bias random walk
up; the mean also reopens the tilt / accelerometer-bias split by the acceleration it left
unexplained (:meth:`AdaptiveNoise._reopen_split`), since the tilt the drift built before is
already hidden in the bias.  Counted ``bias_q_up`` / ``bias_q_down`` /
``tilt_split_reopened``.

The innovations miss a gyro error that wanders within seconds (aliased vibration): the tilt
it builds goes into the accelerometer-bias estimate and the velocity stays right.  The
gyro-bias estimates then move farther than their own covariance allows, which a chi-square
test on their summed corrections over 30 s finds (``gyro_bias_corrections_high``; the walk
steps up and is held there, see ``_CSLOTS``).  On a vehicle whose course is heading the
same error shows sooner in the course innovations, which keep their sign for seconds: the
gyro's white noise and its bias walk step up (``gyro_noise_up``, see ``_CM_UP``).

Counted ``q_scale_up`` / ``q_scale_down`` / ``r_scale_up`` / ``r_scale_down``; the status
record shows both scales.  A restart keeps them (it changes neither sensor).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from navd.config import EstimatorConfig
from navd.core import state as st
from navd.core.aiding.base import (
    ACCEPTED,
    INNOV_COURSE,
    INNOV_FLAG,
    INNOV_NIS,
    INNOV_VEL,
    REJECTED,
)
from navd.core.aiding.gnss_recovery import ACCEL_BIAS_LIMIT
from navd.core.aiding.gyro_rest import GYRO_BIAS_LIMIT
from navd.core.chi2 import chi2_quantile
from navd.units import G0

if TYPE_CHECKING:
    from navd.core.estimator import Estimator

_WINDOW = 50  # velocity epochs per sign test (5 s at 10 Hz)
_Z_UP = 2.5  # sign-test z above which the noise is scaled up
_Z_DOWN = -2.0  # ... below which it comes back down
_STEP = math.sqrt(2.0)  # variance factor per decision (down; the least up)
_MAX_STEP = 4.0  # the most up per decision
_SETTLED = 0.8  # bias sigma / prior sigma below which the biases count as settled
_UNLATCH = 0.5  # bias variance growth (in prior variances) that says a reset widened it

# persistence of the innovations (lag-1 correlation rho of a window): above _RHO_UP the
# gyro-bias random walk is scaled up by _B_STEP, below _RHO_DOWN down by 2.  Simulated IMUs
# whose bias follows the configured walk give rho <= 0.18 in 90 % of windows (car480,
# multirotor, drive_long, Gauss-Markov, 100x walk; never above _RHO_UP in the robustness
# benchmark); the real logs give medians of 0.3-0.85 (log171, quad123, f450, X8).
_RHO_UP = 0.5
_RHO_DOWN = 0.25
# persistence as a non-zero mean: M = |sum z|^2 / sum |z|^2 over the window's horizontal
# velocity innovations is chi-square(2)/2 for white ones, P(M > x) = exp(-x): above _MR_UP
# (p = 0.25 %) the window's innovations carry a mean the filter does not model: the walk is
# scaled up by _B_BIG and the tilt / accelerometer-bias split reopened (_reopen_split).
# Measured (mean ratio per window): car480 clean at most 7.2 in 96 windows; the 600x drifting
# gyro 11-33 from 70 s on while its lag-1 correlation stayed 0.1-0.5; real logs 3-17 (median).
# One window at p = 0.25 % is no proof: a drive of an hour (720 windows) would see ~2 false
# ones, each reopening the split by a mean that is noise (clean car480, seeds 1-10: 2 reopens;
# car_run 300 s seed 2: M 7.3 at 288.7 s, accelerometer-bias sigma 2.7 -> 26 mg).  So a lone
# window above _MR_UP only steps the walk as a persistent rho does (_B_STEP); two in a row
# (p ~ 6e-6) or one above _MR_ONE (p = 3.4e-4, ~0.24 an hour) take _B_BIG and reopen the
# split.  Tried (the 600x drifting gyro, seeds 1-6 pooled, roll / pitch beyond 3 sigma; clean
# reopens in seeds 1-10): one window > 6 (before): 5.7 / 3.5 %, 2; two in a row only:
# 10.2 / 10.4 %, 0; _MR_ONE 8: 5.2 / 5.8 %, 0; 9: 10.1 / 5.7 %; 12: 6.3 / 5.7 %.
_MR_UP = 6.0
_MR_ONE = 8.0
_MR_DOWN = 1.0  # ... the walk comes down only in a window with M below this (and low rho)
_B_DOWN = 1.19  # ... and then by 2^(1/4): a consistent window is no proof the walk is too large
_B_BIG = 256.0  # step on a non-zero mean: the 600x walk (variance 3.6e5) within 3 windows
_B_STEP = 16.0  # a real drift (log171: ~720 deg/h in 2 min) needs a walk 1000x the prior's
# The gyro-bias corrections' own consistency (_corrections_window).  For a consistent
# filter with white innovations the summed correction d_i of gyro-bias axis i over a span
# has variance V_i = sum (P- - P+)_ii, what the span's updates took off P; so
# Z = sum_i d_i^2 / V_i over the last _CSLOTS windows (30 s at 10 Hz, tested at the end of
# every window) is about chi-square(3).  Above _CZ_UP (p ~ 0.1 %) the walk steps up by
# _B_STEP, above _CZ_BIG (p ~ 1e-8) by _B_BIG.  It sees what the innovations do not: a gyro
# error that wanders within seconds (a rotor's vibration aliased to near DC in a rate
# message, tenths of a deg/s that come and go) builds tilt that the accelerometer-bias
# estimate absorbs, so the innovations stay white (car480, 10 deg/s of vibration at
# 100 +- 3 Hz read at 100 Hz, seed 1: median NIS ratio 1.0-1.6, rho and M as clean) while
# the bias estimates move 2-10x farther than their covariance allows (mean d_i^2 / V_i over
# 30 s: 1.6 / 5.0 / 10.8 on x / y / z; clean 0.6 / 1.0 / 0.4).  The tilt it built is what
# the accelerometer-bias estimate absorbed: a high Z reopens the split by that estimate's
# summed correction over the span (the drifting gyro kept 3-5 deg of roll hidden without
# it: docs/results.md, "Aliased vibration").  A high Z also sets a floor under the walk
# that the 5-s windows' down steps cannot pass, lowered by _B_DOWN per consistent 30 s:
# white innovations say nothing about this error, so only this test may take the walk back.
_CSLOTS = 6
_CZ_UP = 16.27
_CZ_BIG = 40.0
# The course innovations' own persistence (_course_window).  Gyro noise the configuration
# does not state but the filter integrates as white noise (a rotor's or engine's vibration
# aliased to within a few Hz of DC in a rate message: ~3 deg/sqrt(h) equivalent from 0.3 to
# 30 s, Allan deviation, for 5 deg/s of it about z at 100 +- 3 Hz read at 100 Hz; the consumer
# preset says 0.5) moves the yaw between course fixes, and the filter, believing its yaw
# within 0.05 deg, takes seconds to follow: the course innovations keep a sign for seconds.
# Neither the IMU's own samples (the measured floor refuses noise that grows with the
# averaging time as motion, imu_noise.py) nor the velocity innovations (the tilt it builds
# goes into the accelerometer-bias estimate) see it.  Per _WINDOW accepted course rows the
# normalised innovations w = z / sqrt(S) give M = (sum w)^2 / sum w^2, chi-square(1) for
# white ones: above _CM_UP the gyro's white-noise variance is scaled by _G_UP (never past
# [filter] max_q_scale with the other scales) and the gyro-bias walk by _B_STEP; it comes
# down by _B_DOWN only when the mean M of _CSLOTS windows in a row (30 s) is below _CM_DOWN
# (then the next 30 s must say so again).  Coming down on one low window (M < 0.1, p 25 %
# when the noise is right) settled the scale where the noise was still understated:
# vib_car_10dps went up and down 20-40 times a run, tilt beyond 3 sigma 6.6 % (3.7 % now).
# The same noise on x and y is what the tilt needs (car480 with 10 / 10 / 5 deg/s of it,
# seeds 1-5: a configured ARW of 6 deg/sqrt(h) leaves roll / pitch / heading beyond 3 sigma
# in 0.6 / 0.6 / 0.0 % of instants, the preset's 0.5 with this test off roll / pitch in
# 11 / 7 %), so the scale is the gyro's, not the yaw's alone.
_CM_UP = 6.63
_CM_DOWN = 0.5
_G_UP = 16.0
# state array: high count, epochs counted, Q scale, R scale, sums for the lag-1 correlation
# of the horizontal velocity innovations (sum z_k z_k-1, sum z_k^2), the previous z (N, E),
# gyro-bias walk scale, sums of z (N, E) and of the unexplained acceleration (N, E), and
# whether the previous window's mean ratio was above _MR_UP
_HIGH, _N, _SCALE, _RSCALE, _SZZ, _SZ2, _PN, _PE, _BSCALE, _SN, _SE, _AN, _AE, _MHIT = range(14)


def _ring_sum(r: npt.NDArray[np.float64]) -> float:
    """Sum of a small ring in scalars (a GNSS epoch creates no arrays)."""
    t = 0.0
    for i in range(r.shape[0]):
        t += float(r[i])
    return t


class AdaptiveNoise:
    """Sign test on the velocity NIS and the scale of the IMU white-noise densities."""

    def __init__(self, cfg: EstimatorConfig) -> None:
        self.cfg = cfg
        self.enabled = cfg.filter.adaptive_noise and (cfg.filter.max_q_scale > 1.0
                                                      or cfg.filter.max_bias_q_scale > 1.0)
        self.max_scale = cfg.filter.max_q_scale
        self.max_bias_scale = cfg.filter.max_bias_q_scale
        # chi-square medians for m = 1..4 degrees of freedom
        self._median = np.array([0.0] + [chi2_quantile(0.5, m) for m in range(1, 5)])
        self._s = np.zeros(14)
        self._s[_SCALE] = 1.0
        self._s[_BSCALE] = 1.0
        self._s[_RSCALE] = 1.0
        self._s[_PN] = math.nan
        # this window's NIS over its chi-square median (refused epochs: inf)
        self._ratio = np.zeros(_WINDOW)
        self._sorted = np.zeros(_WINDOW)  # scratch for the window's median
        imu = cfg.imu
        self._q_bg = imu.gyro_bias_rw ** 2
        self._gyro_sd2 = imu.gyro_bias_sd ** 2
        self._t_prev = -1  # IMU time of the previous epoch, us
        self._fix_dt = 0.1  # the GNSS epoch interval, s (a window is _WINDOW of them)
        self._dwell = 0
        self._known = False  # the biases counted as settled once (latch, _settled)
        self._pv = np.zeros(6)  # the bias variances since then, least seen
        self._ve = np.zeros(3)  # scratch: variance of the specific-force error per NED axis
        self._accel_sd2 = imu.accel_bias_sd ** 2
        self._t = np.zeros(5)  # scratch: the direction _reopen_split widens
        # the biases at the epoch's start (gyro then accelerometer) and the gyro-bias variance
        self._b0 = np.zeros(6)
        self._p0 = np.zeros(3)
        # per _WINDOW of epochs (a slot) the summed corrections and variance reductions, a
        # ring of _CSLOTS slots; the open slot's epochs, the slots filled
        self._cd = np.zeros((_CSLOTS, 6))  # gyro-bias corrections, then accelerometer's
        self._cv = np.zeros((_CSLOTS, 3))
        self._cn = 0
        self._cfill = 0
        self._dsum = np.zeros(3)  # scratch: the span's accelerometer-bias corrections, body
        self._bfloor = 1.0  # the walk scale the corrections' test holds it at, at least
        self._zlast = math.nan  # the last test's Z (status)
        self._cw = np.zeros(3)  # the course window: sum w, sum w^2, rows (_course_window)
        self._cm = np.zeros(_CSLOTS)  # the last windows' M (_course_window), a ring
        self._cmn = 0  # windows in the ring since it was last cleared

    @property
    def scale(self) -> float:
        """Present variance scale of the IMU white noise (1 = as configured)."""
        return float(self._s[_SCALE])

    @property
    def bias_scale(self) -> float:
        """Present variance scale of the gyro-bias random walk (1 = as configured)."""
        return float(self._s[_BSCALE])

    @property
    def corrections_z(self) -> float:
        """The gyro-bias corrections' last Z over its span (about chi-square(3) for a
        consistent filter; NaN before the first test), see ``_CSLOTS``."""
        return self._zlast

    @property
    def r_scale(self) -> float:
        """Present variance scale of the GNSS velocity accuracy (1 = as reported)."""
        return float(self._s[_RSCALE])

    @property
    def r_sd_factor(self) -> float:
        """Factor on the GNSS velocity sigma (sqrt of :attr:`r_scale`)."""
        return math.sqrt(float(self._s[_RSCALE]))

    def reset(self) -> None:
        """Start the window over; the scales are kept (a restart changes neither sensor)."""
        self._clear()
        self._clear_corrections()
        self._cw.fill(0.0)
        self._cmn = 0
        self._s[_MHIT] = 0.0
        self._known = False
        self._dwell = 0

    def _clear(self) -> None:
        s = self._s
        s[_HIGH] = s[_N] = s[_SZZ] = s[_SZ2] = s[_SN] = s[_SE] = s[_AN] = s[_AE] = 0.0
        s[_PN] = math.nan

    def _clear_corrections(self) -> None:
        for k in range(_CSLOTS):
            for i in range(3):
                self._cd[k, i] = self._cd[k, 3 + i] = self._cv[k, i] = 0.0
        self._cn = 0
        self._cfill = 0

    def before_epoch(self, est: Estimator) -> None:
        """Call once per GNSS epoch before its updates: the gyro-bias estimate and variance
        they start from."""
        for i in range(3):
            self._b0[i] = est.bias_g[i]
            self._b0[3 + i] = est.bias_a[i]
            self._p0[i] = est.P[9 + i, 9 + i]

    def _corrections_window(self, est: Estimator) -> None:
        """Add this epoch's gyro-bias corrections; every _WINDOW epochs test the last
        _CSLOTS windows' sum and step the walk up if the corrections moved more than their
        covariance allows (see _CSLOTS)."""
        P = est.P
        for i in range(3):
            if P[9 + i, 9 + i] > self._p0[i]:
                # widened within the epoch (a reset, the split reopened): no longer one filter
                self._clear_corrections()
                return
        slot = self._cfill % _CSLOTS
        for i in range(3):
            self._cd[slot, i] += est.bias_g[i] - self._b0[i]
            self._cd[slot, 3 + i] += est.bias_a[i] - self._b0[3 + i]
            self._cv[slot, i] += self._p0[i] - P[9 + i, 9 + i]
        self._cn += 1
        if self._cn < _WINDOW:
            return
        self._cn = 0
        self._cfill += 1
        zsum = 0.0
        nslots = min(self._cfill, _CSLOTS)
        da = self._dsum
        for i in range(3):
            d = v = 0.0
            da[i] = 0.0
            for k in range(nslots):
                d += self._cd[k, i]
                v += self._cv[k, i]
                da[i] += self._cd[k, 3 + i]
            # an axis the span's updates barely touched (held, unobservable) says nothing;
            # its tiny V must not turn round-off in d into a test result
            if v > 1e-9 * self._gyro_sd2:
                zsum += d * d / v
        nxt = self._cfill % _CSLOTS
        for i in range(3):
            self._cd[nxt, i] = self._cd[nxt, 3 + i] = self._cv[nxt, i] = 0.0
        self._zlast = zsum
        s = self._s
        if zsum > _CZ_UP:
            est.counters["gyro_bias_corrections_high"] += 1
            if s[_BSCALE] < self.max_bias_scale:
                step = _B_BIG if zsum > _CZ_BIG else _B_STEP
                s[_BSCALE] = min(s[_BSCALE] * step, self.max_bias_scale)
                est.counters["bias_q_up"] += 1
                self._apply(est)
            self._bfloor = float(s[_BSCALE])
            if self.max_bias_scale > 1.0:
                # the tilt the wandering bias built went into the accelerometer-bias
                # estimate (the innovations stayed white): reopen the split by what that
                # estimate moved over the span, horizontal NED (never past its prior)
                C = est.mat_nb
                b_n = C[0, 0] * da[0] + C[0, 1] * da[1] + C[0, 2] * da[2]
                b_e = C[1, 0] * da[0] + C[1, 1] * da[1] + C[1, 2] * da[2]
                self._reopen_split(est, b_n, b_e)
            # the evidence is spent: the next test starts afresh
            self._clear_corrections()
        elif self._cfill % _CSLOTS == 0:
            self._bfloor = max(self._bfloor / _B_DOWN, 1.0)

    def _course_window(self, est: Estimator) -> None:
        """Add this epoch's course innovation if its row was applied; every _WINDOW of them
        test their mean and step the gyro's white-noise scale (see _CM_UP)."""
        rec = est.innov[INNOV_COURSE]
        nis = rec[INNOV_NIS]
        if rec[INNOV_FLAG] != ACCEPTED or not nis > 0.0 or not math.isfinite(nis):
            return
        cw = self._cw
        w = math.copysign(math.sqrt(nis), rec[0])
        cw[0] += w
        cw[1] += w * w
        cw[2] += 1.0
        if cw[2] < _WINDOW:
            return
        m = cw[0] * cw[0] / cw[1]
        cw[0] = cw[1] = cw[2] = 0.0
        if est.gnss.course.noise.scale > 1.0:
            # the course against the gyro alone says the course carries a slip of its own
            # (course_noise.py): its persistence is not the gyro's (a raise it made before
            # the slip was sized is taken back), and the rows already carry its variance
            self._cmn = 0
            if est.imu_noise.gyro_scale > 1.0:
                est.imu_noise.set_gyro_scale(1.0, est.buf[st.Q:st.Q + 15])
                est.counters["gyro_noise_down"] += 1
            return
        cm = self._cm
        cm[self._cmn % _CSLOTS] = m
        self._cmn += 1
        noise = est.imu_noise
        g = noise.gyro_scale
        if m > _CM_UP:
            self._cmn = 0  # the ring's evidence for coming down starts over
            s = self._s
            if s[_BSCALE] < self.max_bias_scale:
                # a yaw that keeps leaving its course is also what a gyro bias drifting
                # faster than its walk makes (the 600x drifting gyro fires this ~20 s before
                # the bias tests): the walk steps as for a persistent velocity innovation
                s[_BSCALE] = min(s[_BSCALE] * _B_STEP, self.max_bias_scale)
                est.counters["bias_q_up"] += 1
                self._apply(est)
            if g >= self.max_scale:
                return
            g = min(g * _G_UP, self.max_scale)
            est.counters["gyro_noise_up"] += 1
        elif self._cmn >= _CSLOTS and g > 1.0 and _ring_sum(cm) < _CM_DOWN * _CSLOTS:
            self._cmn = 0
            g = max(g / _B_DOWN, 1.0)
            est.counters["gyro_noise_down"] += 1
        else:
            return
        noise.set_gyro_scale(g, est.buf[st.Q:st.Q + 15])

    def _median_ratio(self) -> float:
        """The window's median NIS ratio, sorted in preallocated scratch (np.median copies:
        a GNSS epoch allocates nothing, even the one that ends a window)."""
        w = self._sorted
        r = self._ratio
        # insertion sort (ndarray.sort takes a few kB of scratch); once per window
        for i in range(_WINDOW):
            x = float(r[i])
            j = i - 1
            while j >= 0 and w[j] > x:
                w[j + 1] = w[j]
                j -= 1
            w[j + 1] = x
        h = _WINDOW // 2
        return float(w[h]) if _WINDOW % 2 else 0.5 * (float(w[h - 1]) + float(w[h]))

    def _settled(self, est: Estimator) -> bool:
        P = est.P
        s = _SETTLED * _SETTLED
        for k in range(3):
            if (P[9 + k, 9 + k] > s * self._gyro_sd2 or abs(est.bias_g[k]) > GYRO_BIAS_LIMIT
                    or abs(est.bias_a[k]) > ACCEL_BIAS_LIMIT):
                return False
        # The accelerometer side: what the velocity innovations see is the specific-force
        # error e = [f^n x] phi + C dba (f^n ~ gravity), not the bias alone.  Tilt and
        # horizontal bias are one unknown until turns separate them (P0 correlates them,
        # core/level.py), so the bias sigma stays near its prior on a straight road while e,
        # which drives the innovations, is known within seconds.  The gyro side in the same
        # currency: the tilt the gyro-bias sigma can build within one window (x g) must be
        # below e's sigma, else large correlated innovations are that bias being learned.
        # Once both held the biases count as settled (a latch): the sigmas grow with the
        # very noise scales this adapts, which must not switch the adaptation off.  A reset
        # that widens a bias again (lock-out, bias limits: half its prior variance or more
        # at once, where the random walks add a tiny fraction) or a restart clears it.
        pv = self._pv
        if self._known:
            for k in range(6):
                v = P[9 + k, 9 + k]
                if v > pv[k] + _UNLATCH * (self._gyro_sd2 if k < 3 else self._accel_sd2):
                    self._known = False
                    return False
                if v < pv[k]:
                    pv[k] = v
            return True
        C = est.mat_nb
        g = G0
        ve = self._ve
        for i in range(3):
            # e_i = a . (phi_N, phi_E, dba_x, dba_y, dba_z)
            a0 = -g if i == 1 else 0.0
            a1 = g if i == 0 else 0.0
            v = a0 * a0 * P[0, 0] + 2.0 * a0 * a1 * P[0, 1] + a1 * a1 * P[1, 1]
            for j in range(3):
                cj = C[i, j]
                v += 2.0 * cj * (a0 * P[0, 12 + j] + a1 * P[1, 12 + j])
                for k in range(3):
                    v += cj * C[i, k] * P[12 + j, 12 + k]
            if v > s * self._accel_sd2:
                return False
            ve[i] = v
        # phi_N' = -(C dbg)_N shows in e_E, phi_E' in e_N
        tw2 = (_WINDOW * self._fix_dt * g) ** 2
        for i in range(2):
            v = 0.0
            for j in range(3):
                for k in range(3):
                    v += C[i, j] * C[i, k] * P[9 + j, 9 + k]
            if v * tw2 > ve[1 - i]:
                return False
        self._known = True
        for k in range(6):
            pv[k] = P[9 + k, 9 + k]
        return True

    def after_epoch(self, est: Estimator, vel_d_reported: bool, vel_sd: float = math.nan) -> None:
        """Call once per GNSS epoch after its updates."""
        if not self.enabled:
            return
        r = est.innov
        flag = r[INNOV_VEL, INNOV_FLAG]
        nis = r[INNOV_VEL, INNOV_NIS]
        if (flag != ACCEPTED and flag != REJECTED) or not math.isfinite(nis):
            return
        if self._t_prev >= 0:
            self._fix_dt = min(max((est.t_us - self._t_prev) * 1e-6, 0.01), 1.0)
        self._t_prev = est.t_us
        if self.max_scale > 1.0:
            self._course_window(est)
        if not self._settled(est):
            self._clear()
            self._clear_corrections()
            self._s[_MHIT] = 0.0
            self._dwell = 0
            return
        if self._dwell < _WINDOW:  # the first window after settling: skipped (module doc)
            self._dwell += 1
            return
        self._corrections_window(est)
        m = (3 if vel_d_reported else 2) + (1 if r[INNOV_COURSE, INNOV_FLAG] == ACCEPTED
                                            and flag == ACCEPTED else 0)
        s = self._s
        ratio = math.inf if flag == REJECTED else nis / self._median[m]
        if ratio > 1.0:
            s[_HIGH] += 1.0
        self._ratio[int(s[_N])] = ratio
        s[_N] += 1.0
        zn, ze = r[INNOV_VEL, 0], r[INNOV_VEL, 1]
        if math.isfinite(zn) and math.isfinite(ze):
            if math.isfinite(s[_PN]):
                s[_SZZ] += zn * s[_PN] + ze * s[_PE]
            s[_SZ2] += zn * zn + ze * ze
            s[_SN] += zn
            s[_SE] += ze
            if flag == ACCEPTED and vel_sd > 0.0:
                r2 = vel_sd * vel_sd
                s[_AN] += zn * min(est.P[3, 3] / r2, 1.0) / self._fix_dt
                s[_AE] += ze * min(est.P[4, 4] / r2, 1.0) / self._fix_dt
            s[_PN] = zn
            s[_PE] = ze
        if s[_N] < _WINDOW:
            return
        z = (s[_HIGH] - 0.5 * s[_N]) / (0.5 * math.sqrt(s[_N]))
        rho = s[_SZZ] / s[_SZ2] if s[_SZ2] > 0.0 else 0.0
        mr = (s[_SN] * s[_SN] + s[_SE] * s[_SE]) / s[_SZ2] if s[_SZ2] > 0.0 else 0.0
        a_n, a_e = s[_AN] / _WINDOW, s[_AE] / _WINDOW
        self._clear()
        mean_seen = mr > _MR_UP
        mean_held = (mean_seen and s[_MHIT] > 0.0) or mr > _MR_ONE  # or one beyond doubt
        s[_MHIT] = 1.0 if mean_seen else 0.0
        if (rho > _RHO_UP or mean_seen) and s[_BSCALE] < self.max_bias_scale:
            step = _B_BIG if mean_held else _B_STEP
            s[_BSCALE] = min(s[_BSCALE] * step, self.max_bias_scale)
            est.counters["bias_q_up"] += 1
            self._apply(est)
            if mean_held:
                self._reopen_split(est, a_n, a_e)
        elif rho < _RHO_DOWN and mr < _MR_DOWN and s[_BSCALE] > self._bfloor:
            s[_BSCALE] = max(s[_BSCALE] / _B_DOWN, self._bfloor)
            est.counters["bias_q_down"] += 1
            self._apply(est)
        if z > _Z_UP:
            # the median NIS ratio says how far off the innovation covariance is: step by
            # it (at least _STEP, at most _MAX_STEP) so a 9x understated noise is found in
            # a few windows, not a dozen
            step = min(max(self._median_ratio(), _STEP), _MAX_STEP)
            # which one: a filter that trusts its propagation too much under-corrects, so
            # its innovations stay correlated from epoch to epoch (rho > 0); one that trusts
            # noisy fixes too much chases their noise and over-corrects (rho < 0)
            k = _SCALE if rho > 0.0 else _RSCALE
            if s[k] < self.max_scale:
                s[k] = min(s[k] * step, self.max_scale)
                est.counters["q_scale_up" if k == _SCALE else "r_scale_up"] += 1
                self._apply(est)
        elif z < _Z_DOWN:
            # too small an innovation: the one that over-corrects (rho < 0) is too large
            k = _SCALE if rho < 0.0 else _RSCALE
            if s[k] <= 1.0:
                k = _RSCALE if k == _SCALE else _SCALE
            if s[k] > 1.0:
                s[k] = max(s[k] / _STEP, 1.0)
                est.counters["q_scale_down" if k == _SCALE else "r_scale_down"] += 1
                self._apply(est)

    def _reopen_split(self, est: Estimator, a_n: float, a_e: float) -> None:
        """Widen P along the direction the velocity cannot see: tilt and horizontal
        accelerometer bias moved together so that the specific-force error
        ``e = [f^n x] phi + C dba`` stays (phi_N = w_E / g, phi_E = -w_N / g, C dba += w, w a
        NED-horizontal bias).

        Why.  A window whose velocity innovations keep a mean says the specific force was
        wrong for a while; with a gyro bias drifting faster than modelled, what the filter made
        of it is a wrong split: the tilt the bias built went into the accelerometer bias (the
        two are one unknown between turns), the tilt stays off and its sigma, believing the
        split known from earlier turns, does not cover it (car480, 600x walk: 4-13 deg with a
        0.5 deg sigma).  Raising the walk only helps from now on.  So the split is reopened, as
        at levelling (core/level.py), by the acceleration the window could not explain:
        a (a_n, a_e; m/s^2, NED) is the mean innovation times the velocity gain (P_vv / R) over
        the GNSS interval, the persistent specific-force error a steady-state velocity loop
        leaves.  Topped up to a^2 along each horizontal direction, never past the
        accelerometer-bias prior variance (what levelling itself leaves open).  A rank-one
        addition per direction: P stays symmetric and positive semi-definite; scalars only."""
        P = est.P
        C = est.mat_nb
        g = G0
        opened = False
        for c in range(2):  # bias direction w along N (c = 0), E (c = 1)
            cur = 0.0  # variance of the bias along that direction, (C P_bb C^T)_cc
            for j in range(3):
                for k in range(3):
                    cur += C[c, j] * C[c, k] * P[12 + j, 12 + k]
            add = min((a_n if c == 0 else a_e) ** 2, self._accel_sd2) - cur
            if add <= 0.0:
                continue
            opened = True
            # the direction t over the states phi_N, phi_E, dba_x..z (indices 0, 1, 12-14)
            t = self._t
            t[0] = 1.0 / g if c == 1 else 0.0
            t[1] = -1.0 / g if c == 0 else 0.0
            t[2], t[3], t[4] = C[c, 0], C[c, 1], C[c, 2]
            for a in range(5):
                ia = a if a < 2 else 10 + a
                for b in range(5):
                    P[ia, 10 + b if b >= 2 else b] += add * t[a] * t[b]
        if opened:
            est.counters["tilt_split_reopened"] += 1

    def _apply(self, est: Estimator) -> None:
        q = est.buf[st.Q:st.Q + 15]  # the continuous noise densities the propagation uses
        # the white noise: this scale times the measured floor (core/aiding/imu_noise.py)
        est.imu_noise.set_scale(float(self._s[_SCALE]), q)
        q[9] = q[10] = q[11] = self._s[_BSCALE] * self._q_bg
