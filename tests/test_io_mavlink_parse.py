"""MAVLink framing and fast decoding (issues 18 and 19): the payloads navd unpacks itself
agree field for field with pymavlink, parsing cost is linear in the input, oversize input
is refused unread, and the counters count datagrams, damaged places and accepted sources."""

from __future__ import annotations

import logging
import math
import random
import re
import struct
import sys
import time
from collections.abc import Callable

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mav

from firmware_sim.transport.mavlink_tx import MavlinkTx
from navd.io.common import Sample
from navd.io.mavlink import MavlinkDecoder, MavlinkInputConfig
from navd.io.mavlink.frame import FrameScanner, Rejects, crc_x25
from navd.io.mavlink.wire import (
    LAYOUTS,
    crc_extra_table,
    fields_dict,
    max_len_table,
    v1_lengths_table,
)
from navd.types import FixType, GnssSample, ImuSample

ALL_IMU = frozenset({"HIGHRES_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3", "RAW_IMU"})
ALL_GNSS = frozenset({"GPS_RAW_INT", "GPS_INPUT", "HIL_GPS"})


def cfg(**kw: object) -> MavlinkInputConfig:
    base: dict[str, object] = {"imu_messages": ALL_IMU, "gnss_messages": ALL_GNSS,
                               "imu_id": None, "gnss_id": None}
    base.update(kw)
    return MavlinkInputConfig(**base)  # type: ignore[arg-type]


def gnss(t_us: int) -> GnssSample:
    return GnssSample(t_us=t_us, lat_rad=math.radians(47.0), lon_rad=math.radians(8.0),
                      alt_m=400.0, vel_n=1.0, vel_e=2.0, vel_d=0.5, h_acc_m=1.0, v_acc_m=2.0,
                      vel_acc_mps=0.3, fix_type=FixType.FIX_3D)


def scanner() -> FrameScanner:
    """Set up as MavlinkDecoder sets up its own."""
    return FrameScanner(crc_extra_table(), max_len_table(), None, v1_lengths_table())


# -- checksum and layouts against pymavlink ----------------------------------------------------


@given(st.binary(max_size=300), st.integers(0, 255))
@settings(max_examples=300, deadline=None)
def test_crc_matches_pymavlink(data: bytes, extra: int) -> None:
    """GIVEN any bytes and CRC_EXTRA byte,
    WHEN navd's C-level X.25 checksum and pymavlink's are computed,
    THEN they are equal."""
    assert crc_x25(data) == mav.x25crc(data).crc
    assert crc_x25(data, extra) == mav.x25crc(data + bytes((extra,))).crc


def test_layouts_are_pymavlinks_wire_order() -> None:
    """GIVEN navd's hand-written payload layouts of the messages it reads (and HEARTBEAT,
    whose vehicle type the daemon compares with its profile),
    WHEN compared with pymavlink's generated classes,
    THEN size, field wire order and CRC_EXTRA agree for every one."""
    assert {lay.name for lay in LAYOUTS.values()} == ALL_IMU | ALL_GNSS | {"HEARTBEAT"}
    for msgid, lay in LAYOUTS.items():
        cls = mav.mavlink_map[msgid]
        assert cls.msgname == lay.name
        assert lay.unpacker.size == cls.unpacker.size, lay.name
        assert lay.fields == tuple(cls.ordered_fieldnames), lay.name
        assert lay.crc_extra == cls.crc_extra, lay.name


_RANGES = {"Q": (0, 2**64 - 1), "I": (0, 2**32 - 1), "i": (-(2**31), 2**31 - 1),
           "H": (0, 2**16 - 1), "h": (-(2**15), 2**15 - 1), "B": (0, 255)}


def _codes(fmt: str) -> list[str]:
    return [c for n, c in re.findall(r"(\d*)([A-Za-z])", fmt) for _ in range(int(n or 1))]


def _field(code: str) -> st.SearchStrategy[float | int]:
    if code == "f":
        return st.floats(width=32)  # NaN and +-inf included
    lo, hi = _RANGES[code]
    # zero often, so MAVLink 2 cuts trailing fields off
    return st.one_of(st.just(0), st.integers(lo, hi))


