"""Payload layouts of the messages navd reads, decoded straight from bytes.

Building a pymavlink message object per IMU sample (header tuple, field list, reordering,
an instance with a dozen attributes) was most of the daemon's per-packet cost (issue 18).
The layouts below are the MAVLink wire order (fields sorted by type size, largest first;
extension fields after, in declaration order) of common.xml; tests compare them with
pymavlink's generated code and decode random frames both ways.

MAVLink 2 cuts trailing zero bytes off a payload, and a newer sender may append extension
fields navd does not know: :func:`payload_fields` pads with zeros to the known length and
ignores what follows, as pymavlink does.
"""

from __future__ import annotations

import re
import struct
from typing import NamedTuple

from pymavlink.dialects.v20 import ardupilotmega as mavlink

__all__ = ["LAYOUTS", "Layout", "crc_extra_table", "fields_dict", "max_len_table",
           "payload_fields", "v1_lengths_table"]


class Layout(NamedTuple):
    name: str
    unpacker: struct.Struct
    fields: tuple[str, ...]  # wire order
    crc_extra: int


def _layout(name: str, msgid: int, crc_extra: int, fmt: str, fields: str) -> tuple[int, Layout]:
    names = tuple(fields.split())
    s = struct.Struct(fmt)
    if len(names) != len(s.unpack(bytes(s.size))):
        raise AssertionError(f"{name}: {len(names)} names for format {fmt}")
    return msgid, Layout(name, s, names, crc_extra)


_IMU3 = "xacc yacc zacc xgyro ygyro zgyro xmag ymag zmag"
LAYOUTS: dict[int, Layout] = dict((
    _layout("HEARTBEAT", 0, 50, "<I5B",
            "custom_mode type autopilot base_mode system_status mavlink_version"),
    _layout("HIGHRES_IMU", 105, 93, "<Q13fHB",
            f"time_usec {_IMU3} abs_pressure diff_pressure pressure_alt temperature "
            "fields_updated id"),
    _layout("RAW_IMU", 27, 144, "<Q9hBh", f"time_usec {_IMU3} id temperature"),
    _layout("SCALED_IMU", 26, 170, "<I10h", f"time_boot_ms {_IMU3} temperature"),
    _layout("SCALED_IMU2", 116, 76, "<I10h", f"time_boot_ms {_IMU3} temperature"),
    _layout("SCALED_IMU3", 129, 46, "<I10h", f"time_boot_ms {_IMU3} temperature"),
    _layout("GPS_RAW_INT", 24, 24, "<Q3i4H2Bi4IH",
            "time_usec lat lon alt eph epv vel cog fix_type satellites_visible "
            "alt_ellipsoid h_acc v_acc vel_acc hdg_acc yaw"),
    _layout("GPS_INPUT", 232, 151, "<QI2i9f2H3BH",
            "time_usec time_week_ms lat lon alt hdop vdop vn ve vd speed_accuracy "
            "horiz_accuracy vert_accuracy ignore_flags time_week gps_id fix_type "
            "satellites_visible yaw"),
    _layout("HIL_GPS", 113, 124, "<Q3i3H3hH3BH",
            "time_usec lat lon alt eph epv vel vn ve vd cog fix_type satellites_visible id "
            "yaw"),
))


def payload_fields(layout: Layout, payload: bytes) -> tuple[int | float, ...]:
    """The payload's fields in wire order (zero-padded / cut to the known length)."""
    size = layout.unpacker.size
    if len(payload) != size:
        payload = payload[:size].ljust(size, b"\x00")
    return layout.unpacker.unpack(payload)


def fields_dict(msgid: int, payload: bytes) -> dict[str, int | float]:
    """Field name -> value (for tests and diagnostics; the decoder unpacks tuples)."""
    lay = LAYOUTS[msgid]
    return dict(zip(lay.fields, payload_fields(lay, payload), strict=True))


def crc_extra_table() -> dict[int, int]:
    """Message id -> CRC_EXTRA of every ardupilotmega (superset of common) message."""
    return {msgid: cls.crc_extra for msgid, cls in mavlink.mavlink_map.items()}


def max_len_table() -> dict[int, int]:
    """Message id -> payload bytes with every extension field (what pymavlink sends)."""
    return {msgid: cls.unpacker.size for msgid, cls in mavlink.mavlink_map.items()}


def v1_lengths_table() -> dict[int, int]:
    """Message id (< 256) -> bit mask of the payload lengths a MAVLink 1 frame of it can have.

    MAVLink 1 never truncates: a sender puts the fields it knows, in wire order, whole.  The
    C library sends the fields without extensions, pymavlink all of them; both end on a field
    boundary, so bit L is set for every L at which a field (an array counts as one) ends.
    """
    out: dict[int, int] = {}
    for msgid, cls in mavlink.mavlink_map.items():
        if msgid > 255:
            continue
        mask, end = 0, 0
        for count, code in re.findall(r"(\d*)([A-Za-z])", cls.unpacker.format.lstrip("<")):
            end += struct.calcsize(f"<{count}{code}")
            mask |= 1 << end
        out[msgid] = mask
    return out
