"""The gyro scale-factor allowance (navd.core.kalman.gyro_scale_allowance, issue 14).

A scale error s_i of body axis i makes s_i of every rotation about that axis into attitude
error.  The kernel adds its variance to P's attitude block as the net rotation grows.  The
kernel tests drive ``state.imu_step`` on a bare state buffer and compare the variance added
(the run with the allowance minus the same run without it) with the attitude errors that
gyros with drawn scale errors really make, rotation composed on rotation (Monte Carlo), not
with the kernel's own formula.  The end-to-end test is the benchmark's car case.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from bench_util import load_benchmark

from firmware_sim import generate, load_scenario
from firmware_sim.score import score_run
from navd.config import load_config
from navd.core import kalman
from navd.core import state as st
from navd.core.rotation import exp_so3
from navd.pipeline import build_estimator

DEG = math.pi / 180.0
DT = 0.01
SD = 0.01  # 1 % per axis


def fresh(scale_sd: float) -> st.StateViews:
    """A still state at 47 deg N rolled 40 deg, no IMU noise densities, small P; the
    allowance at ``scale_sd`` (0: off) with the shipped forgetting time."""
    v = st.StateViews(np.zeros(st.SIZE))
    v.mat_nb[:] = exp_so3(np.array([40.0 * DEG, 0.0, 0.0]))
    v.pos[:] = (47.0 * DEG, 8.0 * DEG, 400.0)
    v.P[:] = np.diag([1e-10] * 15)
    v.sf[0] = scale_sd**2
    v.sf[13] = kalman.SF_FORGET_S
    st.history_reset(v.buf)
    return v


def run(v: st.StateViews, rates: np.ndarray) -> None:
    """Feed body rates (N, 3) rad/s at DT with the specific force of the state's attitude
    at rest (the rotation's own specific force does not matter here)."""
    f_b = v.mat_nb.T @ np.array([0.0, 0.0, -9.80665])
    for k, w in enumerate(rates):
        st.imu_step(v.buf, float((k + 1) * round(DT * 1e6)), w[0] * DT, w[1] * DT, w[2] * DT,
                    f_b[0] * DT, f_b[1] * DT, f_b[2] * DT, DT, False, DT)


def added(rates: np.ndarray, scale_sd: float = SD) -> np.ndarray:
    """The attitude covariance (3, 3) rad^2 the allowance adds over ``rates``."""
    a, b = fresh(scale_sd), fresh(0.0)
    run(a, rates)
    run(b, rates)
    return (a.P[0:3, 0:3] - b.P[0:3, 0:3]).copy()


def monte_carlo(rates: np.ndarray, scale_sd: float = SD, n: int = 4000,
                seed: int = 1) -> np.ndarray:
    """E[phi phi^T] (3, 3) rad^2 of the navigation-frame attitude error that gyros with
    scale errors s ~ N(0, scale_sd^2) per axis make over ``rates``, from the attitude
    started rolled 40 deg (as :func:`fresh`), composing the rotations exactly."""
    c0 = exp_so3(np.array([40.0 * DEG, 0.0, 0.0]))
    true = c0.copy()
    for w in rates:
        true = true @ exp_so3(w * DT)
    rng = np.random.default_rng(seed)
    out = np.zeros((3, 3))
    for s in rng.normal(0.0, scale_sd, (n, 3)):
        c = c0.copy()
        for w in rates:
            c = c @ exp_so3((1.0 + s) * w * DT)
        e = c @ true.T  # C_est C_true^T = exp(phi x), phi small
        phi = 0.5 * np.array([e[2, 1] - e[1, 2], e[0, 2] - e[2, 0], e[1, 0] - e[0, 1]])
        out += np.outer(phi, phi)
    return out / n


def test_a_quick_turn_adds_the_variance_its_scale_errors_make() -> None:
    """GIVEN a vehicle rolled 40 deg that turns 90 deg about its body z axis in 0.5 s (so the
    error lies along the tilted body axis in the navigation frame, heading and tilt),
    WHEN the allowance is on at 1 % per axis,
    THEN the attitude covariance it adds is the one 4000 gyros with drawn 1 % scale errors
    really make, element by element within 8 % of the largest (the forgetting, 5 s, takes
    ~3 % of a 0.5-s turn; the Monte Carlo's own scatter is ~2 %).  A sign or frame slip
    (the body-frame vector instead of C e_z) moves the off-diagonal terms by ~100 %."""
    rates = np.tile([0.0, 0.0, 0.5 * math.pi / 0.5], (50, 1))
    got = added(rates)
    want = monte_carlo(rates)
    assert np.trace(want) == pytest.approx((SD * 0.5 * math.pi) ** 2, rel=0.05)  # s^2 Th^2
    scale = float(np.max(np.abs(want)))
    assert np.max(np.abs(got - want)) < 0.08 * scale, (got, want)


def test_a_turn_back_adds_nothing_and_a_wobble_adds_its_amplitude_once() -> None:
    """GIVEN a 90 deg turn about body z in 0.5 s followed at once by the turn back, and
    separately a +-5 deg roll wobble at 1 Hz for 10 s,
    WHEN the allowance is on,
    THEN the turn back adds < 5 % of what the turn added (the scale errors' error returns
    to zero with the net rotation, the Monte Carlo agrees), and the wobble adds at least its
    amplitude's share, s^2 (5 deg)^2, but < 5 % of what a steady turn through the same total
    angle (200 deg in 10 s) adds: the allowance follows the net rotation, not the rate."""
    turn = np.tile([0.0, 0.0, math.pi], (50, 1))
    there = added(turn)
    back = added(np.vstack([turn, -turn]))
    assert back[2, 2] - there[2, 2] < 0.05 * there[2, 2], (there, back)
    assert monte_carlo(np.vstack([turn, -turn]), n=500)[2, 2] < 1e-3 * there[2, 2]

    t = np.arange(1000) * DT
    wobble = np.zeros((1000, 3))
    wobble[:, 0] = 5.0 * DEG * 2.0 * math.pi * np.cos(2.0 * math.pi * t)
    w_add = float(np.trace(added(wobble)))
    steady = float(np.trace(added(np.tile([200.0 * DEG / 10.0, 0.0, 0.0], (1000, 1)))))
    assert w_add > 0.9 * (SD * 5.0 * DEG) ** 2, w_add
    assert w_add < 0.05 * steady, (w_add, steady)


rb = load_benchmark("robustness")


def test_car_with_uncalibrated_gyro_scale_keeps_its_heading_within_3_sigma() -> None:
    """GIVEN the benchmark's car with gyro scale errors drawn at 1 % per axis (seeds 1-5, as
    the benchmark pools them; a 90 deg turn at 1 % puts 0.9 deg into the heading), default
    config,
    WHEN they are scored,
    THEN the aligned heading is beyond 3 sigma in <= 5 % of the pooled instants (measured
    0.1 %; 2.7 % with the allowance alone, before the course learnt the z scale), and with
    the allowance and the learning off (``imu.gyro_scale_sd_pct=0``) in > 10 % (measured
    21 %: the sigma stayed ~0.1 deg through turns that put 0.8 deg into the heading).  Both
    runs with the course-noise test off (``heading.adapt_course_noise=false``): it sees the
    heading error a scale error leaves correlated over turns too and takes the control to
    10.0 % on its own (docs/results.md, 2026-12-01), so it would blur what this measures."""
    case = next(c for c in rb.CASES if c.name == "gyro_sf_1pct")
    runs = [generate(load_scenario(case.scenario, dict(case.overrides)), seed=s,
                     progress=False) for s in range(1, 6)]

    def exceed(overrides: tuple[str, ...]) -> float:
        hit = n = 0
        for run_ in runs:
            r = rb.score_sim(run_, case.profile, overrides)
            m = r.aligned
            hit += int(np.sum(np.abs(r.err_deg[m, 2]) > 3.0 * r.sd_deg[m, 2]))
            n += int(m.sum())
        return 100.0 * hit / n

    on = exceed(("heading.adapt_course_noise=false",))
    assert on <= 5.0, on
    off = exceed(("imu.gyro_scale_sd_pct=0", "heading.adapt_course_noise=false"))
    assert off > 10.0, off


@pytest.mark.parametrize(("seed", "slip_deg"), [(2, 2.0), (5, 2.0), (5, 0.0)])
def test_the_course_tells_the_z_gyro_scale_from_the_sideslip(seed: int, slip_deg: float
                                                             ) -> None:
    """GIVEN the car with gyro scale errors drawn at 3 % per axis (seed 2: z +4.87 %, seed
    5: z -5.06 %; 3x the consumer preset's 1-sigma) and a sideslip of 2 deg per m/s^2 of
    lateral acceleration (and none), default config,
    WHEN it is scored,
    THEN the z scale error the course taught is within 0.6 % of the drawn one and the
    sideslip gain within 0.15 deg per m/s^2 of the simulated one (both change sign with the
    turn: a slip learner alone read the scale error as slip), and the aligned heading is
    beyond 3 sigma in <= 5 % of instants.

    Measured: learnt 5.17 / -5.25 / -5.19 %, slip 2.03 / 1.99 / 0.00 deg per m/s^2, beyond
    3 sigma 2.8 / 2.1 / 2.2 %; before the scale was learnt (allowance alone) seed 2 and 5
    without slip were 27.6 / 28.3 % (docs/results.md, "The z gyro's scale error learnt")."""
    over: dict[str, object] = {"imu.gyro_scale_factor_sigma_ppm": 30_000.0,
                               "trajectory.sideslip_gain_rad_per_mps2": slip_deg * DEG}
    run_ = generate(load_scenario("car480", over), seed=seed, progress=False)
    est = build_estimator(load_config(None, ["filter.profile=ground"]))
    sc = score_run(run_, est.cfg, 10.0, est=est)
    scale, _ = est.gnss.course.gyro_z_scale
    assert abs(scale - float(run_.gyro_scale[2])) <= 0.006, (scale, run_.gyro_scale)
    assert abs(math.degrees(est.gnss.course.slip_gain) - slip_deg) <= 0.15
    m = sc.aligned
    out = float(np.mean(np.abs(sc.euler_err_deg[m, 2]) > 3.0 * sc.euler_sd_deg[m, 2]))
    assert out <= 0.05, out
