"""Hostile input against a live daemon (issue 19): storms over loopback UDP into ``navd run``.

    python benchmarks/hostile.py [--storm-s 10] [--imu-rate 1000] [--only NAME,...]
                                 [--json PATH] [--set KEY=VALUE]

A real drive (car480 resampled to ``--imu-rate``, HIGHRES_IMU + GPS_INPUT from sysid 1) plays
in real time from start to end.  After navigation has started, the storms follow one after
another, each for ``--storm-s`` seconds with a quiet interval between, each bounded in count:

  baseline    nothing extra: the reference for CPU and attitude error
  oversize    65,507-byte datagrams of 0xFE (the worst case found before the fix), 10 Mbit/s
  garbage     280-byte datagrams at 10 Mbit/s from one address: random bytes, FE/FD-dense
              junk ("FE 01 FD" repeated, the scanner's worst pattern) and real frames with
              their CRC broken
  garbage_ports  280-byte "FE 01 FD" datagrams at 10 Mbit/s from 127.0.0.1 (the real
              sender's host), on a new source port every 10 datagrams (2.8 kB: no one
              address goes over its junk budget)
  garbage_hosts  the same from a new source host (127.0.x.y) every 10 datagrams
  foreign     sysid 7 sends plausible false data on the real clock, 5 ms after each real
              sample: IMU of another stretch of road and the real fixes with the velocity
              reversed (the probe that drove yaw to 178 deg)
  timestamps  sysid 1 itself sends, after each real frame, a copy with a wild time stamp:
              0, >= 2**63, seconds back, a duplicate, hours ahead (IMU and GNSS)
  dronecan    malformed DroneCAN frames: there is no CAN interface shared between processes
              here (no vcan0), so this one runs the daemon's DroneCAN decoder in this process
              on 100,000 random frames (ids of the used data types, random payloads and tail
              bytes) and reports its cost per frame

Per storm: CPU of the navd process (% of one core, utime + stime) and its excess over the
baseline, output rate (ATTITUDE received per second), longest gap between ATTITUDE receipts
(with the longest lateness of the real sender in the same window: a gap this machine's load
put into the input is not navd's),
estimator resets, attitude error against simulator truth at the output's sensor time (max
|roll|, |pitch|, RMS and max |yaw|), RSS after the storm, and the storm's own counters.

Targets: floods (oversize, garbage*) <= 20 % of a core, no gap > 100 ms, no reset; foreign
changes nothing (errors as the baseline's, 0 resets); timestamp storm <= 1 reset.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import platform
import random
import socket
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

sys.path.insert(0, str(Path(__file__).resolve().parent))  # benchmarks/ is not a package
from daemon import StatusSubscriber, cpu_s, start_navd
from soak import rss_kb

from firmware_sim import SimRun, generate, load_scenario
from firmware_sim.stream import mavlink_events, timed_samples
from firmware_sim.transport.mavlink_tx import MavlinkTx
from navd.types import GnssSample, ImuSample

STORMS = ("baseline", "oversize", "garbage", "garbage_ports", "garbage_hosts", "foreign",
          "timestamps", "dronecan")
FLOODS = ("oversize", "garbage", "garbage_ports", "garbage_hosts")
# the rotating storms: datagrams per source port / host, and how the source changes
PER_SOURCE = 10
ROTATE = {"garbage_ports": "port", "garbage_hosts": "host"}
FLOOD_BPS = 10e6  # bits per second of the floods
QUIET_S = 4.0  # between storms: the daemon settles, the next window starts clean
WARMUP_S = 20.0  # sensor seconds before the first storm: levelling, heading alignment


class AttitudeLog(threading.Thread):
    """Every ATTITUDE navd sends: (receipt host time s, time_boot_ms, roll, pitch, yaw)."""

    def __init__(self, port: int) -> None:
        super().__init__(daemon=True)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
        self.sock.bind(("127.0.0.1", port))
        self.sock.settimeout(0.2)
        self.mav = mavlink.MAVLink(None)
        self.rows: list[tuple[float, int, float, float, float]] = []
        self.running = True

    def run(self) -> None:
        while self.running:
            try:
                data = self.sock.recv(65536)
            except TimeoutError:
                continue
            now = time.monotonic()
            for m in self.mav.parse_buffer(data) or []:
                if m.get_type() == "ATTITUDE":
                    self.rows.append((now, m.time_boot_ms, m.roll, m.pitch, m.yaw))


def _wild_stamp(rng: random.Random, t: int, last: int) -> int:
    kind = rng.randrange(5)
    return [0, 2**63 + rng.randrange(1000), max(1, t - rng.randrange(2_000_000, 60_000_000)),
            last, t + 3_600_000_000 * rng.randrange(1, 5)][kind]


def storm_frames(name: str, run: SimRun, t0_us: int, dur_us: int) -> list[tuple[int, bytes]]:
    """(sensor-clock send time us, datagram) of storm ``name`` in [t0, t0 + dur)."""
    rng = random.Random(19)
    out: list[tuple[int, bytes]] = []
    if name == "oversize":
        blob = b"\xfe" * 65507
        step = round(1e6 * len(blob) * 8 / FLOOD_BPS)
        out = [(t, blob) for t in range(t0_us, t0_us + dur_us, step)]
    elif name == "garbage":
        real = [f for _, f, _ in mavlink_events(run)][:2000]
        pool: list[bytes] = []
        for k in range(3000):
            kind = k % 3
            if kind == 0:
                pool.append(rng.randbytes(280))
            elif kind == 1:
                pool.append((b"\xfe\x01\xfd" * 94)[:280])
            else:  # real frames, each with its CRC broken
                frames = real[(k * 7) % len(real): (k * 7) % len(real) + 8]
                pool.append(b"".join(f[:-1] + bytes([f[-1] ^ 0x5A]) for f in frames)[:280])
        per_s = FLOOD_BPS / 8 / 280
        step = 1e6 / per_s
        n = int(dur_us / step)
        out = [(t0_us + round(k * step), pool[k % len(pool)]) for k in range(n)]
    elif name in ROTATE:
        junk = (b"\xfe\x01\xfd" * 94)[:280]
        step = 1e6 * len(junk) * 8 / FLOOD_BPS
        out = [(t0_us + round(k * step), junk) for k in range(int(dur_us / step))]
    elif name == "foreign":
        tx = MavlinkTx(7, 1)
        off = 300_000_000  # another stretch of the same road
        for t, s in timed_samples(run):
            if isinstance(s, ImuSample) and off + 0 <= t - t0_us < off + dur_us:
                fake = dataclasses.replace(s, t_us=s.t_us - off + 5_000)
                out.append((t - off + 5_000, tx.highres_imu(fake)))
            elif isinstance(s, GnssSample) and t0_us <= t < t0_us + dur_us:
                fake_g = dataclasses.replace(s, t_us=s.t_us + 5_000, vel_n=-s.vel_n,
                                             vel_e=-s.vel_e)
                out.append((t + 5_000, tx.gps_input(fake_g)))
        out.sort(key=lambda e: e[0])
    elif name == "timestamps":
        tx = MavlinkTx(1, 1)
        last = 0
        for t, s in timed_samples(run):
            if t0_us <= t < t0_us + dur_us:
                w = min(_wild_stamp(rng, s.t_us, last), 2**64 - 1)
                fake_s = dataclasses.replace(s, t_us=w)
                out.append((t + 100, tx.highres_imu(fake_s) if isinstance(fake_s, ImuSample)
                            else tx.gps_input(fake_s)))  # type: ignore[arg-type]
            last = s.t_us
    return out


class Pacer(threading.Thread):
    """Sends (sensor-clock time us, datagram) lists at real time from a shared origin;
    ``rotate`` ("port" or "host"): from a new source port (127.0.0.1) or source host
    (127.0.x.y) every PER_SOURCE datagrams."""

    def __init__(self, frames: list[tuple[int, bytes]], addr: tuple[str, int],
                 wall0: float, t0_us: int, rotate: str | None = None) -> None:
        super().__init__(daemon=True)
        self.frames, self.addr, self.wall0, self.t0_us = frames, addr, wall0, t0_us
        self.rotate = rotate
        self.sources = 0
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sent = 0
        self.errors = 0
        self.stop_at = math.inf
        # (host time, seconds late) of every send more than 20 ms after its due time: a
        # stalled sender (this machine's load) shows up as an output gap that is not navd's
        self.late: list[tuple[float, float]] = []

    def _next_source(self) -> None:
        j = self.sources
        self.sources += 1
        self.sock.close()
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        host = "127.0.0.1" if self.rotate == "port" else f"127.0.{1 + j // 250}.{1 + j % 250}"
        self.sock.bind((host, 0))  # the kernel picks a free port

    def run(self) -> None:
        for k, (t, f) in enumerate(self.frames):
            if self.rotate is not None and k % PER_SOURCE == 0:
                self._next_source()
            due = self.wall0 + (t - self.t0_us) * 1e-6
            if due > self.stop_at:
                break
            delay = due - time.monotonic()
            if delay > 0.0005:
                time.sleep(delay)
            elif delay < -0.02:
                self.late.append((time.monotonic(), -delay))
            try:
                self.sock.sendto(f, self.addr)
                self.sent += 1
            except OSError:  # ENOBUFS under a flood: the kernel's, counted
                self.errors += 1


def truth_err(run: SimRun, rows: list[tuple[float, int, float, float, float]]
              ) -> dict[str, float]:
    """Attitude error (deg) of ATTITUDE rows against truth at their sensor time."""
    if not rows:
        return {"max_roll_pitch_deg": math.nan, "yaw_rms_deg": math.nan,
                "yaw_max_deg": math.nan}
    ms = np.array([r[1] for r in rows])
    idx = np.clip(np.searchsorted(run.truth_t_us, ms * 1000), 0, len(run.truth_t_us) - 1)
    est = np.array([[r[2], r[3], r[4]] for r in rows])
    d = np.degrees(est - run.truth_euler[idx])
    d = np.abs((d + 180.0) % 360.0 - 180.0)
    return {"max_roll_pitch_deg": round(float(d[:, :2].max()), 3),
            "yaw_rms_deg": round(float(np.sqrt(np.mean(d[:, 2] ** 2))), 3),
            "yaw_max_deg": round(float(d[:, 2].max()), 3)}


def dronecan_storm(n: int = 100_000) -> dict[str, Any]:
    """The daemon's DroneCAN decoder on ``n`` malformed frames, in this process."""
    import can

    from navd.io.dronecan import DronecanConfig, DronecanDecoder
    from navd.io.dronecan.decode import FIX2_DTID, POL_DTID, RAW_IMU_DTID

    rng = random.Random(19)
    dec = DronecanDecoder(DronecanConfig(interface="virtual", relock_s=5.0))
    dtids = [RAW_IMU_DTID, FIX2_DTID, POL_DTID]
    msgs = []
    for _ in range(n):
        dtid = rng.choice(dtids)
        cid = (rng.randrange(32) << 24) | (dtid << 8) | rng.randrange(1, 128)
        msgs.append(can.Message(arbitration_id=cid, is_extended_id=True,
                                data=rng.randbytes(rng.randrange(0, 9))))
    t0 = time.process_time()
    out = 0
    for k, m in enumerate(msgs):
        out += len(dec.feed(m, k * 100))
    dt = time.process_time() - t0
    return {"frames": n, "samples_out": out, "us_per_frame": round(dt / n * 1e6, 2),
            "cpu_pct_at_1000_frames_per_s": round(dt / n * 1000 * 100, 2),
            "pending_after": dec.pending,
            "counters": {k: v for k, v in dec.counters.snapshot().items() if v}}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--storm-s", type=float, default=10.0, help="seconds per storm")
    ap.add_argument("--imu-rate", type=float, default=1000.0, help="real IMU rate, Hz")
    ap.add_argument("--only", default=",".join(STORMS), help="storms to run, comma-separated")
    ap.add_argument("--json", help="write the figures to this file")
    ap.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                    help="passed to navd run")
    a = ap.parse_args(argv)
    names = [n for n in a.only.split(",") if n]
    bad = set(names) - set(STORMS)
    if bad:
        ap.error(f"unknown storm(s) {sorted(bad)}; choose from {STORMS}")
    live = [n for n in names if n != "dronecan"]
    results: dict[str, Any] = {"machine": platform.platform(), "cpus": os.cpu_count(),
                               "python": platform.python_version(),
                               "load_avg_before": os.getloadavg()[0],
                               "imu_rate_hz": a.imu_rate, "storm_s": a.storm_s, "storms": {}}
    if live:
        total_s = WARMUP_S + len(live) * (a.storm_s + QUIET_S) + 2.0
        print(f"generating car480 at {a.imu_rate:g} Hz IMU ...", file=sys.stderr)
        run = generate(load_scenario("car480", overrides={"imu.rate_hz": a.imu_rate,
                                                          "duration_s": 480.0}), seed=1)
        real = [(t, f) for t, f, _ in mavlink_events(run) if t <= total_s * 1e6]
        dur_us = round(a.storm_s * 1e6)
        windows: list[tuple[str, int]] = []
        t = round(WARMUP_S * 1e6)
        for n in live:
            windows.append((n, t))
            t += dur_us + round(QUIET_S * 1e6)
        storms = {n: storm_frames(n, run, t0, dur_us) for n, t0 in windows}
        navd = start_navd([f"mavlink.nominal_imu_rate_hz={a.imu_rate}", *a.set])
        log = AttitudeLog(navd.port_out)
        log.start()
        status: StatusSubscriber | None = None
        try:
            navd.wait_ready()
            status = StatusSubscriber(navd.port_z, navd.vehicle)
            addr = ("127.0.0.1", navd.port_in)
            t0_us = real[0][0]
            wall0 = time.monotonic() + 0.5
            sender = Pacer(real, addr, wall0, t0_us)
            sender.start()
            for n, w0 in windows:
                start = wall0 + (w0 - t0_us) * 1e-6
                time.sleep(max(0.0, start - 3.0 - time.monotonic()))
                before = status.fresh(3.0)  # in the quiet interval: no storm frames yet
                time.sleep(max(0.0, start - time.monotonic()))
                if navd.proc.poll() is not None:
                    break
                c0, h0 = cpu_s(navd.proc.pid), time.monotonic()
                p = Pacer(storms[n], addr, wall0, t0_us, ROTATE.get(n))
                p.start()
                time.sleep(max(0.0, start + a.storm_s - time.monotonic()))
                p.stop_at = time.monotonic()
                p.join(5.0)
                c1, h1 = cpu_s(navd.proc.pid), time.monotonic()
                after = status.fresh(3.0)
                rows = [r for r in log.rows if h0 <= r[0] < h1]
                recv = [r[0] for r in rows]
                gaps = np.diff([h0, *recv, h1]) if recv else np.array([h1 - h0])
                restarts = ((after.get("restart") or {}).get("count", 0)
                            - (before.get("restart") or {}).get("count", 0))
                cnt_b, cnt_a = (before["inputs"].get("mavlink", {}),
                                after["inputs"].get("mavlink", {}))
                grew = {k: v - cnt_b.get(k, 0) for k, v in cnt_a.items()
                        if v != cnt_b.get(k, 0) and k not in ("imu_ok", "gnss_ok")}
                clock = {k: v - (before.get("clock") or {}).get(k, 0)
                         for k, v in (after.get("clock") or {}).items()
                         if isinstance(v, int)}
                late = [d for h, d in sender.late if h0 <= h < h1]
                r = {"sent": p.sent, "send_errors": p.errors, "sources": max(1, p.sources),
                     "real_sender_late_max_ms": round(max(late, default=0.0) * 1e3, 1),
                     "load_avg": os.getloadavg()[0],
                     "mbit_per_s": round(sum(len(f) for _, f in storms[n][:p.sent]) * 8
                                         / (h1 - h0) / 1e6, 2),
                     "cpu_pct_one_core": round(100.0 * (c1 - c0) / (h1 - h0), 1),
                     "output_hz": round(len(rows) / (h1 - h0), 1),
                     "longest_gap_ms": round(float(gaps.max()) * 1e3, 1),
                     "resets": restarts, **truth_err(run, rows),
                     "rss_kb": rss_kb(navd.proc.pid),
                     "state_after": after.get("state"),
                     "input_counters": grew, "clock": clock,
                     "source_lock": after.get("source_lock", {})}
                results["storms"][n] = r
                print(f"  {n}: cpu {r['cpu_pct_one_core']} %, out {r['output_hz']} Hz, gap "
                      f"{r['longest_gap_ms']} ms, resets {restarts}, roll/pitch "
                      f"{r['max_roll_pitch_deg']} deg, yaw rms {r['yaw_rms_deg']} deg",
                      file=sys.stderr)
            sender.stop_at = time.monotonic()
            sender.join(5.0)
            final = status.fresh(3.0)
            results["final_state"] = final.get("state")
        finally:
            log.running = False
            if status is not None:
                # an open Zenoh session keeps the interpreter from exiting after the table
                status.session.close()
            rc = navd.stop()
            results["navd_exit"] = rc
            results["navd_log_tail"] = navd.log_text().splitlines()[-3:]
    if "dronecan" in names:
        results["storms"]["dronecan"] = dronecan_storm()
    results["load_avg_after"] = os.getloadavg()[0]
    _verdicts(results)
    _table(results)
    if a.json:
        Path(a.json).write_text(json.dumps(results, indent=2, default=str) + "\n")
    return 0 if results.get("navd_exit", 0) == 0 else 1


