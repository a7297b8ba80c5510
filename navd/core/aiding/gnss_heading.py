"""Completed heading update: heading from GNSS course (seed 001), docs/design.md §4.

With chi = atan2(vE, vN) the course of the lever-arm-corrected GNSS velocity, and psi_hat
the INS yaw, the innovation and its linear model are::

    z = wrap(psi_hat - chi)
    z = -tan(theta) (cos(psi) phiN + sin(psi) phiE) - phiD + J ([(C u) x] phi - C [l x] dbg)
        + v_chi

(from C_hat = Exp(-phi) C; the seed's eq. 21 coefficient mapped to NED and to our error
sign; the J terms come from removing the lever-arm velocity C_hat (w_hat x l), u = w x l,
from the GNSS velocity before taking its course).
chi shares its noise with the velocity measurement: with ``J = [-vE, vN, 0]/|v_h|^2``
the joint covariance of (velocity, course) innovations is ``[[R_v, R_v J^T], [J R_v,
J R_v J^T + s_beta^2]]``, where s_beta models sideslip/crab.  The block is appended to the
velocity block (row 3) and whitened jointly in :func:`navd.core.kalman.gated_update`.

:class:`CourseHeading` decides when heading ~ course (docs/design.md §4), fuses the course
with the GNSS velocity, aligns or resets the yaw to the course, and reports its status.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from navd.config import EstimatorConfig
from navd.core import state as st
from navd.core._jit import jit
from navd.core.aiding.base import (
    ACCEPTED,
    INNOV_COURSE,
    INNOV_FLAG,
    INNOV_NIS,
    INNOV_VEL,
    REJECTED,
    SINGULAR,
)
from navd.core.aiding.course_learner import CourseLearner, K, S
from navd.core.aiding.course_noise import CourseNoise
from navd.core.aiding.heading_alignment import FLIPPED_RECENT_S, HeadingAlignment
from navd.core.aiding.mount_yaw import MountYaw, installation_moment
from navd.core.aiding.travel_direction import TravelDirection
from navd.core.chi2 import chi2_quantile
from navd.core.errors import I_BA
from navd.core.kalman import SF_SCALE_Z, SF_YAW_Z
from navd.core.rotation import exp_into, mat_to_euler, mul3_into
from navd.types import GnssSample

if TYPE_CHECKING:
    from navd.core.estimator import Estimator

Arr = npt.NDArray[np.float64]

# a yaw set from the course takes the course + 180 deg when the IMU said this lately that
# the vehicle moves backwards (travel_direction.py), s
_DIRECTION_RECENT_S = 10.0
# the sigma of the IMU's yaw on the vehicle when its verdict turned the yaw, rad: a verdict
# made while the course bent tilt and bias was 4-25 deg off the mount (a 45 deg mount read
# 64-77 deg)
_IMU_TURN_SD = 20.0 * math.pi / 180.0
# ... and the course rows wait for it to be learnt to this sigma, rad (mount_yaw.py)
_MOUNT_ROWS_SD = 5.0 * math.pi / 180.0
# the mount watch's mu is short of the mount by about this share of it (its rows bend it
# toward 0; car480, seeds 1-3: 10 deg mounts read 6-9.4 deg when told; mount_yaw.py) ...
_WATCH_BENT = 0.3
# ... and up to this mu the learner starts from it, the course rows going on at once (20 deg
# mounts, read 11.6-13 deg when told, learnt by the rows 13.7 deg, 2.8 sigma off: beyond, as
# a verdict of the travel-direction monitor), rad
_WATCH_SMALL = 10.0 * math.pi / 180.0
# a learnt yaw on the vehicle within this many of its sigmas of 0, once below
# _MOUNT_ROWS_SD, says the turn was told wrongly: the IMU is straight after all
_STRAIGHT_K = 2.0


@jit
def course_row(H: Arr, z: Arr, R: Arr, row: int, mat_nb: Arr, rate_b: Arr, lever_b: Arr,
               vn: float, ve: float, sd_h: float, sd_beta: float) -> None:
    """Write the course row at ``row`` of H/z and its (co)variances into R.

    R[0:row, 0:row] must already hold the velocity covariance R_v when row == 3 (joint);
    with row == 0 only the course variance ``sd_h^2/|v_h|^2 + sd_beta^2`` is written
    (course-only update; sd_h is the per-axis horizontal speed sigma, m/s).
    """
    yaw = math.atan2(mat_nb[1, 0], mat_nb[0, 0])
    sp = -mat_nb[2, 0]
    cp = math.sqrt(max(0.0, 1.0 - sp * sp))
    tp = sp / max(cp, 1e-9)
    chi = math.atan2(ve, vn)
    d = yaw - chi
    z[row] = (d + math.pi) % (2.0 * math.pi) - math.pi
    for k in range(H.shape[1]):
        H[row, k] = 0.0
    vh2 = vn * vn + ve * ve
    jn = -ve / vh2
    je = vn / vh2
    # (vn, ve) had C_hat (w_hat x l) removed, which depends on phi and dbg:
    # d(course) = J d(v_c),  d(v_c) = -[(C u) x] phi + C [l x] dbg,  u = w x l
    ux = rate_b[1] * lever_b[2] - rate_b[2] * lever_b[1]
    uy = rate_b[2] * lever_b[0] - rate_b[0] * lever_b[2]
    uz = rate_b[0] * lever_b[1] - rate_b[1] * lever_b[0]
    cu0 = mat_nb[0, 0] * ux + mat_nb[0, 1] * uy + mat_nb[0, 2] * uz
    cu1 = mat_nb[1, 0] * ux + mat_nb[1, 1] * uy + mat_nb[1, 2] * uz
    cu2 = mat_nb[2, 0] * ux + mat_nb[2, 1] * uy + mat_nb[2, 2] * uz
    # J [(Cu) x] = [jn, je, 0] [[0, -cu2, cu1], [cu2, 0, -cu0], [-cu1, cu0, 0]]
    H[row, 0] = -tp * math.cos(yaw) + je * cu2
    H[row, 1] = -tp * math.sin(yaw) - jn * cu2
    H[row, 2] = -1.0 + jn * cu1 - je * cu0
    lx, ly, lz = lever_b[0], lever_b[1], lever_b[2]
    for i in range(2):
        ji = jn if i == 0 else je
        c0, c1, c2 = mat_nb[i, 0], mat_nb[i, 1], mat_nb[i, 2]
        # - J C [l x]: row i of C [l x] is (c1 lz - c2 ly, c2 lx - c0 lz, c0 ly - c1 lx)
        H[row, 9] -= ji * (c1 * lz - c2 * ly)
        H[row, 10] -= ji * (c2 * lx - c0 * lz)
        H[row, 11] -= ji * (c0 * ly - c1 * lx)
    if row == 3:
        c0 = jn * R[0, 0] + je * R[1, 0]
        c1 = jn * R[0, 1] + je * R[1, 1]
        c2 = jn * R[0, 2] + je * R[1, 2]
        R[3, 0] = c0
        R[3, 1] = c1
        R[3, 2] = c2
        R[0, 3] = c0
        R[1, 3] = c1
        R[2, 3] = c2
        R[3, 3] = jn * c0 + je * c1 + sd_beta * sd_beta
    else:
        R[row, row] = sd_h * sd_h / vh2 + sd_beta * sd_beta


def bias_down(est: Estimator) -> float:
    """The main filter's gyro bias about down (c b, c the third row of C_b^n), rad/s."""
    m, b = est.mat_nb, est.bias_g
    return float(m[2, 0] * b[0] + m[2, 1] * b[1] + m[2, 2] * b[2])


