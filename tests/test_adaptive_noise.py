"""Adaptive process noise (navd.core.aiding.adaptive_noise) with the default config: an IMU
noisier than configured is found from the velocity innovations, a clean one is left alone."""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest
from bench_util import load_benchmark

from firmware_sim import generate, load_scenario
from navd.config import load_config
from navd.core.aiding import adaptive_noise as an
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
    with the measured floor (core/aiding/imu_noise.py) off so that only the innovations
    can tell, WHEN 200 s are run,
    THEN the white-noise variance scale has risen to between 4 and 25, the fixes' variance
    scale has taken at most one step up (a chance fluctuation; a step is the window's median
    NIS ratio, sqrt(2) to 4), and no velocity lock-out reset was needed; with [filter]
    adaptive_noise = false the same run stays at scale 1 and needs at least one reset (the
    control)."""
    est = _run(NOISE_X3, ["filter.measure_imu_noise=false"])
    assert 4.0 <= est.gnss.adaptive.scale <= 25.0
    assert est.counters.get("r_scale_up", 0) - est.counters.get("r_scale_down", 0) <= 1
    assert est.gnss.adaptive.r_scale < est.gnss.adaptive.scale
    assert est.counters["q_scale_up"] >= 2
    assert est.counters.get("reset_lockout_vel", 0) == 0
    off = _run(NOISE_X3, ["filter.adaptive_noise=false", "filter.measure_imu_noise=false"])
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
    # the innovations do not persist: the gyro-bias walk is left as configured and the
    # tilt / accelerometer-bias split is never reopened
    for est in (clean, gyro):
        assert est.gnss.adaptive.bias_scale == 1.0
        assert est.counters.get("tilt_split_reopened", 0) == 0


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


@functools.lru_cache(maxsize=1)
def _drifting() -> tuple[float, float, np.ndarray, np.ndarray]:
    """car480 seeds 1-3 with the gyro bias walking at 3000 deg/h/sqrt(h), default config and
    the control ([filter] max_bias_q_scale = 1): pooled pitch RMS on / off, deg, and the
    (2,) shares of roll and pitch instants beyond 3 sigma on / off; the counters are checked
    per seed on the way."""
    rb = load_benchmark("robustness")
    o = {"imu.gyro_bias_rw_rps_per_sqrt_s": 3000.0 * DEG / 3600.0 / 60.0}
    err_on, err_off, ex_on, ex_off = [], [], [], []
    for seed in (1, 2, 3):
        run = generate(load_scenario("car480", o), seed=seed, progress=False)
        on = rb.score_sim(run, "ground")
        off = rb.score_sim(run, "ground", ("filter.max_bias_q_scale=1",))
        assert on.counters.get("bias_q_up", 0) >= 1, seed
        assert off.counters.get("bias_q_up", 0) == 0, seed
        assert off.counters.get("tilt_split_reopened", 0) == 0, seed
        for r, err, ex in ((on, err_on, ex_on), (off, err_off, ex_off)):
            e, sd = r.err_deg[:, :2], r.sd_deg[:, :2]  # roll, pitch
            err.append(e[:, 1])
            ex.append(np.abs(e) > 3.0 * sd)

    def rms(parts: list[np.ndarray]) -> float:
        e = np.concatenate(parts)
        return float(np.sqrt(np.mean(e * e)))

    return (rms(err_on), rms(err_off), np.mean(np.concatenate(ex_on), axis=0),
            np.mean(np.concatenate(ex_off), axis=0))


def test_a_gyro_bias_drifting_far_faster_than_configured_is_followed() -> None:
    """GIVEN car480 (seeds 1-3) whose gyro bias walks at 3000 deg/h/sqrt(h), 600x the default
    config's 5 (a warming consumer gyro: log171's onboard EKF saw 0.2 deg/s in 2 minutes),
    WHEN each is run with the default config and with [filter] max_bias_q_scale = 1 (control),
    THEN the velocity innovations persist and the gyro-bias random walk is scaled up (counted)
    on every seed, never in the control; pooled over the seeds the pitch RMS is at most half
    the control's, and the share of roll and pitch instants beyond 3 sigma is far below the
    control's (~70 %)."""
    rms_on, rms_off, share_on, share_off = _drifting()
    assert rms_on <= 0.5 * rms_off, (rms_on, rms_off)
    assert np.all(share_on < 0.25 * share_off), (share_on, share_off)


