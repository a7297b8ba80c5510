"""Polarization-compass wire format: MAVLink 2 ``NAVD_SKY_POLARIZATION`` -> :class:`PolSample`.

No standard message carries a skylight-polarization reading, so navd defines one in a
private dialect, ``navd/io/navd_polarization.xml`` (message id 44000, outside every range
pymavlink's ``all.xml`` allocates; CRC_EXTRA 76).  docs/polarization.md documents the
fields.  This module decodes the frames by hand (no generated code to ship): the layout and
CRC_EXTRA are tested against pymavlink's own generator (``mavgen``) run on the XML.

Integration with the MAVLink adapter: with ``[mavlink] polarization`` its frame scanner
knows MSG_ID and CRC_EXTRA, checks the frame (and its signature, if signing is on) and
passes the payload to :func:`decode_payload`.  :func:`decode` checks a whole frame itself
(start marker, message id, length, CRC) for readers without such a scanner.

Time: ``time_usec`` is the sensor clock (same as the IMU) and becomes ``PolSample.t_us``;
``time_gps_usec`` (GPS time, no leap seconds) becomes ``utc_unix_s`` through the
leap-second table in :mod:`navd.core.sun` (``UTC = GPS - 18 s`` since 2017).
"""

from __future__ import annotations

import math
import struct
from collections.abc import MutableMapping
from pathlib import Path

from navd.core.sun import VALID_FROM_UNIX, gps_to_utc_unix
from navd.types import PolSample

__all__ = ["CRC_EXTRA", "DIALECT_XML", "MSG_ID", "crc_x25", "decode", "decode_payload",
           "reading_to_sample"]

MSG_ID = 44000
CRC_EXTRA = 76
PAYLOAD_LEN = 25  # <QQffB
DIALECT_XML = Path(__file__).with_name("navd_polarization.xml")

_STX_V2 = 0xFD
_HEADER_LEN = 10  # STX, len, incompat, compat, seq, sysid, compid, msgid (3)
_SIGNED = 0x01
_SIGNATURE_LEN = 13
_PAYLOAD = struct.Struct("<QQffB")


def crc_x25(data: bytes) -> int:
    """CRC-16/MCRF4XX (MAVLink's X.25 checksum)."""
    crc = 0xFFFF
    for b in data:
        tmp = b ^ (crc & 0xFF)
        tmp = (tmp ^ (tmp << 4)) & 0xFF
        crc = ((crc >> 8) ^ (tmp << 8) ^ (tmp << 3) ^ (tmp >> 4)) & 0xFFFF
    return crc


def _count(counters: MutableMapping[str, int] | None, reason: str) -> None:
    if counters is not None:
        counters[reason] = counters.get(reason, 0) + 1


def decode_payload(payload: bytes, recv_t_us: int = 0, *, use_receive_time: bool = False,
                   counters: MutableMapping[str, int] | None = None) -> PolSample | None:
    """The message payload (possibly truncated, MAVLink 2) -> PolSample, or None (counted).

    Refused (``counters[reason] += 1``): ``pol_wire_no_time`` (time_usec 0 without
    ``use_receive_time``), ``pol_wire_no_gps_time`` (time_gps_usec 0 or before 1972),
    ``pol_wire_bad_value`` (AoP not in [0, pi), DoP not in [0, 1], NaN).  Range checks are
    repeated in the estimator, which counts its own refusals.
    """
    if len(payload) > PAYLOAD_LEN:
        _count(counters, "pol_wire_bad_length")
        return None
    t_us, gps_us, aop, dop, _sensor = _PAYLOAD.unpack(payload.ljust(PAYLOAD_LEN, b"\x00"))
    out = reading_to_sample(recv_t_us if use_receive_time else t_us, gps_us, aop, dop)
    if isinstance(out, str):
        _count(counters, out)
        return None
    return out


def reading_to_sample(t_us: int, gps_us: int, aop: float, dop: float) -> PolSample | str:
    """Wire fields (any carrier) -> PolSample, or the refusal reason: ``pol_wire_no_time``
    (sensor time 0), ``pol_wire_no_gps_time`` (GPS time 0 or before 1972),
    ``pol_wire_bad_value`` (AoP not in [0, pi), DoP not in [0, 1], NaN)."""
    if t_us == 0:
        return "pol_wire_no_time"
    if gps_us == 0:
        return "pol_wire_no_gps_time"
    utc = gps_to_utc_unix(gps_us * 1e-6)
    if utc < VALID_FROM_UNIX:
        return "pol_wire_no_gps_time"
    if not (math.isfinite(aop) and 0.0 <= aop < math.pi and math.isfinite(dop)
            and 0.0 <= dop <= 1.0):
        return "pol_wire_bad_value"
    return PolSample(t_us=int(t_us), aop_rad=float(aop), dop=float(dop), utc_unix_s=utc)


def decode(frame: bytes, recv_t_us: int = 0, *, use_receive_time: bool = False,
           counters: MutableMapping[str, int] | None = None) -> PolSample | None:
    """One whole MAVLink 2 frame -> PolSample, or None when it is not a valid reading.

    Frames of other messages return None without counting anything, so the adapter can
    offer every unknown frame.  A frame of ours with a bad length or
    CRC counts ``pol_wire_bad_frame`` / ``pol_wire_bad_crc``.  Signed frames are accepted
    without checking the signature (navd does not sign its links).
    """
    if len(frame) < _HEADER_LEN + 2 or frame[0] != _STX_V2:
        return None
    plen = frame[1]
    msgid = frame[7] | (frame[8] << 8) | (frame[9] << 16)
    if msgid != MSG_ID:
        return None
    sig = _SIGNATURE_LEN if frame[2] & _SIGNED else 0
    if len(frame) != _HEADER_LEN + plen + 2 + sig or plen == 0:
        _count(counters, "pol_wire_bad_frame")
        return None
    body = frame[1:_HEADER_LEN + plen]
    crc = frame[_HEADER_LEN + plen] | (frame[_HEADER_LEN + plen + 1] << 8)
    if crc_x25(body + bytes([CRC_EXTRA])) != crc:
        _count(counters, "pol_wire_bad_crc")
        return None
    return decode_payload(frame[_HEADER_LEN:_HEADER_LEN + plen], recv_t_us,
                          use_receive_time=use_receive_time, counters=counters)
