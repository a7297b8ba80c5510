"""The I/O adapters' settings objects, made from the daemon's config sections.

Config (:mod:`navd.config.daemon`) does not depend on the adapters; the daemon layer, which
uses both, translates: SI section attributes in, each adapter's own settings dataclass out.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from navd.config import ConfigError
from navd.config.daemon import DronecanSection, MavlinkSection, ZenohSection
from navd.core.plausible import Limits
from navd.io.mavlink import MavlinkInputConfig
from navd.io.mavlink.signing import load_signing_key
from navd.io.zenoh import ZenohConfig
from navd.io.zenoh_security import read_password, read_usernames

if TYPE_CHECKING:
    from navd.io.dronecan import DronecanConfig

__all__ = ["dronecan_bus_config", "mavlink_input_config", "zenoh_session_config"]


def mavlink_input_config(m: MavlinkSection, limits: Limits | None = None, *,
                         warn_interval_s: float = 5.0) -> MavlinkInputConfig:
    """``limits``: the estimator's ``[imu]`` plausibility limits, so a sample the adapter
    passes is one the estimator accepts (default: the built-in limits).
    ``warn_interval_s``: ``[daemon] warn_interval_s``.  Reads ``signing_key_file``;
    raises OSError / ValueError when it cannot be read or is not a key."""
    return MavlinkInputConfig(
        limits=limits or Limits(),
        imu_messages=frozenset(m.imu_messages),
        gnss_messages=frozenset(m.gnss_messages),
        imu_id=None if m.imu_id < 0 else m.imu_id,
        gnss_id=None if m.gnss_id < 0 else m.gnss_id,
        allow=frozenset(m.allow) if m.allow else None,
        nominal_imu_rate_hz=m.nominal_imu_rate or None,
        max_imu_gap_s=m.max_imu_gap,
        raw_gyro_rps_per_lsb=m.raw_gyro or None,
        raw_accel_mps2_per_lsb=m.raw_accel or None,
        geoid_sep_m=m.geoid_sep,
        uere_m=m.uere,
        use_receive_time=m.use_receive_time,
        polarization=m.polarization,
        max_datagram_bytes=m.max_datagram,
        signing_key=load_signing_key(m.signing_key_file) if m.signing_key_file else None,
        accept_unsigned=m.accept_unsigned,
        warn_interval_s=warn_interval_s,
        relock_s=m.relock if m.source_lock else None,
    )


def dronecan_bus_config(d: DronecanSection, limits: Limits | None = None, *,
                        warn_interval_s: float = 5.0) -> DronecanConfig:
    """``limits``, ``warn_interval_s``: as for :func:`mavlink_input_config`."""
    # imported here: the dronecan package parses its DSDL when imported (~0.1 s of every
    # start, 0.4 s on a Pi), which only a daemon with DroneCAN configured needs (issue 18)
    from navd.io.dronecan import DronecanConfig

    return DronecanConfig(
        limits=limits or Limits(),
        interface=d.interface,
        channel=d.channel,
        node_id=d.node_id,
        allow_nodes=frozenset(d.allow_nodes) if d.allow_nodes else None,
        transfer_timeout_s=d.transfer_timeout,
        nominal_imu_rate_hz=d.nominal_imu_rate or None,
        max_imu_gap_s=d.max_imu_gap,
        use_receive_time=d.use_receive_time,
        warn_interval_s=warn_interval_s,
        relock_s=d.relock if d.source_lock else None,
    )


def zenoh_session_config(z: ZenohSection) -> ZenohConfig:
    """Raises ConfigError when the password or users file cannot be read."""
    password = ""
    try:
        if z.user:
            password = read_password(z.password_file)
        if z.users_file:
            read_usernames(z.users_file)  # unreadable or empty: say so before zenoh does
    except (OSError, ValueError) as exc:
        raise ConfigError(f"[zenoh] password_file/users_file: {exc}") from None
    return ZenohConfig(vehicle=z.vehicle, listen=z.listen, connect=z.connect,
                       multicast_scouting=z.multicast_scouting,
                       acl="publisher" if z.access_control else "off", user=z.user,
                       password=password, users_file=z.users_file)
