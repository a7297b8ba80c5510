"""Read pacing: how long a UDP input socket may be left unread without delaying an output.

At 1 kHz IMU a datagram-per-wake-up daemon spends most of its CPU waking up (the kernel's
context switch, the event loop's poll, a cold interpreter cache) rather than working on the
sample (docs/results.md "Daemon CPU (issue 18)").  Only the IMU sample that completes an
output instant has to be read as soon as it arrives: the outputs are due at multiples of
each sink's period on the sensor clock (:class:`navd.pipeline.OutputSchedule`), so the
samples between two instants may wait in the socket buffer and be read in one batch.

:class:`ReadPacer` watches the IMU time stamps the link delivers with the host time they
were read at, estimates how fast sensor time advances against host time (1 for a live
sensor; more for a stream played faster than real time), and answers, right after a batch
was read, for how long the socket may stay unread: until ``margin_us`` before the next
output instant's sample is due, at most ``max_hold_us``, and not at all when that is under
``min_hold_us`` (then every datagram is read as it comes, as without pacing).  Nothing is
dropped or reordered by pacing: every datagram is still read, in arrival order, only later;
the kernel buffer (``[daemon] rx_buffer_bytes``) holds the batch meanwhile.

Pure bookkeeping on integers (microseconds); the link passes its host clock in as data.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

__all__ = ["ReadPacer"]

# host time over which the sensor-time rate is measured
_RATE_WINDOW_US = 200_000
# IMU samples read this far apart (host time): the sender paused, measure its pace afresh
_QUIET_US = 100_000
# a measured sensor/host rate this close to 1 is a live sensor's: taken as exactly 1
_LIVE_RATE_TOLERANCE = 0.05


class ReadPacer:
    """See the module docstring.  ``periods_us``: the output periods of the sinks (sensor
    time); ``note(t_us, host_us)`` for every IMU sample read; ``hold_us(host_us)`` right
    after a batch was read."""

    __slots__ = ("_h0", "_lag", "_lag_prev", "_rate", "_t0", "host_last", "margin_us",
                 "max_hold_us", "min_hold_us", "periods_us", "t_last")

    def __init__(self, periods_us: Sequence[int], max_hold_us: int = 20_000,
                 margin_us: int = 3_000, min_hold_us: int = 1_000) -> None:
        if any(p <= 0 for p in periods_us) or max_hold_us < 0 or margin_us < 0:
            raise ValueError("ReadPacer: bad limits")
        self.periods_us = tuple(periods_us)
        self.max_hold_us = max_hold_us
        self.margin_us = margin_us
        self.min_hold_us = min_hold_us
        self.t_last = -1  # newest IMU stamp read (sensor clock, us)
        self.host_last = 0  # host time it was read at (us)
        self._t0 = -1  # start of the rate window: sensor and host time
        self._h0 = 0
        self._rate = 0.0  # sensor us per host us; 0: not known yet (no holding)
        # host time of reading minus sensor time at the sender's pace (us), least of this
        # rate window and of the one before: the samples read soonest after they were
        # due; a sample that reached us late must not push the next instant later
        self._lag = math.inf
        self._lag_prev = math.inf

    def note(self, t_us: int, host_us: int, edge: bool = True) -> None:
        """An IMU sample stamped ``t_us`` was read at host time ``host_us``.  ``edge``: the
        host time is this sample's own arrival (the last sample of a read); a sample read
        earlier in the same read arrived up to a hold before it and must not bound the
        rate window (an edge 17 ms off over 200 ms read the rate as 0.91-1.09, outside the
        live tolerance, in a third of the windows)."""
        if t_us <= self.t_last:  # disorder, or a clock that started over: measure afresh
            if t_us < self.t_last:
                self._t0 = -1
                self._rate = 0.0
                self.t_last = -1
            return
        quiet = host_us - self.host_last > _QUIET_US
        self.t_last = t_us
        self.host_last = host_us
        if quiet:  # the sender paused: its pace before says nothing about its pace now
            self._t0 = -1
            self._rate = 0.0
        if self._t0 < 0:
            if edge:
                self._t0, self._h0 = t_us, host_us
                self._lag = self._lag_prev = math.inf
            return
        lag = host_us - t_us
        if lag < self._lag:
            self._lag = lag
        if not edge:
            return
        dh = host_us - self._h0
        if dh >= _RATE_WINDOW_US:
            rate = (t_us - self._t0) / dh
            # a live sensor's clock runs at the host's (ppm apart); the measured ratio
            # differs from 1 by the arrival jitter over the window only
            self._rate = 1.0 if abs(rate - 1.0) < _LIVE_RATE_TOLERANCE else rate
            self._t0, self._h0 = t_us, host_us
            self._lag_prev, self._lag = self._lag, math.inf

    def note_run(self, t_us: npt.NDArray[np.int64], i: int, n: int, host_us: int,
                 last: bool = True) -> None:
        """:meth:`note` of ``t_us[i:i + n]`` (n >= 1), strictly increasing stamps read at one
        host time (a run of the batch lane), with three calls: after the first two, every
        further stamp of such a run only moves ``t_last`` and the least lag, which the last
        one sets.  ``last``: the run ends the read, so ``host_us`` is its last sample's
        arrival (that sample may bound the rate window; no other may)."""
        if n == 1:
            self.note(int(t_us[i]), host_us, last)
            return
        self.note(int(t_us[i]), host_us, False)
        if n == 2:
            self.note(int(t_us[i + 1]), host_us, last)
            return
        self.note(int(t_us[i + 1]), host_us, False)
        self.note(int(t_us[i + n - 1]), host_us, last)

    def hold_us(self, host_us: int) -> int:
        """How long (host us) the socket may stay unread from ``host_us``: 0 to read on."""
        rate = self._rate
        if rate <= 0.0 or not self.periods_us or self.max_hold_us <= 0:
            return 0
        t = self.t_last
        t_next = min((t // p + 1) * p for p in self.periods_us)  # next instant, sensor us
        lag = min(self._lag, self._lag_prev)
        if rate == 1.0 and lag < math.inf:
            # due at the least lag seen: a sample that reached us late (a sender that
            # stalled, then caught up) must not move the expected arrival later
            due = t_next + lag
        else:  # a stream faster (or slower) than real time: from the newest sample
            due = self.host_last + (t_next - t) / rate
        hold = due - host_us - self.margin_us
        if not hold >= self.min_hold_us:
            return 0
        return min(round(hold), self.max_hold_us)
