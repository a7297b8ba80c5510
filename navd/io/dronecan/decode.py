"""DroneCAN transfers -> navd samples: the adapter's settings, data type tables and decoder.

Frames are reassembled into transfers by :mod:`navd.io.dronecan.transfer`; this module
checks the transfer CRC and decodes the payload.  Fix2 (bit-packed, 10 Hz) goes through
the ``dronecan`` codec.  RawIMU, the 1 kHz message, and navd's SkyPolarization are
unpacked here (byte-aligned little-endian fields; CRC-16-CCITT seeded with the CRC of the
type signature): 18 us per RawIMU from the first frame to the sample, against 211 us
through the codec (benchmarks/decode.py).  Tests check the two against each other.

Inputs
    uavcan.equipment.ahrs.RawIMU (1003): if ``integration_interval`` > 0, the integrals
    ``rate_gyro_integral`` (rad) and ``accelerometer_integral`` (m/s) are the increments
    over that interval; otherwise the float16 point samples ``rate_gyro_latest`` (rad/s)
    and ``accelerometer_latest`` (m/s^2) are held over the interval since the previous
    sample (float16: ~0.05 % resolution, saturating at 65504).
    uavcan.equipment.gnss.Fix2 (1063): lat/lon int37 in 1e-8 deg, ``height_ellipsoid_mm``,
    ``ned_velocity`` float32 m/s, ``status`` must be 3D fix; ``mode``/``sub_mode`` give
    DGPS/RTK.  Fix2 has ONE ``covariance`` (float16[<=36]) over NED position and velocity
    (the separate position_covariance / velocity_covariance belong to the older Fix, 1060):
    6 entries = diagonal (ArduPilot AP_Periph sends [hacc², hacc², vacc², sacc², sacc²,
    sacc²]), 36 = full 6x6, 0 = unknown (config defaults); NaN entries are unknown.
    ``ecef_position_velocity`` (<=1): position int36 mm, velocity float32 m/s.
    Time: ``timestamp.usec`` (bus-synchronised time, 0 when the node has none: such
    samples are rejected unless ``use_receive_time``).  A transfer repeating its node's
    previous time stamp (redundant interfaces) is dropped, never integrated twice.
    navd.equipment.SkyPolarization (20440, navd's private type, navd/io/dsdl/): a skylight
    polarization reading (docs/polarization.md) -> PolSample; GPS time -> UTC.
Output
    uavcan.equipment.ahrs.Solution (1000): quaternion in x, y, z, w order (navd is w, x, y, z),
"""

from __future__ import annotations

import binascii
import math
import struct
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import can
import dronecan
from dronecan import transport

from navd.core.plausible import gnss_reason
from navd.diag import Counters, RateLimitedLog
from navd.io.adapter import DecoderBase
from navd.io.common import (
    Limits,
    Sample,
    all_finite,
    imu_reject_reason,
    monotonic_us,
)
from navd.io.dronecan.transfer import TransferReassembler, payload_len
from navd.io.pol_wire import reading_to_sample
from navd.io.source_lock import SourceLock
from navd.types import FixType, GnssSample, ImuSample, PolSample
from navd.units import DEG

__all__ = [
    "FIX2_DTID",
    "POL_DTID",
    "POL_SIGNATURE",
    "RAW_IMU_DTID",
    "DronecanConfig",
    "DronecanDecoder",
    "RawImuFields",
]

# The name the single-file adapter logged under; log configuration may select it.
_LOGGER = "navd.io.dronecan"

RAW_IMU_DTID = 1003
FIX2_DTID = 1063
# navd's private message navd.equipment.SkyPolarization (navd/io/dsdl/; vendor-specific
# message range 20000-21799); its DSDL signature, recomputed from the .uavcan file in tests
POL_DTID = 20440
POL_SIGNATURE = 0x53EF5B29B1B13DDF

