"""Chi-square quantiles for innovation gates (no scipy dependency in the core)."""

from __future__ import annotations

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


def chi2_quantile(p: float, dof: int) -> float:
    """x with P(chi2_dof <= x) = p, by bisection (p in (0, 1))."""
    lo, hi = 0.0, 10.0 * dof + 100.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if chi2_cdf(mid, dof) < p:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)
