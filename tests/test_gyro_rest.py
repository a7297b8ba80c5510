"""At-rest gyro offset estimate (navd.core.aiding.gyro_rest) and the bias limits
(navd.core.aiding.gnss_recovery.check_bias_limits), with the default config."""

from __future__ import annotations

import math

import numpy as np

from firmware_sim import SimRun, generate, load_scenario
from navd.config import load_config
from navd.core.aiding.gnss_recovery import check_bias_limits
from navd.core.aiding.gyro_rest import GYRO_BIAS_LIMIT
from navd.core.estimator import Estimator
from navd.pipeline import build_estimator
from navd.types import ImuSample

DEG = math.pi / 180.0
OFFSET_RPS = (1.0 * DEG, -0.7 * DEG, 0.5 * DEG)


def _run_static(extra: dict[str, object], duration_s: float,
                overrides: list[str] | None = None) -> tuple[Estimator, SimRun]:
    scen = load_scenario("static", {"duration_s": duration_s,
                                    "imu.gyro_offset_rps": list(OFFSET_RPS), **extra})
    run = generate(scen, seed=2, progress=False)
    est = build_estimator(load_config(None, overrides or []))
    for s in run.samples():
        est.push(s)
    return est, run


def test_a_1_dps_gyro_offset_is_estimated_at_rest() -> None:
    """GIVEN the default config, a MEMS IMU at rest whose gyro is off by (1, -0.7, 0.5) deg/s
    (no calibration: far outside the configured prior),
    WHEN 30 s of data are pushed,
    THEN the at-rest measurement fires, the gyro bias estimate is within 0.01 deg/s of the
    offset on every axis, its 1-sigma covers the error, and the tilt stays within 0.5 deg."""
    est, run = _run_static({}, 30.0)
    assert est.gyro_rest.updates >= 3
    # the simulated bias: the offset plus the MEMS's own 12 deg/h turn-on bias
    true_bg = np.asarray(run.gyro_bias_rps).reshape(-1, 3)[-1]
    assert np.allclose(true_bg, OFFSET_RPS, atol=0.02 * DEG)
    err = np.asarray(est.bias_g) - true_bg
    assert np.all(np.abs(err) < 0.01 * DEG), np.degrees(err)
    sd = np.sqrt(np.diag(est.P)[9:12])
    assert np.all(np.abs(err) < 4.0 * sd + 1e-9), (np.degrees(err) * 3600, np.degrees(sd) * 3600)
    sol = est.solution()
    assert abs(sol.roll_rad) < 0.5 * DEG and abs(sol.pitch_rad) < 0.5 * DEG


def test_without_rest_calibration_the_same_offset_is_not_found() -> None:
    """The control: with [imu] rest_calibration = false the same run leaves the bias estimate
    off by more than 0.1 deg/s on the vertical axis (GNSS at rest cannot see it)."""
    est, _ = _run_static({}, 30.0, ["imu.rest_calibration=false"])
    assert est.gyro_rest.updates == 0
    assert abs(float(est.bias_g[2]) - OFFSET_RPS[2]) > 0.1 * DEG


def test_a_swaying_platform_is_not_taken_for_rest() -> None:
    """GIVEN the same IMU on a platform that sways 1 deg in roll and pitch (periods 10 s and
    13.7 s: each 1 s window looks quiet, the rate amplitude is ~0.6 deg/s),
    THEN no window run passes the stillness test and no bias measurement is made."""
    est, _ = _run_static({"trajectory.sway_deg": 1.0, "trajectory.sway_period_s": 10.0}, 40.0)
    assert est.gyro_rest.updates == 0
    assert not est.gyro_rest.still


