"""ROS 2 output (navd/io/ros2, Ros2Sink): type hashes, frames, CDR, rmw_zenoh wire format.

The CDR is written with rosbags and read back here with pycdr2 (a separate implementation);
the type hashes are recomputed with this file's own REP-2011 code; the live tests run two
Zenoh sessions on 127.0.0.1 with multicast scouting off.
"""


import asyncio
import hashlib
import json
import math
import socket
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest
import xxhash
import zenoh
import zenoh.ext as zext
from pycdr2 import IdlStruct
from pycdr2.types import array, float64, int8, int32, sequence, uint8, uint16, uint32
from rosbags.typesys import Stores, get_typestore

from navd.config.daemon import DaemonConfig, Ros2Section
from navd.config.load import ConfigError, load_config
from navd.core.earth import radii
from navd.daemon.daemon import Daemon
from navd.daemon.sinks import ROS2_TOPICS, Ros2Sink
from navd.io.ros2 import rmw
from navd.io.ros2.frames import quat_enu_flu
from navd.io.ros2.messages import DIAG_ERROR, DIAG_OK, DIAG_WARN, MessageBuilder
from navd.io.ros2.msgdefs import MSG_DEFINITIONS, TYPE_HASHES, dds_type_name
from navd.io.zenoh import ZenohConfig, ZenohPublisher
from navd.types import NavSolution

DEG = math.pi / 180.0


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def solution(**kw: Any) -> NavSolution:
    base: dict[str, Any] = dict(
        t_us=5_000_000, quat_nb=(1.0, 0.0, 0.0, 0.0), roll_rad=0.0, pitch_rad=0.0,
        yaw_rad=0.0, lat_rad=0.8, lon_rad=0.1, alt_m=500.0, vel_n=(0.0, 0.0, 0.0),
        att_sd_rad=(0.1 * DEG, 0.2 * DEG, 0.5 * DEG), gyro_bias_rps=(0.0, 0.0, 0.0),
        accel_bias_mps2=(0.0, 0.0, 0.0), heading_aligned=True, rate_b=(0.01, 0.02, 0.03),
        pos_sd_m=(1.0, 2.0, 3.0), vel_sd_mps=(0.1, 0.2, 0.3))
    base.update(kw)
    return NavSolution(**base)


# -- an independent REP-2011 (RIHS01) implementation -------------------------------------------

_PRIMITIVE_IDS = {"int8": 2, "uint8": 3, "int16": 4, "uint16": 5, "int32": 6, "uint32": 7,
                  "int64": 8, "uint64": 9, "float32": 10, "float64": 11, "char": 3,
                  "bool": 15, "byte": 16, "string": 17}
_NESTED, _FIXED_ARRAY, _UNBOUNDED_SEQ = 1, 48, 144


def _parse(text: str) -> list[tuple[str, str, int | None]]:
    """``.msg`` field lines -> (type, name, array size: None scalar, 0 unbounded, N fixed)."""
    out = []
    for line in text.splitlines():
        line = line.split("#")[0].strip()
        if not line:
            continue
        typ, name = line.split()[:2]
        size: int | None = None
        if typ.endswith("]"):
            typ, n = typ[:-1].split("[")
            size = int(n) if n else 0
        out.append((typ, name, size))
    return out


def _describe(type_name: str, defs: dict[str, str]) -> dict[str, Any]:
    fields = []
    for typ, name, size in _parse(defs[type_name]):
        nested = "" if typ in _PRIMITIVE_IDS else typ
        tid = _NESTED if nested else _PRIMITIVE_IDS[typ]
        if size is not None:
            tid += _UNBOUNDED_SEQ if size == 0 else _FIXED_ARRAY
        fields.append({"name": name, "type": {"type_id": tid, "capacity": size or 0,
                                              "string_capacity": 0,
                                              "nested_type_name": nested}})
    return {"type_name": type_name, "fields": fields}


def _referenced(type_name: str, defs: dict[str, str], seen: set[str]) -> set[str]:
    for typ, _, _ in _parse(defs[type_name]):
        if typ not in _PRIMITIVE_IDS and typ not in seen:
            seen.add(typ)
            _referenced(typ, defs, seen)
    return seen


def rihs01(type_name: str, defs: dict[str, str]) -> str:
    """sha256 of the type description as rosidl's JSON (", " and ": " separators, fields in
    declaration order, referenced types sorted by name, no default values)."""
    refs = sorted(_referenced(type_name, defs, set()))
    doc = {"type_description": _describe(type_name, defs),
           "referenced_type_descriptions": [_describe(r, defs) for r in refs]}
    text = json.dumps(doc, separators=(", ", ": "))
    return "RIHS01_" + hashlib.sha256(text.encode()).hexdigest()