def rate_var_down(est: Estimator) -> float:
    """The main filter's variance of its gyro bias about down (c P_bb c^T, c the third row
    of C_b^n), (rad/s)^2."""
    m, P = est.mat_nb, est.P
    v = 0.0
    for i in range(3):
        for j in range(3):
            v += m[2, i] * float(P[9 + i, 9 + j]) * m[2, j]
    return v


def course_may_align(cfg: EstimatorConfig, bank: bool) -> bool:
    """Whether a GNSS course may set an unknown heading: ground vehicles and boats (the
    course through the water, its uncertainty widened by the current's), and fixed-wing with
    a crab allowance (``[heading] crab_sd_deg`` > 0) or without a yaw bank (``bank``); a
    multirotor's course is never its heading and a fixed-wing's differs by the crab angle (up
    to +-30 deg in wind), which the yaw bank resolves from turns instead
    (:mod:`navd.core.aiding.yaw_bank`)."""
    p = cfg.filter.profile
    return p in ("ground", "boat") or (
        p == "fixed_wing" and (cfg.heading.crab_sd > 0.0 or not bank))


def course_sd(speed_sd_mps: float, speed_h_mps: float) -> float:
    """1-sigma of the course from a per-axis speed accuracy, rad (sigma_v / |v_h|)."""
    return speed_sd_mps / speed_h_mps


def _shift_yaw(est: Estimator, d: float) -> None:
    """Turn the attitude about down by ``d`` rad (yaw + d) and the tilt error with it
    (navd.core.state.turn_tilt_cov); the yaw's covariance is kept."""
    e = est.work[4]
    t = est.work[5]
    exp_into(e, 0.0, 0.0, d)
    mul3_into(t, e, est.mat_nb)
    est.mat_nb[:, :] = t
    st.turn_tilt_cov(est.buf, d)


def _turn_yaw(est: Estimator, d: float) -> None:
    """:func:`_shift_yaw`, and forget the yaw's covariance (row and column 2 of P, its
    variance left 0 for the caller to set)."""
    _shift_yaw(est, d)
    P = est.P
    P[2, :] = 0.0
    P[:, 2] = 0.0


