"""The IMU's white noise measured from its own samples (navd.core.aiding.imu_noise): the
density of white noise is found, motion is not taken for noise, one wild window moves
nothing, and the estimator propagates with the floor from the start of navigation."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest

from firmware_sim import generate, load_scenario
from navd.config import load_config
from navd.core import state as st
from navd.core.aiding import imu_noise as m
from navd.core.estimator import Estimator
from navd.pipeline import build_estimator

DEG = math.pi / 180.0
ARW = 0.5 * DEG / 60.0  # rad/sqrt(s): the consumer preset's 0.5 deg/sqrt(h)
VRW = 0.3  # m/s/sqrt(s)
DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


def _push(n: m.ImuNoise, q: npt.NDArray[np.float64], t_us: float,
          row: npt.NDArray[np.float64], dt: float) -> None:
    m.noise_push(n.acc, q, t_us, float(row[0]), float(row[1]), float(row[2]), float(row[3]),
                 float(row[4]), float(row[5]), dt)


def _feed(inc: npt.NDArray[np.float64], dt: float, cap: float = 25.0) -> m.ImuNoise:
    n = m.ImuNoise(ARW, VRW, cap, True)
    q = np.zeros(15)
    for k, row in enumerate(inc):
        _push(n, q, (k + 1) * dt * 1e6, row, dt)
    return n


def _white(rate_hz: float, seconds: float, arw: float, vrw: float,
           seed: int = 1) -> npt.NDArray[np.float64]:
    rng = np.random.default_rng(seed)
    dt = 1.0 / rate_hz
    k = int(seconds * rate_hz)
    inc = np.empty((k, 6))
    # increments of white noise of density N over dt: N sqrt(dt) per sample
    inc[:, :3] = rng.normal(0.0, arw * math.sqrt(dt), (k, 3))
    inc[:, 3:] = rng.normal(0.0, vrw * math.sqrt(dt), (k, 3))
    inc[:, 5] += -9.81 * dt  # gravity: a constant, which second differences remove
    return inc


@pytest.mark.parametrize("rate_hz", [100.0, 1000.0])
def test_white_noise_above_the_config_is_measured_as_its_variance_ratio(rate_hz: float) -> None:
    """GIVEN 30 s of white noise at 2x the configured ARW and 3x the configured VRW,
    THEN the floors are the variance ratios 4 and 9 within 15 %, and the densities written
    into q are the floors times the configured ones."""
    inc = _white(rate_hz, 30.0, 2.0 * ARW, 3.0 * VRW)
    n = m.ImuNoise(ARW, VRW, 25.0, True)
    q = np.zeros(15)
    for k, row in enumerate(inc):
        _push(n, q, (k + 1) * 1e6 / rate_hz, row, 1.0 / rate_hz)
    assert n.gyro_floor == pytest.approx(4.0, rel=0.15)
    assert n.accel_floor == pytest.approx(9.0, rel=0.15)
    assert q[0] == q[1] == q[2] == pytest.approx(n.gyro_floor * ARW**2, rel=1e-12)
    assert q[3] == q[4] == q[5] == pytest.approx(n.accel_floor * VRW**2, rel=1e-12)


def test_noise_below_the_config_leaves_the_floor_at_one() -> None:
    """The config may overstate the noise (a vibration allowance): never a floor below 1."""
    n = _feed(_white(200.0, 30.0, 0.5 * ARW, 0.3 * VRW), 1.0 / 200.0)
    assert n.gyro_floor == 1.0
    assert n.accel_floor == 1.0


def test_the_floor_is_capped_with_the_innovation_scale() -> None:
    """The densities written are min(floor x scale, cap) x configured."""
    n = _feed(_white(100.0, 30.0, ARW, 4.0 * VRW), 0.01, cap=25.0)
    assert n.accel_floor == pytest.approx(16.0, rel=0.15)
    q = np.zeros(15)
    n.set_scale(4.0, q)
    assert q[3] == pytest.approx(25.0 * VRW**2)  # 16 x 4 capped at 25
    assert q[0] == pytest.approx(min(n.gyro_floor * 4.0, 25.0) * ARW**2)


def test_motion_is_not_taken_for_noise() -> None:
    """GIVEN a gyro swinging +-60 deg/s at 1.5 Hz and +-20 deg/s at 4 Hz (a vehicle
    manoeuvring) on top of white noise at half the configured density,
    THEN the per-sample second differences alone would read the motion as noise (checked:
    above 2x the configured), but the block check refuses those windows and the floor stays
    1; without the motion the same noise gives 1 too (the control is the next assertion's
    premise: only the motion could raise it)."""
    rate = 100.0
    dt = 1.0 / rate
    inc = _white(rate, 60.0, 0.5 * ARW, 0.5 * VRW)
    t = np.arange(len(inc)) * dt
    inc[:, 0] += 60.0 * DEG * np.sin(2 * math.pi * 1.5 * t) * dt
    inc[:, 1] += 20.0 * DEG * np.sin(2 * math.pi * 4.0 * t) * dt
    for axis in (0, 1):
        d2 = np.diff(inc[:, axis] / dt, 2)
        assert np.mean(d2**2) * dt / 6.0 / ARW**2 > 2.0  # what a check-free estimate says
    n = _feed(inc, dt)
    assert n.gyro_floor == 1.0
    assert n.accel_floor == 1.0


def test_one_wild_window_moves_nothing() -> None:
    """GIVEN white noise at half the configured density with one window (4 s) of 10x the
    VRW in the middle (a crash, a bump: white, so the block check passes it),
    THEN the floor stays 1 (the ring starts full of the configured value: most recent
    windows must agree); two such windows in a row do move it."""
    dt = 0.01
    w = round(m.WINDOW_S / dt)
    inc = _white(100.0, 40.0, 0.5 * ARW, 0.5 * VRW)
    wild = _white(100.0, 2.5 * m.WINDOW_S, 0.5 * ARW, 10.0 * VRW, seed=2)
    n = _feed(np.vstack([inc[:2 * w], wild[:w], inc[2 * w:]]), dt)
    assert n.accel_floor == 1.0
    n2 = _feed(np.vstack([inc[:2 * w], wild]), dt)
    assert n2.accel_floor > 50.0


def test_a_gap_restarts_the_difference_chains() -> None:
    """GIVEN 10 samples, a gap of 0.5 s (the samples' interval unchanged: a dropped stream),
    10 more, then 10 at another interval, THEN second differences are taken only within the
    runs (8 per run: a difference across a gap would see the motion of the whole gap as one
    step); a sample stamped out of order also starts over."""
    dt = 0.01
    n = m.ImuNoise(ARW, VRW, 25.0, True)
    q = np.zeros(15)
    row = np.zeros(6)
    for k in range(10):
        _push(n, q, (k + 1) * 1e4, row, dt)
    assert n.acc[m.N1] == 8
    for k in range(10):
        _push(n, q, 0.6e6 + (k + 1) * 1e4, row, dt)
    assert n.acc[m.N1] == 16
    for k in range(10):
        _push(n, q, 0.8e6 + (k + 1) * 2e4, row, 2 * dt)
    assert n.acc[m.N1] == 24
    _push(n, q, 0.5e6, row, 2 * dt)  # back in time
    _push(n, q, 0.52e6, row, 2 * dt)
    assert n.acc[m.N1] == 24


def test_a_dropped_stream_of_a_turning_vehicle_is_not_read_as_noise() -> None:
    """GIVEN a gyro turning smoothly (100 deg/s at 0.2 Hz: invisible in second differences
    at 100 Hz) with noise at half the configured density and 0.5 s of samples missing in
    every second, THEN the floors stay 1."""
    dt = 0.01
    inc = _white(100.0, 40.0, 0.5 * ARW, 0.5 * VRW)
    t = np.arange(len(inc)) * dt
    inc[:, 2] += 100.0 * DEG * np.sin(2 * math.pi * 0.2 * t) * dt
    n = m.ImuNoise(ARW, VRW, 25.0, True)
    q = np.zeros(15)
    for k in np.flatnonzero((t % 1.0) < 0.5):
        _push(n, q, (k + 1) * dt * 1e6, inc[k], dt)
    assert n.gyro_floor == 1.0
    assert n.accel_floor == 1.0


def test_switched_off_it_measures_nothing() -> None:
    n = m.ImuNoise(ARW, VRW, 25.0, False)
    q = np.zeros(15)
    for k, row in enumerate(_white(100.0, 20.0, ARW, 3.0 * VRW)):
        _push(n, q, (k + 1) * 1e4, row, 0.01)
    assert n.accel_floor == 1.0
    assert not q.any()


def _run(overrides: dict[str, object], config: list[str] | None = None,
         seconds: float = 60.0) -> Estimator:
    sc = load_scenario("car480", {"duration_s": seconds, **overrides})
    run = generate(sc, seed=1, progress=False)
    est = build_estimator(load_config(None, config or []))
    for s in run.samples():
        est.push(s)
    return est


def test_the_estimator_propagates_with_the_measured_noise() -> None:
    """GIVEN car480 whose IMU has 3x the configured VRW and 1.44x its ARW (noise_x3),
    THEN the status shows floors near 9 and 2.07, the propagation's densities carry them,
    and the innovation test's own scale has not had to move; car480 as shipped keeps
    floors below 1.2 (its IMU is the configured one)."""
    est = _run({"imu.arw_rad_per_sqrt_s": 3 * 0.24 * DEG / 60.0,
                   "imu.vrw_mps_per_sqrt_s": 3 * 0.3})
    floors = est.status()["imu_noise_floor"]
    assert isinstance(floors, list)
    gf, af = floors
    assert af == pytest.approx(9.0, rel=0.2)
    assert gf == pytest.approx((3 * 0.24 / 0.5) ** 2, rel=0.2)
    q = est.buf[st.Q:st.Q + 15]
    assert q[3] == pytest.approx(est.imu_noise.accel_floor * VRW**2)
    assert q[0] == pytest.approx(est.imu_noise.gyro_floor * ARW**2)
    assert est.gnss.adaptive.scale == 1.0
    clean = _run({})
    clean_floors = clean.status()["imu_noise_floor"]
    assert isinstance(clean_floors, list)
    assert max(clean_floors) < 1.2


def test_a_noisy_imu_levels_longer_when_it_can_and_not_when_it_cannot() -> None:
    """GIVEN noise_x3's IMU on car480 (straight and unaccelerated for its first 10 s),
    THEN levelling runs past the configured 1 s (its scatter allows 5 deg after 1 s) until
    the tilt sigma reaches init.tilt_sd (2 deg) or level_max_time_s, and navigation starts
    with the tilt sigma of P0 at most that of tilt_sd and the accelerometer-bias prior
    together; with level_max_time_s = 1 it starts after 1 s as before, 5 deg of scatter in
    its P0 (the control)."""
    noisy = {"imu.arw_rad_per_sqrt_s": 3 * 0.24 * DEG / 60.0, "imu.vrw_mps_per_sqrt_s": 3 * 0.3}
    sc = load_scenario("car480", {"duration_s": 15.0, **noisy})
    run = generate(sc, seed=1, progress=False)
    t_nav: dict[str, float] = {}
    tilt_sd: dict[str, float] = {}
    for name, extra in (("auto", []), ("1s", ["init.level_max_time_s=1"])):
        est = build_estimator(load_config(None, extra))
        for s in run.samples():
            est.push(s)
            if est.initialized and name not in t_nav:
                t_nav[name] = (est.t_us - int(run.imu_t_us[0])) * 1e-6
                tilt_sd[name] = math.degrees(math.sqrt(est.P[0, 0]))
    cfg = load_config(None, [])
    est0 = build_estimator(cfg)
    prior = math.degrees(math.hypot(est0.cfg.init.tilt_sd, est0.cfg.imu.accel_bias_sd / 9.8))
    assert 3.0 < t_nav["auto"] <= 10.5
    assert tilt_sd["auto"] <= prior + 0.05
    assert t_nav["1s"] < 2.0
    assert tilt_sd["1s"] > 4.5


@pytest.mark.skipif(not (DATA / "px4-x8-flight/InputFilesPX4.zip").exists(),
                    reason="../shared/data not present")
def test_a_real_fixed_wing_gyro_is_not_read_as_white_noise() -> None:
    """GIVEN the X8's raw autopilot IMU (gyro second differences 1,000x the consumer ARW^2
    in flight: turbulence and manoeuvres), THEN the floors stay 1 over the whole log."""
    from navd.io.logs import LogOptions, read_log
    data = read_log(DATA / "px4-x8-flight/InputFilesPX4.zip", None, LogOptions())
    dt = np.diff(data.imu_t_us) * 1e-6
    n = m.ImuNoise(ARW, VRW, 25.0, True)
    q = np.zeros(15)
    for t_us, row, d in zip(data.imu_t_us[1:], data.imu_inc[1:], dt, strict=True):
        if d > 0:
            _push(n, q, float(t_us), row, float(d))
    assert n.gyro_floor == 1.0
    assert n.accel_floor == 1.0


def test_navigation_starts_with_the_floor_after_a_one_second_levelling() -> None:
    """GIVEN noise_x3's IMU and a levelling of 1 s (level_max_time_s = 1; car480 starts
    straight and unaccelerated, so the levelling is trusted),
    THEN the first propagation already has the accelerometer floor (about 9; one second has
    no two 4-s windows to agree, so only the trusted levelling's window can give it), and
    the same start judged untrusted (static_rate_tol_dps = 0.001) does not."""
    noisy = {"imu.arw_rad_per_sqrt_s": 3 * 0.24 * DEG / 60.0, "imu.vrw_mps_per_sqrt_s": 3 * 0.3}
    run = generate(load_scenario("car480", {"duration_s": 5.0, **noisy}), seed=1,
                   progress=False)
    est = build_estimator(load_config(None, ["init.level_max_time_s=1"]))
    for s in run.samples():
        est.push(s)
        if est.initialized:
            break
    assert est.counters.get("level_not_static", 0) == 0
    assert est.imu_noise.accel_floor == pytest.approx(9.0, rel=0.25)
    assert est.buf[st.Q + 3] == pytest.approx(est.imu_noise.accel_floor * VRW**2)
    turning = build_estimator(load_config(None, ["init.level_max_time_s=1",
                                                 "init.static_rate_tol_dps=0.001"]))
    for s in run.samples():
        turning.push(s)
        if turning.initialized:
            break
    assert turning.counters["level_not_static"] == 1
    assert turning.imu_noise.accel_floor == 1.0
