"""Read pacing (issue 18): the UDP input is read in batches between output instants, and
only the sample completing an instant has to be read as it arrives."""

from __future__ import annotations

import asyncio
import socket
import sys
import threading
import time
from typing import TYPE_CHECKING

import numpy as np
import pytest
from daemon_util import send_paced
from pymavlink.dialects.v20 import ardupilotmega as mav

from navd.io.mavlink import MavlinkDecoder, MavlinkInputConfig, MavlinkLink
from navd.io.mavlink.link import PacedUdpTransport
from navd.io.read_pacing import ReadPacer
from navd.types import ImuSample, Sample

if TYPE_CHECKING:
    from navd.daemon.sources import ReceiveClock


def _live(pacer: ReadPacer, t_end_us: int, lag_us: int, late: dict[int, int] | None = None
          ) -> None:
    """Note a 1 kHz stream read ``lag_us`` after each stamp (host = sensor + lag; samples
    in ``late`` read that much later)."""
    for t in range(1000, t_end_us + 1, 1000):
        pacer.note(t, t + lag_us + (late or {}).get(t, 0))


def test_hold_until_margin_before_the_next_instant() -> None:
    """GIVEN a live 1 kHz stream read 300 us after each stamp and 50 Hz outputs,
    WHEN asked right after reading the sample at 401 ms,
    THEN the socket may stay unread until 2 ms before the 420 ms sample is due, capped
    at the maximum hold; close to the instant it is read on (0)."""
    p = ReadPacer([20_000], max_hold_us=10_000, margin_us=2_000)
    _live(p, 401_000, 300)
    assert p.hold_us(401_300) == 10_000  # 420_300 - 2_000 - 401_300 = 17 ms, capped
    p2 = ReadPacer([20_000], max_hold_us=50_000, margin_us=2_000)
    _live(p2, 401_000, 300)
    assert p2.hold_us(401_300) == 420_300 - 2_000 - 401_300
    _live(p2, 417_000, 300)
    assert p2.hold_us(417_300) == 1_000  # exactly the minimum hold
    _live(p2, 418_000, 300)
    assert p2.hold_us(418_300) == 0  # the instant is near: read every datagram


def test_a_late_sample_does_not_move_the_expected_arrival() -> None:
    """GIVEN a live stream whose sample at 402 ms was read 6 ms late (a stalled sender),
    WHEN asked right after reading it,
    THEN the hold ends 2 ms before the 420 ms sample is due at the usual lag, not 6 ms
    later."""
    p = ReadPacer([20_000], max_hold_us=50_000, margin_us=2_000)
    _live(p, 402_000, 300, late={402_000: 6_000})
    assert p.hold_us(408_300) == 420_300 - 2_000 - 408_300


