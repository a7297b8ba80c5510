"""IMU error model: the simulated noise, biases and scale factors match their specification."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
import pytest

from firmware_sim import SimRun, generate, load_scenario
from firmware_sim.scenario import GRADES

Arr = npt.NDArray[np.float64]


def allan_dev(rate: Arr, dt: float, tau: float) -> Arr:
    """Non-overlapping Allan deviation per column of a rate signal (N, k) at cluster ``tau``."""
    m = round(tau / dt)
    n = rate.shape[0] // m
    avg = rate[: n * m].reshape(n, m, -1).mean(axis=1)
    return np.asarray(np.sqrt(0.5 * np.mean(np.diff(avg, axis=0) ** 2, axis=0)), dtype=np.float64)


@pytest.fixture(scope="module")
def static() -> SimRun:
    """1000 s at rest, 100 Hz, MEMS grade (seed 001): biases + white noise only."""
    return generate(load_scenario("static"), seed=11)


def test_white_noise_density(static: SimRun) -> None:
    """GIVEN 1000 s at rest from the seed-001 MEMS grade,
    WHEN the bias is removed from the increment errors and their spread is measured,
    THEN the noise densities and the Allan deviation at 1 s match the spec's ARW and VRW
    (0.24 deg/sqrt(h), 0.3 m/s/sqrt(s)) within 3 % and 10 %."""
    spec = static.scenario.imu
    dt = static.imu_dt_s
    err = static.imu_inc - static.imu_inc_true
    bias = np.concatenate([static.gyro_bias_rps, static.accel_bias_mps2]) * dt
    white = err - bias
    dens = white.std(axis=0) / math.sqrt(dt)
    np.testing.assert_allclose(dens[:3], spec.arw_rad_per_sqrt_s, rtol=0.03)
    np.testing.assert_allclose(dens[3:], spec.vrw_mps_per_sqrt_s, rtol=0.03)
    # Allan deviation of the rate at tau = 1 s is ARW / sqrt(1 s) for white noise
    adev = allan_dev(err / dt, dt, 1.0)
    np.testing.assert_allclose(adev[:3], spec.arw_rad_per_sqrt_s, rtol=0.10)
    np.testing.assert_allclose(adev[3:], spec.vrw_mps_per_sqrt_s, rtol=0.10)
    # the seed-001 figures, in their own units
    assert spec.arw_rad_per_sqrt_s * 180.0 / math.pi * 60.0 == pytest.approx(0.24)
    assert spec.vrw_mps_per_sqrt_s == pytest.approx(0.3)


def test_constant_bias_recovered(static: SimRun) -> None:
    """GIVEN 1000 s at rest with MEMS biases and white noise,
    WHEN the increment errors are averaged,
    THEN the mean rates equal the drawn gyro and accel biases within 5 sigma of the averaged
    noise, and the drawn biases are on the scale of the spec, not zero."""
    spec = static.scenario.imu
    dt = static.imu_dt_s
    t_total = static.imu_inc.shape[0] * dt
    mean = (static.imu_inc - static.imu_inc_true).mean(axis=0) / dt
    tol_g = 5.0 * spec.arw_rad_per_sqrt_s / math.sqrt(t_total)
    tol_a = 5.0 * spec.vrw_mps_per_sqrt_s / math.sqrt(t_total)
    assert np.abs(mean[:3] - static.gyro_bias_rps).max() < tol_g
    assert np.abs(mean[3:] - static.accel_bias_mps2).max() < tol_a
    # the draw is on the scale of the spec (12 deg/h, 5 mg), not zero
    assert np.abs(static.gyro_bias_rps).max() > 0.05 * spec.gyro_bias_sigma_rps
    assert np.abs(static.accel_bias_mps2).max() > 0.05 * spec.accel_bias_sigma_mps2


def test_bias_draws_follow_sigma() -> None:
    """GIVEN 300 short static runs with seeds 0-299,
    WHEN their drawn gyro and accel biases are pooled,
    THEN their spread matches the spec's bias sigmas within 10 % and the gyro mean is near 0."""
    sc = load_scenario("static", overrides={"duration_s": 0.05, "gnss.rate_hz": 100.0})
    g = np.array([generate(sc, seed=s).gyro_bias_rps for s in range(300)]).ravel()
    a = np.array([generate(sc, seed=s).accel_bias_mps2 for s in range(300)]).ravel()
    assert g.std() == pytest.approx(sc.imu.gyro_bias_sigma_rps, rel=0.1)
    assert a.std() == pytest.approx(sc.imu.accel_bias_sigma_mps2, rel=0.1)
    assert abs(g.mean()) < 0.15 * sc.imu.gyro_bias_sigma_rps


