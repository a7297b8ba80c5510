"""How an aid plugs into the estimator, and where it leaves its last innovation.

An aid is an object the estimator owns (``Estimator.aids``, built in one place in
``Estimator.__init__``, in the order they run).  For every sample of the type it
``consumes`` that reaches it, the estimator calls ``fuse(est, sample)``; the aid forms its
rows in ``est.meas_H`` / ``meas_z`` / ``meas_R``, gates and applies them through
``est.fuse_block`` (or counts why not) and writes its innovation record.  The estimator
keeps the life cycle (levelling, start, restart) and calls ``start`` when navigation starts
and ``reset`` when it restarts.  ``status`` contributes keys to ``Estimator.status()``.

Innovation record (``Estimator.innov``, (N_INNOV, INNOV_W) float64, allocated once): one
row per measurement kind, describing the last sample of that kind pushed while navigating.

=======  =========================================================================
row      z columns 0..2: innovation, computed minus measured (``z`` of the model)
=======  =========================================================================
POS      NED m: ``D (p_hat - p_gnss) + C_hat l_b`` (gnss_position), at time of validity
VEL      NED m/s: ``v_hat + C_hat (w_hat x l_b) - v_gnss`` (gnss_velocity); column 2 is
         the lever-arm term alone when the receiver gave no vertical velocity
COURSE   column 0, rad: ``wrap(psi_hat - chi)`` of the lever-arm-free GNSS velocity
         (gnss_heading) when tried; when not tried (flag NOT_TRIED) and |v_h| >= 1 m/s,
         ``wrap(psi_hat - atan2(vE, vN))`` of the raw GNSS velocity for monitoring, else NaN
POL      column 0, rad: ``wrap(alpha_hat - alpha_meas)`` to [-pi/2, pi/2) (polarization)
=======  =========================================================================

Column NIS: normalised innovation squared of the block the row was applied in (the joint
velocity + course block for VEL when the course joined it; the course row's own 1-dof NIS
for COURSE); positive also when rejected.  Column FLAG: ACCEPTED, REJECTED (gate),
SINGULAR (innovation covariance not positive definite, nothing applied) or NOT_TRIED.
Column T: ``t_us`` of the sample as pushed (before any configured GNSS delay is removed).
Unused columns are NaN.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Protocol

if TYPE_CHECKING:
    from navd.core.estimator import Estimator
    from navd.types import GnssSample

INNOV_POS = 0
INNOV_VEL = 1
INNOV_COURSE = 2
INNOV_POL = 3
N_INNOV = 4

INNOV_NIS = 3
INNOV_FLAG = 4
INNOV_T = 5
INNOV_W = 6

NOT_TRIED = 0.0
ACCEPTED = 1.0
REJECTED = -1.0
SINGULAR = -2.0


class Aid(Protocol):
    """An aid of the estimator (see the module doc)."""

    name: str
    consumes: type[Any]  # the sample type whose pushes reach ``fuse``

    def reset(self) -> None:
        """Navigation restarts: forget per-run state (counts, windows)."""
        ...

    def start(self, est: Estimator, fix: GnssSample) -> None:
        """Navigation starts from ``fix`` (nominal state just set, covariance not yet)."""
        ...

    def fuse(self, est: Estimator, sample: Any) -> bool:
        """Use one sample; True when the navigation state was corrected or the epoch was
        taken (GNSS).  Never raises on bad input: counts it in ``est.counters``."""
        ...

    def status(self, est: Estimator) -> dict[str, object]:
        """Keys this aid adds to the status record."""
        ...
