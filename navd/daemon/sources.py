"""The daemon's inputs: adapter links feeding one bounded queue in front of the estimator.

Each input kind is a small adapter behind one interface (:class:`Input`: ``open(queue)
-> description``, ``counters()``, ``close()``, and the ``link`` a sink may share), listed
in :data:`INPUT_KINDS` under the name its counters appear as in the status (``inputs``).
:class:`Sources` opens the kinds the configuration enables, in that order; adding a
transport is one adapter class and one registry entry, not another branch here.

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
import collections
import logging
import time
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, ClassVar, Generic, Protocol, TypeVar

from navd.config.daemon import DaemonConfig
from navd.core.imu_block import ImuBlock
from navd.core.plausible import Limits
from navd.daemon.adapters import dronecan_bus_config, mavlink_input_config
from navd.diag import RateLimitedLog
from navd.io.common import Sample, SampleCallback
from navd.io.logs.common import vehicle_from_heartbeats
from navd.io.mavlink import MavlinkDecoder, MavlinkLink
from navd.io.read_pacing import ReadPacer

if TYPE_CHECKING:  # imported when DroneCAN is opened (see adapters.dronecan_bus_config)
    from navd.io.dronecan import DronecanDecoder, DronecanLink

__all__ = [
    "INPUT_KINDS",
    "DronecanInput",
    "Input",
    "InputKind",
    "InputOpenError",
    "MavlinkInput",
    "ReceiveClock",
    "SampleQueue",
    "Sources",
]

_log = logging.getLogger("navd.daemon.sources")

# (recv_t_ns, sample or a block of IMU samples); None ends the stream
Item = tuple[int, Sample | ImuBlock]
QueueItem = Item | None


class ReceiveClock:
    """``clock_us`` for an adapter link that also keeps the full-resolution time it handed out.

    A link reads the clock once per datagram/frame, before decoding, and then calls back with
    the samples decoded from it, so ``last_ns`` is the receive time of those samples.  A link
    that knows when its input arrived (the kernel's stamp of a UDP read, which the read
    pacing may take well after the arrival) hands that time to :meth:`at_ns` instead.
    """

    __slots__ = ("last_ns",)

    def __init__(self) -> None:
        self.last_ns = time.monotonic_ns()

    def __call__(self) -> int:
        self.last_ns = time.monotonic_ns()
        return self.last_ns // 1000

    def at_ns(self, ns: int) -> int:
        """Like a call, for input that arrived at ``ns`` (``time.monotonic_ns``), already
        past: the time kept and returned (us) is that one."""
        self.last_ns = ns
        return ns // 1000


class SampleQueue:
    """Bounded FIFO of (recv_t_ns, sample) from the links' callbacks to the estimator task,
    dropping the oldest when full.  An item may be an :class:`ImuBlock` (the UDP batch
    lane: a read's IMU samples as one item, from a pool of a few blocks, so the queue's
    memory stays bounded); a dropped block goes back to its pool, its samples counted.

    A deque and the waiting consumer's future rather than asyncio.Queue: at 1 kHz nearly
    every sample finds the consumer waiting, and asyncio.Queue's bookkeeping around that
    hand-off (getter and putter lists, the unfinished-task count and its Event) cost about as
    much again as waking the consumer (benchmarks/loop_floor.py, issue 18).

    A consumer may also name a ``direct`` handler: an item put while the consumer is parked
    on an empty queue is then handled at once, inside the producer's callback, instead of
    waking the consumer's task (one more event-loop turn, a future and a task step per read
    at 1 kHz).  The order is the same: only an item that would have been taken next, by a
    consumer with nothing else to do, goes direct.  An exception from the handler is the
    consumer's: it is raised from its pending :meth:`get`, as if it had taken the item.
    """

    def __init__(self, maxsize: int, log: RateLimitedLog) -> None:
        self.maxsize = maxsize
        self._q: collections.deque[QueueItem] = collections.deque()
        # what is queued, for a consumer that takes it without awaiting get() per item
        # (popleft while non-empty, get() when empty: the same items in the same order)
        self.ready = self._q
        self._waiter: asyncio.Future[None] | None = None  # the parked consumer, if any
        self.direct: Callable[[Item], None] | None = None
        self._in_direct = False  # an item put while one is handled directly is queued
        self._log = log
        self.drops = 0
        self.high_water = 0
        self.closed = False

    def put(self, recv_ns: int, sample: Sample | ImuBlock) -> None:
        if not self.closed:
            self._put((recv_ns, sample))

    def _put(self, item: QueueItem) -> None:
        q = self._q
        w = self._waiter
        if w is not None and item is not None and not q and not self._in_direct:
            fn = self.direct
            if fn is not None:
                self._in_direct = True
                try:
                    fn(item)
                except Exception as exc:  # the consumer's failure, raised where it waits
                    self._waiter = None
                    if not w.done():
                        w.set_exception(exc)
                finally:
                    self._in_direct = False
                return
        if len(q) >= self.maxsize:
            old = q.popleft()
            if old is not None and type(old[1]) is ImuBlock:
                self.drops += len(old[1])
                old[1].release()
            else:
                self.drops += 1
            self._log.warn("queue_drops", "queue full (%d samples): dropped the oldest; "
                           "%d dropped so far", self.maxsize, self.drops)
        q.append(item)
        n = len(q)
        if n > self.high_water:
            self.high_water = n
        w = self._waiter
        if w is not None:
            self._waiter = None
            if not w.done():
                w.set_result(None)

    def close(self) -> None:
        """No more input; the consumer gets what is queued, then None."""
        if not self.closed:
            self.closed = True
            self._put(None)

    async def get(self) -> QueueItem:
        q = self._q
        while not q:
            w = asyncio.get_running_loop().create_future()
            self._waiter = w
            try:
                await w
            finally:  # also when the consumer is cancelled while waiting
                if self._waiter is w:
                    self._waiter = None
        return q.popleft()

    def qsize(self) -> int:
        return len(self._q)


DecoderT = TypeVar("DecoderT", MavlinkDecoder, "DronecanDecoder")
LinkT = TypeVar("LinkT", MavlinkLink, "DronecanLink")


def _queueing(queue: SampleQueue) -> tuple[ReceiveClock, SampleCallback]:
    """A link's clock and sample callback: each sample is queued with the receive time of
    the datagram or frame it was decoded from."""
    clock = ReceiveClock()

    def on_sample(s: Sample) -> None:
        queue.put(clock.last_ns, s)

    return clock, on_sample


def _block_queueing(queue: SampleQueue, clock: ReceiveClock) -> Callable[[ImuBlock], None]:
    """A UDP link's block callback (the batch lane): the block queued as one item with the
    receive time of the read it came from."""

    def on_block(b: ImuBlock) -> None:
        if queue.closed:
            b.release()
        else:
            queue.put(clock.last_ns, b)

    return on_block


class Input(Protocol):
    """One input kind: opens its link onto the queue, reports its decoder's counters."""

    kind: ClassVar[str]  # key under ``inputs`` in the status
    config_key: ClassVar[str]  # the setting that names the link, for errors: "mavlink.listen"

    @property
    def link(self) -> object:
        """The open link (None before open): a sink may send on it, see Sources.mavlink."""
        ...

    @staticmethod
    def wanted(cfg: DaemonConfig) -> bool:
        """Whether the configuration enables this input."""
        ...

    async def open(self, queue: SampleQueue) -> str:
        """Open the link feeding ``queue``; return a description for the start-up log."""
        ...

    def counters(self) -> dict[str, int] | None:
        """The decoder's counters; None before :meth:`open` has made a decoder."""
        ...

    def lock_status(self) -> dict[str, Any] | None:
        """Which source each kind of input is locked to (navd.io.source_lock); None when
        not locking."""
        ...

    def close(self) -> None:
        """Close the link (also the send side of a link a sink shares)."""
        ...


