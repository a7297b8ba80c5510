"""A UDP address that floods junk is muted (issue 19: garbage floods up to 10 Mbit/s must
cost little): its datagrams are refused unread for a while, other senders keep being read.
A flood that changes its source port (or host) is budgeted per host and over all senders,
and the real sender keeps being read even when the junk comes from its own host."""

from __future__ import annotations

import asyncio
import logging
import random
from typing import Any

import pytest

from firmware_sim.stream import mavlink_events
from navd.io.mavlink import MavlinkDecoder
from navd.io.mavlink.link import (
    HOST_JUNK_BUDGET_BYTES,
    JUNK_BUDGET_BYTES,
    MUTE_US,
    TOTAL_JUNK_BUDGET_BYTES,
    MavlinkUdpProtocol,
)
from navd.types import Sample
from tests.daemon_util import car_run

JUNK_BYTES = 280
FLOOD_STEP_US = round(1e6 * JUNK_BYTES * 8 / 10e6)  # 10 Mbit/s of 280-byte datagrams
# datagrams before the flood changes its source port (or host): 2.8 kB, under one address's
# budget, so that only the host's (or all senders') budget can catch it
PER_SOURCE = 10
assert PER_SOURCE * JUNK_BYTES < JUNK_BUDGET_BYTES
# what one budget lets through before the muting: whole datagrams, the last one over it
BUDGET_DATAGRAMS = {"port": HOST_JUNK_BUDGET_BYTES // JUNK_BYTES + 1,
                    "host": TOTAL_JUNK_BUDGET_BYTES // JUNK_BYTES + 1}


def rotating_flood(pattern: str, vary: str, t0_us: int, dur_us: int) -> list[Event]:
    """(receive time us, datagram, source address) of a 10 Mbit/s junk flood of 280-byte
    datagrams that takes a new source port (``vary="port"``, host 127.0.0.1) or a new
    source host (``"host"``, 127.0.x.y) every PER_SOURCE datagrams."""
    rng = random.Random(19)
    fixed = (b"\xfe\x01\xfd" * 94)[:JUNK_BYTES]
    out = []
    for k, t in enumerate(range(t0_us, t0_us + dur_us, FLOOD_STEP_US)):
        j = k // PER_SOURCE
        addr = (("127.0.0.1", 20000 + j) if vary == "port"
                else (f"127.0.{1 + j // 250}.{1 + j % 250}", 20000))
        out.append((t, fixed if pattern == "FE 01 FD" else rng.randbytes(JUNK_BYTES), addr))
    return out


Event = tuple[int, bytes, tuple[Any, ...]]


def receive(events: list[Event]) -> tuple[list[Sample], dict[str, int]]:
    """Feed (receive time us, datagram, source address) events to a fresh UDP link with the
    default decoder, its clock at each event's time; the samples it delivered and the
    decoder's counters."""
    got: list[Sample] = []

    async def go() -> dict[str, int]:
        clock = {"us": 0}
        dec = MavlinkDecoder()
        p = MavlinkUdpProtocol(dec, got.append, clock_us=lambda: clock["us"])
        for t, data, addr in events:
            clock["us"] = t
            p.datagram_received(data, addr)
        return dec.counters.snapshot()

    return got, asyncio.run(go())


def test_junk_flooder_is_muted_and_the_real_sender_is_not() -> None:
    """GIVEN a UDP link receiving the real sender's frames from one address and, between them,
    280-byte FE/FD-dense junk datagrams from another (2 per real frame, 10 s),
    WHEN they are received,
    THEN the junk address is muted after JUNK_BUDGET_BYTES of junk (its datagrams refused
    unread, at most one budget read per mute period), and every real frame is still decoded
    exactly as without the flood."""
    frames = [(t, f) for t, f, _ in mavlink_events(car_run(10.0))]
    junk = (b"\xfe\x01\xfd" * 94)[:280]
    real_addr, bad_addr = ("127.0.0.1", 5000), ("127.0.0.1", 6000)
    real = [(t, f, real_addr) for t, f in frames]
    flooded = [e for t, f in frames
               for e in ((t, f, real_addr), (t + 1, junk, bad_addr), (t + 2, junk, bad_addr))]

    clean, _ = receive(real)
    got, c = receive(flooded)
    assert got == clean and len(got) > 1000
    n_junk = 2 * len(frames)
    # the budget is read once per mute period at most (10 s / MUTE_US of them); the rest is
    # refused unread
    read_max = (10e6 / MUTE_US + 2) * (JUNK_BUDGET_BYTES // 280 + 1)
    assert c["datagrams_damaged"] <= read_max, c
    assert c["datagrams_muted"] >= n_junk - c["datagrams_damaged"], c
    assert c["peer_muted"] >= 5, c


def test_an_address_that_delivers_samples_is_not_muted() -> None:
    """GIVEN junk datagrams sent in the real sender's name (same address) next to its frames,
    WHEN received,
    THEN that address is not muted (its samples keep coming; the junk costs CPU instead)."""
    frames = [(t, f) for t, f, _ in mavlink_events(car_run(5.0))]
    junk = (b"\xfe\x01\xfd" * 94)[:280]
    addr = ("127.0.0.1", 5000)
    _, c = receive([e for t, f in frames
                    for e in ((t, f, addr), *((t + k, junk, addr) for k in (1, 2, 3)))])
    assert c.get("datagrams_muted", 0) == 0 and c.get("peer_muted", 0) == 0, c
    assert c["imu_ok"] >= 490, c


@pytest.mark.parametrize("vary", ["port", "host"])
@pytest.mark.parametrize("pattern", ["FE 01 FD", "random"])
def test_a_flood_that_changes_its_source_is_budgeted_by_host_and_in_all(
        pattern: str, vary: str, caplog: pytest.LogCaptureFixture) -> None:
    """GIVEN 3 s of a 10 Mbit/s flood of 280-byte junk datagrams ("FE 01 FD" repeated, the
    scanner's costliest common pattern, or random bytes) that changes its source port every
    10 datagrams (so no one address exceeds its budget; before, every one of them was
    scanned: 167 % of a core for "FE 01 FD" changing ports every 100), or its source host,
    WHEN they are received,
    THEN the host (port changes) or all senders (host changes) are muted after one budget:
    at most one budget of datagrams is scanned per mute period, every other one is dropped
    unscanned and counted, each muting is counted and logged rate-limited."""
    caplog.set_level(logging.WARNING, "navd.io.mavlink")
    flood = rotating_flood(pattern, vary, 0, 3_000_000)
    _, c = receive(flood)
    scanned = c.get("datagrams_damaged", 0)
    assert scanned + c.get("datagrams_muted", 0) == len(flood), c
    # the flood starts a budget window, is muted for MUTE_US, and again: 3 windows in 3 s
    assert scanned <= (3_000_000 // MUTE_US + 1) * BUDGET_DATAGRAMS[vary] < len(flood) / 5, c
    muted = "host_muted" if vary == "port" else "senders_muted"
    assert c.get(muted, 0) >= 3 and c.get("peer_muted", 0) == 0, c
    lines = [r.getMessage() for r in caplog.records if "of junk" in r.getMessage()]
    assert len(lines) == 1, lines  # one line per warn_interval_s (5 s)


@pytest.mark.parametrize("start", ["before", "during"])
@pytest.mark.parametrize("vary", ["port", "host"])
def test_the_real_stream_flows_while_junk_comes_from_its_host_on_other_ports(
        vary: str, start: str) -> None:
    """GIVEN the real sender's frames (5 s of car480, one frame per datagram) from
    127.0.0.1:5000 and a 10 Mbit/s "FE 01 FD" flood from the same host on ports that change
    every 10 datagrams (or from hosts that change), the flood starting 1 s after the real
    stream, or 1.5 s before it (the host, or all senders, already muted when it starts),
    WHEN they are received,
    THEN every real frame is decoded exactly as without the flood (the address that
    delivers samples is never muted; a muted sender's datagrams that are one valid frame are
    still read), while the flood's host (or all other senders) is muted and the rest of the
    flood is dropped unscanned."""
    run = car_run(5.0)
    shift = 0 if start == "before" else 1_500_000
    frames = [(t + shift, f, ("127.0.0.1", 5000)) for t, f, _ in mavlink_events(run)]
    flood = rotating_flood("FE 01 FD", vary, 1_000_000 if start == "before" else 0, 4_000_000)
    mixed = sorted(frames + flood, key=lambda e: e[0])
    clean, _ = receive(frames)
    got, c = receive(mixed)
    assert got == clean and len(got) > 500
    assert c.get("host_muted" if vary == "port" else "senders_muted", 0) >= 3, c
    scanned = c.get("datagrams_damaged", 0)
    assert scanned <= (4_000_000 // MUTE_US + 1) * BUDGET_DATAGRAMS[vary], c
    assert c.get("datagrams_muted", 0) == len(flood) - scanned, c
