"""``navd replay --mcap`` / ``navd run --mcap`` (navd/io/foxglove_mcap.py): the file is read
back with the ``mcap`` package's reader and checked for what Foxglove needs: the schema names
of its well-known types (foxglove.PoseInFrame, foxglove.LocationFix) with ``jsonschema``
schema encoding and ``json`` messages, messages valid against the schemas written into the
file, and contents that match the solution CSV written by the same replay.  The live daemon
case is in tests/test_daemon_autopilot.py.

The foxglove.* channels are also checked against Foxglove's official definition of each
schema, read from the foxglove-sdk wheel (tests/foxglove_official.py), not against the
schema text navd writes: a field name, type or enum number of navd's own that Foxglove does
not have fails there."""

from __future__ import annotations

import csv
import json
import math
import re
from pathlib import Path
from typing import Any

import foxglove.messages as fm
import jsonschema
import numpy as np
import pytest
from foxglove_official import (
    assert_official,
    decode_official,
    official_descriptors,
    official_json_schema,
    schema_text_problems,
    sdk_enum_members,
    sdk_round_trip,
)
from mcap.reader import make_reader

from firmware_sim import generate, load_scenario
from navd.cli.replay import main as replay_main
from navd.io.foxglove_mcap import CHANNELS, FoxgloveMessages, encode_json, enu_flu_quat
from navd.types import NavSolution

WGS84_A, WGS84_E2 = 6378137.0, 6.69437999014e-3


