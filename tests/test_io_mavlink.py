"""MAVLink adapter: simulator encoders -> wire -> navd decoder, units, encoders, links."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import os
import socket
from collections.abc import Iterable

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from firmware_sim.transport.mavlink_tx import MavlinkTx
from navd.io.common import Sample
from navd.io.mavlink import (
    MavlinkDecoder,
    MavlinkEncoder,
    MavlinkInputConfig,
    MavlinkLink,
    MavlinkSender,
    open_mavlink,
    parse_mavlink_url,
)
from navd.types import FixType, GnssSample, ImuSample, NavSolution

G0 = 9.80665
ALL_IMU = frozenset({"HIGHRES_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3", "RAW_IMU"})
ALL_GNSS = frozenset({"GPS_RAW_INT", "GPS_INPUT", "HIL_GPS"})


def cfg(**kw: object) -> MavlinkInputConfig:
    base: dict[str, object] = {"imu_messages": ALL_IMU, "gnss_messages": ALL_GNSS}
    base.update(kw)
    return MavlinkInputConfig(**base)  # type: ignore[arg-type]


def feed_all(dec: MavlinkDecoder, frames: Iterable[bytes]) -> list[Sample]:
    out: list[Sample] = []
    for f in frames:
        out += dec.feed_datagram(f, 0)
    return out


def imu_seq(n: int, dt_us: int = 1000, t0: int = 5_000_000) -> list[ImuSample]:
    out = []
    for i in range(n):
        dt = dt_us * 1e-6
        out.append(
            ImuSample(
                t0 + i * dt_us, dt_us,
                0.3 * dt, -0.2 * dt + 1e-3 * i * dt, 0.05 * dt,
                1.2 * dt, -0.4 * dt, -9.79 * dt,
            )
        )
    return out


def gnss(**kw: object) -> GnssSample:
    base: dict[str, object] = dict(
        t_us=7_000_000, lat_rad=math.radians(47.3977), lon_rad=math.radians(-122.2),
        alt_m=512.25, vel_n=3.0, vel_e=4.0, vel_d=-0.5, h_acc_m=1.25, v_acc_m=2.5,
        vel_acc_mps=0.2, fix_type=FixType.FIX_3D,
    )
    base.update(kw)
    return GnssSample(**base)  # type: ignore[arg-type]


def solution(**kw: object) -> NavSolution:
    base: dict[str, object] = dict(
        t_us=12_345_678,
        quat_nb=(0.9, 0.1, -0.2, 0.3),
        roll_rad=0.1, pitch_rad=-0.2, yaw_rad=-math.pi / 2,
        lat_rad=math.radians(47.3977), lon_rad=math.radians(8.5456), alt_m=600.0,
        vel_n=(1.5, -2.25, 0.5), att_sd_rad=(0.01, 0.01, 0.05),
        gyro_bias_rps=(0.0, 0.0, 0.0), accel_bias_mps2=(0.0, 0.0, 0.0),
        heading_aligned=True, rate_b=(0.01, -0.02, 0.03),
    )
    base.update(kw)
    return NavSolution(**base)  # type: ignore[arg-type]


def parse(frames: bytes) -> list[object]:
    p = mav.MAVLink(None)
    return list(p.parse_buffer(frames) or [])


def assert_imu_close(got: ImuSample, want: ImuSample, rel: float, abs_: float = 0.0) -> None:
    assert got.t_us == want.t_us and got.dt_us == want.dt_us
    for name in ("dtheta_x", "dtheta_y", "dtheta_z", "dvel_x", "dvel_y", "dvel_z"):
        assert getattr(got, name) == pytest.approx(getattr(want, name), rel=rel, abs=abs_), name


# -- IMU round trips ---------------------------------------------------------------------------


def test_highres_imu_round_trip_first_sample_dropped_and_counted() -> None:
    """GIVEN 50 IMU samples at 1 kHz sent as HIGHRES_IMU and a decoder with no nominal IMU rate,
    WHEN every frame is decoded,
    THEN the first sample (no interval yet) is dropped and counted as imu_first_sample,
    and the other 49 match the source to float32 precision."""
    tx, dec = MavlinkTx(), MavlinkDecoder(cfg())
    src = imu_seq(50)
    out = feed_all(dec, (tx.highres_imu(s) for s in src))
    assert len(out) == 49
    assert dec.counters["imu_first_sample"] == 1
    for got, want in zip(out, src[1:], strict=True):
        assert isinstance(got, ImuSample)
        assert_imu_close(got, want, rel=1e-6)  # float32 on the wire


def test_highres_imu_nominal_rate_keeps_first_sample() -> None:
    """GIVEN a decoder configured with a nominal IMU rate of 1000 Hz,
    WHEN three HIGHRES_IMU frames are decoded,
    THEN all three samples come out, the first with dt 1000 us from the nominal rate,
    and imu_first_sample is still counted once."""
    tx, dec = MavlinkTx(), MavlinkDecoder(cfg(nominal_imu_rate_hz=1000.0))
    src = imu_seq(3)
    out = feed_all(dec, (tx.highres_imu(s) for s in src))
    assert [s.t_us for s in out] == [s.t_us for s in src]
    assert out[0].dt_us == 1000 and dec.counters["imu_first_sample"] == 1


def test_highres_imu_needs_accel_and_gyro_updated_bits() -> None:
    """GIVEN three HIGHRES_IMU frames, the middle one flagging only the accelerometer as updated,
    WHEN they are decoded,
    THEN the middle one is skipped and counted as imu_fields_not_updated,
    and the third sample spans both intervals (dt 2000 us, zero-order hold)."""
    tx, dec = MavlinkTx(), MavlinkDecoder(cfg(nominal_imu_rate_hz=1000.0))
    src = imu_seq(3)
    out = feed_all(dec, [tx.highres_imu(src[0]), tx.highres_imu(src[1], fields_updated=0x7),
                         tx.highres_imu(src[2])])
    # The stale message is skipped; the next one covers both intervals (zero-order hold).
    assert [s.t_us for s in out] == [src[0].t_us, src[2].t_us]
    assert isinstance(out[1], ImuSample) and out[1].dt_us == 2000
    assert dec.counters["imu_fields_not_updated"] == 1


def test_scaled_imu_units_mg_and_mrad() -> None:
    """GIVEN two SCALED_IMU frames 20 ms apart, the second carrying accel in mG and gyro in mrad/s,
    WHEN they are decoded,
    THEN one sample comes out at 1.02 s with dt 20 ms, reading 1000 mG as 1 g (not 1 m/s^2)
    and 1000 mrad/s as 1 rad/s, integrated over the 20 ms."""
    enc = mav.MAVLink(None, 1, 1)
    dec = MavlinkDecoder(cfg())
    frames = [
        enc.scaled_imu_encode(1000, 0, 0, 0, 0, 0, 0, 0, 0, 0).pack(enc),
        enc.scaled_imu_encode(1020, 1000, -500, -1000, 1000, 0, -250, 0, 0, 0).pack(enc),
    ]
    (s,) = feed_all(dec, frames)
    assert isinstance(s, ImuSample)
    assert (s.t_us, s.dt_us) == (1_020_000, 20_000)
    assert s.dvel_x == pytest.approx(G0 * 0.02)  # 1000 mG = 1 g, not 1 m/s^2
    assert s.dvel_y == pytest.approx(-0.5 * G0 * 0.02)
    assert s.dtheta_x == pytest.approx(1.0 * 0.02)  # 1000 mrad/s = 1 rad/s
    assert s.dtheta_z == pytest.approx(-0.25 * 0.02)


def test_scaled_imu_round_trip_and_time_boot_ms_wrap() -> None:
    """GIVEN 40 IMU samples at 1 kHz sent as SCALED_IMU, starting 20 ms before time_boot_ms wraps,
    WHEN they are decoded,
    THEN 39 samples come out with dt 1000 us and the source timestamps, monotonic past the wrap,
    and values within the mG / mrad/s quantisation."""
    tx, dec = MavlinkTx(), MavlinkDecoder(cfg())
    t0 = (2**32 - 20) * 1000  # 20 ms before time_boot_ms wraps
    src = imu_seq(40, dt_us=1000, t0=t0)
    out = feed_all(dec, (tx.scaled_imu(s) for s in src))
    assert len(out) == 39
    assert all(s.dt_us == 1000 for s in out)
    assert [s.t_us for s in out] == [s.t_us for s in src[1:]]  # monotonic past the wrap
    for got, want in zip(out, src[1:], strict=True):
        assert isinstance(got, ImuSample)
        assert_imu_close(got, want, rel=0, abs_=1.0e-3 * 1e-3 + 1e-3 * G0 * 1e-3)


def test_scaled_imu2_is_instance_1() -> None:
    """GIVEN two SCALED_IMU2 frames,
    WHEN they are decoded with the default imu_id 0 and with imu_id 1,
    THEN the default decoder yields nothing and the imu_id 1 decoder yields one sample
    with dvel_z of -1000 mG over 1 ms."""
    enc = mav.MAVLink(None, 1, 1)
    frames = [enc.scaled_imu2_encode(t, 0, 0, -1000, 0, 0, 0, 0, 0, 0).pack(enc) for t in (10, 11)]
    assert feed_all(MavlinkDecoder(cfg()), frames) == []  # default imu_id=0
    out = feed_all(MavlinkDecoder(cfg(imu_id=1)), frames)
    assert len(out) == 1 and isinstance(out[0], ImuSample)
    assert out[0].dvel_z == pytest.approx(-G0 * 1e-3)


def test_raw_imu_needs_scale_then_round_trips() -> None:
    """GIVEN five RAW_IMU frames encoded with known gyro and accel LSB scales,
    WHEN they are decoded without the scales configured, and again with them,
    THEN the first decoder yields nothing and counts all five as raw_imu_unscaled,
    and the second yields four samples matching the source within half an accel LSB."""
    tx = MavlinkTx()
    src = imu_seq(5)
    gs, as_ = 1e-4, 1e-3
    frames = [tx.raw_imu(s, gs, as_) for s in src]
    dec = MavlinkDecoder(cfg())
    assert feed_all(dec, frames) == []
    assert dec.counters["raw_imu_unscaled"] == 5
    dec = MavlinkDecoder(cfg(raw_gyro_rps_per_lsb=gs, raw_accel_mps2_per_lsb=as_))
    out = feed_all(dec, frames)
    assert len(out) == 4
    for got, want in zip(out, src[1:], strict=True):
        assert isinstance(got, ImuSample)
        assert_imu_close(got, want, rel=0, abs_=0.5 * as_ * 1e-3 + 1e-12)


def test_only_configured_imu_message_feeds() -> None:
    """GIVEN every IMU sample sent both as HIGHRES_IMU and as SCALED_IMU,
    WHEN the frames are decoded with the default config (HIGHRES_IMU only),
    THEN one sample per source sample (after the first) comes out: SCALED_IMU is ignored."""
    tx = MavlinkTx()
    src = imu_seq(3)
    frames = [f for s in src for f in (tx.highres_imu(s), tx.scaled_imu(s))]
    out = feed_all(MavlinkDecoder(MavlinkInputConfig()), frames)  # default: HIGHRES_IMU only
    assert [s.t_us for s in out] == [s.t_us for s in src[1:]]


# -- GNSS round trips --------------------------------------------------------------------------


def test_gps_input_round_trip_with_geoid_separation() -> None:
    """GIVEN an RTK-fixed GNSS sample sent as GPS_INPUT with MSL altitude (geoid separation 47.5 m),
    WHEN it is decoded with the same geoid separation configured,
    THEN time, fix type, lat/lon (to 1e-7 deg), ellipsoid altitude (to 1 mm),
    velocity and accuracies all match the source."""
    g = gnss(fix_type=FixType.RTK_FIXED)
    tx, dec = MavlinkTx(), MavlinkDecoder(cfg(geoid_sep_m=47.5))
    (s,) = feed_all(dec, [tx.gps_input(g, geoid_sep_m=47.5)])
    assert isinstance(s, GnssSample)
    assert s.t_us == g.t_us and s.fix_type == FixType.RTK_FIXED
    assert s.lat_rad == pytest.approx(g.lat_rad, abs=1e-7 * math.pi / 180)
    assert s.lon_rad == pytest.approx(g.lon_rad, abs=1e-7 * math.pi / 180)
    assert s.alt_m == pytest.approx(g.alt_m, abs=1e-3)  # float32 MSL + N = ellipsoid
    assert (s.vel_n, s.vel_e, s.vel_d) == pytest.approx((3.0, 4.0, -0.5))
    assert (s.h_acc_m, s.v_acc_m, s.vel_acc_mps) == pytest.approx((1.25, 2.5, 0.2))


def test_gps_input_ignore_flags_give_nan_and_dop_fallback() -> None:
    """GIVEN a GPS_INPUT flagging vertical velocity, horizontal and speed accuracy as ignored,
    with hdop 0.9, and a decoder with UERE 4 m and default velocity accuracy 0.7 m/s,
    WHEN it is decoded,
    THEN vel_d is NaN (vel_n kept), h_acc is hdop x UERE (hdop unitless, not x100)
    and vel_acc is the configured default."""
    tx = MavlinkTx()
    flags = (mav.GPS_INPUT_IGNORE_FLAG_VEL_VERT | mav.GPS_INPUT_IGNORE_FLAG_HORIZONTAL_ACCURACY
             | mav.GPS_INPUT_IGNORE_FLAG_SPEED_ACCURACY)
    dec = MavlinkDecoder(cfg(uere_m=4.0, default_vel_acc_mps=0.7))
    (s,) = feed_all(dec, [tx.gps_input(gnss(), ignore_flags=flags, hdop=0.9)])
    assert isinstance(s, GnssSample)
    assert math.isnan(s.vel_d) and s.vel_n == pytest.approx(3.0)
    assert s.h_acc_m == pytest.approx(0.9 * 4.0)  # GPS_INPUT hdop is unitless, not x100
    assert s.vel_acc_mps == pytest.approx(0.7)


def test_gps_raw_int_units_velocity_from_course_and_no_vertical() -> None:
    """GIVEN a GNSS sample sent as GPS_RAW_INT,
    WHEN it is decoded,
    THEN altitude comes from alt_ellipsoid, north/east velocity is rebuilt from speed and course
    (within the cdeg quantisation), vel_d is NaN and the accuracies match."""
    tx, dec = MavlinkTx(), MavlinkDecoder(cfg())
    (s,) = feed_all(dec, [tx.gps_raw_int(gnss())])
    assert isinstance(s, GnssSample)
    assert s.alt_m == pytest.approx(512.25, abs=1e-3)  # alt_ellipsoid preferred
    assert (s.vel_n, s.vel_e) == pytest.approx((3.0, 4.0), abs=2e-4)  # cog cdeg quantised
    assert math.isnan(s.vel_d)
    assert (s.h_acc_m, s.v_acc_m, s.vel_acc_mps) == pytest.approx((1.25, 2.5, 0.2))


def test_gps_raw_int_msl_fallback_and_eph_is_dop_not_metres() -> None:
    """GIVEN a GPS_RAW_INT at 100 m MSL with no alt_ellipsoid, eph 150, epv 250, no h_acc and
    unknown velocity, and a decoder with geoid separation 47 m and UERE 3 m,
    WHEN it is decoded,
    THEN altitude is 147 m (counted as gnss_alt_from_msl), h_acc/v_acc are 1.5 and 2.5 x UERE
    (eph/epv are DOP x100, not metres), velocity is NaN and latitude is kept."""
    enc = mav.MAVLink(None, 1, 1)
    # alt 100 m MSL, no alt_ellipsoid, eph 150 (HDOP 1.5), h_acc 0 (unknown), vel unknown.
    frame = enc.gps_raw_int_encode(
        1_000_000, 3, 473977000, 85456000, 100_000, 150, 250, 65535, 65535, 10
    ).pack(enc)
    dec = MavlinkDecoder(cfg(geoid_sep_m=47.0, uere_m=3.0))
    (s,) = feed_all(dec, [frame])
    assert isinstance(s, GnssSample)
    assert s.alt_m == pytest.approx(147.0)
    assert dec.counters["gnss_alt_from_msl"] == 1
    assert s.h_acc_m == pytest.approx(4.5) and s.v_acc_m == pytest.approx(7.5)
    assert math.isnan(s.vel_n) and math.isnan(s.vel_e)
    assert s.lat_rad == pytest.approx(math.radians(47.3977))


def test_hil_gps_velocity_cm_per_s() -> None:
    """GIVEN a GNSS sample with velocity (-12.34, 0.56, 1.5) m/s sent as HIL_GPS (cm/s on the wire),
    WHEN it is decoded with the same geoid separation,
    THEN the velocity comes back exactly and the ellipsoid altitude to 1 mm."""
    tx, dec = MavlinkTx(), MavlinkDecoder(cfg(geoid_sep_m=10.0))
    (s,) = feed_all(dec, [tx.hil_gps(gnss(vel_n=-12.34, vel_e=0.56, vel_d=1.5), geoid_sep_m=10.0)])
    assert isinstance(s, GnssSample)
    assert (s.vel_n, s.vel_e, s.vel_d) == pytest.approx((-12.34, 0.56, 1.5), abs=1e-9)
    assert s.alt_m == pytest.approx(512.25, abs=1e-3)


# -- rejections --------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("kw", "reason"),
    [
        ({"fix_type": FixType.FIX_2D}, "gnss_no_fix"),
        ({"lat_rad": math.radians(91.0)}, "gnss_latlon_range"),
        ({"alt_m": 5.0e5}, "gnss_absurd_alt"),
        ({"vel_n": 3000.0}, "gnss_absurd_velocity"),
        ({"vel_e": math.nan}, "gnss_nonfinite"),
        ({"h_acc_m": math.inf}, "gnss_nonfinite"),
        ({"t_us": 0}, "gnss_no_timestamp"),
        # a uint64 time beyond int64 (issue 16 item 2's frame): no clock, a crafted frame
        ({"t_us": (1 << 63) + 1}, "gnss_time_out_of_range"),
        ({"t_us": (1 << 53) + 1}, "gnss_time_out_of_range"),
    ],
)
def test_gps_input_rejections_are_counted(kw: dict[str, object], reason: str) -> None:
    """GIVEN a GPS_INPUT with one bad field (no 3D fix, latitude out of range, absurd altitude
    or velocity, a non-finite value, zero time, or a time beyond 2^53 / 2^63 us),
    WHEN it is decoded,
    THEN no sample comes out and the counter for that reason is 1."""
    tx, dec = MavlinkTx(), MavlinkDecoder(cfg())
    assert feed_all(dec, [tx.gps_input(gnss(**kw))]) == []
    assert dec.counters[reason] == 1


@pytest.mark.parametrize(
    ("rates", "reason"),
    [
        ((math.nan, 0, 0, 0, 0, -9.8), "imu_nonfinite"),
        ((0, 0, 0, math.inf, 0, -9.8), "imu_nonfinite"),
        ((0, 0, 0, 0, 0, -60 * G0), "imu_absurd_accel"),
        ((40.0, 0, 0, 0, 0, -9.8), "imu_absurd_gyro"),
    ],
)
def test_highres_imu_rejections_are_counted(
    rates: tuple[float, ...], reason: str
) -> None:
    """GIVEN a HIGHRES_IMU with a non-finite value, a 60 g accel or a 40 rad/s gyro, between two
    good frames 2 ms apart,
    WHEN the three are decoded,
    THEN the bad frame is counted under its reason, and the single output sample spans the
    whole 2000 us: the bad sample does not cut the time line."""
    enc = mav.MAVLink(None, 1, 1)
    g = rates[:3]
    a = rates[3:]
    bad = enc.highres_imu_encode(2000, *a, *g, 0, 0, 0, 0, 0, 0, 0, 0xFFFF).pack(enc)
    good = [enc.highres_imu_encode(t, 0, 0, -9.8, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0xFFFF).pack(enc)
            for t in (1000, 3000)]
    dec = MavlinkDecoder(cfg())
    out = feed_all(dec, [good[0], bad, good[1]])
    assert dec.counters[reason] == 1
    # The bad sample does not cut the time line: the next one spans its interval.
    assert len(out) == 1 and isinstance(out[0], ImuSample) and out[0].dt_us == 2000


def test_imu_gap_backwards_and_duplicate_time() -> None:
    """GIVEN HIGHRES_IMU frames a, b, b again, c, one 0.5 s after c, and one before a,
    WHEN they are decoded,
    THEN only b and c come out, and the duplicate time, the gap and the backwards step
    are each counted once."""
    tx, dec = MavlinkTx(), MavlinkDecoder(cfg())
    a, b, c = imu_seq(3)
    far = ImuSample(c.t_us + 500_000, 1000, 0, 0, 0, 0, 0, -0.0098)
    back = ImuSample(a.t_us - 10_000, 1000, 0, 0, 0, 0, 0, -0.0098)
    out = feed_all(dec, [tx.highres_imu(s) for s in (a, b, b, c, far, back)])
    assert [s.t_us for s in out] == [b.t_us, c.t_us]
    assert dec.counters["imu_duplicate_time"] == 1
    assert dec.counters["imu_gap"] == 1
    assert dec.counters["imu_time_backwards"] == 1


def test_zero_time_is_rejected_unless_receive_time_is_used() -> None:
    """GIVEN two HIGHRES_IMU frames with time 0,
    WHEN they are decoded by default, and by a decoder using receive time (1000 and 3500 us),
    THEN the first yields nothing and counts both as imu_no_timestamp, and the second yields
    one sample stamped 3500 us with dt 2500 us."""
    enc = mav.MAVLink(None, 1, 1)
    frames = [enc.highres_imu_encode(0, 0, 0, -9.8, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0xFFFF).pack(enc)
              for _ in range(2)]
    dec = MavlinkDecoder(cfg())
    assert feed_all(dec, frames) == [] and dec.counters["imu_no_timestamp"] == 2
    dec = MavlinkDecoder(cfg(use_receive_time=True))
    out = dec.feed_datagram(frames[0], 1_000) + dec.feed_datagram(frames[1], 3_500)
    assert len(out) == 1 and out[0].t_us == 3_500 and isinstance(out[0], ImuSample)
    assert out[0].dt_us == 2_500


def test_allowlist_and_sequence_loss() -> None:
    """GIVEN a decoder allowing only system/component (1, 1), a frame from (2, 1) among the
    frames of (1, 1), and one frame of (1, 1) lost on the wire,
    WHEN the frames are decoded,
    THEN only (1, 1)'s fixes come out, with not_allowed and seq_lost each counted once."""
    tx_ok, tx_other = MavlinkTx(sysid=1, compid=1), MavlinkTx(sysid=2, compid=1)
    dec = MavlinkDecoder(cfg(allow=frozenset({(1, 1)})))
    frames = [tx_ok.gps_input(gnss(t_us=1)), tx_other.gps_input(gnss(t_us=2)),
              tx_ok.gps_input(gnss(t_us=3))]
    tx_ok.gps_input(gnss(t_us=4))  # a frame lost on the wire
    frames.append(tx_ok.gps_input(gnss(t_us=5)))
    out = feed_all(dec, frames)
    assert [s.t_us for s in out] == [1, 3, 5]
    assert dec.counters["not_allowed"] == 1
    assert dec.counters["seq_lost"] == 1


