"""navd outputs -> MAVLink 2 frames (common.xml messages only).

Outputs
    ATTITUDE, ATTITUDE_QUATERNION (q1..q4 = w, x, y, z of C_b^n), HEARTBEAT
    (MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID), GLOBAL_POSITION_INT (alt MSL mm =
    ellipsoid height - ``geoid_sep_m``; hdg cdeg 0..35999); for an autopilot
    (:mod:`navd.io.mavlink.autopilot` decides the contents): GPS_INPUT, COMMAND_LONG
    MAV_CMD_EXTERNAL_ATTITUDE_ESTIMATE, ESTIMATOR_STATUS.

Only frame building lives here; when and where frames go is :class:`navd.io.mavlink.link.
MavlinkSender`'s job, so the encoder can be tested and benchmarked without a socket.
"""

from __future__ import annotations

import math
import struct
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from navd.io.mavlink.frame import crc_x25
from navd.types import NavSolution

__all__ = ["MAV_CMD_EXTERNAL_ATTITUDE_ESTIMATE", "MavlinkEncoder"]

UINT16_MAX = 0xFFFF  # "unknown" in GLOBAL_POSITION_INT.hdg
# MAVLink development.xml (mavlink/mavlink PR #2334, 2025); pymavlink 2.4.x has no constant
MAV_CMD_EXTERNAL_ATTITUDE_ESTIMATE = 620


# The outputs sent at every output instant, packed here rather than through pymavlink's
# message objects (issue 18); tests/test_io_mavlink.py checks them byte for byte against it.
_HEADER_V2 = struct.Struct("<BBBBBBBHB")
_CRC = struct.Struct("<H")
_ATTITUDE = (mavlink.MAVLINK_MSG_ID_ATTITUDE, mavlink.MAVLink_attitude_message.crc_extra,
             mavlink.MAVLink_attitude_message.unpacker.pack)
_ATTITUDE_Q = (mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION,
               mavlink.MAVLink_attitude_quaternion_message.crc_extra,
               mavlink.MAVLink_attitude_quaternion_message.unpacker.pack)


def _clamp_int(x: float, lo: int, hi: int) -> int:
    if not math.isfinite(x):
        raise ValueError(f"cannot put non-finite {x!r} into an integer field")
    return max(lo, min(hi, round(x)))


