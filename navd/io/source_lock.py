"""Source locking: one sender per kind of input, chosen by who delivered first.

A MAVLink network or a CAN bus carries whatever any participant sends; ``allow`` lists
(``[mavlink] allow``, ``[dronecan] allow_nodes``) are empty by default, so any sysid/compid
or node could feed the estimator.  One IMU stream and one GNSS stream are what the filter
can use: two IMU streams interleaved integrate two motions into one, and a second GNSS
stream pulls the position back and forth.  :class:`SourceLock` therefore locks each kind
(``"imu"``, ``"gnss"``, ``"pol"``) onto the first source that delivers a usable sample of
it, and refuses every other source of that kind (counted ``<kind>_source_refused``, one
rate-limited log line per reason).  The lock moves only when the locked source has been
silent for ``relock_s`` (counted ``<kind>_source_relock``, logged): a rebooted autopilot
comes back, a replaced sensor takes over, a second sender that merely talks at the same
time never does.

A second IMU stream is not thrown away unread: :class:`ImuAgreement` compares its mean
angular rate and specific force over 1 s windows with the locked stream's.  Two IMUs on
one vehicle agree to within their biases; a stream of some other motion (a spoofer, a
bench unit, a mis-addressed vehicle) does not, and that is counted
``imu_source_contradicts`` and logged: the operator learns that the vehicle carries a
sender which is lying, or that the lock chose the wrong one (then ``allow`` pins it).

Sources are opaque hashables (MAVLink ``(sysid, compid)``, a DroneCAN node id); time is the
host receive clock in microseconds (the wire's sensor time is exactly what a hostile
sender controls).  Memory is bounded: at most :data:`MAX_OTHERS` refused sources are
tracked per kind for the status.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Hashable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from navd.io.common import Rejector

__all__ = ["AGREE_ACCEL_MPS2", "AGREE_GYRO_RPS", "MAX_OTHERS", "ImuAgreement", "SourceLock"]

# Refused sources remembered per kind (for the status); a flood of spoofed ids beyond this
# is still refused and counted, just not listed one by one.
MAX_OTHERS = 8
# Two IMUs on one rigid vehicle differ in their 1 s means by their biases (MEMS: < 0.01
# rad/s, < 0.5 m/s^2) and lever-arm terms (small at vehicle rates); beyond these limits
# the two streams describe different motions.
AGREE_GYRO_RPS = 0.05
AGREE_ACCEL_MPS2 = 1.0
_WINDOW_US = 1_000_000
_MIN_SAMPLES = 10


def _note(reject: Rejector, reason: str, detail: str, *args: object) -> None:
    """Count and log (rate-limited) an event that is not the refusal of a sample."""
    reject.counters.inc(reason)
    reject.log.warn(reason, f"{reject.prefix}: {detail}", *args)


@dataclass
class _Mean:
    """Sums of angular rate (rad/s, body FRD) and specific force (m/s^2) over a window."""

    n: int = 0
    gyro: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    accel: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])

    def add(self, gyro: tuple[float, float, float], accel: tuple[float, float, float]) -> None:
        self.n += 1
        g, a = self.gyro, self.accel
        g[0] += gyro[0]
        g[1] += gyro[1]
        g[2] += gyro[2]
        a[0] += accel[0]
        a[1] += accel[1]
        a[2] += accel[2]

    def diff(self, other: _Mean) -> tuple[float, float]:
        """Norms of the differences of the two means: (rad/s, m/s^2)."""
        dg = math.dist([v / self.n for v in self.gyro], [v / other.n for v in other.gyro])
        da = math.dist([v / self.n for v in self.accel], [v / other.n for v in other.accel])
        return dg, da


class ImuAgreement:
    """Compares other IMU streams with the locked one, window by window of receive time.

    The locked stream's window sums are kept in plain attributes (issue 18: it is added to
    at the IMU rate), in the order :class:`_Mean` would add them.
    """

    __slots__ = ("_lax", "_lay", "_laz", "_lgx", "_lgy", "_lgz", "_ln", "_others", "_reject",
                 "_start_us", "_text", "contradicting", "last_diff")

    def __init__(self, reject: Rejector, text: Callable[[Hashable], str]) -> None:
        self._reject = reject
        self._text = text
        self._start_us = -1
        self._ln = 0
        self._lgx = self._lgy = self._lgz = self._lax = self._lay = self._laz = 0.0
        self._others: dict[Hashable, _Mean] = {}
        # the source last found to contradict the locked one, and by how much
        self.contradicting: Hashable | None = None
        self.last_diff: tuple[float, float] = (0.0, 0.0)

    def add(self, locked: bool, src: Hashable, now_us: int,
            gyro: tuple[float, float, float], accel: tuple[float, float, float]) -> None:
        if locked:
            self.add_locked(now_us, gyro[0], gyro[1], gyro[2], accel[0], accel[1], accel[2])
            return
        self._window(now_us)
        m = self._others.get(src)
        if m is None:
            if len(self._others) >= MAX_OTHERS:
                return
            m = self._others[src] = _Mean()
        m.add(gyro, accel)

    def add_locked(self, now_us: int, gx: float, gy: float, gz: float, ax: float, ay: float,
                   az: float) -> None:
        """:meth:`add` of a sample of the locked source, from its components (the decoder's
        per-sample path, issue 18: no tuples)."""
        start = self._start_us
        if start < 0 or now_us < start or now_us - start >= _WINDOW_US:
            self._window(now_us)
        self._ln += 1
        self._lgx += gx
        self._lgy += gy
        self._lgz += gz
        self._lax += ax
        self._lay += ay
        self._laz += az

    def lane_sums(self, now_us: int, sums: npt.NDArray[np.float64]) -> bool:
        """What a run of :meth:`add_locked` at receive time ``now_us`` adds to: the locked
        stream's window sums (rate xyz, specific force xyz) into ``sums`` (6,), or zeros
        when the run starts a new window (returned True: pass it on to
        :meth:`add_locked_run`).  The batch lane."""
        start = self._start_us
        if start < 0 or now_us < start or now_us - start >= _WINDOW_US:
            sums[:] = 0.0
            return True
        sums[0], sums[1], sums[2] = self._lgx, self._lgy, self._lgz
        sums[3], sums[4], sums[5] = self._lax, self._lay, self._laz
        return False

    def add_locked_run(self, now_us: int, fresh: bool, n: int,
                       sums: npt.NDArray[np.float64]) -> None:
        """:meth:`add_locked` of ``n`` samples received at ``now_us``, whose components were
        added in order to the sums :meth:`lane_sums` gave (``fresh``, its answer: from zero,
        and the new window starts here, judging the old one)."""
        if fresh:
            self._window(now_us)
        self._ln += n
        self._lgx, self._lgy, self._lgz = float(sums[0]), float(sums[1]), float(sums[2])
        self._lax, self._lay, self._laz = float(sums[3]), float(sums[4]), float(sums[5])

    def locked_mean(self) -> _Mean:
        """The locked stream's sums over the present window."""
        return _Mean(self._ln, [self._lgx, self._lgy, self._lgz],
                     [self._lax, self._lay, self._laz])

    def _window(self, now_us: int) -> None:
        """Start the first window, or a new one when ``now_us`` is past the present one
        (judging it) or before it."""
        if self._start_us < 0 or now_us < self._start_us:
            self._restart(now_us)
        elif now_us - self._start_us >= _WINDOW_US:
            self._judge()
            self._restart(now_us)

    def _restart(self, now_us: int) -> None:
        self._start_us = now_us
        self._ln = 0
        self._lgx = self._lgy = self._lgz = self._lax = self._lay = self._laz = 0.0
        self._others.clear()

    def _judge(self) -> None:
        ref = self.locked_mean()
        if ref.n < _MIN_SAMPLES:
            return
        for src, m in self._others.items():
            if m.n < _MIN_SAMPLES:
                continue
            dg, da = ref.diff(m)
            if dg > AGREE_GYRO_RPS or da > AGREE_ACCEL_MPS2:
                self.contradicting = src
                self.last_diff = (dg, da)
                _note(self._reject, "imu_source_contradicts",
                      "a second IMU stream (%s) contradicts the locked one: 1 s means "
                      "differ by %.3f rad/s and %.2f m/s^2; one of them is not this "
                      "vehicle's (pin the right one with allow)", self._text(src), dg, da)


