"""ArduPilot DataFlash (``.bin``) reader, decoding with pymavlink's ``DFReader_binary`` (the
reader ``mavutil.mavlink_connection`` returns for ``.bin`` files; built directly here so the
file name does not matter).

Messages (pymavlink applies the format multipliers, so values are in the units below):
    IMU   TimeUS (us since boot; TimeMS x 1000 in old logs), I (instance; older logs name the
          second IMU ``IMU2``), GyrX/Y/Z (rad/s, FRD), AccX/Y/Z (m/s^2, FRD).  Point samples:
          held over the interval to the previous one (RateIntegrator), as the MAVLink adapter
          does with HIGHRES_IMU.
    ACC, GYR  (only when the log has no IMU message of the chosen instance) raw sensor
          streams: TimeUS, I (``ACC1``/``GYR1``.. name suffix in 3.x logs), SampleUS (us since
          boot, when sampled; used as the time), AccX/Y/Z (m/s^2) or GyrX/Y/Z (rad/s), FRD.
          Each stream has its own time stamps and rate; they are paired into increments at
          the slower of the two rates (SampleBuilder.add_split).
    GPS   TimeUS (logging time, not time of validity), I, Status (>= 3: 3D fix), Lat/Lng (deg),
          [older firmware (ArduCopter <= 3.3, Plane/Rover of that age): ``TimeMS`` is GPS
          time of week (ms) next to ``Week``; ``T`` (ms since boot) is the time.  Without
          ``T``, GPS time (week, ms) is mapped to boot time through the messages that log
          both clocks (another GPS instance with ``T``/``TimeUS`` + ``GMS``/``GWk``, ``CAM``
          / ``TRIG`` with ``GPSTime``/``GPSWeek``): boot - GPS time is constant, the median
          is used.  With none of those, the boot time of the message logged just before.]
          TimeUS is preferred whenever logged: it is the IMU's clock; GMS/GWk are not.
          Alt (m, **MSL**), Spd (m/s), GCrs (deg), VZ (m/s, down positive: AP_GPS velocity is
          NED).  vN = Spd cos GCrs, vE = Spd sin GCrs, vD = VZ.
    GPA   HAcc, VAcc (m), SAcc (m/s) and, where logged, Und (geoid undulation, m) and VV
          (have vertical velocity); matched to GPS by TimeUS and instance.  Height above the
          ellipsoid = Alt + Und if Und is logged, else Alt + geoid_sep.
    MSG   the firmware banner ("APM:Copter V3.3-dev", "ArduPlane V4.5.1", "ArduRover ..."):
          the vehicle type (LogData.vehicle: Copter -> multirotor, Plane -> fixed_wing,
          Rover -> ground; Sub, Tracker, Blimp -> none).
    ATT   Roll, Pitch, Yaw (deg; yaw 0..360) of the onboard AHRS/EKF as the reference
          (AHRS2, named AHR2 in the log, if there is no ATT).  ArduPilot reports the
          attitude of the *vehicle* body, which is the autopilot's (IMU) body turned by
          the level trim ``AHRS_TRIM_X/Y`` (rad): C_n,imu = C_n,vehicle R(trim_x, trim_y, 0).
          navd estimates the IMU axes, so the reference is turned back onto them when the
          log's PARM messages give a trim (log171: 1.18 deg of roll, 0.30 deg of pitch, the
          offset between ATT and the accelerometer's own level at rest).
    PARM  also the autopilot's GNSS latency setting, when options.gnss_delay_s is None:
          ``EKF_VEL_DELAY``, else ``EKF_POS_DELAY`` (EKF1, ArduPilot <= 3.4), else
          ``GPS_DELAY_MS`` (> 0; 0 means the driver's default, not stated) in ms; the fixes
          are moved that much earlier (GPS TimeUS is when the fix reached the autopilot);
          and the antenna's and the IMU's positions (``GPS1_POS_X/Y/Z``, before 4.6
          ``GPS_POS1_X/Y/Z``; ``INS_POS1_X/Y/Z``; m, FRD, from the body origin): their
          difference is LogData.lever_arm_m (ArduCopter 3.3 has neither); and the chosen
          IMU's accelerometer calibration (``INS_ACCOFFS_X/Y/Z``, ``INS_ACCSCAL_X/Y/Z``;
          ``INS_ACC2..`` for the second): when set, LogData.accel_calibrated (the IMU
          message's data have it applied).

Damage: messages are read in sequence and the offset of each is checked; the first skipped
bytes (no 0xA3 0x95 header where a message should start, or an unknown type) or a message cut
short by the end of the file stops the read there, with its byte offset.
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from navd.core.rotation import euler_to_mat, mat_to_euler
from navd.io.logs.common import (
    LogDamage,
    LogData,
    LogFormatError,
    LogOptions,
    Reference,
    SampleBuilder,
    accel_calibration_from_params,
    lever_arm_from_params,
)
from navd.types import FixType, GnssSample
from navd.units import DEG

_FIX = {3: FixType.FIX_3D, 4: FixType.DGPS, 5: FixType.RTK_FLOAT, 6: FixType.RTK_FIXED}
# the autopilot's receiver latency settings (ms), in order of preference: velocity is what
# tilt and heading are read from
_DELAY_PARAMS = ("EKF_VEL_DELAY", "EKF_POS_DELAY", "GPS_DELAY_MS")
# a larger setting is not a receiver latency (ArduPilot's defaults were 200-220 ms; the
# receivers measured here are 0.26-0.28 s late)
_MAX_DELAY_MS = 500.0


# words in the firmware banner (a MSG message) that name the vehicle type, and the navd
# profile each means ("": none fits; ArduCopter includes helicopters: rotorcraft too)
_VEHICLES = {"Copter": "multirotor", "Plane": "fixed_wing", "Rover": "ground", "Sub": "",
             "Tracker": "", "Blimp": ""}


def vehicle_from_firmware(banner: str) -> tuple[str, str]:
    """(navd profile or "", what states it) from the firmware banner MSG ("APM:Copter
    V3.3-dev (ae3192b8)", "ArduPlane V4.5.1", "ArduRover V4.2.0"); ("", "") without one."""
    for word, profile in _VEHICLES.items():
        if word in banner:
            return profile, f"firmware {banner.strip()}"
    return "", ""


def _time_us(m: Any) -> int | None:
    t = getattr(m, "TimeUS", None)
    if t is not None:
        return int(t)
    t = getattr(m, "TimeMS", None)
    return int(t) * 1000 if t is not None else None


def _sample_time_us(m: Any) -> int | None:
    """ACC/GYR: ``SampleUS`` (when the sensor sampled; boot us) over ``TimeUS`` (when it was
    logged, possibly a batch later)."""
    fields = m.get_fieldnames()
    if "SampleUS" in fields and int(m.SampleUS) > 0:
        return int(m.SampleUS)
    return _time_us(m)


def _gps_time_us(m: Any, boot_us_before: int | None) -> int | None:
    """A GPS message's time since boot (us).  ArduPilot logs up to ArduCopter 3.3 store GPS
    time of week in ``TimeMS`` (about 6e8 ms on a Tuesday) with ``Week`` beside it, and the
    boot time in ``T`` (ms); read as boot time, TOW put every fix days after the IMU."""
    own = _boot_us(m)
    if own is None and "Week" in m.get_fieldnames():
        return boot_us_before  # no boot time logged: the message logged before it
    return own


# (ms of week, week) field pairs that give GPS time: GPS in TimeUS logs, CAM/TRIG camera
# triggers, and the old GPS message whose TimeMS is the time of week
_GPS_CLOCK_FIELDS = (("GMS", "GWk"), ("GPSTime", "GPSWeek"), ("TimeMS", "Week"))
_WEEK_MS = 604_800_000


def _gps_clock_ms(m: Any) -> int | None:
    """GPS time (ms since the GPS epoch) from a message's week and ms-of-week fields; None
    without them or before the receiver knew the week (week 0)."""
    fields = m.get_fieldnames()
    for ms, wk in _GPS_CLOCK_FIELDS:
        if ms in fields and wk in fields:
            week = int(getattr(m, wk))
            return week * _WEEK_MS + int(getattr(m, ms)) if week > 0 else None
    return None


def _boot_us(m: Any) -> int | None:
    """A message's own boot time (us), if it logs one: TimeUS; T (ms) beside the old GPS time
    of week; TimeMS where it is not the time of week (no Week field)."""
    fields = m.get_fieldnames()
    if "TimeUS" in fields:
        return int(m.TimeUS)
    if "Week" in fields:
        return int(m.T) * 1000 if "T" in fields else None
    return int(m.TimeMS) * 1000 if "TimeMS" in fields else None


def _instance(m: Any, name: str, base: str) -> int:
    """Instance from the ``I`` field, or from the name suffix (IMU2 -> 1) in old logs."""
    i = getattr(m, "I", None)
    if i is not None and "I" in m.get_fieldnames():
        return int(i)
    suffix = name[len(base):]
    return int(suffix) - 1 if suffix.isdigit() else 0


@contextlib.contextmanager
def _c_output_to(sink: io.StringIO) -> Iterator[None]:
    """Capture what C code writes to fd 1/2 (pymavlink's Cython indexer prints one "bad
    header" line per unreadable byte, past any sys.stdout redirect) into ``sink``."""
    saved: list[int] = []
    try:
        tmp = tempfile.TemporaryFile()  # noqa: SIM115 - closed below
        sys.stdout.flush()
        sys.stderr.flush()
        for fd in (1, 2):
            saved.append(os.dup(fd))
            os.dup2(tmp.fileno(), fd)
    except (OSError, ValueError):  # no usable fds (embedded): leave output alone
        for fd, old in zip((1, 2), saved, strict=False):
            os.dup2(old, fd)
            os.close(old)
        yield
        return
    try:
        yield
    finally:
        for fd, old in zip((1, 2), saved, strict=True):
            os.dup2(old, fd)
            os.close(old)
        tmp.seek(0)
        sink.write(tmp.read().decode(errors="replace"))
        tmp.close()


def _summarise(output: str) -> str:
    """pymavlink's console output for a note: repeated "bad header" lines counted, not kept."""
    lines = [ln for ln in output.splitlines() if ln.strip()]
    bad = [ln for ln in lines if ln.startswith("bad header")]
    rest = [ln for ln in lines if not ln.startswith("bad header")]
    parts = [f"{len(bad)} unreadable bytes skipped (first: {bad[0]})"] if bad else []
    return "; ".join(parts + rest)[:500]


def _to_imu_axes(ref: Reference, trim_x: float, trim_y: float) -> None:
    """Turn the vehicle-body attitudes of ``ref`` (ZYX Euler, rad, in place) onto the IMU
    axes: C_n,imu = C_n,vehicle R_trim, R_trim = Rz(0) Ry(trim_y) Rx(trim_x) (ArduPilot's
    AP_AHRS: the vehicle body is the autopilot body rotated by R_trim^T)."""
    r_trim = euler_to_mat(trim_x, trim_y, 0.0)
    for k in range(len(ref.t_us)):
        c = euler_to_mat(float(ref.roll_rad[k]), float(ref.pitch_rad[k]),
                         float(ref.yaw_rad[k])) @ r_trim
        ref.roll_rad[k], ref.pitch_rad[k], ref.yaw_rad[k] = mat_to_euler(c)


def read_dataflash(path: str | Path, options: LogOptions | None = None) -> LogData:
    from pymavlink import DFReader

    opts = options if options is not None else LogOptions()
    p = str(path)
    if not Path(path).is_file():
        raise LogFormatError(f"no such file: {p}")
    sink = io.StringIO()
    try:
        with (contextlib.redirect_stdout(sink), contextlib.redirect_stderr(sink),
              _c_output_to(sink)):
            r = DFReader.DFReader_binary(p, zero_time_base=False)
    except Exception as exc:  # pymavlink raises assorted types on garbage
        raise LogFormatError(f"{p}: pymavlink cannot open it as DataFlash: {exc}") from exc
    b = SampleBuilder(opts)
    gps_rows: list[tuple[int, int, Any]] = []
    gpa: dict[tuple[int, int], Any] = {}
    att: list[tuple[int, float, float, float]] = []
    ahrs2: list[tuple[int, float, float, float]] = []
    acc: list[tuple[int, float, float, float]] = []
    gyr: list[tuple[int, float, float, float]] = []
    n_imu = 0  # IMU messages of the chosen instance
    # boot time - GPS time (us) from every message logging both clocks, and the GPS rows
    # (index, GPS ms) that logged only GPS time, to move onto the boot clock after the read
    clock_offsets: list[int] = []
    week_only: list[tuple[int, int]] = []
    damage: LogDamage | None = None
    boot_us: int | None = None  # boot time of the last IMU message read (any instance)
    firmware = ""  # the MSG naming the vehicle firmware ("APM:Copter V3.3-dev", "ArduPlane")
    trim = [0.0, 0.0]  # AHRS_TRIM_X, AHRS_TRIM_Y (rad): the vehicle body against the IMU's
    delays: dict[str, float] = {}  # the autopilot's GNSS latency settings (ms), by name
    antenna, ins = _position_params(opts)
    positions: dict[str, float] = {}  # antenna and IMU position parameters (m), by name
    accel_cal = _accel_cal_params(opts)
    wanted = {n for trio in (*antenna, *ins, *(t for pair in accel_cal for t in pair))
              for n in trio}
    data_len = int(r.data_len)
    try:
        with contextlib.redirect_stdout(sink), contextlib.redirect_stderr(sink):
            while True:
                off0 = int(r.offset)
                m = r.recv_msg()
                if m is None:
                    if data_len - off0 > 0:
                        damage = LogDamage(p, "byte", off0, (
                            f"message cut short by the end of the file "
                            f"({data_len - off0} bytes left)"))
                    break
                start = int(r.offset) - int(m.fmt.len)
                if start != off0:
                    damage = LogDamage(p, "byte", off0, (
                        f"{start - off0} unreadable bytes (no valid message header) before "
                        f"the next {m.get_type()} message"))
                    break
                name = m.get_type()
                if name.startswith("IMU") and name[3:] in ("", "2", "3"):
                    t = _time_us(m)
                    boot_us = t if t is not None else boot_us
                    if _instance(m, name, "IMU") != opts.imu_instance or t is None:
                        continue
                    b.add_rates(t, (float(m.GyrX), float(m.GyrY), float(m.GyrZ)),
                                (float(m.AccX), float(m.AccY), float(m.AccZ)))
                    n_imu += 1
                elif name[:3] in ("ACC", "GYR") and name[3:] in ("", "1", "2", "3"):
                    # raw sensor streams (ACC1/GYR1.. in 3.x, ACC/GYR with I in 4.x): kept
                    # in case the log has no IMU message of the chosen instance
                    if _instance(m, name, name[:3]) != opts.imu_instance:
                        continue
                    t = _sample_time_us(m)
                    if t is None:
                        continue
                    if name[:3] == "ACC":
                        acc.append((t, float(m.AccX), float(m.AccY), float(m.AccZ)))
                    else:
                        gyr.append((t, float(m.GyrX), float(m.GyrY), float(m.GyrZ)))
                elif name.startswith("GPS") and name[3:] in ("", "2"):
                    gps_ms = _gps_clock_ms(m)
                    own_boot = _boot_us(m)
                    if gps_ms is not None and own_boot is not None:
                        clock_offsets.append(own_boot - gps_ms * 1000)
                    if _instance(m, name, "GPS") != opts.gnss_instance:
                        continue
                    t = _gps_time_us(m, boot_us)
                    if t is not None:
                        if own_boot is None and gps_ms is not None:
                            week_only.append((len(gps_rows), gps_ms))
                        gps_rows.append((t, int(m.Status), m))
                elif name in ("CAM", "TRIG"):
                    # camera triggers log the GPS time next to their boot time: a clock tie
                    gps_ms = _gps_clock_ms(m)
                    own_boot = _boot_us(m)
                    if gps_ms is not None and own_boot is not None:
                        clock_offsets.append(own_boot - gps_ms * 1000)
                elif name.startswith("GPA") and name[3:] in ("", "2"):
                    t = _time_us(m)
                    if t is not None:
                        gpa[(t, _instance(m, name, "GPA"))] = m
                elif name == "ATT":
                    t = _time_us(m)
                    if t is not None:
                        att.append((t, float(m.Roll), float(m.Pitch), float(m.Yaw)))
                elif name == "PARM" and str(getattr(m, "Name", "")) in ("AHRS_TRIM_X",
                                                                        "AHRS_TRIM_Y"):
                    val = float(m.Value)
                    if math.isfinite(val) and abs(val) < 0.2:  # AHRS_TRIM: at most 10 deg
                        trim[0 if str(m.Name).endswith("X") else 1] = val
                elif name == "PARM" and str(getattr(m, "Name", "")) in _DELAY_PARAMS:
                    val = float(m.Value)
                    if math.isfinite(val) and 0.0 < val <= _MAX_DELAY_MS:
                        delays[str(m.Name)] = val
                elif name == "PARM" and str(getattr(m, "Name", "")) in wanted:
                    positions[str(m.Name)] = float(m.Value)
                elif name == "MSG" and not firmware:
                    text = str(getattr(m, "Message", ""))
                    if any(v in text for v in _VEHICLES):
                        firmware = text
                elif name in ("AHRS2", "AHR2"):
                    t = _time_us(m)
                    if t is not None:
                        ahrs2.append((t, float(m.Roll), float(m.Pitch), float(m.Yaw)))
    except Exception as exc:  # a decoder exception mid-file is damage, not a crash
        damage = LogDamage(p, "byte", int(r.offset), f"pymavlink failed: {exc}")
    notes: list[str] = []
    if week_only and clock_offsets:
        # Both clocks run at the same rate, so boot - GPS time is one constant per power
        # cycle; the median shrugs off a message logged late.  Exact to the logged ms, where
        # the message logged before the fix (the fallback) is up to one interval early.
        offset = int(np.median(np.asarray(clock_offsets, dtype=np.int64)))
        for k, gps_ms in week_only:
            _, status, m = gps_rows[k]
            gps_rows[k] = (gps_ms * 1000 + offset, status, m)
        notes.append(f"GPS week/ms mapped to boot time through {len(clock_offsets)} messages "
                     "logging both clocks")
    elif week_only:
        notes.append("GPS logs only GPS week/ms: fixes timed by the message logged before "
                     "each (no message logs both clocks)")
    if n_imu == 0 and acc and gyr:
        # Only ACC/GYR for this instance: pair the two streams (never another instance's)
        a_arr = np.asarray(acc, dtype=np.float64)
        g_arr = np.asarray(gyr, dtype=np.float64)
        slow = b.add_split(a_arr[:, 0].astype(np.int64), a_arr[:, 1:],
                           g_arr[:, 0].astype(np.int64), g_arr[:, 1:])
        notes.append(f"IMU from ACC/GYR instance {opts.imu_instance} (no IMU message), "
                     f"increments at the {slow} rate")
    if opts.gnss_delay_s is None and delays:
        # The autopilot's own setting for its receiver's latency: the log's fixes are stamped
        # when they arrived, and the autopilot's EKF moved them back by it (log171: 200 ms,
        # against ~0.26 s measured from its IMU and GNSS accelerations; docs/results.md).
        key = next(k for k in _DELAY_PARAMS if k in delays)
        b.set_gnss_delay(delays[key] * 1e-3)
        notes.append(f"GNSS fixes taken as valid {delays[key]:.0f} ms before their time "
                     f"stamp: the log's {key} (the autopilot's receiver latency); "
                     "--gnss-delay-ms overrides")
    for t, status, m in gps_rows:
        if status < 3:
            b.counters.inc("gnss_no_3d_fix")
            continue
        a = gpa.get((t, opts.gnss_instance))
        h = v = s = None
        und = None
        vv = 1
        if a is not None:
            h, v, s = float(a.HAcc), float(a.VAcc), float(a.SAcc)
            fields = a.get_fieldnames()
            if "Und" in fields:
                und = float(a.Und)
            if "VV" in fields:
                vv = int(a.VV)
        h_acc, v_acc, vel_acc = b.accuracy(h, v, s)
        spd, crs = float(m.Spd), float(m.GCrs) * DEG
        vd = float(m.VZ) if vv else math.nan
        alt = float(m.Alt) + (und if und is not None and und != 0.0 else opts.geoid_sep_m)
        b.add_gnss(GnssSample(t, float(m.Lat) * DEG, float(m.Lng) * DEG, alt,
                              spd * math.cos(crs), spd * math.sin(crs), vd, h_acc, v_acc,
                              vel_acc, _FIX.get(status, FixType.FIX_3D)))
    rows, src = (att, "ATT") if att else (ahrs2, "AHRS2")
    if rows:
        a_arr = np.asarray(rows, dtype=np.float64)
        ref = Reference(np.asarray([x[0] for x in rows], dtype=np.int64), a_arr[:, 1] * DEG,
                        a_arr[:, 2] * DEG, a_arr[:, 3] * DEG, src)
        if trim[0] != 0.0 or trim[1] != 0.0:
            _to_imu_axes(ref, trim[0], trim[1])
            notes.append(f"{src} turned onto the IMU axes by AHRS_TRIM_X/Y "
                         f"({trim[0] / DEG:.2f}, {trim[1] / DEG:.2f} deg)")
        # yaw 0..360 -> (-180, 180]
        ref.yaw_rad = (ref.yaw_rad + math.pi) % (2.0 * math.pi) - math.pi
    else:
        ref = Reference.empty()
    if not gpa:
        notes.append("no GPA messages: assumed GNSS accuracies from options")
    out = _summarise(sink.getvalue())
    if out:
        notes.append("pymavlink: " + out)
    with contextlib.suppress(Exception):
        r.data_map.close()
        r.filehandle.close()
    return b.build("dataflash", p, ref, damage, notes,
                   vehicle=vehicle_from_firmware(firmware),
                   lever_arm=lever_arm_from_params(positions, antenna, ins),
                   # the IMU message carries the calibrated data; the raw ACC/GYR streams
                   # a log without it falls back on may not
                   accel_calibrated=(accel_calibration_from_params(positions, accel_cal)
                                     if n_imu > 0 else None))


def _accel_cal_params(opts: LogOptions) -> list[tuple[tuple[str, str, str],
                                                     tuple[str, str, str]]]:
    """The chosen IMU's accelerometer calibration parameters (offsets, m/s^2; scales):
    ``INS_ACCOFFS_X``.. / ``INS_ACCSCAL_X``.. for the first, ``INS_ACC2OFFS_X``.. for the
    second, ``INS_ACC3..`` for the third."""
    k = "" if opts.imu_instance == 0 else str(opts.imu_instance + 1)
    return [((f"INS_ACC{k}OFFS_X", f"INS_ACC{k}OFFS_Y", f"INS_ACC{k}OFFS_Z"),
             (f"INS_ACC{k}SCAL_X", f"INS_ACC{k}SCAL_Y", f"INS_ACC{k}SCAL_Z"))]


def _position_params(opts: LogOptions) -> tuple[list[tuple[str, str, str]],
                                                list[tuple[str, str, str]]]:
    """The parameter names of the chosen receiver's antenna position (ArduPilot 4.6+
    ``GPS1_POS_X``, earlier ``GPS_POS1_X``; instance k is k + 1) and of the chosen IMU's
    position (``INS_POS1_X``), m from the body origin, FRD."""
    g, i = opts.gnss_instance + 1, opts.imu_instance + 1
    antenna = [(f"GPS{g}_POS_X", f"GPS{g}_POS_Y", f"GPS{g}_POS_Z"),
               (f"GPS_POS{g}_X", f"GPS_POS{g}_Y", f"GPS_POS{g}_Z")]
    return antenna, [(f"INS_POS{i}_X", f"INS_POS{i}_Y", f"INS_POS{i}_Z")]
