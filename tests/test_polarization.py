"""Polarization-compass aiding: model, Jacobian, ambiguity, gating, config, and the simulator."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from firmware_sim.polarization import (
    parse_utc,
    predict_aop,
    rayleigh_dop,
    simulate_polarization,
)
from firmware_sim.run import generate
from firmware_sim.scenario import PolarizationSpec, ScenarioError, load_scenario
from navd.config import (
    ConfigError,
    EstimatorConfig,
    PolarizationSection,
    build_section,
    load_config,
)
from navd.config.aiding import polarization_section
from navd.core.aiding.polarization import (
    PolarizationAiding,
    _wrap_half_pi,
    build_polarization,
)
from navd.core.estimator import Estimator
from navd.core.rotation import euler_to_mat, exp_so3, log_vec, mat_to_euler
from navd.core.sun import sun_az_el, sun_ned
from navd.types import GnssSample, ImuSample, PolSample

D2R = math.pi / 180.0
MOUNT0 = {"mount_roll_deg": 0.0, "mount_pitch_deg": 0.0, "mount_yaw_deg": 0.0}
UTC0 = parse_utc("2020-06-01T18:12:00+08:00")
LAT, LON = 20.0 * D2R, 120.0 * D2R


def _pol_section(table: dict[str, Any]) -> PolarizationSection:
    return build_section(PolarizationSection, "polarization", table)


def _aid(table: dict[str, Any]) -> PolarizationAiding:
    """The aid a [polarization] table (TOML keys) describes."""
    return PolarizationAiding(_pol_section(table))


def _unit(v: Any) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


# ---------------------------------------------------------------------------- model
def test_level_sensor_evector_is_perpendicular_to_the_solar_meridian() -> None:
    """GIVEN a level sensor aligned with the body, and the sun due east on the horizon, due north,
    or at random azimuths and elevations with random vehicle yaws,
    WHEN the zenith angle of polarization (AoP) is predicted,
    THEN it is 0 (E-vector north-south) for the east sun, pi/2 for the north sun, and
    (sun azimuth + 90 deg) - yaw, mod pi, in general."""
    eye = np.eye(3)
    # sun due east on the horizon: E-vector north-south, i.e. along body x at yaw 0
    assert predict_aop(eye, eye, np.array([0.0, 1.0, 0.0]))[0] == pytest.approx(0.0)
    # sun due north: E-vector east-west = body y: alpha = pi/2
    assert predict_aop(eye, eye, np.array([1.0, 0.0, 0.0]))[0] == pytest.approx(math.pi / 2)
    # at any sun elevation the zenith AoP of a level sensor is (sun azimuth + 90) - yaw, mod pi
    rng = np.random.default_rng(3)
    for _ in range(50):
        az, el, yaw = rng.uniform(0, 2 * math.pi), rng.uniform(-0.1, 1.4), rng.uniform(-3, 3)
        s = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), -math.sin(el)])
        a, _ = predict_aop(euler_to_mat(0.0, 0.0, yaw), eye, s)
        assert _wrap_half_pi(a - (az + math.pi / 2 - yaw)) == pytest.approx(0.0, abs=1e-12)


def test_h_matches_finite_differences_of_the_nonlinear_model() -> None:
    """GIVEN 300 random attitudes, sensor mountings and sun directions,
    WHEN predict_aop gives the AoP and its row H,
    THEN H matches central differences of z = alpha(C_hat) - alpha(C), C_hat = Exp(-phi) C, and
    for a sensor aligned with the body it equals docs/design.md §7's row."""
    rng = np.random.default_rng(11)
    eps = 1e-6
    for trial in range(300):
        c_hat = euler_to_mat(*rng.uniform(-1.5, 1.5, 3))
        mat_sb = euler_to_mat(*rng.uniform(-0.8, 0.8, 3))
        s_n = _unit(rng.normal(size=3))
        _, h = predict_aop(c_hat, mat_sb, s_n)
        num = np.zeros(3)
        for k in range(3):
            d = np.zeros(3)
            d[k] = eps
            ap, _ = predict_aop(exp_so3(d) @ c_hat, mat_sb, s_n)
            am, _ = predict_aop(exp_so3(-d) @ c_hat, mat_sb, s_n)
            num[k] = -_wrap_half_pi(ap - am) / (2 * eps)
        assert np.allclose(h, num, rtol=1e-5, atol=1e-6 * max(1.0, float(np.abs(h).max())))
        # docs/design.md §7's row for a sensor aligned with the body
        if trial < 20:
            sb = c_hat.T @ s_n
            skew = np.array([[0, -s_n[2], s_n[1]], [s_n[2], 0, -s_n[0]], [-s_n[1], s_n[0], 0]])
            design = np.array([-sb[1], sb[0], 0]) / (sb[0] ** 2 + sb[1] ** 2) @ (-c_hat.T @ skew)
            assert np.allclose(predict_aop(c_hat, np.eye(3), s_n)[1], design)


