"""Replay format (docs/replay-format.md): CSV readers, merged sample stream, solution writer.

Readers never raise on a bad row: a row with a wrong field count, a non-number, NaN/Inf,
or a time stamp that is not strictly increasing is skipped and reported as a
:class:`RowIssue` with its line number.  A missing required column is an error
(:class:`ReplayFormatError`) because nothing sensible can be read then.
"""

from __future__ import annotations

import csv
import heapq
import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TextIO

from navd.types import FixType, GnssSample, ImuSample, NavSolution, PolSample
from navd.units import DEG

IMU_RATE_COLS = ("t_us", "gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z")
IMU_INC_COLS = ("t_us", "dt_us", "dtheta_x", "dtheta_y", "dtheta_z", "dvel_x", "dvel_y",
                "dvel_z")
GNSS_COLS = ("t_us", "lat_deg", "lon_deg", "alt_m", "vel_n", "vel_e", "vel_d", "h_acc_m",
             "v_acc_m", "vel_acc_mps")
GNSS_ECEF_VEL = ("vel_x_ecef", "vel_y_ecef", "vel_z_ecef")
GNSS_ECEF_POS = ("x_ecef", "y_ecef", "z_ecef")
POL_COLS = ("t_us", "aop_rad", "dop", "utc_unix_s")
SOLUTION_COLS = ("t_us", "roll_deg", "pitch_deg", "yaw_deg", "lat_deg", "lon_deg", "alt_m",
                 "vel_n", "vel_e", "vel_d", "roll_sd_deg", "pitch_sd_deg", "yaw_sd_deg",
                 "heading_aligned")


class ReplayFormatError(ValueError):
    """The file cannot be read as the replay format at all (e.g. a missing column)."""


@dataclass
class RowIssue:
    path: str
    line: int
    reason: str

    def __str__(self) -> str:
        return f"{self.path}:{self.line}: {self.reason}"


@dataclass
class ReadReport:
    issues: list[RowIssue] = field(default_factory=list)
    rows: int = 0

    def add(self, path: str, line: int, reason: str) -> None:
        self.issues.append(RowIssue(path, line, reason))


def _header(reader: Iterator[list[str]], path: str) -> list[str]:
    try:
        head = next(reader)
    except StopIteration as exc:
        raise ReplayFormatError(f"{path}: empty file (no header)") from exc
    return [h.strip() for h in head]


def _require(cols: list[str], needed: Iterable[str], path: str) -> dict[str, int]:
    idx = {c: i for i, c in enumerate(cols)}
    missing = [c for c in needed if c not in idx]
    if missing:
        raise ReplayFormatError(f"{path}: missing column(s) {', '.join(missing)}; "
                                f"header is {','.join(cols)}")
    return idx


def _rows(reader: Iterator[list[str]], n_cols: int, path: str, rep: ReadReport
          ) -> Iterator[tuple[int, list[str]]]:
    """(file line number, fields) of each non-blank row with the header's field count."""
    for line, row in enumerate(reader, start=2):
        if not row or (len(row) == 1 and not row[0].strip()):
            continue
        if len(row) != n_cols:
            rep.add(path, line, f"{len(row)} fields, header has {n_cols}")
            continue
        yield line, row


def _order_issue(t_us: int, last_t: int) -> str | None:
    if last_t >= 0 and t_us <= last_t:
        return ("duplicate" if t_us == last_t else "non-monotonic") + f" t_us {t_us} after {last_t}"
    return None


def _floats(row: list[str], idx: dict[str, int], names: Iterable[str]) -> list[float] | str:
    out: list[float] = []
    for n in names:
        try:
            v = float(row[idx[n]])
        except (ValueError, IndexError):
            return f"column {n} is not a number: {row[idx[n]] if idx[n] < len(row) else ''!r}"
        if not math.isfinite(v):
            return f"column {n} is {v}"
        out.append(v)
    return out


def read_imu(path: str | Path, report: ReadReport | None = None) -> Iterator[ImuSample]:
    """Yield IMU samples from a rate-form or increment-form CSV (detected from the header)."""
    rep = report if report is not None else ReadReport()
    p = str(path)
    with open(path, newline="") as fh:
        reader = csv.reader(fh)
        cols = _header(reader, p)
        inc = "dtheta_x" in cols
        idx = _require(cols, IMU_INC_COLS if inc else IMU_RATE_COLS, p)
        names = IMU_INC_COLS[2:] if inc else IMU_RATE_COLS[1:]
        last_t = -1
        for line, row in _rows(reader, len(cols), p, rep):
            try:
                t_us = int(row[idx["t_us"]])
                dt_us = int(row[idx["dt_us"]]) if inc else (t_us - last_t if last_t >= 0 else 0)
            except ValueError:
                rep.add(p, line, "t_us/dt_us is not an integer")
                continue
            vals = _floats(row, idx, names)
            if isinstance(vals, str):
                rep.add(p, line, vals)
                continue
            if (why := _order_issue(t_us, last_t)) is not None:
                rep.add(p, line, why)
                continue
            if not inc and last_t < 0:
                # rate form: the first row only starts the clock
                last_t = t_us
                continue
            last_t = t_us
            rep.rows += 1
            if inc:
                yield ImuSample(t_us, dt_us, *vals)
            else:
                dt = dt_us * 1e-6
                yield ImuSample(t_us, dt_us, vals[0] * dt, vals[1] * dt, vals[2] * dt,
                                vals[3] * dt, vals[4] * dt, vals[5] * dt)


