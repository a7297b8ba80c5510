"""The estimator's configuration sections, typed and in SI units (keys carry their unit)."""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any

from navd.config.load import ConfigError, build_section
from navd.config.load import unit_field as _f
from navd.units import G0


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
                kw[f.name] = build_section(sec_cls, f.name, data[f.name])
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
