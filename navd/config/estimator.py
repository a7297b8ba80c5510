"""The estimator's configuration sections, typed and in SI units (keys carry their unit).

Plain dataclasses (core may import them); built by :func:`navd.config.load.build_section`.
"""

from __future__ import annotations

import math
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
    profile: str = _f("ground", choices=("ground", "boat", "fixed_wing", "multirotor"))
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
    # scale the IMU white noise (ARW, VRW) online when the GNSS velocity innovations say it
    # is understated (the gyro's also when the course innovations persist), up to
    # max_q_scale times its variance (navd/core/aiding/adaptive_noise.py).  100: 10x the
    # density, 5 deg/sqrt(h) for the consumer grade, what a loose mount's aliased vibration
    # integrates to (3-6 deg/sqrt(h) Allan-equivalent, docs/results.md "Aliased vibration as
    # gyro noise"); 25 left a car with 10 deg/s of it 5 % beyond 3 sigma in pitch
    adaptive_noise: bool = _f(True)
    max_q_scale: float = _f(100.0)
    # measure the IMU's white noise from its own samples (second differences, motion refused
    # by a whiteness check) and never propagate with less than that, up to max_q_scale
    # (navd/core/aiding/imu_noise.py)
    measure_imu_noise: bool = _f(True)
    # ... and the gyro-bias random walk when the innovations persist from epoch to epoch (a
    # bias that drifts faster than configured: a warming MEMS gyro), up to this many times
    # its variance (1e6: 1000x the density, 5000 deg/h/sqrt(h) for the consumer grade)
    max_bias_q_scale: float = _f(1e6)

    def validate(self) -> None:
        check(0.5 < self.gate_prob < 1.0, "filter", "gate_prob", "in (0.5, 1)")
        check(self.max_lockout >= 0.0, "filter", "max_lockout_s", ">= 0 (0 = never reset)")
        check(self.cov_interval > 0.0, "filter", "cov_interval_ms", "> 0")
        check(self.max_q_scale >= 1.0, "filter", "max_q_scale", ">= 1")
        check(self.max_bias_q_scale >= 1.0, "filter", "max_bias_q_scale", ">= 1")


