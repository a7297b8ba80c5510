"""Input decoding cost per IMU sample: MAVLink HIGHRES_IMU datagrams and DroneCAN RawIMU
transfers (7 CAN frames each), wire bytes -> ImuSample, on this machine, one core; and the
cost of MAVLink junk per byte (issue 19: floods of bytes made to look like frame starts).

    python benchmarks/decode.py [--n 20000] [--repeat 5] [--json PATH]

Prints microseconds per sample (best of ``--repeat`` runs: the least disturbed by other load)
and the share of one core that decoding takes at 1 kHz; then nanoseconds per junk byte.
"""

from __future__ import annotations

import argparse
import json
import random
import time
from pathlib import Path

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


JUNK = {
    "0xFE repeated (every byte a MAVLink 1 start)": b"\xfe" * 16384,
    "0xFD repeated": b"\xfd" * 16384,
    "FE 00 repeated (a MAVLink 1 header every 2 bytes)": b"\xfe\x00" * 8192,
    "FE 01 FD repeated (the worst pattern found)": b"\xfe\x01\xfd" * 5462,
    "random bytes": random.Random(1).randbytes(16384),
}


def bench_junk(data: bytes, repeat: int) -> float:
    """Seconds per byte to parse ``data`` as one datagram (best of ``repeat``)."""
    best = float("inf")
    for _ in range(repeat):
        dec = MavlinkDecoder(MavlinkInputConfig(max_datagram_bytes=len(data)))
        t0 = time.process_time()
        dec.feed_datagram(data, 0)
        best = min(best, time.process_time() - t0)
    return best / len(data)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=20_000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--json", help="write the figures to this file")
    a = ap.parse_args(argv)
    rows = [("MAVLink HIGHRES_IMU (1 datagram)", min(bench_mavlink(a.n) for _ in range(a.repeat))),
            ("DroneCAN RawIMU (7 CAN frames)", min(bench_dronecan(a.n) for _ in range(a.repeat)))]
    print(f"{'input':36s} {'us/sample':>10s} {'core share at 1 kHz':>20s}")
    for name, s in rows:
        print(f"{name:36s} {s * 1e6:10.1f} {s * 1000 * 100:19.1f}%")
    junk = [(name, bench_junk(data, a.repeat)) for name, data in JUNK.items()]
    print(f"\n{'MAVLink junk, 16 kB datagram':46s} {'ns/byte':>8s} {'ms/datagram':>12s}")
    for name, s in junk:
        print(f"{name:46s} {s * 1e9:8.0f} {s * len(JUNK[name]) * 1e3:12.2f}")
    if a.json:
        Path(a.json).write_text(json.dumps(
            {"us_per_sample": {k: round(v * 1e6, 2) for k, v in rows},
             "junk_ns_per_byte": {k: round(v * 1e9, 1) for k, v in junk}}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
