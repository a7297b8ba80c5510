"""A block of IMU samples and the estimator's compiled run over it (issue 18, the batch lane).

At 1 kHz the daemon's remaining cost was the Python executed per sample: the HIGHRES_IMU
decode, an :class:`~navd.types.ImuSample` per sample, its queue item, the clock guard and
:meth:`Estimator._push_imu`.  The batch lane moves a read's worth of samples (up to
``capacity``, ~10 at 1 kHz with read pacing) through one preallocated :class:`ImuBlock`:
the MAVLink decoder writes the samples into its arrays (:mod:`navd.core.highres_batch`),
the block is one queue item, and :func:`push_run` feeds its samples to the estimator.

A block *is* the sequence of ``Estimator.push(ImuSample(...))`` calls of its samples: each
field is what the per-sample path would have put in the ImuSample, bit for bit, and
:func:`push_run` does per sample exactly what ``_push_imu`` does for a plausible,
in-order, navigating sample.  It stops, and hands the rest back to the per-sample path,
at any sample that would need Python there (any failed check, a completed rest window),
so the two paths end in the same state (tests/test_io_mavlink_lane.py).  A recording is
made of per-sample pushes (the daemon takes the per-sample path while recording), so
``navd replay`` reproduces it through :meth:`Estimator.push`.

This module lives in ``navd.core`` so that the install-time kernel build (numpy and numba
only) compiles :func:`push_run` with the estimator's kernels.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from navd.core import state as st
from navd.core._jit import jit
from navd.core.aiding.gyro_rest import rest_completes, rest_push
from navd.core.aiding.imu_noise import noise_push
from navd.core.aiding.yaw_bank_kernels import bank_imu
from navd.types import ImuSample

__all__ = ["BLOCK_CAPACITY", "PUSH_LIMITS", "ImuBlock", "push_run"]

# samples per block: a paced 1 kHz read holds ~10, the reader takes at most 32 per wake-up
BLOCK_CAPACITY = 32

# push_run's ``lim`` array: max IMU interval (us), max rate (rad/s), max specific force
# (m/s^2), rest window (s), covariance interval (s), clock guard: how far back and ahead
# of its newest stamp (us) a sample is on the current clock
LIM_GAP, LIM_GYRO, LIM_ACCEL, LIM_WINDOW, LIM_COV, LIM_BACK, LIM_AHEAD = range(7)
PUSH_LIMITS = 7

# stamps at or beyond this are never on a clock (navd.core.clock_guard._MAX_T_US)
_MAX_T_US = 1 << 53


class ImuBlock:
    """Up to ``capacity`` IMU samples in arrays, one queue item, recycled.

    ``t_us``, ``dt_us``: int64 (capacity,), sensor stamp and interval, us; ``inc``: float64
    (capacity, 6), dtheta xyz (rad) then dvel xyz (m/s), body FRD: sample k is
    ``ImuSample(t_us[k], dt_us[k], *inc[k])``.  Samples ``start..n-1`` are still to be
    consumed.  A producer takes a free block with :meth:`take`, fills it and queues it; the
    consumer (or a queue dropping it) hands it back with :meth:`release`.
    """

    __slots__ = ("_free", "dt_us", "inc", "n", "start", "t_us")

    def __init__(self, free: list[ImuBlock] | None = None,
                 capacity: int = BLOCK_CAPACITY) -> None:
        self.t_us = np.zeros(capacity, np.int64)
        self.dt_us = np.zeros(capacity, np.int64)
        self.inc = np.zeros((capacity, 6))
        self.n = 0
        self.start = 0
        self._free = free

    @staticmethod
    def pool(size: int, capacity: int = BLOCK_CAPACITY) -> list[ImuBlock]:
        """``size`` free blocks sharing one free list (the list returned)."""
        free: list[ImuBlock] = []
        free.extend(ImuBlock(free, capacity) for _ in range(size))
        return free

    def release(self) -> None:
        """Empty the block and put it back on its free list (once per take)."""
        self.n = self.start = 0
        if self._free is not None:
            self._free.append(self)

    def sample(self, k: int) -> ImuSample:
        """Sample ``k`` as the ImuSample the per-sample path makes."""
        r = self.inc[k]
        return ImuSample(int(self.t_us[k]), int(self.dt_us[k]), float(r[0]), float(r[1]),
                         float(r[2]), float(r[3]), float(r[4]), float(r[5]))

    def samples(self) -> list[ImuSample]:
        """The samples not yet consumed (the per-sample fall-back)."""
        return [self.sample(k) for k in range(self.start, self.n)]

    def __len__(self) -> int:
        return self.n - self.start


Arr = npt.NDArray[np.float64]
IArr = npt.NDArray[np.int64]


@jit
def push_run(buf: Arr, rest_acc: Arr, noise: Arr, bank: Arr, has_bank: bool, t_arr: IArr,
             dt_arr: IArr, inc: Arr, i0: int, n: int, last_t: int, guard_t: int, lim: Arr,
             coning: bool, stop_at: int) -> int:
    """Push samples ``i0..n-1`` of a block into a navigating estimator's buffer ``buf``, as
    ``Estimator._push_imu`` does each; return how many were consumed (from ``i0`` on).

    Stops before a sample that the clock guard's usual case would not pass (its newest
    stamp ``guard_t``, running with the samples; window ``lim[LIM_BACK]``/``lim[LIM_AHEAD]``)
    or that ``_push_imu`` would refuse, count anything but ``imu`` for, or close a rest
    window with; and right after the first consumed sample stamped at or past ``stop_at``
    (an output instant: the caller asks its sinks).  ``last_t``: the estimator's newest
    stamp (>= 0).  ``rest_acc``: the rest detector's accumulators; ``noise``: the white-noise
    measurement's (:mod:`navd.core.aiding.imu_noise`); ``bank``: the yaw bank's
    buffer when ``has_bank``.  The caller does the Python side of what was consumed: the
    estimator's ``t_us``, ``_imu_dt_us`` and ``imu`` counter, and the guard's newest stamp.
    """
    max_gap = lim[LIM_GAP]
    max_gyro = lim[LIM_GYRO]
    max_accel = lim[LIM_ACCEL]
    window_s = lim[LIM_WINDOW]
    cov_interval = lim[LIM_COV]
    back = lim[LIM_BACK]
    ahead = lim[LIM_AHEAD]
    k = 0
    for i in range(i0, n):
        t_us = t_arr[i]
        # ClockGuard.on_clock (no candidate pending: the caller checked)
        if guard_t < 0 or not 0 < t_us < _MAX_T_US:
            break
        d = t_us - guard_t
        if not (-back <= d and d <= ahead):
            break
        # Estimator._push_imu, the branch that only counts "imu"
        dt_us = dt_arr[i]
        if dt_us <= 0 or dt_us > max_gap:
            break
        dt = dt_us * 1e-6
        dtx = inc[i, 0]
        dty = inc[i, 1]
        dtz = inc[i, 2]
        dvx = inc[i, 3]
        dvy = inc[i, 4]
        dvz = inc[i, 5]
        max_w = max_gyro * dt
        max_f = max_accel * dt
        if not (dtx * dtx + dty * dty + dtz * dtz <= max_w * max_w
                and dvx * dvx + dvy * dvy + dvz * dvz <= max_f * max_f):
            break
        if t_us <= last_t or t_us - last_t - dt_us > max_gap:
            break
        if buf[st.MOUNT + 9] != 0.0:
            dtx, dty, dtz = st.mount_turn(buf, dtx, dty, dtz)
            dvx, dvy, dvz = st.mount_turn(buf, dvx, dvy, dvz)
        # rest_push would complete the window: _push_imu closes it in Python first
        if rest_completes(rest_acc, dt, window_s):
            break
        if d > 0:
            guard_t = t_us
        last_t = t_us
        t = float(t_us)
        noise_push(noise, buf[st.Q:st.Q + 15], t, dtx, dty, dtz, dvx, dvy, dvz, dt)
        rest_push(rest_acc, dtx, dty, dtz, dvx, dvy, dvz, dt, window_s)
        st.imu_step(buf, t, dtx, dty, dtz, dvx, dvy, dvz, dt, coning, cov_interval)
        if has_bank:
            bank_imu(bank, buf, t, dt)
        k += 1
        if t_us >= stop_at:
            break
    return k
