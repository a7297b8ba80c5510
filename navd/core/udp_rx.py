"""A UDP input socket read by a compiled thread (issue 18): :func:`rx_loop`.

At 1 kHz the daemon's CPU goes to waking the interpreter, not to the samples
(docs/results.md "Where the daemon's CPU goes per wake-up"). Here a thread that never takes
the GIL waits on the socket, reads every datagram into one of two batch buffers as it
arrives, and wakes the event loop (an eventfd) only when the batch has to be handled now:

- a HIGHRES_IMU frame of the watched source whose stamp crosses a multiple of an output
  period: the sample completing an output instant (the outputs are due on the sinks' grids
  of sensor time, :class:`navd.pipeline.OutputSchedule`), or whose stamp goes back, or the
  first one;
- any other datagram (a fix, a heartbeat, junk, another IMU message): the per-datagram path
  decides what it is, as soon as the loop would have;
- the buffer is full, or its oldest datagram has waited ``max_hold_ns``.

After a completing sample, a live sender's socket is left unread until ``margin_ns`` before
the next instant's sample is due (:func:`hold_until`, the rule of
:class:`navd.io.read_pacing.ReadPacer`), so the thread too wakes a few times per output
period. The interpreter wakes about once per output instant instead of ~4 times, and the
thread's wake-ups cost a few microseconds of compiled code each. Nothing is dropped or
reordered: every datagram is handed on, in arrival order; only when is decided here. The
frame is only looked at, not checked (no CRC): a wrong guess costs a wake-up or a wait of at
most ``max_hold_ns``, never a sample; the decoder behind checks everything.

The kernel lives in ``navd.core`` only so that the install-time build compiles it with the
estimator's kernels (a cold start must not wait for it); the socket and the two eventfds
are opened, owned and closed by :class:`navd.io.mavlink.link.PacedUdpTransport`. Linux only
(``poll``, ``ppoll``, ``recvfrom``, ``read``, ``write``, ``clock_gettime`` and ``errno``
called straight from libc).

Hand-over (two buffers, alternating; ``meta[b]`` per buffer, see ``M_*``): the thread fills
buffer ``b`` while its state is FREE, sets N, ARRIVED, SAME_ADDR, then READY, and writes 1
to ``ready_fd``; it then fills ``b ^ 1`` as soon as that is FREE again (else it sets WAITING
and waits on ``ctl_fd``, 10 ms at most). The loop takes READY buffers in order, sets them
FREE and, if WAITING, writes 1 to ``ctl_fd`` (a write per batch would wake a holding thread
for nothing). Stop: ``ctl[C_STOP] = 1`` and a write to ``ctl_fd``.
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np
import numpy.typing as npt
from numba import types

from navd.core._jit import jit

__all__ = ["CTL_SIZE", "MAX_PERIODS", "META_SIZE", "PACE_SIZE", "rx_loop"]

# ctl (int64): written by the loop, read by the thread (C_STOP .. C_PERIODS + MAX_PERIODS),
# and the thread's error report (C_ERRORS, C_ERRNO)
C_STOP = 0  # 1: return
C_MAX_HOLD_NS = 1  # a datagram waits at most this long (ns) before its batch is handed on
C_SYS = 2  # the watched HIGHRES_IMU source: system id, component id, IMU instance
C_COMP = 3  # (-1: any)
C_ID = 4
C_ERRORS = 5  # receive errors other than "nothing to read" (count)
C_ERRNO = 6  # errno of the last of them
C_MARGIN_NS = 7  # a held socket is read again this long before the next instant is due
C_NPER = 8  # output periods (sensor us) in C_PERIODS ..
C_PERIODS = 9
MAX_PERIODS = 8
CTL_SIZE = C_PERIODS + MAX_PERIODS

# meta (int64, (2, META_SIZE)): per batch buffer
M_STATE = 0  # FREE (the thread's) or READY (the loop's)
M_N = 1  # datagrams
M_ARRIVED = 2  # CLOCK_MONOTONIC (time.monotonic_ns) when the last one was read
M_SAME_ADDR = 3  # 1: every datagram came from the first one's address
M_WAITING = 4  # 1: the thread waits for the loop to give this buffer back
META_SIZE = 5
FREE = 0
READY = 1

ADDR_BYTES = 32  # a sockaddr_in6 (28 bytes) fits

# Linux values
_POLLIN = 1
_MSG_DONTWAIT = 0x40
_EINTR = 4
_EAGAIN = 11
_EBADF = 9
_ENOTSOCK = 88
_CLOCK_MONOTONIC = 1
_IDLE_POLL_MS = 1000  # nothing to hold: still look at ctl[C_STOP] this often

_STX_V2 = 0xFD
_STX_V1 = 0xFE
_HIGHRES_ID = 105
_MAX_T_US = 1 << 53  # as navd.core.highres_batch

_poll: Any = types.ExternalFunction("poll", types.int32(types.voidptr, types.uint64, types.int32))
_ppoll: Any = types.ExternalFunction(
    "ppoll", types.int32(types.voidptr, types.uint64, types.voidptr, types.voidptr))
_recvfrom: Any = types.ExternalFunction(
    "recvfrom", types.intp(types.int32, types.voidptr, types.uintp, types.int32,
                           types.voidptr, types.voidptr))
_read: Any = types.ExternalFunction("read", types.intp(types.int32, types.voidptr, types.uintp))
_write: Any = types.ExternalFunction("write", types.intp(types.int32, types.voidptr, types.uintp))
_clock_gettime: Any = types.ExternalFunction("clock_gettime",
                                             types.int32(types.int32, types.voidptr))
_int_ptr: Any = types.CPointer(types.int32)  # type: ignore[no-untyped-call]
_errno_location: Any = types.ExternalFunction("__errno_location", _int_ptr())
_carray: Any = numba.carray  # type: ignore[attr-defined]

U8 = npt.NDArray[np.uint8]
I64 = npt.NDArray[np.int64]


@jit
def _now_ns(ts: I64) -> int:
    _clock_gettime(_CLOCK_MONOTONIC, ts.ctypes.data)
    return int(ts[0] * 1_000_000_000 + ts[1])


@jit
def _errno() -> int:
    return int(_carray(_errno_location(), 1)[0])


@jit
def imu_stamp(buf: U8, p: int, size: int, ctl: I64) -> int:
    """The stamp (us) of datagram ``buf[p:p + size]`` when it is exactly one MAVLink 1 or 2
    HIGHRES_IMU frame of the watched source (``ctl[C_SYS..C_ID]``, -1: any); -1 for a
    HIGHRES_IMU frame of another source; -2 for anything else."""
    if size < 8:
        return -2
    stx = buf[p]
    if stx == _STX_V2:
        if size < 12:
            return -2
        plen = int(buf[p + 1])
        frame = plen + 12 + (13 if buf[p + 2] & 1 else 0)
        msgid = int(buf[p + 7]) | int(buf[p + 8]) << 8 | int(buf[p + 9]) << 16
        sysid = int(buf[p + 5])
        compid = int(buf[p + 6])
        pay = p + 10
    elif stx == _STX_V1:
        plen = int(buf[p + 1])
        frame = plen + 8
        msgid = int(buf[p + 5])
        sysid = int(buf[p + 3])
        compid = int(buf[p + 4])
        pay = p + 6
    else:
        return -2
    if frame != size or msgid != _HIGHRES_ID or plen < 8:
        return -2
    # the IMU instance: a MAVLink 2 extension (MAVLink 2 trims trailing zero bytes)
    imu_id = int(buf[pay + 62]) if stx == _STX_V2 and plen > 62 else 0
    if ((ctl[C_SYS] >= 0 and sysid != ctl[C_SYS])
            or (ctl[C_COMP] >= 0 and compid != ctl[C_COMP])
            or (ctl[C_ID] >= 0 and imu_id != ctl[C_ID])):
        return -1
    t = 0
    for q in range(7, -1, -1):
        t = (t << 8) | int(buf[pay + q])
    if t <= 0 or t > _MAX_T_US:  # the decoder refuses these; ns of it must fit in int64
        return -2
    return t


@jit
def completes(t: int, t_prev: int, ctl: I64) -> bool:
    """A sample stamped ``t`` after one stamped ``t_prev`` (-1: none) must be handled now:
    it is the first at or past an output instant (a multiple of a period), or its stamp
    went back; with no periods every sample must."""
    nper = min(int(ctl[C_NPER]), MAX_PERIODS)
    if nper <= 0 or t_prev < 0 or t <= t_prev:
        return True
    for j in range(nper):
        per = ctl[C_PERIODS + j]
        if per > 0 and t // per != t_prev // per:
            return True
    return False


# pace (int64): what the reader knows of the sender's pace, from the samples completing an
# instant (each read as soon as it arrived, or late): the start of the rate window (sensor
# us, host ns; -1: none), whether the last window ran at the host's rate (a live sensor),
# the least lag (host ns - sensor ns) of this window and of the one before (_NO_LAG: none),
# when the last one was read (host ns)
P_T0, P_H0, P_LIVE, P_LAG, P_LAG_PREV, P_LAST = range(6)
PACE_SIZE = 6
_NO_LAG = 1 << 62
_RATE_WINDOW_NS = 200_000_000  # as navd.io.read_pacing
_QUIET_NS = 100_000_000
_LIVE_RATE_TOLERANCE = 0.05
_MIN_HOLD_NS = 1_000_000
_BURST = 24  # more datagrams in one drain: a burst (or the loop behind), hold nothing


@jit
def pace_note(pace: I64, t: int, now: int) -> None:
    """A sample completing an instant, stamped ``t`` (sensor us), was read at ``now``
    (host ns): measure the sender's pace (:class:`navd.io.read_pacing.ReadPacer`'s rule on
    the completing samples only, which are read as they arrive unless a hold ended late:
    the least lag discounts those)."""
    if pace[P_T0] >= 0 and (t <= pace[P_T0] or now - pace[P_LAST] > _QUIET_NS):
        pace[P_T0] = -1  # stamps back, or the sender paused: measure afresh
        pace[P_LIVE] = 0
    pace[P_LAST] = now
    if pace[P_T0] < 0:
        pace[P_T0] = t
        pace[P_H0] = now
        pace[P_LAG] = _NO_LAG
        pace[P_LAG_PREV] = _NO_LAG
        return
    lag = now - t * 1000
    if lag < pace[P_LAG]:
        pace[P_LAG] = lag
    dh = now - pace[P_H0]
    if dh >= _RATE_WINDOW_NS:
        rate = (t - pace[P_T0]) * 1000.0 / dh
        pace[P_LIVE] = 1 if abs(rate - 1.0) < _LIVE_RATE_TOLERANCE else 0
        pace[P_T0] = t
        pace[P_H0] = now
        pace[P_LAG_PREV] = pace[P_LAG]
        pace[P_LAG] = _NO_LAG


@jit
def hold_until(pace: I64, t: int, now: int, ctl: I64) -> int:
    """After handing on the sample stamped ``t`` that completed an instant, at ``now``
    (host ns): until when (host ns) the socket may stay unread, 0 for not at all. Only a
    live sender is held: until ``ctl[C_MARGIN_NS]`` before the next instant's sample is due
    at the least lag seen, at most ``ctl[C_MAX_HOLD_NS]``, not when under 1 ms."""
    lag = min(pace[P_LAG], pace[P_LAG_PREV])
    nper = min(int(ctl[C_NPER]), MAX_PERIODS)
    if not pace[P_LIVE] or lag >= _NO_LAG or nper <= 0:
        return 0
    t_next = -1
    for j in range(nper):
        per = ctl[C_PERIODS + j]
        if per > 0:
            cand = (t // per + 1) * per
            if t_next < 0 or cand < t_next:
                t_next = cand
    if t_next < 0:
        return 0
    until = t_next * 1000 + lag - ctl[C_MARGIN_NS]
    if until - now < _MIN_HOLD_NS:
        return 0
    return int(min(until, now + ctl[C_MAX_HOLD_NS]))


@jit
def rx_loop(fd: int, ctl_fd: int, ready_fd: int, buf0: U8, buf1: U8, offs0: I64, offs1: I64,
            addr0: U8, addr1: U8, meta: I64, ctl: I64, rx_bytes: int) -> int:
    """Read ``fd`` until ``ctl[C_STOP]`` (module docstring); returns the batches handed on.

    ``buf0``/``buf1``: the two batch buffers (datagram i of buffer b lies at
    ``offs_b[i]:offs_b[i + 1]``, ``offs_b[0] == 0``; at most ``len(offs_b) - 1`` of them);
    a batch is handed on once less than ``rx_bytes`` is left after it (the next datagram
    might not fit whole). ``addr0``/``addr1``: (max datagrams, ADDR_BYTES) uint8, the
    sockaddr each came from. ``meta``: (2, META_SIZE), ``ctl``: (CTL_SIZE,), see ``M_*`` and
    ``C_*``. An fd that is not (or no longer) a socket ends the loop.

    After handing on a sample that completed an instant, a live sender's socket is left
    unread until shortly before the next one is due (:func:`hold_until`): the thread then
    wakes a few times per output period rather than once per datagram.
    """
    pfd = np.zeros(4, np.int32)  # two struct pollfd: the socket, ctl_fd
    p16 = pfd.view(np.int16)
    pfd[0] = fd
    p16[2] = _POLLIN
    pfd[2] = ctl_fd
    p16[6] = _POLLIN
    slen = np.zeros(1, np.int32)  # socklen_t
    one = np.ones(1, np.uint64)  # written to ready_fd
    drop = np.zeros(1, np.uint64)  # ctl_fd's counter, read to clear it
    ts = np.zeros(2, np.int64)
    tmo = np.zeros(2, np.int64)  # ppoll's timespec
    pace = np.full(PACE_SIZE, -1, np.int64)
    pace[P_LIVE] = 0
    handed = 0
    b = 0
    k = 0
    off = 0
    first_ns = 0
    t_prev = -1
    until = 0
    while ctl[C_STOP] == 0:
        buf = buf0 if b == 0 else buf1
        offs = offs0 if b == 0 else offs1
        addr = addr0 if b == 0 else addr1
        wait = -1  # ns; -1: wait for the socket or ctl_fd, with no hold
        if meta[b, M_STATE] != FREE:  # the loop still has it: wait to be told
            # (should the loop miss the flag, the wait ends after 10 ms anyway)
            meta[b, M_WAITING] = 1
            wait = 10_000_000
        elif until:
            wait = until - _now_ns(ts)
            if wait <= 0:
                until = 0
                wait = -1
        if wait >= 0:  # ctl_fd alone (a stop, a buffer given back), at most ``wait``
            tmo[0] = wait // 1_000_000_000
            tmo[1] = wait % 1_000_000_000
            p16[7] = 0
            _ppoll(pfd[2:].ctypes.data, 1, tmo.ctypes.data, 0)
            if p16[7] & _POLLIN:
                _read(ctl_fd, drop.ctypes.data, 8)
            continue
        meta[b, M_WAITING] = 0
        timeout = _IDLE_POLL_MS
        if k:
            left = first_ns + ctl[C_MAX_HOLD_NS] - _now_ns(ts)
            timeout = max(0, int((left + 999_999) // 1_000_000))
        p16[3] = 0
        p16[7] = 0
        r = _poll(pfd.ctypes.data, 2, timeout)
        if r < 0 and _errno() != _EINTR:
            ctl[C_ERRORS] += 1
            ctl[C_ERRNO] = _errno()
            return handed
        if p16[7] & _POLLIN:
            _read(ctl_fd, drop.ctypes.data, 8)
        now = 0
        hand = False
        t_done = -1  # the newest sample read now that completed an instant
        drained = 0
        kmax = len(offs) - 1
        while k < kmax and off <= len(buf) - rx_bytes:
            slen[0] = ADDR_BYTES
            addr[k, :] = 0  # compared whole below: no bytes of an earlier address
            got = _recvfrom(fd, buf[off:].ctypes.data, len(buf) - off, _MSG_DONTWAIT,
                            addr[k].ctypes.data, slen.ctypes.data)
            if got < 0:
                e = _errno()
                if e == _EINTR:
                    continue
                if e == _EAGAIN:
                    break
                ctl[C_ERRORS] += 1
                ctl[C_ERRNO] = e
                if e in (_EBADF, _ENOTSOCK):
                    return handed
                break
            now = _now_ns(ts)
            if k == 0:
                first_ns = now
            t = imu_stamp(buf, off, got, ctl)
            if t == -2:
                hand = True
            elif t >= 0:
                if completes(t, t_prev, ctl):
                    hand = True
                    t_done = t
                t_prev = t
            off += got
            k += 1
            drained += 1
            offs[k] = off
        if k == 0:
            continue
        if now == 0:
            now = _now_ns(ts)
        if k >= kmax or off > len(buf) - rx_bytes or now - first_ns >= ctl[C_MAX_HOLD_NS]:
            hand = True
        if t_done >= 0:
            pace_note(pace, t_done, now)
        if not hand:
            continue
        same = 1
        for i in range(1, k):
            for q in range(ADDR_BYTES):
                if addr[i, q] != addr[0, q]:
                    same = 0
                    break
            if not same:
                break
        meta[b, M_N] = k
        meta[b, M_ARRIVED] = now
        meta[b, M_SAME_ADDR] = same
        meta[b, M_STATE] = READY
        _write(ready_fd, one.ctypes.data, 8)
        handed += 1
        b ^= 1
        k = 0
        off = 0
        if t_done >= 0 and drained <= _BURST:
            until = hold_until(pace, t_done, now, ctl)
    return handed
