"""MAVLink 2 bytes -> navd samples: the input settings, the message tables and the decoder.

Frames are checked against the ardupilotmega dialect's CRC_EXTRA table (a superset of
common, so an ArduPilot stream has no "unknown message" noise) by
:mod:`navd.io.mavlink.frame`; the input messages are unpacked straight from their payload
(:mod:`navd.io.mavlink.wire`), no pymavlink message objects.  This module owns everything
between wire bytes and :data:`navd.io.common.Sample`; it opens nothing (links live in
:mod:`navd.io.mavlink.link`), so log replay (:mod:`navd.io.logs.tlog`) and the daemon share
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

import math
import struct
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from navd.core import highres_batch as hb
from navd.core.imu_block import ImuBlock
from navd.core.plausible import gnss_reason, imu_reason
from navd.diag import Counters, RateLimitedLog
from navd.io import pol_wire
from navd.io.adapter import MAX_SENSOR_T_US, DecoderBase
from navd.io.common import (
    Limits,
    Sample,
    all_finite,
)
from navd.io.mavlink.frame import HEADER_V2, MAX_FRAME_BYTES, Frame, FrameScanner, Rejects
from navd.io.mavlink.signing import KEY_LEN, SignatureCheck
from navd.io.mavlink.wire import (
    LAYOUTS,
    Layout,
    crc_extra_table,
    max_len_table,
    payload_fields,
    v1_lengths_table,
)
from navd.io.source_lock import SourceLock
from navd.types import FixType, GnssSample, ImuSample, PolSample
from navd.units import DEG
from navd.units import G0 as G0_MPS2

__all__ = ["DEFAULT_MAX_DATAGRAM_BYTES", "GNSS_MESSAGES", "IMU_MESSAGES", "MAX_TRACKED_SOURCES",
           "MavlinkDecoder", "MavlinkInputConfig"]

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

# Largest datagram parsed.  ArduPilot's SITL and Linux UDP ports pack whole frames into one
# datagram (SITL up to 10,000 bytes per send); PX4 and mavlink-router send a frame per
# datagram.  16 kB holds 58 frames of the largest size; a bigger datagram is no MAVLink
# sender's and is refused without looking at it.
DEFAULT_MAX_DATAGRAM_BYTES = 16384
# Sources (sysid, compid) with their own counters; beyond this, a flood of spoofed ids
# would grow the status without bound.
MAX_TRACKED_SOURCES = 8

_POL_MSG_ID = pol_wire.MSG_ID
_L_SEQ, _L_LAST_T = hb.L_SEQ, hb.L_LAST_T
_HIGHRES_ID = mavlink.MAVLINK_MSG_ID_HIGHRES_IMU
_HEARTBEAT_ID = mavlink.MAVLINK_MSG_ID_HEARTBEAT
_HIGHRES_SIZE = LAYOUTS[_HIGHRES_ID].unpacker.size
# the HIGHRES_IMU fields the per-sample path reads: time_usec, acc, gyro, (mag, pressures,
# temperature skipped), fields_updated, id
_HIGHRES_UNPACK = struct.Struct("<Q6f28xHB").unpack
assert struct.calcsize("<Q6f28xHB") == _HIGHRES_SIZE
_IGN = (
    mavlink.GPS_INPUT_IGNORE_FLAG_ALT,
    mavlink.GPS_INPUT_IGNORE_FLAG_VEL_HORIZ,
    mavlink.GPS_INPUT_IGNORE_FLAG_VEL_VERT,
    mavlink.GPS_INPUT_IGNORE_FLAG_HORIZONTAL_ACCURACY,
    mavlink.GPS_INPUT_IGNORE_FLAG_VERTICAL_ACCURACY,
    mavlink.GPS_INPUT_IGNORE_FLAG_SPEED_ACCURACY,
    mavlink.GPS_INPUT_IGNORE_FLAG_HDOP,
    mavlink.GPS_INPUT_IGNORE_FLAG_VDOP,
)

Fields = tuple[Any, ...]
Handler = Callable[[tuple[int, int], Fields, int], Sample | None]


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
    max_datagram_bytes: a larger UDP datagram is refused unread (counted ``oversize``).
    signing_key: 32-byte MAVLink 2 signing key; None checks no signatures.  With a key,
        frames with a bad or replayed signature are refused (:mod:`.signing`), and
        unsigned frames too unless ``accept_unsigned``.
    warn_interval_s: at most one log line per rejection reason per interval.
    relock_s: lock IMU, GNSS and polarization input each onto the first (sysid, compid)
        that delivers it and refuse the others until the locked one has been silent this
        long (:mod:`navd.io.source_lock`); None: every allowed source is used.
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
    max_datagram_bytes: int = DEFAULT_MAX_DATAGRAM_BYTES
    signing_key: bytes | None = field(default=None, repr=False)
    accept_unsigned: bool = False
    warn_interval_s: float = 5.0
    relock_s: float | None = None
    limits: Limits = field(default_factory=Limits)

    def __post_init__(self) -> None:
        bad = (self.imu_messages - IMU_MESSAGES) | (self.gnss_messages - GNSS_MESSAGES)
        if bad:
            raise ValueError(f"unsupported MAVLink input message(s): {sorted(bad)}")
        if self.nominal_imu_rate_hz is not None and not self.nominal_imu_rate_hz > 0.0:
            raise ValueError("nominal_imu_rate_hz must be > 0")
        if not self.max_imu_gap_s > 0.0:
            raise ValueError("max_imu_gap_s must be > 0")
        if self.max_datagram_bytes < MAX_FRAME_BYTES:
            raise ValueError(f"max_datagram_bytes must be >= {MAX_FRAME_BYTES} (one frame)")
        if self.signing_key is not None and len(self.signing_key) != KEY_LEN:
            raise ValueError(f"signing_key must have {KEY_LEN} bytes")
        if not self.warn_interval_s >= 0.0:
            raise ValueError("warn_interval_s must be >= 0")
        if self.relock_s is not None and not self.relock_s > 0.0:
            raise ValueError("relock_s must be > 0")


def _source_text(src: object) -> str:
    """(sysid, compid) in the log's words."""
    if isinstance(src, tuple) and len(src) == 2:
        return f"sysid={src[0]} compid={src[1]}"
    return str(src)


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


