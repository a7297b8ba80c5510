"""Simulator truth: error-free increments replay the truth through navd's strapdown, and the
trajectories have the properties the scenarios promise."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
import pytest

from firmware_sim import SimRun, generate, load_scenario
from firmware_sim.profiles import modulation_angle
from firmware_sim.scenario import ModulationSpec
from firmware_sim.truth import euler_to_mats
from navd.core.earth import gravity, radii
from navd.core.rotation import euler_to_mat, log_so3
from navd.core.strapdown import strapdown_step

Arr = npt.NDArray[np.float64]
D2R = math.pi / 180.0


def replay_errors(run: SimRun, check_every: int = 50) -> tuple[float, float, float]:
    """Max attitude (rad), velocity (m/s) and position (m) difference between the strapdown
    fed with the error-free increments and the truth, checked every ``check_every`` steps."""
    c = run.truth_mat_nb[0].copy()
    v = run.truth_vel_n[0].copy()
    p = run.truth_pos[0].copy()
    prev = np.zeros(6)
    work = np.zeros((8, 3, 3))
    dt = run.imu_dt_s
    n = run.imu_inc_true.shape[0]
    att = vel = pos = 0.0
    for k in range(n):
        inc = run.imu_inc_true[k]
        strapdown_step(c, v, p, run.truth_dov[k], inc, prev, dt, True, work)
        prev[:] = inc
        if (k + 1) % check_every == 0 or k == n - 1:
            att = max(att, float(np.linalg.norm(log_so3(c.T @ run.truth_mat_nb[k + 1]))))
            vel = max(vel, float(np.abs(v - run.truth_vel_n[k + 1]).max()))
            r_m, r_n = radii(float(p[0]))
            d = (p - run.truth_pos[k + 1]) * np.array([r_m + p[2], (r_n + p[2]) * math.cos(p[0]),
                                                       1.0])
            pos = max(pos, float(np.abs(d).max()))
    return att, vel, pos


@pytest.fixture(scope="module")
def car() -> SimRun:
    return generate(load_scenario("car480"), seed=1)


def test_car480_full_replay(car: SimRun) -> None:
    """GIVEN the full car480 run (48000 IMU steps),
    WHEN its error-free increments are replayed through navd's strapdown,
    THEN attitude, velocity and position stay within 1e-9 rad, 1e-6 m/s and 1 mm of the truth."""
    assert car.imu_inc_true.shape == (48000, 6)
    att, vel, pos = replay_errors(car)
    assert att <= 1e-9
    assert vel <= 1e-6
    assert pos <= 1e-3


@pytest.mark.parametrize(("name", "duration"), [
    ("drive_long", 400.0), ("multirotor", 240.0), ("ship_dov", 3600.0), ("static", 200.0),
    ("pol_static", 300.0),
])
def test_scenario_replay(name: str, duration: float) -> None:
    """GIVEN the drive_long, multirotor, ship_dov, static and pol_static scenarios at a set
    duration,
    WHEN each is generated and its error-free increments replayed through the strapdown,
    THEN the truth ends at that duration and the replay stays within 1e-9 rad, 1e-6 m/s, 1 mm."""
    run = generate(load_scenario(name, overrides={"duration_s": duration}), seed=3)
    assert run.truth_t_us[-1] == round(duration * 1e6)
    att, vel, pos = replay_errors(run)
    assert att <= 1e-9
    assert vel <= 1e-6
    assert pos <= 1e-3


def test_static_sway_spans_the_seed_tilt_range() -> None:
    """GIVEN pol_static for 600 s set at 30 deg pitch,
    WHEN it is generated,
    THEN the pitch sways over 3.0-3.6 deg (the seed's 28.65-32.14 deg range) with zero velocity."""
    run = generate(load_scenario("pol_static", {"duration_s": 600.0,
                                                "trajectory.pitch_deg": 30.0}), seed=1)
    pitch = np.degrees(run.truth_euler[:, 1])
    assert 3.0 < pitch.max() - pitch.min() < 3.6  # seed Table S1: 28.65~32.14 at 30 deg
    assert np.abs(run.truth_vel_n).max() == 0.0


def test_replay_detects_a_wrong_dov() -> None:
    """GIVEN a ship_dov run whose deflection of the vertical is non-zero,
    WHEN it is replayed through the strapdown with the DOV left out,
    THEN the final velocity is off by more than 1 mm/s: the replay check sees the DOV."""
    run = generate(load_scenario("ship_dov", overrides={"duration_s": 600.0}), seed=3)
    assert np.abs(run.truth_dov[:, :2]).max() > 1e-6
    c = run.truth_mat_nb[0].copy()
    v = run.truth_vel_n[0].copy()
    p = run.truth_pos[0].copy()
    prev = np.zeros(6)
    work = np.zeros((8, 3, 3))
    for k in range(run.imu_inc_true.shape[0]):
        strapdown_step(c, v, p, np.zeros(3), run.imu_inc_true[k], prev, run.imu_dt_s, True, work)
        prev[:] = run.imu_inc_true[k]
    assert np.abs(v - run.truth_vel_n[-1]).max() > 1e-3


def test_euler_to_mats_matches_navd() -> None:
    """GIVEN 20 random Euler angle triples (pitch within +-1.2 rad),
    WHEN the simulator's vectorised euler_to_mats converts them,
    THEN each matrix equals navd's euler_to_mat to 1e-15."""
    rng = np.random.default_rng(0)
    e = rng.uniform(-3.0, 3.0, (20, 3))
    e[:, 1] /= 2.5
    m = euler_to_mats(e)
    for i in range(e.shape[0]):
        np.testing.assert_allclose(m[i], euler_to_mat(*e[i]), atol=1e-15)


def _course(v: Arr) -> Arr:
    return np.arctan2(v[:, 1], v[:, 0])


def _wrap(a: Arr) -> Arr:
    return np.asarray(np.angle(np.exp(1j * a)), dtype=np.float64)


def test_car480_profile(car: SimRun) -> None:
    """GIVEN the car480 run,
    WHEN its truth and error-free increments are examined,
    THEN it is level and unaccelerated at 10 m/s for 10 s, cruises at 10-24 m/s, turns at
    up to ~9 deg/s with an S-curve at 95-125 s, has road grade, course equal to yaw (no
    sideslip) and roll following the lateral acceleration."""
    t = car.truth_t_us * 1e-6
    v = car.truth_vel_n
    speed = np.linalg.norm(v, axis=1)
    # moving from the start (10-24 m/s throughout, as in seed 001), straight and
    # unaccelerated for the first 10 s so the accelerometer can level
    assert np.allclose(speed[t < 10.0], 10.0, atol=1e-9)
    # only Coriolis/transport-rate specific force (~8e-4 m/s^2) while cruising straight
    assert np.abs(car.imu_inc_true[:999, 3:5]).max() / car.imu_dt_s < 2e-3
    cruise = t >= 0.0
    assert speed[cruise].min() >= 10.0 - 1e-9
    assert speed[cruise].max() <= 24.0 + 1e-9
    assert speed[cruise].max() >= 23.9
    # turns up to ~9 deg/s, including both directions
    yaw_rate = car.imu_inc_true[:, 2] / car.imu_dt_s
    assert 8.5 * D2R < np.abs(yaw_rate).max() < 9.2 * D2R
    # an S-curve: yaw rate changes sign twice between 95 and 125 s
    seg = (t[1:] > 95.0) & (t[1:] < 125.0)
    sgn = np.sign(yaw_rate[seg][np.abs(yaw_rate[seg]) > 1.0 * D2R])
    assert np.count_nonzero(np.diff(sgn)) == 2
    # road grade
    pitch = car.truth_euler[:, 1]
    assert pitch.max() > 2.5 * D2R
    assert pitch.min() < -3.5 * D2R
    # no sideslip: GNSS course is yaw exactly
    mv = speed > 0.5
    assert np.abs(_wrap(_course(v[mv]) - car.truth_euler[mv, 2])).max() < 1e-12
    # roll follows the lateral acceleration (gain -0.01 rad per m/s^2)
    vh = np.hypot(v[:, 0], v[:, 1])
    yaw_unwrapped = np.unwrap(car.truth_euler[:, 2])
    rate = np.gradient(yaw_unwrapped, car.imu_dt_s)
    a_lat = vh * rate
    np.testing.assert_allclose(car.truth_euler[:, 0], -0.01 * a_lat, atol=2e-5)
    assert np.abs(car.truth_euler[:, 0]).max() > 1.0 * D2R


def test_sideslip_option_moves_course_off_yaw() -> None:
    """GIVEN car480 for 60 s with a sideslip gain of 0.005 rad per m/s^2,
    WHEN it is generated,
    THEN the course departs from the yaw by more than 0.5 deg while moving, and the
    strapdown replay still matches the attitude to 1e-9 rad."""
    sc = load_scenario("car480", overrides={"duration_s": 60.0,
                                            "trajectory.sideslip_gain_rad_per_mps2": 0.005})
    run = generate(sc, seed=1)
    v = run.truth_vel_n
    mv = np.linalg.norm(v, axis=1) > 1.0
    beta = _wrap(_course(v[mv]) - run.truth_euler[mv, 2])
    assert np.abs(beta).max() > 0.5 * D2R
    assert replay_errors(run)[0] <= 1e-9


def test_drive_long_has_stops_and_crawling() -> None:
    """GIVEN the drive_long scenario,
    WHEN it is generated,
    THEN it lasts 1200 s, stops at least four separate times after the first 20 s,
    and spends over 100 s crawling at 0.5-3 m/s."""
    run = generate(load_scenario("drive_long"), seed=1)
    t = run.truth_t_us * 1e-6
    speed = np.linalg.norm(run.truth_vel_n, axis=1)
    assert run.truth_t_us[-1] == 1_200_000_000
    stopped = (speed == 0.0) & (t > 20.0)
    # several separate stops after the start
    starts = np.flatnonzero(np.diff(stopped.astype(int)) == 1)
    assert starts.size >= 4
    crawl = (speed > 0.5) & (speed < 3.0)
    assert np.count_nonzero(crawl) * run.imu_dt_s > 100.0


def test_multirotor_tilt_and_course() -> None:
    """GIVEN the multirotor scenario,
    WHEN it is generated,
    THEN the body z axis follows the thrust (acceleration, drag, gravity) within 0.05 deg,
    it hovers level for 14 s then tilts past 8 deg, and flies sideways (course 90 deg off
    yaw) at 72-84 s and backwards (180 deg) at 102-114 s."""
    run = generate(load_scenario("multirotor"), seed=1)
    sc = run.scenario
    t = run.truth_t_us * 1e-6
    v = run.truth_vel_n
    a = np.gradient(v, run.imu_dt_s, axis=0)
    g = gravity(sc.trajectory.lat_deg * D2R, sc.trajectory.alt_m)
    thrust = a + 0.35 * v - np.array([0.0, 0.0, g])
    z_b = run.truth_mat_nb[:, :, 2]
    cosang = -np.sum(z_b * thrust, axis=1) / np.linalg.norm(thrust, axis=1)
    assert np.degrees(np.arccos(np.clip(cosang, -1.0, 1.0))).max() < 0.05
    tilt = np.degrees(np.arccos(run.truth_mat_nb[:, 2, 2]))
    assert tilt[t < 14.0].max() < 1e-9          # hover is level
    assert tilt.max() > 8.0
    crs = _course(v)
    yaw = run.truth_euler[:, 2]
    side = (t > 72.0) & (t < 84.0)
    back = (t > 102.0) & (t < 114.0)
    np.testing.assert_allclose(np.degrees(_wrap(crs[side] - yaw[side])), 90.0, atol=1e-9)
    np.testing.assert_allclose(np.abs(np.degrees(_wrap(crs[back] - yaw[back]))), 180.0,
                               atol=1e-9)


def test_ship_modulation_and_dov() -> None:
    """GIVEN ship_dov for 2400 s,
    WHEN it is generated,
    THEN the heading dwells at 0 then 180 deg of modulation turned at 18 deg/s, the ship is
    still for 600 s then cruises at 10 m/s towards 45 deg, and both DOV components are
    20 arcsec sinusoids with a 10 h period."""
    sc = load_scenario("ship_dov", overrides={"duration_s": 2400.0})
    run = generate(sc, seed=1)
    t = run.truth_t_us * 1e-6
    yaw = run.truth_euler[:, 2]
    mod = np.degrees(_wrap(yaw - 45.0 * D2R))
    m = sc.trajectory.modulation  # type: ignore[union-attr]
    t_rot = 180.0 / 18.0 + m.ramp_s
    # dwell 0 deg, rotate, dwell 180 deg, rotate back
    np.testing.assert_allclose(mod[t < 300.0], 0.0, atol=1e-9)
    dwell2 = (t > 300.0 + t_rot) & (t < 600.0 + t_rot)
    np.testing.assert_allclose(np.abs(mod[dwell2]), 180.0, atol=1e-9)
    rate = run.imu_inc_true[:, 2] / run.imu_dt_s
    assert np.degrees(np.abs(rate).max()) == pytest.approx(18.0, rel=1e-3)
    # cruise at 10 m/s north-east after static + acceleration
    cruise = t > 600.0 + 120.0
    v = run.truth_vel_n[cruise]
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), 10.0, rtol=1e-12)
    np.testing.assert_allclose(np.degrees(_course(v)), 45.0, atol=1e-9)
    assert np.all(run.truth_vel_n[t < 600.0] == 0.0)
    # DOV: 20 arcsec sinusoids with a 10 h period
    arcsec = D2R / 3600.0
    np.testing.assert_allclose(run.truth_dov[:, 0], 20.0 * arcsec * np.sin(2 * np.pi * t / 36000),
                               atol=1e-15)
    np.testing.assert_allclose(run.truth_dov[:, 1], 20.0 * arcsec * np.sin(2 * np.pi * t / 36000),
                               atol=1e-15)


