"""``navd demo``: the simulator streams a drive over MAVLink into a real ``navd run``; this
prints navd's Zenoh attitude output against the simulator's truth, live.

    navd demo [--scenario car480] [--rate-factor K] [--duration S] [--seed N]

Three processes on loopback, as on a vehicle: ``firmware-sim stream`` (the IMU and GNSS
receiver, MAVLink UDP) -> ``navd run`` (temporary config, free ports, sd_notify socket to
learn when it is up) -> this process (Zenoh subscriber, and a MAVLink listener counting
ATTITUDE).  One line per second: sensor time, roll/pitch/yaw, their errors against truth and
whether heading is aligned; at the end (or on Ctrl-C) the RMS errors so far.  navd imports
nothing from the simulator; the truth comes from the stream's ``--truth-out`` file.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import math
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from navd.io.zenoh import ZenohConfig, ZenohSubscriber

__all__ = ["main"]

Arr = npt.NDArray[np.float64]


def free_port(kind: int = socket.SOCK_DGRAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass
class Truth:
    t_us: npt.NDArray[np.int64]
    euler_deg: Arr  # (N, 3) roll, pitch, yaw

    @classmethod
    def load(cls, path: Path) -> Truth:
        data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
        return cls(data[:, 0].astype(np.int64), data[:, 4:7])

    def at(self, t_us: int) -> Arr | None:
        i = int(np.searchsorted(self.t_us, t_us))
        if i >= len(self.t_us) or self.t_us[i] != t_us:
            return None  # outputs are at IMU times, which are truth times
        row: Arr = self.euler_deg[i]
        return row


def _wrap180(x: float) -> float:
    return (x + 180.0) % 360.0 - 180.0


@dataclass
class Scoreboard:
    """Attitude outputs compared with truth; errors are navd - truth, degrees."""

    truth: Truth | None = None
    pending: list[dict[str, Any]] = field(default_factory=list)
    n: int = 0
    n_aligned: int = 0
    sq: Arr = field(default_factory=lambda: np.zeros(3))
    worst: Arr = field(default_factory=lambda: np.zeros(3))
    last: dict[str, Any] | None = None
    last_err: Arr | None = None
    aligned_at_s: float | None = None
    status: dict[str, Any] | None = None

    def add(self, msg: dict[str, Any]) -> None:
        if self.truth is None:
            self.pending.append(msg)
            return
        eul = msg.get("euler_deg")
        if not isinstance(eul, list) or any(v is None for v in eul):
            return
        ref = self.truth.at(int(msg["t_us"]))
        if ref is None:
            return
        err = np.array([eul[0] - ref[0], eul[1] - ref[1], _wrap180(eul[2] - ref[2])])
        self.n += 1
        self.last, self.last_err = msg, err
        if msg.get("aligned"):
            if self.aligned_at_s is None:
                self.aligned_at_s = msg["t_us"] * 1e-6
            self.n_aligned += 1
            self.sq += err * err
            self.worst = np.maximum(self.worst, np.abs(err))

    def set_truth(self, truth: Truth) -> None:
        self.truth = truth
        for m in self.pending:
            self.add(m)
        self.pending.clear()

    def rms(self) -> Arr:
        return np.sqrt(self.sq / self.n_aligned) if self.n_aligned else np.full(3, math.nan)


class _MavlinkCounter(asyncio.DatagramProtocol):
    """Counts ATTITUDE frames navd sends to the MAVLink output port (a stock GCS's view)."""

    def __init__(self) -> None:
        from pymavlink.dialects.v20 import ardupilotmega as mavlink

        self.mav = mavlink.MAVLink(None)
        self.mav.robust_parsing = True
        self.attitude = 0
        self.heartbeat = 0

    def datagram_received(self, data: bytes, addr: Any) -> None:
        with contextlib.suppress(Exception):
            for m in self.mav.parse_buffer(data) or []:
                t = m.get_type()
                self.attitude += t == "ATTITUDE"
                self.heartbeat += t == "HEARTBEAT"


HEADER = (f"{'t [s]':>7} {'roll':>7} {'pitch':>7} {'yaw':>7} | {'err roll':>8} {'pitch':>6} "
          f"{'yaw':>6} [deg] | {'1σ yaw':>6}  aligned")


def _line(sb: Scoreboard) -> str:
    m, e = sb.last, sb.last_err
    if m is None or e is None:
        return f"{'':>7} waiting for navd's first attitude output..."
    r, p, y = m["euler_deg"]
    sd = m.get("sigma_deg") or [None] * 3
    sd_y = f"{sd[2]:6.2f}" if sd[2] is not None else "   n/a"
    return (f"{m['t_us'] * 1e-6:7.1f} {r:7.2f} {p:7.2f} {y:7.2f} | {e[0]:8.2f} {e[1]:6.2f} "
            f"{e[2]:6.2f}       | {sd_y}  {'yes' if m.get('aligned') else 'no'}")


def _summary(sb: Scoreboard, mav: _MavlinkCounter, interrupted: bool) -> str:
    rms = sb.rms()
    lines = ["", "summary" + (" (interrupted: results so far)" if interrupted else "") + ":",
             f"  attitude outputs compared with truth: {sb.n} ({sb.n_aligned} heading-aligned)"]
    if sb.aligned_at_s is not None:
        lines.append(f"  heading aligned from GNSS course at t = {sb.aligned_at_s:.1f} s")
    if sb.n_aligned:
        lines += [f"  RMS error   heading {rms[2]:.3f} deg   pitch {rms[1]:.3f} deg   "
                  f"roll {rms[0]:.3f} deg",
                  f"  max |error| heading {sb.worst[2]:.3f} deg   pitch {sb.worst[1]:.3f} deg   "
                  f"roll {sb.worst[0]:.3f} deg"]
    lines.append(f"  MAVLink ATTITUDE received on the output port: {mav.attitude} "
                 f"(HEARTBEAT {mav.heartbeat})")
    st = sb.status
    if st is not None:
        lat = st.get("latency_us", {}).get("mavlink", {})
        if "p99_us" in lat:
            lines.append(f"  navd receive->ATTITUDE latency p50 {lat['p50_us'] / 1e3:.2f} ms, "
                         f"p99 {lat['p99_us'] / 1e3:.2f} ms")
        q = st.get("queue", {})
        counters = st.get("estimator", {}).get("counters", {})
        lines.append(f"  navd: state {st.get('state')}, queue drops {q.get('drops')}, "
                     f"estimator counters {counters}")
    return "\n".join(lines)


async def _wait_ready(sock: socket.socket, proc: subprocess.Popen[bytes], timeout_s: float
                      ) -> bool:
    """Wait for READY=1 on our fake NOTIFY_SOCKET (navd speaks sd_notify to us)."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout_s
    while loop.time() < deadline and proc.poll() is None:
        try:
            msg = sock.recv(4096).decode(errors="replace")
        except BlockingIOError:
            await asyncio.sleep(0.1)
            continue
        if "READY=1" in msg.split("\n"):
            return True
    return False


def _tail(path: Path, n: int = 15) -> str:
    try:
        return "\n".join(path.read_text(errors="replace").splitlines()[-n:])
    except OSError:
        return ""


def _stop(proc: subprocess.Popen[bytes] | None, timeout_s: float = 10.0) -> None:
    if proc is None or proc.poll() is not None:
        return
    proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


async def _demo(a: argparse.Namespace, tmp: Path) -> int:
    loop = asyncio.get_running_loop()
    port_in, port_out, port_z = free_port(), free_port(), free_port(socket.SOCK_STREAM)
    vehicle = "demo"
    cfg = tmp / "navd.toml"
    cfg.write_text(
        "# written by navd demo\n"
        "[mavlink]\n"
        f'listen = "udpin:127.0.0.1:{port_in}"\n'
        f'send = "udpout:127.0.0.1:{port_out}"\n'
        "[zenoh]\n"
        f'vehicle = "{vehicle}"\n'
        f'listen = ["tcp/127.0.0.1:{port_z}"]\n')
    notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    notify.bind(str(tmp / "notify.sock"))
    notify.setblocking(False)
    env = {**os.environ, "NOTIFY_SOCKET": str(tmp / "notify.sock"), "PYTHONUNBUFFERED": "1"}
    navd_log = tmp / "navd.log"
    stream_log = tmp / "stream.log"
    truth_csv = tmp / "truth.csv"
    mav = _MavlinkCounter()
    transport, _ = await loop.create_datagram_endpoint(lambda: mav,
                                                       local_addr=("127.0.0.1", port_out))
    interrupted = asyncio.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, interrupted.set)

    daemon: subprocess.Popen[bytes] | None = None
    stream: subprocess.Popen[bytes] | None = None
    sb = Scoreboard()
    sub: ZenohSubscriber | None = None
    try:
        print("starting navd (a first start on a fresh machine compiles the estimator's "
              "kernels: up to a minute)...", flush=True)
        t0 = time.monotonic()
        with open(navd_log, "wb") as log:
            # own session: Ctrl-C reaches only us, and we stop the children in order
            daemon = subprocess.Popen([sys.executable, "-m", "navd", "run", "--config",
                                       str(cfg)], stderr=log, stdout=log, env=env,
                                      start_new_session=True)
        ready = asyncio.ensure_future(_wait_ready(notify, daemon, a.startup_timeout))
        await asyncio.wait([ready, asyncio.ensure_future(interrupted.wait())],
                           return_when=asyncio.FIRST_COMPLETED)
        if interrupted.is_set():
            ready.cancel()
            return 130
        if not ready.result():
            print(f"navd did not become ready; its log ({navd_log}):\n{_tail(navd_log)}",
                  file=sys.stderr)
            return 1
        print(f"navd is up after {time.monotonic() - t0:.1f} s: MAVLink in on "
              f"udp:127.0.0.1:{port_in}, ATTITUDE out to udp:127.0.0.1:{port_out}, Zenoh "
              f"navd/{vehicle}/attitude on tcp/127.0.0.1:{port_z}", flush=True)

        def on_msg(key: str, obj: dict[str, Any]) -> None:
            if key.endswith("/attitude"):
                sb.add(obj)
            elif key.endswith("/status"):
                sb.status = obj

        sub = ZenohSubscriber(ZenohConfig(vehicle=vehicle, listen=(),
                                          connect=(f"tcp/127.0.0.1:{port_z}",)),
                              f"navd/{vehicle}/**", loop, on_msg)
        cmd = [sys.executable, "-m", "firmware_sim", "stream", "--scenario", a.scenario,
               "--seed", str(a.seed), "--rate-factor", str(a.rate_factor), "--target",
               f"udp:127.0.0.1:{port_in}", "--truth-out", str(truth_csv)]
        if a.duration is not None:
            cmd += ["--set", f"duration_s={a.duration}"]
        with open(stream_log, "wb") as log:
            stream = subprocess.Popen(cmd, stderr=log, stdout=log, start_new_session=True)
        print(f"streaming {a.scenario} (seed {a.seed}) at x{a.rate_factor:g} real time; "
              "Ctrl-C stops early and prints the summary so far\n", flush=True)
        print(HEADER, flush=True)
        next_print = loop.time() + 1.0
        while not interrupted.is_set():
            if sb.truth is None and truth_csv.exists():
                sb.set_truth(Truth.load(truth_csv))
            if stream.poll() is not None:
                break
            if daemon.poll() is not None:
                print(f"navd exited with {daemon.returncode}; log:\n{_tail(navd_log)}",
                      file=sys.stderr)
                return 1
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(interrupted.wait(), max(0.0, next_print - loop.time()))
            if loop.time() >= next_print:
                next_print += 1.0
                print(_line(sb), flush=True)
        if stream.returncode not in (None, 0):
            print(f"the simulator stream failed ({stream.returncode}):\n{_tail(stream_log)}",
                  file=sys.stderr)
            return 1
        if not interrupted.is_set():
            await asyncio.sleep(1.5)  # last outputs and one more status message
            print(_line(sb), flush=True)
        print(_summary(sb, mav, interrupted.is_set()), flush=True)
        return 130 if interrupted.is_set() else 0
    finally:
        if sub is not None:
            sub.close()
        _stop(stream)
        _stop(daemon)
        transport.close()
        notify.close()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.remove_signal_handler(sig)


def main(argv: list[str] | None = None) -> int:
    # the module docstring is for readers of the code (RST, process layout); --help gets
    # whole sentences for a user, including how long a run takes
    ap = argparse.ArgumentParser(
        prog="navd demo",
        description="The simulator streams a drive over MAVLink into a real `navd run`; this "
                    "prints navd's Zenoh attitude output against the simulator's truth, one "
                    "line per second, and the RMS errors at the end (or on Ctrl-C). The "
                    "stream plays in real time: the default car480 drive takes 480 s; "
                    "--duration or --rate-factor make it shorter.")
    ap.add_argument("--scenario", default="car480", help="simulator scenario (default car480)")
    ap.add_argument("--rate-factor", type=float, default=1.0,
                    help="sensor seconds per wall second (default 1: real time)")
    ap.add_argument("--duration", type=float, default=None,
                    help="seconds of the scenario to play (default: all of it)")
    ap.add_argument("--seed", type=int, default=1,
                    help="simulator noise seed (default 1)")
    ap.add_argument("--startup-timeout", type=float, default=300.0,
                    help="seconds to wait for navd to become ready (default 300)")
    ap.add_argument("--keep", action="store_true",
                    help="keep the temporary directory (config, logs, truth)")
    a = ap.parse_args(argv)
    if a.rate_factor <= 0:
        ap.error("--rate-factor must be > 0")
    tmp = Path(tempfile.mkdtemp(prefix="navd-demo-"))
    try:
        return asyncio.run(_demo(a, tmp))
    finally:
        if a.keep:
            print(f"kept {tmp}", file=sys.stderr)
        else:
            shutil.rmtree(tmp, ignore_errors=True)
