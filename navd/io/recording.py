"""Recordings: every sample the daemon pushed into the estimator, replayable bit for bit.

The estimator is deterministic and :meth:`Estimator.push` is its only input, so a log of the
pushed samples (in push order) plus the estimator configuration reproduces every NavSolution
the daemon produced.  ``navd run --record FILE`` writes one; ``navd replay --recording FILE``
reads it.

File layout (little-endian)::

    b"NAVDREC1"                      magic and format version
    uint32 n, n bytes of UTF-8 JSON  header: {"format": 1, "navd": version,
                                     "created_utc": ..., "config": raw config tables,
                                     "output_rate_hz": ...}
    records, each starting with a type byte:
      b"I"  int64 t_us, int64 dt_us, 6 x float64 (dtheta xyz rad, dvel xyz m/s)
      b"G"  int64 t_us, 9 x float64 (lat_rad, lon_rad, alt_m, vel_n/e/d m/s, h_acc_m,
            v_acc_m, vel_acc_mps), uint8 fix_type, uint8 flags
            (bit 0: ECEF position follows, bit 1: ECEF velocity follows), then 3 x float64
            for each present vector (m, m/s)
      b"P"  int64 t_us, 3 x float64 (aop_rad, dop, utc_unix_s)

Floats are stored as IEEE doubles, so nothing is rounded (NaN payloads included).  A record
cut short at the end (the daemon was killed mid-write) ends the stream; it is reported by
:attr:`RecordingReader.truncated_bytes`, never raised.
"""

from __future__ import annotations

import datetime
import json
import math
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO, TextIO

from navd import __version__
from navd.types import FixType, GnssSample, ImuSample, NavSolution, PolSample, Sample

__all__ = [
    "MAGIC",
    "RecordingError",
    "RecordingReader",
    "RecordingWriter",
    "SolutionJsonlWriter",
    "read_solutions_jsonl",
]

MAGIC = b"NAVDREC1"
FORMAT_VERSION = 1

_LEN = struct.Struct("<I")
_IMU = struct.Struct("<qq6d")
_GNSS = struct.Struct("<q9dBB")
_VEC3 = struct.Struct("<3d")
_POL = struct.Struct("<q3d")
_HAS_POS = 1
_HAS_VEL = 2



class RecordingError(ValueError):
    """The file is not a navd recording (or of an unknown format version), or a sample
    cannot be written to one (a value outside its binary field)."""


class RecordingWriter:
    """Appends samples to a recording; ``flush`` periodically, ``close`` at the end."""

    def __init__(self, path: str | Path, config: dict[str, Any], output_rate_hz: float) -> None:
        self.path = Path(path)
        header = {
            "format": FORMAT_VERSION,
            "navd": __version__,
            "created_utc": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
            "config": config,
            "output_rate_hz": output_rate_hz,
        }
        # default=str: TOML dates/times are not JSON; they are not estimator settings anyway
        blob = json.dumps(header, default=str, allow_nan=True).encode()
        self._fh: BinaryIO = open(self.path, "wb")  # noqa: SIM115 - closed by close()
        self._fh.write(MAGIC + _LEN.pack(len(blob)) + blob)
        self.records = 0

    def write(self, s: Sample) -> None:
        """Append one sample.  Raises :class:`RecordingError` (and writes nothing) when a
        value does not fit its field, OSError when the file cannot be written."""
        try:
            blob = self._encode(s)
        except (struct.error, TypeError, ValueError, OverflowError) as exc:
            # The record is built whole before anything is written, so a refused sample
            # leaves the file a valid recording.
            raise RecordingError(f"cannot record {type(s).__name__} at t_us={s.t_us!r}: "
                                 f"{exc}") from exc
        self._fh.write(blob)
        self.records += 1

    @staticmethod
    def _encode(s: Sample) -> bytes:
        if isinstance(s, ImuSample):
            return b"I" + _IMU.pack(s.t_us, s.dt_us, s.dtheta_x, s.dtheta_y,
                                    s.dtheta_z, s.dvel_x, s.dvel_y, s.dvel_z)
        if isinstance(s, GnssSample):
            flags = (_HAS_POS if s.pos_ecef_m is not None else 0) | (
                _HAS_VEL if s.vel_ecef_mps is not None else 0)
            parts = [b"G", _GNSS.pack(s.t_us, s.lat_rad, s.lon_rad, s.alt_m, s.vel_n, s.vel_e,
                                      s.vel_d, s.h_acc_m, s.v_acc_m, s.vel_acc_mps,
                                      int(s.fix_type), flags)]
            if s.pos_ecef_m is not None:
                parts.append(_VEC3.pack(*s.pos_ecef_m))
            if s.vel_ecef_mps is not None:
                parts.append(_VEC3.pack(*s.vel_ecef_mps))
            return b"".join(parts)
        return b"P" + _POL.pack(s.t_us, s.aop_rad, s.dop, s.utc_unix_s)

    def flush(self) -> None:
        self._fh.flush()

    def close(self) -> None:
        if not self._fh.closed:
            self._fh.close()


