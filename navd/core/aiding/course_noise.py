"""The GNSS course's noise beyond white: a sideslip that wanders on its own.

The course row (:mod:`navd.core.aiding.gnss_heading`) takes course = heading + learnt slip
+ white noise.  On loose ground, with skid steering or a boat in a swell, heading and
course also differ by a slip of their own, correlated over seconds.  A filter that takes
it for white noise averages ten fixes a second into a yaw it believes to 0.1 deg and follows
the slip (car480 with 1 deg RMS of it, 2 s correlation: heading 1.0 deg RMS at sigma 0.13 deg,
66 % of instants beyond 3 sigma).  The innovations cannot size it: the filter follows the
slip, so they carry only its fast part, of the size an understated receiver noise has.

What can size it is the course against the gyro alone.  The open-loop course difference
d_k = zc_k - O_k (zc the course innovation psi_hat - chi', O the sum of every correction the
updates made to the yaw since the chain began) is chi' against the gyro-integrated heading:
white course noise, the slip, and the gyro's own random walk.  Over blocks of ``T_BLOCK``
seconds its means m_i are differenced twice, D = m_{i+1} - 2 m_i + m_{i-1}, which cancels a
constant and a drifting (gyro-bias) offset; with white noise of variance r per row and a
yaw random walk of density q::

    E[D^2] = r_{i+1} / n_{i+1} + 4 r_i / n_i + r_{i-1} / n_{i-1} + q T

(the walk's share: the integral of the squared influence of a rate increment, T / 3 per
block).  u = D^2 / E[D^2] is chi-square(1) when the course is what the row says; a slip
correlated over seconds adds its long-run variance (its spectrum at ~1 / (2 T)), so the mean
of u is the factor by which the row's white variance understates the course's noise at the
time scales the filter averages over.  Measured (docs/results.md, "A slip of the course's
own"), largest mean u over 2 minutes, T = 5 s: car480 clean 0.7-1.0, the other car cases
whose course is the heading (vibrating gyro, understated receiver noise, lever arm) at most
2.6, two whose slip learner is still learning a gain (sideslip with gyro scale errors, the
foreign car) 4.4-5.4, the wandering slip 60-550 (its smallest and largest).

When that mean passes ``U_ON`` the course rows' variance is scaled by it (never below 1,
until it falls under ``U_OFF``): the filter then averages the course over minutes, which is
what a slip with a long-run variance lambda r needs, and the gyro carries the yaw between.
Rows whose innovation is beyond ``ROW_GATE`` of the scaled variance are left out of the
blocks (a glitch moves one block mean by its whole size).  Arrays only: the epoch loop
rebinds no Python objects.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

Arr = npt.NDArray[np.float64]

# block length (s), the longest gap between rows inside a chain of blocks (s), the tests
# in the mean (2 minutes of 5-s blocks), the fewest before the mean decides
T_BLOCK = 5.0
MAX_GAP_S = 1.0
N_TESTS = 24
MIN_TESTS = 4
# the mean u of n tests that switches the scale on: U_ON, or U_SIGMAS standard deviations
# of a consistent filter's mean above 1 if that is more (the overlapping second
# differences are correlated, -2/3 and 1/6 at lags 1 and 2: the mean of n has variance
# 2 (1 + 2 (4/9 + 1/36)) / n = U_VAR / n, and chi-square's tail is longer than that):
# white noise of the stated variance, three runs of two hours, mean of 24 at most 2.3-3.05;
# navd on the car cases whose course is the heading, 20 runs of 480 s, at most 2.6
# (docs/results.md).  Off below U_OFF.
U_ON = 4.0
U_SIGMAS = 4.0
U_VAR = 3.9
U_OFF = 1.5
# a row this far (chi-square(1), 4.9 sigma of the scaled variance) out of the blocks
ROW_GATE = 24.0
# a single yaw correction this large (rad) restarts the chain: not a small-error update
MAX_STEP = math.radians(5.0)

# scalar slots: the chain's open-loop offset O (rad), yaw at the epoch's start (rad),
# block sums (d, r, rows), block start and last row time (s), blocks in the chain (0-3),
# tests in the ring, next ring slot, the scale and whether it is on, last mean u, tests
# counted since the start, the last row's d and r, the block's sums of the row-to-row
# test (w, pairs), the scale before the last test
(_O, _Y0, _SD, _SR, _SN, _T0, _TL, _NB, _NU, _IU, _SCALE, _ON, _UBAR, _TESTS, _DL, _RL,
 _SW, _NW, _PREV) = range(19)


class CourseNoise:
    """Scale of the course rows' white variance from the open-loop course difference (see
    the module doc)."""

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled
        self._v = np.zeros(19)
        self._m = np.zeros(3)  # the chain's last three block means, rad
        self._r = np.zeros(3)  # their white variances, rad^2
        self._u = np.zeros(N_TESTS)  # the last tests' u, a ring
        self._w = np.zeros(N_TESTS)  # ... and their blocks' row-to-row w
        self.reset()

    def reset(self) -> None:
        """Forget everything (navigation restarts): the scale back to 1."""
        v = self._v
        v[:] = 0.0
        v[_SCALE] = 1.0
        v[_PREV] = 1.0
        v[_UBAR] = math.nan
        self._u[:] = 0.0
        self._w[:] = 0.0

    def restart_chain(self) -> None:
        """The yaw was set or widened: the open-loop difference starts over (the tests'
        ring, and with it the scale, is kept: the ground has not changed)."""
        v = self._v
        v[_O] = v[_SD] = v[_SR] = v[_SN] = v[_NB] = v[_SW] = v[_NW] = 0.0
        v[_RL] = 0.0  # no previous row

    @property
    def scale(self) -> float:
        """Factor on the course rows' white variance (1: as modelled)."""
        return float(self._v[_SCALE])

    @property
    def mean_u(self) -> float:
        """The last mean of u over the ring (NaN before MIN_TESTS tests)."""
        return float(self._v[_UBAR])

    @property
    def rise(self) -> float:
        """The factor by which the last test changed the scale (new / old)."""
        return float(self._v[_SCALE]) / float(self._v[_PREV])

    @property
    def switched(self) -> int:
        """+1 when the last test switched the scale on, -1 off, 0 neither."""
        was, now = float(self._v[_PREV]) > 1.0, float(self._v[_SCALE]) > 1.0
        return int(now) - int(was)

    @property
    def tests(self) -> int:
        """Second differences tested since the start."""
        return int(self._v[_TESTS])

    def begin_epoch(self, yaw: float) -> None:
        """The main filter's yaw (rad) before the epoch's updates."""
        self._v[_Y0] = yaw

    def end_epoch(self, d_yaw: float) -> None:
        """The epoch's updates turned the yaw by ``d_yaw`` rad."""
        if abs(d_yaw) > MAX_STEP:
            self.restart_chain()
            return
        self._v[_O] += d_yaw

    def row(self, t_s: float, zc: float, r_white: float, s_row: float, yaw: float,
            q_yaw: float) -> bool:
        """One course row (before the epoch's course update), whether a test ended.

        ``zc``: innovation psi_hat - chi' (rad); ``r_white``: the row's modelled white
        variance (rad^2); ``s_row``: its whole innovation variance with this scale applied
        (rad^2, for the row gate); ``yaw``: the main filter's yaw now (rad: the epoch's
        updates before this row moved it from ``begin_epoch``'s); ``q_yaw``: the
        propagation's yaw white-noise density, rad^2/s.
        """
        if not self.enabled or not (math.isfinite(zc) and r_white > 0.0 and s_row > 0.0):
            return False
        if zc * zc > ROW_GATE * s_row:
            return False
        v = self._v
        moved = (yaw - float(v[_Y0]) + math.pi) % (2.0 * math.pi) - math.pi
        d = zc - (float(v[_O]) + moved)
        if v[_SN] > 0.0 and t_s - float(v[_TL]) > MAX_GAP_S:
            self.restart_chain()
        if v[_SN] == 0.0:
            v[_T0] = t_s
        if v[_RL] > 0.0:
            # one row to the next: the slip hardly moves in a fix interval, so this sees the
            # white part alone (a receiver understating its noise), q dt the gyro's share
            dd1 = d - float(v[_DL])
            v[_SW] += dd1 * dd1 / (r_white + float(v[_RL])
                                   + max(q_yaw, 0.0) * (t_s - float(v[_TL])))
            v[_NW] += 1.0
        v[_DL] = d
        v[_RL] = r_white
        v[_SD] += d
        v[_SR] += r_white
        v[_SN] += 1.0
        v[_TL] = t_s
        if t_s - float(v[_T0]) < T_BLOCK - 1e-3 or v[_SN] < 2.0:
            return False
        # the block is complete: its mean and the white variance of that mean
        n = float(v[_SN])
        mean, var = float(v[_SD]) / n, float(v[_SR]) / (n * n)
        span = t_s - float(v[_T0]) + (t_s - float(v[_T0])) / (n - 1.0)
        w = float(v[_SW]) / float(v[_NW]) if v[_NW] > 0.0 else 1.0
        v[_SD] = v[_SR] = v[_SN] = v[_SW] = v[_NW] = 0.0
        m, r = self._m, self._r
        nb = int(v[_NB])
        if nb < 3:
            m[nb] = mean
            r[nb] = var
            v[_NB] = nb + 1
            if nb < 2:
                return False
        else:
            m[0], m[1], m[2] = m[1], m[2], mean
            r[0], r[1], r[2] = r[1], r[2], var
        dd = float(m[2]) - 2.0 * float(m[1]) + float(m[0])
        e = float(r[2]) + 4.0 * float(r[1]) + float(r[0]) + max(q_yaw, 0.0) * span
        self._test(dd * dd / e, w)
        return True

    def _test(self, u: float, w: float) -> None:
        v = self._v
        self._u[int(v[_IU])] = u
        self._w[int(v[_IU])] = w
        v[_IU] = (int(v[_IU]) + 1) % N_TESTS
        v[_NU] = min(float(v[_NU]) + 1.0, float(N_TESTS))
        v[_TESTS] += 1.0
        v[_PREV] = v[_SCALE]
        n = int(v[_NU])
        if n < MIN_TESTS:
            return
        s = sw = 0.0
        for i in range(n):
            s += float(self._u[i])
            sw += float(self._w[i])
        ubar = s / n
        v[_UBAR] = ubar
        # white noise understated by w raises u by as much (the GNSS velocity's own scale
        # takes that up, adaptive_noise.py): only u's excess over w is the slip's
        c = 1.0 + max(ubar - sw / n, 0.0)
        if c > max(U_ON, 1.0 + U_SIGMAS * math.sqrt(U_VAR / n)):
            v[_ON] = 1.0
        elif c < U_OFF:
            v[_ON] = 0.0
        v[_SCALE] = c if v[_ON] else 1.0
