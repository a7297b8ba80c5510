"""Benchmark of the windowed GNSS velocity estimators of navd.core.aiding.mctls.

A car-like truth (speed 10-24 m/s, turns at <= 4 m/s² lateral acceleration, gentle grades)
is integrated on WGS-84; a 10 Hz receiver reports ECEF velocity with white noise of its own
stated σ and a position that defines the ECEF→NED rotation.  Cases:

  a  realistic coefficient noise: position error Gauss-Markov, 10 m, 60 s (≈1.6e-6 rad)
  b  exaggerated coefficient noise: white position error per fix, σ log-uniform in
     [10 m, 300 km] and reported per fix (h_acc); LS ignores it, TLS uses it
  b2 exaggerated and uniform: white position error of 100 km on every fix
  c  runs of velocity jumps: bursts of 3-8 epochs every 5-15 s, 3-5 m/s, random direction

Estimators: the raw epoch (C_e^n v^e, no window), window LS, constrained TLS, robust MCTLS,
and LS with a χ² innovation gate (the cheap alternative).  Scored at the newest epoch:
RMS / 99th percentile of the 3-D velocity error, RMS course error (deg), mean NEES of the
reported covariance (3 is consistent), detection rate on jump epochs and false-alarm rate on
clean ones, and the mean cost of a push.

    .venv/bin/python benchmarks/mctls.py [--duration 600] [--seeds 2] [--orders 3,2]
                                         [--cases a,b,b2,c] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import math
import time
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from navd.core.aiding.mctls import Mctls
from navd.core.earth import mat_ne, radii

Arr = npt.NDArray[np.float64]
RATE_HZ = 10.0
MODES = ("ls", "tls", "mctls", "gate")
CASES = ("a", "b", "b2", "c")


@dataclass
class Truth:
    t_s: Arr  # (n,) epoch times, s
    vel_n: Arr  # (n, 3) NED velocity, m/s
    lat_rad: Arr  # (n,)
    lon_rad: Arr  # (n,)


def car_truth(duration_s: float, rng: np.random.Generator) -> Truth:
    """Car-like trajectory sampled at the GNSS rate (integrated at 100 Hz)."""
    dt = 0.01
    n = round(duration_s / dt) + 1
    t = np.arange(n) * dt
    ph = rng.uniform(0, 2 * np.pi, 3)
    speed = (17.0 + 4.5 * np.sin(2 * np.pi * t / 70 + ph[0])
             + 2.5 * np.sin(2 * np.pi * t / 23 + ph[1]))
    speed = np.clip(speed, 10.0, 24.0)
    # Turns: raised-cosine yaw-rate pulses sized for <= 4 m/s² lateral acceleration.
    yaw_rate = np.zeros(n)
    t0 = 5.0
    while t0 < duration_s:
        ang = math.radians(rng.uniform(20, 120)) * rng.choice([-1.0, 1.0])
        v_at = speed[min(n - 1, int(t0 / dt))]
        dur = max(3.0, 2.0 * abs(ang) * v_at / 4.0)
        sel = (t >= t0) & (t < t0 + dur)
        yaw_rate[sel] += ang / dur * (1.0 - np.cos(2 * np.pi * (t[sel] - t0) / dur))
        t0 += dur + rng.uniform(5, 20)
    yaw = rng.uniform(-np.pi, np.pi) + np.cumsum(yaw_rate) * dt
    grade = 0.03 * np.sin(2 * np.pi * t / 50 + ph[2])
    vel = np.stack([speed * np.cos(yaw) * np.cos(grade), speed * np.sin(yaw) * np.cos(grade),
                    -speed * np.sin(grade)], axis=1)
    lat = np.empty(n)
    lon = np.empty(n)
    h = 100.0
    lat[0], lon[0] = 0.6, 2.0
    for i in range(n - 1):
        r_m, r_n = radii(lat[i])
        lat[i + 1] = lat[i] + vel[i, 0] / (r_m + h) * dt
        lon[i + 1] = lon[i] + vel[i, 1] / ((r_n + h) * math.cos(lat[i])) * dt
        h -= vel[i, 2] * dt
    step = round(1.0 / (RATE_HZ * dt))
    return Truth(t[::step].copy(), vel[::step].copy(), lat[::step].copy(), lon[::step].copy())


@dataclass
class Measurements:
    vel_e: Arr  # (n, 3) reported ECEF velocity, m/s
    sigma: Arr  # (n,) reported speed accuracy, m/s
    lat_rad: Arr  # (n,) reported position
    lon_rad: Arr
    pos_sigma_m: Arr  # (n,) reported horizontal position accuracy, m
    jump: npt.NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, dtype=bool))


def measure(tr: Truth, case: str, rng: np.random.Generator) -> Measurements:
    n = tr.t_s.size
    sigma = 0.14 + 0.06 * np.sin(2 * np.pi * tr.t_s / 40.0 + rng.uniform(0, 6))
    if case in ("a", "c"):
        # Gauss-Markov position error, 10 m steady-state, 60 s correlation.
        a = math.exp(-1.0 / (RATE_HZ * 60.0))
        err = np.zeros((n, 2))
        err[0] = rng.normal(0, 10.0, 2)
        for i in range(1, n):
            err[i] = a * err[i - 1] + rng.normal(0, 10.0 * math.sqrt(1 - a * a), 2)
        pos_sigma = np.full(n, 10.0)
    elif case == "b":
        pos_sigma = np.exp(rng.uniform(math.log(10.0), math.log(3e5), n))
        err = rng.normal(0, 1, (n, 2)) * pos_sigma[:, None]
    else:
        pos_sigma = np.full(n, 1e5)
        err = rng.normal(0, 1, (n, 2)) * pos_sigma[:, None]
    lat = np.empty(n)
    lon = np.empty(n)
    vel_e = np.empty((n, 3))
    for i in range(n):
        r_m, r_n = radii(tr.lat_rad[i])
        lat[i] = tr.lat_rad[i] + err[i, 0] / r_m
        lon[i] = tr.lon_rad[i] + err[i, 1] / (r_n * math.cos(tr.lat_rad[i]))
        vel_e[i] = mat_ne(tr.lat_rad[i], tr.lon_rad[i]).T @ tr.vel_n[i]
    vel_e += rng.normal(0, 1, (n, 3)) * sigma[:, None]
    jump = np.zeros(n, dtype=bool)
    if case == "c":
        i = int(rng.integers(30, 80))
        while i < n:
            ln = int(rng.integers(3, 9))
            mag = rng.uniform(3.0, 5.0)
            az = rng.uniform(0, 2 * np.pi)
            el = rng.uniform(-0.3, 0.3)
            d_n = mag * np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az),
                                  math.sin(el)])
            for k in range(i, min(n, i + ln)):
                vel_e[k] += mat_ne(lat[k], lon[k]).T @ d_n
                jump[k] = True
            i += ln + int(rng.integers(50, 150))
    return Measurements(vel_e, sigma, lat, lon, pos_sigma, jump)


def course_err_deg(v: Arr, v_true: Arr) -> float:
    d = math.atan2(v[1], v[0]) - math.atan2(v_true[1], v_true[0])
    return math.degrees((d + math.pi) % (2 * math.pi) - math.pi)


@dataclass
class Score:
    err: list[float] = field(default_factory=list)
    course: list[float] = field(default_factory=list)
    nees: list[float] = field(default_factory=list)
    burst_err: list[float] = field(default_factory=list)
    det: int = 0
    n_jump: int = 0
    fa: int = 0
    n_clean: int = 0
    cost_s: float = 0.0
    pushes: int = 0


def method_names(orders: list[int]) -> list[str]:
    """"raw" then "<mode><order>" for every order, e.g. "mctls3"."""
    return ["raw"] + [f"{m}{o}" for o in orders for m in MODES]


def run_case(tr: Truth, ms: Measurements, orders: list[int], window: int,
             scores: dict[str, Score]) -> None:
    ests = {f"{m}{o}": Mctls(window=window, order=o, mode=m) for o in orders for m in MODES}
    names = method_names(orders)
    v = np.empty(3)
    cov = np.empty((3, 3))
    for i in range(tr.t_s.size):
        ve = ms.vel_e[i]
        for name in names:
            sc = scores[name]
            if name == "raw":
                c = mat_ne(ms.lat_rad[i], ms.lon_rad[i])
                v[:] = c @ ve
                cov[:] = np.eye(3) * ms.sigma[i] ** 2
                flagged = False
                ok = True
            else:
                est = ests[name]
                t0 = time.perf_counter()
                ok = est.push(float(tr.t_s[i]), ve, float(ms.sigma[i]), float(ms.lat_rad[i]),
                              float(ms.lon_rad[i]), float(ms.pos_sigma_m[i]))
                sc.cost_s += time.perf_counter() - t0
                sc.pushes += 1
                v[:] = est.vel_n
                cov[:] = est.cov_n
                flagged = est.newest_outlier
            if i < window or not ok:
                continue
            e = v - tr.vel_n[i]
            sc.err.append(float(np.linalg.norm(e)))
            sc.course.append(course_err_deg(v, tr.vel_n[i]))
            sc.nees.append(float(e @ np.linalg.solve(cov, e)))
            if ms.jump[i]:
                sc.n_jump += 1
                sc.det += int(flagged)
                sc.burst_err.append(float(np.linalg.norm(e)))
            else:
                sc.n_clean += 1
                sc.fa += int(flagged)


def summarize(sc: Score) -> dict[str, float]:
    err = np.asarray(sc.err)
    crs = np.asarray(sc.course)
    out = {
        "rms_vel_mps": float(np.sqrt(np.mean(err**2))),
        "p99_vel_mps": float(np.percentile(err, 99)),
        "rms_course_deg": float(np.sqrt(np.mean(crs**2))),
        "mean_nees": float(np.mean(sc.nees)),
        "false_alarm_rate": sc.fa / max(1, sc.n_clean),
        "push_us": 1e6 * sc.cost_s / sc.pushes if sc.pushes else float("nan"),
        "epochs": float(err.size),
    }
    if sc.n_jump:
        out["detection_rate"] = sc.det / sc.n_jump
        out["rms_vel_in_bursts_mps"] = float(np.sqrt(np.mean(np.asarray(sc.burst_err) ** 2)))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--duration", type=float, default=600.0, help="seconds per run")
    ap.add_argument("--seeds", type=int, default=2, help="independent runs per case")
    ap.add_argument("--orders", default="3,2",
                    help="comma-separated polynomial orders (3 = constant jerk, the default)")
    ap.add_argument("--window", type=int, default=20, help="epochs per window")
    ap.add_argument("--cases", default=",".join(CASES), help="comma-separated subset of a,b,b2,c")
    ap.add_argument("--json", help="write the figures to this path")
    args = ap.parse_args()
    cases = [c for c in args.cases.split(",") if c]
    orders = [int(o) for o in args.orders.split(",") if o]
    names = method_names(orders)
    results: dict[str, dict[str, dict[str, float]]] = {}
    # Compile (or load from cache) outside the timed pushes.
    Mctls().push(0.0, np.ones(3), 0.1, 0.6, 2.0)
    t_start = time.perf_counter()
    for case in cases:
        scores = {m: Score() for m in names}
        for seed in range(args.seeds):
            rng = np.random.default_rng(1000 * seed + ord(case[0]) + len(case))
            tr = car_truth(args.duration, rng)
            ms = measure(tr, case, rng)
            run_case(tr, ms, orders, args.window, scores)
        results[case] = {m: summarize(scores[m]) for m in names}
    wall = time.perf_counter() - t_start

    hdr = (f"{'case':<4} {'method':<7} {'rms v':>7} {'p99 v':>7} {'burst v':>8} {'course':>7} "
           f"{'NEES':>7} {'detect':>7} {'f.alarm':>8} {'push':>7}")
    print(f"window {args.window}, orders {args.orders} (method name = mode + order), "
          f"{args.seeds} x {args.duration:.0f} s at {RATE_HZ:.0f} Hz per case;\n"
          "velocities m/s (3-D error at the newest epoch), course deg RMS, push µs")
    print(hdr)
    print("-" * len(hdr))
    for case in cases:
        for m in names:
            r = results[case][m]
            burst = r.get("rms_vel_in_bursts_mps", float("nan"))
            det = r.get("detection_rate", float("nan"))
            print(f"{case:<4} {m:<7} {r['rms_vel_mps']:7.3f} {r['p99_vel_mps']:7.3f} "
                  f"{burst:8.3f} {r['rms_course_deg']:7.3f} {r['mean_nees']:7.2f} "
                  f"{det:7.3f} {r['false_alarm_rate']:8.4f} {r['push_us']:7.1f}")
        print()
    print(f"wall time {wall:.1f} s")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"args": vars(args), "results": results, "wall_s": wall}, f, indent=2)


if __name__ == "__main__":
    main()