@st.composite
def hot_frames(draw: st.DrawFn) -> tuple[int, bytes]:
    """A frame of one of navd's messages as pymavlink packs it: random field values, MAVLink
    1 or 2, signed or not, and sometimes with extension bytes navd does not know."""
    msgid = draw(st.sampled_from(sorted(LAYOUTS)))
    lay = LAYOUTS[msgid]
    values = [draw(_field(c)) for c in _codes(lay.unpacker.format.lstrip("<"))]
    v1 = draw(st.booleans())
    enc = mav.MAVLink(None, draw(st.integers(1, 255)), draw(st.integers(0, 255)))
    enc.seq = draw(st.integers(0, 255))
    signed = not v1 and draw(st.booleans())
    if signed:
        enc.signing.secret_key = bytes(32)
        enc.signing.sign_outgoing = True
        enc.signing.timestamp = draw(st.integers(1, 2**40))
    msg = mav.mavlink_map[msgid](**dict(zip(lay.fields, values, strict=True)))
    frame = msg.pack(enc, force_mavlink1=v1)
    extra = b"" if v1 or signed else draw(st.binary(max_size=8))
    if extra:
        # a newer sender: the known payload in full, then extension fields navd lacks
        payload = frame[10:-2].ljust(lay.unpacker.size, b"\x00") + extra
        body = bytes((len(payload),)) + frame[2:10] + payload
        crc = mav.x25crc(body + bytes((lay.crc_extra,))).crc
        frame = b"\xfd" + body + struct.pack("<H", crc)
    return msgid, frame


def _same(a: float | int, b: float | int) -> bool:
    if isinstance(a, float) or isinstance(b, float):
        return struct.pack("<d", a) == struct.pack("<d", b)  # NaN-aware, sign of zero too
    return a == b


@given(hot_frames())
@settings(max_examples=1500, deadline=None, suppress_health_check=[HealthCheck.too_slow])
def test_hot_messages_decode_field_for_field_like_pymavlink(case: tuple[int, bytes]) -> None:
    """GIVEN a frame of a message navd decodes itself (random values incl. NaN/inf, MAVLink
    1 and 2, zero-truncated payloads, signatures, unknown extension bytes),
    WHEN navd's scanner and payload layout and pymavlink's parser read it,
    THEN the header and every field agree, bit for bit."""
    msgid, frame = case
    ref = mav.MAVLink(None).decode(bytearray(frame))
    f = scanner().whole(frame)
    assert f is not None
    rj = Rejects()
    assert list(scanner().datagram(frame, rj)) == [f] and rj.junk_bytes == 0
    assert (f.msgid, f.sysid, f.compid, f.seq) == (
        ref.get_msgId(), ref.get_srcSystem(), ref.get_srcComponent(), ref.get_seq())
    assert f.raw == frame
    got = fields_dict(msgid, f.payload)
    for name in LAYOUTS[msgid].fields:
        assert _same(got[name], getattr(ref, name)), (name, got[name], getattr(ref, name))


def test_decoded_samples_match_pymavlink_fields() -> None:
    """GIVEN HIGHRES_IMU, GPS_RAW_INT and GPS_INPUT frames with known values,
    WHEN navd decodes them,
    THEN the samples are the pymavlink field values in SI units."""
    enc = mav.MAVLink(None, 1, 1)
    dec = MavlinkDecoder(cfg(nominal_imu_rate_hz=1000.0))
    imu = enc.highres_imu_encode(5_000_000, 0.5, -0.25, -9.75, 0.125, -0.0625, 0.03125,
                                 0, 0, 0, 0, 0, 0, 0, 0x3F, 0)
    (s,) = dec.feed_datagram(imu.pack(enc), 0)
    assert isinstance(s, ImuSample) and s.dt_us == 1000
    assert (s.dtheta_x, s.dtheta_y, s.dtheta_z) == pytest.approx((0.125e-3, -0.0625e-3,
                                                                  0.03125e-3))
    assert (s.dvel_x, s.dvel_y, s.dvel_z) == pytest.approx((0.5e-3, -0.25e-3, -9.75e-3))
    raw = enc.gps_raw_int_encode(7_000_000, 3, 473_977_000, 85_456_000, 500_000, 120, 200,
                                 500, 9000, 12, 550_000, 1500, 2500, 300)
    (g,) = dec.feed_datagram(raw.pack(enc), 0)
    assert isinstance(g, GnssSample)
    assert (math.degrees(g.lat_rad), math.degrees(g.lon_rad)) == pytest.approx((47.3977, 8.5456))
    assert g.alt_m == pytest.approx(550.0) and g.vel_n == pytest.approx(0.0, abs=1e-12)
    assert g.vel_e == pytest.approx(5.0) and math.isnan(g.vel_d)
    assert (g.h_acc_m, g.v_acc_m, g.vel_acc_mps) == pytest.approx((1.5, 2.5, 0.3))


