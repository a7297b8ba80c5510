"""The daemon's outputs.  A sink reads NavSolutions (never estimator state) on its own
:class:`~navd.pipeline.OutputSchedule`, and keeps receive -> send latency statistics.

MavlinkSink    ATTITUDE + ATTITUDE_QUATERNION (+ GLOBAL_POSITION_INT), HEARTBEAT task
AutopilotSink  GPS_INPUT (+ yaw), ESTIMATOR_STATUS, MAV_CMD_EXTERNAL_ATTITUDE_ESTIMATE
FoxgloveSink   Foxglove channels into an MCAP file (``--mcap``) or a live WebSocket server
ZenohSink      navd/<vehicle>/attitude per output, navd/<vehicle>/status from the daemon
Ros2Sink       ROS 2 Imu, NavSatFix, Odometry and heading diagnostics on the Zenoh session
DronecanSink   uavcan.equipment.ahrs.Solution on the input bus
CallbackSink   hands solutions to a function (tests, embedding)
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any, Protocol

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from navd.diag import Counters, RateLimitedLog
from navd.io.mavlink import MavlinkEncoder, MavlinkLink, MavlinkSender
from navd.io.mavlink.autopilot import (
    AutopilotPolicy,
    HeadingResetSchedule,
    estimator_flags,
    gps_input_frame,
)
from navd.io.zenoh import ZenohPublisher
from navd.pipeline import OutputSchedule
from navd.types import NavSolution

if TYPE_CHECKING:
    from navd.config.daemon import Ros2Section
    from navd.io.dronecan import DronecanEncoder, DronecanLink

__all__ = [
    "AutopilotSink",
    "CallbackSink",
    "DronecanSink",
    "FoxgloveSink",
    "LatencyStats",
    "MavlinkSink",
    "Ros2Sink",
    "Sink",
    "ZenohSink",
]

_log = logging.getLogger(__name__)


class LatencyStats:
    """Receive -> send latency of the last ``window`` outputs (ns in, µs out), plus all-time
    count and maximum.  A ring buffer: constant memory however long the daemon runs."""

    __slots__ = ("_buf", "_i", "count", "max_ns")

    def __init__(self, window: int = 4096) -> None:
        self._buf: list[int] = [0] * window
        self._i = 0
        self.count = 0
        self.max_ns = 0

    def add(self, ns: int) -> None:
        self._buf[self._i] = ns
        self._i = (self._i + 1) % len(self._buf)
        self.count += 1
        if ns > self.max_ns:
            self.max_ns = ns

    def recent_us(self) -> list[float]:
        """The window, sorted, in µs (the buffer fills from index 0 before it wraps)."""
        n = min(self.count, len(self._buf))
        return sorted(v * 1e-3 for v in self._buf[:n])

    def summary(self) -> dict[str, float | int]:
        v = self.recent_us()
        if not v:
            return {"n": 0}

        def pct(p: float) -> float:
            return round(v[min(len(v) - 1, int(p * len(v)))], 1)

        return {"n": self.count, "window": len(v), "p50_us": pct(0.50), "p90_us": pct(0.90),
                "p99_us": pct(0.99), "max_window_us": round(v[-1], 1),
                "max_us": round(self.max_ns * 1e-3, 1)}


class Sink:
    """Base: a name, an output schedule, latency stats, publish/close."""

    name = "sink"

    def __init__(self, rate_hz: float) -> None:
        self.schedule = OutputSchedule(rate_hz)
        self.latency = LatencyStats()
        self.published = 0

    def publish(self, sol: NavSolution) -> None:
        raise NotImplementedError

    def counters(self) -> dict[str, int]:
        return {"published": self.published}

    def close(self) -> None:
        pass


class MavlinkSink(Sink):
    """ATTITUDE and friends on a MAVLink link; HEARTBEAT from :meth:`run_heartbeat`."""

    name = "mavlink"

    def __init__(self, link: MavlinkLink, encoder: MavlinkEncoder, rate_hz: float, *,
                 quaternion: bool, global_position: bool, own_link: bool) -> None:
        super().__init__(rate_hz)
        self.link = link
        self.sender = MavlinkSender(link, encoder, send_quaternion=quaternion,
                                    send_global_position=global_position)
        self._own_link = own_link

    def publish(self, sol: NavSolution) -> None:
        self.sender.send_solution(sol)
        self.published += 1

    async def run_heartbeat(self, period_s: float, system_status: Callable[[], int]) -> None:
        await self.sender.run_heartbeat(period_s, system_status)

    def counters(self) -> dict[str, int]:
        c = self.link.counters.snapshot() if self._own_link else {}
        # a shared link's counters are the decoder's, already reported under inputs
        return {**{k: v for k, v in c.items() if k.startswith(("tx_", "link_"))},
                "published": self.published}

    def close(self) -> None:
        if self._own_link:
            self.link.close()


class AutopilotSink(Sink):
    """navd as an autopilot's GPS and heading source (docs/autopilot.md), on the MAVLink
    output link and with the MAVLink sink's encoder (one source, one sequence counter)."""

    name = "autopilot"

    def __init__(self, link: MavlinkLink, encoder: MavlinkEncoder, rate_hz: float,
                 policy: AutopilotPolicy, *, gps_input: bool, estimator_status: bool,
                 heading_reset: HeadingResetSchedule | None, target: tuple[int, int] = (1, 1),
                 clock: Callable[[], float] = time.monotonic) -> None:
        super().__init__(rate_hz)
        self.link = link
        self.encoder = encoder
        self.policy = policy
        self.gps_input = gps_input
        self.estimator_status = estimator_status
        self.heading_reset = heading_reset
        self.target = target
        self._clock = clock
        self.sent = {"gps_input": 0, "estimator_status": 0, "heading_reset": 0,
                     "gps_input_yaw": 0, "nonfinite": 0}

    def publish(self, sol: NavSolution) -> None:
        enc, pol = self.encoder, self.policy
        if self.gps_input:
            try:
                frame = gps_input_frame(enc, sol, pol)
            except ValueError:  # no finite position: nothing a GPS could say
                self.sent["nonfinite"] += 1
            else:
                self.link.send(frame)
                self.sent["gps_input"] += 1
                self.sent["gps_input_yaw"] += sol.heading_good(pol.aligned_sd)
        if self.estimator_status:
            sd_n, sd_e, sd_d = sol.pos_sd_m
            self.link.send(enc.encode_estimator_status(
                max(sol.t_us, 0), estimator_flags(sol, pol), math.hypot(sd_n, sd_e), sd_d))
            self.sent["estimator_status"] += 1
        hr = self.heading_reset
        if hr is not None and hr.due(sol.heading_good(pol.aligned_sd), sol.heading_resets,
                                     self._clock()):
            self.link.send(enc.encode_external_attitude_estimate(
                *self.target, math.degrees(sol.yaw_rad) % 360.0,
                math.degrees(sol.att_sd_rad[2])))
            self.sent["heading_reset"] += 1
        self.published += 1

    def counters(self) -> dict[str, int]:
        deferred = self.heading_reset.deferred if self.heading_reset is not None else 0
        return {**self.sent, "heading_reset_deferred": deferred, "published": self.published}


