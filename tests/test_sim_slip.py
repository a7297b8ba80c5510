"""firmware_sim's wandering sideslip (``[trajectory] slip_wander_rad`` / ``slip_wander_tau_s``):
a ground vehicle whose course leaves its heading on its own (loose ground, skid steering)."""

from __future__ import annotations

import math

import numpy as np

from firmware_sim import load_scenario
from firmware_sim.profiles import ground_profile, slip_wander
from firmware_sim.scenario import GroundSpec

DEG = math.pi / 180.0


def _course_minus_yaw(over: dict[str, object], seed: int) -> np.ndarray:
    spec = load_scenario("car480", over).trajectory
    assert isinstance(spec, GroundSpec)
    t = np.arange(0.0, 480.0, 0.01)
    prof = ground_profile(t, spec, seed)
    moving = np.hypot(prof.vel_n[:, 0], prof.vel_n[:, 1]) > 1.0
    course = np.arctan2(prof.vel_n[:, 1], prof.vel_n[:, 0])
    d = (course - prof.euler[:, 2] + math.pi) % (2.0 * math.pi) - math.pi
    return np.asarray(d[moving])


def test_no_wander_is_the_profile_as_before() -> None:
    """GIVEN car480 as shipped (no slip of any kind), THEN its course is its yaw exactly,
    whatever the seed: the new key adds nothing unless set."""
    for seed in (1, 7):
        assert np.max(np.abs(_course_minus_yaw({}, seed))) < 1e-9


def test_the_wander_has_its_sigma_its_correlation_and_is_smooth() -> None:
    """GIVEN slip_wander(sigma 1 deg, tau 2 s) over 2000 s on seeds 1-20,
    THEN pooled its RMS is 1 deg within 15 % and its correlation at lag tau is exp(-1/2)
    within 0.15 (the Gaussian shape the tones' frequencies are drawn for); its rate stays
    below 5 deg/s (a smooth path: a Gauss-Markov one of the same sigma and tau steps
    sigma sqrt(2 dt / tau) = 0.1 deg per 10-ms sample, 10 deg/s); seeds differ, a seed
    repeats."""
    t = np.arange(0.0, 2000.0, 0.01)
    lag = 200
    rms, corr = [], []
    for seed in range(1, 21):
        b = slip_wander(t, DEG, 2.0, seed)
        rms.append(np.mean(b**2))
        corr.append(np.mean(b[:-lag] * b[lag:]) / np.mean(b**2))
        assert np.max(np.abs(np.diff(b))) / 0.01 < 5.0 * DEG, seed
    assert abs(math.sqrt(np.mean(rms)) / DEG - 1.0) < 0.15, math.sqrt(np.mean(rms)) / DEG
    assert abs(np.mean(corr) - math.exp(-0.5)) < 0.15, np.mean(corr)
    assert not np.allclose(slip_wander(t, DEG, 2.0, 1), slip_wander(t, DEG, 2.0, 2))
    assert np.array_equal(slip_wander(t, DEG, 2.0, 3), slip_wander(t, DEG, 2.0, 3))


def test_the_course_carries_the_wander() -> None:
    """GIVEN car480 with slip_wander_rad = 1 deg, THEN course - yaw while moving is that
    wander: RMS of order 1 deg, not 0, and the same function of time slip_wander draws."""
    d = _course_minus_yaw({"trajectory.slip_wander_rad": DEG}, 4)
    assert 0.3 * DEG < float(np.sqrt(np.mean(d**2))) < 2.0 * DEG
    spec = load_scenario("car480").trajectory
    t = np.arange(0.0, 480.0, 0.01)
    prof = ground_profile(t, spec, 4)
    moving = np.hypot(prof.vel_n[:, 0], prof.vel_n[:, 1]) > 1.0
    want = slip_wander(t, DEG, 2.0, 4)[moving]
    assert np.max(np.abs(d - want)) < 1e-9
