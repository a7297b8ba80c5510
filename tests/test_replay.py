"""``navd replay`` over CSV files: same answer as pushing the samples, bad rows skipped by line."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest

from firmware_sim import generate, load_scenario
from firmware_sim.score import initial_heading_config
from navd.cli.replay import main as replay_main
from navd.config import load_config
from navd.io.csv_replay import SOLUTION_COLS, ReadReport, read_gnss, read_imu, read_pol
from navd.pipeline import build_estimator, solutions
from navd.types import NavSolution


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[str]]:
    run = generate(load_scenario("car480", {"duration_s": 60.0}), seed=7, progress=False)
    d = tmp_path_factory.mktemp("car60")
    run.write_csv(d)
    return d, [f"--set={o}" for o in initial_heading_config(run, 0.0)]


def _solution(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def _assert_rows_match(rows: list[dict[str, str]], sols: list[NavSolution]) -> None:
    assert len(rows) == len(sols) > 0
    for r, s in zip(rows, sols, strict=True):
        assert int(r["t_us"]) == s.t_us
        # the CSV keeps 6 decimals of a degree
        assert float(r["yaw_deg"]) == pytest.approx(math.degrees(s.yaw_rad), abs=6e-7)
        assert float(r["roll_deg"]) == pytest.approx(math.degrees(s.roll_rad), abs=6e-7)


def test_csv_replay_matches_direct_push(run_dir: tuple[Path, list[str]], tmp_path: Path) -> None:
    """GIVEN a simulated 60 s car480 drive written as imu.csv and gnss.csv,
    WHEN ``navd replay`` reads them and writes sol.csv,
    THEN the file has the solution columns and, row for row, the solutions of pushing the
    simulator's samples directly: 50 Hz from navigation start (2900-3000 rows), with the heading
    within 1 deg of the truth over the second half."""
    d, sets = run_dir
    out = tmp_path / "sol.csv"
    assert replay_main(["--imu", str(d / "imu.csv"), "--gnss", str(d / "gnss.csv"),
                        "--out", str(out), "--quiet", *sets]) == 0
    rows = _solution(out)
    assert tuple(rows[0].keys()) == SOLUTION_COLS
    # the CSV round trip is exact, so pushing the simulator's samples through the same
    # factory and output rule gives the same rows, sample for sample
    run = generate(load_scenario("car480", {"duration_s": 60.0}), seed=7, progress=False)
    e = build_estimator(load_config(None, [s.removeprefix("--set=") for s in sets]))
    _assert_rows_match(rows, list(solutions(e, run.samples(), 50.0)))
    # the solution tracks the truth
    with open(d / "truth.csv", newline="") as fh:
        truth = {int(r["t_us"]): r for r in csv.DictReader(fh)}
    errs = [abs((float(r["yaw_deg"]) - float(truth[int(r["t_us"])]["yaw_deg"]) + 180) % 360
                - 180) for r in rows[len(rows) // 2:]]
    assert max(errs) < 1.0
    # 50 Hz from navigation start (after ~1 s of levelling)
    assert 2900 < len(rows) <= 3000


def test_no_progress_bar_when_stderr_is_not_a_terminal(run_dir: tuple[Path, list[str]],
                                                      tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    """GIVEN the 60 s drive, WHEN ``navd replay`` runs without --quiet and its stderr is not a
    terminal (pytest captures it: a pipe, as under systemd or in a log file),
    THEN no progress bar is written (no carriage returns, no "samples" counter), only the
    summary lines."""
    d, sets = run_dir
    out = tmp_path / "sol.csv"
    assert replay_main(["--imu", str(d / "imu.csv"), "--gnss", str(d / "gnss.csv"),
                        "--out", str(out), *sets]) == 0
    err = capsys.readouterr().err
    assert "\r" not in err
    assert "samples/s" not in err and "samples]" not in err
    assert "solution rows" in err


def test_missing_column_is_a_clear_error(run_dir: tuple[Path, list[str]], tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    """GIVEN a gnss.csv without its vel_e column,
    WHEN it is replayed,
    THEN replay exits 2, says "missing column(s) vel_e" and writes no solution file."""
    d, _ = run_dir
    lines = (d / "gnss.csv").read_text().splitlines()
    cols = lines[0].split(",")
    drop = cols.index("vel_e")
    bad = tmp_path / "gnss.csv"
    bad.write_text("\n".join(",".join(c for i, c in enumerate(ln.split(",")) if i != drop)
                             for ln in lines) + "\n")
    out = tmp_path / "sol.csv"
    rc = replay_main(["--imu", str(d / "imu.csv"), "--gnss", str(bad), "--out", str(out),
                      "--quiet"])
    assert rc == 2
    assert "missing column(s) vel_e" in capsys.readouterr().err
    assert not out.exists()


def test_bad_rows_are_skipped_with_line_numbers(run_dir: tuple[Path, list[str]],
                                                tmp_path: Path) -> None:
    """GIVEN an imu.csv with a NaN (file line 100), a duplicate (201), a row back in time (301)
    and a row of too few fields (401),
    WHEN it is read and replayed,
    THEN each bad row is reported with its file line and reason and skipped, every other row is
    read, and the replay succeeds with finite attitudes throughout."""
    d, sets = run_dir
    lines = (d / "imu.csv").read_text().splitlines()
    # line numbers are 1-based file lines; line 1 is the header
    lines[99] = lines[99].replace(lines[99].split(",")[3], "nan", 1)  # file line 100: NaN
    lines.insert(200, lines[199])  # file line 201: duplicate of line 200
    lines.insert(300, lines[150])  # file line 301: goes back in time
    lines[400] = "1,2,3"  # file line 401: too few fields
    bad = tmp_path / "imu.csv"
    bad.write_text("\n".join(lines) + "\n")
    rep = ReadReport()
    n = sum(1 for _ in read_imu(bad, rep))
    found = {(i.line, i.reason.split()[0]) for i in rep.issues}
    assert (100, "column") in found
    assert (201, "duplicate") in found
    assert (301, "non-monotonic") in found
    assert (401, "3") in found
    assert n == len(lines) - 1 - 4
    # the replay still runs on the rest and the state never becomes NaN
    out = tmp_path / "sol.csv"
    assert replay_main(["--imu", str(bad), "--gnss", str(d / "gnss.csv"), "--out", str(out),
                        "--quiet", *sets]) == 0
    vals = np.array([[float(r[k]) for k in ("roll_deg", "pitch_deg", "yaw_deg")]
                     for r in _solution(out)])
    assert np.all(np.isfinite(vals))


def test_gnss_reader_reads_optional_ecef(run_dir: tuple[Path, list[str]]) -> None:
    """GIVEN a simulated gnss.csv, which has the optional ECEF position and velocity columns,
    WHEN its first fix is read,
    THEN the fix carries an ECEF position and a finite ECEF velocity."""
    d, _ = run_dir
    g = next(iter(read_gnss(d / "gnss.csv")))
    assert g.vel_ecef_mps is not None and g.pos_ecef_m is not None
    assert math.isfinite(g.vel_ecef_mps[0])


def test_polarization_csv_replays_like_the_direct_push(tmp_path: Path) -> None:
    """GIVEN a simulated 120 s pol_static run pitched 30 deg, written by firmware-sim with pol.csv,
    and a heading configured 5 deg off (sigma 10 deg),
    WHEN ``navd replay --pol`` feeds it through the same push(),
    THEN pol.csv reads back exactly, the rows equal those of the direct push, > 1000 readings are
    accepted and the final heading error is < 0.5 deg."""
    run = generate(load_scenario("pol_static", {"duration_s": 120.0,
                                                "trajectory.pitch_deg": 30.0}), seed=4,
                   progress=False)
    run.write_csv(tmp_path)
    readings = list(read_pol(tmp_path / "pol.csv"))
    assert readings == list(run.pol_samples())  # %.17g: the round trip is exact
    yaw0 = math.degrees(float(run.truth_euler[0, 2])) + 5.0
    sets = ["init.heading_source=config", f"init.heading_deg={yaw0}", "init.heading_sd_deg=10",
            "polarization.enabled=true", "polarization.mount_roll_deg=0",
            "polarization.mount_pitch_deg=0", "polarization.mount_yaw_deg=0"]
    out = tmp_path / "sol.csv"
    assert replay_main(["--imu", str(tmp_path / "imu.csv"), "--gnss", str(tmp_path / "gnss.csv"),
                        "--pol", str(tmp_path / "pol.csv"), "--out", str(out), "--quiet",
                        *[f"--set={s}" for s in sets]]) == 0
    rows = _solution(out)
    e = build_estimator(load_config(None, sets))
    sols = list(solutions(e, run.samples(), 50.0))
    _assert_rows_match(rows, sols)
    assert e.counters["pol_accepted"] > 1000
    sol = sols[-1]
    # and POL is what fixed the heading: 5 deg off at the start, well under 0.5 deg at the end
    k = len(run.truth_t_us) - 1
    err = (math.degrees(sol.yaw_rad - run.truth_euler[k, 2]) + 180.0) % 360.0 - 180.0
    assert abs(err) < 0.5


def test_polarization_csv_bad_rows_are_skipped(tmp_path: Path) -> None:
    """GIVEN a pol.csv with a row back in time, a non-numeric AoP and a NaN AoP,
    WHEN it is read,
    THEN the first two rows are skipped and reported, and the NaN row is passed on (it is the
    estimator's to refuse and count)."""
    p = tmp_path / "pol.csv"
    p.write_text("t_us,aop_rad,dop,utc_unix_s\n100,1.0,0.5,1.6e9\n50,1.0,0.5,1.6e9\n"
                 "200,x,0.5,1.6e9\n300,nan,0.5,1.6e9\n")
    rep = ReadReport()
    got = list(read_pol(p, rep))
    assert [s.t_us for s in got] == [100, 300]  # NaN is the estimator's to refuse (counted)
    assert len(rep.issues) == 2
