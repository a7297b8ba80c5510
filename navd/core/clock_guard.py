"""Clock guard: only a sustained, self-consistent new sensor clock may restart navigation.

The estimator starts over when IMU time jumps back or ahead by more than a second
(``reinit_time_jump``): that is what an autopilot reboot looks like, and issue 16 wants
output back within a second of it.  It is also what one forged or corrupted time stamp
looks like, and a stream of them (zero, 2**63, backwards, duplicates, hours ahead) used to
reset the filter on every packet (issue 19 item 3).  :class:`ClockGuard` sits in front of
:meth:`Estimator.push` and tells the two apart:

* An IMU sample on the current clock (at most ``back_tolerance_us`` behind the newest
  accepted stamp, at most ``max_gap_us`` ahead of it) passes.  Small disorder and
  duplicates are the estimator's to refuse and count, without a reset.
* A jump ahead that the host clock confirms (at least as much host time passed since the
  last accepted sample, less ``max_gap_us``: the link was quiet, a real gap) passes too.
  Without host time (replay) jumps up to 1 s ahead pass, as the estimator alone would
  take them.
* Anything else is held as a *candidate* clock and counted (``clock_wild``).  A candidate
  grows with each sample that continues it (ahead of its newest stamp by at most
  ``max_gap_us``).  It becomes the clock once it holds ``confirm_n`` samples spanning
  ``confirm_us`` of its own time and, when host time is known, ``confirm_us`` of host
  time, while the current clock stayed silent: any sample on the current clock discards
  every candidate.  Then the held samples are released in their order, so the estimator
  sees exactly the new clock's stream (and restarts on its first sample as before); the
  delay is ``confirm_us``, the data is not lost.  A forged stamp is a one-sample candidate
  that never confirms; a burst of forged consistent stamps fails on host time.
* GNSS and polarization samples pass, except that while a candidate is pending a sample
  whose stamp is near the candidate and far from the current clock is held with it (the
  fixes of a rebooted autopilot belong to its new clock).
* Stamps outside (0, 2**53) are refused (``clock_out_of_range``).

Counters (``counters``): ``clock_wild`` (IMU samples not on the current clock),
``clock_new`` (candidates that became the clock), ``clock_dropped`` (held samples thrown
away with a candidate that died), ``clock_out_of_range``.  Pure bookkeeping on integers:
no clock is read here; the caller passes host time as data.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field

from navd.types import ImuSample, Sample

__all__ = ["ClockGuard"]

_MAX_T_US = 1 << 53
# how far a GNSS/polarization stamp may lie from a clock's IMU stamps and still belong to it
_NEAR_US = 2_000_000
# without host time, the estimator's own limit: a jump beyond it restarts navigation
_REPLAY_AHEAD_US = 1_000_000


@dataclass
class _Candidate:
    first_t: int
    last_t: int
    first_host: int | None
    last_host: int | None
    n: int = 1
    items: list[Sample] = field(default_factory=list)


class ClockGuard:
    """See the module docstring.  ``push(sample, host_us)`` returns the samples to hand to
    the estimator now, in order (usually just ``sample``; none while it is held; a candidate's
    whole stream when it becomes the clock)."""

    def __init__(self, max_gap_us: int = 100_000, back_tolerance_us: int = 1_000_000,
                 confirm_n: int = 10, confirm_us: int = 200_000, max_held: int = 4096,
                 max_candidates: int = 4) -> None:
        if max_gap_us <= 0 or confirm_n < 2 or confirm_us <= 0 or max_held < confirm_n:
            raise ValueError("ClockGuard: bad limits")
        self.max_gap_us = max_gap_us
        self.back_tolerance_us = back_tolerance_us
        self.confirm_n = confirm_n
        self.confirm_us = confirm_us
        self.max_held = max_held
        self.max_candidates = max_candidates
        self.counters: defaultdict[str, int] = defaultdict(int)
        self.t_us = -1  # newest IMU stamp accepted on the current clock (-1: no clock yet)
        self._host_at_t: int | None = None
        self._cands: list[_Candidate] = []
        # the last clock change: (old newest stamp, new first stamp), for the status
        self.last_change: tuple[int, int] | None = None

    @property
    def pending(self) -> int:
        """Samples held in candidates."""
        return sum(len(c.items) for c in self._cands)

    def push(self, s: Sample, host_us: int | None = None) -> list[Sample]:
        t = s.t_us
        if not 0 < t < _MAX_T_US:
            self.counters["clock_out_of_range"] += 1
            return []
        if not isinstance(s, ImuSample):
            return self._aid(s)
        ref = self.t_us
        if ref >= 0:
            ahead = t - ref
            if -self.back_tolerance_us <= ahead <= self.max_gap_us or (
                    ahead > 0 and self._gap_is_real(ahead, host_us)):
                if ahead > 0:  # the current clock lives on: no candidate can be a reboot
                    self.t_us = t
                    self._host_at_t = host_us
                    if self._cands:
                        self._drop_candidates()
                return [s]
            self.counters["clock_wild"] += 1
        return self._hold(s, host_us)

    def on_clock(self, t: int, host_us: int | None) -> bool:
        """The usual case of :meth:`push` for an IMU sample stamped ``t``, without building
        its one-sample list: True, with the same bookkeeping, when ``push`` would pass the
        sample alone because it is on the current clock and no candidate is pending; False,
        nothing changed, for anything else (then call :meth:`push`).  The kHz path (issue 18)."""
        ref = self.t_us
        if ref < 0 or self._cands or not 0 < t < _MAX_T_US:
            return False
        ahead = t - ref
        if not -self.back_tolerance_us <= ahead <= self.max_gap_us:
            return False
        if ahead > 0:
            self.t_us = t
            self._host_at_t = host_us
        return True

    def lane_clock(self) -> int:
        """The newest stamp of the current clock when :meth:`on_clock` may pass samples
        (a clock, no candidate pending); -1 otherwise.  With ``back_tolerance_us`` and
        ``max_gap_us`` it is what a compiled run over a block of samples checks
        (``Estimator.push_imu_block``); :meth:`on_clock_run` then does the bookkeeping."""
        return self.t_us if not self._cands else -1

    def on_clock_run(self, t_newest: int, host_us: int | None) -> None:
        """:meth:`on_clock` of a run of samples received at ``host_us`` that were each on
        the clock (checked by the run), in increasing order, the newest stamped
        ``t_newest``: the same bookkeeping."""
        if t_newest > self.t_us:
            self.t_us = t_newest
            self._host_at_t = host_us

    def _gap_is_real(self, ahead: int, host_us: int | None) -> bool:
        if host_us is None or self._host_at_t is None:
            return ahead <= _REPLAY_AHEAD_US
        return host_us - self._host_at_t >= ahead - self.max_gap_us

    def _aid(self, s: Sample) -> list[Sample]:
        """GNSS / polarization: held with a pending candidate it belongs to, else passed."""
        if self._cands:
            t = s.t_us
            if self.t_us < 0 or abs(t - self.t_us) > _NEAR_US:
                for c in self._cands:
                    if c.first_t - _NEAR_US <= t <= c.last_t + _NEAR_US:
                        self._keep(c, s)
                        return []
        return [s]

    def _keep(self, c: _Candidate, s: Sample) -> None:
        if len(c.items) < self.max_held:
            c.items.append(s)
        else:
            self.counters["clock_dropped"] += 1

    def _hold(self, s: ImuSample, host_us: int | None) -> list[Sample]:
        t = s.t_us
        for c in self._cands:
            if 0 < t - c.last_t <= self.max_gap_us:
                c.last_t = t
                c.last_host = host_us
                c.n += 1
                self._keep(c, s)
                if self._confirmed(c):
                    return self._adopt(c)
                return []
        if len(self._cands) >= self.max_candidates:
            # the candidate with the fewest samples goes (the oldest of those): a forged
            # stamp cannot push out a clock that is building up
            worst = min(range(len(self._cands)), key=lambda k: (self._cands[k].n, k))
            self.counters["clock_dropped"] += len(self._cands.pop(worst).items)
        self._cands.append(_Candidate(t, t, host_us, host_us, items=[s]))
        return []

    def _confirmed(self, c: _Candidate) -> bool:
        if c.n < self.confirm_n or c.last_t - c.first_t < self.confirm_us:
            return False
        if c.first_host is None or c.last_host is None:
            return True
        return c.last_host - c.first_host >= self.confirm_us

    def _adopt(self, c: _Candidate) -> list[Sample]:
        self._cands.remove(c)
        self._drop_candidates()
        self.last_change = (self.t_us, c.first_t)
        if self.t_us >= 0:
            self.counters["clock_new"] += 1
        self.t_us = c.last_t
        self._host_at_t = c.last_host
        return c.items

    def _drop_candidates(self) -> None:
        for c in self._cands:
            self.counters["clock_dropped"] += len(c.items)
        self._cands.clear()

    def status(self) -> dict[str, object]:
        out: dict[str, object] = {k: v for k, v in self.counters.items() if v}
        if self._cands:
            out["candidates"] = len(self._cands)
            out["held"] = self.pending
        if self.last_change is not None and self.last_change[0] >= 0:
            out["last_change_s"] = [round(self.last_change[0] * 1e-6, 3),
                                    round(self.last_change[1] * 1e-6, 3)]
        return out