# [imu] grade presets, in the units of their TOML keys (as a user writes them).  A user who
# does not know the IMU's Allan variance picks a grade; any of these keys written in [imu]
# overrides the preset's value.  Figures (1-sigma / densities):
#  consumer    uncalibrated MEMS as autopilots and phones carry them (MPU-6000, ICM-426xx,
#              BMI088): turn-on gyro offsets of 0.3-1 deg/s and accelerometer offsets of
#              20-50 mg must lie inside the prior (0.5 deg/s, 30 mg: 1-2 sigma); datasheet
#              ARW 0.2-0.8 deg/sqrt(h); VRW raised to 0.3 m/s/sqrt(s) for vehicle vibration;
#              bias drifts with temperature (random walks 5 deg/h/sqrt(h), 3e-3 m/s^2/sqrt(s):
#              an accelerometer offset's ~0.2 mg/K over the 10-20 K a board warms in its first
#              minutes is 2-6 mg in 5-10 min, ~3e-3 as a walk; docs/results.md, "Gyro scale
#              factor" for what it changed);
#              gyro sensitivity never calibrated (autopilots calibrate offsets only):
#              datasheet tolerances +-0.5 to +-3 %, 1 % as 1-sigma
#  industrial  calibrated MEMS modules: seed 001's figures (12 deg/h, 5 mg, 0.24 deg/sqrt(h),
#              0.3 m/s/sqrt(s) as printed), navd's defaults before the presets existed;
#              gyro scale factor 0.1 % (a calibrated module's +-0.3 %)
#  tactical    high-end MEMS / FOG (STIM300-, KVH-class): 3 deg/h, 1 mg, 0.15 deg/sqrt(h),
#              0.02 m/s/sqrt(s) (vibration allowance over the datasheet's ~0.001); gyro
#              scale factor 0.02 % (200 ppm)
IMU_GRADES: dict[str, dict[str, float]] = {
    "consumer": {
        "gyro_arw_deg_per_sqrt_h": 0.5, "accel_vrw_mps_per_sqrt_s": 0.3,
        "gyro_bias_sd_deg_per_h": 1800.0, "accel_bias_sd_mg": 30.0,
        "gyro_bias_rw_deg_per_h_per_sqrt_h": 5.0, "accel_bias_rw_mps2_per_sqrt_s": 3e-3,
        "gyro_scale_sd_pct": 1.0,
    },
    "industrial": {
        "gyro_arw_deg_per_sqrt_h": 0.24, "accel_vrw_mps_per_sqrt_s": 0.3,
        "gyro_bias_sd_deg_per_h": 12.0, "accel_bias_sd_mg": 5.0,
        "gyro_bias_rw_deg_per_h_per_sqrt_h": 0.1, "accel_bias_rw_mps2_per_sqrt_s": 1e-5,
        "gyro_scale_sd_pct": 0.1,
    },
    "tactical": {
        "gyro_arw_deg_per_sqrt_h": 0.15, "accel_vrw_mps_per_sqrt_s": 0.02,
        "gyro_bias_sd_deg_per_h": 3.0, "accel_bias_sd_mg": 1.0,
        "gyro_bias_rw_deg_per_h_per_sqrt_h": 0.01, "accel_bias_rw_mps2_per_sqrt_s": 1e-6,
        "gyro_scale_sd_pct": 0.02,
    },
}
DEFAULT_IMU_GRADE = "consumer"
_GR = IMU_GRADES[DEFAULT_IMU_GRADE]
# [gnss] lever_arm_sd_m default (m): an antenna nobody measured sits within ~0.3 m of the
# IMU on a drone and 1-2 m on a car.  0.5 m: a car480 with its antenna 1.6 m off and left
# unconfigured goes from 6.0 to 3.4 % of heading instants beyond 3 sigma; with no lever arm
# it changes no simulated figure by more than 0.02 deg (docs/results.md, "The antenna's
# lever arm").
LEVER_ARM_SD_M = 0.5
# [gnss] delay_sd_ms default (ms): off.  At 100 ms it halves the velocity NEES of the
# simulated 200 ms receiver lag but costs the clean car 10 % of its heading accuracy, and
# on the exactly stamped simulated car it raises the gyro-bias walk scale (to 8) and keeps
# the learnt biases from being stored (docs/results.md, "A receiver's latency as noise");
# a user who stamps fixes on arrival sets it.
DELAY_SD_MS = 0.0


def imu_table_with_grade(table: Any) -> Any:
    """The ``[imu]`` table with the keys it does not write filled from its ``grade`` (or the
    default grade); anything that is not a table, or an unknown grade, is returned as it is
    for :func:`build_section` to refuse with its usual message."""
    if not isinstance(table, dict):
        return table
    preset = IMU_GRADES.get(table.get("grade", DEFAULT_IMU_GRADE))
    if preset is None:
        return table
    return {**preset, **table}


