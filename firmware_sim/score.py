"""Scoring an estimator against simulator truth (used by tests and benchmarks).

The estimator sees only the sensor samples; truth is looked up by time stamp afterwards.
Errors follow navd's conventions (computed minus true): attitude error phi from
``C_hat = Exp(-phi) C``, Euler errors wrapped to (-180, 180] degrees.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from firmware_sim.run import SimRun
from firmware_sim.scenario import ImuSpec
from navd.config import EstimatorConfig
from navd.core.earth import radii
from navd.core.estimator import Estimator
from navd.core.rotation import log_so3, mat_to_euler
from navd.pipeline import solutions
from navd.types import GnssSample
from navd.units import RAD2DEG as R2D

Arr = npt.NDArray[np.float64]


@dataclass
class Score:
    """Errors sampled at a fixed rate after navigation started.

    Attributes:
        t_s: (K,) time, s.
        euler_err_deg: (K, 3) roll, pitch, yaw error, deg.
        euler_sd_deg: (K, 3) the filter's 1-sigma of the same, deg.
        vel_err: (K, 3) NED velocity error, m/s.
        pos_err: (K, 3) NED position error, m.
        nees_att: (K,) phi^T P_att^-1 phi (3 dof).
        nees_vel: (K,) dv^T P_vel^-1 dv (3 dof).
        aligned: (K,) heading aligned flag.
        counters: the estimator's counters at the end.
    """

    t_s: Arr
    euler_err_deg: Arr
    euler_sd_deg: Arr
    vel_err: Arr
    pos_err: Arr
    nees_att: Arr
    nees_vel: Arr
    aligned: npt.NDArray[np.bool_]
    counters: dict[str, int] = field(default_factory=dict)
    course_status: str = ""

    def rmse(self, after_s: float = 0.0) -> dict[str, float]:
        """RMS of each error after ``after_s`` seconds (degrees, m/s, m)."""
        m = self.t_s >= after_s
        e = self.euler_err_deg[m]
        return {
            "roll_rmse_deg": float(np.sqrt(np.mean(e[:, 0] ** 2))),
            "pitch_rmse_deg": float(np.sqrt(np.mean(e[:, 1] ** 2))),
            "heading_rmse_deg": float(np.sqrt(np.mean(e[:, 2] ** 2))),
            "vel_h_rmse_mps": float(np.sqrt(np.mean(np.sum(self.vel_err[m, :2] ** 2, 1)))),
            "pos_h_rmse_m": float(np.sqrt(np.mean(np.sum(self.pos_err[m, :2] ** 2, 1)))),
        }


def initial_heading_config(run: SimRun, yaw_error_deg: float) -> list[str]:
    """Config overrides that start the filter with a heading off by ``yaw_error_deg``."""
    yaw0 = float(run.truth_euler[0, 2]) * R2D + yaw_error_deg
    return ["init.heading_source=config", f"init.heading_deg={yaw0}",
            f"init.heading_sd_deg={max(abs(yaw_error_deg), 1.0)}"]


# the accelerometer-bias walk a matched filter keeps when the simulated IMU has none: the
# consumer preset's until it took a warming board's 3e-3 (2026-11-28), so that the
# benchmarks built on a matched filter (polarization, static heading) keep their figures
MATCHED_ACCEL_RW_FLOOR = 1e-4


def matched_imu_config(imu: ImuSpec) -> list[str]:
    """Config overrides that set the filter's IMU model to the simulated IMU's (a filter
    tuned to its sensor): bias sigmas, white noise, and the accelerometer-bias walk (the
    simulated one, at least MATCHED_ACCEL_RW_FLOOR)."""
    rw = max(imu.accel_bias_rw_mps2_per_sqrt_s, MATCHED_ACCEL_RW_FLOOR)
    return [f"imu.gyro_bias_sd_deg_per_h={imu.gyro_bias_sigma_rps * R2D * 3600.0}",
            f"imu.accel_bias_sd_mg={imu.accel_bias_sigma_mps2 / 9.80665e-3}",
            f"imu.gyro_arw_deg_per_sqrt_h={imu.arw_rad_per_sqrt_s * R2D * 60.0}",
            f"imu.accel_vrw_mps_per_sqrt_s={imu.vrw_mps_per_sqrt_s}",
            f"imu.accel_bias_rw_mps2_per_sqrt_s={rw}"]


def score_run(run: SimRun, cfg: EstimatorConfig, rate_hz: float = 10.0,
              est: Estimator | None = None, mount_exact: bool | None = None) -> Score:
    """Push every sample of ``run`` through an estimator and sample its errors.

    ``mount_exact``: the simulated IMU sits on the vehicle exactly as the config states, so
    the yaw sigma scored leaves out what the config's ``[imu] mount_yaw_sd_deg`` adds for an
    installation's error (``NavSolution.yaw_sd_installation_rad``): the error it allows for
    is not there, and with it the yaw sigma would cover the filter's own errors up to
    three times the installation's.  None: whether the scenario's ``[imu] mount_*_deg`` are
    the config's."""
    e = est if est is not None else Estimator(cfg)
    if mount_exact is None:
        sim = run.scenario.imu
        mount_exact = all(
            abs(math.radians(getattr(sim, f"{k}_deg")) - getattr(e.cfg.imu, k)) < 1e-9
            for k in ("mount_roll", "mount_pitch", "mount_yaw"))
    t0 = int(run.truth_t_us[0])
    dt_truth = int(run.truth_t_us[1] - run.truth_t_us[0])
    rows: list[tuple[float, ...]] = []
    phi = np.zeros(3)
    # the daemon's output rule: on the sensor-time grid of the scoring rate
    for sol in solutions(e, run.samples(), rate_hz):
        k = (sol.t_us - t0) // dt_truth
        c_true = run.truth_mat_nb[k]
        dlt = np.array(mat_to_euler(e.mat_nb)) - run.truth_euler[k]
        dlt = (dlt + math.pi) % (2 * math.pi) - math.pi
        # phi = -Log(C_hat C^T)
        phi[:] = log_so3(e.mat_nb @ c_true.T)
        phi *= -1.0
        patt = e.P[0:3, 0:3]
        pvel = e.P[3:6, 3:6]
        dv = e.vel_n - run.truth_vel_n[k]
        r_m, r_n = radii(float(run.truth_pos[k, 0]))
        h = float(run.truth_pos[k, 2])
        dp = e.pos - run.truth_pos[k]
        dpn = (dp[0] * (r_m + h), dp[1] * (r_n + h) * math.cos(run.truth_pos[k, 0]), -dp[2])
        sd = np.array(sol.att_sd_rad)
        if mount_exact:
            sd[2] = math.sqrt(max(sd[2] * sd[2] - sol.yaw_sd_installation_rad ** 2, 0.0))
        rows.append((sol.t_us * 1e-6, *(dlt * R2D), *(sd * R2D), *dv,
                     *dpn, float(phi @ np.linalg.solve(patt, phi)),
                     float(dv @ np.linalg.solve(pvel, dv)), float(sol.heading_aligned)))
    a = np.array(rows) if rows else np.zeros((0, 18))
    return Score(t_s=a[:, 0], euler_err_deg=a[:, 1:4], euler_sd_deg=a[:, 4:7],
                 vel_err=a[:, 7:10], pos_err=a[:, 10:13], nees_att=a[:, 13],
                 nees_vel=a[:, 14], aligned=a[:, 15] > 0.5, counters=dict(e.counters),
                 course_status=e.course_status)


def gnss_only(run: SimRun) -> list[GnssSample]:
    """The GNSS samples of a run (convenience for tests)."""
    return list(run.gnss_samples())
