"""MAVLink telemetry log (``.tlog``) reader.

A tlog is a sequence of records: an 8-byte big-endian time stamp (receive time, microseconds
since the Unix epoch) followed by one MAVLink 1 or 2 frame.  Frames are read with pymavlink's
``mavutil.mavmmaplog`` (what ``mavutil.mavlink_connection`` opens for a tlog; built directly so
the file name does not matter), and every frame's bytes are then fed to the daemon's own
:class:`navd.io.mavlink.MavlinkDecoder` with the record's time stamp as receive time: the
samples are exactly those the daemon would have pushed had it received this stream.

Message choice (the most informative present, with at least 10 records):
    IMU   HIGHRES_IMU > SCALED_IMU > SCALED_IMU2 > SCALED_IMU3 (RAW_IMU needs scales).
    GNSS  GPS_INPUT > HIL_GPS > GPS_RAW_INT (which has no vertical velocity: NaN vel_d).
    reference  ATTITUDE (time_boot_ms, rad) > AHRS2 (no time field: receive time mapped to
          the IMU clock).
    vehicle type  (LogData.vehicle) HEARTBEAT ``type`` (MAV_TYPE) of the system that sent
          the IMU messages (ground stations, companion computers and peripherals ignored).
Clocks: PX4 stamps HIGHRES_IMU and GPS_RAW_INT with time since boot; ArduPilot stamps
GPS_RAW_INT with Unix time.  When the median (sensor time - receive time) of the GNSS (or
ATTITUDE) messages differs from the IMU's by more than 1 s, their stamps are moved onto the
IMU clock by that difference (noted in the result).

Damage: the first record whose frame is not where the previous one ended (bytes skipped),
fails its CRC, or is cut short by the end of the file stops the read, with its byte offset.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import math
import statistics
from pathlib import Path
from typing import Any

import numpy as np

from navd.diag import Counters
from navd.io.logs.common import (
    LogDamage,
    LogData,
    LogFormatError,
    LogOptions,
    Reference,
    SampleBuilder,
    vehicle_from_heartbeats,
)
from navd.io.mavlink import MavlinkDecoder, MavlinkInputConfig
from navd.types import GnssSample, ImuSample

IMU_PREFERENCE = ("HIGHRES_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3")
GNSS_PREFERENCE = ("GPS_INPUT", "HIL_GPS", "GPS_RAW_INT")
_SCALED_INSTANCE = {"SCALED_IMU": 0, "SCALED_IMU2": 1, "SCALED_IMU3": 2}
_MIN_RECORDS = 10
_CLOCK_TOL_US = 1_000_000


def _open(p: str) -> Any:
    from pymavlink import mavutil

    sink = io.StringIO()
    with contextlib.redirect_stdout(sink), contextlib.redirect_stderr(sink):
        return mavutil.mavmmaplog(p)


def read_tlog(path: str | Path, options: LogOptions | None = None) -> LogData:
    opts = options if options is not None else LogOptions()
    p = str(path)
    if not Path(path).is_file():
        raise LogFormatError(f"no such file: {p}")
    try:
        mlog = _open(p)
    except Exception as exc:  # pymavlink raises assorted types on garbage
        raise LogFormatError(f"{p}: pymavlink cannot open it as a tlog: {exc}") from exc
    if getattr(mlog, "data_map", None) is None:
        raise LogFormatError(f"{p}: empty file")
    counts = {mlog.id_to_name[k]: v for k, v in mlog.counts.items() if k in mlog.id_to_name}
    imu_msg = next((n for n in IMU_PREFERENCE if counts.get(n, 0) >= _MIN_RECORDS), None)
    gnss_msg = next((n for n in GNSS_PREFERENCE if counts.get(n, 0) >= 1), None)
    if imu_msg is None:
        raise LogFormatError(f"{p}: no IMU messages ({', '.join(IMU_PREFERENCE)}) in the log")
    notes = [f"IMU from {imu_msg}, GNSS from {gnss_msg or 'nothing'}"]
    cfg = MavlinkInputConfig(
        imu_messages=frozenset({imu_msg}),
        gnss_messages=frozenset({gnss_msg}) if gnss_msg else frozenset(),
        imu_id=_SCALED_INSTANCE.get(imu_msg, opts.imu_instance),
        gnss_id=opts.gnss_instance,
        max_imu_gap_s=opts.max_imu_gap_s,
        geoid_sep_m=opts.geoid_sep_m,
        default_h_acc_m=opts.h_acc_m,
        default_v_acc_m=opts.v_acc_m,
        default_vel_acc_mps=opts.vel_acc_mps,
    )
    counters = Counters()
    dec = MavlinkDecoder(cfg, counters)
    wanted = {imu_msg, gnss_msg}
    imu: list[ImuSample] = []
    gnss: list[GnssSample] = []
    imu_off: list[int] = []
    gnss_off: list[int] = []
    att: list[tuple[int, int, float, float, float]] = []
    ahrs2: list[tuple[int, int, float, float, float]] = []
    damage: LogDamage | None = None
    beats: list[tuple[int, int, int]] = []  # HEARTBEAT (system id, MAV_TYPE, autopilot)
    imu_sys: int | None = None  # system id of the IMU messages read
    size = int(mlog.data_len)
    f = mlog.f
    f.seek(0)
    sink = io.StringIO()
    with contextlib.redirect_stdout(sink), contextlib.redirect_stderr(sink):
        while True:
            off0 = f.tell()
            try:
                m = mlog.recv_msg()
            except Exception as exc:  # a decoder exception mid-file is damage
                damage = LogDamage(p, "byte", off0, f"pymavlink failed: {exc}")
                break
            if m is None:
                if size - off0 > 0:
                    damage = LogDamage(p, "byte", off0, (
                        f"record cut short by the end of the file ({size - off0} bytes left)"))
                break
            typ = m.get_type()
            buf = bytes(m.get_msgbuf())
            if typ == "BAD_DATA":
                damage = LogDamage(p, "byte", off0, f"bad MAVLink frame: {m.reason}")
                break
            if f.tell() != off0 + 8 + len(buf):
                damage = LogDamage(p, "byte", off0, (
                    f"{f.tell() - off0 - 8 - len(buf)} unreadable bytes before the next "
                    f"{typ} frame"))
                break
            recv_us = round(m._timestamp * 1e6)
            if typ == imu_msg and imu_sys is None:
                imu_sys = int(m.get_srcSystem())
            if typ not in wanted:  # the decoder would only count it as ignored
                if typ == "HEARTBEAT":
                    beats.append((int(m.get_srcSystem()), int(m.type), int(m.autopilot)))
                elif typ == "ATTITUDE":
                    att.append((int(m.time_boot_ms) * 1000, recv_us, float(m.roll),
                                float(m.pitch), float(m.yaw)))
                elif typ == "AHRS2":
                    ahrs2.append((recv_us, recv_us, float(m.roll), float(m.pitch),
                                  float(m.yaw)))
                continue
            for s in dec.feed(buf, recv_us):
                if isinstance(s, ImuSample):
                    imu.append(s)
                    imu_off.append(s.t_us - recv_us)
                elif isinstance(s, GnssSample):  # (PolSample only with polarization=True)
                    gnss.append(s)
                    gnss_off.append(s.t_us - recv_us)
    with contextlib.suppress(Exception):
        mlog.close()
    b = SampleBuilder(opts)
    benign = {"frames_ok", "imu_ok", "gnss_ok", "ignored", "imu_first_sample", "seq_lost",
              "seq_jump", "datagrams"}
    # src_<sysid>_<compid>_* are per-source tallies, not rejections
    rejected = {k: v for k, v in counters.snapshot().items()
                if v and k not in benign and not k.startswith("src_")}
    if rejected:
        notes.append("MAVLink decoder rejected: " + ", ".join(
            f"{k}={v}" for k, v in sorted(rejected.items())))
    for s in imu:
        b.add_imu(s)
    imu_clock = statistics.median(imu_off) if imu_off else 0
    shift = 0
    if gnss_off:
        shift = round(imu_clock - statistics.median(gnss_off))
        if abs(shift) <= _CLOCK_TOL_US:
            shift = 0
        else:
            notes.append(f"{gnss_msg} stamps are on another clock: moved by {shift} us onto "
                         f"the IMU clock (via receive times)")
    for g in gnss:
        b.add_gnss(dataclasses.replace(g, t_us=g.t_us + shift) if shift else g)
    ref = _reference(att, ahrs2, imu_clock, notes)
    out = sink.getvalue().strip()
    if out:
        notes.append("pymavlink: " + out.replace("\n", "; ")[:500])
    return b.build("tlog", p, ref, damage, notes, vehicle=vehicle_from_heartbeats(beats, imu_sys))


def _reference(att: list[tuple[int, int, float, float, float]],
               ahrs2: list[tuple[int, int, float, float, float]], imu_clock: float,
               notes: list[str]) -> Reference:
    """Rows are (sensor t_us, receive t_us, roll, pitch, yaw rad)."""
    rows, src = (att, "ATTITUDE") if att else (ahrs2, "AHRS2")
    if not rows:
        return Reference.empty()
    t = np.asarray([r[0] for r in rows], dtype=np.int64)
    recv = np.asarray([r[1] for r in rows], dtype=np.int64)
    off = float(np.median(t - recv))
    if abs(off - imu_clock) > _CLOCK_TOL_US:
        shift = round(imu_clock - off)
        t = t + shift
        notes.append(f"{src} time moved by {shift} us onto the IMU clock (via receive times)")
    a = np.asarray([r[2:] for r in rows], dtype=np.float64)
    yaw = (a[:, 2] + math.pi) % (2.0 * math.pi) - math.pi
    return Reference(t, a[:, 0], a[:, 1], yaw, src)
