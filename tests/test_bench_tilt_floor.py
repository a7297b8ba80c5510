"""The tilt information floor (benchmarks/tilt_floor.py): the discrete Riccati against its
closed-form limit, and the floor against a Monte Carlo of the optimal filter it describes."""

from __future__ import annotations

import math
from types import ModuleType

import numpy as np
import pytest
from bench_util import load_benchmark

G = 9.80665


@pytest.fixture(scope="module")
def b() -> ModuleType:
    return load_benchmark("tilt_floor")


def test_discrete_floor_tends_to_the_closed_form(b: ModuleType) -> None:
    """GIVEN seed 001's IMU (ARW 0.24 deg/sqrt(h), VRW 0.3 m/s/sqrt(s)),
    WHEN the velocity is measured often and precisely (100 Hz, 1 mm/s),
    THEN the discrete steady state equals sqrt(ARW VRW / g) (0.0837 deg) within 1 %;
    and at car480's 10 Hz / 0.1 m/s it stays within 3 % of it (VRW dominates)."""
    arw = math.radians(0.24) / 60.0
    closed = b.tilt_floor_closed_deg(arw, 0.3)
    assert closed == pytest.approx(math.degrees(math.sqrt(arw * 0.3 / G)))
    assert closed == pytest.approx(0.0837, abs=5e-4)
    fine = b.tilt_floor_deg(arw, 0.3, 0.001, 0.01, 0.01, iters=200000)
    assert fine == pytest.approx(closed, rel=0.01)
    car = b.tilt_floor_deg(arw, 0.3, 0.1, 0.1, 0.01, iters=100000)
    assert car == pytest.approx(closed, rel=0.03)
    # a better accelerometer lowers the floor as the square root of its VRW
    assert b.tilt_floor_deg(arw, 0.03, 0.1, 0.1, 0.01, iters=100000) < 0.5 * car


def test_floor_is_what_the_optimal_filter_reaches_on_simulated_data(b: ModuleType) -> None:
    """GIVEN 400 simulated runs of the two-state model (tilt random walk, velocity driven by
    g x tilt plus white noise, velocity measured at 10 Hz) with a large ARW/VRW so they settle
    within 60 s,
    WHEN the Kalman filter of that model runs on each,
    THEN the RMS tilt error at the end equals the floor within the Monte Carlo's 10 %."""
    rng = np.random.default_rng(7)
    arw, vrw, vsd, dt, n_up = 0.01, 1.0, 0.05, 0.01, 10
    floor = math.radians(b.tilt_floor_deg(arw, vrw, vsd, dt * n_up, dt, iters=100000))
    runs, steps = 400, 6000
    F = np.array([[1.0, G * dt], [0.0, 1.0]])
    Q = np.diag([vrw**2 * dt, arw**2 * dt])
    x = np.zeros((runs, 2))
    x[:, 1] = rng.normal(0.0, 0.02, runs)
    xh = np.zeros((runs, 2))
    P = np.diag([0.0, 0.02**2])
    for k in range(steps):
        w = rng.normal(size=(runs, 2)) * np.sqrt(np.diag(Q))
        x = x @ F.T + w
        xh = xh @ F.T
        P = F @ P @ F.T + Q
        if (k + 1) % n_up == 0:
            z = x[:, 0] + rng.normal(0.0, vsd, runs)
            K = P[:, 0] / (P[0, 0] + vsd**2)
            xh = xh + np.outer(z - xh[:, 0], K)
            P = P - np.outer(K, P[0, :])
    rms = float(np.sqrt(np.mean((x[:, 1] - xh[:, 1]) ** 2)))
    assert math.sqrt(P[1, 1]) == pytest.approx(floor, rel=0.02)
    assert rms == pytest.approx(floor, rel=0.10)


def test_tilt_sigma_with_a_gyro_bias_prior(b: ModuleType) -> None:
    """GIVEN seed 001's IMU with the velocity measured at 10 Hz / 0.1 m/s,
    WHEN the three-state bound runs from a tilt known exactly,
    THEN with no gyro-bias uncertainty it tends to the steady-state floor (after 3000 s);
    at 60 s it grows with the gyro-bias prior (12 < 100 < 1800 deg/h) and a 1800 deg/h
    prior leaves more than 0.3 deg (the issue-14 "tilt <= 1 deg at every instant after 60 s"
    is then exceeded by chance about 1 % of the time on each axis)."""
    arw = math.radians(0.24) / 60.0
    floor = b.tilt_floor_deg(arw, 0.3, 0.1, 0.1, 0.1, iters=100000)
    assert b.tilt_sd_at_deg(3000.0, arw, 0.3, 0.1, 0.1, 0.0, imu_dt_s=0.1) == pytest.approx(
        floor, rel=0.03)
    s = [b.tilt_sd_at_deg(60.0, arw, 0.3, 0.1, 0.1, math.radians(x) / 3600.0)
         for x in (12.0, 100.0, 1800.0)]
    assert s[0] < s[1] < s[2]
    assert s[2] > 0.3
