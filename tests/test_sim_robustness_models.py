"""The error models the robustness benchmark (issue 14) adds to firmware_sim, each against its
spec: uncalibrated IMU offsets, bias random walk, GNSS velocity noise beyond the reported
accuracy, a held GNSS position step, and a GNSS outage."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

from firmware_sim import ScenarioError, SimRun, generate, load_scenario
from navd.core.earth import radii
from navd.units import DEG

Arr = npt.NDArray[np.float64]
MG = 9.80665e-3


def _static(seconds: float, **over: Any) -> dict[str, Any]:
    """Overrides of the ``static`` scenario: ``seconds`` long, no drawn bias."""
    base: dict[str, Any] = {"duration_s": seconds, "imu.gyro_bias_sigma_rps": 0.0,
                            "imu.accel_bias_sigma_mps2": 0.0}
    base.update(over)
    return base


def _sensor_error(run: SimRun) -> Arr:
    """(N, 6) measured minus error-free increments, divided by dt: rad/s and m/s^2."""
    return (run.imu_inc - run.imu_inc_true) / run.imu_dt_s


def test_gyro_offset_at_rest_has_its_stated_size() -> None:
    """GIVEN a 30 s static run with a fixed gyro offset of (0.3, -1.0, 0.5) deg/s and no drawn bias,
    WHEN the gyro error (measured minus error-free rate) is averaged,
    THEN the mean equals the offset (within 6e-5 rad/s) and the recorded gyro bias is exactly
    the offset."""
    off = np.array([0.3, -1.0, 0.5]) * DEG
    run = generate(load_scenario("static", _static(30.0, **{
        "imu.gyro_offset_rps": off.tolist()})), seed=3)
    mean = _sensor_error(run)[:, 0:3].mean(axis=0)
    # white noise averages to arw / sqrt(T) = 7e-5 / sqrt(30) ~ 1.3e-5 rad/s per axis
    np.testing.assert_allclose(mean, off, atol=6e-5)
    np.testing.assert_array_equal(run.gyro_bias_rps, off)  # no drawn part: sigma 0


def test_accel_offset_at_rest_has_its_stated_size() -> None:
    """GIVEN a 30 s static run with a fixed accelerometer offset of (20, -20, 20) mg and no
    drawn bias,
    WHEN the accelerometer error is averaged,
    THEN the mean equals the offset (within 0.2 m/s^2) and the recorded accel bias is the offset."""
    off = np.array([20.0, -20.0, 20.0]) * MG
    run = generate(load_scenario("static", _static(30.0, **{
        "imu.accel_offset_mps2": off.tolist()})), seed=3)
    mean = _sensor_error(run)[:, 3:6].mean(axis=0)
    # vrw / sqrt(T) = 0.3 / sqrt(30) ~ 0.055 m/s^2 per axis; 20 mg = 0.196 m/s^2
    np.testing.assert_allclose(mean, off, atol=0.2)
    np.testing.assert_allclose(run.accel_bias_mps2, off)


def test_offsets_leave_every_other_draw_unchanged() -> None:
    """GIVEN two 20 s car480 runs with the same seed, one with a gyro offset added,
    WHEN their outputs are compared,
    THEN the gyro increments differ by exactly offset * dt, while the accelerometer
    increments and the GNSS latitudes are identical."""
    off = [0.01, 0.02, -0.03]
    a = generate(load_scenario("car480", {"duration_s": 20.0}), seed=5)
    b = generate(load_scenario("car480", {"duration_s": 20.0, "imu.gyro_offset_rps": off}),
                 seed=5)
    np.testing.assert_allclose(b.imu_inc[:, 0:3] - a.imu_inc[:, 0:3],
                               np.tile(np.array(off) * a.imu_dt_s, (a.imu_inc.shape[0], 1)),
                               atol=1e-15)
    np.testing.assert_array_equal(b.imu_inc[:, 3:6], a.imu_inc[:, 3:6])
    np.testing.assert_array_equal(b.gnss["lat_deg"], a.gnss["lat_deg"])


def test_bias_random_walk_steps_and_spread() -> None:
    """GIVEN a 200 s static run with gyro and accel bias random walks and no white noise,
    WHEN the sensor error and the walks are examined,
    THEN the gyro error is the walk itself starting at 0, each step has std q * sqrt(dt)
    (2 %), and the accel walk has wandered by roughly q * sqrt(200 s) by the end."""
    q_g = 10.0 * DEG / 3600.0 / 60.0  # 10 deg/h/sqrt(h) in rad/s/sqrt(s)
    q_a = 1e-3
    run = generate(load_scenario("static", _static(
        200.0, **{"imu.arw_rad_per_sqrt_s": 0.0, "imu.vrw_mps_per_sqrt_s": 0.0,
                  "imu.gyro_bias_rw_rps_per_sqrt_s": q_g,
                  "imu.accel_bias_rw_mps2_per_sqrt_s": q_a})), seed=7)
    err = _sensor_error(run)
    # without white noise the sensor error is the walk itself, starting at 0
    np.testing.assert_allclose(err[:, 0:3], run.gyro_rw_rps, rtol=1e-9, atol=1e-18)
    np.testing.assert_allclose(err[0], 0.0, atol=1e-12)
    dt = run.imu_dt_s
    # each step is q sqrt(dt) w: 20000 x 3 steps estimate its spread to ~0.3 %
    for walk, q in ((run.gyro_rw_rps, q_g), (run.accel_rw_mps2, q_a)):
        step_sd = float(np.std(np.diff(walk, axis=0)))
        assert step_sd == pytest.approx(q * math.sqrt(dt), rel=0.02)
    # and a walk it is: after 200 s it has wandered by ~q sqrt(200) (3 axes: loose bound)
    spread = float(np.sqrt(np.mean(run.accel_rw_mps2[-1] ** 2)))
    assert 0.05 * q_a * math.sqrt(200.0) < spread < 4.0 * q_a * math.sqrt(200.0)


def _ne_error_m(run: SimRun) -> Arr:
    """(M, 2) north/east position error of each fix against the truth, m."""
    p = run.truth_pos[run.gnss_truth_idx]
    lat = np.radians(run.gnss["lat_deg"])
    lon = np.radians(run.gnss["lon_deg"])
    r = np.array([radii(float(x)) for x in p[:, 0]])
    dn = (lat - p[:, 0]) * (r[:, 0] + p[:, 2])
    de = (lon - p[:, 1]) * (r[:, 1] + p[:, 2]) * np.cos(p[:, 0])
    return np.stack([dn, de], axis=1)


def test_velocity_noise_beyond_reported_accuracy() -> None:
    """GIVEN a 1500 s static run with gnss.vel_noise_scale = 3,
    WHEN the horizontal velocity errors of the fixes are taken,
    THEN the fixes still report 0.05 m/s accuracy but the actual error std is 3 x 0.05 m/s (5 %)."""
    run = generate(load_scenario("static", _static(1500.0, **{"gnss.vel_noise_scale": 3.0})),
                   seed=2)
    g = run.gnss
    v = np.stack([g["vel_n"], g["vel_e"]], axis=1) - run.truth_vel_n[run.gnss_truth_idx, :2]
    reported = 0.05  # the static scenario's vel_sigma_h_mps
    np.testing.assert_array_equal(g["vel_acc_mps"], reported)  # still claimed
    assert float(np.std(v)) == pytest.approx(3.0 * reported, rel=0.05)


def test_a_500_m_jump_moves_the_fixes_by_500_m_inside_its_window_only() -> None:
    """GIVEN a 60 s car480 run with a 500 m north position step from 20 to 40 s,
    WHEN the north/east errors of the fixes are taken,
    THEN fixes inside the window are 500 m north on average (3 m) and flagged as outliers,
    and fixes outside are unshifted and unflagged."""
    run = generate(load_scenario("car480", {
        "duration_s": 60.0,
        "gnss.pos_steps": [{"start_s": 20.0, "end_s": 40.0, "north_m": 500.0}]}), seed=4)
    t = run.gnss["t_us"] * 1e-6
    inside = (t >= 20.0) & (t < 40.0)
    e = _ne_error_m(run)
    # car480 position noise is 10 m per axis: means over 200 fixes are good to ~2 m
    assert float(np.mean(e[inside, 0])) == pytest.approx(500.0, abs=3.0)
    assert abs(float(np.mean(e[inside, 1]))) < 3.0
    assert abs(float(np.mean(e[~inside, 0]))) < 3.0
    assert float(np.min(e[inside, 0])) > 450.0 and float(np.max(e[~inside, 0])) < 50.0
    np.testing.assert_array_equal(run.gnss["outlier"], inside)


def test_outage_leaves_no_fix_in_its_window() -> None:
    """GIVEN a 120 s car480 run with a GNSS outage from 30 to 90 s,
    WHEN the GNSS table is generated,
    THEN no fix falls in the window and all 10 Hz fixes before (299) and after (301) it remain."""
    run = generate(load_scenario("car480", {
        "duration_s": 120.0, "gnss.dropouts": [{"start_s": 30.0, "end_s": 90.0}]}), seed=1)
    t = run.gnss["t_us"] * 1e-6
    assert not np.any((t >= 30.0) & (t < 90.0))
    # the fixes around it are all there (10 Hz)
    assert np.sum(t < 30.0) == 299 and np.sum(t >= 90.0) == 301


@pytest.mark.parametrize(("key", "value"), [
    ("imu.gyro_offset_rps", [0.1, 0.2]),
    ("imu.gyro_bias_rw_rps_per_sqrt_s", -1.0),
    ("gnss.vel_noise_scale", -2.0),
    ("gnss.pos_steps", [{"start_s": 10.0, "end_s": 5.0, "north_m": 1.0}]),
])
def test_bad_values_are_refused(key: str, value: Any) -> None:
    """GIVEN a robustness setting with a bad value (wrong-length offset, negative random walk or
    noise scale, a position step ending before it starts),
    WHEN car480 is loaded with it,
    THEN ScenarioError names the setting."""
    with pytest.raises(ScenarioError, match=key.split(".")[1]):
        load_scenario("car480", {key: value})
