"""MAVLink transports: asyncio UDP, TCP and serial links that feed a decoder and send frames.

Addresses (pymavlink connection-string syntax)
    ``udpin:HOST:PORT`` / ``udp:HOST:PORT`` listen (replies go to the last sender),
    ``udpout:HOST:PORT`` send (and receive replies), ``tcp:HOST:PORT`` client,
    ``/dev/ttyUSB0,921600`` serial (raw 8N1, no flow control, set up by pyserial: any baud
    rate the driver accepts).

A stream link (TCP, serial) that closes is reopened with a growing delay; the decoder is
reset first so a partial frame from the old connection cannot corrupt the new one.
:class:`MavlinkSender` puts encoder output on a link (the daemon's MAVLink sink).
"""

from __future__ import annotations

import asyncio
import contextlib
import ctypes
import errno
import fcntl
import logging
import os
import socket
import struct
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar, cast

import numpy as np
import numpy.typing as npt
import serial
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from navd.core import udp_rx
from navd.core.imu_block import ImuBlock
from navd.diag import Counters, RateLimitedLog
from navd.io.adapter import SampleDelivery
from navd.io.common import SampleCallback, monotonic_us
from navd.io.mavlink.decode import MavlinkDecoder
from navd.io.mavlink.encode import MavlinkEncoder
from navd.io.read_pacing import ReadPacer
from navd.types import ImuSample, NavSolution

__all__ = [
    "LinkAddress",
    "MavlinkLink",
    "MavlinkSender",
    "MavlinkStreamProtocol",
    "MavlinkUdpProtocol",
    "PacedUdpTransport",
    "RxBatch",
    "open_mavlink",
    "parse_mavlink_url",
]

# The name the single-file adapter logged under; log configuration may select it.
_log = logging.getLogger("navd.io.mavlink")

# UDP junk budgets (MavlinkUdpProtocol._note_junk): bytes in no valid frame per window,
# per sending address, per sending host (all its ports) and over all senders; a sender
# over one is muted for MUTE_US (only datagrams that are one valid frame are read), except
# an address that delivered samples within USEFUL_US
JUNK_WINDOW_US = 1_000_000
JUNK_BUDGET_BYTES = 4_096
HOST_JUNK_BUDGET_BYTES = 8_192
TOTAL_JUNK_BUDGET_BYTES = 16_384
MUTE_US = 1_000_000
USEFUL_US = 5_000_000
_MAX_PEERS = 64
# datagrams read per readiness callback at most (libuv's own UDP reader takes 32 per loop
# turn): a backlog stays in the socket rather than racing ahead of the estimator task
_MAX_BATCH = 32
# more datagrams than this in one drain: a burst, no hold after it (a paced 1 kHz stream
# gives at most ~12 per drain)
_BURST = 24
# read buffer: the largest UDP payload, so an oversize datagram is seen (and refused) whole
_RX_BYTES = 65536
# a read's datagrams lie back to back in one buffer (RxBatch): room for a batch of small
# ones besides the largest; a read reaching past it is handed on in parts
_BATCH_BYTES = _RX_BYTES + _MAX_BATCH * 512
# ImuBlocks of the batch lane per UDP link: queued but not yet consumed by the estimator
# task, at most this many (beyond, the per-datagram path queues ImuSamples)
_BLOCK_POOL = 8
# ioctl: the receive time of the last datagram read from a socket (struct timespec of the
# wall clock, native longs); Linux's SIOCGSTAMPNS (SIOCGSTAMPNS_OLD since 5.1, same value)
_SIOCGSTAMPNS = 0x8907
_TIMESPEC = struct.Struct("ll")
_STAMP_ZERO = bytes(_TIMESPEC.size)

_K = TypeVar("_K")


def _over_budget(table: dict[_K, tuple[int, int]], key: _K, junk: int, now: int,
                 budget: int) -> bool:
    """Add ``junk`` bytes to ``key``'s window in ``table`` ((start us, bytes) each); True,
    and the window forgotten, when that takes it over ``budget``.  The table holds at most
    _MAX_PEERS keys (spoofed addresses must not grow it without bound)."""
    start, n = table.get(key, (now, 0))
    if now - start > JUNK_WINDOW_US:
        start, n = now, 0
    n += junk
    if n <= budget:
        if len(table) >= _MAX_PEERS and key not in table:
            table.clear()
        table[key] = (start, n)
        return False
    table.pop(key, None)
    return True


def _muted_now(table: dict[_K, int], key: _K, now: int) -> bool:
    """Whether ``key`` is muted at ``now`` in ``table`` (muted until, us); an expired entry
    is forgotten."""
    until = table.get(key)
    if until is None:
        return False
    if now < until:
        return True
    del table[key]
    return False


def _mute(table: dict[_K, int], key: _K, now: int) -> None:
    """Mute ``key`` for MUTE_US; the table holds at most _MAX_PEERS keys."""
    if len(table) >= _MAX_PEERS and key not in table:
        table.clear()
    table[key] = now + MUTE_US


@dataclass(frozen=True)
class LinkAddress:
    kind: str  # "udpin" | "udpout" | "tcp" | "serial"
    host: str = ""
    port: int = 0
    device: str = ""
    baud: int = 115200