def test_gauss_markov_variance_and_correlation() -> None:
    """GIVEN a 20000 s static run at 10 Hz with only first-order Gauss-Markov errors
    (gyro 1e-4 rad/s, accel 2e-3 m/s^2, tau 5 s),
    WHEN the rate errors are examined,
    THEN the gyro error is the reported GM state, the variances are sigma^2 within 10 %, and
    the correlation is exp(-1) at lag tau and exp(-dt/tau) at one step."""
    tau = 5.0
    sc = load_scenario("static", overrides={
        "duration_s": 20000.0, "imu.rate_hz": 10.0, "imu.arw_rad_per_sqrt_s": 0.0,
        "imu.vrw_mps_per_sqrt_s": 0.0, "imu.gyro_bias_sigma_rps": 0.0,
        "imu.accel_bias_sigma_mps2": 0.0, "imu.gyro_gm_sigma_rps": 1e-4,
        "imu.gyro_gm_tau_s": tau, "imu.accel_gm_sigma_mps2": 2e-3, "imu.accel_gm_tau_s": tau,
    })
    run = generate(sc, seed=4)
    dt = run.imu_dt_s
    b = (run.imu_inc - run.imu_inc_true) / dt
    np.testing.assert_allclose(b[:, :3], run.gyro_gm_rps, rtol=1e-9, atol=1e-15)
    for x, sigma in ((b[:, :3], 1e-4), (b[:, 3:], 2e-3)):
        assert x.var(axis=0).mean() == pytest.approx(sigma**2, rel=0.10)
        lag = round(tau / dt)
        xc = x - x.mean(axis=0)
        rho = (xc[lag:] * xc[:-lag]).mean(axis=0) / xc.var(axis=0)
        assert rho.mean() == pytest.approx(math.exp(-1.0), abs=0.05)
        rho1 = (xc[1:] * xc[:-1]).mean(axis=0) / xc.var(axis=0)
        assert rho1.mean() == pytest.approx(math.exp(-dt / tau), abs=0.01)


def test_scale_factor_applied() -> None:
    """GIVEN 60 s of car480 with only scale factor errors (gyro 1000 ppm, accel 500 ppm sigma),
    WHEN each noisy increment is divided by the true one,
    THEN the median ratio per axis is 1 + the drawn scale factor, which is not zero."""
    sc = load_scenario("car480", overrides={
        "duration_s": 60.0, "imu.arw_rad_per_sqrt_s": 0.0, "imu.vrw_mps_per_sqrt_s": 0.0,
        "imu.gyro_bias_sigma_rps": 0.0, "imu.accel_bias_sigma_mps2": 0.0,
        "imu.gyro_scale_factor_sigma_ppm": 1000.0, "imu.accel_scale_factor_sigma_ppm": 500.0,
    })
    run = generate(sc, seed=2)
    big = np.abs(run.imu_inc_true) > 1e-6
    ratio = np.where(big, run.imu_inc / np.where(big, run.imu_inc_true, 1.0) - 1.0, np.nan)
    got = np.nanmedian(ratio, axis=0)
    np.testing.assert_allclose(got, np.concatenate([run.gyro_scale, run.accel_scale]),
                               atol=1e-12)
    assert np.abs(run.gyro_scale).max() > 1e-5


def test_seed_reproducible_and_distinct() -> None:
    """GIVEN 30 s of car480 with GNSS jumps, generated twice with seed 7 and once with seed 8,
    WHEN the runs are compared,
    THEN the seed-7 runs are identical in IMU and GNSS, the seed-8 run differs in both,
    and the true increments are the same for every seed."""
    sc = load_scenario("car480", overrides={"duration_s": 30.0,
                                            "gnss.jumps.enabled": True,
                                            "gnss.jumps.start_s": 0.0})
    a = generate(sc, seed=7)
    b = generate(sc, seed=7)
    c = generate(sc, seed=8)
    np.testing.assert_array_equal(a.imu_inc, b.imu_inc)
    for k in a.gnss:
        np.testing.assert_array_equal(a.gnss[k], b.gnss[k])
    assert not np.array_equal(a.imu_inc, c.imu_inc)
    assert not np.array_equal(a.gnss["vel_n"], c.gnss["vel_n"])
    np.testing.assert_array_equal(a.imu_inc_true, c.imu_inc_true)


def test_grades_match_the_seeds() -> None:
    """GIVEN the built-in IMU grades,
    WHEN their figures are read,
    THEN mems_seed001 has 12 deg/h and 5 mg bias sigmas, mems_seed001_h differs only in VRW
    read as 0.3 m/s/sqrt(h) (used by pol_static), and ship_dov's grade has 0.003 deg/h
    and 1e-4 m/s^2."""
    deg_h = math.pi / 180.0 / 3600.0
    mems = GRADES["mems_seed001"]
    assert mems["gyro_bias_sigma_rps"] == pytest.approx(12.0 * deg_h)
    assert mems["accel_bias_sigma_mps2"] == pytest.approx(5e-3 * 9.80665)
    # the per-sqrt(h) reading of seed 001's VRW: 0.3 m/s/sqrt(h) = 0.005 m/s/sqrt(s)
    h = GRADES["mems_seed001_h"]
    assert h["vrw_mps_per_sqrt_s"] == pytest.approx(0.3 / math.sqrt(3600.0))
    assert {k: v for k, v in h.items() if k != "vrw_mps_per_sqrt_s"} == {
        k: v for k, v in mems.items() if k != "vrw_mps_per_sqrt_s"}
    assert load_scenario("pol_static").imu.vrw_mps_per_sqrt_s == h["vrw_mps_per_sqrt_s"]
    nav = load_scenario("ship_dov").imu
    assert nav.gyro_bias_sigma_rps == pytest.approx(0.003 * deg_h)
    assert nav.accel_bias_sigma_mps2 == pytest.approx(1e-4)
