"""A sensor clock restart (autopilot reboot) mid-run (issue 16 item 1): the estimator starts
over (``reinit_time_jump``), the output schedules start over with it, outputs resume as on a
fresh start, the status says what happened, and HEARTBEAT is ACTIVE only while solutions go
out."""

from __future__ import annotations

import asyncio
import logging
from typing import Any

import numpy as np
import pytest

from navd.config import load_config
from navd.config.daemon import load_daemon_config
from navd.daemon import daemon as daemon_mod
from navd.daemon.daemon import Daemon
from navd.daemon.sinks import MAV_STATE_ACTIVE, CallbackSink
from navd.pipeline import OutputSchedule, build_estimator, solutions
from navd.types import ImuSample, NavSolution, Sample
from tests.daemon_util import car_run

RUN_S = 20.0


@pytest.fixture(scope="module")
def drive() -> list[Sample]:
    return list(car_run(RUN_S).samples())


def test_schedule_starts_over_with_the_estimator() -> None:
    """GIVEN a 50 Hz output schedule that has output at sensor time 400 s,
    WHEN the sensor clock restarts near 0, first in the old epoch, then in epoch 1,
    THEN nothing is due in the old epoch; in the new one output is due every 20 ms again."""
    s = OutputSchedule(50.0)
    assert s.due(400_000_000) and not s.due(400_010_000)
    # the sensor rebooted: its clock starts again near 0, far below the next multiple
    assert not s.due(10_000)
    assert s.due(20_000, epoch=1) and not s.due(30_000, epoch=1) and s.due(40_000, epoch=1)


def test_replay_after_a_clock_restart_outputs_as_a_fresh_start(drive: list[Sample]) -> None:
    """GIVEN a 20 s car drive replayed twice back to back (the sensor clock restarts),
    WHEN the estimator's solutions are taken at 50 Hz,
    THEN it restarts once (reinit_time_jump); the first half equals a fresh run and the
    second starts within ~1 s of the new clock and ends where the fresh run ends."""
    fresh = [sol.t_us for sol in solutions(build_estimator(load_config(None, [])), drive, 50.0)]
    est = build_estimator(load_config(None, []))
    both = [sol.t_us for sol in solutions(est, drive + drive, 50.0)]
    assert est.counters["reinit_time_jump"] == 1 and est.restarts == 1
    k = len(fresh)
    assert both[:k] == fresh
    second = both[k:]
    # the sample that showed the jump was refused, so levelling ends one IMU sample later
    assert second and second[0] <= fresh[0] + 20_000
    assert second[0] < 1_100_000  # within ~1 s of the new clock
    assert second[-1] == fresh[-1] and len(second) >= len(fresh) - 1


def test_daemon_resumes_output_and_reports_the_restart(
        drive: list[Sample], monkeypatch: pytest.MonkeyPatch,
        caplog: pytest.LogCaptureFixture) -> None:
    """GIVEN a daemon fed the drive twice in simulated real time (the host clock advances
    with the sensor clock, the MAVLink state sampled every 0.1 s),
    WHEN its estimate loop runs through the restart,
    THEN output resumes within ~1 s of the new clock, status, status line and one warning
    report reinit_time_jump, and HEARTBEAT is ACTIVE only within 1 s of an output."""
    cfg = load_daemon_config(None, ["zenoh.enabled=false", "daemon.warm_up=false"])
    d = Daemon(cfg, handle_signals=False)
    out: list[tuple[int, float]] = []  # (sensor t_us, host time) of every published solution
    clock = {"now": 1000.0}
    monkeypatch.setattr(daemon_mod.time, "monotonic", lambda: clock["now"])
    monkeypatch.setattr(daemon_mod.time, "monotonic_ns", lambda: int(clock["now"] * 1e9))

    def publish(sol: NavSolution) -> None:
        out.append((sol.t_us, clock["now"]))

    d.sinks = [CallbackSink(publish, 50.0)]
    beats: list[tuple[float, int, str]] = []
    push = d.est.push
    next_beat = [clock["now"]]

    def timed_push(s: Sample) -> bool:
        if isinstance(s, ImuSample):
            clock["now"] += s.dt_us * 1e-6
        while clock["now"] >= next_beat[0]:
            d._note_progress()
            beats.append((clock["now"], d._mav_state(), d.state()))
            next_beat[0] += 0.1
        return push(s)

    monkeypatch.setattr(d.est, "push", timed_push)

    async def go() -> None:
        for s in drive + drive:
            d.queue.put(0, s)
        d.queue.close()
        await d._estimate()

    with caplog.at_level(logging.WARNING, logger="navd"):
        asyncio.run(go())
    t_out = np.array([t for t, _ in out])
    back = np.flatnonzero(np.diff(t_out) < 0)
    assert back.size == 1, "no output after the sensor clock restarted"
    k = int(back[0]) + 1
    assert t_out[k] < 1_100_000 and t_out[-1] == t_out[k - 1]

    st: dict[str, Any] = d.status()
    assert st["restart"]["reason"] == "reinit_time_jump" and st["restart"]["count"] == 1
    assert st["restart"]["sensor_t_before_s"] == pytest.approx(RUN_S, abs=0.01)
    assert "restarted 1x (last: reinit_time_jump" in d.status_line()
    lines = [r.getMessage() for r in caplog.records if "estimator restarted" in r.message]
    assert len(lines) == 1 and "reinit_time_jump" in lines[0] and "reboot" in lines[0]

    # HEARTBEAT: ACTIVE only while solutions went out within the last second
    host_out = np.array([h for _, h in out])
    assert any(mav == MAV_STATE_ACTIVE for _, mav, _ in beats), beats[:5]
    for now, mav, state in beats:
        if mav == MAV_STATE_ACTIVE:
            i = np.searchsorted(host_out, now, side="right")
            assert i > 0 and now - host_out[i - 1] <= 1.0, (now, state)


def test_heartbeat_is_not_active_while_navigating_without_output(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """GIVEN a daemon whose estimator is navigating but whose last output was 3 s ago,
    WHEN its state and MAVLink state are read, then again after an output,
    THEN it is "navigating, no output" and not ACTIVE, then "navigating" and ACTIVE."""
    cfg = load_daemon_config(None, ["zenoh.enabled=false", "daemon.warm_up=false"])
    d = Daemon(cfg, handle_signals=False)
    d.sinks = [CallbackSink(lambda sol: None, 50.0)]
    monkeypatch.setattr(type(d.est), "initialized", property(lambda self: True))
    d.est.t_us = 5_000_000
    now = daemon_mod.time.monotonic()
    d._progress_at, d._nav_since, d._output_at = now, now - 5.0, now - 3.0
    assert d.state() == "navigating, no output" and d._mav_state() != MAV_STATE_ACTIVE
    d._output_at = now
    assert d.state() == "navigating" and d._mav_state() == MAV_STATE_ACTIVE
