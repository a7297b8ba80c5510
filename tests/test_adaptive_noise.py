"""Adaptive process noise (navd.core.aiding.adaptive_noise) with the default config: an IMU
noisier than configured is found from the velocity innovations, a clean one is left alone."""

from __future__ import annotations

import math

import numpy as np
from bench_util import load_benchmark

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
    # the innovations do not persist: the gyro-bias walk is left as configured
    for est in (clean, gyro):
        assert est.gnss.adaptive.bias_scale == 1.0


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


def test_a_gyro_bias_drifting_far_faster_than_configured_raises_its_random_walk() -> None:
    """GIVEN car480 (seed 2) whose gyro bias walks at 3000 deg/h/sqrt(h), 600x the default
    config's 5 (a warming consumer gyro: log171's onboard EKF saw 0.2 deg/s in 2 minutes),
    WHEN run with the default config,
    THEN the velocity innovations persist from epoch to epoch, the gyro-bias random walk is
    scaled up (counted), and pitch is beyond 3 sigma in at most half as many instants as
    in the control with [filter] max_bias_q_scale = 1, with a smaller pitch RMS (the control
    runs 16 deg RMS with 6 heading resets)."""
    rb = load_benchmark("robustness")
    o = {"imu.gyro_bias_rw_rps_per_sqrt_s": 3000.0 * DEG / 3600.0 / 60.0}
    run = generate(load_scenario("car480", o), seed=2, progress=False)
    on = rb.score_sim(run, "ground")
    off = rb.score_sim(run, "ground", ("filter.max_bias_q_scale=1",))
    assert on.counters.get("bias_q_up", 0) >= 1
    assert off.counters.get("bias_q_up", 0) == 0

    def pitch(r: object) -> tuple[float, float]:
        e, sd = r.err_deg[:, 1], r.sd_deg[:, 1]  # type: ignore[attr-defined]
        return float(np.sqrt(np.mean(e * e))), float(np.mean(np.abs(e) > 3.0 * sd))

    (rms_on, ex_on), (rms_off, ex_off) = pitch(on), pitch(off)
    assert ex_on <= 0.5 * ex_off, (ex_on, ex_off)
    assert rms_on < rms_off, (rms_on, rms_off)