class _DecodingInput(Generic[DecoderT, LinkT]):
    """What the input kinds share: the daemon config, a decoder and a link, both made by
    ``open``; counters are the decoder's."""

    def __init__(self, cfg: DaemonConfig) -> None:
        self.cfg = cfg
        self.decoder: DecoderT | None = None
        self.link: LinkT | None = None

    def counters(self) -> dict[str, int] | None:
        return self.decoder.counters.snapshot() if self.decoder is not None else None

    def lock_status(self) -> dict[str, Any] | None:
        lock = self.decoder.source_lock if self.decoder is not None else None
        return lock.status() if lock is not None else None


class MavlinkInput(_DecodingInput[MavlinkDecoder, MavlinkLink]):
    """``[mavlink] listen``: a MAVLink link whose send side a sink may share (send = "same")."""

    kind: ClassVar[str] = "mavlink"
    config_key: ClassVar[str] = "mavlink.listen"

    @staticmethod
    def wanted(cfg: DaemonConfig) -> bool:
        return bool(cfg.mavlink.enabled and cfg.mavlink.listen)

    async def open(self, queue: SampleQueue) -> str:
        m = self.cfg.mavlink
        clock, on_sample = _queueing(queue)
        self.decoder = MavlinkDecoder(mavlink_input_config(
            m, Limits.from_config(self.cfg.estimator.imu),
            warn_interval_s=self.cfg.daemon.warn_interval))
        self.link = await MavlinkLink.open(m.listen, self.decoder, on_sample, clock_us=clock)
        self.link.deliver_blocks(_block_queueing(queue, clock))
        rx = self.cfg.daemon.rx_buffer
        if rx:
            # The default (~200 kB, ~270 small datagrams) overflows during a short
            # stall of the loop at kHz input rates; the kernel counts, nobody else.
            got = self.link.set_receive_buffer(rx)
            if got and got < rx:
                _log.info("UDP receive buffer %d bytes (asked %d; net.core.rmem_max "
                          "limits it)", got, rx)
        return f"mavlink {m.listen}"

    def close(self) -> None:
        # The link object stays: a sink sharing it may still ask for its counters.
        if self.link is not None:
            self.link.close()