def test_a_bias_beyond_its_physical_limit_resets_both_biases() -> None:
    """A gyro bias estimate of 12 deg/s is divergence: both biases go back to the configured
    ones with their prior covariance, counted; within limits nothing happens."""
    est, _ = _run_static({}, 5.0)
    assert not check_bias_limits(est)
    est.bias_g[1] = 1.2 * GYRO_BIAS_LIMIT
    est.bias_a[0] = 0.3
    assert check_bias_limits(est)
    assert est.counters["reset_bias_limit"] == 1
    assert np.all(est.bias_g == 0.0) and np.all(est.bias_a == 0.0)
    assert est.P[10, 10] >= est.cfg.imu.gyro_bias_sd ** 2
    assert est.P[10, 3] == 0.0
    np.linalg.cholesky(est.P[:, :] + 1e-18 * np.eye(15))
    # NaN is beyond every limit too
    est.bias_a[2] = math.nan
    assert check_bias_limits(est)
    assert math.isfinite(float(est.bias_a[2]))


def test_imu_samples_before_navigation_feed_the_windows() -> None:
    """The stillness windows are fed from the first IMU sample, before navigation starts
    (a boot calibration): 3 s of IMU without any fix completes 3 windows."""
    est = build_estimator(load_config(None, []))
    dt = 0.01
    for k in range(300):
        est.push(ImuSample(t_us=(k + 1) * 10_000, dt_us=10_000, dtheta_x=OFFSET_RPS[0] * dt,
                           dtheta_y=0.0, dtheta_z=0.0, dvel_x=0.0, dvel_y=0.0,
                           dvel_z=-9.8 * dt))
    assert not est.initialized
    assert est.gyro_rest.windows == 3


def test_a_slow_sway_of_a_steep_platform_is_not_taken_for_rest() -> None:
    """GIVEN the seed-000 static vehicle pitched 75 deg that sways +-1.7 deg with periods of
    120 s and 164 s (its rate, up to ~300 deg/h, changes by ~14 deg/h per second: about the
    noise of a 1 s window mean; a 5 s test took it for an offset twice in 600 s),
    WHEN 200 s are pushed with the default config,
    THEN no run of windows is judged still and no bias measurement is made."""
    sc = load_scenario("pol_static", {"duration_s": 200.0, "trajectory.pitch_deg": 75.0,
                                      "trajectory.yaw_deg": 278.87})
    run = generate(sc, seed=3, progress=False)
    est = build_estimator(load_config(None, []))
    still_seen = False
    for s in run.samples():
        est.push(s)
        still_seen = still_seen or est.gyro_rest.still
    assert est.initialized
    assert not still_seen
    assert est.gyro_rest.updates == 0


def test_a_run_the_fixes_end_is_measured_though_the_imu_looks_still() -> None:
    """GIVEN six windows of a still IMU, WHEN a seventh window is also still by the IMU
    but another sensor says it ends in motion (a car backing out gently: 0.7 m/s^2 is
    within a noisy accelerometer's scatter), THEN close_window reports a run ended by motion
    of the first five windows (the last still one left out); without the flag the same
    window only extends the run."""
    from navd.core.aiding.gyro_rest import _MIN_WINDOWS, _WINDOWS, close_window
    from navd.core.chi2 import chi2_quantile

    rng = np.random.default_rng(3)
    gates = np.array([chi2_quantile(0.999, 3 * max(k - 1, 1)) for k in range(_WINDOWS + 1)])
    trend = chi2_quantile(0.999, 1)

    def run_of(moving_last: bool) -> tuple[int, float]:
        win = np.zeros((_WINDOWS, 13))
        n = np.zeros(1)
        res = 0
        for w in range(7):
            a = np.zeros(14)
            for _ in range(100):
                r = OFFSET_RPS[0] + rng.normal(0.0, 0.002)
                f = rng.normal(0.0, 0.3, 3) + np.array([0.0, 0.0, -9.8])
                a[:12] += np.array([r, 0.0, 0.0, *f, r * r, 0.0, 0.0, *(f * f)])
                a[12] += 1.0
                a[13] += 0.01
            res = close_window(a, win, n, 5.0 * DEG, 1.5, 9.8, gates, trend, _MIN_WINDOWS,
                               moving_last and w == 6, np.zeros(3), False)
        return res, float(n[0])

    assert run_of(True) == (2, 5.0)
    assert run_of(False) == (0, 7.0)


