"""The daemon's parts on their own: config sections, sd_notify, the queue, recordings, the
output schedule, latency statistics, the stream's timing."""

from __future__ import annotations

import asyncio
import logging
import math
import os
import socket
import tomllib
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import pytest
from daemon_util import ROOT, car_run

from firmware_sim.stream import mavlink_events, parse_udp_target, timed_samples
from navd.config import ConfigError, load_config, toml_keys
from navd.config.daemon import DaemonConfig, DaemonSection, MavlinkSection, ZenohSection
from navd.daemon.adapters import mavlink_input_config, zenoh_session_config
from navd.daemon.service import SdNotifier, watchdog_interval_s
from navd.daemon.sinks import LatencyStats
from navd.daemon.sources import Item, SampleQueue
from navd.diag import RateLimitedLog
from navd.io.mavlink import MavlinkDecoder
from navd.io.recording import RecordingReader, RecordingWriter
from navd.pipeline import OutputSchedule
from navd.types import FixType, GnssSample, ImuSample, PolSample

# -- config -----------------------------------------------------------------------------------


def test_built_in_defaults_stay_on_loopback() -> None:
    """GIVEN no config file, WHEN the daemon's config is built from the built-in defaults,
    THEN every socket it opens is on 127.0.0.1 and Zenoh does not scout multicast (a vehicle
    must not expose attitude on a network nobody configured)."""
    c = DaemonConfig.from_dict({})
    urls = [c.mavlink.listen, c.mavlink.send, *c.zenoh.listen, *c.zenoh.connect]
    assert urls and all("127.0.0.1" in u for u in urls), urls
    assert c.zenoh.multicast_scouting is False


def test_shipped_config_documents_every_daemon_key_with_the_defaults() -> None:
    """GIVEN the shipped config/navd.toml,
    WHEN its daemon sections are parsed and compared with the built-in defaults,
    THEN every section equals the default and lists exactly the section's keys."""
    doc = tomllib.loads((ROOT / "config" / "navd.toml").read_text())
    c = DaemonConfig.from_dict(doc)
    d = DaemonConfig.from_dict({})
    for name in ("daemon", "mavlink", "dronecan", "zenoh", "ros2", "bias_store"):
        assert getattr(c, name) == getattr(d, name), name
        assert set(doc[name]) == set(toml_keys(type(getattr(d, name)))), name


@pytest.mark.parametrize(("override", "message"), [
    ("mavlink.attitude_rate_hz=0", "[mavlink] attitude_rate_hz must be a rate in Hz"),
    ('mavlink.attitude_rate_hz="fast"', "[mavlink] attitude_rate_hz must be a number"),
    ("daemon.status_period_s=-1", "[daemon] status_period_s must be a number of seconds"),
    ("daemon.queue_size=1.5", "[daemon] queue_size must be an integer"),
    ("daemon.queue_sz=10", "[daemon] unknown key 'queue_sz'"),
    ("mavlnk.sysid=2", "unknown config section(s) ['mavlnk']"),
    ('mavlink.listen="udpin:localhost"', "[mavlink] listen: bad MAVLink address"),
    ("mavlink.allow=[[1]]", "[mavlink] allow must be a list of [int, int] pairs"),
    ('mavlink.imu_messages=["ATTITUDE"]', "unsupported: ['ATTITUDE']"),
    ("dronecan.node_id=0", "[dronecan] node_id must be an integer 1..127"),
    ('zenoh.vehicle="a/b"', "[zenoh] vehicle"),
    ("mavlink.enabled=false", "no input"),
    ("filter.mode=sideways", "[filter] mode"),  # the estimator's sections are checked too
])
def test_errors_name_section_key_and_unit(override: str, message: str) -> None:
    """GIVEN one bad config override (bad value, wrong type, unknown key or section,
    bad address, no input enabled, a bad estimator value),
    WHEN the daemon config is built from it,
    THEN ConfigError names the section, the key and what was expected."""
    with pytest.raises(ConfigError) as e:
        DaemonConfig.from_dict(load_config(None, [override]))
    assert message in str(e.value)


