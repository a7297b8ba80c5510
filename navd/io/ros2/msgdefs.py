"""The ROS 2 message types navd publishes: definitions, DDS names and RIHS01 type hashes.

Shipped with navd so nothing is fetched at run time.  The definitions are the field lists of
the ROS 2 interfaces (common_interfaces, rcl_interfaces; identical from Iron to Rolling for
these types), written in ``.msg`` syntax without comments; constants are left out because
they are not part of the wire format nor of the type hash (REP-2011 hashes fields only).

``TYPE_HASHES`` are the REP-2011 ``RIHS01`` hashes that rosidl generates for each type; a
ROS 2 node under rmw_zenoh puts them in the data key expression and in the liveliness token,
so a subscriber with another hash never matches.  ``tests/test_ros2.py`` recomputes every one
from ``MSG_DEFINITIONS`` with its own REP-2011 implementation, checks that implementation on
std_msgs/String against the value printed in rmw_zenoh's docs/design.md, and cross-checks
with rosbags' hashes.
"""

from __future__ import annotations

__all__ = ["MSG_DEFINITIONS", "PUBLISHED_TYPES", "TYPE_HASHES", "dds_type_name"]

# type name -> definition (.msg syntax; nested types by full name)
MSG_DEFINITIONS: dict[str, str] = {
    "builtin_interfaces/msg/Time": "int32 sec\nuint32 nanosec\n",
    "std_msgs/msg/Header": "builtin_interfaces/msg/Time stamp\nstring frame_id\n",
    "geometry_msgs/msg/Vector3": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/msg/Point": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/msg/Quaternion": "float64 x\nfloat64 y\nfloat64 z\nfloat64 w\n",
    "geometry_msgs/msg/Pose": "geometry_msgs/msg/Point position\n"
                              "geometry_msgs/msg/Quaternion orientation\n",
    "geometry_msgs/msg/PoseWithCovariance": "geometry_msgs/msg/Pose pose\n"
                                            "float64[36] covariance\n",
    "geometry_msgs/msg/Twist": "geometry_msgs/msg/Vector3 linear\n"
                               "geometry_msgs/msg/Vector3 angular\n",
    "geometry_msgs/msg/TwistWithCovariance": "geometry_msgs/msg/Twist twist\n"
                                             "float64[36] covariance\n",
    "sensor_msgs/msg/Imu": "std_msgs/msg/Header header\n"
                           "geometry_msgs/msg/Quaternion orientation\n"
                           "float64[9] orientation_covariance\n"
                           "geometry_msgs/msg/Vector3 angular_velocity\n"
                           "float64[9] angular_velocity_covariance\n"
                           "geometry_msgs/msg/Vector3 linear_acceleration\n"
                           "float64[9] linear_acceleration_covariance\n",
    "sensor_msgs/msg/NavSatStatus": "int8 status\nuint16 service\n",
    "sensor_msgs/msg/NavSatFix": "std_msgs/msg/Header header\n"
                                 "sensor_msgs/msg/NavSatStatus status\n"
                                 "float64 latitude\nfloat64 longitude\nfloat64 altitude\n"
                                 "float64[9] position_covariance\n"
                                 "uint8 position_covariance_type\n",
    "nav_msgs/msg/Odometry": "std_msgs/msg/Header header\nstring child_frame_id\n"
                             "geometry_msgs/msg/PoseWithCovariance pose\n"
                             "geometry_msgs/msg/TwistWithCovariance twist\n",
    "diagnostic_msgs/msg/KeyValue": "string key\nstring value\n",
    "diagnostic_msgs/msg/DiagnosticStatus": "byte level\nstring name\nstring message\n"
                                            "string hardware_id\n"
                                            "diagnostic_msgs/msg/KeyValue[] values\n",
    "diagnostic_msgs/msg/DiagnosticArray": "std_msgs/msg/Header header\n"
                                           "diagnostic_msgs/msg/DiagnosticStatus[] status\n",
}

# REP-2011 hashes of the published types (Jazzy, Kilted, Rolling: these types have not
# changed since Iron, the first distro with type hashes)
TYPE_HASHES: dict[str, str] = {
    "sensor_msgs/msg/Imu":
        "RIHS01_7d9a00ff131080897a5ec7e26e315954b8eae3353c3f995c55faf71574000b5b",
    "sensor_msgs/msg/NavSatFix":
        "RIHS01_62223ab3fe210a15976021da7afddc9e200dc9ec75231c1b6a557fc598a65404",
    "nav_msgs/msg/Odometry":
        "RIHS01_3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0",
    "diagnostic_msgs/msg/DiagnosticArray":
        "RIHS01_5a8a36efb05fb25070fa0fb3810290c0e6cd4862b54a8fb975a1ee8dc55a333e",
}

PUBLISHED_TYPES = tuple(TYPE_HASHES)


def dds_type_name(type_name: str) -> str:
    """``sensor_msgs/msg/Imu`` -> ``sensor_msgs::msg::dds_::Imu_``: the name rosidl's DDS
    type support gives the C++ struct, which rmw_zenoh puts in key expressions."""
    pkg, kind, name = type_name.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"
