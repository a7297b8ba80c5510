"""The Skywalker X8 / PX4FMU text log (priseborough/InertialNav ``InputFilesPX4.zip``) and the
InertialNav multirotor logs of the same family (``f450_glitch_log.zip``, ``quad123.zip``).

A directory or zip holding space-separated text files, times in milliseconds from the start:
    IMU.txt     t_ms, t_ms, gyro x y z (rad/s, FRD), accel x y z (m/s^2, FRD), ~146 Hz with
                irregular intervals.  Point samples: held over the interval to the previous
                sample (RateIntegrator), i.e. dtheta = omega_k (t_k - t_{k-1}), exactly as the
                rate-form replay CSV is read; the first sample only starts the clock.
    GPSraw.txt  t_ms, lat (deg), lon (deg), alt (m, taken as MSL: + geoid_sep), vN, vE, vD
                (m/s), 5 Hz.  No accuracies are logged: ``LogOptions`` h_acc_m (2.5 m),
                v_acc_m (5 m), vel_acc_mps (0.3 m/s) are assumed; rows with lat = lon = 0
                are "no fix".  Time stamps are taken as the fixes' times of validity.
    ATT.txt     t_ms, t_ms, roll, pitch, yaw (deg) of the onboard 2013 EKF: the reference.
    GPS.txt     14 columns, the APM GPS message: t_ms, fix type, gps t_ms, 3 unused, lat, lon
                (deg), alt (m, twice), ground speed (m/s), course, vertical speed, unused.
                Read only where there is no GPSraw.txt (quad123.zip): NED velocity is built
                from speed and course, vel_d is NaN ("not reported") because the vertical
                speed column is too noisy to use (several m/s at rest in quad123; its sign is
                positive down: it anti-correlates with the altitude's rate, and InertialNav's
                own reader takes it as gpsVelD).  The course is in degrees in quad123 (and in
                InertialNav's reader) but in radians in the X8 and f450 logs, so the unit is
                detected from the values (any |course| > 2 pi -> degrees) and stated in a note.
                Rows with fix type < 3 are counted as "gnss_no_3d_fix" and skipped.
(MAG.txt, NTUN.txt, FLOW.txt and GPOSonboard.txt are unused: navd has no magnetometer, air-data
or flow aiding.)

ATT column order: InertialNav's reader and the dataset README say roll, pitch, yaw, but the
f450 log stores yaw first (yaw, roll, pitch: 56 deg in the "roll" column at rest).  The files
have no header, so the order is checked against physics: at rest (first 10 s, |gyro| < 0.2
rad/s, |f| within 1 m/s^2 of g) the reference roll and pitch must agree with the accelerometer
tilt within 10 deg.  The documented order is kept when it agrees (or nothing can be checked);
yaw-first is used only when it agrees and the documented one does not.  A note always says
which order was used and why.

Damage: a row with too few columns or a field that is not a finite number stops that file
at its line (reported as ``file:line``); all streams are then cut at the last good time of
the damaged file so the replay never runs on GNSS without IMU.
"""

from __future__ import annotations

import contextlib
import io
import math
import zipfile
import zlib
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from navd.io.logs.common import (
    LogDamage,
    LogData,
    LogFormatError,
    LogOptions,
    Reference,
    SampleBuilder,
)
from navd.types import FixType, GnssSample
from navd.units import DEG, G0

FILES = {"IMU.txt": 8, "GPSraw.txt": 7, "GPS.txt": 13, "ATT.txt": 5}
GNSS_FILES = ("GPSraw.txt", "GPS.txt")  # in order of preference: GPSraw has NED velocity

REST_WINDOW_S = 10.0   # logs start on the ground: look for rest samples here
REST_GYRO_RPS = 0.2
REST_ACCEL_TOL = 1.0   # | |f| - g | at rest, m/s^2
LAYOUT_TOL_DEG = 10.0  # reference tilt vs accelerometer tilt at rest

# ATT.txt (roll, pitch, yaw) column indices for each known layout
ATT_LAYOUTS: dict[str, tuple[int, int, int]] = {
    "roll,pitch,yaw": (2, 3, 4),  # documented (README, InertialNav readAhrsData)
    "yaw,roll,pitch": (3, 4, 2),  # f450_glitch_log.zip
}