class CourseHeading:
    """GNSS course as heading, joined to the GNSS velocity update (part of the GNSS aid).

    Attributes:
        status: why the course is or is not used now (the status record's
            ``course_update``).
    """

    def __init__(self, cfg: EstimatorConfig) -> None:
        c = cfg
        self.cfg = cfg
        p = c.filter.gate_prob
        self._gate1 = chi2_quantile(p, 1)
        self._gate3 = chi2_quantile(p, 3)
        self._gate4 = chi2_quantile(p, 4)
        self._gating = c.filter.robust != "none"
        self.enabled = c.filter.mode == "completed" and (
            c.filter.profile in ("ground", "boat")
            or (c.filter.profile == "fixed_wing" and c.heading.crab_sd > 0.0))
        self.sd_beta = (c.heading.sideslip_sd if c.filter.profile in ("ground", "boat")
                        else c.heading.crab_sd)
        self._lever_var = c.gnss.lever_arm_sd * c.gnss.lever_arm_sd
        self._delay_var = c.gnss.delay_sd * c.gnss.delay_sd
        self._install_var = c.imu.mount_yaw_sd * c.imu.mount_yaw_sd
        self.status = "off"
        self.rejects = 0
        # this epoch's course row is the reversed course (a reversing the IMU confirmed)
        self.backward = False
        # the IMU's yaw on the vehicle once its accelerations showed it turned (mount_yaw.py)
        self.mount = MountYaw()
        # ... and the same beside rows that take it to be 0, to tell a smaller turn (ground)
        self.mount_watch = (MountYaw() if self.enabled and c.filter.profile == "ground"
                            else None)
        # the sideslip per lateral acceleration (course = heading + gain * a_lat for a car
        # whose tyres slip in turns), the z gyro's scale error and a boat's water current,
        # learnt from the course innovations
        self.learn = CourseLearner(cfg)
        # a ground vehicle's course watched for a current it does not model (a boat run as
        # a car, a plane's wind): the boat's learner, applied to nothing
        self.watch = (CourseLearner(cfg, watch=True)
                      if self.enabled and c.filter.profile == "ground"
                      and c.heading.current_sd > 0.0 else None)
        # a slip of the course's own, correlated over seconds: the rows' variance scaled by
        # what the course against the gyro alone says (course_noise.py); cars only (a boat's
        # learner carries its heading error, a plane's crab is the yaw bank's)
        self.noise = CourseNoise(self.enabled and c.filter.profile == "ground"
                                 and c.heading.adapt_course_noise)
        # when the heading may be flagged aligned (not on one sample)
        self.align = HeadingAlignment(cfg)
        # which way the yaw points by the IMU's accelerations: reversing or 180 deg wrong
        # (travel_direction.py); where the course checks run
        self.direction = TravelDirection()
        self._told = [False]  # course_not_heading counted (once per run)
        # the mount watch is off for the run: a turn it told was dropped (_imu_straight)
        self._watch_off = [False]
        self._wv = np.zeros(2)  # the epoch's velocity through the water, m/s (_learn_epoch)

    @property
    def imu_yaw_on_vehicle(self) -> float:
        """The IMU's x axis from the course, rad (right +), learnt once the IMU showed it
        turned on the vehicle; NaN until then."""
        return self.mount.mu if self.mount.active else math.nan

    @property
    def installation_var(self) -> float:
        """What the IMU's yaw on the vehicle as installed (``[imu] mount_yaw_sd_deg``) adds
        to the reported yaw variance, rad^2: where the course is the heading the filter's
        yaw is the vehicle's, and the IMU's axes are off it by the installation's error,
        which no course row reduces.  0 where the course is not used (the yaw bank's and the
        travel-direction monitor's yaw come from the IMU's own accelerations) and once the
        IMU's yaw on the vehicle is learnt (its variance floors the yaw's instead).  While
        the mount watch runs (ground), the installation's prior is a mixture with a wide
        tail, weighed by what the watch has measured (:func:`installation_moment`): a few
        degrees that it sees but does not yet tell widen the sigma."""
        if not self.enabled or self.mount.active:
            return 0.0
        w = self.mount_watch
        if w is None or not w.active or self._watch_off[0]:
            return self._install_var
        # the watch's mu reads about (1 - _WATCH_BENT) of the mount: scaled back
        g = 1.0 / (1.0 - _WATCH_BENT)
        return installation_moment(self._install_var, g * w.mu, g * g * w.var,
                                   g * g * _IMU_TURN_SD * _IMU_TURN_SD)

    def _to_imu(self, vn: float, ve: float) -> tuple[float, float]:
        """A horizontal velocity (m/s, north, east) turned by the IMU's learnt yaw on the
        vehicle: its course is then the course of the body x axis (unturned until the IMU
        showed it turned).  Every velocity the course logic uses is turned, the INS's too,
        before the learnt current is taken out: a boat's current is then learnt in the
        turned frame, where the IMU is the hull."""
        mt = self.mount
        if not mt.active:
            return vn, ve
        c, s = math.cos(mt.mu), math.sin(mt.mu)
        return c * vn - s * ve, s * vn + c * ve

    @property
    def slip_gain(self) -> float:
        """Learned sideslip per lateral acceleration, rad per m/s^2."""
        return float(self.learn.x[K])

    @property
    def slip_sd(self) -> float:
        """Its 1-sigma, rad per m/s^2."""
        return math.sqrt(float(self.learn.P[K, K]))

    @property
    def gyro_z_scale(self) -> tuple[float, float]:
        """The z gyro's learnt scale error and its 1-sigma (dimensionless)."""
        return float(self.learn.x[S]), math.sqrt(float(self.learn.P[S, S]))

    def reset(self) -> None:
        self.rejects = 0
        self.align.reset()
        self.direction.reset()
        self.learn.reset()
        self.noise.reset()
        self.mount.reset()
        self._watch_off[0] = False
        if self.mount_watch is not None:
            self.mount_watch.reset()
        if self.watch is not None:
            self.watch.reset()

    # the yaw's life cycle, told to the learner (and the watch): course_learner.py
    def yaw_known(self, p22: float, yaw: float, t_s: float, rate_var: float) -> None:
        self.noise.restart_chain()
        self.learn.yaw_known(p22, yaw, t_s, rate_var)
        if self.watch is not None:
            self.watch.yaw_known(p22, yaw, t_s, rate_var)

    def yaw_set(self, p22: float, a_lat: float, yaw: float, wn: float, we: float,
                t_s: float, rate_var: float) -> float:
        """The yaw was set to the course of (wn, we) (through the water by the learnt
        current); returns the yaw variance for the main filter."""
        self.noise.restart_chain()
        if self.watch is not None:
            w = self.watch
            w_n, w_e = w.water(*self.learn.ground(wn, we))
            w.yaw_set(p22, a_lat, yaw, w_n, w_e, t_s, rate_var)
        return self.learn.yaw_set(p22, a_lat, yaw, wn, we, t_s, rate_var)

    def widen(self, var: float) -> None:
        self.noise.restart_chain()
        self.learn.widen(var)
        if self.watch is not None:
            self.watch.widen(var)

    def begin_epoch(self, t_s: float, yaw: float, q_yaw: float, q_rate: float) -> None:
        self.noise.begin_epoch(yaw)
        self.learn.begin_epoch(t_s, yaw, q_yaw, q_rate)
        if self.watch is not None:
            self.watch.begin_epoch(t_s, yaw, q_yaw, q_rate)

    def end_epoch(self, est: Estimator, P: Arr, d_yaw: float, yaw: float,
                  d_rate: float) -> None:
        self.noise.end_epoch(d_yaw)
        self.learn.end_epoch(P, d_yaw, yaw, d_rate)
        mt = self.mount
        if mt.active:
            # every course row shares one mount error: the yaw sigma never claims less
            if P[2, 2] < mt.var:
                P[2, 2] = mt.var
            return
        w = self.watch
        if w is not None:
            w.end_epoch(P, d_yaw, yaw, d_rate)
            if w.current_suspect and not self._told[0]:
                self._told[0] = True
                est.counters["course_not_heading"] += 1

    def usable(self, est: Estimator, g: GnssSample) -> bool:
        """Whether heading ~ course now (docs/design.md §4); sets :attr:`status`."""
        c = self.cfg
        if not self.enabled:
            self.status = ("disabled: multirotor profile (course is not heading)"
                           if c.filter.profile == "multirotor" else
                           "disabled: traditional mode" if c.filter.mode == "traditional"
                           else "disabled: fixed_wing without crab allowance")
            return False
        if self.mount.active and self.mount.var > _MOUNT_ROWS_SD * _MOUNT_ROWS_SD:
            # rows at a mount this uncertain made the fixes bend tilt and accelerometer bias
            # to fit it, which bent the verdicts that teach it toward it (mount_yaw.py)
            self.status = "waiting: learning the IMU's yaw on the vehicle"
            return False
        # through the water (boat), over the ground (others: the current is 0); by the
        # IMU's axes when it is turned on the vehicle
        wn, we = self.learn.water(*self._to_imu(g.vel_n, g.vel_e))
        speed = math.hypot(wn, we)
        if speed < c.heading.min_speed:
            self.status = "waiting: speed below threshold"
            return False
        r = est.rate_b
        m = est.mat_nb
        yaw_rate = m[2, 0] * r[0] + m[2, 1] * r[1] + m[2, 2] * r[2]
        if abs(yaw_rate) > c.heading.max_yaw_rate:
            self.status = "waiting: yaw rate too high"
            return False
        if abs(yaw_rate) * speed > c.heading.max_lat_accel:
            self.status = "waiting: lateral acceleration too high"
            return False
        self.learn.set_a_lat(yaw_rate * speed)  # centripetal, positive to the right
        # Backwards motion in body x is reversing when the IMU's accelerations confirmed
        # the yaw (travel_direction.py), or, without that, at reversing speeds and
        # with an aligned (confirmed) heading; else our yaw is off by more than 90 degrees,
        # which the course must correct (an unconfirmed yaw that points backwards is more
        # likely wrong: heading_alignment.py).
        vx = m[0, 0] * wn + m[1, 0] * we + m[2, 0] * g.vel_d
        self.backward = False
        if vx < 0.0 and self.direction.yaw_right(float(est.P[2, 2])):
            # the IMU says the body x axis points the other way: its heading is the course
            # + 180 deg, a row as good as a forward one (and the only heading an IMU
            # mounted backwards, unstated, ever gets)
            self.backward = True
            self.status = "active: reversing"
            return True
        if vx < 0.0 and speed < c.heading.max_reverse_speed and est.heading_aligned:
            self.status = "waiting: reversing"
            return False
        self.status = "active: the IMU turned on the vehicle" if self.mount.active else "active"
        return True

    def _fill_velocity(self, est: Estimator, g: GnssSample, s_sd: float) -> tuple[int, bool]:
        """Velocity rows 0..2 linearised at the fix's time; (m, swapped: restore after)."""
        # no vertical velocity reported: use our own with a variance that ignores it
        vd, sd_v = (g.vel_d, s_sd) if math.isfinite(g.vel_d) else (float(est.vel_n[2]), 1e3)
        swapped = est.state_at(g.t_us) is True
        m = st.fill_velocity(est.buf, g.vel_n, g.vel_e, vd, s_sd, sd_v, self._lever_var,
                             self._delay_var)
        return m, swapped

    def _velocity_alone(self, est: Estimator, g: GnssSample, s_sd: float, hold: int,
                        hold_mask: int = 0) -> None:
        m, swapped = self._fill_velocity(est, g, s_sd)
        if swapped:
            est.state_restore()
        est.record_innovation(INNOV_VEL, 0, 3,
                              est.fuse_block(m, self._gate3, "vel", hold, hold_mask))

    def _water_checks(self, est: Estimator, g: GnssSample, s_sd: float) -> bool:
        """The epoch's course check, realignment and first-course alignment (by the velocity
        through the water: over the ground but on a boat); whether the course is used."""
        cfg = self.cfg
        al = self.align
        wn, we = self.learn.water(*self._to_imu(g.vel_n, g.vel_e))
        if (al.course_checks and al.yaw_set
                and self.direction.yaw_between_since(g.t_us * 1e-6 - FLIPPED_RECENT_S)):
            self._turn_to_imu(est, self.direction.yaw_error)
            wn, we = self.learn.water(*self._to_imu(g.vel_n, g.vel_e))
        al.check_course(est, g.t_us, wn, we, s_sd, self.learn, self.sd_beta, self.direction)
        if al.realign_requested:
            # backwards for longer than reversing explains: the yaw is wrong by > 90 deg
            self.align_yaw(est, wn, we, s_sd, extra_sd=cfg.init.heading_sd)
        use_course = self.usable(est, g)
        if (not use_course and not al.yaw_set
                and cfg.init.heading_source == "gnss_course"
                and course_may_align(cfg, est.yaw_bank is not None)
                and math.hypot(wn, we) >= cfg.heading.align_speed):
            # Without course updates the first fast course still beats a yaw of zero as a
            # starting point (crab makes it coarse: keep the yaw variance wide).
            self.align_yaw(est, wn, we, s_sd, extra_sd=cfg.init.heading_sd)
        return use_course

    def _course_var(self, est: Estimator, a_lat: float) -> float:
        """What the learnt sideslip (and current) leave in the course, rad^2: the row's
        heading and the INS velocity through the water (smooth, unlike the fix's)."""
        lrn = self.learn
        if not lrn.current:
            return lrn.course_var(a_lat, 0.0, 0.0, 0.0)
        m = est.mat_nb
        ins_n, ins_e = lrn.water(*self._to_imu(float(est.vel_n[0]), float(est.vel_n[1])))
        return lrn.course_var(a_lat, math.atan2(m[1, 0], m[0, 0]), ins_n, ins_e)

    def _learn_epoch(self, est: Estimator, g: GnssSample, zc: float, sc: float,
                     a_lat: float, r_white: float) -> None:
        """The learner's step (and the watch's) from this epoch's course; ``r_white``: the
        course's own white noise, rad^2; the water velocity before the slip is in _wv."""
        lrn = self.learn
        wn, we = float(self._wv[0]), float(self._wv[1])
        m = est.mat_nb
        yaw = math.atan2(m[1, 0], m[0, 0])
        if lrn.current:
            # across the heading through the water, m/s (CourseLearner.step_lateral)
            ins_n, ins_e = lrn.water(*self._to_imu(float(est.vel_n[0]), float(est.vel_n[1])))
            lrn.lever_row(m, est.rate_b, yaw)
            learnt = lrn.step_lateral(wn, we, (wn * wn + we * we) * r_white, self._gate1,
                                      a_lat, yaw, ins_n, ins_e, g.t_us * 1e-6)
            # the antenna's learnt position goes into every GNSS row from the next epoch
            lb, l0, dl = est.lever_b, self.cfg.gnss.lever_arm, lrn.lever
            for i in range(3):
                lb[i] = l0[i] + dl[i]
        else:
            learnt = lrn.step(zc, sc, self._gate1, a_lat, float(est.gyro_sf[SF_YAW_Z]))
        if learnt:
            est.gyro_sf[SF_SCALE_Z] = lrn.x[S]
        w = self.watch
        if w is not None and not self.mount.active:
            # (a turned IMU's course is turned by its mount, the INS velocity is not)
            # the same row by the watch's current (step_lateral)
            gn, ge = lrn.ground(wn, we)
            w_n, w_e = w.water(gn, ge)
            i_n, i_e = w.water(float(est.vel_n[0]), float(est.vel_n[1]))
            w.step_lateral(w_n, w_e, (w_n * w_n + w_e * w_e) * r_white, self._gate1, a_lat,
                           yaw, i_n, i_e, g.t_us * 1e-6)

    def fuse_with_velocity(self, est: Estimator, g: GnssSample, s_sd: float,
                           hold: int, hold_mask: int = 0) -> None:
        """The GNSS velocity update, with the course row joined when :meth:`usable`.

        ``s_sd``: per-axis horizontal velocity sigma, m/s; ``hold``: consider-state index
        for the velocity-alone update (-1: none); ``hold_mask``: further consider states
        (bit i: state i).
        """
        z = est.meas_z
        al = self.align
        lrn = self.learn
        if self.mount.active:
            self._learn_mount(est, g, self.mount)
        elif self.mount_watch is not None and al.yaw_set and not self._watch_off[0]:
            if not self.mount_watch.active:
                self.mount_watch.start(0.0, _IMU_TURN_SD * _IMU_TURN_SD)
            self._learn_mount(est, g, self.mount_watch)
            if self.mount_watch.turned:
                self._watch_told(est)
        use_course = self._water_checks(est, g, s_sd)
        m, swapped = self._fill_velocity(est, g, s_sd)
        if not use_course:
            if swapped:
                est.state_restore()
            est.record_innovation(INNOV_VEL, 0, 3,
                                  est.fuse_block(m, self._gate3, "vel", hold, hold_mask))
            self.check_observed(est)
            al.check_observed(est, g.t_us)
            return
        # lever-arm-free GNSS velocity for the course, v_gnss - C (w x l); the velocity
        # innovation just computed is v_hat + C (w x l) - v_gnss; less the learnt current
        vn_c, ve_c = lrn.water(*self._to_imu(g.vel_n - (z[0] - (est.vel_n[0] - g.vel_n)),
                                             g.vel_e - (z[1] - (est.vel_n[1] - g.vel_e))))
        if not al.yaw_set:
            if swapped:
                est.state_restore()
            self.align_yaw(est, vn_c, ve_c, s_sd)
            return
        if self.backward:
            self._backward_row(est, g, vn_c, ve_c, s_sd, swapped, hold, hold_mask)
            return
        self._wv[0] = vn_c
        self._wv[1] = ve_c
        # the course of the body x axis: the GNSS course minus the learned sideslip
        a_lat = lrn.a_lat
        d = float(lrn.x[K]) * a_lat
        cd, sd_ = math.cos(d), math.sin(d)
        vn_c, ve_c = cd * vn_c + sd_ * ve_c, -sd_ * vn_c + cd * ve_c
        sd_b2 = self.sd_beta * self.sd_beta + self._course_var(est, a_lat) + self._mount_var()
        # the row's white variance as modelled, and what the course's own correlated slip
        # adds beyond it (course_noise.py; the speed part is the GNSS velocity's, shared
        # with rows 0-2, so the extra goes into the sideslip term)
        r_white = s_sd * s_sd / max(vn_c * vn_c + ve_c * ve_c, 1e-6) + sd_b2
        extra = (self.noise.scale - 1.0) * r_white
        sd_beta = math.sqrt(sd_b2 + extra)
        # course alone first: its own gate decides whether it joins the velocity update
        zc, sc = self._row(est, vn_c, ve_c, s_sd, sd_beta, swapped)
        m_nb = est.mat_nb
        if self.noise.row(g.t_us * 1e-6, zc, r_white, sc, math.atan2(m_nb[1, 0], m_nb[0, 0]),
                          float(est.buf[st.Q + 2]), a_lat, lrn.P, bias_down(est),
                          float(est.gyro_sf[SF_SCALE_Z])):
            self._noise_changed(est)
        self._learn_epoch(est, g, zc, sc, a_lat, float(est.meas_R[3, 3])
                          - (sd_beta * sd_beta - self.sd_beta * self.sd_beta))
        self._fuse_row(est, g, zc, sc, s_sd, hold, hold_mask, vn_c, ve_c, "course_accepted",
                       "course_rejected")

    def _row(self, est: Estimator, vn_c: float, ve_c: float, s_sd: float, sd_beta: float,
             swapped: bool) -> tuple[float, float]:
        """Write the course row of (vn_c, ve_c) m/s (row 3, beside the velocity's) and
        return its innovation (rad) and variance (rad^2, from the attitude block of P and
        the row's own noise: speed, sideslip, lever arm)."""
        H, z, P = est.meas_H, est.meas_z, est.P
        st.course_row(est.buf, 3, vn_c, ve_c, s_sd, sd_beta)
        if swapped:
            est.state_restore()
        sc = H[3, 0] * H[3, 0] * P[0, 0] + H[3, 1] * H[3, 1] * P[1, 1]
        sc += 2.0 * H[3, 0] * H[3, 1] * P[0, 1] + P[2, 2]
        sc -= 2.0 * (H[3, 0] * P[0, 2] + H[3, 1] * P[1, 2])
        return float(z[3]), sc + float(est.meas_R[3, 3])

    def _fuse_row(self, est: Estimator, g: GnssSample, zc: float, sc: float, s_sd: float,
                  hold: int, hold_mask: int, vn_c: float, ve_c: float, accepted: str,
                  rejected: str) -> None:
        """Velocity and course row together when the row (innovation ``zc`` rad, variance
        ``sc`` rad^2) passes its own chi-square(1) gate, else the velocity alone; counted
        ``accepted`` / ``rejected`` (names, not composed: no string is made per epoch), and a
        run of ``[heading] reset_after`` refusals sets the yaw to the course again."""
        cnt = est.counters
        rec = est.innov[INNOV_COURSE]
        rec[0] = zc
        rec[INNOV_NIS] = zc * zc / sc
        if (not self._gating) or zc * zc / sc <= self._gate1:
            nis = est.fuse_block(4, self._gate4, "vel_course")
            est.record_innovation(INNOV_VEL, 0, 3, nis)
            if nis >= 0.0:
                rec[INNOV_FLAG] = ACCEPTED
                cnt[accepted] += 1
                self.rejects = 0
                return
            # the joint block failed: fall back to velocity alone
            rec[INNOV_FLAG] = REJECTED if nis != -math.inf else SINGULAR
            self._velocity_alone(est, g, s_sd, hold, hold_mask)
            return
        rec[INNOV_FLAG] = REJECTED
        cnt[rejected] += 1
        self.rejects += 1
        self._velocity_alone(est, g, s_sd, hold, hold_mask)
        if self.rejects >= self.cfg.heading.reset_after:
            # persistently inconsistent: the yaw is wrong beyond the linear model; reset it
            # (align_yaw takes the side the IMU implies)
            self.align_yaw(est, vn_c, ve_c, s_sd)
            cnt["heading_reset"] += 1

    def _backward_row(self, est: Estimator, g: GnssSample, vn_c: float, ve_c: float,
                      s_sd: float, swapped: bool, hold: int, hold_mask: int) -> None:
        """The velocity update with the reversed course's row: body x against the motion.

        Nothing is learnt from it (the sideslip and the course-noise tests model forward
        driving; a reversing car steers from its other end): the learnt slip enters only
        as variance, with the course-noise scale as it stands."""
        a_lat = self.learn.a_lat
        slip = float(self.learn.x[K]) * a_lat
        sd_b2 = (self.sd_beta * self.sd_beta + self._course_var(est, a_lat) + slip * slip
                 + self._mount_var())
        r_white = s_sd * s_sd / max(vn_c * vn_c + ve_c * ve_c, 1e-6) + sd_b2
        sd_beta = math.sqrt(sd_b2 + (self.noise.scale - 1.0) * r_white)
        zc, sc = self._row(est, -vn_c, -ve_c, s_sd, sd_beta, swapped)
        self._fuse_row(est, g, zc, sc, s_sd, hold, hold_mask, vn_c, ve_c,
                       "course_reversed_accepted", "course_reversed_rejected")

    def _noise_changed(self, est: Estimator) -> None:
        """A course-noise test ended (course_noise.py): count the scale switching on or off;
        when it rose, the yaw's variance rises with it.  The rows before had given the yaw
        the information of a course that many times less noisy, which the yaw sigma still
        claims (a slip found 45 s in left the yaw 1-2 deg off at sigma 0.15 deg); row and
        column 2 of P are scaled by sqrt(f) each (P stays positive definite, the correlations
        are kept), the variance never beyond the heading prior's."""
        sw = self.noise.switched
        if sw:
            est.counters["course_noise_up" if sw > 0 else "course_noise_down"] += 1
        f = self.noise.rise
        P = est.P
        cap = self.cfg.init.heading_sd * self.cfg.init.heading_sd
        if f > 1.0 and P[2, 2] > 0.0:
            f = min(f, max(cap / float(P[2, 2]), 1.0))
            r = math.sqrt(f)
            for j in range(15):
                P[2, j] *= r
                P[j, 2] *= r

    def note_not_tried(self, est: Estimator, g: GnssSample) -> None:
        """Course record before the epoch's updates (``Estimator.push`` has marked it not
        tried): wrap(psi_hat - chi) of the raw GNSS velocity for monitoring (overwritten when
        the course is tried)."""
        rec = est.innov[INNOV_COURSE]
        if math.hypot(g.vel_n, g.vel_e) >= 1.0:
            m = est.mat_nb
            yaw = math.atan2(m[1, 0], m[0, 0])
            rec[0] = (yaw - math.atan2(g.vel_e, g.vel_n) + math.pi) % (2.0 * math.pi) - math.pi

    def check_observed(self, est: Estimator) -> None:
        """Flag heading aligned once manoeuvres made the yaw observable (sigma small); with a
        yaw bank, the bank alone decides (a linearised yaw sigma can shrink on a wrong yaw)."""
        if (est.yaw_bank is None and not self.align.yaw_set
                and est.P[2, 2] < self.cfg.init.aligned_sd**2):
            # the flag waits for consistency over time (heading_alignment.py)
            self.align.yaw_given(est, from_course=False)
            m = est.mat_nb
            self.yaw_known(float(est.P[2, 2]), math.atan2(m[1, 0], m[0, 0]),
                           est.t_us * 1e-6, rate_var_down(est))

    def _turn_to_imu(self, est: Estimator, err: float) -> None:
        """The IMU's accelerations put the yaw ``err`` rad off the course it follows (a
        verdict 60-120 deg off, or the mount watch's): the course is not this IMU's heading
        (it is mounted turned on the vehicle, unstated; before, a 90 deg mount was flagged
        aligned 90 deg off with sigma 0.1 deg, its roll and pitch 4-8 deg RMS, 28-66 % of
        the instants beyond 3 sigma).  The yaw is turned by ``err``, and the course is the
        heading of the IMU's axes from then on by the IMU's yaw on the vehicle, learnt from
        there with a sigma of ``_IMU_TURN_SD`` (mount_yaw.py; counted
        ``course_not_heading_imu``; status ``imu_yaw_on_vehicle_deg``)."""
        mt = self.mount
        mt.start((mt.mu if mt.active else 0.0) + err, _IMU_TURN_SD * _IMU_TURN_SD,
                 est.t_us * 1e-6)
        _turn_yaw(est, err)
        P = est.P
        P[2, 2] = max(self.cfg.init.heading_sd, _IMU_TURN_SD) ** 2
        # the fixes bent tilt and accelerometer bias to make a turned IMU's accelerations
        # fit the course: their priors again (their sigma claimed what was not so), the
        # bias from its prior mean (a bent bias kept bending the verdicts that teach the
        # mount: a 45 deg mount learnt as 51 deg)
        tilt2 = self.cfg.init.tilt_sd ** 2
        ba2 = self.cfg.imu.accel_bias_sd ** 2
        for i in range(2):
            P[i, i] += tilt2
        est.bias_a[:] = self.cfg.imu.accel_bias
        for i in range(I_BA, I_BA + 3):
            P[i, :] = 0.0
            P[:, i] = 0.0
            P[i, i] = ba2
        self.rejects = 0
        # the slip and the z gyro's scale were learnt from a course that was not this yaw's
        self.learn.reset()
        est.gyro_sf[SF_SCALE_Z] = 0.0
        self.noise.restart_chain()
        self.align.imu_turned(est)
        est.counters["course_not_heading_imu"] += 1

    def _watch_told(self, est: Estimator) -> None:
        """The mount watch says the IMU is turned by its mu (beyond 3 sigma and 5 deg from
        0).  Where that mu is within ``_WATCH_SMALL`` and, widened for how far the watch's
        rows bend it toward 0 (``_WATCH_BENT``), its sigma within ``_MOUNT_ROWS_SD``, the
        learner starts there and the course rows go on at once at course + mu: the yaw
        turns by mu, its variance at least the start's, and the fixes' tilt and bias are
        kept (at 5-10 deg they were bent little; widening the yaw to ``_IMU_TURN_SD`` and
        dropping the rows until it was relearnt let the heading from accelerations alone
        wander 23-75 deg off at sigma 20 deg: car480, a -5 deg mount, seed 1, told at 377
        s).  Else as a verdict of the travel-direction monitor (:meth:`_turn_to_imu`)."""
        w = self.mount_watch
        assert w is not None
        mu = w.mu
        var = w.var + (_WATCH_BENT * mu) ** 2
        if abs(mu) > _WATCH_SMALL or var >= _MOUNT_ROWS_SD * _MOUNT_ROWS_SD:
            self._turn_to_imu(est, mu)
            return
        self.mount.start(mu, var, est.t_us * 1e-6)
        _shift_yaw(est, mu)
        P = est.P
        if P[2, 2] < var:
            P[2, 2] = var
        self.rejects = 0
        self.noise.restart_chain()
        self.align.imu_turned(est)
        est.counters["course_not_heading_imu"] += 1

    def _mount_var(self) -> float:
        """What the learnt IMU yaw on the vehicle leaves in a course row, rad^2 (0 with
        the IMU unturned)."""
        mt = self.mount
        return mt.var if mt.active else 0.0

    def _learn_mount(self, est: Estimator, g: GnssSample, mt: MountYaw) -> None:
        """A decisive epoch of the travel-direction monitor measures the IMU's yaw on the
        vehicle (mount_yaw.py) into ``mt``; the yaw moves with the learnt one (it follows
        course + mount), not with the watch's."""
        dirn = self.direction
        t = g.t_us * 1e-6
        z = dirn.decisive_mount(t)
        if not math.isfinite(z) or math.hypot(g.vel_n, g.vel_e) < self.cfg.heading.min_speed:
            return
        # the course of the body x axis is the GNSS course less the learnt slip
        z += float(self.learn.x[K]) * self.learn.a_lat
        d = mt.measure(z, dirn.decisive_sd, t)
        if d != 0.0 and mt is self.mount:
            _shift_yaw(est, d)
            est.counters["imu_yaw_on_vehicle_learnt"] += 1
            sd = math.sqrt(mt.var)
            # (once it has learnt: a turn the watch told starts within _MOUNT_ROWS_SD)
            if (sd < _MOUNT_ROWS_SD and mt.var < 0.5 * mt.var_start
                    and abs(mt.mu) < _STRAIGHT_K * sd):
                self._imu_straight(est)

    def _imu_straight(self, est: Estimator) -> None:
        """The learnt yaw on the vehicle came back to within ``_STRAIGHT_K`` sigma of 0: the
        turn was told wrongly (a false alarm of the mount watch; none on the benchmark's
        cases), so the course is this IMU's heading again, as before it, and the watch stays
        off for the run (no turn told, dropped, told again).  Counted
        ``imu_yaw_on_vehicle_dropped``."""
        _shift_yaw(est, -self.mount.mu)
        self.mount.reset()
        self._watch_off[0] = True
        self.noise.restart_chain()
        self.align.imu_straight(est)
        est.counters["imu_yaw_on_vehicle_dropped"] += 1

    def align_yaw(self, est: Estimator, vn: float, ve: float, s_sd: float,
                  extra_sd: float = 0.0) -> None:
        """Rotate the attitude about down so yaw equals the course of (vn, ve) m/s (through
        the water on a boat), or the course + 180 deg where the IMU's accelerations of the
        last ``_DIRECTION_RECENT_S`` say the vehicle is reversing (travel_direction.py);
        reset the yaw covariance (row/column 2 of P) to the course's uncertainty (and the
        learnt current's)."""
        _, _, yaw = mat_to_euler(est.mat_nb)
        chi = math.atan2(ve, vn)
        dirn = self.direction
        # the heading the IMU implied lately, less the course
        off = (yaw + dirn.yaw_error - chi + math.pi) % (2.0 * math.pi) - math.pi
        if (dirn.yaw_error_t >= est.t_us * 1e-6 - _DIRECTION_RECENT_S
                and abs(off) > 0.5 * math.pi):
            # behind the course: the vehicle backs up
            chi = (chi + 2.0 * math.pi) % (2.0 * math.pi) - math.pi
            est.counters["heading_course_behind"] += 1
        _turn_yaw(est, -((yaw - chi + math.pi) % (2.0 * math.pi) - math.pi))
        P = est.P
        sd = s_sd / math.hypot(vn, ve)
        P[2, 2] = self.yaw_set(
            sd * sd + self.sd_beta**2 + (1.0 * math.pi / 180.0) ** 2 + extra_sd**2,
            self.learn.a_lat, chi, vn, ve, est.t_us * 1e-6, rate_var_down(est))
        self.rejects = 0
        # the flag waits for the course to agree over time (heading_alignment.py)
        self.align.yaw_given(est, from_course=True)
