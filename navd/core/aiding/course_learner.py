"""What makes the GNSS course differ from the heading, learnt beside the main filter.

A small Kalman filter beside the main one (as the rotor-drag coefficient is), fed once per
GNSS epoch whose course is used (:class:`navd.core.aiding.gnss_heading.CourseHeading`).
Estimates (``x``; k, s and c are corrections, their errors taken out after every step):

====  =====================================================================================
k     sideslip per lateral acceleration, rad per m/s^2 (course = heading + k a_lat: a car
      whose tyres slip in turns)
s     the z gyro's scale error (dimensionless; taken out of every z increment by
      ``kalman.imu_step``, ``sf[SF_SCALE_Z]``)
c_N   water current, NED m/s (``boat`` profile): the hull moves along its heading through
c_E   the water, so heading = course of (v_gnss - c)
e     the main filter's heading error psi_hat - psi, rad (``boat``)
d     its rate, rad/s: the main filter's gyro-bias error about down (``boat``)
====  =====================================================================================

Cars (every profile but ``boat``) learn k and s from the course innovation
zc = wrap(psi_hat - chi') (chi' the slip-corrected course), zc = -a_lat dk + A ds + rest,
A the yaw the z gyro turned lately (the allowance's forgetting sum, ``sf[SF_YAW_Z]``), the
rest (heading error, noise) taken as white: it does not persist against k and s, which
change sign with the turn (:meth:`CourseLearner.step`).

A current does persist: on a straight leg the current across the track and the heading
error are one unknown (a 0.6 m/s current across a boat at 2.5 m/s is a 14 deg crab), so a
learner that took e for white noise would learn a current no data hold, and the main
filter, told the course is good, would claim the crab as heading.  So the boat's learner
carries e and d as states and measures the water velocity across its own heading,
yaw - e_hat, which the main filter's corrections do not move
(:meth:`CourseLearner.step_lateral`); a boat also learns its antenna's lever arm there.
e moves with every correction the main filter makes (a known shift), drifts at d, and grows
with the scale error times the yaw turned; the current separates from it only as the
heading changes (a turn shows the crab changing).
P_ee is then what course and gyro together say about the heading, and the main filter's yaw
variance is never left below it (:meth:`CourseLearner.end_epoch`): the main filter takes the
rest of the crab's uncertainty as white noise and would average it away on a straight leg.
docs/design.md §4 ("A boat's water current") derives the row and says what each guard is
for.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from navd.config import EstimatorConfig
from navd.core._jit import jit

Arr = npt.NDArray[np.float64]

K, S, CN, CE, E, D, LX, LY, LZ = range(9)
_N = 9  # the boat's states; a watch keeps the first _NC, a car the first two
_NC = 6

# sideslip gain: prior sigma (rad per m/s^2; cars slip up to a few deg per m/s^2), the
# smallest lateral acceleration that teaches it, and a random walk per update so that a
# changed load or tyre is followed
SLIP_SD0 = math.radians(3.0)
SLIP_MIN_ALAT = 0.5
SLIP_Q = math.radians(0.001) ** 2
# the z gyro's scale error: the least net yaw turned (rad, the allowance's forgetting sum)
# that teaches it (cars), and a random walk per update (the sensitivity drifts with
# temperature).  Its prior is [imu] gyro_scale_sd_pct.  car480 with scale errors drawn at
# 3 % per axis, seeds 1-5, heading beyond 3 sigma / RMS: not learnt 12.8 % / 0.370 deg;
# learnt, walk 1e-4 / 3e-5 / 1e-5 per update: 1.0 % / 0.118, 0.118, 0.118 deg; the other
# car cases within 0.01 deg (docs/results.md)
SF_MIN_TURN = 0.1
SF_Q = 1e-4 ** 2
# ... and never beyond this many prior sigmas (consumer: 5 %, the datasheets' +-3 % at 25 C
# and their temperature drift): a course that is not the heading (a plane run as a ground
# vehicle: the X8 folder learnt -5.6 % with a sigma of 0.4 %) must not turn it into a gyro
SF_MAX_SD = 5.0
# the current's random walk, m^2/s^3: a tide turns over hours, ~0.1 m/s in 10 minutes
_CURRENT_Q = 0.1 * 0.1 / 600.0
# scalar slots of ``_v``: the epoch's lateral acceleration (m/s^2), the main filter's yaw
# after the last epoch (rad), the time of the last epoch (s), whether e is defined (the yaw
# has been set), whether it was set during this epoch and the yaw it was set to (rad); the
# row's low-passed speed (m/s) and its time (s), the row-noise scale, the row's last NIS,
# the watch's count and flag of epochs with a current, e_hat where the row's frame was
# anchored (rad)
(_ALAT, _YAW_END, _T, _E_SET, _SET_NOW, _YAW_SET, _VLP, _T_LP, _RQ, _NIS, _SUSP_N,
 _SUSPECT, _EREF) = range(13)
# the speed in the boat's row is low-passed (s): its noise (the INS's, 10 % in the first
# seconds, correlated over seconds) reads as speed changes, which separate the crab's
# current from the heading: at 3 s a straight leg with 0.1 m/s of INS speed error (5-s
# correlation) took the learnt heading's sigma from 18 to 4-6 deg with its error beyond
# 3 sigma in 16 % of the epochs (tests/test_boat.py); the low-pass's lag in a real speed change is
# in the row's noise (step_lateral).  3-1000 s tried, docs/results.md
_V_TAU = 20.0
# the row's heading frame stays where it was anchored until e_hat has moved this far from
# it (rad): a frame that followed e_hat at every update let each epoch's speed noise
# re-linearise the row (errors in the variables), and on a straight leg with a receiver's
# velocity noise 3x its report the learner's own heading wandered 35-39 deg at sigma 9-11 deg
# (boat_gnss_vel_x3 seed 4).  0 / 0.03 / 0.1 rad, 12 seeds: boat_gnss_vel_x3 beyond 3 sigma
# 6.8 / 1.1 / 1.0 %, boat_gyro_3 10.2 / 11.5 / 22.6 %, the boat 0.1 / 0.2 / 2.1 %
_EREF_MAX = 0.03
# the boat's row noise is scaled by the row's own normalised innovations (their mean square
# should be 1), at this gain per epoch: a receiver that understates its velocity noise 3x
# made the current look known from the first turn and left it wrong (beyond 3 sigma in
# 17-45 % of instants), since the current, unlike the main filter's states, hardly walks
_RQ_GAIN = 0.05
# a watch calls the course "not the heading" once its current is beyond this Mahalanobis
# distance from zero (chi-square, 2 dof, p = 1e-4) and would turn the course by more than
# this (rad, at the speed through the water) and at least this fast, for this many epochs
# in a row (a boat: crab; a plane run as a ground vehicle: wind)
_SUSPECT_M2 = 18.42
_SUSPECT_CRAB = 0.05
_SUSPECT_MPS = 0.25
_SUSPECT_N = 50


class CourseLearner:
    """Sideslip gain and z gyro scale (every ground-like profile), water current and the
    heading error it hides (``boat``); see the module doc.  Arrays only: the epoch loop
    rebinds no Python objects (the allocation test counts them)."""

    def __init__(self, cfg: EstimatorConfig, watch: bool = False) -> None:
        self._sf_sd0 = cfg.imu.gyro_scale_sd
        self._sf_var0 = self._sf_sd0 * self._sf_sd0
        # watch: the boat's learner run beside a ground vehicle's course update, applied to
        # nothing, to tell a course that is not the heading (:meth:`current_suspect`)
        self.watch = watch
        sd_c = (cfg.heading.current_sd if cfg.filter.profile == "boat" or watch else 0.0)
        self._c_var0 = sd_c * sd_c
        # e's white noise (the gyro's) and d's walk (the gyro bias's), per second
        self._q_e = cfg.imu.gyro_arw * cfg.imu.gyro_arw
        self._q_d = cfg.imu.gyro_bias_rw * cfg.imu.gyro_bias_rw
        # the boat learns k, s, c and e; other profiles k and s
        self.n = (_NC if watch else _N) if self._c_var0 > 0.0 else 2
        # the boat's antenna lever-arm correction (body FRD, m) is learnt from the lateral
        # velocity the hull's roll and yaw swing it through; its prior is the configured
        # lever arm's uncertainty
        self._l_var0 = cfg.gnss.lever_arm_sd * cfg.gnss.lever_arm_sd
        self._hl = np.zeros(3)  # the epoch's lever-arm row (lever_row)
        self.x = np.zeros(_N)
        self.P = np.zeros((_N, _N))
        self._h = np.zeros(_N)
        self._ph = np.zeros(_N)
        self._v = np.zeros(13)
        self.reset()

    def reset(self) -> None:
        self.x[:] = 0.0
        self.P[:, :] = 0.0
        self.P[K, K] = SLIP_SD0 * SLIP_SD0
        self.P[S, S] = self._sf_var0
        if self.n >= _NC and not self.watch:
            # a hull does not slip as a tyre does, and in a turn the slip and the current
            # explain the same lateral velocity: the boat learns no slip gain (its leeway
            # is in [heading] sideslip_sd_deg).  A watch on a car keeps it: a car's slip
            # read as a current would be a false alarm
            self.P[K, K] = 0.0
            self.P[CN, CN] = self._c_var0
            self.P[CE, CE] = self._c_var0
        if self.n == _N:
            for i in (LX, LY, LZ):
                self.P[i, i] = self._l_var0
        self._v[:] = 0.0
        self._v[_RQ] = 1.0

    @property
    def current(self) -> bool:
        """Whether the water current (and the heading error) are learnt."""
        return self.n >= _NC

    @property
    def a_lat(self) -> float:
        return float(self._v[_ALAT])

    def set_a_lat(self, a_lat: float) -> None:
        self._v[_ALAT] = a_lat

    def ground(self, wn: float, we: float) -> tuple[float, float]:
        """Velocity through the water plus the learnt current: over the ground, NED m/s."""
        return wn + float(self.x[CN]), we + float(self.x[CE])

    def water(self, vn: float, ve: float) -> tuple[float, float]:
        """GNSS (ground) velocity minus the learnt current, NED m/s."""
        return vn - float(self.x[CN]), ve - float(self.x[CE])

    def _boat_regressors(self, a_lat: float, psi_l: float) -> float:
        """The lateral-velocity row (boat) in the heading frame ``psi_l`` = yaw - e_ref (rad),
        see :meth:`step_lateral`; returns the row's speed through the water, m/s."""
        h = self._h
        speed = max(float(self._v[_VLP]), 0.1)
        cs = speed * math.cos(float(self.x[K]) * a_lat + self._e_off())
        h[K] = cs * a_lat
        h[S] = 0.0  # the scale error enters through e (begin_epoch)
        h[CN] = -math.sin(psi_l)
        h[CE] = math.cos(psi_l)
        h[E] = -cs
        h[D] = 0.0
        if self.n == _N:
            h[LX] = self._hl[0]
            h[LY] = self._hl[1]
            h[LZ] = self._hl[2]
        return speed

    def _e_off(self) -> float:
        """e_ref - e_hat, rad: the learnt heading error's move since the row's frame was
        anchored (:meth:`step_lateral`)."""
        return float(self._v[_EREF]) - float(self.x[E])

    def lever_row(self, mat_nb: Arr, rate_b: Arr, yaw: float) -> None:
        """The lever-arm part of this epoch's boat row: the lateral velocity n_hat . C (w x dl)
        = dl . (a x w), a = C^T n_hat the lateral direction in body axes; ``rate_b`` the
        body rate (rad/s), ``yaw`` the main filter's heading (rad; the row's is yaw - e_ref).
        Kept until the next call: a yaw set between epochs uses the last one."""
        psi_l = yaw - float(self._v[_EREF])
        nn, ne = -math.sin(psi_l), math.cos(psi_l)
        a0 = mat_nb[0, 0] * nn + mat_nb[1, 0] * ne
        a1 = mat_nb[0, 1] * nn + mat_nb[1, 1] * ne
        a2 = mat_nb[0, 2] * nn + mat_nb[1, 2] * ne
        w0, w1, w2 = rate_b[0], rate_b[1], rate_b[2]
        hl = self._hl
        hl[0] = a1 * w2 - a2 * w1
        hl[1] = a2 * w0 - a0 * w2
        hl[2] = a0 * w1 - a1 * w0

    @property
    def lever(self) -> Arr:
        """The learnt lever-arm correction, body FRD (3,) m (boat; zeros otherwise)."""
        return self.x[LX:LZ + 1]

    def course_var(self, a_lat: float, yaw: float, wn: float, we: float) -> float:
        """Variance the learnt sideslip (and current) leave in the course, rad^2, at the
        estimated heading ``yaw`` (rad) and water velocity ``wn, we`` (m/s)."""
        if self.n < _NC:
            return a_lat * a_lat * float(self.P[K, K])
        v = self._boat_regressors(a_lat, yaw - float(self._v[_EREF]))
        return self._quad(self._h, (K, CN, CE)) / (v * v)

    def _quad(self, h: Arr, idx: tuple[int, ...]) -> float:
        P = self.P
        q = 0.0
        for i in idx:
            for j in idx:
                q += h[i] * float(P[i, j]) * h[j]
        return q

    def step(self, zc: float, sc: float, gate: float, a_lat: float,
             yaw_turned: float) -> bool:
        """One Kalman step for k and s from the course innovation ``zc`` (rad; profiles
        other than ``boat``); whether it updated.

        ``sc``: the main filter's variance of zc (rad^2), ``gate``: chi-square(1) bound,
        ``a_lat``: lateral acceleration (m/s^2), ``yaw_turned``: A (rad).  An epoch with less
        than 0.5 m/s^2 of lateral acceleration and 0.1 rad of recent turn teaches nothing and
        is skipped; the rest of the innovation variance (sc less the learners' part) is the
        noise: zc = -a_lat dk + A ds + (heading error, tilt, course noise).
        """
        turned = yaw_turned if self._sf_var0 > 0.0 else 0.0
        if (abs(a_lat) < SLIP_MIN_ALAT and abs(turned) < SF_MIN_TURN) or not math.isfinite(zc):
            return False
        h = self._h
        h[K] = -a_lat
        h[S] = turned
        return self._update(zc, sc, gate, True)

    def step_lateral(self, wn: float, we: float, r: float, gate: float, a_lat: float,
                     yaw: float, ins_n: float, ins_e: float, t_s: float) -> bool:
        """One Kalman step for k, s, the current, e, d and the lever arm (boat); whether it
        updated.

        ``wn, we``: the fix's lever-arm-free velocity less the learnt current, m/s;
        ``yaw``: the main filter's heading, rad; ``ins_n, ins_e``: the INS velocity, m/s.
        The row is taken in the learner's own heading frame psi_l = yaw - e_ref, which the
        main filter's corrections do not move (they move yaw, e_hat and e_ref alike), and
        which the learner's own updates move only once e_hat is ``_EREF_MAX`` from e_ref:
        the water velocity across it, y = n(psi_l) . w.  With the true water velocity
        V u(psi + k a_lat) (u the unit vector of an angle, V the speed through the water),
        exactly::

            y = V sin(k a_lat + e_off - de) + n(psi_l) . dc + v,   v ~ N(0, r)

        with de = e - e_hat, e_off = e_ref - e_hat, dc = c - c_hat (the scale error's
        heading error is in e, :meth:`begin_epoch`; the lever arm's lateral velocity,
        :meth:`lever_row`, adds h_l . dl). Linear in the current, unlike the course angle (a
        1 m/s current at 3 m/s turns the course by 20 deg), and its row comes from the
        estimated heading and the INS velocity, not from the fix: a row that turned with the
        fix's noise made the current look observable on a straight leg, where only the crab
        (the current across the heading, with the heading error) is; a row in the main
        filter's frame, or one taken at e_hat in it, read the main filter's corrections as
        turns.  ``r``: m^2/s^2; ``gate``: chi-square(1) bound.
        """
        v = self._v
        if abs(self._e_off()) > _EREF_MAX:
            v[_EREF] = self.x[E]
        psi_l = yaw - float(v[_EREF])
        un, ue = math.cos(psi_l), math.sin(psi_l)
        y = -ue * wn + un * we
        if not math.isfinite(y):
            return False
        # the speed through the water along the heading, taking out of the INS velocity
        # only as much of the learnt current along it as is known: a straight leg leaves
        # that part at its prior, and a speed read from a wandering estimate of it (1 m/s
        # off on seed 1 of a mast in waves) turned the first turn into a 30-90 deg
        # disagreement
        P = self.P
        var_along = (un * un * float(P[CN, CN]) + 2.0 * un * ue * float(P[CN, CE])
                     + ue * ue * float(P[CE, CE]))
        known = max(0.0, 1.0 - var_along / self._c_var0)
        along = (un * (ins_n + (1.0 - known) * float(self.x[CN]))
                 + ue * (ins_e + (1.0 - known) * float(self.x[CE])))
        if math.isfinite(along):
            v[_VLP] += (along - float(v[_VLP])) * min(
                max(t_s - float(v[_T_LP]), 0.0) / _V_TAU, 1.0)
            v[_T_LP] = t_s
        speed = self._boat_regressors(a_lat, psi_l)
        # the row is linear in the current and in e, but their product is in the model
        # too: V sin de with V = u . (v - c) carries (u . dc) de, whose variance (current
        # along the heading times heading error) is the row's error while both are wide;
        # so does the low-pass's lag behind a real speed change, dV (e_off - de): without
        # it, boat_gnss_vel_x3 was beyond 3 sigma in 6.1 % of the instants (12 seeds)
        lag = along - float(v[_VLP]) if math.isfinite(along) else 0.0
        e_off = self._e_off()
        so = math.sin(e_off)
        r += (var_along + lag * lag) * (float(P[E, E]) + so * so)
        v[_NIS] = -1.0
        ok = self._update(y - speed * math.sin(float(self.x[K]) * a_lat + e_off),
                          r * float(v[_RQ]), gate, False)
        if v[_NIS] >= 0.0:
            # NIS of this row (gated ones excluded): its mean is 1 when r is right
            v[_RQ] = max(1.0, float(v[_RQ]) * (1.0 + _RQ_GAIN * (float(v[_NIS]) - 1.0)))
        if self.watch:
            self._watch_current()
        return ok

    def _watch_current(self) -> None:
        v = self._v
        x, P = self.x, self.P
        cn, ce = float(x[CN]), float(x[CE])
        a, b, d = float(P[CN, CN]), float(P[CN, CE]), float(P[CE, CE])
        det = a * d - b * b
        m2 = (d * cn * cn - 2.0 * b * cn * ce + a * ce * ce) / det if det > 0.0 else 0.0
        lim = max(_SUSPECT_MPS, _SUSPECT_CRAB * float(v[_VLP]))
        if m2 > _SUSPECT_M2 and cn * cn + ce * ce > lim * lim:
            v[_SUSP_N] += 1.0
            if v[_SUSP_N] >= _SUSPECT_N:
                v[_SUSPECT] = 1.0
        else:
            v[_SUSP_N] = 0.0

    @property
    def current_suspect(self) -> bool:
        """(watch) Whether the course has been seen to carry a current (not the heading)."""
        return bool(self._v[_SUSPECT])

    def _update(self, y: float, r: float, gate: float, rest_of_sc: bool) -> bool:
        """The Kalman step with the row in ``_h``; ``rest_of_sc``: ``r`` is the whole
        innovation variance, of which the learners' part is not noise (cars)."""
        nis = _row_update(self.P, self.x, self._h, self._ph, self.n, y, r, gate, rest_of_sc)
        if nis < 0.0:
            return False  # an outlier teaches nothing
        self._v[_NIS] = nis
        x, P = self.x, self.P
        lim = SF_MAX_SD * self._sf_sd0
        x[S] = min(max(float(x[S]), -lim), lim)
        if self.n < _NC or self.watch:
            P[K, K] += SLIP_Q
        if self._sf_var0 > 0.0:
            P[S, S] += SF_Q
        return True

    def begin_epoch(self, t_s: float, yaw: float, q_yaw: float = 0.0,
                    q_rate: float = 0.0) -> None:
        """Before the epoch's updates (boat), the main filter's yaw ``yaw`` rad: e drifts at
        the rate d since the last epoch, plus the gyro's white noise, plus the scale error
        times the yaw turned; d and the current by their walks.  ``q_yaw``, ``q_rate``: the
        main filter's noise densities of its yaw (rad^2/s) and of its gyro bias about down
        (rad^2/s^3) as it propagates them now; the configured ones are the floor."""
        v = self._v
        n = self.n
        if n < _NC or not v[_E_SET]:
            return
        dt = min(max(t_s - float(v[_T]), 0.0), 10.0)
        turned = (yaw - float(v[_YAW_END]) + math.pi) % (2.0 * math.pi) - math.pi
        v[_T] = t_s
        x, P = self.x, self.P
        x[E] += x[D] * dt
        _drift_e(P, n, dt, turned)
        # e and d are the main filter's errors, so they drift as its yaw and bias do: with
        # its noise as adapted online (core/aiding/adaptive_noise.py), not the config's;
        # on the config's, an IMU whose offsets were 6x the prior left d beyond 3 sigma
        # (7-24 sigma) after the turns and the boat's heading beyond 3 sigma in 11.5 % of
        # the instants (boat_gyro_3, 12 seeds; 0.1 % on the main filter's)
        P[E, E] += max(self._q_e, q_yaw) * dt
        P[D, D] += max(self._q_d, q_rate) * dt
        P[CN, CN] += _CURRENT_Q * dt
        P[CE, CE] += _CURRENT_Q * dt

    def end_epoch(self, P_main: Arr, d_yaw: float, yaw: float, d_rate: float) -> None:
        """After the epoch's updates (boat): the main filter turned its yaw by ``d_yaw`` rad
        to ``yaw`` rad (e moves with it, a known shift; from where it was set when that
        happened this epoch) and its gyro bias about down by ``d_rate`` rad/s (d moves the
        other way); its yaw variance is not left below P_ee."""
        v = self._v
        if self.n < _NC or not v[_E_SET]:
            return
        if v[_SET_NOW]:
            v[_SET_NOW] = 0.0
            d_yaw = (yaw - float(v[_YAW_SET]) + math.pi) % (2.0 * math.pi) - math.pi
        self.x[E] += d_yaw
        v[_EREF] += d_yaw
        self.x[D] -= d_rate
        v[_YAW_END] = yaw
        pee = float(self.P[E, E])
        if P_main[2, 2] < pee and not self.watch:
            P_main[2, 2] = pee

    def _first_rate(self, rate_var: float) -> None:
        if not self._v[_E_SET]:
            x, P = self.x, self.P
            x[D] = 0.0
            P[D, :] = 0.0
            P[:, D] = 0.0
            P[D, D] = rate_var

    def yaw_known(self, p22: float, yaw: float, t_s: float, rate_var: float) -> None:
        """The main filter's yaw was set or widened by something other than the course
        (config, its own observability, a recovery): e starts from its variance ``p22``
        (rad^2), unrelated to the learnt terms; ``rate_var`` as in :meth:`yaw_set`."""
        if self.n < _NC:
            return
        self._first_rate(rate_var)
        x, P = self.x, self.P
        x[E] = 0.0
        P[E, :] = 0.0
        P[:, E] = 0.0
        P[E, E] = p22
        v = self._v
        v[_EREF] = 0.0
        v[_E_SET] = 1.0
        v[_SET_NOW] = 1.0
        v[_YAW_SET] = yaw
        v[_YAW_END] = yaw
        v[_T] = t_s

    def widen(self, var: float) -> None:
        """The main filter added ``var`` rad^2 to its yaw variance (a divergence reset): so
        does e."""
        if self.n >= _NC and self._v[_E_SET]:
            self.P[E, E] += var

    def yaw_set(self, p22: float, a_lat: float, yaw: float, wn: float, we: float,
                t_s: float, rate_var: float) -> float:
        """The main filter's yaw was just set to a course, ``yaw`` rad (variance ``p22``
        rad^2 from the course's own noise; ``wn, we``: the velocity through the water by this
        learner's current, m/s): the lateral velocity y0 = n(yaw) . w (0 when the yaw is the
        course through the water; a watch's current differs) is then y0 = h.dx - V e + v,
        so e = (h.dx + v - y0) / V.
        ``rate_var``: the main filter's variance of its gyro bias about down, (rad/s)^2,
        d's prior the first time.  Returns the yaw variance to give the main filter (rad^2;
        ``p22`` unless the current is learnt)."""
        n = self.n
        if n < _NC:
            return p22
        v = self._v
        P = self.P
        self._first_rate(rate_var)
        self.x[E] = 0.0
        v[_EREF] = 0.0
        v[_VLP] = math.cos(yaw) * wn + math.sin(yaw) * we
        v[_T_LP] = t_s
        v_ = self._boat_regressors(a_lat, yaw)
        self.x[E] = (math.sin(yaw) * wn - math.cos(yaw) * we) / v_
        v[_EREF] = self.x[E]
        h = self._h
        for i in range(n):
            if i == E:
                continue
            a = 0.0
            for j in range(n):
                if j != E:
                    a += float(P[i, j]) * h[j]
            P[i, E] = a / v_
            P[E, i] = a / v_
        pee = p22 + self._quad(h, (K, S, CN, CE, LX, LY, LZ)) / (v_ * v_)
        P[E, E] = pee
        v[_E_SET] = 1.0
        v[_SET_NOW] = 1.0
        v[_YAW_SET] = yaw
        v[_YAW_END] = yaw
        v[_T] = t_s
        return pee


