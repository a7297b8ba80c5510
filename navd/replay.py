"""``navd replay``: run the estimator over recorded data, exactly as the daemon would.

Output rows are written at every GNSS epoch that the estimator consumed and at a fixed rate
(default 50 Hz) in between, so plots have both the update instants and a regular grid.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterable
from pathlib import Path

from navd.config import ConfigError, EstimatorConfig, load_config
from navd.core.estimator import Estimator
from navd.io.replay import ReadReport, ReplayFormatError, SolutionWriter, merge, read_gnss, read_imu
from navd.types import GnssSample, ImuSample


def run_replay(est: Estimator, samples: Iterable[ImuSample | GnssSample], writer: SolutionWriter,
               rate_hz: float = 50.0, progress_total: int | None = None,
               progress: bool = False) -> int:
    """Push every sample; write solutions; return the number of rows written."""
    period_us = int(1e6 / rate_hz) if rate_hz > 0 else 0
    next_out = -1
    rows = 0
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=progress_total, unit="samples", mininterval=0.5, file=sys.stderr)
    for s in samples:
        advanced = est.push(s)
        if bar is not None:
            bar.update(1)
        if not est.initialized or not advanced:
            continue
        if isinstance(s, GnssSample):
            writer.write(est.solution())
            rows += 1
            continue
        if period_us and s.t_us >= next_out:
            writer.write(est.solution())
            rows += 1
            next_out = (s.t_us // period_us + 1) * period_us
    if bar is not None:
        bar.close()
    return rows


def _count_lines(path: Path) -> int:
    with open(path, "rb") as fh:
        return max(0, sum(1 for _ in fh) - 1)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="navd replay", description=__doc__)
    ap.add_argument("--config", help="TOML config (default: built-in defaults)")
    ap.add_argument("--imu", required=True, help="IMU CSV (rates or increments)")
    ap.add_argument("--gnss", required=True, help="GNSS CSV")
    ap.add_argument("--out", required=True, help="solution CSV to write")
    ap.add_argument("--rate", type=float, default=50.0, help="output rate between epochs, Hz")
    ap.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                    help="override a config value (repeatable)")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    a = ap.parse_args(argv)
    try:
        cfg = EstimatorConfig.from_dict(load_config(a.config, a.set))
    except ConfigError as exc:
        print(f"navd replay: config error: {exc}", file=sys.stderr)
        return 2
    est = Estimator(cfg)
    rep = ReadReport()
    imu_path, gnss_path = Path(a.imu), Path(a.gnss)
    for p in (imu_path, gnss_path):
        if not p.is_file():
            print(f"navd replay: no such file: {p}", file=sys.stderr)
            return 2
    total = None if a.quiet else _count_lines(imu_path) + _count_lines(gnss_path)
    out = Path(a.out)
    tmp = out.with_suffix(out.suffix + ".part")
    try:
        with open(tmp, "w") as fh:
            rows = run_replay(est, merge(read_imu(imu_path, rep), read_gnss(gnss_path, rep)),
                              SolutionWriter(fh), a.rate, total, progress=not a.quiet)
    except ReplayFormatError as exc:
        tmp.unlink(missing_ok=True)
        print(f"navd replay: {exc}", file=sys.stderr)
        return 2
    tmp.replace(out)
    for issue in rep.issues[:20]:
        print(f"navd replay: skipped {issue}", file=sys.stderr)
    if len(rep.issues) > 20:
        print(f"navd replay: ... {len(rep.issues) - 20} more skipped rows", file=sys.stderr)
    counters = dict(est.counters)
    print(f"navd replay: {rows} solution rows -> {out}; skipped rows: {len(rep.issues)}; "
          f"estimator: {counters}", file=sys.stderr)
    return 0
