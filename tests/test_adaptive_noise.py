"""Adaptive process noise (navd.core.aiding.adaptive_noise) with the default config: an IMU
noisier than configured is found from the velocity innovations, a clean one is left alone."""

from __future__ import annotations

import math

from firmware_sim import generate, load_scenario
from navd.config import load_config
from navd.core.estimator import Estimator
from navd.pipeline import build_estimator

DEG = math.pi / 180.0


def _run(overrides: dict[str, object], config: list[str] | None = None) -> Estimator:
    sc = load_scenario("car480", {"duration_s": 200.0, **overrides})
    run = generate(sc, seed=1, progress=False)
    est = build_estimator(load_config(None, config or []))
    for s in run.samples():
        est.push(s)
    return est


NOISE_X3 = {"imu.arw_rad_per_sqrt_s": 3 * 0.5 * DEG / 60.0, "imu.vrw_mps_per_sqrt_s": 3 * 0.3}


def test_three_times_the_configured_imu_noise_is_found() -> None:
    """GIVEN car480 whose IMU white noise is 3x the default config's (9x the variance),
    WHEN 200 s are run,
    THEN the white-noise variance scale has risen to between 4 and 25, and no velocity
    lock-out reset was needed; with [filter] adaptive_noise = false the same run stays at
    scale 1 and needs at least one reset (the control)."""
    est = _run(NOISE_X3)
    assert 4.0 <= est.gnss.adaptive.scale <= 25.0
    assert est.gnss.adaptive.r_scale <= math.sqrt(2.0) + 1e-9
    assert est.counters["q_scale_up"] >= 2
    assert est.counters.get("reset_lockout_vel", 0) == 0
    off = _run(NOISE_X3, ["filter.adaptive_noise=false"])
    assert off.gnss.adaptive.scale == 1.0
    assert off.counters.get("reset_lockout_vel", 0) >= 1


def test_a_clean_imu_keeps_the_configured_noise() -> None:
    """GIVEN car480 as shipped (its IMU matches the default's noise figures), or with
    uncalibrated 1 deg/s gyro offsets (a bias problem, not a noise problem),
    THEN the scale stays at most sqrt(2) (one step a chance fluctuation may take)."""
    clean = _run({})
    assert clean.gnss.adaptive.scale <= math.sqrt(2.0) + 1e-9
    assert clean.gnss.adaptive.r_scale <= math.sqrt(2.0) + 1e-9
    gyro = _run({"imu.gyro_offset_rps": [1.0 * DEG, -0.7 * DEG, 0.5 * DEG]})
    assert gyro.gnss.adaptive.scale <= math.sqrt(2.0) + 1e-9


def test_gnss_velocity_noisier_than_reported_scales_r_not_q() -> None:
    """GIVEN car480 whose GNSS velocity noise is 3x what the receiver reports,
    THEN the velocity variance scale rises (>= 2; innovations that anti-correlate from epoch
    to epoch say the fixes, not the IMU, are trusted too much), more often and further than
    the IMU noise scale (a window's correlation is noisy: one step the wrong way may happen)."""
    est = _run({"gnss.vel_noise_scale": 3.0})
    a = est.gnss.adaptive
    assert a.r_scale >= 2.0
    assert est.counters["r_scale_up"] > est.counters.get("q_scale_up", 0)
    assert a.r_scale > 2.0 * a.scale
