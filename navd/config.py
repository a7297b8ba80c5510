"""Configuration: TOML with a unit in every key name, converted to SI once at load.

``load_config(path, overrides)`` returns the raw tables (so each part of navd reads its own
sections); :class:`EstimatorConfig` is the estimator's typed, SI view.  Overrides are
``section.key=value`` strings whose value is parsed as a TOML literal (bare words are taken
as strings), e.g. ``estimator.mode=traditional`` or ``gnss.lever_arm_m=[0.5, 0, -0.2]``.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

DEG = math.pi / 180.0
G0 = 9.80665


class ConfigError(ValueError):
    """A configuration value is missing, unknown or of the wrong type/unit."""


def parse_override(text: str) -> tuple[list[str], Any]:
    if "=" not in text:
        raise ConfigError(f"override {text!r} is not of the form section.key=value")
    key, raw = text.split("=", 1)
    parts = key.strip().split(".")
    if len(parts) < 2 or not all(parts):
        raise ConfigError(f"override key {key!r} must be section.key")
    try:
        value = tomllib.loads(f"v = {raw.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw.strip()
    return parts, value


def load_config(path: str | Path | None, overrides: list[str] | None = None) -> dict[str, Any]:
    """Read a TOML file (None: built-in defaults only) and apply ``section.key=value``."""
    data: dict[str, Any] = {}
    if path is not None:
        try:
            with open(path, "rb") as fh:
                data = tomllib.load(fh)
        except OSError as exc:
            raise ConfigError(f"cannot read config {path}: {exc}") from exc
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"config {path} is not valid TOML: {exc}") from exc
    return apply_overrides(data, overrides or [])


def apply_overrides(data: dict[str, Any], overrides: list[str]) -> dict[str, Any]:
    """Set each ``section.key=value`` in the TOML tables ``data`` (in place); returns it."""
    for ov in overrides:
        parts, value = parse_override(ov)
        node = data
        for p in parts[:-1]:
            node = node.setdefault(p, {})
            if not isinstance(node, dict):
                raise ConfigError(f"override {ov!r}: {p} is not a table")
        node[parts[-1]] = value
    return data


# unit suffix -> factor to SI
_UNITS: dict[str, float] = {
    "deg": DEG, "rad": 1.0, "m": 1.0, "mps": 1.0, "s": 1.0, "ms": 1e-3, "hz": 1.0,
    "dps": DEG, "mps2": 1.0, "mg": 1e-3 * G0,
    "deg_per_h": DEG / 3600.0,
    "deg_per_sqrt_h": DEG / 60.0,  # deg/sqrt(h) -> rad/sqrt(s)
    "mps_per_sqrt_s": 1.0,
    "mps_per_sqrt_h": 1.0 / 60.0,
    "deg_per_h_per_sqrt_h": DEG / 3600.0 / 60.0,  # (deg/h)/sqrt(h) -> rad/s/sqrt(s)
    "mps2_per_sqrt_s": 1.0,
}


def _convert(section: str, key: str, value: Any, unit: str, kind: type) -> Any:
    where = f"[{section}] {key}"
    if kind is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where} must be true or false, got {value!r}")
        return value
    if kind is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where} must be a string, got {value!r}")
        return value
    if kind is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where} must be an integer, got {value!r}")
        return value
    factor = _UNITS[unit] if unit else 1.0
    if kind is tuple:
        if (not isinstance(value, list) or len(value) != 3
                or not all(isinstance(v, int | float) and not isinstance(v, bool)
                           for v in value)):
            raise ConfigError(f"{where} must be a list of 3 numbers in {unit or 'SI'}")
        if not all(math.isfinite(float(v)) for v in value):
            raise ConfigError(f"{where} must be finite, got {value!r}")
        return tuple(float(v) * factor for v in value)
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ConfigError(f"{where} must be a number in {unit}, got {value!r}")
    if not math.isfinite(float(value)):
        raise ConfigError(f"{where} must be finite, got {value!r}")
    return float(value) * factor


def _section(cls: type, section: str, table: dict[str, Any]) -> Any:
    """Build dataclass ``cls`` from a table whose keys are ``<field>_<unit>`` (or bare)."""
    if not isinstance(table, dict):
        raise ConfigError(f"[{section}] must be a table")
    spec = {f.name: f for f in fields(cls)}
    kwargs: dict[str, Any] = {}
    for key, value in table.items():
        match = None
        for name, f in spec.items():
            unit = f.metadata.get("unit", "")
            full = f"{name}_{unit}" if unit else name
            if key == full:
                match = (name, unit, f.metadata.get("kind", f.type))
                break
        if match is None:
            expected = ", ".join(
                f"{n}_{f.metadata['unit']}" if f.metadata.get("unit") else n
                for n, f in spec.items())
            raise ConfigError(f"[{section}] unknown key {key!r}; expected one of: {expected}")
        name, unit, kind = match
        kind_t: type = {"float": float, "bool": bool, "str": str, "int": int,
                        "tuple": tuple}[str(kind)]
        kwargs[name] = _convert(section, key, value, unit, kind_t)
    return cls(**kwargs)


def _f(default: float, unit: str) -> Any:
    """A float field whose TOML key is ``<name>_<unit>``; the default is given in that unit."""
    si = default * (_UNITS[unit] if unit else 1.0)
    return field(default=si, metadata={"unit": unit, "kind": "float"})


@dataclass(frozen=True)
class FilterSection:
    mode: str = field(default="completed", metadata={"kind": "str"})  # traditional|completed
    robust: str = field(default="gate", metadata={"kind": "str"})  # none|gate|mctls
    profile: str = field(default="ground", metadata={"kind": "str"})  # ground|fixed_wing|multirotor
    cov_interval: float = _f(10.0, "ms")
    coning: bool = field(default=True, metadata={"kind": "bool"})
    gate_prob: float = _f(0.9999, "")
    max_imu_gap: float = _f(100.0, "ms")


@dataclass(frozen=True)
class ImuSection:
    gyro_arw: float = _f(0.24, "deg_per_sqrt_h")
    accel_vrw: float = _f(0.3, "mps_per_sqrt_s")
    gyro_bias_sd: float = _f(12.0, "deg_per_h")
    accel_bias_sd: float = _f(5.0, "mg")
    # known biases (measured = true + bias, body FRD): a calibration's offsets or biases
    # learned on an earlier run; the initial estimate, with gyro/accel_bias_sd its 1-sigma
    gyro_bias: tuple[float, float, float] = field(
        default=(0.0, 0.0, 0.0), metadata={"unit": "deg_per_h", "kind": "tuple"})
    accel_bias: tuple[float, float, float] = field(
        default=(0.0, 0.0, 0.0), metadata={"unit": "mg", "kind": "tuple"})
    gyro_bias_rw: float = _f(0.1, "deg_per_h_per_sqrt_h")
    accel_bias_rw: float = _f(1e-5, "mps2_per_sqrt_s")
    max_accel: float = _f(50.0 * G0, "mps2")
    max_rate: float = _f(2000.0, "dps")


@dataclass(frozen=True)
class InitSection:
    heading_source: str = field(default="gnss_course", metadata={"kind": "str"})
    heading: float = _f(0.0, "deg")
    heading_sd: float = _f(10.0, "deg")
    aligned_sd: float = _f(2.0, "deg")
    tilt_sd: float = _f(2.0, "deg")
    vel_sd: float = _f(0.5, "mps")
    pos_sd: float = _f(10.0, "m")
    level_time: float = _f(1.0, "s")
    level_max_accel: float = _f(0.3, "mps2")
    static_rate_tol: float = _f(3.0, "dps")


@dataclass(frozen=True)
class GnssSection:
    lever_arm: tuple[float, float, float] = field(
        default=(0.0, 0.0, 0.0), metadata={"unit": "m", "kind": "tuple"})
    min_pos_sd: float = _f(0.3, "m")
    min_vel_sd: float = _f(0.03, "mps")
    max_age: float = _f(500.0, "ms")
    # fixes stamped this long after their time of validity (a receiver or autopilot that
    # stamps on arrival); PX4's EKF2_GPS_DELAY, ArduPilot's GPS_DELAY_MS
    delay: float = _f(0.0, "ms")
    use_position: bool = field(default=True, metadata={"kind": "bool"})
    use_velocity: bool = field(default=True, metadata={"kind": "bool"})


@dataclass(frozen=True)
class HeadingSection:
    min_speed: float = _f(3.0, "mps")
    max_yaw_rate: float = _f(20.0, "dps")
    max_lat_accel: float = _f(4.0, "mps2")
    sideslip_sd: float = _f(0.3, "deg")
    crab_sd: float = _f(0.0, "deg")  # fixed-wing allowance; 0 disables the update there
    reset_after: int = field(default=10, metadata={"kind": "int"})
    align_speed: float = _f(5.0, "mps")
    max_reverse_speed: float = _f(4.0, "mps")
    # at rest with a gyro too poor to gyrocompass, position/velocity fixes must not move the
    # heading (Estimator._heading_hold says why)
    hold_static: bool = field(default=True, metadata={"kind": "bool"})
    hold_max_speed: float = _f(0.3, "mps")


@dataclass(frozen=True)
class MctlsSection:
    window: int = field(default=20, metadata={"kind": "int"})
    order: int = field(default=2, metadata={"kind": "int"})
    min_weight: float = _f(0.2, "")


@dataclass(frozen=True)
class EstimatorConfig:
    """The estimator's configuration in SI units."""

    filter: FilterSection = field(default_factory=FilterSection)
    imu: ImuSection = field(default_factory=ImuSection)
    init: InitSection = field(default_factory=InitSection)
    gnss: GnssSection = field(default_factory=GnssSection)
    heading: HeadingSection = field(default_factory=HeadingSection)
    mctls: MctlsSection = field(default_factory=MctlsSection)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> EstimatorConfig:
        kw: dict[str, Any] = {}
        for f in fields(cls):
            if f.name in data:
                sec_cls = type(getattr(cls(), f.name))
                kw[f.name] = _section(sec_cls, f.name, data[f.name])
        cfg = cls(**kw)
        cfg.validate()
        return cfg

    def validate(self) -> None:
        choices = {
            "[filter] mode": (self.filter.mode, ("traditional", "completed")),
            "[filter] robust": (self.filter.robust, ("none", "gate", "mctls")),
            "[filter] profile": (self.filter.profile, ("ground", "fixed_wing", "multirotor")),
            "[init] heading_source": (self.init.heading_source,
                                      ("config", "gnss_course", "none")),
        }
        for where, (val, allowed) in choices.items():
            if val not in allowed:
                raise ConfigError(f"{where} = {val!r}; expected one of {allowed}")
        if not 0.5 < self.filter.gate_prob < 1.0:
            raise ConfigError("[filter] gate_prob must be in (0.5, 1)")
        if self.filter.cov_interval <= 0.0:
            raise ConfigError("[filter] cov_interval_ms must be > 0")
        if self.mctls.window < 6 or not 0 <= self.mctls.order <= 3:
            raise ConfigError("[mctls] window_ >= 6 and 0 <= order <= 3 required")