def test_pi_ambiguity_gives_the_same_innovation() -> None:
    """GIVEN random predicted and measured AoPs in [0, pi),
    WHEN the innovation is wrapped,
    THEN it lies in [-pi/2, pi/2), is the same for the reading shifted by +-pi, and a reading
    just across the wrap (pi - 0.003 for a true 0.002) gives a small innovation (0.005)."""
    rng = np.random.default_rng(5)
    for _ in range(100):
        a_hat, a = rng.uniform(0, math.pi, 2)
        z = _wrap_half_pi(a_hat - a)
        assert -math.pi / 2 <= z < math.pi / 2
        assert _wrap_half_pi(a_hat - (a + math.pi)) == pytest.approx(z)
        assert _wrap_half_pi(a_hat - (a - math.pi)) == pytest.approx(z)
    # a reading just across the wrap (pi - 0.003 for a true 0.002) is a small innovation
    assert _wrap_half_pi(0.002 - (math.pi - 0.003)) == pytest.approx(0.005)


# ---------------------------------------------------------------------------- estimator
def _nav_estimator(aid: PolarizationAiding, yaw_deg: float = 210.0,
                   yaw_err_deg: float = 5.0) -> Estimator:
    """A navigating estimator, level, static at 20N 120E; heading off by yaw_err_deg."""
    cfg = EstimatorConfig.from_dict(load_config(None, [
        "init.heading_source=config", f"init.heading_deg={yaw_deg + yaw_err_deg}",
        "init.heading_sd_deg=10"]))
    est = Estimator(cfg, pol=aid)
    g = 9.78
    t = 0
    for _ in range(220):  # two agreeing fixes are needed to start
        t += 10_000
        est.push(ImuSample(t, 10_000, 0.0, 0.0, 0.0, 0.0, 0.0, -g * 0.01))
        if t % 1_000_000 == 0:
            est.push(GnssSample(t, LAT, LON, 50.0, 0.0, 0.0, 0.0, 2.0, 3.0, 0.05))
    assert est.initialized
    return est


def _true_aop(yaw_deg: float, utc: float, mount: tuple[float, float, float] = (0, 0, 0)
              ) -> float:
    s_n = sun_ned(utc, LAT, LON, 50.0)
    msb = euler_to_mat(*(np.array(mount) * D2R)).T
    return predict_aop(euler_to_mat(0.0, 0.0, yaw_deg * D2R), msb, s_n)[0]


def test_update_corrects_heading_and_refusals_are_counted() -> None:
    """GIVEN a navigating, level, static estimator with the heading 5 deg off (sigma 10 deg),
    WHEN readings with too low a DoP, a bad AoP or DoP, a bad or missing UTC, too old a time or
    the sun below the horizon are pushed, then one good reading,
    THEN each bad one is refused, counted under its reason and leaves P and the attitude
    untouched, and the good one is accepted and brings the heading within 0.5 deg."""
    aid = _aid(MOUNT0)
    est = _nav_estimator(aid)
    t = est.t_us
    a = _true_aop(210.0, UTC0)
    p_before = est.P.copy()
    mat_before = est.mat_nb.copy()

    def refused(sample: PolSample, counter: str) -> None:
        n = est.counters[counter]
        assert not est.push(sample)
        assert est.counters[counter] == n + 1
        assert np.array_equal(est.P, p_before) and np.array_equal(est.mat_nb, mat_before)

    refused(PolSample(t, a, 0.01, UTC0), "pol_low_dop")
    for bad_a, bad_d in ((math.pi, 0.6), (-0.1, 0.6), (math.nan, 0.6), (a, math.nan),
                         (a, 1.5), (math.inf, 0.6)):
        refused(PolSample(t, bad_a, bad_d, UTC0), "pol_bad_input")
    refused(PolSample(t, a, 0.6, parse_utc("1965-01-01T00:00:00Z")), "pol_bad_time")
    refused(PolSample(t, a, 0.6, math.nan), "pol_bad_time")
    refused(PolSample(t - 2_000_000, a, 0.6, UTC0), "pol_too_old")
    refused(PolSample(t, a, 0.6, UTC0 + 3600.0), "pol_sun_too_low")  # 19:12 local: dark
    assert est.counters["pol_accepted"] == 0

    assert est.push(PolSample(t, a, 0.6, UTC0))
    assert est.counters["pol_accepted"] == 1
    yaw = math.degrees(mat_to_euler(est.mat_nb)[2]) % 360.0
    assert abs(yaw - 210.0) < 0.5  # 5 deg error, sigma 10 deg prior, 0.3 deg reading