_RAW_IMU = dronecan.TYPENAMES["uavcan.equipment.ahrs.RawIMU"]
_FIX2 = dronecan.TYPENAMES["uavcan.equipment.gnss.Fix2"]
_MIN_PAYLOAD = {
    RAW_IMU_DTID: (_RAW_IMU.get_min_bitlen() + 7) // 8,
    FIX2_DTID: (_FIX2.get_min_bitlen() + 7) // 8,
    POL_DTID: 24,
}
_F16_MAX = 65504.0
# RawIMU after its 56-bit time stamp: float32 integration_interval, float16[3]
# rate_gyro_latest, float32[3] rate_gyro_integral, float16[3] accelerometer_latest,
# float32[3] accelerometer_integral; then float16[<=36] covariance (tail array, unused)
_RAW_IMU_BODY = struct.Struct("<f3e3f3e3f")
_RAW_IMU_CRC0 = int(_RAW_IMU.base_crc)
# SkyPolarization after its 56-bit time stamp: uint64 time_gps_usec, float32 aop, float32
# dop, uint8 sensor_id
_POL_BODY = struct.Struct("<QffB")
_POL_CRC0 = binascii.crc_hqx(struct.pack("<Q", POL_SIGNATURE), 0xFFFF)
_OWN_UNPACK = {RAW_IMU_DTID: _RAW_IMU_CRC0, POL_DTID: _POL_CRC0}


@dataclass(frozen=True)
class DronecanConfig:
    """Bus and decoder settings, SI units.

    interface/channel: python-can bus, e.g. ("socketcan", "can0"), ("virtual", "any").
    node_id: our node ID for outputs (1..127).
    allow_nodes: accepted source node IDs; None accepts any.
    kernel_filters: ask the bus (SocketCAN: the kernel) to deliver only accepted data types.
    """

    interface: str = "socketcan"
    channel: str = "can0"
    node_id: int = 100
    allow_nodes: frozenset[int] | None = None
    transfer_timeout_s: float = 0.1
    nominal_imu_rate_hz: float | None = None
    max_imu_gap_s: float = 0.1
    use_receive_time: bool = False
    default_h_acc_m: float = 5.0
    default_v_acc_m: float = 10.0
    default_vel_acc_mps: float = 0.5
    kernel_filters: bool = True
    priority: int = 16
    warn_interval_s: float = 5.0  # at most one log line per rejection reason per interval
    # lock each kind of input onto the first node that delivers it (navd.io.source_lock);
    # None: every allowed node is used
    relock_s: float | None = None
    limits: Limits = field(default_factory=Limits)

    def __post_init__(self) -> None:
        if not 1 <= self.node_id <= 127:
            raise ValueError(f"node_id must be 1..127, got {self.node_id}")
        if not 0 <= self.priority <= 31:
            raise ValueError(f"priority must be 0..31, got {self.priority}")
        if not self.transfer_timeout_s > 0.0:
            raise ValueError("transfer_timeout_s must be > 0")
        if self.nominal_imu_rate_hz is not None and not self.nominal_imu_rate_hz > 0.0:
            raise ValueError("nominal_imu_rate_hz must be > 0")
        if self.relock_s is not None and not self.relock_s > 0.0:
            raise ValueError("relock_s must be > 0")


class RawImuFields(NamedTuple):
    """The RawIMU fields navd uses (SI, body FRD)."""

    usec: int
    integration_interval: float
    rate_gyro_latest: tuple[float, float, float]
    rate_gyro_integral: tuple[float, float, float]
    accelerometer_latest: tuple[float, float, float]
    accelerometer_integral: tuple[float, float, float]


def _unpack_raw_imu(body: bytes) -> RawImuFields:
    """RawIMU payload (CRC removed, at least 47 bytes) -> fields."""
    v = _RAW_IMU_BODY.unpack_from(body, 7)
    return RawImuFields(int.from_bytes(body[:7], "little"), v[0], v[1:4], v[4:7], v[7:10],
                        v[10:13])



def _fix_type(mode: int, sub_mode: int) -> FixType:
    if mode == 1:
        return FixType.DGPS
    if mode == 2:
        return FixType.RTK_FIXED if sub_mode == 1 else FixType.RTK_FLOAT
    if mode == 3:  # PPP: better than single point, no RTK ambiguity resolution
        return FixType.DGPS
    return FixType.FIX_3D


