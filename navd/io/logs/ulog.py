"""PX4 ULog (``.ulg``) reader, decoding with pyulog.

Topics (``multi_id`` 0 unless ``LogOptions`` says otherwise; one instance per stream, never
mixed):
    sensor_combined     ``timestamp`` (us), ``gyro_rad[3]`` (rad/s, FRD), ``gyro_integral_dt``,
                        ``accelerometer_m_s2[3]`` (m/s^2), ``accelerometer_integral_dt``.
                        The rates are PX4's averages over the integration interval, so
                        increment = rate x integral_dt (uint32 us; float seconds in some old
                        versions).  Without integral_dt fields, rates are held over the
                        interval to the previous sample (RateIntegrator).
    sensor_accel, sensor_gyro  (when there is no sensor_combined of the chosen instance: a
                        log without it, or ``imu_instance`` > 0, since sensor_combined holds
                        only the IMU PX4 selected) the one ``multi_id`` asked for, both topics
                        of the same instance: ``timestamp_sample`` (us, else ``timestamp``),
                        ``x``, ``y``, ``z`` (m/s^2 / rad/s, FRD).  Point samples with their
                        own time stamps, paired into increments at the slower rate
                        (SampleBuilder.add_split).
    vehicle_gps_position (preferred, the selected receiver) or sensor_gps, ``multi_id`` =
                        ``gnss_instance`` (PX4 <= 1.10 published one vehicle_gps_position per
                        receiver; newer ones one sensor_gps per receiver)
                        time = ``timestamp_sample`` if present and non-zero, else ``timestamp``;
                        lat/lon int32 1e-7 deg (older) or ``latitude_deg``/``longitude_deg``
                        float64 deg (PX4 >= 1.14); altitude ``alt_ellipsoid`` / ``alt`` int32
                        mm or ``altitude_ellipsoid_m`` / ``altitude_msl_m`` m (ellipsoid used
                        when non-zero, else MSL + geoid_sep); ``vel_n/e/d_m_s``; ``eph``,
                        ``epv`` (m) and ``s_variance_m_s`` (m/s, a sigma despite its name) as
                        accuracies; ``fix_type`` >= 3 kept; ``vel_ned_valid`` = 0 -> NaN vel.
    vehicle_attitude    ``q[4]`` (w, x, y, z of FRD -> NED) as the reference.
    vehicle type        (LogData.vehicle) the ``MAV_TYPE`` parameter (MAVLink MAV_TYPE: 1
                        fixed wing, 2/3/4/13/14/15.. rotorcraft, 10 rover; VTOL types fit no
                        profile), else ``vehicle_status``: ``is_vtol`` -> none, else
                        ``vehicle_type`` (1 rotary wing, 2 fixed wing, 3 rover; the most
                        common value in the log) or, before PX4 1.9, ``is_rotary_wing``
                        (true: rotorcraft; false says nothing: a plane or a rover).
    antenna position    (LogData.lever_arm_m) the parameters ``EKF2_GPS_POS_X/Y/Z`` minus
                        ``EKF2_IMU_POS_X/Y/Z`` (m, FRD, from the body origin).
    accelerometer cal.  (LogData.accel_calibrated) ``CAL_ACC<i>_X/Y/ZOFF`` (m/s^2) not all
                        zero or ``CAL_ACC<i>_X/Y/ZSCALE`` not all one, i the IMU instance
                        read: PX4's sensor topics carry the calibration applied.

Damage: before pyulog parses, the message framing (3-byte header: uint16 size, uint8 type)
is walked from offset 16; the first unknown message type, data message for an unsubscribed
id, or message cut short by the end of file stops the read there, and pyulog parses only the
bytes before it (pyulog itself would silently resync past corruption).
"""

from __future__ import annotations

import contextlib
import io
import math
import struct
from pathlib import Path
from typing import Any

import numpy as np

from navd.core.quat_series import quat_to_euler
from navd.io.logs.common import (
    F64,
    LogDamage,
    LogData,
    LogFormatError,
    LogOptions,
    Reference,
    SampleBuilder,
    accel_calibration_from_params,
    lever_arm_from_params,
    vehicle_from_mav_type,
)
from navd.types import FixType, GnssSample, ImuSample
from navd.units import DEG

MAGIC = b"ULog\x01\x12\x35"
_TYPES = frozenset(b"FDIMPQARSOLCB")
_HDR = struct.Struct("<HB")
TOPICS = ("sensor_combined", "sensor_accel", "sensor_gyro", "vehicle_gps_position",
          "sensor_gps", "vehicle_attitude", "vehicle_status")
