"""An accelerometer calibration a flight log states sets the replay's accelerometer-bias prior
(issue 14, real logs).

ArduPilot and PX4 apply their accelerometer offsets and scales before logging the IMU's
data, so a log whose parameters hold a calibration carries calibrated data: what is left is
the calibration's residual and the sensor's drift since, not the +-50 mg zero-g tolerance the
consumer grade's 30 mg prior covers.  Such logs are replayed with ``imu.accel_bias_sd_mg``
at navd.cli.replay.LOG_ACCEL_BIAS_SD_MG unless the user set it or the grade.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest
from fixtures.logwriters import Source, source_from_sim, write_dataflash_ac33, write_ulog

from navd.cli import replay
from navd.io.logs import read_log
from navd.io.logs.common import accel_calibration_from_params

AP = [(("INS_ACCOFFS_X", "INS_ACCOFFS_Y", "INS_ACCOFFS_Z"),
       ("INS_ACCSCAL_X", "INS_ACCSCAL_Y", "INS_ACCSCAL_Z"))]
OFFS = {"INS_ACCOFFS_X": -0.03, "INS_ACCOFFS_Y": 0.05, "INS_ACCOFFS_Z": -0.49}
UNCAL = {"INS_ACCOFFS_X": 0.0, "INS_ACCOFFS_Y": 0.0, "INS_ACCOFFS_Z": 0.0,
         "INS_ACCSCAL_X": 1.0, "INS_ACCSCAL_Y": 1.0, "INS_ACCSCAL_Z": 1.0}


@pytest.fixture(scope="module")
def src() -> Source:
    return source_from_sim(12.0)


def test_a_calibration_is_offsets_not_all_zero_or_scales_not_all_one() -> None:
    """GIVEN an autopilot's accelerometer calibration parameters,
    THEN offsets not all zero say "calibrated" (named, in mg), as do scales not all one with
    zero offsets; the never-calibrated values (offsets 0, scales 1), an incomplete triple,
    or a value that is not finite say nothing."""
    got = accel_calibration_from_params(OFFS, AP)
    assert got is not None and got.startswith("INS_ACCOFFS_*")
    assert "(-3.1, 5.1, -50.0 mg)" in got, got
    assert accel_calibration_from_params(UNCAL, AP) is None
    scaled = accel_calibration_from_params({**UNCAL, "INS_ACCSCAL_Y": 1.006}, AP)
    assert scaled is not None and scaled.startswith("INS_ACCSCAL_*")
    assert accel_calibration_from_params({"INS_ACCOFFS_X": 0.1, "INS_ACCOFFS_Y": 0.0}, AP) is None
    assert accel_calibration_from_params({}, AP) is None
    for bad in (math.nan, math.inf):
        assert accel_calibration_from_params({**OFFS, "INS_ACCOFFS_Y": bad}, AP) is None


def test_dataflash_and_ulog_state_their_calibration(src: Source, tmp_path: Path) -> None:
    """GIVEN a DataFlash log with INS_ACCOFFS_* set, one with the never-calibrated values and
    one without them, and a ULog with CAL_ACC0_XOFF.. set,
    WHEN they are read,
    THEN LogData.accel_calibrated names the parameters (and a note says so) for the first
    and the ULog, and is empty for the other two."""
    p = tmp_path / "cal.bin"
    write_dataflash_ac33(p, src, params=OFFS)
    d = read_log(p)
    assert d.accel_calibrated.startswith("INS_ACCOFFS_*"), d.accel_calibrated
    assert any("accelerometer calibrated by the autopilot" in n for n in d.notes), d.notes
    for name, params in (("uncal.bin", UNCAL), ("plain.bin", None)):
        q = tmp_path / name
        write_dataflash_ac33(q, src, params=params)
        e = read_log(q)
        assert e.accel_calibrated == ""
        assert not any("accelerometer calibrated" in n for n in e.notes)
    u = tmp_path / "cal.ulg"
    write_ulog(u, src, params={"CAL_ACC0_XOFF": 0.02, "CAL_ACC0_YOFF": -0.01,
                               "CAL_ACC0_ZOFF": 0.1})
    assert read_log(u).accel_calibrated.startswith("CAL_ACC0_")


def test_replay_takes_the_calibrated_prior_unless_set(src: Source, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str],
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """GIVEN the DataFlash log stating a calibration,
    WHEN it is replayed as it is, with `--set imu.accel_bias_sd_mg=40`, with `--set
    imu.grade=tactical`, and a log stating none as it is,
    THEN the estimator gets the calibrated prior (10 mg) and the replay says why; the user's
    prior, or the user's grade (1 mg), stands and the line names the log's calibration; the
    log without one keeps the consumer grade's 30 mg."""
    p = tmp_path / "cal.bin"
    write_dataflash_ac33(p, src, params=OFFS)
    sds: list[float] = []
    real = replay.build_estimator

    def spy(cfg: Any) -> Any:
        sds.append(round(cfg.estimator.imu.accel_bias_sd / 9.80665e-3, 6))
        return real(cfg)

    monkeypatch.setattr(replay, "build_estimator", spy)
    out = tmp_path / "s.csv"
    assert replay.main(["--log", str(p), "--out", str(out), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "imu.accel_bias_sd_mg = 10: the log states an accelerometer calibration" in err, \
        err[-2000:]
    for setting, want in (("imu.accel_bias_sd_mg=40", 40.0), ("imu.grade=tactical", 1.0)):
        assert replay.main(["--log", str(p), "--out", str(out), "--quiet",
                            "--set", setting]) == 0
        err = capsys.readouterr().err
        assert "imu: accelerometer bias prior as set; note: the log states a calibration" in err
        assert sds[-1] == want, (setting, sds)
    plain = tmp_path / "plain.bin"
    write_dataflash_ac33(plain, src)
    assert replay.main(["--log", str(plain), "--out", str(out), "--quiet"]) == 0
    assert "accel_bias_sd_mg" not in capsys.readouterr().err
    assert sds == [10.0, 40.0, 1.0, 30.0]
