"""Counters and the rate-limited logger."""

from __future__ import annotations

import logging

import pytest

from navd.diag import Counters, RateLimitedLog


def test_counters_count_and_snapshot_is_a_copy() -> None:
    """GIVEN a Counters object declared with bad_crc,
    WHEN counters are incremented (including an undeclared one) around a snapshot,
    THEN the snapshot keeps the values at the time it was taken, unknown names read 0, and
    total() sums all counters or the named ones."""
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
    """GIVEN a RateLimitedLog with a 1 s interval and a fake clock,
    WHEN the same key is warned six times within 0.5 s, another key once, and the first key
    again after 1.2 s,
    THEN only the first warning per key is logged until the interval passes, and the next
    one says how many similar messages were suppressed (5), resetting the count."""
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