# vehicle_status.vehicle_type (PX4 >= 1.9): ROTARY_WING 1, FIXED_WING 2, ROVER 3
# the antenna's and the IMU's position parameters (m from the body origin, FRD)
_ANTENNA = [("EKF2_GPS_POS_X", "EKF2_GPS_POS_Y", "EKF2_GPS_POS_Z")]
_IMU_POS = [("EKF2_IMU_POS_X", "EKF2_IMU_POS_Y", "EKF2_IMU_POS_Z")]


def _accel_cal_params(instance: int) -> list[tuple[tuple[str, str, str],
                                                   tuple[str, str, str]]]:
    """PX4's accelerometer calibration of calibration slot ``instance`` (``CAL_ACC0_XOFF``..,
    m/s^2; ``CAL_ACC0_XSCALE``..): sensor_combined and sensor_accel carry it applied."""
    k = f"CAL_ACC{instance}_"
    return [((k + "XOFF", k + "YOFF", k + "ZOFF"), (k + "XSCALE", k + "YSCALE", k + "ZSCALE"))]


_VEHICLE_TYPE = {1: ("multirotor", "ROTARY_WING"), 2: ("fixed_wing", "FIXED_WING"),
                 3: ("ground", "ROVER")}


def scan_ulog(buf: bytes | memoryview) -> tuple[int, str | None]:
    """Walk the message framing; return (end offset of the intact part, reason or None)."""
    n = len(buf)
    if n < 16 or bytes(buf[:7]) != MAGIC:
        raise LogFormatError("not a ULog file (bad magic or shorter than its 16-byte header)")
    off = 16
    subscribed: set[int] = set()
    unpack = _HDR.unpack_from
    while off < n:
        if n - off < 3:
            return off, f"message header cut short ({n - off} of 3 bytes)"
        size, typ = unpack(buf, off)
        if typ not in _TYPES:
            return off, f"unknown message type 0x{typ:02x} (corrupt data)"
        if off + 3 + size > n:
            return off, (f"message '{chr(typ)}' of {size} bytes cut short "
                         f"({n - off - 3} bytes left)")
        if typ == 0x41 and size >= 3:  # 'A': uint8 multi_id, uint16 msg_id, name
            subscribed.add(struct.unpack_from("<H", buf, off + 4)[0])
        elif typ == 0x44:  # 'D'
            if size < 2:
                return off, "data message shorter than its id"
            msg_id = struct.unpack_from("<H", buf, off + 3)[0]
            if msg_id not in subscribed:
                return off, f"data for unsubscribed message id {msg_id} (corrupt data)"
        elif size == 0 and typ not in (0x52,):
            return off, f"empty '{chr(typ)}' message (corrupt data)"
        off += 3 + size
    return n, None


def _field(d: dict[str, Any], *names: str) -> Any | None:
    for n in names:
        if n in d:
            return d[n]
    return None


def _vec(d: dict[str, Any], *bases: str) -> F64 | None:
    for b in bases:
        if f"{b}[0]" in d:
            return np.stack([np.asarray(d[f"{b}[{i}]"], dtype=np.float64) for i in range(3)], 1)
    return None


def _dt_us(raw: Any) -> Any:
    """integral_dt to integer microseconds (uint32 us, or float seconds in old logs)."""
    a = np.asarray(raw)
    if a.dtype.kind == "f":
        if len(a) and float(np.nanmax(np.abs(a))) < 10.0:
            return np.rint(a.astype(np.float64) * 1e6).astype(np.int64)
        return np.rint(a).astype(np.int64)
    return a.astype(np.int64)


def _dataset(ulog: Any, name: str, instance: int) -> dict[str, Any] | None:
    for ds in ulog.data_list:
        if ds.name == name and ds.multi_id == instance:
            return dict(ds.data)
    return None


def _imu(b: SampleBuilder, d: dict[str, Any]) -> None:
    t = np.asarray(d["timestamp"], dtype=np.int64)
    gyro = _vec(d, "gyro_rad", "gyro_rad_s")
    acc = _vec(d, "accelerometer_m_s2")
    if gyro is None or acc is None:
        raise LogFormatError("sensor_combined has no gyro_rad / accelerometer_m_s2 fields")
    g_dt = _field(d, "gyro_integral_dt")
    a_dt = _field(d, "accelerometer_integral_dt")
    if g_dt is not None and a_dt is not None:
        gdt = _dt_us(g_dt)
        adt = _dt_us(a_dt)
        dth = gyro * (gdt * 1e-6)[:, None]
        dv = acc * (adt * 1e-6)[:, None]
        tl, gl, th, vl = t.tolist(), gdt.tolist(), dth.tolist(), dv.tolist()
        for k in range(len(tl)):
            if gl[k] <= 0:
                b.counters.inc("imu_zero_integral_dt")
                continue
            a, v = th[k], vl[k]
            b.add_imu(ImuSample(tl[k], gl[k], a[0], a[1], a[2], v[0], v[1], v[2]))
        return
    tl, gy, ac = t.tolist(), gyro.tolist(), acc.tolist()
    for k in range(len(tl)):
        g, a = gy[k], ac[k]
        b.add_rates(tl[k], (g[0], g[1], g[2]), (a[0], a[1], a[2]))


