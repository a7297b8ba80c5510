"""The daemon's own config sections: ``[daemon]``, ``[mavlink]``, ``[dronecan]``, ``[zenoh]``,
``[bias_store]``.

Same rules as :mod:`navd.config.load`: the unit is in the key name (``status_period_s``,
``attitude_rate_hz``), every key is checked for type and range, and an error names the
section, the key and what it expects.  Unknown keys and unknown top-level tables are errors
too, so a typo never silently falls back to a default.  :func:`load_daemon_config` also
builds the estimator's :class:`EstimatorConfig` from the same file.
"""

from __future__ import annotations

import math
import typing
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from navd.config import ConfigError, EstimatorConfig, load_config
from navd.daemon.bias_store import BiasStoreSection
from navd.io.dronecan import DronecanConfig
from navd.io.mavlink import GNSS_MESSAGES, IMU_MESSAGES, MavlinkInputConfig, parse_mavlink_url
from navd.io.zenoh import ZenohConfig

__all__ = [
    "DaemonConfig",
    "DaemonSection",
    "DronecanSection",
    "MavlinkSection",
    "ZenohSection",
    "load_daemon_config",
]


@dataclass(frozen=True)
class DaemonSection:
    queue_size: int = 4096
    status_period_s: float = 1.0
    log_period_s: float = 60.0
    warn_interval_s: float = 5.0
    watchdog: bool = True
    warm_up: bool = True
    record: str = ""
    log_level: str = "info"
    event_loop: str = "auto"
    rx_buffer_bytes: int = 1 << 20

    def validate(self) -> None:
        _check(self.event_loop in ("auto", "uvloop", "asyncio"), "daemon", "event_loop",
               'one of "auto", "uvloop", "asyncio"')
        _check(self.rx_buffer_bytes >= 0, "daemon", "rx_buffer_bytes", "a byte count >= 0")
        _check(self.queue_size >= 16, "daemon", "queue_size", "an integer >= 16 (samples)")
        _check(0.05 <= self.status_period_s <= 3600.0, "daemon", "status_period_s",
               "a number of seconds in [0.05, 3600]")
        _check(self.log_period_s > 0.0, "daemon", "log_period_s", "a number of seconds > 0")
        _check(self.warn_interval_s >= 0.0, "daemon", "warn_interval_s",
               "a number of seconds >= 0")
        _check(self.log_level in ("debug", "info", "warning", "error"), "daemon", "log_level",
               'one of "debug", "info", "warning", "error"')