# -- cost and counting of junk -------------------------------------------------------------------


def _python_steps(fn: Callable[[], object]) -> int:
    """Python line events while ``fn`` runs: a machine-independent count of interpreter work."""
    n = 0

    def tracer(frame: object, event: str, arg: object) -> Callable[..., object]:
        nonlocal n
        if event == "line":
            n += 1
        return tracer

    sys.settrace(tracer)
    try:
        fn()
    finally:
        sys.settrace(None)
    return n


JUNK = {
    "0xFE": b"\xfe" * 16384,
    "0xFD": b"\xfd" * 16384,
    "FE 00": b"\xfe\x00" * 8192,
    "FE 01 FD": b"\xfe\x01\xfd" * 5462,  # the worst of ~900 short patterns tried
    "v1 headers": b"\xfe\x00\x00\x00\x00\x00" * 2731,
    "v2 headers": b"\xfd\x01\x00\x00\x00\x00\x00\x00\x00\x00" * 1638,
    "random": random.Random(1).randbytes(16384),
}


@pytest.mark.parametrize("name", sorted(JUNK))
@pytest.mark.parametrize("mode", ["stream", "datagram"])
def test_junk_parse_work_is_linear_with_a_small_constant(name: str, mode: str) -> None:
    """GIVEN 16 kB of junk built to look like frame starts (every byte a start marker, or
    headers of known messages back to back) or random bytes,
    WHEN it is fed as a byte-stream piece or as one datagram,
    THEN the interpreter executes at most 20 lines per input byte (here at most ~17;
    pymavlink's parser with navd's rescans: ~120 for 0xFE), and nothing is decoded."""
    data = JUNK[name]
    dec = MavlinkDecoder(cfg())
    feed = dec.feed if mode == "stream" else dec.feed_datagram
    out: list[Sample] = []
    steps = _python_steps(lambda: out.extend(feed(data, 0)))
    assert out == []
    assert steps <= 20 * len(data), steps / len(data)


def test_64k_junk_stream_parses_in_generous_time() -> None:
    """GIVEN 64 kB of 0xFE fed as one byte-stream piece (no datagram limit applies),
    WHEN it is parsed,
    THEN it takes under 0.2 s of CPU (a very generous bound: about 25 ms here; 0.56 s
    before the linear scanner) and counts one damaged place, not 65,000."""
    dec = MavlinkDecoder(cfg())
    t0 = time.process_time()
    assert dec.feed(b"\xfe" * 65507, 0) == []
    assert time.process_time() - t0 < 0.2
    assert dec.counters["junk_bytes"] >= 65507 - 280
    errors = ("bad_crc", "bad_frame", "bad_prefix", "unknown_msgid", "truncated")
    assert dec.counters.total(errors) <= 2


