"""Source locking (issue 19 item 2): IMU and GNSS input each lock onto the first source that
delivers it; other sources are refused, counted and logged, take over only after the locked
one has been silent for ``relock_s``, and a second IMU stream describing another motion is
reported as contradicting the first."""

from __future__ import annotations

import dataclasses
import heapq
import logging
from collections.abc import Iterator

import numpy as np
import pytest

from firmware_sim import SimRun
from firmware_sim.stream import dronecan_events, mavlink_events, timed_samples
from firmware_sim.transport.mavlink_tx import MavlinkTx
from navd.config import load_config
from navd.config.daemon import load_daemon_config
from navd.daemon.adapters import dronecan_bus_config, mavlink_input_config
from navd.diag import Counters, RateLimitedLog
from navd.io.common import Rejector
from navd.io.dronecan import DronecanDecoder
from navd.io.mavlink import MavlinkDecoder
from navd.io.source_lock import SourceLock
from navd.pipeline import build_estimator, solutions
from navd.types import GnssSample, ImuSample, NavSolution, Sample
from tests.daemon_util import car_run

RUN_S = 40.0


@pytest.fixture(scope="module")
def real() -> SimRun:
    return car_run(RUN_S)


@pytest.fixture(scope="module")
def foreign() -> SimRun:
    """Plausible false data: another car's drive (the car480 track from 100 s on, other
    noise), restamped onto the real clock by :func:`_foreign_events`."""
    return car_run(FOREIGN_OFFSET_S + RUN_S, seed=5)


FOREIGN_OFFSET_S = 100.0


def _foreign_events(run: SimRun, real: SimRun, sysid: int = 7, lag_us: int = 5_000
                    ) -> Iterator[tuple[int, bytes, bool]]:
    """A spoofer on the real clock, ``lag_us`` after it (send and sensor time): IMU of ``run`` from
    FOREIGN_OFFSET_S on (another stretch of road), and the real fixes with the velocity
    reversed (plausible position, the heading 180 deg off)."""
    tx = MavlinkTx(sysid, 1)
    off = round(FOREIGN_OFFSET_S * 1e6)
    imu = ((t - off, dataclasses.replace(s, t_us=s.t_us - off + lag_us))
           for t, s in timed_samples(run) if isinstance(s, ImuSample) and t >= off)
    gnss = ((t, dataclasses.replace(s, t_us=s.t_us + lag_us, vel_n=-s.vel_n, vel_e=-s.vel_e))
            for t, s in timed_samples(real) if isinstance(s, GnssSample))
    for t, s in heapq.merge(imu, gnss, key=lambda e: e[0]):
        if t < 1_000_000:  # the spoofer joins after the vehicle's own sender
            continue
        yield (t + lag_us,
               tx.highres_imu(s) if isinstance(s, ImuSample)
               else tx.gps_input(s) if isinstance(s, GnssSample) else b"", True)


def _merged(*streams: Iterator[tuple[int, bytes, bool]]) -> list[tuple[int, bytes]]:
    return [(t, f) for t, f, _ in heapq.merge(*streams, key=lambda e: e[0])]


def _decode(frames: list[tuple[int, bytes]], *sets: str) -> tuple[list[Sample], MavlinkDecoder]:
    """The daemon's decoder (default [mavlink], or with ``sets``), fed one frame per
    datagram, the send time standing in for the host receive time."""
    cfg = load_daemon_config(None, list(sets))
    dec = MavlinkDecoder(mavlink_input_config(cfg.mavlink, warn_interval_s=5.0))
    out: list[Sample] = []
    for t, f in frames:
        out += dec.feed_datagram(f, t)
    return out, dec


def _solve(samples: list[Sample]) -> list[NavSolution]:
    return list(solutions(build_estimator(load_config(None, [])), samples, 50.0))


