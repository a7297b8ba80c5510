"""MAVLink decoder under hostile input: it counts, it never raises, it never invents data."""

from __future__ import annotations

import math
import struct

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mav

from firmware_sim.transport.mavlink_tx import MavlinkTx
from navd.io.common import Limits, Sample
from navd.io.mavlink import MavlinkDecoder, MavlinkInputConfig
from navd.types import FixType, GnssSample, ImuSample

CFG = MavlinkInputConfig(
    imu_messages=frozenset({"HIGHRES_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3"}),
    gnss_messages=frozenset({"GPS_RAW_INT", "GPS_INPUT", "HIL_GPS"}),
    imu_id=None,
    gnss_id=None,
    nominal_imu_rate_hz=1000.0,
)
FAST = settings(max_examples=1500, deadline=None, suppress_health_check=[HealthCheck.too_slow])
LIM = Limits()

GOOD = GnssSample(
    t_us=123_456, lat_rad=math.radians(47.0), lon_rad=math.radians(8.0), alt_m=400.0,
    vel_n=1.0, vel_e=2.0, vel_d=0.5, h_acc_m=1.0, v_acc_m=2.0, vel_acc_mps=0.3,
    fix_type=FixType.FIX_3D,
)


def _sane(samples: list[Sample]) -> None:
    for s in samples:
        if isinstance(s, ImuSample):
            assert s.dt_us > 0
            vals = (s.dtheta_x, s.dtheta_y, s.dtheta_z, s.dvel_x, s.dvel_y, s.dvel_z)
            assert all(math.isfinite(v) for v in vals)
            dt = s.dt_us * 1e-6
            assert math.sqrt(s.dtheta_x**2 + s.dtheta_y**2 + s.dtheta_z**2) <= LIM.max_gyro_rps * dt
            assert math.sqrt(s.dvel_x**2 + s.dvel_y**2 + s.dvel_z**2) <= LIM.max_accel_mps2 * dt
        else:
            assert abs(s.lat_rad) <= math.pi / 2 and abs(s.lon_rad) <= math.pi
            assert math.isfinite(s.alt_m) and s.fix_type >= FixType.FIX_3D
            assert s.h_acc_m > 0 and s.v_acc_m > 0 and s.vel_acc_mps > 0


def _valid_frames() -> list[bytes]:
    tx = MavlinkTx()
    enc = mav.MAVLink(None, 1, 1)
    return [
        tx.gps_input(GOOD),
        tx.gps_raw_int(GOOD),
        tx.hil_gps(GOOD),
        enc.highres_imu_encode(1000, 0, 0, -9.8, 0.1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0xFFFF).pack(enc),
        enc.scaled_imu_encode(10, 0, 0, -1000, 10, 0, 0, 0, 0, 0).pack(enc),
        enc.heartbeat_encode(2, 3, 0, 0, 4).pack(enc),
    ]


VALID = _valid_frames()


@FAST
@given(st.binary(max_size=700))
def test_random_bytes_never_raise(data: bytes) -> None:
    """GIVEN random bytes (up to 700),
    WHEN they are fed to a decoder as a stream and as a datagram,
    THEN it never raises and every sample it returns is sane (finite, within the limits,
    GNSS in range with a 3D fix and positive accuracies)."""
    dec = MavlinkDecoder(CFG)
    _sane(dec.feed(data, 0))
    _sane(dec.feed_datagram(data, 0))


@FAST
@given(st.lists(st.binary(min_size=1, max_size=80), min_size=1, max_size=12))
def test_random_stream_chunks_with_markers(chunks: list[bytes]) -> None:
    """GIVEN up to 12 random chunks, each fed after a MAVLink 2 and a MAVLink 1 start marker
    so the parser gets past the prefix scan,
    WHEN they are fed to one decoder as a stream,
    THEN it never raises and every sample it returns is sane."""
    # Bias toward the start markers so the parser goes past the prefix scan.
    dec = MavlinkDecoder(CFG)
    for c in chunks:
        _sane(dec.feed(bytes([0xFD]) + c, 0))
        _sane(dec.feed(bytes([0xFE]) + c, 0))


@FAST
@given(st.sampled_from(VALID), st.integers(min_value=0, max_value=300))
def test_truncated_frames_are_counted_not_decoded(frame: bytes, cut: int) -> None:
    """GIVEN a valid frame (GNSS, IMU or heartbeat) cut anywhere before its last byte,
    WHEN the cut frame is fed as a datagram,
    THEN nothing is decoded and, unless empty, it is counted as truncated or bad prefix."""
    cut = min(cut, len(frame) - 1)
    dec = MavlinkDecoder(CFG)
    assert dec.feed_datagram(frame[:cut], 0) == []
    if cut > 0:
        assert dec.counters.total(["truncated", "bad_prefix"]) >= 1