class MavlinkEncoder:
    """Builds MAVLink 2 frames from navd outputs; owns the sequence counter of one source."""

    def __init__(
        self,
        sysid: int = 1,
        compid: int = mavlink.MAV_COMP_ID_ONBOARD_COMPUTER,
        geoid_sep_m: float = 0.0,
    ) -> None:
        if not (1 <= sysid <= 255 and 1 <= compid <= 255):
            raise ValueError(f"sysid/compid out of range: {sysid}/{compid}")
        self._mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self.geoid_sep_m = geoid_sep_m

    @property
    def sysid(self) -> int:
        return int(self._mav.srcSystem)

    @property
    def compid(self) -> int:
        return int(self._mav.srcComponent)

    def _pack(self, msg: Any) -> bytes:
        buf: bytes = msg.pack(self._mav)
        self._mav.seq = (self._mav.seq + 1) & 0xFF
        return buf

    def _frame(self, msgid: int, crc_extra: int, payload: bytes) -> bytes:
        """What pymavlink's MAVLink 2 ``pack`` makes of ``payload`` (trailing zero bytes cut,
        at least one kept; unsigned), with this source's ids and next sequence number."""
        mav = self._mav
        body = payload.rstrip(b"\x00") or payload[:1]
        seq = mav.seq
        frame = _HEADER_V2.pack(0xFD, len(body), 0, 0, seq, mav.srcSystem, mav.srcComponent,
                                msgid & 0xFFFF, msgid >> 16) + body
        mav.seq = (seq + 1) & 0xFF
        return frame + _CRC.pack(crc_x25(frame[1:], crc_extra))

    def encode_attitude(self, sol: NavSolution, time_boot_ms: int) -> bytes:
        p, q, r = sol.rate_b
        msgid, extra, pack = _ATTITUDE
        return self._frame(msgid, extra, pack(time_boot_ms & 0xFFFFFFFF, sol.roll_rad,
                                              sol.pitch_rad, sol.yaw_rad, p, q, r))

    def encode_attitude_quaternion(self, sol: NavSolution, time_boot_ms: int) -> bytes:
        w, x, y, z = sol.quat_nb
        p, q, r = sol.rate_b
        msgid, extra, pack = _ATTITUDE_Q
        return self._frame(msgid, extra, pack(time_boot_ms & 0xFFFFFFFF, w, x, y, z, p, q, r,
                                              1.0, 0.0, 0.0, 0.0))

    def encode_heartbeat(self, system_status: int = mavlink.MAV_STATE_ACTIVE) -> bytes:
        return self._pack(
            self._mav.heartbeat_encode(
                mavlink.MAV_TYPE_ONBOARD_CONTROLLER,
                mavlink.MAV_AUTOPILOT_INVALID,
                0,
                0,
                system_status,
            )
        )

    def encode_global_position_int(
        self, sol: NavSolution, time_boot_ms: int, home_alt_m: float | None = None
    ) -> bytes:
        """Raises ValueError if position or velocity is non-finite (integer fields)."""
        alt_msl_m = sol.alt_m - self.geoid_sep_m
        rel_m = alt_msl_m - home_alt_m if home_alt_m is not None else 0.0
        hdg = UINT16_MAX
        if math.isfinite(sol.yaw_rad):
            hdg = round(math.degrees(sol.yaw_rad) * 100.0) % 36000
        i32 = (-(2**31), 2**31 - 1)
        i16 = (-(2**15), 2**15 - 1)
        vn, ve, vd = sol.vel_n
        return self._pack(
            self._mav.global_position_int_encode(
                time_boot_ms & 0xFFFFFFFF,
                _clamp_int(math.degrees(sol.lat_rad) * 1e7, *i32),
                _clamp_int(math.degrees(sol.lon_rad) * 1e7, *i32),
                _clamp_int(alt_msl_m * 1e3, *i32),
                _clamp_int(rel_m * 1e3, *i32),
                _clamp_int(vn * 100.0, *i16),
                _clamp_int(ve * 100.0, *i16),
                _clamp_int(vd * 100.0, *i16),
                hdg,
            )
        )

    def encode_gps_input(
        self, *, time_usec: int, ignore_flags: int, fix_type: int, lat_deg: float,
        lon_deg: float, alt_msl_m: float, hdop: float, vdop: float,
        vel_n: tuple[float, float, float], speed_acc_mps: float, horiz_acc_m: float,
        vert_acc_m: float, satellites: int, yaw_cdeg: int,
    ) -> bytes:
        """GPS_INPUT (232).  ``yaw_cdeg``: 0 = no yaw, else 1..36000 (36000 = north), as
        ArduPilot's AP_GPS_MAV reads it.  Raises ValueError on non-finite lat/lon."""
        if not 0 <= yaw_cdeg <= 36000:
            raise ValueError(f"GPS_INPUT yaw {yaw_cdeg} cdeg outside 0..36000")
        i32 = (-(2**31), 2**31 - 1)
        return self._pack(
            self._mav.gps_input_encode(
                time_usec & 0xFFFFFFFFFFFFFFFF, 0, ignore_flags, 0, 0, fix_type,
                _clamp_int(lat_deg * 1e7, *i32), _clamp_int(lon_deg * 1e7, *i32),
                alt_msl_m, hdop, vdop, vel_n[0], vel_n[1], vel_n[2], speed_acc_mps,
                horiz_acc_m, vert_acc_m, satellites, yaw_cdeg,
            )
        )

    def encode_external_attitude_estimate(
        self, target_system: int, target_component: int, yaw_deg: float, yaw_acc_deg: float
    ) -> bytes:
        """COMMAND_LONG MAV_CMD_EXTERNAL_ATTITUDE_ESTIMATE with the heading only: param1/2
        (roll, pitch) and param4 (their accuracy) NaN = not given, param3 yaw deg from true
        north, param7 its 1-sigma in deg; param5/6 reserved (NaN)."""
        nan = math.nan
        return self._pack(
            self._mav.command_long_encode(
                target_system, target_component, MAV_CMD_EXTERNAL_ATTITUDE_ESTIMATE, 0,
                nan, nan, yaw_deg, nan, nan, nan, yaw_acc_deg,
            )
        )

    def encode_estimator_status(
        self, time_usec: int, flags: int, pos_horiz_acc_m: float, pos_vert_acc_m: float
    ) -> bytes:
        """ESTIMATOR_STATUS (230).  The innovation test ratios are not computed by navd and
        go out as NaN (a ratio of 0 would claim perfect agreement)."""
        nan = math.nan
        return self._pack(
            self._mav.estimator_status_encode(
                time_usec & 0xFFFFFFFFFFFFFFFF, flags, nan, nan, nan, nan, nan, nan,
                pos_horiz_acc_m, pos_vert_acc_m,
            )
        )
