"""Allocation measurement of steady-state estimator steps (allocation tests, throughput
benchmark)."""

from __future__ import annotations

import tracemalloc
from collections.abc import Iterable
from dataclasses import dataclass

from navd.core.estimator import Estimator
from navd.types import ImuSample, Sample


@dataclass
class Allocation:
    grew: int  # bytes still held after the measured steps
    peak: int  # peak bytes above the start of the measurement
    imu: int  # IMU samples pushed while measuring
    snapshot: tracemalloc.Snapshot


def measure_steps(est: Estimator, samples: Iterable[Sample], warm_imu: int = 20000,
                  max_imu: int | None = None) -> Allocation:
    """Push ``warm_imu`` IMU samples (with what comes between) unmeasured, then the rest (or
    ``max_imu`` more IMU samples) under tracemalloc."""
    it = iter(samples)
    n = 0
    for smp in it:
        est.push(smp)
        n += isinstance(smp, ImuSample)
        if n >= warm_imu:
            break
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        tracemalloc.reset_peak()
        n = 0
        for smp in it:
            est.push(smp)
            n += isinstance(smp, ImuSample)
            if max_imu is not None and n >= max_imu:
                break
        cur, peak = tracemalloc.get_traced_memory()
        snap = tracemalloc.take_snapshot()
    finally:
        tracemalloc.stop()
    return Allocation(cur - base, peak - base, n, snap)
