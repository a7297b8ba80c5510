"""The evaluation page (HTML, PNG figures, statistics) for one replay: ``navd report``.

The work is split by job: :mod:`navd.eval.tables` reads the CSVs, :mod:`navd.eval.evaluate`
aligns and scores, :mod:`navd.eval.figures` plots, this module writes the page and summary.

Inputs are the files ``navd replay`` writes: the solution CSV (``SOLUTION_COLS``), optionally
a reference attitude (``--reference-out`` CSV, or any log ``navd.io.logs`` reads: its onboard
estimate is taken) and the per-epoch aiding side file (``--aiding-out``).

Reference alignment: the reference attitude is interpolated to each solution time by
normalised linear quaternion interpolation (no Euler-angle wrap or gimbal trouble); rows
outside the reference's span or inside a reference gap longer than ``--max-ref-gap-s`` get no
error.  Euler errors are solution minus reference, wrapped to (-180, 180] deg; the "angle"
error is the rotation angle of C_sol C_ref^T (all three axes together).

Figures (matplotlib, Agg backend, no display needed): attitude vs reference; attitude error
with the filter's +-3 sigma; heading with the epochs where the course update was used (green)
or rejected (red); GNSS innovations; bias estimates; the track on a local north/east map.
Statistics: RMS, max and the 50/90/99th percentiles of |error| overall, and RMS/max per
segment (``--segment-s``, 30 s by default); they are also written to ``summary.json``.
Heading (yaw and the total angle) is scored only where the solution's ``heading_aligned``
is 1: an unaligned heading is a placeholder with a wide sigma, not a claim.  Time axes
count from the log's start when its stamps are wall-clock time (PX4 SITL ULogs stamp Unix
time, which matplotlib would show as an offset like "+1.7107733e9"); otherwise they are
the log's boot clock.
"""

from __future__ import annotations

import html
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from navd.eval.evaluate import (
    AXES,
    Evaluation,
    course_check,
    evaluate,
    gyro_consistency,
    time_origin_us,
)
from navd.eval.figures import make_figures
from navd.eval.tables import RefSeries, ReportError, load_reference, read_table

F64 = npt.NDArray[np.float64]


# ---------------------------------------------------------------------------------------------
# page


def _fmt(x: float, nd: int = 2) -> str:
    return "–" if not math.isfinite(x) else f"{x:.{nd}f}"