class DronecanInput(_DecodingInput["DronecanDecoder", "DronecanLink"]):
    """``[dronecan]``: a python-can bus; the DroneCAN sink sends on the same bus."""

    kind: ClassVar[str] = "dronecan"
    config_key: ClassVar[str] = "dronecan.channel"

    @staticmethod
    def wanted(cfg: DaemonConfig) -> bool:
        return bool(cfg.dronecan.enabled)

    async def open(self, queue: SampleQueue) -> str:
        d = self.cfg.dronecan
        clock, on_sample = _queueing(queue)
        from navd.io.dronecan import DronecanDecoder, DronecanLink

        bus_cfg = dronecan_bus_config(d, Limits.from_config(self.cfg.estimator.imu),
                                      warn_interval_s=self.cfg.daemon.warn_interval)
        self.decoder = DronecanDecoder(bus_cfg)
        self.link = await DronecanLink.open(bus_cfg, self.decoder, on_sample, clock_us=clock)
        return f"dronecan {d.interface}:{d.channel}"

    def close(self) -> None:
        # Shutting a python-can bus down twice is not safe on every interface: forget it.
        if self.link is not None:
            self.link.close()
            self.link = None


class InputKind(Protocol):
    """What the registry holds: an :class:`Input` class (its name, its config test, and the
    constructor taking the daemon configuration)."""

    @property
    def kind(self) -> str: ...

    @property
    def config_key(self) -> str: ...

    def wanted(self, cfg: DaemonConfig) -> bool: ...

    def __call__(self, cfg: DaemonConfig) -> Input: ...