def parse_mavlink_url(url: str) -> LinkAddress:
    """Parse pymavlink-style connection strings (see module docstring)."""
    # pymavlink: a bare "udp:" listens, like "udpin:".
    kinds = (("udpin:", "udpin"), ("udp:", "udpin"), ("udpout:", "udpout"), ("tcp:", "tcp"))
    for prefix, kind in kinds:
        if url.startswith(prefix):
            host, sep, port = url[len(prefix) :].rpartition(":")
            if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
                raise ValueError(f"bad MAVLink address {url!r}: want {prefix}HOST:PORT")
            return LinkAddress(kind, host=host, port=int(port))
    if url.startswith("/"):
        device, _, baud = url.partition(",")
        if baud and not baud.isdigit():
            raise ValueError(f"bad serial baud in {url!r}")
        return LinkAddress("serial", device=device, baud=int(baud) if baud else 115200)
    raise ValueError(f"unsupported MAVLink address {url!r}")


class _Delivering(SampleDelivery[MavlinkDecoder]):
    """What both MAVLink protocols share."""


class RxBatch:
    """The datagrams of one read, back to back in one preallocated buffer (reused by the
    next read: nothing may keep a view of it).

    ``data``: the bytes (``u8``: the same memory as a uint8 array, for compiled code);
    datagram i is ``data[offs[i]:offs[i + 1]]`` (``offs``: int64 (_MAX_BATCH + 1,),
    ``offs[0] == 0``), received from ``addrs[i]``; ``n`` datagrams.
    """

    __slots__ = ("addrs", "arrived_ns", "data", "n", "offs", "u8", "view")

    def __init__(self, size: int = _BATCH_BYTES) -> None:
        self.data = bytearray(size)
        self.view = memoryview(self.data)
        self.u8 = np.frombuffer(self.data, np.uint8)
        self.offs = np.zeros(_MAX_BATCH + 1, np.int64)
        self.addrs: list[tuple[Any, ...]] = []
        self.n = 0
        # when the last datagram reached the host (time.monotonic_ns, the kernel's stamp);
        # 0: not known (then the time of the read counts)
        self.arrived_ns = 0

    def fill(self, datagrams: list[tuple[bytes, tuple[Any, ...]]]) -> RxBatch:
        """Put (datagram, address) pairs in, as a read of them would (tests, benchmarks)."""
        off = 0
        self.addrs.clear()
        for k, (d, addr) in enumerate(datagrams):
            self.data[off:off + len(d)] = d
            off += len(d)
            self.offs[k + 1] = off
            self.addrs.append(addr)
        self.n = len(datagrams)
        self.arrived_ns = 0
        return self

    def datagram(self, i: int) -> bytes:
        """Datagram ``i`` as bytes (a copy)."""
        return bytes(self.view[self.offs[i]:self.offs[i + 1]])


