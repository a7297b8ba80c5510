"""InertialNav multirotor text logs (issue 16 item 3): ``quad123.zip`` has GPS.txt (speed and
course, no NED velocity) instead of GPSraw.txt, and ``f450_glitch_log.zip`` writes ATT.txt
yaw first.  Synthetic zips reproduce both layouts (CI has no real logs)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from fixtures.logwriters import Source, source_from_sim, write_inertialnav_quad

from navd.io.logs import detect_format, read_log


@pytest.fixture(scope="module")
def src() -> Source:
    return source_from_sim(20.0)


def _euler_err(data_ref: tuple[np.ndarray, np.ndarray, np.ndarray], want: np.ndarray
               ) -> float:
    e = np.stack(data_ref, 1) - want
    return float(np.abs((e + math.pi) % (2 * math.pi) - math.pi).max())


@pytest.mark.parametrize("unit", ["deg", "rad"])
def test_gps_txt_speed_and_course(unit: str, src: Source, tmp_path: Path) -> None:
    """GIVEN a quad123-style zip (IMU.txt, GPS.txt with speed and course in ``unit``, no
    GPSraw.txt, ATT.txt roll, pitch, yaw),
    WHEN it is detected and read,
    THEN it is an x8 log, every fix is there with position as written, NED velocity is
    speed x (cos, sin) course, vertical velocity is NaN (not reported), the note names the
    course unit and the ATT layout, and the reference is the written attitude."""
    p = tmp_path / "quad.zip"
    write_inertialnav_quad(p, src, gps="GPS.txt", course_unit=unit)
    assert detect_format(p) == "x8"
    data = read_log(p)
    assert data.damage is None
    assert np.array_equal(data.gnss_t_us, [g.t_us for g in src.gnss])
    want = np.array([[g.lat_rad, g.lon_rad, g.alt_m, g.vel_n, g.vel_e] for g in src.gnss])
    np.testing.assert_allclose(data.gnss[:, :2], want[:, :2], atol=2e-9)
    np.testing.assert_allclose(data.gnss[:, 2], want[:, 2], atol=1e-9)
    np.testing.assert_allclose(data.gnss[:, 3:5], want[:, 3:5], atol=1e-9)
    assert np.all(np.isnan(data.gnss[:, 5]))
    assert np.all(data.gnss[:, 6:9] == [2.5, 5.0, 0.3])
    word = "degrees" if unit == "deg" else "radians"
    assert any(f"course read as {word}" in n for n in data.notes), data.notes
    assert any(n.startswith("ATT.txt read as roll,pitch,yaw (documented") for n in data.notes)
    r = data.reference
    assert np.array_equal(r.t_us, src.ref_t_us)
    assert _euler_err((r.roll_rad, r.pitch_rad, r.yaw_rad), src.ref_euler) < 1e-6
    assert len(data.imu_t_us) == len(src.imu_t_us) - 1  # rate form: first sample starts


def test_att_yaw_first_detected(src: Source, tmp_path: Path) -> None:
    """GIVEN an f450-style zip (GPSraw.txt with NED velocity, ATT.txt yaw, roll, pitch; the
    reference yaw is 20 deg, roll and pitch 0, so the two orders differ at rest),
    WHEN it is read,
    THEN the yaw-first order is detected from the accelerometer at rest and said in a note,
    the reference roll/pitch/yaw are the written ones, and GNSS keeps its logged vel_d."""
    p = tmp_path / "f450.zip"
    write_inertialnav_quad(p, src, att_layout="yaw,roll,pitch", gps="GPSraw.txt")
    data = read_log(p)
    assert any(n.startswith("ATT.txt read as yaw,roll,pitch, not the documented")
               for n in data.notes), data.notes
    r = data.reference
    assert _euler_err((r.roll_rad, r.pitch_rad, r.yaw_rad), src.ref_euler) < 1e-6
    np.testing.assert_allclose(data.gnss[:, 5], [g.vel_d for g in src.gnss], atol=1e-9)
    assert not any("GPS.txt" in n for n in data.notes)


def test_no_rest_keeps_documented_order(src: Source, tmp_path: Path) -> None:
    """GIVEN a zip whose IMU never looks at rest (all rates 1 rad/s),
    WHEN it is read,
    THEN the documented order is used and the note says it could not be checked."""
    spun = Source(src.imu_t_us, src.dt_us, np.ones_like(src.gyro), src.accel, src.gnss,
                  src.ref_t_us, src.ref_euler)
    p = tmp_path / "spun.zip"
    write_inertialnav_quad(p, spun, att_layout="yaw,roll,pitch")
    data = read_log(p)
    assert any("documented; no rest samples" in n for n in data.notes), data.notes
