"""Flight-log readers: each format decodes to the right samples, and replaying a log gives
exactly the solution of replaying the equivalent CSV (same samples -> same NavSolution)."""

from __future__ import annotations

import csv
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from fixtures.logwriters import (
    Source,
    source_from_sim,
    write_dataflash,
    write_rate_csv,
    write_tlog,
    write_ulog,
    write_x8,
)

from navd.cli.replay import main as replay_main
from navd.io.logs import LogFormatError, LogOptions, detect_format, read_log
from navd.io.recording import RecordingWriter

Writer = Callable[[Path, Source], object]

# name -> (file name, detected format, writer, IMU stored as rates?)
CASES: dict[str, tuple[str, str, Writer, bool]] = {
    "ulog": ("run.ulg", "ulog", write_ulog, False),
    "ulog_sensor_gps_rates": (
        "run.ulg", "ulog", lambda p, s: write_ulog(p, s, "sensor_gps", integrals=False), True),
    "dataflash": ("run.bin", "dataflash", write_dataflash, True),
    "tlog": ("run.tlog", "tlog", write_tlog, True),
    "x8_dir": ("x8", "x8", lambda p, s: write_x8(p, s), True),
    "x8_zip": ("x8.zip", "x8", lambda p, s: write_x8(p, s, as_zip=True), True),
}


@pytest.fixture(scope="module")
def src() -> Source:
    return source_from_sim(20.0)


def _write(case: str, src: Source, d: Path) -> Path:
    name, _, writer, _ = CASES[case]
    p = d / name
    writer(p, src)
    return p


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.mark.parametrize("case", list(CASES))
def test_detect_and_decode(case: str, src: Source, tmp_path: Path) -> None:
    """GIVEN a 20 s simulated flight written as ULog (integrals or rates), DataFlash, tlog,
    or an X8 directory or zip,
    WHEN the format is detected and the log read,
    THEN the format is named, nothing is damaged, IMU increments are the stored rates x 10 ms
    (rate formats drop the first sample), fixes match to unit precision (X8: the documented
    default accuracies), and the reference attitude matches to 1e-4 rad."""
    path = _write(case, src, tmp_path)
    fmt, rates = CASES[case][1], CASES[case][3]
    assert detect_format(path) == fmt
    data = read_log(path)
    assert data.fmt == fmt and data.damage is None
    # IMU: increments = stored rate x interval (rate formats drop the first sample)
    first = 1 if rates else 0
    n = len(src.imu_t_us) - first
    assert len(data.imu_t_us) == n
    assert np.array_equal(data.imu_t_us, src.imu_t_us[first:])
    assert np.all(data.imu_dt_us == 10_000)
    want = np.hstack([src.gyro, src.accel])[first:] * 0.01
    np.testing.assert_allclose(data.imu_inc, want, rtol=1e-12, atol=1e-15)
    # GNSS: units and frames (1e-7 deg ~ 1 cm, cm altitude, float32 speed and course)
    assert len(data.gnss_t_us) == len(src.gnss)
    g = np.array([[x.lat_rad, x.lon_rad, x.alt_m, x.vel_n, x.vel_e, x.vel_d]
                  for x in src.gnss])
    assert np.array_equal(data.gnss_t_us, [x.t_us for x in src.gnss])
    np.testing.assert_allclose(data.gnss[:, :2], g[:, :2], atol=2e-9)  # rad, ~1 cm
    np.testing.assert_allclose(data.gnss[:, 2], g[:, 2], atol=6e-3)
    np.testing.assert_allclose(data.gnss[:, 3:6], g[:, 3:6], atol=2e-5)
    if fmt == "x8":  # no accuracies in the X8 log: the documented assumptions
        assert np.all(data.gnss[:, 6:9] == [2.5, 5.0, 0.3])
    else:
        want_acc = [[x.h_acc_m, x.v_acc_m, x.vel_acc_mps] for x in src.gnss]
        np.testing.assert_allclose(data.gnss[:, 6:9], want_acc, atol=6e-3)
    # reference attitude
    r = data.reference
    assert len(r) == len(src.ref_t_us) and np.array_equal(r.t_us, src.ref_t_us)
    e = np.stack([r.roll_rad, r.pitch_rad, r.yaw_rad], 1) - src.ref_euler
    e = (e + math.pi) % (2 * math.pi) - math.pi
    assert np.abs(e).max() < 1e-4  # DataFlash stores centidegrees