def test_pi_ambiguous_reading_is_resolved_by_the_ins_prior() -> None:
    """GIVEN a heading where the true AoP is ~0.001 rad and an estimator 3 deg off,
    WHEN the reading arrives as 0.003 rad or as pi - 0.002 rad (the pi ambiguity),
    THEN both are accepted with an innovation < 4 deg, both bring the heading within 0.6 deg,
    and the two results agree within 0.4 deg."""
    s_n = sun_ned(UTC0, LAT, LON, 50.0)
    az = math.atan2(s_n[1], s_n[0])
    yaw = math.degrees(az + math.pi / 2 - 0.001) % 360.0  # true AoP ~ 0.001 rad
    a_true = _true_aop(yaw, UTC0)
    assert min(a_true, math.pi - a_true) < 0.01
    finals = []
    for reading in (0.003, math.pi - 0.002):
        est = _nav_estimator(_aid(MOUNT0), yaw_deg=yaw,
                             yaw_err_deg=3.0)
        assert est.push(PolSample(est.t_us, reading, 0.6, UTC0))
        assert est.pol is not None
        assert abs(est.pol.last_innovation) < 4.0 * D2R  # type: ignore[attr-defined]
        y = math.degrees(mat_to_euler(est.mat_nb)[2]) % 360.0
        finals.append((y - yaw + 180.0) % 360.0 - 180.0)
    assert all(abs(f) < 0.6 for f in finals)
    assert abs(finals[0] - finals[1]) < 0.4


def test_sun_near_boresight_is_refused() -> None:
    """GIVEN a sensor pitched so its boresight (-z_s) points 5 deg from the sun,
    WHEN a reading is pushed,
    THEN it is refused and counted as pol_sun_near_boresight."""
    s_n = sun_ned(UTC0, LAT, LON, 50.0)
    _, el = sun_az_el(UTC0, LAT, LON, 50.0)
    az = math.atan2(s_n[1], s_n[0])
    # sensor pitched so its boresight (-z_s) points 5 deg from the sun
    est = _nav_estimator(_aid(
        {"mount_roll_deg": 0.0, "mount_pitch_deg": -(90.0 - math.degrees(el) - 5.0),
         "mount_yaw_deg": 0.0}), yaw_deg=math.degrees(az))
    assert not est.push(PolSample(est.t_us, 1.0, 0.6, UTC0))
    assert est.counters["pol_sun_near_boresight"] == 1


def test_config_builder() -> None:
    """GIVEN [polarization] tables without a mount, without mount_yaw_deg, with an unknown key,
    or with a non-numeric or zero sigma_deg,
    WHEN the section is built,
    THEN each raises a ConfigError naming the problem; no table or enabled = false gives no aid,
    mount_yaw_deg = 90 gives that mounting, and the shipped config gives sigma 0.3 deg."""
    with pytest.raises(ConfigError, match="mount"):
        _pol_section({"sigma_deg": 0.3})
    with pytest.raises(ConfigError, match="mount_yaw_deg"):
        _pol_section({"mount_roll_deg": 0, "mount_pitch_deg": 0})
    with pytest.raises(ConfigError, match="unknown key"):
        _pol_section({**MOUNT0, "sigma": 0.3})
    with pytest.raises(ConfigError, match="sigma_deg"):
        _pol_section({**MOUNT0, "sigma_deg": "x"})
    with pytest.raises(ConfigError, match="sigma_deg"):
        _pol_section({**MOUNT0, "sigma_deg": 0.0})
    assert polarization_section({}) is None
    assert build_polarization(polarization_section({})) is None
    assert polarization_section({"polarization": {**MOUNT0, "enabled": False}}) is None
    aid = build_polarization(
        polarization_section({"polarization": {**MOUNT0, "mount_yaw_deg": 90.0}}))
    assert aid is not None
    assert np.allclose(aid.mat_sb, euler_to_mat(0.0, 0.0, math.pi / 2).T)
    shipped = load_config("config/navd.toml")["polarization"]
    built = _aid(shipped)
    assert built.sigma == pytest.approx(0.3 * D2R)


