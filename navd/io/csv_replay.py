"""Replay format (docs/replay-format.md): CSV readers, merged sample stream, solution writer.

Readers never raise on a bad row: a row with a wrong field count, a non-number, NaN/Inf,
or a time stamp that is not strictly increasing is skipped and reported as a
:class:`RowIssue` with its line number.  A missing required column is an error
(:class:`ReplayFormatError`) because nothing sensible can be read then; so is a file that is
not UTF-8 text or not CSV at all (a field beyond the csv module's limit).

One wild time stamp must cost one row, not every later one (issue 19): a ``t_us`` outside
[0, 2**53) is skipped, and a row that jumps more than :data:`JUMP_CONFIRM_US` ahead is held
until the next row says whether the jump was real (the next row continues after it) or the
row was wild (the next row continues the old time line: the held row is skipped).
"""

from __future__ import annotations

import csv
import heapq
import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TextIO, TypeVar

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
T = TypeVar("T")
SOLUTION_COLS = ("t_us", "roll_deg", "pitch_deg", "yaw_deg", "lat_deg", "lon_deg", "alt_m",
                 "vel_n", "vel_e", "vel_d", "roll_sd_deg", "pitch_sd_deg", "yaw_sd_deg",
                 "heading_aligned")


# Largest t_us accepted (as the live adapters: navd.io.adapter.MAX_SENSOR_T_US).
MAX_T_US = 1 << 53
# A forward step larger than this needs the next row to confirm it (GNSS outages, logging
# pauses are real; a single row hours ahead is not).
JUMP_CONFIRM_US = 1_000_000


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
    head = next(_checked_rows(reader, path, 1), None)
    if head is None:
        raise ReplayFormatError(f"{path}: empty file (no header)")
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
    for line, row in enumerate(_checked_rows(reader, path, 2), start=2):
        if not row or (len(row) == 1 and not row[0].strip()):
            continue
        if len(row) != n_cols:
            rep.add(path, line, f"{len(row)} fields, header has {n_cols}")
            continue
        yield line, row


def _checked_rows(reader: Iterator[list[str]], path: str, first_line: int
                  ) -> Iterator[list[str]]:
    """The rows of ``reader``; a file that is not UTF-8 CSV raises ReplayFormatError (the csv
    module's and the decoder's own errors name neither the file nor the fix)."""
    line = first_line
    while True:
        try:
            row = next(reader)
        except StopIteration:
            return
        except csv.Error as exc:
            raise ReplayFormatError(f"{path}: near line {line}: not a CSV row ({exc})"
                                    ) from None
        except UnicodeDecodeError as exc:
            raise ReplayFormatError(f"{path}: near line {line}: not UTF-8 text (byte "
                                    f"0x{exc.object[exc.start]:02x}); is this a replay CSV?"
                                    ) from None
        yield row
        line += 1


def _in_time_order(items: Iterable[tuple[int, int, T]], path: str, rep: ReadReport
                   ) -> Iterator[tuple[int, T]]:
    """(t_us, item) of the (line, t_us, item) rows whose time stamps increase strictly;
    the others are reported.  A row more than JUMP_CONFIRM_US ahead of the last one is held
    until the next row: if that one is later still, the jump was real; if it continues the
    old time line, the held row alone was wrong and is skipped (so one wild stamp does not
    make every later row "non-monotonic")."""
    last = -1
    held: tuple[int, int, T] | None = None
    for line, t, item in items:
        if not 0 <= t < MAX_T_US:
            rep.add(path, line, f"t_us {t} out of range [0, 2**53)")
            continue
        if held is not None:
            h_line, h_t, h_item = held
            if t >= h_t:  # the jump is real: the time line goes on after it
                yield h_t, h_item
                last = h_t
                held = None
            elif t > last:  # the held row left the time line alone
                rep.add(path, h_line, f"t_us {h_t} jumps {(h_t - last) * 1e-6:.6g} s ahead "
                        f"and the next row goes back to {t}: skipped")
                held = None
        if (why := _order_issue(t, last)) is not None:
            rep.add(path, line, why)
            continue
        if last >= 0 and t - last > JUMP_CONFIRM_US:
            held = (line, t, item)
            continue
        last = t
        yield t, item
    if held is not None:  # nothing after it to contradict the jump
        yield held[1], held[2]


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
    with open(path, newline="", encoding="utf-8") as fh:
        reader = csv.reader(fh)
        cols = _header(reader, p)
        inc = "dtheta_x" in cols
        idx = _require(cols, IMU_INC_COLS if inc else IMU_RATE_COLS, p)
        names = IMU_INC_COLS[2:] if inc else IMU_RATE_COLS[1:]

        def parsed() -> Iterator[tuple[int, int, tuple[int, list[float]]]]:
            for line, row in _rows(reader, len(cols), p, rep):
                try:
                    t_us = int(row[idx["t_us"]])
                    dt_us = int(row[idx["dt_us"]]) if inc else 0
                except ValueError:
                    rep.add(p, line, "t_us/dt_us is not an integer")
                    continue
                vals = _floats(row, idx, names)
                if isinstance(vals, str):
                    rep.add(p, line, vals)
                    continue
                yield line, t_us, (dt_us, vals)

        last_t = -1
        for t_us, (dt_us, vals) in _in_time_order(parsed(), p, rep):
            if not inc and last_t < 0:
                # rate form: the first row only starts the clock
                last_t = t_us
                continue
            if not inc:
                dt_us = t_us - last_t
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
    with open(path, newline="", encoding="utf-8") as fh:
        reader = csv.reader(fh)
        cols = _header(reader, p)
        idx = _require(cols, GNSS_COLS, p)
        has_vel = all(c in idx for c in GNSS_ECEF_VEL)
        has_pos = all(c in idx for c in GNSS_ECEF_POS)

        def parsed() -> Iterator[tuple[int, int, GnssSample]]:
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
                yield line, t_us, GnssSample(
                    t_us, vals[0] * DEG, vals[1] * DEG, vals[2], vals[3], vals[4], vals[5],
                    vals[6], vals[7], vals[8], FixType.FIX_3D, pos_e, vel_e)

        for _, s in _in_time_order(parsed(), p, rep):
            rep.rows += 1
            yield s


def read_pol(path: str | Path, report: ReadReport | None = None) -> Iterator[PolSample]:
    """Yield polarization readings from a replay CSV (``POL_COLS``).  Only the row format
    and the time order are checked here; the estimator judges the values (and counts)."""
    rep = report if report is not None else ReadReport()
    p = str(path)
    with open(path, newline="", encoding="utf-8") as fh:
        reader = csv.reader(fh)
        cols = _header(reader, p)
        idx = _require(cols, POL_COLS, p)

        def parsed() -> Iterator[tuple[int, int, PolSample]]:
            for line, row in _rows(reader, len(cols), p, rep):
                try:
                    t_us = int(row[idx["t_us"]])
                    vals = [float(row[idx[c]]) for c in POL_COLS[1:]]
                except ValueError:
                    rep.add(p, line, "not a number")
                    continue
                yield line, t_us, PolSample(t_us, vals[0], vals[1], vals[2])

        for _, s in _in_time_order(parsed(), p, rep):
            rep.rows += 1
            yield s


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