def render_html(ev: Evaluation, figs: list[tuple[str, str]], title: str,
                inputs: dict[str, str], aid: dict[str, Any] | None, notes: list[str],
                checks: dict[str, dict[str, Any]] | None = None) -> str:
    e = html.escape
    parts = [
        "<!DOCTYPE html>",
        f"<html><head><meta charset='utf-8'><title>{e(title)}</title>",
        "<style>body{font-family:sans-serif;max-width:1150px;margin:auto;padding:1em}"
        "table{border-collapse:collapse;margin:0.5em 0}td,th{border:1px solid #bbb;"
        "padding:2px 8px;text-align:right}th{background:#eee}img{max-width:100%}"
        "figure{margin:1em 0}figcaption{color:#444}</style></head><body>",
        f"<h1>{e(title)}</h1>",
        "<h2>Inputs</h2><table>",
    ]
    for k, v in inputs.items():
        parts.append(f"<tr><th>{e(k)}</th><td style='text-align:left'>{e(v)}</td></tr>")
    parts.append("</table>")
    if ev.stats:
        parts.append("<h2>Agreement with the reference (|navd − reference|, deg)</h2>")
        parts.append("<table><tr><th>axis</th><th>RMS</th><th>p50</th><th>p90</th>"
                     "<th>p99</th><th>max</th><th>rows</th></tr>")
        for a, st in ev.stats.items():
            parts.append(f"<tr><th>{e(a)}</th><td>{_fmt(st['rms'])}</td>"
                         f"<td>{_fmt(st['p50'])}</td><td>{_fmt(st['p90'])}</td>"
                         f"<td>{_fmt(st['p99'])}</td><td>{_fmt(st['max'])}</td>"
                         f"<td>{int(st['n'])}</td></tr>")
        parts.append("</table>")
        parts.append(f"<p>{e(_heading_note(ev))}.</p>")
    if ev.segments:
        parts.append("<h2>Per segment (RMS / max, deg)</h2><table><tr><th>from [s]</th>"
                     "<th>to [s]</th>" + "".join(f"<th>{a}</th>" for a in (*AXES, "angle"))
                     + "<th>course used</th><th>course rejected</th></tr>")
        for sg in ev.segments:
            cells = "".join(f"<td>{_fmt(sg.rms[a])} / {_fmt(sg.max[a])}</td>"
                            for a in (*AXES, "angle"))
            parts.append(f"<tr><td>{sg.t0_s:.1f}</td><td>{sg.t1_s:.1f}</td>{cells}"
                         f"<td>{sg.course_used}</td><td>{sg.course_rejected}</td></tr>")
        parts.append("</table>")
    if aid is not None and len(aid["t_us"]):
        last = {k: int(aid[k][-1]) for k in ("pos_accepted", "pos_rejected", "vel_accepted",
                                             "vel_rejected", "course_accepted",
                                             "course_rejected")}
        status = aid["course_status"][-1] if aid.get("course_status") else ""
        parts.append("<h2>Aiding</h2><table>")
        for name, count in last.items():
            parts.append(f"<tr><th>{e(name)}</th><td>{count}</td></tr>")
        parts.append(f"<tr><th>course update at the end</th><td style='text-align:left'>"
                     f"{e(status)}</td></tr>")
        for name, val in yaw_bank_summary(aid).items():
            parts.append(f"<tr><th>{e(name)}</th><td style='text-align:left'>{e(val)}</td></tr>")
        parts.append("</table>")
    if checks:
        parts.append(
            "<h2>Consistency checks</h2><p>gyro: RMS per body axis (x, y, z) of the rotation "
            "by which the attitude series departs from the integrated gyros over 1 s windows; "
            "yaw − course: at GNSS epochs faster than 8 m/s, median, interquartile range, and "
            "the amplitude of its once-per-revolution component (crab in a steady wind, or a "
            "heading-sensor error) with the RMS left after removing it.</p>"
            "<table><tr><th>series</th><th>gyro x / y / z [deg per window]</th>"
            "<th>yaw − course median [deg]</th><th>IQR [deg]</th><th>1/rev amplitude [deg]"
            "</th><th>residual RMS [deg]</th></tr>")
        for name, c in checks.items():
            g = c.get("gyro", {})
            gy = (" / ".join(_fmt(x) for x in g["rms_deg"]) if g.get("windows") else "–")
            co = c.get("course", {})
            if co.get("n"):
                cells = (f"<td>{_fmt(co['median_deg'], 1)}</td><td>{_fmt(co['p25_deg'], 1)} … "
                         f"{_fmt(co['p75_deg'], 1)}</td><td>{_fmt(co['amp_deg'], 1)}</td>"
                         f"<td>{_fmt(co['fit_resid_rms_deg'], 1)}</td>")
            else:
                cells = "<td>–</td>" * 4
            parts.append(f"<tr><th>{e(name)}</th><td>{gy}</td>{cells}</tr>")
        parts.append("</table>")
    if notes:
        parts.append("<h2>Notes</h2><ul>" + "".join(f"<li>{e(n)}</li>" for n in notes)
                     + "</ul>")
    parts.append("<h2>Figures</h2>")
    for name, cap in figs:
        parts.append(f"<figure><img src='{e(name)}' alt='{e(cap)}'>"
                     f"<figcaption>{e(cap)}</figcaption></figure>")
    parts.append("</body></html>")
    return "\n".join(parts) + "\n"


def _checks(ev: Evaluation, sol: dict[str, Any], ref: RefSeries | None,
            aid: dict[str, Any] | None, log_data: Any, stats_from_s: float | None
            ) -> dict[str, dict[str, Any]]:
    """Consistency of navd and of the reference with the gyros and with the GNSS course."""
    if not len(ev.t_s):
        return {}
    # ``stats_from_s`` here is on the log's own clock, as the sensor time stamps are
    t_from = float(sol["t_us"][0]) * 1e-6 if stats_from_s is None else stats_from_s
    series = {"navd": RefSeries(sol["t_us"], ev.sol_deg, "navd")}
    if ref is not None:
        series["reference"] = ref
    out: dict[str, dict[str, Any]] = {}
    for name, ser in series.items():
        c: dict[str, Any] = {}
        if log_data is not None and len(log_data.imu_t_us):
            c["gyro"] = gyro_consistency(log_data.imu_t_us, log_data.imu_inc, ser, t_from)
        if aid is not None and len(aid["t_us"]):
            c["course"] = course_check(aid, ser, t_from)
        if c:
            out[name] = c
    return out


def yaw_bank_summary(aid: dict[str, Any]) -> dict[str, str]:
    """The heading bank's story from the aiding file (issue 15), for the page and
    summary.json: its state at the end, when it first aligned the heading, its trials,
    realignments and suspicions, and its last yaw, sigma and largest weight.  Empty when the
    file has no bank columns or the bank was off."""
    states = aid.get("yaw_bank_state")
    if not states or all(x == "off" for x in states):
        return {}
    t = np.asarray(aid["t_us"], dtype=np.float64) * 1e-6
    aligned = [i for i, x in enumerate(states) if x == "aligned"]
    out = {"yaw bank state at the end": states[-1],
           "yaw bank first aligned at": (f"{t[aligned[0]] - t[0]:.1f} s after the first row"
                                         if aligned else "never")}
    for col, name in (("yaw_bank_trials", "yaw bank trials"),
                      ("yaw_bank_realigned", "yaw bank realignments (heading resets)"),
                      ("yaw_bank_suspect", "yaw bank suspicions (aligned cleared)")):
        if col in aid and len(aid[col]):
            out[name] = str(int(aid[col][-1]))
    if "yaw_bank_yaw_deg" in aid and len(aid["yaw_bank_yaw_deg"]):
        out["yaw bank yaw / sigma / largest weight at the end"] = (
            f"{_fmt(float(aid['yaw_bank_yaw_deg'][-1]))} deg / "
            f"{_fmt(float(aid['yaw_bank_sd_deg'][-1]))} deg / "
            f"{_fmt(float(aid['yaw_bank_weight_max'][-1]), 3)}")
    return out


