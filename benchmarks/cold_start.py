"""Start-up of ``navd run``: time to READY and to the first ATTITUDE (issue 18).

    python benchmarks/cold_start.py [--runs N] [--modes prebuilt,jit] [--json PATH]

Each start is a real ``navd run`` subprocess with MAVLink in and out and Zenoh on loopback,
and a sender that streams a simulated drive (car480, 1 kHz HIGHRES_IMU + 10 Hz GPS_INPUT) from
the moment the process is started, as an autopilot that is already running would; what
arrives before navd listens is lost, as it would be.

Per mode, two starts on one numba cache directory (NUMBA_CACHE_DIR, a fresh one per run):
  cold   the cache is empty: a first start after installing navd
  warm   the second start on the cache the first one left: every later start
Modes: ``prebuilt`` = the kernels compiled at install (navd/core/_aot, NAVD_AOT=1),
``jit`` = NAVD_AOT=0 (numba compiles on the first start, as before issue 18).

Figures, from the process start: READY (sd_notify READY=1: kernels ready, links open), the
process's CPU seconds at READY (user + system, /proc; the part a slower computer stretches),
and the first ATTITUDE received.  The gap from READY to the first ATTITUDE is sensor time
(the estimator levels for ``[filter] level_time_s`` = 1 s of IMU data before navigating),
which a slower computer does not stretch; "Pi estimate" = 4 x CPU to READY + that gap.
Targets: cold start to first ATTITUDE <= 3 s, warm start (READY) <= 1 s.

navd's modules are byte-compiled first (``compileall``), as ``pip install`` does: with
PYTHONDONTWRITEBYTECODE set and no ``.pyc``, every start would also compile ~100 modules.
"""

from __future__ import annotations

import argparse
import compileall
import contextlib
import json
import os
import platform
import re
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from firmware_sim import generate, load_scenario
from firmware_sim.stream import mavlink_events

ROOT = Path(__file__).resolve().parents[1]
CLK_TCK = os.sysconf("SC_CLK_TCK")
PI_FACTOR = 4.0


