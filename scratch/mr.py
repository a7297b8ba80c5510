import sys, math, time
import numpy as np
from firmware_sim import generate, load_scenario
from firmware_sim.score import score_run
from navd.config import EstimatorConfig, load_config
from navd.core.estimator import Estimator

scen = sys.argv[1] if len(sys.argv) > 1 else "multirotor"
seeds = [int(x) for x in sys.argv[2].split(",")] if len(sys.argv) > 2 else [1]
extra = sys.argv[3:]
for seed in seeds:
    run = generate(load_scenario(scen), seed=seed, progress=False)
    cfg = EstimatorConfig.from_dict(load_config(None, ["filter.profile=multirotor", *extra]))
    e = Estimator(cfg)
    t0 = time.time()
    s = score_run(run, cfg, est=e)
    err = s.euler_err_deg[:, 2]; sd = s.euler_sd_deg[:, 2]
    al = s.aligned
    t_al = s.t_s[al][0] if al.any() else math.nan
    rms = math.sqrt(np.mean(err[al]**2)) if al.any() else math.nan
    out3 = np.mean(np.abs(err[al]) > 3*sd[al])*100 if al.any() else math.nan
    mx = np.max(np.abs(err[al])) if al.any() else math.nan
    c = {k: v for k, v in e.counters.items() if k.startswith("yaw_bank")}
    print(f"seed {seed}: t_al {t_al:.1f} rms {rms:.2f} max {mx:.1f} >3sd {out3:.1f}% final err {err[-1]:.2f} sd {sd[-1]:.2f} {c} [{time.time()-t0:.1f}s]")
