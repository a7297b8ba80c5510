"""The skeleton every wire adapter (MAVLink, DroneCAN) shares, so it is written once.

DecoderBase     a decoder's reject path (counters + rate-limited log), its rate ->
                increment integrator, and the choice of time stamp (sensor time, or the
                local receive time when the sender's clock is useless)
SampleDelivery  the link side: a decoder, the callback decoded samples go to, and the
                receive clock a link reads once per datagram or frame

What differs per wire format (parsing, message tables, transports) stays in the adapter's
own package; what every adapter checks about a sample's values is :mod:`navd.io.common`.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import ClassVar, Generic, Protocol, TypeVar

from navd.diag import Counters, RateLimitedLog
from navd.io.common import RateIntegrator, Rejector, Sample, SampleCallback, monotonic_us

__all__ = ["MAX_SENSOR_T_US", "DecoderBase", "SampleDelivery", "TimingSettings"]

# The largest sensor time accepted (2**53 us, ~285 years): every time stamp below it is exact
# as a float64 and far from int64 overflow anywhere downstream (the estimator's arithmetic,
# a recording's int64 field).  A uint64 wire field can hold anything up to 2**64 - 1; such a
# value is a corrupt or crafted frame, never a clock.
MAX_SENSOR_T_US = 1 << 53


class TimingSettings(Protocol):
    """The input settings :class:`DecoderBase` reads (both adapters' configs have them)."""

    @property
    def nominal_imu_rate_hz(self) -> float | None: ...

    @property
    def max_imu_gap_s(self) -> float: ...

    @property
    def use_receive_time(self) -> bool: ...

    @property
    def warn_interval_s(self) -> float: ...


ConfigT = TypeVar("ConfigT", bound=TimingSettings)


class DecoderBase(Generic[ConfigT]):
    """Reject path, IMU integrator and time stamp choice of one decoder."""

    # Log detail when a sample has no sensor time: says which field, in the wire's words.
    no_timestamp_detail: ClassVar[str] = "sensor time is zero; set use_receive_time"

    def __init__(
        self,
        config: ConfigT,
        prefix: str,
        logger_name: str,
        counters: Counters | None,
        log: RateLimitedLog | None,
    ) -> None:
        self.config = config
        # [daemon] warn_interval_s reaches the decoders through their config.
        self._reject = Rejector.create(logger_name, prefix, counters, log,
                                       log_interval_s=config.warn_interval_s)
        self.counters = self._reject.counters
        nominal = (
            round(1e6 / config.nominal_imu_rate_hz)
            if config.nominal_imu_rate_hz is not None
            else None
        )
        self._imu = RateIntegrator(self._reject, nominal, round(config.max_imu_gap_s * 1e6))

    def _stamp(self, sensor_t_us: int, recv_t_us: int, what: str) -> int | None:
        """The sample's time: the sensor's, or the receive time if so configured; None
        (counted as ``<what>_no_timestamp``) when the sensor sent none, or (counted as
        ``<what>_time_out_of_range``) when it is beyond :data:`MAX_SENSOR_T_US`."""
        if self.config.use_receive_time:
            return recv_t_us
        if sensor_t_us <= 0:
            self._reject(f"{what}_no_timestamp", self.no_timestamp_detail)
            return None
        if sensor_t_us > MAX_SENSOR_T_US:
            self._reject(f"{what}_time_out_of_range", "sensor time %d us is beyond 2**53 us",
                         sensor_t_us)
            return None
        return sensor_t_us


class _HasCounters(Protocol):
    @property
    def counters(self) -> Counters: ...


DecoderT = TypeVar("DecoderT", bound=_HasCounters)


class SampleDelivery(Generic[DecoderT]):
    """A link's decoder, its sample callback and its clock; counters are the decoder's (a
    send-only link without a decoder gets its own)."""

    def __init__(
        self,
        decoder: DecoderT | None,
        on_sample: SampleCallback | None,
        clock_us: Callable[[], int] = monotonic_us,
    ) -> None:
        self.decoder = decoder
        self.on_sample = on_sample
        self.clock_us = clock_us
        self.counters = decoder.counters if decoder is not None else Counters()
        self._init_link()

    def _init_link(self) -> None:
        """The transport-specific state."""

    def _deliver(self, samples: Iterable[Sample]) -> None:
        if self.on_sample is not None:
            for s in samples:
                self.on_sample(s)