class MavlinkUdpProtocol(_Delivering, asyncio.DatagramProtocol):
    """Decodes each datagram and hands samples to ``on_sample`` on the event loop."""

    def _init_link(self) -> None:
        self.transport: asyncio.DatagramTransport | None = None
        self.last_peer: tuple[Any, ...] | None = None
        # junk windows (start us, junk bytes) per sending address, per host, over all
        # senders; muted until (us) per address, per host, all senders
        self._junk: dict[tuple[Any, ...], tuple[int, int]] = {}
        self._junk_hosts: dict[str, tuple[int, int]] = {}
        self._junk_all: dict[None, tuple[int, int]] = {}
        self._muted: dict[tuple[Any, ...], int] = {}
        self._muted_hosts: dict[str, int] = {}
        self._muted_all = 0
        self._mute_log: RateLimitedLog | None = None
        # per address: receive time (us) of its last datagram that gave samples
        self._useful: dict[tuple[Any, ...], int] = {}
        self.pacer: ReadPacer | None = None  # told the IMU stamps read (read pacing)
        # the batch lane (batch_received): where its blocks go (None: no lane), and the
        # free blocks of its pool
        self.on_block: Callable[[ImuBlock], None] | None = None
        self._free_blocks = ImuBlock.pool(_BLOCK_POOL)
        # the clock's way to take a read's arrival time, if it has one (_receive_time)
        self._clock_at: Callable[[int], int] | None = getattr(self.clock_us, "at_ns", None)

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        # The selector loop's datagram transport does not subclass asyncio.DatagramTransport
        # (CPython 3.11), so an isinstance check here would fail on every open.
        self.transport = cast(asyncio.DatagramTransport, transport)

    def datagram_received(self, data: bytes, addr: tuple[Any, ...]) -> None:
        self._datagram(data, addr, self.clock_us())

    def batch_received(self, batch: RxBatch) -> None:
        """The datagrams of one read (``batch``, at least one), as :meth:`datagram_received`
        of each in turn, all read at one receive time (one clock reading per read; the
        arrival of the read's last datagram when the transport stamped it and the link's
        clock takes it, see :meth:`_receive_time`).

        The batch lane: when nothing is muted and every datagram came from the one address
        that delivered samples within USEFUL_US, the decoder takes the HIGHRES_IMU
        datagrams of its usual case in compiled code (``MavlinkDecoder.feed_lane``) into an
        :class:`ImuBlock` that goes to ``on_block`` as one item; every other datagram goes
        the per-datagram way, in its place in the order (a block holding the samples
        before it is handed on first).  The same samples, counters, useful-address table,
        ``last_peer`` and read pacing notes as datagram by datagram."""
        n = batch.n
        now = self._receive_time(batch.arrived_ns)
        addrs = batch.addrs
        addr = addrs[0]
        dec = self.decoder
        useful = self._useful
        free = self._free_blocks
        on_block = self.on_block
        if (dec is None or on_block is None or not dec.lane or not free or self._muted
                or self._muted_hosts or now < self._muted_all
                or now - useful.get(addr, now - USEFUL_US) >= USEFUL_US
                or addrs.count(addr) != n):
            for i in range(n):
                self._datagram(batch.datagram(i), addrs[i], now, i == n - 1)
            return
        u8, offs = batch.u8, batch.offs
        pacer = self.pacer
        block: ImuBlock | None = None
        took = False
        i = 0
        while i < n:
            if block is None and free:
                block = free.pop()
            if block is not None:
                o = block.n
                k = dec.feed_lane(u8, offs, i, n, now, block)
                if k:
                    if pacer is not None:
                        pacer.note_run(block.t_us, o, k, now, i + k == n)
                    took = True
                    i += k
                    if block.n == len(block.t_us):
                        on_block(block)
                        block = None
                    continue
                if block.n:  # the samples before this datagram go first
                    on_block(block)
                    block = None
            self._datagram(batch.datagram(i), addr, now, i == n - 1)
            i += 1
        if block is not None:
            if block.n:
                on_block(block)
            else:
                block.release()
        self.last_peer = addr
        if took:  # what _datagram does for a datagram that gave samples
            if len(useful) >= _MAX_PEERS and addr not in useful:
                useful.clear()
            useful[addr] = now

    def _receive_time(self, arrived_ns: int) -> int:
        """The receive time (us) of a read whose last datagram arrived at ``arrived_ns``
        (0: unknown).  Only a clock with ``at_ns`` (the daemon's
        :class:`navd.daemon.sources.ReceiveClock`, on ``time.monotonic_ns``) takes the
        arrival; any other clock (a test's, a benchmark's sensor-time clock) is read as
        before, so the stamps never mix two time lines."""
        at = self._clock_at
        if arrived_ns and at is not None:
            return at(arrived_ns)
        return self.clock_us()

    def _datagram(self, data: bytes, addr: tuple[Any, ...], now: int, edge: bool = True
                  ) -> None:
        """One datagram received at ``now`` (us) from ``addr``: decoded, samples delivered.
        ``edge``: it is the read's last datagram (``now`` is its arrival: see
        :meth:`ReadPacer.note`)."""
        self.last_peer = addr
        dec = self.decoder
        if dec is None:
            return
        if (self._muted or self._muted_hosts or now < self._muted_all) and self._is_muted(
                addr, now):
            # a muted sender: only a datagram that is one valid frame is read (a cost that
            # does not depend on its bytes); anything else is dropped unscanned
            whole = dec.feed_whole(data, now)
            if whole is None:
                self.counters.inc("datagrams_muted")
                return
            samples = whole
        else:
            samples = dec.feed_datagram(data, now)
            junk = dec.last_junk
            if junk:
                self._note_junk(addr, junk, now)
        if samples:
            useful = self._useful
            if len(useful) >= _MAX_PEERS and addr not in useful:
                useful.clear()
            useful[addr] = now
            pacer = self.pacer
            on_sample = self.on_sample
            last = samples[-1]
            # what _deliver does, without the call (issue 18)
            for s in samples:
                if pacer is not None and type(s) is ImuSample:
                    pacer.note(s.t_us, now, edge and s is last)
                if on_sample is not None:
                    on_sample(s)

    def _is_muted(self, addr: tuple[Any, ...], now: int) -> bool:
        """Whether ``addr``, its host or all senders are muted for junk (see _note_junk),
        and ``addr`` has not delivered samples within USEFUL_US."""
        # both looked up: each forgets an expired muting
        muted = (_muted_now(self._muted, addr, now)
                 | _muted_now(self._muted_hosts, addr[0], now))
        if not muted and now >= self._muted_all:
            return False
        return now - self._useful.get(addr, now - USEFUL_US) >= USEFUL_US

    def _note_junk(self, addr: tuple[Any, ...], junk: int, now: int) -> None:
        """Budget the bytes in no valid frame that ``addr`` sent: more than
        JUNK_BUDGET_BYTES from one address, HOST_JUNK_BUDGET_BYTES from one host (over all
        its ports: a flood that changes its source port) or TOTAL_JUNK_BUDGET_BYTES from all
        senders together (one that changes its source host, e.g. across 127.0.0.0/8)
        within JUNK_WINDOW_US mutes that address, host or all senders for MUTE_US.  Of a
        muted sender only a datagram that is exactly one valid frame is read (one checksum,
        whatever its bytes: a sender of single-frame datagrams that starts during a flood
        still gets in); anything else is dropped unscanned (counted ``datagrams_muted``;
        each muting counts ``peer_muted``, ``host_muted`` or ``senders_muted`` and is
        logged, rate-limited).

        Scanning junk costs up to ~1 us per byte (crafted frame headers whose checksum has
        to be computed), so a 10 Mbit/s flood would take a core; a real sender's datagrams
        are frames, and its junk (a torn frame now and then) stays far below the budgets.
        An address that delivered samples within USEFUL_US is never muted, by any of the
        three, and its junk is not counted: junk from the host of the real sender, or in
        its name, must not silence it (junk in its name costs CPU instead)."""
        if now - self._useful.get(addr, now - USEFUL_US) < USEFUL_US:
            return
        if _over_budget(self._junk, addr, junk, now, JUNK_BUDGET_BYTES):
            _mute(self._muted, addr, now)
            self._mute_warn("peer_muted", "%s sent over %d bytes", addr, JUNK_BUDGET_BYTES)
        host = addr[0]
        if _over_budget(self._junk_hosts, host, junk, now, HOST_JUNK_BUDGET_BYTES):
            _mute(self._muted_hosts, host, now)
            self._mute_warn("host_muted", "host %s sent over %d bytes (all ports)", host,
                            HOST_JUNK_BUDGET_BYTES)
        if _over_budget(self._junk_all, None, junk, now, TOTAL_JUNK_BUDGET_BYTES):
            self._muted_all = now + MUTE_US
            self._mute_warn("senders_muted", "all senders together sent over %d bytes",
                            TOTAL_JUNK_BUDGET_BYTES)

    def _mute_warn(self, what: str, who: str, *args: object) -> None:
        self.counters.inc(what)
        if self._mute_log is None:
            interval = self.decoder.config.warn_interval_s if self.decoder else 5.0
            self._mute_log = RateLimitedLog(_log, interval)
        self._mute_log.warn(what, "MAVLink: " + who + " of junk (no valid frame) within "
                            "%.1f s: muted for %.1f s (datagrams that are not one valid "
                            "frame dropped unscanned), but for an address that delivered "
                            "samples within %.0f s", *args, JUNK_WINDOW_US * 1e-6,
                            MUTE_US * 1e-6, USEFUL_US * 1e-6)

    def error_received(self, exc: Exception) -> None:
        # ICMP port-unreachable on a connected udpout socket lands here; the link lives on.
        self.counters.inc("link_error")
        _log.debug("MAVLink UDP error: %s", exc)


