"""One simulation run: truth, IMU and GNSS, as arrays, samples and CSV files."""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from tqdm import tqdm

from firmware_sim.profiles import build_profile, dov_profile
from firmware_sim.randomize import randomized
from firmware_sim.scenario import Scenario
from firmware_sim.sensors import corrupt_imu, simulate_gnss
from firmware_sim.truth import build_truth
from navd.types import FixType, GnssSample, ImuSample, PolSample
from navd.units import DEG

Arr = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

#: a run starts at this sensor time; 0 keeps the CSVs easy to read against the scenario
T0_US = 0


@dataclass
class SimRun:
    """Everything one run produced.  Times are integer microseconds of the sensor clock.

    Attributes:
        scenario: the validated scenario.
        seed: the seed of every random draw.
        imu_t_us: (N,) int64, end of each IMU interval.
        imu_dt_us: IMU interval, us.
        imu_inc: (N, 6) dtheta xyz (rad), dvel xyz (m/s), body FRD, with sensor errors.
        imu_inc_true: (N, 6) the same without errors (replays the truth exactly).
        gnss: gnss.csv columns: ``t_us`` (int64, time of validity), ``lat_deg``, ``lon_deg``,
            ``alt_m``, ``vel_n/e/d`` (m/s), ``h_acc_m``, ``v_acc_m``, ``vel_acc_mps``,
            ``vel_x/y/z_ecef`` (m/s), ``x/y/z_ecef`` (m), ``outlier`` (bool),
            ``t_arrival_us`` (int64, time of validity + latency); each (M,).
        gnss_truth_idx: (M,) int64 index into the truth arrays of each GNSS epoch.
        truth_t_us: (N+1,) int64 truth times; IMU interval k runs truth k -> k+1.
        truth_pos: (N+1, 3) lat_rad, lon_rad, alt_m (WGS-84).
        truth_vel_n: (N+1, 3) NED velocity, m/s.
        truth_mat_nb: (N+1, 3, 3) C_b^n.
        truth_euler: (N+1, 3) roll, pitch, yaw (rad, yaw in (-pi, pi]).
        truth_dov: (N+1, 3) xi (rad), eta (rad), dg_D (m/s^2).
        gyro_bias_rps: (3,) constant gyro bias (drawn + scenario offset), body FRD, rad/s.
        accel_bias_mps2: (3,) constant accelerometer bias (drawn + offset), body FRD, m/s^2.
        gyro_scale: (3,) gyro scale-factor error drawn (dimensionless).
        accel_scale: (3,) accelerometer scale-factor error drawn (dimensionless).
        gyro_gm_rps: (N, 3) Gauss-Markov gyro bias per interval, rad/s.
        accel_gm_mps2: (N, 3) Gauss-Markov accelerometer bias per interval, m/s^2.
        gyro_rw_rps: (N, 3) gyro bias random walk per interval, rad/s (empty if none).
        accel_rw_mps2: (N, 3) accelerometer bias random walk per interval, m/s^2.
        pol: polarization readings when the scenario has an enabled ``[polarization]``
            sensor (columns of :data:`firmware_sim.polarization.POL_COLUMNS` plus
            ``truth_idx``), else None.
        randomized: what the scenario's ``[randomize]`` section drew for this seed (see
            :func:`firmware_sim.randomize.randomized`); ``scenario`` is then that variant.
    """

    scenario: Scenario
    seed: int
    imu_t_us: I64
    imu_dt_us: int
    imu_inc: Arr
    imu_inc_true: Arr
    gnss: dict[str, npt.NDArray[Any]]
    gnss_truth_idx: I64
    truth_t_us: I64
    truth_pos: Arr
    truth_vel_n: Arr
    truth_mat_nb: Arr
    truth_euler: Arr
    truth_dov: Arr
    gyro_bias_rps: Arr
    accel_bias_mps2: Arr
    gyro_scale: Arr
    accel_scale: Arr
    gyro_gm_rps: Arr
    accel_gm_mps2: Arr
    pol: dict[str, npt.NDArray[Any]] | None = None
    gyro_rw_rps: Arr = field(default_factory=lambda: np.zeros((0, 3)))
    accel_rw_mps2: Arr = field(default_factory=lambda: np.zeros((0, 3)))
    randomized: dict[str, Any] = field(default_factory=dict)

    @property
    def imu_dt_s(self) -> float:
        return self.imu_dt_us * 1e-6

    def imu_samples(self) -> Iterator[ImuSample]:
        """IMU samples (with sensor errors) in time order."""
        dt = self.imu_dt_us
        for t, row in zip(self.imu_t_us.tolist(), self.imu_inc.tolist(), strict=True):
            yield ImuSample(t, dt, *row)

    def gnss_samples(self) -> Iterator[GnssSample]:
        """GNSS samples in time-of-validity order, ECEF position and velocity filled."""
        g = self.gnss
        lat = np.radians(g["lat_deg"]).tolist()
        lon = np.radians(g["lon_deg"]).tolist()
        cols = [g[k].tolist() for k in ("t_us", "alt_m", "vel_n", "vel_e", "vel_d", "h_acc_m",
                                        "v_acc_m", "vel_acc_mps", "x_ecef", "y_ecef", "z_ecef",
                                        "vel_x_ecef", "vel_y_ecef", "vel_z_ecef")]
        for i in range(len(lat)):
            (t, alt, vn, ve, vd, ha, va, vacc, x, y, z, vx, vy, vz) = (c[i] for c in cols)
            yield GnssSample(t, lat[i], lon[i], alt, vn, ve, vd, ha, va, vacc,
                             FixType.FIX_3D, (x, y, z), (vx, vy, vz))

    def pol_samples(self) -> Iterator[PolSample]:
        """Polarization readings in time order (none without a polarization sensor)."""
        if self.pol is None:
            return
        p = self.pol
        for t, a, d, u in zip(p["t_us"].tolist(), p["aop_rad"].tolist(), p["dop"].tolist(),
                              p["utc_unix_s"].tolist(), strict=True):
            yield PolSample(t, a, d, u)

    def samples(self) -> Iterator[ImuSample | GnssSample | PolSample]:
        """IMU, GNSS and polarization readings merged in arrival order.

        A GNSS fix arrives ``latency`` after its time of validity and is delivered right after
        the last IMU sample stamped at or before its arrival (so with zero latency it follows
        the IMU sample of the same ``t_us``).  A polarization reading follows the IMU sample
        of its own ``t_us`` (after any GNSS fix delivered there).
        """
        if self.pol is not None:
            yield from self._merge_pol(self._imu_gnss())
            return
        yield from self._imu_gnss()

    def _merge_pol(self, stream: Iterator[ImuSample | GnssSample]
                   ) -> Iterator[ImuSample | GnssSample | PolSample]:
        pol = list(self.pol_samples())
        j = 0
        m = len(pol)
        pending_t = -1
        for s in stream:
            if isinstance(s, ImuSample):
                while j < m and pending_t >= 0 and pol[j].t_us <= pending_t:
                    yield pol[j]
                    j += 1
                pending_t = s.t_us
            yield s
        while j < m:
            yield pol[j]
            j += 1

    def _imu_gnss(self) -> Iterator[ImuSample | GnssSample]:
        after = np.searchsorted(self.imu_t_us, self.gnss["t_arrival_us"], side="right")
        order = np.argsort(after, kind="stable")
        gnss = list(self.gnss_samples())
        slots = after[order].tolist()
        j = 0
        m = len(gnss)
        for n_done, s in enumerate(self.imu_samples()):
            while j < m and slots[j] <= n_done:
                yield gnss[int(order[j])]
                j += 1
            yield s
        while j < m:
            yield gnss[int(order[j])]
            j += 1

    def write_csv(self, out_dir: str | Path, progress: bool = False) -> None:
        """Write ``imu.csv``, ``gnss.csv``, ``truth.csv`` and ``meta.json`` into ``out_dir``.

        The directory is created if needed; see docs/replay-format.md for the columns.
        """
        from firmware_sim.csvio import write_run

        write_run(self, Path(out_dir), progress)


