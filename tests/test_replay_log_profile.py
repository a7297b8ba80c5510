"""``navd replay --log`` takes the filter profile from the log's own vehicle type and ends with
the roll/pitch RMS against the log's attitude in flight (issue 16 item 3).

log171.bin ("APM:Copter V3.3-dev") replayed with the default ``ground`` profile was 8.6/11.0
deg RMS from ATT in flight, 3.5/3.7 deg with ``multirotor``, and the replay printed no RMS at
all.  Small logs written at test time (tests/fixtures/logwriters.py) carry each kind of
vehicle-type statement; the real logs are in tests/test_real_logs.py.
"""

from __future__ import annotations

import dataclasses
import math
import re
from pathlib import Path

import numpy as np
import pytest
from fixtures.logwriters import (
    Source,
    source_from_sim,
    write_dataflash_ac33,
    write_inertialnav_quad,
    write_tlog,
    write_ulog,
    write_x8,
)

from navd.cli.replay import main as replay_main
from navd.eval.flight import flight_window, takeoff_s
from navd.io.logs import read_log

DEG = math.pi / 180.0


@pytest.fixture(scope="module")
def src() -> Source:
    return source_from_sim(20.0)


def _vehicle(kind: str, arg: object, src: Source, tmp_path: Path) -> tuple[str, str]:
    if kind == "dataflash":
        p = tmp_path / "log.bin"
        assert isinstance(arg, bytes)
        write_dataflash_ac33(p, src, firmware=arg)
    elif kind == "ulog":
        p = tmp_path / "log.ulg"
        write_ulog(p, src, params=None if arg is None else {"MAV_TYPE": int(str(arg))})
    elif kind == "ulog_status":
        p = tmp_path / "log.ulg"
        write_ulog(p, src, vehicle_type=int(str(arg)))
    elif kind == "tlog":
        p = tmp_path / "log.tlog"
        write_tlog(p, src, mav_type=int(str(arg)), gcs_heartbeat=True)
    else:
        p = tmp_path / "x8"
        write_x8(p, src)
    data = read_log(p)
    return data.vehicle, data.vehicle_from


@pytest.mark.parametrize(("kind", "arg", "vehicle", "said"), [
    ("dataflash", b"APM:Copter V3.3-dev", "multirotor", "firmware APM:Copter V3.3-dev"),
    ("dataflash", b"ArduPlane V3.4.0", "fixed_wing", "firmware ArduPlane V3.4.0"),
    ("dataflash", b"ArduRover v2.50", "ground", "firmware ArduRover v2.50"),
    ("dataflash", b"ArduSub V3.5.2", "", "firmware ArduSub V3.5.2"),
    ("dataflash", b"", "", ""),
    ("ulog", 2, "multirotor", "parameter MAV_TYPE 2 (QUADROTOR)"),
    ("ulog", 1, "fixed_wing", "parameter MAV_TYPE 1 (FIXED_WING)"),
    ("ulog", 10, "ground", "parameter MAV_TYPE 10 (GROUND_ROVER)"),
    ("ulog", 11, "boat", "parameter MAV_TYPE 11 (SURFACE_BOAT)"),
    ("ulog", 21, "", "parameter MAV_TYPE 21 (VTOL_TILTROTOR)"),
    ("ulog", None, "", ""),
    ("ulog_status", 1, "multirotor", "vehicle_status vehicle_type 1 (ROTARY_WING)"),
    ("ulog_status", 2, "fixed_wing", "vehicle_status vehicle_type 2 (FIXED_WING)"),
    ("tlog", 13, "multirotor", "HEARTBEAT MAV_TYPE 13 (HEXAROTOR)"),
    ("tlog", 1, "fixed_wing", "HEARTBEAT MAV_TYPE 1 (FIXED_WING)"),
    ("tlog", 11, "boat", "HEARTBEAT MAV_TYPE 11 (SURFACE_BOAT)"),
    ("x8", None, "", ""),
])
def test_each_log_kind_states_its_vehicle_type(kind: str, arg: object, vehicle: str,
                                               said: str, src: Source, tmp_path: Path) -> None:
    """GIVEN a DataFlash log with a firmware banner (Copter, Plane, Rover, Sub, none), a ULog
    with a MAV_TYPE parameter (quad, plane, rover, VTOL, none) or only a vehicle_status topic
    (rotary wing, fixed wing), a tlog whose vehicle and a
    ground station both send HEARTBEATs, and an X8 text log,
    WHEN each is read,
    THEN the vehicle type maps to the profile (Copter/rotorcraft -> multirotor, Plane/fixed
    wing -> fixed_wing, Rover -> ground; Sub and VTOL to none but still said), the ground
    station's heartbeat is ignored, and the text log states none."""
    assert _vehicle(kind, arg, src, tmp_path) == (vehicle, said)