def _sources(path: Path, stack: contextlib.ExitStack
             ) -> dict[str, tuple[str, Iterator[str]]]:
    """name -> (display path, line iterator) for the files present."""
    out: dict[str, tuple[str, Iterator[str]]] = {}
    if path.is_dir():
        for name in FILES:
            q = path / name
            if q.is_file():
                fh = stack.enter_context(open(q, encoding="ascii", errors="replace"))  # noqa: SIM115
                out[name] = (str(q), iter(fh))
        return out
    try:
        z = stack.enter_context(zipfile.ZipFile(path))
    except (zipfile.BadZipFile, OSError) as exc:
        raise LogFormatError(f"{path}: cannot open as zip: {exc}") from exc
    for info in z.infolist():
        base = info.filename.rsplit("/", 1)[-1]
        if base in FILES and base not in out:
            fh = stack.enter_context(
                io.TextIOWrapper(z.open(info), encoding="ascii", errors="replace"))
            out[base] = (f"{path}:{info.filename}", iter(fh))
    return out


def _rows(name: str, where: str, lines: Iterator[str]
          ) -> tuple[list[list[float]], LogDamage | None]:
    need = FILES[name]
    rows: list[list[float]] = []
    line = 0
    while True:
        try:
            text = next(lines)
        except StopIteration:
            return rows, None
        except (zipfile.BadZipFile, zlib.error, EOFError, OSError) as exc:
            return rows, LogDamage(where, "line", line + 1, f"cannot read further: {exc}")
        line += 1
        parts = text.split()
        if not parts:
            continue
        if len(parts) < need:
            return rows, LogDamage(where, "line", line,
                                   f"{len(parts)} columns, expected at least {need}")
        try:
            vals = [float(x) for x in parts[:need]]
        except ValueError:
            return rows, LogDamage(where, "line", line, "a field is not a number")
        if not all(math.isfinite(v) for v in vals):
            return rows, LogDamage(where, "line", line, "a field is NaN or infinite")
        rows.append(vals)


def _gnss_from_gps_txt(b: SampleBuilder, rows: list[list[float]], opts: LogOptions
                       ) -> str:
    """Fixes from the 14-column GPS.txt (no NED velocity); returns the note on units."""
    course = np.asarray([r[11] for r in rows], dtype=np.float64)
    # radians never exceed 2 pi; a log in degrees does as soon as the course passes ~6 deg
    degrees = bool(course.size) and float(np.max(np.abs(course))) > 2.0 * math.pi + 1e-3
    to_rad = DEG if degrees else 1.0
    h, v, s = b.accuracy(None, None, None)
    for r in rows:
        if r[6] == 0.0 and r[7] == 0.0:
            b.counters.inc("gnss_no_fix")
            continue
        fix = FixType.FIX_3D if r[1] >= 3 else FixType.FIX_2D if r[1] >= 2 else FixType.NONE
        spd, chi = r[10], r[11] * to_rad
        # vel_d NaN: the vertical speed column is not trusted (see the module docstring)
        b.add_gnss(GnssSample(round(r[0] * 1000.0), r[6] * DEG, r[7] * DEG,
                              r[8] + opts.geoid_sep_m, spd * math.cos(chi),
                              spd * math.sin(chi), math.nan, h, v, s, fix))
    unit = "degrees (some |course| > 2 pi)" if degrees else "radians (all |course| <= 2 pi)"
    return (f"GNSS from GPS.txt (no GPSraw.txt): NED velocity from ground speed and course, "
            f"course read as {unit}; vertical velocity not used (NaN)")


