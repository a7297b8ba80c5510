"""The live Foxglove WebSocket server (navd/io/foxglove_ws.py), spoken to with a plain
WebSocket client as Foxglove does (subprotocol foxglove.sdk.v1 / foxglove.websocket.v1:
serverInfo, advertise, subscribe, binary message frames), on 127.0.0.1.  The foxglove.*
channels are checked against Foxglove's official schemas from the SDK wheel as well
(tests/foxglove_official.py)."""

from __future__ import annotations

import asyncio
import json
import math
import struct
from typing import Any

import websockets
from foxglove_official import assert_official, official_json_schema, schema_text_problems

from navd.io.foxglove_mcap import CHANNELS, FoxgloveMessages
from navd.io.foxglove_ws import FoxgloveLive
from navd.types import NavSolution

SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]


def _sol(t_us: int, yaw_deg: float) -> NavSolution:
    h = math.radians(yaw_deg) / 2
    return NavSolution(
        t_us=t_us, quat_nb=(math.cos(h), 0.0, 0.0, math.sin(h)), roll_rad=0.0, pitch_rad=0.0,
        yaw_rad=math.radians(yaw_deg), lat_rad=0.6, lon_rad=1.9, alt_m=400.0,
        vel_n=(0.0, 0.0, 0.0), att_sd_rad=(0.001, 0.001, 0.01), gyro_bias_rps=(0.0, 0.0, 0.0),
        accel_bias_mps2=(0.0, 0.0, 0.0), heading_aligned=True, rate_b=(0.0, 0.0, 0.0),
        pos_sd_m=(1.0, 1.0, 2.0), vel_sd_mps=(0.1, 0.1, 0.1), gnss_age_us=0)


async def foxglove_client(port: int, topics: list[str], n_messages: int,
                          on_subscribed: Any = None, timeout_s: float = 10.0
                          ) -> tuple[dict[str, Any], dict[str, dict[str, Any]],
                                     list[tuple[str, int, dict[str, Any]]]]:
    """Connect, read serverInfo and the advertised channels, subscribe to ``topics``, collect
    ``n_messages`` message frames: (serverInfo, {topic: channel}, [(topic, log_time, obj)])."""
    async with websockets.connect(f"ws://127.0.0.1:{port}", subprotocols=SUBPROTOCOLS,
                                  open_timeout=timeout_s) as ws:
        assert ws.subprotocol in SUBPROTOCOLS
        info: dict[str, Any] = {}
        chans: dict[str, dict[str, Any]] = {}
        while not (info and set(topics) <= set(chans)):
            m = json.loads(await asyncio.wait_for(ws.recv(), timeout_s))
            if m["op"] == "serverInfo":
                info = m
            elif m["op"] == "advertise":
                chans.update({c["topic"]: c for c in m["channels"]})
        subs = {i: t for i, t in enumerate(topics)}
        await ws.send(json.dumps({"op": "subscribe", "subscriptions": [
            {"id": i, "channelId": chans[t]["id"]} for i, t in subs.items()]}))
        if on_subscribed is not None:
            await asyncio.sleep(0.3)  # the subscription reaches the server
            on_subscribed()
        got: list[tuple[str, int, dict[str, Any]]] = []
        while len(got) < n_messages:
            frame = await asyncio.wait_for(ws.recv(), timeout_s)
            if isinstance(frame, bytes) and frame[0] == 0x01:  # MESSAGE_DATA
                sub_id, log_time = struct.unpack_from("<IQ", frame, 1)
                got.append((subs[sub_id], log_time, json.loads(frame[13:])))
        return info, chans, got


def test_live_server_advertises_foxglove_schemas_and_streams_the_solutions() -> None:
    live = FoxgloveLive(host="127.0.0.1", port=0, aligned_sd_rad=math.radians(2.0))
    sols = [_sol(1_000_000 + 100_000 * k, 10.0 * k) for k in range(3)]

    def publish() -> None:
        for k, s in enumerate(sols):
            live.write_solution(s, 5_000 + k)
        live.write_status({"state": "navigating"}, 9_000)

    try:
        info, chans, got = asyncio.run(foxglove_client(
            live.port, list(CHANNELS), 3 * len(sols) + 1, publish))
    finally:
        live.close()
    # subscribe-only: no client publishing, parameters or services
    assert not {"clientPublish", "parameters", "services"} & set(info["capabilities"])
    for topic, (name, schema) in CHANNELS.items():
        c = chans[topic]
        assert (c["schemaName"], c["encoding"], c["schemaEncoding"]) == (
            name, "json", "jsonschema")
        assert json.loads(c["schema"]) == schema
    # the frames carry exactly what the MCAP file would, in order, with the log times given
    ref = FoxgloveMessages(math.radians(2.0))
    want = [(t, 5_000 + k, o) for k, s in enumerate(sols) for t, o in ref.of(s)]
    by_topic = sorted(got[:-1], key=lambda g: (g[1], list(CHANNELS).index(g[0])))
    assert [(t, lt) for t, lt, _ in by_topic] == [(t, lt) for t, lt, _ in want]
    for (_, _, a), (_, _, b) in zip(by_topic, want, strict=True):
        assert a == json.loads(json.dumps(b))
    assert got[-1] == ("/navd/status", 9_000, {"state": "navigating"})


def test_live_foxglove_channels_are_valid_under_the_official_schemas() -> None:
    """What a client receives: each advertised foxglove.* channel's schema text declares
    nothing Foxglove's official schema does not have, and its messages are valid under it."""
    live = FoxgloveLive(host="127.0.0.1", port=0, aligned_sd_rad=math.radians(2.0))
    sols = [_sol(2_000_000 + 100_000 * k, 30.0 * k - 170.0) for k in range(4)]

    def publish() -> None:
        for k, s in enumerate(sols):
            live.write_solution(s, 7_000 + k)

    try:
        _, chans, got = asyncio.run(foxglove_client(
            live.port, [t for t in CHANNELS if t != "/navd/status"], 3 * len(sols), publish))
    finally:
        live.close()
    names = {t: c["schemaName"] for t, c in chans.items()
             if c["schemaName"].startswith("foxglove.")}
    assert set(names.values()) == {"foxglove.PoseInFrame", "foxglove.LocationFix"}
    for topic, name in names.items():
        assert schema_text_problems(json.loads(chans[topic]["schema"]),
                                    official_json_schema(name)) == []
    official = [(names[t], obj) for t, _, obj in got if t in names]
    assert len(official) == 2 * len(sols)
    for name, obj in official:
        assert_official(name, obj)


def test_enabled_without_the_sdk_is_a_clear_startup_error(
        monkeypatch: Any, caplog: Any) -> None:
    """navd[foxglove] not installed: ``navd run`` says what to install and exits 1."""
    import socket
    import sys

    from navd.config.daemon import DaemonConfig
    from navd.daemon.daemon import Daemon

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    monkeypatch.setitem(sys.modules, "foxglove", None)  # import foxglove -> ImportError
    monkeypatch.delitem(sys.modules, "navd.io.foxglove_ws", raising=False)
    cfg = DaemonConfig.from_dict({
        "mavlink": {"listen": f"udpin:127.0.0.1:{port}", "send": ""},
        "zenoh": {"enabled": False}, "daemon": {"warm_up": False},
        "foxglove": {"enabled": True, "port": 0}})
    rc = asyncio.run(Daemon(cfg, handle_signals=False).run())
    assert rc == 1
    assert "pip install 'navd[foxglove]'" in caplog.text