def test_repeated_fix_is_dropped() -> None:
    """GIVEN GPS_RAW_INT frames with time 100 three times then 200 (ArduPilot re-sending a fix),
    WHEN they are decoded,
    THEN each time comes out once and the two repeats are counted as gnss_repeat."""
    # ArduPilot re-sends the last fix (same time_usec) when streaming faster than the GPS.
    tx, dec = MavlinkTx(), MavlinkDecoder(cfg())
    frames = [tx.gps_raw_int(gnss(t_us=t)) for t in (100, 100, 100, 200)]
    assert [s.t_us for s in feed_all(dec, frames)] == [100, 200]
    assert dec.counters["gnss_repeat"] == 2


# -- framing -----------------------------------------------------------------------------------


def test_stream_split_at_every_byte_boundary() -> None:
    """GIVEN a byte stream of three GPS_INPUT frames,
    WHEN it is fed to a fresh decoder in two pieces, cut at every byte in turn,
    THEN all three fixes come out in order for every cut."""
    tx = MavlinkTx()
    blob = b"".join(tx.gps_input(gnss(t_us=1_000_000 + i)) for i in range(3))
    for cut in range(1, len(blob)):
        dec = MavlinkDecoder(cfg())
        out = dec.feed(blob[:cut], 0) + dec.feed(blob[cut:], 0)
        assert [s.t_us for s in out] == [1_000_000, 1_000_001, 1_000_002], cut