# ---------------------------------------------------------------------------- simulator
def test_rayleigh_dop() -> None:
    """GIVEN a maximum DoP,
    WHEN the single-scattering DoP is computed for scattering-angle cosines 0, 1, -1 and 0.5,
    THEN it is the maximum, 0, 0 and 0.75 / 1.25 of the maximum."""
    assert rayleigh_dop(0.0, 0.7) == pytest.approx(0.7)
    assert rayleigh_dop(1.0, 0.7) == pytest.approx(0.0)
    assert rayleigh_dop(-1.0, 0.7) == pytest.approx(0.0)
    assert rayleigh_dop(math.cos(math.radians(60)), 1.0) == pytest.approx(0.75 / 1.25)


def test_parse_utc() -> None:
    """GIVEN UTC strings with a +08:00 offset, with Z, without an offset, and a scenario with
    polarization.start_utc = "yesterday",
    WHEN they are parsed,
    THEN +08:00 and Z give the same instant, the missing offset raises ValueError, and the
    scenario raises a ScenarioError naming polarization.start_utc."""
    assert parse_utc("2020-06-01T18:12:00+08:00") == parse_utc("2020-06-01T10:12:00Z")
    with pytest.raises(ValueError, match="offset"):
        parse_utc("2020-06-01T10:12:00")
    with pytest.raises(ScenarioError, match=r"polarization\.start_utc"):
        load_scenario("pol_static", {"polarization.start_utc": "yesterday"})


def test_sim_readings_follow_the_model_and_merge_in_time_order() -> None:
    """GIVEN a simulated 20 s pol_static run, and a static run without the sensor,
    WHEN its polarization readings and merged sample stream are inspected,
    THEN readings are 100 ms apart, the truth AoP is the model's prediction from the true
    attitude, readings are in [0, pi) with < 0.5 deg noise, each directly follows the IMU sample
    of its own time, and without the sensor there are no readings."""
    sc = load_scenario("pol_static", {"duration_s": 20.0})
    run = generate(sc, seed=3)
    assert run.pol is not None
    p = run.pol
    assert np.all(np.diff(p["t_us"]) == 100_000)
    # truth AoP is the model's prediction from the true attitude
    k = int(p["truth_idx"][5])
    s_n = sun_ned(float(p["utc_unix_s"][5]), *run.truth_pos[k])
    a, _ = predict_aop(run.truth_mat_nb[k], np.eye(3), s_n)
    assert a == pytest.approx(float(p["aop_true_rad"][5]), abs=1e-12)
    assert np.all((p["aop_rad"] >= 0) & (p["aop_rad"] < math.pi))
    assert np.std(np.vectorize(_wrap_half_pi)(p["aop_rad"] - p["aop_true_rad"])) < 0.5 * D2R
    # merged stream: a reading directly after the IMU sample of its own time
    last_imu = -1
    n_pol = 0
    for s in run.samples():
        if isinstance(s, ImuSample):
            last_imu = s.t_us
        elif isinstance(s, PolSample):
            assert s.t_us == last_imu
            n_pol += 1
    assert n_pol == p["t_us"].size
    # without the sensor nothing changes
    plain = generate(load_scenario("static", {"duration_s": 5.0}), seed=3)
    assert plain.pol is None
    assert not any(isinstance(s, PolSample) for s in plain.samples())


