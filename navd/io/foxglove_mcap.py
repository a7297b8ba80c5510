"""NavSolutions -> an MCAP file that Foxglove opens (``navd run --mcap``, ``navd replay --mcap``).

Channels (message encoding ``json``, schema encoding ``jsonschema``, as Foxglove documents
JSON data in MCAP; the JSON Schemas are navd's own, written from the field lists of
Foxglove's published message schemas)

    /navd/pose       foxglove.PoseInFrame   attitude in frame ``enu``: body FLU -> local ENU
                                            (REP-103), position in m east/north/up of the
                                            first solution
    /navd/location   foxglove.LocationFix   WGS-84 lat/lon (deg), ellipsoid height (m),
                                            ENU position covariance (diagonal, m^2)
    /navd/heading    navd.HeadingStatus     navd's own frames: NED/FRD Euler angles (deg),
                                            their 1-sigma, aligned / initialised, resets,
                                            GNSS age
    /navd/status     navd.Status            the daemon's status object (``navd run`` only)

Times: every message's ``timestamp`` is the solution's sensor time (``t_us``).  The MCAP
``log_time`` is given by the caller: sensor time in a replay, host wall-clock time in
``navd run`` (so a live recording lines up with other recordings of the same day).

NED/FRD -> ENU/FLU: q_enu_flu = q_enu_ned * q_nb * q_frd_flu, with q_enu_ned a half turn
about (north + east)/sqrt(2) (it swaps x and y and negates z) and q_frd_flu a half turn
about x.  Checked against the rotation matrices in tests/test_foxglove_mcap.py.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from pathlib import Path
from types import TracebackType
from typing import IO, Any

from mcap.writer import Writer

from navd.core.earth import radii
from navd.types import NavSolution

__all__ = [
    "CHANNELS",
    "HEADING_SCHEMA",
    "LOCATION_FIX_SCHEMA",
    "POSE_IN_FRAME_SCHEMA",
    "FoxgloveMessages",
    "NavMcapWriter",
    "encode_json",
    "enu_flu_quat",
]

_S = math.sqrt(0.5)
_Q_ENU_NED = (0.0, _S, _S, 0.0)  # (w, x, y, z)
_Q_FRD_FLU = (0.0, 1.0, 0.0, 0.0)


def _qmul(a: tuple[float, float, float, float], b: tuple[float, float, float, float]
          ) -> tuple[float, float, float, float]:
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw)


def enu_flu_quat(quat_nb: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
    """(w, x, y, z) of C_flu^enu from navd's (w, x, y, z) of C_frd^ned, with w >= 0 (q and
    -q are the same rotation; one sign keeps consecutive messages comparable)."""
    q = _qmul(_qmul(_Q_ENU_NED, quat_nb), _Q_FRD_FLU)
    return q if q[0] >= 0.0 else (-q[0], -q[1], -q[2], -q[3])


def _num(*props: str) -> dict[str, Any]:
    return {p: {"type": "number"} for p in props}


_TIME = {"type": "object", "title": "time", "properties": {
    "sec": {"type": "integer", "minimum": 0}, "nsec": {"type": "integer", "minimum": 0,
                                                       "maximum": 999_999_999}}}

POSE_IN_FRAME_SCHEMA: dict[str, Any] = {
    "title": "foxglove.PoseInFrame", "type": "object",
    "description": "A timestamped pose for an object or reference frame in 3D space",
    "properties": {
        "timestamp": _TIME,
        "frame_id": {"type": "string"},
        "pose": {"type": "object", "title": "foxglove.Pose", "properties": {
            "position": {"type": "object", "title": "foxglove.Vector3",
                         "properties": _num("x", "y", "z")},
            "orientation": {"type": "object", "title": "foxglove.Quaternion",
                            "properties": _num("x", "y", "z", "w")}}},
    },
}

LOCATION_FIX_SCHEMA: dict[str, Any] = {
    "title": "foxglove.LocationFix", "type": "object",
    "description": "A navigation satellite fix for any Global Navigation Satellite System",
    "properties": {
        "timestamp": _TIME,
        "frame_id": {"type": "string"},
        **_num("latitude", "longitude", "altitude"),
        "position_covariance": {"type": "array", "items": {"type": "number"},
                                "minItems": 9, "maxItems": 9},
        # 0 unknown, 1 approximated, 2 diagonal known, 3 known
        "position_covariance_type": {"type": "integer", "enum": [0, 1, 2, 3]},
    },
}

HEADING_SCHEMA: dict[str, Any] = {
    "title": "navd.HeadingStatus", "type": "object",
    "description": "navd's attitude in its own frames (NED navigation, FRD body, ZYX Euler) "
                   "and whether its heading is usable",
    "properties": {
        "timestamp": _TIME,
        "t_us": {"type": "integer", "description": "sensor time of validity, us"},
        "euler_deg": {"type": "array", "items": {"type": ["number", "null"]},
                      "description": "roll, pitch, yaw (clockwise from north), deg"},
        "sigma_deg": {"type": "array", "items": {"type": ["number", "null"]},
                      "description": "1-sigma of roll, pitch, yaw, deg"},
        "aligned": {"type": "boolean", "description": "heading usable (sigma <= aligned)"},
        "heading_initialised": {"type": "boolean"},
        "heading_resets": {"type": "integer"},
        "gnss_age_s": {"type": ["number", "null"],
                       "description": "age of the last GNSS fix used; null before one"},
    },
}

STATUS_SCHEMA: dict[str, Any] = {
    "title": "navd.Status", "type": "object",
    "description": "navd run's status object (docs/daemon.md)",
    "properties": {"state": {"type": "string"}},
}

# topic -> (schema name, JSON Schema)
CHANNELS: dict[str, tuple[str, dict[str, Any]]] = {
    "/navd/pose": ("foxglove.PoseInFrame", POSE_IN_FRAME_SCHEMA),
    "/navd/location": ("foxglove.LocationFix", LOCATION_FIX_SCHEMA),
    "/navd/heading": ("navd.HeadingStatus", HEADING_SCHEMA),
    "/navd/status": ("navd.Status", STATUS_SCHEMA),
}


def _time(t_us: int) -> dict[str, int]:
    t = max(t_us, 0)
    return {"sec": t // 1_000_000, "nsec": (t % 1_000_000) * 1000}


def _fin(x: float) -> float | None:
    return x if math.isfinite(x) else None


def _scrub(obj: Any) -> Any:
    if isinstance(obj, float):
        return _fin(obj)
    if isinstance(obj, Mapping):
        return {str(k): _scrub(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_scrub(v) for v in obj]
    return obj


class FoxgloveMessages:
    """The channel messages for one solution, shared by the MCAP file and the live server;
    keeps the ENU origin (the first solution with a position)."""

    def __init__(self, aligned_sd_rad: float) -> None:
        self.aligned_sd_rad = aligned_sd_rad
        self._origin: tuple[float, float, float] | None = None

    def _enu_m(self, sol: NavSolution) -> tuple[float, float, float]:
        if self._origin is None:
            self._origin = (sol.lat_rad, sol.lon_rad, sol.alt_m)
        lat0, lon0, h0 = self._origin
        r_m, r_n = radii(lat0)
        return ((sol.lon_rad - lon0) * (r_n + h0) * math.cos(lat0),
                (sol.lat_rad - lat0) * (r_m + h0), sol.alt_m - h0)

    def of(self, sol: NavSolution) -> list[tuple[str, dict[str, Any]]]:
        """[(topic, JSON object)] for ``sol``; pose and location only with a finite position."""
        out: list[tuple[str, dict[str, Any]]] = []
        ts = _time(sol.t_us)
        w, x, y, z = enu_flu_quat(sol.quat_nb)
        if all(math.isfinite(v) for v in (sol.lat_rad, sol.lon_rad, sol.alt_m)):
            e, n, u = self._enu_m(sol)
            out.append(("/navd/pose", {
                "timestamp": ts, "frame_id": "enu",
                "pose": {"position": {"x": e, "y": n, "z": u},
                         "orientation": {"x": x, "y": y, "z": z, "w": w}}}))
            sd_n, sd_e, sd_d = sol.pos_sd_m
            known = all(math.isfinite(v) for v in sol.pos_sd_m)
            cov = [sd_e**2, 0.0, 0.0, 0.0, sd_n**2, 0.0, 0.0, 0.0, sd_d**2] if known \
                else [0.0] * 9
            out.append(("/navd/location", {
                "timestamp": ts, "frame_id": "navd",
                "latitude": math.degrees(sol.lat_rad), "longitude": math.degrees(sol.lon_rad),
                "altitude": sol.alt_m, "position_covariance": cov,
                "position_covariance_type": 2 if known else 0}))
        d = math.degrees
        out.append(("/navd/heading", {
            "timestamp": ts, "t_us": sol.t_us,
            "euler_deg": [d(sol.roll_rad), d(sol.pitch_rad), d(sol.yaw_rad)],
            "sigma_deg": [d(v) for v in sol.att_sd_rad],
            "aligned": sol.heading_good(self.aligned_sd_rad),
            "heading_initialised": bool(sol.heading_initialised or sol.heading_aligned),
            "heading_resets": sol.heading_resets,
            "gnss_age_s": sol.gnss_age_us * 1e-6 if sol.gnss_age_us >= 0 else None,
        }))
        return out


def encode_json(obj: Any) -> bytes:
    """Strict JSON (non-finite numbers as null), compact."""
    return json.dumps(_scrub(obj), separators=(",", ":"), allow_nan=False,
                      default=str).encode()


class NavMcapWriter:
    """Writes the channels above to ``path``.  With ``atomic`` the file is written as
    ``<path>.part`` and renamed on :meth:`close`; :meth:`abort` removes it instead."""

    def __init__(self, path: str | Path, *, aligned_sd_rad: float, atomic: bool = False,
                 status: bool = False) -> None:
        self.path = Path(path)
        self._tmp = self.path.with_name(self.path.name + ".part") if atomic else self.path
        self._msgs = FoxgloveMessages(aligned_sd_rad)
        self._fh: IO[bytes] | None = open(self._tmp, "wb")  # noqa: SIM115 (closed in close)
        self._w = Writer(self._fh)
        self._w.start(profile="", library="navd")
        self._chan: dict[str, int] = {}
        for topic, (name, schema) in CHANNELS.items():
            if topic == "/navd/status" and not status:
                continue
            sid = self._w.register_schema(name=name, encoding="jsonschema",
                                          data=json.dumps(schema).encode())
            self._chan[topic] = self._w.register_channel(topic=topic, message_encoding="json",
                                                         schema_id=sid)
        self.messages = 0

    def _put(self, topic: str, obj: Mapping[str, Any], log_time_ns: int) -> None:
        self._w.add_message(channel_id=self._chan[topic], log_time=log_time_ns,
                            data=encode_json(obj), publish_time=log_time_ns)
        self.messages += 1

    def write_solution(self, sol: NavSolution, log_time_ns: int) -> None:
        for topic, obj in self._msgs.of(sol):
            self._put(topic, obj, log_time_ns)

    def write_status(self, status: Mapping[str, Any], log_time_ns: int) -> None:
        if "/navd/status" in self._chan:
            self._put("/navd/status", status, log_time_ns)

    def close(self) -> None:
        if self._fh is None:
            return
        self._w.finish()  # type: ignore[no-untyped-call]
        self._fh.close()
        self._fh = None
        if self._tmp != self.path:
            self._tmp.replace(self.path)

    def abort(self) -> None:
        """Close without keeping the file (a failed replay leaves nothing behind)."""
        if self._fh is not None:
            self._fh.close()
            self._fh = None
        self._tmp.unlink(missing_ok=True)

    def __enter__(self) -> NavMcapWriter:
        return self

    def __exit__(self, et: type[BaseException] | None, ev: BaseException | None,
                 tb: TracebackType | None) -> None:
        if et is None:
            self.close()
        else:
            self.abort()
