"""Config: every estimator key is documented, units convert, errors name key and unit."""

from __future__ import annotations

import math
import re
import tomllib
from dataclasses import fields
from pathlib import Path

import pytest

from navd.config import ConfigError, EstimatorConfig, load_config

ROOT = Path(__file__).resolve().parents[1]


def _keys(cfg: EstimatorConfig) -> set[str]:
    out = set()
    for sec in fields(cfg):
        for f in fields(getattr(cfg, sec.name)):
            unit = f.metadata.get("unit", "")
            out.add(f"{sec.name}.{f.name}_{unit}" if unit else f"{sec.name}.{f.name}")
    return out


def test_every_key_documented_and_file_matches_defaults() -> None:
    """GIVEN the shipped config/navd.toml,
    WHEN its keys are compared with every estimator config field (with its unit suffix) and the
    file is loaded,
    THEN every field is documented there and the file reproduces the built-in defaults."""
    text = (ROOT / "config" / "navd.toml").read_text()
    doc = tomllib.loads(text)
    documented = {f"{s}.{k}" for s, t in doc.items() if isinstance(t, dict) for k in t}
    # the [imu] grade's figures are documented as commented-out keys (written, they would
    # override the grade)
    documented |= {f"imu.{k}" for k in re.findall(r"^# (\w+) = ", text, re.M)}
    assert _keys(EstimatorConfig()) <= documented
    # the shipped file reproduces the built-in defaults
    assert EstimatorConfig.from_dict(doc) == EstimatorConfig()


def test_units_are_converted_to_si() -> None:
    """GIVEN overrides in deg/sqrt(h), mg, deg/s and ms,
    WHEN the estimator config is built,
    THEN the values are held in SI: rad/sqrt(s), m/s^2, rad/s and s."""
    c = EstimatorConfig.from_dict(load_config(None, [
        "imu.gyro_arw_deg_per_sqrt_h=0.24", "imu.accel_bias_sd_mg=5",
        "heading.max_yaw_rate_dps=20", "filter.cov_interval_ms=10"]))
    assert c.imu.gyro_arw == pytest.approx(0.24 * math.pi / 180 / 60)
    assert c.imu.accel_bias_sd == pytest.approx(5e-3 * 9.80665)
    assert c.heading.max_yaw_rate == pytest.approx(math.radians(20))
    assert c.filter.cov_interval == pytest.approx(0.01)


@pytest.mark.parametrize("override, needle", [
    ("imu.gyro_arw=1", "gyro_arw_deg_per_sqrt_h"),
    ("filter.mode=magic", "[filter] mode"),
    ("gnss.lever_arm_m=[1, 2]", "list of 3 numbers in m"),
    ("imu.accel_bias_sd_mg=\"x\"", "number in mg"),
    ("gnss.lever_arm_sd_m=-0.1", "[gnss] lever_arm_sd_m must be >= 0 (m)"),
    ("imu.gyro_scale_sd_pct=-1", "[imu] gyro_scale_sd_pct must be in [0, 50) (%)"),
    ("imu.gyro_scale_sd_pct=60", "[imu] gyro_scale_sd_pct must be in [0, 50) (%)"),
])
def test_bad_values_name_key_and_unit(override: str, needle: str) -> None:
    """GIVEN a key without its unit suffix, an unknown filter mode, a 2-element lever arm, a
    string where mg are expected, a negative lever-arm allowance, or a gyro scale-factor
    sigma below 0 % or of 50 % and more,
    WHEN the estimator config is built,
    THEN a ConfigError names the key with its unit, or the expected value and its unit."""
    with pytest.raises(ConfigError) as exc:
        EstimatorConfig.from_dict(load_config(None, [override]))
    assert needle in str(exc.value)


