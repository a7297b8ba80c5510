"""benchmarks/host_jitter.py: the lateness statistics and the probe loop itself."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from benchmarks.host_jitter import lateness_ns, summary

ROOT = Path(__file__).resolve().parents[1]


def test_summary_of_known_lateness() -> None:
    # 1000 wake-ups: 980 at 0.1 ms, 10 at 1.5 ms, 10 at 3 ms
    late = [100_000] * 980 + [1_500_000] * 10 + [3_000_000] * 10
    s = summary(late, 5_000_000)
    assert s["wakeups"] == 1000
    assert s["period_ms"] == 5.0
    assert s["late_p50_ms"] == pytest.approx(0.1)
    assert s["late_max_ms"] == pytest.approx(3.0)
    assert s["over_1ms_pct"] == pytest.approx(2.0)
    assert s["over_2ms_pct"] == pytest.approx(1.0)
    # numpy's linear percentile between the 990th (1.5 ms) and 991st (3 ms) of 1000
    assert 1.5 <= s["late_p99_ms"] <= 3.0


def test_summary_refuses_no_data() -> None:
    with pytest.raises(ValueError):
        summary([], 1_000_000)


def test_probe_wakes_once_per_period_and_never_early() -> None:
    late = lateness_ns(0.2, 5_000_000)
    # 40 periods in 0.2 s; a stall longer than a period skips wake-ups, never adds any
    assert 20 <= len(late) <= 40
    assert min(late) >= 0


def test_cli_json_to_stdout() -> None:
    out = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "host_jitter.py"),
                          "--seconds", "0.1", "--period-ms", "5", "--json", "-"],
                         check=True, capture_output=True, text=True, timeout=60).stdout
    res = json.loads(out)
    assert res["policy"] == "other"
    assert 10 <= res["wakeups"] <= 20
    assert res["late_p50_ms"] <= res["late_p99_ms"] <= res["late_max_ms"]
