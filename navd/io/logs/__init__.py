"""Flight logs in: PX4 ULog, ArduPilot DataFlash ``.bin``, MAVLink ``.tlog``, the X8 text log.

``read_log(path)`` detects the format from the content (or takes ``fmt``) and returns a
:class:`LogData`: the samples the daemon would push, in time order, plus the log's onboard
attitude as a reference.  ``navd replay --log FILE`` pushes them through the same
:func:`navd.cli.replay.run_replay` as the CSV path.

Detection (first bytes, not the file name):
    ulog       ``ULog\\x01\\x12\\x35`` magic
    dataflash  ``0xA3 0x95`` message header at offset 0
    tlog       8-byte big-endian microsecond time stamp, then a MAVLink frame (0xFE / 0xFD),
               and the next time stamp + frame where that frame says it ends
    x8         a directory or zip holding ``IMU.txt`` and ``GPSraw.txt`` or ``GPS.txt`` (the
               InertialNav text logs: X8 plane, f450 and quad123 multirotors; they do not
               state a vehicle type, so ``navd replay`` keeps the configured profile); a
               directory holding no log files but exactly one such zip (the dataset folders
               ``px4-x8-flight/``: a README and the zip) reads that zip
    csv        a directory holding ``imu.csv`` and ``gnss.csv`` (docs/replay-format.md)
"""

from __future__ import annotations

import struct
import zipfile
from pathlib import Path

from navd.io.logs.common import (
    FORMATS,
    AidingWriter,
    LogDamage,
    LogData,
    LogFormatError,
    LogOptions,
    Reference,
    write_reference,
)

__all__ = [
    "FORMATS",
    "AidingWriter",
    "LogDamage",
    "LogData",
    "LogFormatError",
    "LogOptions",
    "Reference",
    "detect_format",
    "read_log",
    "write_reference",
]

ULOG_MAGIC = b"ULog\x01\x12\x35"
DATAFLASH_HEAD = b"\xa3\x95"


def _looks_like_tlog(head: bytes) -> bool:
    if len(head) < 8 + 8 or head[8] not in (0xFE, 0xFD):
        return False
    (t_us,) = struct.unpack_from(">Q", head, 0)
    if t_us >= 1 << 62:
        return False
    n = head[9]
    end = 8 + n + (8 if head[8] == 0xFE else 12 + (13 if head[10] & 1 else 0))
    # a second record must start where the first frame ends (if the head reaches there)
    if len(head) >= end + 9:
        return head[end + 8] in (0xFE, 0xFD)
    return True


def detect_format(path: str | Path) -> str:
    """One of ``FORMATS`` from the content; LogFormatError if unrecognised."""
    p = Path(path)
    if p.is_dir():
        names = {q.name for q in p.iterdir()}
        if "IMU.txt" in names and names & {"GPSraw.txt", "GPS.txt"}:
            return "x8"
        if {"imu.csv", "gnss.csv"} <= names:
            return "csv"
        zips = sorted(q.name for q in p.iterdir() if q.suffix.lower() == ".zip")
        hint = (f"; it holds {', '.join(zips[:5])}{' ...' if len(zips) > 5 else ''}: give "
                "one of those" if zips else "")
        raise LogFormatError(f"{p}: directory holds neither IMU.txt + GPSraw.txt/GPS.txt "
                             "(X8/InertialNav) nor "
                             f"imu.csv + gnss.csv (replay CSV){hint}")
    try:
        with open(p, "rb") as fh:
            head = fh.read(600)
    except OSError as exc:
        raise LogFormatError(f"cannot read {p}: {exc}") from exc
    if head.startswith(ULOG_MAGIC):
        return "ulog"
    if head.startswith(DATAFLASH_HEAD):
        return "dataflash"
    if head.startswith(b"PK\x03\x04"):
        try:
            with zipfile.ZipFile(p) as z:
                base = {n.rsplit("/", 1)[-1] for n in z.namelist()}
        except zipfile.BadZipFile as exc:
            raise LogFormatError(f"{p}: damaged zip file: {exc}") from exc
        if "IMU.txt" in base and base & {"GPSraw.txt", "GPS.txt"}:
            return "x8"
        raise LogFormatError(f"{p}: zip file without IMU.txt and GPSraw.txt or GPS.txt")
    if _looks_like_tlog(head):
        return "tlog"
    if not head:
        raise LogFormatError(f"{p}: empty file")
    raise LogFormatError(f"{p}: unknown log format (first bytes {head[:8].hex(' ')}); "
                         f"give --format one of {', '.join(FORMATS)}")


def _only_zip(path: str | Path) -> Path | None:
    """The one InertialNav zip in a directory that holds no log files of its own (the
    dataset folders: a README and the zip), else None."""
    p = Path(path)
    if not p.is_dir():
        return None
    names = {q.name for q in p.iterdir()}
    if "IMU.txt" in names or {"imu.csv", "gnss.csv"} <= names:
        return None
    zips = [q for q in p.iterdir() if q.suffix.lower() == ".zip" and q.is_file()]
    if len(zips) != 1:
        return None
    try:
        return zips[0] if detect_format(zips[0]) == "x8" else None
    except LogFormatError:
        return None


def read_log(path: str | Path, fmt: str | None = None,
             options: LogOptions | None = None) -> LogData:
    """Read a whole log (format detected unless ``fmt`` is given)."""
    opts = options if options is not None else LogOptions()
    inner = _only_zip(path) if fmt in (None, "x8") else None
    if inner is not None:  # a dataset folder (README + one zip): read its zip
        data = read_log(inner, fmt, opts)
        data.notes.insert(0, f"{path} holds one log, {inner.name}: read that")
        return data
    kind = fmt or detect_format(path)
    if fmt is not None and fmt != "csv":
        # A wrong --format made the DataFlash decoder print one "bad header" line per byte
        # of a ULog (543,231 lines) before reading nothing; refuse it up front instead.
        try:
            seen = detect_format(path)
        except LogFormatError:
            seen = None  # unrecognised (maybe damaged) content: the user's word stands
        if seen is not None and seen != fmt:
            raise LogFormatError(f"{path}: --format {fmt}, but the content is a {seen} log; "
                                 f"leave --format out or give --format {seen}")
    if kind == "ulog":
        from navd.io.logs.ulog import read_ulog

        return read_ulog(path, opts)
    if kind == "dataflash":
        from navd.io.logs.dataflash import read_dataflash

        return read_dataflash(path, opts)
    if kind == "tlog":
        from navd.io.logs.tlog import read_tlog

        return read_tlog(path, opts)
    if kind == "x8":
        from navd.io.logs.x8 import read_x8

        return read_x8(path, opts)
    if kind == "csv":
        from navd.io.logs.common import read_csv_dir

        return read_csv_dir(path, opts)
    raise LogFormatError(f"unknown format {kind!r}; expected one of {', '.join(FORMATS)}")
