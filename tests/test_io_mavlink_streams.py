"""MAVLink over the byte-stream links.

Fuzzing (issue 19 item 9): junk, cut frames and good frames, in random pieces, through a
real TCP connection and a real pseudo-terminal (the serial path, pyserial set-up included).
The link never fails, every good frame comes out in order, and the junk is counted.
Serial set-up by pyserial (issue 16 item 9): any baud rate, raw 8N1, an exclusive port."""

from __future__ import annotations

import asyncio
import itertools
import math
import os
from collections.abc import Callable

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from firmware_sim.transport.mavlink_tx import MavlinkTx
from navd.io.common import Sample
from navd.io.mavlink import MavlinkDecoder, MavlinkInputConfig, MavlinkLink
from navd.types import FixType, GnssSample

LINK_FUZZ = settings(max_examples=25, deadline=None,
                     suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def gnss(t_us: int) -> GnssSample:
    return GnssSample(t_us=t_us, lat_rad=math.radians(47.0), lon_rad=math.radians(8.0),
                      alt_m=400.0, vel_n=1.0, vel_e=2.0, vel_d=0.5, h_acc_m=1.0, v_acc_m=2.0,
                      vel_acc_mps=0.3, fix_type=FixType.FIX_3D)


_TX = MavlinkTx()
_FRAME = _TX.gps_input(gnss(1))

junk = st.one_of(
    st.binary(min_size=1, max_size=400),
    st.integers(1, len(_FRAME) - 1).map(lambda n: _FRAME[:n]),  # a frame cut short
    st.tuples(st.sampled_from([b"\xfd", b"\xfe", b"\xfd\x01\x00", b"\xfe\x00"]),
              st.integers(1, 200)).map(lambda t: t[0] * t[1]),  # start markers in a row
)


@st.composite
def streams(draw: st.DrawFn) -> tuple[list[bytes], list[int], int]:
    """Good fixes with junk before them (and maybe after the last), cut into random pieces:
    (pieces, fix times, junk bytes before the last fix)."""
    tx = MavlinkTx()
    blob, want, n_junk = b"", [], 0
    for i in range(draw(st.integers(1, 8))):
        if draw(st.booleans()):
            j = draw(junk)
            blob += j
            n_junk += len(j)
        want.append(100 + i)
        blob += tx.gps_input(gnss(100 + i))
    # junk after the last frame is not counted: it may be the start of a frame to come
    if draw(st.booleans()):
        blob += draw(junk)
    cuts = sorted(set(draw(st.lists(st.integers(1, max(1, len(blob) - 1)), max_size=12))))
    bounds = [0, *cuts, len(blob)]
    return [blob[a:b] for a, b in itertools.pairwise(bounds) if b > a], want, n_junk


def _subsequence(want: list[int], got: list[int]) -> bool:
    it = iter(got)
    return all(any(g == w for g in it) for w in want)


async def _wait_for(pred: Callable[[], bool], timeout_s: float = 5.0) -> None:
    async with asyncio.timeout(timeout_s):
        while not pred():
            await asyncio.sleep(0.005)


def _check(dec: MavlinkDecoder, got: list[Sample], want: list[int], n_junk: int) -> None:
    times = [s.t_us for s in got]
    # every good fix, in order (junk may hide a stray valid frame only with odds of ~2**-16
    # per candidate, and then it would come out as an extra, not displace these)
    assert _subsequence(want, times), (want, times)
    assert dec.counters["parser_error"] == 0
    if n_junk:
        assert dec.counters["junk_bytes"] > 0


@given(streams())
@LINK_FUZZ
def test_tcp_link_fuzz(case: tuple[list[bytes], list[int], int]) -> None:
    """GIVEN a TCP peer sending good fixes, junk and cut frames in random pieces,
    WHEN navd's tcp: link reads them,
    THEN every good fix comes out in order, nothing raises, and junk is counted."""
    pieces, want, n_junk = case

    async def main() -> None:
        async def serve(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            for p in pieces:
                writer.write(p)
                await writer.drain()
            await reader.read()  # hold the connection until the link closes it
            writer.close()

        server = await asyncio.start_server(serve, "127.0.0.1", 0)
        port = server.sockets[0].getsockname()[1]
        dec = MavlinkDecoder(MavlinkInputConfig())
        got: list[Sample] = []
        link = await MavlinkLink.open(f"tcp:127.0.0.1:{port}", dec, got.append)
        try:
            await _wait_for(lambda: len(got) >= len(want))
            await asyncio.sleep(0.01)
            _check(dec, got, want, n_junk)
        finally:
            link.close()
            server.close()
            await server.wait_closed()

    asyncio.run(main())


@given(streams())
@LINK_FUZZ
def test_serial_link_fuzz_on_a_pty(case: tuple[list[bytes], list[int], int]) -> None:
    """GIVEN a pseudo-terminal whose far end writes good fixes, junk and cut frames in
    random pieces,
    WHEN navd's serial link (pyserial set-up, 921600 baud) reads them,
    THEN every good fix comes out in order, nothing raises, and junk is counted."""
    pieces, want, n_junk = case

    async def main() -> None:
        master, slave = os.openpty()
        dec = MavlinkDecoder(MavlinkInputConfig())
        got: list[Sample] = []
        link = await MavlinkLink.open(f"{os.ttyname(slave)},921600", dec, got.append)
        try:
            for p in pieces:
                os.write(master, p)
                await asyncio.sleep(0)
            await _wait_for(lambda: len(got) >= len(want))
            await asyncio.sleep(0.01)
            _check(dec, got, want, n_junk)
        finally:
            link.close()
            await asyncio.sleep(0)
            os.close(master)
            os.close(slave)

    asyncio.run(main())


def test_serial_setup_any_baud_raw_8n1_and_exclusive() -> None:
    """GIVEN a pseudo-terminal,
    WHEN navd opens it as a serial link at 250000 baud (no termios B-constant exists for it),
    THEN the port is raw 8N1 without flow control at that rate, a frame written to the far
    end is decoded, and a second open of the same device is refused while the first holds
    it."""
    import termios

    async def main() -> None:
        master, slave = os.openpty()
        path = os.ttyname(slave)
        got: list[Sample] = []
        link = await MavlinkLink.open(f"{path},250000", MavlinkDecoder(MavlinkInputConfig()),
                                      got.append)
        try:
            iflag, _oflag, cflag, lflag, *_ = termios.tcgetattr(slave)
            assert cflag & termios.CSIZE == termios.CS8
            assert not cflag & (termios.PARENB | termios.CSTOPB | termios.CRTSCTS)
            assert not lflag & (termios.ICANON | termios.ECHO | termios.ISIG)
            assert not iflag & (termios.IXON | termios.IXOFF | termios.ICRNL)
            os.write(master, MavlinkTx().gps_input(gnss(77)))
            await _wait_for(lambda: len(got) == 1)
            assert got[0].t_us == 77
            try:
                second = await MavlinkLink.open(f"{path},250000")
            except OSError:
                pass
            else:
                second.close()
                raise AssertionError("a second open of a held serial port succeeded")
        finally:
            link.close()
            await asyncio.sleep(0)
            os.close(master)
            os.close(slave)

    asyncio.run(main())