class DronecanDecoder(DecoderBase[DronecanConfig]):
    """Frame-by-frame reassembly and decoding; never raises on bus input."""

    no_timestamp_detail = "timestamp.usec is 0 (no time sync); set use_receive_time"

    def __init__(
        self,
        config: DronecanConfig | None = None,
        counters: Counters | None = None,
        log: RateLimitedLog | None = None,
    ) -> None:
        super().__init__(config if config is not None else DronecanConfig(), "dronecan",
                         _LOGGER, counters, log)
        cfg = self.config
        self._transfers = TransferReassembler(
            self._reject, _MIN_PAYLOAD, cfg.allow_nodes, round(cfg.transfer_timeout_s * 1e6)
        )
        self._last_fix_t_us: dict[int, int] = {}
        self._last_pol_t_us: dict[int, int] = {}
        self.source_lock = (SourceLock(cfg.relock_s, self._reject, lambda n: f"node {n}")
                            if cfg.relock_s is not None else None)

    @property
    def pending(self) -> int:
        """Partial transfers being reassembled."""
        return self._transfers.pending

    def evict_stale(self, now_us: int) -> int:
        return self._transfers.evict_stale(now_us)

    def feed(self, msg: can.Message, recv_t_us: int | None = None) -> list[Sample]:
        """Take one CAN frame; return the sample(s) a completed transfer produced."""
        now = recv_t_us if recv_t_us is not None else monotonic_us()
        if self._transfers.pending:
            self._transfers.evict_stale(now)
        try:
            payload = self._reassemble(msg, now)
            if payload is None:
                return []
            sample = self._decode(*payload)
        except Exception as exc:  # bus input must never kill the daemon
            self._reject("decode_error", "%s: %s", type(exc).__name__, exc)
            return []
        if sample is None:
            return []
        self.counters.inc("imu_ok" if isinstance(sample, ImuSample) else
                          "pol_ok" if isinstance(sample, PolSample) else "gnss_ok")
        return [sample]

    def _reassemble(self, msg: can.Message, now: int) -> tuple[int, int, int, Any] | None:
        """(source node, data type ID, receive time of the first frame, payload) once a
        transfer is complete and its CRC checks, else None (the reason counted)."""
        got = self._transfers.push(msg, now)
        if got is None:
            return None
        payload = self._complete(got.can_id, got.frames, got.dtid)
        return (got.src, got.dtid, got.start_us, payload) if payload is not None else None

    def _complete(self, cid: int, frames: list[bytes], dtid: int) -> Any:
        """Payload of a reassembled transfer (toggles and transfer IDs already checked), or
        None with the reason counted."""
        crc0 = _OWN_UNPACK.get(dtid)
        if crc0 is not None:  # unpacked here; both types are multi-frame (>= 24 bytes)
            raw = b"".join([f[:-1] for f in frames])
            body = raw[2:]
            if len(frames) > 1 and binascii.crc_hqx(body, crc0) != raw[0] | (raw[1] << 8):
                self._reject("bad_crc", "dtid %d: transfer CRC mismatch", dtid)
                return None
            if not self._long_enough(dtid, frames):
                return None
            return _unpack_raw_imu(body) if dtid == RAW_IMU_DTID else body
        t = transport.Transfer()
        try:
            t.from_frames([transport.Frame(message_id=cid, data=f) for f in frames])
        except transport.TransferError as exc:
            reason = "bad_crc" if "CRC" in str(exc) else "bad_transfer"
            self._reject(reason, "dtid %d: %s", dtid, str(exc)[:120])
            return None
        # The codec decodes a short payload without complaint (missing bits read as 0 or
        # None), so length is checked here too.
        return t.payload if self._long_enough(dtid, frames) else None

    def _long_enough(self, dtid: int, frames: list[bytes]) -> bool:
        n = payload_len(frames)
        if n < _MIN_PAYLOAD[dtid]:
            self._reject("short_payload", "dtid %d: %d bytes < %d", dtid, n, _MIN_PAYLOAD[dtid])
            return False
        return True

    def _decode(self, src: int, dtid: int, recv_t_us: int, p: Any) -> Sample | None:
        if dtid == RAW_IMU_DTID:
            return self._raw_imu(src, recv_t_us, p)
        if dtid == POL_DTID:
            return self._polarization(src, recv_t_us, p)
        fix = self._fix2(recv_t_us, p)
        lock = self.source_lock
        if fix is not None and lock is not None and not lock.admit("gnss", src, recv_t_us):
            return None
        if fix is not None:
            # Redundant interfaces deliver the same transfer twice.
            if self._last_fix_t_us.get(src) == fix.t_us:
                self.counters.inc("gnss_repeat")
                return None
            self._last_fix_t_us[src] = fix.t_us
        return fix

    def _polarization(self, src: int, recv_t_us: int, body: bytes) -> PolSample | None:
        t_us = self._stamp(int.from_bytes(body[:7], "little"), recv_t_us, "pol")
        if t_us is None:
            return None
        gps_us, aop, dop, _sensor = _POL_BODY.unpack_from(body, 7)
        out = reading_to_sample(t_us, gps_us, aop, dop)
        if isinstance(out, str):
            self._reject(out, "node %d: time_gps_usec=%d aop=%r dop=%r", src, gps_us, aop, dop)
            return None
        if self._last_pol_t_us.get(src) == out.t_us:
            self.counters.inc("pol_repeat")  # the same transfer over redundant interfaces
            return None
        lock = self.source_lock
        if lock is not None and not lock.admit("pol", src, recv_t_us):
            return None
        self._last_pol_t_us[src] = out.t_us
        return out

    def _raw_imu(self, src: int, recv_t_us: int, p: RawImuFields) -> ImuSample | None:
        t_us = self._stamp(p.usec, recv_t_us, "imu")
        if t_us is None:
            return None
        key = (src, RAW_IMU_DTID)
        interval = float(p.integration_interval)
        if math.isfinite(interval) and interval > 0.0:
            dth = p.rate_gyro_integral
            dvl = p.accelerometer_integral
            dt_us = round(interval * 1e6)
            if dt_us <= 0 or not all_finite(*dth, *dvl):
                self._reject("imu_nonfinite", "integrals %s %s over %r s", dth, dvl, interval)
                return None
            k = 1.0 / interval
            reason = imu_reject_reason(
                dth[0] * k, dth[1] * k, dth[2] * k, dvl[0] * k, dvl[1] * k, dvl[2] * k,
                self.config.limits,
            )
            if reason is not None:
                self._reject(reason, "integrals %s %s over %r s", dth, dvl, interval)
                return None
            if not self._lock_imu(src, recv_t_us, (dth[0] * k, dth[1] * k, dth[2] * k),
                                  (dvl[0] * k, dvl[1] * k, dvl[2] * k)):
                return None
            if self._imu.last_time(key) == t_us:
                # Same transfer again (redundant interfaces): integrating it twice would
                # double the motion.
                self._reject("imu_duplicate_time", "node %d repeated t_us=%d", src, t_us)
                return None
            self._imu.note_time(key, t_us)
            return ImuSample(t_us, dt_us, dth[0], dth[1], dth[2], dvl[0], dvl[1], dvl[2])
        gx, gy, gz = p.rate_gyro_latest
        ax, ay, az = p.accelerometer_latest
        reason = imu_reject_reason(gx, gy, gz, ax, ay, az, self.config.limits)
        if reason is not None:
            self._reject(reason, "gyro=%s accel=%s", (gx, gy, gz), (ax, ay, az))
            return None
        if not self._lock_imu(src, recv_t_us, (gx, gy, gz), (ax, ay, az)):
            return None
        return self._imu.push(key, t_us, (gx, gy, gz), (ax, ay, az))

    def _lock_imu(self, src: int, recv_t_us: int, gyro: tuple[float, float, float],
                  accel: tuple[float, float, float]) -> bool:
        """Whether the IMU lock lets node ``src`` feed the estimator; a refused node's
        rates (rad/s) and specific force (m/s^2) are still compared with the locked one's."""
        lock = self.source_lock
        if lock is None:
            return True
        used = lock.admit("imu", src, recv_t_us)
        lock.imu_agreement.add(used, src, recv_t_us, gyro, accel)
        return used

    def _accuracy(self, cov: list[float]) -> tuple[float, float, float] | None:
        """(h_acc, v_acc, vel_acc) 1-sigma from Fix2 covariance; None if unusable."""
        cfg = self.config
        if len(cov) == 6:
            diag = cov
        elif len(cov) == 36:
            diag = [cov[7 * i] for i in range(6)]
        else:
            if cov:
                self.counters.inc("gnss_cov_unrecognised")
            return cfg.default_h_acc_m, cfg.default_v_acc_m, cfg.default_vel_acc_mps
        if any(v >= _F16_MAX or v < 0.0 for v in diag):  # NaN compares False: kept
            # A saturated float16 (65504 m², or inf from a non-saturating encoder) means
            # sigma > 255 m: the receiver is saying "useless", not "unknown".
            return None

        def sigma(values: list[float], default: float) -> float:
            if any(math.isnan(v) for v in values):
                return default
            var = sum(values) / len(values)
            return math.sqrt(var) if var > 0.0 else default

        return (
            sigma(diag[0:2], cfg.default_h_acc_m),
            sigma(diag[2:3], cfg.default_v_acc_m),
            sigma(diag[3:6], cfg.default_vel_acc_mps),
        )

    def _fix2(self, recv_t_us: int, p: Any) -> GnssSample | None:
        if int(p.status) != 3:
            self._reject("gnss_no_fix", "status=%d", int(p.status))
            return None
        t_us = self._stamp(int(p.timestamp.usec), recv_t_us, "gnss")
        if t_us is None:
            return None
        lat_deg = int(p.latitude_deg_1e8) * 1e-8
        lon_deg = int(p.longitude_deg_1e8) * 1e-8
        alt_m = int(p.height_ellipsoid_mm) * 1e-3
        vn, ve, vd = (float(v) for v in p.ned_velocity)
        if not all_finite(vn, ve, vd):
            self._reject("gnss_nonfinite", "ned_velocity=%r", (vn, ve, vd))
            return None
        lat_rad = lat_deg * DEG
        lon_rad = lon_deg * DEG
        reason = gnss_reason(lat_rad, lon_rad, alt_m, vn, ve, vd)
        if reason is not None:
            self._reject(reason, "lat=%r lon=%r alt=%r", lat_deg, lon_deg, alt_m)
            return None
        acc = self._accuracy([float(v) for v in p.covariance])
        if acc is None:
            self._reject("gnss_accuracy_saturated", "covariance inf/negative")
            return None
        pos_ecef: tuple[float, float, float] | None = None
        vel_ecef: tuple[float, float, float] | None = None
        if len(p.ecef_position_velocity) > 0:
            e = p.ecef_position_velocity[0]
            px, py, pz = (int(v) * 1e-3 for v in e.position_xyz_mm)
            ex, ey, ez = (float(v) for v in e.velocity_xyz)
            r = math.sqrt(px * px + py * py + pz * pz)
            if all_finite(ex, ey, ez) and 6.0e6 < r < 6.6e6:
                pos_ecef, vel_ecef = (px, py, pz), (ex, ey, ez)
            else:
                self._reject("gnss_bad_ecef", "|r|=%r m vel=%r", r, (ex, ey, ez))
        return GnssSample(
            t_us=t_us,
            lat_rad=lat_rad,
            lon_rad=lon_rad,
            alt_m=alt_m,
            vel_n=vn,
            vel_e=ve,
            vel_d=vd,
            h_acc_m=acc[0],
            v_acc_m=acc[1],
            vel_acc_mps=acc[2],
            fix_type=_fix_type(int(p.mode), int(p.sub_mode)),
            pos_ecef_m=pos_ecef,
            vel_ecef_mps=vel_ecef,
        )