class SourceLock:
    """Per kind of input, the one source whose samples are used (module docstring).

    ``reject``: the decoder's reject path (counters + rate-limited log); ``text`` turns a
    source into words for the log ("sysid=1 compid=1", "node 12").
    """

    def __init__(self, relock_s: float, reject: Rejector,
                 text: Callable[[Hashable], str] = str) -> None:
        if not relock_s > 0.0:
            raise ValueError("relock_s must be > 0")
        self._relock_us = round(relock_s * 1e6)
        self._reject = reject
        self._text = text
        # kind -> (locked source, receive time of its last sample, us)
        self._locked: dict[str, tuple[Hashable, int]] = {}
        self._refused: dict[str, dict[Hashable, int]] = {}
        self.imu_agreement = ImuAgreement(reject, text)

    def admit(self, kind: str, src: Hashable, now_us: int) -> bool:
        """Whether a usable ``kind`` sample from ``src`` received at ``now_us`` may be used;
        the first source locks the kind, others are refused (counted, logged)."""
        cur = self._locked.get(kind)
        if cur is None:
            self._locked[kind] = (src, now_us)
            return True
        owner, seen = cur
        if owner == src:
            if now_us > seen:
                self._locked[kind] = (src, now_us)
            return True
        if now_us - seen >= self._relock_us:
            self._locked[kind] = (src, now_us)
            self._refused.get(kind, {}).pop(src, None)
            _note(self._reject, f"{kind}_source_relock", "%s input moves to %s: the locked "
                  "source %s was silent for %.1f s", kind.upper(), self._text(src),
                  self._text(owner), (now_us - seen) * 1e-6)
            return True
        refused = self._refused.setdefault(kind, {})
        if src in refused or len(refused) < MAX_OTHERS:
            refused[src] = refused.get(src, 0) + 1
        self._reject(f"{kind}_source_refused", "%s from %s refused: input is locked to %s "
                     "(another source takes over only after %.1f s of silence; list "
                     "trusted sources in allow)", kind.upper(), self._text(src),
                     self._text(owner), self._relock_us * 1e-6)
        return False

    def admit_locked(self, kind: str, src: Hashable, now_us: int) -> bool:
        """:meth:`admit` when ``kind`` is locked to ``src`` (True, the same bookkeeping);
        False, nothing changed, otherwise (then ask :meth:`admit`).  Repeating it, or an
        :meth:`admit`, with the same arguments changes nothing more."""
        cur = self._locked.get(kind)
        if cur is None or cur[0] != src:
            return False
        if now_us > cur[1]:
            self._locked[kind] = (src, now_us)
        return True

    def locked(self, kind: str) -> Hashable | None:
        cur = self._locked.get(kind)
        return cur[0] if cur is not None else None

    def status(self) -> dict[str, Any]:
        """For the status record: per kind the locked source and the refused ones (with
        their counts); the IMU stream that last contradicted the locked one."""
        out: dict[str, Any] = {}
        for kind, (owner, _) in self._locked.items():
            entry: dict[str, Any] = {"locked": self._text(owner)}
            refused = self._refused.get(kind)
            if refused:
                entry["refused"] = {self._text(s): n for s, n in refused.items()}
            out[kind] = entry
        agree = self.imu_agreement
        if agree.contradicting is not None and "imu" in out:
            out["imu"]["contradicted_by"] = self._text(agree.contradicting)
            out["imu"]["contradiction_rps_mps2"] = [round(agree.last_diff[0], 4),
                                                    round(agree.last_diff[1], 3)]
        return out