def test_sections_build_adapter_configs() -> None:
    """GIVEN MAVLink and Zenoh config sections (imu_id -1, nominal rate 0, an allow list),
    WHEN the adapter configs are built from them,
    THEN -1 and 0 become None, the allow list a set, Zenoh keeps vehicle and no
    multicast scouting; the default queue holds at least 16 samples."""
    m = mavlink_input_config(MavlinkSection(allow=((1, 1),), imu_id=-1, nominal_imu_rate=0.0,
                                            max_imu_gap=0.05))
    assert m.allow == frozenset({(1, 1)}) and m.imu_id is None
    assert m.nominal_imu_rate_hz is None and m.max_imu_gap_s == pytest.approx(0.05)
    z = zenoh_session_config(ZenohSection(vehicle="car7", listen=("tcp/127.0.0.1:9",)))
    assert z.vehicle == "car7" and not z.multicast_scouting
    assert DaemonSection().queue_size >= 16


# -- sd_notify --------------------------------------------------------------------------------


def _recv(sock: socket.socket) -> str:
    sock.settimeout(2.0)
    return sock.recv(4096).decode()


@pytest.mark.parametrize("abstract", [False, True])
def test_sd_notify_path_and_abstract_sockets(tmp_path: Path, abstract: bool) -> None:
    """GIVEN NOTIFY_SOCKET naming a path socket or an abstract (@) socket,
    WHEN the notifier sends ready, watchdog, a two-line status and stopping,
    THEN the socket receives READY=1 with STATUS, WATCHDOG=1, a one-line STATUS and
    STOPPING=1."""
    server = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    if abstract:
        name = f"navd-test-{os.getpid()}"
        server.bind("\0" + name)
        env = {"NOTIFY_SOCKET": "@" + name}
    else:
        path = str(tmp_path / "n")
        server.bind(path)
        env = {"NOTIFY_SOCKET": path}
    n = SdNotifier(env)
    try:
        assert n.enabled
        assert n.ready("up") and _recv(server) == "READY=1\nSTATUS=up"
        assert n.watchdog() and _recv(server) == "WATCHDOG=1"
        assert n.status("two\nlines") and _recv(server) == "STATUS=two lines"
        assert n.stopping() and _recv(server) == "STOPPING=1"
    finally:
        n.close()
        server.close()


def test_sd_notify_without_socket_is_a_no_op_and_never_raises(tmp_path: Path) -> None:
    """GIVEN no NOTIFY_SOCKET, or one naming a socket that does not exist,
    WHEN a notification is sent,
    THEN it returns False without raising, and the failed send is counted."""
    assert not SdNotifier({}).notify("READY=1")
    gone = SdNotifier({"NOTIFY_SOCKET": str(tmp_path / "missing")})
    assert gone.enabled and not gone.watchdog() and gone.errors == 1


def test_watchdog_interval_respects_watchdog_pid() -> None:
    """GIVEN WATCHDOG_USEC absent, zero, set, or set with WATCHDOG_PID,
    WHEN the watchdog interval is read,
    THEN it is None, None, the value in seconds, and the value only when the PID is ours."""
    assert watchdog_interval_s({}) is None
    assert watchdog_interval_s({"WATCHDOG_USEC": "0"}) is None
    assert watchdog_interval_s({"WATCHDOG_USEC": "4000000"}) == 4.0
    me = str(os.getpid())
    assert watchdog_interval_s({"WATCHDOG_USEC": "2000000", "WATCHDOG_PID": me}) == 2.0
    assert watchdog_interval_s({"WATCHDOG_USEC": "2000000", "WATCHDOG_PID": "1"}) is None


# -- queue, schedule, latency -----------------------------------------------------------------


def _imu(t_us: int) -> ImuSample:
    return ImuSample(t_us, 1000, 0.0, 0.0, 0.0, 0.0, 0.0, -0.0098)


