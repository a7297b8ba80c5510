"""Filter consistency (NEES) with the DEFAULT config on the robustness benchmark's Monte Carlo
car cases (issue 14, "NEES within its band on the Monte Carlo cases").  The figures per case,
pooled over 5 seeds, are the benchmark's NEES column (docs/results.md); this checks seed 1
of the car cases where the filter is consistent, so a change that makes it overconfident
fails here.  Cases where it is not (multirotor heading, 3x IMU noise, Gauss-Markov biases:
attitude NEES 5-11) are listed as NOT met in docs/results.md, not tested as if they were."""

from __future__ import annotations

import pytest
from bench_util import load_benchmark

from firmware_sim import generate, load_scenario

rb = load_benchmark("robustness")


@pytest.mark.parametrize("name", ["car_clean", "gyro_1", "accel_20mg", "sideslip_2"])
def test_car_cases_are_consistent(name: str) -> None:
    """GIVEN one of the benchmark's car cases (seed 1, default config, ground profile),
    WHEN its attitude and velocity NEES are averaged after 60 s,
    THEN the velocity NEES lies inside its 99 % chi-square band and the attitude NEES is not
    above the band (sigma never smaller than the error says; the consumer preset's wide
    accelerometer-bias prior leaves the tilt sigma conservative, NEES ~2)."""
    case = next(c for c in rb.CASES if c.name == name)
    run = generate(load_scenario(case.scenario, dict(case.overrides)), seed=1,
                   progress=False)
    fig = rb.nees_figures([rb.score_sim(run, case.profile)])
    lo, hi = fig["nees_band"]
    assert lo < fig["nees_vel"] < hi, fig
    assert fig["nees_att"] < hi, fig
