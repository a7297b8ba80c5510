"""What the autopilot and Foxglove outputs carry, against simulator truth (issue 17).

Per seed of the car480 drive: the solutions at 5 Hz go through the GPS_INPUT encoder and
back through pymavlink's parser (what ArduPilot's AP_GPS_MAV receives), then

- yaw: share of frames with a yaw (aligned heading), the first one's sensor time, and the
  error of the decoded centidegree yaw against true heading (RMS, max);
- accuracy honesty: RMS of error / reported accuracy for horizontal position
  (per axis, against horiz_accuracy), vertical position (vert_accuracy) and velocity
  (per axis, against speed_accuracy); 1 = honest, < 1 conservative, > 1 optimistic;
- MCAP: bytes per solution and writer time per solution for ``--mcap`` (10 Hz).

    .venv/bin/python benchmarks/outputs.py [--seeds 3] [--duration-s 240] [--json PATH]
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import common as mav

from firmware_sim import generate, load_scenario
from navd.config import EstimatorConfig
from navd.core.estimator import Estimator
from navd.io.foxglove_mcap import NavMcapWriter
from navd.io.mavlink import MavlinkEncoder
from navd.io.mavlink.autopilot import AutopilotPolicy, gps_input_frame
from navd.pipeline import solutions

WGS84_A, WGS84_E2 = 6378137.0, 6.69437999014e-3


def _radii(lat: float) -> tuple[float, float]:
    w2 = 1.0 - WGS84_E2 * math.sin(lat) ** 2
    return WGS84_A * (1 - WGS84_E2) / w2**1.5, WGS84_A / math.sqrt(w2)


def run_seed(seed: int, duration_s: float) -> dict[str, Any]:
    run = generate(load_scenario("car480", {"duration_s": duration_s}), seed=seed)
    est = Estimator(EstimatorConfig())
    policy = AutopilotPolicy(aligned_sd=est.cfg.init.aligned_sd)
    enc, parser = MavlinkEncoder(), mav.MAVLink(None)
    yaw_err, z_h, z_v, z_s = [], [], [], []
    frames = with_yaw = 0
    first_yaw_s = math.nan
    for sol in solutions(est, run.samples(), 5.0):
        m = parser.parse_buffer(gps_input_frame(enc, sol, policy))[0]
        frames += 1
        k = sol.t_us // run.imu_dt_us
        if m.yaw:
            with_yaw += 1
            if math.isnan(first_yaw_s):
                first_yaw_s = sol.t_us * 1e-6
            d = m.yaw * 0.01 - math.degrees(run.truth_euler[k, 2])
            yaw_err.append((d + 180.0) % 360.0 - 180.0)
        if sol.t_us < 10_000_000:  # after the start-up transient, as a receiver settles
            continue
        lat, lon, h = run.truth_pos[k]
        r_m, r_n = _radii(lat)
        en = (m.lat * 1e-7 - math.degrees(lat)) * math.pi / 180 * (r_m + h)
        ee = (m.lon * 1e-7 - math.degrees(lon)) * math.pi / 180 * (r_n + h) * math.cos(lat)
        z_h += [en / m.horiz_accuracy, ee / m.horiz_accuracy]
        z_v.append((m.alt - h) / m.vert_accuracy)
        dv = np.array([m.vn, m.ve, m.vd]) - run.truth_vel_n[k]
        z_s += list(dv / m.speed_accuracy)
    err = np.asarray(yaw_err)

    def rms(z: list[float]) -> float:
        return float(np.sqrt(np.mean(np.square(z))))

    return {"seed": seed, "frames": frames, "yaw_share": with_yaw / frames,
            "first_yaw_s": first_yaw_s, "yaw_rms_deg": float(np.sqrt(np.mean(err**2))),
            "yaw_max_deg": float(np.max(np.abs(err))), "z_horiz": rms(z_h), "z_vert": rms(z_v),
            "z_speed": rms(z_s)}


def mcap_cost(duration_s: float) -> dict[str, float]:
    run = generate(load_scenario("car480", {"duration_s": duration_s}), seed=1)
    est = Estimator(EstimatorConfig())
    sols = list(solutions(est, run.samples(), 10.0))
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "b.mcap"
        t0 = time.perf_counter()
        with NavMcapWriter(path, aligned_sd_rad=est.cfg.init.aligned_sd) as w:
            for s in sols:
                w.write_solution(s, s.t_us * 1000)
        dt = time.perf_counter() - t0
        size = path.stat().st_size
    return {"solutions": len(sols), "bytes_per_solution": size / len(sols),
            "us_per_solution": dt / len(sols) * 1e6, "mb_per_hour_at_10hz":
                size / len(sols) * 36000 / 1e6}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--duration-s", type=float, default=240.0)
    ap.add_argument("--json", metavar="PATH")
    a = ap.parse_args(argv)
    recs = [run_seed(s, a.duration_s) for s in range(1, a.seeds + 1)]
    print(f"car480, {a.duration_s:.0f} s, GPS_INPUT at 5 Hz decoded by pymavlink, vs truth")
    print("seed | frames | with yaw | first yaw s | yaw RMS / max deg | "
          "err/acc RMS: horiz  vert  speed")
    for r in recs:
        print(f"{r['seed']:4d} | {r['frames']:6d} | {r['yaw_share']:8.1%} | "
              f"{r['first_yaw_s']:11.1f} | {r['yaw_rms_deg']:7.3f} / {r['yaw_max_deg']:6.3f} | "
              f"{r['z_horiz']:17.2f} {r['z_vert']:5.2f} {r['z_speed']:6.2f}")
    mc = mcap_cost(min(a.duration_s, 120.0))
    print(f"\nMCAP (--mcap, 10 Hz): {mc['bytes_per_solution']:.0f} bytes and "
          f"{mc['us_per_solution']:.0f} us per solution ({mc['mb_per_hour_at_10hz']:.1f} MB/h)")
    if a.json:
        Path(a.json).write_text(json.dumps({"seeds": recs, "mcap": mc}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
