"""benchmarks/daemon_path.py measures the steady 1 kHz path only if its warm-up reaches the
estimator as sent; it checks that itself and raises otherwise."""

from __future__ import annotations

import pytest
from bench_util import load_benchmark

daemon_path = load_benchmark("daemon_path")


def test_daemon_path_runs_with_its_warm_up_reaching_the_estimator(
        capsys: pytest.CaptureFixture[str]) -> None:
    """GIVEN the daemon-path benchmark on a short run,
    WHEN it runs,
    THEN its warm-up check passes (the estimator navigating, every warm-up IMU sample
    taken) and it prints its per-datagram figures and output hashes."""
    assert daemon_path.main(["--seconds", "3", "--trace", "200", "--top", "3"]) == 0
    out = capsys.readouterr().out
    assert "bytecode instructions" in out and "outputs: MAVLink" in out


def test_daemon_path_refuses_a_warm_up_that_did_not_reach_the_estimator(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """GIVEN the daemon-path benchmark whose link takes the kernel's host-time arrival
    stamps again (the bug it had: its sensor-time clock mixed with host time),
    WHEN it runs,
    THEN it raises instead of printing figures of the wrong path."""
    from navd.io.mavlink.link import PacedUdpTransport

    # the benchmark turns the stamps off after opening; keep them on behind its back
    monkeypatch.setattr(PacedUdpTransport, "_stamps",
                        property(lambda self: True, lambda self, value: None), raising=False)
    with pytest.raises(RuntimeError, match="warm-up"):
        daemon_path.main(["--seconds", "3", "--trace", "200", "--top", "3"])
