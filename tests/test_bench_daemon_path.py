"""benchmarks/daemon_path.py measures the steady 1 kHz path only if its warm-up reaches the
estimator as sent; it checks that itself and raises otherwise.  Run in a subprocess: the
benchmark replaces module attributes (the receive clock) for its whole process."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ARGS = ["--seconds", "3", "--trace", "200", "--top", "3"]


def _run(code: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), str(ROOT / "benchmarks")])}
    return subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=600, check=False)


def test_daemon_path_runs_with_its_warm_up_reaching_the_estimator() -> None:
    """GIVEN the daemon-path benchmark on a short run,
    WHEN it runs,
    THEN its warm-up check passes (the estimator navigating, every warm-up IMU sample
    taken) and it prints its per-datagram figures and output hashes."""
    r = _run(f"import daemon_path; raise SystemExit(daemon_path.main({ARGS!r}))")
    assert r.returncode == 0, r.stderr[-2000:]
    assert "bytecode instructions" in r.stdout and "outputs: MAVLink" in r.stdout


def test_daemon_path_refuses_a_warm_up_that_did_not_reach_the_estimator() -> None:
    """GIVEN the daemon-path benchmark whose link takes host-time arrival stamps again (the
    bug it had: its sensor-time clock mixed with host time; here a host stamp that stays
    at the start, so that the mix shows however fast the machine feeds),
    WHEN it runs,
    THEN it fails with the warm-up error instead of printing figures of the wrong path."""
    r = _run("import time\n"
             "from navd.io.mavlink.link import PacedUdpTransport as P\n"
             # the benchmark turns the stamps off after opening: keep them on behind its back
             "P._stamps = property(lambda self: True, lambda self, value: None)\n"
             # every read stamped on a host clock that does not follow the feed's: with the
             # kernel's own stamps (real time) the mix went unnoticed whenever the machine
             # was slow enough to feed near real time (2 of 6 runs beside two busy
             # processes passed the warm-up); a stamp held at the start fails on any machine
             "P._arrival_ns = lambda self, t0=time.monotonic_ns(): t0\n"
             f"import daemon_path; raise SystemExit(daemon_path.main({ARGS!r}))")
    assert r.returncode != 0
    assert "warm-up: the estimator took" in r.stderr, r.stderr[-2000:]
    assert "bytecode instructions" not in r.stdout
