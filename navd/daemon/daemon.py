"""The daemon: sources -> bounded queue -> estimator task -> sinks, as a systemd service.

One ``asyncio.TaskGroup`` holds four tasks:

estimator  the queue's only consumer: passes each sample through the clock guard
           (:mod:`navd.core.clock_guard`), records it, pushes it into the estimator
           (sensor time only) and, right after a push that carried the state past a sink's
           next output instant, hands that sink the solution and notes the latency from the
           packet's host receive time to the send.  While it waits on an empty queue the
           same handling runs in the read's callback (``SampleQueue.direct``).
status     every ``status_period_s``: Zenoh status, sd_notify STATUS, rate-limited warnings
           for what the estimator refused, an info line every ``log_period_s``.
watchdog   WATCHDOG=1 every half ``WATCHDOG_USEC``, only while outputs are produced
           (sensor time moved and, once navigating, a solution went out since the last
           tick): stalled input, a stuck estimator or failing outputs let systemd restart us.
heartbeat  MAVLink HEARTBEAT, system_status from :data:`HEALTH`.

Start: warm the estimator's JIT kernels, open sinks, open sources, READY=1.  Stop (SIGTERM,
SIGINT): STOPPING=1, stop accepting input, let the estimator drain what is queued, close
everything, log the final statistics, exit 0.  An unexpected error in any task ends the group
and exits 1 (``Restart=on-failure``).  Configuration: :mod:`navd.config.daemon`.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import errno
import json
import logging
import math
import re
import signal
import time
from collections.abc import Sequence
from typing import Any

from navd.config import ConfigError
from navd.config.aiding import NavConfig
from navd.config.daemon import DaemonConfig
from navd.core._jit import aot_status, describe_status
from navd.core.aiding.dov import dov_status
from navd.core.aot_build import exercise_lane
from navd.core.clock_guard import ClockGuard
from navd.core.imu_block import ImuBlock
from navd.daemon import bias_store
from navd.daemon.adapters import zenoh_session_config
from navd.daemon.service import SdNotifier, watchdog_interval_s
from navd.daemon.sinks import (
    MAV_STATE_ACTIVE,
    MAV_STATE_CRITICAL,
    MAV_STATE_EMERGENCY,
    MAV_STATE_POWEROFF,
    MAV_STATE_STANDBY,
    AutopilotSink,
    DronecanSink,
    FoxgloveSink,
    MavlinkSink,
    Ros2Sink,
    Sink,
    ZenohSink,
)
from navd.daemon.sources import InputOpenError, Item, SampleQueue, Sources
from navd.diag import RateLimitedLog
from navd.io.common import Sample
from navd.io.mavlink import MavlinkEncoder, MavlinkLink
from navd.io.mavlink.autopilot import AutopilotPolicy, HeadingResetSchedule
from navd.io.read_pacing import ReadPacer
from navd.io.recording import RecordingError, RecordingWriter
from navd.io.zenoh import ZenohPublisher, attitude_key, status_key
from navd.pipeline import build_estimator, output_instant
from navd.types import GnssSample, ImuSample, NavSolution

__all__ = ["Daemon", "StartupError", "counter_warning", "explain_open_error", "warm_up"]

_log = logging.getLogger("navd")

# Estimator counters that count normal work or a standing condition of the setup (a receiver
# without vertical velocity, a DOV grid that ends): informational.  Every other counter
# that grows is a refusal of input and gets a (rate-limited) warning.
_INFO_COUNTERS = frozenset({"imu", "gnss", "nav_start", "heading_aligned_from_course",
                            "heading_yaw_from_course", "heading_yaw_observable",
                            "heading_aligned_by_observability", "gnss_delayed", "pol_delayed",
                            "gnss_no_velocity", "dov_off_grid", "heading_held",
                            "yaw_bank_tilt_held"})


_CLOCK_WORDS = {
    "clock_wild": "IMU samples off the current sensor clock, held until a new clock is "
                  "confirmed (a single wild time stamp never restarts navigation)",
    "clock_dropped": "held samples of a clock that did not go on, dropped",
    "clock_out_of_range": "time stamps outside (0, 2**53) us, refused",
}


# What the estimator's adaptive and diagnostic counters mean, for the operator's log line
# (the refusals name themselves: "vel_rejected", "gnss_absurd_jump").
_EST_WORDS = {
    "course_not_heading": "the GNSS course keeps leaving the heading as a water current or a "
                          "crab would: on a boat run [filter] profile = \"boat\"",
    "course_not_heading_imu": "the IMU's accelerations put its heading off the GNSS "
                              "course: the IMU is turned on the vehicle (status "
                              "imu_yaw_on_vehicle_deg; set [imu] mount_yaw_deg to it); "
                              "until then that angle is learnt, the course holds the "
                              "heading of the IMU's axes by it, and the attitude is the "
                              "IMU's",
    "gyro_bias_corrections_high": "the gyro-bias estimates moved more than their covariance "
                                  "allows (a gyro error wandering within seconds, e.g. "
                                  "vibration aliased into rate samples): bias walk raised",
    "bias_q_up": "the velocity innovations persist: gyro-bias random walk raised",
    "tilt_split_reopened": "a tilt error hidden in the accelerometer bias is suspected: "
                           "both widened",
    "q_scale_up": "the IMU is noisier than configured: its noise densities raised",
    "gyro_noise_up": "the GNSS course keeps its sign for seconds against the heading: the "
                     "gyro is noisier than configured where the filter integrates it (e.g. "
                     "vibration aliased into rate samples): its noise density raised",
    "r_scale_up": "the GNSS velocity is noisier than the receiver reports: its sigma raised",
    "course_noise_up": "the GNSS course wanders against the gyro-integrated heading for "
                       "seconds (a slip of its own: loose ground, skid steering): the course "
                       "rows' variance raised",
    "reversing_long": "moving backwards for longer than [heading] max_reverse_s while the "
                      "IMU's accelerations confirm the heading: a long reverse, or an IMU "
                      "mounted backwards on the vehicle (then set [imu] mount_yaw_deg = 180; "
                      "until then heading and attitude are the IMU's)",
    "heading_course_behind": "a heading set from the GNSS course took the course + 180 deg: "
                             "the IMU's accelerations said the vehicle backs up",
}


def counter_warning(name: str, grew: int, total: int) -> str:
    """The log line for an estimator counter that grew: its name, the growth, the total and,
    for the adaptive and diagnostic counters, what it means."""
    words = _EST_WORDS.get(name)
    line = f"estimator: {name} +{grew} (total {total})"
    return f"{line}: {words}" if words else line


def _is_refusal(counter: str) -> bool:
    return counter not in _INFO_COUNTERS and not counter.endswith("_accepted")


# " at /root/.cargo/.../tcp.rs:61." in Zenoh's errors: where in Zenoh's Rust source, which
# tells an operator nothing
_RUST_SOURCE = re.compile(r"\s*at /\S+\.rs:\d+\.?")


class StartupError(Exception):
    """An input or output could not be opened; the message names the setting and the fix."""


def explain_open_error(key: str, value: object, exc: BaseException) -> str:
    """One line for an input/output that failed to open: the setting (``section.key``), its
    value, the cause without Rust source paths, and what to do about it."""
    cause = _RUST_SOURCE.sub("", str(exc)).strip() or type(exc).__name__
    # uvloop wraps the OS error ("could not bind to local_addr ..."): its errno is the cause's
    err: int | None = None
    e: BaseException | None = exc
    while e is not None and err is None:
        err = getattr(e, "errno", None)
        if err is not None and (strerror := getattr(e, "strerror", None)) and strerror not in cause:
            cause = f"{cause} ({strerror})"
        e = e.__cause__
    section, name = key.split(".", 1)
    text = f"[{section}] {name} = {value!r}: cannot open: {cause}"
    in_use = err == errno.EADDRINUSE or "address already in use" in cause.lower()
    if in_use:
        return (f"{text}. The port is in use (another navd, or another program): stop it, "
                f"or give a free port with --set {key}=... (or in the config file)")
    if err in (errno.EADDRNOTAVAIL, errno.ENOENT, errno.EACCES):
        return (f"{text}. Check the address/device and its permissions; change it with "
                f"--set {key}=... (or in the config file)")
    return f"{text}. Change it with --set {key}=... (or in the config file)"


# no sensor-time progress for this long (host time) means the input has stalled
_STALL_S = 1.0

GNSS_LOST = "coasting (GNSS lost)"
GNSS_LOCKED_OUT = "coasting (GNSS locked out)"
NO_OUTPUT = "navigating, no output"
# What each state means, as HEARTBEAT's system_status and in words (the Zenoh status
# "health"; docs/daemon.md "Health").  ACTIVE only while solutions aided by GNSS go out;
# CRITICAL: still navigating, on the IMU alone; EMERGENCY: navd does not do its job.
HEALTH: dict[str, tuple[int, str, str]] = {
    "waiting for IMU": (MAV_STATE_STANDBY, "STANDBY", "no IMU data yet; no output"),
    "initializing": (MAV_STATE_STANDBY, "STANDBY",
                     "levelling / waiting for agreeing GNSS fixes; no output yet"),
    "navigating": (MAV_STATE_ACTIVE, "ACTIVE", "solutions go out, GNSS positions fused"),
    GNSS_LOST: (MAV_STATE_CRITICAL, "CRITICAL",
                "no GNSS fix for gnss_timeout_s: attitude and position from the IMU alone, "
                "heading and position drift"),
    GNSS_LOCKED_OUT: (MAV_STATE_CRITICAL, "CRITICAL",
                      "GNSS fixes arrive but no position was fused for gnss_timeout_s (the "
                      "gate refuses them): coasting on the IMU"),
    NO_OUTPUT: (MAV_STATE_EMERGENCY, "EMERGENCY",
                "navigating but no solution published (every output failing)"),
    "stalled": (MAV_STATE_EMERGENCY, "EMERGENCY",
                "sensor time stopped moving (input stopped): no output"),
    "stopping": (MAV_STATE_POWEROFF, "POWEROFF", "shutting down"),
}


def warm_up(nav: NavConfig) -> float:
    """Drive a throwaway estimator through 4 s of synthetic straight driving; return seconds.

    Compiles (or loads from numba's cache) every kernel the first real samples would need,
    before READY=1: otherwise the first fix stalls the input for 10-20 s on a cold cache,
    and systemd's watchdog starts counting at READY.  Fixes arrive 50 ms late, so the
    delayed-fix path is exercised too.
    """
    t0 = time.perf_counter()
    est = build_estimator(nav)
    dt_us, speed, lat0, lon0, r_earth = 10_000, 10.0, 0.6, 1.9, 6.37e6
    for k in range(1, 401):
        t_us = k * dt_us
        est.push(ImuSample(t_us, dt_us, 0.0, 0.0, 0.0, 0.0, 0.0, -9.8 * dt_us * 1e-6))
        if k % 10 == 5 and k > 10:
            tv = t_us - 50_000
            est.push(GnssSample(tv, lat0 + speed * tv * 1e-6 / r_earth, lon0, 400.0, speed,
                                0.0, 0.0, 2.0, 3.0, 0.1))
    est.solution()
    exercise_lane(est, est.t_us)  # the UDP batch lane's kernels
    return time.perf_counter() - t0


class Daemon:
    """The running daemon.  ``await run()`` until :meth:`stop` (or a signal); returns the
    exit code.  ``extra_sinks`` receive solutions like the configured ones (tests, embedding).
    """

    def __init__(self, cfg: DaemonConfig, *, record_path: str | None = None,
                 notifier: SdNotifier | None = None, extra_sinks: Sequence[Sink] = (),
                 handle_signals: bool = True, mcap_path: str | None = None,
                 mcap_rate_hz: float = 10.0) -> None:
        tables, self.bias_store_state = bias_store.apply(cfg.tables, cfg.bias_store,
                                                         cfg.estimator.imu, time.time())
        if self.bias_store_state.startswith("refused"):
            _log.warning("learned IMU biases %s", self.bias_store_state)
        elif cfg.bias_store.path:
            _log.info("learned IMU biases: %s", self.bias_store_state)
        if tables is not cfg.tables:  # the estimator and any recording see the biases used
            cfg = dataclasses.replace(cfg, tables=tables, nav=NavConfig.from_tables(tables))
        self.cfg = cfg
        self.est = build_estimator(cfg.nav)
        # only a sustained, consistent new sensor clock may restart navigation (issue 19)
        self.clock_guard = ClockGuard(max_gap_us=round(cfg.estimator.filter.max_imu_gap * 1e6))
        self.notifier = notifier if notifier is not None else SdNotifier()
        self.rlog = RateLimitedLog(_log, cfg.daemon.warn_interval)
        self.queue = SampleQueue(cfg.daemon.queue_size, self.rlog)
        self.sources = Sources(cfg, self.queue)
        self.sinks: list[Sink] = []
        self.mavlink_sink: MavlinkSink | None = None
        self.autopilot_sink: AutopilotSink | None = None
        self.zenoh_sink: ZenohSink | None = None
        self.mcap_sink: FoxgloveSink | None = None
        self.foxglove_sink: FoxgloveSink | None = None
        self.mcap_path = mcap_path
        self.mcap_rate_hz = mcap_rate_hz
        self.recorder: RecordingWriter | None = None
        self.record_path = record_path
        self.record_stopped = ""  # why recording stopped early, if it did
        self.sink_errors = 0
        self.record_errors = 0
        self._extra = list(extra_sinks)
        self._handle_signals = handle_signals
        self._stop = asyncio.Event()
        self.ready = asyncio.Event()  # set once the inputs are open (READY=1)
        self.stop_reason = ""
        self._t0 = time.monotonic()
        self._progress_t_us = -1
        self._progress_at = time.monotonic()
        self._rate_prev: tuple[float, int, int] = (self._t0, 0, 0)
        self.rates_hz = {"imu": 0.0, "gnss": 0.0}
        # what the last estimator restart was (status "restart"); None: it never restarted
        self.last_restart: dict[str, Any] | None = None
        # host times of the last published solution and of the start of navigation: "navigating"
        # (HEARTBEAT ACTIVE) needs outputs actually going out, not just a navigating estimator
        self._output_at = -math.inf
        self._vehicle_told = False  # _check_vehicle warned
        self._nav_since = -math.inf
        self._output_t_us = -1  # sensor time of the last published solution
        # sensor times at which a valid GNSS fix last reached the estimator (counter "gnss")
        # and a GNSS position was last fused ("pos_accepted"); -1: not since this start
        self._gnss_seen_t_us = -1
        self._pos_fused_t_us = -1
        self._gnss_counts = (0, 0)
        # the estimator task's state (_estimate): the restart count it last saw, whether it
        # has seen the estimator navigate, and when a sink may next be due (_outputs)
        self._restarts_seen = 0
        self._navigating = False
        self._quiet_until, self._quiet_epoch = -1, 0

    # -- life cycle ---------------------------------------------------------------------------

    def stop(self, reason: str = "requested") -> None:
        """Begin a clean shutdown (idempotent; safe from a signal handler)."""
        if self._stop.is_set():
            return
        self.stop_reason = reason
        self.notifier.stopping(f"stopping ({reason})")
        _log.info("stopping (%s): draining %d queued samples", reason, self.queue.qsize())
        self._stop.set()

    async def run(self) -> int:
        if self.cfg.daemon.warm_up:
            _log.info("estimator kernels ready in %.1f s", warm_up(self.cfg.nav))
            kernels = aot_status()  # prebuilt at install, or compiled now (stale, absent)
            _log.log(logging.WARNING if kernels["state"] == "stale" else logging.INFO, "%s",
                     describe_status(kernels))
        try:
            inputs = await self._open()
        except StartupError as exc:  # says which setting and what to do
            _log.error("startup failed: %s", exc)
            self._close()
            return 1
        except Exception as exc:  # any failure to open is fatal and must say what failed
            _log.error("startup failed: %s: %s", type(exc).__name__, exc)
            self._close()
            return 1
        loop = asyncio.get_running_loop()
        signals = (signal.SIGTERM, signal.SIGINT) if self._handle_signals else ()
        for sig in signals:
            loop.add_signal_handler(sig, self.stop, sig.name)
        self.notifier.ready(f"ready; inputs: {', '.join(inputs)}")
        self.ready.set()
        _log.info("ready: inputs %s; outputs %s", ", ".join(inputs) or "none",
                  "; ".join(self.output_destinations()) or "none")
        rc = 0
        try:
            async with asyncio.TaskGroup() as tg:
                consumer = tg.create_task(self._estimate(), name="estimator")
                helpers = [tg.create_task(self._status_loop(), name="status")]
                wd = watchdog_interval_s()
                if wd is not None and self.cfg.daemon.watchdog and self.notifier.enabled:
                    helpers.append(tg.create_task(self._watchdog_loop(wd), name="watchdog"))
                hb = self.cfg.mavlink.heartbeat_period
                if self.mavlink_sink is not None and hb > 0.0:
                    helpers.append(tg.create_task(
                        self.mavlink_sink.run_heartbeat(hb, self._mav_state), name="heartbeat"))
                await self._stop.wait()
                self.queue.close()
                await consumer  # drains the queue
                for t in helpers:
                    t.cancel()
        except Exception as exc:  # an ExceptionGroup from the task group: a bug, restart us
            _log.error("fatal: %s", exc, exc_info=exc)
            rc = 1
        finally:
            for sig in signals:
                loop.remove_signal_handler(sig)
            self._finish()
        return rc

    async def _open(self) -> list[str]:
        c = self.cfg
        if c.zenoh.enabled:
            try:
                zcfg = zenoh_session_config(c.zenoh)
            except ConfigError as exc:
                raise StartupError(str(exc)) from exc
            try:
                session = ZenohPublisher(zcfg)
            except Exception as exc:  # zenoh.ZError: listen/connect endpoints
                key = "zenoh.listen" if c.zenoh.listen else "zenoh.connect"
                raise StartupError(explain_open_error(
                    key, list(c.zenoh.listen or c.zenoh.connect), exc)) from exc
            self.zenoh_sink = ZenohSink(session, c.zenoh.attitude_rate,
                                        c.nav.estimator.init.aligned_sd)
        try:
            inputs = await self.sources.open()
        except InputOpenError as exc:
            section, name = exc.config_key.split(".", 1)
            value = getattr(getattr(c, section), name, "?")
            raise StartupError(explain_open_error(exc.config_key, value, exc.cause)) from exc
        m = c.mavlink
        if m.enabled and m.send:
            shared = m.send == "same"
            try:
                link = self.sources.mavlink if shared else await MavlinkLink.open(m.send)
            except Exception as exc:
                raise StartupError(explain_open_error("mavlink.send", m.send, exc)) from exc
            assert link is not None  # config validation: "same" needs a listen link
            encoder = MavlinkEncoder(m.sysid, m.compid, m.geoid_sep)
            self.mavlink_sink = MavlinkSink(
                link, encoder, m.attitude_rate,
                quaternion=m.attitude_quaternion, global_position=m.global_position,
                own_link=not shared)
            if c.autopilot.any:
                self.autopilot_sink = self._autopilot_sink(link, encoder)
        sinks: list[Sink] = [self.mavlink_sink] if self.mavlink_sink is not None else []
        if self.autopilot_sink is not None:
            sinks.append(self.autopilot_sink)
        d = c.dronecan
        if d.enabled and d.solution_out and self.sources.dronecan is not None:
            from navd.io.dronecan import DronecanEncoder  # only with DroneCAN (sources.py)

            sinks.append(DronecanSink(self.sources.dronecan, DronecanEncoder(d.node_id),
                                      d.solution_rate))
        if self.zenoh_sink is not None:
            sinks.append(self.zenoh_sink)
            if c.ros2.enabled:  # config validation: [ros2] needs [zenoh]
                sinks.append(Ros2Sink(self.zenoh_sink.publisher.session, c.ros2,
                                      c.nav.estimator.init.aligned_sd))
        if self.mcap_path:
            from navd.io.foxglove_mcap import NavMcapWriter  # mcap only with --mcap (issue 18)

            try:
                writer = NavMcapWriter(self.mcap_path, aligned_sd_rad=c.nav.estimator.init
                                       .aligned_sd, status=True)
            except OSError as exc:
                raise StartupError(f"--mcap {self.mcap_path}: cannot write: "
                                   f"{exc.strerror or exc} (does its directory exist?)"
                                   ) from exc
            self.mcap_sink = FoxgloveSink(writer, self.mcap_rate_hz, "mcap")
            sinks.append(self.mcap_sink)
        f = c.foxglove
        if f.enabled:
            try:
                from navd.io.foxglove_ws import FoxgloveLive  # optional: navd[foxglove]
            except ImportError as exc:
                raise StartupError("[foxglove] enabled needs the Foxglove SDK: pip install "
                                   "'navd[foxglove]'") from exc
            try:
                live = FoxgloveLive(host=f.host, port=f.port,
                                    aligned_sd_rad=c.nav.estimator.init.aligned_sd)
            except Exception as exc:  # the SDK's error for a port in use, bad host
                raise StartupError(explain_open_error("foxglove.port", f.port, exc)) from exc
            self.foxglove_sink = FoxgloveSink(live, f.rate, "foxglove")
            sinks.append(self.foxglove_sink)
        self.sinks = sinks + self._extra
        hold = round(c.daemon.read_hold_max * 1e6)
        margin = round(c.daemon.read_hold_margin * 1e6)
        periods = [s.schedule.period_us for s in self.sinks]
        if hold > 0 and self.sinks and c.daemon.rx_thread and self.sources.read_in_thread(
                periods, hold, margin):
            # the loop wakes about once per output instant; a thread of compiled code
            # reads the datagrams (issue 18)
            _log.info("UDP input read by a compiled thread, handed on at each output "
                      "instant (at most %.0f ms held, read again %.0f ms before each)",
                      hold * 1e-3, margin * 1e-3)
        elif hold > 0 and self.sinks:
            # outputs are due on the sinks' grids of sensor time: between two instants the
            # UDP input may wait in the socket and be read in one batch (issue 18)
            pacer = ReadPacer(periods, hold, margin)
            if self.sources.pace_reads(pacer):
                _log.info("UDP input read in batches between output instants (at most "
                          "%.0f ms apart, from %.0f ms before each)", hold * 1e-3,
                          c.daemon.read_hold_margin * 1e3)
        if self.record_path:
            rate = 1e6 / self.sinks[0].schedule.period_us if self.sinks else m.attitude_rate
            try:
                self.recorder = RecordingWriter(self.record_path, c.tables, rate)
            except OSError as exc:
                raise StartupError(f"--record {self.record_path}: cannot write: "
                                   f"{exc.strerror or exc} (does its directory exist?)"
                                   ) from exc
            _log.info("recording pushed samples to %s", self.record_path)
        return inputs

    def _autopilot_sink(self, link: MavlinkLink, encoder: MavlinkEncoder) -> AutopilotSink:
        a, m = self.cfg.autopilot, self.cfg.mavlink
        policy = AutopilotPolicy(aligned_sd=self.cfg.nav.estimator.init.aligned_sd,
                                 max_gnss_age_us=round(a.max_gnss_age * 1e6), uere_m=m.uere,
                                 geoid_sep_m=m.geoid_sep)
        schedule = (HeadingResetSchedule(a.heading_reset_min_interval, a.heading_reset_period)
                    if a.heading_reset else None)
        return AutopilotSink(link, encoder, a.gps_input_rate, policy, gps_input=a.gps_input,
                             estimator_status=a.estimator_status, heading_reset=schedule,
                             target=(a.target_sysid, a.target_compid))

    def output_destinations(self) -> list[str]:
        """Where each output goes, for the ready line: an operator wiring a consumer needs
        the address and the key, not only the sink's name."""
        c = self.cfg
        out: list[str] = []
        for sink in self.sinks:
            hz = 1e6 / sink.schedule.period_us
            if sink is self.mavlink_sink:
                dest = (f"the input link {c.mavlink.listen}" if c.mavlink.send == "same"
                        else c.mavlink.send)
                out.append(f"mavlink ATTITUDE {hz:g} Hz + HEARTBEAT -> {dest}")
            elif sink is self.autopilot_sink:
                a = c.autopilot
                what = [n for n, on in (("GPS_INPUT", a.gps_input),
                                        ("ESTIMATOR_STATUS", a.estimator_status),
                                        ("EXTERNAL_ATTITUDE_ESTIMATE", a.heading_reset)) if on]
                out.append(f"autopilot {' + '.join(what)} {hz:g} Hz -> "
                           f"{c.mavlink.send} (target {a.target_sysid}/{a.target_compid})")
            elif sink is self.zenoh_sink:
                ends = ", ".join([*(f"listen {e}" for e in c.zenoh.listen),
                                  *(f"connect {e}" for e in c.zenoh.connect)]) or "scouting"
                status = f" + {status_key(c.zenoh.vehicle)}" if c.zenoh.status else ""
                out.append(f"zenoh {attitude_key(c.zenoh.vehicle)} {hz:g} Hz{status} "
                           f"({ends})")
            elif isinstance(sink, Ros2Sink):
                topics = " ".join(p.topic for p in sink.pubs.values())
                out.append(f"ros2 node {sink.node.namespace.rstrip('/')}/{sink.node.node} "
                           f"(domain {c.ros2.domain_id}) {topics} {hz:g} Hz")
            elif sink is self.foxglove_sink:
                out.append(f"foxglove ws://{c.foxglove.host}:{c.foxglove.port} "
                           f"/navd/pose, /navd/location, /navd/heading {hz:g} Hz + "
                           "/navd/status")
            elif sink is self.mcap_sink:
                out.append(f"mcap /navd/pose, /navd/location, /navd/heading {hz:g} Hz + "
                           f"/navd/status -> {self.mcap_path}")
            elif isinstance(sink, DronecanSink):
                out.append(f"dronecan Solution {hz:g} Hz as node {c.dronecan.node_id} on "
                           f"{c.dronecan.interface}:{c.dronecan.channel}")
            else:
                out.append(f"{sink.name} {hz:g} Hz")
        return out

    def _close(self) -> None:
        for s in self.sinks or [x for x in (self.zenoh_sink,) if x is not None]:
            try:
                s.close()
            except Exception as exc:  # closing must go on for the rest
                _log.warning("closing %s: %s", s.name, exc)
        self.sources.close()
        if self.recorder is not None:
            try:
                self.recorder.close()
            except OSError as exc:  # the last buffered records are lost; say so
                _log.error("recording %s: cannot close: %s", self.recorder.path, exc)

    def save_biases(self) -> bool:
        """Write the learned biases to ``[bias_store] path`` if they are known well enough."""
        s = self.cfg.bias_store
        if not s.path:
            return False
        rec = bias_store.snapshot(self.est, s, time.time())
        if rec is None:
            return False
        try:
            bias_store.save(s.path, rec)
        except OSError as exc:
            self.rlog.warn("bias_store", "cannot save learned IMU biases to %s: %s", s.path,
                           exc)
            return False
        self.bias_store_state = f"saved {s.path}"
        return True

    def _finish(self) -> None:
        if self.save_biases():
            _log.info("learned IMU biases saved to %s", self.cfg.bias_store.path)
        status = self.status()
        if self.zenoh_sink is not None and self.cfg.zenoh.status:
            self.zenoh_sink.publish_status(status)
        self._foxglove_status()
        self._close()
        _log.info("stopped (%s); final stats %s", self.stop_reason or "error",
                  json.dumps(status, separators=(",", ":"), default=str))
        self.notifier.close()

    # -- the estimator task -------------------------------------------------------------------

    async def _estimate(self) -> None:
        get, ready, take = self.queue.get, self.queue.ready, self._take
        n = 0
        self._restarts_seen = self.est.restarts
        self._navigating = False
        # every sink's schedule has its next instant at or after _quiet_until (sensor us)
        # in estimator epoch _quiet_epoch; -1: ask them
        self._quiet_until, self._quiet_epoch = -1, self.est.restarts
        # while this task waits on an empty queue, a read's samples are taken in the
        # read's own callback (issue 18: no task wake-up per read; SampleQueue.direct)
        self.queue.direct = take
        try:
            while True:
                # what is queued is taken without a get() coroutine per sample (issue 18)
                item = ready.popleft() if ready else await get()
                if item is None:
                    break
                take(item)
                n += 1
                if n % 64 == 0:
                    await asyncio.sleep(0)  # a long backlog must not starve the sockets
        finally:
            self.queue.direct = None

    def _take(self, item: Item) -> None:
        """One queue item: through the clock guard, which holds samples off the current
        sensor clock until a new clock is confirmed (usually it passes just this sample:
        ``on_clock``, that case without a list per sample), into the estimator."""
        recv_ns, sample = item
        host_us = recv_ns // 1000 if recv_ns else None
        if isinstance(sample, ImuBlock):
            self._push_block(sample, recv_ns, host_us)
        elif type(sample) is ImuSample and self.clock_guard.on_clock(sample.t_us, host_us):
            self._push(sample, recv_ns)
        else:
            for s in self.clock_guard.push(sample, host_us):
                self._push(s, recv_ns)

    def _push(self, s: Sample, recv_ns: int) -> None:
        """One sample the clock guard passed: recorded, pushed, outputs when due."""
        est = self.est
        if self.recorder is not None:
            self._record(s)
        t_before = est.t_us
        # the one output rule (navd.pipeline); _outputs' usual "nothing due" without a call
        if output_instant(est, s) and (est.t_us >= self._quiet_until or not self._navigating
                                       or est.restarts != self._quiet_epoch):
            self._outputs(recv_ns)
        if est.restarts != self._restarts_seen:
            self._restarts_seen = est.restarts
            self._navigating = est.initialized
            self._restarted(t_before, s.t_us)

    def _push_block(self, block: ImuBlock, recv_ns: int, host_us: int | None) -> None:
        """A block of IMU samples (the UDP batch lane), as :meth:`_push` of each sample the
        clock guard passes, in order: runs of usual samples in one compiled call
        (``Estimator.push_imu_block``, which stops at each output instant, so the outputs
        come at the same samples), the others one by one; all one by one while recording
        (a recording holds the pushes one by one).  The block goes back to its pool."""
        est, g = self.est, self.clock_guard
        try:
            while block.start < block.n:
                if self.recorder is None:
                    stop = self._quiet_until if est.restarts == self._quiet_epoch else -1
                    if est.push_imu_block(block, stop, g.lane_clock(), g.back_tolerance_us,
                                          g.max_gap_us):
                        g.on_clock_run(int(block.t_us[block.start - 1]), host_us)
                        self._outputs(recv_ns)  # output_instant's True: an IMU sample
                        continue
                s = block.sample(block.start)
                block.start += 1
                if g.on_clock(s.t_us, host_us):
                    self._push(s, recv_ns)
                else:
                    for x in g.push(s, host_us):
                        self._push(x, recv_ns)
        finally:
            block.release()

    def _outputs(self, recv_ns: int) -> None:
        """An IMU sample of a navigating estimator was pushed: publish to the sinks due."""
        est = self.est
        if not self._navigating:
            self._navigating = True
            self._nav_since = time.monotonic()
        # before _quiet_until in its epoch no sink is due: each due() would say False and
        # change nothing (issue 18: not asked per sample)
        if est.t_us >= self._quiet_until or est.restarts != self._quiet_epoch:
            sol: NavSolution | None = None
            sinks = self.sinks
            for sink in sinks:
                # the restart count starts a sink's schedule over with the estimator
                if sink.schedule.due(est.t_us, est.restarts):
                    if sol is None:
                        sol = est.solution()
                    self._publish(sink, sol, recv_ns)
            self._quiet_epoch = est.restarts
            self._quiet_until = min((sink.schedule.next_us for sink in sinks), default=-1)

    def _restarted(self, t_before_us: int, t_new_us: int) -> None:
        """The estimator started over: say so at once (the periodic line may be a minute away)
        and keep it for the status record."""
        est = self.est
        reason = est.restart_reason or "restart"
        self.last_restart = {
            "count": est.restarts, "reason": reason,
            "sensor_t_before_s": round(t_before_us * 1e-6, 3),
            "sensor_t_after_s": round(t_new_us * 1e-6, 3),
            "uptime_s": round(time.monotonic() - self._t0, 1),
        }
        why = (" (the sensor clock jumped: a sensor or autopilot reboot?)"
               if reason == "reinit_time_jump" else "")
        self._gnss_seen_t_us = self._pos_fused_t_us = -1  # times of the old clock
        self.rlog.warn("restart", "estimator restarted (%s, %d so far): sensor time %.3f s -> "
                       "%.3f s%s; levelling again, outputs resume when it navigates",
                       reason, est.restarts, t_before_us * 1e-6, t_new_us * 1e-6, why)

    def _record(self, s: Sample) -> None:
        """Append ``s`` to the recording.  A recording is a debugging aid: no sample and no
        disk error may end the daemon because of it."""
        rec = self.recorder
        assert rec is not None
        try:
            rec.write(s)
        except RecordingError as exc:  # a value outside the file's fields: skip, count
            self.record_errors += 1
            self.rlog.warn("record_refused", "recording: sample not written (%d so far): %s",
                           self.record_errors, exc)
        except OSError as exc:  # disk full, I/O error: a torn record may follow; stop it
            self._stop_recording(exc)

    def _stop_recording(self, exc: OSError) -> None:
        rec = self.recorder
        assert rec is not None
        self.record_errors += 1
        self.recorder = None
        self.record_stopped = f"{type(exc).__name__}: {exc}"
        _log.error("recording %s stopped after %d records: %s; navigation goes on",
                   rec.path, rec.records, self.record_stopped)
        with contextlib.suppress(OSError):  # already reported above; the file is what it is
            rec.close()

    def _publish(self, sink: Sink, sol: NavSolution, recv_ns: int) -> None:
        try:
            sink.publish(sol)
        except Exception as exc:  # one broken output must not stop the others
            self.sink_errors += 1
            self.rlog.warn(f"sink_{sink.name}", "%s output failed: %s: %s", sink.name,
                           type(exc).__name__, exc)
            return
        now_ns = time.monotonic_ns()
        sink.latency.add(now_ns - recv_ns)
        self._output_at = now_ns * 1e-9
        self._output_t_us = sol.t_us

    # -- periodic tasks -----------------------------------------------------------------------

    async def _status_loop(self) -> None:
        d = self.cfg.daemon
        next_log = time.monotonic() + d.log_period
        next_save = time.monotonic() + self.cfg.bias_store.save_period
        seen = dict(self.est.counters)
        seen_clock = dict(self.clock_guard.counters)
        state = self.state()
        while True:
            await asyncio.sleep(d.status_period)
            self._note_progress()
            state = self._log_state_change(state, self.state())
            if self.zenoh_sink is not None and self.cfg.zenoh.status:
                self.zenoh_sink.publish_status(self.status())
            self._foxglove_status()
            self.notifier.status(self.status_line())
            now_counts = dict(self.est.counters)
            for name, n in now_counts.items():
                grew = n - seen.get(name, 0)
                if grew > 0 and _is_refusal(name):
                    self.rlog.warn(f"est_{name}", "%s", counter_warning(name, grew, n))
            seen = now_counts
            self._check_vehicle()
            clock = dict(self.clock_guard.counters)
            for name, n in clock.items():
                grew = n - seen_clock.get(name, 0)
                if grew > 0 and name != "clock_new":  # a new clock is logged as a restart
                    self.rlog.warn(name, "sensor clock: %s +%d (total %d): %s", name, grew,
                                   n, _CLOCK_WORDS.get(name, ""))
            seen_clock = clock
            if self.recorder is not None:
                try:
                    self.recorder.flush()
                except OSError as exc:
                    self._stop_recording(exc)
            if time.monotonic() >= next_save:
                next_save += self.cfg.bias_store.save_period
                self.save_biases()
            if time.monotonic() >= next_log:
                next_log += d.log_period
                _log.info("%s", self.log_line())

    def _foxglove_status(self) -> None:
        for sink in (self.mcap_sink, self.foxglove_sink):
            if sink is None:
                continue
            try:
                sink.publish_status(self.status())
            except (OSError, ValueError) as exc:  # a full disk must not end navigation
                self.sink_errors += 1
                self.rlog.warn(f"sink_{sink.name}_status", "%s status not written: %s",
                               sink.name, exc)

    def _log_state_change(self, old: str, new: str) -> str:
        """Say at once when the state changes (input stops or resumes, output stops, GNSS
        is lost or refused, navigation starts), rather than in the periodic line up to
        ``log_period_s`` later; return ``new``."""
        if new == old or new == "stopping":
            return new
        t = self.est.t_us * 1e-6
        mav = HEALTH[new][1]
        if new == "stalled":
            _log.warning("input stopped: no sensor data for %.1f s (last sensor time %.3f s); "
                         "no output until it resumes (HEARTBEAT %s)",
                         time.monotonic() - self._progress_at, t, mav)
        elif new == NO_OUTPUT:
            _log.warning("navigating but no solution published for %.1f s (sink errors %d; "
                         "HEARTBEAT %s)", time.monotonic() - max(self._output_at,
                                                                  self._nav_since),
                         self.sink_errors, mav)
        elif new == GNSS_LOST:
            _log.warning("GNSS lost: no fix for %.1f s of sensor time (t=%.3f s); coasting on "
                         "the IMU, heading and position drift (HEARTBEAT %s)",
                         (self.est.t_us - self._gnss_seen_t_us) * 1e-6, t, mav)
        elif new == GNSS_LOCKED_OUT:
            c = self.est.counters
            refused = {k: v for k, v in c.items() if k.endswith("_rejected") and v}
            _log.warning("GNSS locked out: fixes arrive but no position was fused for %.1f s "
                         "(t=%.3f s; refusals so far %s); coasting on the IMU until they fit "
                         "or the lock-out recovery resets to them (HEARTBEAT %s)",
                         (self.est.t_us - self._pos_fused_t_us) * 1e-6, t, refused, mav)
        elif old == "stalled":
            _log.info("input resumed (sensor time %.3f s): %s (HEARTBEAT %s)", t, new, mav)
        elif old in (GNSS_LOST, GNSS_LOCKED_OUT) and new == "navigating":
            _log.info("GNSS fused again at sensor time %.3f s: navigating (HEARTBEAT %s)",
                      t, mav)
        elif old == NO_OUTPUT and new == "navigating":
            _log.info("output resumed (HEARTBEAT %s)", mav)
        else:
            _log.info("state: %s -> %s at sensor time %.3f s (HEARTBEAT %s)", old, new, t,
                      mav)
        return new

    async def _watchdog_loop(self, timeout_s: float) -> None:
        loop = asyncio.get_running_loop()
        period = timeout_s / 2.0
        last = self.est.t_us
        last_tick = time.monotonic()
        deadline = loop.time()
        while True:
            deadline += period
            await asyncio.sleep(max(0.0, deadline - loop.time()))
            t = self.est.t_us
            why = self._watchdog_withheld(t != last, last_tick)
            if not why:
                self.notifier.watchdog()
            else:
                self.rlog.warn(f"watchdog {why}", "withholding WATCHDOG=1: %s (t_us=%d, state %s)",
                               why, t, self.state())
            last = t
            last_tick = time.monotonic()

    def _watchdog_withheld(self, sensor_moved: bool, since: float) -> str:
        """Why WATCHDOG=1 must not be sent for the tick that began at host time ``since``
        ('' to send it): only while outputs are actually produced (or, before navigation,
        while IMU data flows into levelling)."""
        if not sensor_moved:
            return "no sensor-time progress since the last tick"
        self._note_sensor_progress()  # the status task's note may be a period old
        state = self.state()
        if state in (NO_OUTPUT, "stalled"):
            return state
        if self.est.initialized and self.sinks and self._output_at < since:
            return "no solution published since the last tick"
        return ""

    # -- status -------------------------------------------------------------------------------

    def _note_sensor_progress(self) -> None:
        if self.est.t_us != self._progress_t_us:
            self._progress_t_us = self.est.t_us
            self._progress_at = time.monotonic()

    def _check_vehicle(self) -> None:
        """Once: warn when the autopilot's HEARTBEAT names a vehicle whose profile is not
        the one navd runs (a boat run as a car keeps a heading sigma its crab belies)."""
        if self._vehicle_told:
            return
        profile, said = self.sources.vehicle()
        ours = self.est.cfg.filter.profile
        if profile and profile != ours:
            self._vehicle_told = True
            _log.warning("the vehicle's %s fits [filter] profile = \"%s\", but navd runs "
                         "\"%s\": set it in the config (heading and its sigma depend on it)",
                         said, profile, ours)

    def _note_progress(self) -> None:
        now = time.monotonic()
        self._note_sensor_progress()
        t_prev, imu_prev, gnss_prev = self._rate_prev
        imu, gnss = self.est.counters.get("imu", 0), self.est.counters.get("gnss", 0)
        self._note_gnss()
        if now > t_prev:
            self.rates_hz = {"imu": round((imu - imu_prev) / (now - t_prev), 1),
                             "gnss": round((gnss - gnss_prev) / (now - t_prev), 1)}
        self._rate_prev = (now, imu, gnss)

    def state(self) -> str:
        """The daemon's state; :data:`HEALTH` says what each one means."""
        if self._stop.is_set():
            return "stopping"
        if self.est.t_us < 0:
            return "waiting for IMU"
        stall_s = max(_STALL_S, 2.0 * self.cfg.daemon.status_period)
        now = time.monotonic()
        if now - self._progress_at > stall_s:
            return "stalled"
        if not self.est.initialized:
            return "initializing"
        # "no output" while input still flows: if the input stopped, that is "stalled"
        # (a second later), not a failure of the outputs
        if self.sinks:
            limit = self._output_limit_s()
            if (now - max(self._output_at, self._nav_since) > limit
                    and self.est.t_us - self._output_t_us > limit * 1e6):
                return NO_OUTPUT
        return self._gnss_state()

    def _note_gnss(self) -> None:
        """Note the sensor time at which fixes last arrived and positions were last fused
        (from the estimator's counters, so the per-sample path pays nothing)."""
        est = self.est
        now = (est.counters.get("gnss", 0), est.counters.get("pos_accepted", 0))
        seen, fused = self._gnss_counts
        if now[0] != seen or self._gnss_seen_t_us < 0 <= est.t_us:
            self._gnss_seen_t_us = est.t_us
        if now[1] != fused or self._pos_fused_t_us < 0 <= est.t_us:
            self._pos_fused_t_us = est.t_us
        self._gnss_counts = now

    def _gnss_state(self) -> str:
        """navigating, or coasting for ``gnss_timeout_s`` of sensor time: no valid fix
        arrived (GNSS lost), or fixes arrive but no position was fused (locked out: the gate
        refuses them until the lock-out recovery, ``[filter] max_lockout_s``)."""
        t = self.est.t_us
        timeout_us = self.cfg.daemon.gnss_timeout * 1e6
        if 0 <= self._gnss_seen_t_us < t - timeout_us:
            return GNSS_LOST
        if 0 <= self._pos_fused_t_us < t - timeout_us:
            return GNSS_LOCKED_OUT
        return "navigating"

    def _output_limit_s(self) -> float:
        """How long navigation may go without a published solution before the state says so:
        two periods of the slowest sink, at least _STALL_S."""
        slowest_us = max(s.schedule.period_us for s in self.sinks)
        return max(_STALL_S, 2.0 * slowest_us * 1e-6)

    def _mav_state(self) -> int:
        return HEALTH[self.state()][0]

    def status(self) -> dict[str, Any]:
        """Everything an operator needs: the Zenoh status payload and the final stats."""
        state = self.state()
        mav, mav_name, meaning = HEALTH[state]
        out: dict[str, Any] = {
            "state": state,
            "health": {"mav_state": mav_name, "mav_state_id": mav, "meaning": meaning},
            "uptime_s": round(time.monotonic() - self._t0, 1),
            "t_us": self.est.t_us,
            "estimator": {**self.est.status(), **dov_status(self.est)},
            "inputs": self.sources.counters(),
            "clock": self.clock_guard.status(),
            "source_lock": self.sources.locks(),
            "outputs": {s.name: s.counters() for s in self.sinks},
            "queue": {"capacity": self.queue.maxsize, "size": self.queue.qsize(),
                      "high_water": self.queue.high_water, "drops": self.queue.drops},
            "latency_us": {s.name: s.latency.summary() for s in self.sinks},
            "rates_hz": self.rates_hz,
            "sink_errors": self.sink_errors,
            "bias_store": self.bias_store_state,
        }
        if self.last_restart is not None:
            out["restart"] = self.last_restart
        if self.recorder is not None:
            out["recording"] = {"path": str(self.recorder.path),
                                "records": self.recorder.records,
                                "errors": self.record_errors}
        elif self.record_stopped:
            out["recording"] = {"path": self.record_path, "stopped": self.record_stopped,
                                "errors": self.record_errors}
        return out

    def _headline(self) -> tuple[str, str]:
        lat = self.sinks[0].latency.summary() if self.sinks else {}
        lat_txt = (f"latency p50/p99 {lat['p50_us'] / 1e3:.2f}/{lat['p99_us'] / 1e3:.2f} ms"
                   if "p99_us" in lat else "no output yet")
        aligned = self._heading_words()
        if self.est.heading_held:
            aligned += " (held at rest)"
        r = self.last_restart
        restarted = (f", restarted {r['count']}x (last: {r['reason']} at sensor time "
                     f"{r['sensor_t_before_s']:.1f} -> {r['sensor_t_after_s']:.1f} s)"
                     if r is not None else "")
        return f"{self.state()}, {aligned}{restarted}", lat_txt

    def _heading_words(self) -> str:
        """The heading's state as the Zenoh ``aligned`` flag has it (navd.io.zenoh): a first
        course gives the yaw a value with a wide sigma (initialised); aligned means flagged
        (confirmed over time) and within ``[init] aligned_sd_deg``."""
        est = self.est
        if not est.initialized:
            return "heading not aligned"
        sol = est.solution()
        if not (sol.heading_initialised or sol.heading_aligned):
            return "heading not aligned"
        if sol.heading_good(self.cfg.nav.estimator.init.aligned_sd):
            return "heading aligned"
        return (f"heading coarse (sigma {math.degrees(sol.att_sd_rad[2]):.1f} deg, "
                "not yet aligned)")

    def status_line(self) -> str:
        head, lat = self._headline()
        r = self.rates_hz
        return (f"{head}; imu {r['imu']:.0f} Hz, gnss {r['gnss']:.0f} Hz; "
                f"queue drops {self.queue.drops}; {lat}")

    def log_line(self) -> str:
        head, lat = self._headline()
        c = self.est.counters
        refused = {k: v for k, v in c.items() if _is_refusal(k)}
        # tallies (frames, datagrams, per-source counts) are not rejections
        inputs = {name: {k: v for k, v in cnt.items() if v and not k.endswith("_ok")
                         and k not in ("frames_ok", "datagrams") and not k.startswith("src_")}
                  for name, cnt in self.sources.counters().items()}
        t = self.est.t_us * 1e-6 if self.est.t_us >= 0 else math.nan
        clock = {k: v for k, v in self.clock_guard.counters.items() if v}
        return (f"t={t:.1f} s {head}; imu={c.get('imu', 0)} gnss={c.get('gnss', 0)} "
                f"estimator refused={refused} input rejects={inputs} clock={clock} "
                f"queue_drops={self.queue.drops} {lat} "
                f"outputs={ {s.name: s.published for s in self.sinks} }")


