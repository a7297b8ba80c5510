"""The GNSS antenna position a flight log states reaches the filter (issue 14, real logs).

An antenna off the IMU moves at w x l while the vehicle turns; with the lever arm left at
zero the filter explains that velocity by accelerometer bias and tilt (log171: a yaw at
55 deg/s, and a lateral offset of 0.2 m worth ~1 deg of roll; docs/results.md, "log171's
remaining roll").  Autopilot logs that carry the antenna's and the IMU's positions (ArduPilot
GPS1_POS_* / GPS_POS1_* and INS_POS1_*, PX4 EKF2_GPS_POS_* and EKF2_IMU_POS_*) are replayed
with their difference as ``[gnss] lever_arm_m`` unless the user set one.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest
from fixtures.logwriters import Source, source_from_sim, write_dataflash_ac33, write_ulog

from navd.cli import replay
from navd.io.logs import read_log
from navd.io.logs.common import lever_arm_from_params

ANT = [("GPS1_POS_X", "GPS1_POS_Y", "GPS1_POS_Z"), ("GPS_POS1_X", "GPS_POS1_Y", "GPS_POS1_Z")]
IMU = [("INS_POS1_X", "INS_POS1_Y", "INS_POS1_Z")]


@pytest.fixture(scope="module")
def src() -> Source:
    return source_from_sim(12.0)


def test_antenna_minus_imu_from_the_first_complete_name_set() -> None:
    """GIVEN autopilot parameters of the antenna's and the IMU's positions from the body
    origin,
    THEN the lever arm is antenna minus IMU from the first complete set of names (the newer
    naming first), the IMU counting as the origin when its position is not there; nothing is
    returned without a complete antenna set, for a zero difference (the default, nothing
    stated), or for a value that is not finite or beyond 10 m."""
    p = {"GPS1_POS_X": 0.3, "GPS1_POS_Y": -0.2, "GPS1_POS_Z": -0.1,
         "GPS_POS1_X": 9.0, "GPS_POS1_Y": 9.0, "GPS_POS1_Z": 9.0,
         "INS_POS1_X": 0.05, "INS_POS1_Y": 0.0, "INS_POS1_Z": 0.02}
    got = lever_arm_from_params(p, ANT, IMU)
    assert got is not None
    assert got[0] == pytest.approx((0.25, -0.2, -0.12))
    assert "GPS1_POS_*" in got[1] and "INS_POS1_*" in got[1]
    old = {k: v for k, v in p.items() if not k.startswith("GPS1_")}
    got = lever_arm_from_params(old, ANT, IMU)
    assert got is not None and got[0] == pytest.approx((8.95, 9.0, 8.98))
    no_imu = lever_arm_from_params({"GPS_POS1_X": 0.1, "GPS_POS1_Y": 0.0, "GPS_POS1_Z": 0.0},
                                   ANT, IMU)
    assert no_imu is not None and no_imu[0] == (0.1, 0.0, 0.0) and "minus" not in no_imu[1]
    assert lever_arm_from_params({"GPS1_POS_X": 0.1, "GPS1_POS_Y": 0.0}, ANT, IMU) is None
    assert lever_arm_from_params({n: 0.0 for n in ANT[0] + IMU[0]}, ANT, IMU) is None
    same = {"GPS1_POS_X": 0.1, "GPS1_POS_Y": 0.2, "GPS1_POS_Z": 0.3,
            "INS_POS1_X": 0.1, "INS_POS1_Y": 0.2, "INS_POS1_Z": 0.3}
    assert lever_arm_from_params(same, ANT, IMU) is None
    for bad in (math.nan, math.inf, 11.0):
        assert lever_arm_from_params({**p, "GPS1_POS_Y": bad}, ANT, IMU) is None


def test_dataflash_log_states_its_antenna_position(src: Source, tmp_path: Path) -> None:
    """GIVEN a DataFlash log whose PARM messages place the antenna at (0.12, -0.2, -0.15) m
    and the IMU at (0.02, 0, 0) m from the body origin (pre-4.6 names),
    WHEN it is read,
    THEN LogData.lever_arm_m is their difference (float32 parameters) and a note says so; a
    log without them has none and no note."""
    p = tmp_path / "pos.bin"
    write_dataflash_ac33(p, src, params={"GPS_POS1_X": 0.12, "GPS_POS1_Y": -0.2,
                                         "GPS_POS1_Z": -0.15, "INS_POS1_X": 0.02,
                                         "INS_POS1_Y": 0.0, "INS_POS1_Z": 0.0})
    d = read_log(p)
    assert d.lever_arm_m is not None
    assert d.lever_arm_m == pytest.approx((0.10, -0.2, -0.15), abs=1e-6)
    assert "GPS_POS1_*" in d.lever_arm_from
    assert any("GNSS antenna at (0.100, -0.200, -0.150) m" in n for n in d.notes), d.notes
    plain = tmp_path / "plain.bin"
    write_dataflash_ac33(plain, src)
    q = read_log(plain)
    assert q.lever_arm_m is None and q.lever_arm_from == ""
    assert not any("GNSS antenna" in n for n in q.notes)


def test_ulog_states_its_antenna_position(src: Source, tmp_path: Path) -> None:
    """GIVEN a PX4 ULog with EKF2_GPS_POS_X/Y/Z = (0.3, 0, -0.2) and EKF2_IMU_POS_X/Y/Z =
    (0.1, 0, 0) m,
    WHEN it is read,
    THEN LogData.lever_arm_m is (0.2, 0, -0.2) m."""
    p = tmp_path / "pos.ulg"
    write_ulog(p, src, params={"EKF2_GPS_POS_X": 0.3, "EKF2_GPS_POS_Y": 0.0,
                               "EKF2_GPS_POS_Z": -0.2, "EKF2_IMU_POS_X": 0.1,
                               "EKF2_IMU_POS_Y": 0.0, "EKF2_IMU_POS_Z": 0.0})
    d = read_log(p)
    assert d.lever_arm_m == pytest.approx((0.2, 0.0, -0.2), abs=1e-6)
    assert "EKF2_GPS_POS_*" in d.lever_arm_from


def test_replay_takes_the_logs_lever_arm_unless_set(src: Source, tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str],
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """GIVEN the DataFlash log stating an antenna 0.1 m ahead of, 0.2 m left of and 0.15 m
    above the IMU,
    WHEN it is replayed as it is, then with `--set gnss.lever_arm_m=[0,0,0]`,
    THEN the estimator is built with the log's lever arm, as a measured one (1-sigma
    0.05 m), and the replay says it came from the log; with the user's setting, the user's
    stands (with the default 1-sigma) and the line names the log's."""
    p = tmp_path / "pos.bin"
    write_dataflash_ac33(p, src, params={"GPS_POS1_X": 0.1, "GPS_POS1_Y": -0.2,
                                         "GPS_POS1_Z": -0.15})
    built: list[tuple[float, ...]] = []
    sds: list[float] = []
    real = replay.build_estimator

    def spy(cfg: Any) -> Any:
        built.append(tuple(cfg.estimator.gnss.lever_arm))
        sds.append(cfg.estimator.gnss.lever_arm_sd)
        return real(cfg)

    monkeypatch.setattr(replay, "build_estimator", spy)
    out = tmp_path / "s.csv"
    assert replay.main(["--log", str(p), "--out", str(out), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert ("gnss.lever_arm_m = [0.100, -0.200, -0.150] from the log, "
            "gnss.lever_arm_sd_m = 0.05") in err, err[-2000:]
    assert built[-1] == pytest.approx((0.1, -0.2, -0.15), abs=1e-6)
    assert replay.main(["--log", str(p), "--out", str(out), "--quiet",
                        "--set", "gnss.lever_arm_m=[0,0,0]"]) == 0
    err = capsys.readouterr().err
    assert "gnss.lever_arm_m as set; note: the log states (0.100, -0.200, -0.150) m" in err
    assert built[-1] == (0.0, 0.0, 0.0)
    assert sds == [0.05, 0.5]  # the log's lever arm is a measured one; the user's: default
    plain = tmp_path / "plain.bin"
    write_dataflash_ac33(plain, src)
    assert replay.main(["--log", str(plain), "--out", str(out), "--quiet"]) == 0
    assert "the log states no antenna position" in capsys.readouterr().err
    assert built[-1] == (0.0, 0.0, 0.0) and sds[-1] == 0.5