def test_oversize_datagram_is_refused_unread_and_counted() -> None:
    """GIVEN a decoder with the default datagram limit (16 kB),
    WHEN a 65,507-byte datagram arrives, even one full of valid frames,
    THEN it is refused as one ``oversize`` datagram, no frame of it is read, and a datagram
    of valid frames at the limit is decoded."""
    tx = MavlinkTx()
    frame = tx.gps_input(gnss(1))
    dec = MavlinkDecoder(cfg())
    big = frame * (65507 // len(frame))
    assert dec.feed_datagram(big, 0) == []
    assert dec.counters["oversize"] == 1 and dec.counters["frames_ok"] == 0
    assert dec.counters["datagrams"] == 1
    at_limit = b"".join(tx.gps_input(gnss(10 + i)) for i in range(16384 // len(frame)))
    assert len(at_limit) <= 16384
    assert len(dec.feed_datagram(at_limit, 0)) == 16384 // len(frame)
    assert dec.counters["oversize"] == 1


def test_junk_datagram_counts_places_not_bytes() -> None:
    """GIVEN a 16 kB datagram of 0xFD 0x01 junk with one good frame in the middle,
    WHEN it is decoded,
    THEN the fix comes out, ``junk_bytes`` counts every other byte, each rejection reason is
    counted at most twice (one run before, one after the frame), and the datagram once as
    damaged."""
    tx = MavlinkTx()
    frame = tx.gps_input(gnss(5))
    junk = JUNK["v2 headers"][:8000]
    dec = MavlinkDecoder(cfg())
    (s,) = dec.feed_datagram(junk + frame + junk, 0)
    assert s.t_us == 5
    assert dec.counters["junk_bytes"] == 2 * len(junk)
    for reason in ("bad_crc", "bad_frame", "bad_prefix", "unknown_msgid", "truncated"):
        assert dec.counters[reason] <= 2, (reason, dec.counters)
    assert dec.counters["datagrams"] == 1 and dec.counters["datagrams_damaged"] == 1


def test_datagrams_and_frames_are_counted_apart() -> None:
    """GIVEN five datagrams of three GPS_INPUT frames each,
    WHEN they are decoded,
    THEN 5 datagrams, 15 frames and 15 fixes are counted, and none as damaged."""
    tx = MavlinkTx()
    dec = MavlinkDecoder(cfg())
    n = 0
    for k in range(5):
        dg = b"".join(tx.gps_input(gnss(100 * k + i + 1)) for i in range(3))
        n += len(dec.feed_datagram(dg, 0))
    assert n == 15
    c = dec.counters
    assert (c["datagrams"], c["frames_ok"], c["gnss_ok"], c["datagrams_damaged"]) == (5, 15, 15, 0)


def test_sequence_loss_is_counted_for_accepted_sources_only() -> None:
    """GIVEN fixes from (1, 1) with two frames lost on the wire, mixed with 500 valid
    HEARTBEATs from 250 other sources with random sequence numbers,
    WHEN they are decoded,
    THEN ``seq_lost`` is 2 (the hostile frames add nothing), (1, 1) has its own counters,
    and no other source gets any."""
    tx = MavlinkTx(sysid=1, compid=1)
    rnd = random.Random(2)
    hostile = []
    for i in range(500):
        enc = mav.MAVLink(None, 2 + i % 250, 1)
        enc.seq = rnd.randrange(256)
        hostile.append(enc.heartbeat_encode(2, 3, 0, 0, 4).pack(enc))
    good = [tx.gps_input(gnss(1000 + i)) for i in range(20)]
    del good[7], good[12]  # lost on the wire
    dec = MavlinkDecoder(cfg())
    out = []
    for i, frame in enumerate(good):
        out += dec.feed_datagram(frame, 0)
        for h in hostile[25 * i:25 * (i + 1)]:
            out += dec.feed_datagram(h, 0)
    assert len(out) == 18
    snap = dec.counters.snapshot()
    assert snap["seq_lost"] == 2 and snap["src_1_1_seq_lost"] == 2
    assert snap["src_1_1_frames"] == 18
    assert [k for k in snap if k.startswith("src_")] == ["src_1_1_frames", "src_1_1_seq_lost"]


def test_per_source_counters_are_bounded() -> None:
    """GIVEN valid fixes from 50 different sources,
    WHEN they are decoded (no allow list),
    THEN only the first 8 sources get counters of their own; the rest are counted as
    ``src_untracked``."""
    dec = MavlinkDecoder(cfg())
    for sysid in range(1, 51):
        dec.feed_datagram(MavlinkTx(sysid=sysid, compid=1).gps_input(gnss(sysid)), 0)
    snap = dec.counters.snapshot()
    tracked = {m.group(0) for k in snap if (m := re.match(r"src_\d+_\d+_", k))}
    assert tracked == {f"src_{i}_1_" for i in range(1, 9)}
    assert snap["src_untracked"] == 42


# -- [daemon] warn_interval_s reaches the decoders ----------------------------------------


def _bad_crc_frames(n: int) -> list[bytes]:
    tx = MavlinkTx()
    out = []
    for i in range(n):
        f = bytearray(tx.gps_input(gnss(i + 1)))
        f[-1] ^= 0x5A
        out.append(bytes(f))
    return out


@pytest.mark.parametrize(("interval_s", "lines"), [(0.0, 4), (3600.0, 1)])
def test_mavlink_decoder_honours_warn_interval(
        caplog: pytest.LogCaptureFixture, interval_s: float, lines: int) -> None:
    """GIVEN a decoder configured with warn_interval_s = 0 (or 1 h),
    WHEN four datagrams with a bad CRC arrive,
    THEN four warning lines are logged (or one), and four rejections counted either way."""
    dec = MavlinkDecoder(cfg(warn_interval_s=interval_s))
    with caplog.at_level(logging.WARNING, logger="navd.io.mavlink"):
        for f in _bad_crc_frames(4):
            dec.feed_datagram(f, 0)
    assert len([r for r in caplog.records if "bad_crc" in r.getMessage()]) == lines
    assert dec.counters["bad_crc"] == 4


def test_daemon_warn_interval_reaches_mavlink_and_dronecan_decoders(
        caplog: pytest.LogCaptureFixture) -> None:
    """GIVEN a daemon configuration with ``[daemon] warn_interval_s = 0``,
    WHEN the daemon's adapter settings are made from it and each decoder rejects three inputs,
    THEN each decoder logs all three lines (a fixed 5 s interval would log one)."""
    import can

    from firmware_sim.transport.dronecan_tx import DronecanTx
    from navd.config.daemon import load_daemon_config
    from navd.daemon.adapters import dronecan_bus_config, mavlink_input_config
    from navd.io.dronecan import DronecanDecoder
    from navd.io.dronecan.decode import DronecanConfig

    dc = load_daemon_config(None, ["daemon.warn_interval_s=0", "dronecan.enabled=true",
                                   "dronecan.interface=virtual"])
    w = dc.daemon.warn_interval
    mdec = MavlinkDecoder(mavlink_input_config(dc.mavlink, warn_interval_s=w))
    ddec = DronecanDecoder(dronecan_bus_config(dc.dronecan, warn_interval_s=w))
    assert isinstance(ddec.config, DronecanConfig)
    with caplog.at_level(logging.WARNING):
        for f in _bad_crc_frames(3):
            mdec.feed_datagram(f, 0)
        tx = DronecanTx(node_id=30)
        for _ in range(3):
            for m in tx.fix2(gnss(0)):
                assert isinstance(m, can.Message)
                ddec.feed(m, 0)
    msgs = [r.getMessage() for r in caplog.records]
    assert len([m for m in msgs if "bad_crc" in m]) == 3, msgs
    assert len([m for m in msgs if "gnss_no_timestamp" in m]) == 3, msgs


def test_mavlink1_frame_without_extensions_as_the_c_library_sends_it() -> None:
    """GIVEN a MAVLink 1 GPS_RAW_INT carrying only its 30 base bytes (the C library leaves
    the extensions out of MAVLink 1), and one cut at 27 bytes (not a field boundary),
    WHEN decoded,
    THEN the first gives a fix with the MSL height (the extension alt_ellipsoid reads 0) and
    the same fields as pymavlink, and the second is refused before its checksum."""
    enc = mav.MAVLink(None, 1, 1)
    full = enc.gps_raw_int_encode(7_000_000, 3, 473_977_000, 85_456_000, 500_000, 120, 200,
                                  500, 9000, 12, 550_000).pack(enc, force_mavlink1=True)

    def v1(payload: bytes) -> bytes:
        body = bytes((len(payload),)) + full[2:6] + payload
        return b"\xfe" + body + struct.pack("<H", mav.x25crc(body + bytes((24,))).crc)

    base = v1(full[6:36])
    dec = MavlinkDecoder(cfg())
    (g,) = dec.feed_datagram(base, 0)
    assert isinstance(g, GnssSample) and g.alt_m == pytest.approx(500.0)
    ref = mav.MAVLink(None).decode(bytearray(base))
    f = scanner().whole(base)
    assert f is not None
    got = fields_dict(24, f.payload)
    assert all(_same(got[k], getattr(ref, k)) for k in LAYOUTS[24].fields)
    assert scanner().whole(v1(full[6:33])) is None  # 27 bytes: inside the cog field
