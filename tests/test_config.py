"""Config: every estimator key is documented, units convert, errors name key and unit."""

from __future__ import annotations

import math
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
    doc = tomllib.loads((ROOT / "config" / "navd.toml").read_text())
    documented = {f"{s}.{k}" for s, t in doc.items() if isinstance(t, dict) for k in t}
    assert _keys(EstimatorConfig()) <= documented
    # the shipped file reproduces the built-in defaults
    assert EstimatorConfig.from_dict(doc) == EstimatorConfig()


def test_units_are_converted_to_si() -> None:
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
])
def test_bad_values_name_key_and_unit(override: str, needle: str) -> None:
    with pytest.raises(ConfigError) as exc:
        EstimatorConfig.from_dict(load_config(None, [override]))
    assert needle in str(exc.value)
