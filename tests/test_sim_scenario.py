"""Scenario loading: every built-in validates; bad input names the field and its unit."""

from __future__ import annotations

from pathlib import Path

import pytest

from firmware_sim import ScenarioError, builtin_scenarios, load_scenario
from firmware_sim.scenario import GroundSpec, ShipSpec

GOOD = """
name = "mini"
duration_s = 20.0

[trajectory]
kind = "ground"
lat_deg = 34.2
lon_deg = 108.9
alt_m = 400.0
speed = [{ t_s = 2.0, dur_s = 5.0, to = 10.0 }]

[imu]
rate_hz = 100.0
gyro_bias_sigma_rps = 5.8e-5
accel_bias_sigma_mps2 = 0.049
arw_rad_per_sqrt_s = 7e-5
vrw_mps_per_sqrt_s = 0.3

[gnss]
rate_hz = 10.0
pos_sigma_h_m = 10.0
pos_sigma_v_m = 10.0
vel_sigma_h_mps = 0.1
vel_sigma_v_mps = 0.1
"""


def _write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "sc.toml"
    p.write_text(text, encoding="utf-8")
    return p


def test_builtins_load() -> None:
    """GIVEN the scenarios shipped with firmware_sim,
    WHEN each is loaded by name,
    THEN all validate with their own name and a positive duration, car480 is a 480 s ground
    drive with 100 Hz IMU, 10 Hz GNSS and jumps off, and ship_dov is a ship at 22 N 113 E
    with modulation and deflection of the vertical on."""
    names = builtin_scenarios()
    assert {"car480", "drive_long", "multirotor", "ship_dov", "static"} <= set(names)
    for n in names:
        sc = load_scenario(n)
        assert sc.name == n
        assert sc.duration > 0.0
    car = load_scenario("car480")
    assert isinstance(car.trajectory, GroundSpec)
    assert car.trajectory.sideslip_gain_rad_per_mps2 == 0.0
    assert car.imu.rate_hz == 100.0 and car.gnss.rate_hz == 10.0
    assert car.duration == 480.0
    assert not car.gnss.jumps.enabled
    ship = load_scenario("ship_dov")
    assert isinstance(ship.trajectory, ShipSpec)
    assert (ship.trajectory.lat_deg, ship.trajectory.lon_deg) == (22.0, 113.0)
    assert ship.trajectory.modulation.enabled and ship.dov.enabled


def test_file_and_overrides(tmp_path: Path) -> None:
    """GIVEN a valid scenario file,
    WHEN it is loaded with dotted-key overrides, and again by its path as a string,
    THEN the overrides replace the file's values (an int yaw becomes a float) and the
    scenario records the path as its source."""
    p = _write(tmp_path, GOOD)
    sc = load_scenario(p, overrides={"gnss.jumps.enabled": True, "duration_s": 5.0,
                                     "trajectory.yaw0_deg": 10})
    assert sc.gnss.jumps.enabled
    assert sc.duration_s == 5.0
    assert isinstance(sc.trajectory, GroundSpec) and sc.trajectory.yaw0_deg == 10.0
    assert load_scenario(str(p)).source == str(p)


def test_missing_field_names_field_and_unit(tmp_path: Path) -> None:
    """GIVEN a scenario file without imu.arw_rad_per_sqrt_s,
    WHEN it is loaded,
    THEN ScenarioError says the field is missing, with its dotted name and unit rad/sqrt(s)."""
    p = _write(tmp_path, GOOD.replace("arw_rad_per_sqrt_s = 7e-5\n", ""))
    with pytest.raises(ScenarioError) as e:
        load_scenario(p)
    msg = str(e.value)
    assert "imu.arw_rad_per_sqrt_s" in msg and "missing" in msg and "rad/sqrt(s)" in msg


def test_misspelt_field_is_unknown_with_suggestion(tmp_path: Path) -> None:
    """GIVEN a scenario file with gnss.vel_sigma_h_ms instead of gnss.vel_sigma_h_mps,
    WHEN it is loaded,
    THEN ScenarioError calls it an unknown field and suggests the right name and its unit m/s."""
    p = _write(tmp_path, GOOD.replace("vel_sigma_h_mps", "vel_sigma_h_ms"))
    with pytest.raises(ScenarioError) as e:
        load_scenario(p)
    msg = str(e.value)
    assert "gnss.vel_sigma_h_ms: unknown field" in msg
    assert "gnss.vel_sigma_h_mps" in msg and "m/s" in msg