class MavlinkStreamProtocol(_Delivering, asyncio.Protocol):
    """Byte-stream twin of :class:`MavlinkUdpProtocol` for TCP and serial."""

    def _init_link(self) -> None:
        self.closed: asyncio.Future[None] = asyncio.get_running_loop().create_future()

    def data_received(self, data: bytes) -> None:
        if self.decoder is not None:
            self._deliver(self.decoder.feed(data, self.clock_us()))

    def eof_received(self) -> bool | None:
        return None

    def connection_lost(self, exc: Exception | None) -> None:
        if exc is not None:
            self.counters.inc("link_error")
            _log.warning("MAVLink stream closed: %s", exc)
        if not self.closed.done():
            self.closed.set_result(None)


class PacedUdpTransport(asyncio.DatagramTransport):
    """A listening (``udpin``) UDP socket read by navd itself rather than by the event
    loop's datagram transport, so that reading can be paced (:mod:`navd.io.read_pacing`).

    Each readiness callback drains the socket (up to ``_MAX_BATCH`` datagrams, back to back
    in one preallocated :class:`RxBatch` handed to the protocol's ``batch_received`` in one
    call, in arrival order); then, while ``hold_us`` (set by the daemon
    through :meth:`MavlinkLink.pace_reads`) says no output instant is near, the socket is
    taken off the loop and read again when the hold ends: at 1 kHz the loop wakes a few
    times per output period instead of once per datagram.  Without ``hold_us`` every
    datagram is read as it arrives, as by the loop's own transport.

    Or (:meth:`read_in_thread`, the daemon's default on Linux) a thread of compiled code
    (:mod:`navd.core.udp_rx`) reads the socket and the loop only takes the batches it hands
    on (``_ready``), through the same ``batch_received``: about one wake-up of the loop
    per output instant.
    """

    def __init__(self, loop: asyncio.AbstractEventLoop, sock: socket.socket,
                 protocol: MavlinkUdpProtocol) -> None:
        super().__init__({"socket": sock, "sockname": sock.getsockname()})
        self._loop = loop
        self._sock = sock
        self._fd = sock.fileno()
        self._protocol = protocol
        self._batch = RxBatch()
        # the kernel's arrival stamp of the last datagram read (SIOCGSTAMPNS, Linux): the
        # latency navd reports then counts the time a datagram waited unread in the socket
        # during a hold; asking once here turns the socket's stamping on
        self._stamps = sys.platform.startswith("linux")
        self._arrival_ns()
        self._closing = False
        self._timer: asyncio.TimerHandle | None = None
        self.hold_us: Callable[[], int] | None = None
        # the compiled reader (read_in_thread): its thread, eventfds, shared arrays, the
        # next buffer to take, the errors it reported so far, sockaddr -> address tuple
        self._thread: threading.Thread | None = None
        self._reader_ended = False
        self._ctl_fd = self._ready_fd = -1
        self._ctl = np.zeros(udp_rx.CTL_SIZE, np.int64)
        self._meta = np.zeros((2, udp_rx.META_SIZE), np.int64)
        self._tbatches = (self._batch, RxBatch())
        self._taddr = np.zeros((2, _MAX_BATCH, udp_rx.ADDR_BYTES), np.uint8)
        self._tb = 0
        self._errors_seen = 0
        self._addr_cache: dict[bytes, tuple[Any, ...]] = {}
        protocol.connection_made(self)
        loop.add_reader(self._fd, self._readable)

    @classmethod
    def bind(cls, loop: asyncio.AbstractEventLoop, host: str, port: int,
             protocol: MavlinkUdpProtocol) -> PacedUdpTransport:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM)
        family, _, _, _, addr = infos[0]
        sock = socket.socket(family, socket.SOCK_DGRAM)
        try:
            sock.setblocking(False)
            sock.bind(addr)
        except BaseException:
            sock.close()
            raise
        return cls(loop, sock, protocol)

    def _readable(self) -> None:
        recv = self._sock.recvfrom_into
        batch = self._batch
        view, offs, addrs = batch.view, batch.offs, batch.addrs
        deliver = self._protocol.batch_received
        limit = len(view) - _RX_BYTES  # past it, the next datagram might not fit whole
        off = k = n_read = 0
        drained = False
        for n_read in range(_MAX_BATCH):  # noqa: B007 - the count is used below
            try:
                nbytes, addr = recv(view[off:])
            except (BlockingIOError, InterruptedError):
                drained = True
                break
            except OSError as exc:  # ICMP errors and the like: the socket lives on
                self._protocol.error_received(exc)
                drained = True
                break
            off += nbytes
            k += 1
            offs[k] = off
            addrs.append(addr)
            if off > limit:  # hand on what was read so far, read on into an empty buffer
                batch.n = k
                batch.arrived_ns = self._arrival_ns()
                deliver(batch)
                addrs.clear()
                off = k = 0
        if k:
            batch.n = k
            batch.arrived_ns = self._arrival_ns()
            deliver(batch)
            addrs.clear()
        if not drained:
            return  # more may be waiting: stay on the loop, read on at the next turn
        hold = self.hold_us
        if hold is None or self._closing or n_read > _BURST:
            # a burst (a fast sender, or navd fell behind): read on, hold nothing
            return
        us = hold()
        if us > 0:
            self._loop.remove_reader(self._fd)
            self._timer = self._loop.call_later(us * 1e-6, self._resume)

    def _arrival_ns(self) -> int:
        """When the last datagram read reached the host, as ``time.monotonic_ns`` (the
        kernel stamps it on the wall clock: converted with the two clocks' present
        offset); 0 when not known (no datagram stamped yet, not Linux, or an implausible
        stamp: in the future, or older than a second)."""
        if not self._stamps:
            return 0
        try:
            raw = fcntl.ioctl(self._fd, _SIOCGSTAMPNS, _STAMP_ZERO)
        except OSError as exc:
            if exc.errno != errno.ENOENT:  # not "nothing stamped yet": no stamps here
                self._stamps = False
            return 0
        sec, nsec = _TIMESPEC.unpack(raw)
        mono = time.monotonic_ns()
        ns: int = sec * 1_000_000_000 + nsec - (time.time_ns() - mono)
        if mono - 1_000_000_000 < ns <= mono:
            return ns
        return 0

    def _resume(self) -> None:
        self._timer = None
        if self._closing:
            return
        self._loop.add_reader(self._fd, self._readable)
        self._readable()  # what arrived during the hold

    @property
    def threaded(self) -> bool:
        """The socket is read by the compiled thread (:meth:`read_in_thread`)."""
        return self._thread is not None

    def read_in_thread(self, periods_us: Sequence[int], max_hold_us: int,
                       margin_us: int) -> bool:
        """From now on read the socket in a thread running compiled code
        (:func:`navd.core.udp_rx.rx_loop`) instead of on the event loop: the loop is woken
        only for a batch that must be handled now (a sample completing an instant of
        ``periods_us``, sensor us; any datagram not a HIGHRES_IMU frame of the watched
        source; a full buffer; a datagram held ``max_hold_us``) and gets it through the
        same ``batch_received`` as a read of its own.  Between instants a live sender's
        socket is left unread until ``margin_us`` before the next is due.  False (nothing
        changes) where that cannot run: not Linux, the kernels run uncompiled
        (``NUMBA_DISABLE_JIT``), more periods than the reader takes, or already threaded
        or closing."""
        periods = [int(p) for p in periods_us if p > 0]
        if (self._closing or self._thread is not None or not sys.platform.startswith("linux")
                or not hasattr(os, "eventfd") or len(periods) > udp_rx.MAX_PERIODS
                or not hasattr(udp_rx.rx_loop, "py_func") or max_hold_us < 0
                or margin_us < 0):
            return False
        ctl = self._ctl
        ctl[:] = 0
        ctl[udp_rx.C_MAX_HOLD_NS] = max_hold_us * 1000
        ctl[udp_rx.C_MARGIN_NS] = margin_us * 1000
        ctl[udp_rx.C_SYS:udp_rx.C_ID + 1] = -1
        ctl[udp_rx.C_NPER] = len(periods)
        ctl[udp_rx.C_PERIODS:udp_rx.C_PERIODS + len(periods)] = periods
        self._meta[:] = udp_rx.FREE
        self._tb = 0
        self._errors_seen = 0
        self._reader_ended = False
        flags = os.EFD_NONBLOCK | os.EFD_CLOEXEC
        self._ctl_fd = os.eventfd(0, flags)
        self._ready_fd = os.eventfd(0, flags)
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        self._loop.remove_reader(self._fd)
        b0, b1 = self._tbatches
        args = (self._fd, self._ctl_fd, self._ready_fd, b0.u8, b1.u8, b0.offs, b1.offs,
                self._taddr[0], self._taddr[1], self._meta, ctl, _RX_BYTES)
        self._thread = threading.Thread(target=self._run_reader, args=args,
                                        name="navd-udp-rx", daemon=True)
        self._loop.add_reader(self._ready_fd, self._ready)
        self._thread.start()
        return True

    def _run_reader(self, *args: Any) -> None:
        """The reader thread: the kernel runs without the GIL until told to stop."""
        _name_thread(b"navd-udp-rx")  # its CPU shows apart in top -H and the benchmark
        try:
            udp_rx.rx_loop(*args)
        finally:
            # the loop learns that the reader ended (_ready sees the flag)
            self._reader_ended = True
            with contextlib.suppress(OSError):
                os.eventfd_write(self._ready_fd, 1)

    def _ready(self) -> None:
        """The reader handed on one or more batches (or ended): deliver them in order."""
        with contextlib.suppress(BlockingIOError):
            os.eventfd_read(self._ready_fd)
        meta = self._meta
        b = self._tb
        deliver = self._protocol.batch_received
        while meta[b, udp_rx.M_STATE] == udp_rx.READY and not self._closing:
            batch = self._tbatches[b]
            n = int(meta[b, udp_rx.M_N])
            batch.n = n
            batch.arrived_ns = int(meta[b, udp_rx.M_ARRIVED])
            raw = self._taddr[b]
            if meta[b, udp_rx.M_SAME_ADDR]:
                batch.addrs = [self._address(raw[0])] * n
            else:
                batch.addrs = [self._address(raw[i]) for i in range(n)]
            try:
                deliver(batch)
            finally:
                batch.addrs = []  # a read on the loop (after a fallback) appends to it
                meta[b, udp_rx.M_STATE] = udp_rx.FREE
                if meta[b, udp_rx.M_WAITING]:
                    os.eventfd_write(self._ctl_fd, 1)
                b ^= 1
                self._tb = b
        ctl = self._ctl
        dec = self._protocol.decoder
        if dec is not None:
            ctl[udp_rx.C_SYS], ctl[udp_rx.C_COMP], ctl[udp_rx.C_ID] = dec.watched_imu()
        errors = int(ctl[udp_rx.C_ERRORS])
        if errors != self._errors_seen:
            # the last one goes the usual way; the ones before it are counted as it counts
            if errors - self._errors_seen > 1:
                self._protocol.counters.inc("link_error", errors - self._errors_seen - 1)
            self._errors_seen = errors
            e = int(ctl[udp_rx.C_ERRNO])
            self._protocol.error_received(OSError(e, os.strerror(e)))
        if self._reader_ended and self._thread is not None and not self._closing:
            # the reader ended on its own (an error it cannot read past): read on the loop
            _log.warning("UDP input: the reader thread ended; reading on the event loop")
            self._stop_reader()
            self._loop.add_reader(self._fd, self._readable)

    def _address(self, raw: npt.NDArray[np.uint8]) -> tuple[Any, ...]:
        """The address tuple Python's ``recvfrom`` gives for the sockaddr ``raw``."""
        key = raw.tobytes()
        addr = self._addr_cache.get(key)
        if addr is None:
            addr = _sockaddr(key)
            if len(self._addr_cache) >= _MAX_PEERS:
                self._addr_cache.clear()
            self._addr_cache[key] = addr
        return addr

    def _stop_reader(self) -> None:
        """Stop the reader thread and close its eventfds (the socket stays open)."""
        thread = self._thread
        if thread is None:
            return
        self._thread = None
        self._ctl[udp_rx.C_STOP] = 1
        with contextlib.suppress(OSError):
            os.eventfd_write(self._ctl_fd, 1)
        thread.join(timeout=2.0)
        self._loop.remove_reader(self._ready_fd)
        if thread.is_alive():  # never seen; an fd it may still use must not be reused
            _log.error("UDP input: the reader thread did not stop")
            return
        for fd in (self._ctl_fd, self._ready_fd):
            with contextlib.suppress(OSError):
                os.close(fd)
        self._ctl_fd = self._ready_fd = -1

    def sendto(self, data: bytes | bytearray | memoryview,  # type: ignore[override]
               addr: tuple[Any, ...] | None = None) -> None:
        if self._closing:
            return
        try:
            if addr is None:
                self._sock.send(data)
            else:
                self._sock.sendto(data, addr)
        except OSError as exc:  # a full send buffer or an ICMP error: this frame is lost
            self._protocol.error_received(exc)

    def is_closing(self) -> bool:
        return self._closing

    def close(self) -> None:
        if self._closing:
            return
        self._closing = True
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        self._stop_reader()
        self._loop.remove_reader(self._fd)
        self._sock.close()
        self._loop.call_soon(self._protocol.connection_lost, None)

    def abort(self) -> None:
        self.close()

    def get_write_buffer_size(self) -> int:
        return 0


