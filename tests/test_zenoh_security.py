"""Issue 19 item 8: Zenoh is no longer open to any local process (navd/io/zenoh_security.py).

Everything on 127.0.0.1, multicast scouting off.  The refusals are shown next to a control
run without the protection, in which the same foreign publisher does get through, so each
test fails if the protection is missing.
"""

from __future__ import annotations

import json
import socket
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import zenoh

from navd.config.daemon import DaemonConfig
from navd.config.load import ConfigError
from navd.daemon.adapters import zenoh_session_config
from navd.io.zenoh import ZenohConfig, ZenohPublisher
from navd.io.zenoh_security import consumer_acl
from navd.types import NavSolution

VEHICLE = "veh"


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _sol() -> NavSolution:
    return NavSolution(
        t_us=1_000_000, quat_nb=(1.0, 0.0, 0.0, 0.0), roll_rad=0.0, pitch_rad=0.0,
        yaw_rad=0.0, lat_rad=0.8, lon_rad=0.1, alt_m=500.0, vel_n=(0.0, 0.0, 0.0),
        att_sd_rad=(0.001, 0.001, 0.01), gyro_bias_rps=(0.0, 0.0, 0.0),
        accel_bias_mps2=(0.0, 0.0, 0.0), heading_aligned=True, rate_b=(0.0, 0.0, 0.0))


@pytest.fixture()
def users(tmp_path: Path) -> Path:
    p = tmp_path / "users"
    p.write_text("navd:navd-secret\nconsumer:consumer-secret\nintruder:intruder-secret\n")
    return p


def _wait(cond: Callable[[], bool], timeout_s: float = 5.0) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.02)
    return cond()


def _payloads(got: list[bytes]) -> list[Any]:
    return [json.loads(b) if b.startswith(b"{") else b.decode() for b in got]


def _listening_consumer(acl: str, users: Path, port: int
                        ) -> tuple[Any, list[bytes]]:
    """A consumer that listens on an endpoint (the case of the issue) and requires usrpwd."""
    cfg = ZenohConfig(vehicle=VEHICLE, listen=(f"tcp/127.0.0.1:{port}",), acl=acl,
                      users_file=str(users), user="consumer", password="consumer-secret")
    session = zenoh.open(cfg.to_zenoh())
    got: list[bytes] = []
    session.declare_subscriber(f"navd/{VEHICLE}/**", lambda s: got.append(s.payload.to_bytes()))
    return session, got


def _peer(port: int, user: str = "", password: str = "") -> Any:
    cfg = ZenohConfig(vehicle=VEHICLE, listen=(), connect=(f"tcp/127.0.0.1:{port}",),
                      user=user, password=password)
    return zenoh.open(cfg.to_zenoh())


@pytest.mark.parametrize("acl", ["off", "consumer"])
def test_foreign_publisher_on_navd_attitude_is_refused_by_the_consumer_acl(
        acl: str, users: Path) -> None:
    """navd and an intruder (valid credentials, another user name) both connect to a
    listening consumer and put on navd/veh/attitude.  Without the ACL (control) the fake
    arrives; with it only navd's sample does."""
    port = free_port()
    consumer, got = _listening_consumer(acl, users, port)
    navd = ZenohPublisher(ZenohConfig(vehicle=VEHICLE, listen=(),
                                      connect=(f"tcp/127.0.0.1:{port}",), acl="publisher",
                                      user="navd", password="navd-secret"))
    intruder = _peer(port, "intruder", "intruder-secret")
    try:
        assert _wait(lambda: len(list(consumer.info.peers_zid())) == 2)
        time.sleep(0.5)  # subscriber declarations reach both peers
        intruder.put(f"navd/{VEHICLE}/attitude", b"fake")
        navd.publish_attitude(_sol())
        assert _wait(lambda: any(b.startswith(b"{") for b in got)), "navd's sample arrives"
        time.sleep(0.5)
        fakes = [p for p in _payloads(got) if p == "fake"]
        if acl == "off":
            assert fakes == ["fake"], "control: without the ACL the fake gets through"
        else:
            assert fakes == []
            assert [p["t_us"] for p in _payloads(got)] == [1_000_000]
    finally:
        for s in (intruder, consumer):
            s.close()
        navd.close()


@pytest.mark.parametrize("users_file", [False, True])
def test_unauthenticated_process_cannot_connect_to_navd(users_file: bool,
                                                        users: Path) -> None:
    """navd listens (the daemon's default) with a users file: a process without credentials
    gets no session, so neither attitude nor anything else; an authenticated one does.
    Control: without the users file the same process receives the attitude."""
    port = free_port()
    navd = ZenohPublisher(ZenohConfig(
        vehicle=VEHICLE, listen=(f"tcp/127.0.0.1:{port}",), acl="publisher",
        users_file=str(users) if users_file else ""))
    anon = _peer(port)
    # zenoh 1.10: a peer presenting credentials cannot join a listener without a users file
    member = _peer(port, "consumer", "consumer-secret") if users_file else _peer(port)
    got_anon: list[bytes] = []
    got_member: list[bytes] = []
    anon.declare_subscriber(f"navd/{VEHICLE}/**", lambda s: got_anon.append(b"x"))
    member.declare_subscriber(f"navd/{VEHICLE}/**", lambda s: got_member.append(b"x"))
    try:
        time.sleep(1.0)
        for _ in range(5):
            navd.publish_attitude(_sol())
            time.sleep(0.05)
        assert _wait(lambda: len(got_member) == 5)
        time.sleep(0.3)
        if users_file:
            assert got_anon == [] and list(anon.info.peers_zid()) == []
        else:
            assert len(got_anon) == 5
    finally:
        for s in (anon, member):
            s.close()
        navd.close()