MAV_STATE_STANDBY: int = mavlink.MAV_STATE_STANDBY
MAV_STATE_ACTIVE: int = mavlink.MAV_STATE_ACTIVE
MAV_STATE_CRITICAL: int = mavlink.MAV_STATE_CRITICAL
MAV_STATE_EMERGENCY: int = mavlink.MAV_STATE_EMERGENCY
MAV_STATE_POWEROFF: int = mavlink.MAV_STATE_POWEROFF


class ZenohSink(Sink):
    name = "zenoh"

    def __init__(self, publisher: ZenohPublisher, rate_hz: float,
                 aligned_sd_rad: float = math.inf) -> None:
        super().__init__(rate_hz)
        self.publisher = publisher
        self.aligned_sd_rad = aligned_sd_rad  # yaw sigma bound for "aligned": true

    def publish(self, sol: NavSolution) -> None:
        self.publisher.publish_attitude(sol, self.aligned_sd_rad)
        self.published += 1

    def publish_status(self, status: Mapping[str, Any]) -> None:
        self.publisher.publish_status(status)

    def counters(self) -> dict[str, int]:
        return {**self.publisher.counters.snapshot(), "published": self.published}

    def close(self) -> None:
        self.publisher.close()


# ROS 2 topics, relative to [ros2] namespace except the absolute /diagnostics (where
# diagnostic aggregators listen): (name, type)
ROS2_TOPICS: dict[str, tuple[str, str]] = {
    "imu": ("imu", "sensor_msgs/msg/Imu"),
    "fix": ("fix", "sensor_msgs/msg/NavSatFix"),
    "odom": ("odom", "nav_msgs/msg/Odometry"),
    "diagnostics": ("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray"),
}


