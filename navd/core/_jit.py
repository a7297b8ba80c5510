"""Typed wrapper around numba's ``njit``.

The estimator's kernels are plain Python on preallocated numpy arrays; numba compiles them
so a steady-state IMU step costs microseconds instead of the ~0.7 ms of equivalent CPython
array code.  ``NUMBA_DISABLE_JIT=1`` runs the very same code uncompiled (debugging,
coverage).  Compiled code is cached on disk (``NUMBA_CACHE_DIR`` where the package is
read-only, as under systemd).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar, cast

import numba

F = TypeVar("F", bound=Callable[..., Any])


def jit(fn: F) -> F:
    """Compile ``fn`` in nopython mode, cached, without the GIL held."""
    return cast(F, numba.njit(cache=True, nogil=True)(fn))