def read_mcap(path: Path) -> dict[str, Any]:
    """{"schemas": {topic: (name, encoding, schema dict)}, "encodings": {topic: enc},
    "messages": {topic: [(log_time, obj)]}}"""
    out: dict[str, Any] = {"schemas": {}, "encodings": {}, "messages": {}}
    with open(path, "rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        assert summary is not None, "finished file: summary section present"
        for schema, channel, message in reader.iter_messages():
            t = channel.topic
            out["schemas"][t] = (schema.name, schema.encoding, json.loads(schema.data))
            out["encodings"][t] = channel.message_encoding
            out["messages"].setdefault(t, []).append((message.log_time,
                                                      json.loads(message.data)))
    return out


def _euler_mat(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """C_b^n for ZYX Euler angles, written out independently of navd.core.rotation."""
    cr, sr, cp, sp, cy, sy = (math.cos(roll), math.sin(roll), math.cos(pitch),
                              math.sin(pitch), math.cos(yaw), math.sin(yaw))
    return np.array([[cp * cy, sr * sp * cy - cr * sy, cr * sp * cy + sr * sy],
                     [cp * sy, sr * sp * sy + cr * cy, cr * sp * sy - sr * cy],
                     [-sp, sr * cp, cr * cp]])


def _quat_mat(q: tuple[float, float, float, float]) -> np.ndarray:
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _mat_quat(m: np.ndarray) -> tuple[float, float, float, float]:
    w = math.sqrt(max(0.0, 1 + m[0, 0] + m[1, 1] + m[2, 2])) / 2
    if w > 1e-3:
        return (w, (m[2, 1] - m[1, 2]) / (4 * w), (m[0, 2] - m[2, 0]) / (4 * w),
                (m[1, 0] - m[0, 1]) / (4 * w))
    raise AssertionError("test angles avoid the w ~ 0 branch")


ENU_NED = np.array([[0.0, 1, 0], [1, 0, 0], [0, 0, -1]])  # x_enu = ENU_NED @ x_ned
FRD_FLU = np.diag([1.0, -1, -1])                        # x_frd = FRD_FLU @ x_flu


@pytest.mark.parametrize("euler_deg", [(0, 0, 0), (10, -5, 30), (-20, 15, -120),
                                       (3, 40, 179), (0, 0, -90)])
def test_enu_flu_quaternion_matches_the_rotation_matrices(euler_deg: tuple[float, ...]) -> None:
    r, p, y = (math.radians(v) for v in euler_deg)
    c_nb = _euler_mat(r, p, y)
    q_enu_flu = enu_flu_quat(_mat_quat(c_nb))
    np.testing.assert_allclose(_quat_mat(q_enu_flu), ENU_NED @ c_nb @ FRD_FLU, atol=1e-12)


def test_enu_flu_known_cases() -> None:
    s = math.sqrt(0.5)
    # level, facing north: FLU x is ENU y, a +90 deg (counter-clockwise) ENU yaw
    np.testing.assert_allclose(enu_flu_quat((1.0, 0.0, 0.0, 0.0)), (s, 0, 0, s), atol=1e-12)
    # level, facing east (navd yaw +90): ENU yaw 0, the identity
    q = enu_flu_quat((s, 0.0, 0.0, s))
    assert abs(abs(q[0]) - 1.0) < 1e-12


@pytest.fixture(scope="module")
def replayed(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    d = tmp_path_factory.mktemp("mcap")
    generate(load_scenario("car480", {"duration_s": 30.0}), seed=3).write_csv(d)
    out, mc = d / "sol.csv", d / "nav.mcap"
    rc = replay_main(["--imu", str(d / "imu.csv"), "--gnss", str(d / "gnss.csv"),
                      "--out", str(out), "--rate", "10", "--mcap", str(mc), "--quiet"])
    assert rc == 0
    return out, mc


def test_replay_mcap_channels_and_schemas_are_what_foxglove_expects(
        replayed: tuple[Path, Path]) -> None:
    _, mc = replayed
    assert not mc.with_name(mc.name + ".part").exists()
    f = read_mcap(mc)
    assert set(f["schemas"]) == {"/navd/pose", "/navd/location", "/navd/heading"}
    assert f["schemas"]["/navd/pose"][:2] == ("foxglove.PoseInFrame", "jsonschema")
    assert f["schemas"]["/navd/location"][:2] == ("foxglove.LocationFix", "jsonschema")
    assert f["schemas"]["/navd/heading"][:2] == ("navd.HeadingStatus", "jsonschema")
    assert set(f["encodings"].values()) == {"json"}
    for topic, (name, _, schema) in f["schemas"].items():
        assert schema["title"] == name == CHANNELS[topic][0]
        jsonschema.Draft7Validator.check_schema(schema)
        v = jsonschema.Draft7Validator(schema)
        for _, obj in f["messages"][topic]:
            v.validate(obj)
    # the fields Foxglove's Map and 3D panels read
    loc = f["messages"]["/navd/location"][0][1]
    assert {"timestamp", "frame_id", "latitude", "longitude", "altitude",
            "position_covariance", "position_covariance_type"} <= set(loc)
    pose = f["messages"]["/navd/pose"][0][1]
    assert set(pose["pose"]) == {"position", "orientation"}
    assert set(pose["pose"]["orientation"]) == {"x", "y", "z", "w"}


FOXGLOVE_NAMES = sorted({name for name, _ in CHANNELS.values() if name.startswith("foxglove.")})
COV_TYPE = ".foxglove.LocationFix.PositionCovarianceType"


@pytest.mark.parametrize("name", FOXGLOVE_NAMES)
def test_official_schema_read_from_the_sdk_agrees_with_the_sdk_classes(name: str) -> None:
    """The descriptor reader against the SDK's Python API: field names are the message
    class's documented parameters, enum numbers its enum members', and a message built and
    encoded by the SDK decodes to what was given."""
    assert set(FOXGLOVE_NAMES) >= {"foxglove.LocationFix", "foxglove.PoseInFrame"}
    d = official_descriptors(name)
    for msg, fields in d.messages.items():
        if msg.startswith(".foxglove."):
            doc = getattr(fm, msg.removeprefix(".foxglove.")).__doc__
            assert {f.name for f in fields} == set(re.findall(r":param (\w+):", doc)), msg
    for enum, values in d.enums.items():
        members = sdk_enum_members(enum)
        assert {v: n.replace("_", "").lower() for v, n in values.items()} == {
            v: m.name.lower() for v, m in members.items()}, enum
    if name == "foxglove.LocationFix":
        assert d.enums[COV_TYPE] == {0: "UNKNOWN", 1: "APPROXIMATED", 2: "DIAGONAL_KNOWN",
                                     3: "KNOWN"}
        sdk = fm.LocationFix(timestamp=fm.Timestamp(sec=7, nsec=8), frame_id="f",
                             latitude=1.5, longitude=-2.25, altitude=3.0,
                             position_covariance=[float(k) for k in range(9)],
                             position_covariance_type=fm.LocationFixPositionCovarianceType.Known,
                             heading=0.5)
        want = {"timestamp": {"sec": 7, "nsec": 8}, "frame_id": "f", "latitude": 1.5,
                "longitude": -2.25, "altitude": 3.0,
                "position_covariance": [float(k) for k in range(9)],
                "position_covariance_type": 3, "heading": 0.5}
        assert decode_official(name, sdk.encode()) == want
        assert sdk_round_trip(name, want) == want
    # a wrong field name is refused on both paths
    bad = {"timestamp": {"sec": 1, "nanosec": 0}}
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.Draft7Validator(official_json_schema(name)).validate(bad)
    with pytest.raises(TypeError):
        sdk_round_trip(name, bad)


def _nav_sol(t_us: int, pos_sd_m: tuple[float, float, float]) -> NavSolution:
    h = math.radians(35.0) / 2
    return NavSolution(
        t_us=t_us, quat_nb=(math.cos(h), 0.0, 0.0, math.sin(h)), roll_rad=0.0, pitch_rad=0.0,
        yaw_rad=math.radians(35.0), lat_rad=0.6, lon_rad=1.9, alt_m=400.0,
        vel_n=(0.0, 0.0, 0.0), att_sd_rad=(0.001, 0.001, 0.01), gyro_bias_rps=(0.0, 0.0, 0.0),
        accel_bias_mps2=(0.0, 0.0, 0.0), heading_aligned=True, rate_b=(0.0, 0.0, 0.0),
        pos_sd_m=pos_sd_m, vel_sd_mps=(0.1, 0.1, 0.1), gnss_age_us=0)


@pytest.mark.parametrize("pos_sd_m", [(1.0, 2.0, 3.0), (math.nan, math.nan, math.nan)])
def test_foxglove_messages_are_valid_under_the_official_schemas(
        pos_sd_m: tuple[float, float, float]) -> None:
    """Every foxglove.* message navd makes (the same objects go to the MCAP file and the live
    server), with a known and an unknown position covariance."""
    out = FoxgloveMessages(math.radians(2.0)).of(_nav_sol(3_000_250, pos_sd_m))
    seen: set[str] = set()
    for topic, obj in out:
        name, schema = CHANNELS[topic]
        if not name.startswith("foxglove."):
            continue
        seen.add(name)
        msg = json.loads(encode_json(obj))
        assert_official(name, msg)
        assert schema_text_problems(schema, official_json_schema(name)) == []
        assert msg["timestamp"] == {"sec": 3, "nsec": 250_000}
    assert seen == set(FOXGLOVE_NAMES)
    loc = json.loads(encode_json(dict(out)["/navd/location"]))
    kind = official_descriptors("foxglove.LocationFix").enums[COV_TYPE][
        loc["position_covariance_type"]]
    cov = loc["position_covariance"]
    if math.isnan(pos_sd_m[0]):
        assert kind == "UNKNOWN" and cov == [0.0] * 9
    else:  # ENU, row-major: east, north, up on the diagonal
        assert kind == "DIAGONAL_KNOWN" and cov == [4.0, 0, 0, 0, 1.0, 0, 0, 0, 9.0]


def test_replay_mcap_foxglove_channels_are_valid_under_the_official_schemas(
        replayed: tuple[Path, Path]) -> None:
    """Read back with the mcap reader: each foxglove.* channel's messages are valid under
    Foxglove's official schema of the channel's schema name, and the schema text in the file
    declares nothing the official one does not have."""
    _, mc = replayed
    f = read_mcap(mc)
    names = {t: s[0] for t, s in f["schemas"].items() if s[0].startswith("foxglove.")}
    assert set(names.values()) == set(FOXGLOVE_NAMES)
    for topic, name in names.items():
        assert schema_text_problems(f["schemas"][topic][2], official_json_schema(name)) == []
        for _, obj in f["messages"][topic]:
            assert_official(name, obj)


def test_replay_mcap_contents_match_the_solution_csv(replayed: tuple[Path, Path]) -> None:
    out, mc = replayed
    with open(out, newline="") as fh:
        rows = list(csv.DictReader(fh))
    f = read_mcap(mc)
    msgs = f["messages"]
    assert len(rows) == len(msgs["/navd/pose"]) == len(msgs["/navd/location"]) \
        == len(msgs["/navd/heading"]) > 200
    lat0 = lon0 = h0 = None
    for row, (lt, pose), (_, loc), (_, hd) in zip(rows, msgs["/navd/pose"],
                                                   msgs["/navd/location"],
                                                   msgs["/navd/heading"], strict=True):
        t_us = int(row["t_us"])
        assert lt == t_us * 1000  # replay: log time = sensor time
        for m in (pose, loc, hd):
            assert m["timestamp"] == {"sec": t_us // 10**6, "nsec": (t_us % 10**6) * 1000}
        assert loc["latitude"] == pytest.approx(float(row["lat_deg"]), abs=1e-8)
        assert loc["longitude"] == pytest.approx(float(row["lon_deg"]), abs=1e-8)
        assert loc["altitude"] == pytest.approx(float(row["alt_m"]), abs=1e-3)
        assert loc["position_covariance_type"] == 2
        cov = loc["position_covariance"]
        assert cov[0] > 0 and cov[4] > 0 and cov[8] > 0 and cov[1] == cov[3] == 0
        # heading status in navd's frames, as in the CSV
        e = hd["euler_deg"]
        assert e[2] == pytest.approx(float(row["yaw_deg"]), abs=1e-5)
        assert hd["sigma_deg"][2] == pytest.approx(float(row["yaw_sd_deg"]), abs=1e-5)
        # the pose's ENU/FLU quaternion is the CSV's NED/FRD Euler angles, converted
        c_nb = _euler_mat(*(math.radians(float(row[k]))
                            for k in ("roll_deg", "pitch_deg", "yaw_deg")))
        o = pose["pose"]["orientation"]
        np.testing.assert_allclose(_quat_mat((o["w"], o["x"], o["y"], o["z"])),
                                   ENU_NED @ c_nb @ FRD_FLU, atol=1e-5)
        # position: metres east/north/up of the first solution
        lat, lon, h = (math.radians(float(row["lat_deg"])), math.radians(float(row["lon_deg"])),
                       float(row["alt_m"]))
        if lat0 is None:
            lat0, lon0, h0 = lat, lon, h
        assert lon0 is not None and h0 is not None
        w2 = 1 - WGS84_E2 * math.sin(lat0) ** 2
        r_m, r_n = WGS84_A * (1 - WGS84_E2) / w2**1.5, WGS84_A / math.sqrt(w2)
        p = pose["pose"]["position"]
        assert p["x"] == pytest.approx((lon - lon0) * (r_n + h0) * math.cos(lat0), abs=0.01)
        assert p["y"] == pytest.approx((lat - lat0) * (r_m + h0), abs=0.01)
        assert p["z"] == pytest.approx(h - h0, abs=0.01)
    assert any(hd["aligned"] for _, hd in msgs["/navd/heading"])


def test_replay_mcap_failure_leaves_no_file(tmp_path: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    d = tmp_path
    generate(load_scenario("car480", {"duration_s": 5.0}), seed=3).write_csv(d)
    gnss = (d / "gnss.csv").read_text().splitlines()
    drop = gnss[0].split(",").index("vel_e")  # a required column: the replay fails (exit 2)
    (d / "bad.csv").write_text("\n".join(",".join(c for i, c in enumerate(ln.split(","))
                                                  if i != drop) for ln in gnss) + "\n")
    mc = d / "nav.mcap"
    rc = replay_main(["--imu", str(d / "imu.csv"), "--gnss", str(d / "bad.csv"),
                      "--out", str(d / "sol.csv"), "--mcap", str(mc), "--quiet"])
    assert rc == 2
    assert not mc.exists() and not mc.with_name("nav.mcap.part").exists()
    rc = replay_main(["--imu", str(d / "imu.csv"), "--gnss", str(d / "gnss.csv"),
                      "--out", str(d / "sol.csv"), "--mcap", str(d / "no" / "nav.mcap"),
                      "--quiet"])
    assert rc == 2 and "--mcap" in capsys.readouterr().err
