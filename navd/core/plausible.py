"""Input plausibility: values beyond these limits are wire garbage or a broken sensor, not
motion.  One rule, used by the input adapters (:mod:`navd.io.common`, point samples at the
wire) and by the estimator (increments, ``Estimator.push``), so a sample either side of the
wire meets the same limits.

IMU: the magnitude of the angular rate and of the specific force, limited by config
``[imu] max_rate_dps`` and ``max_accel_mps2`` (:class:`Limits`; defaults 2000 deg/s and
50 g, above the full scale of any common MEMS IMU).  Increments are checked as rates:
``|dtheta| > max_rate dt`` is ``|omega| > max_rate``.

GNSS (constants, not configurable):

=====================  ==========================================================
``|lat| <= pi/2``       and ``|lon| <= pi`` (+-180 deg, as every GNSS wire format
                        gives it), else ``gnss_latlon_range``
``MIN_ALT_M..MAX_ALT_M``  -2 km (below the Dead Sea shore with margin) to 100 km
                        (ellipsoidal height), else ``gnss_absurd_alt``
``|v| <= MAX_SPEED_MPS``  1000 m/s, magnitude of the finite NED components (a missing
                        component is NaN on purpose); an infinite one fails,
                        else ``gnss_absurd_velocity``
=====================  ==========================================================

Non-finite position (or IMU value): ``gnss_nonfinite`` / ``imu_nonfinite``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from navd.units import DEG, G0

if TYPE_CHECKING:
    from navd.config.estimator import ImuSection

DEFAULT_MAX_ACCEL_MPS2 = 50.0 * G0
DEFAULT_MAX_RATE_RPS = 2000.0 * DEG
MAX_LAT_RAD = 0.5 * math.pi
MAX_LON_RAD = math.pi
MIN_ALT_M = -2000.0
MAX_ALT_M = 100_000.0
MAX_SPEED_MPS = 1000.0


@dataclass(frozen=True, slots=True)
class Limits:
    """IMU limits: magnitude of specific force (m/s^2) and of angular rate (rad/s)."""

    max_accel_mps2: float = DEFAULT_MAX_ACCEL_MPS2
    max_gyro_rps: float = DEFAULT_MAX_RATE_RPS

    @classmethod
    def from_config(cls, imu: ImuSection) -> Limits:
        """From ``[imu] max_accel_mps2`` / ``max_rate_dps`` (already SI in the section)."""
        return cls(imu.max_accel, imu.max_rate)


def imu_reason(wx: float, wy: float, wz: float, fx: float, fy: float, fz: float,
               max_gyro: float, max_accel: float) -> str | None:
    """Why an IMU sample is implausible, or None.

    Rates (rad/s, m/s^2) with the limits of :class:`Limits`, or increments over dt
    (rad, m/s) with the limits times dt.  Body FRD.
    """
    w2 = wx * wx + wy * wy + wz * wz
    f2 = fx * fx + fy * fy + fz * fz
    # one comparison each on the kHz path: NaN compares false, so a non-finite value
    # falls through to the classification below
    if w2 <= max_gyro * max_gyro and f2 <= max_accel * max_accel:
        return None
    if not (math.isfinite(wx) and math.isfinite(wy) and math.isfinite(wz)
            and math.isfinite(fx) and math.isfinite(fy) and math.isfinite(fz)):
        return "imu_nonfinite"
    if w2 > max_gyro * max_gyro:
        return "imu_absurd_gyro"
    return "imu_absurd_accel"


def gnss_reason(lat_rad: float, lon_rad: float, alt_m: float, vel_n: float, vel_e: float,
                vel_d: float) -> str | None:
    """Why a GNSS fix is implausible, or None (limits in the module doc).

    NaN velocity components mean "not reported" and fail no test here.
    """
    if not (math.isfinite(lat_rad) and math.isfinite(lon_rad) and math.isfinite(alt_m)):
        return "gnss_nonfinite"
    if abs(lat_rad) > MAX_LAT_RAD or abs(lon_rad) > MAX_LON_RAD:
        return "gnss_latlon_range"
    if not MIN_ALT_M <= alt_m <= MAX_ALT_M:
        return "gnss_absurd_alt"
    if math.isinf(vel_n) or math.isinf(vel_e) or math.isinf(vel_d):
        return "gnss_absurd_velocity"
    sq = 0.0
    if vel_n == vel_n:
        sq += vel_n * vel_n
    if vel_e == vel_e:
        sq += vel_e * vel_e
    if vel_d == vel_d:
        sq += vel_d * vel_d
    if sq > MAX_SPEED_MPS * MAX_SPEED_MPS:
        return "gnss_absurd_velocity"
    return None