@jit
def _row_update(P: Arr, x: Arr, h: Arr, ph: Arr, n: int, y: float, r: float, gate: float,
                rest_of_sc: bool) -> float:
    """The scalar Kalman update of the first ``n`` states (``x`` (N,), ``P`` (N, N), the row
    ``h`` (N,), ``ph`` (N,) scratch for P h) in place; returns the NIS, or -1 when gated
    (nothing changed).  ``rest_of_sc``: ``r`` is the whole innovation variance."""
    for i in range(n):
        a = 0.0
        for j in range(n):
            a += P[i, j] * h[j]
        ph[i] = a
    hph = 0.0
    for i in range(n):
        hph += h[i] * ph[i]
    if rest_of_sc:
        r = max(r - hph, 1e-12)
    s = hph + r
    if y * y > gate * s:
        return -1.0
    for i in range(n):
        g = ph[i] / s
        x[i] += g * y
        for j in range(i, n):
            P[i, j] = P[i, j] - g * ph[j]
            P[j, i] = P[i, j]
    return y * y / s


@jit
def _drift_e(P: Arr, n: int, dt: float, turned: float) -> None:
    """P <- F P F^T with F = I + dt (row e, column d) + turned (row e, column s), in place
    on the first ``n`` states."""
    for j in range(n):
        P[E, j] += dt * P[D, j] + turned * P[S, j]
    for i in range(n):
        P[i, E] += dt * P[i, D] + turned * P[i, S]
