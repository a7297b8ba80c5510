"""MAVLink 2 bytes -> navd samples: the input settings, the message tables and the decoder.

Decoding uses the ardupilotmega dialect (a superset of common) so an ArduPilot stream parses
without "unknown message" noise; everything emitted is from common.xml.  This module owns
everything between wire bytes and :data:`navd.io.common.Sample`; it opens nothing (links live
in :mod:`navd.io.mavlink.link`), so log replay (:mod:`navd.io.logs.tlog`) and the daemon share
it unchanged.

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
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from navd.core.plausible import gnss_reason
from navd.diag import Counters, RateLimitedLog
from navd.io.adapter import DecoderBase
from navd.io.common import (
    Limits,
    Sample,
    all_finite,
    imu_reject_reason,
)
from navd.types import FixType, GnssSample, ImuSample, PolSample
from navd.units import DEG
from navd.units import G0 as G0_MPS2

__all__ = ["GNSS_MESSAGES", "IMU_MESSAGES", "MavlinkDecoder", "MavlinkInputConfig"]

# The name the single-file adapter logged under; log configuration may select it.
_LOGGER = "navd.io.mavlink"

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


def _dop(dop_x100: int) -> float | None:
    """GPS_RAW_INT / HIL_GPS ``eph``/``epv``: DOP x 100, UINT16_MAX when unknown."""
    return dop_x100 * 1e-2 if dop_x100 != UINT16_MAX else None


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


class MavlinkDecoder(DecoderBase[MavlinkInputConfig]):
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
        super().__init__(config if config is not None else MavlinkInputConfig(), "mavlink",
                         _LOGGER, counters, log)
        cfg = self.config
        self._mav = self._new_parser()
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
            # the same time checks as every other sample (pol_wire already chose the clock)
            if self._stamp(s.t_us, recv_t_us, "pol") is None:
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
        return self._instance_ok(self.config.imu_id, imu_id, "imu_other_instance")

    def _gnss_id_ok(self, gps_id: int) -> bool:
        return self._instance_ok(self.config.gnss_id, gps_id, "gnss_other_instance")

    def _instance_ok(self, want: int | None, got: int, counter: str) -> bool:
        """Whether a message is from the configured sensor instance (None: any); another
        instance is counted, not rejected: it is expected on a multi-sensor vehicle."""
        if want is not None and got != want:
            self.counters.inc(counter)
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
        lat_rad = lat_deg * DEG
        lon_rad = lon_deg * DEG
        reason = gnss_reason(lat_rad, lon_rad, alt_m, *vel)
        if reason is not None:
            self._reject(reason, "lat=%r lon=%r alt=%r vel=%r", lat_deg, lon_deg, alt_m, vel)
            return None
        return GnssSample(
            t_us=t_us,
            lat_rad=lat_rad,
            lon_rad=lon_rad,
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
        return self._scaled_sample(m, key, t_us, 1e-3, G0_MPS2 * 1e-3)  # mrad/s, mG

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
        return self._scaled_sample(m, key, t_us, g, a)

    def _scaled_sample(
        self, m: Any, key: tuple[int, int, int, int], t_us: int | None, g: float, a: float
    ) -> ImuSample | None:
        """Integer x/y/z gyro and accel fields times their scales (rad/s and m/s^2 per
        unit): what SCALED_IMU* and RAW_IMU share."""
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
        eph, epv = _dop(m.eph), _dop(m.epv)
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
        eph, epv = _dop(m.eph), _dop(m.epv)
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
