"""Input decoding cost per IMU sample: MAVLink HIGHRES_IMU datagrams and DroneCAN RawIMU
transfers (7 CAN frames each), wire bytes -> ImuSample, on this machine, one core.

    python benchmarks/decode.py [--n 20000]

Prints microseconds per sample and the share of one core that decoding takes at 1 kHz.
"""

from __future__ import annotations

import argparse
import time

from firmware_sim.transport.dronecan_tx import DronecanTx
from firmware_sim.transport.mavlink_tx import MavlinkTx
from navd.io.dronecan import DronecanConfig, DronecanDecoder
from navd.io.mavlink import MavlinkDecoder, MavlinkInputConfig
from navd.types import ImuSample


def _imu(k: int) -> ImuSample:
    dt_us = 1000
    dt = dt_us * 1e-6
    return ImuSample(1_000_000 + k * dt_us, dt_us, 0.01 * dt, -0.02 * dt, 0.03 * dt,
                     0.1 * dt, -0.2 * dt, -9.8 * dt)


def bench_mavlink(n: int) -> float:
    tx = MavlinkTx()
    datagrams = [tx.highres_imu(_imu(k)) for k in range(n)]
    dec = MavlinkDecoder(MavlinkInputConfig(nominal_imu_rate_hz=1000.0))
    t0 = time.perf_counter()
    out = 0
    for d in datagrams:
        out += len(dec.feed_datagram(d, 0))
    dt = time.perf_counter() - t0
    assert out == n, (out, n)
    return dt / n


def bench_dronecan(n: int) -> float:
    tx = DronecanTx(node_id=21)
    transfers = [tx.raw_imu(_imu(k)) for k in range(n)]
    dec = DronecanDecoder(DronecanConfig(interface="virtual", nominal_imu_rate_hz=1000.0))
    t0 = time.perf_counter()
    out = 0
    for frames in transfers:
        for f in frames:
            out += len(dec.feed(f, 0))
    dt = time.perf_counter() - t0
    assert out == n, (out, n, dec.counters)
    return dt / n


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=20_000)
    a = ap.parse_args(argv)
    rows = [("MAVLink HIGHRES_IMU (1 datagram)", bench_mavlink(a.n)),
            ("DroneCAN RawIMU (7 CAN frames)", bench_dronecan(a.n))]
    print(f"{'input':36s} {'us/sample':>10s} {'core share at 1 kHz':>20s}")
    for name, s in rows:
        print(f"{name:36s} {s * 1e6:10.1f} {s * 1000 * 100:19.1f}%")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
