"""A vehicle type from the GNSS track, for logs that state none (the InertialNav text logs).

Only one kind is recognised, by a signature no ground vehicle and no fixed wing can make:
**climbing or descending steeply while standing still horizontally**.  Over a window of
``WINDOW_S`` seconds in which no fix is faster than ``MAX_SPEED``, the altitude (median of
the first and the last ``END_S`` seconds) changes by at least ``MIN_CLIMB_M`` and 5 times
the noise of that difference (from the scatter at each end), the vertical velocity, where
the log has it, agrees, and the net horizontal displacement (the velocity integrated, so a
position jump is no travel) is below 1.7 times the change: a climb steeper than 30 degrees
at walking pace.  The path flown must also stay below 3 times the change (a car on a spiral
ramp).  A car needs a 58 % grade for that, a fixed wing would stall; a multirotor (or a
helicopter, or a VTOL in hover: the multirotor profile suits them) does it at every
take-off.  Anything else stays unknown and the configured profile is kept.

Checked on the four real logs and on every simulator scenario, seeds 1-3 (docs/results.md,
"InertialNav quads"); tests/test_logs_infer.py keeps a take-off, four look-alikes and four
of the scenarios.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

WINDOW_S = 15.0  # s
END_S = 3.0  # s: the altitude at each end of a window is the median over this long
MIN_CLIMB_M = 6.0  # m: well beyond consumer GNSS altitude noise after a 3 s median
MAX_SPEED = 3.0  # m/s: every fix of the window at most this fast (a hover, not a glitch)
STEEP = 1.7  # net horizontal displacement below this times the climb: steeper than 30 deg


def hover_climb(gnss_t_us: npt.NDArray[np.int64], gnss: npt.NDArray[np.float64]
                ) -> tuple[float, float, float] | None:
    """The first window that climbs or descends >= MIN_CLIMB_M over a net horizontal
    displacement shorter than the climb: (start s from the first fix, altitude change m,
    displacement m), or None.

    ``gnss_t_us`` (M,) int64; ``gnss`` (M, >= 5): lat, lon (rad), altitude (m), velocity
    north, east (m/s) (:class:`navd.io.logs.common.LogData` layout).  Non-finite rows are
    ignored."""
    ok = np.isfinite(gnss[:, 2]) & np.isfinite(gnss[:, 3]) & np.isfinite(gnss[:, 4])
    if ok.sum() < 3:
        return None
    t = (gnss_t_us[ok] - gnss_t_us[ok][0]) * 1e-6
    alt = gnss[ok, 2]
    speed = np.hypot(gnss[ok, 3], gnss[ok, 4])
    vd = gnss[ok, 5] if gnss.shape[1] > 5 else np.full(t.size, np.nan)
    # path flown up to each fix: trapezoid of the ground speed (a position jump is no travel)
    dt = np.diff(t)
    path = np.concatenate(([0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * dt)))
    climb_vd = np.concatenate(([0.0], np.cumsum(-0.5 * (vd[1:] + vd[:-1]) * dt)))
    disp_n = np.concatenate(([0.0], np.cumsum(0.5 * (gnss[ok, 3][1:] + gnss[ok, 3][:-1]) * dt)))
    disp_e = np.concatenate(([0.0], np.cumsum(0.5 * (gnss[ok, 4][1:] + gnss[ok, 4][:-1]) * dt)))
    t0 = 0.0
    while t0 + WINDOW_S <= t[-1]:
        a = np.flatnonzero((t >= t0) & (t < t0 + END_S))
        b = np.flatnonzero((t > t0 + WINDOW_S - END_S) & (t <= t0 + WINDOW_S))
        t0 += END_S
        if a.size < 3 or b.size < 3:
            continue
        w = slice(int(a[0]), int(b[-1]) + 1)
        if float(np.max(speed[w])) > MAX_SPEED:
            continue
        climb = float(np.median(alt[b]) - np.median(alt[a]))
        # the noise of that difference, from the scatter at each end (white GNSS noise, as
        # simulators make it, is large; a real receiver's altitude is smooth over seconds and
        # MIN_CLIMB_M covers its slow wander); 1.25: a median's efficiency
        sd = 1.25 * math.hypot(float(np.std(alt[a])) / math.sqrt(a.size),
                               float(np.std(alt[b])) / math.sqrt(b.size))
        ia, ib = int(a[0]), int(b[-1])
        flown = float(path[ib] - path[ia])
        moved = math.hypot(float(disp_n[ib] - disp_n[ia]), float(disp_e[ib] - disp_e[ia]))
        # net displacement below STEEP times the climb: steeper than 30 deg; the path flown
        # (which speed noise inflates in a hover) below 3 times it: not a spiral car-park ramp
        if (abs(climb) < max(MIN_CLIMB_M, 5.0 * sd) or moved >= STEEP * abs(climb)
                or flown >= 3.0 * abs(climb)):
            continue
        by_vd = float(climb_vd[ib] - climb_vd[ia])
        if math.isfinite(by_vd) and abs(by_vd - climb) > max(3.0, 0.5 * abs(climb)):
            continue  # the vertical velocity does not confirm it: an altitude jump
        return t0 - END_S, climb, moved
    return None


def infer_vehicle(gnss_t_us: npt.NDArray[np.int64], gnss: npt.NDArray[np.float64]
                  ) -> tuple[str, str]:
    """("multirotor", why) when the track shows :func:`hover_climb`, else ("", "")."""
    h = hover_climb(gnss_t_us, gnss)
    if h is None:
        return "", ""
    t0, climb, flown = h
    verb = "climbed" if climb > 0 else "descended"
    return "multirotor", (f"inferred from the GNSS track: {verb} {abs(climb):.1f} m while "
                          f"moving {flown:.1f} m horizontally in {WINDOW_S:.0f} s from "
                          f"{t0:.0f} s (steeper than 30 deg at <= 3 m/s: it hovers)")