def free_port(kind: int = socket.SOCK_DGRAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLK_TCK


class Sender(threading.Thread):
    """Streams the frames at their sensor time from ``start()``; ignores refusals."""

    def __init__(self, frames: list[tuple[int, bytes, bool]], port: int) -> None:
        super().__init__(daemon=True)
        self.frames, self.addr, self.running = frames, ("127.0.0.1", port), True

    def run(self) -> None:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        t0_us, wall0 = self.frames[0][0], time.monotonic()
        for t_us, frame, _ in self.frames:
            if not self.running:
                break
            delay = wall0 + (t_us - t0_us) * 1e-6 - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            with contextlib.suppress(OSError):  # nobody listening yet
                sock.sendto(frame, self.addr)
        sock.close()


def first_attitude(sock: socket.socket, deadline: float) -> float | None:
    """monotonic time of the first ATTITUDE received on ``sock`` (None: none by deadline)."""
    mav = mavlink.MAVLink(None)
    while time.monotonic() < deadline:
        try:
            data = sock.recv(4096)
        except TimeoutError:
            continue
        now = time.monotonic()
        for m in mav.parse_buffer(data) or []:
            if m.get_type() == "ATTITUDE":
                return now
    return None


def one_start(frames: list[tuple[int, bytes, bool]], cache_dir: Path, aot: bool,
              timeout_s: float) -> dict[str, Any]:
    tmp = Path(tempfile.mkdtemp(prefix="navd-cold-"))
    port_in, port_out, port_z = free_port(), free_port(), free_port(socket.SOCK_STREAM)
    cfg = tmp / "navd.toml"
    cfg.write_text(
        f'[mavlink]\nlisten = "udpin:127.0.0.1:{port_in}"\n'
        f'send = "udpout:127.0.0.1:{port_out}"\nnominal_imu_rate_hz = 1000.0\n'
        f'[zenoh]\nvehicle = "cold{port_z}"\nlisten = ["tcp/127.0.0.1:{port_z}"]\n')
    notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    notify.bind(str(tmp / "notify"))
    notify.settimeout(0.05)
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", port_out))
    rx.settimeout(0.05)
    env = {**os.environ, "NOTIFY_SOCKET": str(tmp / "notify"),
           "NUMBA_CACHE_DIR": str(cache_dir), "NAVD_AOT": "1" if aot else "0"}
    env.pop("NAVD_AOT_DIR", None)
    log = open(tmp / "navd.log", "wb")  # noqa: SIM115 - closed below
    sender = Sender(frames, port_in)
    t0 = time.monotonic()
    sender.start()
    proc = subprocess.Popen([sys.executable, "-m", "navd", "run", "--config", str(cfg)],
                            stdout=log, stderr=log, cwd=ROOT, env=env)
    out: dict[str, Any] = {"ready_s": None, "cpu_at_ready_s": None, "attitude_s": None}
    deadline = t0 + timeout_s
    try:
        while time.monotonic() < deadline and proc.poll() is None:
            try:
                msg = notify.recv(4096)
            except TimeoutError:
                continue
            if b"READY=1" in msg:
                out["cpu_at_ready_s"] = round(cpu_s(proc.pid), 3)
                out["ready_s"] = round(time.monotonic() - t0, 3)
                break
        if out["ready_s"] is not None:
            t_att = first_attitude(rx, deadline)
            if t_att is not None:
                out["attitude_s"] = round(t_att - t0, 3)
    finally:
        sender.running = False
        if proc.poll() is None:
            proc.terminate()
            proc.wait(30)
        log.close()
        notify.close()
        rx.close()
    text = (tmp / "navd.log").read_text(errors="replace")
    m = re.search(r"kernels: (\d+) prebuilt, (\d+) from numba's cache, (\d+) compiled", text)
    if m:
        out["kernels"] = {"prebuilt": int(m[1]), "numba_cache": int(m[2]),
                          "compiled": int(m[3])}
    m = re.search(r"estimator kernels ready in ([0-9.]+) s", text)
    out["warm_up_s"] = float(m[1]) if m else None
    if out["attitude_s"] is None:
        out["log_tail"] = text[-1500:]
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=1, help="repetitions of each mode")
    ap.add_argument("--modes", default="prebuilt,jit", help="prebuilt, jit or both")
    ap.add_argument("--timeout", type=float, default=180.0, help="seconds per start")
    ap.add_argument("--json", help="write the figures to this file")
    a = ap.parse_args(argv)
    modes = [m.strip() for m in a.modes.split(",") if m.strip()]
    compileall.compile_dir(ROOT / "navd", quiet=1)
    if "prebuilt" in modes:
        from navd.core._jit import AOT_DIR
        from navd.core.aot_build import is_stale

        why = is_stale(AOT_DIR)
        print(f"install-time kernels in {AOT_DIR}: {why or 'up to date'}"
              f"{' (make kernels rebuilds them)' if why else ''}", file=sys.stderr)
    print("generating car480 with a 1 kHz IMU, 60 s ...", file=sys.stderr)
    run = generate(load_scenario("car480", overrides={"imu.rate_hz": 1000.0,
                                                      "duration_s": 60.0}), seed=1)
    frames = list(mavlink_events(run))
    results: dict[str, Any] = {"machine": platform.platform(), "cpus": os.cpu_count(),
                               "python": platform.python_version(),
                               "load_avg_before": round(os.getloadavg()[0], 2), "starts": []}
    for r in range(a.runs):
        for mode in modes:
            with tempfile.TemporaryDirectory(prefix="navd-numba-") as cache:
                for cache_state in ("cold", "warm"):
                    print(f"run {r + 1}: {mode}, {cache_state} numba cache ...", file=sys.stderr)
                    res = one_start(frames, Path(cache), mode == "prebuilt", a.timeout)
                    res.update(mode=mode, cache=cache_state, run=r + 1)
                    results["starts"].append(res)
    results["load_avg_after"] = round(os.getloadavg()[0], 2)
    print(table(results))
    if a.json:
        Path(a.json).write_text(json.dumps(results, indent=1) + "\n")
    return 0


def _f(x: float | None, nd: int = 2) -> str:
    return "-" if x is None else f"{x:.{nd}f}"


def table(results: dict[str, Any]) -> str:
    lines = [f"navd cold start ({results['machine']}, {results['cpus']} CPUs, load average "
             f"{results['load_avg_before']} before / {results['load_avg_after']} after)",
             "| kernels | numba cache | READY s | CPU to READY s | first ATTITUDE s | "
             "Pi estimate s | kernels prebuilt / cached / compiled |",
             "|---|---|---|---|---|---|---|"]
    for s in results["starts"]:
        pi = None
        if s["attitude_s"] is not None and s["cpu_at_ready_s"] is not None:
            pi = PI_FACTOR * s["cpu_at_ready_s"] + (s["attitude_s"] - s["ready_s"])
        k = s.get("kernels")
        ks = f"{k['prebuilt']} / {k['numba_cache']} / {k['compiled']}" if k else "-"
        lines.append(f"| {s['mode']} | {s['cache']} | {_f(s['ready_s'])} | "
                     f"{_f(s['cpu_at_ready_s'])} | {_f(s['attitude_s'])} | {_f(pi, 1)} | {ks} |")
    lines.append("Targets: first ATTITUDE <= 3 s after a cold start (also on a Pi: the estimate "
                 f"column, {PI_FACTOR:g} x CPU to READY + the sensor wait); warm start "
                 "(READY) <= 1 s.")
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