class Ros2Sink(Sink):
    """Imu, NavSatFix and Odometry per output and the heading DiagnosticArray every
    ``diagnostics_period`` of sensor time, published as node ``[ros2] node_name`` on an open
    Zenoh session (the [zenoh] sink's).  Header stamps and attachment timestamps are the
    host clock at publish (ROS time), the solution's sensor time is in the diagnostics."""

    name = "ros2"

    def __init__(self, session: Any, cfg: Ros2Section,
                 aligned_sd_rad: float = math.inf) -> None:
        # imported here: a daemon without [ros2] never loads the serialiser
        from navd.io.ros2.messages import MessageBuilder
        from navd.io.ros2.rmw import Ros2Node

        super().__init__(cfg.rate)
        self.cfg = cfg
        self.aligned_sd_rad = aligned_sd_rad
        self.stats = Counters()
        self._rlog = RateLimitedLog(_log, 5.0)
        self.builder = MessageBuilder(cfg.frame_id, cfg.world_frame_id)
        self.node = Ros2Node(session, domain_id=cfg.domain_id, namespace=cfg.namespace,
                             node=cfg.node_name)
        try:
            self.pubs = {k: self.node.publisher(topic, typ)
                         for k, (topic, typ) in ROS2_TOPICS.items()}
        except BaseException:
            self.node.close()
            raise
        self._diag_period_us = max(1, round(cfg.diagnostics_period * 1e6))
        self._diag_due_us: int | None = None

    def _send(self, kind: str, msg: Any) -> None:
        import zenoh

        try:
            self.pubs[kind].put(self.builder.serialize(msg))
        except zenoh.ZError as exc:
            self.stats.inc(f"{kind}_put_error")
            self._rlog.warn(f"ros2_{kind}", "ros2: put %s failed: %s", kind, exc)
            return
        self.stats.inc(f"{kind}_sent")

    def publish(self, sol: NavSolution) -> None:
        stamp = time.time_ns()
        b = self.builder
        self._send("imu", b.imu(sol, stamp))
        self._send("fix", b.navsatfix(sol, stamp))
        self._send("odom", b.odometry(sol, stamp))
        if self._diag_due_us is None or sol.t_us >= self._diag_due_us:
            self._diag_due_us = sol.t_us + self._diag_period_us
            self._send("diagnostics", b.diagnostics(sol, stamp, self.aligned_sd_rad,
                                                    self.cfg.node_name))
        self.published += 1

    def counters(self) -> dict[str, int]:
        return {**self.stats.snapshot(), "published": self.published}

    def close(self) -> None:
        self.node.close()


class FoxgloveWriter(Protocol):
    """NavMcapWriter (file) or FoxgloveLive (WebSocket server)."""

    messages: int

    def write_solution(self, sol: NavSolution, log_time_ns: int) -> None: ...

    def write_status(self, status: Mapping[str, Any], log_time_ns: int) -> None: ...

    def close(self) -> None: ...


class FoxgloveSink(Sink):
    """Solutions (and the daemon's status) as Foxglove channels, into an MCAP file
    (``name`` "mcap") or a live WebSocket server ("foxglove"); the log time is the host's
    wall clock, each message's timestamp the sensor time."""

    def __init__(self, writer: FoxgloveWriter, rate_hz: float, name: str,
                 clock_ns: Callable[[], int] = time.time_ns) -> None:
        super().__init__(rate_hz)
        self.writer = writer
        self.name = name
        self._clock_ns = clock_ns

    def publish(self, sol: NavSolution) -> None:
        self.writer.write_solution(sol, self._clock_ns())
        self.published += 1

    def publish_status(self, status: Mapping[str, Any]) -> None:
        self.writer.write_status(status, self._clock_ns())

    def counters(self) -> dict[str, int]:
        return {"published": self.published, "messages": self.writer.messages}

    def close(self) -> None:
        self.writer.close()


class DronecanSink(Sink):
    """Solution frames on the (shared) input bus; the bus belongs to the sources."""

    name = "dronecan"

    def __init__(self, link: DronecanLink, encoder: DronecanEncoder, rate_hz: float) -> None:
        super().__init__(rate_hz)
        self.link = link
        self.encoder = encoder
        self.failed = 0

    def publish(self, sol: NavSolution) -> None:
        if self.link.send(self.encoder.encode_solution(sol)):
            self.published += 1
        else:
            self.failed += 1

    def counters(self) -> dict[str, int]:
        return {"published": self.published, "tx_failed": self.failed}


class CallbackSink(Sink):
    name = "callback"

    def __init__(self, fn: Callable[[NavSolution], None], rate_hz: float,
                 name: str = "callback") -> None:
        super().__init__(rate_hz)
        self.fn = fn
        self.name = name

    def publish(self, sol: NavSolution) -> None:
        self.fn(sol)
        self.published += 1
