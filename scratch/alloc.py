from firmware_sim import generate, load_scenario
from firmware_sim.alloc import measure_steps
from navd.config import EstimatorConfig, load_config
from navd.core.estimator import Estimator
from navd.types import GnssSample, ImuSample
run = generate(load_scenario("multirotor", {"duration_s": 240.0, "trajectory.yaw0_deg": 0.0}), seed=1, progress=False)
e = Estimator(EstimatorConfig.from_dict(load_config(None, ["yaw_bank.enabled=auto", "filter.profile=multirotor"])))
a = measure_steps(e, list(run.samples()), warm_imu=30000, max_imu=10000)
print(a.peak, a.grew)
for st in a.snapshot.statistics("traceback")[:3]:
    print(st)
    for l in st.traceback.format()[-8:]: print(l)