def read_gnss(path: str | Path, report: ReadReport | None = None) -> Iterator[GnssSample]:
    """Yield GNSS samples from the replay CSV (optional ECEF position/velocity columns)."""
    rep = report if report is not None else ReadReport()
    p = str(path)
    with open(path, newline="") as fh:
        reader = csv.reader(fh)
        cols = _header(reader, p)
        idx = _require(cols, GNSS_COLS, p)
        has_vel = all(c in idx for c in GNSS_ECEF_VEL)
        has_pos = all(c in idx for c in GNSS_ECEF_POS)
        last_t = -1
        for line, row in _rows(reader, len(cols), p, rep):
            try:
                t_us = int(row[idx["t_us"]])
            except ValueError:
                rep.add(p, line, "t_us is not an integer")
                continue
            vals = _floats(row, idx, GNSS_COLS[1:])
            if isinstance(vals, str):
                rep.add(p, line, vals)
                continue
            vel_e: tuple[float, float, float] | None = None
            pos_e: tuple[float, float, float] | None = None
            if has_vel:
                v = _floats(row, idx, GNSS_ECEF_VEL)
                if isinstance(v, str):
                    rep.add(p, line, v)
                    continue
                vel_e = (v[0], v[1], v[2])
            if has_pos:
                q = _floats(row, idx, GNSS_ECEF_POS)
                if isinstance(q, str):
                    rep.add(p, line, q)
                    continue
                pos_e = (q[0], q[1], q[2])
            if (why := _order_issue(t_us, last_t)) is not None:
                rep.add(p, line, why)
                continue
            last_t = t_us
            rep.rows += 1
            yield GnssSample(t_us, vals[0] * DEG, vals[1] * DEG, vals[2], vals[3], vals[4],
                             vals[5], vals[6], vals[7], vals[8], FixType.FIX_3D, pos_e, vel_e)


def read_pol(path: str | Path, report: ReadReport | None = None) -> Iterator[PolSample]:
    """Yield polarization readings from a replay CSV (``POL_COLS``).  Only the row format
    and the time order are checked here; the estimator judges the values (and counts)."""
    rep = report if report is not None else ReadReport()
    p = str(path)
    with open(path, newline="") as fh:
        reader = csv.reader(fh)
        cols = _header(reader, p)
        idx = _require(cols, POL_COLS, p)
        last_t = -1
        for line, row in _rows(reader, len(cols), p, rep):
            try:
                t_us = int(row[idx["t_us"]])
                vals = [float(row[idx[c]]) for c in POL_COLS[1:]]
            except ValueError:
                rep.add(p, line, "not a number")
                continue
            if (why := _order_issue(t_us, last_t)) is not None:
                rep.add(p, line, why)
                continue
            last_t = t_us
            rep.rows += 1
            yield PolSample(t_us, vals[0], vals[1], vals[2])


def merge(imu: Iterable[ImuSample], gnss: Iterable[GnssSample],
          pol: Iterable[PolSample] = ()) -> Iterator[ImuSample | GnssSample | PolSample]:
    """Time-ordered stream; GNSS and then polarization at the same t_us follow the IMU
    sample."""
    Item = tuple[int, int, ImuSample | GnssSample | PolSample]
    keyed_imu: Iterator[Item] = ((s.t_us, 0, s) for s in imu)
    keyed_gnss: Iterator[Item] = ((s.t_us, 1, s) for s in gnss)
    keyed_pol: Iterator[Item] = ((s.t_us, 2, s) for s in pol)
    for _, _, s in heapq.merge(keyed_imu, keyed_gnss, keyed_pol, key=lambda k: (k[0], k[1])):
        yield s


class SolutionWriter:
    """Writes solution rows (the columns of SOLUTION_COLS) to a text stream."""

    def __init__(self, fh: TextIO) -> None:
        self._fh = fh
        fh.write(",".join(SOLUTION_COLS) + "\n")

    def write(self, s: NavSolution) -> None:
        r = 180.0 / math.pi
        self._fh.write(
            f"{s.t_us},{s.roll_rad * r:.6f},{s.pitch_rad * r:.6f},{s.yaw_rad * r:.6f},"
            f"{s.lat_rad * r:.9f},{s.lon_rad * r:.9f},{s.alt_m:.4f},"
            f"{s.vel_n[0]:.5f},{s.vel_n[1]:.5f},{s.vel_n[2]:.5f},"
            f"{s.att_sd_rad[0] * r:.6f},{s.att_sd_rad[1] * r:.6f},{s.att_sd_rad[2] * r:.6f},"
            f"{int(s.heading_aligned)}\n")
