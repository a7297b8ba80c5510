"""Health that tells the truth (issue 19 item 4): GNSS lost, GNSS locked out, no output and
stalled input each map to a state with a documented meaning, a HEARTBEAT system_status and a
log line at the transition; WATCHDOG=1 only while outputs are actually produced."""

from __future__ import annotations

import asyncio
import dataclasses
import itertools
import logging
from collections.abc import Callable
from typing import Any

import pytest

from firmware_sim import SimRun
from navd.config.daemon import load_daemon_config
from navd.daemon import daemon as daemon_mod
from navd.daemon.daemon import GNSS_LOCKED_OUT, GNSS_LOST, HEALTH, NO_OUTPUT, Daemon
from navd.daemon.sinks import (
    MAV_STATE_ACTIVE,
    MAV_STATE_CRITICAL,
    MAV_STATE_EMERGENCY,
    MAV_STATE_STANDBY,
    CallbackSink,
)
from navd.types import GnssSample, ImuSample, NavSolution, Sample
from tests.daemon_util import car_run

RUN_S = 45.0
OUT_FROM, OUT_TO = 20_000_000, 30_000_000  # the GNSS outage / lock-out, sensor time


@pytest.fixture(scope="module")
def drive() -> SimRun:
    return car_run(RUN_S)


def _timed(d: Daemon, monkeypatch: pytest.MonkeyPatch, samples: list[Sample],
           on_tick: Callable[[float], None] | None = None
           ) -> list[tuple[float, int, str, int]]:
    """Run ``samples`` through the daemon's estimator task in simulated real time (host
    clock = sensor clock); every 0.1 s run the status bookkeeping and note (host time,
    sensor t_us, state, HEARTBEAT system_status)."""
    clock = {"now": 1000.0}
    monkeypatch.setattr(daemon_mod.time, "monotonic", lambda: clock["now"])
    monkeypatch.setattr(daemon_mod.time, "monotonic_ns", lambda: int(clock["now"] * 1e9))
    ticks: list[tuple[float, int, str, int]] = []
    push = d.est.push
    next_tick = [clock["now"]]
    state = [d.state()]

    def timed_push(s: Sample) -> bool:
        if isinstance(s, ImuSample):
            clock["now"] += s.dt_us * 1e-6
        while clock["now"] >= next_tick[0]:
            d._note_progress()
            state[0] = d._log_state_change(state[0], d.state())
            ticks.append((clock["now"], d.est.t_us, d.state(), d._mav_state()))
            if on_tick is not None:
                on_tick(clock["now"])
            next_tick[0] += 0.1
        return push(s)

    monkeypatch.setattr(d.est, "push", timed_push)

    async def go() -> None:
        for s in samples:
            d.queue.put(0, s)
        d.queue.close()
        await d._estimate()

    asyncio.run(go())
    return ticks


def _daemon(*sets: str) -> tuple[Daemon, list[NavSolution]]:
    cfg = load_daemon_config(None, ["zenoh.enabled=false", "daemon.warm_up=false", *sets])
    d = Daemon(cfg, handle_signals=False)
    out: list[NavSolution] = []
    d.sinks = [CallbackSink(out.append, 50.0)]
    return d, out


def _between(ticks: list[tuple[float, int, str, int]], t0: int, t1: int) -> set[str]:
    return {st for _, t, st, _ in ticks if t0 <= t < t1}


def test_gnss_outage_is_coasting_and_heartbeat_critical(
        drive: SimRun, monkeypatch: pytest.MonkeyPatch,
        caplog: pytest.LogCaptureFixture) -> None:
    """GIVEN a 45 s drive whose GNSS stops from 20 s to 30 s (sensor time),
    WHEN the daemon navigates through it,
    THEN it is "navigating" (ACTIVE) before, "coasting (GNSS lost)" (CRITICAL) from
    gnss_timeout_s (3 s) after the last fix until fixes return, "navigating" again after;
    one warning at the loss and one info line at the return; outputs never stop."""
    samples = [s for s in drive.samples()
               if not (isinstance(s, GnssSample) and OUT_FROM <= s.t_us < OUT_TO)]
    d, out = _daemon()
    with caplog.at_level(logging.INFO, logger="navd"):
        ticks = _timed(d, monkeypatch, samples)
    assert _between(ticks, 12_000_000, OUT_FROM + 2_800_000) == {"navigating"}
    assert _between(ticks, OUT_FROM + 3_300_000, OUT_TO) == {GNSS_LOST}
    assert _between(ticks, OUT_TO + 1_000_000, 44_000_000) == {"navigating"}
    for _, _t, st, mav in ticks:
        assert mav == HEALTH[st][0]
        if st == GNSS_LOST:
            assert mav == MAV_STATE_CRITICAL
        if st == "navigating":
            assert mav == MAV_STATE_ACTIVE
    lost = [r for r in caplog.records if "GNSS lost" in r.getMessage()]
    back = [r for r in caplog.records if "GNSS fused again" in r.getMessage()]
    assert len(lost) == 1 and lost[0].levelno == logging.WARNING and len(back) == 1
    assert "CRITICAL" in lost[0].getMessage()
    ts = [s.t_us for s in out]
    assert max(b - a for a, b in itertools.pairwise(ts)) <= 20_000
    st: dict[str, Any] = d.status()
    assert st["health"]["mav_state"] == "ACTIVE" and st["health"]["meaning"]


