"""NavSolution -> ROS 2 messages (sensor_msgs/Imu, sensor_msgs/NavSatFix, nav_msgs/Odometry,
diagnostic_msgs/DiagnosticArray) serialised as CDR, the bytes an rmw_zenoh publisher sends.

CDR: XCDR1 little-endian with the 4-byte encapsulation header ``00 01 00 00`` (CDR_LE), as
Fast-CDR writes it for rmw_zenoh; the serialiser is rosbags' (built from navd's own
definitions in :mod:`navd.io.ros2.msgdefs`, no ROS installation).

Frames (:mod:`navd.io.ros2.frames`): world ENU, body FLU (REP-103); orientation is the body
w.r.t. ENU (REP-145).  Covariances are row-major, variances only (navd reports no
correlations); an element 0 of -1 means "not estimated" (sensor_msgs/Imu convention), all
zeros "not known".

    Imu          orientation, cov diag(sd_roll^2, sd_pitch^2, sd_yaw^2) rad^2 (the same
                 variances in NED/FRD and ENU/FLU); angular_velocity = rate_b in FLU, rad/s,
                 cov unknown (zeros); linear_acceleration not estimated (cov[0] = -1)
    NavSatFix    lat/lon deg, altitude m above the WGS-84 ellipsoid; cov diag(sd_E^2, sd_N^2,
                 sd_U^2) m^2, type DIAGONAL_KNOWN (UNKNOWN when the sigmas are not finite);
                 status FIX, service GPS (navd does not know the constellations)
    Odometry     header.frame_id = world frame: local ENU (m) whose origin is the first
                 published position; child_frame_id = body frame; pose covariance
                 diag(sd_E^2, sd_N^2, sd_U^2, sd_roll^2, sd_pitch^2, sd_yaw^2); twist in the
                 body frame (nav_msgs convention): linear = velocity rotated into FLU with its
                 covariance rotated alike, angular = rate_b in FLU with unknown covariance
    DiagnosticArray  one status "navd: heading": OK when the heading is initialised and its
                 1-sigma <= the aligned bound, WARN when initialised but wider, ERROR before
                 it is initialised; key/values with the numbers
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from navd.core.earth import geodetic_to_ecef
from navd.io.ros2.frames import frd_to_flu, ned_to_enu, quat_enu_flu
from navd.io.ros2.msgdefs import MSG_DEFINITIONS
from navd.types import NavSolution

__all__ = ["DIAG_ERROR", "DIAG_OK", "DIAG_WARN", "MessageBuilder", "heading_level", "typestore"]

DIAG_OK, DIAG_WARN, DIAG_ERROR = 0, 1, 2  # diagnostic_msgs/DiagnosticStatus levels
_STATUS_FIX = 0  # sensor_msgs/NavSatStatus
_SERVICE_GPS = 1
_COV_UNKNOWN, _COV_DIAGONAL_KNOWN = 0, 2  # sensor_msgs/NavSatFix position_covariance_type

_store: Any = None


def typestore() -> Any:
    """rosbags type store with exactly navd's definitions (built once)."""
    global _store
    if _store is None:
        ts = get_typestore(Stores.EMPTY)
        for name, text in MSG_DEFINITIONS.items():
            ts.register(get_types_from_msg(text, name))
        _store = ts
    return _store


def _finite(*xs: float) -> bool:
    return all(math.isfinite(x) for x in xs)


def heading_level(sol: NavSolution, aligned_sd_rad: float) -> int:
    if not (sol.heading_initialised or sol.heading_aligned):
        return DIAG_ERROR
    return DIAG_OK if sol.heading_good(aligned_sd_rad) else DIAG_WARN


def _mat(q: tuple[float, float, float, float]) -> np.ndarray[Any, np.dtype[np.float64]]:
    """3x3 rotation matrix of the unit quaternion (w, x, y, z)."""
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


