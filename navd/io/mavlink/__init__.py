"""MAVLink 2 adapter: wire bytes <-> navd.types, plus asyncio links (UDP, TCP, serial).

One module per job, so a reader (or a log replay) takes only what it needs:

frame    FrameScanner: MAVLink 1/2 frames out of bytes in linear time, CRC checked
wire     payload layouts of the input messages (unpacked without pymavlink objects)
signing  MAVLink 2 signature check and key file loading
decode   MavlinkInputConfig, the accepted message tables, MavlinkDecoder (bytes -> samples)
encode   MavlinkEncoder (NavSolution -> ATTITUDE, ATTITUDE_QUATERNION, HEARTBEAT, ...)
link     parse_mavlink_url, UDP/TCP/serial (pyserial) transports with reconnection, MavlinkLink,
         MavlinkSender (encoder output onto a link)

The names below are the adapter's public surface; ``from navd.io.mavlink import X`` keeps
working as it did when the adapter was one file.  navd's private polarization message is
:mod:`navd.io.pol_wire` (dialect ``navd/io/navd_polarization.xml``).
"""

from navd.io.mavlink.decode import GNSS_MESSAGES, IMU_MESSAGES, MavlinkDecoder, MavlinkInputConfig
from navd.io.mavlink.encode import MavlinkEncoder
from navd.io.mavlink.link import (
    LinkAddress,
    MavlinkLink,
    MavlinkSender,
    MavlinkStreamProtocol,
    MavlinkUdpProtocol,
    open_mavlink,
    parse_mavlink_url,
)

__all__ = [
    "GNSS_MESSAGES",
    "IMU_MESSAGES",
    "LinkAddress",
    "MavlinkDecoder",
    "MavlinkEncoder",
    "MavlinkInputConfig",
    "MavlinkLink",
    "MavlinkSender",
    "MavlinkStreamProtocol",
    "MavlinkUdpProtocol",
    "open_mavlink",
    "parse_mavlink_url",
]