def _att_layout(imu: list[list[float]], att: list[list[float]]
                ) -> tuple[tuple[int, int, int], str]:
    """(roll, pitch, yaw) columns of ATT.txt and a note saying which layout and why."""
    doc = "roll,pitch,yaw"
    if not imu or len(att) < 2:
        return ATT_LAYOUTS[doc], f"ATT.txt read as {doc} (documented; too little data to check)"
    m = np.asarray(imu, dtype=np.float64)
    a = np.asarray(att, dtype=np.float64)
    t0 = m[0, 0]
    f = m[:, 5:8]
    rest = ((m[:, 0] <= t0 + REST_WINDOW_S * 1000.0)
            & (np.linalg.norm(m[:, 2:5], axis=1) < REST_GYRO_RPS)
            & (np.abs(np.linalg.norm(f, axis=1) - G0) < REST_ACCEL_TOL)
            & (m[:, 0] >= a[0, 0]) & (m[:, 0] <= a[-1, 0]))
    if int(rest.sum()) < 10:
        return ATT_LAYOUTS[doc], (f"ATT.txt read as {doc} (documented; no rest samples in the "
                                  f"first {REST_WINDOW_S:.0f} s to check it)")
    fr = f[rest]
    # FRD specific force at rest is -g rotated into the body: f = g (sin p, -sin r cos p,
    # -cos r cos p)
    acc_roll = np.degrees(np.arctan2(-fr[:, 1], -fr[:, 2]))
    acc_pitch = np.degrees(np.arctan2(fr[:, 0], np.hypot(fr[:, 1], fr[:, 2])))
    order = np.argsort(a[:, 0], kind="stable")
    ta = a[order, 0]
    err: dict[str, float] = {}
    for name, (ri, pi, _) in ATT_LAYOUTS.items():
        r = np.interp(m[rest, 0], ta, a[order, ri])
        p = np.interp(m[rest, 0], ta, a[order, pi])
        err[name] = max(abs(float(np.median(r - acc_roll))),
                        abs(float(np.median(p - acc_pitch))))
    figures = ", ".join(f"{k} {v:.1f} deg" for k, v in err.items())
    why = (f"reference tilt minus accelerometer tilt at rest ({int(rest.sum())} samples): "
           f"{figures}")
    if err[doc] <= LAYOUT_TOL_DEG:
        return ATT_LAYOUTS[doc], f"ATT.txt read as {doc} (documented; {why})"
    alt = "yaw,roll,pitch"
    if err[alt] <= LAYOUT_TOL_DEG:
        return ATT_LAYOUTS[alt], (f"ATT.txt read as {alt}, not the documented {doc} "
                                  f"({why})")
    return ATT_LAYOUTS[doc], (f"ATT.txt read as {doc} (documented) but NO layout agrees "
                              f"with the accelerometer at rest ({why}): reference doubtful")


def read_x8(path: str | Path, options: LogOptions | None = None) -> LogData:
    opts = options if options is not None else LogOptions()
    p = Path(path)
    if not p.exists():
        raise LogFormatError(f"no such file or directory: {p}")
    data: dict[str, list[list[float]]] = {}
    damages: list[tuple[int, LogDamage]] = []
    with contextlib.ExitStack() as stack:
        src = _sources(p, stack)
        if "IMU.txt" not in src:
            raise LogFormatError(f"{p}: no IMU.txt")
        if not any(n in src for n in GNSS_FILES):
            raise LogFormatError(f"{p}: no GPSraw.txt or GPS.txt")
        if "GPSraw.txt" in src:
            src.pop("GPS.txt", None)  # the same fixes without NED velocity: not needed
        for name, (where, lines) in src.items():
            rows, dmg = _rows(name, where, lines)
            data[name] = rows
            if dmg is not None:
                last_t = round(rows[-1][0] * 1000.0) if rows else -1
                damages.append((last_t, dmg))
    b = SampleBuilder(opts)
    for r in data["IMU.txt"]:
        b.add_rates(round(r[0] * 1000.0), (r[2], r[3], r[4]), (r[5], r[6], r[7]))
    h, v, s = b.accuracy(None, None, None)
    notes = [f"GNSS accuracies assumed (not logged): h {h} m, v {v} m, vel {s} m/s"]
    if "GPSraw.txt" in data:
        for r in data["GPSraw.txt"]:
            if r[1] == 0.0 and r[2] == 0.0:
                b.counters.inc("gnss_no_fix")
                continue
            b.add_gnss(GnssSample(round(r[0] * 1000.0), r[1] * DEG, r[2] * DEG,
                                  r[3] + opts.geoid_sep_m, r[4], r[5], r[6], h, v, s,
                                  FixType.FIX_3D))
    else:
        notes.append(_gnss_from_gps_txt(b, data["GPS.txt"], opts))
    att = data.get("ATT.txt", [])
    if att:
        (ri, pi, yi), layout_note = _att_layout(data["IMU.txt"], att)
        notes.append(layout_note)
        a = np.asarray(att, dtype=np.float64)
        ref = Reference(np.rint(a[:, 0] * 1000.0).astype(np.int64), a[:, ri] * DEG,
                        a[:, pi] * DEG, (a[:, yi] * DEG + math.pi) % (2 * math.pi) - math.pi,
                        "ATT.txt")
    else:
        ref = Reference.empty()
    damage = None
    t_end = None
    if damages:
        t_end, damage = min(damages, key=lambda d: d[0])
        notes += [str(d) for _, d in damages if d is not damage]
        notes.append(f"all streams cut at t_us {t_end} (last good row of the damaged file)")
    return b.build("x8", str(p), ref, damage, notes, t_end)