class _Source:
    """Counters of one accepted source; ``prefix`` is ``src_<sysid>_<compid>_``."""

    __slots__ = ("frames_key", "last_seq", "prefix")

    def __init__(self, src: tuple[int, int]) -> None:
        self.prefix = f"src_{src[0]}_{src[1]}_"
        self.frames_key = self.prefix + "frames"
        self.last_seq: int | None = None


class MavlinkDecoder(DecoderBase[MavlinkInputConfig]):
    """Non-blocking MAVLink parser producing navd samples; never raises on wire input.

    ``feed`` treats input as a byte stream (serial, TCP): a frame may span calls.
    ``feed_datagram`` is for UDP, where a frame never spans datagrams, so a partial frame
    left at the end is dropped (counted) instead of corrupting the next datagram.

    Framing is :class:`navd.io.mavlink.frame.FrameScanner` (linear time, CRC checked);
    the messages navd uses are unpacked straight from the payload
    (:mod:`navd.io.mavlink.wire`), no pymavlink message objects.

    Counters (besides the rejection reasons): ``datagrams``, ``frames_ok`` (CRC-valid
    frames), ``junk_bytes`` (bytes in no valid frame), ``ignored`` (valid frames of
    messages not used), ``datagrams_damaged`` (datagrams with any byte in no valid frame),
    and per accepted source ``src_<sysid>_<compid>_frames`` / ``_seq_lost`` (a source is
    accepted once it passed ``allow`` and delivered a sample; sequence loss is counted only
    for accepted sources, and one frame adds at most 127; a larger jump counts
    ``seq_jump``).
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
        table, lengths = crc_extra_table(), max_len_table()
        if cfg.polarization:
            table[_POL_MSG_ID] = pol_wire.CRC_EXTRA
            lengths[_POL_MSG_ID] = pol_wire.PAYLOAD_LEN
        check = (SignatureCheck(cfg.signing_key, cfg.accept_unsigned)
                 if cfg.signing_key is not None else None)
        self._scanner = FrameScanner(table, lengths, check, v1_lengths_table())
        self._ms = _MsUnwrapper()
        self._sources: dict[tuple[int, int], _Source] = {}
        self._last_gnss_t_us: dict[tuple[int, int, int], int] = {}
        # (MAV_TYPE, MAV_AUTOPILOT) of each source's last HEARTBEAT: what the vehicle says it
        # is (the daemon compares it with [filter] profile); not a filter input
        self.heartbeats: dict[tuple[int, int], tuple[int, int]] = {}
        self._handlers: dict[int, tuple[Layout, Handler]] = {}
        self.source_lock = (SourceLock(cfg.relock_s, self._reject, _source_text)
                            if cfg.relock_s is not None else None)
        self._recv_us = 0  # receive time of the frame being decoded (the lock's clock)
        self.last_junk = 0  # bytes in no valid frame in the last feed_datagram
        # per-sample path: the counters' dict and the IMU limits without a call or an
        # attribute chain each time (issue 18)
        self._counts = self.counters.counts
        self._max_gyro = cfg.limits.max_gyro_rps
        self._max_accel = cfg.limits.max_accel_mps2
        for name in cfg.imu_messages | cfg.gnss_messages:
            msgid: int = getattr(mavlink, f"MAVLINK_MSG_ID_{name}")
            self._handlers[msgid] = (LAYOUTS[msgid], getattr(self, f"_on_{name.lower()}"))
        # HIGHRES_IMU datagrams of an unsigned link stamped with sensor time take
        # _highres_imu_datagram (issue 18), with these settings at hand
        self._highres_fast = (_HIGHRES_ID in self._handlers and check is None
                              and not cfg.use_receive_time)
        self._allow = cfg.allow
        self._max_datagram = cfg.max_datagram_bytes
        self._want_imu_id = cfg.imu_id
        self._updated_mask = _HIGHRES_ACC_GYRO if cfg.require_fields_updated else 0
        # the batch lane (feed_lane): the fast path's datagrams of one IMU instance, a
        # read's worth at a time in compiled code; its settings and scratch arrays
        self.lane = self._highres_fast and cfg.imu_id is not None
        self._lane = np.zeros(hb.LANE_STATE, np.int64)
        self._lane[hb.L_ID] = -1 if cfg.imu_id is None else cfg.imu_id
        self._lane[hb.L_MASK] = self._updated_mask
        self._lane[hb.L_EXTRA] = table[_HIGHRES_ID]
        self._lane[hb.L_MAX_GAP] = round(cfg.max_imu_gap_s * 1e6)
        self._lane_lim = np.array([self._max_gyro, self._max_accel])
        self._lane_scratch = np.zeros(64, np.uint8)
        self._lane_sums = np.zeros(6)
        self._lane_src: tuple[int, int] | None = None  # the lane's source (_lane_select)
        self._lane_source: _Source | None = None
        self._lane_key: tuple[int, int, int, int] = (0, 0, 0, 0)

    def reset(self) -> None:
        """Forget partial frames, IMU time lines and sequence numbers (e.g. after a link
        reconnect, across which neither continues)."""
        self._scanner.reset()
        self._imu.reset()
        for source in self._sources.values():
            source.last_seq = None

    # -- byte input ---------------------------------------------------------------------------

    def feed(self, data: bytes, recv_t_us: int) -> list[Sample]:
        rj = Rejects()
        out = self._decode(self._scanner.stream(data, rj), rj, recv_t_us)
        if rj.counts:
            self._account(rj, "stream piece", len(data))
        return out

    def feed_datagram(self, data: bytes, recv_t_us: int) -> list[Sample]:
        c = self._counts
        c["datagrams"] = c.get("datagrams", 0) + 1
        self.last_junk = 0
        if len(data) > self._max_datagram:
            # Refused unread: its cost must not depend on what an attacker put in it.
            self._reject("oversize", "datagram of %d bytes (limit %d)", len(data),
                         self.config.max_datagram_bytes)
            return []
        if self._highres_fast:
            s = self._highres_imu_datagram(data, recv_t_us)
            if s is not None:
                return [s]
        # Most datagrams are exactly one frame: checked and decoded without the scan's
        # bookkeeping (anything else, including a frame refused here, goes the long way).
        f = self._scanner.whole(data)
        if f is not None:
            return self._one_frame(f, recv_t_us)
        rj = Rejects()
        out = self._decode(self._scanner.datagram(data, rj), rj, recv_t_us)
        self.last_junk = rj.junk_bytes
        if rj.counts:
            self.counters.inc("datagrams_damaged")
            self._account(rj, "datagram", len(data))
        return out

    def feed_whole(self, data: bytes, recv_t_us: int) -> list[Sample] | None:
        """:meth:`feed_datagram` for a datagram that is exactly one valid frame, at a cost
        that does not depend on its content (one checksum over at most 280 bytes); None,
        and nothing counted, for any other datagram (the caller drops it unscanned: a muted
        sender, see :class:`navd.io.mavlink.link.MavlinkUdpProtocol`)."""
        f = self._scanner.whole(data) if len(data) <= MAX_FRAME_BYTES else None
        if f is None:
            return None
        c = self._counts
        c["datagrams"] = c.get("datagrams", 0) + 1
        self.last_junk = 0
        return self._one_frame(f, recv_t_us)

    def _highres_imu_datagram(self, data: bytes, recv_t_us: int) -> ImuSample | None:
        """The kHz path (issue 18): a datagram that is one unsigned HIGHRES_IMU frame of an
        accepted source, carrying a sample that passes every check and continues its time
        line, decoded straight to its ImuSample with the same counting as
        ``_one_frame`` -> ``_on_frame`` -> ``_on_highres_imu`` -> ``_imu_sample``.  None
        for anything else, and then the general path decodes it and counts what is wrong:
        nothing is counted before the sample is known to be accepted, and what the source
        lock and the integrator did by then their general path repeats without effect."""
        if not self._scanner.is_unsigned_v2(data, _HIGHRES_ID):
            return None
        src = (data[5], data[6])
        source = self._sources.get(src)
        allow = self._allow
        if source is None or (allow is not None and src not in allow):
            return None
        payload = data[HEADER_V2:-2]
        if len(payload) != _HIGHRES_SIZE:
            payload = payload[:_HIGHRES_SIZE].ljust(_HIGHRES_SIZE, b"\x00")
        t, ax, ay, az, gx, gy, gz, updated, imu_id = _HIGHRES_UNPACK(payload)
        want = self._want_imu_id
        mask = self._updated_mask
        if ((want is not None and imu_id != want) or updated & mask != mask
                or not 0 < t <= MAX_SENSOR_T_US):
            return None
        # plausible.imu_reason's test, which passes None
        mg, ma = self._max_gyro, self._max_accel
        if not (gx * gx + gy * gy + gz * gz <= mg * mg
                and ax * ax + ay * ay + az * az <= ma * ma):
            return None
        lock = self.source_lock
        if lock is not None and not lock.admit_locked("imu", src, recv_t_us):
            return None
        sample = self._imu.advance((src[0], src[1], _HIGHRES_ID, imu_id), t, gx, gy, gz, ax,
                                   ay, az)
        if sample is None:
            return None
        # accepted: the general path's counting, in its order
        c = self._counts
        c["frames_ok"] = c.get("frames_ok", 0) + 1
        seq, last = data[4], source.last_seq
        if last is None or not (seq - last - 1) & 0xFF:  # _track when no frame was lost
            key = source.frames_key
            c[key] = c.get(key, 0) + 1
            source.last_seq = seq
        else:
            self._track(source, seq)
        self._recv_us = recv_t_us
        if lock is not None:
            lock.imu_agreement.add_locked(recv_t_us, gx, gy, gz, ax, ay, az)
        c["imu_ok"] = c.get("imu_ok", 0) + 1
        return sample

    def feed_lane(self, buf: npt.NDArray[np.uint8], offs: npt.NDArray[np.int64], i: int,
                  n: int, recv_t_us: int, block: ImuBlock) -> int:
        """:meth:`feed_datagram` of datagrams ``i``, ``i + 1``, ... ``n - 1`` of one read
        (datagram j is ``buf[offs[j]:offs[j + 1]]``) while each is a datagram of the
        per-sample path (:meth:`_highres_imu_datagram`) from the source of datagram ``i``
        (accepted, allowed, locked), with sequence numbers continuing: their samples are
        appended to ``block`` (as long as it has room), in compiled code
        (:func:`navd.core.highres_batch.decode_run`), and counted as that path counts them.
        Returns how many were taken; 0 for a decoder without the lane (:attr:`lane`: the
        per-sample path for one configured IMU instance).  The caller feeds a datagram not
        taken through :meth:`feed_datagram` and calls again for the rest."""
        if not self.lane:
            return 0
        p = int(offs[i])
        if offs[i + 1] - p < 12:
            return 0
        src = (int(buf[p + 5]), int(buf[p + 6]))
        if src != self._lane_src and not self._lane_select(src):
            return 0
        source = self._lane_source
        assert source is not None
        seq = source.last_seq
        lock = self.source_lock
        if seq is None or (lock is not None and lock.locked("imu") != src):
            return 0  # _track would count the sequence afresh; admit_locked would refuse
        key = self._lane_key
        last_t = self._imu.last_time(key)
        if last_t is None:
            return 0
        lane = self._lane
        lane[_L_SEQ] = seq
        lane[_L_LAST_T] = last_t
        sums = self._lane_sums
        # the locked stream's agreement window goes on, or a new one starts at this receive
        # time: then the run's sums start from zero (ImuAgreement.add_locked)
        agree = lock.imu_agreement if lock is not None else None
        fresh = agree.lane_sums(recv_t_us, sums) if agree is not None else False
        o = block.n
        k = hb.decode_run(buf, offs, i, n, lane, self._lane_lim, self._lane_scratch, sums,
                          block.t_us, block.dt_us, block.inc, o)
        if not k:
            return 0
        block.n = o + k
        # what _highres_imu_datagram counts and changes per datagram, for k of them in the
        # order it does (so new counter keys come in the same order)
        c = self._counts
        c["datagrams"] = c.get("datagrams", 0) + k
        self.last_junk = 0
        c["frames_ok"] = c.get("frames_ok", 0) + k
        fk = source.frames_key
        c[fk] = c.get(fk, 0) + k
        source.last_seq = int(lane[_L_SEQ])
        self._imu.continue_line(key, int(lane[_L_LAST_T]))
        self._recv_us = recv_t_us
        if lock is not None and agree is not None:
            lock.admit_locked("imu", src, recv_t_us)
            agree.add_locked_run(recv_t_us, fresh, k, sums)
        c["imu_ok"] = c.get("imu_ok", 0) + k
        return k

    def watched_imu(self) -> tuple[int, int, int]:
        """(system id, component id, IMU instance) of the HIGHRES_IMU stream whose samples
        complete the output instants: the locked IMU source, else the lane's; -1 where not
        known (any).  What the compiled UDP reader watches (:mod:`navd.core.udp_rx`)."""
        imu_id = int(self._lane[hb.L_ID]) if self.lane else -1
        lock = self.source_lock
        src = lock.locked("imu") if lock is not None else None
        if src is None:
            src = self._lane_src
        if isinstance(src, tuple) and len(src) == 2:
            return int(src[0]), int(src[1]), imu_id
        return -1, -1, imu_id

    def _lane_select(self, src: tuple[int, int]) -> bool:
        """Make ``src`` the lane's source if it is accepted and allowed (kept until another
        source's datagram comes: accepted sources stay accepted, ``allow`` is fixed)."""
        source = self._sources.get(src)
        if source is None or (self._allow is not None and src not in self._allow):
            return False
        self._lane_src = src
        self._lane_source = source
        self._lane_key = (src[0], src[1], _HIGHRES_ID, int(self._lane[hb.L_ID]))
        self._lane[hb.L_SYS], self._lane[hb.L_COMP] = src
        return True

    def _one_frame(self, f: Frame, recv_t_us: int) -> list[Sample]:
        """The samples of a datagram that is exactly the valid frame ``f``."""
        try:
            s = self._on_frame(f, recv_t_us)
        except Exception as exc:  # wire input must never kill the daemon
            self._reject("parser_error", "%s: %s", type(exc).__name__, exc)
            return []
        return [] if s is None else [s]

    def _decode(self, frames: Iterable[Frame], rj: Rejects, recv_t_us: int) -> list[Sample]:
        out: list[Sample] = []
        try:
            for f in frames:
                s = self._on_frame(f, recv_t_us)
                if s is not None:
                    out.append(s)
        except Exception as exc:  # wire input must never kill the daemon
            self._reject("parser_error", "%s: %s", type(exc).__name__, exc)
            self._scanner.reset()
        return out

    def _account(self, rj: Rejects, what: str, size: int) -> None:
        """Count one scan's rejections (framing reasons once per run of junk, see Rejects)."""
        self.counters.inc("junk_bytes", rj.junk_bytes)
        for reason, n in rj.counts.items():
            self.counters.inc(reason, n - 1)
            self._reject(reason, "%d of %d bytes of a %s in no valid frame", rj.junk_bytes,
                         size, what)

    def _on_frame(self, f: Frame, recv_t_us: int) -> Sample | None:
        c = self._counts
        c["frames_ok"] = c.get("frames_ok", 0) + 1
        src = (f.sysid, f.compid)
        source = self._sources.get(src)
        if source is not None:
            self._track(source, f.seq)
        if f.msgid == _POL_MSG_ID and self.config.polarization:
            return self._polarization(f, src, recv_t_us)
        if f.msgid == _HEARTBEAT_ID:
            # noted, still "ignored": nothing of it reaches the filter
            v = payload_fields(LAYOUTS[_HEARTBEAT_ID], f.payload)
            self.heartbeats[src] = (int(v[1]), int(v[2]))
        h = self._handlers.get(f.msgid)
        if h is None:
            self.counters.inc("ignored")
            return None
        if self.config.allow is not None and src not in self.config.allow:
            self._reject("not_allowed", "source sysid=%d compid=%d", *src)
            return None
        layout, handler = h
        self._recv_us = recv_t_us
        try:
            sample = handler(src, payload_fields(layout, f.payload), recv_t_us)
        except (TypeError, ValueError, OverflowError) as exc:
            self._reject("decode_error", "%s: %s", layout.name, exc)
            return None
        if sample is None:
            return None
        if isinstance(sample, GnssSample):
            lock = self.source_lock
            if lock is not None and not lock.admit("gnss", src, recv_t_us):
                return None
            # ArduPilot streams GPS_RAW_INT faster than many receivers update and repeats
            # the last fix, time stamp included; a repeat is no new information.
            key = (src[0], src[1], f.msgid)
            if self._last_gnss_t_us.get(key) == sample.t_us:
                self.counters.inc("gnss_repeat")
                return None
            self._last_gnss_t_us[key] = sample.t_us
            c["gnss_ok"] = c.get("gnss_ok", 0) + 1
        else:
            c["imu_ok"] = c.get("imu_ok", 0) + 1
        if source is None:
            self._accepted(src, f.seq)
        return sample

    def _accepted(self, src: tuple[int, int], seq: int) -> None:
        """``src`` delivered its first sample: from now on its frames and sequence are
        counted per source (up to MAX_TRACKED_SOURCES; ``src_untracked`` counts the rest)."""
        if src in self._sources:
            return
        if len(self._sources) >= MAX_TRACKED_SOURCES:
            self.counters.inc("src_untracked")
            return
        source = self._sources[src] = _Source(src)
        source.last_seq = seq
        self.counters.inc(source.frames_key)

    def _track(self, source: _Source, seq: int) -> None:
        c = self._counts
        c[source.frames_key] = c.get(source.frames_key, 0) + 1
        last = source.last_seq
        source.last_seq = seq
        if last is None:
            return
        lost = (seq - last - 1) & 0xFF
        if lost == 0:
            return
        # A "loss" of 128 or more is a restart, a duplicate, reordering or a second sender
        # using the same ids, not that many dropped frames.
        if lost < 128:
            self.counters.inc("seq_lost", lost)
            self.counters.inc(source.prefix + "seq_lost", lost)
        else:
            self.counters.inc("seq_jump")

    def _polarization(self, f: Frame, src: tuple[int, int], recv_t_us: int) -> PolSample | None:
        """NAVD_SKY_POLARIZATION (CRC already checked) -> PolSample; None if refused
        (counted)."""
        if f.version != 2:
            self._reject("pol_wire_bad_frame", "NAVD_SKY_POLARIZATION in a MAVLink 1 frame")
            return None
        if self.config.allow is not None and src not in self.config.allow:
            self._reject("not_allowed", "source sysid=%d compid=%d", *src)
            return None
        why: dict[str, int] = {}
        s = pol_wire.decode_payload(f.payload, recv_t_us,
                                    use_receive_time=self.config.use_receive_time, counters=why)
        if s is None:
            for reason in why:
                self._reject(reason, "NAVD_SKY_POLARIZATION from sysid=%d compid=%d", *src)
            return None
        # the same time checks as every other sample (pol_wire already chose the clock)
        if self._stamp(s.t_us, recv_t_us, "pol") is None:
            return None
        lock = self.source_lock
        if lock is not None and not lock.admit("pol", src, recv_t_us):
            return None
        self.counters.inc("pol_ok")
        self._accepted(src, f.seq)
        return s

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
        reason = imu_reason(*gyro, *accel, self._max_gyro, self._max_accel)
        if reason is not None:
            # Rejecting before the time line advances lets the next good sample cover the
            # gap by zero-order hold instead of losing the interval.
            self._reject(reason, "gyro=%s accel=%s", gyro, accel)
            return None
        lock = self.source_lock
        if lock is not None:
            src, now = key[:2], self._recv_us
            used = lock.admit("imu", src, now)
            lock.imu_agreement.add(used, src, now, gyro, accel)
            if not used:
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

    # -- IMU messages (fields in wire order, navd.io.mavlink.wire.LAYOUTS) ---------------------

    def _on_highres_imu(self, src: tuple[int, int], f: Fields, recv_t_us: int) -> ImuSample | None:
        t, ax, ay, az, gx, gy, gz = f[:7]
        updated, imu_id = f[14], f[15]
        cfg = self.config
        if cfg.imu_id is not None and imu_id != cfg.imu_id and not self._imu_id_ok(imu_id):
            return None
        if (cfg.require_fields_updated
                and (updated & _HIGHRES_ACC_GYRO) != _HIGHRES_ACC_GYRO):
            self.counters.inc("imu_fields_not_updated")
            return None
        # the usual stamp without a call: a sensor time in (0, 2**53] us, not overridden
        t_us = (t if 0 < t <= MAX_SENSOR_T_US and not cfg.use_receive_time
                else self._stamp(t, recv_t_us, "imu"))
        key = (src[0], src[1], mavlink.MAVLINK_MSG_ID_HIGHRES_IMU, imu_id)
        return self._imu_sample(key, t_us, (gx, gy, gz), (ax, ay, az))

    def _scaled(self, src: tuple[int, int], f: Fields, recv_t_us: int, msgid: int,
                instance: int) -> ImuSample | None:
        if not self._imu_id_ok(instance):
            return None
        key = (src[0], src[1], msgid, instance)
        t_us = self._stamp(self._ms.us(key[:3], f[0]), recv_t_us, "imu")
        return self._scaled_sample(f, key, t_us, 1e-3, G0_MPS2 * 1e-3)  # mrad/s, mG

    def _on_scaled_imu(self, src: tuple[int, int], f: Fields, recv_t_us: int) -> ImuSample | None:
        return self._scaled(src, f, recv_t_us, mavlink.MAVLINK_MSG_ID_SCALED_IMU, 0)

    def _on_scaled_imu2(self, src: tuple[int, int], f: Fields, recv_t_us: int) -> ImuSample | None:
        return self._scaled(src, f, recv_t_us, mavlink.MAVLINK_MSG_ID_SCALED_IMU2, 1)

    def _on_scaled_imu3(self, src: tuple[int, int], f: Fields, recv_t_us: int) -> ImuSample | None:
        return self._scaled(src, f, recv_t_us, mavlink.MAVLINK_MSG_ID_SCALED_IMU3, 2)

    def _on_raw_imu(self, src: tuple[int, int], f: Fields, recv_t_us: int) -> ImuSample | None:
        g = self.config.raw_gyro_rps_per_lsb
        a = self.config.raw_accel_mps2_per_lsb
        if g is None or a is None:
            self._reject("raw_imu_unscaled", "RAW_IMU needs raw_*_per_lsb scales in config")
            return None
        imu_id = f[10]
        if not self._imu_id_ok(imu_id):
            return None
        t_us = self._stamp(f[0], recv_t_us, "imu")
        key = (src[0], src[1], mavlink.MAVLINK_MSG_ID_RAW_IMU, imu_id)
        return self._scaled_sample(f, key, t_us, g, a)

    def _scaled_sample(
        self, f: Fields, key: tuple[int, int, int, int], t_us: int | None, g: float, a: float
    ) -> ImuSample | None:
        """Integer x/y/z accel and gyro fields (wire positions 1-6) times their scales
        (m/s^2 and rad/s per unit): what SCALED_IMU* and RAW_IMU share."""
        _, ax, ay, az, gx, gy, gz = f[:7]
        return self._imu_sample(key, t_us, (gx * g, gy * g, gz * g), (ax * a, ay * a, az * a))

    # -- GNSS messages ------------------------------------------------------------------------

    def _on_gps_raw_int(self, src: tuple[int, int], f: Fields, recv_t_us: int) -> GnssSample | None:
        (t, lat, lon, alt, eph_x100, epv_x100, vel, cog, fix_type, _sats, alt_ellipsoid,
         h_acc, v_acc, vel_acc) = f[:14]
        cfg = self.config
        t_us = self._stamp(t, recv_t_us, "gnss")
        if alt_ellipsoid != 0:
            alt_m = alt_ellipsoid * 1e-3
        else:
            # 0 is what an absent MAVLink 2 extension decodes to.
            alt_m = alt * 1e-3 + cfg.geoid_sep_m
            self.counters.inc("gnss_alt_from_msl")
        if vel != UINT16_MAX and cog != UINT16_MAX:
            speed = vel * 1e-2
            course = cog * 1e-2 * DEG
            v = (speed * math.cos(course), speed * math.sin(course), math.nan)
        else:
            v = (math.nan, math.nan, math.nan)
        eph, epv = _dop(eph_x100), _dop(epv_x100)
        return self._gnss_sample(
            t_us, fix_type, lat, lon, alt_m, v,
            self._acc_or(h_acc * 1e-3, eph, cfg.default_h_acc_m),
            self._acc_or(v_acc * 1e-3, epv, cfg.default_v_acc_m),
            self._acc_or(vel_acc * 1e-3, None, cfg.default_vel_acc_mps),
        )

    def _on_gps_input(self, src: tuple[int, int], f: Fields, recv_t_us: int) -> GnssSample | None:
        (t, _week_ms, lat, lon, alt, hdop, vdop, vn, ve, vd, sacc, hacc, vacc, ign, _week,
         gps_id, fix_type) = f[:17]
        if not self._gnss_id_ok(gps_id):
            return None
        cfg = self.config
        i_alt, i_vh, i_vv, i_hacc, i_vacc, i_sacc, i_hdop, i_vdop = _IGN
        # NaN from an ignore flag is intended; NaN/Inf in a field the sender vouches for
        # is a broken sender.
        vouched = [v for v, flag in ((alt, i_alt), (vn, i_vh), (ve, i_vh), (vd, i_vv),
                                     (hacc, i_hacc), (vacc, i_vacc), (sacc, i_sacc))
                   if not ign & flag]
        if not all_finite(*vouched):
            self._reject("gnss_nonfinite", "GPS_INPUT field is NaN/Inf")
            return None
        if ign & i_alt:
            self._reject("gnss_no_alt", "GPS_INPUT with ALT ignored")
            return None
        nan = math.nan
        t_us = self._stamp(t, recv_t_us, "gnss")
        return self._gnss_sample(
            t_us, fix_type, lat, lon, alt + cfg.geoid_sep_m,
            (nan if ign & i_vh else vn, nan if ign & i_vh else ve, nan if ign & i_vv else vd),
            self._acc_or(nan if ign & i_hacc else hacc, nan if ign & i_hdop else hdop,
                         cfg.default_h_acc_m),
            self._acc_or(nan if ign & i_vacc else vacc, nan if ign & i_vdop else vdop,
                         cfg.default_v_acc_m),
            self._acc_or(nan if ign & i_sacc else sacc, None, cfg.default_vel_acc_mps),
        )

    def _on_hil_gps(self, src: tuple[int, int], f: Fields, recv_t_us: int) -> GnssSample | None:
        (t, lat, lon, alt, eph_x100, epv_x100, _vel, vn, ve, vd, _cog, fix_type, _sats,
         gps_id) = f[:14]
        if not self._gnss_id_ok(gps_id):
            return None
        cfg = self.config
        t_us = self._stamp(t, recv_t_us, "gnss")
        eph, epv = _dop(eph_x100), _dop(epv_x100)
        return self._gnss_sample(
            t_us, fix_type, lat, lon, alt * 1e-3 + cfg.geoid_sep_m,
            (vn * 1e-2, ve * 1e-2, vd * 1e-2),
            self._acc_or(math.nan, eph, cfg.default_h_acc_m),
            self._acc_or(math.nan, epv, cfg.default_v_acc_m),
            cfg.default_vel_acc_mps,
        )
