"""Plain sample types that cross every boundary: adapters -> estimator -> sinks.

All are frozen and slotted so they are cheap, hashable and safe to hand between tasks.
Frames and units follow the conventions in :mod:`navd`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum


@dataclass(frozen=True, slots=True)
class ImuSample:
    """Inertial increments over ``(t_us - dt_us, t_us]``.

    Attributes:
        t_us: sensor time stamp at the end of the interval, integer microseconds.
        dt_us: integration interval, microseconds (> 0).
        dtheta_x/y/z: angle increment, body FRD, rad.
        dvel_x/y/z: velocity increment of specific force, body FRD, m/s.
    """

    t_us: int
    dt_us: int
    dtheta_x: float
    dtheta_y: float
    dtheta_z: float
    dvel_x: float
    dvel_y: float
    dvel_z: float


class FixType(IntEnum):
    NONE = 0
    FIX_2D = 2
    FIX_3D = 3
    DGPS = 4
    RTK_FLOAT = 5
    RTK_FIXED = 6


@dataclass(frozen=True, slots=True)
class GnssSample:
    """One GNSS epoch.

    Attributes:
        t_us: time of validity of the fix (sensor clock), integer microseconds.
        lat_rad, lon_rad: WGS-84 geodetic latitude and longitude, rad.
        alt_m: height above the WGS-84 ellipsoid, m.
        vel_n, vel_e, vel_d: velocity in NED, m/s.
        h_acc_m, v_acc_m: 1-sigma horizontal / vertical position accuracy, m.
        vel_acc_mps: 1-sigma speed accuracy (per axis), m/s.
        fix_type: receiver fix type.
        pos_ecef_m: optional ECEF position (x, y, z), m.
        vel_ecef_mps: optional ECEF velocity (x, y, z), m/s.
    """

    t_us: int
    lat_rad: float
    lon_rad: float
    alt_m: float
    vel_n: float
    vel_e: float
    vel_d: float
    h_acc_m: float
    v_acc_m: float
    vel_acc_mps: float
    fix_type: FixType = FixType.FIX_3D
    pos_ecef_m: tuple[float, float, float] | None = None
    vel_ecef_mps: tuple[float, float, float] | None = None


@dataclass(frozen=True, slots=True)
class NavSolution:
    """Estimator output at one IMU time.

    Attributes:
        t_us: time of validity, microseconds.
        quat_nb: attitude quaternion (w, x, y, z) of C_b^n.
        roll_rad, pitch_rad, yaw_rad: ZYX Euler angles, rad (yaw in (-pi, pi]).
        lat_rad, lon_rad, alt_m: WGS-84 position.
        vel_n: NED velocity, m/s.
        att_sd_rad: 1-sigma of (roll, pitch, yaw), rad.
        gyro_bias_rps: estimated gyro bias, body FRD, rad/s.
        accel_bias_mps2: estimated accelerometer bias, body FRD, m/s^2.
        heading_aligned: True once the heading is flagged aligned: given a value from a trusted
            source and confirmed over time (docs/design.md §4, alignment integrity).
        rate_b: last bias-compensated angular rate, body FRD, rad/s.
        pos_sd_m: 1-sigma of the position along (north, east, down), m (NaN: not given).
        vel_sd_mps: 1-sigma of vel_n along (north, east, down), m/s (NaN: not given).
        gnss_age_us: sensor-time age of the last GNSS fix the filter used, µs; -1 before
            the first (a growing age means the INS is coasting).
        heading_resets: times the heading was reset without a measurement update (a yaw
            reset to the GNSS course, a reset after a velocity lock-out, a restart) since the
            estimator was made; a change tells a consumer the heading jumped.
        heading_initialised: the heading has a value from a trusted source (config, a first
            GNSS course, observability), confirmed or not; always True when
            ``heading_aligned`` is.
        yaw_sd_installation_rad: the share of ``att_sd_rad[2]`` (added in quadrature) that
            is the IMU's yaw on the vehicle as installed (``[imu] mount_yaw_sd_deg``) where
            the heading comes from the GNSS course; 0 elsewhere.  A simulator that mounts
            the IMU exactly as stated scores against the rest.
    """

    t_us: int
    quat_nb: tuple[float, float, float, float]
    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    lat_rad: float
    lon_rad: float
    alt_m: float
    vel_n: tuple[float, float, float]
    att_sd_rad: tuple[float, float, float]
    gyro_bias_rps: tuple[float, float, float]
    accel_bias_mps2: tuple[float, float, float]
    heading_aligned: bool
    rate_b: tuple[float, float, float]
    # after the fields every producer sets, so solutions made before these existed (tests,
    # recordings) still construct; a ROS 2 consumer needs them for its covariances
    pos_sd_m: tuple[float, float, float] = (math.nan, math.nan, math.nan)
    vel_sd_mps: tuple[float, float, float] = (math.nan, math.nan, math.nan)
    gnss_age_us: int = -1
    heading_initialised: bool = False
    heading_resets: int = 0
    yaw_sd_installation_rad: float = 0.0

    def heading_good(self, max_sd_rad: float) -> bool:
        """The heading is initialised *and* its 1-sigma is within ``max_sd_rad``: what an
        output that says "aligned" means (a first course initialises the heading with the
        wide start-up sigma; the daemon passes ``[init] aligned_sd_deg``)."""
        return self.heading_aligned and self.att_sd_rad[2] <= max_sd_rad


@dataclass(frozen=True, slots=True)
class PolSample:
    """A zenith skylight-polarization reading (docs/design.md §7).

    Attributes:
        t_us: sensor time stamp, integer microseconds (same clock as the IMU).
        aop_rad: angle of polarization of the E-vector in the sensor frame, rad, in [0, pi).
        dop: degree of polarization, 0..1.
        utc_unix_s: UTC of the reading (POSIX seconds, leap seconds removed), for the sun.
    """

    t_us: int
    aop_rad: float
    dop: float
    utc_unix_s: float


Sample = ImuSample | GnssSample | PolSample
"""Anything :meth:`navd.core.estimator.Estimator.push` takes."""
