"""NAVD_SKY_POLARIZATION over MAVLink 2: encoder (firmware_sim) and decoder (navd.io)."""

from __future__ import annotations

import importlib.util
import math
import struct
import sys
from pathlib import Path
from types import ModuleType

import pytest
from pymavlink.dialects.v20 import all as mav_all
from pymavlink.dialects.v20 import ardupilotmega
from pymavlink.generator import mavgen, mavparse

from firmware_sim.polarization import PolMavlinkEncoder, encode_mavlink, parse_utc
from navd.core.sun import utc_to_gps_s
from navd.io.pol_wire import CRC_EXTRA, DIALECT_XML, MSG_ID, decode, decode_payload
from navd.types import PolSample

UTC0 = parse_utc("2020-06-01T10:12:00Z")


@pytest.fixture(scope="module")
def generated(tmp_path_factory: pytest.TempPathFactory) -> ModuleType:
    """pymavlink's own generator run on the dialect XML (the reference implementation)."""
    out = tmp_path_factory.mktemp("mavgen") / "navd_pol"
    opts = mavgen.Opts(str(out), wire_protocol="2.0", language="Python3", validate=True)
    assert mavgen.mavgen(opts, [str(DIALECT_XML)])
    spec = importlib.util.spec_from_file_location("navd_pol_generated", f"{out}.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules["navd_pol_generated"] = mod
    spec.loader.exec_module(mod)
    return mod


def test_dialect_constants_match_the_xml() -> None:
    """GIVEN the shipped dialect XML parsed by pymavlink,
    WHEN its one message is read,
    THEN name, ID, CRC extra and field order match navd's constants and the ID clashes with
    no dialect pymavlink ships."""
    xml = mavparse.MAVXML(str(DIALECT_XML), "2.0")
    (msg,) = xml.message
    assert (msg.name, msg.id, msg.crc_extra) == ("NAVD_SKY_POLARIZATION", MSG_ID, CRC_EXTRA)
    assert [f.name for f in msg.ordered_fields] == ["time_usec", "time_gps_usec", "aop", "dop",
                                                     "id"]
    assert MSG_ID not in mav_all.mavlink_map  # no clash with any dialect pymavlink ships


@pytest.mark.parametrize("args", [
    (123456, 1275000000123456, 1.234, 0.5, 0),
    (1, 2, 0.0, 0.0, 0),          # trailing zeros: MAVLink 2 payload truncation
    (7, 8, 3.0, 1.0, 3),
])
def test_encoder_is_byte_identical_to_mavgen(generated: ModuleType,
                                             args: tuple[int, int, float, float, int]) -> None:
    """GIVEN pymavlink's generator run on the dialect XML (the reference) and a family of
    field values, including all-zero trailing fields (MAVLink 2 truncation),
    WHEN the firmware_sim encoder and the generated code pack the same message,
    THEN the frames are byte-identical and both parsers read them back."""
    mav = generated.MAVLink(None, srcSystem=1, srcComponent=158)
    seq = mav.seq
    ref = generated.MAVLink_navd_sky_polarization_message(*args).pack(mav)
    mine = encode_mavlink(*args, seq=seq, sysid=1, compid=158)
    assert mine == bytes(ref)
    parsed = generated.MAVLink(None).parse_char(mine)
    assert parsed.get_type() == "NAVD_SKY_POLARIZATION"
    assert parsed.time_usec == args[0] and parsed.time_gps_usec == args[1]
    s = decode(bytes(ref))
    assert s is not None and s.t_us == args[0] and s.aop_rad == pytest.approx(args[2], abs=1e-6)


def test_round_trip_and_gps_time() -> None:
    """GIVEN a polarization reading with a UTC time in 2020,
    WHEN it is encoded twice and decoded,
    THEN the sequence number counts 0, 1, the values come back, and the wire time is GPS
    time: UTC + 18 s."""
    enc = PolMavlinkEncoder()
    s = PolSample(t_us=12_345_678, aop_rad=2.5, dop=0.42, utc_unix_s=UTC0 + 0.25)
    frame = enc.encode(s)
    _, _, _, _, seq, *_ = struct.unpack("<BBBBBBBHB", frame[:10])
    assert seq == 0 and enc.encode(s)[4] == 1
    d = decode(frame)
    assert d is not None
    assert d.t_us == s.t_us
    assert d.aop_rad == pytest.approx(2.5, abs=1e-6)
    assert d.dop == pytest.approx(0.42, abs=1e-6)
    assert d.utc_unix_s == pytest.approx(s.utc_unix_s, abs=1e-6)
    # on the wire it is GPS time: UTC + 18 s in 2020
    gps_us = struct.unpack("<QQ", frame[10:26])[1]
    assert gps_us * 1e-6 == pytest.approx(utc_to_gps_s(UTC0 + 0.25), abs=1e-6)
    assert gps_us * 1e-6 - (UTC0 + 0.25 - 315964800) == pytest.approx(18.0, abs=1e-6)


def test_ardupilotmega_parser_hands_over_the_frame_as_unknown() -> None:
    """GIVEN a polarization frame and the stock ardupilotmega parser (robust parsing),
    WHEN the parser reads it,
    THEN it yields msgid UNKNOWN with the whole frame in m.data (how the MAVLink adapter
    finds our frames), which decodes to the reading, or to the receive time if asked."""
    frame = encode_mavlink(5_000_000, round(utc_to_gps_s(UTC0) * 1e6), 1.0, 0.6)
    mav = ardupilotmega.MAVLink(None)
    mav.robust_parsing = True
    m = mav.parse_char(frame)
    assert m.get_msgId() == ardupilotmega.MAVLINK_MSG_ID_UNKNOWN
    s = decode(bytes(m.data), recv_t_us=99)
    assert s == PolSample(5_000_000, pytest.approx(1.0, abs=1e-6),  # type: ignore[arg-type]
                          pytest.approx(0.6, abs=1e-6), UTC0)  # type: ignore[arg-type]
    s2 = decode(bytes(m.data), recv_t_us=99, use_receive_time=True)
    assert s2 is not None and s2.t_us == 99


def test_bad_frames_and_values_are_refused_and_counted() -> None:
    """GIVEN frames with a bad CRC or cut short, other messages, garbage, readings with a
    bad AoP/DoP or missing times, and a payload of the wrong length,
    WHEN they are decoded,
    THEN none yields a sample; each bad one is counted under its reason, the heartbeat is not."""
    good = encode_mavlink(5, round(utc_to_gps_s(UTC0) * 1e6), 1.0, 0.6)
    c: dict[str, int] = {}
    corrupt = bytearray(good)
    corrupt[12] ^= 0xFF
    assert decode(bytes(corrupt), counters=c) is None and c == {"pol_wire_bad_crc": 1}
    assert decode(good[:-1], counters=c) is None and c["pol_wire_bad_frame"] == 1
    # another message: silently not ours
    hb = ardupilotmega.MAVLink(None).heartbeat_encode(6, 8, 0, 0, 0).pack(
        ardupilotmega.MAVLink(None))
    n = sum(c.values())
    assert decode(bytes(hb), counters=c) is None and sum(c.values()) == n
    assert decode(b"", counters=c) is None and decode(b"\xfe" * 20, counters=c) is None
    gps = round(utc_to_gps_s(UTC0) * 1e6)
    for args, reason in (((5, gps, math.nan, 0.6), "pol_wire_bad_value"),
                         ((5, gps, math.pi + 0.01, 0.6), "pol_wire_bad_value"),
                         ((5, gps, -0.5, 0.6), "pol_wire_bad_value"),
                         ((5, gps, 1.0, 1.5), "pol_wire_bad_value"),
                         ((5, 0, 1.0, 0.6), "pol_wire_no_gps_time"),
                         ((0, gps, 1.0, 0.6), "pol_wire_no_time")):
        c = {}
        assert decode(encode_mavlink(*args), counters=c) is None  # type: ignore[arg-type]
        assert c == {reason: 1}
    assert decode_payload(b"\x00" * 30, counters=c) is None and c["pol_wire_bad_length"] == 1


def test_xml_is_shipped_next_to_the_decoder() -> None:
    """GIVEN the installed navd.io.pol_wire module,
    WHEN the dialect XML path is checked,
    THEN the file exists in the module's own directory."""
    assert DIALECT_XML.is_file() and DIALECT_XML.parent == Path(
        __import__("navd.io.pol_wire", fromlist=["x"]).__file__).parent
