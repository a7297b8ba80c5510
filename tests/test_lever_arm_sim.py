"""The GNSS antenna's lever arm end to end: simulated at the antenna, removed by the filter.

A multirotor that yaws at 60 deg/s moves an antenna 0.36 m off its IMU at ~0.4 m/s; a filter
told the lever arm is zero explains that velocity by accelerometer bias and tilt (log171's
roll offset, docs/results.md "log171's remaining roll").  With a quiet IMU (so that the lever
arm, not the sensor noise, is what limits the tilt) this checks that the filter's lever-arm
model, given the right lever arm, takes the effect out.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from bench_util import load_benchmark

from firmware_sim import generate, load_scenario

rb = load_benchmark("robustness")

LEVER = [0.0, -0.3, -0.2]
# six 90-deg yaws in 1.5 s each (60 deg/s), alternating, every 20 s from 40 s
SCENARIO: dict[str, Any] = {
    "duration_s": 160.0, "imu.grade": "mems_seed001_h",
    "trajectory.turns": [{"t_s": 40.0 + 20.0 * k, "dur_s": 1.5,
                          "dyaw_deg": 90.0 if k % 2 == 0 else -90.0} for k in range(6)]}


def _tilt_after_60s(lever: list[float] | None, config: tuple[str, ...]) -> tuple[float, float]:
    over = dict(SCENARIO)
    if lever is not None:
        over["gnss.lever_arm_m"] = lever
    r = rb.score_sim(generate(load_scenario("multirotor", over), seed=1), "multirotor",
                     config)
    m = r.t_s >= 60.0
    e, sd = r.err_deg[m, :2], r.sd_deg[m, :2]
    return float(np.sqrt(np.mean(e * e))), float(np.mean(np.abs(e) > 3.0 * sd))


def test_configured_lever_arm_takes_the_antenna_motion_out() -> None:
    """GIVEN the multirotor scenario with a quiet IMU (VRW 0.005 m/s/sqrt(s)) and six 60 deg/s
    yaws, flown with the antenna at the IMU and at (0, -0.3, -0.2) m from it,
    WHEN each is run with the default config, the second with and without
    `gnss.lever_arm_m=[0,-0.3,-0.2]`,
    THEN with the lever arm configured the tilt RMS after 60 s is within 1.5x (+0.01 deg) of
    the antenna-at-the-IMU run's; left at zero it is over 2x that, and every run's tilt
    stays within 3 sigma in at least 95 % of instants.

    Measured (seed 1): at the IMU 0.043 deg, lever arm configured 0.046, left at zero 0.123;
    seeds 2-5: 0.016-0.042, 0.018-0.050 and 0.135-0.166 deg."""
    base, b_out = _tilt_after_60s(None, ())
    known, k_out = _tilt_after_60s(LEVER, ("gnss.lever_arm_m=[0,-0.3,-0.2]",))
    unknown, u_out = _tilt_after_60s(LEVER, ())
    assert known <= 1.5 * base + 0.01, (base, known)
    assert unknown > 2.0 * known, (known, unknown)
    assert max(b_out, k_out, u_out) <= 0.05, (b_out, k_out, u_out)
