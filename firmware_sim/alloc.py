"""Allocation measurement of steady-state estimator steps (allocation tests, throughput
benchmark)."""

from __future__ import annotations

import tracemalloc
from collections.abc import Iterable
from dataclasses import dataclass

from navd.core.estimator import Estimator
from navd.core.imu_block import ImuBlock
from navd.types import ImuSample, Sample


@dataclass
class Allocation:
    grew: int  # bytes still held after the measured steps
    peak: int  # peak bytes above the start of the measurement
    imu: int  # IMU samples pushed while measuring
    snapshot: tracemalloc.Snapshot


class BlockPusher:
    """Pushes IMU samples in blocks of ``size`` (``Estimator.push_imu_block``, stopping at
    every ``period_us`` of sensor time as the daemon does at its output instants; what the
    block run leaves goes one by one), other samples one by one, as the daemon's UDP batch
    lane does; no clock guard (a window that passes everything)."""

    def __init__(self, est: Estimator, size: int = 10, period_us: int = 20_000) -> None:
        self.est = est
        self.block = ImuBlock(None, size)
        self.period_us = period_us

    def push(self, s: Sample) -> None:
        b = self.block
        if isinstance(s, ImuSample):
            k = b.n
            b.t_us[k], b.dt_us[k] = s.t_us, s.dt_us
            inc = b.inc
            inc[k, 0], inc[k, 1], inc[k, 2] = s.dtheta_x, s.dtheta_y, s.dtheta_z
            inc[k, 3], inc[k, 4], inc[k, 5] = s.dvel_x, s.dvel_y, s.dvel_z
            b.n = k + 1
            if b.n == len(b.t_us):
                self.flush()
            return
        self.flush()
        self.est.push(s)

    def flush(self) -> None:
        b, est, p = self.block, self.est, self.period_us
        while b.start < b.n:
            stop = (est.t_us // p + 1) * p
            if not est.push_imu_block(b, stop, est.t_us, 1 << 60, 1 << 60):
                est.push(b.sample(b.start))
                b.start += 1
        b.n = b.start = 0


def measure_steps(est: Estimator, samples: Iterable[Sample], warm_imu: int = 20000,
                  max_imu: int | None = None, block: int = 0) -> Allocation:
    """Push ``warm_imu`` IMU samples (with what comes between) unmeasured, then the rest (or
    ``max_imu`` more IMU samples) under tracemalloc; ``block`` > 0: IMU samples in blocks
    of that many (:class:`BlockPusher`)."""
    it = iter(samples)
    pusher = BlockPusher(est, block) if block else None
    push = pusher.push if pusher is not None else est.push
    n = 0
    for smp in it:
        push(smp)
        n += isinstance(smp, ImuSample)
        if n >= warm_imu:
            break
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        tracemalloc.reset_peak()
        n = 0
        for smp in it:
            push(smp)
            n += isinstance(smp, ImuSample)
            if max_imu is not None and n >= max_imu:
                break
        if pusher is not None:
            pusher.flush()
        cur, peak = tracemalloc.get_traced_memory()
        snap = tracemalloc.take_snapshot()
    finally:
        tracemalloc.stop()
    return Allocation(cur - base, peak - base, n, snap)
