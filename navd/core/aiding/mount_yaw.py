"""The IMU's yaw on a ground vehicle, learnt once its accelerations showed it turned.

Why.  A course is the heading of the vehicle, not of an IMU turned on it.  When the IMU's
accelerations put its yaw 60-120 deg from the course (travel_direction.py) the course used
to be dropped for the rest of the run; the heading then came from accelerations alone and
wandered 6-21 deg off at sigma ~3 deg between them (issue 14).  The course still tells the
heading between accelerations, to within one constant: the IMU's yaw on the vehicle, mu.

What.  One scalar Kalman filter for mu (rad, heading of the body x axis less the course;
constant: a bracket does not turn).  Each decisive epoch of the travel-direction monitor
measures it as the filter's yaw plus the yaw error the epoch showed, less the course then
(:meth:`TravelDirection.decisive_mount`): where the fixes have put the yaw cancels.  The
monitor's leaky sums share most of their data over their longest time constant, so one
measurement per ``_MEAS_DT`` is taken, with ``_MEAS_FLOOR`` added to the sums' own noise for
what it leaves out (antenna lever arm in turns, the GNSS latency, tilt errors).  The course
rows use course + mu (gnss_heading.py) with P_mumu added to their noise, and the yaw
variance is never left below P_mumu: every row shares the same mu error, which independent
rows would average away.  docs/design.md §4 ("An IMU turned on the vehicle").

Before that, on the ground profile, a second instance is a *watch* beside course rows that
take mu = 0 (applied to nothing): an IMU turned by less than 60 deg never shows a verdict
"between", and the rows bend the verdicts toward 0, but not to it.  The watch's mu beyond
``WATCH_K`` sigma and ``WATCH_MIN`` for ``WATCH_N`` measurements in a row says the IMU is
turned (the benchmark's ground cases, seeds 1-3: never beyond 1.7 sigma; 20 deg mounts
reach 4.5-4.8 sigma, reading 9-15 deg, seeds 1-2, and are told at 122-176 s, seeds 1-3;
10 deg mounts on 2 seeds of 3, at 239-365 s).  A told mu up to 10 deg starts the learner
with the course rows kept on (gnss_heading.py, ``_watch_told``); before any verdict the
watch's likelihood weighs the installation's prior, a mixture (:func:`installation_moment`),
into the reported yaw sigma.
"""

from __future__ import annotations

import math

import numpy as np

from navd.core.rotation import wrap_pi

_MEAS_DT = 6.0  # s between measurements: travel_direction._TAUS' longest
_MEAS_FLOOR = 3.0 * math.pi / 180.0  # rad, added to every measurement's sigma
_GATE = 9.0  # chi-square(1), a measurement beyond it is not used (a GNSS glitch, a skid)
(_MU, _VAR, _T, _ON, _RUN, _T0, _V0) = range(7)
WATCH_K = 3.0
WATCH_MIN = 5.0 * math.pi / 180.0  # rad: less is not worth a yaw sigma floored at P_mumu
WATCH_N = 3


class MountYaw:
    """The IMU's yaw on the vehicle and its variance (module doc).  Arrays only: the epoch
    loop rebinds no Python objects."""

    def __init__(self) -> None:
        self._s = np.zeros(7)
        self.reset()

    def reset(self) -> None:
        self._s[:] = 0.0
        self._s[_T] = -math.inf
        self._s[_T0] = math.nan

    @property
    def active(self) -> bool:
        return bool(self._s[_ON])

    @property
    def mu(self) -> float:
        """The IMU's yaw on the vehicle, rad (right +: the body x axis right of travel)."""
        return float(self._s[_MU])

    @property
    def var(self) -> float:
        """Its variance, rad^2."""
        return float(self._s[_VAR])

    @property
    def t_start_s(self) -> float:
        """When it was last started, s (NaN: never)."""
        return float(self._s[_T0])

    @property
    def var_start(self) -> float:
        """The variance it was started with, rad^2."""
        return float(self._s[_V0])

    def start(self, mu: float, var: float, t_s: float = math.nan) -> None:
        """The IMU's accelerations put its yaw ``mu`` rad from the course (variance ``var``
        rad^2) at ``t_s``; a later turn restarts from its own verdict."""
        s = self._s
        s[_MU] = wrap_pi(mu)
        s[_VAR] = var
        s[_T] = -math.inf
        s[_ON] = 1.0
        s[_T0] = t_s
        s[_V0] = var

    def measure(self, z: float, sd: float, t_s: float) -> float:
        """A decisive epoch's mu ``z`` rad with its sigma ``sd`` rad at ``t_s``; returns
        how far the estimate moved, rad (0 when not used)."""
        s = self._s
        if not s[_ON] or not math.isfinite(z) or t_s - s[_T] < _MEAS_DT:
            return 0.0
        r = sd * sd + _MEAS_FLOOR * _MEAS_FLOOR
        nu = wrap_pi(z - s[_MU])
        if abs(nu) > 0.5 * math.pi or nu * nu > _GATE * (s[_VAR] + r):
            # (beyond 90 deg: a vehicle backing up, its course behind it)
            return 0.0
        s[_T] = t_s
        k = s[_VAR] / (s[_VAR] + r)
        d = k * nu
        s[_MU] = wrap_pi(s[_MU] + d)
        s[_VAR] = (1.0 - k) * s[_VAR]
        # measurements in a row that put mu beyond the watch's bounds (:attr:`turned`)
        out = abs(s[_MU]) > max(WATCH_MIN, WATCH_K * math.sqrt(s[_VAR]))
        s[_RUN] = s[_RUN] + 1.0 if out else 0.0
        return float(d)

    @property
    def turned(self) -> bool:
        """Whether the last ``WATCH_N`` measurements each left mu beyond ``WATCH_K`` sigma
        and ``WATCH_MIN`` from 0 (the watch's verdict: the IMU is turned)."""
        return bool(self._s[_RUN] >= WATCH_N)


