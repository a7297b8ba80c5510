"""Core throughput and allocation: IMU samples/s through ``Estimator.push`` on car480.

Completed mode, GNSS at 10 Hz, default config.  Samples are built beforehand so only the
estimator is timed.  Allocation: tracemalloc peak growth over 10,000 steady-state IMU steps
(after warm-up, so JIT compilation and first-time code paths are excluded).

    python benchmarks/throughput.py [--robust gate|mctls|none] [--json PATH]
"""

from __future__ import annotations

import argparse
import json
import platform
import time

from firmware_sim import generate, load_scenario
from firmware_sim.alloc import measure_steps
from navd.config import EstimatorConfig, load_config
from navd.core.estimator import Estimator
from navd.types import ImuSample


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--robust", default="gate", choices=["none", "gate", "mctls"])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", help="write the figures to this file")
    a = ap.parse_args(argv)

    run = generate(load_scenario("car480"), seed=1, progress=False)
    samples = list(run.samples())
    n_imu = sum(isinstance(s, ImuSample) for s in samples)
    overrides = ["filter.mode=completed", f"filter.robust={a.robust}",
                 "init.heading_source=config"]
    cfg = EstimatorConfig.from_dict(load_config(None, overrides))

    # warm-up run: compiles/loads every kernel
    e = Estimator(cfg)
    for s in samples:
        e.push(s)

    best = float("inf")
    for _ in range(a.repeats):
        e = Estimator(cfg)
        push = e.push
        t0 = time.perf_counter()
        for s in samples:
            push(s)
        best = min(best, time.perf_counter() - t0)
    rate = n_imu / best

    # allocation over 10,000 steady-state IMU steps (after 200 s of navigation)
    growth = measure_steps(Estimator(cfg), samples, max_imu=10000).peak
    # the same in blocks of 10 (Estimator.push_imu_block: the daemon's UDP batch lane)
    block_growth = measure_steps(Estimator(cfg), samples, max_imu=10000, block=10).peak

    print(f"{'metric':<40}{'value':>16}{'target':>14}")
    print(f"{'IMU samples/s (completed, ' + a.robust + ')':<40}{rate:>16,.0f}{'>= 50,000':>14}")
    print(f"{'time per IMU sample (incl. GNSS), us':<40}{1e6 / rate:>16.1f}{'':>14}")
    print(f"{'tracemalloc peak growth, 10k steps, B':<40}{growth:>16d}{'< 1024':>14}")
    print(f"{'  the same in blocks of 10, B':<40}{block_growth:>16d}{'< 1024':>14}")
    print(f"({n_imu} IMU + {len(samples) - n_imu} GNSS samples, best of {a.repeats}, "
          f"{platform.processor() or platform.machine()}, Python {platform.python_version()})")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump({"imu_samples_per_s": rate, "alloc_peak_growth_bytes": growth,
                       "alloc_peak_growth_blocks_bytes": block_growth,
                       "robust": a.robust, "n_imu": n_imu}, fh, indent=2)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
