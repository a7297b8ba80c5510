"""Zenoh sink: a publisher and a subscriber session on 127.0.0.1, no multicast scouting."""

from __future__ import annotations

import asyncio
import json
import math
import socket
from typing import Any

import pytest
import zenoh

from navd.io.zenoh import (
    SCHEMA_VERSION,
    ZenohConfig,
    ZenohPublisher,
    ZenohSubscriber,
    attitude_payload,
    attitude_text,
)
from navd.types import NavSolution


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def solution(**kw: object) -> NavSolution:
    base: dict[str, object] = dict(
        t_us=42_000_123, quat_nb=(0.9238795, 0.0, 0.0, 0.3826834),
        roll_rad=math.radians(1.0), pitch_rad=math.radians(-2.0), yaw_rad=math.radians(45.0),
        lat_rad=0.8, lon_rad=0.1, alt_m=500.0, vel_n=(1.0, 2.0, 0.0),
        att_sd_rad=(math.radians(0.1), math.radians(0.1), math.radians(0.5)),
        gyro_bias_rps=(0.0, 0.0, 0.0), accel_bias_mps2=(0.0, 0.0, 0.0),
        heading_aligned=True, rate_b=(0.0, 0.0, 0.0),
    )
    base.update(kw)
    return NavSolution(**base)  # type: ignore[arg-type]


def test_config_is_peer_without_multicast_scouting() -> None:
    """GIVEN a Zenoh config for vehicle car1 listening on one TCP endpoint,
    WHEN it is turned into a zenoh config, and configs with vehicle names "a/b", "x*", "" are made,
    THEN the session is a peer with multicast scouting off listening on that endpoint,
    and the bad vehicle names raise ValueError."""
    c = ZenohConfig(vehicle="car1", listen=("tcp/127.0.0.1:1",)).to_zenoh()
    assert json.loads(c.get_json("mode")) == "peer"
    assert json.loads(c.get_json("scouting/multicast/enabled")) is False
    assert json.loads(c.get_json("listen/endpoints")) == ["tcp/127.0.0.1:1"]
    for bad in ("a/b", "x*", ""):
        with pytest.raises(ValueError):
            ZenohConfig(vehicle=bad)


def test_attitude_payload_fields_and_nan_as_null() -> None:
    """GIVEN a solution whose attitude sigmas are NaN, 0 and inf,
    WHEN its attitude payload is built,
    THEN it carries the schema version, time, quaternion, Euler angles in degrees and the
    aligned flag, the non-finite sigmas are null, and it serialises as strict JSON."""
    p = attitude_payload(solution(att_sd_rad=(math.nan, 0.0, math.inf)))
    assert p["schema"] == SCHEMA_VERSION and p["t_us"] == 42_000_123
    assert p["quat_wxyz"] == pytest.approx([0.9238795, 0.0, 0.0, 0.3826834])
    assert p["euler_deg"] == pytest.approx([1.0, -2.0, 45.0])
    assert p["sigma_deg"] == [None, 0.0, None] and p["aligned"] is True
    json.dumps(p, allow_nan=False)


def test_attitude_text_is_json_dumps_of_the_payload_character_for_character() -> None:
    """GIVEN solutions with random attitudes, rates and sigmas, and ones with 0.0, -0.0,
    NaN, +-inf, subnormal and huge values in every position, aligned or not, initialised
    or not, and numpy float64 fields,
    WHEN the published attitude text is made,
    THEN it is exactly json.dumps(attitude_payload(...)) as strict compact JSON (what was
    published before it was written directly), for any aligned bound."""
    import numpy as np

    rng = np.random.default_rng(7)
    special = (0.0, -0.0, math.nan, math.inf, -math.inf, 5e-324, 1.7e308, -1e-300, 1e16)
    cases: list[NavSolution] = []
    for _ in range(300):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        cases.append(solution(
            t_us=int(rng.integers(0, 2**62)), quat_nb=tuple(float(v) for v in q),
            roll_rad=float(rng.uniform(-math.pi, math.pi)),
            pitch_rad=float(rng.uniform(-1.5, 1.5)), yaw_rad=float(rng.uniform(-4, 4)),
            att_sd_rad=tuple(float(v) for v in rng.uniform(0.0, 0.2, 3)),
            heading_aligned=bool(rng.integers(2)), heading_initialised=bool(rng.integers(2))))
    for pos in range(10):
        for v in special:
            vals = [0.5, -0.5, 0.5, 0.5, 0.1, -0.2, 3.0, 0.001, 0.002, 0.01]
            vals[pos] = v
            cases.append(solution(quat_nb=tuple(vals[:4]), roll_rad=vals[4],
                                  pitch_rad=vals[5], yaw_rad=vals[6],
                                  att_sd_rad=tuple(vals[7:])))
    cases.append(solution(quat_nb=tuple(np.float64(v) for v in (0.5, 0.5, -0.5, 0.5)),
                          roll_rad=np.float64(0.3), att_sd_rad=(np.float64(0.01), 0.0, 0.1)))
    for sol in cases:
        for bound in (math.inf, math.radians(2.0), 0.0):
            want = json.dumps(attitude_payload(sol, bound), allow_nan=False,
                              separators=(",", ":"))
            assert attitude_text(sol, bound) == want