def test_queue_drops_the_oldest_and_counts(caplog: pytest.LogCaptureFixture) -> None:
    """GIVEN a sample queue of 16 that is sent 40 samples, then closed and sent one more,
    WHEN it is drained,
    THEN the 24 oldest were dropped and counted, the newest 15 come out in order,
    the sample after close is ignored and "queue full" is logged once."""
    async def go() -> list[int]:
        q = SampleQueue(16, RateLimitedLog(logging.getLogger("t"), 60.0))
        for k in range(40):
            q.put(k, _imu(k + 1))
        assert q.drops == 24 and q.high_water == 16
        q.close()
        q.put(99, _imu(1000))  # after close: ignored
        got = []
        while (item := await q.get()) is not None:
            got.append(item[1].t_us)
        return got

    with caplog.at_level(logging.WARNING):
        got = asyncio.run(go())
    # the newest 15 survive (the closing marker took one slot), in order
    assert got == list(range(26, 41))
    assert len([r for r in caplog.records if "queue full" in r.message]) == 1


def _t(item: Item | None) -> int:
    assert item is not None and isinstance(item[1], ImuSample)
    return item[1].t_us


def test_queue_hands_items_direct_to_a_parked_consumer_in_order() -> None:
    """GIVEN a sample queue whose consumer names a direct handler and is parked in get(),
    WHEN samples are put from callbacks, one of them while the handler is running (it puts
    another), and one while items are already queued,
    THEN the handler takes them in the callback in put order, the one put during a
    handled item is queued (not handled inside it) and comes out of get() next, an item
    put behind queued ones waits its turn, and close() still ends the stream with None."""
    async def go() -> tuple[list[tuple[str, int]], list[int]]:
        q = SampleQueue(16, RateLimitedLog(logging.getLogger("t"), 60.0))
        seen: list[tuple[str, int]] = []

        def direct(item: Item) -> None:
            seen.append(("direct", _t(item)))
            if _t(item) == 2:
                q.put(0, _imu(3))  # put from inside a direct hand-off: queued

        q.direct = direct
        taken: list[int] = []

        async def consume() -> None:
            while (item := await q.get()) is not None:
                seen.append(("get", _t(item)))
                taken.append(_t(item))
                if _t(item) == 3:
                    # while the consumer is busy (not parked), puts are queued
                    q.put(0, _imu(4))
                    q.put(0, _imu(5))

        task = asyncio.get_running_loop().create_task(consume())
        await asyncio.sleep(0)  # the consumer parks
        loop = asyncio.get_running_loop()
        loop.call_soon(q.put, 0, _imu(1))
        loop.call_soon(q.put, 0, _imu(2))
        for _ in range(5):
            await asyncio.sleep(0)
        loop.call_soon(q.put, 0, _imu(6))
        await asyncio.sleep(0)
        q.close()
        await task
        return seen, taken

    seen, taken = asyncio.run(go())
    assert seen == [("direct", 1), ("direct", 2), ("get", 3), ("get", 4), ("get", 5),
                    ("direct", 6)]
    assert taken == [3, 4, 5]


def test_queue_direct_handler_failure_is_raised_in_the_consumer() -> None:
    """GIVEN a parked consumer whose direct handler raises on a sample,
    WHEN that sample is put,
    THEN the put returns (the producer's read goes on) and the consumer's get() raises the
    handler's exception, as if it had taken the item and failed on it."""
    async def go() -> None:
        q = SampleQueue(16, RateLimitedLog(logging.getLogger("t"), 60.0))

        def direct(item: Item) -> None:
            raise ZeroDivisionError("handler")

        q.direct = direct
        task = asyncio.get_running_loop().create_task(q.get())
        await asyncio.sleep(0)
        q.put(0, _imu(1))  # must not raise here
        with pytest.raises(ZeroDivisionError, match="handler"):
            await task

    asyncio.run(go())