def _att_err_deg(run: SimRun, sols: list[NavSolution]) -> np.ndarray:
    """|navd - truth| of roll, pitch, yaw (deg, wrapped) at each solution, (N, 3)."""
    idx = np.array([s.t_us for s in sols]) // run.imu_dt_us
    est = np.array([[s.roll_rad, s.pitch_rad, s.yaw_rad] for s in sols])
    d = np.degrees(est - run.truth_euler[idx])
    return np.abs((d + 180.0) % 360.0 - 180.0)


def test_foreign_sysid_with_false_data_changes_nothing(real: SimRun, foreign: SimRun) -> None:
    """GIVEN the car drive from sysid 1 and, from 1 s on, interleaved 5 ms after it on the
    same clock, sysid 7 sending another stretch of road's IMU and the real fixes with the
    velocity reversed,
    WHEN decoded with the default [mavlink] settings and navigated,
    THEN the decoded samples (so the solutions) equal those of the car alone, sysid 7 is
    refused and counted for IMU and GNSS, and its IMU is reported as contradicting; with
    source_lock = false the same input makes roll/pitch worse by > 2 deg after 10 s (the
    test can fail)."""
    clean, _ = _decode(_merged(mavlink_events(real, sysid=1)))
    # the foreign stream starts 5 ms later: the real one locks first
    mixed = _merged(mavlink_events(real, sysid=1), _foreign_events(foreign, real))
    got, dec = _decode(mixed)
    assert got == clean  # the estimator sees exactly the car's samples
    sols = _solve(got)
    settled = np.array([s.t_us for s in sols]) > 10_000_000
    err = _att_err_deg(real, sols)[settled]
    c = dec.counters.snapshot()
    assert c["imu_source_refused"] > 1000 and c["gnss_source_refused"] > 100, c
    assert c["imu_source_contradicts"] >= 5, c
    st = dec.source_lock.status() if dec.source_lock else {}
    assert st["imu"]["locked"] == "sysid=1 compid=1" == st["gnss"]["locked"]
    assert st["imu"]["contradicted_by"] == "sysid=7 compid=1"
    assert "src_7_1_frames" not in c  # per-source counters only for the accepted source

    unlocked, _ = _decode(mixed, "mavlink.source_lock=false")
    assert unlocked != clean
    sols_u = _solve(unlocked)
    worst = _att_err_deg(real, sols_u)[np.array([s.t_us for s in sols_u]) > 10_000_000]
    assert worst[:, :2].max() > err[:, :2].max() + 2.0, (worst.max(0), err.max(0))


def test_an_agreeing_second_imu_is_refused_but_not_contradicting(real: SimRun) -> None:
    """GIVEN the car drive from sysid 1 and a second IMU on the same car from sysid 2 (the
    same motion with its own biases: 0.5 deg/s per gyro axis, 0.3 m/s^2 per accelerometer
    axis, and 0.5 ms later),
    WHEN decoded,
    THEN sysid 2 is refused and no contradiction is reported."""
    tx = MavlinkTx(2, 1)
    bg, ba = np.radians(0.5), 0.3

    def twin() -> Iterator[tuple[int, bytes, bool]]:
        for t, s in timed_samples(real):
            if isinstance(s, ImuSample):
                dt = s.dt_us * 1e-6
                s = dataclasses.replace(
                    s, t_us=s.t_us + 500, dtheta_x=s.dtheta_x + bg * dt,
                    dtheta_y=s.dtheta_y - bg * dt, dtheta_z=s.dtheta_z + bg * dt,
                    dvel_x=s.dvel_x + ba * dt, dvel_y=s.dvel_y + ba * dt,
                    dvel_z=s.dvel_z - ba * dt)
                yield t + 500, tx.highres_imu(s), True

    got, dec = _decode(_merged(mavlink_events(real, sysid=1), twin()))
    c = dec.counters.snapshot()
    assert c["imu_source_refused"] > 1000 and c.get("imu_source_contradicts", 0) == 0, c
    assert got == _decode(_merged(mavlink_events(real, sysid=1)))[0]


