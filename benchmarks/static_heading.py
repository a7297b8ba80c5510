"""Heading at rest with no heading source: is the filter honest about what it does not know?

A MEMS IMU (scenario ``pol_static``, 12 deg/h gyro bias, POL readings ignored) stands still
for 41 minutes, its heading 5 deg off at start (1-sigma 10 deg); GNSS reports zero velocity.
Nothing observes the heading: a 12 deg/h gyro cannot gyrocompass (that needs a gyro good to
about 1 deg/h).  An honest filter keeps a sigma near its prior while the error drifts with
the vertical gyro bias.  ``--hold off`` shows the EKF without the heading hold
(``[heading] hold_static``): it relinearises the gyro-bias coupling about a heading its own
corrections keep moving, gains heading information that is not there, and steers the heading
by a gyrocompass built on biases it does not know.

Per seed: the final rotation error about the vertical (computed - true), the filter's sigma,
and their ratio; NEES is the mean squared ratio (1 for a consistent filter, below 1 for a
conservative one).

    .venv/bin/python benchmarks/static_heading.py [--seeds 8] [--duration-s 2460]
"""

from __future__ import annotations

import argparse
import math
import time
from concurrent.futures import ProcessPoolExecutor
from typing import Any

import numpy as np

from firmware_sim.run import generate
from firmware_sim.scenario import load_scenario
from firmware_sim.score import matched_imu_config
from navd.config import EstimatorConfig, load_config
from navd.core.estimator import Estimator
from navd.core.rotation import log_vec
from navd.types import PolSample
from navd.units import RAD2DEG as R2D


def run_case(case: dict[str, Any]) -> dict[str, Any]:
    sc = load_scenario("pol_static", {"duration_s": case["duration_s"]})
    run = generate(sc, seed=case["seed"])
    yaw0 = float(run.truth_euler[0, 2]) * R2D + 5.0
    cfg = EstimatorConfig.from_dict(load_config(None, [
        *matched_imu_config(sc.imu), "init.heading_source=config", f"init.heading_deg={yaw0}",
        "init.heading_sd_deg=10",
        f"heading.hold_static={'true' if case['hold'] else 'false'}"]))
    est = Estimator(cfg)
    for s in run.samples():
        if not isinstance(s, PolSample):
            est.push(s)
    phi = -np.array(log_vec(est.mat_nb @ run.truth_mat_nb[-1].T))
    return {"seed": case["seed"], "hold": case["hold"], "err_deg": float(phi[2]) * R2D,
            "sd_deg": math.sqrt(float(est.P[2, 2])) * R2D,
            "held": est.counters.get("heading_held", 0)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--duration-s", type=float, default=2460.0)
    ap.add_argument("--hold", default="on,off", help="which of hold on/off to run")
    ap.add_argument("--jobs", type=int, default=2)
    a = ap.parse_args(argv)
    holds = [{"on": True, "off": False}[x] for x in a.hold.split(",")]
    cases = [{"seed": s, "hold": h, "duration_s": a.duration_s}
             for h in holds for s in range(1, a.seeds + 1)]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(a.jobs) as ex:
        recs = list(ex.map(run_case, cases))
    print(f"static MEMS, no heading source, {a.duration_s:.0f} s, heading 5 deg off "
          f"(sigma 10 deg) at start; deg")
    print("hold | per seed: error / filter sigma                                     | "
          "max |err|  mean sigma  NEES")
    for h in holds:
        rs = [r for r in recs if r["hold"] == h]
        cells = " ".join(f"{r['err_deg']:+.1f}/{r['sd_deg']:.1f}" for r in rs)
        nees = float(np.mean([(r["err_deg"] / r["sd_deg"]) ** 2 for r in rs]))
        print(f"{'on ' if h else 'off'}  | {cells:66s} | {max(abs(r['err_deg']) for r in rs):8.1f}"
              f"  {np.mean([r['sd_deg'] for r in rs]):10.1f}  {nees:5.2f}")
    print(f"\n{len(cases)} runs in {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
