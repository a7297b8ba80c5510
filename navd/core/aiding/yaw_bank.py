"""Heading from motion: a bank of yaw hypotheses weighted by GNSS velocity (issue 15).

A multirotor's GNSS course says nothing about its heading and a fixed-wing's differs from it
by the crab angle, but accelerations do: a horizontal specific force seen in the body frame
and the same acceleration seen by GNSS differ by exactly the yaw.  The bank
(:mod:`navd.core.aiding.yaw_bank_kernels` has the model) holds ``members`` small EKFs whose
yaw offsets start evenly spread over the circle; each is driven by the main filter's
attitude (tilt, and the gyro integrated with its bias estimates) and corrected by GNSS
horizontal velocity; a Gaussian sum weights them by likelihood.

What it does with that (docs/design.md §4.1), and why:

- weights change only while the horizontal specific force is large enough (``min_accel``):
  without it every hypothesis explains the data, and noise alone would pick one;
- the bank is *trusted* only after its composite sigma stayed below ``trust_sd`` and its
  composite yaw within ``agree`` of itself for ``agree_time`` of excited flight, never on one
  low-variance epoch (the EKF-GSF failure of PX4 PR #28014, whose variance collapsed onto a
  wrong yaw within a second);
- a trusted bank starts a *trial*: the main heading is set from the bank with a sigma of
  at least ``aligned_sd``, and the heading is declared aligned only if the main filter's own
  velocity innovations over the next ``trial_epochs`` excited epochs are chi-square
  consistent; otherwise the heading goes back to unknown and the bank starts over;
- while the heading is unaligned the main filter's GNSS updates leave its yaw alone
  (Schmidt consider state, as the heading hold at rest), so a wrong linearised yaw cannot
  corrupt tilt and biases, nor shrink the yaw sigma into a false "aligned";
- once aligned, the bank keeps watching: if it stays trusted and disagrees with the main
  heading beyond 3 sigma of both for ``agree_time``, the heading is reset to the bank, marked
  unaligned, the gyro-bias sigma widened to the drift seen, and a new trial decides.

Allocation-free in steady state: scalars live in arrays, the kernels are compiled.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from navd.config import EstimatorConfig
from navd.core import state as st
from navd.core.aiding import yaw_bank_kernels as yk
from navd.core.aiding.base import INNOV_FLAG, INNOV_NIS, INNOV_VEL, NOT_TRIED
from navd.core.chi2 import chi2_quantile
from navd.core.earth import radii
from navd.types import GnssSample

if TYPE_CHECKING:
    from navd.core.estimator import Estimator

Arr = npt.NDArray[np.float64]

SEARCH = 0
TRIAL = 1
ALIGNED = 2
STATE_NAMES = ("search", "trial", "aligned")

_DEFAULT_VEL_ACC = 0.5  # m/s, as the GNSS aid when the receiver gives none
_DEFAULT_H_ACC = 5.0  # m
_G = 9.80665  # m/s^2, what a tilt error turns into horizontal specific force

# scalar state (self._s)
_STATE = 0
_AGREE_T0 = 1  # t_us the present agreement window started (-1: none)
_AGREE_REF = 2  # composite offset at its start (rad)
_AGREE_N = 3  # excited epochs in it
_TRIAL_T0 = 4
_TRIAL_NIS = 5  # sum of the main filter's velocity NIS over the trial's excited epochs
_TRIAL_N = 6
_DIS_T0 = 7  # t_us main and bank started to disagree (-1: they agree)
_LAST_AGREE_T = 8  # t_us main and bank last agreed
_RESULT = 9  # last bank_fix result
_ALIGNED_T = 10  # t_us of the last alignment
_SD_V = 11  # the last fix's per-axis horizontal speed sigma (m/s)
_HOLD_TILT = 12  # 1: this epoch's GNSS updates leave tilt and IMU biases alone (holds_tilt)
_ALIGNED_SD = 13  # the main heading's sigma when the last trial ended in alignment (rad)
_TRIAL_TRUSTED = 14  # 1: the bank has been trusted (sigma <= trust_sd) during this trial
_NS = 15


def bank_enabled(cfg: EstimatorConfig) -> bool:
    """Whether the estimator runs a yaw bank: ``[yaw_bank] enabled``, where "auto" means the
    multirotor profile (its course says nothing about heading) and the fixed_wing profile
    (its course differs from its heading by the crab angle; turns show the heading).
    fixed_wing_wind, 100 seeds: aligned <= 7.6 s after the first turn, 0 aligned > 10 deg
    off, 1.12 deg RMS, 0 % beyond 3 sigma, where the course checks alone align after ~63 s
    (docs/results.md, session 2026-11-26); "on" enables it for any profile."""
    e = cfg.yaw_bank.enabled
    return e == "on" or (e == "auto" and cfg.filter.profile in ("multirotor", "fixed_wing"))


class YawBank:
    """The bank and its alignment logic, owned by the estimator (see the module doc)."""

    def __init__(self, cfg: EstimatorConfig) -> None:
        self.cfg = cfg
        c = cfg.yaw_bank
        self.c = c
        self.n = c.members
        self.buf = np.zeros(yk.SIZE)
        self._s = np.zeros(_NS)
        par = np.zeros(yk.N_PAR)
        par[yk.P_QV] = cfg.imu.accel_vrw ** 2
        par[yk.P_QA] = c.accel_noise ** 2
        par[yk.P_QD] = c.yaw_noise ** 2
        par[yk.P_QS] = c.gyro_scale_sd ** 2
        par[yk.P_QR] = c.rate_noise ** 2
        par[yk.P_QB] = c.accel_bias_noise ** 2
        par[yk.P_MINACC] = c.min_accel
        par[yk.P_TAU] = c.excitation_tau
        par[yk.P_NISCAP] = c.nis_cap
        par[yk.P_FLOOR] = c.weight_floor
        par[yk.P_D0] = math.pi / self.n
        par[yk.P_R0] = c.rate_sd
        par[yk.P_B0] = c.accel_bias_sd
        self._par = par
        # the kernels a trial or a reset needs run for the first time only when the bank is
        # trusted, mid-flight; compile (or load) them now, with the estimator, on scratch
        # buffers, so that an alignment never waits for numba
        yk.bank_rotate(np.zeros(yk.SIZE), 0.0)
        yk.rotate_main(np.zeros(st.SIZE), 0.0)
        self._trial_gate = [0.0] + [chi2_quantile(cfg.filter.gate_prob, 3 * k)
                                    for k in range(1, c.trial_epochs + 1)]
        self.reset()

    # ------------------------------------------------------------------ life cycle
    def reset(self) -> None:
        yk.bank_reset(self.buf, self.n)
        s = self._s
        s[:] = 0.0
        s[_AGREE_T0] = -1.0
        s[_DIS_T0] = -1.0
        s[_LAST_AGREE_T] = -1.0
        s[_RESULT] = yk.NOT_KEPT

    def start(self, est: Estimator) -> None:
        """Navigation started: a heading given by config or course is monitored, not
        searched for."""
        self.reset()
        self._s[_STATE] = ALIGNED if est.heading_aligned else SEARCH

    @property
    def state(self) -> int:
        return int(self._s[_STATE])

    @property
    def offset(self) -> float:
        """Composite yaw minus the main filter's yaw, rad."""
        return float(self.buf[yk.H_OFF])

    @property
    def sd(self) -> float:
        """Composite 1-sigma, rad."""
        return math.sqrt(max(float(self.buf[yk.H_VAR]), 0.0))

    @property
    def started(self) -> bool:
        return bool(self.buf[yk.H_TLAST] >= 0.0)

    def holds_heading(self, est: Estimator) -> bool:
        """Whether GNSS updates must leave the main yaw alone: unaligned and not in trial."""
        return self.c.hold_unaligned and not est.heading_aligned and self.state == SEARCH

    def holds_tilt(self, est: Estimator) -> bool:
        """Whether this epoch's GNSS updates must also leave tilt and the IMU biases alone
        (consider states): the heading is held (unknown) and the velocity error it can make
        over the interval, along the acceleration (:meth:`_heading_velocity_noise`), is at
        least the fix's own velocity sigma.  A wrong heading's velocity error persists from
        epoch to epoch while the turn or leg lasts; persistent is what tilt and
        accelerometer bias look like to the filter, and process noise cannot tell it
        otherwise.  Velocity and position still follow the fixes.  The test uses the IMU's
        horizontal velocity change in the main frame less three tilt sigmas' worth of it
        (g x tilt x T): a filter not yet levelled (5 deg at start, or thrown off by a bad
        fix) must not take its own tilt error for acceleration and so never level."""
        return bool(self._s[_HOLD_TILT] > 0.0) and self.holds_heading(est)

    # ------------------------------------------------------------------ per sample
    def imu(self, est: Estimator, t_us: int, dt: float) -> None:
        yk.bank_imu(self.buf, est.buf, float(t_us), dt)

    def before_fix(self, est: Estimator, g: GnssSample) -> None:
        """Bring the members to the fix's time and update them (before the main filter's
        update, whose yaw correction :meth:`main_turned` then accounts for)."""
        if not (math.isfinite(g.vel_n) and math.isfinite(g.vel_e)):
            self._s[_RESULT] = yk.NOT_KEPT
            return
        sd = (g.vel_acc_mps if g.vel_acc_mps > 0.0 and math.isfinite(g.vel_acc_mps)
              else _DEFAULT_VEL_ACC)
        sd = max(sd, self.cfg.gnss.min_vel_sd)
        self._s[_SD_V] = sd
        self._s[_HOLD_TILT] = 0.0
        res = yk.bank_fix(self.buf, est.buf, self._par, float(g.t_us),
                          0.5 * est.imu_dt_us + 1.0, g.vel_n, g.vel_e, sd)
        self._s[_RESULT] = res
        if res == yk.NOT_KEPT:
            est.counters["yaw_bank_fix_not_kept"] += 1
        elif res == yk.PREDICTED or res == yk.WEIGHTED:
            self._heading_velocity_noise(est)

    def _heading_velocity_noise(self, est: Estimator) -> None:
        """What the main filter's linear yaw column leaves out of its velocity covariance.

        A heading error psi turns the interval's horizontal velocity change dv (main frame)
        into the velocity error (Rz(psi) - I) dv.  The filter's F knows only its first-order
        part, psi x dv, across dv; the rest lies along dv, (cos psi - 1) |dv|, with
        c = E[(cos psi - 1)^2] = 3/2 - 2 exp(-s^2/2) + exp(-2 s^2)/2 for psi ~ N(0, s^2)
        (7e-4 at s = 10 deg, so nothing once the heading is known; 0.92 at s = 90 deg).
        Without it, an unknown heading's velocity error along an acceleration has nowhere to
        go but tilt and the accelerometer bias: a fixed-wing's first turn at 6 m/s^2 with
        the heading 128 deg off put 3 deg into its roll (seed 7 of fixed_wing_wind, roll
        then 3.6 sigma off), a multirotor's first leg 1.3 deg into its pitch (seed 47 of
        multirotor_manoeuvre; docs/results.md, issue 15).  Added to P before the main
        filter's update of the epoch, as process noise along dv.  Where the part of dv that
        three tilt sigmas cannot explain (a tilt error is no acceleration) can make a
        velocity error as large as the fix's sigma, the epoch's updates also leave tilt and
        the IMU biases alone (:meth:`holds_tilt`)."""
        var = float(est.P[2, 2])
        c = 1.5 - 2.0 * math.exp(-0.5 * var) + 0.5 * math.exp(-2.0 * var)
        if c <= 1e-9:
            return
        b = self.buf
        t = float(b[yk.H_DT])
        dn = float(b[yk.H_ACCN]) * t
        de = float(b[yk.H_ACCE]) * t
        dv = math.hypot(dn, de)
        # the part of dv that three tilt sigmas cannot explain decides the hold
        eff = dv - 3.0 * _G * t * math.sqrt(max(float(est.P[0, 0]), float(est.P[1, 1])))
        if eff > 0.0 and self.holds_heading(est) and c * eff * eff >= self._s[_SD_V] ** 2:
            self._s[_HOLD_TILT] = 1.0
        P = est.P
        P[3, 3] += c * dn * dn
        P[3, 4] += c * dn * de
        P[4, 3] += c * dn * de
        P[4, 4] += c * de * de

    def main_turned(self, d: float) -> None:
        """The main filter turned its yaw by ``d`` rad (an update or reset)."""
        if d != 0.0:
            yk.bank_rotate(self.buf, d)
            s = self._s
            s[_AGREE_REF] = yk.wrap(s[_AGREE_REF] - d)

    def after_fix(self, est: Estimator, g: GnssSample) -> None:
        """After the main filter's update of this epoch: trust, trial, alignment, watch."""
        s = self._s
        res = int(s[_RESULT])
        if res != yk.PREDICTED and res != yk.WEIGHTED:
            return
        if est.heading_aligned and s[_STATE] == SEARCH:
            s[_STATE] = ALIGNED  # aligned by another source (course with crab model)
        t = float(g.t_us)
        state = int(s[_STATE])
        c = self.c
        off = self.offset
        sd = self.sd
        trusted = sd <= c.trust_sd
        if state == SEARCH:
            if sd > c.trial_sd:
                s[_AGREE_T0] = -1.0
                return
            self._agree_step(t, off, res)
            if s[_AGREE_N] >= 1.0:
                # trusted and excited: try the bank's yaw in the main filter at once, while
                # the agreement over time is still being established
                self._begin_trial(est, t, g)
                est.counters["yaw_bank_trials"] += 1
            return
        p22 = float(est.P[2, 2])
        comb = math.sqrt(max(float(self.buf[yk.H_VAR]), 0.0) + p22)
        if state == TRIAL:
            # The bank's sigma past trial_sd contradicts the trial.  Below it, a bank that
            # is not trusted at present (never yet, or its sigma grew: a straight leg, or
            # members spreading in an excited epoch) only delays the verdict, and a bank that
            # moved while not trusted is still converging: the trial takes its new yaw and
            # the bank keeps its weights.  Only a trusted bank that moves contradicts itself
            # (its weights are then thrown away).  Failing on every widening, or on a move
            # before the bank was trusted, threw converged weights away: multirotor_manoeuvre
            # seeds 25, 36, 39, 47, 59 aligned 15-19 s after their first leg instead of ~5 s.
            if sd > max(1.5 * c.trust_sd, c.trial_sd):
                self._fail_trial(est, "yaw_bank_trial_failed_bank")
                return
            if trusted and s[_TRIAL_TRUSTED] == 0.0:
                # first trusted epoch of a trial started below trial_sd: the agreement over
                # time is counted from here, about where the converged bank now is (seed 59:
                # it had moved 15 deg towards the truth since the trial began, and the main
                # yaw, free in the trial, with it); a main yaw it does not agree with takes
                # the bank's
                s[_TRIAL_TRUSTED] = 1.0
                s[_AGREE_T0] = t
                s[_AGREE_REF] = off
                s[_AGREE_N] = 0.0
                if abs(off) > max(c.agree, 1.5 * sd):
                    self._restart_trial(est, t, g)
                    return
            if abs(yk.wrap(off - s[_AGREE_REF])) > max(c.agree, 1.5 * sd):
                if trusted:  # (and so marked trusted in this trial, just above)
                    self._fail_trial(est, "yaw_bank_trial_failed_bank")
                else:
                    s[_AGREE_T0] = -1.0
                    self._restart_trial(est, t, g)
                return
            self._agree_step(t, off, res)
            rec = est.innov[INNOV_VEL]
            if (res == yk.WEIGHTED and rec[INNOV_FLAG] != NOT_TRIED
                    and s[_TRIAL_N] < c.trial_epochs):
                nis = float(rec[INNOV_NIS])
                s[_TRIAL_NIS] += nis if math.isfinite(nis) else 1e6
                s[_TRIAL_N] += 1.0
            k = int(s[_TRIAL_N])
            timed_out = (t - s[_TRIAL_T0]) * 1e-6 > c.trial_timeout
            if k >= c.trial_epochs:
                if s[_TRIAL_NIS] > self._trial_gate[c.trial_epochs]:
                    self._fail_trial(est, "yaw_bank_trial_failed_nis")
                elif not trusted:
                    # started below trial_sd: the main filter agrees, the bank has not yet
                    # converged far enough to vouch for it
                    if timed_out:
                        self._fail_trial(est, "yaw_bank_trial_timeout")
                elif (t - s[_AGREE_T0]) * 1e-6 >= c.agree_time:
                    s[_STATE] = ALIGNED
                    s[_DIS_T0] = -1.0
                    s[_LAST_AGREE_T] = t
                    s[_ALIGNED_T] = t
                    s[_ALIGNED_SD] = math.sqrt(p22)
                    est.heading_aligned = True
                    est.counters["yaw_bank_aligned"] += 1
            elif timed_out:
                self._fail_trial(est, "yaw_bank_trial_timeout")
            return
        # aligned: watch for a main heading that left the bank
        if abs(off) <= 3.0 * comb:
            s[_LAST_AGREE_T] = t
        # a trusted bank more than 2 sigma (of both) away, or any bank more than 3: the
        # heading may be off by more than its sigma says; it is not called aligned until a
        # trusted bank agrees again (within 1.5 sigma) or resets it (3 sigma for agree_time,
        # below).  An untrusted bank counts too: its sigma (the members' spread included)
        # is honest, and hovering it keeps following the main yaw's drift with its rate
        # state while its sigma grows (quad123: the main yaw drifted ~1 deg/s for 300 s
        # with a 6-8 deg sigma, flagged aligned, while the bank, at 10-50 deg sigma, moved
        # away from it; docs/results.md, issue 15).  Agreeing again needs a trusted bank: a
        # wide one agrees with anything.
        if (trusted and abs(off) > max(2.0 * comb, c.agree)) or abs(off) > 3.0 * comb:
            if est.heading_aligned:
                est.heading_aligned = False
                est.counters["yaw_bank_suspect"] += 1
        elif p22 > max(c.max_aligned_sd, s[_ALIGNED_SD]) ** 2:
            # honest but grown too wide to be called aligned (a fixed wing's straight legs
            # between the turns that observe its heading): above max_aligned_sd, or above
            # the sigma the trial ended with, whichever is larger
            if est.heading_aligned:
                est.heading_aligned = False
                est.counters["yaw_bank_sd_unflagged"] += 1
        elif not est.heading_aligned and trusted and abs(off) <= 1.5 * comb:
            est.heading_aligned = True
        if trusted and abs(off) > max(3.0 * comb, c.agree):
            if s[_DIS_T0] < 0.0:
                s[_DIS_T0] = t
            elif (t - s[_DIS_T0]) * 1e-6 >= c.agree_time:
                self._realign(est, t, off, g)
        else:
            s[_DIS_T0] = -1.0

    def _agree_step(self, t: float, off: float, res: int) -> None:
        """The agreement window: restarted whenever the composite yaw moves more than
        ``agree`` (or 1.5 of its sigmas, while it still converges) from where the window
        began (its reference turns with the main yaw)."""
        s = self._s
        if (s[_AGREE_T0] < 0.0
                or abs(yk.wrap(off - s[_AGREE_REF])) > max(self.c.agree, 1.5 * self.sd)):
            s[_AGREE_T0] = t
            s[_AGREE_REF] = off
            s[_AGREE_N] = 0.0
        if res == yk.WEIGHTED:
            s[_AGREE_N] += 1.0

    # ------------------------------------------------------------------ actions
    def _set_main_yaw(self, est: Estimator, d: float, var: float) -> None:
        """Turn the main attitude by d (about down), its yaw variance to var, no yaw
        correlations left (the yaw is new information).

        The tilt error is a navigation-frame vector: turning the attitude by d turns it
        too (C_hat' = Rz(d) Exp(-phi) C = Exp(-Rz(d) phi) Rz(d) C), so the rows and columns
        of roll/pitch error in P turn with it.  Left as they were, their correlation with
        the body-frame accelerometer bias (levelling makes g x tilt + bias known, either
        alone not) belongs to a heading up to 180 deg away, and the next accelerations
        "separate" tilt from bias with information that is not there: seed 47 of
        multirotor_manoeuvre, pitch 3.5 deg off at a 0.45 deg sigma after its trial
        (docs/results.md, issue 15).  Velocity (also navigation-frame) turns the same way
        before the trial moves it onto the fix."""
        yk.rotate_main(est.buf, d)
        yk.bank_rotate(self.buf, d)
        self._s[_AGREE_REF] = yk.wrap(self._s[_AGREE_REF] - d)
        P = est.P
        c = math.cos(d)
        sn = math.sin(d)
        for a in (0, 3):  # tilt N/E, velocity N/E: rows then columns, P <- R P R^T
            b = a + 1
            for k in range(15):
                x = float(P[a, k])
                y = float(P[b, k])
                P[a, k] = c * x - sn * y
                P[b, k] = sn * x + c * y
            for k in range(15):
                x = float(P[k, a])
                y = float(P[k, b])
                P[k, a] = c * x - sn * y
                P[k, b] = sn * x + c * y
        P[2, :] = 0.0
        P[:, 2] = 0.0
        P[2, 2] = var

    def _begin_trial(self, est: Estimator, t: float, g: GnssSample) -> None:
        s = self._s
        if s[_AGREE_T0] < 0.0:
            s[_AGREE_T0] = t
            s[_AGREE_REF] = self.offset
            s[_AGREE_N] = 0.0
        var = max(float(self.buf[yk.H_VAR]), self.c.aligned_sd ** 2)
        self._set_main_yaw(est, self.offset, var)
        self._main_onto_fix(est, g)
        s[_STATE] = TRIAL
        s[_TRIAL_T0] = t
        s[_TRIAL_NIS] = 0.0
        s[_TRIAL_N] = 0.0
        s[_TRIAL_TRUSTED] = 1.0 if self.sd <= self.c.trust_sd else 0.0

    def _restart_trial(self, est: Estimator, t: float, g: GnssSample) -> None:
        """The trial again from the bank's present yaw, the bank's weights kept; the
        timeout still runs from the first start, so a bank that keeps moving below
        trial_sd without ever being trusted fails after trial_timeout."""
        t0 = float(self._s[_TRIAL_T0])
        self._begin_trial(est, t, g)
        self._s[_TRIAL_T0] = t0
        est.counters["yaw_bank_trial_restarted"] += 1

    def _fail_trial(self, est: Estimator, reason: str) -> None:
        s = self._s
        est.counters[reason] += 1
        est.heading_aligned = False
        P = est.P
        P[2, :] = 0.0
        P[:, 2] = 0.0
        P[2, 2] = (math.pi / 2.0) ** 2
        s[_STATE] = SEARCH
        s[_AGREE_T0] = -1.0
        # the bank's confident answer did not survive the main filter: let it start over
        # from its present members with equal weights
        for i in range(self.n):
            o = yk.MEM + i * yk.MW
            self.buf[o + yk.M_LW] = 0.0
            self.buf[o + yk.M_W] = 1.0 / self.n
        yk.composite(self.buf)

    def _main_onto_fix(self, est: Estimator, g: GnssSample) -> None:
        """With its yaw in doubt the main filter propagated its horizontal velocity and
        position with a wrong heading (or without updates): now that the heading is new,
        move both onto this epoch's fix (lever arm removed with the new attitude) with the
        fix's accuracy and no correlations, as the lock-out recovery does."""
        m = est.mat_nb
        lb = est.cfg.gnss.lever_arm
        w = est.rate_b
        ux = w[1] * lb[2] - w[2] * lb[1]
        uy = w[2] * lb[0] - w[0] * lb[2]
        uz = w[0] * lb[1] - w[1] * lb[0]
        P = est.P
        sd_v = float(self._s[_SD_V])
        est.vel_n[0] = g.vel_n - (m[0, 0] * ux + m[0, 1] * uy + m[0, 2] * uz)
        est.vel_n[1] = g.vel_e - (m[1, 0] * ux + m[1, 1] * uy + m[1, 2] * uz)
        for k in (3, 4):
            P[k, :] = 0.0
            P[:, k] = 0.0
            P[k, k] = sd_v * sd_v
        h_sd = g.h_acc_m if g.h_acc_m > 0.0 and math.isfinite(g.h_acc_m) else _DEFAULT_H_ACC
        h_sd = max(h_sd, self.cfg.gnss.min_pos_sd)
        h = float(est.pos[2])
        r_m, r_n = radii(g.lat_rad)
        ln = m[0, 0] * lb[0] + m[0, 1] * lb[1] + m[0, 2] * lb[2]
        le = m[1, 0] * lb[0] + m[1, 1] * lb[1] + m[1, 2] * lb[2]
        est.pos[0] = g.lat_rad - ln / (r_m + h)
        est.pos[1] = g.lon_rad - le / ((r_n + h) * math.cos(g.lat_rad))
        for k in (6, 7):
            P[k, :] = 0.0
            P[:, k] = 0.0
        P[6, 6] = (h_sd / (r_m + h)) ** 2
        P[7, 7] = (h_sd / ((r_n + h) * math.cos(g.lat_rad))) ** 2
        st.history_reset(est.buf)

    def _realign(self, est: Estimator, t: float, off: float, g: GnssSample) -> None:
        """The main heading left a trusted bank: its own sigma did not cover its error.
        Reset it to the bank, clear "aligned" and let a new trial decide.  (Widening the
        gyro-bias sigma to the drift seen was tried: with a noisy accelerometer a bank that
        is itself a few sigma off then drags the bias estimate away, and tilt with it.)"""
        s = self._s
        est.heading_aligned = False
        est.counters["yaw_bank_realigned"] += 1
        s[_AGREE_T0] = -1.0
        self._begin_trial(est, t, g)
        s[_DIS_T0] = -1.0

    # ------------------------------------------------------------------ status
    def status(self, est: Estimator) -> dict[str, object]:
        b = self.buf
        yaw = math.atan2(float(est.mat_nb[1, 0]), float(est.mat_nb[0, 0]))
        s = self._s
        agree = ((est.t_us - s[_AGREE_T0]) * 1e-6
                 if s[_AGREE_T0] >= 0.0 and self.state == SEARCH else 0.0)
        return {"yaw_bank": {
            "state": STATE_NAMES[self.state] if self.started else "waiting: no GNSS velocity",
            "yaw_deg": round(math.degrees(yk.wrap(yaw + self.offset)), 2),
            "sd_deg": round(math.degrees(self.sd), 2),
            "offset_deg": round(math.degrees(self.offset), 2),
            "excitation_mps2": round(float(b[yk.H_EXC]), 3),
            "agree_s": round(agree, 2),
            "members_yaw_deg": [round(math.degrees(yk.wrap(yaw + float(b[yk.MEM + i * yk.MW
                                                                            + 2]))), 1)
                                for i in range(self.n)],
            "weights": [round(float(b[yk.MEM + i * yk.MW + yk.M_W]), 4) for i in range(self.n)],
        }}