def test_gnss_lock_out_is_reported_as_such(drive: SimRun, monkeypatch: pytest.MonkeyPatch,
                                           caplog: pytest.LogCaptureFixture) -> None:
    """GIVEN the drive with every fix from 20 s to 30 s moved 3 km north (the filter refuses
    them: a position lock-out),
    WHEN the daemon navigates through it,
    THEN it reports "coasting (GNSS locked out)" (CRITICAL) within that window, not "GNSS
    lost", with one warning that names the refusals."""
    def moved(s: Sample) -> Sample:
        if isinstance(s, GnssSample) and OUT_FROM <= s.t_us < OUT_TO:
            return dataclasses.replace(s, lat_rad=s.lat_rad + 3000.0 / 6.37e6)
        return s

    d, _ = _daemon()
    with caplog.at_level(logging.INFO, logger="navd"):
        ticks = _timed(d, monkeypatch, [moved(s) for s in drive.samples()])
    during = _between(ticks, OUT_FROM + 3_500_000, OUT_TO)
    assert GNSS_LOCKED_OUT in during and GNSS_LOST not in during, during
    assert all(mav == MAV_STATE_CRITICAL for _, t, st, mav in ticks if st == GNSS_LOCKED_OUT)
    warn = [r.getMessage() for r in caplog.records if "GNSS locked out" in r.getMessage()]
    assert warn and "_rejected" in warn[0], warn


def test_no_output_and_stall_are_emergency(monkeypatch: pytest.MonkeyPatch) -> None:
    """GIVEN a navigating daemon whose last output was 3 s ago, then one whose input stopped,
    WHEN its state and HEARTBEAT status are read,
    THEN both are EMERGENCY; without any sink it is navigating; initializing is STANDBY."""
    d, _ = _daemon()
    monkeypatch.setattr(type(d.est), "initialized", property(lambda self: True))
    d.est.t_us = 5_000_000
    now = daemon_mod.time.monotonic()
    d._progress_at, d._nav_since, d._output_at = now, now - 5.0, now - 3.0
    assert d.state() == NO_OUTPUT and d._mav_state() == MAV_STATE_EMERGENCY
    d._progress_at = now - 10.0
    assert d.state() == "stalled" and d._mav_state() == MAV_STATE_EMERGENCY
    d._progress_at = now
    d.sinks = []  # no output configured (e.g. only --record): nothing can be missing
    assert d.state() == "navigating" and d._mav_state() == MAV_STATE_ACTIVE
    monkeypatch.setattr(type(d.est), "initialized", property(lambda self: False))
    assert d.state() == "initializing" and d._mav_state() == MAV_STATE_STANDBY


def test_watchdog_only_while_outputs_are_produced(monkeypatch: pytest.MonkeyPatch) -> None:
    """GIVEN a daemon whose sensor time moves,
    WHEN a watchdog tick is judged while navigating with an output since the tick began,
    without one, with every output failing, while levelling, and with no sensor progress,
    THEN only the first and the levelling case send WATCHDOG=1."""
    d, _ = _daemon()
    now = daemon_mod.time.monotonic()
    d.est.t_us = 5_000_000
    d._progress_at = now
    assert d._watchdog_withheld(True, now - 5.0) == ""  # levelling: IMU flows, no output due
    monkeypatch.setattr(type(d.est), "initialized", property(lambda self: True))
    d._nav_since, d._output_at = now - 20.0, now - 0.1
    assert d._watchdog_withheld(True, now - 5.0) == ""
    assert "no solution published" in d._watchdog_withheld(True, now - 0.05)
    d._output_at = now - 3.0
    assert d._watchdog_withheld(True, now - 5.0) == NO_OUTPUT
    assert "no sensor-time progress" in d._watchdog_withheld(False, now - 5.0)


def test_watchdog_withheld_while_sinks_fail(drive: SimRun,
                                            monkeypatch: pytest.MonkeyPatch) -> None:
    """GIVEN a daemon fed the drive in simulated real time whose only output raises from
    15 s (sensor time) on,
    WHEN the watchdog is judged every 5 s (WatchdogSec=10 s),
    THEN WATCHDOG=1 goes out before 15 s and not from 2 ticks after (state
    "navigating, no output", EMERGENCY)."""
    d, _ = _daemon()

    def publish(sol: NavSolution) -> None:
        if sol.t_us >= 15_000_000:
            raise OSError("broken pipe")

    d.sinks = [CallbackSink(publish, 50.0)]
    verdicts: list[tuple[int, str]] = []
    last = {"t": d.est.t_us, "tick": 1000.0}

    def tick(now: float) -> None:
        if now - last["tick"] >= 5.0:
            verdicts.append((d.est.t_us, d._watchdog_withheld(d.est.t_us != last["t"],
                                                              last["tick"])))
            last["t"], last["tick"] = d.est.t_us, now

    ticks = _timed(d, monkeypatch, list(car_run(30.0).samples()), tick)
    assert any(st == NO_OUTPUT for _, _, st, _ in ticks)
    sent = [t for t, why in verdicts if not why]
    held = [t for t, why in verdicts if why]
    assert sent and max(sent) < 15_000_000 + 5_000_000
    assert held and all(t > 15_000_000 for t in held)
    assert any(t >= 25_000_000 for t in held)
