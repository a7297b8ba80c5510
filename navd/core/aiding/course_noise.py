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
The first tests may switch it on alone when overwhelming (``U_FIRST``); once on it is an
upper bound of the mean, not the mean (``UPPER``).

Two things bend the gyro-integrated heading that are not slip, and the test takes them out:
the filter's gyro bias and z scale estimates change while the chain runs (fastest at the
start of a drive), so d is taken against the yaw integrated with the chain's first bias
and scale (the foreign car's first test: u 38 -> 2.1); and what the slip learner does not
yet know (sideslip gain k, z gyro scale s; zc = -a_lat dk + A ds + ...) adds
h^T P_ks h to E[D^2], h the second differences of the blocks' mean -a_lat and of the
yaw turned since the chain began.
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
# before MIN_TESTS tests the mean of n switches on above 1 + U_FIRST / n (the sum of n
# above ~30: chi-square's tail ~1e-7 for one to three tests); the wandering slip's first
# test is in the hundreds, and waiting for four left 15 s more of a yaw that followed it
U_FIRST = 29.0
# when on, the scale is 1 + the mean's excess, times UPPER = 1 + 2 sqrt(U_VAR / N_TESTS)
# (two standard deviations of a full ring's mean): the mean of 24 scatters by ~40 % of
# itself, and a scale drawn low left the yaw beyond 3 sigma for seconds (slip_wander_1 seed
# 3: 20-50 where seeds 1-2 give 100-250); a full ring's factor even when fewer tests are in
# it (sqrt(U_VAR / n) at n = 4 tripled a receiver's understated noise into the IMU scale)
UPPER = 1.0 + 2.0 * math.sqrt(U_VAR / N_TESTS)
# a row this far (chi-square(1), 4.9 sigma of the scaled variance) out of the blocks
ROW_GATE = 24.0
# a single yaw correction this large (rad) restarts the chain: not a small-error update
MAX_STEP = math.radians(5.0)

# scalar slots: the chain's open-loop offset O (rad), yaw at the epoch's start (rad),
# block sums (d, r, rows), block start and last row time (s), blocks in the chain (0-3),
# tests in the ring, next ring slot, the scale and whether it is on, last mean u, tests
# counted since the start, the last row's d and r, the block's sums of the row-to-row
# test (w, pairs), the scale and on flag before the last test, the yaw unwrapped since the
# chain began and at the last row (rad), the block's sums of gyro-integrated yaw (rad) and
# lateral acceleration (m/s^2), the chain's first bias about down (rad/s) and z scale, and
# the integral of their changes since (rad)
(_O, _Y0, _SD, _SR, _SN, _T0, _TL, _NB, _NU, _IU, _SCALE, _ON, _UBAR, _TESTS, _DL, _RL,
 _SW, _NW, _PREV, _PON, _YU, _YL, _SG, _SA, _B0, _S0, _IB) = range(27)


class CourseNoise:
    """Scale of the course rows' white variance from the open-loop course difference (see
    the module doc)."""

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled
        self._v = np.zeros(27)
        self._m = np.zeros(3)  # the chain's last three block means, rad
        self._r = np.zeros(3)  # their white variances, rad^2
        self._g = np.zeros(3)  # their mean gyro-integrated yaw since the chain began, rad
        self._a = np.zeros(3)  # ... and mean lateral acceleration, m/s^2
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
        v[_SG] = v[_SA] = v[_YU] = v[_IB] = 0.0
        v[_RL] = 0.0  # no previous row

    @property
    def scale(self) -> float:
        """Factor on the course rows' white variance (1: as modelled)."""
        return float(self._v[_SCALE])

    @property
    def mean_u(self) -> float:
        """The last mean of u over the ring (NaN before the first test)."""
        return float(self._v[_UBAR])

    @property
    def rise(self) -> float:
        """The factor by which the last test changed the scale (new / old)."""
        return float(self._v[_SCALE]) / float(self._v[_PREV])

    @property
    def switched(self) -> int:
        """+1 when the last test switched the scale on, -1 off, 0 neither."""
        return int(self._v[_ON]) - int(self._v[_PON])

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
            q_yaw: float, a_lat: float = 0.0, p_learn: Arr | None = None,
            b_down: float = 0.0, s_z: float = 0.0) -> bool:
        """One course row (before the epoch's course update), whether a test ended.

        ``zc``: innovation psi_hat - chi' (rad); ``r_white``: the row's modelled white
        variance (rad^2); ``s_row``: its whole innovation variance with this scale applied
        (rad^2, for the row gate); ``yaw``: the main filter's yaw now (rad: the epoch's
        updates before this row moved it from ``begin_epoch``'s); ``q_yaw``: the
        propagation's yaw white-noise density, rad^2/s; ``a_lat``: the lateral acceleration
        the slip learner's row takes (m/s^2); ``p_learn``: that learner's covariance (its
        [K, S] block: sideslip gain rad per m/s^2, z gyro scale), None if it learns nothing;
        ``b_down``: the main filter's gyro bias about down now, rad/s; ``s_z``: the z gyro
        scale it takes out now.
        """
        if not self.enabled or not (math.isfinite(zc) and r_white > 0.0 and s_row > 0.0):
            return False
        if zc * zc > ROW_GATE * s_row:
            return False
        v = self._v
        if v[_SN] > 0.0 and t_s - float(v[_TL]) > MAX_GAP_S:
            self.restart_chain()
        moved = (yaw - float(v[_Y0]) + math.pi) % (2.0 * math.pi) - math.pi
        if v[_RL] > 0.0:
            turned = (yaw - float(v[_YL]) + math.pi) % (2.0 * math.pi) - math.pi
            v[_YU] += turned
            # the yaw integrates the gyro less the bias and scale estimated at each instant:
            # their changes since the chain began (fast at the start of a drive, when the
            # bias is still being learnt) bend it; take the yaw integrated with the chain's
            # first bias and scale instead (a constant bias error only tilts d: D cancels it)
            v[_IB] += ((b_down - float(v[_B0])) * (t_s - float(v[_TL]))
                       + (s_z - float(v[_S0])) * turned)
        else:
            v[_B0] = b_down
            v[_S0] = s_z
        v[_YL] = yaw
        d = zc - (float(v[_O]) + moved) + float(v[_IB])
        if v[_SN] == 0.0:
            v[_T0] = t_s
        # the yaw the gyro alone turned since the chain began: what a scale error grows on
        v[_SG] += float(v[_YU]) - (float(v[_O]) + moved)
        v[_SA] += a_lat
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
        mg, ma = float(v[_SG]) / n, float(v[_SA]) / n
        v[_SD] = v[_SR] = v[_SN] = v[_SW] = v[_NW] = v[_SG] = v[_SA] = 0.0
        m, r, g, a = self._m, self._r, self._g, self._a
        nb = int(v[_NB])
        if nb < 3:
            m[nb] = mean
            r[nb] = var
            g[nb] = mg
            a[nb] = ma
            v[_NB] = nb + 1
            if nb < 2:
                return False
        else:
            m[0], m[1], m[2] = m[1], m[2], mean
            r[0], r[1], r[2] = r[1], r[2], var
            g[0], g[1], g[2] = g[1], g[2], mg
            a[0], a[1], a[2] = a[1], a[2], ma
        dd = float(m[2]) - 2.0 * float(m[1]) + float(m[0])
        e = float(r[2]) + 4.0 * float(r[1]) + float(r[0]) + max(q_yaw, 0.0) * span
        if p_learn is not None:
            # what the slip learner does not yet know moves the course against the gyro too:
            # zc = -a_lat dk + A ds + ..., so D carries -D_a dk + D_g ds
            hk = -(float(a[2]) - 2.0 * float(a[1]) + float(a[0]))
            hs = float(g[2]) - 2.0 * float(g[1]) + float(g[0])
            e += (hk * hk * float(p_learn[0, 0]) + 2.0 * hk * hs * float(p_learn[0, 1])
                  + hs * hs * float(p_learn[1, 1]))
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
        v[_PON] = v[_ON]
        n = int(v[_NU])
        s = sw = 0.0
        for i in range(n):
            s += float(self._u[i])
            sw += float(self._w[i])
        ubar = s / n
        v[_UBAR] = ubar
        # white noise understated by w raises u by as much (the GNSS velocity's own scale
        # takes that up, adaptive_noise.py): only u's excess over w is the slip's
        c = 1.0 + max(ubar - sw / n, 0.0)
        on = (max(U_ON, 1.0 + U_SIGMAS * math.sqrt(U_VAR / n)) if n >= MIN_TESTS
              else 1.0 + U_FIRST / n)
        if c > on:
            v[_ON] = 1.0
        elif c < U_OFF:
            v[_ON] = 0.0
        v[_SCALE] = c * UPPER if v[_ON] else 1.0