# std_msgs/String, AddTwoInts: printed in rmw_zenoh docs/design.md (key expression examples).
# builtin_interfaces/Time and std_msgs/Header: the expected-hash constants rosidl_generator_c
# writes into generated *__description.c files (seen in public generated sources).
PUBLISHED = {
    "std_msgs/msg/String":
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
    "builtin_interfaces/msg/Time":
        "RIHS01_b106235e25a4c5ed35098aa0a61a3ee9c9b18d197f398b0e4206cea9acf9c197",
    "std_msgs/msg/Header":
        "RIHS01_f49fb3ae2cf070f793645ff749683ac6b06203e41c891e17701b1cb597ce6a01",
}
# The four types navd publishes: the values in public generated ROS 2 code of other
# projects (golden-hash checks of a C++ CDR library, message classes generated for Python,
# Swift and Elixir clients), all Jazzy-era; typed in here, not computed.
PUBLISHED_NAVD = {
    "sensor_msgs/msg/Imu":
        "RIHS01_7d9a00ff131080897a5ec7e26e315954b8eae3353c3f995c55faf71574000b5b",
    "sensor_msgs/msg/NavSatFix":
        "RIHS01_62223ab3fe210a15976021da7afddc9e200dc9ec75231c1b6a557fc598a65404",
    "nav_msgs/msg/Odometry":
        "RIHS01_3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0",
    "diagnostic_msgs/msg/DiagnosticArray":
        "RIHS01_5a8a36efb05fb25070fa0fb3810290c0e6cd4862b54a8fb975a1ee8dc55a333e",
}


def test_type_hashes_match_an_independent_rep2011_and_published_values() -> None:
    """GIVEN this file's own REP-2011 hashing,
    WHEN it hashes std_msgs/String, Time and Header and navd's shipped definitions,
    THEN String/Time/Header equal the values printed by rmw_zenoh's design doc and rosidl's
    generated code, the shipped Imu/NavSatFix/Odometry/DiagnosticArray hashes equal the
    values in public generated ROS 2 code, every shipped TYPE_HASHES entry equals the hash
    of navd's definitions,
    and equals rosbags' hash for the Jazzy and Kilted type stores (their own definitions)."""
    defs = {**MSG_DEFINITIONS, "std_msgs/msg/String": "string data\n"}
    for name, expected in PUBLISHED.items():
        assert rihs01(name, defs) == expected, name
    for name, expected in PUBLISHED_NAVD.items():
        assert TYPE_HASHES[name] == expected, name
    jazzy, kilted = get_typestore(Stores.ROS2_JAZZY), get_typestore(Stores.ROS2_KILTED)
    assert set(TYPE_HASHES) == {t for _, t in ROS2_TOPICS.values()}
    for name, h in TYPE_HASHES.items():
        assert rihs01(name, MSG_DEFINITIONS) == h, name
        assert jazzy.hash_rihs01(name) == h == kilted.hash_rihs01(name), name
    # the hash changes when a field changes: the check can fail
    bad = {**MSG_DEFINITIONS, "sensor_msgs/msg/NavSatStatus": "int8 status\nuint8 service\n"}
    assert rihs01("sensor_msgs/msg/NavSatFix", bad) != TYPE_HASHES["sensor_msgs/msg/NavSatFix"]


# -- frames -------------------------------------------------------------------------------------


def _mat_ned_frd(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """C_frd^ned = Rz(yaw) Ry(pitch) Rx(roll) (navd's ZYX convention)."""
    cr, sr, cp, sp, cy, sy = (math.cos(roll), math.sin(roll), math.cos(pitch),
                              math.sin(pitch), math.cos(yaw), math.sin(yaw))
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    return rz @ ry @ rx


def _quat_of(m: np.ndarray) -> tuple[float, float, float, float]:
    """(w, x, y, z) of a rotation matrix (largest-component method)."""
    t = np.trace(m)
    cand = [1 + t, 1 + 2 * m[0, 0] - t, 1 + 2 * m[1, 1] - t, 1 + 2 * m[2, 2] - t]
    k = int(np.argmax(cand))
    r = math.sqrt(cand[k]) * 2
    if k == 0:
        q = (r / 4, (m[2, 1] - m[1, 2]) / r, (m[0, 2] - m[2, 0]) / r, (m[1, 0] - m[0, 1]) / r)
    elif k == 1:
        q = ((m[2, 1] - m[1, 2]) / r, r / 4, (m[0, 1] + m[1, 0]) / r, (m[0, 2] + m[2, 0]) / r)
    elif k == 2:
        q = ((m[0, 2] - m[2, 0]) / r, (m[0, 1] + m[1, 0]) / r, r / 4, (m[1, 2] + m[2, 1]) / r)
    else:
        q = ((m[1, 0] - m[0, 1]) / r, (m[0, 2] + m[2, 0]) / r, (m[1, 2] + m[2, 1]) / r, r / 4)
    return q


def _mat_of(q: tuple[float, float, float, float]) -> np.ndarray:
    w, x, y, z = q
    return np.array([[w * w + x * x - y * y - z * z, 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), w * w - x * x + y * y - z * z, 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), w * w - x * x - y * y + z * z]])


