"""The attitude variance a point-sampled rate adds (navd.core.kalman.imu_step, issue 14).

An increment made from a rate sampled at one instant misses what the rate did between
samples; the step adds (|inc_k - inc_(k-1)|^2 - 2 q dt) / 12 per axis to the attitude
variance at that step (the rectangle rule's error for a linearly changing rate, less what
the gyro's white noise alone explains).  These tests drive the kernel on a state buffer directly.
"""

from __future__ import annotations

import math

import numpy as np

from navd.core import state as st

DEG = math.pi / 180.0
ARW = 0.3 * DEG / 60.0  # rad/sqrt(s)
DT = 0.02  # 50 Hz, a log's IMU message rate
COV_INTERVAL = 0.1


def fresh() -> st.StateViews:
    """A level, still state at 47 deg N with a consumer IMU's white-noise densities."""
    v = st.StateViews(np.zeros(st.SIZE))
    v.mat_nb[:] = np.eye(3)
    v.pos[:] = (47.0 * DEG, 8.0 * DEG, 400.0)
    v.q[0:3] = ARW**2
    v.q[3:6] = 0.02**2
    v.P[:] = np.diag([(1.0 * DEG) ** 2] * 3 + [0.1**2] * 3 + [1e-12] * 2 + [1.0]
                     + [(0.1 * DEG) ** 2] * 3 + [0.05**2] * 3)
    st.history_reset(v.buf)
    return v


def run(v: st.StateViews, rates: np.ndarray) -> None:
    """Feed body rates (N, 3) rad/s at 50 Hz with the specific force of a level vehicle."""
    g_dt = -9.80665 * DT
    for k, w in enumerate(rates):
        st.imu_step(v.buf, float((k + 1) * 20_000), w[0] * DT, w[1] * DT, w[2] * DT,
                    0.0, 0.0, g_dt, DT, False, COV_INTERVAL)


def att_var(v: st.StateViews) -> np.ndarray:
    return np.diag(v.P)[0:3].copy()


def test_a_steady_rate_adds_nothing_and_a_changing_one_adds_its_rectangle_error() -> None:
    """GIVEN two 50 Hz runs over one covariance interval with the same mean body rate,
    WHEN one rate is steady and the other alternates by +-0.5 rad/s about it each sample,
    THEN the steady run's attitude variance is what the gyro noise gives, and the
    alternating run's exceeds it by the sum over its steps of (|inc change|^2 - 2*3*ARW^2*dt)
    / 12 per axis (the first step's change is from zero, as after a start)."""
    n = 5  # 5 x 20 ms = one covariance interval
    w0 = np.array([0.2, -0.1, 0.3])
    steady = np.tile(w0, (n, 1))
    wobble = steady + np.outer([(-1) ** k for k in range(n)], [0.5, 0.0, 0.0])
    a, b = fresh(), fresh()
    run(a, steady)
    run(b, wobble)
    inc = wobble * DT
    changes = np.diff(np.vstack([np.zeros(3), inc]), axis=0)
    white = 2.0 * 3.0 * ARW**2 * DT
    steps = np.sum(changes**2, axis=1) - white
    inc_first = np.sum((steady[0] * DT) ** 2) - white  # steady: only its first step adds
    expected_extra = (np.sum(steps[steps > 0]) - max(inc_first, 0.0)) / 12.0
    extra = att_var(b) - att_var(a)
    # the two runs' F differ a little (the attitude turned differently) and the variance
    # added at a step is propagated over the rest of the interval: 2 % of the extra
    np.testing.assert_allclose(extra, expected_extra, rtol=0.02)
    assert expected_extra > 10 * ARW**2 * n * DT  # the effect is not lost in the noise


def test_white_gyro_noise_alone_adds_little() -> None:
    """GIVEN a still IMU whose gyro has exactly the white noise the filter is told (ARW),
    WHEN 60 s at 50 Hz are propagated with and without that noise in the samples,
    THEN the attitude variance grows by less than 20 % more than from the gyro noise
    density itself (the change of white increments is mostly explained away)."""
    rng = np.random.default_rng(3)
    n = 3000
    noisy = rng.normal(0.0, ARW / math.sqrt(DT), size=(n, 3))
    quiet = np.zeros((n, 3))
    a, b = fresh(), fresh()
    run(a, quiet)
    run(b, noisy)
    grown_quiet = att_var(a) - (1.0 * DEG) ** 2
    grown_noisy = att_var(b) - (1.0 * DEG) ** 2
    assert np.all(grown_noisy > grown_quiet)  # some clipping of the subtraction remains
    assert np.all(grown_noisy < 1.2 * grown_quiet)


def test_a_rate_change_is_counted_once() -> None:
    """GIVEN a run with one sharp rate change followed by a steady rate,
    WHEN several covariance intervals pass,
    THEN the change is added once: the later intervals grow the attitude variance as a
    steady run does."""
    n = 25
    w = np.tile([0.0, 0.0, 0.1], (n, 1))
    w[2] = [1.0, 0.0, 0.1]
    jump, steady = fresh(), fresh()
    run(jump, w[:5])
    run(steady, np.tile([0.0, 0.0, 0.1], (5, 1)))
    after_first = att_var(jump) - att_var(steady)
    run(jump, w[5:])
    run(steady, np.tile([0.0, 0.0, 0.1], (n - 5, 1)))
    np.testing.assert_allclose(att_var(jump) - att_var(steady), after_first, rtol=0.05)