def test_stream_resyncs_after_a_lost_byte() -> None:
    """GIVEN a stream of four GPS_INPUT frames with one byte lost inside frame 1,
    WHEN it is fed to the decoder,
    THEN frames 0, 2 and 3 come out (frame 2 is not skipped with the damaged one)
    and a bad CRC is counted."""
    tx = MavlinkTx()
    frames = [tx.gps_input(gnss(t_us=1_000_000 + i)) for i in range(4)]
    damaged = frames[1][:20] + frames[1][21:]  # one byte lost inside frame 1
    dec = MavlinkDecoder(cfg())
    out = dec.feed(frames[0] + damaged + frames[2] + frames[3], 0)
    # pymavlink alone would skip frame 2 together with the damaged frame.
    assert [s.t_us for s in out] == [1_000_000, 1_000_002, 1_000_003]
    assert dec.counters["bad_crc"] >= 1


def test_datagram_with_truncated_frame_then_good_frame() -> None:
    """GIVEN a datagram with the first 30 bytes of one frame followed by a whole frame,
    and then a datagram with a frame missing its last 3 bytes,
    WHEN each is fed as a datagram,
    THEN the whole frame comes out, the cut one is counted as truncated, and a following
    good datagram decodes (no state left behind)."""
    tx = MavlinkTx()
    f1, f2 = tx.gps_input(gnss(t_us=1)), tx.gps_input(gnss(t_us=2))
    dec = MavlinkDecoder(cfg())
    out = dec.feed_datagram(f1[:30] + f2, 0)
    assert [s.t_us for s in out] == [2]
    out = dec.feed_datagram(f1[:-3], 0)
    assert out == [] and dec.counters["truncated"] >= 1
    f3 = tx.gps_input(gnss(t_us=3))
    assert [s.t_us for s in dec.feed_datagram(f3, 0)] == [3]  # no state left behind