@dataclass(frozen=True)
class MavlinkSection:
    enabled: bool = True
    listen: str = "udpin:127.0.0.1:14560"
    send: str = "udpout:127.0.0.1:14550"
    sysid: int = 1
    compid: int = 191
    attitude_rate_hz: float = 50.0
    attitude_quaternion: bool = True
    heartbeat_period_s: float = 1.0
    global_position: bool = False
    geoid_sep_m: float = 0.0
    allow: tuple[tuple[int, int], ...] = ()
    imu_messages: tuple[str, ...] = ("HIGHRES_IMU",)
    gnss_messages: tuple[str, ...] = ("GPS_INPUT",)
    imu_id: int = 0
    gnss_id: int = 0
    nominal_imu_rate_hz: float = 0.0
    max_imu_gap_ms: float = 100.0
    use_receive_time: bool = False
    raw_gyro_rps_per_lsb: float = 0.0
    raw_accel_mps2_per_lsb: float = 0.0
    uere_m: float = 3.0
    polarization: bool = False

    def validate(self) -> None:
        s = "mavlink"
        for key, url in (("listen", self.listen), ("send", self.send)):
            if url in ("", "same"):
                continue
            try:
                parse_mavlink_url(url)
            except ValueError as exc:
                raise ConfigError(f"[{s}] {key}: {exc}") from None
        _check(self.listen != "same", s, "listen", 'a link address or "" (not "same")')
        if self.send == "same" and not self.listen:
            raise ConfigError(f'[{s}] send = "same" needs a listen link')
        _check(1 <= self.sysid <= 255, s, "sysid", "an integer 1..255")
        _check(1 <= self.compid <= 255, s, "compid", "an integer 1..255")
        _check(0.0 < self.attitude_rate_hz <= 1000.0, s, "attitude_rate_hz",
               "a rate in Hz in (0, 1000]")
        _check(self.heartbeat_period_s >= 0.0, s, "heartbeat_period_s",
               "a number of seconds >= 0 (0 = no HEARTBEAT)")
        for pair in self.allow:
            _check(1 <= pair[0] <= 255 and 0 <= pair[1] <= 255, s, "allow",
                   "a list of [sysid, compid] pairs (1..255, 0..255)")
        bad = sorted((set(self.imu_messages) - IMU_MESSAGES)
                     | (set(self.gnss_messages) - GNSS_MESSAGES))
        _check(not bad, s, "imu_messages/gnss_messages",
               f"message names from {sorted(IMU_MESSAGES)} / {sorted(GNSS_MESSAGES)}; "
               f"unsupported: {bad}")
        _check(self.imu_id >= -1 and self.gnss_id >= -1, s, "imu_id/gnss_id",
               "an instance number >= 0, or -1 for any")
        _check(self.nominal_imu_rate_hz >= 0.0, s, "nominal_imu_rate_hz",
               "a rate in Hz >= 0 (0 = drop the first sample after a gap)")
        _check(self.max_imu_gap_ms > 0.0, s, "max_imu_gap_ms", "a number of ms > 0")
        _check(self.raw_gyro_rps_per_lsb >= 0.0 and self.raw_accel_mps2_per_lsb >= 0.0, s,
               "raw_*_per_lsb", "a scale >= 0 (0 = RAW_IMU not usable)")
        _check(self.uere_m > 0.0, s, "uere_m", "a number of metres > 0")

    def input_config(self) -> MavlinkInputConfig:
        return MavlinkInputConfig(
            imu_messages=frozenset(self.imu_messages),
            gnss_messages=frozenset(self.gnss_messages),
            imu_id=None if self.imu_id < 0 else self.imu_id,
            gnss_id=None if self.gnss_id < 0 else self.gnss_id,
            allow=frozenset(self.allow) if self.allow else None,
            nominal_imu_rate_hz=self.nominal_imu_rate_hz or None,
            max_imu_gap_s=self.max_imu_gap_ms * 1e-3,
            raw_gyro_rps_per_lsb=self.raw_gyro_rps_per_lsb or None,
            raw_accel_mps2_per_lsb=self.raw_accel_mps2_per_lsb or None,
            geoid_sep_m=self.geoid_sep_m,
            uere_m=self.uere_m,
            use_receive_time=self.use_receive_time,
            polarization=self.polarization,
        )


@dataclass(frozen=True)
class DronecanSection:
    enabled: bool = False
    interface: str = "socketcan"
    channel: str = "can0"
    node_id: int = 100
    allow_nodes: tuple[int, ...] = ()
    solution_out: bool = False
    solution_rate_hz: float = 50.0
    nominal_imu_rate_hz: float = 0.0
    max_imu_gap_ms: float = 100.0
    transfer_timeout_ms: float = 100.0
    use_receive_time: bool = False

    def validate(self) -> None:
        s = "dronecan"
        _check(bool(self.interface), s, "interface", 'a python-can interface ("socketcan", '
               '"virtual", ...)')
        _check(1 <= self.node_id <= 127, s, "node_id", "an integer 1..127")
        _check(all(1 <= n <= 127 for n in self.allow_nodes), s, "allow_nodes",
               "a list of node IDs 1..127")
        _check(0.0 < self.solution_rate_hz <= 1000.0, s, "solution_rate_hz",
               "a rate in Hz in (0, 1000]")
        _check(self.nominal_imu_rate_hz >= 0.0, s, "nominal_imu_rate_hz", "a rate in Hz >= 0")
        _check(self.max_imu_gap_ms > 0.0, s, "max_imu_gap_ms", "a number of ms > 0")
        _check(self.transfer_timeout_ms > 0.0, s, "transfer_timeout_ms", "a number of ms > 0")

    def bus_config(self) -> DronecanConfig:
        return DronecanConfig(
            interface=self.interface,
            channel=self.channel,
            node_id=self.node_id,
            allow_nodes=frozenset(self.allow_nodes) if self.allow_nodes else None,
            transfer_timeout_s=self.transfer_timeout_ms * 1e-3,
            nominal_imu_rate_hz=self.nominal_imu_rate_hz or None,
            max_imu_gap_s=self.max_imu_gap_ms * 1e-3,
            use_receive_time=self.use_receive_time,
        )