def test_output_schedule_on_sensor_time() -> None:
    """GIVEN a 50 Hz output schedule,
    WHEN samples arrive every 10 ms, or at irregular times,
    THEN output is due on each 20 ms boundary of sensor time, or on the first sample
    at or past it; a rate of 0 is refused."""
    s = OutputSchedule(50.0)
    due = [t for t in range(0, 100_001, 10_000) if s.due(t)]
    assert due == [0, 20_000, 40_000, 60_000, 80_000, 100_000]
    s = OutputSchedule(50.0)
    # irregular samples: the first one at or past each 20 ms boundary (the first output
    # waits for the first boundary, so samples on the grid are output exactly on it)
    assert [t for t in (5_000, 19_999, 20_001, 39_000, 41_000, 95_000) if s.due(t)] == [
        20_001, 41_000, 95_000]
    with pytest.raises(ValueError):
        OutputSchedule(0.0)


def test_latency_stats_window_and_percentiles() -> None:
    """GIVEN latency statistics with a window of 100 and latencies of 1..250 us,
    WHEN the summary is taken,
    THEN it counts all 250 and takes p50, p99 and max over the last 100 only;
    with no data it reports n = 0."""
    st = LatencyStats(window=100)
    assert st.summary() == {"n": 0}
    for k in range(1, 251):
        st.add(k * 1000)  # 1..250 us
    s = st.summary()
    assert s["n"] == 250 and s["window"] == 100
    assert s["p50_us"] == 201.0 and s["p99_us"] == 250.0 and s["max_us"] == 250.0


# -- recordings -------------------------------------------------------------------------------


