"""Filter consistency (NEES) with the DEFAULT config on the robustness benchmark's Monte Carlo
car cases (issue 14, "NEES within its band on the Monte Carlo cases").  The figures per case,
pooled over 5 seeds, are the benchmark's NEES column (docs/results.md); this checks seed 1
of the car cases where the filter is consistent, and the multirotor pooled over its 5 seeds,
so a change that makes it overconfident fails here.  3x IMU noise is checked on seed 1 like
the others (its NEES over the benchmark's 20 seeds was 3.6, above the band, before the gyro
scale-factor allowance and is 2.8 with it; seed 1 alone 1.5 and 1.7; docs/results.md, "Gyro
scale factor").  Gauss-Markov biases are checked pooled over the benchmark's 5 seeds, where
they were above the band until the consumer accelerometer-bias walk took a warming board's
temperature drift (docs/results.md, "The consumer accelerometer-bias walk")."""

from __future__ import annotations

from typing import Any

import pytest
from bench_util import load_benchmark

from firmware_sim import generate, load_scenario

rb = load_benchmark("robustness")


def pooled_nees(name: str) -> dict[str, Any]:
    """The benchmark's NEES figures of case ``name`` pooled over seeds 1-5."""
    case = next(c for c in rb.CASES if c.name == name)
    runs = [rb.score_sim(generate(load_scenario(case.scenario, dict(case.overrides)),
                                  seed=s, progress=False), case.profile)
            for s in range(1, 6)]
    fig: dict[str, Any] = rb.nees_figures(runs)
    return fig


@pytest.mark.parametrize("name", ["car_clean", "gyro_1", "accel_20mg", "sideslip_2",
                                  "noise_x3"])
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


def test_multirotor_attitude_nees_is_not_above_its_band() -> None:
    """GIVEN mr_clean (the multirotor scenario, default config, multirotor profile), seeds 1-5
    as the benchmark pools them,
    WHEN the attitude NEES is averaged after 60 s,
    THEN it is not above its 99 % band (measured 2.9 in [2.71, 3.31]).  With the raw
    accelerometer noise in F it was 3.96: seeds 4 and 5 held a bank-aligned heading 3.5-5 deg
    off while the noise "told" the filter its heading was right (sigma 1.6-2 deg for 190 s;
    docs/results.md, "mr_clean: heading information from accelerometer noise")."""
    fig = pooled_nees("mr_clean")
    assert fig["nees_att"] < fig["nees_band"][1], fig


@pytest.mark.parametrize("seed", [4, 5])
def test_multirotor_heading_sigma_covers_its_error(seed: int) -> None:
    """GIVEN mr_clean seeds 4 and 5 (default config, multirotor profile: heading from the yaw
    bank, then from the accelerations of the legs),
    WHEN the heading's (error / sigma)^2 is averaged over the aligned instants after 60 s,
    THEN it is not above the 99 % band of a consistent filter's mean (1 dof, one independent
    sample per 2 s).  With the raw accelerometer noise in F the heading stayed 3.5-5 deg off
    at a 1.6-2 deg sigma for 190 s (means 4.85 and 3.10, band ~1.4); with the body-frame
    low-pass of F's specific force 2.15 (seed 4, its sigma ~20 % below the information floor)
    and 0.85; with kalman.multirotor_f's drag model and noise-energy correction below it
    (docs/results.md, "mr_clean: heading information from accelerometer noise" and "The
    information floor")."""
    from navd.core.chi2 import chi2_quantile

    case = next(c for c in rb.CASES if c.name == "mr_clean")
    run = generate(load_scenario(case.scenario, dict(case.overrides)), seed=seed,
                   progress=False)
    r = rb.score_sim(run, case.profile)
    m = (r.t_s >= rb.NEES_FROM_S) & r.aligned
    assert m.sum() > 1000, m.sum()  # aligned for most of the 180 s after 60 s
    q = float(((r.err_deg[m, 2] / r.sd_deg[m, 2]) ** 2).mean())
    k = max(1, int((r.t_s[m][-1] - r.t_s[m][0]) / rb.NEES_BLOCK_S))
    assert q < chi2_quantile(0.995, k) / k, (q, k)


def test_gauss_markov_biases_are_consistent_over_the_benchmark_seeds() -> None:
    """GIVEN gm_100s (car480 whose gyro and accelerometer biases wander as Gauss-Markov
    processes, 12 deg/h and 5 mg with 100 s correlation; default config), seeds 1-5 as the
    benchmark pools them,
    WHEN the attitude NEES is averaged after 60 s,
    THEN it is not above its 99 % band (measured 2.9, band <= 3.20).  With the consumer
    accelerometer-bias walk at 1e-4 m/s^2/sqrt(s) it was 3.7 (4.5 before the gyro
    scale-factor allowance), pitch beyond 3 sigma 3.5 % (now 1.2 %): a sigma that assumed
    the bias nearly constant."""
    fig = pooled_nees("gm_100s")
    assert fig["nees_att"] < fig["nees_band"][1], fig