def test_a_gyro_bias_drifting_far_faster_than_configured_keeps_sigma_honest() -> None:
    """GIVEN the drifting-gyro runs above, THEN roll and pitch are each beyond 3 sigma in at
    most 5 % of instants (issue 14's target; measured 2.2 / 0.5 %).  It failed (a strict
    xfail) until the gyro-bias corrections' test reopened the tilt split by what the
    accelerometer-bias estimate moved: 6.0 / 4.8 % before that test, 13.9 / 2.1 % with the
    test alone (seed 2's 4 deg of roll hidden in the accelerometer bias), docs/results.md
    "Aliased vibration".

    Pooled, not one seed: a single seed's figures move with small changes of the initial tilt
    sigma (docs/results.md, "Tilt with the consumer default").  On main before the
    non-zero-mean test and the reopened tilt split (docs/results.md, "Drifting gyro: honest
    sigma") the adaptation alone left ~55 % of pitch instants beyond 3 sigma.  The target
    held on seeds 1-3 only: over seeds 1-6 the code before the gyro scale allowance had
    roll beyond 3 sigma in 9.8 % (seed 6: 32.6 %)."""
    _, _, share_on, share_off = _drifting()
    assert share_on[0] <= 0.05 and share_on[1] <= 0.05, (share_on, share_off)