def test_recording_round_trip_is_exact(tmp_path: Path) -> None:
    """GIVEN IMU, GNSS and polarization samples with NaN, inf, -0.0 and missing ECEF,
    WHEN they are written to a recording and read back,
    THEN config, output rate and every sample come back exactly; a recording cut short
    ends one sample early without raising and reports the truncated bytes."""
    samples = [
        _imu(1000),
        ImuSample(2000, 1000, 1e-300, -0.0, math.nan, math.inf, 0.1 + 0.2, -1.5e-7),
        GnssSample(1500, 0.6, 1.9, 400.123456789, 1.0, 2.0, math.nan, 1.5, 2.5, 0.1,
                   FixType.RTK_FIXED, (1.0, 2.0, 3.0), (0.1, 0.2, 0.3)),
        GnssSample(2500, -0.6, -1.9, -10.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
        GnssSample(3500, 0.1, 0.2, 3.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0, FixType.FIX_3D, None,
                   (4.0, 5.0, 6.0)),
        PolSample(4000, 1.25, 0.6, 1.7e9),
    ]
    path = tmp_path / "r.navdrec"
    w = RecordingWriter(path, {"filter": {"mode": "completed"}}, 25.0)
    for s in samples:
        w.write(s)
    w.close()
    r = RecordingReader(path)
    assert r.config == {"filter": {"mode": "completed"}} and r.output_rate_hz == 25.0
    got = list(r.samples())
    assert len(got) == len(samples) and r.truncated_bytes == 0
    for a, b in zip(got, samples, strict=True):
        assert type(a) is type(b)
        assert repr(a) == repr(b)  # repr: NaN == NaN, -0.0 != 0.0
    # a record cut short (daemon killed mid-write) ends the stream without raising
    path.write_bytes(path.read_bytes()[:-5])
    r = RecordingReader(path)
    assert len(list(r.samples())) == len(samples) - 1 and r.truncated_bytes > 0


def test_recording_refuses_an_unrepresentable_sample_and_stays_valid(tmp_path: Path) -> None:
    """GIVEN a recording being written,
    WHEN samples whose time does not fit the record format are written between valid ones,
    THEN each is refused with RecordingError and the file still reads back the valid ones."""
    from navd.io.recording import RecordingError

    path = tmp_path / "r.navdrec"
    w = RecordingWriter(path, {}, 50.0)
    w.write(_imu(1000))
    for bad in (_imu((1 << 63) + 1),
                GnssSample((1 << 64) - 1, 0.6, 1.9, 400.0, 0.0, 0.0, 0.0, 1.0, 1.0, 0.1)):
        with pytest.raises(RecordingError, match="cannot record"):
            w.write(bad)
    w.write(_imu(2000))
    w.close()
    r = RecordingReader(path)
    assert [s.t_us for s in r.samples()] == [1000, 2000] and r.truncated_bytes == 0


def test_daemon_survives_a_recording_it_cannot_write(caplog: pytest.LogCaptureFixture) -> None:
    """GIVEN a daemon recording to /dev/full (disk full),
    WHEN it records an unpackable sample and then samples until the write fails,
    THEN both errors are counted, the unpackable one is skipped, the full disk stops the
    recording with the reason in status and a warning, and no error escapes the daemon."""
    from navd.config.daemon import load_daemon_config
    from navd.daemon.daemon import Daemon

    cfg = load_daemon_config(None, ["zenoh.enabled=false",
                                    "daemon.warm_up=false"])
    d = Daemon(cfg, record_path="/dev/full", handle_signals=False)
    d.recorder = RecordingWriter("/dev/full", {}, 50.0)
    d._record(_imu((1 << 63) + 1))  # cannot be packed: skipped, counted
    assert d.record_errors == 1 and d.recorder is not None
    with caplog.at_level(logging.WARNING):
        for k in range(1, 5000):  # fills the write buffer: ENOSPC
            d._record(_imu(k * 1000))
            if d.recorder is None:
                break
    assert d.recorder is None and d.record_errors == 2
    assert "No space left" in d.status()["recording"]["stopped"]
    assert any("recording /dev/full stopped" in r.message for r in caplog.records)
    d._close()


def test_reader_refuses_a_file_that_is_not_a_recording(tmp_path: Path) -> None:
    """GIVEN a file that is a CSV, not a recording,
    WHEN a RecordingReader opens it,
    THEN RecordingError is raised."""
    from navd.io.recording import RecordingError

    p = tmp_path / "x"
    p.write_bytes(b"t_us,dt_us\n")
    with pytest.raises(RecordingError):
        RecordingReader(p)


# -- the stream's timing ----------------------------------------------------------------------


def test_stream_sends_gnss_at_arrival_with_time_of_validity() -> None:
    """GIVEN a 3 s car run with 50 ms GNSS latency,
    WHEN the simulator's stream is timed and encoded as MAVLink,
    THEN events are in time order, each fix is sent 50 ms after its time of validity and
    decodes to that time; UDP targets without a host are refused."""
    run = car_run(3.0, **{"gnss.latency_s": 0.05})
    events = list(timed_samples(run))
    times = [t for t, _ in events]
    assert times == sorted(times)
    gnss = [(t, s) for t, s in events if isinstance(s, GnssSample)]
    assert gnss and all(t == s.t_us + 50_000 for t, s in gnss)
    # on the wire: a GPS_INPUT decodes to the time of validity, not the send time
    dec = MavlinkDecoder()
    decoded = [s for _, frame, _ in mavlink_events(run) for s in dec.feed_datagram(frame, 0)]
    fixes = [s for s in decoded if isinstance(s, GnssSample)]
    assert [f.t_us for f in fixes] == [s.t_us for _, s in gnss]
    assert parse_udp_target("udp:127.0.0.1:14560") == ("127.0.0.1", 14560)
    with pytest.raises(ValueError):
        parse_udp_target("udp:14560")


def test_polarization_readings_stream_over_mavlink_into_the_estimator() -> None:
    """GIVEN a 20 s pol_moving run streamed as MAVLink,
    WHEN it is decoded with polarization off, then on, and pushed into the estimator,
    THEN off: the private message is only counted as unknown; on: every reading arrives
    as sent and most are fused."""
    from firmware_sim import generate, load_scenario
    from navd.io.mavlink import MavlinkInputConfig
    from navd.pipeline import build_estimator

    run = generate(load_scenario("pol_moving", overrides={"duration_s": 20.0}), seed=1)
    frames = [f for _, f, _ in mavlink_events(run)]
    ref = list(run.pol_samples())
    # off by default: the private message is an unknown frame, counted, never a sample
    off = MavlinkDecoder()
    assert not [s for f in frames for s in off.feed_datagram(f, 0)
                if isinstance(s, PolSample)]
    assert off.counters["unknown_msgid"] >= len(ref)
    on = MavlinkDecoder(MavlinkInputConfig(polarization=True))
    tables = load_config(None, ["polarization.enabled=true", "mavlink.polarization=true",
                                "polarization.mount_roll_deg=0", "polarization.mount_pitch_deg=0",
                                "polarization.mount_yaw_deg=0"])
    assert mavlink_input_config(DaemonConfig.from_dict(tables).mavlink).polarization
    est = build_estimator(tables)
    _push_and_compare(est, (s for f in frames for s in on.feed_datagram(f, 0)), ref)
    assert on.counters["pol_ok"] == len(ref) and on.counters["unknown_msgid"] == 0


def test_polarization_readings_over_dronecan_into_the_estimator() -> None:
    """GIVEN a 20 s pol_moving run streamed as DroneCAN (navd's private SkyPolarization),
    WHEN the frames are decoded and pushed into the estimator,
    THEN every reading arrives as sent, is counted pol_ok, and most are fused."""
    from firmware_sim import generate, load_scenario
    from firmware_sim.stream import dronecan_events
    from navd.io.dronecan import DronecanConfig, DronecanDecoder
    from navd.pipeline import build_estimator

    run = generate(load_scenario("pol_moving", overrides={"duration_s": 20.0}), seed=1)
    ref = list(run.pol_samples())
    tables = load_config(None, ["polarization.enabled=true", "polarization.mount_roll_deg=0",
                                "polarization.mount_pitch_deg=0",
                                "polarization.mount_yaw_deg=0"])
    est = build_estimator(tables)
    dec = DronecanDecoder(DronecanConfig(interface="virtual", nominal_imu_rate_hz=100.0))
    _push_and_compare(est, (s for _, frames, _ in dronecan_events(run) for f in frames
                            for s in dec.feed(f, 0)), ref)
    assert dec.counters["pol_ok"] == len(ref)


def _push_and_compare(est: Any, decoded: Iterable[Any], ref: list[PolSample]) -> None:
    """Push every decoded sample; the readings must be the sent ones, and fused."""
    got = []
    for s in decoded:
        est.push(s)
        if isinstance(s, PolSample):
            got.append(s)
    assert [s.t_us for s in got] == [s.t_us for s in ref]
    assert all(abs(a.aop_rad - b.aop_rad) < 1e-6 for a, b in zip(got, ref, strict=True))
    assert est.counters["pol_accepted"] > 0.9 * len(ref)


def test_a_clean_static_run_raises_no_refusal_warnings() -> None:
    """GIVEN a clean 60 s static run (the vehicle parked),
    WHEN the estimator processes it,
    THEN the heading hold is active and no counter counts as a refusal: normal work,
    the heading hold at rest among it, must not be logged as refused input."""
    from firmware_sim import generate, load_scenario
    from navd.config import EstimatorConfig
    from navd.core.estimator import Estimator
    from navd.daemon.daemon import _is_refusal

    run = generate(load_scenario("static", {"duration_s": 60.0}), seed=1, progress=False)
    est = Estimator(EstimatorConfig.from_dict(load_config(None, [])))
    for s in run.samples():
        est.push(s)
    assert est.counters["heading_held"] > 50 and est.heading_held
    assert {k: v for k, v in est.counters.items() if _is_refusal(k)} == {}


def test_adapters_refuse_what_the_estimator_would_refuse() -> None:
    """GIVEN ``[imu] max_rate_dps = 100`` (a gyro whose full scale is 100 deg/s),
    WHEN the daemon's MAVLink decoder meets a HIGHRES_IMU sample turning at 150 deg/s,
    THEN it refuses it at the wire as ``imu_absurd_gyro``, with the estimator's limit."""
    from pymavlink.dialects.v20 import ardupilotmega as mav

    from navd.core.plausible import Limits
    from navd.io.mavlink import MavlinkDecoder

    tables = load_config(None, ["imu.max_rate_dps=100"])
    cfg = DaemonConfig.from_dict(tables)
    dec = MavlinkDecoder(mavlink_input_config(cfg.mavlink, Limits.from_config(cfg.estimator.imu)))
    enc = mav.MAVLink(None, 1, 1)
    w = math.radians(150.0)
    frames = [enc.highres_imu_encode(t, 0, 0, -9.8, 0, 0, w, 0, 0, 0, 0, 0, 0, 0, 0xFFFF
                                     ).pack(enc) for t in (1000, 3000)]
    for f in frames:
        dec.feed_datagram(f, 0)
    assert dec.counters["imu_absurd_gyro"] == 2
    # the built-in limit (2000 deg/s) passes the same samples
    dec = MavlinkDecoder(mavlink_input_config(cfg.mavlink))
    for f in frames:
        dec.feed_datagram(f, 0)
    assert dec.counters["imu_absurd_gyro"] == 0


def test_daemon_warns_once_when_the_autopilot_is_a_boat_and_navd_runs_a_car(
        caplog: pytest.LogCaptureFixture) -> None:
    """GIVEN a daemon with the default (ground) profile whose MAVLink input decoded the
    HEARTBEATs of a ground station (GCS, no autopilot) and of the flight controller that
    sends the IMU, an ArduPilot SURFACE_BOAT,
    WHEN the status loop checks them (twice),
    THEN one warning names the boat profile and the setting; with the boat profile
    configured, none; with only the ground station's heartbeat, none."""
    from pymavlink.dialects.v20 import common as mav

    from navd.config.daemon import load_daemon_config
    from navd.daemon.daemon import Daemon
    from navd.daemon.sources import MavlinkInput

    def beats(*who: tuple[int, int, int, int]) -> MavlinkDecoder:
        dec = MavlinkDecoder()
        for sysid, compid, mav_type, autopilot in who:
            enc = mav.MAVLink(None, sysid, compid)
            dec.feed(enc.heartbeat_encode(mav_type, autopilot, 0, 0, 4).pack(enc), 0)
        return dec

    boat = (1, 1, mav.MAV_TYPE_SURFACE_BOAT, mav.MAV_AUTOPILOT_ARDUPILOTMEGA)
    gcs = (255, 190, mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID)
    for profile, who, warned in (("ground", (gcs, boat), 1), ("boat", (gcs, boat), 0),
                                 ("ground", (gcs,), 0)):
        cfg = load_daemon_config(None, ["zenoh.enabled=false", "daemon.warm_up=false",
                                        f"filter.profile={profile}"])
        d = Daemon(cfg, handle_signals=False)
        inp = MavlinkInput(cfg)
        inp.decoder = beats(*who)
        d.sources.inputs[MavlinkInput.kind] = inp
        caplog.clear()
        with caplog.at_level(logging.WARNING):
            d._check_vehicle()
            d._check_vehicle()
        said = [r.message for r in caplog.records if "fits [filter] profile" in r.message]
        assert len(said) == warned, (profile, said)
        if warned:
            assert 'profile = "boat"' in said[0] and "SURFACE_BOAT" in said[0], said
        d._close()


def test_an_adaptive_counter_says_what_it_means_a_refusal_names_itself() -> None:
    """GIVEN the estimator counters the daemon warns about when they grow,
    THEN an adaptive or diagnostic one (course_not_heading, gyro_bias_corrections_high) is
    followed by what it means and what to do, a refusal (vel_rejected) is its name alone, and
    every counter with words is one the estimator really counts (a misspelt key would never
    be explained)."""
    import re

    from navd.daemon.daemon import _EST_WORDS, counter_warning

    line = counter_warning("course_not_heading", 1, 1)
    assert line.startswith("estimator: course_not_heading +1 (total 1): ")
    assert 'profile = "boat"' in line
    assert "vibration" in counter_warning("gyro_bias_corrections_high", 2, 5)
    assert counter_warning("vel_rejected", 3, 7) == "estimator: vel_rejected +3 (total 7)"
    src = "".join(p.read_text() for p in (ROOT / "navd" / "core").rglob("*.py"))
    # every quoted name inside counters[...], also those picked by an expression
    counted = {w for e in re.findall(r"counters\[([^\]]+)\]", src)
               for w in re.findall(r'"(\w+)"', e)}
    assert set(_EST_WORDS) <= counted, set(_EST_WORDS) - counted
