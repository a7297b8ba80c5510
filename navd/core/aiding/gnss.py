"""The GNSS aid: one epoch's position, velocity and course updates (docs/design.md §3.5-§5).

Per epoch, after the estimator has accepted the fix as plausible, in order and not too old:
accuracies (receiver's or defaults, floored by config), refusal of absurd jumps (> 100 km,
even with gating off; a run of them restarts navigation), heading hold at rest (§3.7),
the MCTLS velocity weight (§5, ``robust = "mctls"``), the position rows
(:mod:`gnss_position`), then the velocity rows with the course joined when heading ~ course
(:class:`navd.core.aiding.gnss_heading.CourseHeading`), then the lock-out check
(:class:`navd.core.aiding.gnss_recovery.LockoutRecovery`).  Rows are linearised about the
state at the fix's time of validity (``Estimator.state_at``).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from navd.config import EstimatorConfig
from navd.core import state as st
from navd.core.aiding.adaptive_noise import AdaptiveNoise
from navd.core.aiding.base import INNOV_POS
from navd.core.aiding.course_learner import CE, CN
from navd.core.aiding.gnss_heading import CourseHeading
from navd.core.aiding.gnss_recovery import LockoutRecovery
from navd.core.aiding.mount_check import PitchMountCheck
from navd.core.aiding.travel_direction import specific_force_sd
from navd.core.chi2 import chi2_quantile
from navd.core.earth import OMEGA_IE, mat_ne_into
from navd.types import GnssSample

if TYPE_CHECKING:
    from navd.core.aiding.mctls import Mctls
    from navd.core.estimator import Estimator

_REINIT_AFTER_JUMPS = 20  # consecutive >100 km disagreements that restart navigation
_YAW = 2  # error-state index of phi_D
# roll/pitch tilt (0, 1), gyro bias (9-11), horizontal accelerometer bias (12, 13): what a
# velocity innovation made by a wrong heading during an acceleration would be taken for
_TILT_BIAS_MASK = (1 << 0) | (1 << 1) | (1 << 9) | (1 << 10) | (1 << 11) | (1 << 12) | (1 << 13)
_GYROCOMPASS_USELESS_RAD = 5.0 * math.pi / 180.0

# GNSS accuracies below these are treated as missing and replaced by config defaults
_DEFAULT_H_ACC = 5.0
_DEFAULT_V_ACC = 10.0
_DEFAULT_VEL_ACC = 0.5


def _rate_down(est: Estimator) -> float:
    """The body's rate about down (yaw rate), rad/s."""
    m = est.mat_nb
    r = est.rate_b
    return float(m[2, 0] * r[0] + m[2, 1] * r[1] + m[2, 2] * r[2])


