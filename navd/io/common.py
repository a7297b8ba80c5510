"""What every input adapter shares: IMU plausibility (the estimator's own rule,
:mod:`navd.core.plausible`, whose ``gnss_reason`` the adapters call directly), the rate ->
increment conversion, and the reject path (count + rate-limited log line).

Rate-type IMU messages (MAVLink HIGHRES_IMU / SCALED_IMU / RAW_IMU, DroneCAN RawIMU without
integrals) carry a point sample of angular rate and specific force.  The estimator wants
increments, so each sample is held over the interval back to the previous sample of the same
source (zero-order hold): ``dtheta = omega * dt``, ``dv = f * dt``, ``dt`` from consecutive
sensor time stamps.  The first sample after start, a gap or a clock jump has no interval: it
is either given the nominal one from config or dropped (counted either way).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Hashable

from navd.core.plausible import Limits, imu_reason
from navd.diag import Counters, RateLimitedLog
from navd.types import ImuSample, Sample

SampleCallback = Callable[[Sample], None]

__all__ = ["Limits", "RateIntegrator", "Rejector", "Sample", "SampleCallback", "all_finite",
           "imu_reject_reason", "monotonic_us"]


def monotonic_us() -> int:
    """Local receive clock, integer microseconds (never jumps with wall-clock changes)."""
    return time.monotonic_ns() // 1000


class Rejector:
    """Counts a rejection under ``reason`` and logs it, at most once per interval per reason."""

    __slots__ = ("counters", "log", "prefix")

    def __init__(self, counters: Counters, log: RateLimitedLog, prefix: str) -> None:
        self.counters = counters
        self.log = log
        self.prefix = prefix

    @classmethod
    def create(
        cls,
        logger_name: str,
        prefix: str,
        counters: Counters | None = None,
        log: RateLimitedLog | None = None,
        log_interval_s: float = 5.0,
    ) -> Rejector:
        c = counters if counters is not None else Counters()
        if log is None:
            log = RateLimitedLog(logging.getLogger(logger_name), log_interval_s)
        return cls(c, log, prefix)

    def __call__(self, reason: str, detail: str = "", *args: object) -> None:
        self.counters.inc(reason)
        if detail:
            self.log.warn(reason, f"{self.prefix}: rejected ({reason}): {detail}", *args)
        else:
            self.log.warn(reason, f"{self.prefix}: rejected ({reason})")


def all_finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


def imu_reject_reason(
    gx: float, gy: float, gz: float, ax: float, ay: float, az: float, limits: Limits
) -> str | None:
    """Reason to drop one IMU point sample (rad/s, m/s^2), or None if plausible
    (:func:`navd.core.plausible.imu_reason`)."""
    return imu_reason(gx, gy, gz, ax, ay, az, limits.max_gyro_rps, limits.max_accel_mps2)


class RateIntegrator:
    """Turns point rate samples into increments, one time line per source key.

    ``max_gap_us``: a larger interval is a gap (lost samples, sensor restart), not one long
    hold; integrating a rate over it would inject a large false increment.
    """

    __slots__ = ("_last_t_us", "_max_gap_us", "_new_line", "_nominal_dt_us", "_reject")

    def __init__(
        self,
        reject: Rejector,
        nominal_dt_us: int | None,
        max_gap_us: int,
    ) -> None:
        if nominal_dt_us is not None and nominal_dt_us <= 0:
            raise ValueError("nominal_dt_us must be > 0")
        self._reject = reject
        self._nominal_dt_us = nominal_dt_us
        self._max_gap_us = max_gap_us
        self._last_t_us: dict[Hashable, int] = {}
        # per source: the stamp of a sample off its time line, which may start a new one
        self._new_line: dict[Hashable, int] = {}

    def reset(self) -> None:
        self._last_t_us.clear()
        self._new_line.clear()

    def note_time(self, key: Hashable, t_us: int) -> None:
        """Record a sample that arrived already integrated, so a later rate sample of the same
        source gets the right interval."""
        self._last_t_us[key] = t_us

    def last_time(self, key: Hashable) -> int | None:
        return self._last_t_us.get(key)

    def interval_us(self, key: Hashable, t_us: int) -> int | None:
        """Interval ending at ``t_us`` for this source, or None if the sample is to be dropped.

        A sample off the source's time line (back in time, or a gap) does not move the line
        at once: it is held as the start of a possible new line, which the next sample
        confirms by continuing it (a sensor restart, a real gap).  If the next sample
        continues the old line instead, the odd one was a single wild stamp and cost only
        itself (issue 19: interleaved forged stamps must not drop every real sample).
        """
        last = self._last_t_us.get(key)
        if last is None:
            self._last_t_us[key] = t_us
            return self._restart("imu_first_sample", "first sample of source %r", key)
        dt_us = t_us - last
        if dt_us == 0:
            self._reject("imu_duplicate_time", "source %r repeated t_us=%d", key, t_us)
            return None
        if 0 < dt_us <= self._max_gap_us:
            self._last_t_us[key] = t_us
            self._new_line.pop(key, None)
            return dt_us
        start = self._new_line.get(key)
        if start is not None and 0 < t_us - start <= self._max_gap_us:
            # the held sample started a line that goes on: switch to it
            self._last_t_us[key] = t_us
            del self._new_line[key]
            return t_us - start
        self._new_line[key] = t_us
        if dt_us < 0:
            return self._restart(
                "imu_time_backwards", "source %r time went back by %d us", key, -dt_us
            )
        return self._restart("imu_gap", "source %r gap of %d us", key, dt_us)

    def advance(self, key: Hashable, t_us: int, gx: float, gy: float, gz: float, ax: float,
                ay: float, az: float) -> ImuSample | None:
        """:meth:`push` of a sample that simply continues ``key``'s time line (0 < interval
        <= max_gap_us), from its components (the decoders' per-sample path, issue 18); None,
        nothing changed, for any other (then :meth:`push` sorts it out)."""
        last = self._last_t_us.get(key)
        if last is None:
            return None
        dt_us = t_us - last
        if not 0 < dt_us <= self._max_gap_us:
            return None
        self._last_t_us[key] = t_us
        if self._new_line:
            self._new_line.pop(key, None)
        dt_s = dt_us * 1e-6
        return ImuSample(t_us, dt_us, gx * dt_s, gy * dt_s, gz * dt_s, ax * dt_s, ay * dt_s,
                         az * dt_s)

    def continue_line(self, key: Hashable, t_us: int) -> None:
        """What :meth:`advance` leaves behind for a run of samples that each continued
        ``key``'s time line, the newest stamped ``t_us`` (the batch lane, whose compiled
        decoder checked the intervals: navd.core.highres_batch)."""
        self._last_t_us[key] = t_us
        if self._new_line:
            self._new_line.pop(key, None)

    def _restart(self, reason: str, detail: str, *args: object) -> int | None:
        # Counted even when a nominal interval rescues the sample: a restart is worth knowing.
        self._reject.counters.inc(reason)
        rescued = self._nominal_dt_us is not None
        if reason != "imu_first_sample":
            what = "assumed nominal interval" if rescued else "dropped IMU sample"
            self._reject.log.warn(reason, f"{self._reject.prefix}: {what}: {detail}", *args)
        return self._nominal_dt_us

    def push(
        self,
        key: Hashable,
        t_us: int,
        gyro_rps: tuple[float, float, float],
        accel_mps2: tuple[float, float, float],
    ) -> ImuSample | None:
        dt_us = self.interval_us(key, t_us)
        if dt_us is None:
            return None
        dt_s = dt_us * 1e-6
        return ImuSample(
            t_us=t_us,
            dt_us=dt_us,
            dtheta_x=gyro_rps[0] * dt_s,
            dtheta_y=gyro_rps[1] * dt_s,
            dtheta_z=gyro_rps[2] * dt_s,
            dvel_x=accel_mps2[0] * dt_s,
            dvel_y=accel_mps2[1] * dt_s,
            dvel_z=accel_mps2[2] * dt_s,
        )