def test_modulation_angle_is_continuous() -> None:
    """GIVEN a modulation spec at 18 deg/s with 5 s dwells and 1 s ramps,
    WHEN the modulation angle is sampled every 1 ms for 60 s,
    THEN it stays within 0-180 deg and never steps faster than 18 deg/s."""
    m = ModulationSpec(enabled=True, rate_rps=18.0 * D2R, dwell_s=5.0, ramp_s=1.0)
    t = np.arange(0.0, 60.0, 1e-3)
    a = modulation_angle(t, m)
    assert np.degrees(a).min() >= -1e-9
    assert np.degrees(a).max() <= 180.0 + 1e-9
    assert np.degrees(np.abs(np.diff(a)).max() / 1e-3) <= 18.0 + 1e-6


def test_duration_scale_and_truncation_keep_the_prefix() -> None:
    """GIVEN car480 for 40 s, and car480 for 80 s scaled by 0.25, with the same seed,
    WHEN both are generated,
    THEN the scaled run has 2000 IMU steps and its increments (true and noisy), truth
    positions and GNSS velocities equal the start of the 40 s run."""
    long = generate(load_scenario("car480", overrides={"duration_s": 40.0}), seed=5)
    short = generate(load_scenario("car480", overrides={"duration_s": 80.0,
                                                        "duration_scale": 0.25}), seed=5)
    n = short.imu_inc.shape[0]
    assert n == 2000
    np.testing.assert_array_equal(short.imu_inc_true, long.imu_inc_true[:n])
    np.testing.assert_array_equal(short.imu_inc, long.imu_inc[:n])
    np.testing.assert_array_equal(short.truth_pos, long.truth_pos[: n + 1])
    m = short.gnss["t_us"].shape[0]
    np.testing.assert_array_equal(short.gnss["vel_n"], long.gnss["vel_n"][:m])
