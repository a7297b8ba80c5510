"""A live Foxglove WebSocket server (``[foxglove] enabled``): the same channels and JSON
messages as ``--mcap`` (:mod:`navd.io.foxglove_mcap`), served with the foxglove-sdk on a
loopback port so Foxglove can "Open connection" to ``ws://127.0.0.1:8765``.

The server advertises no client-publish, parameter or service capability: a connected
client can only subscribe.  It has no authentication, so it stays on 127.0.0.1 unless the
operator says otherwise (docs/daemon.md, threat model).  Its own context keeps its channels
apart from anything else in the process that uses the SDK's global one.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

import foxglove

from navd.io.foxglove_mcap import CHANNELS, FoxgloveMessages, encode_json
from navd.types import NavSolution

__all__ = ["FoxgloveLive"]


class FoxgloveLive:
    """Owns the server and its channels; :meth:`close` stops it.  ``port`` 0 picks a free
    port (:attr:`port` then says which)."""

    def __init__(self, *, host: str, port: int, aligned_sd_rad: float,
                 name: str = "navd") -> None:
        self._ctx = foxglove.Context()
        self._msgs = FoxgloveMessages(aligned_sd_rad)
        self._chan: dict[str, Any] = {}
        for topic, (schema_name, schema) in CHANNELS.items():
            self._chan[topic] = foxglove.Channel(
                topic, message_encoding="json", context=self._ctx,
                schema=foxglove.Schema(name=schema_name, encoding="jsonschema",
                                       data=json.dumps(schema).encode()))
        self._server: Any = foxglove.start_server(name=name, host=host, port=port,
                                                  context=self._ctx)
        self.messages = 0

    @property
    def port(self) -> int:
        return int(self._server.port)

    def write_solution(self, sol: NavSolution, log_time_ns: int) -> None:
        for topic, obj in self._msgs.of(sol):
            self._chan[topic].log(encode_json(obj), log_time=log_time_ns)
            self.messages += 1

    def write_status(self, status: Mapping[str, Any], log_time_ns: int) -> None:
        self._chan["/navd/status"].log(encode_json(status), log_time=log_time_ns)
        self.messages += 1

    def close(self) -> None:
        if self._server is not None:
            self._server.stop()
            self._server = None