def test_sim_mounting_and_dark_sky() -> None:
    """GIVEN the simulator's polarization sensor with its noise off, at 20N 120E,
    WHEN it is simulated at 12:30 UTC (night there), and by day mounted at yaw 0 and 30 deg,
    THEN at night the true and measured DoP are 0, and the sensor yawed by +30 deg sees the
    E-vector 30 deg further counter-clockwise."""
    sc = load_scenario("pol_static", {"duration_s": 2.0})
    spec = PolarizationSpec(enabled=True, start_utc="2020-06-01T12:30:00Z", rate_hz=10.0,
                            mount_yaw_deg=30.0, aop_sigma_deg=0.0, dop_sigma=0.0)
    run = generate(sc, seed=1)
    night = simulate_polarization(run.truth_t_us, run.truth_mat_nb, run.truth_pos, 0,
                                  run.imu_dt_us, spec, 1)
    assert np.all(night["dop_true"] == 0.0) and np.all(night["dop"] == 0.0)
    spec0 = PolarizationSpec(enabled=True, rate_hz=10.0, aop_sigma_deg=0.0, dop_sigma=0.0)
    spec30 = PolarizationSpec(enabled=True, rate_hz=10.0, mount_yaw_deg=30.0,
                              aop_sigma_deg=0.0, dop_sigma=0.0)
    a0 = simulate_polarization(run.truth_t_us, run.truth_mat_nb, run.truth_pos, 0,
                               run.imu_dt_us, spec0, 1)["aop_rad"]
    a30 = simulate_polarization(run.truth_t_us, run.truth_mat_nb, run.truth_pos, 0,
                                run.imu_dt_us, spec30, 1)["aop_rad"]
    # a sensor yawed by +30 deg sees the E-vector 30 deg further counter-clockwise
    assert np.allclose(np.vectorize(_wrap_half_pi)(a0 - a30 - 30.0 * D2R), 0.0, atol=1e-9)


def _static_tilted(duration_s: float, pitch_deg: float, yaw_deg: float, seed: int,
                   pol_on: bool) -> tuple[Any, Estimator]:
    """A pol_static run and an estimator started with the heading 5 deg off (sigma 10)."""
    sc = load_scenario("pol_static", {"duration_s": duration_s,
                                      "trajectory.pitch_deg": pitch_deg,
                                      "trajectory.yaw_deg": yaw_deg})
    run = generate(sc, seed=seed)
    yaw0 = math.degrees(float(run.truth_euler[0, 2])) + 5.0
    cfg = EstimatorConfig.from_dict(load_config(None, [
        "init.heading_source=config", f"init.heading_deg={yaw0}", "init.heading_sd_deg=10"]))
    return run, Estimator(cfg, pol=_aid(MOUNT0) if pol_on else None)


@pytest.mark.parametrize("pol_on", [True, False])
def test_static_heading_converges_with_pol_only(pol_on: bool) -> None:
    """GIVEN a static vehicle pitched 30 deg for 180 s, started with the heading 5 deg off
    (sigma 10 deg), with or without the polarization sensor,
    WHEN the run is fused,
    THEN with it the heading error stays < 0.3 deg over the last 60 s, > 1700 readings accepted
    and < 20 rejected; without it the error stays > 1.5 deg (unobservable: it only drifts)."""
    run, est = _static_tilted(180.0, 30.0, 233.87, 2, pol_on)
    errs = []
    for s in run.samples():
        est.push(s)
        if isinstance(s, ImuSample) and est.initialized and s.t_us % 1_000_000 == 0:
            k = s.t_us // run.imu_dt_us
            d = mat_to_euler(est.mat_nb)[2] - run.truth_euler[k, 2]
            errs.append(math.degrees((d + math.pi) % (2 * math.pi) - math.pi))
    tail = np.abs(np.array(errs[-60:]))
    if pol_on:
        assert tail.max() < 0.3
        assert est.counters["pol_accepted"] > 1700
        assert est.counters["pol_rejected"] < 20
    else:
        assert tail.min() > 1.5  # unobservable: the error only drifts (gyro bias)


def test_pitched_75_deg_heading_misalignment_is_observed_and_consistent() -> None:
    """GIVEN a static vehicle pitched 75 deg for 600 s, heading 5 deg off (Table S1's 75 deg row:
    sun ~20 deg from the anti-boresight, DoP 0.03-0.07, about half the readings below dop_min),
    WHEN it is run with and without the polarization sensor,
    THEN with it readings are refused for low DoP yet > 1000 accepted, and the rotation error
    about the vertical ends < 0.3 deg and within 4 sigma; without it the error is > 1 deg."""
    errs: dict[bool, float] = {}
    for pol_on in (True, False):
        run, est = _static_tilted(600.0, 75.0, 278.87, 3, pol_on)
        k = 0
        for s in run.samples():
            est.push(s)
            if isinstance(s, ImuSample):
                k = s.t_us // run.imu_dt_us
        phi = -np.array(log_vec(est.mat_nb @ run.truth_mat_nb[k].T))
        errs[pol_on] = abs(math.degrees(float(phi[2])))
        if pol_on:
            assert est.counters["pol_low_dop"] > 0 and est.counters["pol_accepted"] > 1000
            assert errs[pol_on] < 4.0 * math.degrees(math.sqrt(float(est.P[2, 2])))
    assert errs[True] < 0.3
    assert errs[False] > 1.0


