"""DOV through the mechanization and the estimator, against simulator truth.

* A truth whose gravity carries the DOV of a grid replays through navd's strapdown to
  round-off when the strapdown evaluates that grid at its own position (what the estimator
  does), and does not without it.
* Seed 002 in short (ship_dov, nav-grade IMU, 1.5 h): the DOV-induced tilt of a GNSS-aided
  INS follows phi_N = eta, phi_E = -xi within 1", and the estimator given the field removes it.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import numpy.typing as npt

from firmware_sim import SimRun, generate, load_scenario
from firmware_sim.dov_field import AlongTrackSinusoid
from firmware_sim.profiles import build_profile
from firmware_sim.scenario import Scenario
from firmware_sim.sensors import corrupt_imu
from firmware_sim.truth import build_truth
from navd.config import EstimatorConfig, load_config
from navd.core.aiding.dov import ARCSEC, MGAL, DovGrid
from navd.core.estimator import DovField, Estimator
from navd.core.rotation import log_so3
from navd.core.strapdown import strapdown_step
from navd.types import ImuSample

Arr = npt.NDArray[np.float64]


def rebuild_with_dov(base: SimRun, sc: Scenario, field: DovField) -> SimRun:
    """``base`` with the truth gravity carrying ``field`` at the truth positions."""
    t_s = (base.truth_t_us - base.truth_t_us[0]).astype(np.float64) * 1e-6
    prof = build_profile(t_s, sc.trajectory)
    dov = np.zeros((base.truth_pos.shape[0], 3))
    for k in range(dov.shape[0]):
        assert field.eval_into(float(base.truth_pos[k, 0]), float(base.truth_pos[k, 1]), dov[k])
    truth = build_truth(prof.euler, prof.vel_n, base.truth_pos[0], dov, base.imu_dt_s)
    assert np.array_equal(truth.pos, base.truth_pos)
    inc, _ = corrupt_imu(truth.inc, base.imu_dt_s, sc.imu, base.seed)
    return dataclasses.replace(base, imu_inc=inc, imu_inc_true=truth.inc,
                               truth_mat_nb=truth.mat_nb, truth_dov=dov)


def test_grid_dov_truth_replays_to_round_off() -> None:
    """GIVEN a 30 min ship_dov truth rebuilt so its gravity carries a random DovGrid
    (30 arcsec deflections, 50 mGal disturbance),
    WHEN navd's strapdown replays the true IMU increments, with and without evaluating the
    grid at its own position,
    THEN with the grid attitude stays within 1e-9 rad and velocity within 1e-6 m/s of truth;
    with normal gravity alone velocity departs by more than 0.1 m/s."""
    sc = load_scenario("ship_dov", {"duration_s": 1800.0, "dov.enabled": False})
    base = generate(sc, seed=4)
    lat = np.degrees(base.truth_pos[:, 0])
    lon = np.degrees(base.truth_pos[:, 1])
    la = np.linspace(lat.min() - 0.05, lat.max() + 0.05, 9)
    lo = np.linspace(lon.min() - 0.05, lon.max() + 0.05, 9)
    rng = np.random.default_rng(8)
    grid = DovGrid(la, lo, rng.normal(0, 30 * ARCSEC, (9, 9)), rng.normal(0, 30 * ARCSEC, (9, 9)),
                   rng.normal(0, 50 * MGAL, (9, 9)))
    run = rebuild_with_dov(base, sc, grid)
    for use_field in (True, False):
        c = run.truth_mat_nb[0].copy()
        v = run.truth_vel_n[0].copy()
        p = run.truth_pos[0].copy()
        prev = np.zeros(6)
        work = np.zeros((8, 3, 3))
        dov = np.zeros(3)
        att = vel = 0.0
        for k in range(run.imu_inc_true.shape[0]):
            if use_field:
                assert grid.eval_into(float(p[0]), float(p[1]), dov)
            strapdown_step(c, v, p, dov, run.imu_inc_true[k], prev, run.imu_dt_s, True, work)
            prev[:] = run.imu_inc_true[k]
            if k % 100 == 0:
                att = max(att, float(np.linalg.norm(log_so3(c.T @ run.truth_mat_nb[k + 1]))))
                vel = max(vel, float(np.abs(v - run.truth_vel_n[k + 1]).max()))
        if use_field:
            assert att <= 1e-9 and vel <= 1e-6
        else:
            assert vel > 0.1  # normal gravity alone cannot reproduce this truth


NAV = ["filter.mode=traditional", "filter.robust=none", "init.heading_source=config",
       "init.heading_sd_deg=0.05", "init.tilt_sd_deg=0.1", "init.vel_sd_mps=0.1",
       "init.pos_sd_m=3.0", "imu.gyro_arw_deg_per_sqrt_h=0.0005",
       "imu.accel_vrw_mps_per_sqrt_s=1e-4", "imu.gyro_bias_sd_deg_per_h=0.003",
       "imu.accel_bias_sd_mg=0.0102", "imu.gyro_bias_rw_deg_per_h_per_sqrt_h=1e-5",
       "imu.accel_bias_rw_mps2_per_sqrt_s=1e-8", "imu.gyro_scale_sd_pct=0.0005"]


def _tilt(run: SimRun, cfg: EstimatorConfig, field: DovField | None) -> tuple[Arr, Arr, Arr]:
    est = Estimator(cfg, dov_field=field)
    t0 = int(run.truth_t_us[0])
    out_t: list[float] = []
    out_k: list[int] = []
    phis: list[Arr] = []
    for s in run.samples():
        est.push(s)
        if isinstance(s, ImuSample) and est.initialized and (s.t_us - t0) % 30_000_000 == 0:
            k = (s.t_us - t0) // run.imu_dt_us
            phis.append(-np.array(log_so3(est.mat_nb @ run.truth_mat_nb[k].T)))
            out_t.append((s.t_us - t0) * 1e-6)
            out_k.append(k)
    return np.array(out_t), np.array(out_k), np.array(phis)


def test_ship_dov_tilt_follows_theory_and_compensation_removes_it() -> None:
    """GIVEN a 1.5 h ship_dov run with a nav-grade IMU, without DOV and with an along-track
    sinusoid DOV (20 arcsec amplitudes) in the truth,
    WHEN the GNSS-aided estimator runs without the field and then given it,
    THEN after 30 min the uncompensated tilt change follows phi_N = eta, phi_E = -xi within
    1 arcsec, and the given field cuts the tilt RMS and the (over 5 arcsec) heading RMS
    below 10 % of the uncompensated values."""
    sc = load_scenario("ship_dov", {"duration_s": 5400.0, "dov.enabled": False})
    base = generate(sc, seed=1)
    tr = sc.trajectory
    field = AlongTrackSinusoid(math.radians(tr.lat_deg), math.radians(tr.lon_deg),
                               math.radians(45.0), xi_amp_rad=20 * ARCSEC,
                               xi_wavelength_m=360e3, eta_amp_rad=20 * ARCSEC,
                               eta_wavelength_m=360e3, eta_phase_rad=1.0)
    run = rebuild_with_dov(base, sc, field)
    cfg = EstimatorConfig.from_dict(load_config(None, [
        *NAV, f"init.heading_deg={math.degrees(base.truth_euler[0, 2])}"]))
    t, k, phi_b = _tilt(base, cfg, None)
    _, _, phi_u = _tilt(run, cfg, None)
    _, _, phi_c = _tilt(run, cfg, field)
    m = t >= 1800.0
    d_u = (phi_u - phi_b)[m] / ARCSEC
    d_c = (phi_c - phi_b)[m] / ARCSEC
    xi = run.truth_dov[k[m], 0] / ARCSEC
    eta = run.truth_dov[k[m], 1] / ARCSEC
    assert np.max(np.abs(eta)) > 15.0 and np.max(np.abs(xi)) > 5.0
    assert np.max(np.abs(d_u[:, 0] - eta)) < 1.0  # phi_N = eta
    assert np.max(np.abs(d_u[:, 1] + xi)) < 1.0  # phi_E = -xi
    tilt_u = np.sqrt(np.mean(d_u[:, 0] ** 2 + d_u[:, 1] ** 2))
    tilt_c = np.sqrt(np.mean(d_c[:, 0] ** 2 + d_c[:, 1] ** 2))
    assert tilt_c < 0.1 * tilt_u
    head_u = np.sqrt(np.mean(d_u[:, 2] ** 2))
    head_c = np.sqrt(np.mean(d_c[:, 2] ** 2))
    assert head_u > 5.0 and head_c < 0.1 * head_u