def test_aliased_gyro_vibration_is_found_from_the_bias_corrections(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """GIVEN the robustness case vib_car_10dps (a BMI088-class IMU read as 100 Hz rate
    samples, 10/10/5 deg/s of engine vibration at 100 +- 3 Hz through a 20 Hz low-pass: about
    0.4 deg/s wandering through DC) on seeds 1-2, and car480 as shipped on the same seeds,
    WHEN each runs with the default config but the course test off (on a car the course
    innovations find this first, the test below; a multirotor has no course row, and then
    this test is what finds it),
    THEN on the vibrating car the gyro-bias corrections are found inconsistent with their
    covariance (counted) on every seed, pooled roll and pitch are each beyond 3 sigma in fewer
    instants than in the control without the corrections' test either (measured 9.8 / 11.3 %
    against 13.8 / 14.8 %; over seeds 1-5 11.1 / 6.9 against 18.2 / 12.9 %), and the clean
    car never counts it.  Alone it does not reach 5 %: it did on the vibration's first draws,
    which shared their random stream with [randomize] (docs/results.md, session 2026-11-28
    (f)); on a car the course test brings the case within 5 % (test below)."""
    monkeypatch.setattr(an, "_CM_UP", math.inf)
    rb = load_benchmark("robustness")
    case = next(c for c in rb.CASES if c.name == "vib_car_10dps")
    ex, ctl = [], []
    for seed in (1, 2):
        run = generate(load_scenario(case.scenario, dict(case.overrides)), seed=seed,
                       progress=False)
        r = rb.score_sim(run, case.profile)
        assert r.counters.get("gyro_bias_corrections_high", 0) >= 1, seed
        ex.append(np.abs(r.err_deg[:, :2]) > 3.0 * r.sd_deg[:, :2])
        with monkeypatch.context() as m:
            m.setattr(an, "_CZ_UP", math.inf)
            m.setattr(an, "_CZ_BIG", math.inf)
            c = rb.score_sim(run, case.profile)
        assert c.counters.get("gyro_bias_corrections_high", 0) == 0, seed
        ctl.append(np.abs(c.err_deg[:, :2]) > 3.0 * c.sd_deg[:, :2])
        clean = rb.score_sim(generate(load_scenario("car480"), seed=seed, progress=False),
                             "ground")
        assert clean.counters.get("gyro_bias_corrections_high", 0) == 0, seed
    share = np.mean(np.concatenate(ex), axis=0)
    control = np.mean(np.concatenate(ctl), axis=0)
    assert np.all(share < control), (share, control)


def _corrections_z(overrides: dict[str, object], seed: int) -> np.ndarray:
    """Every Z the gyro-bias corrections' test computed on car480 (default config)."""
    est = build_estimator(load_config(None, []))
    run = generate(load_scenario("car480", overrides), seed=seed, progress=False)
    zs: list[float] = []
    last = math.nan
    for s in run.samples():
        est.push(s)
        z = est.gnss.adaptive.corrections_z
        if z != last and math.isfinite(z):  # a new window's test (ties: negligible)
            zs.append(z)
        last = z
    return np.asarray(zs)


def test_the_gyro_bias_corrections_statistic_is_chi_square_3_when_consistent(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """GIVEN car480 as shipped (its IMU as configured: a consistent filter), seeds 1-2,
    THEN the corrections' Z (sum over the three gyro-bias axes of d^2 / V over 30 s) has a
    mean near chi-square(3)'s 3 (measured ~2; 1-4.5 allowed: the windows overlap, and the
    random walk's share of the corrections is not in V) and never reaches the 16.27 that
    raises the walk; with 10 deg/s of aliased vibration (vib_car_10dps, seed 1) its mean is
    more than twice the clean one with the course test off (which otherwise raises the gyro
    noise first and leaves the corrections consistent): the test measures what it claims,
    not a tuned number."""
    clean = np.concatenate([_corrections_z({}, seed) for seed in (1, 2)])
    assert len(clean) > 100
    assert 1.0 <= clean.mean() <= 4.5, clean.mean()
    assert clean.max() < 16.27, clean.max()
    rb = load_benchmark("robustness")
    case = next(c for c in rb.CASES if c.name == "vib_car_10dps")
    monkeypatch.setattr(an, "_CM_UP", math.inf)
    shaken = _corrections_z(dict(case.overrides), 1)
    assert shaken.mean() > 2.0 * clean.mean(), (shaken.mean(), clean.mean())


def test_gyro_noise_aliased_near_dc_is_found_from_the_course(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """GIVEN vib_car_10dps (10/10/5 deg/s of engine vibration aliased to within a few Hz of
    DC: ~3 deg/sqrt(h) of gyro noise where the filter integrates, the consumer preset says
    0.5) on seeds 1-2, and car480 as shipped on the same seeds,
    WHEN each runs with the default config, and the vibrating car again with the course
    test switched off (its threshold at infinity: the control),
    THEN the vibrating car's course innovations raise the gyro's noise scale on every seed
    and pooled heading (aligned), roll and pitch are each beyond 3 sigma in at most 5 % of
    instants (measured 2.7 / 2.1 / 1.3 %), while the control leaves the heading beyond 3
    sigma in more than 5 % (measured 9.8 / 11.3 / 9.6 %); the clean car's course never
    raises it."""
    rb = load_benchmark("robustness")
    case = next(c for c in rb.CASES if c.name == "vib_car_10dps")
    runs = [generate(load_scenario(case.scenario, dict(case.overrides)), seed=seed,
                     progress=False) for seed in (1, 2)]

    def shares(results: list[Any]) -> npt.NDArray[np.float64]:
        tilt = np.concatenate([np.abs(r.err_deg[:, :2]) > 3.0 * r.sd_deg[:, :2]
                               for r in results])
        hdg = np.concatenate([np.abs(r.err_deg[r.aligned, 2]) > 3.0 * r.sd_deg[r.aligned, 2]
                              for r in results])
        return np.array([*np.mean(tilt, axis=0), np.mean(hdg)])

    on = [rb.score_sim(run, case.profile) for run in runs]
    for seed, r in zip((1, 2), on, strict=True):
        assert r.counters.get("gyro_noise_up", 0) >= 1, seed
        clean = rb.score_sim(generate(load_scenario("car480"), seed=seed, progress=False),
                             "ground")
        assert clean.counters.get("gyro_noise_up", 0) == 0, seed
    share_on = shares(on)
    assert np.all(share_on <= 0.05), share_on
    monkeypatch.setattr(an, "_CM_UP", math.inf)
    share_off = shares([rb.score_sim(run, case.profile) for run in runs])
    assert share_off[2] > 0.05, share_off
