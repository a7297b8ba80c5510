"""Build an :class:`Estimator` from raw config tables, with its optional aiding models.

``build_estimator(tables)`` is what the daemon, replay and tools call with the TOML tables of
:func:`navd.config.load_config`: it validates the estimator sections
(:class:`EstimatorConfig`) and the ``[dov]`` section, and loads the DOV grid.  A grid that
cannot be used (missing file, NaN cells, unsorted axes, wrong shapes, unknown units) never
stops navd: it is refused with a warning naming the file and the cause, the estimator runs
on normal gravity, and the status record says so (``dov_model = "refused: ...; normal
gravity"`` from :func:`navd.core.aiding.dov.dov_status`).  Config *syntax* errors in
``[dov]`` (unknown key, wrong type) raise :class:`ConfigError` like every other section.
"""

from __future__ import annotations

import logging
from typing import Any

from navd.config import EstimatorConfig
from navd.core.aiding.dov import DovGridError, note_refused
from navd.core.estimator import DovField, Estimator, PolAiding
from navd.io.dov_grid import DovSettings, load_from_settings

log = logging.getLogger("navd.dov")


def dov_field_from_config(tables: dict[str, Any]) -> tuple[DovField | None, str | None]:
    """(field, None) when ``[dov]`` is enabled and its grid loads; (None, None) when DOV is
    off; (None, reason) when the grid was refused.  Raises ConfigError on a bad [dov] table."""
    s = DovSettings.from_table(tables.get("dov", {}))
    if not s.enabled:
        return None, None
    try:
        return load_from_settings(s), None
    except DovGridError as exc:
        return None, str(exc)


def build_estimator(raw_cfg: dict[str, Any], pol: PolAiding | None = None) -> Estimator:
    """Estimator from config tables, with the DOV field of ``[dov]`` when it is usable.

    Raises:
        ConfigError: a malformed estimator or ``[dov]`` section.
    """
    cfg = EstimatorConfig.from_dict(raw_cfg)
    field, refused = dov_field_from_config(raw_cfg)
    est = Estimator(cfg, dov_field=field, pol=pol)
    if refused is not None:
        note_refused(est, refused)
        log.warning("DOV grid refused, running on normal gravity: %s", refused)
    elif field is not None:
        describe = getattr(field, "describe", None)
        log.info("DOV model: %s", describe() if callable(describe) else type(field).__name__)
    return est