def test_wrong_type_names_field_and_unit(tmp_path: Path) -> None:
    """GIVEN a scenario with a string IMU rate, a boolean speed target, or a string override
    for a boolean flag,
    WHEN it is loaded,
    THEN ScenarioError names the field and the expected type (with the unit where it has one)."""
    p = _write(tmp_path, GOOD.replace("rate_hz = 100.0", 'rate_hz = "fast"'))
    with pytest.raises(ScenarioError, match=r"imu\.rate_hz: expected a number in Hz"):
        load_scenario(p)
    p = _write(tmp_path, GOOD.replace("to = 10.0", "to = true"))
    with pytest.raises(ScenarioError, match=r"trajectory\.speed\[0\]\.to: expected a number"):
        load_scenario(p)
    with pytest.raises(ScenarioError, match=r"gnss\.jumps\.enabled: expected a boolean"):
        load_scenario(_write(tmp_path, GOOD), overrides={"gnss.jumps.enabled": "yes"})


@pytest.mark.parametrize(("override", "pattern"), [
    ({"imu.rate_hz": 30.0}, r"imu\.rate_hz: 1e6 / rate_hz must be a whole number"),
    ({"gnss.rate_hz": 3.0}, r"gnss\.rate_hz: the GNSS period"),
    ({"gnss.jumps.enabeld": True}, r"gnss\.jumps\.enabeld: unknown field; did you mean "
                                   r"gnss\.jumps\.enabled"),
    ({"trajectory.kind": "boat"}, r"trajectory\.kind: expected one of"),
    ({"duration_s": -1.0}, r"duration_s: must be > 0 s"),
    ({"gnss.jumps.min_mps": 6.0}, r"gnss\.jumps\.min_mps"),
    ({"imu.gyro_bias_sigma_rps": -1.0}, r"imu\.gyro_bias_sigma_rps: must be >= 0"),
    ({"trajectory.speed": [{"t_s": 5.0, "dur_s": 5.0, "to": 3.0},
                           {"t_s": 7.0, "dur_s": 5.0, "to": 1.0}]},
     r"trajectory\.speed\[1\]\.t_s: events must be in time order"),
    ({"trajectory.speed": [{"t_s": 5.0, "dur_s": 5.0}]},
     r"trajectory\.speed\[0\]\.to: missing; expected a number"),
    ({"imu.grade": "tactical"}, r"imu\.grade: expected one of"),
    ({"imu.rate_hz.x": 1}, r"imu\.rate_hz: is not a table"),
])
def test_bad_values(tmp_path: Path, override: dict[str, object], pattern: str) -> None:
    """GIVEN a valid scenario file and one bad override (inexact rate, unknown or misspelt key,
    bad enum, negative or out-of-range value, unordered or incomplete speed events),
    WHEN it is loaded,
    THEN ScenarioError names the offending field and says what is wrong with it."""
    with pytest.raises(ScenarioError, match=pattern):
        load_scenario(_write(tmp_path, GOOD), overrides=override)


def test_unknown_scenario_and_bad_toml(tmp_path: Path) -> None:
    """GIVEN an unknown scenario name, a file with invalid TOML, or a path that does not exist,
    WHEN each is loaded,
    THEN ScenarioError says so (an unknown name lists the built-ins such as car480)."""
    with pytest.raises(ScenarioError, match=r"unknown scenario 'nope'.*car480"):
        load_scenario("nope")
    with pytest.raises(ScenarioError, match="invalid TOML"):
        load_scenario(_write(tmp_path, "name = \n"))
    with pytest.raises(ScenarioError, match="cannot read scenario file"):
        load_scenario(tmp_path / "absent.toml")


def test_grade_preset_fills_missing_keys(tmp_path: Path) -> None:
    """GIVEN a scenario whose IMU gives grade = "nav_seed002" in place of the gyro bias sigma,
    WHEN it is loaded,
    THEN the gyro bias comes from the preset while keys set in the file keep their values."""
    text = GOOD.replace("gyro_bias_sigma_rps = 5.8e-5\n", 'grade = "nav_seed002"\n')
    sc = load_scenario(_write(tmp_path, text))
    assert sc.imu.gyro_bias_sigma_rps == pytest.approx(1.454441043328608e-08)
    assert sc.imu.arw_rad_per_sqrt_s == 7e-5      # explicit keys win over the preset


def test_builtin_name_wins_over_a_folder_of_that_name(tmp_path: Path,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """GIVEN a working directory holding a folder named car480,
    WHEN the scenario "car480" is loaded,
    THEN the built-in scenario is returned."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "car480").mkdir()          # e.g. a previous --out car480
    assert load_scenario("car480").name == "car480"
