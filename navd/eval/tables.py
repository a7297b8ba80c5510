"""Reading the files ``navd replay`` writes (solution, aiding, reference CSVs) for the report."""

from __future__ import annotations

import csv
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from navd.units import RAD2DEG as R2D

F64 = npt.NDArray[np.float64]
_BIG_BYTES = 5_000_000


class ReportError(ValueError):
    """An input cannot be used (missing file, missing column)."""


# ---------------------------------------------------------------------------------------------
# reading


def _rows(path: Path, progress: bool) -> Iterator[list[str]]:
    size = path.stat().st_size
    bar = None
    if progress and size > _BIG_BYTES:
        from tqdm import tqdm

        bar = tqdm(total=size, unit="B", unit_scale=True, desc=path.name, file=sys.stderr,
                   mininterval=0.5, disable=None)
    with open(path, newline="") as fh:
        for line in fh:
            if bar is not None:
                bar.update(len(line))
            yield next(csv.reader([line]))
    if bar is not None:
        bar.close()


def read_table(path: str | Path, needed: tuple[str, ...], text: tuple[str, ...] = (),
               progress: bool = False) -> dict[str, Any]:
    """Read a CSV with a header into column arrays (float64; ``text`` columns as str lists).

    Rows with a wrong field count or a non-number are skipped (counted in ``_skipped``).
    """
    p = Path(path)
    if not p.is_file():
        raise ReportError(f"no such file: {p}")
    it = _rows(p, progress)
    try:
        head = [h.strip() for h in next(it)]
    except StopIteration as exc:
        raise ReportError(f"{p}: empty file") from exc
    idx = {h: i for i, h in enumerate(head)}
    missing = [c for c in needed if c not in idx]
    if missing:
        raise ReportError(f"{p}: missing column(s) {', '.join(missing)}")
    num_cols = [c for c in head if c not in text]
    vals: dict[str, list[float]] = {c: [] for c in num_cols}
    txt: dict[str, list[str]] = {c: [] for c in text if c in idx}
    skipped = 0
    for row in it:
        if len(row) != len(head):
            if row:
                skipped += 1
            continue
        try:
            parsed = [float(row[idx[c]]) for c in num_cols]
        except ValueError:
            skipped += 1
            continue
        for c, v in zip(num_cols, parsed, strict=True):
            vals[c].append(v)
        for c in txt:
            txt[c].append(row[idx[c]])
    out: dict[str, Any] = {c: np.asarray(v, dtype=np.float64) for c, v in vals.items()}
    out.update(txt)
    out["_skipped"] = skipped
    out["_path"] = str(p)
    return out


@dataclass
class RefSeries:
    t_us: F64
    euler_deg: F64  # (K, 3)
    source: str


def load_reference(path: str | Path, progress: bool = False) -> RefSeries:
    """A reference CSV (t_us,roll_deg,pitch_deg,yaw_deg) or any log navd can read."""
    p = Path(path)
    if p.is_file():
        with open(p, "rb") as fh:
            head = fh.read(64)
        if head.startswith(b"t_us,"):
            t = read_table(p, ("t_us", "roll_deg", "pitch_deg", "yaw_deg"), progress=progress)
            e = np.stack([t["roll_deg"], t["pitch_deg"], t["yaw_deg"]], 1)
            return RefSeries(t["t_us"], e, str(p))
    from navd.io.logs import LogFormatError, read_log

    try:
        data = read_log(p)
    except LogFormatError as exc:
        raise ReportError(f"reference {p}: {exc}") from exc
    r = data.reference
    if len(r) == 0:
        raise ReportError(f"reference {p}: the log has no onboard attitude")
    e = np.stack([r.roll_rad, r.pitch_rad, r.yaw_rad], 1) * R2D
    return RefSeries(r.t_us.astype(np.float64), e, f"{p} ({r.source})")


