"""``navd demo`` (what ``make run`` runs): a short run to the end, and one stopped with
Ctrl-C, which must still print the summary so far."""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import time

from daemon_util import ROOT


def _demo(*args: str) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "navd", "demo", *args], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def test_demo_runs_to_the_end_with_small_errors() -> None:
    """GIVEN `navd demo` for 30 s at 10x speed,
    WHEN it runs to the end,
    THEN it exits 0 after attitude lines, reports RMS errors of heading < 0.5, pitch < 1 and
    roll < 1.5 deg, and at least 100 MAVLink ATTITUDE received on the output port."""
    p = _demo("--duration", "30", "--rate-factor", "10")
    out, _ = p.communicate(timeout=240)
    assert p.returncode == 0, out
    rows = [ln for ln in out.splitlines() if re.match(r"^\s+\d+\.\d\s", ln)]
    assert len(rows) >= 2, out
    m = re.search(r"RMS error\s+heading ([\d.]+) deg\s+pitch ([\d.]+) deg\s+roll ([\d.]+)", out)
    assert m is not None, out
    heading, pitch, roll = (float(g) for g in m.groups())
    assert heading < 0.5 and pitch < 1.0 and roll < 1.5, out
    assert re.search(r"MAVLink ATTITUDE received on the output port: [1-9]\d{2,}", out), out


def test_demo_ctrl_c_prints_the_summary_so_far() -> None:
    """GIVEN `navd demo` over the whole car480 run at 2x speed,
    WHEN it gets SIGINT (Ctrl-C) after the first aligned attitude line,
    THEN it prints the interrupted summary with RMS errors and exits 130."""
    p = _demo("--rate-factor", "2")  # whole car480: would take 4 minutes
    assert p.stdout is not None
    deadline = time.monotonic() + 240
    seen = []
    for line in p.stdout:
        seen.append(line)
        if re.match(r"^\s+\d+\.\d\s.*\byes$", line.rstrip()):  # an aligned attitude line
            break
        assert time.monotonic() < deadline, "".join(seen)
    p.send_signal(signal.SIGINT)
    rest, _ = p.communicate(timeout=60)
    out = "".join(seen) + rest
    assert "summary (interrupted: results so far)" in out, out
    assert "RMS error" in out
    assert p.returncode == 130