@pytest.mark.parametrize("case", list(CASES))
def test_log_replay_equals_csv_replay(case: str, src: Source, tmp_path: Path) -> None:
    """GIVEN each log format and its equivalent CSV (same IMU rates or increments, same fixes),
    WHEN both are replayed with the heading taken from the GNSS course,
    THEN the two solution files are identical, and over the second half the yaw stays
    within 1 deg of the simulated truth written as the reference."""
    path = _write(case, src, tmp_path)
    data = read_log(path)
    # the equivalent CSV: the stored rates in rate form (the CSV reader integrates them
    # the same way), or the decoded increments; the decoded fixes
    csv_dir = tmp_path / "csv"
    data.write_replay_csv(csv_dir)
    if CASES[case][3]:
        write_rate_csv(src, csv_dir / "imu.csv")
    sets = ["--set=init.heading_source=gnss_course", "--quiet"]
    out_log, out_csv = tmp_path / "log.csv", tmp_path / "csv.csv"
    ref, aid = tmp_path / "ref.csv", tmp_path / "aid.csv"
    assert replay_main(["--log", str(path), "--out", str(out_log), "--reference-out", str(ref),
                        "--aiding-out", str(aid), *sets]) == 0
    assert replay_main(["--imu", str(csv_dir / "imu.csv"), "--gnss", str(csv_dir / "gnss.csv"),
                        "--out", str(out_csv), *sets]) == 0
    a, b = out_log.read_text(), out_csv.read_text()
    assert a.count("\n") > 500
    assert a == b
    # and the solution follows the simulated truth written as the reference
    rows = _rows(out_log)
    refs = {int(r["t_us"]): r for r in _rows(ref)}
    errs = [abs((float(r["yaw_deg"]) - float(refs[int(r["t_us"])]["yaw_deg"]) + 180) % 360 - 180)
            for r in rows[len(rows) // 2:] if int(r["t_us"]) in refs]
    assert len(errs) > 50 and max(errs) < 1.0
    assert len(_rows(aid)) > 150


def test_format_option_and_unknown_files(src: Source, tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    """GIVEN a DataFlash log and a file that is not a flight log,
    WHEN they are read and replayed with and without --format,
    THEN --format dataflash reads it, the junk file is an "unknown log format" (exit 2),
    a wrong --format is refused with the reader's message (exit 2), and --log with --imu
    is a usage error."""
    p = _write("dataflash", src, tmp_path)
    assert read_log(p, "dataflash").fmt == "dataflash"
    junk = tmp_path / "junk.dat"
    junk.write_bytes(b"hello, this is not a flight log\n" * 10)
    with pytest.raises(LogFormatError, match="unknown log format"):
        detect_format(junk)
    out = tmp_path / "sol.csv"
    assert replay_main(["--log", str(junk), "--out", str(out), "--quiet"]) == 2
    assert "unknown log format" in capsys.readouterr().err
    # a wrong --format is refused with the reader's message, not a traceback
    assert replay_main(["--log", str(p), "--format", "ulog", "--out", str(out), "--quiet"]) == 2
    assert "--format ulog, but the content is a dataflash log" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        replay_main(["--log", str(p), "--imu", "x.csv", "--out", str(out)])


def test_tlog_gps_raw_int_on_unix_clock(src: Source, tmp_path: Path) -> None:
    """GIVEN a tlog whose GPS_RAW_INT is stamped with Unix time, as ArduPilot does,
    WHEN it is read and replayed,
    THEN a note says the fixes were on another clock and they are moved onto the IMU clock,
    vel_d is NaN, vel_n matches to 2 cm/s, and the replay writes a solution."""
    p = tmp_path / "ap.tlog"
    write_tlog(p, src, "GPS_RAW_INT", gnss_unix_time=True)
    data = read_log(p)
    assert any("another clock" in n for n in data.notes)
    assert np.array_equal(data.gnss_t_us, [x.t_us for x in src.gnss])
    assert np.all(np.isnan(data.gnss[:, 5]))
    vn = np.array([x.vel_n for x in src.gnss])
    np.testing.assert_allclose(data.gnss[:, 3], vn, atol=0.02)  # cm/s and centidegrees
    out = tmp_path / "sol.csv"
    assert replay_main(["--log", str(p), "--out", str(out), "--quiet"]) == 0
    assert len(_rows(out)) > 500


def test_ulog_gnss_delay_option_moves_fixes_earlier(src: Source, tmp_path: Path) -> None:
    """GIVEN a ULog of the simulated flight,
    WHEN it is read with a GNSS delay option of 0.05 s,
    THEN the first fix is stamped 50 ms earlier than it was logged."""
    p = _write("ulog", src, tmp_path)
    data = read_log(p, options=LogOptions(gnss_delay_s=0.05))
    assert data.gnss_t_us[0] == src.gnss[0].t_us - 50_000


def test_log_replay_agrees_with_recording_replay(src: Source, tmp_path: Path) -> None:
    """GIVEN the samples of a flight log, recorded as the daemon records its pushes,
    WHEN the log and the recording are replayed at the same output rate,
    THEN both write the same rows, sample for sample (one factory, one output rule)."""
    p = _write("dataflash", src, tmp_path)
    data = read_log(p)
    rec = tmp_path / "run.navdrec"
    w = RecordingWriter(rec, {}, 50.0)
    for s in data.samples():
        w.write(s)
    w.close()
    a, b = tmp_path / "log.csv", tmp_path / "rec.csv"
    assert replay_main(["--log", str(p), "--out", str(a), "--quiet"]) == 0
    assert replay_main(["--recording", str(rec), "--out", str(b), "--quiet"]) == 0
    rows_a, rows_b = _rows(a), _rows(b)
    assert len(rows_a) > 200
    assert rows_a == rows_b
