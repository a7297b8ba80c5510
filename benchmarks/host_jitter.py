"""How late this host wakes a sleeping process: the floor under any daemon's latency tail.

    python benchmarks/host_jitter.py [--seconds 20] [--period-ms 1] [--fifo] [--json PATH|-]

A loop sleeps until the next multiple of the period (``time.sleep`` to an absolute
``time.monotonic_ns`` instant) and records how late it woke.  That is the scheduling delay a
daemon waiting on a socket or a timer also meets before it can run: the kernel's wake-up,
the run queue when other threads hold the cores, and on a virtual machine the time the
hypervisor gives the virtual CPU to someone else (which the guest's run-queue statistics do
not show).  ``benchmarks/daemon.py`` runs it beside navd during its 1 kHz phase, at a 5 ms
period (~0.3 % of a core), so each daemon figure comes with the host's own tail of that run.
In 7 runs navd's latency p99 followed this probe's p99 (docs/results.md); a run in which
more than 1 % of these wake-ups were over 2 ms late is one whose p99 says more about the
host than about the daemon.

``--fifo`` asks for SCHED_FIFO (needs the privilege): what a real-time priority would buy.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Sequence
from typing import Any

import numpy as np


def lateness_ns(seconds: float, period_ns: int) -> list[int]:
    """Wake-up lateness (ns) of a loop sleeping to every multiple of ``period_ns`` for
    ``seconds``."""
    late: list[int] = []
    now = time.monotonic_ns
    due = now() + period_ns
    end = due + int(seconds * 1e9)
    while due < end:
        d = due - now()
        if d > 0:
            time.sleep(d * 1e-9)
        late.append(now() - due)  # time.sleep rounds its deadline up: never negative
        due += period_ns
        t = now()
        if t > due:  # a stall longer than a period: the next wake-up is the next multiple
            due += ((t - due) // period_ns + 1) * period_ns
    return late


def summary(late_ns: Sequence[int], period_ns: int) -> dict[str, Any]:
    """Percentiles (ms) of the lateness and the share (%) of wake-ups over 1 and 2 ms late."""
    a = np.asarray(late_ns, dtype=np.float64) * 1e-6
    if a.size == 0:
        raise ValueError("no wake-ups measured")
    return {
        "period_ms": period_ns * 1e-6, "wakeups": int(a.size),
        "late_p50_ms": round(float(np.percentile(a, 50)), 3),
        "late_p99_ms": round(float(np.percentile(a, 99)), 3),
        "late_p999_ms": round(float(np.percentile(a, 99.9)), 3),
        "late_max_ms": round(float(a.max()), 3),
        "over_1ms_pct": round(100.0 * float(np.mean(a > 1.0)), 2),
        "over_2ms_pct": round(100.0 * float(np.mean(a > 2.0)), 2),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--period-ms", type=float, default=1.0)
    ap.add_argument("--fifo", action="store_true", help="run at SCHED_FIFO priority 10")
    ap.add_argument("--json", help="write the figures to this file ('-': stdout, no table)")
    a = ap.parse_args(argv)
    if a.seconds <= 0 or a.period_ms <= 0:
        ap.error("--seconds and --period-ms must be positive")
    if a.fifo:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(10))
    period_ns = round(a.period_ms * 1e6)
    res = summary(lateness_ns(a.seconds, period_ns), period_ns)
    res["policy"] = "fifo" if a.fifo else "other"
    res["load_avg_after"] = round(os.getloadavg()[0], 2)
    if a.json == "-":
        json.dump(res, sys.stdout)
        return 0
    print(f"wake-up lateness, {res['wakeups']} sleeps to every {res['period_ms']:g} ms "
          f"({res['policy']}, load average {res['load_avg_after']:.2f} after)")
    for key in ("late_p50_ms", "late_p99_ms", "late_p999_ms", "late_max_ms",
                "over_1ms_pct", "over_2ms_pct"):
        print(f"| {key:<14} | {res[key]:>9.3f} |")
    if a.json:
        with open(a.json, "w") as f:
            json.dump(res, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
