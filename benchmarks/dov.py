"""Seed-002 simulation: attitude errors caused by an uncompensated deflection of the vertical.

Scenario ``ship_dov`` (22 N 113 E, static 600 s, 120 s to 10 m/s on course 45 deg, cruise;
navigation-grade IMU at 20 Hz with single-axis rotation modulation, 18 deg/s, 300 s dwell;
GNSS 1 Hz, 2 m / 0.03 m/s horizontal, 4 m / 0.06 m/s vertical).  The truth DOV is a
function of *position*: sinusoids of the distance along the course
(:class:`~firmware_sim.dov_field.AlongTrackSinusoid`) of 20" amplitude and 360 km wavelength,
i.e. a 10 h period at cruise speed as in the seed (which drives its DOV in time; ours is
constant while the ship is static and identical to the seed's once it cruises).  The
scenario's own time-based DOV is switched off and the IMU increments are rebuilt from the
same trajectory with this DOV (same seed, so identical sensor noise).

Cases: ``eta`` (xi = 0; the seed's Figs. 3-5), ``xi`` (eta = 0; Figs. 6-8) and ``both``.
For each, navd's :class:`Estimator` runs three times on identical noise:

    base    truth without DOV                 (isolates everything that is not DOV)
    uncomp  truth with DOV, normal gravity    (DOV left out of the mechanization)
    comp    truth with DOV, DOV field given   (``Estimator(cfg, dov_field=...)``)

The DOV-induced error is ``phi(uncomp) - phi(base)`` (the seed's "difference of the two
attitude results"), compared with the seed's prediction in navd's convention
(phi computed - true, NED): tilt ``phi_N = eta, phi_E = -xi`` and early yaw error
``dpsi = -phi_D = eta tan L + xi' sec L / omega_ie``.  Compensation leaves
``phi(comp) - phi(base)``.  Targets: uncompensated tilt within 1" of theory; compensation
removes >= 90 % of the DOV-induced tilt and heading error (RMS).

Filter (navigation-grade config overrides, see NAV_CONFIG): traditional mode (GNSS position
+ velocity), because with rotation modulation the IMU's body yaw is the ship's heading plus
the modulation angle, so GNSS course is not the body heading and the completed (course)
update would be wrong; heading is initialised from config (true heading, 0.05 deg 1-sigma)
and kept by gyrocompassing through the GNSS velocity.  No innovation gate: the simulated
receiver has no outliers and reports one speed accuracy (0.03 m/s) for a vertical noise of
0.06 m/s, which a 3-D gate would punish with ~3 % rejected epochs.

    .venv/bin/python benchmarks/dov.py [--hours 10] [--seed 1] [--json PATH] [--plots DIR]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from firmware_sim import generate, load_scenario
from firmware_sim.dov_field import AlongTrackSinusoid
from firmware_sim.profiles import build_profile
from firmware_sim.run import SimRun
from firmware_sim.scenario import Scenario, ShipSpec
from firmware_sim.sensors import corrupt_imu
from firmware_sim.truth import build_truth
from navd.config import EstimatorConfig, load_config
from navd.core.aiding.dov import ARCSEC, dov_status
from navd.core.earth import OMEGA_IE
from navd.core.estimator import Estimator
from navd.core.rotation import log_so3
from navd.types import ImuSample

Arr = npt.NDArray[np.float64]

AMP_ARCSEC = 20.0
PERIOD_S = 36000.0
CASES = ("eta", "xi", "both")
SEED_FIGS = {"eta": "seed 002 Figs. 3-5", "xi": "seed 002 Figs. 6-8", "both": "xi and eta"}
NAV_CONFIG = [
    "filter.mode=traditional", "filter.robust=none",
    "init.heading_source=config", "init.heading_sd_deg=0.05", "init.tilt_sd_deg=0.1",
    "init.vel_sd_mps=0.1", "init.pos_sd_m=3.0",
    "imu.gyro_arw_deg_per_sqrt_h=0.0005", "imu.accel_vrw_mps_per_sqrt_s=1e-4",
    "imu.gyro_bias_sd_deg_per_h=0.003", "imu.accel_bias_sd_mg=0.0102",
    "imu.gyro_bias_rw_deg_per_h_per_sqrt_h=1e-5", "imu.accel_bias_rw_mps2_per_sqrt_s=1e-8",
    "imu.gyro_scale_sd_pct=0.0005",  # an RLG's 5 ppm; the consumer 1 % would be 1.8 deg a turn
    "gnss.min_pos_sd_m=0.3", "gnss.min_vel_sd_mps=0.03",
]


def case_field(sc: Scenario, case: str) -> AlongTrackSinusoid:
    tr = sc.trajectory
    assert isinstance(tr, ShipSpec)
    wavelength = tr.speed_mps * PERIOD_S
    amp = AMP_ARCSEC * ARCSEC
    return AlongTrackSinusoid(
        math.radians(tr.lat_deg), math.radians(tr.lon_deg), math.radians(tr.course_deg),
        xi_amp_rad=amp if case in ("xi", "both") else 0.0, xi_wavelength_m=wavelength,
        eta_amp_rad=amp if case in ("eta", "both") else 0.0, eta_wavelength_m=wavelength)


def with_dov(base: SimRun, sc: Scenario, field: AlongTrackSinusoid) -> SimRun:
    """``base`` (generated without DOV) with the IMU rebuilt for a truth DOV from ``field``.

    Positions do not depend on gravity, so the DOV is evaluated on the base truth track;
    the same seed gives the same sensor noise.
    """
    t_s = (base.truth_t_us - base.truth_t_us[0]).astype(np.float64) * 1e-6
    prof = build_profile(t_s, sc.trajectory)
    dov = field.eval_track(base.truth_pos)
    truth = build_truth(prof.euler, prof.vel_n, base.truth_pos[0], dov, base.imu_dt_s)
    if not np.array_equal(truth.pos, base.truth_pos):
        raise RuntimeError("truth positions changed: the rebuild is not consistent")
    inc, _ = corrupt_imu(truth.inc, base.imu_dt_s, sc.imu, base.seed)
    return dataclasses.replace(base, imu_inc=inc, imu_inc_true=truth.inc,
                               truth_mat_nb=truth.mat_nb, truth_dov=dov)


@dataclasses.dataclass
class Track:
    t_s: Arr  # (K,)
    phi: Arr  # (K, 3) attitude error (computed - true), rad, NED
    idx: npt.NDArray[np.int64]  # (K,) truth index
    counters: dict[str, int]
    status: dict[str, object]


def run_filter(run: SimRun, overrides: list[str], field: AlongTrackSinusoid | None,
               every_s: float) -> Track:
    cfg = EstimatorConfig.from_dict(load_config(None, overrides))
    est = Estimator(cfg, dov_field=field)
    period = round(every_s * 1e6)
    t0 = int(run.truth_t_us[0])
    dt = run.imu_dt_us
    ts: list[float] = []
    phis: list[Arr] = []
    idx: list[int] = []
    for s in run.samples():
        est.push(s)
        if isinstance(s, ImuSample) and est.initialized and (s.t_us - t0) % period == 0:
            k = (s.t_us - t0) // dt
            phis.append(-np.array(log_so3(est.mat_nb @ run.truth_mat_nb[k].T)))
            ts.append((s.t_us - t0) * 1e-6)
            idx.append(k)
    return Track(np.array(ts), np.array(phis), np.array(idx, dtype=np.int64),
                 dict(est.counters), dov_status(est))


def theory(run: SimRun, tr: Track) -> Arr:
    """(K, 3): predicted uncompensated [phi_N, phi_E, dpsi] along the sampled track, rad."""
    dov = run.truth_dov[tr.idx]
    lat = run.truth_pos[tr.idx, 0]
    xi_dot = np.gradient(dov[:, 0], tr.t_s)
    dpsi = dov[:, 1] * np.tan(lat) + xi_dot / (np.cos(lat) * OMEGA_IE)
    return np.stack([dov[:, 1], -dov[:, 0], dpsi], axis=1)


def rms(a: Arr) -> float:
    return float(np.sqrt(np.mean(np.square(a)))) if a.size else float("nan")


def metrics(t: Arr, d_u: Arr, d_c: Arr, th: Arr, settle_s: float) -> dict[str, float]:
    """Arcsec figures over t >= settle_s.  d_u, d_c: DOV-induced [phi_N, phi_E, dpsi]."""
    m = t >= settle_s
    u, c, p = d_u[m] / ARCSEC, d_c[m] / ARCSEC, th[m] / ARCSEC
    tilt_u = np.hypot(u[:, 0], u[:, 1])
    tilt_c = np.hypot(c[:, 0], c[:, 1])
    out = {
        "tilt_n_max_dev_arcsec": float(np.max(np.abs(u[:, 0] - p[:, 0]))),
        "tilt_e_max_dev_arcsec": float(np.max(np.abs(u[:, 1] - p[:, 1]))),
        "tilt_rms_dev_arcsec": rms(np.hypot(u[:, 0] - p[:, 0], u[:, 1] - p[:, 1])),
        "tilt_uncomp_rms_arcsec": rms(tilt_u),
        "tilt_comp_rms_arcsec": rms(tilt_c),
        "tilt_removed_pct": 100.0 * (1.0 - rms(tilt_c) / rms(tilt_u)),
        "heading_uncomp_rms_arcsec": rms(u[:, 2]),
        "heading_theory_rms_arcsec": rms(p[:, 2]),
        "heading_rms_dev_arcsec": rms(u[:, 2] - p[:, 2]),
        "heading_corr": float(np.corrcoef(u[:, 2], p[:, 2])[0, 1]),
        "heading_comp_rms_arcsec": rms(c[:, 2]),
        "heading_removed_pct": 100.0 * (1.0 - rms(c[:, 2]) / rms(u[:, 2])),
    }
    # the seed's "early" heading prediction: first quarter of the run after settling
    q = t[m] <= settle_s + 0.25 * (t[-1] - settle_s)
    out["heading_early_rms_dev_arcsec"] = rms(u[q, 2] - p[q, 2])
    out["heading_early_theory_rms_arcsec"] = rms(p[q, 2])
    # the filter's heading responds late: the lag (up to 3 h) that best aligns simulation
    # and theory, the gain (least squares) and the deviation left after that alignment
    dt = float(t[1] - t[0]) if t.size > 1 else 1.0
    best = (-2.0, 0, 1.0, float("nan"))
    for lag in range(0, min(int(3 * 3600 / dt), u.shape[0] // 2) + 1):
        a = u[lag:, 2]
        b = p[:p.shape[0] - lag, 2]
        r = float(np.corrcoef(a, b)[0, 1])
        if r > best[0]:
            gain = float(a @ b / (b @ b))
            best = (r, lag, gain, rms(a - gain * b))
    out["heading_lag_min"] = best[1] * dt / 60.0
    out["heading_lag_corr"] = best[0]
    out["heading_lag_gain"] = best[2]
    out["heading_lag_rms_dev_arcsec"] = best[3]
    return out


def yaw_part(phi: Arr) -> Arr:
    """[phi_N, phi_E, dpsi] from phi (dpsi = -phi_D, exact enough for sub-arcminute tilts)."""
    return np.stack([phi[:, 0], phi[:, 1], -phi[:, 2]], axis=1)


def plot_case(path: Path, case: str, t: Arr, d_u: Arr, d_c: Arr, th: Arr) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    h = t / 3600.0
    names = (r"$\phi_N$ (tilt about north)", r"$\phi_E$ (tilt about east)",
             r"$\delta\psi = -\phi_D$ (heading)")
    theory_lbl = (r"theory $\eta$", r"theory $-\xi$",
                  r"theory $\eta\tan L + \dot\xi\sec L/\omega_{ie}$")
    fig, axes = plt.subplots(3, 1, figsize=(9, 9), sharex=True)
    for k, ax in enumerate(axes):
        ax.plot(h, th[:, k] / ARCSEC, "k--", lw=1.5, label=theory_lbl[k])
        ax.plot(h, d_u[:, k] / ARCSEC, "C3", lw=1.0, label="simulation, uncompensated")
        ax.plot(h, d_c[:, k] / ARCSEC, "C0", lw=1.0, label="simulation, DOV compensated")
        ax.set_ylabel(f"{names[k]} [arcsec]")
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right", fontsize=8)
    axes[-1].set_xlabel("time [h]")
    fig.suptitle(f"DOV-induced attitude error, case '{case}' ({SEED_FIGS[case]}); "
                 "navd conventions: NED, computed - true", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--hours", type=float, default=10.0,
                    help="simulated duration, h (seed: 40; default 10 = one DOV period)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--every-s", type=float, default=10.0, help="error sampling period, s")
    ap.add_argument("--settle-s", type=float, default=1800.0,
                    help="metrics from this time on, s (filter convergence)")
    ap.add_argument("--cases", default=",".join(CASES), help="comma list of eta, xi, both")
    ap.add_argument("--json", help="write the metrics and the setup to this file")
    ap.add_argument("--plots", default="out/dov", help="directory for PNG plots ('' = none)")
    a = ap.parse_args(argv)
    cases = [c for c in a.cases.split(",") if c]
    if any(c not in CASES for c in cases):
        ap.error(f"--cases: expected some of {CASES}")
    t_start = time.perf_counter()
    duration = a.hours * 3600.0
    sc = load_scenario("ship_dov", {"duration_s": duration, "dov.enabled": False})
    base = generate(sc, seed=a.seed)
    overrides = [*NAV_CONFIG, f"init.heading_deg={math.degrees(base.truth_euler[0, 2])}"]
    tb = run_filter(base, overrides, None, a.every_s)
    plots = Path(a.plots) if a.plots else None
    if plots is not None:
        plots.mkdir(parents=True, exist_ok=True)
    records: list[dict[str, Any]] = []
    for case in cases:
        field = case_field(sc, case)
        run = with_dov(base, sc, field)
        tu = run_filter(run, overrides, None, a.every_s)
        tc = run_filter(run, overrides, field, a.every_s)
        if not (np.array_equal(tu.t_s, tb.t_s) and np.array_equal(tc.t_s, tb.t_s)):
            raise RuntimeError("runs sampled at different times")
        d_u = yaw_part(tu.phi) - yaw_part(tb.phi)
        d_c = yaw_part(tc.phi) - yaw_part(tb.phi)
        th = theory(run, tb)
        rec: dict[str, Any] = {"case": case, **metrics(tb.t_s, d_u, d_c, th, a.settle_s)}
        rec["abs_tilt_rms_arcsec"] = {
            name: rms(np.hypot(tr.phi[tb.t_s >= a.settle_s, 0],
                               tr.phi[tb.t_s >= a.settle_s, 1]) / ARCSEC)
            for name, tr in (("base", tb), ("uncomp", tu), ("comp", tc))}
        rec["dov_status_end"] = tc.status
        rec["counters_comp"] = tc.counters
        records.append(rec)
        if plots is not None:
            plot_case(plots / f"dov_{case}.png", case, tb.t_s, d_u, d_c, th)

    print(f"ship_dov, {a.hours:g} h (seed: 40 h), seed {a.seed}, 20\" / {PERIOD_S / 3600:g} h "
          f"DOV sinusoids along the track; metrics after {a.settle_s:g} s; arcsec")
    head = (f"{'case':<6}{'tiltN dev':>10}{'tiltE dev':>10}{'tilt rms':>9}{'removed':>9}"
            f"{'hdg rms':>9}{'theory':>8}{'dev':>7}{'corr':>6}{'lag min':>8}{'corr@lag':>9}"
            f"{'gain':>6}{'removed':>9}")
    print(head)
    print("-" * len(head))
    for r in records:
        print(f"{r['case']:<6}{r['tilt_n_max_dev_arcsec']:>10.2f}"
              f"{r['tilt_e_max_dev_arcsec']:>10.2f}{r['tilt_uncomp_rms_arcsec']:>9.2f}"
              f"{r['tilt_removed_pct']:>8.2f}%{r['heading_uncomp_rms_arcsec']:>9.2f}"
              f"{r['heading_theory_rms_arcsec']:>8.2f}{r['heading_rms_dev_arcsec']:>7.2f}"
              f"{r['heading_corr']:>6.2f}{r['heading_lag_min']:>8.0f}"
              f"{r['heading_lag_corr']:>9.3f}{r['heading_lag_gain']:>6.2f}"
              f"{r['heading_removed_pct']:>8.2f}%")
    print("tiltN/E dev: max |DOV-induced tilt - theory (phi_N = eta, phi_E = -xi)|; tilt rms: "
          "DOV-induced, uncompensated;\nremoved: 1 - rms(compensated)/rms(uncompensated); hdg: "
          "DOV-induced yaw error vs theory eta tanL + xi' secL/w_ie\n(dev: rms difference, "
          "corr: correlation; lag, corr@lag, gain: after delaying the theory by the best lag)")
    print("targets: tilt dev <= 1\", removed >= 90 % (tilt and heading)")
    for r in records:
        ab = r["abs_tilt_rms_arcsec"]
        print(f"  {r['case']}: absolute tilt error rms base {ab['base']:.2f}\", uncompensated "
              f"{ab['uncomp']:.2f}\", compensated {ab['comp']:.2f}\"")
    print(f"({time.perf_counter() - t_start:.0f} s{', plots in ' + str(plots) if plots else ''})")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump({"scenario": "ship_dov", "hours": a.hours, "seed": a.seed,
                       "settle_s": a.settle_s, "config": overrides, "records": records},
                      fh, indent=2, default=str)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