@dataclass(frozen=True)
class ZenohSection:
    enabled: bool = True
    vehicle: str = "vehicle"
    listen: tuple[str, ...] = ("tcp/127.0.0.1:7447",)
    connect: tuple[str, ...] = ()
    multicast_scouting: bool = False
    attitude_rate_hz: float = 50.0
    status: bool = True

    def validate(self) -> None:
        _check(0.0 < self.attitude_rate_hz <= 1000.0, "zenoh", "attitude_rate_hz",
               "a rate in Hz in (0, 1000]")
        try:
            self.session_config()
        except ValueError as exc:
            raise ConfigError(f"[zenoh] vehicle: {exc}") from None

    def session_config(self) -> ZenohConfig:
        return ZenohConfig(vehicle=self.vehicle, listen=self.listen, connect=self.connect,
                           multicast_scouting=self.multicast_scouting)


# sections other parts of navd read (navd.pipeline: [dov]; polarization aid: [polarization])
_OTHER_SECTIONS = frozenset({"dov", "polarization"})

_SECTIONS: dict[str, type[Any]] = {
    "daemon": DaemonSection,
    "mavlink": MavlinkSection,
    "dronecan": DronecanSection,
    "zenoh": ZenohSection,
    "bias_store": BiasStoreSection,
}


@dataclass(frozen=True)
class DaemonConfig:
    """Everything ``navd run`` needs, validated; ``tables`` is the raw TOML (for recordings)."""

    daemon: DaemonSection = field(default_factory=DaemonSection)
    mavlink: MavlinkSection = field(default_factory=MavlinkSection)
    dronecan: DronecanSection = field(default_factory=DronecanSection)
    zenoh: ZenohSection = field(default_factory=ZenohSection)
    bias_store: BiasStoreSection = field(default_factory=BiasStoreSection)
    estimator: EstimatorConfig = field(default_factory=EstimatorConfig)
    tables: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> DaemonConfig:
        known = set(_SECTIONS) | _OTHER_SECTIONS | {f.name for f in fields(EstimatorConfig)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ConfigError(f"unknown config section(s) {unknown}; expected some of "
                              f"{sorted(known)}")
        kw: dict[str, Any] = {name: _build(sec, name, data.get(name, {}))
                              for name, sec in _SECTIONS.items()}
        if not (kw["mavlink"].enabled and kw["mavlink"].listen) and not kw["dronecan"].enabled:
            raise ConfigError("no input: enable [mavlink] (with listen) or [dronecan]")
        return cls(**kw, estimator=EstimatorConfig.from_dict(data), tables=data)


def load_daemon_config(path: str | Path | None, overrides: list[str] | None = None
                       ) -> DaemonConfig:
    return DaemonConfig.from_dict(load_config(path, overrides))


# -- parsing helpers ---------------------------------------------------------------------------


def _check(ok: bool, section: str, key: str, expected: str) -> None:
    if not ok:
        raise ConfigError(f"[{section}] {key} must be {expected}")


def _describe(tp: Any) -> str:
    return {bool: "true or false", int: "an integer", float: "a number", str: "a string",
            tuple[str, ...]: "a list of strings", tuple[int, ...]: "a list of integers",
            tuple[tuple[int, int], ...]: "a list of [int, int] pairs"}.get(tp, str(tp))


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _coerce(value: Any, tp: Any) -> Any:
    """Value as type ``tp``, or raise TypeError."""
    if tp is bool and isinstance(value, bool):
        return value
    if tp is int and _is_int(value):
        return value
    if tp is float and (_is_int(value) or isinstance(value, float)) and math.isfinite(value):
        return float(value)
    if tp is str and isinstance(value, str):
        return value
    if isinstance(value, list):
        if tp == tuple[str, ...] and all(isinstance(v, str) for v in value):
            return tuple(value)
        if tp == tuple[int, ...] and all(_is_int(v) for v in value):
            return tuple(value)
        if tp == tuple[tuple[int, int], ...] and all(
                isinstance(p, list) and len(p) == 2 and all(_is_int(v) for v in p)
                for p in value):
            return tuple((p[0], p[1]) for p in value)
    raise TypeError


def _build(cls: type[Any], section: str, table: Any) -> Any:
    if not isinstance(table, dict):
        raise ConfigError(f"[{section}] must be a table")
    hints = typing.get_type_hints(cls)
    names = [f.name for f in fields(cls)]
    kwargs: dict[str, Any] = {}
    for key, value in table.items():
        if key not in hints:
            raise ConfigError(f"[{section}] unknown key {key!r}; expected one of: "
                              f"{', '.join(names)}")
        try:
            kwargs[key] = _coerce(value, hints[key])
        except TypeError:
            raise ConfigError(f"[{section}] {key} must be {_describe(hints[key])}, "
                              f"got {value!r}") from None
    obj = cls(**kwargs)
    obj.validate()
    return obj
