"""Play a simulated run onto the wire in (scaled) real time, as the sensors would send it.

Each IMU sample goes out at its sensor time stamp, each GNSS fix at its arrival time
(``t_arrival_us`` = time of validity + receiver latency) carrying its time of validity, so a
receiver sees the same ordering and latency the scenario describes.  Wall-clock pacing:
``rate_factor`` K plays K sensor seconds per wall second (1 = real time, 0 = as fast as
possible).  Deadlines are absolute (start + t / K), so sleep overshoot never accumulates.

    firmware-sim stream --scenario car480 --transport mavlink --rate-factor 1 \\
        --target udp:127.0.0.1:14560
    firmware-sim stream --scenario car480 --transport dronecan --interface socketcan \\
        --channel vcan0
"""

from __future__ import annotations

import asyncio
import socket
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import can
import numpy as np

from firmware_sim.csvio import write_table
from firmware_sim.polarization import PolMavlinkEncoder
from firmware_sim.run import SimRun
from firmware_sim.transport.dronecan_tx import DronecanTx
from firmware_sim.transport.mavlink_tx import MavlinkTx
from navd.types import GnssSample, ImuSample, PolSample

__all__ = [
    "GNSS_MESSAGES",
    "IMU_MESSAGES",
    "StreamStats",
    "dronecan_events",
    "mavlink_events",
    "parse_udp_target",
    "stream_dronecan",
    "stream_dronecan_async",
    "stream_mavlink_udp",
    "timed_samples",
    "write_truth_attitude",
]

IMU_MESSAGES = ("HIGHRES_IMU", "SCALED_IMU")
GNSS_MESSAGES = ("GPS_INPUT", "GPS_RAW_INT", "HIL_GPS")
TRUTH_ATTITUDE_COLUMNS = ("t_us", "lat_deg", "lon_deg", "alt_m", "roll_deg", "pitch_deg",
                          "yaw_deg")


@dataclass
class StreamStats:
    imu: int = 0
    gnss: int = 0
    packets: int = 0
    wall_s: float = 0.0
    max_late_s: float = 0.0  # how far behind its deadline the worst send was


def _send_frames(bus: Any, frames: list[can.Message], is_imu: bool, st: StreamStats) -> None:
    """One sample's CAN frames onto the bus, counted."""
    for f in frames:
        bus.send(f)
    st.packets += len(frames)
    st.imu += is_imu
    st.gnss += not is_imu


def timed_samples(run: SimRun) -> Iterator[tuple[int, ImuSample | GnssSample | PolSample]]:
    """(send time µs on the sensor clock, sample), non-decreasing in send time.

    GNSS fixes go out at their arrival time, IMU samples and polarization readings at their
    own time stamp.
    """
    arrival = dict(zip(run.gnss["t_us"].tolist(), run.gnss["t_arrival_us"].tolist(),
                       strict=True))
    for s in run.samples():
        yield (arrival[s.t_us] if isinstance(s, GnssSample) else s.t_us), s


def mavlink_events(run: SimRun, imu_message: str = "HIGHRES_IMU",
                   gnss_message: str = "GPS_INPUT", sysid: int = 1, compid: int = 1
                   ) -> Iterator[tuple[int, bytes, bool]]:
    """(send time µs, one MAVLink frame, is_imu); polarization readings (scenarios with a
    ``[polarization]`` sensor) as NAVD_SKY_POLARIZATION."""
    if imu_message not in IMU_MESSAGES or gnss_message not in GNSS_MESSAGES:
        raise ValueError(f"unsupported message {imu_message}/{gnss_message}")
    tx = MavlinkTx(sysid, compid)
    enc_imu: Callable[[ImuSample], bytes] = (tx.highres_imu if imu_message == "HIGHRES_IMU"
                                             else tx.scaled_imu)
    gnss_encoders: dict[str, Callable[[GnssSample], bytes]] = {
        "GPS_INPUT": tx.gps_input, "GPS_RAW_INT": tx.gps_raw_int, "HIL_GPS": tx.hil_gps}
    enc_gnss = gnss_encoders[gnss_message]
    pol = PolMavlinkEncoder(sysid)  # navd's private NAVD_SKY_POLARIZATION, compid 158
    for t, s in timed_samples(run):
        if isinstance(s, ImuSample):
            yield t, enc_imu(s), True
        elif isinstance(s, GnssSample):
            yield t, enc_gnss(s), False
        else:
            yield t, pol.encode(s), False