# The installation's prior, as a mixture (:func:`installation_moment`): most IMUs are fixed
# within ``[imu] mount_yaw_sd_deg`` of the vehicle's axis, some are not (a bracket bent, a
# board screwed in by eye); a Gaussian of 1 deg alone makes a 10 deg mount a 10-sigma
# event that no evidence short of the watch's verdict can move.
# One in fifty: the prior's own moment (1.73 deg with the 1 deg core) leaves a straight IMU's
# heading usable at alignment ([init] aligned_sd_deg 2); 0.1 covered more 3-10 deg mounts
# before they were told but kept a straight IMU's heading above 2 deg until 66-98 s into
# car480, aligned at 4.1 s (docs/design.md §4, "The installation's share").
TAIL_P = 0.02  # the share of installations in the tail
TAIL_SD = 10.0 * math.pi / 180.0  # rad: its sigma (turns beyond ~20 deg the watch tells)


def installation_moment(core_var: float, mu: float, var: float, start_var: float) -> float:
    """The second moment of the IMU's yaw on the vehicle about 0, rad^2: what the reported
    yaw (the course's, taken to be the IMU's) is off by, given the installation's prior
    (``core_var`` rad^2 with probability 1 - ``TAIL_P``, ``TAIL_SD`` with ``TAIL_P``) and
    the watch's estimate ``mu`` rad with variance ``var`` rad^2, started at 0 with
    ``start_var`` rad^2 (whose prior is taken out, leaving the measurements' likelihood;
    with none yet, the prior's own moment).  ``core_var`` 0 (an IMU stated boresighted)
    has no tail: 0.  Never below ``core_var``: the watch's rows take the mount to be 0 and
    bend its verdicts toward 0 (module doc), so evidence for a small mount is weaker than
    it states."""
    if core_var <= 0.0:
        return 0.0
    tail_var = max(TAIL_SD * TAIL_SD, core_var)
    prior = (1.0 - TAIL_P) * core_var + TAIL_P * tail_var
    if not (math.isfinite(mu) and math.isfinite(var)) or var <= 0.0:
        return prior
    # the measurements' information, rad^-2 (the watch's start taken out)
    lam = max(1.0 / var - 1.0 / start_var, 0.0)
    # per component k, with the likelihood N(mu_l; m, 1/lam) written through lam so that no
    # evidence (lam 0) is the prior: the weight's log (less common terms) and the posterior
    # second moment about 0; a_k = 1 + core_k * lam
    b = mu / var  # mu_l * lam (the watch started at 0), rad^-1
    a0 = 1.0 + core_var * lam
    a1 = 1.0 + tail_var * lam
    l0 = math.log(1.0 - TAIL_P) - 0.5 * math.log(a0) + 0.5 * core_var * b * b / a0
    l1 = math.log(TAIL_P) - 0.5 * math.log(a1) + 0.5 * tail_var * b * b / a1
    w1 = 1.0 / (1.0 + math.exp(max(min(l0 - l1, 700.0), -700.0)))
    m0 = core_var * b / a0
    m1 = tail_var * b / a1
    e0 = m0 * m0 + core_var / a0
    e1 = m1 * m1 + tail_var / a1
    return max(core_var, (1.0 - w1) * e0 + w1 * e1)
