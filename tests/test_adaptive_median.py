"""The adaptive-noise window median: exact, and computed without allocating (a GNSS epoch that
ends a window must stay allocation-free like any other)."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from navd.config import EstimatorConfig
from navd.core.aiding.adaptive_noise import AdaptiveNoise


@pytest.mark.alloc
def test_window_median_is_numpys_and_allocates_nothing() -> None:
    """GIVEN windows of NIS ratios (random, with refused epochs as inf, with ties),
    WHEN the window median is taken,
    THEN it equals np.median, and a second call under tracemalloc peaks below 512 bytes
    (np.median, and ndarray.sort in place, took ~2.6 kB)."""
    a = AdaptiveNoise(EstimatorConfig())
    rng = np.random.default_rng(5)
    n = a._ratio.size
    for window in (rng.random(n) * 3.0, np.r_[np.full(12, np.inf), rng.random(n - 12)],
                   np.round(rng.random(n), 1)):
        a._ratio[:] = window
        assert a._median_ratio() == float(np.median(window))
    a._median_ratio()
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        tracemalloc.reset_peak()
        a._median_ratio()
        peak = tracemalloc.get_traced_memory()[1] - base
    finally:
        tracemalloc.stop()
    assert peak < 512, peak
