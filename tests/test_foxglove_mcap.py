"""``navd replay --mcap`` / ``navd run --mcap`` (navd/io/foxglove_mcap.py): the file is read
back with the ``mcap`` package's reader and checked for what Foxglove needs: the schema names
of its well-known types (foxglove.PoseInFrame, foxglove.LocationFix) with ``jsonschema``
schema encoding and ``json`` messages, messages valid against the schemas written into the
file, and contents that match the solution CSV written by the same replay.  The live daemon
case is in tests/test_daemon_autopilot.py."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from typing import Any

import jsonschema
import numpy as np
import pytest
from mcap.reader import make_reader

from firmware_sim import generate, load_scenario
from navd.cli.replay import main as replay_main
from navd.io.foxglove_mcap import CHANNELS, enu_flu_quat

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
