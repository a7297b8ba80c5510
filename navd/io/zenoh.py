"""Zenoh sink: NavSolution / status dicts -> JSON samples on ``navd/<vehicle>/...``.

Session: peer mode, multicast scouting OFF, explicit endpoints (default: listen on
``tcp/127.0.0.1:7447``, connect to nothing) so nothing leaves the host unless configured.

Key expressions (``<vehicle>`` is one key chunk: no ``/ * $ ? #``)
    navd/<vehicle>/attitude   one sample per published solution
    navd/<vehicle>/status     whatever the daemon reports, as a JSON object

Encoding ``application/json``; every object has ``"schema": 1``.  Attitude fields:
    schema      1
    t_us        int, time of validity (sensor clock), microseconds
    quat_wxyz   [w, x, y, z] of C_b^n (body FRD -> local NED), scalar first
    euler_deg   [roll, pitch, yaw], ZYX, degrees; yaw clockwise from north in (-180, 180]
    sigma_deg   [roll, pitch, yaw] 1-sigma, degrees
    aligned     bool, heading initialised from a trusted source
Non-finite numbers are sent as ``null`` (JSON has no NaN).  A status object is the dict
given to :meth:`ZenohPublisher.publish_status` with ``schema`` set (and overriding any
``schema`` key in it).

Zenoh calls subscriber callbacks on its own threads; :class:`ZenohSubscriber` hands each
message to the asyncio loop with ``loop.call_soon_threadsafe``.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import zenoh

from navd.config.daemon import ZENOH_BAD_CHUNK_CHARS
from navd.diag import Counters
from navd.io.zenoh_security import consumer_acl, publisher_acl, read_usernames, usrpwd
from navd.types import NavSolution

__all__ = [
    "SCHEMA_VERSION",
    "ZenohConfig",
    "ZenohPublisher",
    "ZenohSubscriber",
    "attitude_key",
    "attitude_payload",
    "attitude_text",
    "status_key",
]

_log = logging.getLogger(__name__)

SCHEMA_VERSION = 1


@dataclass(frozen=True)
class ZenohConfig:
    vehicle: str = "vehicle"
    listen: tuple[str, ...] = ("tcp/127.0.0.1:7447",)
    connect: tuple[str, ...] = ()
    multicast_scouting: bool = False
    # security (navd.io.zenoh_security, docs/daemon.md "Zenoh threat model")
    acl: str = "off"  # "off" | "publisher" (navd's session) | "consumer" (a subscriber's)
    user: str = ""  # presented when connecting ("" = no credentials)
    password: str = ""
    users_file: str = ""  # user:password lines accepted on listen endpoints ("" = anyone)
    publisher_user: str = "navd"  # consumer ACL: the only user that may put navd/<vehicle>/**

    def __post_init__(self) -> None:
        if not self.vehicle or ZENOH_BAD_CHUNK_CHARS & set(self.vehicle):
            raise ValueError(f"vehicle {self.vehicle!r} must be one key chunk (no / * $ ? #)")
        if self.acl not in ("off", "publisher", "consumer"):
            raise ValueError(f"acl {self.acl!r}: expected off, publisher or consumer")
        if self.acl == "consumer" and not self.users_file:
            raise ValueError("a consumer ACL needs a users_file: it tells navd from other "
                             "peers by authenticated user name")

    def to_zenoh(self) -> Any:
        c = zenoh.Config()
        c.insert_json5("mode", json.dumps("peer"))
        c.insert_json5("scouting/multicast/enabled", json.dumps(self.multicast_scouting))
        c.insert_json5("listen/endpoints", json.dumps(list(self.listen)))
        c.insert_json5("connect/endpoints", json.dumps(list(self.connect)))
        # the admin space (@/<zid>/...) tells a local process our config and peers: off,
        # stated rather than left to the library's default
        c.insert_json5("adminspace/enabled", "false")
        auth = usrpwd(self.user, self.password, self.users_file)
        if auth:
            c.insert_json5("transport/auth/usrpwd", json.dumps(auth))
        if self.acl == "publisher":
            c.insert_json5("access_control", json.dumps(publisher_acl()))
        elif self.acl == "consumer":
            acl = consumer_acl(self.vehicle, self.publisher_user,
                               read_usernames(self.users_file))
            c.insert_json5("access_control", json.dumps(acl))
        return c


def attitude_key(vehicle: str) -> str:
    return f"navd/{vehicle}/attitude"


def status_key(vehicle: str) -> str:
    return f"navd/{vehicle}/status"


def _num(x: float) -> float | None:
    return x if math.isfinite(x) else None


def attitude_payload(sol: NavSolution, aligned_sd_rad: float = math.inf) -> dict[str, Any]:
    """The attitude object (docs/interfaces.md).

    ``aligned`` is what a consumer acts on, so it says the heading is good, not only that it
    was started: the estimator's ``heading_aligned`` is set as soon as a first course gives
    the heading a value, with the wide start-up sigma (``[init] heading_sd_deg``, 10 deg);
    ``aligned`` also needs the yaw sigma at or below ``aligned_sd_rad`` (the daemon passes
    ``[init] aligned_sd_deg``, the estimator's own "aligned by observability" bound).
    ``heading_initialised`` says the yaw has a value at all (confirmed or not).
    """
    d = math.degrees
    return {
        "schema": SCHEMA_VERSION,
        "t_us": sol.t_us,
        "quat_wxyz": [_num(v) for v in sol.quat_nb],
        "euler_deg": [_num(d(sol.roll_rad)), _num(d(sol.pitch_rad)), _num(d(sol.yaw_rad))],
        "sigma_deg": [_num(d(v)) for v in sol.att_sd_rad],
        "aligned": sol.heading_good(aligned_sd_rad),
        "heading_initialised": bool(sol.heading_initialised or sol.heading_aligned),
    }


_float_text = float.__repr__  # what json writes for a float (a numpy scalar's repr differs)


def attitude_text(sol: NavSolution, aligned_sd_rad: float = math.inf) -> str:
    """``attitude_payload`` as the compact JSON text navd publishes: the same characters as
    ``json.dumps(attitude_payload(sol, aligned_sd_rad), allow_nan=False,
    separators=(",", ":"))``, written directly (issue 18: the dict, its lists and the
    encoder's own machinery were ~20 of the ~80 bytecode instructions per datagram the
    outputs cost, ``benchmarks/daemon_path.py``; now ~10)."""
    d = math.degrees
    w, x, y, z = sol.quat_nb
    r, p, h = d(sol.roll_rad), d(sol.pitch_rad), d(sol.yaw_rad)
    sr, sp, sh = sol.att_sd_rad
    sr, sp, sh = d(sr), d(sp), d(sh)
    f = _float_text
    if math.isfinite(w + x + y + z + r + p + h + sr + sp + sh):
        q = f"{f(w)},{f(x)},{f(y)},{f(z)}],\"euler_deg\":[{f(r)},{f(p)},{f(h)}],\"sigma_deg\":[" \
            f"{f(sr)},{f(sp)},{f(sh)}"
    else:  # JSON has no NaN or infinity: null, as _num gives json.dumps
        t = [f(float(v)) if math.isfinite(v) else "null"
             for v in (w, x, y, z, r, p, h, sr, sp, sh)]
        q = f"{t[0]},{t[1]},{t[2]},{t[3]}],\"euler_deg\":[{t[4]},{t[5]},{t[6]}]," \
            f"\"sigma_deg\":[{t[7]},{t[8]},{t[9]}"
    aligned = "true" if sol.heading_good(aligned_sd_rad) else "false"
    init = "true" if sol.heading_initialised or sol.heading_aligned else "false"
    return (f'{{"schema":{SCHEMA_VERSION},"t_us":{int(sol.t_us)},"quat_wxyz":[{q}],'
            f'"aligned":{aligned},"heading_initialised":{init}}}')


def _scrub(obj: Any) -> Any:
    """Replace non-finite floats (anywhere in the structure) by None for strict JSON."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, Mapping):
        return {str(k): _scrub(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_scrub(v) for v in obj]
    return obj


def _close_session(session: Any) -> None:
    session.close()


class ZenohPublisher:
    """Owns one Zenoh session and the two publishers; ``close`` (or ``with``) ends it."""

    def __init__(self, config: ZenohConfig | None = None) -> None:
        self.config = config if config is not None else ZenohConfig()
        self.counters = Counters()
        self._session: Any = zenoh.open(self.config.to_zenoh())
        try:
            enc = zenoh.Encoding.APPLICATION_JSON
            self._att = self._session.declare_publisher(
                attitude_key(self.config.vehicle), encoding=enc
            )
            self._status = self._session.declare_publisher(
                status_key(self.config.vehicle), encoding=enc
            )
        except BaseException:
            _close_session(self._session)
            raise

    @property
    def session(self) -> Any:
        """The open Zenoh session, for other outputs that share it (the [ros2] sink)."""
        if self._session is None:
            raise RuntimeError("zenoh session is closed")
        return self._session

    def publish_attitude(self, sol: NavSolution, aligned_sd_rad: float = math.inf) -> None:
        self._send(self._att, attitude_text(sol, aligned_sd_rad), "attitude")

    def publish_status(self, status: Mapping[str, Any]) -> None:
        self._put(self._status, {**status, "schema": SCHEMA_VERSION}, "status")

    def _put(self, pub: Any, obj: Mapping[str, Any], what: str) -> None:
        try:
            text = json.dumps(_scrub(obj), allow_nan=False, separators=(",", ":"))
        except (TypeError, ValueError) as exc:
            # A status dict with an unserialisable value is a daemon bug; keep publishing
            # attitude regardless.
            self.counters.inc(f"{what}_unserialisable")
            _log.warning("zenoh: cannot serialise %s: %s", what, exc)
            return
        self._send(pub, text, what)

    def _send(self, pub: Any, text: str, what: str) -> None:
        try:
            pub.put(text)
        except zenoh.ZError as exc:
            self.counters.inc(f"{what}_put_error")
            _log.warning("zenoh: put %s failed: %s", what, exc)
            return
        self.counters.inc(f"{what}_sent")

    def close(self) -> None:
        if self._session is not None:
            _close_session(self._session)
            self._session = None

    def __enter__(self) -> ZenohPublisher:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class ZenohSubscriber:
    """Test/demo subscriber: JSON samples delivered on the asyncio loop.

    ``on_message(key, obj)`` runs on ``loop``; by default messages go to :attr:`queue`.
    Payloads not marked ``application/json`` (``wrong_encoding``) or not a JSON object
    (``bad_json``) are counted and dropped.
    """

    def __init__(
        self,
        config: ZenohConfig,
        key_expr: str,
        loop: asyncio.AbstractEventLoop,
        on_message: Callable[[str, dict[str, Any]], None] | None = None,
    ) -> None:
        self.loop = loop
        self.counters = Counters()
        self.queue: asyncio.Queue[tuple[str, dict[str, Any]]] = asyncio.Queue()
        self._on_message = on_message if on_message is not None else self._enqueue
        self._session: Any = zenoh.open(config.to_zenoh())
        try:
            self._sub = self._session.declare_subscriber(key_expr, self._on_sample)
        except BaseException:
            _close_session(self._session)
            raise

    def _enqueue(self, key: str, obj: dict[str, Any]) -> None:
        self.queue.put_nowait((key, obj))

    def _on_sample(self, sample: Any) -> None:
        # Zenoh thread: parse here, touch asyncio state only through the loop.
        if not str(sample.encoding).startswith("application/json"):
            self._to_loop(self.counters.inc, "wrong_encoding")
            return
        try:
            obj = json.loads(sample.payload.to_bytes())
            if not isinstance(obj, dict):
                raise ValueError("not a JSON object")
        except ValueError:  # includes JSONDecodeError and UnicodeDecodeError
            self._to_loop(self.counters.inc, "bad_json")
            return
        self._to_loop(self._on_message, str(sample.key_expr), obj)

    def _to_loop(self, fn: Callable[..., None], *args: Any) -> None:
        # RuntimeError: loop closed while the session was still delivering (shutdown).
        with contextlib.suppress(RuntimeError):
            self.loop.call_soon_threadsafe(fn, *args)

    async def recv(self, timeout_s: float | None = None) -> tuple[str, dict[str, Any]]:
        return await asyncio.wait_for(self.queue.get(), timeout_s)

    def close(self) -> None:
        if self._session is not None:
            _close_session(self._session)
            self._session = None

    def __enter__(self) -> ZenohSubscriber:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