def _navd_session(port: int, acl: str, adminspace: bool) -> Any:
    """navd's session config (ZenohConfig.to_zenoh), optionally with the admin space forced
    on, as a library default or an operator's override might have it."""
    cfg = ZenohConfig(vehicle=VEHICLE, listen=(f"tcp/127.0.0.1:{port}",), acl=acl).to_zenoh()
    if adminspace:
        cfg.insert_json5("adminspace/enabled", "true")
    return zenoh.open(cfg)


@pytest.mark.parametrize(("access_control", "adminspace"),
                         [(False, True), (True, True), (False, False)])
def test_nothing_can_be_pushed_into_navd_and_its_admin_space_is_closed(
        access_control: bool, adminspace: bool) -> None:
    """A local peer connected to navd puts on navd/veh/attitude and queries navd's admin
    space.  With navd's publisher ACL the put is refused at navd's ingress (a subscriber in
    navd's own session, standing in for anything navd might listen to, sees nothing) and
    the admin space answers nothing even when forced on.  Controls: without the ACL the put
    arrives, and a forced-on admin space hands out navd's config (@/<zid>/peer...); navd's
    own config (admin space off) answers nothing."""
    port = free_port()
    navd = _navd_session(port, "publisher" if access_control else "off", adminspace)
    inside: list[bytes] = []
    navd.declare_subscriber(f"navd/{VEHICLE}/**", lambda s: inside.append(s.payload.to_bytes()))
    foreign = _peer(port)
    try:
        assert _wait(lambda: len(list(foreign.info.peers_zid())) == 1)
        time.sleep(0.5)
        foreign.put(f"navd/{VEHICLE}/attitude", b"fake")
        time.sleep(0.5)
        assert inside == ([] if access_control else [b"fake"])
        navd_zid = str(navd.zid())
        keys = [str(r.ok.key_expr) for r in foreign.get("@/**", timeout=1.0)
                if r.ok is not None]
        navd_keys = [k for k in keys if k.startswith(f"@/{navd_zid}/")]
        if adminspace and not access_control:
            assert f"@/{navd_zid}/peer" in navd_keys  # control: the leak the ACL closes
        else:
            assert navd_keys == [], navd_keys
    finally:
        foreign.close()
        navd.close()


def test_config_keys_reach_the_session(tmp_path: Path, users: Path) -> None:
    pw = tmp_path / "pw"
    pw.write_text("navd-secret\n")
    cfg = DaemonConfig.from_dict({"zenoh": {"user": "navd", "password_file": str(pw),
                                            "users_file": str(users)}})
    assert cfg.zenoh.access_control  # on by default
    z = zenoh_session_config(cfg.zenoh).to_zenoh()
    assert json.loads(z.get_json("access_control/enabled")) is True
    assert json.loads(z.get_json("adminspace/enabled")) is False
    auth = json.loads(z.get_json("transport/auth/usrpwd"))
    assert (auth["user"], auth["password"], auth["dictionary_file"]) == (
        "navd", "navd-secret", str(users))
    off = DaemonConfig.from_dict({"zenoh": {"access_control": False}})
    assert json.loads(zenoh_session_config(off.zenoh).to_zenoh()
                      .get_json("access_control/enabled")) is False
    with pytest.raises(ConfigError, match="password_file"):
        DaemonConfig.from_dict({"zenoh": {"user": "navd"}})
    missing = DaemonConfig.from_dict({"zenoh": {"user": "navd",
                                                "password_file": str(tmp_path / "nope")}})
    with pytest.raises(ConfigError, match="password_file"):
        zenoh_session_config(missing.zenoh)
    with pytest.raises(ValueError, match="users_file"):
        ZenohConfig(acl="consumer")


def test_shipped_consumer_config_loads_and_holds_the_consumer_acl() -> None:
    """config/zenoh-consumer.json5 (for consumers that are not navd's Python classes) is
    valid for the installed zenoh and carries the same ACL as consumer_acl()."""
    path = Path(__file__).resolve().parents[1] / "config" / "zenoh-consumer.json5"
    c = zenoh.Config.from_file(str(path))

    def no_nulls(x: Any) -> Any:  # zenoh fills the subject fields not given with null
        if isinstance(x, dict):
            return {k: no_nulls(v) for k, v in x.items() if v is not None}
        return [no_nulls(v) for v in x] if isinstance(x, list) else x

    assert no_nulls(json.loads(c.get_json("access_control"))) == json.loads(json.dumps(
        consumer_acl("vehicle", "navd", ["navd", "consumer"])))
    assert json.loads(c.get_json("adminspace/enabled")) is False
    assert json.loads(c.get_json("scouting/multicast/enabled")) is False
    assert json.loads(c.get_json("transport/auth/usrpwd/dictionary_file"))
