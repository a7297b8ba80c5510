"""Alignment integrity: when the heading may be flagged "aligned" (docs/design.md §4).

Why.  The flag tells users (and autopilots fed by navd) that the yaw can be trusted.  Set
from one sample it lied: a single fast course at start, or a yaw sigma that an EKF shrank
on a wrong heading (at 2-3.4 m/s with noisy accelerometers the filter converged 90-150 deg
off with sigma ~1 deg and flagged it aligned), after which a >90 deg error looked like
reversing below ``[heading] max_reverse_speed_mps`` and blocked every correction (issue 14).

What.  Giving the filter a yaw (from a course, from observability) and *flagging* it aligned
are separate steps.  The yaw is set as before; the flag waits for evidence over time:

ground and boat profiles (course ~ heading)
    every GNSS epoch at >= ``_CHECK_SPEED`` (the default ``[heading] min_speed_mps`` of the
    course update; a configured higher one leaves the slower epochs to the checks alone)
    outside fast turns is a *course check*: d = wrap(yaw -
    course - learned sideslip); the check is *consistent* when |d| < 90 deg and
    d^2 <= 9 (P_yaw + sigma_course^2 + sigma_sideslip^2).  ``_CONFIRM_N`` consistent checks
    in a row spanning ``_CONFIRM_S`` set the flag (counted ``heading_aligned_from_course``
    or ``heading_aligned_by_observability`` by where the yaw came from); on a boat the yaw
    sigma must also be below ``[init] aligned_sd_deg`` (the course carries the crab of an
    unknown current until turns have told it).
other profiles (no course; without a yaw bank)
    the yaw sigma must stay below ``[init] aligned_sd_deg`` for ``_CONFIRM_N`` epochs over
    ``_CONFIRM_S`` while the GNSS updates move the yaw by less than 3 aligned_sd in total.

A run of consistent-direction checks beyond 3 sigma (``_CONFIRM_N`` over ``_CONFIRM_S``) says
the yaw has left its sigma: it is set to the course again and the flag drops
(``heading_reset_inconsistent``; where the course update does not run, nothing else would
notice).
That run is slow and one check back inside 3 sigma restarts it: a yaw drifting off at 2 m/s,
where one check's course sigma (~3 deg) is as large as the yaw's own, stayed flagged 20-50
deg off with sigma ~5 deg (issue 14).  So the flag also answers to the mean of the last
``_WATCH_N`` checks, whose course noise is ``_WATCH_N`` times smaller: beyond 3 sigma of
(P_yaw + mean course variance / ``_WATCH_N`` + sideslip) and beyond ``_WATCH_FLOOR`` the flag
drops at once (``heading_unflagged_drift``; the yaw is left to the filter and the run rule)
and comes back only after ``_CONFIRM_N`` consistent checks over ``_CONFIRM_S``, each with the
mean consistent too.  The floor: without it the mean (replayed on the logged checks of this
case) dropped the flag on 1-5 % of the instants of seeds whose heading error never left 3
sigma, so the window's checks are less independent than the white course noise model says;
a flag is a coarse statement, the sigma the fine one.
Backwards motion (|d| > 90 deg at a check) is reversing only for so long: from the first
backward check of a run, ``[heading] max_reverse_s`` (30 s) once the flag is set, or
``_CONFIRM_S`` with ``_CONFIRM_N`` checks while it is not (an unconfirmed yaw that points
backwards is more likely wrong than a car that reverses before it ever drove forward).
Beyond that the yaw is taken to be wrong: it is set to the course again (the caller does it)
and the flag drops until confirmed again (``heading_reset_reverse``).  The IMU's
accelerations tell reversing from a yaw 180 deg off (travel_direction.py): a yaw they
confirmed reverses however long (``reversing_long`` said once past ``max_reverse_s``), its
checks taken against the course + 180 deg as forward ones are against the course (a run
beyond 3 sigma then only drops the flag: ``heading_unflagged_inconsistent``), one
they show flipped is reset at once (``heading_reset_flipped``; ``heading_reset_behind`` when
the yaw came from the course of a vehicle backing up), and on the ground profile forward
checks below ``max_reverse_speed_mps`` flag the yaw only with their confirmation or after
``max_reverse_s`` of forward checks (a car backing out of its space has the same course as
one driving off).  In traditional mode,
which does not take course as heading, a failed check only drops the flag
(``heading_unflagged_*``).  Any yaw reset drops
the flag the same way.

With a yaw bank (``est.yaw_bank``) the bank owns the flag: this monitor only records the
yaw's origin and sets the flag where the yaw is set, as before.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from navd.config import EstimatorConfig
from navd.core.aiding.course_learner import CourseLearner, K

if TYPE_CHECKING:
    from navd.core.aiding.travel_direction import TravelDirection
    from navd.core.estimator import Estimator

_CHECK_SPEED = 1.5  # m/s: course checks from here (course sigma ~4 deg at 0.1 m/s noise)
_CONFIRM_N = 5  # consistent checks (epochs) in a row ...
_CONFIRM_S = 3.0  # ... spanning at least this long, s

# mean of the last few checks: course noise averaged down, so a yaw a few sigma off shows
# within half a second at 10 Hz (a run of single checks beyond 3 sigma needs _CONFIRM_S)
_WATCH_N = 5
_WATCH_FLOOR = 5.0 * math.pi / 180.0  # rad: below this the mean never drops the flag
# the IMU's accelerations showed the yaw 180 deg off within this: acted on at once, s
FLIPPED_RECENT_S = 5.0

_NONE, _COURSE, _OBSERVED = 0, 1, 2
# state array layout (no Python floats are rebound on the epoch path: the allocation test
# counts them): yaw origin, consistent run length, its first time (s), backward run length,
# its first time (s), yaw movement during the run (rad), flag for a requested realignment,
# inconsistent run length, its first time (s), checks in the watch window (count), first
# forward check since the last backward one (s, -1: none), this backward run counted as
# reversing_long (1)
(_ORIGIN, _OK_N, _OK_T0, _BACK_N, _BACK_T0, _MOVED, _REALIGN, _BAD_N, _BAD_T0,
 _WIN_N, _FWD_T0, _LONG) = range(12)


class HeadingAlignment:
    """When the heading may be flagged aligned (see the module doc); owned by
    :class:`navd.core.aiding.gnss_heading.CourseHeading`."""

    def __init__(self, cfg: EstimatorConfig) -> None:
        self.cfg = cfg
        self.course_checks = cfg.filter.profile in ("ground", "boat")
        # a boat's course agrees with its yaw whatever the current: the crab is in both
        # (the yaw was set from the course), so its flag also waits for the yaw sigma
        # (the current learnt in turns, aiding/course_learner.py)
        self._boat = cfg.filter.profile == "boat"
        # a car may reverse: below [heading] max_reverse_speed_mps its course checks flag
        # the yaw only once the IMU's accelerations confirmed it (travel_direction.py) or
        # after [heading] max_reverse_s of forward checks
        self._reverses = cfg.filter.profile == "ground"
        # traditional mode does not take course as heading: there a failed check only drops
        # the flag, the yaw is left to the filter
        self.may_realign = cfg.filter.mode == "completed"
        self._s = np.zeros(12)
        # the last _WATCH_N forward checks: (d (rad), course variance (rad^2)) per column,
        # written round-robin at _WIN_N % _WATCH_N
        self._win = np.zeros((2, _WATCH_N))
        self.reset()

    def reset(self) -> None:
        self._sigma_too = self._boat
        self._s[:] = 0.0
        self._s[_OK_T0] = -1.0
        self._s[_BACK_T0] = -1.0
        self._s[_BAD_T0] = -1.0
        self._s[_FWD_T0] = -1.0

    @property
    def yaw_set(self) -> bool:
        """Whether the filter's yaw has been given a value (course, observability, config)."""
        return bool(self._s[_ORIGIN] != _NONE)

    @property
    def realign_requested(self) -> bool:
        return bool(self._s[_REALIGN])

    def yaw_given(self, est: Estimator, from_course: bool) -> None:
        """The yaw was just set (from a course, or found observable): the flag waits."""
        s = self._s
        s[_ORIGIN] = _COURSE if from_course else _OBSERVED
        s[_OK_N] = 0.0
        s[_OK_T0] = -1.0
        s[_BACK_N] = 0.0
        s[_BACK_T0] = -1.0
        s[_BAD_N] = 0.0
        s[_BAD_T0] = -1.0
        s[_MOVED] = 0.0
        s[_REALIGN] = 0.0
        s[_WIN_N] = 0.0
        s[_FWD_T0] = -1.0
        s[_LONG] = 0.0
        if est.yaw_bank is not None:
            # the bank owns the flag; where the yaw is set the flag was set before
            if not est.heading_aligned:
                est.heading_aligned = True
                est.counters["heading_aligned_from_course" if from_course
                             else "heading_aligned_by_observability"] += 1
            return
        est.heading_aligned = False
        est.counters["heading_yaw_from_course" if from_course
                     else "heading_yaw_observable"] += 1

    def imu_turned(self, est: Estimator) -> None:
        """The yaw was turned to what the IMU's accelerations show (an IMU turned on the
        vehicle, gnss_heading.py): the checks go on against the course turned by the
        learnt mount, and the flag waits, as on a boat, also for the yaw sigma below
        ``[init] aligned_sd_deg`` (the mount's sigma floors it)."""
        self._sigma_too = True
        self.yaw_given(est, from_course=True)

    def imu_straight(self, est: Estimator) -> None:
        """A turn told by the IMU was dropped (gnss_heading.py): the checks go on against
        the course itself, the flag waiting for them as after any yaw given."""
        self._sigma_too = self._boat
        self.yaw_given(est, from_course=True)

    def config_heading(self) -> None:
        """The yaw came from config and is flagged aligned at once (the user says so)."""
        self._s[_ORIGIN] = _COURSE

    def note_yaw_moved(self, est: Estimator, d_yaw: float) -> None:
        """The epoch's GNSS updates turned the yaw by ``d_yaw`` rad.

        A flagged yaw that one epoch turns by more than three ``[init] aligned_sd`` was that
        far off while flagged: the flag drops and waits for a new run of consistent checks
        (``heading_unflagged_jump``).  After a velocity lock-out's reset widened the heading
        sigma to 10 deg, the next fixes turned a flagged yaw by 15 deg within 0.3 s, and
        the mean-of-checks watch dropped the flag only 0.4 s later (car480 at 2-3.4 m/s with
        5x the accelerometer noise, seed 5, 71 s, tilt 12 deg off).  With a yaw bank the
        bank owns the flag."""
        s = self._s
        s[_MOVED] += abs(d_yaw)
        if (est.heading_aligned and est.yaw_bank is None
                and abs(d_yaw) > 3.0 * self.cfg.init.aligned_sd):
            est.heading_aligned = False
            est.counters["heading_unflagged_jump"] += 1
            s[_OK_N] = 0.0
            s[_OK_T0] = -1.0
            s[_WIN_N] = 0.0

    def check_course(self, est: Estimator, t_us: int, vn: float, ve: float, s_sd: float,
                     learn: CourseLearner, sd_beta: float, dirn: TravelDirection) -> None:
        """One epoch's course check (ground and boat profiles, yaw set); may set the flag or
        request a realignment (:attr:`realign_requested`).  ``vn, ve``: the GNSS velocity
        (through the water on a boat: less the learnt current), m/s; ``s_sd``: per-axis
        speed sigma, m/s; ``learn``: the learnt sideslip (and current); ``sd_beta``: the
        configured sideslip sigma, rad; ``dirn``: which way the IMU's accelerations say the
        yaw points."""
        s = self._s
        if not self.course_checks or s[_ORIGIN] == _NONE or est.yaw_bank is not None:
            return
        speed = math.hypot(vn, ve)
        if speed < _CHECK_SPEED:
            s[_WIN_N] = 0.0  # the window holds consecutive checks only
            return
        c = self.cfg.heading
        m = est.mat_nb
        r = est.rate_b
        yaw_rate = m[2, 0] * r[0] + m[2, 1] * r[1] + m[2, 2] * r[2]
        if abs(yaw_rate) > c.max_yaw_rate or abs(yaw_rate) * speed > c.max_lat_accel:
            s[_WIN_N] = 0.0
            return
        t = t_us * 1e-6
        a_lat = yaw_rate * speed
        yaw = math.atan2(m[1, 0], m[0, 0])
        d = ((yaw - math.atan2(ve, vn) + float(learn.x[K]) * a_lat + math.pi)
             % (2.0 * math.pi) - math.pi)
        flipped = dirn.yaw_flipped_since(t - FLIPPED_RECENT_S)
        backward = abs(d) >= 0.5 * math.pi
        if backward and not flipped and dirn.yaw_right(float(est.P[2, 2])):
            # the IMU confirmed the yaw: reversing, however long (said once per run beyond
            # max_reverse_s: an IMU mounted backwards looks the same), and the reversed
            # course is the check (the course update fuses it too: gnss_heading.py)
            if s[_BACK_N] == 0.0:
                s[_BACK_T0] = t
                s[_OK_N] = 0.0
                s[_BAD_N] = 0.0
                s[_WIN_N] = 0.0
            s[_BACK_N] += 1.0
            if s[_LONG] == 0.0 and t - s[_BACK_T0] >= c.max_reverse:
                est.counters["reversing_long"] += 1
                s[_LONG] = 1.0
            d = (d + 2.0 * math.pi) % (2.0 * math.pi) - math.pi
        elif backward:
            s[_OK_N] = 0.0
            s[_BAD_N] = 0.0
            s[_WIN_N] = 0.0
            s[_FWD_T0] = -1.0
            if s[_BACK_N] == 0.0:
                s[_BACK_T0] = t
            s[_BACK_N] += 1.0
            if flipped:
                # the course and the IMU agree: forwards on a yaw 180 deg off
                self._wrong(est, "flipped")
                return
            # without the IMU's confirmation, reversing for as long as reversing explains
            limit = c.max_reverse if est.heading_aligned else _CONFIRM_S
            if (t - s[_BACK_T0] >= limit
                    and (est.heading_aligned or s[_BACK_N] >= _CONFIRM_N)):
                self._wrong(est, "reverse")
            return
        else:
            if flipped:
                # the yaw was set from the course of a vehicle that backs up (the IMU says
                # it points 180 deg off): realigned to the course + 180 deg
                # (gnss_heading.align_yaw)
                s[_BACK_N] = 0.0
                self._wrong(est, "behind")
                return
            if s[_BACK_N] > 0.0:
                # the direction of travel changed: a new run of checks
                s[_OK_N] = 0.0
                s[_BAD_N] = 0.0
                s[_WIN_N] = 0.0
            s[_BACK_N] = 0.0
            s[_LONG] = 0.0
            if s[_FWD_T0] < 0.0:
                s[_FWD_T0] = t
        var_c = (s_sd / speed) ** 2
        var_y = float(est.P[2, 2]) + sd_beta * sd_beta + learn.course_var(a_lat, yaw, vn, ve)
        var = var_y + var_c
        drift = self._watch(d, var_c, var_y)
        if drift and est.heading_aligned:
            # the mean of the last checks says the yaw has left its sigma: not aligned now
            est.heading_aligned = False
            est.counters["heading_unflagged_drift"] += 1
        if d * d > 9.0 * var:
            # forwards but beyond 3 sigma: a few epochs are noise or an unmodelled slip;
            # a run of them says the yaw has left its sigma (a filter whose tilt a noisy
            # accelerometer corrupts turns its yaw slowly), and at low speed no course
            # update is there to notice
            s[_OK_N] = 0.0
            if s[_BAD_N] == 0.0:
                s[_BAD_T0] = t
            s[_BAD_N] += 1.0
            if s[_BAD_N] >= _CONFIRM_N and t - s[_BAD_T0] >= _CONFIRM_S:
                if backward:
                    # reversing: the IMU vouches for the yaw's side, a realignment to the
                    # course would not know it; the flag waits for consistency again
                    s[_BAD_N] = 0.0
                    if est.heading_aligned:
                        est.heading_aligned = False
                        est.counters["heading_unflagged_inconsistent"] += 1
                else:
                    self._wrong(est, "inconsistent")
            return
        s[_BAD_N] = 0.0
        if drift:
            s[_OK_N] = 0.0
            return
        if s[_OK_N] == 0.0:
            s[_OK_T0] = t
        s[_OK_N] += 1.0
        if (not est.heading_aligned and s[_OK_N] >= _CONFIRM_N
                and t - s[_OK_T0] >= _CONFIRM_S
                and (not self._sigma_too or est.P[2, 2] < self.cfg.init.aligned_sd ** 2)
                and (speed >= c.max_reverse_speed or not self._reverses
                     or t - s[_FWD_T0] >= c.max_reverse
                     or dirn.yaw_right(float(est.P[2, 2])))):
            # at reversing speeds a car's course agrees as well with a yaw 180 deg off
            # (it backs out of its space): the flag waits for the IMU to tell the two
            # apart, or for forward checks for longer than reversing lasts
            self._flag(est)

    def _watch(self, d: float, var_c: float, var_y: float) -> bool:
        """Add one forward check (``d`` rad, course variance ``var_c``, the rest of its
        variance ``var_y``, rad^2) to the window; whether the window's mean is beyond 3 sigma
        and ``_WATCH_FLOOR`` (the yaw has left its sigma)."""
        s = self._s
        w = self._win
        k = int(s[_WIN_N]) % _WATCH_N
        w[0, k] = d
        w[1, k] = var_c
        s[_WIN_N] += 1.0
        if s[_WIN_N] < _WATCH_N:
            return False
        mean = 0.0
        vc = 0.0
        for i in range(_WATCH_N):
            mean += w[0, i]
            vc += w[1, i]
        mean /= _WATCH_N
        # var of the mean: the yaw's (common to all checks) + the course noise averaged down
        lim = 3.0 * math.sqrt(var_y + vc / (_WATCH_N * _WATCH_N))
        return abs(mean) > max(lim, _WATCH_FLOOR)

    def check_observed(self, est: Estimator, t_us: int) -> None:
        """One epoch of the observability rule (profiles without course checks)."""
        s = self._s
        if (self.course_checks or est.yaw_bank is not None or est.heading_aligned
                or s[_ORIGIN] == _NONE):
            return
        sd = self.cfg.init.aligned_sd
        if est.P[2, 2] >= sd * sd or s[_MOVED] > 3.0 * sd:
            s[_OK_N] = 0.0
            s[_MOVED] = 0.0
            return
        t = t_us * 1e-6
        if s[_OK_N] == 0.0:
            s[_OK_T0] = t
        s[_OK_N] += 1.0
        if s[_OK_N] >= _CONFIRM_N and t - s[_OK_T0] >= _CONFIRM_S:
            self._flag(est)

    def _wrong(self, est: Estimator, why: str) -> None:
        """The checks say the yaw is wrong: ask for a realignment (completed mode) or, where
        course is not heading (traditional mode), drop the flag until they agree again."""
        s = self._s
        if self.may_realign:
            s[_REALIGN] = 1.0
            est.counters["heading_reset_" + why] += 1
            return
        s[_BACK_N] = 0.0
        s[_BAD_N] = 0.0
        if est.heading_aligned:
            est.heading_aligned = False
            est.counters["heading_unflagged_" + why] += 1

    def _flag(self, est: Estimator) -> None:
        est.heading_aligned = True
        est.counters["heading_aligned_from_course" if self._s[_ORIGIN] == _COURSE
                     else "heading_aligned_by_observability"] += 1

    @property
    def status(self) -> str:
        """For the status record: none / pending / aligned."""
        o = self._s[_ORIGIN]
        if o == _NONE:
            return "no yaw yet"
        return f"yaw from {'course' if o == _COURSE else 'observability'}"