def _heading_note(ev: Evaluation) -> str:
    """What the yaw and angle rows score, said on the page."""
    hs = ev.heading_scored
    if hs is None:
        return ("the solution has no heading_aligned column: heading is scored on every row, "
                "aligned or not")
    n, k = len(hs), int(np.count_nonzero(hs))
    if k == 0:
        return (f"navd's heading was never aligned (heading_aligned = 0 on all {n} rows): yaw "
                "and angle are not scored")
    return (f"heading (yaw and angle) is scored only where navd's heading is aligned "
            f"(heading_aligned = 1): {k} of {n} rows; roll and pitch on every row")


SOL_NEEDED = ("t_us", "roll_deg", "pitch_deg", "yaw_deg", "lat_deg", "lon_deg",
              "roll_sd_deg", "pitch_sd_deg", "yaw_sd_deg")


def build_report(solution: str | Path, out: str | Path, reference: str | Path | None = None,
                 aiding: str | Path | None = None, segment_s: float = 30.0,
                 stats_from_s: float | None = None, max_ref_gap_s: float = 1.0,
                 title: str | None = None, progress: bool = False,
                 log: str | Path | None = None) -> dict[str, Any]:
    """Write ``index.html``, the PNGs and ``summary.json`` into ``out``; return the summary.

    ``log``: the flight log the solution was replayed from; its IMU feeds the gyro
    consistency check (and its onboard attitude is the reference if none is given).
    """
    out_dir = Path(out)
    out_dir.mkdir(parents=True, exist_ok=True)
    sol = read_table(solution, SOL_NEEDED, progress=progress)
    notes: list[str] = []
    if sol["_skipped"]:
        notes.append(f"{sol['_skipped']} unreadable solution rows skipped")
    if not len(sol["t_us"]):
        notes.append("the solution is empty: the filter never started")
    log_data = None
    if log is not None:
        from navd.io.logs import LogFormatError, read_log

        try:
            log_data = read_log(log)
        except LogFormatError as exc:
            raise ReportError(f"log {log}: {exc}") from exc
    ref_src = reference if reference is not None else log
    ref = load_reference(ref_src, progress) if ref_src is not None else None
    aid = None
    if aiding is not None:
        aid = read_table(aiding, ("t_us", "course", "speed_mps", "course_deg"),
                         text=("course_status", "course", "yaw_bank_state"), progress=progress)
    t0_us = time_origin_us(sol["t_us"], *([ref.t_us] if ref is not None else []),
                           *([aid["t_us"]] if aid is not None else []))
    ev = evaluate(sol, ref, aid, segment_s, stats_from_s, max_ref_gap_s, t0_us)
    if t0_us:
        notes.append(f"times are seconds from the log's start; the log's clock reads "
                     f"{t0_us * 1e-6:.0f} s there (a wall-clock time stamp)")
    notes.append(_heading_note(ev))
    if ev.err_deg is not None and not np.any(np.isfinite(ev.err_deg)):
        notes.append("the reference does not overlap the solution in time")
    if stats_from_s is not None:
        notes.append(f"statistics and segments from t = {stats_from_s:g} s on")
    checks = _checks(ev, sol, ref, aid, log_data,
                     None if stats_from_s is None else stats_from_s + t0_us * 1e-6)
    figs = make_figures(ev, sol, aid, out_dir, progress)
    inputs = {"solution": str(solution)}
    if ref is not None:
        inputs["reference"] = ref.source
    if aiding is not None:
        inputs["aiding"] = str(aiding)
    if len(ev.t_s):
        inputs["span"] = f"{ev.t_s[0]:.2f} … {ev.t_s[-1]:.2f} s, {len(ev.t_s)} rows"
        if t0_us:
            inputs["span"] += " (from the log's start)"
    if log is not None:
        inputs["log"] = str(log)
    page = render_html(ev, figs, title or f"navd report: {Path(solution).name}", inputs, aid,
                       notes, checks)
    (out_dir / "index.html").write_text(page)
    summary: dict[str, Any] = {
        "inputs": inputs,
        "stats_deg": ev.stats,
        "segments": [{"t0_s": sg.t0_s, "t1_s": sg.t1_s, "n": sg.n, "rms_deg": sg.rms,
                      "max_deg": sg.max, "course_used": sg.course_used,
                      "course_rejected": sg.course_rejected} for sg in ev.segments],
        "figures": [f for f, _ in figs],
        "checks": checks,
        "notes": notes,
    }
    if aid is not None:
        bank = yaw_bank_summary(aid)
        if bank:
            summary["yaw_bank"] = bank
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=1, allow_nan=True) + "\n")
    return summary
