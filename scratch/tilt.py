import sys, math, json, os
import numpy as np
from firmware_sim import generate, load_scenario
from navd.config import EstimatorConfig, load_config
from navd.core.estimator import Estimator
from navd.core.rotation import log_so3
from navd.types import GnssSample
scen=sys.argv[1]; seed=int(sys.argv[2])
run = generate(load_scenario(scen, json.loads(os.environ.get("SIMOV","{}"))), seed=seed, progress=False)
cfg = EstimatorConfig.from_dict(load_config(None, ["filter.profile=multirotor", *sys.argv[3:]]))
e = Estimator(cfg)
t0 = int(run.truth_t_us[0]); dtt = int(run.truth_t_us[1] - run.truth_t_us[0]); last=-10
for smp in run.samples():
    e.push(smp)
    if isinstance(smp, GnssSample) and e.initialized:
        t = smp.t_us*1e-6
        if t-last < 2: continue
        last=t
        k=(e.t_us-t0)//dtt
        phi = -np.array(log_so3(e.mat_nb @ run.truth_mat_nb[k].T))
        print(f"{t:6.1f} phiN {math.degrees(phi[0]):6.2f} phiE {math.degrees(phi[1]):6.2f} sd {math.degrees(math.sqrt(e.P[0,0])):5.2f} {math.degrees(math.sqrt(e.P[1,1])):5.2f} ba {e.bias_a*1000/9.8}")
