"""DroneCAN on a python-can bus: open the bus, deliver decoded samples on the event loop,
send frames without blocking.

python-can's ``Notifier`` calls :class:`DronecanLink` back on the asyncio loop, so
decoding and the sample callback never race the estimator task.  Reassembly is not done
here but in :mod:`navd.io.dronecan.transfer` (through the decoder), so log replay and
tests can feed frames without a bus.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable, Iterable
from typing import Any

import can

from navd.io.adapter import SampleDelivery
from navd.io.common import SampleCallback, monotonic_us
from navd.io.dronecan.decode import (
    FIX2_DTID,
    POL_DTID,
    RAW_IMU_DTID,
    DronecanConfig,
    DronecanDecoder,
)

__all__ = ["DronecanLink", "open_bus"]

# The name the single-file adapter logged under; log configuration may select it.
_log = logging.getLogger("navd.io.dronecan")


def open_bus(config: DronecanConfig,
             dtids: Iterable[int] = (RAW_IMU_DTID, FIX2_DTID, POL_DTID)) -> Any:
    """Open the python-can bus named in config (SocketCAN needs no privileges to use)."""
    filters = None
    if config.kernel_filters:
        # Message frames: data type ID in bits 8..23, service flag (bit 7) clear.
        filters = [{"can_id": d << 8, "can_mask": 0xFFFF80, "extended": True} for d in dtids]
    return can.Bus(interface=config.interface, channel=config.channel, can_filters=filters)


class DronecanLink(SampleDelivery[DronecanDecoder], can.Listener):
    """A bus, a python-can Notifier calling back on the asyncio loop, and a decoder."""

    def __init__(
        self,
        bus: Any,
        decoder: DronecanDecoder,
        on_sample: SampleCallback | None,
        clock_us: Callable[[], int] = monotonic_us,
    ) -> None:
        self.bus = bus
        super().__init__(decoder, on_sample, clock_us)

    def _init_link(self) -> None:
        self._notifier: Any = None

    @classmethod
    async def open(
        cls,
        config: DronecanConfig,
        decoder: DronecanDecoder | None = None,
        on_sample: SampleCallback | None = None,
        *,
        clock_us: Callable[[], int] = monotonic_us,
    ) -> DronecanLink:
        dec = decoder if decoder is not None else DronecanDecoder(config)
        bus = open_bus(config)
        link = cls(bus, dec, on_sample, clock_us)
        # With a loop, the Notifier delivers on the loop thread (add_reader for SocketCAN,
        # call_soon_threadsafe from its reader thread otherwise), so decoding and the
        # callback never race the estimator task.
        link._notifier = can.Notifier(bus, [link], loop=asyncio.get_running_loop())
        return link

    def on_message_received(self, msg: can.Message) -> None:
        if self.decoder is not None:  # always set: open() makes one if none is given
            self._deliver(self.decoder.feed(msg, self.clock_us()))

    def on_error(self, exc: Exception) -> None:
        self.counters.inc("bus_error")
        _log.warning("CAN bus error: %s", exc)

    def send(self, msgs: list[can.Message]) -> bool:
        """Send all frames of a transfer without blocking; False (counted) if the bus refused."""
        for m in msgs:
            try:
                self.bus.send(m, timeout=0.0)
            except can.CanError as exc:
                self.counters.inc("tx_dropped")
                _log.debug("CAN send failed: %s", exc)
                return False
        return True

    def close(self) -> None:
        if self._notifier is not None:
            self._notifier.stop()
            self._notifier = None
        self.bus.shutdown()
