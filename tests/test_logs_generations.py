"""Every generation of autopilot log reads onto one clock (issue 16 item 3).

ArduCopter <= 3.3 DataFlash (log171.bin) stores GPS time of week in the GPS message's
``TimeMS``; read as time since boot every fix lay days after the IMU and the replay produced 0
rows.  The fixture writes that generation's exact formats (from log171's FMT messages).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from fixtures.logwriters import (
    ACC_EVERY,
    Source,
    source_from_sim,
    write_dataflash,
    write_dataflash_ac33,
    write_ulog,
)

from navd.cli.replay import main as replay_main
from navd.io.logs import LogData, LogFormatError, LogOptions, read_log
from navd.types import GnssSample


@pytest.fixture(scope="module")
def src() -> Source:
    return source_from_sim(20.0)


@pytest.mark.parametrize("boot_time_in_gps", [True, False])
def test_ac33_dataflash_gps_time_of_week_is_not_boot_time(src: Source, tmp_path: Path,
                                                          boot_time_in_gps: bool) -> None:
    """GIVEN an ArduCopter 3.3 DataFlash log whose GPS TimeMS is GPS time of week, with and
    without a boot-time field T in the GPS message,
    WHEN it is read,
    THEN the fixes land on the IMU clock: at their boot time exactly with T, within one IMU
    interval (10 ms) without; the reference is the whole ATT and the vehicle type is the
    firmware banner's: a multirotor."""
    p = tmp_path / "ac33.bin"
    write_dataflash_ac33(p, src, boot_time_in_gps)
    data = read_log(p)
    assert data.fmt == "dataflash"
    fixes = [s for s in data.samples() if isinstance(s, GnssSample)]
    assert len(fixes) >= len(src.gnss) - 1
    want = np.asarray([g.t_us // 1000 * 1000 for g in src.gnss])
    got = np.asarray([g.t_us for g in fixes])
    if boot_time_in_gps:  # T: the boot time of the fix, exactly
        assert set(got) <= set(want)
    else:  # no T: the IMU sample logged before it, within one IMU interval
        k = np.searchsorted(want, got)
        assert np.all(np.abs(got - want[np.clip(k, 0, len(want) - 1)]) <= 10_000)
    assert data.reference.source == "ATT" and len(data.reference.t_us) == len(src.ref_t_us)
    assert data.vehicle == "multirotor", (data.vehicle, data.vehicle_from)
    assert data.vehicle_from == "firmware APM:Copter V3.3-dev"


def test_ac33_dataflash_replays_and_agrees_with_its_attitude(src: Source, tmp_path: Path,
                                                            capsys: pytest.CaptureFixture[str]
                                                            ) -> None:
    """GIVEN an ArduCopter 3.3 DataFlash log of a 20 s flight,
    WHEN it is replayed with its reference attitude written out,
    THEN it exits 0 with solutions for over 90 % of 19 s at 50 Hz, and after 5 s the roll
    and pitch RMS errors against the logged attitude are under 0.5 deg.

    The replay is told the simulated IMU's grade (car480's: 12 deg/h, 5 mg = "industrial"):
    this checks the reader (axes, units, clocks), and 20 s of straight road cannot separate
    tilt from an uncalibrated gyro's bias under the default consumer prior (1800 deg/h: tilt
    sigma ~1 deg after 20 s; docs/results.md, "Tilt with the consumer default")."""
    p = tmp_path / "ac33.bin"
    write_dataflash_ac33(p, src)
    out, ref = tmp_path / "s.csv", tmp_path / "ref.csv"
    rc = replay_main(["--log", str(p), "--out", str(out), "--reference-out", str(ref),
                      "--quiet", "--set", "imu.grade=industrial"])
    assert rc == 0, capsys.readouterr().err
    sol = np.genfromtxt(out, delimiter=",", names=True)
    r = np.genfromtxt(ref, delimiter=",", names=True)
    assert len(sol) > 0.9 * 50 * 19
    late = sol["t_us"] > 5e6
    for axis in ("roll_deg", "pitch_deg"):
        err = sol[axis][late] - np.interp(sol["t_us"][late], r["t_us"], r[axis])
        assert np.sqrt(np.mean(err**2)) < 0.5, axis


def test_wrong_format_is_one_clear_error_not_a_flood(src: Source, tmp_path: Path,
                                                     capfd: pytest.CaptureFixture[str]) -> None:
    """GIVEN a ULog,
    WHEN it is replayed with --format dataflash,
    THEN it exits 2 with "--format dataflash, but the content is a ulog log" in under 5 lines
    (issue 16 item 5: it printed a line per byte, then exit 0)."""
    log = tmp_path / "run.ulg"
    write_ulog(log, src)
    rc = replay_main(["--log", str(log), "--format", "dataflash", "--out",
                      str(tmp_path / "s.csv"), "--quiet"])
    out, err = capfd.readouterr()
    assert rc == 2, err
    assert "--format dataflash, but the content is a ulog log" in err, err
    assert len((out + err).splitlines()) < 5, (out + err)[:2000]


def test_garbage_in_a_dataflash_log_is_counted_not_printed(src: Source, tmp_path: Path,
                                                           capfd: pytest.CaptureFixture[str]
                                                           ) -> None:
    """GIVEN an ArduCopter 3.3 DataFlash log preceded by 6000 bytes of garbage,
    WHEN it is replayed with --format dataflash,
    THEN no "bad header" lines are printed, the output is under 12 lines, and it either
    fails or says the start is unreadable."""
    good = tmp_path / "good.bin"
    write_dataflash_ac33(good, src)
    bad = tmp_path / "bad.bin"
    bad.write_bytes(b"\x00\x01" * 3000 + good.read_bytes())  # unreadable start
    rc = replay_main(["--log", str(bad), "--format", "dataflash", "--out",
                      str(tmp_path / "s.csv"), "--quiet"])
    out, err = capfd.readouterr()
    assert "bad header" not in out, out[:500]
    lines = (out + err).splitlines()
    assert len(lines) < 12, (out + err)[:2000]
    assert rc != 0 or any("unreadable" in ln for ln in lines), err


def _split_increments(src: Source, every: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What pairing a gyro at every sample with an accel at every ``every``-th must give:
    at each accel time T[k] (after the first), dt = T[k] - T[k-1], dtheta = mean of the gyro
    samples in (T[k-1], T[k]] x dt, dvel = accel(T[k]) x dt."""
    idx = np.arange(0, len(src.imu_t_us), every)
    t = src.imu_t_us[idx]
    dt = np.diff(t)
    dth = np.stack([src.gyro[i - every + 1:i + 1].mean(axis=0) for i in idx[1:]])
    dv = src.accel[idx[1:]]
    s = dt[:, None] * 1e-6
    return t[1:], dt, np.hstack([dth * s, dv * s])


def _assert_split_pairing(data: LogData, src: Source) -> int:
    """``data`` holds the increments of pairing ``src``'s gyro with its accel at every
    ``ACC_EVERY``-th sample (``_split_increments``); return how many."""
    t, dt, inc = _split_increments(src, ACC_EVERY)
    np.testing.assert_array_equal(data.imu_t_us, t)
    np.testing.assert_array_equal(data.imu_dt_us, dt)
    np.testing.assert_allclose(data.imu_inc, inc, rtol=1e-9, atol=1e-12)
    return len(t)


def _assert_instance_one(other: LogData, n: int) -> None:
    """``other`` holds ``n`` increments of the writers' instance 1 only: 9 rad/s, zero accel."""
    assert len(other.imu_t_us) == n
    np.testing.assert_allclose(other.imu_inc[:, :3] / (other.imu_dt_us[:, None] * 1e-6), 9.0,
                               rtol=1e-6)
    np.testing.assert_allclose(other.imu_inc[:, 3:], 0.0)


@pytest.mark.parametrize("style", ["ACC/GYR", "ACC1/GYR1"])
def test_dataflash_acc_gyr_streams_pair_at_the_slower_rate(src: Source, tmp_path: Path,
                                                          style: str) -> None:
    """GIVEN a DataFlash log with no IMU message, only raw ACC and GYR streams (4.x with an
    ``I`` field, or 3.x ACC1/GYR1 names), accel at half the gyro rate, stamped in SampleUS
    (logged 1 ms later in TimeUS), and a second instance holding 9 rad/s,
    WHEN it is read (instance 0, then instance 1),
    THEN the increments sit at the accel (slower) SampleUS times with dtheta = mean gyro over
    the interval x dt and dvel = accel x dt, and no instance-1 value leaks in; instance 1 reads
    only instance 1."""
    p = tmp_path / "acc.bin"
    write_dataflash(p, src, imu=style)
    data = read_log(p)
    count = _assert_split_pairing(data, src)
    assert any("ACC/GYR instance 0" in n and "accel rate" in n for n in data.notes), data.notes
    _assert_instance_one(read_log(p, options=LogOptions(imu_instance=1)), count)


def test_ulog_split_accel_gyro_topics_and_instance_choice(src: Source, tmp_path: Path) -> None:
    """GIVEN a ULog without sensor_combined, whose sensor_accel / sensor_gyro are published as
    multi_id 0 (the source; accel at half the gyro rate, timestamp_sample = sample time,
    timestamp 1 ms later) and multi_id 1 (gyro 9 rad/s, zero accel),
    WHEN it is read with the default instance and with imu_instance=1,
    THEN instance 0 gives the increments of pairing at the accel (slower) sample times, and
    instance 1 gives only instance 1's values (never a mix)."""
    p = tmp_path / "split.ulg"
    write_ulog(p, src, imu_topics="split")
    data = read_log(p)
    count = _assert_split_pairing(data, src)
    assert any("multi_id 0" in n and "accel rate" in n for n in data.notes), data.notes
    assert len(data.gnss_t_us) == len(src.gnss)
    _assert_instance_one(read_log(p, options=LogOptions(imu_instance=1)), count)


def test_ulog_sensor_combined_is_instance_0_other_instances_from_split_topics(
        src: Source, tmp_path: Path) -> None:
    """GIVEN a ULog with sensor_combined and sensor_accel / sensor_gyro multi_id 0 and 1,
    WHEN it is read by default and with imu_instance=1 and 2,
    THEN the default reads sensor_combined (every source sample, with its integral dt),
    instance 1 reads the multi_id 1 pair only, and instance 2 is an error naming 0 and 1."""
    p = tmp_path / "both.ulg"
    write_ulog(p, src, imu_topics="both")
    data = read_log(p)
    np.testing.assert_array_equal(data.imu_t_us, src.imu_t_us)
    one = read_log(p, options=LogOptions(imu_instance=1))
    np.testing.assert_allclose(one.imu_inc[:, :3] / (one.imu_dt_us[:, None] * 1e-6), 9.0,
                               rtol=1e-6)
    with pytest.raises(LogFormatError, match=r"instances: \[0, 1\]"):
        read_log(p, options=LogOptions(imu_instance=2))


def test_dataflash_gps_week_ms_only_maps_through_messages_with_both_clocks(
        src: Source, tmp_path: Path) -> None:
    """GIVEN an old DataFlash log whose GPS messages carry only GPS time (TimeMS = ms of week,
    Week) and are logged just before the IMU sample of their millisecond, and CAM messages
    logging boot time (TimeMS) beside GPS time (GPSTime, GPSWeek),
    WHEN it is read,
    THEN every fix lands exactly at its boot time (GPS time + the CAM clock offset), not at
    the message logged before it (10 ms early), and a note says how it was timed."""
    p = tmp_path / "ac32.bin"
    write_dataflash_ac33(p, src, boot_time_in_gps=False, camera=True)
    data = read_log(p)
    want = np.asarray([g.t_us // 1000 * 1000 for g in src.gnss])
    np.testing.assert_array_equal(data.gnss_t_us, want)
    assert any("mapped to boot time" in n for n in data.notes), data.notes


@pytest.mark.parametrize("topic", ["vehicle_gps_position", "sensor_gps"])
def test_ulog_gnss_instance_is_one_receiver(src: Source, tmp_path: Path, topic: str) -> None:
    """GIVEN a ULog with two receivers in ``topic`` (multi_id 1: 0.01 deg north, 50 ms later;
    PX4 <= 1.10 per-receiver vehicle_gps_position, newer sensor_gps),
    WHEN it is read by default and with gnss_instance=1,
    THEN each read holds exactly one receiver's fixes, all of them, none of the other's."""
    p = tmp_path / "gps2.ulg"
    write_ulog(p, src, topic, second_receiver=True)
    lat0 = np.asarray([g.lat_rad for g in src.gnss])
    for inst, dlat, dt in ((0, 0.0, 0), (1, 0.01, 50_000)):
        d = read_log(p, options=LogOptions(gnss_instance=inst))
        np.testing.assert_array_equal(d.gnss_t_us, [g.t_us + dt for g in src.gnss])
        np.testing.assert_allclose(d.gnss[:, 0], lat0 + np.radians(dlat), atol=1e-8)
        assert any(f"multi_id {inst}" in n for n in d.notes), d.notes


def test_dataflash_old_imu2_is_instance_1(src: Source, tmp_path: Path) -> None:
    """GIVEN an ArduCopter 3.3 log with IMU and IMU2 (IMU2: 9 rad/s, zero accel),
    WHEN it is read with imu_instance=1,
    THEN only IMU2 values are read, on IMU's time stamps."""
    p = tmp_path / "ac33.bin"
    write_dataflash_ac33(p, src)
    d = read_log(p, options=LogOptions(imu_instance=1))
    assert len(d.imu_t_us) == len(src.imu_t_us) - 1
    np.testing.assert_allclose(d.imu_inc[:, :3] / (d.imu_dt_us[:, None] * 1e-6), 9.0,
                               rtol=1e-6)
    np.testing.assert_allclose(d.imu_inc[:, 3:], 0.0)


def test_dataflash_reference_is_turned_onto_the_imu_axes_by_ahrs_trim(
        src: Source, tmp_path: Path) -> None:
    """GIVEN an ArduCopter 3.3 log whose ATT is the vehicle body's attitude under a level
    trim AHRS_TRIM_X/Y of 1.18/0.30 deg (log171's: ATT sat 1.18/0.37 deg below the
    accelerometer's own level at rest), logged as PARM,
    WHEN it is read,
    THEN the reference is the IMU axes' attitude (the simulated truth) to the log's 0.01 deg
    resolution, a note names the trim, and without the PARM messages the reference is ATT as
    logged (1.18 deg of roll away from the truth where level)."""
    trim = (math.radians(1.18), math.radians(0.30))
    p = tmp_path / "trim.bin"
    write_dataflash_ac33(p, src, trim_rad=trim)
    d = read_log(p)
    ref = d.reference
    k = np.searchsorted(src.ref_t_us, ref.t_us)
    assert np.all(src.ref_t_us[k] == ref.t_us)
    err = np.degrees(np.stack([ref.roll_rad - src.ref_euler[k, 0],
                               ref.pitch_rad - src.ref_euler[k, 1],
                               (ref.yaw_rad - src.ref_euler[k, 2] + np.pi) % (2 * np.pi)
                               - np.pi]))
    assert np.max(np.abs(err)) < 0.02, np.max(np.abs(err), axis=1)
    assert any("AHRS_TRIM" in n for n in d.notes), d.notes
    # the control: the same ATT without the PARM messages is read as logged
    plain = tmp_path / "plain.bin"
    write_dataflash_ac33(plain, src, trim_rad=trim, log_trim=False)
    q = read_log(plain)
    roll_off = np.degrees(q.reference.roll_rad - src.ref_euler[k, 0])
    assert abs(float(np.median(roll_off)) + 1.18) < 0.05
    assert not any("AHRS_TRIM" in n for n in q.notes)


def test_dataflash_fixes_are_moved_by_the_latency_the_log_states(src: Source,
                                                                 tmp_path: Path) -> None:
    """GIVEN an ArduCopter 3.3 log whose PARM messages state the autopilot's receiver latency
    (EKF_VEL_DELAY 200 ms, EKF_POS_DELAY 220 ms, as log171's 200/200),
    WHEN it is read with the default options,
    THEN every fix is taken as valid 200 ms (the velocity delay) before its stamp, and a note
    says so; an explicit latency (here 0) overrides the log's, and a log without the
    parameters is read as stamped."""
    p = tmp_path / "delay.bin"
    write_dataflash_ac33(p, src, params={"EKF_VEL_DELAY": 200.0, "EKF_POS_DELAY": 220.0})
    plain = tmp_path / "plain.bin"
    write_dataflash_ac33(plain, src)
    stamped = read_log(plain)
    d = read_log(p)
    assert len(d.gnss_t_us) == len(stamped.gnss_t_us) > 10
    np.testing.assert_array_equal(d.gnss_t_us, stamped.gnss_t_us - 200_000)
    np.testing.assert_array_equal(d.gnss, stamped.gnss)
    assert any("200 ms" in n and "EKF_VEL_DELAY" in n for n in d.notes), d.notes
    assert not any("EKF_VEL_DELAY" in n for n in stamped.notes)
    explicit = read_log(p, options=LogOptions(gnss_delay_s=0.0))
    np.testing.assert_array_equal(explicit.gnss_t_us, stamped.gnss_t_us)
    assert not any("EKF_VEL_DELAY" in n for n in explicit.notes)
