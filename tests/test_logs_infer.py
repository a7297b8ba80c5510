"""The vehicle type inferred from a GNSS track (navd/io/logs/infer.py), for logs that state
none: only a steep climb at walking pace says "multirotor"; cars, fixed wings, a car-park
spiral, noisy altitude and an altitude jump do not."""

from __future__ import annotations

import math

import numpy as np
import pytest

from firmware_sim import generate, load_scenario
from navd.io.logs.infer import infer_vehicle
from navd.types import GnssSample

DT = 0.2  # s, 5 Hz


def _track(t: np.ndarray, alt: np.ndarray, vn: np.ndarray, ve: np.ndarray,
           vd: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    g = np.zeros((t.size, 9))
    g[:, 2], g[:, 3], g[:, 4] = alt, vn, ve
    g[:, 5] = np.nan if vd is None else vd
    return np.rint(t * 1e6).astype(np.int64), g


def test_a_hover_take_off_is_a_multirotor() -> None:
    """GIVEN 20 s at rest, a 10 m climb in 10 s, then a hover, with 0.2 m/s of horizontal
    speed noise and 0.3 m of altitude noise (seeded),
    WHEN the vehicle is inferred, THEN multirotor, and the reason names the climb."""
    rng = np.random.default_rng(1)
    t = np.arange(0.0, 60.0, DT)
    alt = np.clip((t - 20.0), 0.0, 10.0) + rng.normal(0.0, 0.3, t.size)
    vd = -np.where((t >= 20.0) & (t < 30.0), 1.0, 0.0)
    v, why = infer_vehicle(*_track(t, alt, rng.normal(0, 0.2, t.size),
                                   rng.normal(0, 0.2, t.size), vd))
    assert v == "multirotor"
    assert why.startswith("inferred from the GNSS track: climbed")


@pytest.mark.parametrize("case", ["steep_road", "spiral_ramp", "noisy_rest", "jump"])
def test_what_is_not_a_hover_climb(case: str) -> None:
    """GIVEN a car climbing a 30 % grade at 3 m/s (13 m in 15 s over 43 m), a car circling a
    5 m-radius car-park ramp at 3 m/s (8 m up in 15 s, net displacement < 10 m but 45 m
    driven), a receiver at rest with 4 m white altitude noise (as the simulators make it),
    and a 10 m altitude jump that the vertical velocity (0) does not confirm,
    WHEN the vehicle is inferred, THEN nothing is inferred."""
    rng = np.random.default_rng(2)
    t = np.arange(0.0, 60.0, DT)
    z = np.zeros(t.size)
    if case == "steep_road":
        sp = 3.0 * math.cos(math.atan(0.3))
        track = _track(t, 0.3 * sp * t, np.full(t.size, sp), z, np.full(t.size, -0.3 * sp))
    elif case == "spiral_ramp":
        w = 3.0 / 5.0
        track = _track(t, 8.0 / 15.0 * t, 3.0 * np.cos(w * t), 3.0 * np.sin(w * t),
                       np.full(t.size, -8.0 / 15.0))
    elif case == "noisy_rest":
        track = _track(t, rng.normal(0.0, 4.0, t.size), rng.normal(0, 0.05, t.size),
                       rng.normal(0, 0.05, t.size), rng.normal(0, 0.08, t.size))
    else:
        track = _track(t, np.where(t > 30.0, 10.0, 0.0), z, z, z)
    assert infer_vehicle(*track) == ("", "")


@pytest.mark.parametrize("scenario, expect", [("car480", ""), ("fixed_wing_wind", ""),
                                               ("static", ""), ("multirotor", "multirotor")])
def test_simulated_vehicles(scenario: str, expect: str) -> None:
    """GIVEN the simulator's car, fixed wing (in wind), static receiver and multirotor
    (seed 1), WHEN their GNSS tracks are read as a log would be, THEN only the multirotor is
    inferred (as multirotor)."""
    run = generate(load_scenario(scenario), seed=1, progress=False)
    gs = [s for s in run.samples() if isinstance(s, GnssSample)]
    t = np.array([s.t_us for s in gs], dtype=np.int64)
    g = np.array([[s.lat_rad, s.lon_rad, s.alt_m, s.vel_n, s.vel_e, s.vel_d, s.h_acc_m,
                   s.v_acc_m, s.vel_acc_mps] for s in gs])
    assert infer_vehicle(t, g)[0] == expect