@dataclass(frozen=True)
class ImuSection:
    # preset for the seven noise/bias/scale figures below (IMU_GRADES); explicit keys override it.
    # The field defaults are the default grade's.
    grade: str = _f(DEFAULT_IMU_GRADE, choices=tuple(IMU_GRADES))
    gyro_arw: float = _f(_GR["gyro_arw_deg_per_sqrt_h"], "deg_per_sqrt_h")
    accel_vrw: float = _f(_GR["accel_vrw_mps_per_sqrt_s"], "mps_per_sqrt_s")
    gyro_bias_sd: float = _f(_GR["gyro_bias_sd_deg_per_h"], "deg_per_h")
    accel_bias_sd: float = _f(_GR["accel_bias_sd_mg"], "mg")
    # known biases (measured = true + bias, body FRD, i.e. after the mount): a calibration's
    # offsets or biases learned on an earlier run; the initial estimate, with
    # gyro/accel_bias_sd its 1-sigma
    gyro_bias: tuple[float, float, float] = _f((0.0, 0.0, 0.0), "deg_per_h")
    accel_bias: tuple[float, float, float] = _f((0.0, 0.0, 0.0), "mg")
    gyro_bias_rw: float = _f(_GR["gyro_bias_rw_deg_per_h_per_sqrt_h"], "deg_per_h_per_sqrt_h")
    accel_bias_rw: float = _f(_GR["accel_bias_rw_mps2_per_sqrt_s"], "mps2_per_sqrt_s")
    # 1-sigma of each gyro axis's scale-factor error (fraction; 0: none): every rotation
    # makes that share of itself into attitude error, added to P as the net rotation grows
    # (navd/core/kalman.py, gyro_scale_allowance)
    gyro_scale_sd: float = _f(_GR["gyro_scale_sd_pct"], "pct")
    # the IMU's axes on the vehicle, sensor -> body C_s^b as ZYX roll/pitch/yaw (as
    # [polarization]): the IMU's attitude on the vehicle (yaw 90: its x points to the
    # vehicle's right).  Increments are turned into the body axes where they enter the
    # estimator, so everything after (attitude, biases, lever arm, the bias store) is the
    # vehicle's.
    mount_roll: float = _f(0.0, "deg")
    mount_pitch: float = _f(0.0, "deg")
    mount_yaw: float = _f(0.0, "deg")
    # 1-sigma of mount_yaw as installed (stated or left 0): where the course is the
    # heading it is the vehicle's, and no motion tells an IMU a few degrees off it, so
    # the reported yaw sigma carries this (docs/design.md §4, "The installation's share")
    mount_yaw_sd: float = _f(1.0, "deg")
    max_accel: float = _f(50.0 * G0, "mps2")
    max_rate: float = _f(2000.0, "dps")
    # at rest (IMU still over 10 s, Allan-type test), measure the gyro offset and feed it to
    # the gyro-bias state, as autopilots calibrate at boot (navd/core/aiding/gyro_rest.py)
    rest_calibration: bool = _f(True)

    def validate(self) -> None:
        check(0.0 <= self.gyro_scale_sd < 0.5, "imu", "gyro_scale_sd_pct", "in [0, 50) (%)")
        for key in ("mount_roll", "mount_pitch", "mount_yaw"):
            check(abs(getattr(self, key)) <= math.pi + 1e-9, "imu", f"{key}_deg",
                  "in [-180, 180] (deg)")
        check(0.0 <= self.mount_yaw_sd <= math.radians(30.0) + 1e-12, "imu",
              "mount_yaw_sd_deg", "in [0, 30] (deg)")

    @property
    def mount(self) -> tuple[float, float, float]:
        """(roll, pitch, yaw) of the IMU's mounting, rad."""
        return (self.mount_roll, self.mount_pitch, self.mount_yaw)


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
    # ... and longer, up to this, while the window is unaccelerated and the mean specific
    # force's own scatter still allows a tilt sigma above tilt_sd (a noisy IMU)
    level_max_time: float = _f(10.0, "s")
    level_max_accel: float = _f(0.3, "mps2")
    static_rate_tol: float = _f(3.0, "dps")

    def validate(self) -> None:
        check(self.level_max_time >= self.level_time, "init", "level_max_time_s",
              ">= level_time_s")