def test_every_shipped_key_loads_through_the_one_builder() -> None:
    """GIVEN config/navd.toml as shipped,
    WHEN each section is built by build_section and the whole file by DaemonConfig,
    THEN its sections are exactly the known dataclasses, every key written there is one of its
    TOML keys (``<name>_<unit>`` or bare ``<name>``), and every value type-checks and validates."""
    from navd.config import DovSection, PolarizationSection, build_section, toml_keys
    from navd.config.daemon import _SECTIONS, DaemonConfig

    doc = tomllib.loads((ROOT / "config" / "navd.toml").read_text())
    est = {f.name: type(getattr(EstimatorConfig(), f.name)) for f in fields(EstimatorConfig)}
    sections = {**est, **_SECTIONS, "polarization": PolarizationSection, "dov": DovSection}
    assert set(doc) == set(sections)
    for name, table in doc.items():
        cls = sections[name]
        assert set(table) <= set(toml_keys(cls)), name
        build_section(cls, name, table)  # every value type-checks and validates
    DaemonConfig.from_dict(doc)


@pytest.mark.parametrize("override", ["daemon.status_period=1", "filter.max_imu_gap=0.1",
                                      "mavlink.max_imu_gap=0.1", "dov.grdi=x"])
def test_unknown_keys_give_one_style_of_error(override: str) -> None:
    """GIVEN an unknown key in [daemon], [filter], [mavlink] or [dov] (for the first three the
    attribute name instead of the key),
    WHEN the daemon config is built,
    THEN each is refused alike: "[section] unknown key 'key'; expected one of: " and the valid
    keys with their units."""
    from navd.config.daemon import DaemonConfig

    section, key = override.split("=")[0].split(".")
    with pytest.raises(ConfigError) as exc:
        DaemonConfig.from_dict(load_config(None, [override]))
    msg = str(exc.value)
    assert msg.startswith(f"[{section}] unknown key {key!r}; expected one of: "), msg
    if section != "dov":
        assert "max_imu_gap_ms" in msg or "status_period_s" in msg, msg


@pytest.mark.parametrize("grade", ["consumer", "industrial", "tactical"])
def test_imu_grade_sets_its_figures_and_written_keys_override_them(grade: str) -> None:
    """GIVEN [imu] grade = <grade> alone, and the same with gyro_bias_sd_deg_per_h = 7,
    THEN the seven noise/bias/scale figures are the grade's (in SI), except the written key, which
    wins; the shipped file's commented figures are the grades' own."""
    from navd.config.estimator import IMU_GRADES

    preset = IMU_GRADES[grade]
    c = EstimatorConfig.from_dict(load_config(None, [f"imu.grade={grade}"])).imu
    assert c.grade == grade
    assert c.gyro_arw == pytest.approx(preset["gyro_arw_deg_per_sqrt_h"] * math.pi / 180 / 60)
    assert c.accel_vrw == pytest.approx(preset["accel_vrw_mps_per_sqrt_s"])
    assert c.gyro_bias_sd == pytest.approx(preset["gyro_bias_sd_deg_per_h"] * math.pi / 180
                                           / 3600)
    assert c.accel_bias_sd == pytest.approx(preset["accel_bias_sd_mg"] * 9.80665e-3)
    assert c.gyro_bias_rw == pytest.approx(
        preset["gyro_bias_rw_deg_per_h_per_sqrt_h"] * math.pi / 180 / 3600 / 60)
    assert c.accel_bias_rw == pytest.approx(preset["accel_bias_rw_mps2_per_sqrt_s"])
    assert c.gyro_scale_sd == pytest.approx(preset["gyro_scale_sd_pct"] / 100.0)
    o = EstimatorConfig.from_dict(load_config(None, [
        f"imu.grade={grade}", "imu.gyro_bias_sd_deg_per_h=7"])).imu
    assert o.gyro_bias_sd == pytest.approx(7 * math.pi / 180 / 3600)
    assert o.gyro_arw == c.gyro_arw
    text = (ROOT / "config" / "navd.toml").read_text()
    for key, value in preset.items():
        line = re.search(rf"^# {key} = .*$", text, re.M)
        assert line is not None, key
        k = list(IMU_GRADES).index(grade)
        listed = line.group(0).split(":")[-1].split("/")[k]
        assert float(listed.split("(")[0]) == pytest.approx(value), key


def test_unknown_imu_grade_is_refused_with_the_choices() -> None:
    with pytest.raises(ConfigError, match=r"grade.*consumer"):
        EstimatorConfig.from_dict(load_config(None, ["imu.grade=automotive"]))