def test_the_fastest_sink_decides_and_unknown_rate_reads_on() -> None:
    """GIVEN sinks at 50 Hz and 200 Hz,
    THEN the 200 Hz grid sets the next instant; before the rate is known (first 0.2 s) and
    for a stream 16x faster than real time nothing is held."""
    p = ReadPacer([20_000, 5_000], max_hold_us=50_000, margin_us=1_000)
    p.note(1_000, 1_100)
    assert p.hold_us(1_100) == 0  # rate not known yet
    _live(p, 401_000, 100)
    assert p.hold_us(401_100) == 405_100 - 1_000 - 401_100
    fast = ReadPacer([20_000], max_hold_us=10_000, margin_us=2_000)
    for k in range(1, 8001):  # 16 kHz of sensor time per host second
        fast.note(k * 1000, k * 1000 // 16)
    assert fast.hold_us(8_000_000 // 16) == 0


def test_clock_restart_stops_holding_until_the_rate_is_measured_again() -> None:
    p = ReadPacer([20_000], max_hold_us=10_000)
    _live(p, 401_000, 300)
    assert p.hold_us(401_300) > 0
    p.note(1_000, 500_000)  # the sensor clock started over
    assert p.hold_us(500_000) == 0


def test_a_held_batch_does_not_bias_the_live_rate() -> None:
    """GIVEN a live 1 kHz stream read as the paced daemon reads it: per 20 ms output period
    one batch of the samples up to 2-5 ms before the instant (the hold's end varies with
    the timer), read at its last sample's arrival (the others arrived up to 17 ms earlier),
    then the rest one by one,
    WHEN asked after every read of an instant's sample, for 4 s,
    THEN the hold is the live one (the least lag from the instant, minus the margin) every
    time after the first rate window: a window bounded by a batch's first sample measured
    the rate up to 9 % off, outside the live tolerance, and a hold came out 15.5 ms for
    17 (the assertion, tried on the code before)."""
    lag = 300
    p = ReadPacer([20_000], max_hold_us=20_000, margin_us=3_000)
    rng = np.random.default_rng(1)
    for period in range(1, 201):
        instant = period * 20_000
        end = instant - int(rng.integers(2, 6)) * 1000
        batch = np.arange(instant - 19_000, end + 1, 1000, dtype=np.int64)
        p.note_run(batch, 0, len(batch), int(batch[-1]) + lag)
        for t in range(end + 1000, instant + 1, 1000):
            p.note_run(np.array([t], dtype=np.int64), 0, 1, t + lag)
        if period > 15:  # after the first windows (and their least lag) are in
            # asked at the instant's arrival: due 20 ms later at the same lag, minus the margin
            assert p.hold_us(instant + lag) == 20_000 - 3_000, period


def _imu_frames(n: int) -> list[bytes]:
    m = mav.MAVLink(None, srcSystem=1, srcComponent=1)
    out = []
    for k in range(1, n + 1):
        msg = mav.MAVLink_highres_imu_message(k * 1000, 0.0, 0.0, -9.8, 0.0, 0.0, 0.01, 0.0,
                                              0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0x3F, 0)
        out.append(msg.pack(m))
    return out


@pytest.mark.realtime
@pytest.mark.parametrize("paced", [True, False])
def test_paced_udp_link_reads_everything_in_order_with_fewer_wake_ups(paced: bool) -> None:
    """GIVEN a navd udpin link receiving 1000 HIGHRES_IMU datagrams at 1 kHz,
    WHEN its reads are paced for 50 Hz outputs (or not),
    THEN every sample arrives, in order; paced, once the pace is measured (the last 600
    datagrams) the socket is read in well under half as many wake-ups as datagrams,
    unpaced about once per datagram."""
    frames = _imu_frames(1000)
    got: list[Sample] = []
    wakes = 0

    async def main() -> None:
        nonlocal wakes
        cfg = MavlinkInputConfig(nominal_imu_rate_hz=1000.0, relock_s=None)
        link = await MavlinkLink.open("udpin:127.0.0.1:0", MavlinkDecoder(cfg), got.append)
        t = link._udp_transport
        assert isinstance(t, PacedUdpTransport)
        inner = t._readable

        def counting() -> None:
            nonlocal wakes
            if len(got) >= 400:
                wakes += 1
            inner()

        # the loop calls the bound method it was given: hand it the counting one
        asyncio.get_running_loop().remove_reader(t._fd)
        t._readable = counting  # type: ignore[method-assign]
        asyncio.get_running_loop().add_reader(t._fd, counting)
        if paced:
            assert link.pace_reads(ReadPacer([20_000], 10_000, 2_000))
        port = link.local_address[1] if link.local_address else 0
        th = threading.Thread(target=send_paced, args=(port, frames, 1e-3))
        th.start()
        while th.is_alive():
            await asyncio.sleep(0.05)
        await asyncio.sleep(0.1)
        link.close()

    asyncio.run(main())
    ts = [s.t_us for s in got if isinstance(s, ImuSample)]
    assert ts == [k * 1000 for k in range(1, 1001)]
    if paced:
        assert wakes < 0.4 * 600, wakes
    else:
        assert wakes > 0.6 * 600, wakes


def test_paced_link_refuses_an_oversize_datagram_by_its_real_size() -> None:
    """GIVEN a 20,000-byte datagram on a navd udpin link (limit 16,384),
    THEN it is refused unread and counted as oversize; the frame after it is decoded."""
    got: list[Sample] = []

    async def main() -> dict[str, int]:
        cfg = MavlinkInputConfig(nominal_imu_rate_hz=1000.0, relock_s=None)
        dec = MavlinkDecoder(cfg)
        link = await MavlinkLink.open("udpin:127.0.0.1:0", dec, got.append)
        port = link.local_address[1] if link.local_address else 0
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.sendto(b"\xfd" * 20_000, ("127.0.0.1", port))
        for f in _imu_frames(2):
            s.sendto(f, ("127.0.0.1", port))
        s.close()
        for _ in range(40):
            await asyncio.sleep(0.025)
            if len(got) >= 1:
                break
        link.close()
        return dec.counters.snapshot()

    c = asyncio.run(main())
    assert c.get("oversize") == 1 and c.get("datagrams") == 3, c
    assert [s.t_us for s in got] == [1000, 2000]


def test_a_pause_makes_the_pace_unknown_again() -> None:
    """GIVEN a live 1 kHz stream that pauses for 1.5 s and then goes on (a benchmark
    between its rate steps, a link that was down),
    THEN nothing is held until the pace is measured again: the pace before the pause
    (sensor time per host time across it) says nothing about the pace now."""
    p = ReadPacer([20_000], max_hold_us=10_000)
    _live(p, 401_000, 300)
    assert p.hold_us(401_300) > 0
    p.note(402_000, 1_902_300)
    assert p.hold_us(1_902_300) == 0


def test_no_hold_after_a_burst() -> None:
    """GIVEN a paced navd udpin link,
    WHEN one drain reads 30 datagrams (a fast sender, or navd fell behind),
    THEN it does not ask for a hold and stays on the loop; after a drain of 3 it asks."""
    asked: list[int] = []

    async def main() -> None:
        cfg = MavlinkInputConfig(nominal_imu_rate_hz=1000.0, relock_s=None)
        link = await MavlinkLink.open("udpin:127.0.0.1:0", MavlinkDecoder(cfg), None)
        t = link._udp_transport
        assert isinstance(t, PacedUdpTransport)
        loop = asyncio.get_running_loop()
        loop.remove_reader(t._fd)  # this test drains by hand
        link.set_receive_buffer(1 << 20)

        def hold() -> int:
            asked.append(1)
            return 0

        t.hold_us = hold
        port = link.local_address[1] if link.local_address else 0
        frames = _imu_frames(33)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            for f in frames[:30]:
                s.sendto(f, ("127.0.0.1", port))
            t._readable()
            assert not asked
            for f in frames[30:]:
                s.sendto(f, ("127.0.0.1", port))
            t._readable()
            assert asked == [1]
        loop.add_reader(t._fd, t._readable)
        link.close()

    asyncio.run(main())


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="SIOCGSTAMPNS is Linux's")
def test_a_read_after_a_hold_is_timed_at_the_arrival() -> None:
    """GIVEN a navd udpin link with the daemon's receive clock, and a HIGHRES_IMU datagram
    left unread in the socket for 80 ms (as during a hold),
    WHEN it is read,
    THEN its receive time is the kernel's arrival stamp (within 20 ms of the send), not the
    read 80 ms later: the latency navd reports counts the wait in the socket.

    Two things outside navd can spoil one try, and such a try is repeated (up to 5; the
    last is judged, so stamps that never work still fail): the kernel stamps on the wall
    clock and navd converts with the two clocks' offset at the read, so a step of the wall
    clock in between moves the arrival by the step; and Linux turns stamping on through
    deferred work, so a datagram that arrives before it ran carries no stamp and the
    kernel answers with the time of the ask, i.e. the read.  One CI run on 2026-11-27 saw
    the arrival 80.6 ms after the send (the read); which of the two it was is not known."""
    for _ in range(5):
        off0 = time.time_ns() - time.monotonic_ns()
        rc, got, (sent, before_read, arrived) = _held_read()
        stepped = abs(time.time_ns() - time.monotonic_ns() - off0) >= 2_000_000
        unstamped = abs(arrived - before_read) < 2_000_000
        if not (stepped or unstamped):
            break
    assert got == [1000], got
    assert 0 < arrived - sent < 20_000_000, (arrived - sent) / 1e6
    assert rc.last_ns == arrived  # the receive time handed on is the arrival
    assert before_read - rc.last_ns > 50_000_000


def _held_read() -> tuple[ReceiveClock, list[int], tuple[int, int, int]]:
    """One HIGHRES_IMU datagram sent to a fresh udpin link and read by hand 80 ms later:
    the receive clock, the samples, and (send, read, arrival) times in monotonic ns."""
    from navd.daemon.sources import ReceiveClock

    rc = ReceiveClock()
    got: list[int] = []

    async def main() -> tuple[int, int, int]:
        cfg = MavlinkInputConfig(nominal_imu_rate_hz=1000.0, relock_s=None)
        link = await MavlinkLink.open("udpin:127.0.0.1:0", MavlinkDecoder(cfg),
                                      lambda s: got.append(s.t_us), clock_us=rc)
        t = link._udp_transport
        assert isinstance(t, PacedUdpTransport)
        asyncio.get_running_loop().remove_reader(t._fd)  # held: this test reads by hand
        port = link.local_address[1] if link.local_address else 0
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sent = time.monotonic_ns()
        s.sendto(_imu_frames(1)[0], ("127.0.0.1", port))
        s.close()
        await asyncio.sleep(0.08)
        before_read = time.monotonic_ns()
        t._readable()
        link.close()
        return sent, before_read, t._batch.arrived_ns

    return rc, got, asyncio.run(main())


def test_a_clock_without_at_ns_is_read_not_replaced() -> None:
    """GIVEN the protocol with a plain clock function and a batch stamped at some arrival,
    THEN the receive time is the clock's value; with the daemon's ReceiveClock it is the
    arrival."""
    from navd.daemon.sources import ReceiveClock
    from navd.io.mavlink.link import MavlinkUdpProtocol

    p = MavlinkUdpProtocol(None, None, lambda: 42)
    assert p._receive_time(5_000_000) == 42
    rc = ReceiveClock()
    p2 = MavlinkUdpProtocol(None, None, rc)
    assert p2._receive_time(5_000_000) == 5_000
    assert rc.last_ns == 5_000_000
    now_us = p2._receive_time(0)  # unknown arrival: the clock is read (now), not at_ns(0)
    assert abs(now_us - time.monotonic_ns() // 1000) < 1_000_000, now_us
    assert rc.last_ns // 1000 == now_us