def _verdicts(results: dict[str, Any]) -> None:
    s = results["storms"]
    base = s.get("baseline")
    for n in FLOODS:
        if n in s:
            r = s[n]
            r["target_met"] = (r["cpu_pct_one_core"] <= 20.0 and r["longest_gap_ms"] <= 100.0
                               and r["resets"] == 0)
    if "foreign" in s and base is not None:
        r = s["foreign"]
        r["target_met"] = (r["resets"] == 0
                           and r["max_roll_pitch_deg"] <= base["max_roll_pitch_deg"] + 0.5
                           and r["yaw_max_deg"] <= base["yaw_max_deg"] + 1.0)
    if "timestamps" in s:
        s["timestamps"]["target_met"] = s["timestamps"]["resets"] <= 1


def _table(results: dict[str, Any]) -> None:
    hdr = (f"{'storm':<13} {'sent':>7} {'Mbit/s':>7} {'CPU %':>6} {'out Hz':>7} "
           f"{'gap ms':>7} {'late ms':>7} {'resets':>6} {'r/p max':>8} {'yaw rms':>8} "
           f"{'yaw max':>8} "
           f"{'RSS MB':>7} {'target':>7}")
    print(hdr)
    for n, r in results["storms"].items():
        if n == "dronecan":
            print(f"{n:<13} {r['frames']:>7} (in-process decoder: {r['us_per_frame']} us per "
                  f"malformed frame, {r['samples_out']} samples out)")
            continue
        met = r.get("target_met")
        print(f"{n:<13} {r['sent']:>7} {r['mbit_per_s']:>7} {r['cpu_pct_one_core']:>6} "
              f"{r['output_hz']:>7} {r['longest_gap_ms']:>7} "
              f"{r['real_sender_late_max_ms']:>7} {r['resets']:>6} "
              f"{r['max_roll_pitch_deg']:>8} {r['yaw_rms_deg']:>8} {r['yaw_max_deg']:>8} "
              f"{r['rss_kb'] / 1024:>7.1f} {'' if met is None else ('met' if met else 'NOT'):>7}")


if __name__ == "__main__":
    raise SystemExit(main())
