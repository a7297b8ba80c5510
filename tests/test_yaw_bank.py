"""The yaw bank (heading from motion, issue 15): its kernels against finite differences and
a textbook EKF, convergence from every yaw, no alignment without horizontal acceleration,
an unknown heading in a turn not taken for tilt, and allocation-freedom
(navd/core/aiding/yaw_bank.py)."""

from __future__ import annotations

import math
from functools import cache

import numpy as np
import pytest

from firmware_sim import SimRun, generate, load_scenario
from firmware_sim.alloc import measure_steps
from navd.config import EstimatorConfig, load_config
from navd.core.aiding import yaw_bank_kernels as yk
from navd.core.estimator import Estimator
from navd.core.rotation import mat_to_euler
from navd.types import GnssSample, ImuSample


def cfg(*overrides: str) -> EstimatorConfig:
    return EstimatorConfig.from_dict(load_config(None, ["yaw_bank.enabled=auto",
                                                        *overrides]))


@cache
def multirotor(seed: int, duration_s: float, yaw0_deg: float = 0.0) -> SimRun:
    return generate(load_scenario("multirotor", {"duration_s": duration_s,
                                                 "trajectory.yaw0_deg": yaw0_deg}),
                    seed=seed, progress=False)


def _fd_jacobian(fn: object, x: np.ndarray, m: int, *args: float) -> np.ndarray:
    out_p = np.zeros(m)
    out_m = np.zeros(m)
    J = np.zeros((m, 6))
    for k in range(6):
        h = 1e-6
        xp = x.copy()
        xm = x.copy()
        xp[k] += h
        xm[k] -= h
        fn(xp, *args, out_p)  # type: ignore[operator]
        fn(xm, *args, out_m)  # type: ignore[operator]
        J[:, k] = (out_p - out_m) / (2 * h)
    return J


