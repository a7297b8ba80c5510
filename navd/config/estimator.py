"""The estimator's configuration sections, typed and in SI units (keys carry their unit).

Plain dataclasses (core may import them); built by :func:`navd.config.load.build_section`.
"""

from __future__ import annotations

import typing
from dataclasses import dataclass, field, fields
from typing import Any

from navd.config.load import build_section, check
from navd.config.load import setting as _f
from navd.units import G0


@dataclass(frozen=True)
class FilterSection:
    mode: str = _f("completed", choices=("traditional", "completed"))
    robust: str = _f("gate", choices=("none", "gate", "mctls"))
    profile: str = _f("ground", choices=("ground", "fixed_wing", "multirotor"))
    cov_interval: float = _f(10.0, "ms")
    coning: bool = _f(True)
    gate_prob: float = _f(0.9999)
    # the estimator's IMU gap (s): an IMU sample whose interval (dt) is longer than this is
    # refused and counted (imu_bad_dt); a time jump longer than this between two samples
    # is counted as imu_gap, and beyond 1 s navigation re-initialises
    max_imu_gap: float = _f(100.0, "ms")
    # GNSS position (velocity) updates all refused by the gate for longer than this: the
    # state, not the receiver, is wrong; reset it to GNSS (0 = never)
    max_lockout: float = _f(5.0, "s")

    def validate(self) -> None:
        check(0.5 < self.gate_prob < 1.0, "filter", "gate_prob", "in (0.5, 1)")
        check(self.max_lockout >= 0.0, "filter", "max_lockout_s", ">= 0 (0 = never reset)")
        check(self.cov_interval > 0.0, "filter", "cov_interval_ms", "> 0")


@dataclass(frozen=True)
class ImuSection:
    gyro_arw: float = _f(0.24, "deg_per_sqrt_h")
    accel_vrw: float = _f(0.3, "mps_per_sqrt_s")
    gyro_bias_sd: float = _f(12.0, "deg_per_h")
    accel_bias_sd: float = _f(5.0, "mg")
    # known biases (measured = true + bias, body FRD): a calibration's offsets or biases
    # learned on an earlier run; the initial estimate, with gyro/accel_bias_sd its 1-sigma
    gyro_bias: tuple[float, float, float] = _f((0.0, 0.0, 0.0), "deg_per_h")
    accel_bias: tuple[float, float, float] = _f((0.0, 0.0, 0.0), "mg")
    gyro_bias_rw: float = _f(0.1, "deg_per_h_per_sqrt_h")
    accel_bias_rw: float = _f(1e-5, "mps2_per_sqrt_s")
    max_accel: float = _f(50.0 * G0, "mps2")
    max_rate: float = _f(2000.0, "dps")
    # at rest (IMU still over 5 s, Allan-type test), measure the gyro offset and feed it to
    # the gyro-bias state, as autopilots calibrate at boot (navd/core/aiding/gyro_rest.py)
    rest_calibration: bool = _f(True)


@dataclass(frozen=True)
class InitSection:
    heading_source: str = _f("gnss_course", choices=("config", "gnss_course", "none"))
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
    lever_arm: tuple[float, float, float] = _f((0.0, 0.0, 0.0), "m")
    min_pos_sd: float = _f(0.3, "m")
    min_vel_sd: float = _f(0.03, "mps")
    max_age: float = _f(500.0, "ms")
    # fixes stamped this long after their time of validity (a receiver or autopilot that
    # stamps on arrival); PX4's EKF2_GPS_DELAY, ArduPilot's GPS_DELAY_MS
    delay: float = _f(0.0, "ms")
    use_position: bool = _f(True)
    use_velocity: bool = _f(True)


@dataclass(frozen=True)
class HeadingSection:
    min_speed: float = _f(3.0, "mps")
    max_yaw_rate: float = _f(20.0, "dps")
    max_lat_accel: float = _f(4.0, "mps2")
    sideslip_sd: float = _f(0.3, "deg")
    crab_sd: float = _f(0.0, "deg")  # fixed-wing allowance; 0 disables the update there
    reset_after: int = _f(10)
    align_speed: float = _f(5.0, "mps")
    max_reverse_speed: float = _f(4.0, "mps")
    # at rest with a gyro too poor to gyrocompass, position/velocity fixes must not move the
    # heading (GnssAiding._heading_hold in navd/core/aiding/gnss.py says why)
    hold_static: bool = _f(True)
    hold_max_speed: float = _f(0.3, "mps")


@dataclass(frozen=True)
class MctlsSection:
    window: int = _f(20)
    order: int = _f(2)
    min_weight: float = _f(0.2)

    def validate(self) -> None:
        check(self.window >= 6 and 0 <= self.order <= 3, "mctls", "window/order",
              "window >= 6 and 0 <= order <= 3")


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
        hints = typing.get_type_hints(cls)
        kw: dict[str, Any] = {f.name: build_section(hints[f.name], f.name, data[f.name])
                              for f in fields(cls) if f.name in data}
        return cls(**kw)