class GnssAiding:
    """GNSS position + velocity (+ course as heading) aid; see the module doc."""

    name = "gnss"
    consumes = GnssSample

    def __init__(self, cfg: EstimatorConfig) -> None:
        c = cfg
        self.cfg = cfg
        self._gate3 = chi2_quantile(c.filter.gate_prob, 3)
        # the unknown part of the receiver's latency, as position noise v v^T delay_var
        self._delay_var = c.gnss.delay_sd * c.gnss.delay_sd
        self.course = CourseHeading(cfg)
        # the IMU's pitch on a ground vehicle, from the velocity in body axes (a check)
        self.mount_check = PitchMountCheck(cfg)
        self.recovery = LockoutRecovery(cfg)
        self.adaptive = AdaptiveNoise(cfg)
        self._mctls: Mctls | None = None
        if c.filter.robust == "mctls":
            from navd.core.aiding.mctls import Mctls as _Mctls

            self._mctls = _Mctls(window=c.mctls.window, order=c.mctls.order, mode="mctls")
        self._cne = np.zeros((3, 3))
        self._vel_ecef = np.zeros(3)
        # Gyrocompassing at rest gives heading to gyro_bias_sd / (OMEGA_IE cos lat) at best;
        # beyond ~5 deg (a gyro worse than ~1.3 deg/h) it is no heading source worth keeping.
        self.hold_enabled = (c.heading.hold_static
                              and c.imu.gyro_bias_sd > OMEGA_IE * _GYROCOMPASS_USELESS_RAD)
        self.hold = -1  # consider-state index of this epoch's updates, -1: none
        self.hold_mask = 0  # further consider states of this epoch's updates (bit i: state i)
        self._absurd_in_row = 0
        # horizontal speed of the last fix that had one, m/s (inf: none yet)
        self.last_speed_h = math.inf

    def reset(self) -> None:
        self.hold = -1
        self.hold_mask = 0
        self._absurd_in_row = 0
        self.last_speed_h = math.inf
        self.course.reset()
        self.mount_check.reset()
        self.recovery.reset()
        self.adaptive.reset()
        if self._mctls is not None:
            self._mctls.reset()

    def start(self, est: Estimator, fix: GnssSample) -> None:
        pass

    def _pitch_on_vehicle(self) -> list[float] | None:
        e = self.mount_check.estimate
        return None if e is None else [round(math.degrees(x), 3) for x in e]

    def _imu_yaw_error(self) -> list[float] | None:
        d = self.course.direction
        if not math.isfinite(d.yaw_error_t):
            return None
        return [round(math.degrees(d.yaw_error), 1), round(d.yaw_error_t, 1)]

    def _current(self) -> list[float] | None:
        lrn = self.course.learn
        if not lrn.current:
            return None
        x, P = lrn.x, lrn.P
        return [round(float(x[i]), 3) for i in (CN, CE)] + [
            round(math.sqrt(float(P[i, i])), 3) for i in (CN, CE)]

    def status(self, est: Estimator) -> dict[str, object]:
        return {
            "course_update": self.course.status,
            # learned sideslip per lateral acceleration and its 1-sigma (ground profile)
            "sideslip_deg_per_mps2": [round(math.degrees(self.course.slip_gain), 3),
                                      round(math.degrees(self.course.slip_sd), 3)],
            # ... and the z gyro's scale error learnt beside it (%, and its 1-sigma), taken
            # out of the z increments
            "gyro_z_scale_pct": [round(100.0 * x, 3) for x in self.course.gyro_z_scale],
            # a boat's water current north, east and their 1-sigmas (m/s; boat profile:
            # heading = course through the water).  A ground vehicle's course that turns as
            # a current would make it is counted once, course_not_heading
            "water_current_mps": self._current(),
            # the velocity's mean pitch above the body x axis and its 1-sigma (deg; ground
            # profile, straight driving): an IMU pitched on the vehicle shows here (the
            # counter imu_pitch_mount_suspect says when it is beyond 3 sigma)
            "imu_pitch_on_vehicle_deg": self._pitch_on_vehicle(),
            # at rest with a MEMS gyro: GNSS fixes leave the heading alone (its sigma grows)
            "heading_held": self.hold >= 0,
            # how long position / velocity updates have been refused (s; reset to GNSS
            # beyond [filter] max_lockout_s)
            "gnss_refused_s": [round(x, 2) for x in self.recovery.refused_s(est.t_us)],
            # variance scale of the IMU white noise, adapted from the velocity innovations
            "q_scale": self.adaptive.scale,
            # ... and of the GNSS velocity accuracy
            "r_scale": self.adaptive.r_scale,
            # ... and of the gyro's white noise alone, from the course innovations' persistence
            "gyro_q_scale": est.imu_noise.gyro_scale,
            # ... and of the gyro-bias random walk
            "bias_q_scale": self.adaptive.bias_scale,
            # factor on the GNSS course rows' variance: a slip of the course's own sized
            # against the gyro alone (1: the course is what the rows model)
            "course_noise_scale": round(self.course.noise.scale, 2),
            # the yaw error the IMU's accelerations last showed (deg, true minus ours, with
            # our later corrections taken out) and when (s; travel_direction.py: reversing
            # told from a yaw 180 deg off); None before a verdict (ground and boat profiles)
            "yaw_error_by_imu_deg": self._imu_yaw_error(),
            # the IMU's x axis from the vehicle's course when the IMU's accelerations put
            # it 60-120 deg off (deg, right +: an IMU turned on the vehicle; the course is
            # then not used); None while never
            "imu_yaw_on_vehicle_deg": (None if math.isnan(self.course.imu_yaw_on_vehicle)
                                       else round(math.degrees(
                                           self.course.imu_yaw_on_vehicle), 1)),
            # the gyro-bias corrections' chi-square(3) statistic over its last 30 s (about 3
            # when consistent; above 16.3 the walk is raised); None before the first
            "gyro_bias_corrections_z": (round(self.adaptive.corrections_z, 2)
                                        if math.isfinite(self.adaptive.corrections_z)
                                        else None),
            # the IMU's white noise measured from its samples, as a variance over the
            # configured (gyro, accelerometer; >= 1: a floor under the scale above)
            "imu_noise_floor": [round(est.imu_noise.gyro_floor, 3),
                                round(est.imu_noise.accel_floor, 3)],
        }

    def fuse(self, est: Estimator, g: GnssSample) -> bool:
        """One epoch; False when refused as an absurd jump (navigation may restart)."""
        cnt = est.counters
        c = self.cfg
        h_sd = g.h_acc_m if g.h_acc_m > 0.0 and math.isfinite(g.h_acc_m) else _DEFAULT_H_ACC
        v_sd = g.v_acc_m if g.v_acc_m > 0.0 and math.isfinite(g.v_acc_m) else _DEFAULT_V_ACC
        s_sd = (g.vel_acc_mps if g.vel_acc_mps > 0.0 and math.isfinite(g.vel_acc_mps)
                else _DEFAULT_VEL_ACC)
        h_sd = max(h_sd, c.gnss.min_pos_sd)
        v_sd = max(v_sd, c.gnss.min_pos_sd)
        # a receiver that understates its velocity noise: scaled from the innovations
        s_sd = max(s_sd, c.gnss.min_vel_sd) * self.adaptive.r_sd_factor

        # absurd jumps are refused even with gating off: they are not measurements of us
        pos = est.pos
        dn = (g.lat_rad - pos[0]) * 6.4e6
        de = (g.lon_rad - pos[1]) * 6.4e6 * math.cos(pos[0])
        if dn * dn + de * de > 1e10:  # 100 km
            cnt["gnss_absurd_jump"] += 1
            self._absurd_in_row += 1
            if self._absurd_in_row >= _REINIT_AFTER_JUMPS:
                # every fix for a while says we are elsewhere: it is our state that is wrong
                est.restart("reinit_gnss_jump")
            return False
        self._absurd_in_row = 0
        has_vel_h = math.isfinite(g.vel_n) and math.isfinite(g.vel_e)
        if has_vel_h:
            self.last_speed_h = math.hypot(g.vel_n, g.vel_e)
        yb = est.yaw_bank
        self.hold = (_YAW if has_vel_h and (self._heading_hold(est, g)
                                            or (yb is not None and yb.holds_heading(est)))
                     else -1)
        # unknown heading while accelerating: tilt and IMU biases are considered too
        # (YawBank.holds_tilt)
        self.hold_mask = (_TILT_BIAS_MASK if self.hold >= 0 and yb is not None
                          and yb.holds_tilt(est) else 0)
        if self.hold_mask:
            cnt["yaw_bank_tilt_held"] += 1
        if has_vel_h:
            self.course.note_not_tried(est, g)

        vel_scale = 1.0
        if self._mctls is not None:
            vel_scale = self._mctls_weight(g, s_sd)
            if vel_scale <= 0.0:
                cnt["vel_rejected_mctls"] += 1

        m_nb = est.mat_nb
        yaw0 = math.atan2(m_nb[1, 0], m_nb[0, 0])
        if has_vel_h and self.course.align.course_checks:
            self._direction_before(est, g, s_sd)
        self.course.begin_epoch(g.t_us * 1e-6, yaw0, float(est.buf[st.Q + 2]),
                                float(est.buf[st.Q + 11]))
        self.adaptive.before_epoch(est)
        bg = est.bias_g
        rate0 = m_nb[2, 0] * bg[0] + m_nb[2, 1] * bg[1] + m_nb[2, 2] * bg[2]
        if c.gnss.use_position:
            swapped = est.state_at(g.t_us) is True
            m = st.fill_position(est.buf, g.lat_rad, g.lon_rad, g.alt_m, h_sd, v_sd,
                                 self._delay_var)
            if swapped:
                est.state_restore()
            est.record_innovation(INNOV_POS, 0, 3,
                                  est.fuse_block(m, self._gate3, "pos", self.hold,
                                                 self.hold_mask))
        if not has_vel_h:
            cnt["gnss_no_velocity"] += 1
        elif c.gnss.use_velocity and vel_scale > 0.0:
            self.course.fuse_with_velocity(est, g, s_sd / math.sqrt(vel_scale), self.hold,
                                           self.hold_mask)
            if self.course.status == "active":
                self.mount_check.on_epoch(est, g, s_sd)
        # how far this epoch's updates turned the yaw (alignment integrity without a course)
        yaw1 = math.atan2(m_nb[1, 0], m_nb[0, 0])
        d_yaw = (yaw1 - yaw0 + math.pi) % (2.0 * math.pi) - math.pi
        self.course.align.note_yaw_moved(est, d_yaw)
        # a boat's learnt heading error moves with the yaw; the yaw sigma stays above it
        self.course.end_epoch(
            est, est.P, d_yaw, yaw1,
            m_nb[2, 0] * bg[0] + m_nb[2, 1] * bg[1] + m_nb[2, 2] * bg[2] - rate0)
        self.recovery.after_epoch(est, g.t_us, h_sd, v_sd, s_sd, math.isfinite(g.vel_d))
        self.adaptive.after_epoch(est, math.isfinite(g.vel_d), s_sd)
        if has_vel_h and self.course.align.course_checks:
            yaw2 = math.atan2(m_nb[1, 0], m_nb[0, 0])
            self.course.direction.after_epoch(
                est.vel_n, yaw2, _rate_down(est),
                (yaw2 - yaw0 + math.pi) % (2.0 * math.pi) - math.pi)
        return True

    def _direction_before(self, est: Estimator, g: GnssSample, s_sd: float) -> None:
        """Feed the travel-direction monitor the fix and the INS velocity before the
        epoch's updates."""
        C = est.mat_nb
        vrw = self.cfg.imu.accel_vrw * math.sqrt(self.adaptive.scale
                                                 * est.imu_noise.accel_floor)
        self.course.direction.before_epoch(g.t_us * 1e-6, g.vel_n, g.vel_e, est.vel_n,
                                           math.atan2(C[1, 0], C[0, 0]), _rate_down(est),
                                           s_sd, specific_force_sd(est.P, C), vrw)

    def _heading_hold(self, est: Estimator, g: GnssSample) -> bool:
        """Whether this epoch's fixes (with horizontal velocity) must leave the heading
        (phi_D) alone.

        At rest the heading is unobservable to a gyro that cannot gyrocompass: the fixes
        see only east-gyro-bias + earth-rate x heading, as one number.  An EKF nevertheless
        gains heading information there, because it relinearises the gyro-bias coupling
        (-C_b^n) about a heading that its own corrections keep moving; over 40 minutes at
        rest the heading sigma fell from 10 to 3.6 deg while the heading error grew from 5
        to 25 deg.  Holding phi_D as a Schmidt consider state in these updates (no gain,
        exact cross-covariances) keeps the filter honest; heading aids (course,
        polarization) still correct it.
        """
        if not self.hold_enabled:
            return False
        r = est.rate_b
        if (math.sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2])
                > self.cfg.init.static_rate_tol):
            return False
        # At rest either the fix or the IMU-propagated velocity says so: one noisy fix above
        # the threshold (1 in ~74 static epochs of a MEMS receiver) must not end the hold,
        # because that single update can turn the unobservable heading by tens of degrees.
        # Moving off, the IMU raises the filter's speed within a fraction of a second.
        # Hysteresis: once held, the hold ends only above twice the threshold, so speeds
        # that hover around it (noise at rest, creeping) do not toggle it epoch by epoch.
        v = est.vel_n
        still = self.cfg.heading.hold_max_speed * (2.0 if self.hold >= 0 else 1.0)
        if (math.hypot(g.vel_n, g.vel_e) > still
                and math.sqrt(v[0] * v[0] + v[1] * v[1]) > still):
            return False
        est.counters["heading_held"] += 1
        return True

    def _mctls_weight(self, g: GnssSample, s_sd: float) -> float:
        """Feed MCTLS; return the variance divisor for this epoch's velocity (0 = skip)."""
        mc = self._mctls
        assert mc is not None
        v = self._vel_ecef
        if g.vel_ecef_mps is not None:
            v[0], v[1], v[2] = g.vel_ecef_mps
        else:
            mat_ne_into(self._cne, g.lat_rad, g.lon_rad)
            # C_e^n^T v_n
            for i in range(3):
                v[i] = (self._cne[0, i] * g.vel_n + self._cne[1, i] * g.vel_e
                        + self._cne[2, i] * g.vel_d)
        ready = mc.push(g.t_us * 1e-6, v, s_sd, g.lat_rad, g.lon_rad)
        if not ready:
            return 1.0
        w = mc.newest_weight
        if w < self.cfg.mctls.min_weight:
            return 0.0
        return w
