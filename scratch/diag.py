import sys, math
import numpy as np
from firmware_sim import generate, load_scenario
from navd.config import EstimatorConfig, load_config
from navd.core.estimator import Estimator
from navd.core.rotation import mat_to_euler
from navd.types import GnssSample, ImuSample
from navd.core.aiding import yaw_bank_kernels as yk

scen = sys.argv[1]; seed = int(sys.argv[2]); extra = sys.argv[3:]
import json, os
ov = json.loads(os.environ.get("SIMOV", "{}"))
run = generate(load_scenario(scen, ov), seed=seed, progress=False)
g0 = next(iter(run.gnss_samples())); print("gnss vel_acc", g0.vel_acc_mps, g0.t_us)
cfg = EstimatorConfig.from_dict(load_config(None, [f"filter.profile={os.environ.get('PROF','multirotor')}", *extra]))
e = Estimator(cfg)
t0 = int(run.truth_t_us[0]); dtt = int(run.truth_t_us[1] - run.truth_t_us[0])
last = -10
for smp in run.samples():
    e.push(smp)
    if isinstance(smp, GnssSample) and e.initialized and e.yaw_bank is not None:
        t = smp.t_us * 1e-6
        if t - last < 1.0: continue
        last = t
        k = (e.t_us - t0) // dtt
        ty = run.truth_euler[k, 2]
        y = mat_to_euler(e.mat_nb)[2]
        err = math.degrees(yk.wrap(y - ty))
        b = e.yaw_bank
        berr = math.degrees(yk.wrap(y + b.offset - ty))
        w = b.buf[yk.MEM + yk.M_W: yk.MEM + 16*yk.MW: yk.MW][:b.n]
        ms = [math.degrees(yk.wrap(y + b.buf[yk.MEM+i*yk.MW+2] - ty)) for i in range(b.n)]
        ib = int(np.argmax(w))
        print(f"{t:6.1f} st {b.state} al {int(e.heading_aligned)} err {err:7.2f} sd {math.degrees(math.sqrt(e.P[2,2])):6.2f} bank_err {berr:7.2f} bsd {math.degrees(b.sd):6.2f} exc {b.buf[yk.H_EXC]:.2f} wmax {w[ib]:.2f} mbest {ms[ib]:7.1f} bgz {math.degrees(e.bias_g[2])*3600:8.1f}")
print({k: v for k, v in e.counters.items() if k.startswith(("yaw_bank", "heading", "reset"))})