def test_the_stillness_test_reads_only_the_vertical_rate_before_a_calibration() -> None:
    """``turning``: before any calibration a mean raw rate of 4.4 deg/s that is mostly about
    the horizontal axes (an MPU-6000-class offset, +3/-2.5/+2 deg/s with the IMU level) is not
    taken for a turn, 4 deg/s about the vertical is; after one, the rate less the offset
    measured counts whole (3.1 deg/s about a horizontal axis is a turn); anything beyond the
    gyro-bias limit always is."""
    from navd.core.aiding.gyro_rest import turning
    tol = 3.0 * DEG
    g = (0.0, 0.0, -9.8)
    off = (3.0 * DEG, -2.5 * DEG, 2.0 * DEG)
    assert not turning(*off, *g, 0.0, 0.0, 0.0, tol, False)
    assert turning(0.0, 0.0, 4.0 * DEG, *g, 0.0, 0.0, 0.0, tol, False)
    # the vertical is the specific force's, not the body z axis: rolled 90 deg, body y
    assert turning(0.0, 4.0 * DEG, 0.0, 0.0, -9.8, 0.0, 0.0, 0.0, 0.0, tol, False)
    assert not turning(4.0 * DEG, 0.0, 0.0, 0.0, -9.8, 0.0, 0.0, 0.0, 0.0, tol, False)
    # calibrated: the same raw rate is still, with the offset taken off ...
    assert not turning(*off, *g, *off, tol, True)
    # ... and a horizontal turn on top of it is a turn
    assert turning(off[0] + 3.1 * DEG, off[1], off[2], *g, *off, tol, True)
    assert turning(0.0, 0.0, 0.0, *g, *off, tol, True)  # 4.4 deg/s off the calibration
    assert turning(0.1 + GYRO_BIAS_LIMIT, 0.0, 0.0, *g, 0.0, 0.0, 0.0, tol, False)


def test_a_multirotor_gyro_offset_beyond_the_stillness_limit_is_calibrated_at_rest() -> None:
    """GIVEN the multirotor scenario (15 s on the ground first) whose gyro is off by
    +3/-2.5/+2 deg/s (4.4 deg/s together: beyond ``static_rate_tol_dps``, 3 deg/s, which a
    limit on the whole rate took for turning), seed 1, default config,
    WHEN it runs,
    THEN the at-rest measurement fires before take-off, the tilt is re-levelled at the first
    refusal (``gyro_rest_relevel``), the bias is within 0.02 deg/s of the truth on every axis
    by 25 s (the next measurement, from the windows before take-off at 15 s), and over the
    run roll and pitch are each beyond 3 sigma in at most 5 % of instants with an RMS below
    3 deg (before: 9 / 28 % and 29 / 18 deg RMS pooled over seeds 1-3)."""
    from bench_util import load_benchmark
    rb = load_benchmark("robustness")
    off = [3.0 * DEG, -2.5 * DEG, 2.0 * DEG]
    run = generate(load_scenario("multirotor", {"imu.gyro_offset_rps": off}), seed=1,
                   progress=False)
    est = build_estimator(load_config(None, ["filter.profile=multirotor"]))
    for s in run.samples():
        if s.t_us > 25_000_000:
            break
        est.push(s)
    assert est.counters.get("gyro_rest_relevel", 0) >= 1
    true_bg = np.asarray(run.gyro_bias_rps).reshape(-1, 3)[-1]
    err = np.asarray(est.bias_g) - true_bg
    assert np.all(np.abs(err) < 0.02 * DEG), np.degrees(err)
    r = rb.score_sim(run, "multirotor")
    beyond = np.mean(np.abs(r.err_deg[:, :2]) > 3.0 * r.sd_deg[:, :2], axis=0)
    rms = np.sqrt(np.mean(r.err_deg[:, :2] ** 2, axis=0))
    assert np.all(beyond <= 0.05), beyond
    assert np.all(rms < 3.0), rms
