"""Skylight-polarization compass: the zenith angle-of-polarization update (seed 000).

Model and derivation: docs/design.md §7.

Model.  In a single-scattering (Rayleigh) sky the E-vector of the light arriving along the
sensor boresight ``d`` is perpendicular to the scattering plane spanned by ``d`` and the sun
direction ``s``: ``E ∝ d × s``.  In the sensor frame s (x, y in the detector plane, boresight
``d = -z_s``: a sensor mounted with zero rotation on an FRD body looks up) ``d × s_s =
(s_sy, -s_sx, 0)``, so the angle of polarization, measured from +x_s towards +y_s, is::

    alpha = atan2(-s_sx, s_sy)   (mod pi),    s_s = C_b^s C_n^b s_n = C_b^s Ĉ^T s_n

with ``s_n`` the NED unit vector to the sun (:mod:`navd.core.sun`) and ``C_b^s`` the mounting
(sensor -> body rotation ``C_s^b`` from config as roll/pitch/yaw, ZYX).  The reading is
defined only modulo pi (a polariser cannot tell E from -E), so the innovation is wrapped
to [-pi/2, pi/2): an alpha off by exactly pi gives the same innovation; the INS attitude
prior resolves the ambiguity (it must be better than +-90 deg).

Linearisation with ``Ĉ = Exp(-phi) C`` (errors computed - true)::

    ŝ_s - s_s = -C_b^s Ĉ^T [s_n×] phi
    z = wrap(alpha_hat - alpha_meas) = h^T phi + v,   v ~ N(0, sigma^2)
    h^T = [-s_sy, s_sx, 0] / (s_sx² + s_sy²) · (-C_b^s Ĉ^T [s_n×])

i.e. docs/design.md §7's row with the mounting inserted (checked against finite differences of the
nonlinear alpha(phi) in tests/test_polarization.py).  Only the attitude columns are
non-zero; position errors move s_n by |dp|/1 AU, nothing.  With a level sensor this is a
heading measurement (pure heading when the sun is on the horizon); tilt enters as the sun
climbs or the sensor tilts.  Observability is lost when the sun nears the boresight or the
anti-boresight (``s_sx² + s_sy² -> 0``: alpha undefined, the gain 1/rho² explodes, and the
Rayleigh degree of polarization ``DoP = d_max sin²g / (1 + cos²g)`` (g the scattering angle)
goes to 0).

Refusals are counted in ``est.counters`` (``pol_bad_input``, ``pol_bad_time``,
``pol_low_dop``, ``pol_sun_too_low``, ``pol_sun_near_boresight``, ``pol_too_old``); the
estimator counts ``pol_accepted`` / ``pol_rejected`` (chi-square gate).

Noise: ``sigma = sigma_deg * max(1, sigma_dop_ref / DoP)``; the AoP noise of a real sensor
grows as the DoP falls (fewer polarised photons per unit of intensity noise).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from navd.config.aiding import PolarizationSection
from navd.core._jit import jit
from navd.core.aiding.base import INNOV_POL
from navd.core.chi2 import chi2_quantile
from navd.core.rotation import euler_to_mat_into
from navd.core.sun import sun_ned_into
from navd.types import GnssSample, PolSample

if TYPE_CHECKING:
    from navd.core.estimator import Estimator

Arr = npt.NDArray[np.float64]

__all__ = ["PolarizationAiding", "build_polarization", "pol_row"]


@jit
def pol_row(H: Arr, row: int, mat_nb: Arr, mat_sb: Arr, s_n: Arr) -> tuple[float, float, float]:
    """Predicted AoP and its attitude row, written into ``H[row]`` (15 columns).

    Args:
        H: (>= row + 1, 15) measurement rows; row ``row`` is overwritten (zeros outside 0:3).
        mat_nb: Ĉ = C_b^n.  mat_sb: C_b^s (body -> sensor).  s_n: unit vector to the sun, NED.
    Returns:
        (alpha_hat in [0, pi), rho2 = s_sx² + s_sy², cos of the angle between boresight and
        sun).  With rho2 == 0 the row is left zero.
    """
    # G = C_b^s Ĉ^T (NED -> sensor); s_s = G s_n
    g00 = mat_sb[0, 0] * mat_nb[0, 0] + mat_sb[0, 1] * mat_nb[0, 1] + mat_sb[0, 2] * mat_nb[0, 2]
    g01 = mat_sb[0, 0] * mat_nb[1, 0] + mat_sb[0, 1] * mat_nb[1, 1] + mat_sb[0, 2] * mat_nb[1, 2]
    g02 = mat_sb[0, 0] * mat_nb[2, 0] + mat_sb[0, 1] * mat_nb[2, 1] + mat_sb[0, 2] * mat_nb[2, 2]
    g10 = mat_sb[1, 0] * mat_nb[0, 0] + mat_sb[1, 1] * mat_nb[0, 1] + mat_sb[1, 2] * mat_nb[0, 2]
    g11 = mat_sb[1, 0] * mat_nb[1, 0] + mat_sb[1, 1] * mat_nb[1, 1] + mat_sb[1, 2] * mat_nb[1, 2]
    g12 = mat_sb[1, 0] * mat_nb[2, 0] + mat_sb[1, 1] * mat_nb[2, 1] + mat_sb[1, 2] * mat_nb[2, 2]
    g20 = mat_sb[2, 0] * mat_nb[0, 0] + mat_sb[2, 1] * mat_nb[0, 1] + mat_sb[2, 2] * mat_nb[0, 2]
    g21 = mat_sb[2, 0] * mat_nb[1, 0] + mat_sb[2, 1] * mat_nb[1, 1] + mat_sb[2, 2] * mat_nb[1, 2]
    g22 = mat_sb[2, 0] * mat_nb[2, 0] + mat_sb[2, 1] * mat_nb[2, 1] + mat_sb[2, 2] * mat_nb[2, 2]
    sn0, sn1, sn2 = s_n[0], s_n[1], s_n[2]
    sx = g00 * sn0 + g01 * sn1 + g02 * sn2
    sy = g10 * sn0 + g11 * sn1 + g12 * sn2
    sz = g20 * sn0 + g21 * sn1 + g22 * sn2
    for j in range(H.shape[1]):
        H[row, j] = 0.0
    rho2 = sx * sx + sy * sy
    alpha = math.atan2(-sx, sy)
    if alpha < 0.0:
        alpha += math.pi
    if alpha >= math.pi:
        alpha -= math.pi
    if rho2 <= 0.0:
        return alpha, 0.0, -sz
    # a = d alpha / d s_s = [-sy, sx, 0] / rho2;  w = G^T a;  h = s_n x w
    a0 = -sy / rho2
    a1 = sx / rho2
    w0 = g00 * a0 + g10 * a1
    w1 = g01 * a0 + g11 * a1
    w2 = g02 * a0 + g12 * a1
    H[row, 0] = sn1 * w2 - sn2 * w1
    H[row, 1] = sn2 * w0 - sn0 * w2
    H[row, 2] = sn0 * w1 - sn1 * w0
    return alpha, rho2, -sz


def _wrap_half_pi(x: float) -> float:
    """Wrap to [-pi/2, pi/2): the AoP is an axis, not a direction."""
    return x - math.pi * math.floor(x / math.pi + 0.5)


class PolarizationAiding:
    """The estimator's polarization aid (``Estimator(cfg, pol=PolarizationAiding(...))``).

    Owns its scratch arrays; :meth:`fuse` allocates no ndarray.
    """

    def __init__(self, cfg: PolarizationSection) -> None:
        """``cfg``: the validated ``[polarization]`` section (SI; :mod:`navd.config.aiding`)."""
        self.sigma = cfg.sigma
        self.dop_min = cfg.dop_min
        self.sigma_dop_ref = cfg.sigma_dop_ref
        self.rho2_min = math.sin(cfg.boresight_exclusion) ** 2
        self.cos_zenith_max = math.cos(cfg.sun_zenith_max)
        self.gate = chi2_quantile(cfg.gate_prob, 1)
        self.max_age_us = cfg.max_age * 1e6
        mat_bs = np.zeros((3, 3))
        euler_to_mat_into(mat_bs, *cfg.mount_rpy)  # C_s^b
        self.mat_sb = np.ascontiguousarray(mat_bs.T)  # C_b^s
        self.s_n = np.zeros(3)
        self.last_innovation = math.nan

    # ------------------------------------------------------------------ the aid
    name = "pol"
    consumes = PolSample

    def reset(self) -> None:
        pass

    def start(self, est: Estimator, fix: GnssSample) -> None:
        pass

    def status(self, est: Estimator) -> dict[str, object]:
        return {}

    def fuse(self, est: Estimator, sample: PolSample) -> bool:
        """Fuse one reading into ``est`` or count why not (never raises on bad input);
        True when accepted."""
        cnt = est.counters
        # reported from the first reading that reaches the aid on, 0 included
        cnt.setdefault("pol_accepted", 0)
        a = sample.aop_rad
        dop = sample.dop
        if not (math.isfinite(a) and 0.0 <= a < math.pi and math.isfinite(dop)
                and 0.0 <= dop <= 1.0):
            cnt["pol_bad_input"] += 1
            return False
        if abs(est.t_us - sample.t_us) > self.max_age_us:
            cnt["pol_too_old" if sample.t_us < est.t_us else "pol_from_future"] += 1
            return False
        if dop < self.dop_min:
            cnt["pol_low_dop"] += 1
            return False
        s_n = self.s_n
        pos = est.pos
        if not sun_ned_into(s_n, sample.utc_unix_s, float(pos[0]), float(pos[1]),
                            float(pos[2])):
            cnt["pol_bad_time"] += 1
            return False
        if -s_n[2] < self.cos_zenith_max:
            cnt["pol_sun_too_low"] += 1
            return False
        H = est.meas_H
        swapped = est.state_at(sample.t_us)
        if swapped is None:
            cnt["pol_too_old"] += 1
            return False
        try:
            # a late reading is compared with the attitude of its own time: in a 20 deg/s
            # turn, 50 ms of transport delay would otherwise be a 1 deg AoP error
            alpha_hat, rho2, _ = pol_row(H, 0, est.mat_nb, self.mat_sb, s_n)
        finally:
            if swapped:
                est.state_restore()
        if swapped:
            cnt["pol_delayed"] += 1
        if rho2 < self.rho2_min or rho2 <= 0.0:
            cnt["pol_sun_near_boresight"] += 1
            return False
        z = _wrap_half_pi(alpha_hat - a)
        sd = self.sigma
        if self.sigma_dop_ref > dop:
            sd *= self.sigma_dop_ref / max(dop, 1e-3)
        est.meas_z[0] = z
        est.meas_R[0, 0] = sd * sd
        self.last_innovation = z
        nis = est.fuse_block(1, self.gate, "pol")
        est.record_innovation(INNOV_POL, 0, 1, nis)
        return nis >= 0.0


def build_polarization(cfg: PolarizationSection | None) -> PolarizationAiding | None:
    """The aid a ``[polarization]`` section describes (None: no aid)."""
    return None if cfg is None else PolarizationAiding(cfg)
