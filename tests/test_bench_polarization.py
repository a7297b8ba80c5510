"""The polarization benchmark's scoring: the target rule and a short end-to-end case."""

from __future__ import annotations

from types import ModuleType

import pytest
from bench_util import load_benchmark


def _bench() -> ModuleType:
    return load_benchmark("polarization")


def test_target_rule() -> None:
    """GIVEN heading sigmas and the range of the sun's angle from the sensor axis,
    WHEN target_verdict and sun_axis_deg judge them,
    THEN sigma < 0.1 deg passes and 0.1 deg misses, a sun that stays inside the 10 deg cone is
    exempt but one that leaves it counts, and the sun's angle is taken from the nearer of
    boresight and anti-boresight (90 deg when the range crosses it)."""
    b = _bench()
    assert b.target_verdict(0.099, 25.0) == "pass"
    assert b.target_verdict(0.100, 25.0) == "MISS"
    assert b.target_verdict(5.0, 7.0).startswith("exempt")
    assert b.target_verdict(5.0, 10.5) == "MISS"  # leaves the cone: it counts
    # the sun's angle from the nearer axis: boresight (scatter 0) and anti-boresight (180)
    assert b.sun_axis_deg({"scatter_deg_min": 155.0, "scatter_deg_max": 162.0}) == (18.0, 25.0)
    assert b.sun_axis_deg({"scatter_deg_min": 19.0, "scatter_deg_max": 25.0}) == (19.0, 25.0)
    assert b.sun_axis_deg({"scatter_deg_min": 84.0, "scatter_deg_max": 96.0}) == (84.0, 90.0)


@pytest.mark.parametrize("pol_on", [True, False])
def test_short_static_case_scores_phi_d_beside_yaw(pol_on: bool) -> None:
    """GIVEN a 240 s static case pitched 60 deg, readings sent over the wire, with the
    polarization aid on or off,
    WHEN run_case scores it,
    THEN no wire decode fails; with the aid on phi_D RMS is under 0.3 deg from over 2000
    accepted readings and the ZYX yaw error exceeds it; with it off phi_D RMS exceeds 1 deg
    and no readings are counted."""
    b = _bench()
    r = b.run_case({"table": "S1", "tilt": 60, "variant": "static", "pol": pol_on,
                    "duration_s": 240.0, "seed": 1, "wire": True})
    assert r["wire_fail"] == 0
    if pol_on:
        assert r["phiD_rms_deg"] < 0.3 and r["counters"]["pol_accepted"] > 2000
        # pitched 60 deg, ZYX yaw carries tan(60) x a tilt error on top of phi_D
        assert r["heading_rms_deg"] > r["phiD_rms_deg"]
    else:
        assert r["phiD_rms_deg"] > 1.0 and "pol_accepted" not in r["counters"]