def _name_thread(name: bytes) -> None:
    """Name the calling thread for the OS (Linux prctl PR_SET_NAME; a no-op elsewhere)."""
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None, use_errno=True).prctl(15, name[:15], 0, 0, 0)


def _sockaddr(raw: bytes) -> tuple[Any, ...]:
    """The address tuple Python's ``socket.recvfrom`` returns for a Linux sockaddr_in or
    sockaddr_in6 ``raw`` (the compiled reader's)."""
    family = int.from_bytes(raw[0:2], sys.byteorder)
    port = int.from_bytes(raw[2:4], "big")
    if family == socket.AF_INET:
        return socket.inet_ntop(socket.AF_INET, raw[4:8]), port
    if family == socket.AF_INET6:
        flow = int.from_bytes(raw[4:8], "big")
        scope = int.from_bytes(raw[24:28], sys.byteorder)
        host = socket.inet_ntop(socket.AF_INET6, raw[8:24])
        if scope:  # as Python names it: with the interface ("fe80::1%eth0")
            host = socket.getnameinfo((host, port, flow, scope), socket.NI_NUMERICHOST)[0]
        return host, port, flow, scope
    return f"family {family}", 0


class _WriteOnlyProtocol(asyncio.BaseProtocol):
    pass


def _open_serial(device: str, baud: int) -> int:
    """Open ``device`` as a plain telemetry UART (raw 8N1, no flow control, no modem
    control lines) and return a non-blocking descriptor the caller owns.

    pyserial does the port setup (including rates without a termios constant); its own
    descriptor is closed again, the settings stay with the device.
    """
    try:
        port = serial.Serial(device, baud, bytesize=serial.EIGHTBITS, parity=serial.PARITY_NONE,
                             stopbits=serial.STOPBITS_ONE, xonxoff=False, rtscts=False,
                             dsrdtr=False, timeout=0, exclusive=True)
    except serial.SerialException as exc:  # an OSError only in name; keep reopen logic simple
        raise OSError(str(exc)) from exc
    except ValueError as exc:
        raise ValueError(f"{device}: {exc}") from exc
    try:
        port.reset_input_buffer()
        # The duplicate shares the open file (and pyserial's exclusive flock on it), so the
        # port stays locked against a second opener after pyserial's descriptor is closed.
        fd = os.dup(port.fileno())
    finally:
        port.close()
    os.set_blocking(fd, False)
    return fd


