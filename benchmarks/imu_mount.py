"""An IMU turned on a ground vehicle about down, the turn not stated: is it told, its yaw on
the vehicle learnt, and is the heading of the IMU's own axes honest?

car480 (``--scenario``) with ``imu.mount_yaw_deg`` set in the simulator (the IMU's
increments turned, the truth the vehicle's) and navd's default config with
``filter.profile = ground`` (``--profile``; no ``[imu] mount_yaw_deg``).  Errors are
against the attitude of the IMU's axes, which is what navd reports when the mount is not
stated (docs/design.md §4, "An IMU turned on the
vehicle").  Per mount and seed: when the turn was (last) told,
the learnt yaw on the vehicle and its sigma at the end, the heading RMS and share of instants
beyond 3 sigma after the turn was told, and from ``--from-s`` on the heading
RMS, the share of instants beyond 3 sigma, the share flagged aligned and the largest
aligned error; roll / pitch RMS and beyond 3 sigma.

    .venv/bin/python benchmarks/imu_mount.py [--mounts 10,20,30,45,60,90,-90,120,180,0]
        [--seeds 1,2,3] [--from-s 300] [--jobs 2] [--scenario car480 --profile ground]
"""

from __future__ import annotations

import argparse
import math
import time
from concurrent.futures import ProcessPoolExecutor
from typing import Any

import numpy as np
import numpy.typing as npt
from robustness import RunResult, score_sim

from firmware_sim import SimRun, generate, load_scenario
from navd.config import load_config
from navd.core.rotation import euler_to_mat_into, mat_to_euler
from navd.pipeline import build_estimator


def imu_axes_errors(run: SimRun, r: RunResult, mount_deg: float) -> npt.NDArray[np.float64]:
    """navd's roll / pitch / heading errors (deg, (n, 3), at ``r.t_s``) against the attitude
    of the IMU's own axes: the vehicle's truth turned by ``mount_deg`` about down, what navd
    reports with no [imu] mount_yaw_deg."""
    tt = run.truth_t_us * 1e-6
    idx = np.clip(np.searchsorted(tt, r.t_s), 0, len(tt) - 1)
    rz = np.zeros((3, 3))
    euler_to_mat_into(rz, 0.0, 0.0, math.radians(mount_deg))
    est = run.truth_euler[idx] + np.radians(r.err_deg)
    imu = np.array([mat_to_euler(run.truth_mat_nb[i] @ rz) for i in idx])
    return np.asarray(np.degrees((est - imu + math.pi) % (2.0 * math.pi) - math.pi))


def run_case(case: tuple[float, int, float, str, str]) -> dict[str, Any]:
    mount, seed, from_s, scenario, profile = case
    run = generate(load_scenario(scenario, {"imu.mount_yaw_deg": mount}), seed=seed,
                   progress=False)
    est = build_estimator(load_config(None, [f"filter.profile={profile}"]))
    r = score_sim(run, profile, est=est)
    e = imu_axes_errors(run, r, mount)
    sd = r.sd_deg
    beyond = np.abs(e) > 3.0 * sd
    late = r.t_s >= from_s
    al = r.aligned
    mt = est.gnss.course.mount
    return {
        "mount": mount, "seed": seed,
        # when the turn was last told (by the watch or the travel-direction monitor)
        "told_s": mt.t_start_s if mt.active else math.nan,
        "mu_deg": math.degrees(mt.mu) if mt is not None and mt.active else math.nan,
        "mu_sd_deg": (math.degrees(math.sqrt(mt.var)) if mt is not None and mt.active
                      else math.nan),
        # after the turn was told (from 1 s on: the fix that told it is older than the
        # output instant it reached)
        "post_rms": (float(np.sqrt(np.mean(e[post, 2] ** 2))) if (post := (
            r.t_s >= (mt.t_start_s if mt.active else math.inf) + 1.0)).any() else math.nan),
        "post_beyond": 100.0 * float(beyond[post, 2].mean()) if post.any() else math.nan,
        "h_rms": float(np.sqrt(np.mean(e[late, 2] ** 2))),
        "h_beyond": 100.0 * float(beyond[late, 2].mean()),
        "aligned": 100.0 * float(al[late].mean()),
        # what the outputs call usable (NavSolution.heading_good): aligned, sigma within
        # [init] aligned_sd_deg; the largest error then
        "max_usable": (float(np.abs(e[use, 2]).max()) if (use := late & al & (
            sd[:, 2] <= math.degrees(est.cfg.init.aligned_sd) + 1e-9)).any() else math.nan),
        "usable": 100.0 * float(use[late].mean()),
        "max_al": float(np.abs(e[late & al, 2]).max()) if (late & al).any() else math.nan,
        "rp_rms": [float(np.sqrt(np.mean(e[late, i] ** 2))) for i in (0, 1)],
        "rp_beyond": [100.0 * float(beyond[late, i].mean()) for i in (0, 1)],
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mounts", default="10,20,30,45,60,90,-90,120,180,0")
    ap.add_argument("--seeds", default="1,2,3")
    ap.add_argument("--from-s", type=float, default=300.0)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--scenario", default="car480")
    ap.add_argument("--profile", default="ground")
    a = ap.parse_args(argv)
    cases = [(float(m), int(s), a.from_s, a.scenario, a.profile) for m in a.mounts.split(",")
             for s in a.seeds.split(",")]
    t0 = time.monotonic()
    with ProcessPoolExecutor(a.jobs) as ex:
        rows = list(ex.map(run_case, cases))
    print(f"{a.scenario}, from {a.from_s:.0f} s on (errors against the IMU's axes; default "
          f"config, {a.profile})")
    print("mount seed  told_s  mu +- sd (deg)   after told: rms >3s %   hdg rms  >3s %  "
          "aligned %  max al  usable %  max us   roll/pitch rms  >3s %")
    for r in rows:
        print(f"{r['mount']:5.0f} {r['seed']:4d} {r['told_s']:7.0f} {r['mu_deg']:7.2f} +- "
              f"{r['mu_sd_deg']:4.2f}   {r['post_rms']:15.2f} {r['post_beyond']:6.1f}   "
              f"{r['h_rms']:7.2f} {r['h_beyond']:6.1f} "
              f"{r['aligned']:9.0f} {r['max_al']:7.1f} {r['usable']:9.0f} {r['max_usable']:7.1f}   "
              f"{r['rp_rms'][0]:.2f} / "
              f"{r['rp_rms'][1]:.2f}     {r['rp_beyond'][0]:.1f} / {r['rp_beyond'][1]:.1f}")
    print(f"({time.monotonic() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