def _replay(log: Path, out: Path, capsys: pytest.CaptureFixture[str], *args: str
            ) -> tuple[int, str]:
    rc = replay_main(["--log", str(log), "--out", str(out), "--quiet",
                      "--set", "imu.grade=industrial", *args])
    return rc, capsys.readouterr().err


def test_replay_takes_the_profile_from_the_log_and_an_explicit_setting_wins(
        src: Source, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """GIVEN an ArduCopter 3.3 DataFlash log (a multirotor by its firmware banner),
    WHEN it is replayed with no profile set, with --set filter.profile=multirotor, with
    --set filter.profile=ground, and with a --config file setting fixed_wing,
    THEN without a setting one line says "profile multirotor from the log's vehicle type" and
    the solution equals the explicit multirotor replay's byte for byte; --set ground and the
    config's fixed_wing stand (the line says "as set" and notes the log's multirotor), and
    the ground replay differs from the multirotor one."""
    log = tmp_path / "copter.bin"
    write_dataflash_ac33(log, src)
    auto, mr, gr, fw = (tmp_path / f"{n}.csv" for n in ("auto", "mr", "gr", "fw"))
    rc, err = _replay(log, auto, capsys)
    assert rc == 0, err
    line = ("navd replay: profile multirotor from the log's vehicle type (firmware APM:Copter "
            "V3.3-dev); --set filter.profile=... to override")
    assert line in err.splitlines(), err
    assert "course update: disabled: multirotor profile" in err, err
    rc, err = _replay(log, mr, capsys, "--set", "filter.profile=multirotor")
    assert rc == 0 and "profile multirotor as set (filter.profile)" in err, err
    assert auto.read_text() == mr.read_text()
    rc, err = _replay(log, gr, capsys, "--set", "filter.profile=ground")
    assert rc == 0, err
    assert ("profile ground as set (filter.profile); note: the log's vehicle type says "
            "multirotor (firmware APM:Copter V3.3-dev)") in err, err
    assert "multirotor profile" not in err.split("course update:", 1)[1].split(";")[0]
    assert gr.read_text() != mr.read_text()
    cfg = tmp_path / "navd.toml"
    cfg.write_text('[filter]\nprofile = "fixed_wing"\n')
    rc, err = _replay(log, fw, capsys, "--config", str(cfg))
    assert rc == 0 and "profile fixed_wing as set (filter.profile)" in err, err


def test_replay_of_a_log_without_a_vehicle_type_keeps_the_default_and_says_so(
        src: Source, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """GIVEN an InertialNav quad zip (no vehicle type in it) and a tlog from a fixed wing,
    WHEN each is replayed with no profile set,
    THEN the zip replays with the default ground profile and the line says the log does not
    state its vehicle type and how to choose one; the tlog replays as fixed_wing."""
    z = tmp_path / "quad.zip"
    write_inertialnav_quad(z, src)
    rc, err = _replay(z, tmp_path / "q.csv", capsys)
    assert rc == 0, err
    assert ("profile ground (the default): the log does not state its vehicle type; --set "
            "filter.profile=multirotor (or fixed_wing) if it flies") in err, err
    t = tmp_path / "plane.tlog"
    write_tlog(t, src, mav_type=1)
    rc, err = _replay(t, tmp_path / "t.csv", capsys)
    assert rc == 0, err
    assert "profile fixed_wing from the log's vehicle type (HEARTBEAT MAV_TYPE 1" in err, err


_RMS = re.compile(r"roll/pitch RMS navd - ATT (?P<span>.*): (?P<roll>[0-9.]+) / "
                  r"(?P<pitch>[0-9.]+) deg over (?P<n>\d+) rows")


def _independent_rms(sol_csv: Path, ref_csv: Path, from_us: float) -> tuple[float, float, int]:
    """Roll and pitch RMS of solution minus reference (linear interpolation, no wrap needed
    here) over rows at or after ``from_us`` that have a reference sample within 0.1 s."""
    s = np.genfromtxt(sol_csv, delimiter=",", names=True)
    r = np.genfromtxt(ref_csv, delimiter=",", names=True)
    t = s["t_us"]
    k = np.clip(np.searchsorted(r["t_us"], t), 1, len(r) - 1)
    near = np.minimum(np.abs(r["t_us"][k] - t), np.abs(r["t_us"][k - 1] - t)) <= 100_000
    use = near & (t >= from_us)
    out = []
    for axis in ("roll_deg", "pitch_deg"):
        e = s[axis][use] - np.interp(t[use], r["t_us"], r[axis])
        out.append(float(np.sqrt(np.mean(e * e))))
    return out[0], out[1], int(use.sum())


def test_rms_line_against_a_reference_with_a_known_offset(
        src: Source, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """GIVEN a 20 s DataFlash log whose ATT is the true attitude plus +2.0 deg roll and -1.5
    deg pitch, and whose gyros vibrate from 6 s on (+-0.1 rad/s, alternating sample by
    sample: a 5.7 deg/s spread, the take-off; the attitude it adds is 0.06 deg),
    WHEN it is replayed,
    THEN the closing line says in flight from 6.0 s to the end, and its RMS equal the RMS
    computed here from the solution and --reference-out files over the same rows (to the
    printed 0.01 deg), which are the offsets within navd's own error (0.3 deg)."""
    sign = np.where(np.arange(len(src.imu_t_us)) % 2 == 0, 1.0, -1.0)
    vib = np.where((src.imu_t_us >= 6_000_000)[:, None], 0.1 * sign[:, None], 0.0)
    offset = np.array([2.0, -1.5, 0.0]) * DEG
    shaken = dataclasses.replace(src, gyro=src.gyro + vib, ref_euler=src.ref_euler + offset)
    log = tmp_path / "offset.bin"
    write_dataflash_ac33(log, shaken)
    out, ref = tmp_path / "s.csv", tmp_path / "ref.csv"
    rc, err = _replay(log, out, capsys, "--reference-out", str(ref))
    assert rc == 0, err
    m = _RMS.search(err)
    assert m is not None, err
    # the take-off instant to the microsecond (its rule is tested below): 6 s after the
    # start of the IMU's 1 s windows, which count from the log's second IMU sample
    data = read_log(log)
    t0_us = int(min(data.imu_t_us[0], data.reference.t_us[0]))
    win = flight_window(data.imu_t_us, data.imu_inc, t0_us)
    assert win.from_s == pytest.approx(6.0 - t0_us * 1e-6, abs=0.05)
    assert m["span"].startswith(f"in flight, {win.from_s:.1f} s to the end from the log's "
                                "start (take-off:"), m["span"]
    roll, pitch, n = _independent_rms(out, ref, t0_us + win.from_s * 1e6 - 0.5)
    assert int(m["n"]) == n > 0.9 * 50 * 13
    assert float(m["roll"]) == pytest.approx(roll, abs=0.006)
    assert float(m["pitch"]) == pytest.approx(pitch, abs=0.006)
    assert float(m["roll"]) == pytest.approx(2.0, abs=0.3)
    assert float(m["pitch"]) == pytest.approx(1.5, abs=0.3)


def test_rms_line_without_a_take_off_scores_the_whole_solution(
        src: Source, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """GIVEN a 20 s DataFlash log of a car on a straight road (gyro spread far below 2 deg/s:
    no take-off), ATT the true attitude,
    WHEN it is replayed,
    THEN the closing line says "over the whole solution (no take-off found" and its RMS equal
    those computed here over every row with a reference sample."""
    log = tmp_path / "car.bin"
    write_dataflash_ac33(log, src)
    out, ref = tmp_path / "s.csv", tmp_path / "ref.csv"
    rc, err = _replay(log, out, capsys, "--reference-out", str(ref))
    assert rc == 0, err
    m = _RMS.search(err)
    assert m is not None, err
    assert m["span"].startswith("over the whole solution (no take-off found"), m["span"]
    roll, pitch, n = _independent_rms(out, ref, -math.inf)
    assert int(m["n"]) == n
    assert float(m["roll"]) == pytest.approx(roll, abs=0.006)
    assert float(m["pitch"]) == pytest.approx(pitch, abs=0.006)


def test_take_off_skips_handling_on_the_ground_and_flight_ends_at_a_crash() -> None:
    """GIVEN 80 s of gyro rates at 100 Hz: at rest (0.02 deg/s noise), picked up for 2 s at
    5 s (10 deg/s spread), at rest again, flying from 30 s (8 deg/s spread, one quiet 1 s
    window at 40 s), a 1500 deg/s tumble at 70 s,
    WHEN the flight window is found,
    THEN take-off is 30 s (the handling at 5 s is followed by rest), the end is the crash's
    onset 1 s before the tumble's first 1500 deg/s sample (69 s), and times count from the
    given log start (1 s before the first sample)."""
    rng = np.random.default_rng(1)
    t = np.arange(0, 80_000_000, 10_000, dtype=np.int64) + 1_000_000
    ts = (t - t[0]) * 1e-6
    sd = np.where((ts >= 5) & (ts < 7), 10.0, 0.02)
    sd = np.where((ts >= 30) & ~((ts >= 40) & (ts < 41)), 8.0, sd)
    rates = rng.normal(0.0, 1.0, (len(t), 3)) * sd[:, None] * DEG
    rates[ts >= 70.0] = 1500.0 * DEG
    assert takeoff_s(t, rates) == 30.0
    inc = np.zeros((len(t), 6))
    inc[1:, :3] = rates[1:] * 0.01  # increments over the 10 ms intervals
    win = flight_window(t, inc, 0)
    assert win.from_s == pytest.approx(31.0, abs=0.011)
    assert win.to_s == pytest.approx(70.0, abs=0.011)
    assert win.mask(np.array([30_500_000, 32_000_000, 69_900_000, 70_100_000])).tolist() == [
        False, True, True, False]