class MavlinkLink:
    """One open MAVLink link: decodes what arrives, writes what is sent, never blocks.

    Open with :meth:`open`.  ``send`` queues bytes on the transport; when a stream's write
    buffer exceeds ``max_tx_buffer`` (stuck UART, slow TCP peer) frames are dropped and
    counted rather than letting memory grow.
    """

    def __init__(self, address: LinkAddress, counters: Counters, max_tx_buffer: int) -> None:
        self.address = address
        self.counters = counters
        self.max_tx_buffer = max_tx_buffer
        self._udp: MavlinkUdpProtocol | None = None
        self._udp_transport: asyncio.DatagramTransport | None = None
        self._rx_transport: asyncio.BaseTransport | None = None
        self._tx_transport: asyncio.WriteTransport | None = None
        self._decoder: MavlinkDecoder | None = None
        self._on_sample: SampleCallback | None = None
        self._clock_us: Callable[[], int] = monotonic_us
        self._closing = False
        self._watch: asyncio.Task[None] | None = None
        self.reconnect_delays_s: tuple[float, ...] = (0.5, 1.0, 2.0, 5.0)

    @classmethod
    async def open(
        cls,
        url: str,
        decoder: MavlinkDecoder | None = None,
        on_sample: SampleCallback | None = None,
        *,
        clock_us: Callable[[], int] = monotonic_us,
        max_tx_buffer: int = 64 * 1024,
    ) -> MavlinkLink:
        addr = parse_mavlink_url(url)
        loop = asyncio.get_running_loop()
        counters = decoder.counters if decoder is not None else Counters()
        link = cls(addr, counters, max_tx_buffer)
        if addr.kind in ("udpin", "udpout"):
            proto = MavlinkUdpProtocol(decoder, on_sample, clock_us)
            transport: asyncio.DatagramTransport
            if addr.kind == "udpin":  # the input link: navd reads it itself (read pacing)
                transport = PacedUdpTransport.bind(loop, addr.host, addr.port, proto)
            else:
                transport, _ = await loop.create_datagram_endpoint(
                    lambda: proto, remote_addr=(addr.host, addr.port))
            link._udp = proto
            link._udp_transport = transport
        else:
            link._decoder, link._on_sample, link._clock_us = decoder, on_sample, clock_us
            sproto = await link._open_stream()
            link._watch = loop.create_task(link._keep_open(sproto), name=f"mavlink {url}")
        return link

    async def _open_stream(self) -> MavlinkStreamProtocol:
        """Connect a TCP or serial link; the transports replace any previous ones."""
        addr = self.address
        loop = asyncio.get_running_loop()
        sproto = MavlinkStreamProtocol(self._decoder, self._on_sample, self._clock_us)
        if addr.kind == "tcp":
            transport2, _ = await loop.create_connection(lambda: sproto, addr.host, addr.port)
            self._rx_transport = transport2
            self._tx_transport = transport2
            return sproto
        fd = _open_serial(addr.device, addr.baud)
        try:
            wfd = os.dup(fd)
        except BaseException:
            os.close(fd)
            raise
        # Two file objects on one tty: asyncio's pipe transports each own (and close)
        # their descriptor.
        rpipe = os.fdopen(fd, "rb", buffering=0)
        wpipe = os.fdopen(wfd, "wb", buffering=0)
        try:
            rt, _ = await loop.connect_read_pipe(lambda: sproto, rpipe)
            wt, _ = await loop.connect_write_pipe(_WriteOnlyProtocol, wpipe)
        except BaseException:
            rpipe.close()
            wpipe.close()
            raise
        self._rx_transport = rt
        self._tx_transport = wt
        return sproto

    async def _keep_open(self, proto: MavlinkStreamProtocol) -> None:
        """A TCP peer that restarts or a USB serial adapter that drops out must not need a
        daemon restart: when the stream closes, reopen it with a growing delay (capped),
        forgetting any partial frame, until :meth:`close`."""
        where = self.address.device or f"{self.address.host}:{self.address.port}"
        while not self._closing:
            await asyncio.shield(proto.closed)
            if self._closing:
                return
            for t in (self._rx_transport, self._tx_transport):
                if t is not None and not t.is_closing():
                    t.close()
            self.counters.inc("link_lost")
            _log.warning("MAVLink %s %s closed; reopening", self.address.kind, where)
            attempt = 0
            while not self._closing:
                delay = self.reconnect_delays_s[min(attempt, len(self.reconnect_delays_s) - 1)]
                await asyncio.sleep(delay)
                if self._closing:
                    return
                try:
                    if self._decoder is not None:
                        self._decoder.reset()
                    proto = await self._open_stream()
                except (OSError, ValueError) as exc:
                    attempt += 1
                    if attempt == 1 or attempt % 20 == 0:  # rate-limited: one line per ~100 s
                        _log.warning("MAVLink %s %s: reopen failed (%d attempts): %s",
                                     self.address.kind, where, attempt, exc)
                    continue
                self.counters.inc("link_reopened")
                _log.info("MAVLink %s %s reopened", self.address.kind, where)
                break

    @property
    def peer(self) -> tuple[Any, ...] | None:
        """Where ``send`` goes on a listening UDP link (the last sender), else None."""
        return self._udp.last_peer if self._udp is not None else None

    @property
    def local_address(self) -> tuple[Any, ...] | None:
        t = self._udp_transport or self._rx_transport
        if t is None:
            return None
        sockname: tuple[Any, ...] | None = t.get_extra_info("sockname")
        return sockname

    def pace_reads(self, pacer: ReadPacer) -> bool:
        """Read a listening UDP link in batches between output instants
        (:mod:`navd.io.read_pacing`); False (nothing changes) for other links."""
        t = self._udp_transport
        if not isinstance(t, PacedUdpTransport) or self._udp is None:
            return False
        self._udp.pacer = pacer
        clock = self._udp.clock_us
        t.hold_us = lambda: pacer.hold_us(clock())
        return True

    def read_in_thread(self, periods_us: Sequence[int], max_hold_us: int,
                       margin_us: int) -> bool:
        """Read a listening UDP link in a compiled thread that wakes the loop once per
        output instant (:meth:`PacedUdpTransport.read_in_thread`); False (nothing
        changes) for other links or where that cannot run."""
        t = self._udp_transport
        return isinstance(t, PacedUdpTransport) and t.read_in_thread(periods_us, max_hold_us,
                                                                     margin_us)

    def deliver_blocks(self, on_block: Callable[[ImuBlock], None]) -> bool:
        """Let a listening UDP link's reads take the batch lane
        (:meth:`MavlinkUdpProtocol.batch_received`): its IMU samples then come as
        :class:`ImuBlock` items to ``on_block`` (which must :meth:`ImuBlock.release` each
        when done) besides samples to ``on_sample``; False (nothing changes) for other
        links."""
        if not isinstance(self._udp_transport, PacedUdpTransport) or self._udp is None:
            return False
        self._udp.on_block = on_block
        return True

    def set_receive_buffer(self, nbytes: int) -> int:
        """Ask for an ``nbytes`` socket receive buffer on a UDP link (the kernel caps it at
        net.core.rmem_max); return what the kernel granted, 0 for other links."""
        if self._udp_transport is None:
            return 0
        sock = self._udp_transport.get_extra_info("socket")
        if sock is None:
            return 0
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, nbytes)
        return int(sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF))

    def send(self, data: bytes) -> bool:
        """Queue ``data``; False (and counted) if it could not be sent now."""
        if self._udp_transport is not None:
            if self._udp_transport.is_closing():
                self.counters.inc("tx_closed")
                return False
            if self.address.kind == "udpout":
                self._udp_transport.sendto(data)
                return True
            peer = self.peer
            if peer is None:
                # pymavlink udpin semantics: nobody to talk to until someone talks to us.
                self.counters.inc("tx_no_peer")
                return False
            self._udp_transport.sendto(data, peer)
            return True
        t = self._tx_transport
        if t is None or t.is_closing():
            self.counters.inc("tx_closed")
            return False
        if t.get_write_buffer_size() > self.max_tx_buffer:
            self.counters.inc("tx_dropped")
            return False
        t.write(data)
        return True

    def close(self) -> None:
        self._closing = True
        if self._watch is not None and not self._watch.done():
            self._watch.cancel()
        for t in (self._udp_transport, self._rx_transport, self._tx_transport):
            if t is not None and not t.is_closing():
                t.close()


