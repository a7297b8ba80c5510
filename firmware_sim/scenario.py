"""Scenario files: TOML -> validated, typed, SI :class:`Scenario`.

Every value carries its unit in its key (``rate_hz``, ``arw_rad_per_sqrt_s``, ``turns[].dyaw_deg``);
sensor-model keys are SI, geometry keys may be degrees where the key says so.  The loader
rejects missing, mistyped and unknown keys with a :class:`ScenarioError` that names the
field and the unit it expects, so a typo never silently falls back to a default.

Overrides use dotted paths (``"gnss.jumps.enabled"``, ``"imu.rate_hz"``) and are applied to
the raw TOML tree before validation, so they are checked exactly like file content.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import tomllib
import types
import typing
from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from navd.config.load import ConfigError, set_override
from navd.units import DEG

__all__ = [
    "DovSpec",
    "DropoutSpec",
    "FixedWingSpec",
    "GnssSpec",
    "GroundSpec",
    "ImuSpec",
    "JumpSpec",
    "ModulationSpec",
    "MultirotorSpec",
    "PolarizationSpec",
    "PosStepSpec",
    "RandomizeSpec",
    "Scenario",
    "ScenarioError",
    "ShipSpec",
    "StaticSpec",
    "TargetEvent",
    "TrajectorySpec",
    "TurnEvent",
    "VelEvent",
    "builtin_scenarios",
    "load_scenario",
    "scenario_dict",
]



class ScenarioError(ValueError):
    """A scenario file or override is missing a field, has a wrong type/unit or bad value."""


def _f(unit: str, default: Any = dataclasses.MISSING, doc: str = "") -> Any:
    """Dataclass field that records its unit (for error messages and docs)."""
    meta = {"unit": unit, "doc": doc}
    if default is dataclasses.MISSING:
        return field(metadata=meta)
    if isinstance(default, (list, dict)):
        raise TypeError("mutable default")  # pragma: no cover - programming error guard
    return field(default=default, metadata=meta)


# ---------------------------------------------------------------------------------------------
# trajectory events
# ---------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class TargetEvent:
    """Smooth change of a scalar to an absolute target over ``[t_s, t_s + dur_s]``."""

    t_s: float = _f("s")
    dur_s: float = _f("s")
    to: float = _f("unit of the profile (m/s for speed, deg for pitch)")


@dataclass(frozen=True)
class TurnEvent:
    """Smooth heading change by ``dyaw_deg`` (positive = clockwise seen from above)."""

    t_s: float = _f("s")
    dur_s: float = _f("s")
    dyaw_deg: float = _f("deg")


@dataclass(frozen=True)
class VelEvent:
    """Smooth change of the NED velocity to an absolute target."""

    t_s: float = _f("s")
    dur_s: float = _f("s")
    to_n_mps: float = _f("m/s")
    to_e_mps: float = _f("m/s")
    to_d_mps: float = _f("m/s")


# ---------------------------------------------------------------------------------------------
# trajectory kinds
# ---------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class _Where:
    lat_deg: float = _f("deg")
    lon_deg: float = _f("deg")
    alt_m: float = _f("m")


@dataclass(frozen=True)
class StaticSpec(_Where):
    """Vehicle at rest (zero velocity) with a fixed attitude, optionally swaying about it.

    ``sway_deg`` > 0 adds slow roll and pitch oscillations of that amplitude (periods
    ``sway_period_s`` and 1.37 times it), like the seed-000 vehicle whose real tilt wandered
    over ~3.5 deg around each nominal value (Tables S1/S2, "Real gamma min~max").
    """

    kind: str = _f("", "static")
    roll_deg: float = _f("deg", 0.0)
    pitch_deg: float = _f("deg", 0.0)
    yaw_deg: float = _f("deg", 0.0)
    sway_deg: float = _f("deg", 0.0)
    sway_period_s: float = _f("s", 120.0)


@dataclass(frozen=True)
class GroundSpec(_Where):
    """Ground or surface vehicle: speed, heading and road-grade profiles; body roll from
    lateral accel.

    ``speed`` targets are in m/s (through the water for a boat), ``grade`` targets are pitch
    angles in deg.  ``current_n/e_mps``: a boat's water current, added to the velocity along
    the heading, so the GNSS course differs from the heading by a crab angle that depends on
    the heading (0 for a car).  ``sway_deg`` > 0 rolls and pitches the body about the
    profile's attitude with that amplitude (periods ``sway_period_s`` and 0.73 times it):
    waves.
    """

    kind: str = _f("", "ground")
    yaw0_deg: float = _f("deg", 0.0)
    speed0_mps: float = _f("m/s", 0.0)
    speed: tuple[TargetEvent, ...] = _f("m/s (targets)", ())
    turns: tuple[TurnEvent, ...] = _f("deg", ())
    grade: tuple[TargetEvent, ...] = _f("deg (pitch targets)", ())
    roll_gain_rad_per_mps2: float = _f("rad/(m/s^2)", 0.0)
    sideslip_gain_rad_per_mps2: float = _f("rad/(m/s^2)", 0.0)
    slip_wander_rad: float = _f("rad", 0.0, "1-sigma of a sideslip that wanders on its own "
                                "(loose ground, skid steering), smooth, drawn per seed")
    slip_wander_tau_s: float = _f("s", 2.0, "its correlation time (Gaussian-shaped)")
    current_n_mps: float = _f("m/s", 0.0)
    current_e_mps: float = _f("m/s", 0.0)
    sway_deg: float = _f("deg", 0.0)
    sway_period_s: float = _f("s", 6.0)


@dataclass(frozen=True)
class MultirotorSpec(_Where):
    """Multirotor: NED velocity profile independent of heading; tilt follows thrust."""

    kind: str = _f("", "multirotor")
    yaw0_deg: float = _f("deg", 0.0)
    vel: tuple[VelEvent, ...] = _f("m/s", ())
    turns: tuple[TurnEvent, ...] = _f("deg", ())
    drag_per_s: float = _f("1/s", 0.0, "linear drag per unit mass (tilt in steady flight)")


@dataclass(frozen=True)
class FixedWingSpec(_Where):
    """Fixed-wing aircraft in coordinated flight through a steady wind.

    Airspeed, yaw and climb-rate profiles; body x points along the air-relative velocity in
    the horizontal (no sideslip), so with wind the GNSS course differs from the yaw by the
    crab angle.  Turns are coordinated: the bank puts the specific force in the body x-z
    plane (no lateral force), so the bank follows ``tan(bank) ~ V_air * yaw_rate / g``.  Pitch
    is the flight-path angle plus ``alpha_deg`` times the load factor (the wing needs more
    angle of attack in a banked turn).  The flight starts airborne at ``airspeed0_mps``.
    """

    kind: str = _f("", "fixed_wing")
    yaw0_deg: float = _f("deg", 0.0)
    airspeed0_mps: float = _f("m/s", 20.0)
    airspeed: tuple[TargetEvent, ...] = _f("m/s (targets)", ())
    turns: tuple[TurnEvent, ...] = _f("deg", ())
    climb: tuple[TargetEvent, ...] = _f("m/s (climb-rate targets, up positive)", ())
    wind_n_mps: float = _f("m/s", 0.0, "wind velocity (the air moves toward) north")
    wind_e_mps: float = _f("m/s", 0.0, "wind velocity east")
    alpha_deg: float = _f("deg", 3.0, "angle of attack in 1-g flight")

    def min_airspeed_mps(self) -> float:
        """The slowest airspeed the profile flies (its targets and start), m/s."""
        return min([self.airspeed0_mps, *(ev.to for ev in self.airspeed)])

    def min_horizontal_airspeed_mps(self) -> float:
        """A lower bound of the horizontal airspeed: the slowest airspeed with the steepest
        climb or descent rate, m/s (what bounds the crab angle in a given wind)."""
        climb = max([0.0, *(abs(ev.to) for ev in self.climb)])
        return math.sqrt(self.min_airspeed_mps() ** 2 - climb**2)


@dataclass(frozen=True)
class ModulationSpec:
    """Single-axis rotation modulation of the IMU about body z: 0 -> 180 deg -> 0 ..."""

    enabled: bool = _f("", False)
    rate_rps: float = _f("rad/s", 18.0 * DEG)
    dwell_s: float = _f("s", 300.0)
    ramp_s: float = _f("s", 1.0, "raised-cosine rate ramp at each end of a rotation")
    angle_deg: float = _f("deg", 180.0)


@dataclass(frozen=True)
class ShipSpec(_Where):
    """Ship: static, smooth acceleration to a cruise speed on a course, optional sea motion."""

    kind: str = _f("", "ship")
    course_deg: float = _f("deg", 0.0)
    static_s: float = _f("s", 0.0)
    accel_s: float = _f("s", 120.0)
    speed_mps: float = _f("m/s", 0.0)
    turns: tuple[TurnEvent, ...] = _f("deg", ())
    roll_amp_deg: float = _f("deg", 0.0)
    roll_period_s: float = _f("s", 10.0)
    pitch_amp_deg: float = _f("deg", 0.0)
    pitch_period_s: float = _f("s", 7.0)
    modulation: ModulationSpec = field(default_factory=ModulationSpec)


TrajectorySpec = StaticSpec | GroundSpec | MultirotorSpec | ShipSpec | FixedWingSpec
_KINDS: dict[str, type[Any]] = {
    "static": StaticSpec, "ground": GroundSpec, "multirotor": MultirotorSpec, "ship": ShipSpec,
    "fixed_wing": FixedWingSpec,
}


# ---------------------------------------------------------------------------------------------
# sensors and environment
# ---------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class ImuSpec:
    """IMU error model, all SI.  Constant biases and scale factors are drawn per seed."""

    rate_hz: float = _f("Hz")
    gyro_bias_sigma_rps: float = _f("rad/s")
    accel_bias_sigma_mps2: float = _f("m/s^2")
    arw_rad_per_sqrt_s: float = _f("rad/sqrt(s)")
    vrw_mps_per_sqrt_s: float = _f("m/s/sqrt(s)")
    gyro_gm_sigma_rps: float = _f("rad/s", 0.0)
    gyro_gm_tau_s: float = _f("s", 3600.0)
    accel_gm_sigma_mps2: float = _f("m/s^2", 0.0)
    accel_gm_tau_s: float = _f("s", 3600.0)
    gyro_scale_factor_sigma_ppm: float = _f("ppm", 0.0)
    accel_scale_factor_sigma_ppm: float = _f("ppm", 0.0)
    grade: str = _f("", "", "preset filling the keys not given (see GRADES)")
    # An uncalibrated IMU: a known, fixed offset on top of the drawn bias (the drawn bias is
    # a calibration residual; these are what a factory-fresh MEMS part reads at rest).
    gyro_offset_rps: tuple[float, ...] = _f("rad/s", (0.0, 0.0, 0.0),
                                            "constant gyro offset x y z, body FRD")
    accel_offset_mps2: tuple[float, ...] = _f("m/s^2", (0.0, 0.0, 0.0),
                                              "constant accelerometer offset x y z, body FRD")
    # The IMU turned on the vehicle (a board fixed at an angle, a module on its side): the
    # true sensor -> body rotation (ZYX, as for the polarization sensor).  The increments are
    # the IMU's, every error above is in the IMU's axes; the truth stays the vehicle's.  navd
    # is told with ``[imu] mount_*_deg`` (the same angles).
    mount_roll_deg: float = _f("deg", 0.0)
    mount_pitch_deg: float = _f("deg", 0.0)
    mount_yaw_deg: float = _f("deg", 0.0)
    gyro_bias_rw_rps_per_sqrt_s: float = _f("rad/s/sqrt(s)", 0.0,
                                            "gyro bias random walk (starts at 0)")
    accel_bias_rw_mps2_per_sqrt_s: float = _f("m/s^2/sqrt(s)", 0.0,
                                              "accelerometer bias random walk (starts at 0)")
    # Airframe vibration at the rotors' (or engine's) frequency, as a sensor that low-passes
    # its output (second order, ``vib_lpf_hz``) and is read as point samples at ``rate_hz``
    # sees it: a rate message (HIGHRES_IMU, RAW_IMU, a log's IMU), not a delta-angle IMU,
    # whose integration would average the tone out.  The tone aliases to |f - k rate_hz|,
    # to near DC whenever the frequency, which wanders with the throttle, crosses a multiple
    # of the rate: a bias that comes and goes.  The real motion's samples are left as they
    # are (the low-pass's delay on them is not modelled).
    vib_freq_hz: float = _f("Hz", 0.0, "rotor frequency; 0 = no vibration")
    vib_freq_sd_hz: float = _f("Hz", 0.0, "its wander, Gauss-Markov 1-sigma")
    vib_freq_tau_s: float = _f("s", 5.0, "its wander's correlation time")
    vib_lpf_hz: float = _f("Hz", 0.0, "the sensor's low-pass cut-off; 0 = none")
    vib_gyro_rps: tuple[float, ...] = _f("rad/s", (0.0, 0.0, 0.0),
                                         "peak angular-rate vibration x y z before the low-pass")
    vib_accel_mps2: tuple[float, ...] = _f("m/s^2", (0.0, 0.0, 0.0),
                                           "peak acceleration vibration x y z before the low-pass")


@dataclass(frozen=True)
class DropoutSpec:
    start_s: float = _f("s")
    end_s: float = _f("s")


@dataclass(frozen=True)
class PosStepSpec:
    """Every fix valid in ``[start_s, end_s)`` is moved by (north, east, down) metres: a
    position jump that lasts (a wrong solution the receiver holds), not a one-epoch spike."""

    start_s: float = _f("s")
    end_s: float = _f("s")
    north_m: float = _f("m", 0.0)
    east_m: float = _f("m", 0.0)
    down_m: float = _f("m", 0.0)


@dataclass(frozen=True)
class JumpSpec:
    """Bursts of consecutive GNSS epochs whose velocity jumps (the seed-001 outlier case)."""

    enabled: bool = _f("", False)
    bursts: int = _f("count", 5)
    min_epochs: int = _f("epochs", 3)
    max_epochs: int = _f("epochs", 8)
    min_mps: float = _f("m/s", 3.0)
    max_mps: float = _f("m/s", 5.0)
    start_s: float = _f("s", 0.0, "bursts are placed in [start_s, end_s]")
    end_s: float = _f("s", 1e18)
    shared_direction: bool = _f("", False, "one direction per burst instead of per epoch")


@dataclass(frozen=True)
class GnssSpec:
    """GNSS receiver model: 1-sigma per-axis noises, latency, dropouts, velocity jumps.

    The ``*_sigma_*`` values are what the receiver reports as its accuracy; the velocity noise
    actually added is ``vel_noise_scale`` times them (1: an honest receiver; 3: a receiver
    whose velocity is 3x noisier than it claims).
    """

    rate_hz: float = _f("Hz")
    pos_sigma_h_m: float = _f("m")
    pos_sigma_v_m: float = _f("m")
    vel_sigma_h_mps: float = _f("m/s")
    vel_sigma_v_mps: float = _f("m/s")
    pos_tau_s: float = _f("s", 0.0, "0: white position noise; > 0: Gauss-Markov")
    latency_s: float = _f("s", 0.0)
    stamped_on_arrival: bool = _f("", False, "fixes carry their arrival time (validity + "
                                  "latency), as an autopilot that stamps on receipt sends them")
    dropouts: tuple[DropoutSpec, ...] = _f("s", ())
    jumps: JumpSpec = field(default_factory=JumpSpec)
    vel_noise_scale: float = _f("", 1.0, "true velocity noise / reported velocity accuracy")
    pos_steps: tuple[PosStepSpec, ...] = _f("s, m", ())
    # The antenna off the IMU: the receiver measures the antenna's position and velocity,
    # p + C l and v + C (w x l), which a filter told a lever arm of zero must explain some
    # other way while the vehicle turns.
    lever_arm_m: tuple[float, ...] = _f("m", (0.0, 0.0, 0.0),
                                        "antenna position x y z from the IMU, body FRD")


@dataclass(frozen=True)
class DovSpec:
    """Truth deflection of the vertical: offset + sinusoid in time, per component."""

    enabled: bool = _f("", False)
    xi_offset_arcsec: float = _f("arcsec", 0.0)
    xi_amp_arcsec: float = _f("arcsec", 0.0)
    xi_period_s: float = _f("s", 36000.0)
    xi_phase_deg: float = _f("deg", 0.0)
    eta_offset_arcsec: float = _f("arcsec", 0.0)
    eta_amp_arcsec: float = _f("arcsec", 0.0)
    eta_period_s: float = _f("s", 36000.0)
    eta_phase_deg: float = _f("deg", 0.0)
    dg_mps2: float = _f("m/s^2", 0.0, "gravity disturbance along down, constant")


@dataclass(frozen=True)
class PolarizationSpec:
    """Zenith skylight-polarization sensor (firmware_sim.polarization): Rayleigh sky.

    Sensor frame: x/y in the detector plane, boresight along -z (a zero mounting on an FRD
    body looks up).  ``mount_*_deg`` is the true sensor -> body rotation (ZYX).  The AoP
    noise is ``aop_sigma_deg * dop_max / DoP`` (white), the DoP noise ``dop_sigma``.
    """

    enabled: bool = _f("", False)
    start_utc: str = _f("ISO 8601 UTC", "2020-06-01T10:12:00Z", "UTC at sensor time 0")
    rate_hz: float = _f("Hz", 10.0)
    aop_sigma_deg: float = _f("deg", 0.2, "AoP noise at DoP = dop_max")
    dop_max: float = _f("", 0.7, "degree of polarization at 90 deg scattering angle")
    dop_sigma: float = _f("", 0.01)
    mount_roll_deg: float = _f("deg", 0.0)
    mount_pitch_deg: float = _f("deg", 0.0)
    mount_yaw_deg: float = _f("deg", 0.0)
    dark_sun_elevation_deg: float = _f("deg", -8.0, "below this the sky is dark: DoP = 0")


@dataclass(frozen=True)
class RandomizeSpec:
    """Per-seed Monte Carlo variation (applied by :func:`firmware_sim.randomize.randomized`).

    Every draw comes from its own random stream of the run's seed, so seed N always flies the
    same variant.  Ranges are ``[low, high]`` (uniform); an empty range leaves the value alone.
    Angles: a uniform draw in ``[-x, +x]`` deg added to the scenario's value.
    """

    enabled: bool = _f("", False)
    yaw0_deg: float = _f("deg", 0.0, "initial yaw: + uniform in [-x, x]")
    legs_rotate_deg: float = _f("deg", 0.0,
                                "every horizontal velocity target rotated by one draw in [-x, x]")
    legs_jitter_deg: float = _f("deg", 0.0,
                                "then each target by its own draw in [-x, x]")
    mirror_turns: bool = _f("", False, "turn directions all flipped with probability 1/2")
    wind_speed_mps: tuple[float, ...] = _f("m/s", (), "[low, high]; fixed-wing only")
    wind_dir_deg: float = _f("deg", 0.0, "wind direction (from) + uniform in [-x, x]")
    max_crab_deg: float = _f("deg", 90.0,
                             "wind speed capped at min airspeed * sin(max_crab_deg)")
    gyro_offset_rps: tuple[float, ...] = _f("rad/s", (),
                                            "[low, high] |offset| per axis, random sign")
    accel_offset_mps2: tuple[float, ...] = _f("m/s^2", (),
                                              "[low, high] |offset| per axis, random sign")


@dataclass(frozen=True)
class Scenario:
    """A validated scenario.  ``duration`` (s) = ``duration_s * duration_scale``."""

    name: str
    duration_s: float = field(metadata={"unit": "s"})
    trajectory: TrajectorySpec
    imu: ImuSpec
    gnss: GnssSpec
    description: str = _f("", "")
    duration_scale: float = _f("", 1.0)
    dov: DovSpec = field(default_factory=DovSpec)
    polarization: PolarizationSpec = field(default_factory=PolarizationSpec)
    randomize: RandomizeSpec = field(default_factory=RandomizeSpec)
    source: str = _f("", "", "file it was loaded from")

    @property
    def duration(self) -> float:
        """Effective duration, s."""
        return self.duration_s * self.duration_scale


# ---------------------------------------------------------------------------------------------
# IMU grade presets (SI)
# ---------------------------------------------------------------------------------------------

_DEG_PER_H = DEG / 3600.0
_MG = 9.80665e-3
GRADES: dict[str, dict[str, float]] = {
    # seed 001: 12 deg/h, 5 mg, 0.24 deg/sqrt(h), 0.3 m/s/sqrt(Hz)
    "mems_seed001": {
        "gyro_bias_sigma_rps": 12.0 * _DEG_PER_H,
        "accel_bias_sigma_mps2": 5.0 * _MG,
        "arw_rad_per_sqrt_s": 0.24 * DEG / 60.0,
        "vrw_mps_per_sqrt_s": 0.3,
    },
    # The same MEMS with the velocity random walk read as 0.3 m/s/sqrt(h) (= 0.005 m/s/sqrt(s)).
    # Seed 001 prints "0.3 m/s2/sqrt(Hz)" in its simulation and "0.3 m/s/sqrt(Hz)" for its car
    # test: units that disagree, and 0.3 m/s2/sqrt(Hz) (30 mg/sqrt(Hz)) would be ~100x the noise
    # of a phone accelerometer, while 0.3 m/s/sqrt(h) is an ordinary MEMS figure.  Used where a
    # scenario's tilt accuracy at rest matters (the seed-000 polarization cases, whose own IMU
    # the supplement does not give); car480 keeps the value as printed.
    "mems_seed001_h": {
        "gyro_bias_sigma_rps": 12.0 * _DEG_PER_H,
        "accel_bias_sigma_mps2": 5.0 * _MG,
        "arw_rad_per_sqrt_s": 0.24 * DEG / 60.0,
        "vrw_mps_per_sqrt_s": 0.3 / 60.0,
    },
    # Consumer MEMS of a flight controller, as installed: the noise densities of the noisier
    # of two common parts, Bosch BMI088 (datasheet BST-BMI088-DS001: gyro 0.014 deg/s/sqrt(Hz),
    # accel 175 ug/sqrt(Hz) typ.) rather than TDK ICM-42688-P (DS-000347: 0.0028 deg/s/sqrt(Hz),
    # 70 ug/sqrt(Hz)); uncalibrated offsets of the size both datasheets allow (gyro zero-rate
    # output +-0.5 deg/s ICM-42688, +-1 deg/s BMI088; accel zero-g +-20 mg typ., more after
    # soldering), drawn with sigma 0.3 deg/s and 35 mg; sensitivity tolerance +-0.5 % as a
    # 5000 ppm sigma.  Scenarios usually set the offsets per seed in [randomize] instead.
    "consumer_mems": {
        "gyro_bias_sigma_rps": 0.3 * DEG,
        "accel_bias_sigma_mps2": 35.0 * _MG,
        "arw_rad_per_sqrt_s": 0.014 * DEG,
        "vrw_mps_per_sqrt_s": 175e-6 * 9.80665,
        "gyro_scale_factor_sigma_ppm": 5000.0,
        "accel_scale_factor_sigma_ppm": 5000.0,
        # in-run drift: a few deg/h of bias instability over minutes
        "gyro_bias_rw_rps_per_sqrt_s": 5.0 * _DEG_PER_H / 10.0,
        "accel_bias_rw_mps2_per_sqrt_s": 0.1 * _MG,
    },
    # seed 002 (RLG + quartz accelerometers): 0.003 deg/h, 10 mGal, 0.0005 deg/sqrt(h),
    # 10 mGal/sqrt(Hz); its Table 2 gives the random walk per sqrt(h), Table 1's per sqrt(s)
    # would be 60x a navigation-grade RLG.
    "nav_seed002": {
        "gyro_bias_sigma_rps": 0.003 * _DEG_PER_H,
        "accel_bias_sigma_mps2": 1e-4,
        "arw_rad_per_sqrt_s": 0.0005 * DEG / 60.0,
        "vrw_mps_per_sqrt_s": 1e-4,
    },
}


# ---------------------------------------------------------------------------------------------
# generic typed builder
# ---------------------------------------------------------------------------------------------

def _describe(tp: Any, unit: str) -> str:
    """Human description of what a field expects, with its unit."""
    u = f" in {unit}" if unit else ""
    origin = typing.get_origin(tp)
    if tp is float:
        return f"a number{u}"
    if tp is int:
        return f"an integer{u}"
    if tp is bool:
        return "a boolean (true/false)"
    if tp is str:
        return "a string"
    if origin is tuple:
        inner = typing.get_args(tp)[0]
        if dataclasses.is_dataclass(inner):
            keys = ", ".join(f"{f.name} [{f.metadata.get('unit', '')}]"
                             for f in dataclasses.fields(inner))
            return f"an array of tables {{{keys}}}"
        return f"an array{u}"
    if dataclasses.is_dataclass(tp):
        return "a table"
    return f"a trajectory table with kind = one of {sorted(_KINDS)}"


def _convert(value: Any, tp: Any, path: str, unit: str) -> Any:
    def bad() -> ScenarioError:
        return ScenarioError(f"{path}: expected {_describe(tp, unit)}, "
                             f"got {type(value).__name__} {value!r}")

    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise bad()
        x = float(value)
        if not math.isfinite(x):
            raise ScenarioError(f"{path}: must be finite ({_describe(tp, unit)}), got {x!r}")
        return x
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise bad()
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise bad()
        return value
    if tp is str:
        if not isinstance(value, str):
            raise bad()
        return value
    origin = typing.get_origin(tp)
    if origin is tuple:
        if not isinstance(value, list):
            raise bad()
        inner = typing.get_args(tp)[0]
        return tuple(_convert(v, inner, f"{path}[{i}]", unit) for i, v in enumerate(value))
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise bad()
        return _build(typing.cast(type[Any], tp), value, path)
    if origin in (types.UnionType, typing.Union):  # the trajectory kinds
        if not isinstance(value, dict):
            raise bad()
        kind = value.get("kind")
        if kind not in _KINDS:
            raise ScenarioError(f"{path}.kind: expected one of {sorted(_KINDS)}, got {kind!r}")
        return _build(_KINDS[kind], value, path)
    raise TypeError(f"unsupported field type {tp!r}")  # pragma: no cover


def _build(cls: type[Any], data: Mapping[str, Any], path: str) -> Any:
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    prefix = f"{path}." if path else ""
    for key in data:
        if key not in fields:
            close = difflib.get_close_matches(key, list(fields), n=1, cutoff=0.5)
            hint = ""
            if close:
                f = fields[close[0]]
                hint = (f"; did you mean {prefix}{close[0]} "
                        f"({_describe(hints[close[0]], f.metadata.get('unit', ''))})?")
            raise ScenarioError(f"{prefix}{key}: unknown field{hint}")
    kwargs: dict[str, Any] = {}
    for name, f in fields.items():
        unit = f.metadata.get("unit", "")
        if name in data:
            kwargs[name] = _convert(data[name], hints[name], prefix + name, unit)
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise ScenarioError(f"{prefix}{name}: missing; expected {_describe(hints[name], unit)}")
    return cls(**kwargs)


# ---------------------------------------------------------------------------------------------
# semantic checks (after types are right)
# ---------------------------------------------------------------------------------------------

def _check(cond: bool, path: str, msg: str) -> None:
    if not cond:
        raise ScenarioError(f"{path}: {msg}")


def _check_events(events: tuple[Any, ...], path: str) -> None:
    end = -math.inf
    for i, ev in enumerate(events):
        p = f"{path}[{i}]"
        _check(ev.dur_s > 0.0, f"{p}.dur_s", f"must be > 0 s, got {ev.dur_s}")
        _check(ev.t_s >= end, f"{p}.t_s",
               f"events must be in time order and not overlap (previous ends at {end} s)")
        end = ev.t_s + ev.dur_s


def _validate(sc: Scenario) -> None:
    _check(sc.duration_s > 0.0, "duration_s", "must be > 0 s")
    _check(sc.duration_scale > 0.0, "duration_scale", "must be > 0")
    tr = sc.trajectory
    _check(-90.0 < tr.lat_deg < 90.0, "trajectory.lat_deg", "must be in (-90, 90) deg")
    if isinstance(tr, StaticSpec):
        _check(0.0 <= tr.sway_deg <= 30.0, "trajectory.sway_deg", "must be in [0, 30] deg")
        _check(tr.sway_period_s > 0.0, "trajectory.sway_period_s", "must be > 0 s")
    if isinstance(tr, GroundSpec):
        for name in ("speed", "turns", "grade"):
            _check_events(getattr(tr, name), f"trajectory.{name}")
        _check(tr.speed0_mps >= 0.0, "trajectory.speed0_mps", "must be >= 0 m/s")
        for i, ev in enumerate(tr.speed):
            # a negative target reverses along body x (parking, a robot backing out)
            _check(abs(ev.to) < 100.0, f"trajectory.speed[{i}].to",
                   "speed target must be within +-100 m/s")
        for i, ev in enumerate(tr.grade):
            _check(abs(ev.to) < 45.0, f"trajectory.grade[{i}].to", "pitch must be < 45 deg")
        _check(0.0 <= tr.sway_deg <= 30.0, "trajectory.sway_deg", "must be in [0, 30] deg")
        _check(tr.sway_period_s > 0.0, "trajectory.sway_period_s", "must be > 0 s")
    elif isinstance(tr, MultirotorSpec):
        _check_events(tr.vel, "trajectory.vel")
        _check_events(tr.turns, "trajectory.turns")
        _check(tr.drag_per_s >= 0.0, "trajectory.drag_per_s", "must be >= 0 1/s")
    elif isinstance(tr, FixedWingSpec):
        for name in ("airspeed", "turns", "climb"):
            _check_events(getattr(tr, name), f"trajectory.{name}")
        _check(tr.min_airspeed_mps() > 5.0, "trajectory.airspeed",
               "airspeeds (start and targets) must be > 5 m/s")
        for i, ev in enumerate(tr.climb):
            _check(abs(ev.to) < 0.5 * tr.min_airspeed_mps(), f"trajectory.climb[{i}].to",
                   "climb rate must be below half the slowest airspeed (m/s)")
        _check(-15.0 <= tr.alpha_deg <= 15.0, "trajectory.alpha_deg", "must be in [-15, 15] deg")
    elif isinstance(tr, ShipSpec):
        _check_events(tr.turns, "trajectory.turns")
        _check(tr.accel_s > 0.0, "trajectory.accel_s", "must be > 0 s")
        _check(tr.speed_mps >= 0.0, "trajectory.speed_mps", "must be >= 0 m/s")
        _check(tr.roll_period_s > 0.0, "trajectory.roll_period_s", "must be > 0 s")
        _check(tr.pitch_period_s > 0.0, "trajectory.pitch_period_s", "must be > 0 s")
        m = tr.modulation
        if m.enabled:
            _check(m.rate_rps > 0.0, "trajectory.modulation.rate_rps", "must be > 0 rad/s")
            _check(m.dwell_s >= 0.0, "trajectory.modulation.dwell_s", "must be >= 0 s")
            _check(m.ramp_s >= 0.0 and m.ramp_s <= abs(m.angle_deg) * DEG / m.rate_rps,
                   "trajectory.modulation.ramp_s",
                   "must be >= 0 s and no longer than angle/rate")
    imu = sc.imu
    _check(imu.rate_hz > 0.0, "imu.rate_hz", "must be > 0 Hz")
    dt_us = 1e6 / imu.rate_hz
    _check(abs(dt_us - round(dt_us)) < 1e-9 * dt_us, "imu.rate_hz",
           f"1e6 / rate_hz must be a whole number of microseconds, got {dt_us} us")
    for name in ("gyro_bias_sigma_rps", "accel_bias_sigma_mps2", "arw_rad_per_sqrt_s",
                 "vrw_mps_per_sqrt_s", "gyro_gm_sigma_rps", "accel_gm_sigma_mps2",
                 "gyro_scale_factor_sigma_ppm", "accel_scale_factor_sigma_ppm"):
        _check(getattr(imu, name) >= 0.0, f"imu.{name}", "must be >= 0")
    for name in ("gyro_bias_rw_rps_per_sqrt_s", "accel_bias_rw_mps2_per_sqrt_s"):
        _check(getattr(imu, name) >= 0.0, f"imu.{name}", "must be >= 0")
    for name in ("gyro_offset_rps", "accel_offset_mps2", "vib_gyro_rps", "vib_accel_mps2"):
        _check(len(getattr(imu, name)) == 3, f"imu.{name}", "needs 3 values (x, y, z)")
    for name in ("vib_freq_hz", "vib_freq_sd_hz", "vib_lpf_hz"):
        _check(getattr(imu, name) >= 0.0, f"imu.{name}", "must be >= 0 Hz")
    _check(imu.vib_freq_tau_s > 0.0, "imu.vib_freq_tau_s", "must be > 0 s")
    for name in ("mount_roll_deg", "mount_pitch_deg", "mount_yaw_deg"):
        _check(abs(getattr(imu, name)) <= 180.0, f"imu.{name}", "must be in [-180, 180]")
    _check(imu.gyro_gm_tau_s > 0.0, "imu.gyro_gm_tau_s", "must be > 0 s")
    _check(imu.accel_gm_tau_s > 0.0, "imu.accel_gm_tau_s", "must be > 0 s")
    g = sc.gnss
    _check(g.rate_hz > 0.0, "gnss.rate_hz", "must be > 0 Hz")
    period_us = 1e6 / g.rate_hz
    _check(abs(period_us - round(period_us)) < 1e-9 * period_us
           and round(period_us) % round(dt_us) == 0, "gnss.rate_hz",
           f"the GNSS period ({period_us} us) must be a whole multiple of the IMU interval "
           f"({dt_us} us)")
    for name in ("pos_sigma_h_m", "pos_sigma_v_m", "vel_sigma_h_mps", "vel_sigma_v_mps",
                 "pos_tau_s", "latency_s"):
        _check(getattr(g, name) >= 0.0, f"gnss.{name}", "must be >= 0")
    for i, d in enumerate(g.dropouts):
        _check(d.end_s > d.start_s, f"gnss.dropouts[{i}].end_s", "must be > start_s (s)")
    _check(g.vel_noise_scale >= 0.0, "gnss.vel_noise_scale", "must be >= 0")
    for i, st in enumerate(g.pos_steps):
        _check(st.end_s > st.start_s, f"gnss.pos_steps[{i}].end_s", "must be > start_s (s)")
    _check(len(g.lever_arm_m) == 3, "gnss.lever_arm_m", "needs 3 values (x, y, z)")
    j = g.jumps
    _check(j.bursts >= 0, "gnss.jumps.bursts", "must be >= 0")
    _check(1 <= j.min_epochs <= j.max_epochs, "gnss.jumps.min_epochs",
           "need 1 <= min_epochs <= max_epochs (epochs)")
    _check(0.0 <= j.min_mps <= j.max_mps, "gnss.jumps.min_mps",
           "need 0 <= min_mps <= max_mps (m/s)")
    _check(j.end_s > j.start_s, "gnss.jumps.end_s", "must be > start_s (s)")
    pol = sc.polarization
    if pol.enabled:
        from firmware_sim.polarization import parse_utc

        try:
            parse_utc(pol.start_utc)
        except ValueError as e:
            raise ScenarioError(f"polarization.start_utc: {e}") from None
        _check(pol.rate_hz > 0.0 and round(1e6 / pol.rate_hz) % round(dt_us) == 0,
               "polarization.rate_hz",
               f"the polarization period must be a whole multiple of the IMU interval "
               f"({dt_us} us)")
        _check(pol.aop_sigma_deg >= 0.0 and pol.dop_sigma >= 0.0, "polarization.aop_sigma_deg",
               "noises must be >= 0")
        _check(0.0 < pol.dop_max <= 1.0, "polarization.dop_max", "must be in (0, 1]")
    _validate_randomize(sc.randomize)
    _check(sc.dov.xi_period_s > 0.0, "dov.xi_period_s", "must be > 0 s")
    _check(sc.dov.eta_period_s > 0.0, "dov.eta_period_s", "must be > 0 s")


def _validate_randomize(r: RandomizeSpec) -> None:
    for name in ("yaw0_deg", "legs_rotate_deg", "legs_jitter_deg", "wind_dir_deg"):
        v = getattr(r, name)
        _check(0.0 <= v <= 180.0, f"randomize.{name}", f"must be in [0, 180] deg, got {v}")
    _check(0.0 < r.max_crab_deg <= 90.0, "randomize.max_crab_deg", "must be in (0, 90] deg")
    for name in ("wind_speed_mps", "gyro_offset_rps", "accel_offset_mps2"):
        v = getattr(r, name)
        _check(len(v) in (0, 2) and all(x >= 0.0 for x in v) and (not v or v[0] <= v[1]),
               f"randomize.{name}", f"must be [] or [low, high] with 0 <= low <= high, got {v}")


# ---------------------------------------------------------------------------------------------
# loading
# ---------------------------------------------------------------------------------------------

def builtin_scenarios() -> list[str]:
    """Names of the scenarios shipped in ``firmware_sim/scenarios``."""
    root = resources.files("firmware_sim") / "scenarios"
    return sorted(p.name[:-5] for p in root.iterdir() if p.name.endswith(".toml"))


def _read_source(name_or_path: str | Path) -> tuple[str, str]:
    p = Path(name_or_path)
    # a bare name is a built-in even when a folder of that name exists (e.g. an output dir)
    if p.suffix == ".toml" or p.is_file() or len(p.parts) > 1:
        try:
            return p.read_text(encoding="utf-8"), str(p)
        except OSError as e:
            raise ScenarioError(f"cannot read scenario file {p}: {e.strerror}") from e
    res = resources.files("firmware_sim") / "scenarios" / f"{name_or_path}.toml"
    if not res.is_file():
        raise ScenarioError(f"unknown scenario {name_or_path!r}; built-in: "
                            f"{', '.join(builtin_scenarios())} (or give a path to a .toml)")
    return res.read_text(encoding="utf-8"), str(name_or_path)


def _apply_override(tree: dict[str, Any], dotted: str, value: Any) -> None:
    try:  # navd's override rule (navd.config), with the scenario's error type
        set_override(tree, dotted.split("."), list(value) if isinstance(value, tuple) else value)
    except ConfigError as exc:
        raise ScenarioError(str(exc)) from None


def load_scenario(name_or_path: str | Path,
                  overrides: Mapping[str, Any] | None = None) -> Scenario:
    """Load and validate a scenario.

    Args:
        name_or_path: a built-in name (``"car480"``) or a path to a TOML file.
        overrides: dotted keys to values, e.g. ``{"gnss.jumps.enabled": True}``; values are
            TOML-typed Python values (float, int, bool, str, lists, dicts).

    Raises:
        ScenarioError: naming the offending field and the unit it expects.
    """
    text, source = _read_source(name_or_path)
    try:
        tree = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ScenarioError(f"{source}: invalid TOML: {e}") from e
    for key, value in (overrides or {}).items():
        _apply_override(tree, key, value)
    imu = tree.get("imu")
    if isinstance(imu, dict) and isinstance(imu.get("grade"), str) and imu["grade"]:
        preset = GRADES.get(imu["grade"])
        if preset is None:
            raise ScenarioError(f"imu.grade: expected one of {sorted(GRADES)} or \"\", "
                                f"got {imu['grade']!r}")
        tree["imu"] = {**preset, **imu}
    tree.setdefault("source", source)
    try:
        sc = typing.cast(Scenario, _build(Scenario, tree, ""))
        _validate(sc)
    except ScenarioError as e:
        raise ScenarioError(f"{source}: {e}") from None
    return sc


def scenario_dict(sc: Scenario) -> dict[str, Any]:
    """The resolved scenario as plain data (JSON-ready; tuples become lists on dumping)."""
    return dataclasses.asdict(sc)