class RecordingReader:
    """Reads a recording: :attr:`header`, then :meth:`samples` in push order."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._data = self.path.read_bytes()
        d = self._data
        if d[: len(MAGIC)] != MAGIC:
            raise RecordingError(f"{self.path}: not a navd recording (bad magic)")
        off = len(MAGIC)
        if len(d) < off + _LEN.size:
            raise RecordingError(f"{self.path}: truncated header")
        (n,) = _LEN.unpack_from(d, off)
        off += _LEN.size
        try:
            header = json.loads(d[off : off + n])
        except (ValueError, RecursionError) as exc:
            raise RecordingError(f"{self.path}: header is not JSON: {exc}") from exc
        if not isinstance(header, dict) or header.get("format") != FORMAT_VERSION:
            raise RecordingError(f"{self.path}: unsupported recording format "
                                 f"{header.get('format') if isinstance(header, dict) else '?'}")
        self.header: dict[str, Any] = header
        self._start = off + n
        self.truncated_bytes = 0

    @property
    def config(self) -> dict[str, Any]:
        cfg = self.header.get("config", {})
        return cfg if isinstance(cfg, dict) else {}

    @property
    def output_rate_hz(self) -> float:
        r = self.header.get("output_rate_hz", 50.0)
        return float(r) if isinstance(r, int | float) and math.isfinite(r) and r > 0 else 50.0

    def samples(self) -> Iterator[Sample]:
        d = self._data
        off = self._start
        end = len(d)
        while off < end:
            kind = d[off : off + 1]
            if kind == b"I":
                if off + 1 + _IMU.size > end:
                    break
                t, dt, a, b, c, x, y, z = _IMU.unpack_from(d, off + 1)
                off += 1 + _IMU.size
                yield ImuSample(t, dt, a, b, c, x, y, z)
            elif kind == b"G":
                if off + 1 + _GNSS.size > end:
                    break
                (t, lat, lon, alt, vn, ve, vd, ha, va, sa, fix, flags) = _GNSS.unpack_from(
                    d, off + 1)
                need = 1 + _GNSS.size + _VEC3.size * (bool(flags & _HAS_POS)
                                                      + bool(flags & _HAS_VEL))
                if off + need > end:
                    break
                p = off + 1 + _GNSS.size
                pos: tuple[float, float, float] | None = None
                vel: tuple[float, float, float] | None = None
                if flags & _HAS_POS:
                    pos = _VEC3.unpack_from(d, p)
                    p += _VEC3.size
                if flags & _HAS_VEL:
                    vel = _VEC3.unpack_from(d, p)
                try:
                    fix_type = FixType(fix)
                except ValueError:
                    raise RecordingError(f"{self.path}: GNSS record at byte {off} has fix "
                                         f"type {fix}, which no FixType is (damaged file?)"
                                         ) from None
                off += need
                yield GnssSample(t, lat, lon, alt, vn, ve, vd, ha, va, sa, fix_type, pos, vel)
            elif kind == b"P":
                if off + 1 + _POL.size > end:
                    break
                t, aop, dop, utc = _POL.unpack_from(d, off + 1)
                off += 1 + _POL.size
                yield PolSample(t, aop, dop, utc)
            else:
                raise RecordingError(f"{self.path}: bad record type {kind!r} at byte {off} "
                                     "(damaged file?)")
        self.truncated_bytes = end - off


@dataclass
class SolutionJsonlWriter:
    """One NavSolution per line as JSON; floats via repr, so they read back bit for bit."""

    fh: TextIO

    def write(self, s: NavSolution) -> None:
        self.fh.write(json.dumps({
            "t_us": s.t_us, "quat_nb": s.quat_nb, "roll_rad": s.roll_rad,
            "pitch_rad": s.pitch_rad, "yaw_rad": s.yaw_rad, "lat_rad": s.lat_rad,
            "lon_rad": s.lon_rad, "alt_m": s.alt_m, "vel_n": s.vel_n,
            "att_sd_rad": s.att_sd_rad, "gyro_bias_rps": s.gyro_bias_rps,
            "accel_bias_mps2": s.accel_bias_mps2, "heading_aligned": s.heading_aligned,
            "heading_initialised": s.heading_initialised,
            "rate_b": s.rate_b, "pos_sd_m": s.pos_sd_m, "vel_sd_mps": s.vel_sd_mps,
            "gnss_age_us": s.gnss_age_us, "heading_resets": s.heading_resets,
            "yaw_sd_installation_rad": s.yaw_sd_installation_rad}) + "\n")


_NAN3 = (math.nan, math.nan, math.nan)  # files written before the sigmas were recorded


def _t3(v: Any) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))


def read_solutions_jsonl(path: str | Path) -> list[NavSolution]:
    out: list[NavSolution] = []
    with open(path, encoding="utf-8") as fh:
        for line in fh:
            d = json.loads(line)
            q = d["quat_nb"]
            out.append(NavSolution(
                t_us=int(d["t_us"]), quat_nb=(float(q[0]), float(q[1]), float(q[2]), float(q[3])),
                roll_rad=float(d["roll_rad"]), pitch_rad=float(d["pitch_rad"]),
                yaw_rad=float(d["yaw_rad"]), lat_rad=float(d["lat_rad"]),
                lon_rad=float(d["lon_rad"]), alt_m=float(d["alt_m"]), vel_n=_t3(d["vel_n"]),
                att_sd_rad=_t3(d["att_sd_rad"]), gyro_bias_rps=_t3(d["gyro_bias_rps"]),
                accel_bias_mps2=_t3(d["accel_bias_mps2"]),
                heading_aligned=bool(d["heading_aligned"]), rate_b=_t3(d["rate_b"]),
                pos_sd_m=_t3(d.get("pos_sd_m", _NAN3)), vel_sd_mps=_t3(d.get("vel_sd_mps", _NAN3)),
                # files written before these were recorded: the NavSolution defaults
                gnss_age_us=int(d.get("gnss_age_us", -1)),
                heading_resets=int(d.get("heading_resets", 0)),
                heading_initialised=bool(d.get("heading_initialised",
                                               d["heading_aligned"])),
                yaw_sd_installation_rad=float(d.get("yaw_sd_installation_rad", 0.0))))
    return out
