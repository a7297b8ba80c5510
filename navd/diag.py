"""Diagnostics shared by adapters and the daemon: named counters and rate-limited warnings.

Bad input must never pass silently and never flood the journal: every rejection bumps a
named counter (exported in status) and logs one line per reason per interval, with the
number of lines it held back since the last one.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterable


class Counters:
    """Named non-negative integer counters; missing names read as zero."""

    __slots__ = ("_counts",)

    def __init__(self, names: Iterable[str] = ()) -> None:
        # Pre-registering names makes them appear (as 0) in snapshots before the first event,
        # so a status consumer can tell "no errors" from "counter does not exist".
        self._counts: dict[str, int] = dict.fromkeys(names, 0)

    def inc(self, name: str, n: int = 1) -> None:
        self._counts[name] = self._counts.get(name, 0) + n

    @property
    def counts(self) -> dict[str, int]:
        """The live name -> count mapping, for a per-sample path that counts without a
        method call per event (issue 18); only ever add to it."""
        return self._counts

    def __getitem__(self, name: str) -> int:
        return self._counts.get(name, 0)

    def __contains__(self, name: object) -> bool:
        return name in self._counts

    def total(self, names: Iterable[str] | None = None) -> int:
        if names is None:
            return sum(self._counts.values())
        return sum(self._counts.get(n, 0) for n in names)

    def snapshot(self) -> dict[str, int]:
        """A copy, safe to serialise or compare while counting continues."""
        return dict(self._counts)

    def __repr__(self) -> str:
        return f"Counters({self._counts!r})"


class RateLimitedLog:
    """Log at most one line per key per ``interval_s``; report how many were held back."""

    __slots__ = ("_clock", "_interval_s", "_last", "_logger", "_suppressed")

    def __init__(
        self,
        logger: logging.Logger,
        interval_s: float,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if interval_s < 0.0:
            raise ValueError(f"interval_s must be >= 0, got {interval_s}")
        self._logger = logger
        self._interval_s = interval_s
        self._clock = clock
        self._last: dict[str, float] = {}
        self._suppressed: dict[str, int] = {}

    def warn(self, key: str, msg: str, *args: object) -> bool:
        """Log ``msg % args`` at WARNING unless ``key`` logged within the interval.

        Returns True when a line was emitted.  Formatting is deferred to logging, so a
        suppressed call costs a dict lookup and no string work.
        """
        return self._emit(logging.WARNING, key, msg, args)

    def error(self, key: str, msg: str, *args: object) -> bool:
        return self._emit(logging.ERROR, key, msg, args)

    def _emit(self, level: int, key: str, msg: str, args: tuple[object, ...]) -> bool:
        now = self._clock()
        last = self._last.get(key)
        if last is not None and now - last < self._interval_s:
            self._suppressed[key] = self._suppressed.get(key, 0) + 1
            return False
        self._last[key] = now
        held = self._suppressed.pop(key, 0)
        if held:
            self._logger.log(level, msg + " (%d similar suppressed)", *args, held)
        else:
            self._logger.log(level, msg, *args)
        return True

    def suppressed(self, key: str) -> int:
        return self._suppressed.get(key, 0)