def dronecan_events(run: SimRun, node_id: int = 42, gnss_ecef: bool = True
                    ) -> Iterator[tuple[int, list[can.Message], bool]]:
    """(send time µs, the frames of one transfer, is_imu).  Polarization readings go out as
    navd's private SkyPolarization message."""
    tx = DronecanTx(node_id)
    for t, s in timed_samples(run):
        if isinstance(s, ImuSample):
            yield t, tx.raw_imu(s), True
        elif isinstance(s, GnssSample):
            yield t, tx.fix2(s, with_ecef=gnss_ecef), False
        elif isinstance(s, PolSample):
            yield t, tx.polarization(s), False


class _Pacer:
    """Absolute deadlines: event at sensor time t is due at wall0 + (t - t0) / K."""

    def __init__(self, rate_factor: float) -> None:
        if rate_factor < 0.0:
            raise ValueError(f"rate factor must be >= 0, got {rate_factor}")
        self.k = rate_factor
        self.t0_us: int | None = None
        self.wall0 = 0.0

    def wait_s(self, t_us: int) -> float:
        """Seconds until the event is due (<= 0: due now)."""
        if self.k == 0.0:
            return 0.0
        now = time.monotonic()
        if self.t0_us is None:
            self.t0_us, self.wall0 = t_us, now
        return self.wall0 + (t_us - self.t0_us) * 1e-6 / self.k - now


def parse_udp_target(target: str) -> tuple[str, int]:
    """``udp:HOST:PORT`` / ``udpout:HOST:PORT`` / ``HOST:PORT`` -> (host, port)."""
    rest = target.split(":", 1)[1] if target.startswith(("udp:", "udpout:")) else target
    host, sep, port = rest.rpartition(":")
    if not sep or not host or not port.isdigit():
        raise ValueError(f"bad UDP target {target!r}: want udp:HOST:PORT")
    return host, int(port)


def stream_mavlink_udp(events: Iterator[tuple[int, bytes, bool]], target: str,
                       rate_factor: float, stop: Callable[[], bool] = lambda: False
                       ) -> StreamStats:
    """Send each frame as one datagram to ``target`` (unconnected socket: a receiver that is
    not up yet costs datagrams, not an error)."""
    addr = parse_udp_target(target)
    pacer = _Pacer(rate_factor)
    st = StreamStats()
    t_start = time.monotonic()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        for t_us, frame, is_imu in events:
            wait = pacer.wait_s(t_us)
            if wait > 0.0:
                time.sleep(wait)
            else:
                st.max_late_s = max(st.max_late_s, -wait)
            sock.sendto(frame, addr)
            st.packets += 1
            st.imu += is_imu
            st.gnss += not is_imu
            if stop():
                break
    st.wall_s = time.monotonic() - t_start
    return st


def stream_dronecan(events: Iterator[tuple[int, list[can.Message], bool]], bus: Any,
                    rate_factor: float) -> StreamStats:
    pacer = _Pacer(rate_factor)
    st = StreamStats()
    t_start = time.monotonic()
    for t_us, frames, is_imu in events:
        wait = pacer.wait_s(t_us)
        if wait > 0.0:
            time.sleep(wait)
        else:
            st.max_late_s = max(st.max_late_s, -wait)
        _send_frames(bus, frames, is_imu, st)
    st.wall_s = time.monotonic() - t_start
    return st


async def stream_dronecan_async(events: Iterator[tuple[int, list[can.Message], bool]],
                                bus: Any, rate_factor: float) -> StreamStats:
    """As :func:`stream_dronecan`, sleeping on the event loop (for in-process tests with a
    python-can ``virtual`` bus, which only connects buses of one process)."""
    pacer = _Pacer(rate_factor)
    st = StreamStats()
    t_start = time.monotonic()
    for n, (t_us, frames, is_imu) in enumerate(events, start=1):
        wait = pacer.wait_s(t_us)
        if wait > 0.0:
            await asyncio.sleep(wait)
        else:
            st.max_late_s = max(st.max_late_s, -wait)
            if n % 32 == 0:
                await asyncio.sleep(0)  # behind schedule: still let the receiver run
        _send_frames(bus, frames, is_imu, st)
    st.wall_s = time.monotonic() - t_start
    return st


def write_truth_attitude(run: SimRun, path: str | Path) -> None:
    """Truth position and attitude at every IMU boundary (columns TRUTH_ATTITUDE_COLUMNS,
    degrees), written atomically so a reader that sees the file sees all of it."""
    p = Path(path)
    tmp = p.with_name(f".{p.name}.tmp")
    eul = np.degrees(run.truth_euler)
    write_table(tmp, TRUTH_ATTITUDE_COLUMNS,
                [run.truth_t_us, np.degrees(run.truth_pos[:, 0]),
                 np.degrees(run.truth_pos[:, 1]), run.truth_pos[:, 2],
                 eul[:, 0], eul[:, 1], eul[:, 2]])
    tmp.replace(p)