@pytest.mark.parametrize("d", [-2.9, -1.0, 0.0, 0.4, 2.2])
def test_member_kernels_match_finite_difference_jacobians_and_a_textbook_ekf(d: float) -> None:
    """GIVEN a member state (vN, vE, d, r, bN, bE) with a random covariance, a specific-force
    increment a over T and a lever-arm velocity u (main frame),
    WHEN predict_member and update_member run in the bank buffer,
    THEN the predicted state is f(x) and its covariance F P F^T + Q (F's offset column on
    the increment's part above its noise, sqrt(1 - 2 q_n / |a|^2) of it), and the updated
    state/covariance/NIS are the textbook EKF's, with F and H the central-difference
    Jacobians of the nonlinear model (member_f, member_h), to 1e-7 relative."""
    rng = np.random.default_rng(int(1000 * (d + 3)))
    x = np.array([1.3, -0.7, d, 0.004, 0.05, -0.08])
    A = rng.normal(size=(6, 6))
    P = A @ A.T * 0.05 + np.diag([0.01, 0.01, 0.2, 1e-4, 0.1, 0.1])
    a_n, a_e, u_n, u_e, T = 0.31, -0.22, 0.4, 0.9, 0.2
    q_v, q_d, q_r, q_b, r = 0.003, 1e-4, 1e-6, 1e-3, 0.02
    bb = np.zeros(yk.SIZE)
    o = yk.MEM
    n = yk.NX
    bb[o:o + n] = x
    bb[o + yk.M_P:o + yk.M_P + n * n] = P.ravel()
    q_n = 0.004
    yk.predict_member(bb, o, a_n, a_e, T, q_v, q_d, q_r, q_b, q_n)
    F = _fd_jacobian(yk.member_f, x, 6, a_n, a_e, T)
    fx = np.zeros(6)
    yk.member_f(x, a_n, a_e, T, fx)
    q_ve = q_v + P[2, 2] * q_n  # the measured increment's noise turned by the offset
    # the covariance's Jacobian turns only the increment's part above its noise with d
    Fc = F.copy()
    Fc[0:2, 2] *= math.sqrt(1.0 - 2.0 * q_n / (a_n * a_n + a_e * a_e))
    Pp = Fc @ P @ Fc.T + np.diag([q_ve, q_ve, q_d, q_r, q_b, q_b])
    np.testing.assert_allclose(bb[o:o + n], fx, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(bb[o + yk.M_P:o + yk.M_P + n * n].reshape(n, n), Pp,
                               rtol=1e-7, atol=1e-12)
    # update with a measured antenna velocity
    vn, ve = fx[0] + 0.2, fx[1] - 0.1
    yk.update_member(bb, o, vn, ve, u_n, u_e, r, False)
    H = _fd_jacobian(yk.member_h, fx, 2, u_n, u_e)
    hx = np.zeros(2)
    yk.member_h(fx, u_n, u_e, hx)
    S = H @ Pp @ H.T + r * np.eye(2)
    K = Pp @ H.T @ np.linalg.inv(S)
    zz = np.array([vn, ve]) - hx
    x_ref = fx + K @ zz
    P_ref = Pp - K @ S @ K.T
    np.testing.assert_allclose(bb[o:o + 2], x_ref[:2], rtol=1e-7, atol=1e-10)
    assert abs(yk.wrap(bb[o + 2] - x_ref[2])) < 1e-9
    np.testing.assert_allclose(bb[o + 3:o + n], x_ref[3:], rtol=1e-7, atol=1e-12)
    np.testing.assert_allclose(bb[o + yk.M_P:o + yk.M_P + n * n].reshape(n, n), P_ref,
                               rtol=1e-6, atol=1e-10)
    assert bb[o + yk.M_NIS] == pytest.approx(float(zz @ np.linalg.solve(S, zz)), rel=1e-7)


def _run(run: SimRun, est: Estimator) -> list[tuple[float, float, float, bool]]:
    """Push every sample; per GNSS epoch (t_s, bank yaw error, bank sigma, aligned), rad."""
    t0 = int(run.truth_t_us[0])
    dtt = int(run.truth_t_us[1] - run.truth_t_us[0])
    out = []
    yb = est.yaw_bank
    assert yb is not None
    for s in run.samples():
        est.push(s)
        if isinstance(s, GnssSample) and est.initialized and yb.started:
            k = (est.t_us - t0) // dtt
            yaw = mat_to_euler(est.mat_nb)[2]
            err = yk.wrap(yaw + yb.offset - float(run.truth_euler[k, 2]))
            out.append((s.t_us * 1e-6, err, yb.sd, est.heading_aligned))
    return out


@cache
def consumer(scenario: str, seed: int, duration_s: float = 0.0,
             yaw0_deg: float | None = None) -> SimRun:
    """A consumer-IMU scenario of issue 15; with ``yaw0_deg`` the per-seed randomisation is
    off and the nose starts there."""
    ov: dict[str, object] = {}
    if duration_s > 0.0:
        ov["duration_s"] = duration_s
    if yaw0_deg is not None:
        ov["randomize.enabled"] = False
        ov["trajectory.yaw0_deg"] = yaw0_deg
    return generate(load_scenario(scenario, ov), seed=seed, progress=False)


def _aligned_errors(run: SimRun, est: Estimator) -> tuple[np.ndarray, np.ndarray,
                                                          np.ndarray, np.ndarray]:
    """(t_s, heading error, heading sigma, aligned) at every GNSS epoch while navigating,
    rad; the estimator's own yaw and 1-sigma."""
    t0 = int(run.truth_t_us[0])
    dtt = int(run.truth_t_us[1] - run.truth_t_us[0])
    rows = []
    for s in run.samples():
        est.push(s)
        if isinstance(s, GnssSample) and est.initialized:
            k = (est.t_us - t0) // dtt
            sol = est.solution()
            err = yk.wrap(sol.yaw_rad - float(run.truth_euler[k, 2]))
            rows.append((s.t_us * 1e-6, err, sol.att_sd_rad[2], float(sol.heading_aligned)))
    a = np.array(rows)
    return a[:, 0], a[:, 1], a[:, 2], a[:, 3] > 0.5


@pytest.mark.parametrize("yaw0_deg", [-157.5, -112.5, -67.5, -22.5, 22.5, 67.5, 112.5, 157.5])
def test_bank_converges_from_every_starting_yaw(yaw0_deg: float) -> None:
    """GIVEN the multirotor_manoeuvre scenario (consumer IMU; first leg north at 30 s)
    flown with the nose anywhere on the circle while the filter starts at yaw 0,
    WHEN its first 60 s run with the default config's multirotor profile,
    THEN the heading is aligned within 10 s of the first leg's start, and at every aligned
    epoch its error is below 10 deg and within 3 of the reported sigmas."""
    run = consumer("multirotor_manoeuvre", 1, 60.0, yaw0_deg)
    e = Estimator(cfg("filter.profile=multirotor"))
    t, err, sd, aligned = _aligned_errors(run, e)
    assert aligned.any()
    assert t[aligned][0] < 40.0
    assert np.all(np.abs(err[aligned]) < math.radians(10.0))
    assert np.all(np.abs(err[aligned]) < 3.0 * sd[aligned])


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_acceleration_sign_changes_make_no_false_alignment(seed: int) -> None:
    """GIVEN accel_sign_change (PX4 PR #28014's case: back and forth along one line at
    2.7 m/s^2, three sign changes inside 1.2 s GNSS gaps; consumer IMU, random yaw),
    WHEN it runs with the multirotor profile,
    THEN the heading is aligned within 10 s of the first leg (25 s), never aligned with an
    error above 10 deg, and no more than 5 % of aligned epochs are beyond 3 sigma."""
    run = consumer("accel_sign_change", seed)
    e = Estimator(cfg("filter.profile=multirotor"))
    t, err, sd, aligned = _aligned_errors(run, e)
    assert aligned.any() and t[aligned][0] < 35.0
    assert not np.any(np.abs(err[aligned]) > math.radians(10.0))
    assert np.mean(np.abs(err[aligned]) > 3.0 * sd[aligned]) <= 0.05


def test_multirotor_profile_aligns_and_stays_within_3_sigma() -> None:
    """GIVEN the multirotor_manoeuvre scenario (seed 4: consumer IMU, its own yaw, legs,
    gyro and accelerometer offsets), 180 s,
    WHEN it runs with the default config's multirotor profile,
    THEN the heading is aligned from the first leg on and stays aligned, never more than
    10 deg off while aligned, and at most 5 % of the aligned epochs beyond 3 sigma."""
    run = consumer("multirotor_manoeuvre", 4)
    e = Estimator(cfg("filter.profile=multirotor"))
    t, err, sd, aligned = _aligned_errors(run, e)
    k = int(np.argmax(aligned))
    assert aligned[k] and t[k] < 45.0
    assert aligned[k:].all()
    assert np.all(np.abs(err[aligned]) < math.radians(10.0))
    assert np.mean(np.abs(err[aligned]) > 3.0 * sd[aligned]) <= 0.05


@pytest.mark.parametrize("seed", [42, 63])
def test_fixed_wing_default_aligns_in_turns_and_unflags_a_widening_heading(seed: int) -> None:
    """GIVEN fixed_wing_wind seeds 42 and 63 (consumer IMU, 3-10 m/s wind, crab up to 30 deg;
    with the bank on before the sigma rule they were flagged aligned while 10-11 deg off at a
    6.7-8.3 deg sigma on the straight legs between turns),
    WHEN they run with the default config's fixed_wing profile (bank on by default),
    THEN the bank runs, the heading is aligned within 10 s of the first turn (15 s), never
    more than 10 deg off while aligned, and the flag is dropped at least once for a sigma
    grown past max_aligned_sd (counted)."""
    run = consumer("fixed_wing_wind", seed)
    e = Estimator(cfg("filter.profile=fixed_wing"))
    assert e.yaw_bank is not None
    t, err, sd, aligned = _aligned_errors(run, e)
    assert aligned.any() and t[aligned][0] < 25.0
    assert np.all(np.abs(err[aligned]) < math.radians(10.0))
    assert np.all(sd[aligned] <= math.radians(6.0) + 1e-9)
    assert e.counters.get("yaw_bank_sd_unflagged", 0) >= 1


@pytest.mark.parametrize("seed", [3, 12])
def test_a_turn_at_unknown_heading_is_not_taken_for_tilt(seed: int) -> None:
    """GIVEN fixed_wing_wind's first 25 s (consumer IMU, straight and level, then the first
    turn at up to 6 m/s^2 from 15 s while the heading is still unknown, then the bank's trial
    and alignment), bank on,
    WHEN it runs with the fixed_wing profile,
    THEN the velocity error the unknown heading makes along the turn's acceleration is not
    taken for tilt: roll and pitch stay within 3 of their sigmas at every GNSS epoch, and some
    epochs held tilt and the IMU biases (counter yaw_bank_tilt_held).  (Before the bank's heading
    velocity noise and tilt hold these seeds' roll or pitch left 3 sigma in this window, 3.2
    and 4.5 sigma; seeds 1, 7 and 13 still do after alignment: docs/results.md, issue 15.)"""
    run = consumer("fixed_wing_wind", seed, 25.0)
    e = Estimator(cfg("filter.profile=fixed_wing", "yaw_bank.enabled=on"))
    t0 = int(run.truth_t_us[0])
    dtt = int(run.truth_t_us[1] - run.truth_t_us[0])
    worst = 0.0
    for s in run.samples():
        e.push(s)
        if isinstance(s, GnssSample) and e.initialized:
            k = (e.t_us - t0) // dtt
            err = np.array(mat_to_euler(e.mat_nb)) - run.truth_euler[k]
            err = (err + math.pi) % (2.0 * math.pi) - math.pi
            sd = e.solution().att_sd_rad
            worst = max(worst, abs(err[0]) / sd[0], abs(err[1]) / sd[1])
    assert e.counters.get("yaw_bank_tilt_held", 0) > 0
    assert e.counters.get("yaw_bank_trials", 0) > 0
    assert worst <= 3.0


@pytest.mark.parametrize("seed", [19, 47])
def test_the_formerly_false_seeds_stay_within_10_deg(seed: int) -> None:
    """GIVEN multirotor_manoeuvre seeds 19 and 47 (consumer IMU; the two seeds of 100 that
    were flagged aligned more than 10 deg off: their trial turned the heading by ~150 deg
    while the roll/pitch rows of P kept the accelerometer-bias correlation of the old
    heading, and pitch then went 3.5 deg off at a 0.45 deg sigma),
    WHEN they run with the default multirotor profile,
    THEN they align, are never more than 10 deg off while aligned, and at most 5 % of the
    aligned epochs are beyond 3 sigma."""
    run = consumer("multirotor_manoeuvre", seed)
    e = Estimator(cfg("filter.profile=multirotor"))
    _, err, sd, aligned = _aligned_errors(run, e)
    assert aligned.any()
    assert np.all(np.abs(err[aligned]) < math.radians(10.0))
    assert np.mean(np.abs(err[aligned]) > 3.0 * sd[aligned]) <= 0.05


@pytest.mark.parametrize("seed", [47, 59])
def test_a_short_first_acceleration_aligns_within_10_s(seed: int) -> None:
    """GIVEN multirotor_manoeuvre seeds 47 and 59 (consumer IMU): the first leg accelerates
    for ~3 s from 31.25 s, then cruises until ~46 s; the bank's sigma reaches trust_sd only
    as that acceleration ends, and on the way it moves ~15 deg towards the truth,
    WHEN their first 60 s run with the default multirotor profile,
    THEN the heading is aligned within 10 s of the first acceleration >= 1 m/s^2 (the
    issue-15 target; seed 47 took 15.6 s when a trial began only at trust_sd, seed 59
    18.6 s when a trial begun below trial_sd failed on a move made before the bank was
    trusted), within 10 deg and 3 sigma while aligned."""
    run = consumer("multirotor_manoeuvre", seed, 60.0)
    acc = np.diff(run.truth_vel_n[:, :2], axis=0) / run.imu_dt_s
    k = int(np.flatnonzero(np.hypot(acc[:, 0], acc[:, 1]) >= 1.0)[0])
    t_man = (run.truth_t_us[k] - run.truth_t_us[0]) * 1e-6
    e = Estimator(cfg("filter.profile=multirotor"))
    t, err, sd, aligned = _aligned_errors(run, e)
    assert aligned.any()
    t_al = t[aligned][0] - run.truth_t_us[0] * 1e-6
    assert t_al - t_man <= 10.0
    assert np.all(np.abs(err[aligned]) < math.radians(10.0))
    assert np.all(np.abs(err[aligned]) < 3.0 * sd[aligned])


def test_a_restarted_trial_keeps_its_first_start_for_the_timeout() -> None:
    """GIVEN the multirotor_manoeuvre scenario after 35 s (the bank has run a trial) with a
    trial that began 31 s ago and was never trusted,
    WHEN the trial restarts on the bank's new yaw (a bank still converging moved),
    THEN the trial goes on (state TRIAL, counted as restarted) but its start time, which the
    trial_timeout (30 s) runs from, is the first one, not now: a bank that keeps moving
    below trial_sd can restart it only until then."""
    from navd.core.aiding import yaw_bank as yb_mod

    run = consumer("multirotor_manoeuvre", 1, 36.0)
    e = Estimator(cfg("filter.profile=multirotor"))
    last = None
    for smp in run.samples():
        e.push(smp)
        if isinstance(smp, GnssSample):
            last = smp
    yb = e.yaw_bank
    assert yb is not None and last is not None and e.initialized
    s = yb._s
    t = float(last.t_us)
    s[yb_mod._STATE] = yb_mod.TRIAL
    s[yb_mod._TRIAL_T0] = t - 31e6
    s[yb_mod._TRIAL_TRUSTED] = 0.0
    n0 = e.counters["yaw_bank_trial_restarted"]
    yb._restart_trial(e, t, last)
    assert s[yb_mod._STATE] == yb_mod.TRIAL
    assert s[yb_mod._TRIAL_T0] == t - 31e6
    assert s[yb_mod._TRIAL_N] == 0.0
    assert e.counters["yaw_bank_trial_restarted"] == n0 + 1


@pytest.mark.parametrize("d", [0.3, -2.6, math.pi])
def test_a_bank_heading_reset_turns_the_tilt_and_velocity_covariance(d: float) -> None:
    """GIVEN an estimator whose P is a random covariance (tilt correlated with everything,
    the accelerometer bias among it),
    WHEN the bank turns the main heading by d (its trial or realignment),
    THEN the roll/pitch and north/east velocity rows and columns of P are turned by Rz(d)
    (navigation-frame errors turn with the attitude), the yaw row is the new variance alone,
    the body-frame blocks are untouched, and P stays symmetric positive definite."""
    e = Estimator(cfg("filter.profile=multirotor"))
    yb = e.yaw_bank
    assert yb is not None
    rng = np.random.default_rng(5)
    a = rng.normal(size=(15, 15))
    P0 = a @ a.T + 15.0 * np.eye(15)
    e.P[:, :] = P0
    yb._set_main_yaw(e, d, 0.01)
    T = np.eye(15)
    c, s = math.cos(d), math.sin(d)
    for i in (0, 3):
        T[i:i + 2, i:i + 2] = [[c, -s], [s, c]]
    want = T @ P0 @ T.T
    want[2, :] = 0.0
    want[:, 2] = 0.0
    want[2, 2] = 0.01
    np.testing.assert_allclose(e.P, want, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(e.P[9:, 9:], P0[9:, 9:])
    assert np.all(np.linalg.eigvalsh(e.P) > 0.0)


def test_no_alignment_in_hover_without_horizontal_acceleration() -> None:
    """GIVEN the multirotor scenario's first 34 s (levelling, climb to hover, hover: no
    horizontal acceleration),
    WHEN it runs with the multirotor profile,
    THEN the bank never left its search (no trial), the heading is never aligned, and the
    heading sigma the filter reports stays above 45 deg (unknown, honestly)."""
    run = multirotor(3, 34.0)
    e = Estimator(cfg("filter.profile=multirotor"))
    rows = _run(run, e)
    assert len(rows) > 100
    assert not any(r[3] for r in rows)
    assert e.counters.get("yaw_bank_trials", 0) == 0
    assert e.yaw_bank is not None and e.yaw_bank.state == 0
    assert math.degrees(e.solution().att_sd_rad[2]) > 45.0
    st = e.status()["yaw_bank"]
    assert isinstance(st, dict) and st["state"] == "search"


def test_an_unexcited_update_teaches_a_member_no_yaw() -> None:
    """GIVEN a member with a full covariance and an update with hold_yaw (the bank's
    unexcited epochs: the increment that F turns by the offset is noise there),
    WHEN update_member runs,
    THEN it equals a Schmidt-Kalman update computed independently in numpy (gain rows of
    offset and rate zeroed, P in Joseph form): offset and rate keep their value and their
    2x2 covariance, the rest is corrected, P stays symmetric positive definite.  Without
    the hold, 35 s of hover took every member's offset sigma from 22.5 to ~4.7 deg without
    moving it (multirotor seed 4), and the first leg's nearest member, 21 deg off, took all
    the weight at a 4 deg sigma."""
    rng = np.random.default_rng(7)
    x = np.array([1.3, -0.7, 0.4, 0.004, 0.05, -0.08])
    A = rng.normal(size=(6, 6))
    P = A @ A.T * 0.05 + np.diag([0.01, 0.01, 0.2, 1e-4, 0.1, 0.1])
    u_n, u_e, r = 0.4, 0.9, 0.02
    bb = np.zeros(yk.SIZE)
    o = yk.MEM
    n = yk.NX
    bb[o:o + n] = x
    bb[o + yk.M_P:o + yk.M_P + n * n] = P.ravel()
    vn, ve = 1.5, -0.8
    yk.update_member(bb, o, vn, ve, u_n, u_e, r, True)
    H = _fd_jacobian(yk.member_h, x, 2, u_n, u_e)
    hx = np.zeros(2)
    yk.member_h(x, u_n, u_e, hx)
    S = H @ P @ H.T + r * np.eye(2)
    K = P @ H.T @ np.linalg.inv(S)
    K[2:4, :] = 0.0
    ImKH = np.eye(n) - K @ H
    P_ref = ImKH @ P @ ImKH.T + r * K @ K.T
    x_ref = x + K @ (np.array([vn, ve]) - hx)
    got = bb[o + yk.M_P:o + yk.M_P + n * n].reshape(n, n)
    np.testing.assert_allclose(bb[o:o + n], x_ref, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(got, P_ref, rtol=1e-7, atol=1e-12)
    np.testing.assert_allclose(bb[o + 2:o + 4], x[2:4], rtol=0.0, atol=1e-15)
    np.testing.assert_allclose(got[2:4, 2:4], P[2:4, 2:4], rtol=1e-12, atol=0.0)
    assert np.all(np.linalg.eigvalsh(got) > 0.0) and np.allclose(got, got.T)


def test_the_gnss_excitation_noise_floor_is_what_white_velocity_noise_gives() -> None:
    """GIVEN bank_fix fed fixes at rest (IMU increments zero) whose horizontal velocity is
    white noise with the stated per-axis sigma (0.1 m/s, 5 Hz; tau 0.5 s, so g = 0.4),
    WHEN 20,000 epochs run,
    THEN the low-passed GNSS acceleration's mean square matches 2 axes x (sigma^2 / T^2) x
    2 g^2 / (2 - g) within 5 %, and the kernel's excitation (that floor subtracted) is
    positive in e^-1 of the epochs (|LP|^2 of 2 white axes is exponential): the noise
    subtracted is the noise there is, so at rest the gate passes as rarely as the
    threshold says.  No epoch is weighed (the IMU side sees nothing)."""
    from navd.core import state as st
    from navd.core.aiding.yaw_bank import YawBank
    bank = YawBank(cfg("filter.profile=multirotor"))
    par = bank._par
    bb = np.zeros(yk.SIZE)
    yk.bank_reset(bb, bank.n)
    sb = np.zeros(st.SIZE)
    sb[st.MAT] = sb[st.MAT + 4] = sb[st.MAT + 8] = 1.0
    rng = np.random.default_rng(11)
    sd, T, dt_us = 0.1, 0.2, 5000
    g = min(1.0, T / bank.c.excitation_tau)
    floor = 2.0 * (sd * sd / (T * T)) * 2.0 * g * g / (2.0 - g)
    t = 0.0
    ms: list[float] = []
    above = 0
    weighed = 0
    for k in range(20_020):
        for _ in range(int(T * 1e6) // dt_us):
            t += dt_us
            yk.bank_imu(bb, sb, t, dt_us * 1e-6)
        res = yk.bank_fix(bb, sb, par, t, 1.0, rng.normal(0.0, sd), rng.normal(0.0, sd), sd)
        weighed += int(res == yk.WEIGHTED)
        if k >= 20:
            ms.append(bb[yk.H_GLPN] ** 2 + bb[yk.H_GLPE] ** 2)
            above += int(bb[yk.H_GEXC] > 0.0)  # the kernel's own floor subtracted
    m = np.asarray(ms)
    assert abs(m.mean() / floor - 1.0) < 0.05, (m.mean(), floor)
    assert abs(above / len(ms) - math.exp(-1.0)) < 0.02, above / len(ms)
    assert weighed == 0


def test_at_rest_the_bank_weighs_almost_no_epoch_and_its_members_keep_their_prior() -> None:
    """GIVEN the multirotor scenario's first 14.5 s, seeds 1-5 (the vehicle at rest on the
    ground: no acceleration at all, while the consumer accelerometer's noise and the
    levelling tilt make 0.3-2 m/s^2 of apparent horizontal specific force per 0.2 s epoch),
    WHEN it runs with the multirotor profile,
    THEN at most 3 % of the bank's epochs change its weights and the members' offset sigma
    stays near its 22.5 deg prior (median of the seeds' widest member >= 20 deg).  With the
    excitation judged on the IMU alone, 21.8 % of those epochs were weighed (seeds 1-10) and
    the offsets' sigma fell to a median of 11 deg before any motion (mr_clean seed 12 then
    aligned 11-18 deg off); an acceleration must also show in the GNSS velocity."""
    weighted = total = 0
    widest: list[float] = []
    for seed in range(1, 6):
        run = multirotor(seed, 14.5)
        e = Estimator(cfg("filter.profile=multirotor"))
        bank = e.yaw_bank
        assert bank is not None
        for s in run.samples():
            e.push(s)
            if isinstance(s, GnssSample) and bank.started:
                total += 1
                weighted += int(bank.buf[yk.H_WUPD] > 0.0)
        b = bank.buf
        widest.append(max(math.degrees(math.sqrt(b[yk.MEM + i * yk.MW + yk.M_P + 2 * yk.NX + 2]))
                          for i in range(int(b[yk.H_N]))))
    assert total > 300
    assert weighted / total <= 0.03, (weighted, total)
    assert float(np.median(widest)) >= 20.0, widest


@pytest.mark.parametrize("seed", [4, 5, pytest.param(12, marks=pytest.mark.xfail(
    strict=True, reason="seed 12: the bank aligns 10.8 deg off at sigma 8.6 deg (honest), then "
    "the main filter's yaw sigma shrinks to 3 deg over five acceleration pulses while the "
    "error stays 8-12 deg: 34 % of aligned epochs beyond 3 sigma (docs/results.md, session "
    "2026-11-27 (f))"))])
def test_multirotor_scenario_heading_stays_within_3_sigma(seed: int) -> None:
    """GIVEN navd's own `multirotor` scenario (issue 15's "Shown by"), seeds 4 and 5: on
    those the bank aligned the heading 12-20 deg off with a 3-4 deg sigma and the main
    filter kept it beyond 3 sigma for 100-150 s (80 % / 31 % of aligned instants),
    WHEN it runs with the default config's multirotor profile,
    THEN the heading is aligned at some point, and at most 5 % of the aligned epochs are
    beyond 3 sigma."""
    run = multirotor(seed, 240.0)
    e = Estimator(cfg("filter.profile=multirotor"))
    _t, err, sd, aligned = _aligned_errors(run, e)
    assert aligned.any()
    assert np.mean(np.abs(err[aligned]) > 3.0 * sd[aligned]) <= 0.05


@pytest.mark.alloc
def test_steady_state_steps_with_the_bank_do_not_allocate() -> None:
    """GIVEN the estimator with the multirotor profile (bank running) warmed up on the
    multirotor scenario,
    WHEN 10000 more IMU steps (with their GNSS fixes) run under tracemalloc,
    THEN the peak allocation stays < 1024 bytes and < 256 bytes are still held afterwards."""
    run = multirotor(1, 240.0)
    e = Estimator(cfg("filter.profile=multirotor"))
    assert e.yaw_bank is not None
    samples = [s for s in run.samples() if isinstance(s, (ImuSample, GnssSample))]
    a = measure_steps(e, samples, warm_imu=30000, max_imu=10000)
    assert a.imu == 10000
    assert e.yaw_bank.started
    assert a.peak < 1024
    assert a.grew < 256
