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
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from navd.config import EstimatorConfig
from navd.core import plausible
from navd.core import state as st
from navd.core.aiding.base import (
    ACCEPTED,
    INNOV_FLAG,
    INNOV_NIS,
    INNOV_POL,
    INNOV_POS,
    INNOV_T,
    INNOV_W,
    N_INNOV,
    NOT_TRIED,
    REJECTED,
    SINGULAR,
    Aid,
)
from navd.core.aiding.dov import DovAid, DovField
from navd.core.aiding.gnss import GnssAiding
from navd.core.aiding.gnss_heading import course_may_align
from navd.core.aiding.gyro_rest import GyroRest, rest_push
from navd.core.aiding.imu_noise import ImuNoise, noise_push
from navd.core.aiding.yaw_bank import YawBank, bank_enabled
from navd.core.aiding.yaw_bank_kernels import bank_imu, main_yaw, wrap
from navd.core.earth import geodetic_to_ecef, radii
from navd.core.imu_block import LIM_AHEAD, LIM_BACK, PUSH_LIMITS, ImuBlock, push_run
from navd.core.kalman import F_TAU_S, SF_FORGET_S, SF_SCALE_Z
from navd.core.level import level_cov
from navd.core.output import attitude_outputs
from navd.core.rotation import euler_to_mat_into
from navd.types import FixType, GnssSample, ImuSample, NavSolution, PolSample, Sample
from navd.units import G0

if TYPE_CHECKING:
    from navd.core.aiding.polarization import PolarizationAiding

__all__ = ["DovField", "Estimator"]

_WAIT = 0
_NAV = 1

_MAX_GNSS_LEAD_US = 1_000_000  # a fix may be stamped at most this far ahead of the IMU