def _delayed(samples: Any, delay_us: int) -> Any:
    """The sample stream with every polarization reading arriving ``delay_us`` late."""
    held: list[PolSample] = []
    last_imu_t = -1
    for s in samples:
        if isinstance(s, PolSample):
            if s.t_us + delay_us <= last_imu_t:
                yield s
            else:
                held.append(s)
            continue
        yield s
        if isinstance(s, ImuSample):
            last_imu_t = s.t_us
            while held and held[0].t_us + delay_us <= s.t_us:
                yield held.pop(0)


def _turning_heading_rms(run: Any, delay_us: int, at_arrival: bool = False) -> tuple[float,
                                                                                      Estimator]:
    yaw0 = math.degrees(float(run.truth_euler[0, 2])) + 3.0
    # The filter is told the simulated IMU's grade (car480's seed-001 MEMS has the industrial
    # preset's 12 deg/h and 5 mg): this test is about when a reading is linearised.  With the
    # consumer priors the horizontal gyro bias of this noisy accelerometer (0.3 m/s/sqrt(s))
    # takes minutes to learn, and the tilt, with the heading the polarization row draws from
    # it, still wanders by ~0.2 deg RMS over 120-240 s (0.10-0.25 over seeds 1-8, either way
    # of 0.15; docs/results.md, issue 14).
    cfg = EstimatorConfig.from_dict(load_config(None, [
        "imu.grade=industrial", "filter.mode=traditional", "init.heading_source=config",
        f"init.heading_deg={yaw0}", "init.heading_sd_deg=5"]))
    est = Estimator(cfg, pol=_aid(MOUNT0))
    if at_arrival:  # what navd did before: linearise about the state at arrival
        est.state_at = lambda t_us: False  # type: ignore[method-assign]
    errs = []
    for s in _delayed(run.samples(), delay_us):
        est.push(s)
        if isinstance(s, ImuSample) and est.initialized and s.t_us % 100_000 == 0:
            k = s.t_us // run.imu_dt_us
            d = mat_to_euler(est.mat_nb)[2] - run.truth_euler[k, 2]
            errs.append(math.degrees((d + math.pi) % (2 * math.pi) - math.pi))
    return float(np.sqrt(np.mean(np.square(errs[len(errs) // 2:])))), est


def test_late_readings_are_fused_at_their_time_of_validity() -> None:
    """GIVEN a car turning at up to 9 deg/s (traditional mode) with 10 Hz polarization readings,
    WHEN the readings arrive on time, 250 ms late, or 250 ms late and linearised at arrival,
    THEN the late ones are fused as delayed (> 1000) with a heading RMS within 1.3x (+0.01 deg)
    of the prompt ones' (< 0.15 deg), while fusing at arrival more than doubles it."""
    sc = load_scenario("car480", {
        "duration_s": 240.0, "polarization.enabled": True,
        "polarization.start_utc": "2020-06-01T17:30:00+08:00", "polarization.rate_hz": 10.0,
        "polarization.aop_sigma_deg": 0.2, "polarization.dop_max": 0.7,
        "polarization.dop_sigma": 0.01, "polarization.mount_roll_deg": 0.0,
        "polarization.mount_pitch_deg": 0.0, "polarization.mount_yaw_deg": 0.0})
    run = generate(sc, seed=3)
    prompt, prompt_est = _turning_heading_rms(run, 0)
    late, est = _turning_heading_rms(run, 250_000)
    stale, _ = _turning_heading_rms(run, 250_000, at_arrival=True)
    assert est.counters["pol_delayed"] > 1000 and prompt_est.counters["pol_delayed"] == 0
    assert prompt < 0.15
    assert late < 1.3 * prompt + 0.01
    assert stale > 2.0 * late
