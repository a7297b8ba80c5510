"""``navd run``: the daemon from a config file, as a systemd service.

    navd run [--config FILE] [--set section.key=value ...] [--record FILE] [--mcap FILE]

What the daemon does is described in :mod:`navd.daemon.daemon`.
"""

from __future__ import annotations

import argparse
import asyncio
import importlib
import logging
import os
import sys
from collections.abc import Callable, Coroutine
from typing import Any, cast

from navd.config import ConfigError
from navd.config.daemon import load_daemon_config
from navd.daemon.daemon import Daemon

_log = logging.getLogger("navd")

_SYSLOG_PRIORITY = {logging.DEBUG: 7, logging.INFO: 6, logging.WARNING: 4, logging.ERROR: 3,
                    logging.CRITICAL: 2}


class _JournalFormatter(logging.Formatter):
    """journald takes a leading ``<N>`` as the syslog priority and adds its own time stamp."""

    def format(self, record: logging.LogRecord) -> str:
        return f"<{_SYSLOG_PRIORITY.get(record.levelno, 6)}>{super().format(record)}"


def setup_logging(level: str) -> None:
    handler = logging.StreamHandler(sys.stderr)
    if os.environ.get("JOURNAL_STREAM"):
        handler.setFormatter(_JournalFormatter("%(name)s: %(message)s"))
    else:
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(level.upper())
    # zenoh's Rust side logs through Python logging at INFO per session event
    logging.getLogger("zenoh").setLevel(logging.WARNING)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="navd run",
                                 description="run the daemon (sources, estimator, sinks)")
    ap.add_argument("--config", help="TOML config (default: built-in defaults)")
    ap.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                    help="override a config value (repeatable), e.g. mavlink.sysid=2")
    ap.add_argument("--record", metavar="FILE",
                    help="write every pushed sample to FILE (replay: navd replay --recording)")
    ap.add_argument("--mcap", metavar="FILE",
                    help="also write attitude, position, heading status and the daemon status "
                         "to FILE as MCAP for Foxglove (docs/interfaces.md)")
    ap.add_argument("--mcap-rate-hz", type=float, default=10.0, metavar="HZ",
                    help="solutions per second of sensor time in the MCAP file (default 10)")
    a = ap.parse_args(argv)
    if not 0.0 < a.mcap_rate_hz <= 1000.0:
        ap.error("--mcap-rate-hz must be in (0, 1000]")
    try:
        cfg = load_daemon_config(a.config, a.set)
        setup_logging(cfg.daemon.log_level)
        daemon = Daemon(cfg, record_path=a.record or cfg.daemon.record or None,
                        mcap_path=a.mcap, mcap_rate_hz=a.mcap_rate_hz)
        run = _loop_runner(cfg.daemon.event_loop)
    except ConfigError as exc:
        print(f"navd run: config error: {exc}", file=sys.stderr)
        return 2
    return run(daemon.run())


def _loop_runner(kind: str) -> Callable[[Coroutine[Any, Any, int]], int]:
    """uvloop when available ("auto") or required: its event loop costs a fifth of CPython's
    selector loop per datagram, which is most of the daemon's CPU at a 1 kHz IMU rate."""
    if kind != "asyncio":
        try:
            uvloop = importlib.import_module("uvloop")
        except ImportError:
            if kind == "uvloop":
                raise ConfigError('[daemon] event_loop = "uvloop" but uvloop is not '
                                  "installed") from None
        else:
            _log.info("event loop: uvloop %s", uvloop.__version__)
            return cast(Callable[[Coroutine[Any, Any, int]], int], uvloop.run)
    _log.info("event loop: asyncio")
    return asyncio.run

