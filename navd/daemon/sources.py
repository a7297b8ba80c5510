"""The daemon's inputs: adapter links feeding one bounded queue in front of the estimator.

Adapters call back on the event loop with decoded samples; each sample is queued together
with the host receive time (``time.monotonic_ns``) of the datagram or CAN frame it came in,
so the daemon can measure receive -> output latency.  The estimator only ever sees the
sensor time stamps inside the samples.

Queue policy: when full, the OLDEST sample is dropped (counted as ``queue_drops``).  The
queue only absorbs bursts; if the estimator falls behind for good, no queue size helps, and
then fresh data is what matters for an attitude output: dropping the newest would keep the
queue full and every output a full queue late for as long as the overload lasts, while
dropping the oldest bounds the lag by the queue length and the estimator sees a counted
IMU gap instead.
"""

from __future__ import annotations

import asyncio
import logging
import time

from navd.config.daemon import DaemonConfig
from navd.diag import RateLimitedLog
from navd.io.common import Sample
from navd.io.dronecan import DronecanDecoder, DronecanLink
from navd.io.mavlink import MavlinkDecoder, MavlinkLink

__all__ = ["ReceiveClock", "SampleQueue", "Sources"]

_log = logging.getLogger("navd.daemon.sources")

QueueItem = tuple[int, Sample] | None  # (recv_t_ns, sample); None ends the stream


class ReceiveClock:
    """``clock_us`` for an adapter link that also keeps the full-resolution time it handed out.

    A link reads the clock once per datagram/frame, before decoding, and then calls back with
    the samples decoded from it, so ``last_ns`` is the receive time of those samples.
    """

    __slots__ = ("last_ns",)

    def __init__(self) -> None:
        self.last_ns = time.monotonic_ns()

    def __call__(self) -> int:
        self.last_ns = time.monotonic_ns()
        return self.last_ns // 1000


class SampleQueue:
    """Bounded asyncio queue of (recv_t_ns, sample), dropping the oldest when full."""

    def __init__(self, maxsize: int, log: RateLimitedLog) -> None:
        self.maxsize = maxsize
        self._q: asyncio.Queue[QueueItem] = asyncio.Queue(maxsize)
        self._log = log
        self.drops = 0
        self.high_water = 0
        self.closed = False

    def put(self, recv_ns: int, sample: Sample) -> None:
        if self.closed:
            return
        self._put((recv_ns, sample))

    def _put(self, item: QueueItem) -> None:
        q = self._q
        if q.full():
            q.get_nowait()
            self.drops += 1
            self._log.warn("queue_drops", "queue full (%d samples): dropped the oldest; "
                           "%d dropped so far", self.maxsize, self.drops)
        q.put_nowait(item)
        n = q.qsize()
        if n > self.high_water:
            self.high_water = n

    def close(self) -> None:
        """No more input; the consumer gets what is queued, then None."""
        if not self.closed:
            self.closed = True
            self._put(None)

    async def get(self) -> QueueItem:
        return await self._q.get()

    def qsize(self) -> int:
        return self._q.qsize()


class Sources:
    """Opens the configured input links; all of them feed :class:`SampleQueue`."""

    def __init__(self, cfg: DaemonConfig, queue: SampleQueue) -> None:
        self.cfg = cfg
        self.queue = queue
        self.mavlink: MavlinkLink | None = None
        self.mavlink_decoder: MavlinkDecoder | None = None
        self.dronecan: DronecanLink | None = None
        self.dronecan_decoder: DronecanDecoder | None = None

    async def open(self) -> list[str]:
        """Open every configured input; return descriptions.  Raises OSError & co. on failure
        (after closing what was already open)."""
        opened: list[str] = []
        try:
            m = self.cfg.mavlink
            if m.enabled and m.listen:
                clock = ReceiveClock()
                queue = self.queue
                self.mavlink_decoder = MavlinkDecoder(m.input_config())

                def on_mavlink(s: Sample) -> None:
                    queue.put(clock.last_ns, s)

                self.mavlink = await MavlinkLink.open(m.listen, self.mavlink_decoder,
                                                      on_mavlink, clock_us=clock)
                rx = self.cfg.daemon.rx_buffer_bytes
                if rx:
                    # The default (~200 kB, ~270 small datagrams) overflows during a short
                    # stall of the loop at kHz input rates; the kernel counts, nobody else.
                    got = self.mavlink.set_receive_buffer(rx)
                    if got and got < rx:
                        _log.info("UDP receive buffer %d bytes (asked %d; net.core.rmem_max "
                                  "limits it)", got, rx)
                opened.append(f"mavlink {m.listen}")
            d = self.cfg.dronecan
            if d.enabled:
                dclock = ReceiveClock()
                dqueue = self.queue
                bus_cfg = d.bus_config()
                self.dronecan_decoder = DronecanDecoder(bus_cfg)

                def on_dronecan(s: Sample) -> None:
                    dqueue.put(dclock.last_ns, s)

                self.dronecan = await DronecanLink.open(bus_cfg, self.dronecan_decoder,
                                                        on_dronecan, clock_us=dclock)
                opened.append(f"dronecan {d.interface}:{d.channel}")
        except BaseException:
            self.close()
            raise
        return opened

    def counters(self) -> dict[str, dict[str, int]]:
        out: dict[str, dict[str, int]] = {}
        if self.mavlink_decoder is not None:
            out["mavlink"] = self.mavlink_decoder.counters.snapshot()
        if self.dronecan_decoder is not None:
            out["dronecan"] = self.dronecan_decoder.counters.snapshot()
        return out

    def close(self) -> None:
        """Close every link (also the send side of a link a sink shares)."""
        if self.mavlink is not None:
            self.mavlink.close()
        if self.dronecan is not None:
            self.dronecan.close()
            self.dronecan = None
