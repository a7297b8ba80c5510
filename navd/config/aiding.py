"""The estimator's aiding sections, ``[polarization]`` and ``[dov]``, and :class:`NavConfig`:
everything :func:`navd.pipeline.build_estimator` needs, typed and in SI units.

Plain dataclasses built by :func:`navd.config.load.build_section`; the polarization aid
(:mod:`navd.core.aiding.polarization`) and the DOV grid loader (:mod:`navd.io.dov_grid`)
receive them and parse nothing themselves.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from navd.config.estimator import EstimatorConfig
from navd.config.load import build_section, check
from navd.config.load import setting as _f

__all__ = ["DOV_ANGLE_UNITS", "DovSection", "NavConfig", "PolarizationSection",
           "polarization_section"]

_MOUNT_REQUIRED = ("the sensor -> body mounting rotation (ZYX roll/pitch/yaw, deg) must be "
                   "configured; use 0 for a sensor whose x/y axes are the body's forward/right "
                   "and that looks up (-z)")


@dataclass(frozen=True)
class PolarizationSection:
    """``[polarization]``: the skylight-polarization compass (docs/polarization.md).

    The mounting has no default a user may rely on: an AoP is meaningless without it, so the
    three ``mount_*_deg`` keys must be written (a missing one is a ConfigError).  A table
    without ``enabled`` is enabled; no table at all is off (:func:`polarization_section`).
    """

    enabled: bool = _f(True)
    mount_roll: float = _f(0.0, "deg", required=_MOUNT_REQUIRED)  # sensor -> body, ZYX
    mount_pitch: float = _f(0.0, "deg", required=_MOUNT_REQUIRED)
    mount_yaw: float = _f(0.0, "deg", required=_MOUNT_REQUIRED)
    sigma: float = _f(0.3, "deg")  # 1-sigma AoP noise at high degree of polarization
    sigma_dop_ref: float = _f(0.5)  # below this DoP: sigma * sigma_dop_ref / DoP
    dop_min: float = _f(0.05)  # readings with a lower DoP are skipped
    boresight_exclusion: float = _f(10.0, "deg")  # sun this close to (anti-)boresight: skip
    sun_zenith_max: float = _f(96.0, "deg")  # sun lower than this: skip
    gate_prob: float = _f(0.9999)  # chi-square gate probability (1 dof)
    max_age: float = _f(500.0, "ms")  # |reading time - newest IMU time| above this: skip

    @property
    def mount_rpy(self) -> tuple[float, float, float]:
        """The sensor -> body rotation as (roll, pitch, yaw), rad."""
        return (self.mount_roll, self.mount_pitch, self.mount_yaw)

    def validate(self) -> None:
        s = "polarization"
        check(self.sigma > 0.0 and math.isfinite(self.sigma), s, "sigma_deg", "> 0")
        check(0.0 <= self.dop_min < 1.0, s, "dop_min", "in [0, 1)")
        check(0.0 <= self.boresight_exclusion < 0.5 * math.pi, s, "boresight_exclusion_deg",
              "in [0, 90)")
        check(0.0 < self.sun_zenith_max <= math.pi, s, "sun_zenith_max_deg", "in (0, 180]")
        check(0.5 < self.gate_prob < 1.0, s, "gate_prob", "in (0.5, 1)")
        check(self.sigma_dop_ref >= 0.0, s, "sigma_dop_ref", ">= 0")
        check(self.max_age > 0.0, s, "max_age_ms", "> 0")


def polarization_section(tables: Mapping[str, Any]) -> PolarizationSection | None:
    """The ``[polarization]`` section of the config tables; None when there is no such table
    or it says ``enabled = false``."""
    table = tables.get("polarization")
    if table is None:
        return None
    if isinstance(table, Mapping) and table.get("enabled", True) is False:
        return None  # off: the rest of the table is not looked at
    return build_section(PolarizationSection, "polarization", table)


# units a netCDF DOV grid without a units attribute may be declared in ("" = from the file)
DOV_ANGLE_UNITS = ("", "arcsec", "microrad", "rad")


@dataclass(frozen=True)
class DovSection:
    """``[dov]``: deflection of the vertical from a grid (see config/navd.toml, docs/dov.md)."""

    enabled: bool = _f(False)
    grid: str = _f("")  # .npz (navd layout) or GMT/COARDS netCDF
    eta_grid: str = _f("")  # second one-variable GMT grid holding eta ("" = eta is in `grid`)
    xi_var: str = _f("")  # netCDF variable names ("" = found by name)
    eta_var: str = _f("")
    dg_var: str = _f("")
    # the angle unit of netCDF variables without a units attribute
    angle_unit: str = _f("", choices=DOV_ANGLE_UNITS)
    use_dg: bool = _f(True)  # apply the grid's gravity disturbance along down, when it has one


@dataclass(frozen=True)
class NavConfig:
    """Everything the estimator is built from: its own sections, the polarization aid
    (None: off) and the DOV model.  Built once from the TOML tables (:meth:`from_tables`)."""

    estimator: EstimatorConfig = field(default_factory=EstimatorConfig)
    polarization: PolarizationSection | None = None
    dov: DovSection = field(default_factory=DovSection)

    @classmethod
    def from_tables(cls, tables: Mapping[str, Any]) -> NavConfig:
        return cls(estimator=EstimatorConfig.from_dict(dict(tables)),
                   polarization=polarization_section(tables),
                   dov=build_section(DovSection, "dov", tables.get("dov", {})))