def test_publish_and_receive_over_loopback() -> None:
    """GIVEN a publisher session listening on loopback and a subscriber connected to it,
    WHEN attitude and a status (with its own schema 99 and a NaN) are published until both
    arrive,
    THEN the subscriber gets the attitude fields, and the status with schema set to 1 and
    the NaN as null, with nothing counted as wrong encoding or bad JSON."""
    async def main() -> None:
        port = free_port()
        vehicle = f"v{port}"
        pub_cfg = ZenohConfig(vehicle=vehicle, listen=(f"tcp/127.0.0.1:{port}",))
        sub_cfg = ZenohConfig(vehicle=vehicle, listen=(), connect=(f"tcp/127.0.0.1:{port}",))
        loop = asyncio.get_running_loop()
        with ZenohPublisher(pub_cfg) as pub, \
                ZenohSubscriber(sub_cfg, f"navd/{vehicle}/**", loop) as sub:
            got: dict[str, dict[str, Any]] = {}
            async with asyncio.timeout(10):
                # Declarations take a moment to propagate; publish until both arrive.
                while len(got) < 2:
                    pub.publish_attitude(solution())
                    pub.publish_status({"mode": "completed", "imu_rate_hz": 1000.0,
                                        "schema": 99, "bad": math.nan})
                    try:
                        key, obj = await sub.recv(timeout_s=0.1)
                    except TimeoutError:
                        continue
                    got[key] = obj
            att = got[f"navd/{vehicle}/attitude"]
            assert att["schema"] == 1 and att["t_us"] == 42_000_123
            assert att["euler_deg"] == pytest.approx([1.0, -2.0, 45.0])
            assert att["aligned"] is True
            st = got[f"navd/{vehicle}/status"]
            assert st == {"mode": "completed", "imu_rate_hz": 1000.0, "schema": 1, "bad": None}
            assert sub.counters.snapshot() == {}  # no wrong_encoding / bad_json
            assert pub.counters["attitude_sent"] >= 1

    asyncio.run(main())


def test_subscriber_counts_non_json() -> None:
    """GIVEN a subscriber connected to a raw zenoh session,
    WHEN that session puts a text/plain payload and a payload labelled JSON that is not JSON,
    THEN the subscriber counts wrong_encoding and bad_json and queues nothing."""
    async def main() -> None:
        port = free_port()
        cfg_l = ZenohConfig(vehicle="x", listen=(f"tcp/127.0.0.1:{port}",))
        cfg_c = ZenohConfig(vehicle="x", listen=(), connect=(f"tcp/127.0.0.1:{port}",))
        loop = asyncio.get_running_loop()
        raw = zenoh.open(cfg_l.to_zenoh())
        try:
            with ZenohSubscriber(cfg_c, "navd/x/**", loop) as sub:
                async with asyncio.timeout(10):
                    while sub.counters["wrong_encoding"] == 0 or sub.counters["bad_json"] == 0:
                        raw.put("navd/x/attitude", "{}", encoding=zenoh.Encoding.TEXT_PLAIN)
                        raw.put("navd/x/attitude", "not json",
                                encoding=zenoh.Encoding.APPLICATION_JSON)
                        await asyncio.sleep(0.05)
                assert sub.queue.empty()
        finally:
            raw.close()  # type: ignore[no-untyped-call]

    asyncio.run(main())