def _rpy(m: np.ndarray) -> tuple[float, float, float]:
    return (math.degrees(math.atan2(m[2, 1], m[2, 2])), math.degrees(-math.asin(m[2, 0])),
            math.degrees(math.atan2(m[1, 0], m[0, 0])))


@pytest.mark.parametrize(("ned_rpy_deg", "enu_rpy_deg"), [
    ((0, 0, 0), (0, 0, 90)),      # facing north: ENU yaw +90 (counter-clockwise from east)
    ((0, 0, 90), (0, 0, 0)),      # facing east
    ((0, 0, -90), (0, 0, 180)),   # facing west
    ((0, 10, 90), (0, -10, 0)),   # nose up: negative pitch about FLU's left axis
    ((10, 0, 90), (10, 0, 0)),    # right wing down: positive roll in both
    ((5, -20, 30), (5, 20, 60)),
])
def test_orientation_ned_frd_to_enu_flu_known_cases(
        ned_rpy_deg: tuple[float, float, float], enu_rpy_deg: tuple[float, float, float]) -> None:
    """GIVEN navd attitudes (roll, pitch, yaw clockwise from north) with known ROS answers,
    WHEN quat_enu_flu converts the NED/FRD quaternion,
    THEN the ROS (ENU/FLU) ZYX angles are roll, -pitch, 90 deg - yaw, and the body axes
    point the same physical way: FLU forward = FRD forward, FLU left = -FRD right, FLU up =
    -FRD down, each mapped NED -> ENU by swapping north/east and negating down."""
    r, p, y = (v * DEG for v in ned_rpy_deg)
    c_nb = _mat_ned_frd(r, p, y)
    q = quat_enu_flu(_quat_of(c_nb))
    c = _mat_of(q)
    assert _rpy(c) == pytest.approx(enu_rpy_deg, abs=1e-9)
    ned_to_enu = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1]])
    assert c[:, 0] == pytest.approx(ned_to_enu @ c_nb[:, 0], abs=1e-12)
    assert c[:, 1] == pytest.approx(ned_to_enu @ -c_nb[:, 1], abs=1e-12)
    assert c[:, 2] == pytest.approx(ned_to_enu @ -c_nb[:, 2], abs=1e-12)
    assert q[0] >= 0.0 and math.isclose(sum(v * v for v in q), 1.0)


# -- CDR, decoded with pycdr2 -------------------------------------------------------------------


@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32
    nanosec: uint32


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time
    frame_id: str


@dataclass
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: float64
    y: float64
    z: float64


@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: float64
    y: float64
    z: float64
    w: float64


@dataclass
class Imu(IdlStruct, typename="sensor_msgs::msg::dds_::Imu_"):
    header: Header
    orientation: Quaternion
    orientation_covariance: array[float64, 9]
    angular_velocity: Vector3
    angular_velocity_covariance: array[float64, 9]
    linear_acceleration: Vector3
    linear_acceleration_covariance: array[float64, 9]


@dataclass
class NavSatStatus(IdlStruct, typename="sensor_msgs::msg::dds_::NavSatStatus_"):
    status: int8
    service: uint16


@dataclass
class NavSatFix(IdlStruct, typename="sensor_msgs::msg::dds_::NavSatFix_"):
    header: Header
    status: NavSatStatus
    latitude: float64
    longitude: float64
    altitude: float64
    position_covariance: array[float64, 9]
    position_covariance_type: uint8