# The input kinds the daemon knows, opened (and closed) in this order.
INPUT_KINDS: tuple[InputKind, ...] = (MavlinkInput, DronecanInput)


class InputOpenError(Exception):
    """An input could not be opened: which setting names it, and the underlying error."""

    def __init__(self, config_key: str, cause: BaseException) -> None:
        super().__init__(f"{config_key}: {cause}")
        self.config_key = config_key
        self.cause = cause


class Sources:
    """Opens the configured input kinds; all of them feed :class:`SampleQueue`."""

    def __init__(self, cfg: DaemonConfig, queue: SampleQueue) -> None:
        self.cfg = cfg
        self.queue = queue
        self.inputs: dict[str, Input] = {}

    async def open(self) -> list[str]:
        """Open every configured input; return descriptions.  Raises :class:`InputOpenError`
        naming the input's setting (after closing what was already open)."""
        opened: list[str] = []
        try:
            for kind in INPUT_KINDS:
                if kind.wanted(self.cfg):
                    inp = kind(self.cfg)
                    self.inputs[kind.kind] = inp
                    try:
                        opened.append(await inp.open(self.queue))
                    except Exception as exc:
                        raise InputOpenError(kind.config_key, exc) from exc
        except BaseException:
            self.close()
            raise
        return opened

    def vehicle(self) -> tuple[str, str]:
        """(navd profile or "", what states it) from the MAVLink input's HEARTBEATs: the
        type the flight controller that sends the IMU says it is (as a tlog's replay
        reads it); ("", "") before one came or without a MAVLink input."""
        inp = self.inputs.get(MavlinkInput.kind)
        dec = inp.decoder if isinstance(inp, MavlinkInput) else None
        if dec is None or not dec.heartbeats:
            return "", ""
        imu_sys = dec.watched_imu()[0]
        return vehicle_from_heartbeats([(src[0], t, a) for src, (t, a) in
                                        dec.heartbeats.items()],
                                       imu_sys if imu_sys >= 0 else None)

    @property
    def mavlink(self) -> MavlinkLink | None:
        """The MAVLink input link, for a sink that sends on it (send = "same")."""
        inp = self.inputs.get(MavlinkInput.kind)
        return inp.link if isinstance(inp, MavlinkInput) else None

    @property
    def dronecan(self) -> DronecanLink | None:
        """The DroneCAN input bus, for the Solution sink."""
        inp = self.inputs.get(DronecanInput.kind)
        return inp.link if isinstance(inp, DronecanInput) else None

    def pace_reads(self, pacer: ReadPacer) -> bool:
        """Read the MAVLink UDP input in batches between output instants
        (:mod:`navd.io.read_pacing`); False when there is no such input."""
        link = self.mavlink
        return link is not None and link.pace_reads(pacer)

    def read_in_thread(self, periods_us: Sequence[int], max_hold_us: int,
                       margin_us: int) -> bool:
        """Read the MAVLink UDP input in a compiled thread that wakes the loop once per
        output instant (:meth:`navd.io.mavlink.link.MavlinkLink.read_in_thread`); False
        when there is no such input or the thread cannot run here."""
        link = self.mavlink
        return link is not None and link.read_in_thread(periods_us, max_hold_us, margin_us)

    def counters(self) -> dict[str, dict[str, int]]:
        out: dict[str, dict[str, int]] = {}
        for name, inp in self.inputs.items():
            c = inp.counters()
            if c is not None:
                out[name] = c
        return out

    def locks(self) -> dict[str, dict[str, Any]]:
        """Per input kind, the source lock's state (kinds that lock and saw input)."""
        out: dict[str, dict[str, Any]] = {}
        for name, inp in self.inputs.items():
            st = inp.lock_status()
            if st:
                out[name] = st
        return out

    def close(self) -> None:
        """Close every link (also the send side of a link a sink shares)."""
        for inp in self.inputs.values():
            inp.close()