def test_relock_only_after_silence(real: SimRun, foreign: SimRun,
                                   caplog: pytest.LogCaptureFixture) -> None:
    """GIVEN the car from sysid 1 for 20 s, a foreign sysid 7 sending throughout,
    WHEN the car falls silent,
    THEN sysid 7 is refused until 5 s (relock_s) after the car's last sample, then takes
    over once (counted, logged)."""
    stop = 20_000_000
    mixed = _merged(((t, f, i) for t, f, i in mavlink_events(real, sysid=1) if t < stop),
                    _foreign_events(foreign, real))
    with caplog.at_level(logging.WARNING):
        got, dec = _decode(mixed)
    c = dec.counters.snapshot()
    assert c["imu_source_relock"] == 1 and c["gnss_source_relock"] == 1, c
    imu_t = [s.t_us for s in got if type(s).__name__ == "ImuSample"]
    after = [t for t in imu_t if t >= stop]
    assert after and stop + 5_000_000 <= after[0] <= stop + 5_100_000
    assert any("moves to sysid=7 compid=1" in r.getMessage() for r in caplog.records)


def test_source_lock_unit() -> None:
    """GIVEN a lock with relock 5 s,
    WHEN A delivers, B delivers, A goes silent 4.9 s, then 5 s,
    THEN A is locked, B refused (counted) until A's silence reaches 5 s; kinds are
    independent."""
    c = Counters()
    lock = SourceLock(5.0, Rejector(c, RateLimitedLog(logging.getLogger("t"), 0.0), "t"))
    assert lock.admit("imu", "A", 0) and not lock.admit("imu", "B", 1)
    assert lock.admit("gnss", "B", 2)  # another kind: its own lock
    assert lock.admit("imu", "A", 100)
    assert not lock.admit("imu", "B", 4_900_099)
    assert lock.admit("imu", "B", 5_000_100) and lock.locked("imu") == "B"
    assert not lock.admit("imu", "A", 5_000_200)
    assert c["imu_source_refused"] == 3 and c["imu_source_relock"] == 1
    with pytest.raises(ValueError):
        SourceLock(0.0, Rejector(c, RateLimitedLog(logging.getLogger("t"), 0.0), "t"))


def test_dronecan_node_lock(real: SimRun, foreign: SimRun) -> None:
    """GIVEN RawIMU/Fix2 transfers from node 42 (the car) and, from 1 s on, node 43 (another
    stretch of road),
    WHEN decoded with the default [dronecan] settings,
    THEN only node 42's samples come out, node 43 is refused for IMU and GNSS and its IMU
    contradicts node 42's."""
    cfg = load_daemon_config(None, ["dronecan.enabled=true", "dronecan.interface=virtual"])
    dec = DronecanDecoder(dronecan_bus_config(cfg.dronecan, warn_interval_s=5.0))
    ref = DronecanDecoder(dronecan_bus_config(cfg.dronecan, warn_interval_s=5.0))
    events = heapq.merge(((t, m, 42) for t, m, _ in dronecan_events(real, node_id=42)),
                         ((t - round(FOREIGN_OFFSET_S * 1e6) + 3_000, m, 43)
                          for t, m, _ in dronecan_events(foreign, node_id=43)
                          if t >= (FOREIGN_OFFSET_S + 1.0) * 1e6),
                         key=lambda e: e[0])
    got: list[Sample] = []
    want: list[Sample] = []
    for t, msgs, node in events:
        for m in msgs:
            got += dec.feed(m, t)
            if node == 42:
                want += ref.feed(m, t)
    assert got == want and len(got) > 1000
    c = dec.counters.snapshot()
    assert c["imu_source_refused"] > 1000 and c["gnss_source_refused"] > 100, c
    assert c["imu_source_contradicts"] >= 5, c
