"""The daemon under load: 1 kHz HIGHRES_IMU + 10 Hz GPS_INPUT over loopback UDP into a real
``navd run`` subprocess, then a short sweep of faster IMU rates.

    python benchmarks/daemon.py [--duration 60] [--sweep 2000,4000,8000,16000,32000]
                                [--sweep-duration 5] [--json PATH] [--set KEY=VALUE]
                                [--profile PATH] [--py-spy PATH]

Figures (issue 18 targets: <= 5 % of one core, p99 IMU-in -> ATTITUDE-out <= 2 ms,
no loss):
  CPU          utime + stime of the daemon process (all its threads, /proc/<pid>/stat) over
               the streaming phase, as % of one core.  Start-up (imports, JIT warm-up) excluded.
  latency      measured two ways.  navd: the daemon's own, from the kernel's arrival stamp
               of the read's last IMU datagram (the read time where there is no stamp), so
               time spent unread in the socket during a read-pacing hold counts, to the
               return of the ATTITUDE sendto, per output (Zenoh status).  end-to-end:
               here, from just before our sendto of the IMU datagram that completed an
               output instant to our receipt of the ATTITUDE carrying that time_boot_ms
               (adds both kernel hops and the receiving thread's wake-up, which shares a
               GIL with the sending thread).
  lost         IMU datagrams sent minus IMU samples the estimator consumed.
  sweep        the same at K kHz (the 1 kHz data played K times faster, same time line);
               "held" = no loss and no queue drop.
  --profile    runs the daemon under cProfile (writes PATH, prints the functions with the
               most own time); profiling slows it down, so take CPU and latency figures
               from a run without it.
  host         benchmarks/host_jitter.py beside navd through the 1 kHz phase (5 ms sleeps):
               how late the host woke a process that only sleeps: the host's own tail in
               the same seconds (off with --no-jitter-probe).
  --py-spy     samples the running daemon with py-spy during the 1 kHz phase only (little
               overhead; needs py-spy installed and ptrace allowed).

The scenario is car480 resampled to a 1 kHz IMU; frames are encoded before the clock starts,
so the sender's cost is a sendto per frame.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np
import zenoh
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from firmware_sim import generate, load_scenario
from firmware_sim.stream import mavlink_events

ROOT = Path(__file__).resolve().parents[1]
CLK_TCK = os.sysconf("SC_CLK_TCK")


def free_port(kind: int = socket.SOCK_DGRAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def cpu_s(pid: int) -> float:
    """User + system CPU seconds of a process (all threads)."""
    user, system = cpu_split_s(pid)
    return user + system


def thread_cpu_s(pid: int) -> dict[str, float]:
    """CPU seconds (user + system) per thread name of a process; threads sharing a name
    (Zenoh's runtime pools) are summed."""
    out: dict[str, float] = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            name = (task / "comm").read_text().strip()
            fields = (task / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:  # the thread ended meanwhile
            continue
        out[name] = out.get(name, 0.0) + (int(fields[11]) + int(fields[12])) / CLK_TCK
    return out


def cpu_split_s(pid: int) -> tuple[float, float]:
    """(user, system) CPU seconds of a process (all threads)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return int(fields[11]) / CLK_TCK, int(fields[12]) / CLK_TCK  # utime, stime (14, 15)


@dataclass
class Navd:
    """A ``navd run`` subprocess on free loopback ports: MAVLink in (``port_in``), ATTITUDE
    out (``port_out``), Zenoh (``port_z``); its log in ``tmp/navd.log``."""

    proc: subprocess.Popen[bytes]
    tmp: Path
    port_in: int
    port_out: int
    port_z: int
    vehicle: str
    log: IO[bytes]
    notify: socket.socket

    def wait_ready(self) -> None:
        """Block until systemd-style READY=1 (start-up then excluded from the figures)."""
        while b"READY=1" not in self.notify.recv(4096):
            pass

    def stop(self) -> int | None:
        """SIGTERM (navd drains its queue and logs its final stats); the exit code."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            self.proc.wait(30)
        self.log.close()
        self.notify.close()
        return self.proc.returncode

    def log_text(self) -> str:
        return (self.tmp / "navd.log").read_text(errors="replace")


def start_navd(sets: list[str], status_period_s: float = 1.0,
               log_period_s: float = 3600.0, profile: str | None = None) -> Navd:
    """Start ``navd run`` with a 1 kHz MAVLink UDP config; ``sets`` are ``--set`` values."""
    tmp = Path(tempfile.mkdtemp(prefix="navd-bench-"))
    port_in, port_out, port_z = free_port(), free_port(), free_port(socket.SOCK_STREAM)
    vehicle = f"bench{port_z}"
    cfg = tmp / "navd.toml"
    cfg.write_text(
        f'[mavlink]\nlisten = "udpin:127.0.0.1:{port_in}"\n'
        f'send = "udpout:127.0.0.1:{port_out}"\nnominal_imu_rate_hz = 1000.0\n'
        f'[zenoh]\nvehicle = "{vehicle}"\nlisten = ["tcp/127.0.0.1:{port_z}"]\n'
        f"[daemon]\nstatus_period_s = {status_period_s}\nlog_period_s = {log_period_s}\n")
    notify_path = str(tmp / "notify")
    notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    notify.bind(notify_path)
    notify.settimeout(300)
    log = open(tmp / "navd.log", "wb")  # noqa: SIM115 - closed by Navd.stop
    navd_set = [arg for kv in sets for arg in ("--set", kv)]
    prof = ["-m", "cProfile", "-o", profile] if profile else []
    proc = subprocess.Popen([sys.executable, *prof, "-m", "navd", "run", "--config", str(cfg),
                             *navd_set],
                            stdout=log, stderr=log, cwd=ROOT,
                            env={**os.environ, "NOTIFY_SOCKET": notify_path})
    return Navd(proc, tmp, port_in, port_out, port_z, vehicle, log, notify)


class AttitudeReceiver(threading.Thread):
    """Receipt time of every ATTITUDE, by time_boot_ms."""

    def __init__(self, port: int) -> None:
        super().__init__(daemon=True)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
        self.sock.bind(("127.0.0.1", port))
        self.sock.settimeout(0.2)
        self.mav = mavlink.MAVLink(None)
        self.got: dict[int, int] = {}
        self.running = True

    def run(self) -> None:
        while self.running:
            try:
                data = self.sock.recv(4096)
            except TimeoutError:
                continue
            now = time.monotonic_ns()
            for m in self.mav.parse_buffer(data) or []:
                if m.get_type() == "ATTITUDE":
                    self.got.setdefault(m.time_boot_ms, now)


class StatusSubscriber:
    def __init__(self, port: int, vehicle: str) -> None:
        from navd.io.zenoh import ZenohConfig

        cfg = ZenohConfig(vehicle=vehicle, listen=(), connect=(f"tcp/127.0.0.1:{port}",))
        self.session = zenoh.open(cfg.to_zenoh())
        self.latest: dict[str, Any] | None = None
        self.n = 0
        self.session.declare_subscriber(f"navd/{vehicle}/status", self._on)

    def _on(self, s: Any) -> None:
        self.latest = json.loads(s.payload.to_bytes())
        self.n += 1

    def fresh(self, timeout_s: float = 5.0) -> dict[str, Any]:
        """A status published after this call (so it covers everything sent before it)."""
        n0 = self.n
        deadline = time.monotonic() + timeout_s
        while self.n < n0 + 2 and time.monotonic() < deadline:
            time.sleep(0.05)
        if self.latest is None:
            raise RuntimeError("no status from navd")
        return self.latest


def send_paced(sock: socket.socket, addr: tuple[str, int],
               frames: list[tuple[int, bytes, bool]], rate_factor: float,
               sent_at: dict[int, int]) -> tuple[int, float]:
    """Send frames at sensor time / rate_factor; note the send time of IMU frames at 20 ms
    output instants.  Returns (IMU frames sent, wall seconds)."""
    t0_us = frames[0][0]
    wall0 = time.monotonic()
    n_imu = 0
    for t_us, frame, is_imu in frames:
        delay = wall0 + (t_us - t0_us) * 1e-6 / rate_factor - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        # taken before the sendto: on loopback the datagram is in navd's socket (and navd
        # possibly at work on it) before sendto returns
        t_send = time.monotonic_ns()
        sock.sendto(frame, addr)
        if is_imu:
            n_imu += 1
            if t_us % 20_000 == 0:
                sent_at[t_us // 1000] = t_send
    return n_imu, time.monotonic() - wall0


def pct(v: list[float], p: float) -> float:
    return float(np.percentile(v, p)) if v else float("nan")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=60.0, help="1 kHz phase, seconds")
    ap.add_argument("--sweep", default="2000,4000,8000,16000,32000",
                    help="IMU rates (Hz) to try after the 1 kHz phase ('' = none)")
    ap.add_argument("--sweep-duration", type=float, default=5.0, help="seconds per sweep step")
    ap.add_argument("--json", help="write the figures to this file")
    ap.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                    help="passed to navd run, e.g. daemon.event_loop=asyncio")
    ap.add_argument("--profile", metavar="PATH",
                    help="run navd under cProfile, write the stats to PATH, print a summary")
    ap.add_argument("--py-spy", metavar="PATH", dest="py_spy",
                    help="sample navd with py-spy (if installed) during the 1 kHz phase, "
                         "write the collapsed stacks to PATH, print a summary")
    ap.add_argument("--no-jitter-probe", dest="jitter_probe", action="store_false",
                    help="do not run benchmarks/host_jitter.py beside navd in the 1 kHz phase")
    a = ap.parse_args(argv)
    sweep = [float(x) for x in a.sweep.split(",") if x.strip()]
    # The receiver thread shares the GIL with the pacing loop; at the default 5 ms switch
    # interval its wake-up, not navd, would dominate the end-to-end tail.
    sys.setswitchinterval(1e-4)

    total_sensor_s = a.duration + sum(a.sweep_duration * r / 1000.0 for r in sweep) + 2.0
    print(f"generating car480 with a 1 kHz IMU, {total_sensor_s:.0f} s ...", file=sys.stderr)
    run = generate(load_scenario("car480", overrides={
        "imu.rate_hz": 1000.0, "duration_s": min(480.0, total_sensor_s)}), seed=1)
    frames = list(mavlink_events(run))
    navd = start_navd(a.set, profile=a.profile)
    port_in, port_out, port_z = navd.port_in, navd.port_out, navd.port_z
    vehicle, proc = navd.vehicle, navd.proc
    rx = AttitudeReceiver(port_out)
    rx.start()
    results: dict[str, Any] = {"machine": platform.platform(), "cpus": os.cpu_count(),
                               "python": platform.python_version(),
                               "load_avg_before": os.getloadavg()[0]}
    status: StatusSubscriber | None = None
    try:
        navd.wait_ready()
        status = StatusSubscriber(port_z, vehicle)
        time.sleep(1.0)
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        addr = ("127.0.0.1", port_in)
        sent_at: dict[int, int] = {}

        n_main = sum(1 for t, _, _ in frames if t <= frames[0][0] + a.duration * 1e6)
        print(f"streaming {a.duration:.0f} s at 1 kHz IMU + 10 Hz GNSS ...", file=sys.stderr)
        # What the daemon costs with no input (Zenoh's threads, timers): a floor under
        # the figure below.
        i0, w0 = cpu_s(proc.pid), time.monotonic()
        time.sleep(3.0)
        idle_pct = 100.0 * (cpu_s(proc.pid) - i0) / (time.monotonic() - w0)
        spy = start_py_spy(proc.pid, a.py_spy, a.duration) if a.py_spy else None
        jitter = start_jitter_probe(a.duration) if a.jitter_probe else None
        (u0, s0), c0, th0 = cpu_split_s(proc.pid), cpu_s(proc.pid), thread_cpu_s(proc.pid)
        n_imu, wall = send_paced(sock, addr, frames[:n_main], 1.0, sent_at)
        (u1, s1), c1, th1 = cpu_split_s(proc.pid), cpu_s(proc.pid), thread_cpu_s(proc.pid)
        host = read_jitter_probe(jitter) if jitter is not None else None
        by_thread = {k: round(100.0 * (v - th0.get(k, 0.0)) / wall, 1) for k, v in th1.items()}
        if spy is not None:
            spy.wait(60)
        time.sleep(0.5)
        st = status.fresh()
        e2e = [(rx.got[ms] - sent_at[ms]) * 1e-3 for ms in sent_at if ms in rx.got]
        lat = st["latency_us"]["mavlink"]
        consumed = st["estimator"]["counters"].get("imu", 0)
        main = {
            "imu_rate_hz": 1000, "seconds": round(wall, 1), "imu_sent": n_imu,
            "imu_consumed": consumed, "lost": n_imu - consumed,
            "queue_drops": st["queue"]["drops"],
            "cpu_pct_one_core": round(100.0 * (c1 - c0) / wall, 1),
            "cpu_user_pct": round(100.0 * (u1 - u0) / wall, 1),
            "cpu_system_pct": round(100.0 * (s1 - s0) / wall, 1),
            "cpu_idle_pct_one_core": round(idle_pct, 1),
            "cpu_pct_by_thread": dict(sorted(by_thread.items(), key=lambda kv: -kv[1])),
            "navd_latency_p50_ms": round(lat["p50_us"] / 1e3, 3),
            "navd_latency_p99_ms": round(lat["p99_us"] / 1e3, 3),
            "navd_latency_max_ms": round(lat["max_window_us"] / 1e3, 3),
            "navd_latency_outputs": lat["window"],
            "e2e_latency_p50_ms": round(pct(e2e, 50) / 1e3, 3),
            "e2e_latency_p99_ms": round(pct(e2e, 99) / 1e3, 3),
            "attitude_received": len(rx.got),
            "host_wakeup": host,
        }
        results["main"] = main
        results["load_avg_after_main"] = os.getloadavg()[0]

        steps = []
        pos = n_main
        for rate in sweep:
            k = rate / 1000.0
            n_step = int(a.sweep_duration * rate)  # IMU frames in this step
            end, n_imu_chunk = pos, 0
            while end < len(frames) and n_imu_chunk < n_step:
                n_imu_chunk += frames[end][2]
                end += 1
            if n_imu_chunk < n_step:
                print(f"  sweep {rate:.0f} Hz: not enough data, stopping", file=sys.stderr)
                break
            chunk, pos = frames[pos:end], end
            before = status.fresh()
            imu0 = before["estimator"]["counters"].get("imu", 0)
            drops0 = before["queue"]["drops"]
            c0 = cpu_s(proc.pid)
            n_imu, wall = send_paced(sock, addr, chunk, k, {})
            c1 = cpu_s(proc.pid)
            time.sleep(0.5)
            after = status.fresh()
            lost = n_imu - (after["estimator"]["counters"].get("imu", 0) - imu0)
            drops = after["queue"]["drops"] - drops0
            steps.append({"imu_rate_hz": rate, "achieved_hz": round(n_imu / wall),
                          "imu_sent": n_imu, "lost": lost, "queue_drops": drops,
                          "cpu_pct_one_core": round(100.0 * (c1 - c0) / wall, 1),
                          "held": lost == 0 and drops == 0})
            print(f"  sweep {rate:.0f} Hz: lost {lost}, cpu {steps[-1]['cpu_pct_one_core']} %",
                  file=sys.stderr)
        results["sweep"] = steps
        held = [s["imu_rate_hz"] for s in steps if s["held"]]
        results["max_rate_held_hz"] = max([1000.0, *held]) if main["lost"] == 0 else None
        sock.close()
    finally:
        if status is not None:  # an open Zenoh session would keep this process alive
            status.session.close()
        rx.running = False
        navd.stop()

    loop_line = [ln for ln in navd.log_text().splitlines() if "event loop:" in ln]
    results["event_loop"] = loop_line[0].split("event loop: ", 1)[1] if loop_line else "?"
    m = results["main"]
    rows = [
        ("CPU, % of one core (1 kHz)", f"{m['cpu_pct_one_core']:.1f}", "<= 5"),
        ("  of which user / system", f"{m['cpu_user_pct']:.1f} / {m['cpu_system_pct']:.1f}", ""),
        ("CPU with no input (3 s before streaming), %", f"{m['cpu_idle_pct_one_core']:.1f}", ""),
        ("  by thread (top 3), %", ", ".join(
            f"{k} {v:.1f}" for k, v in list(m["cpu_pct_by_thread"].items())[:3]), ""),
        ("navd recv -> ATTITUDE send p50 / p99, ms",
         f"{m['navd_latency_p50_ms']:.3f} / {m['navd_latency_p99_ms']:.3f}", "p99 <= 2"),
        ("end-to-end IMU sendto -> ATTITUDE recv p50 / p99, ms",
         f"{m['e2e_latency_p50_ms']:.3f} / {m['e2e_latency_p99_ms']:.3f}", ""),
    ]
    host = m["host_wakeup"]
    if host is not None:
        rows.append((f"  host: a {host['period_ms']:g} ms sleep loop beside navd, wake-up late "
                     "p99 / max, ms", f"{host['late_p99_ms']:.3f} / {host['late_max_ms']:.2f}",
                     ""))
        rows.append(("  host: its wake-ups > 2 ms late, %",
                     f"{host['over_2ms_pct']:.2f}", ""))
    rows += [
        ("IMU datagrams sent / consumed / lost",
         f"{m['imu_sent']} / {m['imu_consumed']} / {m['lost']}", "0 lost"),
        ("queue drops", f"{m['queue_drops']}", "0"),
    ]
    rows += [(f"sweep {s['imu_rate_hz'] / 1000:g} kHz (achieved {s['achieved_hz']} Hz): "
              "lost / CPU %", f"{s['lost']} / {s['cpu_pct_one_core']}",
              "held" if s["held"] else "NOT held") for s in results["sweep"]]
    rows.append(("highest IMU rate held without loss, Hz", f"{results['max_rate_held_hz']}",
                 ">= 1000"))
    w = max(len(r[0]) for r in rows)
    print(f"\nnavd daemon benchmark ({a.duration:.0f} s at 1 kHz, {results['machine']}, "
          f"{results['cpus']} CPUs, load average {results['load_avg_before']:.2f} before / "
          f"{results['load_avg_after_main']:.2f} after the 1 kHz phase; navd event loop "
          f"{results['event_loop']})")
    print(f"| {'what':<{w}} | {'measured':>22} | {'target':>8} |")
    print(f"|{'-' * (w + 2)}|{'-' * 24}|{'-' * 10}|")
    for what, val, target in rows:
        print(f"| {what:<{w}} | {val:>22} | {target:>8} |")
    if a.profile:
        results["profile_top"] = profile_summary(a.profile)
    if a.py_spy and Path(a.py_spy).exists():
        results["py_spy_top"] = py_spy_summary(a.py_spy)
    if a.json:
        Path(a.json).write_text(json.dumps(results, indent=2) + "\n")
    return 0


def start_jitter_probe(seconds: float) -> subprocess.Popen[bytes]:
    """benchmarks/host_jitter.py at a 5 ms period for ``seconds`` in its own process: the
    host's wake-up tail during the same seconds navd is measured."""
    return subprocess.Popen([sys.executable, str(ROOT / "benchmarks" / "host_jitter.py"),
                             "--seconds", f"{seconds:g}", "--period-ms", "5", "--json", "-"],
                            stdout=subprocess.PIPE)


def read_jitter_probe(probe: subprocess.Popen[bytes]) -> dict[str, Any] | None:
    try:
        out, _ = probe.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        probe.kill()
        probe.communicate()
        return None
    if probe.returncode != 0:
        return None
    res: dict[str, Any] = json.loads(out)
    return res


def start_py_spy(pid: int, path: str, duration_s: float) -> subprocess.Popen[bytes] | None:
    """py-spy sampling ``pid`` for ``duration_s`` into ``path`` (collapsed stacks, idle
    samples left out); None if py-spy is not installed."""
    exe = Path(sys.executable).with_name("py-spy")
    if not exe.exists():
        print("py-spy not installed: no sampling profile", file=sys.stderr)
        return None
    return subprocess.Popen([str(exe), "record", "-p", str(pid), "-d", str(int(duration_s)),
                             "-r", "500", "-f", "raw", "-o", path, "--nonblocking"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def py_spy_summary(path: str, n: int = 15) -> dict[str, Any]:
    """Own samples per function and the share of the main paths, from collapsed stacks."""
    own: dict[str, int] = {}
    incl: dict[str, int] = {}
    total = 0
    for line in Path(path).read_text().splitlines():
        stack, _, count = line.rpartition(" ")
        if not stack or not count.isdigit():
            continue
        k = int(count)
        total += k
        frames = stack.split(";")
        leaf = frames[-1].split(" (")[0] + " (" + frames[-1].rsplit("/", 1)[-1]
        own[leaf] = own.get(leaf, 0) + k
        # py-spy names methods Class.method: the share is keyed by the method name
        for name in {f.split(" (")[0].rsplit(".", 1)[-1] for f in frames}:
            incl[name] = incl.get(name, 0) + k
    paths = {name: round(100.0 * incl.get(name, 0) / max(total, 1), 1)
             for name in ("_readable", "batch_received", "datagram_received", "_estimate",
                          "_push_block", "_outputs", "send_solution", "publish_attitude",
                          "_status_loop")}
    top = sorted(own.items(), key=lambda kv: kv[1], reverse=True)[:n]
    print(f"\npy-spy ({path}): {total} busy samples in the 1 kHz phase; inclusive share "
          f"of: {paths}")
    print(f"| {'function (own samples)':<70} | {'samples':>7} | {'%':>5} |")
    print(f"|{'-' * 72}|{'-' * 9}|{'-' * 7}|")
    for name, k in top:
        print(f"| {name[-70:]:<70} | {k:>7} | {100.0 * k / max(total, 1):>5.1f} |")
    return {"busy_samples": total, "inclusive_pct": paths,
            "top_own": [{"function": f, "samples": k} for f, k in top]}


def profile_summary(path: str, n: int = 15) -> list[dict[str, Any]]:
    """Print (and return) the ``n`` functions with the most own time in a cProfile dump."""
    import pstats

    st = pstats.Stats(path)
    stats: dict[tuple[str, int, str], tuple[int, int, float, float, Any]] = st.stats  # type: ignore[attr-defined]
    total = sum(v[2] for v in stats.values())
    rows = sorted(stats.items(), key=lambda kv: kv[1][2], reverse=True)[:n]
    out = []
    print(f"\nprofile ({path}): {total:.2f} s own time in all functions; top {n} by own time")
    print(f"| {'function':<60} | {'calls':>9} | {'own s':>7} | {'own %':>6} | {'cum s':>7} |")
    print(f"|{'-' * 62}|{'-' * 11}|{'-' * 9}|{'-' * 8}|{'-' * 9}|")
    for (file, line, func), (_cc, nc, tt, ct, _callers) in rows:
        where = f"{Path(file).name}:{line}({func})" if line else func
        out.append({"function": where, "calls": nc, "own_s": round(tt, 3),
                    "own_pct": round(100.0 * tt / total, 1), "cum_s": round(ct, 3)})
        print(f"| {where[-60:]:<60} | {nc:>9} | {tt:>7.2f} | {100.0 * tt / total:>6.1f} "
              f"| {ct:>7.2f} |")
    return out


if __name__ == "__main__":
    sys.exit(main())