async def open_mavlink(
    url: str,
    decoder: MavlinkDecoder | None = None,
    on_sample: SampleCallback | None = None,
    **kw: Any,
) -> MavlinkLink:
    """Open a pymavlink-style connection string; see :meth:`MavlinkLink.open`."""
    return await MavlinkLink.open(url, decoder, on_sample, **kw)


class MavlinkSender:
    """The daemon's MAVLink sink: solution -> ATTITUDE (+ QUATERNION, GLOBAL_POSITION_INT).

    ``time_boot_ms`` of every output is the solution's ``t_us`` in ms, i.e. the sensor time
    of validity, so a consumer can match attitude to the IMU stream it came from.
    """

    def __init__(
        self,
        link: MavlinkLink,
        encoder: MavlinkEncoder,
        *,
        send_quaternion: bool = True,
        send_global_position: bool = False,
        home_alt_m: float | None = None,
    ) -> None:
        self.link = link
        self.encoder = encoder
        self.send_quaternion = send_quaternion
        self.send_global_position = send_global_position
        self.home_alt_m = home_alt_m

    def send(self, data: bytes) -> bool:
        return self.link.send(data)

    def send_solution(self, sol: NavSolution) -> None:
        """The solution's frames in one send: one datagram on UDP (MAVLink over UDP may
        carry several frames per datagram, as ArduPilot sends them), so each output instant
        costs one system call and one wake-up of the receiver rather than two or three."""
        ms = sol.t_us // 1000
        out = self.encoder.encode_attitude(sol, ms)
        if self.send_quaternion:
            out += self.encoder.encode_attitude_quaternion(sol, ms)
        if self.send_global_position:
            try:
                out += self.encoder.encode_global_position_int(sol, ms, self.home_alt_m)
            except ValueError:
                self.link.counters.inc("tx_nonfinite_position")
        self.send(out)

    def send_heartbeat(self, system_status: int = mavlink.MAV_STATE_ACTIVE) -> bool:
        return self.send(self.encoder.encode_heartbeat(system_status))

    async def run_heartbeat(
        self,
        period_s: float = 1.0,
        status: Callable[[], int] = lambda: mavlink.MAV_STATE_ACTIVE,
    ) -> None:
        """Send HEARTBEAT every ``period_s`` until cancelled."""
        while True:
            with contextlib.suppress(OSError):
                self.send_heartbeat(status())
            await asyncio.sleep(period_s)