@dataclass(frozen=True)
class GnssSection:
    lever_arm: tuple[float, float, float] = _f((0.0, 0.0, 0.0), "m")
    # 1-sigma per axis of what lever_arm may be off by (a user who never measured it: the
    # default of zero with an antenna somewhere on the vehicle).  Its velocity C (w x dl)
    # goes into the GNSS velocity and course noise while the vehicle turns.
    lever_arm_sd: float = _f(LEVER_ARM_SD_M, "m")
    min_pos_sd: float = _f(0.3, "m")
    min_vel_sd: float = _f(0.03, "mps")
    max_age: float = _f(500.0, "ms")
    # fixes stamped this long after their time of validity (a receiver or autopilot that
    # stamps on arrival); PX4's EKF2_GPS_DELAY, ArduPilot's GPS_DELAY_MS
    delay: float = _f(0.0, "ms")
    # 1-sigma by which delay may be off (a receiver's latency nobody measured: 0.1-0.3 s
    # for a fix stamped on arrival).  Its errors, v dt in position and a dt in velocity,
    # go into the GNSS noise while the vehicle moves, accelerates or turns.
    delay_sd: float = _f(DELAY_SD_MS, "ms")
    use_position: bool = _f(True)
    use_velocity: bool = _f(True)

    def validate(self) -> None:
        check(self.lever_arm_sd >= 0.0, "gnss", "lever_arm_sd_m", ">= 0 (m)")
        check(self.delay_sd >= 0.0, "gnss", "delay_sd_ms", ">= 0 (ms)")


@dataclass(frozen=True)
class HeadingSection:
    min_speed: float = _f(1.5, "mps")
    max_yaw_rate: float = _f(20.0, "dps")
    max_lat_accel: float = _f(4.0, "mps2")
    sideslip_sd: float = _f(0.3, "deg")
    crab_sd: float = _f(0.0, "deg")  # fixed-wing allowance; 0 disables the update there
    # boat profile: prior 1-sigma per axis of the water current, learnt from the course as
    # the boat turns (navd/core/aiding/course_learner.py); 0: heading = course over ground
    current_sd: float = _f(1.0, "mps")
    reset_after: int = _f(10)
    align_speed: float = _f(5.0, "mps")
    max_reverse_speed: float = _f(4.0, "mps")
    # backwards motion (course > 90 deg from the aligned yaw) for longer than this is a
    # wrong yaw, not reversing: the yaw is set to the course again (heading_alignment.py),
    # unless the IMU's accelerations confirmed the yaw (travel_direction.py); below
    # max_reverse_speed a car's forward course checks flag the heading after this long
    # without that confirmation
    max_reverse: float = _f(30.0, "s")
    # at rest with a gyro too poor to gyrocompass, position/velocity fixes must not move the
    # heading (GnssAiding._heading_hold in navd/core/aiding/gnss.py says why)
    hold_static: bool = _f(True)
    hold_max_speed: float = _f(0.3, "mps")
    # a slip of the course's own (loose ground, skid steering), correlated over seconds:
    # the course rows' variance scaled by the course against the gyro alone
    # (navd/core/aiding/course_noise.py); ground profile
    adapt_course_noise: bool = _f(True)

    def validate(self) -> None:
        check(self.current_sd >= 0.0, "heading", "current_sd_mps", ">= 0 (m/s)")


@dataclass(frozen=True)
class MctlsSection:
    window: int = _f(20)
    order: int = _f(2)
    min_weight: float = _f(0.2)

    def validate(self) -> None:
        check(self.window >= 6 and 0 <= self.order <= 3, "mctls", "window/order",
              "window >= 6 and 0 <= order <= 3")


