"""The GNSS antenna's lever arm end to end: simulated at the antenna, removed by the filter.

A multirotor that yaws at 60 deg/s moves an antenna 0.36 m off its IMU at ~0.4 m/s; a filter
told the lever arm is zero explains that velocity by accelerometer bias and tilt (log171's
roll offset, docs/results.md "log171's remaining roll").  With a quiet IMU (so that the lever
arm, not the sensor noise, is what limits the tilt) this checks that the filter's lever-arm
model, given the right lever arm, takes the effect out.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from bench_util import load_benchmark

from firmware_sim import generate, load_scenario
from navd.core.aiding import adaptive_noise

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


def test_lever_arm_configured_or_uncertain_keeps_the_antenna_motion_out() -> None:
    """GIVEN the multirotor scenario with a quiet IMU (VRW 0.005 m/s/sqrt(s)) and six 60 deg/s
    yaws, flown with the antenna at the IMU and at (0, -0.3, -0.2) m from it,
    WHEN the second is run with the lever arm configured (1-sigma 0.05 m), with the default
    config (lever arm 0 with its default 1-sigma of 0.5 m), and with the lever arm 0 trusted
    (`gnss.lever_arm_sd_m=0`),
    THEN configured and default both keep the tilt RMS after 60 s within 1.5x (+0.01 deg) of
    the antenna-at-the-IMU run's; the trusted zero is over 2x the configured one; every run's
    tilt stays within 3 sigma in at least 95 % of instants.

    Measured (seed 1): at the IMU 0.031 deg, configured 0.043, default 0.033, trusted zero
    0.123; seeds 2-5 with the lever arm trusted at zero: 0.135-0.166 deg."""
    base, b_out = _tilt_after_60s(None, ())
    known, k_out = _tilt_after_60s(LEVER, ("gnss.lever_arm_m=[0,-0.3,-0.2]",
                                           "gnss.lever_arm_sd_m=0.05"))
    default, d_out = _tilt_after_60s(LEVER, ())
    trusted, t_out = _tilt_after_60s(LEVER, ("gnss.lever_arm_sd_m=0",))
    assert known <= 1.5 * base + 0.01, (base, known)
    assert default <= 1.5 * base + 0.01, (base, default)
    assert trusted > 2.0 * known, (known, trusted)
    assert max(b_out, k_out, d_out, t_out) <= 0.05, (b_out, k_out, d_out, t_out)


def test_car_with_an_unmeasured_roof_antenna_keeps_heading_sigma_honest(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """GIVEN car480 (seeds 1-3) whose antenna is 1 m behind, 0.3 m right of and 1.2 m above
    the IMU (benchmarks/robustness.py's lever_1.6m case), the lever arm not configured,
    WHEN it runs with the default config, with the lever-arm allowance alone (the gyro
    scale-factor allowance off, ``imu.gyro_scale_sd_pct=0``: it widens the heading sigma in
    turns too), and with neither (the control: the lever arm of zero trusted,
    ``gnss.lever_arm_sd_m=0``), each with the course innovations' test off (it raises the
    gyro noise on the persistence the lever arm leaves, so it would cover the control too:
    this test measures the allowance),
    THEN pooled over the seeds the aligned heading is beyond 3 sigma in at most 5 % of
    instants (issue 14's target) in the first two, where the control exceeds it: in a turn
    the antenna's course differs from the IMU's by (w x l) / v, which the control takes for
    heading.

    Measured: default 0.0 %, lever-arm allowance alone 3.4 % (seeds 1-3: 3.1 / 2.7 /
    4.5 %), control 6.4 % (5.4 / 6.1 / 7.9 %); with max_q_scale 100 (2026-11-28 f) 0.3 /
    3.4 / 6.3 %, and the control with the course test on 3.6 %."""
    monkeypatch.setattr(adaptive_noise, "_CM_UP", math.inf)
    share = []
    for config in ((), ("imu.gyro_scale_sd_pct=0",),
                   ("gnss.lever_arm_sd_m=0", "imu.gyro_scale_sd_pct=0")):
        ex = []
        for seed in (1, 2, 3):
            run = generate(load_scenario("car480",
                                         {"gnss.lever_arm_m": list(rb.LEVER_1_6M)}), seed=seed)
            r = rb.score_sim(run, "ground", config)
            al = r.aligned
            ex.append(np.abs(r.err_deg[al, 2]) > 3.0 * r.sd_deg[al, 2])
        share.append(float(np.mean(np.concatenate(ex))))
    assert share[0] <= 0.05, share
    assert share[1] <= 0.05, share
    assert share[2] > 0.05, share
