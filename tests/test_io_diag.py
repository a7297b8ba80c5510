"""Counters and the rate-limited logger."""

from __future__ import annotations

import logging

import pytest

from navd.diag import Counters, RateLimitedLog


def test_counters_count_and_snapshot_is_a_copy() -> None:
    c = Counters(["bad_crc"])
    assert c.snapshot() == {"bad_crc": 0}
    c.inc("bad_crc")
    c.inc("truncated", 3)
    snap = c.snapshot()
    c.inc("bad_crc")
    assert snap == {"bad_crc": 1, "truncated": 3}
    assert c["bad_crc"] == 2 and c["never"] == 0
    assert c.total() == 5 and c.total(["truncated"]) == 3


def test_rate_limited_log_suppresses_and_reports_count(caplog: pytest.LogCaptureFixture) -> None:
    now = [0.0]
    log = RateLimitedLog(logging.getLogger("t.rl"), 1.0, clock=lambda: now[0])
    with caplog.at_level(logging.WARNING, logger="t.rl"):
        assert log.warn("crc", "bad crc %d", 1)
        for i in range(5):
            now[0] += 0.1
            assert not log.warn("crc", "bad crc %d", i)
        assert log.warn("other", "independent key")
        now[0] = 1.2
        assert log.warn("crc", "bad crc %d", 99)
    msgs = [r.getMessage() for r in caplog.records]
    assert msgs == ["bad crc 1", "independent key", "bad crc 99 (5 similar suppressed)"]
    assert log.suppressed("crc") == 0
