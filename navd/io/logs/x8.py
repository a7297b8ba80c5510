"""The Skywalker X8 / PX4FMU text log (priseborough/InertialNav ``InputFilesPX4.zip``).

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
(GPS.txt repeats the fix with speed and course in radians; MAG.txt and NTUN.txt are unused:
navd has no magnetometer or air-data aiding.)

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
from navd.units import DEG

FILES = {"IMU.txt": 8, "GPSraw.txt": 7, "ATT.txt": 5}


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


def read_x8(path: str | Path, options: LogOptions | None = None) -> LogData:
    opts = options if options is not None else LogOptions()
    p = Path(path)
    if not p.exists():
        raise LogFormatError(f"no such file or directory: {p}")
    data: dict[str, list[list[float]]] = {}
    damages: list[tuple[int, LogDamage]] = []
    with contextlib.ExitStack() as stack:
        src = _sources(p, stack)
        for need in ("IMU.txt", "GPSraw.txt"):
            if need not in src:
                raise LogFormatError(f"{p}: no {need}")
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
    for r in data["GPSraw.txt"]:
        if r[1] == 0.0 and r[2] == 0.0:
            b.counters.inc("gnss_no_fix")
            continue
        b.add_gnss(GnssSample(round(r[0] * 1000.0), r[1] * DEG, r[2] * DEG,
                              r[3] + opts.geoid_sep_m, r[4], r[5], r[6], h, v, s,
                              FixType.FIX_3D))
    att = data.get("ATT.txt", [])
    if att:
        a = np.asarray(att, dtype=np.float64)
        ref = Reference(np.rint(a[:, 0] * 1000.0).astype(np.int64), a[:, 2] * DEG,
                        a[:, 3] * DEG, (a[:, 4] * DEG + math.pi) % (2 * math.pi) - math.pi,
                        "ATT.txt")
    else:
        ref = Reference.empty()
    notes = [f"GNSS accuracies assumed (not logged): h {h} m, v {v} m, vel {s} m/s"]
    damage = None
    t_end = None
    if damages:
        t_end, damage = min(damages, key=lambda d: d[0])
        notes += [str(d) for _, d in damages if d is not damage]
        notes.append(f"all streams cut at t_us {t_end} (last good row of the damaged file)")
    return b.build("x8", str(p), ref, damage, notes, t_end)