class MessageBuilder:
    """Builds and serialises the four messages for one node.

    ``frame_id``: the body frame (Imu, NavSatFix header, Odometry child frame);
    ``world_frame_id``: Odometry's header frame (local ENU).
    """

    def __init__(self, frame_id: str, world_frame_id: str) -> None:
        self.frame_id = frame_id
        self.world_frame_id = world_frame_id
        self._ts = typestore()
        self._t = self._ts.types
        self.origin: tuple[float, float, float] | None = None  # lat_rad, lon_rad, alt_m
        self._origin_ecef = (0.0, 0.0, 0.0)

    def serialize(self, msg: Any) -> bytes:
        return bytes(self._ts.serialize_cdr(msg, msg.__msgtype__))

    def _header(self, stamp_ns: int, frame_id: str) -> Any:
        t = self._t
        sec, nsec = divmod(stamp_ns, 1_000_000_000)
        return t["std_msgs/msg/Header"](
            stamp=t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec), frame_id=frame_id)

    def _quat(self, sol: NavSolution) -> Any:
        w, x, y, z = quat_enu_flu(sol.quat_nb)
        return self._t["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w)

    def _vec(self, v: tuple[float, float, float]) -> Any:
        return self._t["geometry_msgs/msg/Vector3"](x=v[0], y=v[1], z=v[2])

    def imu(self, sol: NavSolution, stamp_ns: int) -> Any:
        sr, sp, sy = sol.att_sd_rad
        cov_att = np.zeros(9)
        if _finite(sr, sp, sy):
            cov_att[0], cov_att[4], cov_att[8] = sr * sr, sp * sp, sy * sy
        else:
            cov_att[0] = -1.0
        cov_acc = np.zeros(9)
        cov_acc[0] = -1.0
        return self._t["sensor_msgs/msg/Imu"](
            header=self._header(stamp_ns, self.frame_id), orientation=self._quat(sol),
            orientation_covariance=cov_att,
            angular_velocity=self._vec(frd_to_flu(sol.rate_b)),
            angular_velocity_covariance=np.zeros(9),
            linear_acceleration=self._vec((0.0, 0.0, 0.0)),
            linear_acceleration_covariance=cov_acc)

    def navsatfix(self, sol: NavSolution, stamp_ns: int) -> Any:
        sd_e, sd_n, sd_u = ned_to_enu(sol.pos_sd_m)
        cov = np.zeros(9)
        kind = _COV_UNKNOWN
        if _finite(sd_e, sd_n, sd_u):
            cov[0], cov[4], cov[8] = sd_e * sd_e, sd_n * sd_n, sd_u * sd_u
            kind = _COV_DIAGONAL_KNOWN
        t = self._t
        return t["sensor_msgs/msg/NavSatFix"](
            header=self._header(stamp_ns, self.frame_id),
            status=t["sensor_msgs/msg/NavSatStatus"](status=_STATUS_FIX, service=_SERVICE_GPS),
            latitude=math.degrees(sol.lat_rad), longitude=math.degrees(sol.lon_rad),
            altitude=sol.alt_m, position_covariance=cov, position_covariance_type=kind)

    def local_enu(self, sol: NavSolution) -> tuple[float, float, float]:
        """Position in the local ENU frame (m) whose origin is the first position seen."""
        if self.origin is None:
            self.origin = (sol.lat_rad, sol.lon_rad, sol.alt_m)
            self._origin_ecef = geodetic_to_ecef(*self.origin)
        lat0, lon0, _ = self.origin
        x, y, z = geodetic_to_ecef(sol.lat_rad, sol.lon_rad, sol.alt_m)
        dx, dy, dz = (x - self._origin_ecef[0], y - self._origin_ecef[1],
                      z - self._origin_ecef[2])
        sl, cl = math.sin(lat0), math.cos(lat0)
        so, co = math.sin(lon0), math.cos(lon0)
        return (-so * dx + co * dy,
                -sl * co * dx - sl * so * dy + cl * dz,
                cl * co * dx + cl * so * dy + sl * dz)

    def odometry(self, sol: NavSolution, stamp_ns: int) -> Any:
        t = self._t
        q = quat_enu_flu(sol.quat_nb)
        mat_enu_flu = _mat(q)
        e, n, u = self.local_enu(sol)
        pose_cov = np.zeros(36)
        var_pos = [s * s for s in ned_to_enu(sol.pos_sd_m)]
        var_att = [s * s for s in sol.att_sd_rad]
        for i, v in enumerate(var_pos + var_att):
            pose_cov[7 * i] = v if math.isfinite(v) else 0.0
        vel_flu = mat_enu_flu.T @ np.array(ned_to_enu(sol.vel_n))
        cov_vel_enu = np.diag([s * s if math.isfinite(s) else 0.0
                               for s in ned_to_enu(sol.vel_sd_mps)])
        cov_vel_flu = mat_enu_flu.T @ cov_vel_enu @ mat_enu_flu
        twist_cov = np.zeros((6, 6))
        twist_cov[:3, :3] = cov_vel_flu
        return t["nav_msgs/msg/Odometry"](
            header=self._header(stamp_ns, self.world_frame_id), child_frame_id=self.frame_id,
            pose=t["geometry_msgs/msg/PoseWithCovariance"](
                pose=t["geometry_msgs/msg/Pose"](
                    position=t["geometry_msgs/msg/Point"](x=e, y=n, z=u),
                    orientation=t["geometry_msgs/msg/Quaternion"](x=q[1], y=q[2], z=q[3],
                                                                  w=q[0])),
                covariance=pose_cov),
            twist=t["geometry_msgs/msg/TwistWithCovariance"](
                twist=t["geometry_msgs/msg/Twist"](
                    linear=self._vec((float(vel_flu[0]), float(vel_flu[1]),
                                      float(vel_flu[2]))),
                    angular=self._vec(frd_to_flu(sol.rate_b))),
                covariance=twist_cov.reshape(36)))

    def diagnostics(self, sol: NavSolution, stamp_ns: int, aligned_sd_rad: float,
                    hardware_id: str) -> Any:
        t = self._t
        level = heading_level(sol, aligned_sd_rad)
        sd_deg = math.degrees(sol.att_sd_rad[2])
        bound_deg = math.degrees(aligned_sd_rad)
        text = {DIAG_OK: "heading aligned",
                DIAG_WARN: f"heading initialised, 1-sigma {sd_deg:.2f} deg > {bound_deg:g} deg",
                DIAG_ERROR: "heading not initialised"}[level]
        yaw_ned = math.degrees(sol.yaw_rad)
        yaw_enu = math.degrees(math.remainder(math.pi / 2 - sol.yaw_rad, 2 * math.pi))
        pairs = [("yaw_enu_deg", f"{yaw_enu:.3f}"), ("heading_deg", f"{yaw_ned % 360.0:.3f}"),
                 ("yaw_sd_deg", f"{sd_deg:.3f}"),
                 ("roll_sd_deg", f"{math.degrees(sol.att_sd_rad[0]):.3f}"),
                 ("pitch_sd_deg", f"{math.degrees(sol.att_sd_rad[1]):.3f}"),
                 ("aligned_sd_deg", f"{bound_deg:g}"),
                 ("heading_initialised",
                  str(bool(sol.heading_initialised or sol.heading_aligned)).lower()),
                 ("aligned", str(level == DIAG_OK).lower()),
                 ("t_us", str(sol.t_us))]
        status = t["diagnostic_msgs/msg/DiagnosticStatus"](
            level=level, name="navd: heading", message=text, hardware_id=hardware_id,
            values=[t["diagnostic_msgs/msg/KeyValue"](key=k, value=v) for k, v in pairs])
        return t["diagnostic_msgs/msg/DiagnosticArray"](
            header=self._header(stamp_ns, self.frame_id), status=[status])