def test_crc_corruption_is_counted() -> None:
    """GIVEN a GPS_INPUT frame with its last CRC byte flipped,
    WHEN it is fed as a datagram,
    THEN nothing comes out and bad_crc is counted once."""
    tx = MavlinkTx()
    f = bytearray(tx.gps_input(gnss()))
    f[-1] ^= 0x55
    dec = MavlinkDecoder(cfg())
    assert dec.feed_datagram(bytes(f), 0) == []
    assert dec.counters["bad_crc"] == 1


def test_mavlink1_frames_are_accepted() -> None:
    """GIVEN a GPS_INPUT packed as a MAVLink 1 frame,
    WHEN it is decoded,
    THEN one GNSS sample comes out with its east velocity."""
    enc = mav.MAVLink(None, 1, 1)
    m = enc.gps_input_encode(5, 0, 0, 0, 0, 3, 473977000, 85456000, 400.0, 1.0, 1.0,
                             1.0, 2.0, 3.0, 0.3, 1.0, 2.0, 9)
    (s,) = feed_all(MavlinkDecoder(cfg()), [m.pack(enc, force_mavlink1=True)])
    assert isinstance(s, GnssSample) and s.vel_e == pytest.approx(2.0)


# -- encoders ----------------------------------------------------------------------------------


