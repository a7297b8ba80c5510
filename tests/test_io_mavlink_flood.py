"""A UDP address that floods junk is muted (issue 19: garbage floods up to 10 Mbit/s must
cost little): its datagrams are refused unread for a while, other senders keep being read."""

from __future__ import annotations

import asyncio

from firmware_sim.stream import mavlink_events
from navd.io.mavlink import MavlinkDecoder
from navd.io.mavlink.link import JUNK_BUDGET_BYTES, MUTE_US, MavlinkUdpProtocol
from navd.types import Sample
from tests.daemon_util import car_run


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

    def receive(flood: bool) -> tuple[list[Sample], dict[str, int]]:
        got: list[Sample] = []
        clock = {"us": 0}

        async def go() -> dict[str, int]:
            dec = MavlinkDecoder()
            p = MavlinkUdpProtocol(dec, got.append, clock_us=lambda: clock["us"])
            for t, f in frames:
                clock["us"] = t
                p.datagram_received(f, real_addr)
                if flood:
                    for k in (1, 2):
                        clock["us"] = t + k
                        p.datagram_received(junk, bad_addr)
            return dec.counters.snapshot()

        return got, asyncio.run(go())

    clean, _ = receive(False)
    got, c = receive(True)
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
    got: list[Sample] = []
    clock = {"us": 0}

    async def go() -> dict[str, int]:
        dec = MavlinkDecoder()
        p = MavlinkUdpProtocol(dec, got.append, clock_us=lambda: clock["us"])
        for t, f in frames:
            clock["us"] = t
            p.datagram_received(f, ("127.0.0.1", 5000))
            for k in (1, 2, 3):
                clock["us"] = t + k
                p.datagram_received(junk, ("127.0.0.1", 5000))
        return dec.counters.snapshot()

    c = asyncio.run(go())
    assert c.get("datagrams_muted", 0) == 0 and c.get("peer_muted", 0) == 0, c
    assert c["imu_ok"] >= 490, c