def _sample_times(d: dict[str, Any]) -> Any:
    """``timestamp_sample`` (when measured) where present and non-zero, else ``timestamp``
    (when published)."""
    t = np.asarray(d["timestamp"], dtype=np.int64)
    ts = _field(d, "timestamp_sample")
    if ts is not None:
        tsa = np.asarray(ts, dtype=np.int64)
        t = np.where(tsa > 0, tsa, t)
    return t


def _split_imu(b: SampleBuilder, ulog: Any, instance: int) -> str | None:
    """sensor_accel + sensor_gyro of one multi_id as increments at the slower rate; None if
    that instance lacks either topic (never pairs one instance's accel with another's gyro)."""
    acc = _dataset(ulog, "sensor_accel", instance)
    gyr = _dataset(ulog, "sensor_gyro", instance)
    if acc is None or gyr is None:
        return None
    av, gv = _xyz(acc), _xyz(gyr)
    if av is None or gv is None:
        raise LogFormatError("sensor_accel / sensor_gyro without x, y, z fields")
    return b.add_split(_sample_times(acc), av, _sample_times(gyr), gv)


def _xyz(d: dict[str, Any]) -> F64 | None:
    if not all(c in d for c in "xyz"):
        return None
    return np.stack([np.asarray(d[c], dtype=np.float64) for c in "xyz"], 1)


def _instances(ulog: Any, name: str) -> list[int]:
    return sorted({int(ds.multi_id) for ds in ulog.data_list if ds.name == name})


def _gnss(b: SampleBuilder, d: dict[str, Any], opts: LogOptions) -> None:
    t = _sample_times(d)
    n = len(t)

    def deg(*names: str) -> F64:
        raw = _field(d, *names)
        if raw is None:
            raise LogFormatError(f"GPS topic has none of the fields {names}")
        a = np.asarray(raw)
        x = a.astype(np.float64)
        if a.dtype.kind in "iu" or (len(x) and float(np.nanmax(np.abs(x))) > 360.0):
            x = x * 1e-7
        return x

    lat = deg("latitude_deg", "lat")
    lon = deg("longitude_deg", "lon")
    zeros = np.zeros(n)
    ell_m = _field(d, "altitude_ellipsoid_m")
    msl_m = _field(d, "altitude_msl_m")
    if ell_m is not None or msl_m is not None:
        ell = np.asarray(ell_m, dtype=np.float64) if ell_m is not None else zeros
        msl = np.asarray(msl_m, dtype=np.float64) if msl_m is not None else zeros
    else:
        ell_mm = _field(d, "alt_ellipsoid")
        msl_mm = _field(d, "alt")
        ell = np.asarray(ell_mm, dtype=np.float64) * 1e-3 if ell_mm is not None else zeros
        msl = np.asarray(msl_mm, dtype=np.float64) * 1e-3 if msl_mm is not None else zeros
    alt = np.where(ell != 0.0, ell, msl + opts.geoid_sep_m)
    vel = [np.asarray(_field(d, f"vel_{c}_m_s"), dtype=np.float64)
           if _field(d, f"vel_{c}_m_s") is not None else np.full(n, math.nan) for c in "ned"]
    valid = _field(d, "vel_ned_valid")
    if valid is not None:
        bad = np.asarray(valid) == 0
        for v in vel:
            v[bad] = math.nan
    eph = _field(d, "eph")
    epv = _field(d, "epv")
    sacc = _field(d, "s_variance_m_s")
    fix = _field(d, "fix_type")
    fx = (np.asarray(fix, dtype=np.int64) if fix is not None
          else np.full(n, int(FixType.FIX_3D))).tolist()
    cols = [t.tolist(), lat.tolist(), lon.tolist(), alt.tolist(), vel[0].tolist(),
            vel[1].tolist(), vel[2].tolist(),
            np.asarray(eph, dtype=np.float64).tolist() if eph is not None else [None] * n,
            np.asarray(epv, dtype=np.float64).tolist() if epv is not None else [None] * n,
            np.asarray(sacc, dtype=np.float64).tolist() if sacc is not None else [None] * n]
    for k in range(n):
        f = fx[k]
        if f < 3:
            b.counters.inc("gnss_no_3d_fix")
            continue
        h_acc, v_acc, s_acc = b.accuracy(cols[7][k], cols[8][k], cols[9][k])
        b.add_gnss(GnssSample(cols[0][k], cols[1][k] * DEG, cols[2][k] * DEG, cols[3][k],
                              cols[4][k], cols[5][k], cols[6][k], h_acc, v_acc, s_acc,
                              FixType(min(f, int(FixType.RTK_FIXED)))))