def test_encoders_attitude_quaternion_heartbeat_global_position() -> None:
    """GIVEN an encoder (sysid 42, compid 191, geoid separation 47 m) and a solution at 600 m,
    WHEN HEARTBEAT, ATTITUDE, ATTITUDE_QUATERNION and GLOBAL_POSITION_INT (home 500 m) are
    encoded and parsed by pymavlink,
    THEN they are MAVLink 2 with our ids and sequence 0..3, and carry the solution's angles,
    rates, quaternion, lat/lon, MSL/relative altitude in mm, velocity in cm/s and heading."""
    enc = MavlinkEncoder(sysid=42, compid=191, geoid_sep_m=47.0)
    sol = solution()
    blob = (enc.encode_heartbeat() + enc.encode_attitude(sol, 1234)
            + enc.encode_attitude_quaternion(sol, 1234)
            + enc.encode_global_position_int(sol, 1234, home_alt_m=500.0))
    assert blob[0] == 0xFD  # MAVLink 2
    hb, att, q, gp = parse(blob)
    for i, m in enumerate((hb, att, q, gp)):
        assert (m.get_srcSystem(), m.get_srcComponent(), m.get_seq()) == (42, 191, i)  # type: ignore[attr-defined]
    assert hb.type == mav.MAV_TYPE_ONBOARD_CONTROLLER  # type: ignore[attr-defined]
    assert hb.autopilot == mav.MAV_AUTOPILOT_INVALID  # type: ignore[attr-defined]
    assert att.time_boot_ms == 1234  # type: ignore[attr-defined]
    assert (att.roll, att.pitch, att.yaw) == pytest.approx((0.1, -0.2, -math.pi / 2))  # type: ignore[attr-defined]
    assert (att.rollspeed, att.pitchspeed, att.yawspeed) == pytest.approx((0.01, -0.02, 0.03))  # type: ignore[attr-defined]
    assert (q.q1, q.q2, q.q3, q.q4) == pytest.approx((0.9, 0.1, -0.2, 0.3))  # type: ignore[attr-defined]
    assert gp.lat == round(47.3977e7) and gp.lon == round(8.5456e7)  # type: ignore[attr-defined]
    assert gp.alt == 553_000 and gp.relative_alt == 53_000  # type: ignore[attr-defined]
    assert (gp.vx, gp.vy, gp.vz) == (150, -225, 50)  # type: ignore[attr-defined]
    assert gp.hdg == 27000  # yaw -90 deg = west  # type: ignore[attr-defined]


