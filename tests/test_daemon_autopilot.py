"""End to end: ``firmware-sim stream`` -> MAVLink UDP -> ``navd run`` with ``[autopilot]`` on
-> a stock pymavlink connection standing in for the autopilot, all on 127.0.0.1.  What the
"autopilot" receives is checked against the simulator's truth."""

from __future__ import annotations

import asyncio
import math
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from daemon_util import (
    ROOT,
    STARTUP_TIMEOUT_S,
    NotifySocket,
    car_run,
    free_port,
    heading_errors_deg,
    start_daemon,
    stop_daemon,
    write_config,
)
from pymavlink import mavutil
from test_foxglove_mcap import read_mcap
from test_foxglove_ws import foxglove_client

from navd.config import EstimatorConfig
from navd.core.estimator import Estimator
from navd.pipeline import solutions

DURATION_S = 40.0
RATE_FACTOR = 8.0


def _autopilot(port: int, out: list[tuple[str, dict[str, Any]]], stop: threading.Event) -> None:
    conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}")
    try:
        while not stop.is_set():
            m = conn.recv_match(blocking=True, timeout=0.1)
            if m is not None and m.get_type() in ("GPS_INPUT", "COMMAND_LONG",
                                                  "ESTIMATOR_STATUS"):
                out.append((m.get_type(), m.to_dict()))
    finally:
        conn.close()


@pytest.fixture(scope="module")
def received(tmp_path_factory: pytest.TempPathFactory) -> Any:
    tmp: Path = tmp_path_factory.mktemp("ap")
    port_in, port_out = free_port(), free_port()
    port_fox = free_port(socket.SOCK_STREAM)
    cfg = write_config(tmp / "navd.toml", {
        "mavlink": {"listen": f"udpin:127.0.0.1:{port_in}",
                    "send": f"udpout:127.0.0.1:{port_out}"},
        "autopilot": {"gps_input": True, "gps_input_rate_hz": 5.0, "heading_reset": True,
                      "estimator_status": True, "target_sysid": 42, "target_compid": 1},
        "zenoh": {"enabled": False},
        "foxglove": {"enabled": True, "port": port_fox, "rate_hz": 10.0},
    })
    notify = NotifySocket()
    mcap_path = tmp / "live.mcap"
    proc = start_daemon(cfg, tmp / "navd.log", {"NOTIFY_SOCKET": notify.path},
                        ("--mcap", str(mcap_path), "--mcap-rate-hz", "10"))
    out: list[tuple[str, dict[str, Any]]] = []
    stop = threading.Event()
    client = threading.Thread(target=_autopilot, args=(port_out, out, stop), daemon=True)
    live: list[Any] = []

    def fox_client() -> None:  # Foxglove's view of the run: 50 heading messages
        live.append(asyncio.run(foxglove_client(port_fox, ["/navd/heading"], 50,
                                                timeout_s=60.0)))

    fox = threading.Thread(target=fox_client, daemon=True)
    try:
        notify.wait_for("READY=1", STARTUP_TIMEOUT_S, proc)
        fox.start()
        client.start()
        time.sleep(0.3)
        st = subprocess.run(
            [sys.executable, "-m", "firmware_sim", "stream", "--scenario", "car480",
             "--set", f"duration_s={DURATION_S}", "--seed", "1", "--rate-factor",
             str(RATE_FACTOR), "--target", f"udp:127.0.0.1:{port_in}"],
            cwd=ROOT, capture_output=True, text=True, timeout=120)
        assert st.returncode == 0, st.stderr
        time.sleep(0.5)
    finally:
        stop.set()
        rc = stop_daemon(proc)
        client.join(2)
        fox.join(5)
        notify.close()
    assert rc == 0, (tmp / "navd.log").read_text()[-2000:]
    return out, (tmp / "navd.log").read_text(), mcap_path, live


def test_gps_input_reaches_the_autopilot_with_yaw_only_once_aligned(received: Any) -> None:
    out, _, _, _ = received
    run = car_run(DURATION_S)
    gps = [m for t, m in out if t == "GPS_INPUT"]
    assert len(gps) >= 0.8 * DURATION_S * 5.0  # 5 Hz of sensor time, UDP on loopback
    yaws = [m["yaw"] for m in gps]
    # the same samples through the estimator offline: yaw is sent exactly when that
    # solution's heading is good (initialised, sigma <= [init] aligned_sd_deg)
    est = Estimator(EstimatorConfig())
    good = {s.t_us: s.heading_good(est.cfg.init.aligned_sd)
            for s in solutions(est, run.samples(), 5.0)}
    assert [y != 0 for y in yaws] == [good[m["time_usec"]] for m in gps]
    first = next(i for i, y in enumerate(yaws) if y != 0)
    assert all(y != 0 for y in yaws[first:]), "aligned stays aligned on this drive"
    assert all(1 <= y <= 36000 for y in yaws[first:])
    t_us = [m["time_usec"] for m in gps[first:]]
    err = heading_errors_deg(run, t_us, [math.radians(y * 0.01) for y in yaws[first:]])
    assert np.max(np.abs(err)) < 1.0, np.max(np.abs(err))
    assert all(m["fix_type"] == 3 and m["ignore_flags"] == 0 for m in gps)
    # position as a GPS gives it: lat/lon degE7, altitude MSL (the simulator's MSL is its
    # ellipsoid height: geoid_sep_m = 0, for input and output alike), after the start-up
    # transient (the first second's error is the initial fix's, with a 7 m sigma)
    for m in [m for m in gps if m["time_usec"] >= 10_000_000][::10]:
        k = m["time_usec"] // run.imu_dt_us
        lat, lon, h = run.truth_pos[k]
        assert abs(m["lat"] * 1e-7 - math.degrees(lat)) * 111e3 < 3.0
        assert abs(m["lon"] * 1e-7 - math.degrees(lon)) * 111e3 * math.cos(lat) < 3.0
        assert abs(m["alt"] - h) < 3.0
        assert 0.05 < m["horiz_accuracy"] < 3.0 and 0.005 < m["speed_accuracy"] < 1.0


