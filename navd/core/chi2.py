"""Chi-square quantiles for innovation gates (no scipy dependency in the core)."""

from __future__ import annotations

import functools
import math


def _lower_reg_gamma(s: float, x: float) -> float:
    """Regularised lower incomplete gamma P(s, x) by its power series (x < ~50 here)."""
    if x <= 0.0:
        return 0.0
    term = 1.0 / s
    total = term
    n = 1
    while n < 500:
        term *= x / (s + n)
        total += term
        if term < total * 1e-16:
            break
        n += 1
    return min(1.0, math.exp(s * math.log(x) - x - math.lgamma(s)) * total)


def chi2_cdf(x: float, dof: int) -> float:
    return _lower_reg_gamma(0.5 * dof, 0.5 * x)


def _normal_quantile(p: float) -> float:
    lo, hi = -40.0, 40.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if 0.5 * (1.0 + math.erf(mid / math.sqrt(2.0))) < p:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


@functools.cache  # the same few gates for every estimator built
def chi2_quantile(p: float, dof: int) -> float:
    """x with P(chi2_dof <= x) = p (p in (0, 1)).

    Bisection on the exact CDF for the small dof of innovation gates; above 50 dof the
    power series needs thousands of terms, and Wilson-Hilferty is accurate to < 0.1 %.
    """
    if dof > 50:
        z = _normal_quantile(p)
        a = 2.0 / (9.0 * dof)
        return dof * (1.0 - a + z * math.sqrt(a)) ** 3
    lo, hi = 0.0, 10.0 * dof + 100.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if mid in (lo, hi):
            # lo and hi are adjacent floats: every further step returns this same value
            # (~60 steps instead of 200; estimators are built at start-up, issue 18)
            return mid
        if chi2_cdf(mid, dof) < p:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)
