import sys, math, os
import numpy as np
sys.path.insert(0, "benchmarks")
import yaw_bank as ybm
from firmware_sim import generate, load_scenario
from navd.config import load_config
from navd.pipeline import build_estimator, solutions
from navd.core.aiding import yaw_bank_kernels as yk
scen = sys.argv[1]; prof = sys.argv[2]; seeds = [int(x) for x in sys.argv[3].split(",")]; extra = sys.argv[4:]
tot_false = 0
for seed in seeds:
    run = generate(load_scenario(scen), seed=seed, progress=False)
    est = build_estimator(load_config(None, [f"filter.profile={prof}", *extra]))
    t0 = int(run.truth_t_us[0]); dtt = int(run.truth_t_us[1] - run.truth_t_us[0])
    rows = []
    for sol in solutions(est, run.samples(), 10.0):
        k = (sol.t_us - t0) // dtt
        e = yk.wrap(sol.yaw_rad - run.truth_euler[k, 2])
        rows.append((sol.t_us*1e-6, math.degrees(e), math.degrees(sol.att_sd_rad[2]), sol.heading_aligned))
    a = np.array(rows)
    al = a[:, 3] > 0
    t_al = a[al, 0][0] if al.any() else math.nan
    rms = math.sqrt(np.mean(a[al, 1]**2)) if al.any() else math.nan
    ex = np.mean(np.abs(a[al, 1]) > 3*a[al, 2])*100 if al.any() else math.nan
    mx = np.max(np.abs(a[al, 1])) if al.any() else math.nan
    fa = mx > 10
    tot_false += fa
    c = {k.replace("yaw_bank_", ""): v for k, v in est.counters.items() if k.startswith("yaw_bank")}
    print(f"seed {seed}: t_al {t_al:6.1f} rms {rms:5.2f} max {mx:6.1f} >3sd {ex:5.1f}% {'FALSE' if fa else ''} {c}")
print("false", tot_false)