def test_global_position_rejects_non_finite() -> None:
    """GIVEN a solution with a NaN latitude,
    WHEN GLOBAL_POSITION_INT is encoded,
    THEN ValueError is raised."""
    with pytest.raises(ValueError):
        MavlinkEncoder().encode_global_position_int(solution(lat_rad=math.nan), 0)


def test_url_parsing() -> None:
    """GIVEN udpin/udp/udpout/serial link URLs and malformed ones,
    WHEN they are parsed,
    THEN udp means udpin, udpout keeps host and port, "device,baud" gives a serial link,
    and a missing host, bad port, unknown scheme or bad baud raise ValueError."""
    assert parse_mavlink_url("udpin:0.0.0.0:14550").kind == "udpin"
    assert parse_mavlink_url("udp:127.0.0.1:14550").kind == "udpin"
    out = parse_mavlink_url("udpout:10.0.0.2:14551")
    assert (out.kind, out.host, out.port) == ("udpout", "10.0.0.2", 14551)
    ser = parse_mavlink_url("/dev/ttyUSB0,921600")
    assert (ser.kind, ser.device, ser.baud) == ("serial", "/dev/ttyUSB0", 921600)
    for bad in ("udpin:14550", "udpin:host:x", "bogus:1:2", "/dev/ttyS0,fast"):
        with pytest.raises(ValueError):
            parse_mavlink_url(bad)


# -- links -------------------------------------------------------------------------------------


async def _wait_for(pred: object, timeout_s: float = 3.0) -> None:
    assert callable(pred)
    async with asyncio.timeout(timeout_s):
        while not pred():
            await asyncio.sleep(0.005)


def test_udp_loopback_samples_and_replies() -> None:
    """GIVEN a udpin link and a udpout link to it on loopback,
    WHEN 100 HIGHRES_IMU frames are sent, then the udpin side sends a solution, a heartbeat
    and runs its periodic heartbeat,
    THEN udpin refuses to send before it has a peer, receives the 99 samples in order,
    and its replies (including the periodic heartbeats) reach the last sender."""
    async def main() -> None:
        got: list[Sample] = []
        rx = await MavlinkLink.open("udpin:127.0.0.1:0", MavlinkDecoder(cfg()), got.append)
        port = rx.local_address[1] if rx.local_address else 0
        replies = MavlinkDecoder(cfg())
        tx = await MavlinkLink.open(f"udpout:127.0.0.1:{port}", replies, None)
        try:
            assert not rx.send(b"x") and rx.counters["tx_no_peer"] == 1  # nobody yet
            sim = MavlinkTx()
            src = imu_seq(100)
            for s in src:
                assert tx.send(sim.highres_imu(s))
            await _wait_for(lambda: len(got) >= 99)
            assert [s.t_us for s in got] == [s.t_us for s in src[1:]]
            # udpin answers the last sender, like pymavlink.
            sender = MavlinkSender(rx, MavlinkEncoder(sysid=9))
            sender.send_solution(solution())
            assert sender.send_heartbeat()
            await _wait_for(lambda: replies.counters["frames_ok"] >= 3)
            before = replies.counters["frames_ok"]
            hb_task = asyncio.create_task(sender.run_heartbeat(period_s=0.01))
            await _wait_for(lambda: replies.counters["frames_ok"] >= before + 3)
            hb_task.cancel()
        finally:
            rx.close()
            tx.close()

    asyncio.run(main())


