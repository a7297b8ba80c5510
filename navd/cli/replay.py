"""``navd replay``: run the estimator over recorded data, exactly as the daemon would.

Output rows follow the daemon's output rule (:mod:`navd.pipeline`): a solution at the first
IMU sample at or past each multiple of the output period (default 50 Hz) on the sensor clock.
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import math
import sys
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from navd.config import ConfigError, apply_overrides, load_config
from navd.config.daemon import RUN_ONLY_SECTIONS, DaemonConfig
from navd.config.estimator import DEFAULT_IMU_GRADE, IMU_GRADES
from navd.core.aiding.course_learner import CE, CN
from navd.core.estimator import Estimator
from navd.io.csv_replay import (
    ReadReport,
    ReplayFormatError,
    SolutionWriter,
    merge,
    read_gnss,
    read_imu,
    read_pol,
)
from navd.io.foxglove_mcap import NavMcapWriter
from navd.pipeline import build_estimator, solutions
from navd.types import NavSolution, Sample

if TYPE_CHECKING:
    from navd.config import NavConfig
    from navd.io.logs import AidingWriter, LogData


class RowWriter(Protocol):
    """Anything that takes solution rows (SolutionWriter, the MCAP tee)."""

    def write(self, s: NavSolution) -> None: ...


def run_replay(est: Estimator, samples: Iterable[Sample], writer: RowWriter,
               rate_hz: float = 50.0, progress_total: int | None = None,
               progress: bool = False, aiding: AidingWriter | None = None) -> int:
    """Push every sample; write the solutions a sink at ``rate_hz`` would get; return the
    number of rows written (:func:`navd.pipeline.solutions`: the daemon's output rule).

    ``aiding``: also write one row per GNSS epoch on what the filter did with it.
    """
    rows = 0
    bar = None
    if progress:
        from tqdm import tqdm

        # disable=None: no bar when stderr is not a terminal (logs, pipes, systemd)
        bar = tqdm(total=progress_total, unit="samples", mininterval=0.5, file=sys.stderr,
                   disable=None)
        samples = _counted(samples, bar)
    for sol in solutions(est, samples, rate_hz, aiding):
        writer.write(sol)
        rows += 1
    if bar is not None:
        bar.close()
    return rows


def _counted(samples: Iterable[Sample], bar: Any) -> Iterator[Sample]:
    for s in samples:
        bar.update(1)
        yield s


def _count_lines(path: Path) -> int:
    with open(path, "rb") as fh:
        return max(0, sum(1 for _ in fh) - 1)


def main(argv: list[str] | None = None) -> int:
    # argparse cannot mark "one of these groups" as required in the usage line, so the
    # description says it, and the check below names all three choices
    ap = argparse.ArgumentParser(
        prog="navd replay",
        description="Run the estimator over recorded data exactly as the daemon would, and "
                    "write its solution CSV. Input: one of --imu and --gnss (replay CSVs, "
                    "docs/replay-format.md), --recording (a `navd run --record` file) or "
                    "--log (a flight log) is required. Rows follow the daemon's output rule: "
                    "a solution at the first IMU sample at or past each multiple of the "
                    "output period on the sensor clock.")
    ap.add_argument("--config", help="TOML config (default: built-in defaults)")
    ap.add_argument("--imu", help="IMU CSV (rates or increments); needs --gnss")
    ap.add_argument("--gnss", help="GNSS CSV; needs --imu")
    ap.add_argument("--pol", help="polarization CSV (t_us, aop_rad, dop, utc_unix_s), with "
                                  "--imu/--gnss; needs [polarization] in the config")
    ap.add_argument("--recording", metavar="FILE",
                    help="a `navd run --record` file instead of --imu/--gnss: replays the "
                         "daemon's pushes with its config, output at its output instants")
    ap.add_argument("--out", required=True,
                    help="solution CSV to write (with --recording, *.jsonl writes every "
                         "NavSolution field exactly)")
    ap.add_argument("--rate", type=float, default=None,
                    help="output rate between epochs, Hz (default 50; with --recording the "
                         "daemon's)")
    ap.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                    help="override a config value (repeatable)")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    ap.add_argument("--max-skipped", type=float, default=1.0, metavar="PERCENT",
                    help="CSV input: exit 1 when more than this share of the rows is skipped "
                         "(bad rows, time stamps out of order), after writing the output "
                         "(default %(default)s %%)")
    ap.add_argument("--mcap", metavar="FILE",
                    help="also write the output rows to FILE as MCAP for Foxglove (pose, "
                         "location, heading status; log time = sensor time)")
    _add_log_arguments(ap)
    a = ap.parse_args(argv)
    missing = _missing_output_dir(a)
    if missing:
        print(f"navd replay: {missing}", file=sys.stderr)
        return 2
    if a.log is not None:
        if a.imu or a.gnss or a.recording:
            ap.error("--log replaces --imu/--gnss/--recording")
        return _replay_log(a)
    if a.recording is not None:
        if a.imu or a.gnss:
            ap.error("--recording replaces --imu/--gnss")
        return _replay_recording(a)
    if not (a.imu and a.gnss):
        ap.error("an input is required: --imu and --gnss (both), --recording, or --log")
    if a.rate is None:
        a.rate = 50.0
    try:
        est = _build(a)
    except ConfigError as exc:
        print(f"navd replay: config error: {exc}", file=sys.stderr)
        return 2
    rep = ReadReport()
    imu_path, gnss_path = Path(a.imu), Path(a.gnss)
    pol_path = Path(a.pol) if a.pol else None
    for p in (imu_path, gnss_path, *([pol_path] if pol_path else [])):
        if not p.is_file():
            print(f"navd replay: no such file: {p}", file=sys.stderr)
            return 2
    total = None if a.quiet else (_count_lines(imu_path) + _count_lines(gnss_path)
                                  + (_count_lines(pol_path) if pol_path else 0))
    out = Path(a.out)
    tmp = out.with_suffix(out.suffix + ".part")
    try:
        with open(tmp, "w") as fh, _aiding(a.aiding_out) as aid, _mcap(a, est) as mc:
            pol = read_pol(pol_path, rep) if pol_path is not None else ()
            rows = run_replay(est, merge(read_imu(imu_path, rep), read_gnss(gnss_path, rep),
                                         pol),
                              _Tee(SolutionWriter(fh), mc), a.rate, total,
                              progress=not a.quiet, aiding=aid)
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
    _mount_hint(est)
    rc = _exit_code(rows, est)
    return rc or _skipped_code(rep, a.max_skipped)


def _skipped_code(rep: ReadReport, max_percent: float) -> int:
    """1 (saying why) when more than ``max_percent`` of the input rows were skipped: a
    replay of what is left would look like a success while describing another run."""
    total = rep.rows + len(rep.issues)
    if not total or len(rep.issues) * 100.0 <= max_percent * total:
        return 0
    print(f"navd replay: error: {len(rep.issues)} of {total} input rows skipped "
          f"({len(rep.issues) * 100.0 / total:.2f} % > --max-skipped {max_percent:g} %); "
          f"first: {rep.issues[0]}", file=sys.stderr)
    return 1


def _replay_recording(a: argparse.Namespace) -> int:
    """Replay a daemon recording: same config (unless --config/--set), same output rule."""
    from navd.io.recording import RecordingError, RecordingReader, SolutionJsonlWriter

    try:
        rec = RecordingReader(a.recording)
    except (OSError, RecordingError) as exc:
        print(f"navd replay: {exc}", file=sys.stderr)
        return 2
    try:
        if a.config:
            tables = load_config(a.config, a.set)
        else:  # the daemon's own configuration, --set applied on top
            tables = apply_overrides(copy.deepcopy(rec.config), a.set)
        est = build_estimator(_checked(tables, a.set, from_file=bool(a.config)))
    except ConfigError as exc:
        print(f"navd replay: config error: {exc}", file=sys.stderr)
        return 2
    except (TypeError, ValueError, AttributeError, KeyError) as exc:
        # a damaged header can hold JSON of any shape where the config should be
        print(f"navd replay: {a.recording}: the recorded configuration is unusable "
              f"({type(exc).__name__}: {exc}); give one with --config", file=sys.stderr)
        return 2
    rate = a.rate if a.rate is not None else rec.output_rate_hz
    out = Path(a.out)
    tmp = out.with_suffix(out.suffix + ".part")
    rows = 0
    try:
        with open(tmp, "w") as fh, _mcap(a, est) as mc:
            writer = _Tee(SolutionJsonlWriter(fh) if out.suffix == ".jsonl"
                          else SolutionWriter(fh), mc)
            for sol in solutions(est, rec.samples(), rate):
                writer.write(sol)
                rows += 1
    except RecordingError as exc:  # a damaged record: no half-written output is left
        tmp.unlink(missing_ok=True)
        print(f"navd replay: {exc} (after {rows} solution rows; nothing written)",
              file=sys.stderr)
        return 2
    tmp.replace(out)
    if rec.truncated_bytes:
        print(f"navd replay: recording ends in a partial record ({rec.truncated_bytes} bytes "
              "ignored)", file=sys.stderr)
    print(f"navd replay: {rows} solution rows at {rate:g} Hz -> {out}; "
          f"estimator: {dict(est.counters)}", file=sys.stderr)
    return _exit_code(rows, est)


class _Tee:
    """The solution file's writer, plus the MCAP file when ``--mcap`` is given, plus
    ``extra`` (another row sink) when given."""

    def __init__(self, writer: RowWriter, mcap: NavMcapWriter | None,
                 extra: RowWriter | None = None) -> None:
        self._writer = writer
        self._mcap = mcap
        self._extra = extra

    def write(self, sol: NavSolution) -> None:
        self._writer.write(sol)
        if self._mcap is not None:
            self._mcap.write_solution(sol, max(sol.t_us, 0) * 1000)
        if self._extra is not None:
            self._extra.write(sol)


@contextlib.contextmanager
def _mcap(a: argparse.Namespace, est: Estimator) -> Iterator[NavMcapWriter | None]:
    """``--mcap``: written as FILE.part and renamed when the replay ends; an error removes
    it (no half-written file is left behind)."""
    if not a.mcap:
        yield None
        return
    with NavMcapWriter(a.mcap, aligned_sd_rad=est.cfg.init.aligned_sd, atomic=True) as mc:
        yield mc


def _missing_output_dir(a: argparse.Namespace) -> str:
    """Why an output file cannot be created ('' if all can): checked before the replay, which
    may take minutes, rather than a traceback at its end."""
    for opt in ("out", "reference_out", "aiding_out", "mcap"):
        path = getattr(a, opt, None)
        if path is None:
            continue
        parent = Path(path).parent
        if not parent.is_dir():
            flag = "--" + opt.replace("_", "-")
            return (f"{flag} {path}: directory {parent} does not exist "
                    f"(create it first: mkdir -p {parent})")
    return ""


def _exit_code(rows: int, est: Estimator) -> int:
    """0 when the replay produced a solution; else 1, saying why (an empty solution file is
    never a success: a script would go on to score nothing)."""
    if rows > 0:
        return 0
    c = est.counters
    if c.get("imu", 0) == 0:
        why = "no IMU sample reached the estimator (none in the input, or all refused)"
    elif c.get("gnss", 0) == 0:
        why = ("no GNSS fix reached the estimator, and navigation starts at the first fix "
               "(none in the input, or all refused)")
    else:
        why = (f"the estimator never started navigating: {c.get('imu', 0)} IMU samples, "
               f"{c.get('gnss', 0)} GNSS fixes; see the estimator counters above for what "
               "it refused")
    print(f"navd replay: error: no solution rows: {why}", file=sys.stderr)
    return 1


def _checked(tables: dict[str, Any], overrides: list[str], *, from_file: bool) -> NavConfig:
    """Validate the whole configuration as ``navd run`` would (unknown sections and keys are
    errors; ConfigError), and say which given settings a replay does not use."""
    cfg = DaemonConfig.from_dict(tables, need_input=False)
    for ov in overrides:
        key = ov.split("=", 1)[0].strip()
        if key.split(".", 1)[0] in RUN_ONLY_SECTIONS:
            print(f"navd replay: note: --set {key} has no effect on a replay: "
                  f"[{key.split('.', 1)[0]}] configures `navd run` (its inputs, outputs and "
                  "service); a replay takes samples and their time stamps from its files",
                  file=sys.stderr)
    if from_file:
        unused = sorted(s for s in tables if s in RUN_ONLY_SECTIONS)
        if unused:
            print("navd replay: note: config sections " + ", ".join(f"[{s}]" for s in unused)
                  + " configure `navd run` only; a replay checks but does not use them",
                  file=sys.stderr)
    return cfg.nav


# -- flight logs (navd.io.logs): --log FILE [--format ...] ------------------------------------


def _add_log_arguments(ap: argparse.ArgumentParser) -> None:
    from navd.io.logs import FORMATS, LogOptions

    d = LogOptions()
    g = ap.add_argument_group("flight logs (instead of --imu/--gnss)")
    g.add_argument("--log", metavar="FILE",
                   help="PX4 ULog, ArduPilot DataFlash .bin, MAVLink .tlog, InertialNav text "
                        "log (dir or zip: the X8 plane layout and the InertialNav quad layouts, "
                        "f450_glitch with ATT.txt yaw first, quad123 with GPS.txt and no "
                        "GPSraw.txt) or a "
                        "replay-CSV folder.  filter.profile follows the vehicle type the log "
                        "states (Copter -> multirotor, Plane -> fixed_wing, Rover -> ground) "
                        "unless --set or --config sets it; at the end the roll/pitch RMS "
                        "against the log's own attitude in flight is printed")
    g.add_argument("--format", choices=FORMATS, default=None,
                   help="log format (default: detected from the content)")
    g.add_argument("--reference-out", metavar="CSV",
                   help="write the log's onboard attitude (t_us,roll_deg,pitch_deg,yaw_deg)")
    g.add_argument("--aiding-out", metavar="CSV",
                   help="write one row per GNSS epoch: course update used/rejected, "
                        "innovations, bias estimates (for navd report; also with --imu/--gnss)")
    g.add_argument("--gnss-h-acc-m", type=float, default=d.h_acc_m,
                   help="horizontal 1-sigma where the log has none, m (default %(default)s)")
    g.add_argument("--gnss-v-acc-m", type=float, default=d.v_acc_m,
                   help="vertical 1-sigma where the log has none, m (default %(default)s)")
    g.add_argument("--gnss-vel-acc-mps", type=float, default=d.vel_acc_mps,
                   help="velocity 1-sigma where the log has none, m/s (default %(default)s)")
    g.add_argument("--geoid-sep-m", type=float, default=d.geoid_sep_m,
                   help="geoid undulation added to MSL-only altitudes, m (default %(default)s)")
    g.add_argument("--gnss-delay-ms", type=float, default=None,
                   help="receiver latency: fixes are taken as valid this long before their "
                        "log time stamp, ms (default: the latency the log states, an "
                        "ArduPilot log's EKF_VEL_DELAY/EKF_POS_DELAY/GPS_DELAY_MS, else 0)")


def _aiding(path: str | None) -> contextlib.AbstractContextManager[AidingWriter | None]:
    if path is None:
        return contextlib.nullcontext()

    @contextlib.contextmanager
    def cm() -> Iterator[AidingWriter]:
        from navd.io.logs import AidingWriter

        with open(path, "w") as fh:
            yield AidingWriter(fh)

    return cm()


def _build(a: argparse.Namespace) -> Estimator:
    """The estimator exactly as the daemon builds it (:func:`navd.pipeline.build_estimator`),
    from a configuration validated as a whole."""
    return build_estimator(_checked(load_config(a.config, a.set), a.set,
                                    from_file=bool(a.config)))


def _replay_log(a: argparse.Namespace) -> int:
    """Read a flight log into samples and replay them through :func:`run_replay`; the filter
    profile is the log's vehicle type unless the user set one; the tilt against the log's
    own attitude in flight is printed at the end."""
    from navd.io.logs import LogFormatError, LogOptions, read_log, write_reference
    from navd.io.logs.infer import infer_vehicle

    try:
        tables = load_config(a.config, a.set)
        nav = _checked(tables, a.set, from_file=bool(a.config))
    except ConfigError as exc:
        print(f"navd replay: config error: {exc}", file=sys.stderr)
        return 2
    opts = LogOptions(h_acc_m=a.gnss_h_acc_m, v_acc_m=a.gnss_v_acc_m,
                      vel_acc_mps=a.gnss_vel_acc_mps, geoid_sep_m=a.geoid_sep_m,
                      gnss_delay_s=(None if a.gnss_delay_ms is None
                                    else a.gnss_delay_ms * 1e-3))
    try:
        data = read_log(a.log, a.format, opts)
    except (LogFormatError, ReplayFormatError) as exc:
        print(f"navd replay: {exc}", file=sys.stderr)
        return 2
    print(f"navd replay: {data.summary()}", file=sys.stderr)
    for note in data.notes:
        print(f"navd replay: note: {note}", file=sys.stderr)
    if data.damage is not None:
        print(f"navd replay: WARNING: {data.damage}", file=sys.stderr)
    tables, said = log_lever_arm(tables, data.lever_arm_m)
    if said:
        if data.lever_arm_m is not None:
            nav = DaemonConfig.from_dict(tables, need_input=False).nav
        print(f"navd replay: {said}", file=sys.stderr)
    chosen, said = log_accel_calibration(tables, data.accel_calibrated)
    if chosen is not tables:
        tables = chosen
        nav = DaemonConfig.from_dict(tables, need_input=False).nav
    if said:
        print(f"navd replay: {said}", file=sys.stderr)
    vehicle, vehicle_from = data.vehicle, data.vehicle_from
    if not vehicle and not vehicle_from:
        vehicle, vehicle_from = infer_vehicle(data.gnss_t_us, data.gnss)
    nav, said = log_profile(tables, nav, vehicle, vehicle_from)
    print(f"navd replay: {said}", file=sys.stderr)
    est = build_estimator(nav)
    if a.reference_out:
        with open(a.reference_out, "w") as fh:
            n = write_reference(data.reference, fh)
        src = data.reference.source or "none in the log"
        print(f"navd replay: {n} reference attitudes ({src}) -> {a.reference_out}",
              file=sys.stderr)
    out = Path(a.out)
    tmp = out.with_suffix(out.suffix + ".part")
    tilt = _TiltRows()
    with open(tmp, "w") as fh, _aiding(a.aiding_out) as aid, _mcap(a, est) as mc:
        rows = run_replay(est, data.samples(), _Tee(SolutionWriter(fh), mc, tilt),
                          50.0 if a.rate is None else a.rate, data.n_samples,
                          progress=not a.quiet, aiding=aid)
    tmp.replace(out)
    print(f"navd replay: {rows} solution rows -> {out}; course update: {est.course_status}; "
          f"estimator: {dict(est.counters)}", file=sys.stderr)
    _mount_hint(est)
    if rows and len(data.reference) >= 2:
        print(f"navd replay: {tilt.agreement_line(data)}", file=sys.stderr)
    elif rows:
        print("navd replay: no roll/pitch RMS: the log carries no onboard attitude to compare "
              "with", file=sys.stderr)
    return _exit_code(rows, est)


def _mount_hint(est: Estimator) -> None:
    """Say so when the velocity said the IMU is pitched on the (ground) vehicle
    (core/aiding/mount_check.py), or the IMU's accelerations that it is turned on it
    (core/aiding/gnss_heading.py: its yaw 60-120 deg from the course); and
    when the course of a "ground" vehicle carried a current (core/aiding/course_learner.py:
    a boat, or a plane, run as a car)."""
    w = est.gnss.course.watch
    if est.counters.get("course_not_heading") and w is not None:
        print(f"navd replay: the course is not the heading here: it turns with the heading "
              f"as a current of ~{math.hypot(w.x[CN], w.x[CE]):.1f} m/s would make it (a boat "
              "in a current? --set filter.profile=boat; a plane in wind: fixed_wing); as a "
              "ground vehicle the heading and its sigma follow the course", file=sys.stderr)
    turned = est.status().get("imu_yaw_on_vehicle_deg")
    if est.counters.get("course_not_heading_imu") and isinstance(turned, (int, float)):
        print(f"navd replay: the IMU's accelerations put its heading {turned:.0f} deg from "
              f"the GNSS course: the IMU is turned on the vehicle? (--set "
              f"imu.mount_yaw_deg={turned:.0f}, or the mounting's measured angle; until it "
              "is set navd learns that angle each run and the attitude is that of the "
              "IMU's axes)", file=sys.stderr)
    pitch = est.status().get("imu_pitch_on_vehicle_deg")
    if est.counters.get("imu_pitch_mount_suspect") and isinstance(pitch, list):
        print(f"navd replay: driving straight, the velocity rose {pitch[0]:.2f} +- "
              f"{pitch[1]:.2f} deg above the IMU's x axis: the IMU is pitched on the vehicle? "
              f"(--set imu.mount_pitch_deg={pitch[0]:.1f}; roll and pitch are the IMU's "
              "until then)", file=sys.stderr)


LOG_LEVER_ARM_SD_M = 0.05  # 1-sigma of an antenna position an autopilot's parameters state
# 1-sigma (mg) of what an autopilot's accelerometer calibration leaves: the sensor's zero-g
# drift with temperature since (MPU-6000: +-35 mg over 0-70 C, ~+-10 mg for 20 C away from
# the calibration's) and the six-position fit's own error (a few mg).  The consumer grade's
# 30 mg is for uncalibrated parts (+-50 mg zero-g tolerance); applied only where neither
# imu.accel_bias_sd_mg nor imu.grade was set
LOG_ACCEL_BIAS_SD_MG = 10.0


def log_lever_arm(tables: dict[str, Any], lever: tuple[float, float, float] | None
                  ) -> tuple[dict[str, Any], str]:
    """The config tables with ``[gnss] lever_arm_m`` taken from the log where it states the
    antenna's position (LogData.lever_arm_m) and the user set none (``--set`` or
    ``--config`` always stands), and the line that says what the replay uses ("" when the
    user set it and the log states nothing)."""
    gnss = tables.get("gnss")
    if lever is None:
        if isinstance(gnss, dict) and "lever_arm_m" in gnss:
            return tables, ""
        return tables, ("gnss.lever_arm_m: the log states no antenna position; 0 with a "
                        "lever_arm_sd_m allowance (--set gnss.lever_arm_m=[x,y,z] if known)")
    if isinstance(gnss, dict) and "lever_arm_m" in gnss:
        return tables, (f"gnss.lever_arm_m as set; note: the log states ({lever[0]:.3f}, "
                        f"{lever[1]:.3f}, {lever[2]:.3f}) m")
    chosen = copy.deepcopy(tables)
    g = chosen.setdefault("gnss", {})
    if not isinstance(g, dict):
        return tables, ""
    g["lever_arm_m"] = [float(v) for v in lever]
    said = f"gnss.lever_arm_m = [{lever[0]:.3f}, {lever[1]:.3f}, {lever[2]:.3f}] from the log"
    if "lever_arm_sd_m" not in g:
        # the autopilot's own setting: someone measured it, to a few centimetres
        g["lever_arm_sd_m"] = LOG_LEVER_ARM_SD_M
        said += f", gnss.lever_arm_sd_m = {LOG_LEVER_ARM_SD_M:g}"
    return chosen, said


def log_accel_calibration(tables: dict[str, Any], calibrated: str
                          ) -> tuple[dict[str, Any], str]:
    """The config tables with ``[imu] accel_bias_sd_mg`` at LOG_ACCEL_BIAS_SD_MG where the
    log states that the autopilot calibrated the accelerometer (LogData.accel_calibrated)
    and the user set neither it nor ``imu.grade`` (``--set`` or ``--config`` always
    stands), and the line that says so ("" when the log states no calibration)."""
    if not calibrated:
        return tables, ""
    imu = tables.get("imu")
    if isinstance(imu, dict) and ("accel_bias_sd_mg" in imu or "grade" in imu):
        return tables, (f"imu: accelerometer bias prior as set; note: the log states a "
                        f"calibration ({calibrated})")
    grade = IMU_GRADES[DEFAULT_IMU_GRADE]["accel_bias_sd_mg"]
    chosen = copy.deepcopy(tables)
    t = chosen.setdefault("imu", {})
    if not isinstance(t, dict):
        return tables, ""
    t["accel_bias_sd_mg"] = LOG_ACCEL_BIAS_SD_MG
    return chosen, (f"imu.accel_bias_sd_mg = {LOG_ACCEL_BIAS_SD_MG:g}: the log states an "
                    f"accelerometer calibration (the {DEFAULT_IMU_GRADE} grade's {grade:g} mg "
                    "is for uncalibrated parts); --set imu.accel_bias_sd_mg=... overrides")


def log_profile(tables: dict[str, Any], nav: NavConfig, vehicle: str, vehicle_from: str
                ) -> tuple[NavConfig, str]:
    """The configuration a log replays with, and the one line that says which profile and
    why.  ``filter.profile`` set by the user (``--set`` or ``--config``) always stands; else
    the profile of the vehicle type the log states (``vehicle``, from ``vehicle_from``),
    else the configured default."""
    filt = tables.get("filter")
    explicit = isinstance(filt, dict) and "profile" in filt
    have = nav.estimator.filter.profile
    if explicit:
        if vehicle and vehicle != have:
            return nav, (f"profile {have} as set (filter.profile); note: the log's vehicle "
                         f"type says {vehicle} ({vehicle_from})")
        return nav, f"profile {have} as set (filter.profile)"
    if vehicle:
        if vehicle != have:
            chosen = copy.deepcopy(tables)
            chosen.setdefault("filter", {})["profile"] = vehicle
            nav = DaemonConfig.from_dict(chosen, need_input=False).nav
        if vehicle_from.startswith("inferred"):
            return nav, (f"profile {vehicle} ({vehicle_from}; the log states no vehicle "
                         "type); --set filter.profile=... to override")
        return nav, (f"profile {vehicle} from the log's vehicle type ({vehicle_from}); "
                     "--set filter.profile=... to override")
    if vehicle_from:
        return nav, (f"profile {have} (the default): no navd profile fits the log's vehicle "
                     f"type ({vehicle_from}); --set filter.profile=... to choose one")
    return nav, (f"profile {have} (the default): the log does not state its vehicle type; "
                 "--set filter.profile=multirotor (or fixed_wing) if it flies")


class _TiltRows:
    """Keeps each solution row's time, roll and pitch for the closing agreement line."""

    def __init__(self) -> None:
        self.t_us: list[int] = []
        self.roll: list[float] = []
        self.pitch: list[float] = []

    def write(self, sol: NavSolution) -> None:
        self.t_us.append(sol.t_us)
        self.roll.append(sol.roll_rad)
        self.pitch.append(sol.pitch_rad)

    def agreement_line(self, data: LogData) -> str:
        """Roll/pitch RMS of navd minus the log's reference in flight, and what "in flight"
        was (:mod:`navd.eval.flight`, the benchmarks' rule)."""
        import numpy as np

        from navd.eval.flight import FLIGHT_RULE, flight_window, tilt_agreement

        ref = data.reference
        t0 = int(min(data.imu_t_us[0], ref.t_us[0]))
        win = flight_window(data.imu_t_us, data.imu_inc, t0)
        ag = tilt_agreement(np.asarray(self.t_us, dtype=np.int64), np.asarray(self.roll),
                            np.asarray(self.pitch), ref.t_us, ref.roll_rad, ref.pitch_rad, win)
        src = ref.source or "the reference"
        if ag.whole:
            span = f"over the whole solution (no take-off found; {FLIGHT_RULE})"
        else:
            end = f"{win.to_s:.1f} s (a crash)" if np.isfinite(win.to_s) else "the end"
            span = (f"in flight, {win.from_s:.1f} s to {end} from the log's start "
                    f"({FLIGHT_RULE})")
        if ag.n == 0:
            return (f"no roll/pitch RMS vs {src}: no solution row {span} has a {src} sample "
                    "within 0.1 s")
        return (f"roll/pitch RMS navd - {src} {span}: {ag.roll_rms_deg:.2f} / "
                f"{ag.pitch_rms_deg:.2f} deg over {ag.n} rows ({src} is the log's own "
                "estimate, not truth)")
