"""What navd tells an autopilot: the contents of GPS_INPUT, ESTIMATOR_STATUS and the
heading-reset command, decided from a :class:`~navd.types.NavSolution` (docs/autopilot.md).

GPS_INPUT (ArduPilot ``GPS_TYPE = 14``)
    navd's position, velocity and, once the heading is aligned, its heading as the
    "GPS yaw" an EKF3 without a compass can use (``EK3_SRC1_YAW``).  ``yaw`` is centidegrees
    from true north, 0 = no yaw, so north goes out as 36000 (ArduPilot's AP_GPS_MAV takes any
    non-zero value as a yaw).  Accuracies are the filter's 1-sigma, per axis, as a receiver's
    hAcc/vAcc/sAcc would be read.  The fix type says 3D only while a GNSS fix was used within
    ``max_gnss_age``: a coasting INS is reported as no fix rather than as a receiver.

MAV_CMD_EXTERNAL_ATTITUDE_ESTIMATE (620, PX4 EKF2)
    the heading (deg) and its 1-sigma (deg), sent when the heading becomes aligned and after
    every heading reset, at most once per ``min_interval``: :class:`HeadingResetSchedule`.

ESTIMATOR_STATUS (230)
    :func:`estimator_flags`: the ESTIMATOR_STATUS_FLAGS that are true of navd's solution.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mavlink

from navd.io.mavlink.encode import MavlinkEncoder
from navd.types import NavSolution

__all__ = [
    "GPS_FIX_TYPE_3D_FIX",
    "GPS_FIX_TYPE_NO_FIX",
    "SATELLITES_UNKNOWN",
    "AutopilotPolicy",
    "HeadingResetSchedule",
    "estimator_flags",
    "fix_type",
    "gps_input_frame",
    "yaw_cdeg",
]

GPS_FIX_TYPE_NO_FIX: int = mavlink.GPS_FIX_TYPE_NO_FIX  # 1: a GPS is there, no position
GPS_FIX_TYPE_3D_FIX: int = mavlink.GPS_FIX_TYPE_3D_FIX  # 3
# navd does not see satellites; GPS_RAW_INT's "unknown" (UINT8_MAX) is the honest value
SATELLITES_UNKNOWN = 255


@dataclass(frozen=True)
class AutopilotPolicy:
    """Thresholds for what is claimed.

    aligned_sd: the heading counts as known (yaw sent) when initialised and its 1-sigma is at
        or below this, rad (the daemon passes ``[init] aligned_sd_deg``, as for Zenoh).
    max_gnss_age_us: 3D fix only while the last GNSS fix used is at most this old, µs.
    uere_m: DOP = accuracy / uere (the inverse of navd's input rule accuracy = DOP * uere).
    geoid_sep_m: N = ellipsoid - MSL height; GPS_INPUT.alt is MSL.
    """

    aligned_sd: float = math.radians(2.0)
    max_gnss_age_us: int = 1_000_000
    uere_m: float = 3.0
    geoid_sep_m: float = 0.0


def yaw_cdeg(sol: NavSolution, aligned_sd: float) -> int:
    """GPS_INPUT.yaw: 0 unless the heading is aligned, else 1..36000 cdeg (north = 36000)."""
    if not sol.heading_good(aligned_sd) or not math.isfinite(sol.yaw_rad):
        return 0
    c = round(math.degrees(sol.yaw_rad) * 100.0) % 36000
    return c if c != 0 else 36000


def _gnss_fresh(sol: NavSolution, max_age_us: int) -> bool:
    return 0 <= sol.gnss_age_us <= max_age_us


def fix_type(sol: NavSolution, policy: AutopilotPolicy) -> int:
    """3D while GNSS is being used and the position sigma is known; no fix otherwise."""
    ok = _gnss_fresh(sol, policy.max_gnss_age_us) and all(
        math.isfinite(v) for v in (*sol.pos_sd_m, sol.lat_rad, sol.lon_rad, sol.alt_m))
    return GPS_FIX_TYPE_3D_FIX if ok else GPS_FIX_TYPE_NO_FIX


def _rms(*v: float) -> float:
    return math.sqrt(sum(x * x for x in v) / len(v))


def gps_input_frame(enc: MavlinkEncoder, sol: NavSolution, policy: AutopilotPolicy) -> bytes:
    """One GPS_INPUT frame for ``sol``.  Raises ValueError if lat/lon are not finite.

    horiz_accuracy = RMS of the north/east sigmas and speed_accuracy = RMS of the three
    velocity sigmas: per-axis values, which is how EKF3 uses a receiver's hAcc/sAcc.
    """
    sd_n, sd_e, sd_d = sol.pos_sd_m
    h_acc = _rms(sd_n, sd_e)
    s_acc = _rms(*sol.vel_sd_mps)
    flags = 0
    if not math.isfinite(h_acc):
        flags |= (mavlink.GPS_INPUT_IGNORE_FLAG_HORIZONTAL_ACCURACY
                  | mavlink.GPS_INPUT_IGNORE_FLAG_HDOP)
        h_acc = 0.0
    if not math.isfinite(sd_d):
        flags |= (mavlink.GPS_INPUT_IGNORE_FLAG_VERTICAL_ACCURACY
                  | mavlink.GPS_INPUT_IGNORE_FLAG_VDOP)
        sd_d = 0.0
    if not math.isfinite(s_acc):
        flags |= mavlink.GPS_INPUT_IGNORE_FLAG_SPEED_ACCURACY
        s_acc = 0.0
    vel = sol.vel_n
    if not all(math.isfinite(v) for v in vel[:2]):
        flags |= mavlink.GPS_INPUT_IGNORE_FLAG_VEL_HORIZ | mavlink.GPS_INPUT_IGNORE_FLAG_VEL_VERT
        vel = (0.0, 0.0, 0.0)
    elif not math.isfinite(vel[2]):
        flags |= mavlink.GPS_INPUT_IGNORE_FLAG_VEL_VERT
        vel = (vel[0], vel[1], 0.0)
    alt = sol.alt_m - policy.geoid_sep_m
    if not math.isfinite(alt):
        flags |= mavlink.GPS_INPUT_IGNORE_FLAG_ALT
        alt = 0.0
    return enc.encode_gps_input(
        time_usec=max(sol.t_us, 0), ignore_flags=flags, fix_type=fix_type(sol, policy),
        lat_deg=math.degrees(sol.lat_rad), lon_deg=math.degrees(sol.lon_rad),
        alt_msl_m=alt, hdop=h_acc / policy.uere_m, vdop=sd_d / policy.uere_m, vel_n=vel,
        speed_acc_mps=s_acc, horiz_acc_m=h_acc, vert_acc_m=sd_d,
        satellites=SATELLITES_UNKNOWN, yaw_cdeg=yaw_cdeg(sol, policy.aligned_sd),
    )


def estimator_flags(sol: NavSolution, policy: AutopilotPolicy) -> int:
    """ESTIMATOR_STATUS_FLAGS true of ``sol`` (docs/autopilot.md has the table).

    ATTITUDE needs the heading aligned too: roll and pitch alone are not an attitude an
    autopilot can steer by.  Velocity and position flags need GNSS in use; while coasting
    only PRED_POS_HORIZ_ABS says a fix would give position again.
    """
    f = 0
    if sol.heading_good(policy.aligned_sd):
        f |= mavlink.ESTIMATOR_ATTITUDE
    if _gnss_fresh(sol, policy.max_gnss_age_us):
        f |= (mavlink.ESTIMATOR_VELOCITY_HORIZ | mavlink.ESTIMATOR_VELOCITY_VERT
              | mavlink.ESTIMATOR_POS_HORIZ_REL | mavlink.ESTIMATOR_POS_HORIZ_ABS
              | mavlink.ESTIMATOR_POS_VERT_ABS)
    elif sol.gnss_age_us >= 0:
        f |= mavlink.ESTIMATOR_PRED_POS_HORIZ_ABS
    return f


class HeadingResetSchedule:
    """When to send MAV_CMD_EXTERNAL_ATTITUDE_ESTIMATE.

    A send is due when the heading becomes aligned, when it was reset while aligned
    (``NavSolution.heading_resets`` changed), and every ``period_s`` if > 0.  Sends are at
    least ``min_interval_s`` apart (host time): a due send inside that interval waits for its
    end rather than being lost.  A heading that stops being aligned cancels a waiting send.
    """

    def __init__(self, min_interval_s: float, period_s: float = 0.0) -> None:
        self.min_interval_s = min_interval_s
        self.period_s = period_s
        self._aligned = False
        self._resets = -1
        self._pending = False
        self._last_s = -math.inf
        self.sent = 0
        self.deferred = 0  # events that had to wait for the interval

    def due(self, aligned: bool, heading_resets: int, now_s: float) -> bool:
        """Feed every output; True when the command should go out now (counted as sent)."""
        event = aligned and (not self._aligned or heading_resets != self._resets)
        self._aligned = aligned
        self._resets = heading_resets
        if not aligned:
            self._pending = False
            return False
        if event or (self.period_s > 0.0 and now_s - self._last_s >= self.period_s):
            self._pending = True
        if not self._pending:
            return False
        if now_s - self._last_s < self.min_interval_s:
            if event:
                self.deferred += 1
            return False
        self._pending = False
        self._last_s = now_s
        self.sent += 1
        return True
