"""MAVLink 2 adapter: wire bytes <-> navd.types, plus asyncio links (UDP, TCP, serial).

Decoding uses the ardupilotmega dialect (a superset of common) so an ArduPilot stream parses
without "unknown message" noise; everything emitted is from common.xml.

Inputs (all converted to SI, NED / FRD, integer microseconds)
    HIGHRES_IMU      m/s^2, rad/s, time_usec.  Used only if ``fields_updated`` has the six
                     accel+gyro bits (PX4 repeats stale values with the bit cleared).
    SCALED_IMU(2,3)  mG and mrad/s in int16 (saturates at ±32.767 g / ±32.767 rad/s),
                     time_boot_ms (uint32 ms, unwrapped here at its 49.7-day wrap).
    RAW_IMU          int16 counts; needs ``raw_gyro_rps_per_lsb`` / ``raw_accel_mps2_per_lsb``.
                     ArduPilot actually fills it with mG / mrad/s, i.e. scales
                     9.80665e-3 and 1e-3; without configured scales it is rejected.
    GPS_RAW_INT      lat/lon degE7; ``alt`` is MSL mm, ``alt_ellipsoid`` (extension, 0 when
                     absent) is used when present, else MSL + ``geoid_sep_m``; vel cm/s and
                     cog cdeg give NED north/east; there is no vertical velocity, so
                     ``vel_d`` is NaN; h_acc/v_acc mm, vel_acc mm/s (0 = unknown);
                     eph/epv are DOP x 100, not metres (fallback: DOP x ``uere_m``).
    GPS_INPUT        lat/lon degE7, ``alt`` MSL in m (float!), vn/ve/vd m/s, accuracies m and
                     m/s, hdop/vdop unitless (not x100); honours ``ignore_flags``.
    HIL_GPS          lat/lon degE7, alt MSL mm, vn/ve/vd cm/s (int16), eph/epv DOP x 100.
    Components not on the wire (GPS_RAW_INT vertical velocity, ignored GPS_INPUT fields,
    unknown cog/speed) are NaN in GnssSample: consumers must skip non-finite components.
    A fix repeating the previous time stamp of its source is dropped (ArduPilot re-sends
    the last fix when GPS_RAW_INT streams faster than the receiver updates).
    Rate-type IMU messages become increments in :class:`navd.io.common.RateIntegrator`.

Outputs
    ATTITUDE, ATTITUDE_QUATERNION (q1..q4 = w, x, y, z of C_b^n), HEARTBEAT
    (MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID), GLOBAL_POSITION_INT (alt MSL mm =
    ellipsoid height - ``geoid_sep_m``; hdg cdeg 0..35999).

Links (pymavlink connection-string syntax)
    ``udpin:HOST:PORT`` / ``udp:HOST:PORT`` listen (replies go to the last sender),
    ``udpout:HOST:PORT`` send (and receive replies), ``tcp:HOST:PORT`` client,
    ``/dev/ttyUSB0,921600`` serial (termios raw 8N1, no flow control; no pyserial needed).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import os
import socket
import termios
import tty
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any, Literal, cast

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from navd.diag import Counters, RateLimitedLog
from navd.io.common import (
    Limits,
    RateIntegrator,
    Rejector,
    Sample,
    SampleCallback,
    all_finite,
    gnss_reject_reason,
    imu_reject_reason,
    monotonic_us,
)
from navd.types import FixType, GnssSample, ImuSample, NavSolution, PolSample
from navd.units import DEG
from navd.units import G0 as G0_MPS2

__all__ = [
    "MavlinkDecoder",
    "MavlinkEncoder",
    "MavlinkInputConfig",
    "MavlinkLink",
    "MavlinkSender",
    "MavlinkStreamProtocol",
    "MavlinkUdpProtocol",
    "open_mavlink",
    "parse_mavlink_url",
]

_log = logging.getLogger(__name__)

UINT16_MAX = 0xFFFF
_HIGHRES_ACC_GYRO = 0x3F  # HIGHRES_IMU_UPDATED_{X,Y,Z}ACC | {X,Y,Z}GYRO
_GPS_FIX = {
    mavlink.GPS_FIX_TYPE_3D_FIX: FixType.FIX_3D,
    mavlink.GPS_FIX_TYPE_DGPS: FixType.DGPS,
    mavlink.GPS_FIX_TYPE_RTK_FLOAT: FixType.RTK_FLOAT,
    mavlink.GPS_FIX_TYPE_RTK_FIXED: FixType.RTK_FIXED,
    mavlink.GPS_FIX_TYPE_STATIC: FixType.FIX_3D,
    mavlink.GPS_FIX_TYPE_PPP: FixType.DGPS,
}
IMU_MESSAGES = frozenset({"HIGHRES_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3", "RAW_IMU"})
GNSS_MESSAGES = frozenset({"GPS_RAW_INT", "GPS_INPUT", "HIL_GPS"})


@dataclass(frozen=True)
class MavlinkInputConfig:
    """Decoder settings, SI units.

    imu_messages / gnss_messages: which message types feed the estimator.  An autopilot
        often streams several IMU messages for the same sensor; accepting two of them
        would integrate the same motion twice, so pick one.
    imu_id: IMU instance (HIGHRES_IMU/RAW_IMU ``id``; SCALED_IMU=0, SCALED_IMU2=1,
        SCALED_IMU3=2); None accepts all, which is only right with a single IMU.
    gnss_id: GPS_INPUT ``gps_id`` / HIL_GPS ``id``; None accepts all.
    allow: accepted (sysid, compid) sources; None accepts any.
    nominal_imu_rate_hz: interval given to the first sample after start or a gap; None
        drops that sample instead.
    geoid_sep_m: geoid undulation N = h_ellipsoid - H_msl, used where only MSL is sent.
    use_receive_time: stamp samples with the local receive clock instead of the sensor time
        (for senders whose time fields are zero or unrelated between IMU and GNSS).
    polarization: also accept navd's NAVD_SKY_POLARIZATION (private dialect, id 44000,
        :mod:`navd.io.pol_wire`) as PolSample.
    """

    imu_messages: frozenset[str] = frozenset({"HIGHRES_IMU"})
    gnss_messages: frozenset[str] = frozenset({"GPS_INPUT"})
    imu_id: int | None = 0
    gnss_id: int | None = 0
    allow: frozenset[tuple[int, int]] | None = None
    nominal_imu_rate_hz: float | None = None
    max_imu_gap_s: float = 0.1
    require_fields_updated: bool = True
    raw_gyro_rps_per_lsb: float | None = None
    raw_accel_mps2_per_lsb: float | None = None
    geoid_sep_m: float = 0.0
    uere_m: float = 3.0
    default_h_acc_m: float = 5.0
    default_v_acc_m: float = 10.0
    default_vel_acc_mps: float = 0.5
    use_receive_time: bool = False
    polarization: bool = False
    limits: Limits = field(default_factory=Limits)

    def __post_init__(self) -> None:
        bad = (self.imu_messages - IMU_MESSAGES) | (self.gnss_messages - GNSS_MESSAGES)
        if bad:
            raise ValueError(f"unsupported MAVLink input message(s): {sorted(bad)}")
        if self.nominal_imu_rate_hz is not None and not self.nominal_imu_rate_hz > 0.0:
            raise ValueError("nominal_imu_rate_hz must be > 0")
        if not self.max_imu_gap_s > 0.0:
            raise ValueError("max_imu_gap_s must be > 0")


class _MsUnwrapper:
    """Extends uint32 millisecond stamps past their wrap so t_us stays monotonic."""

    __slots__ = ("_state",)

    def __init__(self) -> None:
        self._state: dict[tuple[int, int, int], tuple[int, int]] = {}

    def us(self, key: tuple[int, int, int], ms: int) -> int:
        last, offset = self._state.get(key, (ms, 0))
        # Only a big backwards step is a wrap; a small one is a reboot or reorder and must
        # reach the integrator as "time went back".
        if ms < last and last - ms > 0x8000_0000:
            offset += 0x1_0000_0000
        self._state[key] = (ms, offset)
        return (ms + offset) * 1000


class MavlinkDecoder:
    """Non-blocking MAVLink parser producing navd samples; never raises on wire input.

    ``feed`` treats input as a byte stream (serial, TCP): a frame may span calls.
    ``feed_datagram`` is for UDP, where a frame never spans datagrams, so a partial frame
    left at the end is dropped (counted) instead of corrupting the next datagram.
    """

    def __init__(
        self,
        config: MavlinkInputConfig | None = None,
        counters: Counters | None = None,
        log: RateLimitedLog | None = None,
    ) -> None:
        self.config = config if config is not None else MavlinkInputConfig()
        self._reject = Rejector.create(__name__, "mavlink", counters, log)
        self.counters = self._reject.counters
        self._mav = self._new_parser()
        cfg = self.config
        nominal = (
            round(1e6 / cfg.nominal_imu_rate_hz) if cfg.nominal_imu_rate_hz is not None else None
        )
        self._imu = RateIntegrator(self._reject, nominal, round(cfg.max_imu_gap_s * 1e6))
        self._ms = _MsUnwrapper()
        self._last_seq: dict[tuple[int, int], int] = {}
        self._last_gnss_t_us: dict[tuple[int, int, int], int] = {}
        self._handlers: dict[int, Callable[[Any, int], Sample | None]] = {}
        for name in cfg.imu_messages | cfg.gnss_messages:
            self._handlers[getattr(mavlink, f"MAVLINK_MSG_ID_{name}")] = getattr(
                self, f"_on_{name.lower()}"
            )

    @staticmethod
    def _new_parser() -> Any:
        mav = mavlink.MAVLink(None)
        mav.robust_parsing = True
        return mav

    def reset(self) -> None:
        """Forget partial frames and IMU time lines (e.g. after a link reconnect)."""
        self._mav = self._new_parser()
        self._imu.reset()

    # -- byte input ---------------------------------------------------------------------------

    def feed(self, data: bytes, recv_t_us: int) -> list[Sample]:
        out: list[Sample] = []
        try:
            m = self._mav.parse_char(data)
            while m is not None:
                s = self._on_message(m, recv_t_us)
                if s is not None:
                    out.append(s)
                m = self._mav.parse_char(b"")
        except Exception as exc:  # wire input must never kill the daemon
            self._reject("parser_error", "%s: %s", type(exc).__name__, exc)
            self._mav = self._new_parser()
        return out

    def feed_datagram(self, data: bytes, recv_t_us: int) -> list[Sample]:
        # Fast path for the common case at kHz IMU rates: the datagram is exactly one
        # unsigned MAVLink 2 frame of a message we use.  pymavlink's frame decoder checks it
        # (CRC included) without the byte-stream machinery, a quarter of the cost per frame.
        # Anything else, or any error, takes the robust stream path, which counts it.
        if (len(data) > 11 and data[0] == 0xFD and len(data) == data[1] + 12
                and not data[2] & 0x01
                and (data[7] | data[8] << 8 | data[9] << 16) in self._handlers):
            try:
                m = self._mav.decode(bytearray(data))
            except Exception:  # the robust path below counts and reports it
                pass
            else:
                s = self._on_message(m, recv_t_us)
                return [] if s is None else [s]
        out = self.feed(data, recv_t_us)
        counted = False
        while self._mav.buf_len() > 0:
            # The parser is waiting for the rest of a frame that will never come.  Good
            # frames may sit behind its (truncated) start: rescan from the next byte.
            rest = bytes(self._mav.buf[self._mav.buf_index + 1 :])
            if not counted:
                self._reject("truncated", "partial frame at datagram end (%d bytes)", len(rest) + 1)
                counted = True
            self._mav = self._new_parser()
            out += self.feed(rest, recv_t_us)
        return out

    def _on_message(self, m: Any, recv_t_us: int) -> Sample | None:
        msgid: int = m.get_msgId()
        if msgid == mavlink.MAVLINK_MSG_ID_BAD_DATA:
            self._on_bad_data(m)
            return None
        if msgid == mavlink.MAVLINK_MSG_ID_UNKNOWN:
            if self.config.polarization:
                pol = self._polarization(bytes(m.data), recv_t_us)
                if pol is not False:
                    return pol
            # Without the message's CRC_EXTRA pymavlink cannot check the CRC, so this may be
            # noise whose fake header swallowed the start of a real frame.  Rescan it.
            self.counters.inc("unknown_msgid")
            self._rescan(bytes(m.data))
            return None
        src = (m.get_srcSystem(), m.get_srcComponent())
        self.counters.inc("frames_ok")
        self._track_seq(src, m.get_seq())
        handler = self._handlers.get(msgid)
        if handler is None:
            self.counters.inc("ignored")
            return None
        if self.config.allow is not None and src not in self.config.allow:
            self._reject("not_allowed", "source sysid=%d compid=%d", *src)
            return None
        try:
            sample = handler(m, recv_t_us)
        except (TypeError, ValueError, OverflowError) as exc:
            self._reject("decode_error", "%s: %s", m.get_type(), exc)
            return None
        if sample is None:
            return None
        if isinstance(sample, ImuSample):
            self.counters.inc("imu_ok")
            return sample
        # ArduPilot streams GPS_RAW_INT faster than many receivers update and repeats the
        # last fix, time stamp included; a repeat is no new information.
        key = (src[0], src[1], msgid)
        if self._last_gnss_t_us.get(key) == sample.t_us:
            self.counters.inc("gnss_repeat")
            return None
        self._last_gnss_t_us[key] = sample.t_us
        self.counters.inc("gnss_ok")
        return sample

    def _polarization(self, frame: bytes, recv_t_us: int) -> PolSample | Literal[False] | None:
        """NAVD_SKY_POLARIZATION -> PolSample; None if it is ours but refused (counted);
        False if the frame is not ours, or ours with a bad CRC (then it may be noise)."""
        from navd.io import pol_wire

        why: dict[str, int] = {}
        s = pol_wire.decode(frame, recv_t_us, use_receive_time=self.config.use_receive_time,
                            counters=why)
        if s is None and not why:
            return False
        src = (frame[5], frame[6]) if len(frame) > 6 else (0, 0)
        if s is not None:
            self.counters.inc("frames_ok")
            if self.config.allow is not None and src not in self.config.allow:
                self._reject("not_allowed", "source sysid=%d compid=%d", *src)
                return None
            self.counters.inc("pol_ok")
            return s
        for reason in why:
            self._reject(reason, "NAVD_SKY_POLARIZATION from sysid=%d compid=%d", *src)
        return False if "pol_wire_bad_crc" in why or "pol_wire_bad_frame" in why else None

    def _on_bad_data(self, m: Any) -> None:
        reason: str = m.reason
        if reason == "Bad prefix":
            self._reject("bad_prefix", "%d junk bytes", len(m.data))
            return
        if "CRC" in reason:
            self._reject("bad_crc", "%s", reason)
        else:
            self._reject("bad_frame", "%s", reason)
        self._rescan(bytes(m.data))

    def _rescan(self, frame: bytes) -> None:
        """Put a rejected frame, minus its start marker, back in front of the parser buffer.

        pymavlink skips the whole length a broken header announced; on a serial link that
        swallows the good frames behind a lost byte, and noise that looks like a header
        eats the start of the next real frame.
        """
        if len(frame) > 1:
            mav = self._mav
            mav.buf = bytearray(frame[1:]) + mav.buf[mav.buf_index :]
            mav.buf_index = 0
            mav.expected_length = mavlink.HEADER_LEN_V1 + 2

    def _track_seq(self, src: tuple[int, int], seq: int) -> None:
        last = self._last_seq.get(src)
        self._last_seq[src] = seq
        if last is not None:
            lost = (seq - last - 1) & 0xFF
            # A huge "loss" is a restart or a duplicate, not 200+ dropped frames.
            if 0 < lost < 128:
                self.counters.inc("seq_lost", lost)

    # -- helpers ------------------------------------------------------------------------------

    def _stamp(self, sensor_t_us: int, recv_t_us: int, what: str) -> int | None:
        if self.config.use_receive_time:
            return recv_t_us
        if sensor_t_us <= 0:
            self._reject(f"{what}_no_timestamp", "sensor time is zero; set use_receive_time")
            return None
        return sensor_t_us

    def _imu_sample(
        self,
        key: tuple[int, int, int, int],
        t_us: int | None,
        gyro: tuple[float, float, float],
        accel: tuple[float, float, float],
    ) -> ImuSample | None:
        if t_us is None:
            return None
        reason = imu_reject_reason(*gyro, *accel, self.config.limits)
        if reason is not None:
            # Rejecting before the time line advances lets the next good sample cover the
            # gap by zero-order hold instead of losing the interval.
            self._reject(reason, "gyro=%s accel=%s", gyro, accel)
            return None
        return self._imu.push(key, t_us, gyro, accel)

    def _imu_id_ok(self, imu_id: int) -> bool:
        want = self.config.imu_id
        if want is not None and imu_id != want:
            self.counters.inc("imu_other_instance")
            return False
        return True

    def _gnss_id_ok(self, gps_id: int) -> bool:
        want = self.config.gnss_id
        if want is not None and gps_id != want:
            self.counters.inc("gnss_other_instance")
            return False
        return True

    def _acc_or(self, acc_m: float, dop: float | None, default: float) -> float:
        """Receiver accuracy if given, else DOP x UERE, else the configured default."""
        if math.isfinite(acc_m) and acc_m > 0.0:
            return acc_m
        if dop is not None and math.isfinite(dop) and 0.0 < dop < 99.0:
            return dop * self.config.uere_m
        return default

    def _gnss_sample(
        self,
        t_us: int | None,
        fix_type: int,
        lat_e7: int,
        lon_e7: int,
        alt_m: float,
        vel: tuple[float, float, float],
        h_acc_m: float,
        v_acc_m: float,
        vel_acc_mps: float,
    ) -> GnssSample | None:
        if t_us is None:
            return None
        fix = _GPS_FIX.get(fix_type)
        if fix is None:
            self._reject("gnss_no_fix", "fix_type=%d", fix_type)
            return None
        lat_deg = lat_e7 * 1e-7
        lon_deg = lon_e7 * 1e-7
        reason = gnss_reject_reason(lat_deg, lon_deg, alt_m, vel, self.config.limits)
        if reason is not None:
            self._reject(reason, "lat=%r lon=%r alt=%r vel=%r", lat_deg, lon_deg, alt_m, vel)
            return None
        return GnssSample(
            t_us=t_us,
            lat_rad=lat_deg * DEG,
            lon_rad=lon_deg * DEG,
            alt_m=alt_m,
            vel_n=vel[0],
            vel_e=vel[1],
            vel_d=vel[2],
            h_acc_m=h_acc_m,
            v_acc_m=v_acc_m,
            vel_acc_mps=vel_acc_mps,
            fix_type=fix,
        )

    # -- IMU messages -------------------------------------------------------------------------

    def _on_highres_imu(self, m: Any, recv_t_us: int) -> ImuSample | None:
        if not self._imu_id_ok(m.id):
            return None
        if (
            self.config.require_fields_updated
            and (m.fields_updated & _HIGHRES_ACC_GYRO) != _HIGHRES_ACC_GYRO
        ):
            self.counters.inc("imu_fields_not_updated")
            return None
        t_us = self._stamp(m.time_usec, recv_t_us, "imu")
        key = (m.get_srcSystem(), m.get_srcComponent(), mavlink.MAVLINK_MSG_ID_HIGHRES_IMU, m.id)
        return self._imu_sample(
            key, t_us, (m.xgyro, m.ygyro, m.zgyro), (m.xacc, m.yacc, m.zacc)
        )

    def _scaled(self, m: Any, recv_t_us: int, msgid: int, instance: int) -> ImuSample | None:
        if not self._imu_id_ok(instance):
            return None
        key = (m.get_srcSystem(), m.get_srcComponent(), msgid, instance)
        t_us = self._stamp(self._ms.us(key[:3], m.time_boot_ms), recv_t_us, "imu")
        g = 1e-3  # mrad/s -> rad/s
        a = G0_MPS2 * 1e-3  # mG -> m/s^2
        return self._imu_sample(
            key,
            t_us,
            (m.xgyro * g, m.ygyro * g, m.zgyro * g),
            (m.xacc * a, m.yacc * a, m.zacc * a),
        )

    def _on_scaled_imu(self, m: Any, recv_t_us: int) -> ImuSample | None:
        return self._scaled(m, recv_t_us, mavlink.MAVLINK_MSG_ID_SCALED_IMU, 0)

    def _on_scaled_imu2(self, m: Any, recv_t_us: int) -> ImuSample | None:
        return self._scaled(m, recv_t_us, mavlink.MAVLINK_MSG_ID_SCALED_IMU2, 1)

    def _on_scaled_imu3(self, m: Any, recv_t_us: int) -> ImuSample | None:
        return self._scaled(m, recv_t_us, mavlink.MAVLINK_MSG_ID_SCALED_IMU3, 2)

    def _on_raw_imu(self, m: Any, recv_t_us: int) -> ImuSample | None:
        g = self.config.raw_gyro_rps_per_lsb
        a = self.config.raw_accel_mps2_per_lsb
        if g is None or a is None:
            self._reject("raw_imu_unscaled", "RAW_IMU needs raw_*_per_lsb scales in config")
            return None
        if not self._imu_id_ok(m.id):
            return None
        t_us = self._stamp(m.time_usec, recv_t_us, "imu")
        key = (m.get_srcSystem(), m.get_srcComponent(), mavlink.MAVLINK_MSG_ID_RAW_IMU, m.id)
        return self._imu_sample(
            key,
            t_us,
            (m.xgyro * g, m.ygyro * g, m.zgyro * g),
            (m.xacc * a, m.yacc * a, m.zacc * a),
        )

    # -- GNSS messages ------------------------------------------------------------------------

    def _on_gps_raw_int(self, m: Any, recv_t_us: int) -> GnssSample | None:
        cfg = self.config
        t_us = self._stamp(m.time_usec, recv_t_us, "gnss")
        if m.alt_ellipsoid != 0:
            alt_m = m.alt_ellipsoid * 1e-3
        else:
            # 0 is what an absent MAVLink 2 extension decodes to.
            alt_m = m.alt * 1e-3 + cfg.geoid_sep_m
            self.counters.inc("gnss_alt_from_msl")
        if m.vel != UINT16_MAX and m.cog != UINT16_MAX:
            speed = m.vel * 1e-2
            cog = m.cog * 1e-2 * DEG
            vel = (speed * math.cos(cog), speed * math.sin(cog), math.nan)
        else:
            vel = (math.nan, math.nan, math.nan)
        eph = m.eph * 1e-2 if m.eph != UINT16_MAX else None
        epv = m.epv * 1e-2 if m.epv != UINT16_MAX else None
        return self._gnss_sample(
            t_us,
            m.fix_type,
            m.lat,
            m.lon,
            alt_m,
            vel,
            self._acc_or(m.h_acc * 1e-3, eph, cfg.default_h_acc_m),
            self._acc_or(m.v_acc * 1e-3, epv, cfg.default_v_acc_m),
            self._acc_or(m.vel_acc * 1e-3, None, cfg.default_vel_acc_mps),
        )

    def _on_gps_input(self, m: Any, recv_t_us: int) -> GnssSample | None:
        if not self._gnss_id_ok(m.gps_id):
            return None
        cfg = self.config
        ign: int = m.ignore_flags

        def used(flag: int, value: float) -> float:
            return math.nan if ign & flag else value

        alt = used(mavlink.GPS_INPUT_IGNORE_FLAG_ALT, m.alt)
        vn = used(mavlink.GPS_INPUT_IGNORE_FLAG_VEL_HORIZ, m.vn)
        ve = used(mavlink.GPS_INPUT_IGNORE_FLAG_VEL_HORIZ, m.ve)
        vd = used(mavlink.GPS_INPUT_IGNORE_FLAG_VEL_VERT, m.vd)
        hacc = used(mavlink.GPS_INPUT_IGNORE_FLAG_HORIZONTAL_ACCURACY, m.horiz_accuracy)
        vacc = used(mavlink.GPS_INPUT_IGNORE_FLAG_VERTICAL_ACCURACY, m.vert_accuracy)
        sacc = used(mavlink.GPS_INPUT_IGNORE_FLAG_SPEED_ACCURACY, m.speed_accuracy)
        hdop = used(mavlink.GPS_INPUT_IGNORE_FLAG_HDOP, m.hdop)
        vdop = used(mavlink.GPS_INPUT_IGNORE_FLAG_VDOP, m.vdop)
        # NaN from an ignore flag is intended; NaN/Inf in a field the sender vouches for
        # is a broken sender.
        vouched = [
            v
            for v, f in (
                (m.alt, mavlink.GPS_INPUT_IGNORE_FLAG_ALT),
                (m.vn, mavlink.GPS_INPUT_IGNORE_FLAG_VEL_HORIZ),
                (m.ve, mavlink.GPS_INPUT_IGNORE_FLAG_VEL_HORIZ),
                (m.vd, mavlink.GPS_INPUT_IGNORE_FLAG_VEL_VERT),
                (m.horiz_accuracy, mavlink.GPS_INPUT_IGNORE_FLAG_HORIZONTAL_ACCURACY),
                (m.vert_accuracy, mavlink.GPS_INPUT_IGNORE_FLAG_VERTICAL_ACCURACY),
                (m.speed_accuracy, mavlink.GPS_INPUT_IGNORE_FLAG_SPEED_ACCURACY),
            )
            if not ign & f
        ]
        if not all_finite(*vouched):
            self._reject("gnss_nonfinite", "GPS_INPUT field is NaN/Inf")
            return None
        if math.isnan(alt):
            self._reject("gnss_no_alt", "GPS_INPUT with ALT ignored")
            return None
        t_us = self._stamp(m.time_usec, recv_t_us, "gnss")
        return self._gnss_sample(
            t_us,
            m.fix_type,
            m.lat,
            m.lon,
            alt + cfg.geoid_sep_m,
            (vn, ve, vd),
            self._acc_or(hacc, hdop, cfg.default_h_acc_m),
            self._acc_or(vacc, vdop, cfg.default_v_acc_m),
            self._acc_or(sacc, None, cfg.default_vel_acc_mps),
        )

    def _on_hil_gps(self, m: Any, recv_t_us: int) -> GnssSample | None:
        if not self._gnss_id_ok(m.id):
            return None
        cfg = self.config
        t_us = self._stamp(m.time_usec, recv_t_us, "gnss")
        eph = m.eph * 1e-2 if m.eph != UINT16_MAX else None
        epv = m.epv * 1e-2 if m.epv != UINT16_MAX else None
        return self._gnss_sample(
            t_us,
            m.fix_type,
            m.lat,
            m.lon,
            m.alt * 1e-3 + cfg.geoid_sep_m,
            (m.vn * 1e-2, m.ve * 1e-2, m.vd * 1e-2),
            self._acc_or(math.nan, eph, cfg.default_h_acc_m),
            self._acc_or(math.nan, epv, cfg.default_v_acc_m),
            cfg.default_vel_acc_mps,
        )


# -- encoders ---------------------------------------------------------------------------------


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

    def encode_attitude(self, sol: NavSolution, time_boot_ms: int) -> bytes:
        p, q, r = sol.rate_b
        return self._pack(
            self._mav.attitude_encode(
                time_boot_ms & 0xFFFFFFFF, sol.roll_rad, sol.pitch_rad, sol.yaw_rad, p, q, r
            )
        )

    def encode_attitude_quaternion(self, sol: NavSolution, time_boot_ms: int) -> bytes:
        w, x, y, z = sol.quat_nb
        p, q, r = sol.rate_b
        return self._pack(
            self._mav.attitude_quaternion_encode(
                time_boot_ms & 0xFFFFFFFF, w, x, y, z, p, q, r, (1.0, 0.0, 0.0, 0.0)
            )
        )

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


# -- asyncio links ----------------------------------------------------------------------------


@dataclass(frozen=True)
class LinkAddress:
    kind: str  # "udpin" | "udpout" | "tcp" | "serial"
    host: str = ""
    port: int = 0
    device: str = ""
    baud: int = 115200


def parse_mavlink_url(url: str) -> LinkAddress:
    """Parse pymavlink-style connection strings (see module docstring)."""
    # pymavlink: a bare "udp:" listens, like "udpin:".
    kinds = (("udpin:", "udpin"), ("udp:", "udpin"), ("udpout:", "udpout"), ("tcp:", "tcp"))
    for prefix, kind in kinds:
        if url.startswith(prefix):
            host, sep, port = url[len(prefix) :].rpartition(":")
            if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
                raise ValueError(f"bad MAVLink address {url!r}: want {prefix}HOST:PORT")
            return LinkAddress(kind, host=host, port=int(port))
    if url.startswith("/"):
        device, _, baud = url.partition(",")
        if baud and not baud.isdigit():
            raise ValueError(f"bad serial baud in {url!r}")
        return LinkAddress("serial", device=device, baud=int(baud) if baud else 115200)
    raise ValueError(f"unsupported MAVLink address {url!r}")


class _Delivering:
    """What both MAVLink protocols share: a decoder, a sample callback and a clock."""

    def __init__(
        self,
        decoder: MavlinkDecoder | None,
        on_sample: SampleCallback | None,
        clock_us: Callable[[], int] = monotonic_us,
    ) -> None:
        self.decoder = decoder
        self.on_sample = on_sample
        self.clock_us = clock_us
        self.counters = decoder.counters if decoder is not None else Counters()
        self._init_link()

    def _init_link(self) -> None:
        """The transport-specific state."""

    def _deliver(self, samples: Iterable[Sample]) -> None:
        if self.on_sample is not None:
            for s in samples:
                self.on_sample(s)


class MavlinkUdpProtocol(_Delivering, asyncio.DatagramProtocol):
    """Decodes each datagram and hands samples to ``on_sample`` on the event loop."""

    def _init_link(self) -> None:
        self.transport: asyncio.DatagramTransport | None = None
        self.last_peer: tuple[Any, ...] | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        # The selector loop's datagram transport does not subclass asyncio.DatagramTransport
        # (CPython 3.11), so an isinstance check here would fail on every open.
        self.transport = cast(asyncio.DatagramTransport, transport)

    def datagram_received(self, data: bytes, addr: tuple[Any, ...]) -> None:
        self.last_peer = addr
        if self.decoder is not None:
            self._deliver(self.decoder.feed_datagram(data, self.clock_us()))

    def error_received(self, exc: Exception) -> None:
        # ICMP port-unreachable on a connected udpout socket lands here; the link lives on.
        self.counters.inc("link_error")
        _log.debug("MAVLink UDP error: %s", exc)


class MavlinkStreamProtocol(_Delivering, asyncio.Protocol):
    """Byte-stream twin of :class:`MavlinkUdpProtocol` for TCP and serial."""

    def _init_link(self) -> None:
        self.closed: asyncio.Future[None] = asyncio.get_running_loop().create_future()

    def data_received(self, data: bytes) -> None:
        if self.decoder is not None:
            self._deliver(self.decoder.feed(data, self.clock_us()))

    def eof_received(self) -> bool | None:
        return None

    def connection_lost(self, exc: Exception | None) -> None:
        if exc is not None:
            self.counters.inc("link_error")
            _log.warning("MAVLink stream closed: %s", exc)
        if not self.closed.done():
            self.closed.set_result(None)


class _WriteOnlyProtocol(asyncio.BaseProtocol):
    pass


_SERIAL_SPEEDS = {
    b: getattr(termios, f"B{b}")
    for b in (9600, 19200, 38400, 57600, 115200, 230400, 460800, 500000, 921600, 1000000,
              1500000, 2000000, 3000000)
    if hasattr(termios, f"B{b}")
}


def _configure_serial(fd: int, baud: int) -> None:
    """Raw 8N1, no flow control, no modem control: a plain telemetry UART."""
    speed = _SERIAL_SPEEDS.get(baud)
    if speed is None:
        raise ValueError(f"unsupported baud rate {baud}; choose one of {sorted(_SERIAL_SPEEDS)}")
    tty.setraw(fd)
    attrs = termios.tcgetattr(fd)
    attrs[2] = (attrs[2] & ~(termios.CSIZE | termios.PARENB | termios.CSTOPB | termios.CRTSCTS)) | (
        termios.CS8 | termios.CLOCAL | termios.CREAD
    )
    attrs[4] = speed
    attrs[5] = speed
    termios.tcsetattr(fd, termios.TCSANOW, attrs)
    termios.tcflush(fd, termios.TCIOFLUSH)


class MavlinkLink:
    """One open MAVLink link: decodes what arrives, writes what is sent, never blocks.

    Open with :meth:`open`.  ``send`` queues bytes on the transport; when a stream's write
    buffer exceeds ``max_tx_buffer`` (stuck UART, slow TCP peer) frames are dropped and
    counted rather than letting memory grow.
    """

    def __init__(self, address: LinkAddress, counters: Counters, max_tx_buffer: int) -> None:
        self.address = address
        self.counters = counters
        self.max_tx_buffer = max_tx_buffer
        self._udp: MavlinkUdpProtocol | None = None
        self._udp_transport: asyncio.DatagramTransport | None = None
        self._rx_transport: asyncio.BaseTransport | None = None
        self._tx_transport: asyncio.WriteTransport | None = None
        self._decoder: MavlinkDecoder | None = None
        self._on_sample: SampleCallback | None = None
        self._clock_us: Callable[[], int] = monotonic_us
        self._closing = False
        self._watch: asyncio.Task[None] | None = None
        self.reconnect_delays_s: tuple[float, ...] = (0.5, 1.0, 2.0, 5.0)

    @classmethod
    async def open(
        cls,
        url: str,
        decoder: MavlinkDecoder | None = None,
        on_sample: SampleCallback | None = None,
        *,
        clock_us: Callable[[], int] = monotonic_us,
        max_tx_buffer: int = 64 * 1024,
    ) -> MavlinkLink:
        addr = parse_mavlink_url(url)
        loop = asyncio.get_running_loop()
        counters = decoder.counters if decoder is not None else Counters()
        link = cls(addr, counters, max_tx_buffer)
        if addr.kind in ("udpin", "udpout"):
            proto = MavlinkUdpProtocol(decoder, on_sample, clock_us)
            kw: dict[str, Any] = (
                {"local_addr": (addr.host, addr.port)}
                if addr.kind == "udpin"
                else {"remote_addr": (addr.host, addr.port)}
            )
            transport, _ = await loop.create_datagram_endpoint(lambda: proto, **kw)
            link._udp = proto
            link._udp_transport = transport
        else:
            link._decoder, link._on_sample, link._clock_us = decoder, on_sample, clock_us
            sproto = await link._open_stream()
            link._watch = loop.create_task(link._keep_open(sproto), name=f"mavlink {url}")
        return link

    async def _open_stream(self) -> MavlinkStreamProtocol:
        """Connect a TCP or serial link; the transports replace any previous ones."""
        addr = self.address
        loop = asyncio.get_running_loop()
        sproto = MavlinkStreamProtocol(self._decoder, self._on_sample, self._clock_us)
        if addr.kind == "tcp":
            transport2, _ = await loop.create_connection(lambda: sproto, addr.host, addr.port)
            self._rx_transport = transport2
            self._tx_transport = transport2
            return sproto
        fd = os.open(addr.device, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        try:
            _configure_serial(fd, addr.baud)
            wfd = os.dup(fd)
        except BaseException:
            os.close(fd)
            raise
        # Two file objects on one tty: asyncio's pipe transports each own (and close)
        # their descriptor.
        rpipe = os.fdopen(fd, "rb", buffering=0)
        wpipe = os.fdopen(wfd, "wb", buffering=0)
        try:
            rt, _ = await loop.connect_read_pipe(lambda: sproto, rpipe)
            wt, _ = await loop.connect_write_pipe(_WriteOnlyProtocol, wpipe)
        except BaseException:
            rpipe.close()
            wpipe.close()
            raise
        self._rx_transport = rt
        self._tx_transport = wt
        return sproto

    async def _keep_open(self, proto: MavlinkStreamProtocol) -> None:
        """A TCP peer that restarts or a USB serial adapter that drops out must not need a
        daemon restart: when the stream closes, reopen it with a growing delay (capped),
        forgetting any partial frame, until :meth:`close`."""
        where = self.address.device or f"{self.address.host}:{self.address.port}"
        while not self._closing:
            await asyncio.shield(proto.closed)
            if self._closing:
                return
            for t in (self._rx_transport, self._tx_transport):
                if t is not None and not t.is_closing():
                    t.close()
            self.counters.inc("link_lost")
            _log.warning("MAVLink %s %s closed; reopening", self.address.kind, where)
            attempt = 0
            while not self._closing:
                delay = self.reconnect_delays_s[min(attempt, len(self.reconnect_delays_s) - 1)]
                await asyncio.sleep(delay)
                if self._closing:
                    return
                try:
                    if self._decoder is not None:
                        self._decoder.reset()
                    proto = await self._open_stream()
                except (OSError, ValueError) as exc:
                    attempt += 1
                    if attempt == 1 or attempt % 20 == 0:  # rate-limited: one line per ~100 s
                        _log.warning("MAVLink %s %s: reopen failed (%d attempts): %s",
                                     self.address.kind, where, attempt, exc)
                    continue
                self.counters.inc("link_reopened")
                _log.info("MAVLink %s %s reopened", self.address.kind, where)
                break

    @property
    def peer(self) -> tuple[Any, ...] | None:
        """Where ``send`` goes on a listening UDP link (the last sender), else None."""
        return self._udp.last_peer if self._udp is not None else None

    @property
    def local_address(self) -> tuple[Any, ...] | None:
        t = self._udp_transport or self._rx_transport
        if t is None:
            return None
        sockname: tuple[Any, ...] | None = t.get_extra_info("sockname")
        return sockname

    def set_receive_buffer(self, nbytes: int) -> int:
        """Ask for an ``nbytes`` socket receive buffer on a UDP link (the kernel caps it at
        net.core.rmem_max); return what the kernel granted, 0 for other links."""
        if self._udp_transport is None:
            return 0
        sock = self._udp_transport.get_extra_info("socket")
        if sock is None:
            return 0
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, nbytes)
        return int(sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF))

    def send(self, data: bytes) -> bool:
        """Queue ``data``; False (and counted) if it could not be sent now."""
        if self._udp_transport is not None:
            if self._udp_transport.is_closing():
                self.counters.inc("tx_closed")
                return False
            if self.address.kind == "udpout":
                self._udp_transport.sendto(data)
                return True
            peer = self.peer
            if peer is None:
                # pymavlink udpin semantics: nobody to talk to until someone talks to us.
                self.counters.inc("tx_no_peer")
                return False
            self._udp_transport.sendto(data, peer)
            return True
        t = self._tx_transport
        if t is None or t.is_closing():
            self.counters.inc("tx_closed")
            return False
        if t.get_write_buffer_size() > self.max_tx_buffer:
            self.counters.inc("tx_dropped")
            return False
        t.write(data)
        return True

    def close(self) -> None:
        self._closing = True
        if self._watch is not None and not self._watch.done():
            self._watch.cancel()
        for t in (self._udp_transport, self._rx_transport, self._tx_transport):
            if t is not None and not t.is_closing():
                t.close()


async def open_mavlink(
    url: str,
    decoder: MavlinkDecoder | None = None,
    on_sample: SampleCallback | None = None,
    **kw: Any,
) -> MavlinkLink:
    """Open a pymavlink-style connection string; see :meth:`MavlinkLink.open`."""
    return await MavlinkLink.open(url, decoder, on_sample, **kw)


class MavlinkSender:
    """The daemon's MAVLink sink: solution -> ATTITUDE (+ QUATERNION, GLOBAL_POSITION_INT).

    ``time_boot_ms`` of every output is the solution's ``t_us`` in ms, i.e. the sensor time
    of validity, so a consumer can match attitude to the IMU stream it came from.
    """

    def __init__(
        self,
        link: MavlinkLink,
        encoder: MavlinkEncoder,
        *,
        send_quaternion: bool = True,
        send_global_position: bool = False,
        home_alt_m: float | None = None,
    ) -> None:
        self.link = link
        self.encoder = encoder
        self.send_quaternion = send_quaternion
        self.send_global_position = send_global_position
        self.home_alt_m = home_alt_m

    def send(self, data: bytes) -> bool:
        return self.link.send(data)

    def send_solution(self, sol: NavSolution) -> None:
        ms = sol.t_us // 1000
        self.send(self.encoder.encode_attitude(sol, ms))
        if self.send_quaternion:
            self.send(self.encoder.encode_attitude_quaternion(sol, ms))
        if self.send_global_position:
            try:
                self.send(self.encoder.encode_global_position_int(sol, ms, self.home_alt_m))
            except ValueError:
                self.link.counters.inc("tx_nonfinite_position")

    def send_heartbeat(self, system_status: int = mavlink.MAV_STATE_ACTIVE) -> bool:
        return self.send(self.encoder.encode_heartbeat(system_status))

    async def run_heartbeat(
        self,
        period_s: float = 1.0,
        status: Callable[[], int] = lambda: mavlink.MAV_STATE_ACTIVE,
    ) -> None:
        """Send HEARTBEAT every ``period_s`` until cancelled."""
        while True:
            with contextlib.suppress(OSError):
                self.send_heartbeat(status())
            await asyncio.sleep(period_s)