def _fixes_agree(a: GnssSample, b: GnssSample) -> bool:
    """Two start-up fixes describe the same platform: positions within what the reported
    velocity (and 50 m of noise) allows over their interval."""
    dt = abs(b.t_us - a.t_us) * 1e-6
    dn = (b.lat_rad - a.lat_rad) * 6.37e6
    de = (b.lon_rad - a.lon_rad) * 6.37e6 * math.cos(a.lat_rad)
    du = b.alt_m - a.alt_m
    reach = 50.0 + (math.hypot(a.vel_n, a.vel_e) + 5.0) * dt
    return dn * dn + de * de + du * du <= reach * reach


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
        aids: the aids, in the order they see a sample (:mod:`navd.core.aiding.base`).
        innov: last innovation per measurement kind, (N_INNOV, INNOV_W); rows, columns,
            frames, units and signs in :mod:`navd.core.aiding.base` (``INNOV_*``).
    """

    def __init__(self, config: EstimatorConfig | None = None, dov_field: DovField | None = None,
                 pol: PolarizationAiding | None = None, dov_refused: str | None = None) -> None:
        self.cfg = config or EstimatorConfig()
        self._gnss_delay_us = round(self.cfg.gnss.delay * 1e6)
        c = self.cfg
        self._max_imu_gap_us = c.filter.max_imu_gap * 1e6
        self._max_gnss_age_us = c.gnss.max_age * 1e6
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
        self.work = v.work  # (8, 3, 3) scratch, free between calls (aids use it too)
        # the gyro scale-factor block (kalman.SF_N): the allowance, and the z gyro's scale
        # error the course teaches (aiding/gnss_heading.py)
        self.gyro_sf = v.sf
        self._prev_inc = v.prev_inc
        self._dprev = v.dprev
        self._acc = v.acc
        self._H = v.H
        self._z = v.z
        self._R = v.R
        self._M = v.M
        self.mat_nb[:, :] = np.eye(3)
        # the GNSS antenna's position, body FRD (3,) m: the configured one, plus what a
        # boat learns from its roll (aiding/course_learner.py)
        self.lever_b = v.lever_b
        v.lever_b[:] = c.gnss.lever_arm
        # the IMU's axes to the body's ([imu] mount_*_deg); None: the identity, nothing to turn
        euler_to_mat_into(v.mat_bs, *c.imu.mount)
        mounted = float(np.max(np.abs(v.mat_bs - np.eye(3)))) > 1e-12
        self._buf[st.MOUNT + 9] = 1.0 if mounted else 0.0
        self._mount = tuple(float(a) for a in v.mat_bs.ravel()) if mounted else None
        self._level_sum = np.zeros(9)  # sums of dvel xyz, dtheta xyz, dvel^2 xyz
        self.innov = np.full((N_INNOV, INNOV_W), math.nan)

        q = self._q
        q[0:3] = c.imu.gyro_arw**2
        q[3:6] = c.imu.accel_vrw**2
        q[9:12] = c.imu.gyro_bias_rw**2
        q[12:15] = c.imu.accel_bias_rw**2

        self._limits = plausible.Limits.from_config(c.imu)
        self._max_gyro_rps = self._limits.max_gyro_rps
        self._max_accel_mps2 = self._limits.max_accel_mps2
        self._gating = c.filter.robust != "none"
        self._coning = c.filter.coning
        # F's specific force low-passed on a multirotor only (navd/core/kalman.py, F_TAU_S)
        v.f_lp[6] = F_TAU_S if c.filter.profile == "multirotor" else 0.0
        v.sf[0] = c.imu.gyro_scale_sd**2
        v.sf[13] = SF_FORGET_S
        self._cov_interval = c.filter.cov_interval

        # The aids, in the order they see a sample: the gravity model is evaluated at the
        # epoch before the GNSS rows are formed.
        self.dov_aid = DovAid(dov_field, dov_refused)
        self.gnss = GnssAiding(c)
        self.gyro_rest = GyroRest(c)
        self._rest_acc = self.gyro_rest.acc
        # the IMU's white noise measured from its samples: a floor under q (imu_noise.py)
        self.imu_noise = ImuNoise(c.imu.gyro_arw, c.imu.accel_vrw, c.filter.max_q_scale,
                                  c.filter.measure_imu_noise)
        self._noise_acc = self.imu_noise.acc
        self.pol = pol
        aids: list[Aid] = [self.dov_aid, self.gnss]
        if pol is not None:
            aids.append(pol)
        self.aids: tuple[Aid, ...] = tuple(aids)
        self._consumers: dict[type, tuple[Aid, ...]] = {
            t: tuple(a for a in self.aids if a.consumes is t) for t in (GnssSample, PolSample)}

        # heading from motion (multirotor, fixed-wing): not an Aid, it runs beside the GNSS
        # aid, before and after its update (core/aiding/yaw_bank.py)
        self.yaw_bank: YawBank | None = YawBank(c) if bank_enabled(c) else None
        self._bank_buf = self.yaw_bank.buf if self.yaw_bank is not None else None
        # push_imu_block's constants (imu_block.LIM_*; the clock window is the caller's)
        self._block_lim = np.array([self._max_imu_gap_us, self._max_gyro_rps,
                                    self._max_accel_mps2, self.gyro_rest.window_s,
                                    self._cov_interval, 0.0, 0.0])
        assert self._block_lim.shape == (PUSH_LIMITS,)
        self._no_bank = np.zeros(1)

        self.counters: defaultdict[str, int] = defaultdict(int)
        self.heading_aligned = False
        # times the state started over (sensor clock jump, restart()): front ends watch it to
        # restart their output schedules and to report it; the first _reset_state() is the
        # start, not a restart
        self.restarts = -1
        self.restart_reason = ""
        self._reset_state()

    # ------------------------------------------------------------------ state
    def _reset_state(self, reason: str = "") -> None:
        self.restarts += 1
        self.restart_reason = reason
        self._stage = _WAIT
        self.t_us = -1
        self._last_gnss_t_us = -1
        self._level_sum[:] = 0.0
        self._level_n = 0
        self._level_static = True
        self._level_t = 0.0
        self._pending_fix: GnssSample | None = None
        self._fix_agreement = 0
        self._level_fix0: GnssSample | None = None
        self.heading_aligned = False
        self.x[:] = 0.0
        st.history_reset(self._buf)
        self._imu_dt_us = 0
        # how old the reading being fused is, s (state_at; 0 outside a delayed reading)
        self._lag_s = 0.0
        self._prev_inc[:] = 0.0
        self._dprev[:] = 0.0
        self._acc[:] = 0.0
        # the low-passes and high-passes restart; the drag coefficient's regression stays
        self._v.f_lp[:6] = 0.0
        self._v.f_lp[8:14] = 0.0
        self._v.sf[1:13] = 0.0  # the scale allowance's net rotations start again
        self._v.sf[SF_SCALE_Z] = 0.0  # the course learns it again (gnss_heading.py)
        for aid in self.aids:
            aid.reset()
        self.gyro_rest.reset()
        self.imu_noise.restart()
        if self.yaw_bank is not None:
            self.yaw_bank.reset()

    def restart(self, reason: str) -> None:
        """Count ``reason`` and start over (wait for levelling and a fix): for an aid whose
        inputs say the state is wrong beyond repair."""
        self.counters[reason] += 1
        self._reset_state(reason)

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
        try:
            return self._push_aiding(sample)
        finally:
            self._lag_s = 0.0

    def _push_aiding(self, sample: Sample) -> bool:
        if isinstance(sample, GnssSample):
            if self._stage == _NAV:
                self._innov_begin(INNOV_POS, INNOV_POL, sample.t_us)
            if self._gnss_delay_us:
                sample = replace(sample, t_us=sample.t_us - self._gnss_delay_us)
            if not self._gnss_valid(sample):
                return False
            self.counters["gnss"] += 1
            if self._stage == _WAIT:
                return self._gnss_start(sample)
            if not self._gnss_in_time(sample):
                return False
            yb = self.yaw_bank
            if yb is not None:
                yb.before_fix(self, sample)
            if self._dispatch(sample):
                if yb is not None:
                    yb.after_fix(self, sample)
                self._last_gnss_t_us = sample.t_us
                return True
            return False
        if isinstance(sample, PolSample):
            if not self._consumers[PolSample]:
                self.counters["pol_no_aiding_configured"] += 1
                return False
            if self._stage != _NAV:
                self.counters["pol_before_nav"] += 1
                return False
            self._innov_begin(INNOV_POL, N_INNOV, sample.t_us)
            return self._dispatch(sample)
        self.counters["unknown_sample"] += 1
        return False

    def _dispatch(self, sample: GnssSample | PolSample) -> bool:
        advanced = False
        yb = self.yaw_bank
        y0 = main_yaw(self._buf) if yb is not None else 0.0
        for aid in self._consumers[type(sample)]:
            advanced = aid.fuse(self, sample) or advanced
        if yb is not None and self._stage == _NAV:
            # the bank's hypotheses are offsets from the main yaw: keep them where they were
            yb.main_turned(wrap(main_yaw(self._buf) - y0))
        return advanced

    def _innov_begin(self, first: int, stop: int, t_us: int) -> None:
        """Mark innovation rows first..stop-1 'not tried' for a sample stamped t_us."""
        r = self.innov
        for k in range(first, stop):
            r[k, 0] = math.nan
            r[k, 1] = math.nan
            r[k, 2] = math.nan
            r[k, INNOV_NIS] = math.nan
            r[k, INNOV_FLAG] = NOT_TRIED
            r[k, INNOV_T] = t_us

    def record_innovation(self, kind: int, row0: int, n: int, nis: float) -> None:
        """Copy ``meas_z[row0:row0 + n]`` and the outcome of :meth:`fuse_block` (its return
        value ``nis``) into row ``kind`` of :attr:`innov`."""
        r = self.innov
        z = self._z
        for i in range(n):
            r[kind, i] = z[row0 + i]
        if nis >= 0.0:
            r[kind, INNOV_NIS] = nis
            r[kind, INNOV_FLAG] = ACCEPTED
        elif nis == -math.inf:
            r[kind, INNOV_NIS] = math.inf
            r[kind, INNOV_FLAG] = SINGULAR
        else:
            r[kind, INNOV_NIS] = -nis
            r[kind, INNOV_FLAG] = REJECTED

    def fuse_block(self, m: int, chi2_gate: float, name: str, hold: int = -1,
                   hold_mask: int = 0) -> float:
        """Apply the measurement block already written to H, z, R (first m rows) with a gate.

        For aids: fill ``self.meas_H`` (4, 15), ``self.meas_z`` (4,), ``self.meas_R``
        (4, 4) for the present nominal state, then call this.  ``chi2_gate`` is ignored when
        ``[filter] robust = "none"``; ``hold``: a consider-state index (-1: none),
        ``hold_mask``: further consider states, bit i for state i (0: none).  Counts
        ``<name>_accepted`` / ``_rejected`` / ``_singular`` and returns the NIS (negative
        -NIS if gated out, -inf if the innovation covariance was singular).
        """
        # a reading linearised about its own past time (state_at) is an update of that
        # time's covariance: the process noise since is not what it measures (st.update)
        nis = st.update(self._buf, m, chi2_gate if self._gating else 0.0, hold, hold_mask,
                        self._lag_s)
        if nis >= 0.0:
            st.inject(self._buf)
            self.counters[name + "_accepted"] += 1
        elif nis == -math.inf:
            self.counters[name + "_singular"] += 1
            self.x[:] = 0.0
        else:
            self.counters[name + "_rejected"] += 1
        return nis

    def state_at(self, t_us: int) -> bool | None:
        """Put the nominal state of time ``t_us`` in place, for an aid to linearise about.

        A reading older than the newest IMU sample is linearised about the state at its own
        time of validity (as GNSS is), its correction then applied to the present state, and
        until the sample's push returns every update is one of the covariance of then
        (``st.update``'s ``lag``).
        Returns False when ``t_us`` is the present (nothing swapped), True when the recorded
        state was swapped in (call :meth:`state_restore` before :meth:`fuse_block`), None
        when that time is no longer kept.
        """
        if (self.t_us - t_us) * 2 <= self._imu_dt_us:
            self._lag_s = 0.0
            return False
        if not st.history_swap(self._buf, float(t_us), 0.5 * self._imu_dt_us + 1.0):
            self._lag_s = 0.0
            return None
        # the updates of this sample (until push returns) are of the covariance of then
        self._lag_s = (self.t_us - t_us) * 1e-6
        return True

    def state_restore(self) -> None:
        """Undo :meth:`state_at` (after True)."""
        st.history_restore(self._buf)

    @property
    def imu_dt_us(self) -> int:
        """The last IMU sample's interval, us (0 before the first step)."""
        return self._imu_dt_us

    @property
    def buf(self) -> npt.NDArray[np.float64]:
        """The state buffer (:mod:`navd.core.state`), for the compiled row kernels."""
        return self._buf

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
    def push_imu_block(self, block: ImuBlock, stop_at_us: int, clock_t_us: int = -1,
                       clock_back_us: int = 0, clock_ahead_us: int = 0) -> int:
        """Push the block's samples from ``block.start`` on, as :meth:`push` of each one's
        ImuSample would, while each is one the compiled run takes (a plausible, in-order,
        navigating sample that completes no rest window); return how many were consumed
        (``block.start`` advanced by that many).  The rest is the caller's to :meth:`push`
        one by one.  The same pushes, so the same state, counters and recordable input as
        :meth:`push` of the samples (:mod:`navd.core.imu_block`).

        Stops right after the first consumed sample stamped at or past ``stop_at_us`` (the
        caller's next output instant), and before a sample off the clock the caller's guard
        keeps: newest stamp ``clock_t_us`` (-1: none, nothing consumed), a sample more than
        ``clock_back_us`` behind or ``clock_ahead_us`` ahead of it is not taken
        (:meth:`navd.core.clock_guard.ClockGuard.on_clock`)."""
        i0 = block.start
        if self._stage != _NAV or self.t_us < 0 or i0 >= block.n:
            return 0
        lim = self._block_lim
        lim[LIM_BACK] = clock_back_us
        lim[LIM_AHEAD] = clock_ahead_us
        bank = self._bank_buf
        k = push_run(self._buf, self._rest_acc, self._noise_acc,
                     self._no_bank if bank is None else bank,
                     bank is not None, block.t_us, block.dt_us, block.inc, i0, block.n,
                     self.t_us, clock_t_us, lim, self._coning, stop_at_us)
        if k:
            last = i0 + k - 1
            self.t_us = int(block.t_us[last])
            self._imu_dt_us = int(block.dt_us[last])
            self.counters["imu"] += k
            block.start = i0 + k
        return k

    def _push_imu(self, s: ImuSample) -> bool:
        # The kHz path (issue 18): each field read once, the usual plausibility test inline
        # (the same arithmetic as plausible.imu_reason, which still classifies a failure).
        cnt = self.counters
        dt_us = s.dt_us
        if dt_us <= 0 or dt_us > self._max_imu_gap_us:
            cnt["imu_bad_dt"] += 1
            return False
        dt = dt_us * 1e-6
        dtx, dty, dtz = s.dtheta_x, s.dtheta_y, s.dtheta_z
        dvx, dvy, dvz = s.dvel_x, s.dvel_y, s.dvel_z
        max_w = self._max_gyro_rps * dt
        max_f = self._max_accel_mps2 * dt
        if not (dtx * dtx + dty * dty + dtz * dtz <= max_w * max_w
                and dvx * dvx + dvy * dvy + dvz * dvz <= max_f * max_f):
            bad = plausible.imu_reason(dtx, dty, dtz, dvx, dvy, dvz, max_w, max_f)
            if bad is not None:
                cnt["imu_nonfinite" if bad == "imu_nonfinite" else "imu_out_of_range"] += 1
                return False
        m = self._mount
        if m is not None:
            # after the plausibility test (a rotation keeps the norms), before anything
            # that reads an axis
            dtx, dty, dtz = (m[0] * dtx + m[1] * dty + m[2] * dtz,
                             m[3] * dtx + m[4] * dty + m[5] * dtz,
                             m[6] * dtx + m[7] * dty + m[8] * dtz)
            dvx, dvy, dvz = (m[0] * dvx + m[1] * dvy + m[2] * dvz,
                             m[3] * dvx + m[4] * dvy + m[5] * dvz,
                             m[6] * dvx + m[7] * dvy + m[8] * dvz)
        t_us = s.t_us
        last = self.t_us
        if last >= 0:
            if t_us == last:
                cnt["imu_duplicate"] += 1
                return False
            if t_us < last:
                cnt["imu_out_of_order"] += 1
                if last - t_us > 1_000_000:
                    # the sensor clock went back by seconds: a sensor reboot; start over
                    cnt["reinit_time_jump"] += 1
                    self._reset_state("reinit_time_jump")
                return False
            gap = t_us - last - dt_us
            if gap > self._max_imu_gap_us:
                cnt["imu_gap"] += 1
                if gap > 1_000_000:
                    cnt["reinit_time_jump"] += 1
                    self._reset_state("reinit_time_jump")
        self.t_us = t_us
        cnt["imu"] += 1
        t = float(t_us)
        if self._stage != _WAIT:
            # rest detector and step in one kernel call, unless a rest window completes
            # (then it is closed first and the step follows, as for a waiting estimator)
            if not st.rest_then_step(self._rest_acc, self._noise_acc, self._buf, t, dtx, dty,
                                     dtz, dvx, dvy, dvz, dt, self.gyro_rest.window_s,
                                     self._coning, self._cov_interval):
                if self._bank_buf is not None:
                    bank_imu(self._bank_buf, self._buf, t, dt)
                self._imu_dt_us = dt_us
                return True
            self.gyro_rest.window_done(self)
        else:
            noise_push(self._noise_acc, self._q, t, dtx, dty, dtz, dvx, dvy, dvz, dt)
            if rest_push(self._rest_acc, dtx, dty, dtz, dvx, dvy, dvz, dt,
                         self.gyro_rest.window_s):
                self.gyro_rest.window_done(self)
        if self._stage == _WAIT:
            self._level(dtx, dty, dtz, dvx, dvy, dvz, dt)
            return False
        st.imu_step(self._buf, t, dtx, dty, dtz, dvx, dvy, dvz, dt, self._coning,
                    self._cov_interval)
        if self._bank_buf is not None:
            bank_imu(self._bank_buf, self._buf, t, dt)
        self._imu_dt_us = dt_us
        return True

    def _level(self, dtx: float, dty: float, dtz: float, dvx: float, dvy: float, dvz: float,
               dt: float) -> None:
        """Average specific force and rate while waiting (body-frame increments, rad and
        m/s); levels once a fix is present."""
        ls = self._level_sum
        ls[0] += dvx
        ls[1] += dvy
        ls[2] += dvz
        ls[3] += dtx
        ls[4] += dty
        ls[5] += dtz
        ls[6] += dvx * dvx
        ls[7] += dvy * dvy
        ls[8] += dvz * dvz
        self._level_n += 1
        self._level_t += dt
        if (self._level_t >= self.cfg.init.level_time and self._pending_fix is not None
                and self._fix_agreement >= 1 and self._level_done(self._pending_fix)):
            self._start_nav(self._pending_fix)
        elif self._level_t > 30.0:
            # no fix for a long time: restart the average so it describes the present
            ls[:] = 0.0
            self._level_n = 0
            self._level_t = 0.0
            self._level_fix0 = None

    def _level_static_now(self, fix: GnssSample) -> bool:
        """Whether the levelling window so far is unaccelerated: no turning and no change of
        velocity.  Per-sample accelerometer noise of a MEMS IMU can exceed any useful
        threshold, so this is judged from the mean rate and the GNSS velocity change between
        the window's first fix and ``fix``."""
        c = self.cfg
        ls = self._level_sum
        f0 = self._level_fix0 if self._level_fix0 is not None else fix
        dt_fix = (fix.t_us - f0.t_us) * 1e-6
        dv = math.sqrt((fix.vel_n - f0.vel_n) ** 2 + (fix.vel_e - f0.vel_e) ** 2
                       + (fix.vel_d - f0.vel_d) ** 2)
        return bool(
            math.sqrt(ls[3] ** 2 + ls[4] ** 2 + ls[5] ** 2) / self._level_t < c.init.static_rate_tol
            and (dv < c.init.level_max_accel * dt_fix + 4.0 * max(fix.vel_acc_mps, 0.0)
                 if dt_fix > 0.0 else math.hypot(fix.vel_n, fix.vel_e) < 0.5))

    def _level_scatter_sd(self) -> float:
        """Tilt sigma (rad) the mean specific force's own noise allows, from the window's
        scatter (never the configured noise, which may be understated): Var(sum dv) =
        n Var(dv) for increments of equal length, so the mean specific force sum(dv)/T has
        n Var(dv)/T^2 per axis; over g for the tilt."""
        ls = self._level_sum
        n = self._level_n
        if n < 2:
            return math.inf
        T = self._level_t
        var_dv = sum(max(ls[6 + i] - ls[i] * ls[i] / n, 0.0) for i in range(3)) / (3 * (n - 1))
        g = max(math.sqrt(ls[0] ** 2 + ls[1] ** 2 + ls[2] ** 2) / T, 0.5 * G0)
        return math.sqrt(n * var_dv) / T / g

    def _level_done(self, fix: GnssSample) -> bool:
        """Whether levelling may end now (``level_time`` has passed): its tilt is as good as
        ``tilt_sd`` asks, or cannot get better (the window stopped being unaccelerated, or
        ``level_max_time`` is reached).  A noisy IMU levels longer, where it can, rather than
        start navigation several degrees off (noise_x3: 1 s of 3x the configured VRW gives
        5 deg of tilt sigma, and errors of that size leave the gyro-bias estimate off by
        more than its sigma for minutes)."""
        c = self.cfg.init
        return (self._level_t >= c.level_max_time or not self._level_static_now(fix)
                or self._level_scatter_sd() <= c.tilt_sd)

    def _start_nav(self, fix: GnssSample) -> None:
        c = self.cfg
        ls = self._level_sum
        T = self._level_t
        # the known accelerometer bias comes off before levelling: at rest it is a tilt error
        ba0 = c.imu.accel_bias
        fx, fy, fz = ls[0] / T - ba0[0], ls[1] / T - ba0[1], ls[2] / T - ba0[2]
        self._level_static = self._level_static_now(fix)
        roll = math.atan2(-fy, -fz)
        pitch = math.atan2(fx, math.sqrt(fy * fy + fz * fz))
        yaw = 0.0
        self.heading_aligned = False
        src = c.init.heading_source
        speed = math.hypot(fix.vel_n, fix.vel_e)
        yaw_known = False
        if src == "config":
            yaw = c.init.heading
            self.heading_aligned = yaw_known = True
            self.gnss.course.align.config_heading()
        elif (src == "gnss_course" and speed >= c.heading.align_speed
              and course_may_align(c, self.yaw_bank is not None)):
            yaw = math.atan2(fix.vel_e, fix.vel_n)
            yaw_known = True
            # flagged aligned once the course agrees over time (aiding/heading_alignment.py)
            self.gnss.course.align.yaw_given(self, from_course=True)
        euler_to_mat_into(self.mat_nb, roll, pitch, yaw)
        self.pos[0] = fix.lat_rad
        self.pos[1] = fix.lon_rad
        self.pos[2] = fix.alt_m
        self.vel_n[0] = fix.vel_n
        self.vel_n[1] = fix.vel_e
        self.vel_n[2] = fix.vel_d if math.isfinite(fix.vel_d) else 0.0
        for aid in self.aids:
            aid.start(self, fix)
        self.bias_g[:] = c.imu.gyro_bias
        self.bias_a[:] = c.imu.accel_bias
        P = self.P
        P[:, :] = 0.0
        tilt_sd = c.init.tilt_sd if self._level_static else max(c.init.tilt_sd, 5.0 * math.pi
                                                                   / 180.0)
        if not self._level_static:
            self.counters["level_not_static"] += 1
        g = max(math.sqrt(fx * fx + fy * fy + fz * fz), 0.5 * G0)
        # a tilt_sd below the mean's own noise would claim a levelling better than the data
        # allow (noise_x3 after 1 s: 5.3 deg against 2)
        tilt_sd = max(tilt_sd, self._level_scatter_sd())
        heading_sd = c.init.heading_sd if yaw_known else math.inf
        level_cov(P, self.mat_nb, pitch, yaw, tilt_sd, heading_sd, c.imu.accel_bias_sd, g)
        P[3, 3] = P[4, 4] = P[5, 5] = c.init.vel_sd**2
        self._set_pos_var(c.init.pos_sd)
        P[9, 9] = P[10, 10] = P[11, 11] = c.imu.gyro_bias_sd**2
        if yaw_known:
            # a boat's learnt heading error starts here (aiding/course_learner.py)
            crs = self.gnss.course
            if src == "config":
                crs.yaw_known(float(P[2, 2]), yaw, fix.t_us * 1e-6, float(P[11, 11]))
            else:
                P[2, 2] = crs.yaw_set(float(P[2, 2]), 0.0, yaw, fix.vel_n, fix.vel_e,
                                      fix.t_us * 1e-6, float(P[11, 11]))
        self.imu_noise.close_window(self._q, self._level_static)
        self._stage = _NAV
        self.counters["nav_start"] += 1
        if self.yaw_bank is not None:
            self.yaw_bank.start(self)

    def _set_pos_var(self, sd_m: float) -> None:
        r_m, r_n = radii(self.pos[0])
        self.P[6, 6] = (sd_m / (r_m + self.pos[2])) ** 2
        self.P[7, 7] = (sd_m / ((r_n + self.pos[2]) * math.cos(self.pos[0]))) ** 2
        self.P[8, 8] = sd_m**2

    # ------------------------------------------------------------------ GNSS
    def _gnss_valid(self, g: GnssSample) -> bool:
        cnt = self.counters
        # NaN velocity components mean "not reported" (e.g. MAVLink GPS_RAW_INT has no
        # vertical velocity); they are handled in the update, and fail no range test
        bad = plausible.gnss_reason(g.lat_rad, g.lon_rad, g.alt_m, g.vel_n, g.vel_e, g.vel_d)
        if bad == "gnss_nonfinite":
            cnt["gnss_nonfinite"] += 1
            return False
        if g.fix_type < FixType.FIX_3D:
            cnt["gnss_no_fix"] += 1
            return False
        if bad is not None:
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

    def _gnss_start(self, g: GnssSample) -> bool:
        """A fix before navigation: feeds the start-up; True when navigation started."""
        cnt = self.counters
        if not (math.isfinite(g.vel_n) and math.isfinite(g.vel_e)):
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
        if (self._level_t >= self.cfg.init.level_time and self._fix_agreement >= 1
                and self._level_done(g)):
            self._start_nav(g)
            return True
        return False

    def _gnss_in_time(self, g: GnssSample) -> bool:
        """Whether a fix while navigating is still within reach of the history ring."""
        cnt = self.counters
        age_us = self.t_us - g.t_us
        if age_us > self._max_gnss_age_us:
            cnt["gnss_too_old"] += 1
            return False
        # A fix older than the newest IMU sample is linearised about the state at its own
        # time of validity (history ring), not at arrival.
        swapped = self.state_at(g.t_us)
        if swapped is None:
            cnt["gnss_too_old"] += 1
            return False
        if swapped:
            cnt["gnss_delayed"] += 1
            self.state_restore()
        return True

    # ------------------------------------------------------------------ outputs
    def solution(self) -> NavSolution:
        """The current navigation solution (allocates a small frozen object, not arrays)."""
        r, p, y, qw, qx, qy, qz, sr, sp, sy = attitude_outputs(self.mat_nb, self.P, self._M)
        # the IMU's axes are off the course-defined heading by the installation's error
        inst = self.gnss.course.installation_var
        sy = math.sqrt(sy * sy + inst)
        v = self.vel_n
        bg = self.bias_g
        ba = self.bias_a
        w = self.rate_b
        P = self.P
        lat, h = float(self.pos[0]), float(self.pos[2])
        r_m, r_n = radii(lat)
        # the position error states are (dL, dlambda, dh): rad, rad, m up -> metres N, E, D
        pos_sd = (math.sqrt(max(float(P[6, 6]), 0.0)) * (r_m + h),
                  math.sqrt(max(float(P[7, 7]), 0.0)) * (r_n + h) * math.cos(lat),
                  math.sqrt(max(float(P[8, 8]), 0.0)))
        vel_sd = (math.sqrt(max(float(P[3, 3]), 0.0)), math.sqrt(max(float(P[4, 4]), 0.0)),
                  math.sqrt(max(float(P[5, 5]), 0.0)))
        age = (self.t_us - self._last_gnss_t_us
               if self._last_gnss_t_us >= 0 and self.t_us >= 0 else -1)
        return NavSolution(
            t_us=self.t_us, quat_nb=(qw, qx, qy, qz), roll_rad=r, pitch_rad=p, yaw_rad=y,
            lat_rad=float(self.pos[0]), lon_rad=float(self.pos[1]), alt_m=float(self.pos[2]),
            vel_n=(float(v[0]), float(v[1]), float(v[2])), att_sd_rad=(sr, sp, sy),
            gyro_bias_rps=(float(bg[0]), float(bg[1]), float(bg[2])),
            accel_bias_mps2=(float(ba[0]), float(ba[1]), float(ba[2])),
            heading_aligned=self.heading_aligned,
            rate_b=(float(w[0]), float(w[1]), float(w[2])), pos_sd_m=pos_sd,
            vel_sd_mps=vel_sd, gnss_age_us=age, heading_resets=self.heading_resets,
            heading_initialised=self.heading_aligned or self.gnss.course.align.yaw_set,
            yaw_sd_installation_rad=math.sqrt(inst))

    @property
    def heading_resets(self) -> int:
        """Heading resets so far (:attr:`NavSolution.heading_resets`): yaw resets to the
        course, resets after a velocity lock-out (they widen and re-seed attitude), and
        restarts."""
        c = self.counters
        return (c.get("heading_reset", 0) + c.get("reset_lockout_vel", 0)
                + c.get("yaw_bank_realigned", 0) + max(self.restarts, 0))

    @property
    def heading_held(self) -> bool:
        """Whether the last GNSS epoch left the heading alone (at rest, MEMS gyro)."""
        return self.gnss.hold >= 0

    @property
    def course_status(self) -> str:
        """Why GNSS course is or is not used as heading now (status ``course_update``)."""
        return self.gnss.course.status

    @property
    def dov_field(self) -> DovField | None:
        return self.dov_aid.field

    @property
    def dov_on_grid(self) -> bool:
        return self.dov_aid.on_grid

    @dov_on_grid.setter
    def dov_on_grid(self, on: bool) -> None:
        self.dov_aid.on_grid = on

    def status(self) -> dict[str, object]:
        """Counters and aiding status for the status topic and logs."""
        out: dict[str, object] = {
            "initialized": self.initialized,
            "heading_aligned": self.heading_aligned,
            "mode": self.cfg.filter.mode,
            "robust": self.cfg.filter.robust,
            "profile": self.cfg.filter.profile,
        }
        for aid in self.aids:
            out.update(aid.status(self))
        if self.yaw_bank is not None:
            out.update(self.yaw_bank.status(self))
        out.update({
            # sensor-time age of the last GNSS fix used; None before the first (absent GNSS
            # shows as a growing age: the INS is coasting)
            "gnss_age_s": ((self.t_us - self._last_gnss_t_us) * 1e-6
                           if self._last_gnss_t_us >= 0 and self.t_us >= 0 else None),
            "counters": dict(self.counters),
            "gyro_bias_dph": [float(b) * 180.0 / math.pi * 3600.0 for b in self.bias_g],
            "accel_bias_mg": [float(b) / 9.80665e-3 for b in self.bias_a],
            "dov_arcsec": [float(self.dov[0]) * 206264.806, float(self.dov[1]) * 206264.806],
            # the rotor-drag coefficient F's multirotor model has learnt (kalman.multirotor_f),
            # 1/s; None on the other profiles
            "drag_per_s": (round(float(self._v.f_lp[7]), 3) if self._v.f_lp[6] > 0.0
                           else None),
        })
        return out

    def ecef_position(self) -> tuple[float, float, float]:
        return geodetic_to_ecef(float(self.pos[0]), float(self.pos[1]), float(self.pos[2]))