def test_pymavlink_client_sees_attitude() -> None:
    """GIVEN a stock pymavlink udpin connection (what mavlogdump.py uses),
    WHEN our encoder (sysid 7) sends it ATTITUDE frames,
    THEN it decodes an ATTITUDE from system 7 with our roll, pitch and yaw."""
    from pymavlink import mavutil

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}")
    try:
        enc = MavlinkEncoder(sysid=7)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as out:
            m = None
            for i in range(30):
                out.sendto(enc.encode_attitude(solution(), 1000 + i), ("127.0.0.1", port))
                m = conn.recv_match(type="ATTITUDE", blocking=True, timeout=0.1)
                if m is not None:
                    break
        assert m is not None, "pymavlink did not receive ATTITUDE"
        assert m.get_srcSystem() == 7
        assert (m.roll, m.pitch, m.yaw) == pytest.approx((0.1, -0.2, -math.pi / 2))
    finally:
        conn.close()


def test_serial_link_on_a_pty() -> None:
    """GIVEN a serial link opened on a pseudo-terminal at 921600 baud,
    WHEN five GPS_INPUT frames are written to the other end in two pieces split mid-frame,
    and the link sends a heartbeat,
    THEN the five fixes come out in order and the other end reads back the heartbeat bytes."""
    async def main() -> None:
        master, slave = os.openpty()
        path = os.ttyname(slave)
        got: list[Sample] = []
        link = await MavlinkLink.open(f"{path},921600", MavlinkDecoder(cfg()), got.append)
        try:
            sim = MavlinkTx()
            blob = b"".join(sim.gps_input(gnss(t_us=100 + i)) for i in range(5))
            os.write(master, blob[:37])
            os.write(master, blob[37:])
            await _wait_for(lambda: len(got) == 5)
            assert [s.t_us for s in got] == [100, 101, 102, 103, 104]
            hb = MavlinkEncoder().encode_heartbeat()
            assert link.send(hb)
            loop = asyncio.get_running_loop()
            data = b""
            async with asyncio.timeout(3):
                while len(data) < len(hb):
                    data += await loop.run_in_executor(None, os.read, master, 256)
            assert data == hb
        finally:
            link.close()
            await asyncio.sleep(0)
            os.close(master)
            os.close(slave)

    asyncio.run(main())


