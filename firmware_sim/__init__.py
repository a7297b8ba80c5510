"""Sensor simulator for navd: truth trajectories, IMU and GNSS error models, replay files.

Truth is built so that an error-free IMU replayed through navd's own strapdown reproduces it
to round-off (:mod:`firmware_sim.truth`); sensor errors are added on top
(:mod:`firmware_sim.sensors`).  Typical use::

    from firmware_sim import load_scenario, generate
    sc = load_scenario("car480", overrides={"duration_s": 60.0})
    run = generate(sc, seed=1)
    for s in run.samples(): ...

Conventions are navd's (NED, FRD, ZYX Euler, SI, integer microseconds).
"""

from firmware_sim.run import SimRun, generate
from firmware_sim.scenario import Scenario, ScenarioError, builtin_scenarios, load_scenario

__all__ = ["Scenario", "ScenarioError", "SimRun", "builtin_scenarios", "generate",
           "load_scenario"]
