"""The daemon's own config sections: ``[daemon]``, ``[mavlink]``, ``[autopilot]``,
``[dronecan]``, ``[zenoh]``, ``[ros2]``, ``[foxglove]``, ``[bias_store]``, and
:class:`DaemonConfig` (all of ``navd run``'s configuration).

Same builder and naming rule as every section (:mod:`navd.config.load`): the TOML key carries
the unit (``status_period_s``, ``attitude_rate_hz``), the attribute drops it and holds the SI
value (``status_period`` in s, ``attitude_rate`` in Hz, ``max_imu_gap`` in s).  Every key is
checked for type and range, and an error names the section, the key and what it expects.
Unknown keys and unknown top-level tables are errors too, so a typo never silently falls
back to a default.  :func:`load_daemon_config` also builds the estimator's
:class:`NavConfig` from the same file, once.

The adapters' own settings objects (``MavlinkInputConfig``, ``DronecanConfig``,
``ZenohConfig``) are made from these sections in the daemon layer
(:mod:`navd.daemon.adapters`); this module imports from :mod:`navd.io.mavlink` only what
validation needs (the supported message names and the link-address parser).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from navd.config.aiding import DovSection, NavConfig, PolarizationSection
from navd.config.estimator import EstimatorConfig
from navd.config.load import ConfigError, build_section, check, load_config
from navd.config.load import setting as _f
from navd.io.mavlink import GNSS_MESSAGES, IMU_MESSAGES, parse_mavlink_url
from navd.io.mavlink.signing import load_signing_key
from navd.io.ros2.names import validate_name, validate_namespace

__all__ = [
    "RUN_ONLY_SECTIONS",
    "ZENOH_BAD_CHUNK_CHARS",
    "AutopilotSection",
    "BiasStoreSection",
    "DaemonConfig",
    "DaemonSection",
    "DronecanSection",
    "FoxgloveSection",
    "MavlinkSection",
    "Ros2Section",
    "ZenohSection",
    "load_daemon_config",
]

# characters a Zenoh key chunk (the vehicle name) may not contain
ZENOH_BAD_CHUNK_CHARS = frozenset("/*$?#")


@dataclass(frozen=True)
class DaemonSection:
    queue_size: int = _f(4096)  # samples between inputs and estimator (count)
    status_period: float = _f(1.0, "s")  # status / sd_notify / stall detection period
    log_period: float = _f(60.0, "s")  # one info line with all counters this often
    warn_interval: float = _f(5.0, "s")  # at most one warning per reason per interval
    watchdog: bool = _f(True)
    warm_up: bool = _f(True)
    record: str = _f("")
    log_level: str = _f("info", choices=("debug", "info", "warning", "error"))
    event_loop: str = _f("auto", choices=("auto", "uvloop", "asyncio"))
    rx_buffer: int = _f(1 << 20, "bytes")  # UDP input socket receive buffer
    # read pacing (navd.io.read_pacing): the UDP input may stay unread up to this long
    # between output instants (0: read every datagram as it arrives), and is read again
    # this long before the next output instant's sample is due
    read_hold_max: float = _f(20.0, "ms")
    read_hold_margin: float = _f(3.0, "ms")
    # the UDP input read by a thread of compiled code that wakes the event loop once per
    # output instant (Linux; read_hold_max_ms then bounds how long a datagram is held);
    # false: read on the event loop, paced as above
    rx_thread: bool = _f(True)
    # navigating without a fused GNSS fix for this long (sensor time) is "coasting"
    gnss_timeout: float = _f(3.0, "s")

    def validate(self) -> None:
        s = "daemon"
        check(self.rx_buffer >= 0, s, "rx_buffer_bytes", "a byte count >= 0")
        check(0.0 <= self.read_hold_max <= 0.1, s, "read_hold_max_ms",
              "a number of milliseconds in [0, 100]")
        check(self.read_hold_margin >= 0.0, s, "read_hold_margin_ms",
              "a number of milliseconds >= 0")
        check(self.queue_size >= 16, s, "queue_size", "an integer >= 16 (samples)")
        check(0.05 <= self.status_period <= 3600.0, s, "status_period_s",
              "a number of seconds in [0.05, 3600]")
        check(self.log_period > 0.0, s, "log_period_s", "a number of seconds > 0")
        check(self.warn_interval >= 0.0, s, "warn_interval_s", "a number of seconds >= 0")
        check(self.gnss_timeout > 0.0, s, "gnss_timeout_s", "a number of seconds > 0")


@dataclass(frozen=True)
class MavlinkSection:
    enabled: bool = _f(True)
    listen: str = _f("udpin:127.0.0.1:14560")
    send: str = _f("udpout:127.0.0.1:14550")
    sysid: int = _f(1)
    compid: int = _f(191)
    attitude_rate: float = _f(50.0, "hz")  # ATTITUDE (+ _QUATERNION) per second of sensor time
    attitude_quaternion: bool = _f(True)
    heartbeat_period: float = _f(1.0, "s")  # 0 = no HEARTBEAT
    global_position: bool = _f(False)
    geoid_sep: float = _f(0.0, "m")  # geoid undulation N = ellipsoid - MSL height
    allow: tuple[tuple[int, int], ...] = _f(())
    imu_messages: tuple[str, ...] = _f(("HIGHRES_IMU",))
    gnss_messages: tuple[str, ...] = _f(("GPS_INPUT",))
    imu_id: int = _f(0)
    gnss_id: int = _f(0)
    # interval (as a rate) given to the first rate-type IMU sample after a gap; 0 = drop it
    nominal_imu_rate: float = _f(0.0, "hz")
    # the adapter's IMU gap (s): the longest interval between two rate-type IMU samples
    # (RAW_IMU, SCALED_IMU*, HIGHRES_IMU: rates, not increments) over which the earlier
    # rate is held and integrated; a longer interval restarts that source's time line
    # (counted imu_gap): the sample is dropped, or given the nominal interval
    max_imu_gap: float = _f(100.0, "ms")
    use_receive_time: bool = _f(False)
    raw_gyro: float = _f(0.0, "rps_per_lsb")  # RAW_IMU gyro scale; 0 = RAW_IMU not usable
    raw_accel: float = _f(0.0, "mps2_per_lsb")  # RAW_IMU accelerometer scale
    uere: float = _f(3.0, "m")  # accuracy = DOP * uere when a fix sends none
    polarization: bool = _f(False)
    # a bigger UDP datagram is refused unread (counted oversize); >= 280 (one frame)
    max_datagram: int = _f(16384, "bytes")
    signing_key_file: str = _f("")  # MAVLink 2 signing key (32 raw bytes or 64 hex); "" = off
    accept_unsigned: bool = _f(False)  # with a key: also take unsigned (and MAVLink 1) frames
    # lock IMU / GNSS / polarization input each onto the first source that delivers it
    # (navd.io.source_lock); another takes over after the locked one is silent for relock
    source_lock: bool = _f(True)
    relock: float = _f(5.0, "s")

    def validate(self) -> None:
        s = "mavlink"
        for key, url in (("listen", self.listen), ("send", self.send)):
            if url in ("", "same"):
                continue
            try:
                parse_mavlink_url(url)
            except ValueError as exc:
                raise ConfigError(f"[{s}] {key}: {exc}") from None
        check(self.listen != "same", s, "listen", 'a link address or "" (not "same")')
        if self.send == "same" and not self.listen:
            raise ConfigError(f'[{s}] send = "same" needs a listen link')
        check(1 <= self.sysid <= 255, s, "sysid", "an integer 1..255")
        check(1 <= self.compid <= 255, s, "compid", "an integer 1..255")
        check(0.0 < self.attitude_rate <= 1000.0, s, "attitude_rate_hz",
              "a rate in Hz in (0, 1000]")
        check(self.heartbeat_period >= 0.0, s, "heartbeat_period_s",
              "a number of seconds >= 0 (0 = no HEARTBEAT)")
        for pair in self.allow:
            check(1 <= pair[0] <= 255 and 0 <= pair[1] <= 255, s, "allow",
                  "a list of [sysid, compid] pairs (1..255, 0..255)")
        bad = sorted((set(self.imu_messages) - IMU_MESSAGES)
                     | (set(self.gnss_messages) - GNSS_MESSAGES))
        check(not bad, s, "imu_messages/gnss_messages",
              f"message names from {sorted(IMU_MESSAGES)} / {sorted(GNSS_MESSAGES)}; "
              f"unsupported: {bad}")
        check(self.imu_id >= -1 and self.gnss_id >= -1, s, "imu_id/gnss_id",
              "an instance number >= 0, or -1 for any")
        check(self.nominal_imu_rate >= 0.0, s, "nominal_imu_rate_hz",
              "a rate in Hz >= 0 (0 = drop the first sample after a gap)")
        check(self.max_imu_gap > 0.0, s, "max_imu_gap_ms", "a number of ms > 0")
        check(self.raw_gyro >= 0.0 and self.raw_accel >= 0.0, s,
              "raw_*_per_lsb", "a scale >= 0 (0 = RAW_IMU not usable)")
        check(self.uere > 0.0, s, "uere_m", "a number of metres > 0")
        check(self.relock > 0.0, s, "relock_s", "a number of seconds > 0")
        check(self.max_datagram >= 280, s, "max_datagram_bytes",
              "a byte count >= 280 (the largest MAVLink frame)")
        if self.signing_key_file:
            try:
                load_signing_key(self.signing_key_file)
            except (OSError, ValueError) as exc:
                raise ConfigError(f"[{s}] signing_key_file: {exc}") from None


@dataclass(frozen=True)
class AutopilotSection:
    """``[autopilot]``: navd as a GPS / heading source for an autopilot, on the ``[mavlink]``
    send link (docs/autopilot.md).  Everything is off by default."""

    gps_input: bool = _f(False)  # GPS_INPUT with navd's position, velocity and heading (yaw)
    gps_input_rate: float = _f(5.0, "hz")  # per second of sensor time
    max_gnss_age: float = _f(1.0, "s")  # 3D fix only while a GNSS fix was used this recently
    heading_reset: bool = _f(False)  # COMMAND_LONG MAV_CMD_EXTERNAL_ATTITUDE_ESTIMATE (PX4)
    heading_reset_min_interval: float = _f(10.0, "s")  # at most one command per interval
    heading_reset_period: float = _f(0.0, "s")  # also repeat this often while aligned; 0 = no
    target_sysid: int = _f(1)  # the autopilot that gets the command
    target_compid: int = _f(1)  # 1 = MAV_COMP_ID_AUTOPILOT1
    estimator_status: bool = _f(False)  # ESTIMATOR_STATUS with each GPS_INPUT (or at its rate)

    @property
    def any(self) -> bool:
        return self.gps_input or self.heading_reset or self.estimator_status

    def validate(self) -> None:
        s = "autopilot"
        check(0.0 < self.gps_input_rate <= 50.0, s, "gps_input_rate_hz",
              "a rate in Hz in (0, 50]")
        check(self.max_gnss_age > 0.0, s, "max_gnss_age_s", "a number of seconds > 0")
        check(self.heading_reset_min_interval >= 1.0, s, "heading_reset_min_interval_s",
              "a number of seconds >= 1 (the autopilot resets its heading on each command)")
        check(self.heading_reset_period == 0.0
              or self.heading_reset_period >= self.heading_reset_min_interval, s,
              "heading_reset_period_s", "0 or at least heading_reset_min_interval_s")
        check(1 <= self.target_sysid <= 255 and 0 <= self.target_compid <= 255, s,
              "target_sysid/target_compid", "1..255 / 0..255")


@dataclass(frozen=True)
class DronecanSection:
    enabled: bool = _f(False)
    interface: str = _f("socketcan")
    channel: str = _f("can0")
    node_id: int = _f(100)
    allow_nodes: tuple[int, ...] = _f(())
    solution_out: bool = _f(False)
    solution_rate: float = _f(50.0, "hz")  # Solution messages per second of sensor time
    nominal_imu_rate: float = _f(0.0, "hz")  # as [mavlink], for RawIMU without integrals
    # as [mavlink] max_imu_gap: the longest interval over which a RawIMU rate sample (one
    # without integrals) is held and integrated; longer restarts the time line (imu_gap)
    max_imu_gap: float = _f(100.0, "ms")
    transfer_timeout: float = _f(100.0, "ms")  # unfinished multi-frame transfers evicted
    use_receive_time: bool = _f(False)
    source_lock: bool = _f(True)  # as [mavlink]: one node per kind of input
    relock: float = _f(5.0, "s")

    def validate(self) -> None:
        s = "dronecan"
        check(bool(self.interface), s, "interface", 'a python-can interface ("socketcan", '
              '"virtual", ...)')
        check(1 <= self.node_id <= 127, s, "node_id", "an integer 1..127")
        check(all(1 <= n <= 127 for n in self.allow_nodes), s, "allow_nodes",
              "a list of node IDs 1..127")
        check(0.0 < self.solution_rate <= 1000.0, s, "solution_rate_hz",
              "a rate in Hz in (0, 1000]")
        check(self.nominal_imu_rate >= 0.0, s, "nominal_imu_rate_hz", "a rate in Hz >= 0")
        check(self.max_imu_gap > 0.0, s, "max_imu_gap_ms", "a number of ms > 0")
        check(self.transfer_timeout > 0.0, s, "transfer_timeout_ms", "a number of ms > 0")
        check(self.relock > 0.0, s, "relock_s", "a number of seconds > 0")


@dataclass(frozen=True)
class ZenohSection:
    enabled: bool = _f(True)
    vehicle: str = _f("vehicle")
    listen: tuple[str, ...] = _f(("tcp/127.0.0.1:7447",))
    connect: tuple[str, ...] = _f(())
    multicast_scouting: bool = _f(False)
    attitude_rate: float = _f(50.0, "hz")  # attitude samples per second of sensor time
    status: bool = _f(True)
    # docs/daemon.md "Zenoh threat model": refuse data pushed in and admin-space queries
    access_control: bool = _f(True)
    user: str = _f("")  # presented when navd connects out ("" = none)
    password_file: str = _f("")  # that user's password, first line (kept out of navd.toml)
    users_file: str = _f("")  # user:password lines a peer must match to connect ("" = any)

    def validate(self) -> None:
        check(0.0 < self.attitude_rate <= 1000.0, "zenoh", "attitude_rate_hz",
              "a rate in Hz in (0, 1000]")
        check(not self.user or bool(self.password_file), "zenoh", "password_file",
              "set when user is (a file holding the password)")
        if not self.vehicle or ZENOH_BAD_CHUNK_CHARS & set(self.vehicle):
            raise ConfigError(f"[zenoh] vehicle: vehicle {self.vehicle!r} must be one key "
                              "chunk (no / * $ ? #)")


@dataclass(frozen=True)
class Ros2Section:
    """``[ros2]``: ROS 2 topics over the [zenoh] session, as an rmw_zenoh node publishes them
    (docs/interfaces.md)."""

    enabled: bool = _f(False)
    domain_id: int = _f(0)  # ROS_DOMAIN_ID: the first chunk of every key expression
    namespace: str = _f("/")  # absolute: "/" or "/robot1"
    node_name: str = _f("navd")
    frame_id: str = _f("base_link")  # body frame: Imu, NavSatFix, Odometry child frame
    world_frame_id: str = _f("map")  # Odometry's frame: local ENU, origin at the first fix
    rate: float = _f(50.0, "hz")  # Imu, NavSatFix, Odometry per second of sensor time
    diagnostics_period: float = _f(1.0, "s")  # heading status on /diagnostics (sensor time)

    def validate(self) -> None:
        s = "ros2"
        check(0 <= self.domain_id <= 232, s, "domain_id", "an integer 0..232 (ROS_DOMAIN_ID)")
        for key, err in (("namespace", validate_namespace(self.namespace)),
                         ("node_name", validate_name(self.node_name))):
            if err is not None:
                raise ConfigError(f"[{s}] {key}: {err}")
        for key, fid in (("frame_id", self.frame_id), ("world_frame_id", self.world_frame_id)):
            check(bool(fid) and fid.isprintable(), s, key, "a non-empty frame name")
        check(0.0 < self.rate <= 1000.0, s, "rate_hz", "a rate in Hz in (0, 1000]")
        check(self.diagnostics_period > 0.0, s, "diagnostics_period_s",
              "a number of seconds > 0")


@dataclass(frozen=True)
class FoxgloveSection:
    """``[foxglove]``: a live Foxglove WebSocket server (navd/io/foxglove_ws.py)."""

    enabled: bool = _f(False)
    host: str = _f("127.0.0.1")  # no authentication: keep it on loopback
    port: int = _f(8765)
    rate: float = _f(10.0, "hz")  # solutions per second of sensor time

    def validate(self) -> None:
        check(0 <= self.port <= 65535, "foxglove", "port", "a TCP port 0..65535 (0 = any free)")
        check(0.0 < self.rate <= 1000.0, "foxglove", "rate_hz", "a rate in Hz in (0, 1000]")
        check(bool(self.host), "foxglove", "host", "an address to listen on")


@dataclass(frozen=True)
class BiasStoreSection:
    """``[bias_store]``: learned IMU biases kept between runs (:mod:`navd.daemon.bias_store`)."""

    path: str = _f("")  # "" = off; under systemd: /var/lib/navd/imu_bias.json (StateDirectory)
    imu_id: str = _f("")  # names the IMU (serial, node); a file of another IMU is refused
    save_period: float = _f(600.0, "s")
    max_gyro_sd: float = _f(3.0, "deg_per_h")  # save only when every gyro 1-sigma is within
    max_accel_sd: float = _f(1.0, "mg")  # ... and every accelerometer 1-sigma within this
    repeat_gyro_sd: float = _f(1.0, "deg_per_h")  # turn-on repeatability, added at load
    repeat_accel_sd: float = _f(0.5, "mg")
    max_age: float = _f(30.0, "days")  # an older file is refused

    def validate(self) -> None:
        s = "bias_store"
        check(self.save_period >= 10.0, s, "save_period_s", "a number of seconds >= 10")
        for key, v in (("max_gyro_sd_deg_per_h", self.max_gyro_sd),
                       ("max_accel_sd_mg", self.max_accel_sd), ("max_age_days", self.max_age)):
            check(v > 0.0, s, key, "a number > 0")
        for key, v in (("repeat_gyro_sd_deg_per_h", self.repeat_gyro_sd),
                       ("repeat_accel_sd_mg", self.repeat_accel_sd)):
            check(v >= 0.0, s, key, "a number >= 0")


_SECTIONS: dict[str, type[Any]] = {
    "daemon": DaemonSection,
    "mavlink": MavlinkSection,
    "autopilot": AutopilotSection,
    "dronecan": DronecanSection,
    "zenoh": ZenohSection,
    "ros2": Ros2Section,
    "foxglove": FoxgloveSection,
    "bias_store": BiasStoreSection,
}
# sections that configure `navd run` only (inputs, outputs, the service): a replay reads its
# samples, with their own time stamps, from files and validates but does not use these
RUN_ONLY_SECTIONS = frozenset(_SECTIONS)
# sections of the estimator's NavConfig (estimator sections, [polarization], [dov])
_NAV_SECTIONS = frozenset({f.name for f in fields(EstimatorConfig)} | {"polarization", "dov"})


@dataclass(frozen=True)
class DaemonConfig:
    """Everything ``navd run`` needs, validated.  ``nav`` is what the estimator is built from;
    ``tables`` is the raw TOML it came from (written into recordings, so a replay rebuilds
    the same ``nav``)."""

    daemon: DaemonSection = field(default_factory=DaemonSection)
    mavlink: MavlinkSection = field(default_factory=MavlinkSection)
    autopilot: AutopilotSection = field(default_factory=AutopilotSection)
    dronecan: DronecanSection = field(default_factory=DronecanSection)
    zenoh: ZenohSection = field(default_factory=ZenohSection)
    ros2: Ros2Section = field(default_factory=Ros2Section)
    foxglove: FoxgloveSection = field(default_factory=FoxgloveSection)
    bias_store: BiasStoreSection = field(default_factory=BiasStoreSection)
    nav: NavConfig = field(default_factory=NavConfig)
    tables: dict[str, Any] = field(default_factory=dict)

    @property
    def estimator(self) -> EstimatorConfig:
        return self.nav.estimator

    @property
    def polarization(self) -> PolarizationSection | None:
        return self.nav.polarization

    @property
    def dov(self) -> DovSection:
        return self.nav.dov

    @classmethod
    def from_dict(cls, data: dict[str, Any], *, need_input: bool = True) -> DaemonConfig:
        """Validate every section and key of ``data``.  ``need_input=False`` (a replay, which
        reads files) accepts a configuration without an enabled input."""
        known = set(_SECTIONS) | _NAV_SECTIONS
        unknown = sorted(set(data) - known)
        if unknown:
            raise ConfigError(f"unknown config section(s) {unknown}; expected some of "
                              f"{sorted(known)}")
        kw: dict[str, Any] = {name: build_section(sec, name, data.get(name, {}))
                              for name, sec in _SECTIONS.items()}
        if kw["autopilot"].any and not (kw["mavlink"].enabled and kw["mavlink"].send):
            raise ConfigError("[autopilot] needs a MAVLink output: [mavlink] enabled with a "
                              'send link (to the autopilot, often send = "same")')
        has_input = (kw["mavlink"].enabled and kw["mavlink"].listen) or kw["dronecan"].enabled
        if need_input and not has_input:
            raise ConfigError("no input: enable [mavlink] (with listen) or [dronecan]")
        if kw["ros2"].enabled and not kw["zenoh"].enabled:
            raise ConfigError("[ros2] enabled publishes over the [zenoh] session: enable "
                              "[zenoh] too")
        return cls(**kw, nav=NavConfig.from_tables(data), tables=data)


def load_daemon_config(path: str | Path | None, overrides: list[str] | None = None
                       ) -> DaemonConfig:
    return DaemonConfig.from_dict(load_config(path, overrides))

