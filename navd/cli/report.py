"""``navd report``: an HTML evaluation page (PNG figures, statistics) for one replay.

What the page shows and how errors are computed: :mod:`navd.eval.report`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from navd.eval.report import build_report
from navd.eval.tables import ReportError

_DESCRIPTION = """\
Write an HTML evaluation page (index.html, PNG figures, summary.json) for one replay.

Inputs are what `navd replay` writes: the solution CSV (--out), and optionally the
onboard attitude of the log (--reference-out, or give the log itself as --reference)
and the per-epoch aiding file (--aiding-out).

Errors are solution minus reference, wrapped to +-180 deg; "angle" is the whole
rotation between the two.  The reference is interpolated to each solution time;
rows outside it or in a reference gap longer than --max-ref-gap-s get no error.
Statistics: RMS, max and the 50/90/99th percentiles of |error|, overall and per
segment (--segment-s).  Heading (yaw and angle) is scored only on rows where navd's
heading is aligned (heading_aligned = 1); roll and pitch on every row.  Times are
seconds of the log's clock, or from the log's start where the log stamps wall-clock
time (PX4 SITL); --stats-from-s uses the same axis.

example:
  navd replay --log flight.ulg --out sol.csv --reference-out ref.csv --aiding-out aid.csv
  navd report --solution sol.csv --reference ref.csv --aiding aid.csv --out report/
"""


def main(argv: list[str] | None = None) -> int:
    # navd.eval.report's docstring is for the code's readers (RST, module names); --help says
    # what a user gives and gets
    ap = argparse.ArgumentParser(
        prog="navd report", formatter_class=argparse.RawDescriptionHelpFormatter,
        description=_DESCRIPTION)
    ap.add_argument("--solution", required=True, help="solution CSV from navd replay")
    ap.add_argument("--reference", help="reference attitude: CSV from --reference-out, or a "
                                        "log (its onboard estimate); default: the --log's "
                                        "onboard attitude, else none")
    ap.add_argument("--aiding", help="aiding CSV from navd replay --aiding-out")
    ap.add_argument("--log", help="the flight log replayed: its IMU for the gyro consistency "
                                  "check (and its onboard attitude if no --reference)")
    ap.add_argument("--out", required=True, help="output directory (index.html, *.png)")
    ap.add_argument("--segment-s", type=float, default=30.0,
                    help="segment length for the per-segment table, s (0: none; default "
                         "%(default)s)")
    ap.add_argument("--stats-from-s", type=float, default=None,
                    help="statistics and segments only from this log time on, s (e.g. after "
                         "take-off; default: from the first row); figures show everything")
    ap.add_argument("--max-ref-gap-s", type=float, default=1.0,
                    help="no error where the reference has a longer gap, s (default "
                         "%(default)s)")
    ap.add_argument("--title", help="page title (default: navd report: <solution file name>)")
    ap.add_argument("--quiet", action="store_true", help="no progress bars")
    a = ap.parse_args(argv)
    try:
        summary = build_report(a.solution, a.out, a.reference, a.aiding, a.segment_s,
                               a.stats_from_s, a.max_ref_gap_s, a.title, progress=not a.quiet,
                               log=a.log)
    except (ReportError, OSError) as exc:
        print(f"navd report: {exc}", file=sys.stderr)
        return 2
    print(f"navd report: {Path(a.out) / 'index.html'} ({len(summary['figures'])} figures)",
          file=sys.stderr)
    for axis, st in summary["stats_deg"].items():
        print(f"  {axis:6s} RMS {st['rms']:7.2f}  p50 {st['p50']:7.2f}  p90 {st['p90']:7.2f}  "
              f"p99 {st['p99']:7.2f}  max {st['max']:7.2f} deg", file=sys.stderr)
    return 0
