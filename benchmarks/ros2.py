"""ROS 2 output cost per published solution: building and CDR-serialising Imu, NavSatFix,
Odometry (every output) and the heading DiagnosticArray (once a second), plus the rmw_zenoh
attachment, on this machine, one core.  No Zenoh put (that is the session's cost).

    python benchmarks/ros2.py [--n 5000] [--json PATH]

Prints microseconds per message and the share of one core at the default 50 Hz.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from collections.abc import Callable
from typing import Any

from navd.io.ros2.messages import MessageBuilder
from navd.io.ros2.rmw import attachment, entity_gid
from navd.types import NavSolution


def _solution(k: int) -> NavSolution:
    yaw = 0.001 * k
    return NavSolution(
        t_us=1_000_000 + 20_000 * k, quat_nb=(math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)),
        roll_rad=0.0, pitch_rad=0.0, yaw_rad=yaw, lat_rad=0.8, lon_rad=0.1 + 1e-8 * k,
        alt_m=500.0, vel_n=(1.0, 2.0, 0.0), att_sd_rad=(0.002, 0.002, 0.01),
        gyro_bias_rps=(0.0, 0.0, 0.0), accel_bias_mps2=(0.0, 0.0, 0.0), heading_aligned=True,
        rate_b=(0.0, 0.0, 0.001), pos_sd_m=(1.0, 1.0, 2.0), vel_sd_mps=(0.1, 0.1, 0.2))


def _bench(n: int, build: Callable[[NavSolution, int], Any], b: MessageBuilder) -> float:
    sols = [_solution(k) for k in range(n)]
    gid = entity_gid("@ros2_lv/0/x/0/1/MP/%/%/navd/%imu/t/h/::,10:,:,:,,")
    b.serialize(build(sols[0], 0))  # compiles the numba geodesy once (the daemon's first fix)
    t0 = time.perf_counter()
    for k, s in enumerate(sols):
        b.serialize(build(s, 1_700_000_000_000_000_000 + k))
        attachment(k + 1, 1_700_000_000_000_000_000 + k, gid)
    return (time.perf_counter() - t0) / n


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=5000)
    ap.add_argument("--json", help="write the figures to this file")
    a = ap.parse_args(argv)
    b = MessageBuilder("base_link", "map")
    rows = {"Imu": _bench(a.n, b.imu, b), "NavSatFix": _bench(a.n, b.navsatfix, b),
            "Odometry": _bench(a.n, b.odometry, b),
            "DiagnosticArray": _bench(a.n, lambda s, t: b.diagnostics(s, t, 0.03, "navd"), b)}
    per_output = rows["Imu"] + rows["NavSatFix"] + rows["Odometry"]
    share = (50 * per_output + rows["DiagnosticArray"]) * 100
    print(f"{'message':16s} {'us/message':>10s}")
    for name, s in rows.items():
        print(f"{name:16s} {s * 1e6:10.1f}")
    print(f"one core at 50 Hz (3 messages per output + 1 diagnostic/s): {share:.2f} %")
    if a.json:
        with open(a.json, "w", encoding="utf-8") as fh:
            json.dump({"us_per_message": {k: v * 1e6 for k, v in rows.items()},
                       "core_percent_at_50hz": share}, fh, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