@dataclass
class Pose(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
    position: Vector3  # Point has the same layout
    orientation: Quaternion


@dataclass
class PoseWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::PoseWithCovariance_"):
    pose: Pose
    covariance: array[float64, 36]


@dataclass
class Twist(IdlStruct, typename="geometry_msgs::msg::dds_::Twist_"):
    linear: Vector3
    angular: Vector3


@dataclass
class TwistWithCovariance(IdlStruct,
                          typename="geometry_msgs::msg::dds_::TwistWithCovariance_"):
    twist: Twist
    covariance: array[float64, 36]


@dataclass
class Odometry(IdlStruct, typename="nav_msgs::msg::dds_::Odometry_"):
    header: Header
    child_frame_id: str
    pose: PoseWithCovariance
    twist: TwistWithCovariance


@dataclass
class KeyValue(IdlStruct, typename="diagnostic_msgs::msg::dds_::KeyValue_"):
    key: str
    value: str


@dataclass
class DiagnosticStatus(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticStatus_"):
    level: uint8  # IDL octet: one byte
    name: str
    message: str
    hardware_id: str
    values: sequence[KeyValue]


@dataclass
class DiagnosticArray(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticArray_"):
    header: Header
    status: sequence[DiagnosticStatus]


DECODERS: dict[str, type[IdlStruct]] = {
    "sensor_msgs/msg/Imu": Imu, "sensor_msgs/msg/NavSatFix": NavSatFix,
    "nav_msgs/msg/Odometry": Odometry, "diagnostic_msgs/msg/DiagnosticArray": DiagnosticArray}


def decode(type_name: str, data: bytes) -> Any:
    """pycdr2 decode, after checking the CDR_LE encapsulation header; re-encoding the result
    with pycdr2 must give the same bytes (nothing left over, same padding)."""
    assert data[:4] == b"\x00\x01\x00\x00", data[:4].hex()
    msg = DECODERS[type_name].deserialize(data)
    assert msg.serialize() == data
    return msg


STAMP_NS = 1_700_000_000_123_456_789


def test_cdr_messages_decode_with_pycdr2() -> None:
    """GIVEN a level solution heading east (yaw 90 deg) at 5 m/s with known sigmas,
    WHEN navd builds and serialises Imu, NavSatFix, Odometry and DiagnosticArray (rosbags),
    THEN pycdr2 decodes each: stamps and frames, ENU/FLU orientation (identity: FLU forward
    is east), orientation variances, rate in FLU, "no acceleration" marker, lat/lon in
    degrees with ENU variances, Odometry at the origin with body-frame velocity (5, 0, 0),
    and the heading status OK."""
    b = MessageBuilder("base_link", "map")
    sol = solution(quat_nb=(math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4)),
                   yaw_rad=math.pi / 2, vel_n=(0.0, 5.0, 0.0))
    imu = decode("sensor_msgs/msg/Imu", b.serialize(b.imu(sol, STAMP_NS)))
    assert (imu.header.stamp.sec, imu.header.stamp.nanosec) == (1_700_000_000, 123_456_789)
    assert imu.header.frame_id == "base_link"
    o = imu.orientation
    assert (o.x, o.y, o.z, o.w) == pytest.approx((0.0, 0.0, 0.0, 1.0), abs=1e-12)
    assert imu.orientation_covariance == pytest.approx(
        np.diag([(0.1 * DEG) ** 2, (0.2 * DEG) ** 2, (0.5 * DEG) ** 2]).ravel())
    w = imu.angular_velocity
    assert (w.x, w.y, w.z) == pytest.approx((0.01, -0.02, -0.03))
    assert imu.linear_acceleration_covariance[0] == -1.0

    fix = decode("sensor_msgs/msg/NavSatFix", b.serialize(b.navsatfix(sol, STAMP_NS)))
    assert (fix.latitude, fix.longitude, fix.altitude) == pytest.approx(
        (math.degrees(0.8), math.degrees(0.1), 500.0))
    assert fix.position_covariance == pytest.approx([4.0, 0, 0, 0, 1.0, 0, 0, 0, 9.0])
    assert fix.position_covariance_type == 2 and fix.status.status == 0

    odom = decode("nav_msgs/msg/Odometry", b.serialize(b.odometry(sol, STAMP_NS)))
    assert odom.header.frame_id == "map" and odom.child_frame_id == "base_link"
    p = odom.pose.pose.position
    assert (p.x, p.y, p.z) == pytest.approx((0.0, 0.0, 0.0), abs=1e-9)
    assert np.diag(np.reshape(odom.pose.covariance, (6, 6))) == pytest.approx(
        [4.0, 1.0, 9.0, (0.1 * DEG) ** 2, (0.2 * DEG) ** 2, (0.5 * DEG) ** 2])
    v = odom.twist.twist.linear
    assert (v.x, v.y, v.z) == pytest.approx((5.0, 0.0, 0.0), abs=1e-12)
    # body x = east: its variance is the east one (0.2^2), body y (left) = north (0.1^2)
    assert np.diag(np.reshape(odom.twist.covariance, (6, 6)))[:3] == pytest.approx(
        [0.04, 0.01, 0.09])

    diag = decode("diagnostic_msgs/msg/DiagnosticArray",
                  b.serialize(b.diagnostics(sol, STAMP_NS, 1.0 * DEG, "navd")))
    (st,) = diag.status
    assert st.level == DIAG_OK and st.name == "navd: heading" and st.hardware_id == "navd"
    kv = {x.key: x.value for x in st.values}
    assert float(kv["heading_deg"]) == pytest.approx(90.0)
    assert float(kv["yaw_enu_deg"]) == pytest.approx(0.0, abs=1e-9)
    assert kv["aligned"] == "true" and float(kv["yaw_sd_deg"]) == pytest.approx(0.5)


def test_odometry_position_is_local_enu_and_statuses_degrade() -> None:
    """GIVEN a first solution (the origin), then one 100 m north and 50 m east of it and
    10 m higher, with non-finite position sigmas,
    WHEN Odometry and NavSatFix are built, and diagnostics for a heading wider than the
    aligned bound and for one not yet initialised,
    THEN Odometry is at (50, 100, 10) m ENU to 1 cm, the fix reports covariance UNKNOWN,
    and the status levels are WARN and ERROR."""
    b = MessageBuilder("base_link", "map")
    first = solution()
    b.odometry(first, STAMP_NS)
    r_m, r_n = radii(0.8)
    moved = solution(lat_rad=0.8 + 100.0 / (r_m + 500.0),
                     lon_rad=0.1 + 50.0 / ((r_n + 500.0) * math.cos(0.8)), alt_m=510.0,
                     pos_sd_m=(math.nan, 1.0, 1.0))
    odom = decode("nav_msgs/msg/Odometry", b.serialize(b.odometry(moved, STAMP_NS)))
    p = odom.pose.pose.position
    assert (p.x, p.y, p.z) == pytest.approx((50.0, 100.0, 10.0), abs=0.01)
    fix = decode("sensor_msgs/msg/NavSatFix", b.serialize(b.navsatfix(moved, STAMP_NS)))
    assert fix.position_covariance_type == 0 and fix.position_covariance == [0.0] * 9
    wide = decode("diagnostic_msgs/msg/DiagnosticArray",
                  b.serialize(b.diagnostics(first, STAMP_NS, 0.1 * DEG, "navd")))
    assert wide.status[0].level == DIAG_WARN and "0.50 deg > 0.1 deg" in wide.status[0].message
    none = decode("diagnostic_msgs/msg/DiagnosticArray", b.serialize(
        b.diagnostics(solution(heading_aligned=False), STAMP_NS, 1.0 * DEG, "navd")))
    assert none.status[0].level == DIAG_ERROR


def test_solution_position_and_velocity_sigmas_in_metres() -> None:
    """GIVEN the default estimator levelled at rest and started by GNSS fixes (h_acc 2 m),
    WHEN the first navigating solution and one 19 s later are read,
    THEN the first reports the configured start-up sigmas ([init] pos_sd_m, vel_sd_mps) in
    metres along N, E and D (the filter holds latitude/longitude errors in radians), and the
    later one sigmas shrunk below the fixes' 2 m and the start-up 0.5 m/s."""
    from navd.config.aiding import NavConfig
    from navd.pipeline import build_estimator, output_instant
    from navd.types import GnssSample, ImuSample

    nav = NavConfig()
    est = build_estimator(nav)
    sols = []
    for k in range(1, 2001):
        t_us = k * 10_000
        if output_instant(est, ImuSample(t_us, 10_000, 0.0, 0.0, 0.0, 0.0, 0.0, -0.098)):
            sols.append(est.solution())
        if k % 10 == 5 and k > 10:
            tv = t_us - 50_000
            est.push(GnssSample(tv, 0.6 + 10.0 * tv * 1e-6 / 6.37e6, 1.9, 400.0, 10.0, 0.0, 0.0,
                                2.0, 3.0, 0.1))
    init = nav.estimator.init
    assert sols[0].pos_sd_m == pytest.approx((init.pos_sd,) * 3, rel=1e-9)
    assert sols[0].vel_sd_mps == pytest.approx((init.vel_sd,) * 3, rel=1e-9)
    assert max(sols[-1].pos_sd_m[:2]) < 2.0 and max(sols[-1].vel_sd_mps) < init.vel_sd


# -- rmw_zenoh wire format ------------------------------------------------------------------------

STRING = "std_msgs/msg/String"
STRING_HASH = PUBLISHED[STRING]


def test_key_expressions_and_tokens_reproduce_rmw_zenoh_examples() -> None:
    """GIVEN the examples in rmw_zenoh's docs/design.md (talker/listener on /chatter, domain
    2, and the /robot1 namespace),
    WHEN navd's helpers build the same key expressions and liveliness tokens,
    THEN they are character for character the documented ones; navd's own Imu key and
    publisher token follow the same layout."""
    assert rmw.topic_key(0, "/chatter", STRING, STRING_HASH) == (
        f"0/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}")
    fq = rmw.fully_qualified("/robot1", "chatter")
    assert rmw.topic_key(0, fq, STRING, STRING_HASH) == (
        f"0/robot1/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}")
    zid = "aac3178e146ba6f1fc6e6a4085e77f21"
    assert rmw.node_token(2, zid, 0, "/", "/", "listener") == (
        f"@ros2_lv/2/{zid}/0/0/NN/%/%/listener")
    zid = "8b20917502ee955ac4476e0266340d5c"
    assert rmw.publisher_token(2, zid, 0, 10, "/", "/", "talker", "/chatter", STRING,
                               "::,7:,:,:,,", STRING_HASH) == (
        f"@ros2_lv/2/{zid}/0/10/MP/%/%/talker/%chatter/std_msgs::msg::dds_::String_/"
        f"{STRING_HASH}/::,7:,:,:,,")
    imu = "sensor_msgs/msg/Imu"
    fq = rmw.fully_qualified("/robot1", "imu")
    assert rmw.topic_key(3, fq, imu) == f"3/robot1/imu/{dds_type_name(imu)}/{TYPE_HASHES[imu]}"
    assert rmw.publisher_token(3, "ab", 0, 1, "/", "/robot1", "navd", fq, imu) == (
        f"@ros2_lv/3/ab/0/1/MP/%/%robot1/navd/%robot1%imu/sensor_msgs::msg::dds_::Imu_/"
        f"{TYPE_HASHES[imu]}/::,10:,:,:,,")
    assert rmw.fully_qualified("/robot1", "/diagnostics") == "/diagnostics"


def test_attachment_layout_decodes_with_zenoh_ext() -> None:
    """GIVEN sequence number 7, a source time in ns and a publisher GID,
    WHEN the attachment is built,
    THEN it is 33 bytes that Zenoh's own deserializer (what rmw_zenoh uses) reads as
    (int64, int64, 16 bytes), Zenoh's serializer writes the same bytes, and the GID is
    XXH3-128 of the token, low 64 bits first, little-endian."""
    token = "@ros2_lv/0/ab/0/1/MP/%/%/navd/%imu/x/y/::,10:,:,:,,"
    gid = rmw.entity_gid(token)
    assert gid == xxhash.xxh3_128_digest(token.encode())[::-1]  # canonical digest is big-endian
    att = rmw.attachment(7, STAMP_NS, gid)
    assert len(att) == 33
    seq, ts, g = zext.z_deserialize(tuple[zext.Int64, zext.Int64, bytes], zenoh.ZBytes(att))
    assert (seq, ts, g) == (7, STAMP_NS, gid)
    # and Zenoh's serializer writes exactly these bytes (no more: the Python deserializer
    # would ignore trailing bytes that rmw_zenoh's C++ one refuses)
    assert zext.z_serialize((zext.Int64(7), zext.Int64(STAMP_NS), gid)).to_bytes() == att


def test_config_section_defaults_and_errors() -> None:
    """GIVEN the built-in config and bad [ros2] values,
    WHEN the daemon config is built,
    THEN ROS 2 is off by default, and a relative namespace, a bad node name, a domain id
    over 232, and [ros2] without [zenoh] are refused naming the key."""
    assert DaemonConfig.from_dict({}).ros2 == Ros2Section() and not Ros2Section().enabled
    for override, msg in [('ros2.namespace="robot1"', "[ros2] namespace"),
                          ('ros2.node_name="1navd"', "[ros2] node_name"),
                          ("ros2.domain_id=233", "[ros2] domain_id"),
                          ('ros2.world_frame_id=""', "[ros2] world_frame_id")]:
        with pytest.raises(ConfigError, match=msg.replace("[", r"\[").replace("]", r"\]")):
            DaemonConfig.from_dict(load_config(None, [override]))
    with pytest.raises(ConfigError, match=r"\[ros2\] enabled.*\[zenoh\]"):
        DaemonConfig.from_dict(load_config(None, ["ros2.enabled=true", "zenoh.enabled=false"]))


# -- live, on loopback ------------------------------------------------------------------------


def _peer(listen: tuple[str, ...] = (), connect: tuple[str, ...] = ()) -> ZenohConfig:
    return ZenohConfig(vehicle="t", listen=listen, connect=connect, multicast_scouting=False)


def _tokens(session: Any, domain: int) -> set[str]:
    return {str(r.ok.key_expr) for r in session.liveliness().get(f"@ros2_lv/{domain}/**",
                                                               timeout=2.0) if r.ok}


def test_ros2_sink_publishes_like_an_rmw_zenoh_node_over_loopback() -> None:
    """GIVEN a Ros2Sink (domain 7, namespace /robot1) on a peer session listening on
    127.0.0.1 and a second session connected to it (no multicast scouting),
    WHEN solutions are published until every topic has arrived twice,
    THEN the graph holds the node token and one MP token per topic (parsed field by field as
    rmw_zenoh does: 13 chunks, zid of the publishing session, demangled names), each data key
    is domain/topic/type/hash, each attachment reads back with Zenoh's deserializer with
    sequence numbers 1, 2, ..., a host-clock timestamp and the GID of its token, the payloads
    decode with pycdr2, and after close the tokens are gone.  (Two samples per topic: each
    publish sends all four, diagnostics too since the sensor time steps 1 s.)"""
    port = free_port()
    cfg = Ros2Section(enabled=True, domain_id=7, namespace="/robot1", frame_id="imu_link")
    with ZenohPublisher(_peer(listen=(f"tcp/127.0.0.1:{port}",))) as pub_session:
        sink = Ros2Sink(pub_session.session, cfg, aligned_sd_rad=1.0 * DEG)
        sub = zenoh.open(_peer(connect=(f"tcp/127.0.0.1:{port}",)).to_zenoh())
        got: dict[str, list[Any]] = {}
        try:
            s = sub.declare_subscriber("7/**", lambda smp: got.setdefault(
                str(smp.key_expr), []).append(smp))
            t0 = time.time_ns()
            deadline = time.monotonic() + 15.0
            t_us = 1_000_000
            n_published = 0
            while (len(got) < 4 or min(len(v) for v in got.values()) < 2) \
                    and time.monotonic() < deadline:
                sink.publish(solution(t_us=t_us))
                n_published += 1
                t_us += 1_000_000  # a sensor second: diagnostics every time
                time.sleep(0.05)
            t1 = time.time_ns()
            kinds = {rmw.fully_qualified("/robot1", topic): k
                     for k, (topic, _) in ROS2_TOPICS.items()}
            tokens = _tokens(sub, 7)
            zid = str(pub_session.session.zid())
            node = f"@ros2_lv/7/{zid}/0/0/NN/%/%robot1/navd"
            assert node in tokens
            by_topic: dict[str, str] = {}
            for tok in tokens - {node}:
                parts = tok.split("/")
                assert len(parts) == 13 and parts[:3] == ["@ros2_lv", "7", zid], tok
                assert parts[5] == "MP" and parts[6:9] == ["%", "%robot1", "navd"]
                assert parts[12] == rmw.DEFAULT_QOS
                by_topic[parts[9].replace("%", "/")] = tok
            assert set(by_topic) == {"/robot1/imu", "/robot1/fix", "/robot1/odom",
                                     "/diagnostics"}
            assert sink.stats.snapshot().get("imu_put_error", 0) == 0
            for topic, typ in (("/robot1/imu", "sensor_msgs/msg/Imu"),
                               ("/robot1/fix", "sensor_msgs/msg/NavSatFix"),
                               ("/robot1/odom", "nav_msgs/msg/Odometry"),
                               ("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray")):
                tok = by_topic[topic]
                assert tok.split("/")[10:12] == [dds_type_name(typ), TYPE_HASHES[typ]]
                key = f"7/{topic.strip('/')}/{dds_type_name(typ)}/{TYPE_HASHES[typ]}"
                samples = got[key]
                seqs = []
                for smp in samples:
                    seq, ts, gid = zext.z_deserialize(
                        tuple[zext.Int64, zext.Int64, bytes], smp.attachment)
                    seqs.append(seq)
                    assert t0 <= ts <= t1 and gid == rmw.entity_gid(tok)
                    msg = decode(typ, smp.payload.to_bytes())
                # the first samples may go out before the subscription has propagated:
                # what arrives is consecutive, and the publisher numbered from 1
                assert seqs == list(range(seqs[0], seqs[0] + len(seqs))) and seqs[0] >= 1
                assert sink.pubs[kinds[topic]].seq == n_published >= seqs[-1]
                assert msg.header.frame_id == ("map" if "odom" in topic else "imu_link")
            sink.close()
            deadline = time.monotonic() + 10.0
            while _tokens(sub, 7) and time.monotonic() < deadline:
                time.sleep(0.1)
            assert _tokens(sub, 7) == set()
            s.undeclare()
        finally:
            sink.close()
            sub.close()  # type: ignore[no-untyped-call]


def test_daemon_wires_the_ros2_sink_to_its_zenoh_session() -> None:
    """GIVEN a daemon config with [ros2] enabled on a loopback Zenoh endpoint,
    WHEN the daemon opens its inputs and outputs,
    THEN a Ros2Sink on the daemon's own Zenoh session is among the sinks, the ready line
    names the node and its topics, and a session connected to the daemon sees the node's
    liveliness token; closing the daemon removes it."""
    zport, uport = free_port(), free_port()
    cfg = DaemonConfig.from_dict(load_config(None, [
        f'zenoh.listen=["tcp/127.0.0.1:{zport}"]', "ros2.enabled=true",
        f'mavlink.listen="udpin:127.0.0.1:{uport}"', 'mavlink.send=""',
        "daemon.warm_up=false"]))
    d = Daemon(cfg, handle_signals=False)
    sub = zenoh.open(_peer(connect=(f"tcp/127.0.0.1:{zport}",)).to_zenoh())

    async def wait_tokens(want: bool, key: str) -> None:
        deadline = time.monotonic() + 10.0
        while (key in _tokens(sub, 0)) != want and time.monotonic() < deadline:
            await asyncio.sleep(0.1)

    async def go() -> None:
        await d._open()
        try:
            (sink,) = [s for s in d.sinks if isinstance(s, Ros2Sink)]
            assert d.zenoh_sink is not None
            assert sink.node.session is d.zenoh_sink.publisher.session
            line = "; ".join(d.output_destinations())
            assert "ros2 node /navd (domain 0) /imu /fix /odom /diagnostics 50 Hz" in line
            await wait_tokens(True, sink.node.token_key)
            assert sink.node.token_key in _tokens(sub, 0)
        finally:
            d._close()
        await wait_tokens(False, sink.node.token_key)
        assert _tokens(sub, 0) == set()

    try:
        asyncio.run(go())
    finally:
        sub.close()  # type: ignore[no-untyped-call]


def test_a_ros2_subscriber_gets_navd_heading_from_a_simulated_drive() -> None:
    """GIVEN the daemon with [ros2] on a loopback Zenoh endpoint, a second session subscribed
    to the Imu key, and 60 s of the simulated car drive pushed through the daemon's
    estimator loop (a callback sink at the same rate records the published solutions),
    WHEN the subscriber decodes each Imu sample with pycdr2 and pairs it with its solution
    by the attachment's sequence number,
    THEN most samples arrive, each orientation is the solution's attitude in ENU/FLU, and
    once the heading variance is below (2 deg)^2 the heading read back from the ROS message
    (90 deg - ENU yaw) is within 3 sigma (the message's own covariance) of the truth."""
    from navd.daemon.sinks import CallbackSink
    from tests.daemon_util import car_run, heading_errors_deg

    run = car_run(60.0)
    zport, uport = free_port(), free_port()
    cfg = DaemonConfig.from_dict(load_config(None, [
        f'zenoh.listen=["tcp/127.0.0.1:{zport}"]', "ros2.enabled=true", "ros2.rate_hz=10",
        f'mavlink.listen="udpin:127.0.0.1:{uport}"', 'mavlink.send=""',
        "daemon.warm_up=false", "daemon.queue_size=100000"]))  # the whole drive queued
    d = Daemon(cfg, handle_signals=False)
    sols: list[NavSolution] = []
    key = (f"0/imu/{dds_type_name('sensor_msgs/msg/Imu')}/"
           f"{TYPE_HASHES['sensor_msgs/msg/Imu']}")
    got: list[tuple[int, bytes]] = []
    sub = zenoh.open(_peer(connect=(f"tcp/127.0.0.1:{zport}",)).to_zenoh())

    def on_sample(smp: Any) -> None:
        seq, _, _ = zext.z_deserialize(tuple[zext.Int64, zext.Int64, bytes], smp.attachment)
        got.append((seq, smp.payload.to_bytes()))

    async def go() -> None:
        await d._open()
        try:
            d.sinks.append(CallbackSink(sols.append, 10.0))
            node = next(s for s in d.sinks if isinstance(s, Ros2Sink)).node.token_key
            deadline = time.monotonic() + 10.0
            while node not in _tokens(sub, 0) and time.monotonic() < deadline:
                await asyncio.sleep(0.1)
            await asyncio.sleep(0.5)  # the subscription reaches the publisher's session
            for s in run.samples():
                d.queue.put(0, s)
            d.queue.close()
            await d._estimate()
            await asyncio.sleep(1.0)
        finally:
            d._close()

    s_ = sub.declare_subscriber(key, on_sample)
    try:
        asyncio.run(go())
    finally:
        s_.undeclare()
        sub.close()  # type: ignore[no-untyped-call]
    assert len(sols) > 400 and len(got) >= 0.95 * len(sols), (len(got), len(sols))
    t_us, yaw, sd = [], [], []
    for seq, data in got:
        sol = sols[seq - 1]
        imu = decode("sensor_msgs/msg/Imu", data)
        o = imu.orientation
        q = quat_enu_flu(sol.quat_nb)
        assert (o.w, o.x, o.y, o.z) == pytest.approx(q, abs=1e-12)
        c = _mat_of((o.w, o.x, o.y, o.z))
        yaw_enu = math.atan2(c[1, 0], c[0, 0])
        var = imu.orientation_covariance[8]
        if var < (2.0 * DEG) ** 2:
            t_us.append(sol.t_us)
            yaw.append(math.pi / 2 - yaw_enu)
            sd.append(math.sqrt(var))
    assert len(t_us) > 100, "heading never aligned in the drive"
    err = heading_errors_deg(run, t_us, yaw)
    assert np.all(np.abs(err) <= 3.0 * np.degrees(sd)), float(np.max(np.abs(err) / np.degrees(sd)))
