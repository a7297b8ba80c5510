"""``navd replay`` refuses what would silently produce nothing (issue 16 item 4): empty output
is an error that says why, and the configuration is validated as a whole (unknown sections
and keys are errors; settings a replay does not use are named)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fixtures.logwriters import Source, source_from_sim, write_rate_csv, write_tlog, write_ulog

from navd.cli.replay import main as replay_main
from navd.io.csv_replay import GNSS_COLS


@pytest.fixture(scope="module")
def src() -> Source:
    return source_from_sim(8.0)


def _no_imu(src: Source) -> Source:
    empty = np.zeros(0, dtype=np.int64)
    return dataclasses.replace(src, imu_t_us=empty, dt_us=empty, gyro=np.zeros((0, 3)),
                               accel=np.zeros((0, 3)))


def _nan_imu(src: Source) -> Source:
    """IMU records present, every one of them unusable."""
    return dataclasses.replace(src, gyro=np.full_like(src.gyro, np.nan))


def _csvs(src: Source, d: Path) -> tuple[Path, Path]:
    imu, gnss = d / "imu.csv", d / "gnss.csv"
    write_rate_csv(src, imu)
    gnss.write_text(",".join(GNSS_COLS) + "\n")  # a header, no fix
    return imu, gnss


def test_ulog_without_gps_is_an_error_that_says_why(src: Source, tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    """GIVEN a ULog with IMU data but no GNSS fix,
    WHEN it is replayed,
    THEN replay fails and says "no GNSS fix"."""
    log = tmp_path / "nogps.ulg"
    write_ulog(log, dataclasses.replace(src, gnss=[]))
    rc = replay_main(["--log", str(log), "--out", str(tmp_path / "s.csv"), "--quiet"])
    err = capsys.readouterr().err
    assert rc != 0, err
    assert "no GNSS fix" in err, err


@pytest.mark.parametrize("imu", [_no_imu, _nan_imu])
def test_tlog_without_imu_is_an_error_that_says_why(src: Source, tmp_path: Path, imu: Any,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    """GIVEN a tlog with no IMU records, or with IMU records whose gyro readings are all NaN,
    WHEN it is replayed,
    THEN replay fails and its last error line names the IMU."""
    log = tmp_path / "noimu.tlog"
    write_tlog(log, imu(src))
    rc = replay_main(["--log", str(log), "--out", str(tmp_path / "s.csv"), "--quiet"])
    err = capsys.readouterr().err
    assert rc != 0, err
    assert "IMU" in err.splitlines()[-1], err


def test_csv_replay_with_zero_rows_is_an_error(src: Source, tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    """GIVEN an imu.csv and a gnss.csv with a header but no fix,
    WHEN they are replayed,
    THEN replay exits 1 with "error: no solution rows" and says "no GNSS fix"."""
    imu, gnss = _csvs(src, tmp_path)
    rc = replay_main(["--imu", str(imu), "--gnss", str(gnss), "--out", str(tmp_path / "s.csv"),
                      "--quiet"])
    err = capsys.readouterr().err
    assert rc == 1 and "error: no solution rows" in err and "no GNSS fix" in err, err


@pytest.mark.parametrize("override", ["mavlink.bogus=1", "bogus.key=1", "daemon.queue_size=-3",
                                      "filter.bogus=1"])
def test_unknown_or_bad_settings_are_errors(src: Source, tmp_path: Path, override: str,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    """GIVEN a good tlog and a --set of an unknown key, an unknown section or a bad value
    (daemon.queue_size=-3),
    WHEN it is replayed,
    THEN replay exits 2 with a config error."""
    log = tmp_path / "run.tlog"
    write_tlog(log, src)
    rc = replay_main(["--log", str(log), "--out", str(tmp_path / "s.csv"), "--quiet",
                      "--set", override])
    err = capsys.readouterr().err
    assert rc == 2 and "config error" in err, err


def test_settings_a_replay_does_not_use_are_named(src: Source, tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    """GIVEN a good tlog,
    WHEN it is replayed with --set mavlink.use_receive_time=true, then with the shipped config,
    THEN both succeed; the first says the setting has no effect on a replay, the second names
    [mavlink] as a section a replay checks but does not use."""
    log = tmp_path / "run.tlog"
    write_tlog(log, src)
    rc = replay_main(["--log", str(log), "--out", str(tmp_path / "s.csv"), "--quiet",
                      "--set", "mavlink.use_receive_time=true"])
    err = capsys.readouterr().err
    assert rc == 0, err
    assert "--set mavlink.use_receive_time has no effect on a replay" in err, err
    root = Path(__file__).resolve().parents[1]
    rc = replay_main(["--log", str(log), "--out", str(tmp_path / "s.csv"), "--quiet",
                      "--config", str(root / "config" / "navd.toml")])
    err = capsys.readouterr().err
    assert rc == 0 and "[mavlink]" in err and "a replay checks but does not use" in err, err


@pytest.mark.parametrize("flag", ["--out", "--reference-out", "--aiding-out"])
def test_missing_output_directory_is_a_clear_error(src: Source, tmp_path: Path, flag: str,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    """GIVEN --out, --reference-out or --aiding-out in a directory that does not exist,
    WHEN a tlog is replayed,
    THEN replay exits 2, naming the flag, saying the directory does not exist and suggesting
    mkdir -p, without a traceback."""
    log = tmp_path / "run.tlog"
    write_tlog(log, src)
    outs = {"--out": str(tmp_path / "s.csv")}
    outs[flag] = str(tmp_path / "nowhere" / "x.csv")
    args = ["--log", str(log), "--quiet"] + [x for kv in outs.items() for x in kv]
    rc = replay_main(args)
    err = capsys.readouterr().err
    assert rc == 2 and f"{flag} " in err and "does not exist" in err, err
    assert "mkdir -p" in err and "Traceback" not in err