def test_one_heading_reset_command_when_the_heading_aligns(received: Any) -> None:
    out, _, _, _ = received
    cmds = [m for t, m in out if t == "COMMAND_LONG"]
    assert len(cmds) == 1, cmds  # aligned once; no reset on this drive
    c = cmds[0]
    assert c["command"] == 620 and (c["target_system"], c["target_component"]) == (42, 1)
    assert 0.0 <= c["param3"] < 360.0 and 0.0 < c["param7"] <= 2.0
    # sent right after the first GPS_INPUT with a yaw, and agreeing with it
    i = next(i for i, (t, m) in enumerate(out) if t == "COMMAND_LONG")
    prior = [m["yaw"] for t, m in out[:i] if t == "GPS_INPUT"]
    assert prior and prior[-1] != 0
    assert abs((prior[-1] * 0.01 - c["param3"] + 180.0) % 360.0 - 180.0) < 0.02


def test_estimator_status_flags_and_log_line(received: Any) -> None:
    out, log, _, _ = received
    st = [m for t, m in out if t == "ESTIMATOR_STATUS"]
    # ATTITUDE (bit 1) exactly when GPS_INPUT carries a yaw for the same solution
    yaw = {m["time_usec"]: m["yaw"] != 0 for t, m in out if t == "GPS_INPUT"}
    assert len(st) >= 100 and any(yaw.values())
    assert all(bool(m["flags"] & 1) == yaw[m["time_usec"]] for m in st)
    assert all(m["flags"] & 16 for m in st)  # POS_HORIZ_ABS: GNSS in use throughout
    assert "autopilot GPS_INPUT + ESTIMATOR_STATUS + EXTERNAL_ATTITUDE_ESTIMATE 5 Hz" in log


def test_run_mcap_has_the_foxglove_channels_and_the_status(received: Any) -> None:
    """``navd run --mcap``: closed cleanly at SIGTERM (summary present), the Foxglove
    channels at 10 Hz of sensor time, the daemon status; log time = host wall clock."""
    _, _, path, _ = received
    f = read_mcap(path)
    assert f["schemas"]["/navd/pose"][:2] == ("foxglove.PoseInFrame", "jsonschema")
    assert f["schemas"]["/navd/location"][:2] == ("foxglove.LocationFix", "jsonschema")
    assert f["schemas"]["/navd/status"][0] == "navd.Status"
    poses = f["messages"]["/navd/pose"]
    assert 0.8 * DURATION_S * 10 <= len(poses) <= DURATION_S * 10 + 1
    t = [p["timestamp"]["sec"] * 10**9 + p["timestamp"]["nsec"] for _, p in poses]
    assert np.all(np.diff(t) == 100_000_000)  # one per 0.1 s of sensor time
    wall = [lt for lt, _ in poses]
    assert abs(wall[-1] * 1e-9 - time.time()) < 600 and np.all(np.diff(wall) >= 0)
    states = [m["state"] for _, m in f["messages"]["/navd/status"]]
    assert "navigating" in states and states[-1] == "stopping"


def test_live_foxglove_server_streams_the_heading(received: Any) -> None:
    """``[foxglove] enabled``: a WebSocket client subscribed while the drive streams gets
    navd.HeadingStatus messages at 10 Hz of sensor time, with the yaw GPS_INPUT carried."""
    out, log, _, live = received
    assert live, "the Foxglove client got its 50 messages"
    _, chans, got = live[0]
    assert chans["/navd/heading"]["schemaName"] == "navd.HeadingStatus"
    t = [m["t_us"] for _, _, m in got]
    assert np.all(np.diff(t) == 100_000)
    gps = {m["time_usec"]: m["yaw"] for k, m in out if k == "GPS_INPUT"}
    same = [m for _, _, m in got if gps.get(m["t_us"])]
    assert len(same) >= 10  # 5 Hz GPS_INPUT instants among the 10 Hz heading messages
    for m in same:
        assert abs((m["euler_deg"][2] - gps[m["t_us"]] * 0.01 + 180) % 360 - 180) < 0.006
    assert "foxglove ws://127.0.0.1:" in log
