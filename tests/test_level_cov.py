"""P0 after levelling (issue 14): tilt and accelerometer bias start correlated.

Levelling takes the mean specific force for gravity, so the horizontal accelerometer bias
becomes a tilt error of -b_h/g; a diagonal P0 claimed the two independent, and the velocity
updates then split each correction between them by their prior variances (with the consumer
bias prior most of it went into the bias and stayed in the tilt until turns separated them)."""

from __future__ import annotations

import math

import numpy as np

from navd.config import EstimatorConfig, load_config
from navd.core.estimator import Estimator
from navd.core.level import level_cov, relevel_cov
from navd.core.rotation import euler_to_mat, log_so3
from navd.types import FixType, GnssSample, ImuSample
from navd.units import DEG

IDX = [0, 1, 2, 12, 13, 14]  # phi_N, phi_E, phi_D, dba_x, dba_y, dba_z
G = 9.79


def _start(cfg: EstimatorConfig, mat_nb: np.ndarray, ba: np.ndarray, noise_sd: float,
           rng: np.random.Generator) -> Estimator:
    """Level a static IMU (attitude mat_nb, accelerometer bias ba, white noise) for 1 s at
    100 Hz and start navigation from two agreeing fixes."""
    e = Estimator(cfg)
    dt_us, n = 10_000, 100
    f_b = mat_nb.T @ np.array([0.0, 0.0, -G]) + ba
    dv = f_b * 1e-2 + rng.normal(0.0, noise_sd, (n, 3))
    for k in range(n):
        e.push(ImuSample((k + 1) * dt_us, dt_us, 0.0, 0.0, 0.0, *dv[k]))
    for t_us in (n * dt_us - 100_000, n * dt_us):
        e.push(GnssSample(t_us, 0.6, 0.2, 100.0, 0.0, 0.0, 0.0, 2.0, 3.0, 0.1,
                          FixType.FIX_3D))
    assert e.initialized
    return e


def test_levelling_p0_matches_monte_carlo_of_tilt_bias_and_heading() -> None:
    """GIVEN 800 static levellings of a body rolled -10 deg, pitched 20 deg, heading given
    as 30 deg with an error drawn from its sigma, accelerometer biases drawn from the prior
    and noise whose 1 s mean has the configured tilt sigma,
    WHEN navigation starts,
    THEN the errors (phi, accelerometer bias) whitened by the filter's P0 have the identity
    covariance within sampling error (a diagonal P0 fails: tilt and bias are correlated
    about -0.7)."""
    # level_max_time_s = 1: this checks P0 for a 1-s levelling; noise at tilt_sd would
    # otherwise level longer in about half the draws (scatter above tilt_sd)
    cfg = EstimatorConfig.from_dict(load_config(None, [
        "init.heading_source=config", "init.heading_deg=30", "init.heading_sd_deg=3",
        "init.level_max_time_s=1"]))
    rng = np.random.default_rng(14)
    sd_b = cfg.imu.accel_bias_sd
    # per-increment noise whose 1 s mean (100 increments over 1 s) is g * tilt_sd
    noise_sd = G * cfg.init.tilt_sd * 1.0 / math.sqrt(100)
    errs, p0 = [], None
    for _ in range(800):
        d_psi = rng.normal(0.0, cfg.init.heading_sd)  # yaw error, computed - true
        c_true = euler_to_mat(-10 * DEG, 20 * DEG, 30 * DEG - d_psi)
        ba = rng.normal(0.0, sd_b, 3)
        e = _start(cfg, c_true, ba, noise_sd, rng)
        phi = -np.array(log_so3(e.mat_nb @ c_true.T))
        errs.append(np.concatenate([phi, ba - e.bias_a]))
        p0 = e.P[np.ix_(IDX, IDX)].copy()
    assert p0 is not None
    x = np.array(errs)
    emp = x.T @ x / len(x)
    L = np.linalg.cholesky(p0)
    w = np.linalg.solve(L, np.linalg.solve(L, emp).T)
    # sampling sd of a whitened second moment: ~1/sqrt(800) off the diagonal, ~0.05 on it
    assert np.max(np.abs(w - np.eye(6))) < 0.2, np.round(w, 2)
    # and the tilt does carry the bias: corr(phi_E, b_N) strongly negative, as -b_N/g says
    assert p0[1, 3] != 0.0


def test_unknown_heading_keeps_the_tilt_variance_without_a_direction() -> None:
    """GIVEN levelling with no heading (yaw guessed 0), WHEN P0 is built, THEN each tilt axis
    has variance tilt_sd^2 + (sigma_ba/g)^2 (the bias's tilt does not depend on the heading),
    no NED correlation with the body-frame bias (its direction is unknown) and phi_D (pi/2)^2."""
    c0 = euler_to_mat(5 * DEG, -8 * DEG, 0.0)
    p = np.full((15, 15), 7.0)  # rows of phi and dba must be rewritten, others left alone
    level_cov(p, c0, -8 * DEG, 0.0, 2 * DEG, math.inf, 0.3, G)
    want = (2 * DEG) ** 2 + (0.3 / G) ** 2
    np.testing.assert_allclose([p[0, 0], p[1, 1]], [want, want], rtol=1e-12)
    assert abs(p[0, 1]) < 1e-18 and np.all(p[0:3, 12:15] == 0.0) and p[2, 2] == (math.pi / 2) ** 2
    np.testing.assert_allclose(p[12:15, 12:15], 0.09 * np.eye(3))
    assert p[3, 4] == 7.0 and p[0, 3] == 0.0


def test_relevel_at_rest_gives_the_tilt_the_residual_bias_and_its_correlations() -> None:
    """GIVEN a random full P and a re-level from the mean specific force less the estimated
    accelerometer bias (the tilt error becomes eps + J dba, the old tilt forgotten),
    WHEN relevel_cov updates P,
    THEN P equals T P T^T + tilt_sd^2 on phi_N, phi_E, T the identity with the tilt rows
    replaced by J times the accelerometer-bias rows (matrix form, computed independently);
    with the heading unknown, the same variances and no tilt correlations."""
    rng = np.random.default_rng(3)
    a = rng.normal(size=(15, 15)) * np.r_[np.full(3, 0.02), np.ones(9), np.full(3, 0.1)]
    p = a @ a.T
    c = euler_to_mat(4 * DEG, -12 * DEG, 130 * DEG)
    tilt_sd, g = 0.01, 9.8
    t = np.eye(15)
    t[0] = 0.0
    t[1] = 0.0
    t[0, 12:15] = c[1] / g
    t[1, 12:15] = -c[0] / g
    want = t @ p @ t.T
    want[0, 0] += tilt_sd**2
    want[1, 1] += tilt_sd**2
    got = p.copy()
    relevel_cov(got, c, tilt_sd, g, True)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-18)
    assert np.all(np.linalg.eigvalsh(got) > 0.0)
    lost = p.copy()
    relevel_cov(lost, c, tilt_sd, g, False)
    np.testing.assert_allclose(lost[:2, :2], want[:2, :2], rtol=1e-12)
    assert np.all(lost[:2, 2:] == 0.0) and np.all(lost[2:, 2:] == p[2:, 2:])
