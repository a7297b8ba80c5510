"""The attitude variance a point-sampled rate adds (navd.core.kalman.imu_step, issue 14).

An increment made from a rate sampled at one instant misses what the rate did between
samples.  Each step adds, per axis, (|d2|^2 - 18 q dt) / 12 when positive, d2 being the
second difference of the angle increments (what a rate changing linearly over a few steps
cannot explain), 18 q dt three times what the gyro's white noise alone gives |d2|^2.  These
tests drive the kernel on a state buffer directly and check it against an independent
numpy computation of that sum.
"""

from __future__ import annotations

import math

import numpy as np

from navd.core import state as st

DEG = math.pi / 180.0
ARW = 0.3 * DEG / 60.0  # rad/sqrt(s), consumer
DT = 0.02  # 50 Hz, a log's IMU message rate
COV_INTERVAL = 0.1


def fresh(arw: float = ARW) -> st.StateViews:
    """A level, still state at 47 deg N with white-noise densities for gyro ARW ``arw``
    (no bias walk)."""
    v = st.StateViews(np.zeros(st.SIZE))
    v.mat_nb[:] = np.eye(3)
    v.pos[:] = (47.0 * DEG, 8.0 * DEG, 400.0)
    v.q[0:3] = arw**2
    v.q[3:6] = 0.02**2
    # biases known (1e-12): how their variance turns into attitude depends on the body's
    # turning, which differs between the runs compared here
    v.P[:] = np.diag([(1.0 * DEG) ** 2] * 3 + [0.1**2] * 3 + [1e-12] * 2 + [1.0]
                     + [1e-12] * 6)
    st.history_reset(v.buf)
    return v


def run(v: st.StateViews, rates: np.ndarray, dt: float = DT) -> None:
    """Feed body rates (N, 3) rad/s at interval ``dt`` with a level vehicle's specific force."""
    g_dt = -9.80665 * dt
    for k, w in enumerate(rates):
        st.imu_step(v.buf, float((k + 1) * round(dt * 1e6)), w[0] * dt, w[1] * dt, w[2] * dt,
                    0.0, 0.0, g_dt, dt, False, COV_INTERVAL)


def expected_added(rates: np.ndarray, arw: float = ARW, dt: float = DT) -> float:
    """The variance per axis the rule adds over a run (increments from zero, as after a
    start): sum over steps of max(0, |d2|^2 - 18 * 3 arw^2 dt) / 12."""
    inc = np.vstack([np.zeros((2, 3)), rates * dt])
    d2 = np.diff(inc, n=2, axis=0)
    step = np.sum(d2**2, axis=1) - 18.0 * 3.0 * arw**2 * dt
    return float(np.sum(step[step > 0.0]) / 12.0)


def att_var(v: st.StateViews) -> np.ndarray:
    return np.diag(v.P)[0:3].copy()


def test_only_what_a_linearly_changing_rate_cannot_explain_is_added() -> None:
    """GIVEN three 50 Hz runs of 1 s, all starting from rest: a steady rate, a rate growing
    at 2 rad/s^2 (a linear change), and a rate alternating by +-0.5 rad/s each sample,
    WHEN each is propagated,
    THEN the growing rate adds only its start as the steady one does (its second differences
    vanish after two steps), and the alternating one adds the sum of its (|d2|^2 - white)
    / 12 over the steady run's: to 2 % (the runs' F differ a little, and a step's variance
    is propagated over its interval)."""
    n = 50
    w0 = np.array([0.2, -0.1, 0.3])
    steady = np.tile(w0, (n, 1))
    ramp = steady + np.outer(np.arange(n) * DT, [2.0, 0.0, 0.0])
    wobble = steady + np.outer([(-1) ** k for k in range(n)], [0.5, 0.0, 0.0])
    a, b, c = fresh(), fresh(), fresh()
    run(a, steady)
    run(b, ramp)
    run(c, wobble)
    start = expected_added(steady)
    assert expected_added(ramp) == expected_added(ramp[:2])  # nothing after its start
    np.testing.assert_allclose(att_var(b) - att_var(a), expected_added(ramp) - start,
                               atol=0.02 * start)
    extra = expected_added(wobble) - start
    assert extra > 100 * ARW**2 * n * DT  # far above the gyro noise over the run
    np.testing.assert_allclose(att_var(c) - att_var(a), extra, rtol=0.02)


def test_white_gyro_noise_alone_adds_little() -> None:
    """GIVEN a still IMU whose gyro has exactly the white noise the filter is told (ARW),
    WHEN 60 s at 50 Hz are propagated with and without that noise in the samples,
    THEN the noise adds at most 10 % of what its density adds over the run (ARW^2 T): three
    times the noise's own mean |d2|^2 is not counted, ~3 % gets through."""
    rng = np.random.default_rng(3)
    n = 3000
    noisy = rng.normal(0.0, ARW / math.sqrt(DT), size=(n, 3))
    a, b = fresh(), fresh()
    run(a, np.zeros((n, 3)))
    run(b, noisy)
    added = att_var(b) - att_var(a)
    assert np.all(added < 0.1 * ARW**2 * n * DT), added / (ARW**2 * n * DT)


def test_true_increments_of_a_smooth_swell_add_nothing_to_a_navigation_grade_gyro() -> None:
    """GIVEN a navigation-grade gyro (ARW 0.003 deg/sqrt(h)) at 100 Hz on a ship rolling 5 deg
    at 0.1 Hz, fed its true angle increments (what firmware_sim and a delta-angle IMU give),
    WHEN 10 min are propagated, with and without the swell,
    THEN no step adds anything: the second difference of a smooth motion's increments,
    ~omega'' dt^3, stays below the white-noise threshold (what the kernel adds for a given
    sequence is checked against the same sum in the first test)."""
    arw, dt, n = 0.003 * DEG / 60.0, 0.01, 60_000
    t = np.arange(n + 3) * dt
    roll = 5.0 * DEG * np.sin(2.0 * math.pi * 0.1 * t)
    inc = np.zeros((n + 2, 3))
    inc[:, 0] = np.diff(roll)  # the increments are exact: d(roll) per step
    d2 = np.diff(inc, n=2, axis=0)
    worst = float(np.max(np.sum(d2**2, axis=1)))
    assert worst < 0.01 * 18.0 * 3.0 * arw**2 * dt  # a hundredth of the threshold
    # and the kernel keeps the history that sum is taken over (the swell going on before:
    # no start from rest)
    v = fresh(arw)
    v.prev_inc[0:3] = inc[1]
    v.dprev[:] = inc[1] - inc[0]
    run(v, inc[2:12] / dt, dt)
    np.testing.assert_allclose(v.dprev, inc[11] - inc[10], rtol=1e-9)