@FAST
@given(
    st.sampled_from(VALID),
    st.integers(min_value=1, max_value=300),
    st.integers(min_value=1, max_value=255),
)
def test_single_byte_corruption_never_yields_a_wrong_sample(
    frame: bytes, pos: int, xor: int
) -> None:
    """GIVEN a valid frame with one byte after the start marker XOR-ed with a non-zero value,
    WHEN it is fed as a datagram,
    THEN either nothing comes out (and something is counted) or exactly what the clean frame
    gives: a corrupted frame never yields a different sample."""
    pos = pos % (len(frame) - 1) + 1  # keep the start marker
    bad = bytearray(frame)
    bad[pos] ^= xor
    clean = MavlinkDecoder(CFG).feed_datagram(frame, 0)
    dec = MavlinkDecoder(CFG)
    out = dec.feed_datagram(bytes(bad), 0)
    # CRC-16 catches every single-byte error, so either nothing or the original comes out
    # (a corrupted sequence number or length in a trailing-zero-truncated payload is benign).
    assert out == [] or out == clean
    if out == []:
        assert dec.counters.total() >= 1


@FAST
@given(st.binary(max_size=300), st.binary(max_size=300))
def test_good_frame_survives_surrounding_junk(junk1: bytes, junk2: bytes) -> None:
    """GIVEN a GPS_INPUT frame with random junk before and after it in one datagram,
    WHEN the datagram is fed,
    THEN every sample returned is sane and the good fix is among them."""
    frame = MavlinkTx().gps_input(GOOD)
    dec = MavlinkDecoder(CFG)
    out = dec.feed_datagram(junk1 + frame + junk2, 0)
    _sane(out)
    assert GOOD.t_us in [s.t_us for s in out if isinstance(s, GnssSample)]


def _f32_bits(x: float) -> float:
    return float(struct.unpack("<f", struct.pack("<f", x))[0])


@FAST
@given(
    st.lists(
        st.one_of(
            st.floats(allow_nan=True, allow_infinity=True, width=32),
            st.sampled_from([math.nan, math.inf, -math.inf, 1e30, -1e30, 600.0]),
        ),
        min_size=6,
        max_size=6,
    )
)
def test_highres_imu_hostile_values(vals: list[float]) -> None:
    """GIVEN a HIGHRES_IMU with arbitrary float32 accel and gyro values (NaN, inf, huge),
    WHEN it is decoded,
    THEN a sane sample comes out exactly when all values are finite and within the accel and
    gyro limits; otherwise one non-finite / absurd-accel / absurd-gyro rejection is counted."""
    enc = mav.MAVLink(None, 1, 1)
    ax, ay, az, gx, gy, gz = vals
    dec = MavlinkDecoder(CFG)
    frame = enc.highres_imu_encode(5000, ax, ay, az, gx, gy, gz, 0, 0, 0, 0, 0, 0, 0, 0xFFFF)
    out = dec.feed_datagram(frame.pack(enc), 0)
    _sane(out)
    finite = all(math.isfinite(_f32_bits(v)) for v in vals)
    acc = math.sqrt(sum(_f32_bits(v) ** 2 for v in vals[:3])) if finite else math.inf
    gyr = math.sqrt(sum(_f32_bits(v) ** 2 for v in vals[3:])) if finite else math.inf
    plausible = finite and acc <= LIM.max_accel_mps2 and gyr <= LIM.max_gyro_rps
    assert (len(out) == 1) == plausible
    if not plausible:
        assert dec.counters.total(["imu_nonfinite", "imu_absurd_accel", "imu_absurd_gyro"]) == 1


@FAST
@given(
    st.integers(min_value=-(2**31), max_value=2**31 - 1),
    st.integers(min_value=-(2**31), max_value=2**31 - 1),
    st.floats(allow_nan=True, allow_infinity=True, width=32),
    st.floats(allow_nan=True, allow_infinity=True, width=32),
    st.integers(min_value=0, max_value=9),
)
def test_gps_input_hostile_values(lat: int, lon: int, alt: float, vn: float, fix: int) -> None:
    """GIVEN a GPS_INPUT with arbitrary lat/lon integers, float32 altitude and north velocity
    (NaN, inf included) and fix type 0-9,
    WHEN it is decoded,
    THEN a sample comes out only if it is sane, with a 3D fix and lat/lon in range;
    otherwise a rejection is counted."""
    enc = mav.MAVLink(None, 1, 1)
    frame = enc.gps_input_encode(9, 0, 0, 0, 0, fix, lat, lon, alt, 1.0, 1.0, vn, 0.0, 0.0,
                                 0.3, 1.0, 2.0, 9)
    dec = MavlinkDecoder(CFG)
    out = dec.feed_datagram(frame.pack(enc), 0)
    _sane(out)
    if out:
        assert fix >= 3 and abs(lat) <= 900_000_000 and abs(lon) <= 1_800_000_000
    else:
        assert dec.counters.total() > dec.counters["frames_ok"]
