"""The estimator: one entry point, :meth:`Estimator.push`, for every input sample.

A 15-state error-state Kalman filter (docs/design.md §3) around the strapdown mechanization, aided
by GNSS position, velocity and (in ``completed`` mode) GNSS course as heading (§4), with an
optional robust GNSS velocity pre-filter (MCTLS, §5).  Every array is allocated in
``__init__``; a steady-state IMU step or GNSS update creates no ndarray.

The estimator is a plain library: no clocks, no I/O, no logging.  Anything it refuses is
counted in :attr:`Estimator.counters` (the daemon turns counts into rate-limited log lines).

Life cycle::

    WAIT   collect IMU increments for levelling (static) and wait for a GNSS fix
    NAV    navigate; heading is "aligned" once it came from config or a trusted course
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import replace
from typing import TYPE_CHECKING, Protocol

import numpy as np
import numpy.typing as npt

from navd.config import EstimatorConfig
from navd.core import state as st
from navd.core.chi2 import chi2_quantile
from navd.core.earth import OMEGA_IE, geodetic_to_ecef, mat_ne_into, radii
from navd.core.output import attitude_outputs
from navd.core.rotation import euler_to_mat_into, exp_into, mat_to_euler, mul3_into
from navd.types import FixType, GnssSample, ImuSample, NavSolution, PolSample

if TYPE_CHECKING:
    from navd.core.aiding.mctls import Mctls

Sample = ImuSample | GnssSample | PolSample


class DovField(Protocol):
    """A deflection-of-the-vertical model evaluated along the track (navd.core.aiding.dov)."""

    def eval_into(self, lat_rad: float, lon_rad: float, out: npt.NDArray[np.float64]) -> bool:
        """Write (xi_rad, eta_rad, dg_d_mps2) into ``out``; False when off the model's area
        (``out`` is then zeroed: normal gravity)."""
        ...


class PolAiding(Protocol):
    """Skylight-polarization heading aiding (navd.core.aiding.polarization)."""

    def update(self, est: Estimator, sample: PolSample) -> None:
        """Fuse one reading into ``est`` (through est.fuse_block) or count why not."""
        ...

_WAIT = 0
_NAV = 1

_MAX_GNSS_LEAD_US = 1_000_000  # a fix may be stamped at most this far ahead of the IMU
_REINIT_AFTER_JUMPS = 20  # consecutive >100 km disagreements that restart navigation
_YAW = 2  # error-state index of phi_D
_GYROCOMPASS_USELESS_RAD = 5.0 * math.pi / 180.0


def _fixes_agree(a: GnssSample, b: GnssSample) -> bool:
    """Two start-up fixes describe the same platform: positions within what the reported
    velocity (and 50 m of noise) allows over their interval."""
    dt = abs(b.t_us - a.t_us) * 1e-6
    dn = (b.lat_rad - a.lat_rad) * 6.37e6
    de = (b.lon_rad - a.lon_rad) * 6.37e6 * math.cos(a.lat_rad)
    du = b.alt_m - a.alt_m
    reach = 50.0 + (math.hypot(a.vel_n, a.vel_e) + 5.0) * dt
    return dn * dn + de * de + du * du <= reach * reach


# GNSS accuracies below these are treated as missing and replaced by config defaults
_DEFAULT_H_ACC = 5.0
_DEFAULT_V_ACC = 10.0
_DEFAULT_VEL_ACC = 0.5


class Estimator:
    """GNSS/INS attitude and heading estimator.

    Attributes (read-only for callers):
        mat_nb: C_b^n (3, 3).
        vel_n: NED velocity (3,), m/s.
        pos: (lat_rad, lon_rad, alt_m).
        bias_g: gyro bias estimate, body FRD (3,), rad/s.
        bias_a: accelerometer bias estimate, body FRD (3,), m/s^2.
        P: error covariance (15, 15) in the state order of :mod:`navd`.
        dov: gravity disturbance (xi_rad, eta_rad, dg_d_mps2) used by the mechanization.
        counters: accepted/rejected/skipped counts by name.
        heading_aligned: heading came from config or a trusted GNSS course.
    """

    def __init__(self, config: EstimatorConfig | None = None, dov_field: DovField | None = None,
                 pol: PolAiding | None = None) -> None:
        self.cfg = config or EstimatorConfig()
        self.dov_field = dov_field
        self.dov_on_grid = False
        self.pol = pol
        self._gnss_delay_us = round(self.cfg.gnss.delay * 1e6)
        c = self.cfg
        self._buf = np.zeros(st.SIZE)
        v = st.StateViews(self._buf)
        self._v = v
        self.mat_nb = v.mat_nb
        self.vel_n = v.vel_n
        self.pos = v.pos
        self.bias_g = v.bias_g
        self.bias_a = v.bias_a
        self.dov = v.dov
        self.P = v.P
        self.x = v.x
        self.rate_b = v.rate_b
        self._q = v.q
        self._work = v.work
        self._prev_inc = v.prev_inc
        self._acc = v.acc
        self._H = v.H
        self._z = v.z
        self._R = v.R
        self._M = v.M
        self.mat_nb[:, :] = np.eye(3)
        v.lever_b[:] = c.gnss.lever_arm
        self._cne = np.zeros((3, 3))
        self._vel_ecef = np.zeros(3)
        self._level_sum = np.zeros(6)

        q = self._q
        q[0:3] = c.imu.gyro_arw**2
        q[3:6] = c.imu.accel_vrw**2
        q[9:12] = c.imu.gyro_bias_rw**2
        q[12:15] = c.imu.accel_bias_rw**2

        p = c.filter.gate_prob
        self._gate1 = chi2_quantile(p, 1)
        self._gate3 = chi2_quantile(p, 3)
        self._gate4 = chi2_quantile(p, 4)
        self._gating = c.filter.robust != "none"
        self._coning = c.filter.coning
        self._cov_interval = c.filter.cov_interval
        self._mctls: Mctls | None = None
        if c.filter.robust == "mctls":
            from navd.core.aiding.mctls import Mctls as _Mctls

            self._mctls = _Mctls(window=c.mctls.window, order=c.mctls.order, mode="mctls")
        self._course_enabled = c.filter.mode == "completed" and (
            c.filter.profile == "ground"
            or (c.filter.profile == "fixed_wing" and c.heading.crab_sd > 0.0))
        self._sd_beta = (c.heading.sideslip_sd if c.filter.profile == "ground"
                         else c.heading.crab_sd)
        # Gyrocompassing at rest gives heading to gyro_bias_sd / (OMEGA_IE cos lat) at best;
        # beyond ~5 deg (a gyro worse than ~1.3 deg/h) it is no heading source worth keeping.
        self._hold_enabled = (c.heading.hold_static
                              and c.imu.gyro_bias_sd > OMEGA_IE * _GYROCOMPASS_USELESS_RAD)
        self._hold = -1

        self.counters: defaultdict[str, int] = defaultdict(int)
        self.heading_aligned = False
        self.course_status = "off"
        self.last_course_used_t_us = -1
        self._reset_state()

    # ------------------------------------------------------------------ state
    def _reset_state(self) -> None:
        self._stage = _WAIT
        self._hold = -1
        self.t_us = -1
        self._last_gnss_t_us = -1
        self._level_sum[:] = 0.0
        self._level_n = 0
        self._level_static = True
        self._level_t = 0.0
        self._pending_fix: GnssSample | None = None
        self._fix_agreement = 0
        self._absurd_in_row = 0
        self._level_fix0: GnssSample | None = None
        self._course_rejects = 0
        self.heading_aligned = False
        self.x[:] = 0.0
        st.history_reset(self._buf)
        self._imu_dt_us = 0
        self._prev_inc[:] = 0.0
        self._acc[:] = 0.0
        if self._mctls is not None:
            self._mctls.reset()

    @property
    def initialized(self) -> bool:
        return self._stage == _NAV

    # ------------------------------------------------------------------ entry point
    def push(self, sample: Sample) -> bool:
        """Feed one sample; return True when the navigation state advanced or was corrected.

        This is the only way input reaches the filter, so a log of push() calls replays a
        run exactly.  Bad samples are counted and ignored; they never raise.
        """
        if isinstance(sample, ImuSample):
            return self._push_imu(sample)
        if isinstance(sample, GnssSample):
            if self._gnss_delay_us:
                sample = replace(sample, t_us=sample.t_us - self._gnss_delay_us)
            return self._push_gnss(sample)
        if isinstance(sample, PolSample):
            if self.pol is None:
                self.counters["pol_no_aiding_configured"] += 1
                return False
            if self._stage != _NAV:
                self.counters["pol_before_nav"] += 1
                return False
            n = self.counters["pol_accepted"]
            self.pol.update(self, sample)
            return self.counters["pol_accepted"] > n
        self.counters["unknown_sample"] += 1
        return False

    def fuse_block(self, m: int, chi2_gate: float, name: str) -> float:
        """Apply the measurement block already written to H, z, R (first m rows) with a gate.

        For aiding modules outside this file: fill ``self.meas_H`` (4, 15), ``self.meas_z``
        (4,), ``self.meas_R`` (4, 4) for the present nominal state, then call this.  Counts
        ``<name>_accepted`` / ``<name>_rejected`` and returns the NIS (negative if refused).
        """
        return self._apply(m, chi2_gate, name)

    def state_at(self, t_us: int) -> bool | None:
        """Put the nominal state of time ``t_us`` in place, for an aid to linearise about.

        A reading older than the newest IMU sample is linearised about the state at its own
        time of validity (as GNSS is), its correction then applied to the present state.
        Returns False when ``t_us`` is the present (nothing swapped), True when the recorded
        state was swapped in (call :meth:`state_restore` before :meth:`fuse_block`), None
        when that time is no longer kept.
        """
        if (self.t_us - t_us) * 2 <= self._imu_dt_us:
            return False
        if not st.history_swap(self._buf, float(t_us), 0.5 * self._imu_dt_us + 1.0):
            return None
        return True

    def state_restore(self) -> None:
        """Undo :meth:`state_at` (after True)."""
        st.history_restore(self._buf)

    @property
    def meas_H(self) -> npt.NDArray[np.float64]:
        return self._H

    @property
    def meas_z(self) -> npt.NDArray[np.float64]:
        return self._z

    @property
    def meas_R(self) -> npt.NDArray[np.float64]:
        return self._R

    # ------------------------------------------------------------------ IMU
    def _push_imu(self, s: ImuSample) -> bool:
        cnt = self.counters
        if s.dt_us <= 0 or s.dt_us > self.cfg.filter.max_imu_gap * 1e6:
            cnt["imu_bad_dt"] += 1
            return False
        if not (math.isfinite(s.dtheta_x) and math.isfinite(s.dtheta_y)
                and math.isfinite(s.dtheta_z) and math.isfinite(s.dvel_x)
                and math.isfinite(s.dvel_y) and math.isfinite(s.dvel_z)):
            cnt["imu_nonfinite"] += 1
            return False
        dt = s.dt_us * 1e-6
        amax = self.cfg.imu.max_accel * dt
        wmax = self.cfg.imu.max_rate * dt
        if (abs(s.dvel_x) > amax or abs(s.dvel_y) > amax or abs(s.dvel_z) > amax
                or abs(s.dtheta_x) > wmax or abs(s.dtheta_y) > wmax or abs(s.dtheta_z) > wmax):
            cnt["imu_out_of_range"] += 1
            return False
        if self.t_us >= 0:
            if s.t_us == self.t_us:
                cnt["imu_duplicate"] += 1
                return False
            if s.t_us < self.t_us:
                cnt["imu_out_of_order"] += 1
                if self.t_us - s.t_us > 1_000_000:
                    # the sensor clock went back by seconds: a sensor reboot; start over
                    cnt["reinit_time_jump"] += 1
                    self._reset_state()
                return False
            gap = s.t_us - self.t_us - s.dt_us
            if gap > self.cfg.filter.max_imu_gap * 1e6:
                cnt["imu_gap"] += 1
                if gap > 1_000_000:
                    cnt["reinit_time_jump"] += 1
                    self._reset_state()
        self.t_us = s.t_us
        cnt["imu"] += 1
        if self._stage == _WAIT:
            self._level(s, dt)
            return False
        st.imu_step(self._buf, float(s.t_us), s.dtheta_x, s.dtheta_y, s.dtheta_z, s.dvel_x,
                    s.dvel_y, s.dvel_z, dt, self._coning, self._cov_interval)
        self._imu_dt_us = s.dt_us
        return True

    def _level(self, s: ImuSample, dt: float) -> None:
        """Average specific force and rate while waiting; levels once a fix is present."""
        ls = self._level_sum
        ls[0] += s.dvel_x
        ls[1] += s.dvel_y
        ls[2] += s.dvel_z
        ls[3] += s.dtheta_x
        ls[4] += s.dtheta_y
        ls[5] += s.dtheta_z
        self._level_n += 1
        self._level_t += dt
        if (self._level_t >= self.cfg.init.level_time and self._pending_fix is not None
                and self._fix_agreement >= 1):
            self._start_nav(self._pending_fix)
        elif self._level_t > 30.0:
            # no fix for a long time: restart the average so it describes the present
            ls[:] = 0.0
            self._level_n = 0
            self._level_t = 0.0
            self._level_fix0 = None

    def _start_nav(self, fix: GnssSample) -> None:
        c = self.cfg
        ls = self._level_sum
        T = self._level_t
        # the known accelerometer bias comes off before levelling: at rest it is a tilt error
        ba0 = c.imu.accel_bias
        fx, fy, fz = ls[0] / T - ba0[0], ls[1] / T - ba0[1], ls[2] / T - ba0[2]
        # Levelling needs the mean specific force to be gravity alone: no turning and no
        # change of velocity over the window.  Per-sample accelerometer noise of a MEMS IMU
        # can exceed any useful threshold, so this is judged from the mean rate and the GNSS
        # velocity change between the window's first and last fix.
        f0 = self._level_fix0 if self._level_fix0 is not None else fix
        dt_fix = (fix.t_us - f0.t_us) * 1e-6
        dv = math.sqrt((fix.vel_n - f0.vel_n) ** 2 + (fix.vel_e - f0.vel_e) ** 2
                       + (fix.vel_d - f0.vel_d) ** 2)
        self._level_static = (
            math.sqrt(ls[3] ** 2 + ls[4] ** 2 + ls[5] ** 2) / T < c.init.static_rate_tol
            and (dv < c.init.level_max_accel * dt_fix + 4.0 * max(fix.vel_acc_mps, 0.0)
                 if dt_fix > 0.0 else math.hypot(fix.vel_n, fix.vel_e) < 0.5))
        roll = math.atan2(-fy, -fz)
        pitch = math.atan2(fx, math.sqrt(fy * fy + fz * fz))
        yaw = 0.0
        self.heading_aligned = False
        src = c.init.heading_source
        speed = math.hypot(fix.vel_n, fix.vel_e)
        if src == "config":
            yaw = c.init.heading
            self.heading_aligned = True
        elif (src == "gnss_course" and speed >= c.heading.align_speed
              and c.filter.profile != "multirotor"):
            yaw = math.atan2(fix.vel_e, fix.vel_n)
            self.heading_aligned = True
            self.counters["heading_aligned_from_course"] += 1
        euler_to_mat_into(self.mat_nb, roll, pitch, yaw)
        self.pos[0] = fix.lat_rad
        self.pos[1] = fix.lon_rad
        self.pos[2] = fix.alt_m
        self.vel_n[0] = fix.vel_n
        self.vel_n[1] = fix.vel_e
        self.vel_n[2] = fix.vel_d if math.isfinite(fix.vel_d) else 0.0
        if self.dov_field is not None:
            self.dov_on_grid = self.dov_field.eval_into(fix.lat_rad, fix.lon_rad, self.dov)
        self.bias_g[:] = c.imu.gyro_bias
        self.bias_a[:] = c.imu.accel_bias
        P = self.P
        P[:, :] = 0.0
        tilt_sd = c.init.tilt_sd if self._level_static else max(c.init.tilt_sd, 5.0 * math.pi
                                                                   / 180.0)
        if not self._level_static:
            self.counters["level_not_static"] += 1
        P[0, 0] = P[1, 1] = tilt_sd**2
        P[2, 2] = (math.pi / 2) ** 2
        if self.heading_aligned:
            # The heading given is a ZYX yaw, the azimuth of the nose; with the nose pitched
            # by theta, a tilt error phi_h about the nose's horizontal direction h moves that
            # azimuth by tan(theta) phi_h, so phi_D = -d_yaw - tan(theta) phi_h: its variance
            # grows by tan^2 * tilt^2 and it correlates with the tilt (the Schur complement
            # stays heading_sd^2, so P stays positive).  Near 90 deg pitch the nose has no
            # azimuth: past a quarter turn of doubt, the heading is simply unknown.
            tp = math.tan(pitch)
            var_d = c.init.heading_sd**2 + (tp * tilt_sd) ** 2
            if var_d < P[2, 2]:
                P[2, 2] = var_d
                P[0, 2] = P[2, 0] = -tp * tilt_sd**2 * math.cos(yaw)
                P[1, 2] = P[2, 1] = -tp * tilt_sd**2 * math.sin(yaw)
        P[3, 3] = P[4, 4] = P[5, 5] = c.init.vel_sd**2
        self._set_pos_var(c.init.pos_sd)
        P[9, 9] = P[10, 10] = P[11, 11] = c.imu.gyro_bias_sd**2
        P[12, 12] = P[13, 13] = P[14, 14] = c.imu.accel_bias_sd**2
        self._stage = _NAV
        self.counters["nav_start"] += 1

    def _set_pos_var(self, sd_m: float) -> None:
        r_m, r_n = radii(self.pos[0])
        self.P[6, 6] = (sd_m / (r_m + self.pos[2])) ** 2
        self.P[7, 7] = (sd_m / ((r_n + self.pos[2]) * math.cos(self.pos[0]))) ** 2
        self.P[8, 8] = sd_m**2

    # ------------------------------------------------------------------ GNSS
    def _gnss_valid(self, g: GnssSample) -> bool:
        cnt = self.counters
        if not (math.isfinite(g.lat_rad) and math.isfinite(g.lon_rad)
                and math.isfinite(g.alt_m)):
            cnt["gnss_nonfinite"] += 1
            return False
        if g.fix_type < FixType.FIX_3D:
            cnt["gnss_no_fix"] += 1
            return False
        # NaN velocity components mean "not reported" (e.g. MAVLink GPS_RAW_INT has no
        # vertical velocity); they are handled in the update, and fail no range test here
        if (abs(g.lat_rad) > 0.5 * math.pi or abs(g.lon_rad) > 2.0 * math.pi
                or abs(g.alt_m) > 1e5 or abs(g.vel_n) > 500.0 or abs(g.vel_e) > 500.0
                or abs(g.vel_d) > 500.0 or math.isinf(g.vel_n) or math.isinf(g.vel_e)
                or math.isinf(g.vel_d)):
            cnt["gnss_out_of_range"] += 1
            return False
        if self._last_gnss_t_us >= 0 and g.t_us <= self._last_gnss_t_us:
            cnt["gnss_duplicate" if g.t_us == self._last_gnss_t_us else "gnss_out_of_order"] += 1
            return False
        if self.t_us >= 0 and g.t_us > self.t_us + _MAX_GNSS_LEAD_US:
            # stamped ahead of the IMU clock: accepting it would make every real fix after it
            # look out of order until the IMU caught up
            cnt["gnss_from_future"] += 1
            return False
        return True

    def _push_gnss(self, g: GnssSample) -> bool:
        if not self._gnss_valid(g):
            return False
        cnt = self.counters
        cnt["gnss"] += 1
        has_vel_h = math.isfinite(g.vel_n) and math.isfinite(g.vel_e)
        if self._stage == _WAIT:
            if not has_vel_h:
                cnt["gnss_no_velocity"] += 1
                return False
            self._last_gnss_t_us = g.t_us
            # Navigation starts from a fix only when the one before agrees with it: a single
            # wild fix must not become the starting position (every later real fix would be
            # refused as an absurd jump).
            p = self._pending_fix
            if p is not None and _fixes_agree(p, g):
                self._fix_agreement += 1
            else:
                if p is not None:
                    cnt["gnss_start_disagree"] += 1
                self._fix_agreement = 0
                self._level_fix0 = g
            self._pending_fix = g
            if self._level_t >= self.cfg.init.level_time and self._fix_agreement >= 1:
                self._start_nav(g)
                return True
            return False
        age_us = self.t_us - g.t_us
        if age_us > self.cfg.gnss.max_age * 1e6:
            cnt["gnss_too_old"] += 1
            return False
        # A fix older than the newest IMU sample is linearised about the state at its own
        # time of validity (history ring), not at arrival.
        swapped = self.state_at(g.t_us)
        if swapped is None:
            cnt["gnss_too_old"] += 1
            return False
        delayed = swapped
        if delayed:
            cnt["gnss_delayed"] += 1
            self.state_restore()
        if self.dov_field is not None:
            self.dov_on_grid = self.dov_field.eval_into(float(self.pos[0]), float(self.pos[1]),
                                                        self.dov)
            if not self.dov_on_grid:
                cnt["dov_off_grid"] += 1
        c = self.cfg
        h_sd = g.h_acc_m if g.h_acc_m > 0.0 and math.isfinite(g.h_acc_m) else _DEFAULT_H_ACC
        v_sd = g.v_acc_m if g.v_acc_m > 0.0 and math.isfinite(g.v_acc_m) else _DEFAULT_V_ACC
        s_sd = (g.vel_acc_mps if g.vel_acc_mps > 0.0 and math.isfinite(g.vel_acc_mps)
                else _DEFAULT_VEL_ACC)
        h_sd = max(h_sd, c.gnss.min_pos_sd)
        v_sd = max(v_sd, c.gnss.min_pos_sd)
        s_sd = max(s_sd, c.gnss.min_vel_sd)

        # absurd jumps are refused even with gating off: they are not measurements of us
        dn = (g.lat_rad - self.pos[0]) * 6.4e6
        de = (g.lon_rad - self.pos[1]) * 6.4e6 * math.cos(self.pos[0])
        if dn * dn + de * de > 1e10:  # 100 km
            cnt["gnss_absurd_jump"] += 1
            self._absurd_in_row += 1
            if self._absurd_in_row >= _REINIT_AFTER_JUMPS:
                # every fix for a while says we are elsewhere: it is our state that is wrong
                cnt["reinit_gnss_jump"] += 1
                self._reset_state()
            return False
        self._absurd_in_row = 0
        self._last_gnss_t_us = g.t_us
        self._hold = _YAW if self._heading_hold(g) else -1

        vel_scale = 1.0
        if self._mctls is not None:
            vel_scale = self._mctls_weight(g, s_sd)
            if vel_scale <= 0.0:
                cnt["vel_rejected_mctls"] += 1

        if c.gnss.use_position:
            self._swap_in(g.t_us, delayed)
            m = st.fill_position(self._buf, g.lat_rad, g.lon_rad, g.alt_m, h_sd, v_sd)
            self._swap_out(delayed)
            self._apply(m, self._gate3, "pos", self._hold)
        if not has_vel_h:
            cnt["gnss_no_velocity"] += 1
        elif c.gnss.use_velocity and vel_scale > 0.0:
            self._velocity_and_course(g, s_sd / math.sqrt(vel_scale), delayed)
        return True

    def _heading_hold(self, g: GnssSample) -> bool:
        """Whether this epoch's fixes must leave the heading (phi_D) alone.

        At rest the heading is unobservable to a gyro that cannot gyrocompass: the fixes
        see only east-gyro-bias + earth-rate x heading, as one number.  An EKF nevertheless
        gains heading information there, because it relinearises the gyro-bias coupling
        (-C_b^n) about a heading that its own corrections keep moving; over 40 minutes at
        rest the heading sigma fell from 10 to 3.6 deg while the heading error grew from 5
        to 25 deg.  Holding phi_D as a Schmidt consider state in these updates (no gain,
        exact cross-covariances) keeps the filter honest; heading aids (course,
        polarization) still correct it.
        """
        if not self._hold_enabled:
            return False
        if not (math.isfinite(g.vel_n) and math.isfinite(g.vel_e)):
            return False
        r = self.rate_b
        if (math.hypot(g.vel_n, g.vel_e) > self.cfg.heading.hold_max_speed
                or math.sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2])
                > self.cfg.init.static_rate_tol):
            return False
        self.counters["heading_held"] += 1
        return True

    def _swap_in(self, t_us: int, delayed: bool) -> None:
        if delayed:
            self.state_at(t_us)

    def _swap_out(self, delayed: bool) -> None:
        if delayed:
            self.state_restore()

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

    def _apply(self, m: int, gate: float, name: str, hold: int = -1) -> float:
        nis = st.update(self._buf, m, gate if self._gating else 0.0, hold)
        if nis >= 0.0:
            st.inject(self._buf)
            self.counters[name + "_accepted"] += 1
        elif nis == -math.inf:
            self.counters[name + "_singular"] += 1
            self.x[:] = 0.0
        else:
            self.counters[name + "_rejected"] += 1
        return nis

    def _course_usable(self, g: GnssSample) -> bool:
        """Whether heading ~ course now (docs/design.md §4); sets :attr:`course_status`."""
        c = self.cfg
        if not self._course_enabled:
            self.course_status = ("disabled: multirotor profile (course is not heading)"
                                  if c.filter.profile == "multirotor" else
                                  "disabled: traditional mode" if c.filter.mode == "traditional"
                                  else "disabled: fixed_wing without crab allowance")
            return False
        speed = math.hypot(g.vel_n, g.vel_e)
        if speed < c.heading.min_speed:
            self.course_status = "waiting: speed below threshold"
            return False
        r = self.rate_b
        m = self.mat_nb
        yaw_rate = m[2, 0] * r[0] + m[2, 1] * r[1] + m[2, 2] * r[2]
        if abs(yaw_rate) > c.heading.max_yaw_rate:
            self.course_status = "waiting: yaw rate too high"
            return False
        if abs(yaw_rate) * speed > c.heading.max_lat_accel:
            self.course_status = "waiting: lateral acceleration too high"
            return False
        # Backwards motion in body x is reversing only at reversing speeds; faster than that
        # it means our yaw is off by more than 90 degrees, which the course must correct.
        vx = m[0, 0] * g.vel_n + m[1, 0] * g.vel_e + m[2, 0] * g.vel_d
        if vx < 0.0 and speed < c.heading.max_reverse_speed:
            self.course_status = "waiting: reversing"
            return False
        self.course_status = "active"
        return True

    def _fill_velocity(self, g: GnssSample, s_sd: float, delayed: bool) -> int:
        # no vertical velocity reported: use our own with a variance that ignores it
        vd, sd_v = (g.vel_d, s_sd) if math.isfinite(g.vel_d) else (float(self.vel_n[2]), 1e3)
        self._swap_in(g.t_us, delayed)
        m = st.fill_velocity(self._buf, g.vel_n, g.vel_e, vd, s_sd, sd_v)
        return m

    def _velocity_and_course(self, g: GnssSample, s_sd: float, delayed: bool) -> None:
        cnt = self.counters
        H, z = self._H, self._z
        use_course = self._course_usable(g)
        if (not use_course and not self.heading_aligned
                and self.cfg.init.heading_source == "gnss_course"
                and self.cfg.filter.profile != "multirotor"
                and math.hypot(g.vel_n, g.vel_e) >= self.cfg.heading.align_speed):
            # Without course updates the first fast course still beats a yaw of zero as a
            # starting point (crab makes it coarse: keep the yaw variance wide).
            self._align_yaw_to_course(g.vel_n, g.vel_e, s_sd, extra_sd=self.cfg.init.heading_sd)
        m = self._fill_velocity(g, s_sd, delayed)
        if not use_course:
            self._swap_out(delayed)
            self._apply(m, self._gate3, "vel", self._hold)
            self._check_observed_heading()
            return
        # lever-arm-free GNSS velocity for the course, v_gnss - C (w x l); the velocity
        # innovation just computed is v_hat + C (w x l) - v_gnss
        vn_c = g.vel_n - (z[0] - (self.vel_n[0] - g.vel_n))
        ve_c = g.vel_e - (z[1] - (self.vel_n[1] - g.vel_e))
        if not self.heading_aligned:
            self._swap_out(delayed)
            self._align_yaw_to_course(vn_c, ve_c, s_sd)
            return
        # course alone first: its own gate decides whether it joins the velocity update
        st.course_row(self._buf, 3, vn_c, ve_c, s_sd, self._sd_beta)
        self._swap_out(delayed)
        zc = z[3]
        sc = H[3, 0] * H[3, 0] * self.P[0, 0] + H[3, 1] * H[3, 1] * self.P[1, 1]
        sc += 2.0 * H[3, 0] * H[3, 1] * self.P[0, 1] + self.P[2, 2]
        sc -= 2.0 * (H[3, 0] * self.P[0, 2] + H[3, 1] * self.P[1, 2])
        sc += s_sd * s_sd / (vn_c * vn_c + ve_c * ve_c) + self._sd_beta**2
        course_ok = (not self._gating) or zc * zc / sc <= self._gate1
        if course_ok:
            nis = self._apply(4, self._gate4, "vel_course")
            if nis >= 0.0:
                cnt["course_accepted"] += 1
                self._course_rejects = 0
                self.last_course_used_t_us = g.t_us
                return
            # the joint block failed: fall back to velocity alone
            m = self._fill_velocity(g, s_sd, delayed)
            self._swap_out(delayed)
            self._apply(m, self._gate3, "vel", self._hold)
            return
        cnt["course_rejected"] += 1
        self._course_rejects += 1
        m = self._fill_velocity(g, s_sd, delayed)
        self._swap_out(delayed)
        self._apply(m, self._gate3, "vel", self._hold)
        if self._course_rejects >= self.cfg.heading.reset_after:
            # persistently inconsistent: the yaw is wrong beyond the linear model; reset it
            self._align_yaw_to_course(vn_c, ve_c, s_sd)
            cnt["heading_reset"] += 1

    def _check_observed_heading(self) -> None:
        """Flag heading aligned once manoeuvres made the yaw observable (sigma small)."""
        if not self.heading_aligned and self.P[2, 2] < self.cfg.init.aligned_sd**2:
            self.heading_aligned = True
            self.counters["heading_aligned_by_observability"] += 1

    def _align_yaw_to_course(self, vn: float, ve: float, s_sd: float,
                             extra_sd: float = 0.0) -> None:
        """Rotate the attitude about down so yaw equals the course; reset yaw covariance."""
        _, _, yaw = mat_to_euler(self.mat_nb)
        chi = math.atan2(ve, vn)
        d = (yaw - chi + math.pi) % (2.0 * math.pi) - math.pi
        e = self._work[4]
        t = self._work[5]
        exp_into(e, 0.0, 0.0, -d)
        mul3_into(t, e, self.mat_nb)
        self.mat_nb[:, :] = t
        P = self.P
        P[2, :] = 0.0
        P[:, 2] = 0.0
        sd = s_sd / math.hypot(vn, ve)
        P[2, 2] = sd * sd + self._sd_beta**2 + (1.0 * math.pi / 180.0) ** 2 + extra_sd**2
        self._course_rejects = 0
        if not self.heading_aligned:
            self.counters["heading_aligned_from_course"] += 1
        self.heading_aligned = True

    # ------------------------------------------------------------------ outputs
    def solution(self) -> NavSolution:
        """The current navigation solution (allocates a small frozen object, not arrays)."""
        r, p, y, qw, qx, qy, qz, sr, sp, sy = attitude_outputs(self.mat_nb, self.P, self._M)
        v = self.vel_n
        bg = self.bias_g
        ba = self.bias_a
        w = self.rate_b
        return NavSolution(
            t_us=self.t_us, quat_nb=(qw, qx, qy, qz), roll_rad=r, pitch_rad=p, yaw_rad=y,
            lat_rad=float(self.pos[0]), lon_rad=float(self.pos[1]), alt_m=float(self.pos[2]),
            vel_n=(float(v[0]), float(v[1]), float(v[2])), att_sd_rad=(sr, sp, sy),
            gyro_bias_rps=(float(bg[0]), float(bg[1]), float(bg[2])),
            accel_bias_mps2=(float(ba[0]), float(ba[1]), float(ba[2])),
            heading_aligned=self.heading_aligned,
            rate_b=(float(w[0]), float(w[1]), float(w[2])))

    @property
    def heading_held(self) -> bool:
        """Whether the last GNSS epoch left the heading alone (at rest, MEMS gyro)."""
        return self._hold >= 0

    def status(self) -> dict[str, object]:
        """Counters and aiding status for the status topic and logs."""
        return {
            "initialized": self.initialized,
            "heading_aligned": self.heading_aligned,
            "mode": self.cfg.filter.mode,
            "robust": self.cfg.filter.robust,
            "profile": self.cfg.filter.profile,
            "course_update": self.course_status,
            # at rest with a MEMS gyro: GNSS fixes leave the heading alone (its sigma grows)
            "heading_held": self.heading_held,
            # sensor-time age of the last GNSS fix used; None before the first (absent GNSS
            # shows as a growing age: the INS is coasting)
            "gnss_age_s": ((self.t_us - self._last_gnss_t_us) * 1e-6
                           if self._last_gnss_t_us >= 0 and self.t_us >= 0 else None),
            "counters": dict(self.counters),
            "gyro_bias_dph": [float(b) * 180.0 / math.pi * 3600.0 for b in self.bias_g],
            "accel_bias_mg": [float(b) / 9.80665e-3 for b in self.bias_a],
            "dov_arcsec": [float(self.dov[0]) * 206264.806, float(self.dov[1]) * 206264.806],
            "dov_model": ("off" if self.dov_field is None else
                          "on grid" if self.dov_on_grid else "off grid: normal gravity"),
        }

    def ecef_position(self) -> tuple[float, float, float]:
        return geodetic_to_ecef(float(self.pos[0]), float(self.pos[1]), float(self.pos[2]))
