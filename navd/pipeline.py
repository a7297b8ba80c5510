"""The pipeline every front end shares: one estimator factory and one output rule.

The daemon (:mod:`navd.daemon.daemon`), ``navd replay`` (CSV files, flight logs and daemon
recordings), the simulator's scoring (:mod:`firmware_sim.score`) and the benchmarks all build
their estimator with :func:`build_estimator` and decide when a solution is output with
:func:`output_instant` and :class:`OutputSchedule`, so a replay of a recording reproduces the
daemon's outputs sample for sample.

``build_estimator(config)`` takes a :class:`navd.config.aiding.NavConfig` (the estimator
sections, ``[polarization]`` and ``[dov]``, typed and validated once), or the TOML tables of
:func:`navd.config.load_config` it is built from, and loads the DOV grid.  A grid that
cannot be used (missing file, NaN cells, unsorted axes, wrong shapes, unknown units) never
stops navd: it is refused with a warning naming the file and the cause, the estimator runs
on normal gravity, and the status record says so (``dov_model = "refused: ...; normal
gravity"`` from :func:`navd.core.aiding.dov.dov_status`).  Config *syntax* errors (unknown
key, wrong type) raise :class:`ConfigError`.

The output rule: a solution may be output right after the push of an IMU sample while the
estimator navigates; a sink at rate ``f`` takes the first such instant at or past each
multiple of ``1/f`` of the estimator's *sensor* time (:class:`OutputSchedule`), so the output
sequence is a function of the input alone.  When the estimator starts over
(``Estimator.restarts``: a sensor reboot restarts its clock), every schedule starts over with
it: outputs after a restart are those of a fresh start on the same input.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Iterator, Mapping
from typing import TYPE_CHECKING, Any

from navd.config.aiding import DovSection, NavConfig
from navd.core.aiding.dov import DovField, DovGridError
from navd.core.aiding.polarization import build_polarization
from navd.core.estimator import Estimator
from navd.io.dov_grid import load_from_settings
from navd.types import GnssSample, ImuSample, NavSolution, Sample

if TYPE_CHECKING:
    from navd.io.logs import AidingWriter

__all__ = ["OutputSchedule", "build_estimator", "output_instant", "solutions"]

log = logging.getLogger("navd.dov")


def dov_field_from_config(s: DovSection) -> tuple[DovField | None, str | None]:
    """(field, None) when ``[dov]`` is enabled and its grid loads; (None, None) when DOV is
    off; (None, reason) when the grid was refused."""
    if not s.enabled:
        return None, None
    try:
        return load_from_settings(s), None
    except DovGridError as exc:
        return None, str(exc)


def build_estimator(config: NavConfig | Mapping[str, Any]) -> Estimator:
    """The estimator a :class:`NavConfig` (or the config tables it is built from) describes,
    with its DOV model and polarization aid.

    Raises:
        ConfigError: (tables only) a malformed estimator, ``[dov]`` or ``[polarization]``
            section.
    """
    cfg = config if isinstance(config, NavConfig) else NavConfig.from_tables(config)
    pol = build_polarization(cfg.polarization)
    field, refused = dov_field_from_config(cfg.dov)
    est = Estimator(cfg.estimator, dov_field=field, pol=pol, dov_refused=refused)
    if refused is not None:
        log.warning("DOV grid refused, running on normal gravity: %s", refused)
    elif field is not None:
        describe = getattr(field, "describe", None)
        log.info("DOV model: %s", describe() if callable(describe) else type(field).__name__)
    return est


def output_instant(est: Estimator, s: Sample) -> bool:
    """Push ``s``; True when a solution may be output now: ``s`` is an IMU sample and the
    estimator is navigating.  Sinks then ask their :class:`OutputSchedule` with ``est.t_us``
    (a refused sample leaves ``est.t_us`` where it was, so it is never output twice).
    Every front end pushes through this function."""
    est.push(s)
    return isinstance(s, ImuSample) and est.initialized


class OutputSchedule:
    """When a sink at ``rate_hz`` gets a solution: the first output instant at or past each
    multiple of the output period, on the sensor clock (the first output waits for the first
    multiple, so IMU samples on the period's grid are output exactly on it).

    Sensor time, not the host clock, decides, so the output sequence is a function of the
    input alone (and a faster-than-real-time stream still gets ``rate_hz`` per sensor second).

    ``epoch`` is the estimator's restart count (``Estimator.restarts``): a new one starts the
    schedule over, since the restarted sensor clock may begin far before the next multiple
    of the old one (an autopilot reboot starts again at 0).
    """

    __slots__ = ("_epoch", "_next_us", "period_us")

    def __init__(self, rate_hz: float) -> None:
        if not rate_hz > 0.0:
            raise ValueError(f"output rate must be > 0 Hz, got {rate_hz}")
        self.period_us = max(1, round(1e6 / rate_hz))
        self._next_us: int | None = None
        self._epoch = 0

    @property
    def next_us(self) -> int:
        """The next output instant (sensor us) of the epoch :meth:`due` was last asked in:
        ``due(t, that epoch)`` is False, and changes nothing, for every ``t`` before it;
        -1 before the first :meth:`due`."""
        return -1 if self._next_us is None else self._next_us

    def due(self, t_us: int, epoch: int = 0) -> bool:
        p = self.period_us
        if epoch != self._epoch:
            self._epoch = epoch
            self._next_us = None
        if self._next_us is None:
            self._next_us = -(-t_us // p) * p  # the first multiple at or after t_us
        if t_us < self._next_us:
            return False
        self._next_us = (t_us // p + 1) * p
        return True


def solutions(est: Estimator, samples: Iterable[Sample], rate_hz: float,
              aiding: AidingWriter | None = None) -> Iterator[NavSolution]:
    """Push every sample; yield what a sink at ``rate_hz`` would have received.

    While a solution is being handled, ``est`` holds the state it came from (scoring reads
    the covariance there).  ``aiding``: also write one row per GNSS epoch on what the filter
    did with it (read from the estimator after the push).
    """
    sched = OutputSchedule(rate_hz)
    for s in samples:
        if output_instant(est, s):
            if sched.due(est.t_us, est.restarts):
                yield est.solution()
        elif aiding is not None and isinstance(s, GnssSample):
            aiding.after(est, s)