def test_tcp_client_link() -> None:
    """GIVEN a TCP server that sends three GPS_INPUT frames and then reads,
    WHEN navd opens a tcp: link to it and sends a heartbeat,
    THEN the three fixes come out in order and the server receives exactly the heartbeat."""
    async def main() -> None:
        sim = MavlinkTx()
        received = bytearray()
        done = asyncio.Event()

        async def serve(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            for i in range(3):
                writer.write(sim.gps_input(gnss(t_us=10 + i)))
                await writer.drain()
            received.extend(await reader.read(64))
            done.set()
            writer.close()

        server = await asyncio.start_server(serve, "127.0.0.1", 0)
        port = server.sockets[0].getsockname()[1]
        got: list[Sample] = []
        link = await open_mavlink(f"tcp:127.0.0.1:{port}", MavlinkDecoder(cfg()), got.append)
        try:
            await _wait_for(lambda: len(got) == 3)
            hb = MavlinkEncoder().encode_heartbeat()
            assert link.send(hb)
            async with asyncio.timeout(3):
                await done.wait()
            assert bytes(received) == hb
            assert [s.t_us for s in got] == [10, 11, 12]
        finally:
            link.close()
            server.close()
            await server.wait_closed()

    asyncio.run(main())


def test_tcp_link_reopens_after_the_peer_drops_and_returns(
        caplog: pytest.LogCaptureFixture) -> None:
    """GIVEN a TCP peer that sends two fixes per connection then closes (the first ending in a
    partial frame), and a link reopening with a growing delay,
    WHEN the peer is gone for 0.4 s and then returns on the same port, and the link is closed,
    THEN no reopen succeeds while it is gone ("reopen failed" logged), the link reopens and
    decodes 100, 101, 200, 201, and after close it makes no more attempts."""
    caplog.set_level(logging.INFO, logger="navd")

    async def main() -> None:
        sim = MavlinkTx()
        conns = 0

        async def serve(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            nonlocal conns
            conns += 1
            base = 100 * conns
            # a partial frame at the end of the first connection must not poison the next
            blob = b"".join(sim.gps_input(gnss(t_us=base + i)) for i in range(2))
            writer.write(blob + (sim.gps_input(gnss(t_us=base + 9))[:20] if conns == 1 else b""))
            await writer.drain()
            writer.close()

        server = await asyncio.start_server(serve, "127.0.0.1", 0)
        port = server.sockets[0].getsockname()[1]
        got: list[Sample] = []
        dec = MavlinkDecoder(cfg())
        link = await open_mavlink(f"tcp:127.0.0.1:{port}", dec, got.append)
        link.reconnect_delays_s = (0.05, 0.1)
        try:
            await _wait_for(lambda: len(got) >= 2)
            # the peer goes away entirely: reopening fails until it is back
            server.close()
            await server.wait_closed()
            await _wait_for(lambda: dec.counters["link_lost"] >= 1)
            await asyncio.sleep(0.4)
            assert dec.counters["link_reopened"] == 0
            server = await asyncio.start_server(serve, "127.0.0.1", port)
            await _wait_for(lambda: len(got) >= 4, timeout_s=5.0)
            assert [s.t_us for s in got] == [100, 101, 200, 201]
            assert dec.counters["link_reopened"] >= 1
            link.send(MavlinkEncoder().encode_heartbeat())  # on the reopened link: must not raise
        finally:
            link.close()
            server.close()
            await server.wait_closed()
        await asyncio.sleep(0.2)
        n = conns
        await asyncio.sleep(0.3)
        assert conns == n  # closed: no more reconnect attempts

    asyncio.run(main())
    assert "reopen failed" in caplog.text and "reopened" in caplog.text


def test_polarization_time_beyond_two_to_the_53_is_refused_like_other_samples() -> None:
    """GIVEN the decoder with the private polarization message enabled,
    WHEN a CRC-valid NAVD_SKY_POLARIZATION frame carries time_usec = 2**63 + 1 (a value a
    recording cannot hold) and then one with a plausible time,
    THEN the first is refused and counted as pol_time_out_of_range, as IMU and GNSS
    samples are, and the second is decoded."""
    from firmware_sim.polarization import encode_mavlink

    dec = MavlinkDecoder(MavlinkInputConfig(polarization=True))
    gps_us = 1_300_000_000 * 10**6  # a GPS time in 2021
    bad = encode_mavlink(2**63 + 1, gps_us, 1.0, 0.5)
    good = encode_mavlink(5_000_000, gps_us, 1.0, 0.5, seq=1)
    assert dec.feed_datagram(bad, 0) == []
    assert dec.counters["pol_time_out_of_range"] == 1
    out = dec.feed_datagram(good, 0)
    assert len(out) == 1 and out[0].t_us == 5_000_000 and dec.counters["pol_ok"] == 1


def test_one_datagram_per_output_instant() -> None:
    """GIVEN a MAVLink sender with ATTITUDE_QUATERNION and GLOBAL_POSITION_INT on,
    WHEN it sends one solution over UDP,
    THEN exactly one datagram arrives, and pymavlink decodes ATTITUDE,
    ATTITUDE_QUATERNION and GLOBAL_POSITION_INT from it, all stamped with the solution's
    time (issue 18: one system call and one receiver wake-up per output instant)."""
    async def main() -> list[bytes]:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as rx:
            rx.bind(("127.0.0.1", 0))
            rx.settimeout(2.0)
            link = await MavlinkLink.open(f"udpout:127.0.0.1:{rx.getsockname()[1]}")
            try:
                MavlinkSender(link, MavlinkEncoder(sysid=9), send_global_position=True,
                              home_alt_m=0.0).send_solution(solution())
                got = [rx.recv(4096)]
                rx.settimeout(0.2)
                with contextlib.suppress(TimeoutError):  # a second datagram: the failure
                    got.append(rx.recv(4096))
                return got
            finally:
                link.close()

    datagrams = asyncio.run(main())
    assert len(datagrams) == 1
    msgs = mav.MAVLink(None).parse_buffer(datagrams[0]) or []
    assert [m.get_type() for m in msgs] == ["ATTITUDE", "ATTITUDE_QUATERNION",
                                           "GLOBAL_POSITION_INT"]
    assert len({m.time_boot_ms for m in msgs}) == 1


def test_attitude_frames_are_byte_for_byte_pymavlinks() -> None:
    """ATTITUDE and ATTITUDE_QUATERNION are packed by navd itself (issue 18, every output
    instant): the bytes must be pymavlink's, sequence numbers and trailing-zero cutting
    included, for ordinary, zero, negative-zero and non-finite values."""
    import random

    rng = random.Random(7)
    enc = MavlinkEncoder(sysid=42, compid=191)
    ref = mav.MAVLink(None, srcSystem=42, srcComponent=191)

    def ref_pack(msg: object) -> bytes:
        buf: bytes = msg.pack(ref)  # type: ignore[attr-defined]
        ref.seq = (ref.seq + 1) & 0xFF
        return buf

    specials = [0.0, -0.0, math.nan, math.inf, -math.inf, 1e-40, 3.0e38]
    for k in range(600):  # past a sequence-number wrap
        def v() -> float:
            return rng.choice(specials) if rng.random() < 0.3 else rng.uniform(-4.0, 4.0)
        sol = solution(quat_nb=(v(), v(), v(), v()), roll_rad=v(), pitch_rad=v(), yaw_rad=v(),
                       rate_b=(v(), v(), v()))
        ms = rng.choice([0, 1, k * 20, 0xFFFFFFFF, 0x1_0000_0005])
        p, q, r = sol.rate_b
        assert enc.encode_attitude(sol, ms) == ref_pack(ref.attitude_encode(
            ms & 0xFFFFFFFF, sol.roll_rad, sol.pitch_rad, sol.yaw_rad, p, q, r))
        w, x, y, z = sol.quat_nb
        assert enc.encode_attitude_quaternion(sol, ms) == ref_pack(ref.attitude_quaternion_encode(
            ms & 0xFFFFFFFF, w, x, y, z, p, q, r, (1.0, 0.0, 0.0, 0.0)))
        if k % 50 == 0:  # the pymavlink-packed messages share the sequence
            assert enc.encode_heartbeat() == ref_pack(ref.heartbeat_encode(
                mav.MAV_TYPE_ONBOARD_CONTROLLER, mav.MAV_AUTOPILOT_INVALID, 0, 0,
                mav.MAV_STATE_ACTIVE))
    zero = solution(quat_nb=(0.0, 0.0, 0.0, 0.0), roll_rad=0.0, pitch_rad=0.0, yaw_rad=0.0,
                    rate_b=(0.0, 0.0, 0.0))
    assert enc.encode_attitude(zero, 0) == ref_pack(ref.attitude_encode(0, 0, 0, 0, 0, 0, 0))
    big = solution(roll_rad=1e39)
    with pytest.raises(OverflowError):
        enc.encode_attitude(big, 0)
    with pytest.raises(OverflowError):
        ref.attitude_encode(0, 1e39, 0, 0, 0, 0, 0).pack(ref)
