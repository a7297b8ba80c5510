"""Soak: a long drive at 1 kHz HIGHRES_IMU + 10 Hz GPS_INPUT over loopback UDP into a real
``navd run`` subprocess, in real time, watching its memory and CPU (issue 16 item 10).

    python benchmarks/soak.py --minutes N [--json PATH] [--sample-s 5] [--set KEY=VALUE]

The scenario is drive_long (stops, crawling, tight turns, GNSS outages) with its IMU at 1 kHz
and GNSS at 10 Hz through scenario overrides.  Runs longer than the drive (20 min) replay it
with the sensor clock continuing (each pass shifted by the drive's length), so the daemon sees
one monotonic clock; the position jumps back at each seam, which the estimator's GNSS gating
handles like any bad fix.

Every ``--sample-s`` seconds: the daemon's RSS (/proc/<pid>/status VmRSS) and its CPU
(utime + stime over the interval, % of one core).  At the end the daemon is stopped with
SIGTERM (it drains its queue and logs its final stats), and the table gives:
  IMU sent / consumed / lost   our datagrams vs the estimator's ``imu`` counter (final stats)
  queue drops                  the daemon's input queue overflows
  RSS start / end / max        kB; start = first sample after READY
  RSS slope                    kB/min, least squares over the second half of the samples
                               (the first half holds warm-up: JIT, caches, allocator arenas)
  CPU median / p95             of the per-interval figures, % of one core
Exit 1 if the daemon died or anything was lost or dropped, so CI catches it; "RSS flat" (slope
below ``--flat-kb-per-min``) is a verdict printed, not an exit code, because a 1-minute run's
second half is too short for a slope to mean much.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # benchmarks/ is not a package
from daemon import cpu_s, pct, start_navd

from firmware_sim import generate, load_scenario
from firmware_sim.run import SimRun
from firmware_sim.stream import StreamStats, mavlink_events, stream_mavlink_udp

SCENARIO = "drive_long"
# 64 kB/min is ~3.8 MB an hour: a leak of one small object per IMU sample (>= 60 kB/min at
# 1 kHz) would exceed it, allocator noise does not.
FLAT_KB_PER_MIN = 64.0


def rss_kb(pid: int) -> int:
    """Resident set size of a process, kB (VmRSS)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise RuntimeError(f"no VmRSS for pid {pid}")


def shifted(run: SimRun, offset_us: int) -> SimRun:
    """The same run with every sensor time stamp ``offset_us`` later (only the fields that
    streaming reads)."""
    gnss = {**run.gnss, "t_us": run.gnss["t_us"] + offset_us,
            "t_arrival_us": run.gnss["t_arrival_us"] + offset_us}
    return dataclasses.replace(run, imu_t_us=run.imu_t_us + offset_us, gnss=gnss)


def looped_events(run: SimRun, seconds: float) -> Iterator[tuple[int, bytes, bool]]:
    """MAVLink frames of ``run`` replayed back to back on one continuous clock until
    ``seconds`` of sensor time; frames are encoded as they go (an hour at 1 kHz would not
    fit in memory encoded up front)."""
    period_us = int(run.imu_t_us[-1] - run.imu_t_us[0]) + run.imu_dt_us
    t_end = int(run.imu_t_us[0]) + round(seconds * 1e6)
    k = 0
    while True:
        for ev in mavlink_events(shifted(run, k * period_us) if k else run):
            if ev[0] > t_end:
                return
            yield ev
        k += 1


def udp_drops(port: int) -> int | None:
    """Datagrams the kernel dropped at the UDP socket bound to ``port`` on this host (the
    ``drops`` column of /proc/net/udp and udp6: a full receive buffer), None if no such
    socket is listed.  Tells loss before navd read the socket from loss inside navd."""
    total: int | None = None
    for name in ("/proc/net/udp", "/proc/net/udp6"):
        try:
            lines = Path(name).read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            f = line.split()
            if len(f) >= 13 and int(f[1].rsplit(":", 1)[1], 16) == port:
                total = (total or 0) + int(f[-1])
    return total


