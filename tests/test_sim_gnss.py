"""GNSS model: noise levels, course noise, velocity-jump bursts, dropouts, latency, frames."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
import pytest

from firmware_sim import SimRun, generate, load_scenario
from firmware_sim.sensors import mats_ne
from navd.core.earth import ecef_to_geodetic, geodetic_to_ecef, mat_ne, radii
from navd.types import GnssSample, ImuSample

Arr = npt.NDArray[np.float64]


@pytest.fixture(scope="module")
def car() -> SimRun:
    return generate(load_scenario("car480"), seed=21)


def _truth_at(run: SimRun) -> tuple[Arr, Arr]:
    idx = np.searchsorted(run.truth_t_us, run.gnss["t_us"])
    np.testing.assert_array_equal(run.truth_t_us[idx], run.gnss["t_us"])
    np.testing.assert_array_equal(idx, run.gnss_truth_idx)
    return run.truth_pos[idx], run.truth_vel_n[idx]


def test_epochs_and_accuracy_fields(car: SimRun) -> None:
    """GIVEN the car480 scenario (480 s, 10 Hz GNSS, no jumps, no latency),
    WHEN its GNSS table is generated,
    THEN it has 4800 epochs 100 ms apart with int64 times, no outliers, arrival equal to
    validity time, and the reported accuracies are 10 m horizontal and 0.1 m/s velocity."""
    g = car.gnss
    assert g["t_us"].dtype == np.int64
    assert g["outlier"].dtype == np.bool_
    np.testing.assert_array_equal(np.diff(g["t_us"]), 100_000)
    assert g["t_us"].shape[0] == 4800
    assert not g["outlier"].any()
    np.testing.assert_array_equal(g["t_arrival_us"], g["t_us"])
    assert np.all(g["h_acc_m"] == 10.0)
    assert np.all(g["vel_acc_mps"] == 0.1)


def test_noise_levels(car: SimRun) -> None:
    """GIVEN the car480 GNSS fixes and the truth at the same instants,
    WHEN the fix errors are taken per axis,
    THEN velocity noise has a std of 0.1 m/s (5 %) and north/east/down position noise a std
    of 10 m (5 %) with a mean under 0.6 m."""
    pos, vel = _truth_at(car)
    g = car.gnss
    dv = np.stack([g["vel_n"], g["vel_e"], g["vel_d"]], axis=1) - vel
    np.testing.assert_allclose(dv.std(axis=0), 0.1, rtol=0.05)
    r_m, r_n = radii(float(pos[0, 0]))
    dn = (np.radians(g["lat_deg"]) - pos[:, 0]) * (r_m + pos[:, 2])
    de = (np.radians(g["lon_deg"]) - pos[:, 1]) * (r_n + pos[:, 2]) * np.cos(pos[:, 0])
    dh = g["alt_m"] - pos[:, 2]
    for d in (dn, de, dh):
        assert d.std() == pytest.approx(10.0, rel=0.05)
        assert abs(d.mean()) < 0.6


def test_course_noise_matches_sigma_over_speed(car: SimRun) -> None:
    """GIVEN the car480 GNSS velocities and the true velocities,
    WHEN the course-over-ground error is taken wherever the speed exceeds 5 m/s,
    THEN the error scaled by speed / velocity sigma has unit std (10 %), and on the 20 m/s
    straight from 75 to 145 s its std is 0.1/20 rad (15 %)."""
    _, vel = _truth_at(car)
    g = car.gnss
    vh = np.hypot(vel[:, 0], vel[:, 1])
    m = vh > 5.0
    err = np.angle(np.exp(1j * (np.arctan2(g["vel_e"], g["vel_n"])
                                - np.arctan2(vel[:, 1], vel[:, 0]))))[m]
    z = err * vh[m] / g["vel_acc_mps"][m]
    assert z.std() == pytest.approx(1.0, rel=0.10)
    # and in absolute terms at constant speed (20 m/s from 70 to 150 s): 0.1/20 rad
    t = car.gnss["t_us"] * 1e-6
    seg = (t > 75.0) & (t < 145.0)
    e2 = np.angle(np.exp(1j * (np.arctan2(g["vel_e"], g["vel_n"])
                               - np.arctan2(vel[:, 1], vel[:, 0]))))[seg]
    assert e2.std() == pytest.approx(0.1 / 20.0, rel=0.15)


def _runs(flag: npt.NDArray[np.bool_]) -> list[tuple[int, int]]:
    out = []
    i = 0
    n = flag.shape[0]
    while i < n:
        if flag[i]:
            j = i
            while j < n and flag[j]:
                j += 1
            out.append((i, j))
            i = j
        else:
            i += 1
    return out


def test_velocity_jump_bursts() -> None:
    """GIVEN car480 with velocity jumps enabled and the white velocity noise switched off,
    WHEN the GNSS table is generated,
    THEN there are exactly 6 flagged bursts of 3 to 8 epochs between 60 and 470 s, each with a
    3-5 m/s velocity error in random directions, unflagged epochs are exact, and with jumps
    at their default (off) no epoch is flagged."""
    sc = load_scenario("car480", overrides={"gnss.jumps.enabled": True,
                                            "gnss.vel_sigma_h_mps": 0.0,
                                            "gnss.vel_sigma_v_mps": 0.0})
    run = generate(sc, seed=5)
    _, vel = _truth_at(run)
    g = run.gnss
    jump = np.stack([g["vel_n"], g["vel_e"], g["vel_d"]], axis=1) - vel
    mag = np.linalg.norm(jump, axis=1)
    flag = g["outlier"]
    runs = _runs(flag)
    assert len(runs) == sc.gnss.jumps.bursts == 6
    for a, b in runs:
        assert 3 <= b - a <= 8
    assert np.all((mag[flag] >= 3.0 - 1e-9) & (mag[flag] <= 5.0 + 1e-9))
    assert np.all(mag[~flag] < 1e-9)
    t = g["t_us"][flag] * 1e-6
    assert t.min() >= 60.0
    assert t.max() <= 470.0
    dirs = jump[flag] / mag[flag, None]
    assert np.linalg.norm(dirs.mean(axis=0)) < 0.6      # random, not one direction
    # off by default
    assert not generate(load_scenario("car480", overrides={"duration_s": 100.0}),
                        seed=5).gnss["outlier"].any()


def test_jumps_with_noise_keep_the_flag_column() -> None:
    """GIVEN car480 with velocity jumps enabled and the normal velocity noise left on,
    WHEN the GNSS table is generated,
    THEN at least 18 epochs are flagged as outliers, every flagged epoch errs by more than
    2.4 m/s and every unflagged one by less than 0.8 m/s."""
    run = generate(load_scenario("car480", overrides={"gnss.jumps.enabled": True}), seed=9)
    _, vel = _truth_at(run)
    g = run.gnss
    mag = np.linalg.norm(np.stack([g["vel_n"], g["vel_e"], g["vel_d"]], axis=1) - vel, axis=1)
    assert g["outlier"].sum() >= 18
    assert mag[g["outlier"]].min() > 2.4
    assert mag[~g["outlier"]].max() < 0.8


def test_dropouts() -> None:
    """GIVEN the drive_long scenario (5 Hz GNSS) with dropouts at 650-680 s and 900-905 s,
    WHEN its GNSS table is generated,
    THEN no fix falls inside either window and the only gaps longer than 200 ms are
    5.2 s and 30.2 s."""
    run = generate(load_scenario("drive_long"), seed=1)
    t = run.gnss["t_us"] * 1e-6
    assert not np.any((t >= 650.0) & (t < 680.0))
    assert not np.any((t >= 900.0) & (t < 905.0))
    gaps = np.diff(run.gnss["t_us"])
    assert gaps.min() == 200_000
    assert sorted(gaps[gaps > 200_000].tolist()) == [5_200_000, 30_200_000]


def test_frames_consistent(car: SimRun) -> None:
    """GIVEN the car480 GNSS fixes, which carry both geodetic/NED and ECEF columns,
    WHEN a sample of epochs is converted between the frames,
    THEN ECEF and NED velocities, geodetic and ECEF positions agree to round-off in both
    directions, and the vectorised mats_ne matches mat_ne exactly."""
    g = car.gnss
    lat = np.radians(g["lat_deg"])
    lon = np.radians(g["lon_deg"])
    vn = np.stack([g["vel_n"], g["vel_e"], g["vel_d"]], axis=1)
    ve = np.stack([g["vel_x_ecef"], g["vel_y_ecef"], g["vel_z_ecef"]], axis=1)
    for k in range(0, lat.shape[0], 97):
        c = mat_ne(float(lat[k]), float(lon[k]))
        np.testing.assert_allclose(ve[k], c.T @ vn[k], atol=1e-12)
        np.testing.assert_allclose(c @ ve[k], vn[k], atol=1e-12)
        x, y, z = g["x_ecef"][k], g["y_ecef"][k], g["z_ecef"][k]
        np.testing.assert_allclose(geodetic_to_ecef(float(lat[k]), float(lon[k]),
                                                    float(g["alt_m"][k])), (x, y, z), atol=1e-6)
        la, lo, h = ecef_to_geodetic(float(x), float(y), float(z))
        assert la == pytest.approx(lat[k], abs=1e-12)
        assert lo == pytest.approx(lon[k], abs=1e-12)
        assert h == pytest.approx(g["alt_m"][k], abs=1e-5)
    np.testing.assert_allclose(np.linalg.norm(ve, axis=1), np.linalg.norm(vn, axis=1),
                               rtol=1e-12, atol=1e-12)
    m = mats_ne(lat[:5], lon[:5])
    for k in range(5):
        np.testing.assert_array_equal(m[k], mat_ne(float(lat[k]), float(lon[k])))


def test_gnss_samples_and_merge_order() -> None:
    """GIVEN a 5 s car480 run (10 Hz GNSS, 100 Hz IMU),
    WHEN it is read as GnssSample, ImuSample and merged sample streams,
    THEN there are 50 fixes and 500 IMU samples with fields copied from the tables, and in the
    merged stream of 550 each fix comes right after the IMU sample of the same time."""
    run = generate(load_scenario("car480", overrides={"duration_s": 5.0}), seed=1)
    gs = list(run.gnss_samples())
    assert len(gs) == 50
    s0 = gs[0]
    assert s0.t_us == 100_000
    assert s0.lat_rad == pytest.approx(math.radians(run.gnss["lat_deg"][0]), abs=1e-15)
    assert s0.vel_acc_mps == 0.1
    assert s0.h_acc_m == 10.0
    assert s0.pos_ecef_m is not None and s0.vel_ecef_mps is not None
    assert s0.pos_ecef_m[0] == run.gnss["x_ecef"][0]
    imu = list(run.imu_samples())
    assert len(imu) == 500
    assert imu[0].t_us == 10_000 and imu[0].dt_us == 10_000
    assert imu[3].dtheta_y == run.imu_inc[3, 1]
    merged = list(run.samples())
    assert len(merged) == 550
    last_imu_t = -1
    for s in merged:
        if isinstance(s, ImuSample):
            last_imu_t = s.t_us
        else:
            assert isinstance(s, GnssSample)
            assert last_imu_t == s.t_us          # right after the IMU sample of the same time


def test_stamped_on_arrival_carries_the_arrival_time() -> None:
    """GIVEN the same 5 s car480 run with 0.2 s latency and gnss.stamped_on_arrival (an
    autopilot that stamps fixes on receipt), THEN every fix's t_us is its arrival time,
    validity + 200 ms, its velocity is still the truth of its time of validity (the same
    draw as without the flag), and each fix follows the IMU sample of its own stamp."""
    base = {"duration_s": 5.0, "gnss.latency_s": 0.2}
    plain = generate(load_scenario("car480", overrides=base), seed=1).gnss
    run = generate(load_scenario("car480", overrides={**base,
                                                      "gnss.stamped_on_arrival": True}),
                   seed=1)
    g = run.gnss
    np.testing.assert_array_equal(g["t_us"], plain["t_us"] + 200_000)
    np.testing.assert_array_equal(g["t_arrival_us"], g["t_us"])
    np.testing.assert_array_equal(g["vel_n"], plain["vel_n"])
    last_imu_t = -1
    for s in run.samples():
        if isinstance(s, ImuSample):
            last_imu_t = s.t_us
        elif s.t_us <= run.imu_t_us[-1]:
            assert last_imu_t == s.t_us


def test_latency_delays_arrival_only() -> None:
    """GIVEN a 5 s car480 run with 0.25 s GNSS latency,
    WHEN the GNSS table and the merged sample stream are produced,
    THEN arrival times are validity + 250 ms while validity times are unchanged, and each fix
    is delivered after the IMU sample at its arrival time (or after the last IMU sample)."""
    run = generate(load_scenario("car480", overrides={"duration_s": 5.0,
                                                      "gnss.latency_s": 0.25}), seed=1)
    g = run.gnss
    np.testing.assert_array_equal(g["t_arrival_us"], g["t_us"] + 250_000)
    assert g["t_us"][0] == 100_000                    # time of validity unchanged
    last_imu_t = -1
    seen = 0
    for s in run.samples():
        if isinstance(s, ImuSample):
            last_imu_t = s.t_us
        else:
            if s.t_us + 250_000 <= run.imu_t_us[-1]:
                assert last_imu_t == s.t_us + 250_000
            else:
                assert last_imu_t == run.imu_t_us[-1]
            seen += 1
    # fixes valid after 4.75 s would arrive after the end of the IMU data: delivered last
    assert seen == 50


def test_gauss_markov_position_noise() -> None:
    """GIVEN a 4000 s static run with a 60 s Gauss-Markov time constant on position noise,
    WHEN the autocorrelation of the north position error is taken at a 60 s lag,
    THEN it is exp(-1) (within 0.2), while with the default white noise the lag-one
    autocorrelation stays under 0.1."""
    sc = load_scenario("static", overrides={"duration_s": 4000.0, "gnss.pos_tau_s": 60.0,
                                            "imu.rate_hz": 10.0})
    run = generate(sc, seed=3)
    pos, _ = _truth_at(run)
    r_m, _ = radii(float(pos[0, 0]))
    dn = (np.radians(run.gnss["lat_deg"]) - pos[:, 0]) * (r_m + pos[:, 2])
    dnc = dn - dn.mean()
    rho = (dnc[60:] * dnc[:-60]).mean() / dnc.var()
    assert rho == pytest.approx(math.exp(-1.0), abs=0.2)
    white = generate(load_scenario("static", overrides={"duration_s": 4000.0,
                                                        "imu.rate_hz": 10.0}), seed=3)
    pw, _ = _truth_at(white)
    dw = (np.radians(white.gnss["lat_deg"]) - pw[:, 0]) * (r_m + pw[:, 2])
    dwc = dw - dw.mean()
    assert abs((dwc[1:] * dwc[:-1]).mean() / dwc.var()) < 0.1


def test_antenna_lever_arm_moves_the_fixes_by_c_l_and_c_w_cross_l() -> None:
    """GIVEN the multirotor scenario with a yaw of 90 deg in 1.5 s at 20 s, flown twice with
    the same seed: the antenna at the IMU, and at (0.2, -0.3, -0.25) m from it (body FRD),
    WHEN their GNSS tables are compared,
    THEN each fix of the second lies C l from the first's (NED, to 1 mm) and its velocity
    differs by C (w x l) (to 1e-9 m/s), with C the true attitude and w the true body rate of
    the IMU interval ending at the epoch: up to 0.3 m/s in the yaw, 0 while not turning."""
    lever = np.array([0.2, -0.3, -0.25])
    over = {"duration_s": 30.0,
            "trajectory.turns": [{"t_s": 20.0, "dur_s": 1.5, "dyaw_deg": 90.0}]}
    a = generate(load_scenario("multirotor", over), seed=4)
    b = generate(load_scenario("multirotor", {**over, "gnss.lever_arm_m": lever.tolist()}),
                 seed=4)
    np.testing.assert_array_equal(a.gnss_truth_idx, b.gnss_truth_idx)
    idx = b.gnss_truth_idx
    c = b.truth_mat_nb[idx]
    dt = (b.truth_t_us[1] - b.truth_t_us[0]) * 1e-6
    rate = b.imu_inc_true[idx - 1, :3] / dt
    want_v = np.einsum("kij,kj->ki", c, np.cross(rate, lever))
    got_v = np.column_stack([b.gnss[k] - a.gnss[k] for k in ("vel_n", "vel_e", "vel_d")])
    np.testing.assert_allclose(got_v, want_v, atol=1e-9)
    assert np.max(np.hypot(want_v[:, 0], want_v[:, 1])) > 0.25
    lat = np.radians(a.gnss["lat_deg"])
    r_m = np.array([radii(float(x))[0] for x in lat])
    r_n = np.array([radii(float(x))[1] for x in lat])
    alt = b.truth_pos[idx, 2]
    d_n = np.radians(b.gnss["lat_deg"] - a.gnss["lat_deg"]) * (r_m + alt)
    d_e = np.radians(b.gnss["lon_deg"] - a.gnss["lon_deg"]) * (r_n + alt) * np.cos(
        b.truth_pos[idx, 0])
    d_d = -(b.gnss["alt_m"] - a.gnss["alt_m"])
    np.testing.assert_allclose(np.column_stack([d_n, d_e, d_d]), c @ lever, atol=1e-3)
