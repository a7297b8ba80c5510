"""The IMU's white noise measured from its own samples: a floor under the process noise
(docs/design.md §3.3, "Measured white noise").

Why.  A configured ARW / VRW that understates the sensor makes the filter trust its
propagation too much; the innovation test of :mod:`navd.core.aiding.adaptive_noise` finds
that only after the biases settled, which the understated noise itself delays (issue 14,
noise_x3: 3x the configured VRW, the white-noise scale still 1 after 33 s, tilt beyond 3
sigma 6.9 % of the time, 19 resets over 20 seeds).  The samples say it directly and at once.

Measurement.  For white noise of density N (rad/sqrt(s) or m/s/sqrt(s)) a rate sample over dt
s has variance N^2/dt, and its second difference ``r_k - 2 r_k-1 + r_k-2`` six times that,
so ``N^2 = E[d2^2 dt] / 6``; a smooth motion contributes only its second derivative times
dt^2 (a car at 100 Hz: nothing).  Pooled over the three axes of each sensor, per window of
``WINDOW_S``.

Motion is not noise.  Real logs show gyro second differences 100-1000x the consumer ARW^2
in flight (X8, log171, quad123: turbulence, manoeuvres and airframe vibration, aliased), so
a window counts only if its noise is white over the time scales the filter integrates: the
same estimate from block means of ``BLOCK_S`` (``N^2 = E[d2_block^2 T_block] / 6`` again)
must agree within ``FLAT``; motion grows with the block, vibration shrinks, white noise
stays.  Measured (the estimate over the configured density, squared; median over 2-s
windows, per sample / over 0.2-s blocks): the simulated IMUs 0.23 / 0.24 (gyro) and 1.0 /
0.87 (accelerometer); noise_x3 2.05 / 2.11 and 9.0 / 7.8; X8's gyro 1,226 / 55,610, quad123
694 / 11,413, log171 in flight 1,232 / 17,996 (so refused); the real logs' accelerometers
0.01-0.2 (their autopilots low-pass them).  Not every flight window is refused: log171's 50
Hz gyro passes in 3 of 40 windows at 50,000-140,000 (22 deg/s per sample, white to 0.2 s:
aliased vibration, which integrates as noise does); its floor then sits at the cap.  A
stream whose intervals jitter by more than half (X8: 5.6-13 ms) is never judged: its
difference chains break too often for a block estimate.

Use.  The floor is the median of the last ``RING`` accepted windows, the ring starting full
of 1 (the configured value): it rises only once most recent windows say so, so one wild
window moves nothing; never below 1, since the config may overstate the noise (a vibration
allowance) and a filtered stream measures low.
The densities the propagation uses are then ``min(floor * s, cap) * configured`` with ``s``
the innovation test's own scale and ``cap`` its ``[filter] max_q_scale``.  Applied the moment
a window closes, inside the IMU kernel (no Python per sample); the per-sample path and the
compiled batch run both call :func:`noise_push`, so they stay identical.  Navigation's start
judges the open window at once; after a trusted levelling (no turning, no velocity change)
its per-sample estimate alone sets the whole ring.  A restart keeps the floors (same
sensor) and restarts the difference chains.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from navd.core._jit import jit

Arr = npt.NDArray[np.float64]

WINDOW_S = 4.0  # one measurement window, s of samples
BLOCK_S = 0.2  # block length of the whiteness check, s (at least MIN_BLOCK samples)
MIN_BLOCK = 4
FLAT = 2.0  # block estimate at most FLAT x the per-sample one: not motion
RING = 3  # accepted windows whose median is the floor
_MIN_D2 = 10  # second differences (all three axes at once) a window needs, per sample and
# per block

# accumulator layout (float64): previous two rate samples (gyro xyz, accel xyz), chain
# length, previous interval; window sums of d2^2 dt (gyro, accel) and their count, window
# time; block sums of the increments, samples in the block, block time, block length;
# previous two block rates, block chain length; window sums over blocks and their count;
# per sensor a ring of accepted window ratios, its next slot and the floor; the innovation
# test's scale, the configured densities^2 (gyro, accel), the cap, on/off, the previous
# stamp; scratch
P1, P2 = 0, 6
CHAIN, PDT = 12, 13
S1G, S1A, N1, WT = 14, 15, 16, 17
BSUM, BN, BT, BLEN = 18, 24, 25, 26
BP1, BP2, BCHAIN = 27, 33, 39
SBG, SBA, NB = 40, 41, 42
RINGS = 43  # sensor k (0 gyro, 1 accel): ring at RINGS + k * RING_W, then slot, floor
RING_W = RING + 2
_SLOT, _FLOOR = RING, RING + 1
FLOOR_G, FLOOR_A = RINGS + _FLOOR, RINGS + RING_W + _FLOOR
SCALE = RINGS + 2 * RING_W
Q0G, Q0A, CAP, ON = SCALE + 1, SCALE + 2, SCALE + 3, SCALE + 4
PT = SCALE + 5  # the previous sample's stamp, us
SORT = SCALE + 6  # scratch for a ring's median (RING)
RATES = SORT + RING  # scratch: the sample's rates (gyro xyz, accel xyz)
GSCALE = RATES + 6  # the course test's variance scale on the gyro alone (adaptive_noise)
SIZE = GSCALE + 1


@jit
def _ring_median(na: Arr, ring: int, n: int) -> float:
    """Median of the first ``n`` entries of the ring at ``ring`` (insertion sort, scratch)."""
    for i in range(n):
        x = na[ring + i]
        j = i - 1
        while j >= 0 and na[SORT + j] > x:
            na[SORT + j + 1] = na[SORT + j]
            j -= 1
        na[SORT + j + 1] = x
    h = n // 2
    if n % 2:
        return float(na[SORT + h])
    return 0.5 * (float(na[SORT + h - 1]) + float(na[SORT + h]))


@jit
def noise_apply(na: Arr, q: Arr) -> None:
    """Write the white-noise densities into ``q`` (the propagation's 15 densities):
    ``min(floor * scale, cap) * configured`` for the gyro (0-2; its scale times the course
    test's gyro scale) and the accelerometer (3-5)."""
    s = na[SCALE]
    cap = na[CAP]
    vg = min(na[FLOOR_G] * s * na[GSCALE], cap) * na[Q0G]  # floors stay 1 while switched off
    va = min(na[FLOOR_A] * s, cap) * na[Q0A]
    q[0] = vg
    q[1] = vg
    q[2] = vg
    q[3] = va
    q[4] = va
    q[5] = va


@jit
def _clear_window(na: Arr) -> None:
    na[S1G] = na[S1A] = na[N1] = na[WT] = 0.0
    na[SBG] = na[SBA] = na[NB] = 0.0


@jit
def _restart_chains(na: Arr) -> None:
    """Both difference chains start over (the window's sums are kept)."""
    na[CHAIN] = 0.0
    na[BCHAIN] = 0.0
    na[BN] = 0.0
    na[BT] = 0.0
    for j in range(6):
        na[BSUM + j] = 0.0


@jit
def _close(na: Arr, q: Arr) -> None:
    """End of a window: judge each sensor's, update its ring and floor, apply."""
    n1 = na[N1]
    nb = na[NB]
    changed = False
    if n1 >= _MIN_D2 and nb >= _MIN_D2:
        for k in range(2):
            q0 = na[Q0G] if k == 0 else na[Q0A]
            e1 = na[S1G + k] / (18.0 * n1) / q0
            eb = na[SBG + k] / (18.0 * nb) / q0
            if not (e1 > 0.0 and eb <= e1 * FLAT):
                continue  # motion, not noise (module doc): the floor stays
            ring = RINGS + k * RING_W
            slot = int(na[ring + _SLOT])
            na[ring + slot] = e1
            na[ring + _SLOT] = (slot + 1) % RING
            f = max(_ring_median(na, ring, RING), 1.0)
            if f != na[ring + _FLOOR]:
                na[ring + _FLOOR] = f
                changed = True
    _clear_window(na)
    if changed:
        noise_apply(na, q)


@jit
def _close_still(na: Arr, q: Arr) -> None:
    """The open window at a trusted levelling's end (no turning, no change of velocity:
    nothing but noise to see): its per-sample estimate, with no block check, becomes the
    whole ring, so navigation starts with the floor (a start after 1 s has no 0.2-s blocks
    to check and no two windows to agree)."""
    n1 = na[N1]
    if n1 >= _MIN_D2:
        for k in range(2):
            e1 = na[S1G + k] / (18.0 * n1) / (na[Q0G] if k == 0 else na[Q0A])
            ring = RINGS + k * RING_W
            for i in range(RING):
                na[ring + i] = e1
            na[ring + _FLOOR] = max(e1, 1.0)
        noise_apply(na, q)
    _clear_window(na)


@jit
def _chain_step(na: Arr, rates: int, p1: int, p2: int, chain: int, sums: int, count: int,
                weight: float) -> None:
    """One step of a second-difference chain: the rates at ``na[rates:rates + 6]`` against
    the chain's previous two (``na[p1:]``, ``na[p2:]``, then shifted); once the chain is two
    long, d2^2 times ``weight`` (the sample's or block's length, s) is added to ``na[sums]``
    (gyro) and ``na[sums + 1]`` (accelerometer) and counted in ``na[count]``."""
    full = na[chain] >= 2.0
    sg = 0.0
    sa = 0.0
    for j in range(6):
        r = na[rates + j]
        if full:
            d = r - 2.0 * na[p1 + j] + na[p2 + j]
            if j < 3:
                sg += d * d
            else:
                sa += d * d
        na[p2 + j] = na[p1 + j]
        na[p1 + j] = r
    if full:
        na[sums] += sg * weight
        na[sums + 1] += sa * weight
        na[count] += 1.0
    else:
        na[chain] += 1.0


@jit
def noise_push(na: Arr, q: Arr, t_us: float, dtx: float, dty: float, dtz: float, dvx: float,
               dvy: float, dvz: float, dt: float) -> None:
    """Add one IMU sample (stamped ``t_us``, increments in rad and m/s over ``dt`` s) to the
    accumulators ``na`` (SIZE,); at the end of a window update the floors and ``q``."""
    if na[ON] == 0.0:
        return
    pdt = na[PDT]
    if pdt > 0.0 and (dt > 1.5 * pdt or dt * 1.5 < pdt
                      or t_us - na[PT] > 1.5e6 * dt or t_us <= na[PT]):
        # a gap, another interval, a stamp out of order: the motion across it is not
        # small, so differences across it are not white noise's
        _restart_chains(na)
    na[PDT] = dt
    na[PT] = t_us
    inv = 1.0 / dt
    for j in range(6):
        x = dtx if j == 0 else dty if j == 1 else dtz if j == 2 else dvx if j == 3 \
            else dvy if j == 4 else dvz
        na[RATES + j] = x * inv
        na[BSUM + j] += x
    _chain_step(na, RATES, P1, P2, CHAIN, S1G, N1, dt)
    # block means
    if na[BLEN] == 0.0:
        na[BLEN] = max(float(MIN_BLOCK), float(round(BLOCK_S * inv)))
    na[BN] += 1.0
    na[BT] += dt
    if na[BN] >= na[BLEN]:
        bt = na[BT]
        binv = 1.0 / bt
        for j in range(6):
            na[BSUM + j] *= binv  # the block's mean rates, in place
        _chain_step(na, BSUM, BP1, BP2, BCHAIN, SBG, NB, bt)
        for j in range(6):
            na[BSUM + j] = 0.0
        na[BN] = 0.0
        na[BT] = 0.0
    na[WT] += dt
    if na[WT] >= WINDOW_S:
        _close(na, q)


class ImuNoise:
    """The accumulators and floors of one estimator (``acc``: the kernel's array)."""

    def __init__(self, gyro_arw: float, accel_vrw: float, cap: float, enabled: bool) -> None:
        """``gyro_arw`` rad/sqrt(s), ``accel_vrw`` m/s/sqrt(s): the configured densities;
        ``cap``: the largest variance scale (``[filter] max_q_scale``)."""
        self.acc = np.zeros(SIZE)
        a = self.acc
        a[FLOOR_G] = a[FLOOR_A] = a[SCALE] = a[GSCALE] = 1.0
        # the rings start full of the configured value: the floor rises only once most of
        # the last RING accepted windows say so (one wild window, a crash, moves nothing)
        for k in range(2):
            a[RINGS + k * RING_W:RINGS + k * RING_W + RING] = 1.0
        a[Q0G] = gyro_arw * gyro_arw
        a[Q0A] = accel_vrw * accel_vrw
        a[CAP] = max(cap, 1.0)
        a[ON] = 1.0 if enabled else 0.0

    def restart(self) -> None:
        """Start the difference chains over (a time jump); floors and rings stay."""
        _restart_chains(self.acc)
        _clear_window(self.acc)
        self.acc[PDT] = 0.0

    def close_window(self, q: Arr, still: bool) -> None:
        """Judge the samples of the open window now (navigation starts: the floor should be
        in place from the first propagation, not windows later); ``still``: the levelling
        was trusted as unaccelerated, so the window is noise alone (:func:`_close_still`)."""
        if still:
            _close_still(self.acc, q)
        else:
            _close(self.acc, q)

    def set_scale(self, scale: float, q: Arr) -> None:
        """The innovation test's variance scale changed: write the densities into ``q``."""
        self.acc[SCALE] = scale
        noise_apply(self.acc, q)

    def set_gyro_scale(self, scale: float, q: Arr) -> None:
        """The course test's gyro variance scale changed: write the densities into ``q``."""
        self.acc[GSCALE] = scale
        noise_apply(self.acc, q)

    @property
    def gyro_scale(self) -> float:
        """The course test's variance scale on the gyro white noise (1 = none)."""
        return float(self.acc[GSCALE])

    @property
    def gyro_floor(self) -> float:
        """Measured gyro white-noise variance over the configured one (>= 1)."""
        return float(self.acc[FLOOR_G])

    @property
    def accel_floor(self) -> float:
        """Measured accelerometer white-noise variance over the configured one (>= 1)."""
        return float(self.acc[FLOOR_A])