def generate(scenario: Scenario, seed: int, progress: bool = False) -> SimRun:
    """Simulate one run of ``scenario`` with a reproducible ``seed`` (>= 0).

    ``progress`` shows a tqdm bar over the generation stages (long scenarios take seconds).
    """
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    scenario, drawn = randomized(scenario, seed)
    dt_us = round(1e6 / scenario.imu.rate_hz)
    dt_s = dt_us * 1e-6
    n = max(1, math.floor(scenario.duration / dt_s + 1e-9))
    stages = ["profile", "truth", "imu", "gnss"]
    bar = tqdm(total=len(stages), desc=scenario.name, unit="stage", disable=not progress,
               leave=False)
    try:
        bar.set_postfix_str(f"{stages[0]} ({n} IMU samples)")
        t_us = T0_US + dt_us * np.arange(n + 1, dtype=np.int64)
        t_s = (t_us - T0_US).astype(np.float64) * 1e-6
        tr = scenario.trajectory
        prof = build_profile(t_s, tr, seed)
        dov = dov_profile(t_s, scenario.dov)
        bar.update()
        bar.set_postfix_str(stages[1])
        pos0 = np.array([tr.lat_deg * DEG, tr.lon_deg * DEG, tr.alt_m])
        truth = build_truth(prof.euler, prof.vel_n, pos0, dov, dt_s)
        bar.update()
        bar.set_postfix_str(stages[2])
        inc, err = corrupt_imu(truth.inc, dt_s, scenario.imu, seed)
        bar.update()
        bar.set_postfix_str(stages[3])
        gnss, gidx = simulate_gnss(t_us, truth.pos, truth.vel_n, T0_US, scenario.gnss, seed,
                                   truth.mat_nb, truth.inc)
        pol = None
        if scenario.polarization.enabled:
            from firmware_sim.polarization import simulate_polarization

            pol = simulate_polarization(t_us, truth.mat_nb, truth.pos, T0_US, dt_us,
                                        scenario.polarization, seed)
        bar.update()
    finally:
        bar.close()
    return SimRun(
        scenario=scenario, seed=seed, imu_t_us=t_us[1:].copy(), imu_dt_us=dt_us, imu_inc=inc,
        imu_inc_true=truth.inc, gnss=gnss, gnss_truth_idx=gidx, truth_t_us=t_us,
        truth_pos=truth.pos, truth_vel_n=truth.vel_n, truth_mat_nb=truth.mat_nb,
        truth_euler=truth.euler, truth_dov=truth.dov, gyro_bias_rps=err.gyro_bias_rps,
        accel_bias_mps2=err.accel_bias_mps2, gyro_scale=err.gyro_scale,
        accel_scale=err.accel_scale, gyro_gm_rps=err.gyro_gm_rps,
        accel_gm_mps2=err.accel_gm_mps2, pol=pol, gyro_rw_rps=err.gyro_rw_rps,
        accel_rw_mps2=err.accel_rw_mps2, randomized=drawn,
    )
