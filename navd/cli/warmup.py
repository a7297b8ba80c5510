"""``navd warmup``: get the estimator's kernels ready and say where they came from.

    navd warmup [--config FILE] [--set section.key=value ...] [--build] [--strict] [--json]

Runs the daemon's start-up warm-up on the configured estimator, opening no link.  After an
install or an update it shows whether the kernels compiled at install time are used ("N
prebuilt") or had to be compiled now (stale: a source edited after the build; absent: no
build for this numba/Python), and what it compiled stays in numba's cache
(NUMBA_CACHE_DIR) for the next start.  --build first remakes the install-time kernels if
they are stale (needs write access to the installed package).
"""

from __future__ import annotations

import argparse
import json
import sys

from navd.config import ConfigError


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="navd warmup",
        description="load or compile the estimator's kernels (as navd run does before "
                    "READY) and report whether the kernels compiled at install were used")
    ap.add_argument("--config", help="TOML config (default: built-in defaults)")
    ap.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                    help="override a config value (repeatable)")
    ap.add_argument("--build", action="store_true",
                    help="first rebuild the install-time kernels if they are stale")
    ap.add_argument("--strict", action="store_true",
                    help="exit 1 if any kernel had to be compiled (an install check)")
    ap.add_argument("--json", action="store_true", help="print the figures as JSON")
    a = ap.parse_args(argv)
    if a.build:
        from navd.core import aot_build

        rc = aot_build.main(["--if-stale"])
        if rc != 0:
            return rc
    from navd.config.daemon import load_daemon_config
    from navd.core._jit import aot_status, describe_status
    from navd.daemon.daemon import warm_up

    try:
        cfg = load_daemon_config(a.config, a.set)
    except ConfigError as exc:
        print(f"navd warmup: config error: {exc}", file=sys.stderr)
        return 2
    seconds = warm_up(cfg.nav)
    status = aot_status()
    if a.json:
        print(json.dumps({"seconds": round(seconds, 3), **status}))
    else:
        print(f"estimator kernels ready in {seconds:.2f} s")
        print(describe_status(status))
    return 1 if a.strict and status["compiled"] else 0