def slope_kb_per_min(t_s: list[float], rss: list[int]) -> float:
    """Least-squares RSS slope over the second half of the samples, kB/min."""
    h = len(t_s) // 2
    if len(t_s) - h < 2:
        return float("nan")
    return float(np.polyfit(np.asarray(t_s[h:]) / 60.0, np.asarray(rss[h:], float), 1)[0])


def final_stats(log: str) -> dict[str, Any] | None:
    """The JSON of the daemon's "final stats" line, if it got that far."""
    for line in reversed(log.splitlines()):
        if "final stats " in line:
            stats: dict[str, Any] = json.loads(line.split("final stats ", 1)[1])
            return stats
    return None


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, required=True, help="streaming time, minutes")
    ap.add_argument("--sample-s", type=float, default=5.0, help="RSS/CPU sampling period, s")
    ap.add_argument("--flat-kb-per-min", type=float, default=FLAT_KB_PER_MIN,
                    help="RSS slope bound for the 'flat' verdict, kB/min")
    ap.add_argument("--json", help="write the figures and samples to this file")
    ap.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                    help="passed to navd run")
    a = ap.parse_args(argv)
    seconds = a.minutes * 60.0

    scenario = load_scenario(SCENARIO, overrides={"imu.rate_hz": 1000.0, "gnss.rate_hz": 10.0})
    # generate no more than is streamed (generation of the whole 1200 s takes ~2 min)
    scenario = load_scenario(SCENARIO, overrides={
        "imu.rate_hz": 1000.0, "gnss.rate_hz": 10.0,
        "duration_s": min(scenario.duration, seconds + 1.0)})
    print(f"generating {SCENARIO} ({scenario.duration:.0f} s, 1 kHz IMU, 10 Hz GNSS) ...",
          file=sys.stderr)
    run = generate(scenario, seed=1)

    # status over Zenoh is not read here; the periodic log line every minute is part of the
    # daemon's normal day, so keep it
    navd = start_navd(a.set, status_period_s=1.0, log_period_s=60.0)
    pid = navd.proc.pid
    died = False
    samples: list[dict[str, float]] = []
    sent = StreamStats()
    kernel_drops: int | None = None
    try:
        navd.wait_ready()
        print(f"streaming {a.minutes:g} min at 1 kHz IMU + 10 Hz GNSS into navd "
              f"(pid {pid}) ...", file=sys.stderr)
        stop = threading.Event()

        def send() -> None:
            nonlocal sent
            sent = stream_mavlink_udp(
                looped_events(run, seconds), f"udp:127.0.0.1:{navd.port_in}", 1.0,
                stop=lambda: stop.is_set() or navd.proc.poll() is not None)

        sender = threading.Thread(target=send, name="sender", daemon=True)
        wall0 = time.monotonic()
        c_prev, w_prev = cpu_s(pid), wall0
        samples.append({"t_s": 0.0, "rss_kb": rss_kb(pid), "cpu_pct": float("nan")})
        sender.start()
        next_minute = 60.0
        while sender.is_alive():
            sender.join(max(0.0, wall0 + len(samples) * a.sample_s - time.monotonic()))
            if navd.proc.poll() is not None:
                died = True
                break
            now, c = time.monotonic(), cpu_s(pid)
            samples.append({"t_s": round(now - wall0, 2), "rss_kb": rss_kb(pid),
                            "cpu_pct": round(100.0 * (c - c_prev) / (now - w_prev), 2)})
            c_prev, w_prev = c, now
            if now - wall0 >= next_minute:  # the trend as it goes
                print(f"  {(now - wall0) / 60:5.1f} min: RSS {samples[-1]['rss_kb']:.0f} kB, "
                      f"CPU {samples[-1]['cpu_pct']:.1f} %", file=sys.stderr)
                next_minute += 60.0
        stop.set()
        sender.join(10)
        time.sleep(1.0)  # let the last datagrams reach the queue before SIGTERM
        kernel_drops = udp_drops(navd.port_in)
        died = died or navd.proc.poll() is not None
    finally:
        rc = navd.stop()
    stats = final_stats(navd.log_text())

    consumed = stats["estimator"]["counters"].get("imu", 0) if stats else 0
    drops = stats["queue"]["drops"] if stats else -1
    lost = sent.imu - consumed
    t_s = [s["t_s"] for s in samples]
    rss = [int(s["rss_kb"]) for s in samples]
    cpu = [s["cpu_pct"] for s in samples[1:]]
    slope = slope_kb_per_min(t_s, rss)
    flat = bool(slope < a.flat_kb_per_min)
    ok = not died and stats is not None and lost == 0 and drops == 0
    res: dict[str, Any] = {
        "machine": platform.platform(), "cpus": os.cpu_count(),
        "python": platform.python_version(), "scenario": SCENARIO, "minutes": a.minutes,
        "wall_s": round(sent.wall_s, 1), "imu_sent": sent.imu, "gnss_sent": sent.gnss,
        "imu_consumed": consumed, "lost": lost, "queue_drops": drops,
        "kernel_udp_drops": kernel_drops,
        "sender_max_late_ms": round(sent.max_late_s * 1e3, 1),
        "daemon_alive": not died, "exit_code": rc, "final_stats": stats is not None,
        "rss_start_kb": rss[0], "rss_end_kb": rss[-1], "rss_max_kb": max(rss),
        "rss_slope_kb_per_min": round(slope, 1), "rss_flat_bound_kb_per_min": a.flat_kb_per_min,
        "rss_flat": flat, "cpu_median_pct": round(pct(cpu, 50), 1),
        "cpu_p95_pct": round(pct(cpu, 95), 1), "ok": ok, "samples": samples,
    }

    rows = [
        ("minutes streamed (wall)", f"{sent.wall_s / 60:.2f}"),
        ("IMU datagrams sent / consumed / lost", f"{sent.imu} / {consumed} / {lost}"),
        ("GNSS datagrams sent", f"{sent.gnss}"),
        ("queue drops", f"{drops}"),
        ("of the lost: dropped by the kernel (full socket buffer)",
         "not read" if kernel_drops is None else f"{kernel_drops}"),
        ("sender: latest behind schedule, ms", f"{sent.max_late_s * 1e3:.0f}"),
        ("RSS start / end / max, kB", f"{rss[0]} / {rss[-1]} / {max(rss)}"),
        ("RSS slope (2nd half), kB/min", f"{slope:.1f}"),
        ("CPU median / p95, % of one core", f"{pct(cpu, 50):.1f} / {pct(cpu, 95):.1f}"),
        ("daemon alive to the end / exit code", f"{not died} / {rc}"),
    ]
    # the trend: RSS at each whole minute (nearest sample)
    trend = [rss[int(np.argmin(np.abs(np.asarray(t_s) - 60.0 * m)))]
             for m in range(int(t_s[-1] // 60.0) + 1)]
    w = max(len(r[0]) for r in rows)
    print(f"\nnavd soak: {SCENARIO}, 1 kHz IMU + 10 Hz GNSS over MAVLink UDP, {a.minutes:g} min "
          f"({res['machine']}, {res['cpus']} CPUs, Python {res['python']})")
    print(f"| {'what':<{w}} | {'measured':>28} |")
    print(f"|{'-' * (w + 2)}|{'-' * 30}|")
    for what, val in rows:
        print(f"| {what:<{w}} | {val:>28} |")
    print("RSS trend, kB at each minute: " + " ".join(str(v) for v in trend))
    print(f"verdict: RSS {'flat' if flat else 'NOT flat'} (slope {slope:.1f} kB/min, bound "
          f"{a.flat_kb_per_min:g}); loss {lost}, drops {drops}; daemon "
          f"{'alive' if not died else 'DIED'} -> {'PASS' if ok and flat else 'FAIL'}")
    if a.json:
        Path(a.json).write_text(json.dumps(res, indent=2) + "\n")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