def _reference(d: dict[str, Any] | None) -> Reference:
    if d is None or "q[0]" not in d:
        return Reference.empty()
    t = _sample_times(d)
    q = [np.asarray(d[f"q[{i}]"], dtype=np.float64) for i in range(4)]
    r, p, y = quat_to_euler(np.stack(q, 1)).T
    return Reference(t, r, p, y, "vehicle_attitude")


def _vehicle(ulog: Any) -> tuple[str, str]:
    """(navd profile or "", what states it) from the MAV_TYPE parameter or vehicle_status."""
    params = getattr(ulog, "initial_parameters", {}) or {}
    if "MAV_TYPE" in params:
        with contextlib.suppress(TypeError, ValueError):
            return vehicle_from_mav_type(int(params["MAV_TYPE"]), "parameter")
    d = _dataset(ulog, "vehicle_status", 0)
    if d is None:
        return "", ""
    vtol = _field(d, "is_vtol")
    if vtol is not None and np.any(np.asarray(vtol) != 0):
        return "", "vehicle_status is_vtol (a VTOL: no single profile)"
    vt = _field(d, "vehicle_type")
    if vt is not None and len(vt):
        vals, counts = np.unique(np.asarray(vt, dtype=np.int64), return_counts=True)
        v = int(vals[np.argmax(counts)])
        profile, name = _VEHICLE_TYPE.get(v, ("", str(v)))
        return profile, f"vehicle_status vehicle_type {v} ({name})"
    rw = _field(d, "is_rotary_wing")
    # false is a plane or a rover (or an old VTOL): no vehicle type stated
    if rw is not None and len(rw) and bool(np.mean(np.asarray(rw) != 0) >= 0.5):
        return "multirotor", "vehicle_status is_rotary_wing"
    return "", ""


def read_ulog(path: str | Path, options: LogOptions | None = None) -> LogData:
    from pyulog import ULog

    opts = options if options is not None else LogOptions()
    p = str(path)
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise LogFormatError(f"cannot read {p}: {exc}") from exc
    try:
        end, reason = scan_ulog(data)
    except LogFormatError as exc:
        raise LogFormatError(f"{p}: {exc}") from exc
    damage = LogDamage(p, "byte", end, reason) if reason is not None else None
    sink = io.StringIO()
    try:
        with contextlib.redirect_stdout(sink):
            ulog = ULog(io.BytesIO(data[:end]), list(TOPICS), True)
    except Exception as exc:  # pyulog raises assorted types on a broken definition section
        raise LogFormatError(f"{p}: pyulog cannot parse the file: {exc}") from exc
    b = SampleBuilder(opts)
    # sensor_combined is the IMU PX4 itself selected (one instance); another instance, or a
    # log without sensor_combined, reads that multi_id's sensor_accel + sensor_gyro
    notes: list[str] = []
    sc = _dataset(ulog, "sensor_combined", opts.imu_instance)
    if sc is not None:
        _imu(b, sc)
    else:
        slow = _split_imu(b, ulog, opts.imu_instance)
        if slow is None:
            have = sorted(set(_instances(ulog, "sensor_accel"))
                          & set(_instances(ulog, "sensor_gyro")))
            raise LogFormatError(
                f"{p}: no sensor_combined instance {opts.imu_instance} and no sensor_accel + "
                f"sensor_gyro multi_id {opts.imu_instance} before byte {end}"
                + (f" (sensor_accel + sensor_gyro instances: {have})" if have else ""))
        notes.append(f"IMU from sensor_accel + sensor_gyro multi_id {opts.imu_instance}, "
                     f"increments at the {slow} rate")
    gps = _dataset(ulog, "vehicle_gps_position", opts.gnss_instance)
    src = "vehicle_gps_position"
    if gps is None:
        gps = _dataset(ulog, "sensor_gps", opts.gnss_instance)
        src = "sensor_gps"
    notes.append(f"GNSS from {src} multi_id {opts.gnss_instance}" if gps is not None
                 else "no GNSS topic in the log")
    if gps is not None:
        _gnss(b, gps, opts)
    ref = _reference(_dataset(ulog, "vehicle_attitude", 0))
    out = sink.getvalue().strip()
    if out:
        notes.append("pyulog: " + out.replace("\n", "; "))
    params = getattr(ulog, "initial_parameters", {}) or {}
    return b.build("ulog", p, ref, damage, notes, vehicle=_vehicle(ulog),
                   lever_arm=lever_arm_from_params(params, _ANTENNA, _IMU_POS),
                   accel_calibrated=accel_calibration_from_params(
                       params, _accel_cal_params(opts.imu_instance)))