@dataclass(frozen=True)
class YawBankSection:
    """Heading from motion (navd/core/aiding/yaw_bank.py, docs/design.md §4.1)."""

    # "auto": on for the multirotor and fixed_wing profiles (navd/core/aiding/yaw_bank.py,
    # bank_enabled)
    enabled: str = _f("auto", choices=("auto", "on", "off"))
    members: int = _f(8)
    # unmodelled horizontal specific force per member (tilt error x g, vibration, m/s^2)
    accel_noise: float = _f(0.1, "mps2")
    # yaw offset random walk: covers the main filter's own yaw drift between GNSS epochs
    yaw_noise: float = _f(0.3, "deg_per_sqrt_s")
    # gyro scale-factor uncertainty: yaw variance grows by (this)^2 per radian turned
    gyro_scale_sd: float = _f(1.0, "pct")
    # the main filter's yaw drift (its unestimated gyro bias about down), learned by every
    # hypothesis: prior 1-sigma and random walk
    rate_sd: float = _f(0.1, "dps")
    rate_noise: float = _f(0.01, "dps_per_sqrt_s")
    # what the main filter's tilt and accelerometer-bias errors leave in the horizontal
    # specific force, per hypothesis: prior 1-sigma and random walk
    accel_bias_sd: float = _f(0.5, "mps2")
    accel_bias_noise: float = _f(0.02, "mps2_per_sqrt_s")
    # weights change (and the bank can become trusted) only while the low-passed horizontal
    # specific force is at least this: without it yaw is unobservable
    min_accel: float = _f(0.5, "mps2")
    excitation_tau: float = _f(0.5, "s")
    # the bank is trusted once its composite sigma stayed below trust_sd and its estimate
    # within agree of itself for agree_time
    trust_sd: float = _f(10.0, "deg")
    # a trial may start once the composite sigma is below trial_sd (>= trust_sd): the main
    # filter then sees the rest of the same acceleration with the bank's yaw; it still ends
    # aligned only with a trusted bank
    trial_sd: float = _f(15.0, "deg")
    agree: float = _f(5.0, "deg")
    agree_time: float = _f(3.0, "s")
    # trial: the main heading is set from the bank and kept only if the velocity NIS of the
    # next trial_epochs excited GNSS epochs is consistent (chi-square at filter.gate_prob)
    trial_epochs: int = _f(5)
    trial_timeout: float = _f(30.0, "s")
    # the main filter's heading sigma at alignment is at least this
    aligned_sd: float = _f(4.0, "deg")
    # once aligned by the bank, the heading stays called aligned only while its sigma is at
    # most this (or the sigma it was aligned with, if larger): a fixed wing's heading sigma
    # grows on straight legs between the turns that observe it
    max_aligned_sd: float = _f(6.0, "deg")
    # per-epoch NIS cap in the weight update (an outlier epoch costs no member more than
    # this) and the floor of a member's log weight below the best (nats): no hypothesis is
    # ever lost for good
    # while unaligned, GNSS updates leave the main yaw alone (Schmidt consider state)
    hold_unaligned: bool = _f(True)
    nis_cap: float = _f(16.0)
    weight_floor: float = _f(20.0)

    def validate(self) -> None:
        check(2 <= self.members <= 16, "yaw_bank", "members", "2..16")
        check(self.trust_sd > 0.0 and self.agree > 0.0, "yaw_bank", "trust_sd_deg/agree_deg",
              "> 0")
        check(self.trial_epochs >= 1, "yaw_bank", "trial_epochs", ">= 1")
        check(self.trial_sd >= self.trust_sd, "yaw_bank", "trial_sd_deg", ">= trust_sd_deg")
        check(self.excitation_tau > 0.0, "yaw_bank", "excitation_tau_s", "> 0")


@dataclass(frozen=True)
class EstimatorConfig:
    """The estimator's configuration in SI units."""

    filter: FilterSection = field(default_factory=FilterSection)
    imu: ImuSection = field(default_factory=ImuSection)
    init: InitSection = field(default_factory=InitSection)
    gnss: GnssSection = field(default_factory=GnssSection)
    heading: HeadingSection = field(default_factory=HeadingSection)
    mctls: MctlsSection = field(default_factory=MctlsSection)
    yaw_bank: YawBankSection = field(default_factory=YawBankSection)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> EstimatorConfig:
        hints = typing.get_type_hints(cls)
        data = {**data, "imu": imu_table_with_grade(data.get("imu", {}))}
        kw: dict[str, Any] = {f.name: build_section(hints[f.name], f.name, data[f.name])
                              for f in fields(cls) if f.name in data}
        return cls(**kw)
