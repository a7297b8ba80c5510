"""The ``navd`` command: ``run`` (daemon), ``demo``, ``replay``."""

from __future__ import annotations

import importlib
import sys

_COMMANDS = {
    "replay": ("navd.replay", "run the estimator over recorded CSV data or flight logs"),
    "run": ("navd.daemon", "run the daemon (sources, estimator, sinks from config)"),
    "demo": ("navd.demo", "simulator -> MAVLink -> daemon -> Zenoh, live errors vs truth"),
    "dov-grid": ("navd.dov_cli", "deflection-of-the-vertical grid from a gravity model (EGM96)"),
    "report": ("navd.report", "HTML evaluation (figures, RMS/percentiles) of a replay"),
}


def _usage() -> str:
    lines = ["usage: navd COMMAND [options]", "", "commands:"]
    lines += [f"  {name:<8} {desc}" for name, (_, desc) in _COMMANDS.items()]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if not args or args[0] in ("-h", "--help"):
        print(_usage())
        return 0 if args else 2
    cmd, rest = args[0], args[1:]
    if cmd not in _COMMANDS:
        print(f"navd: unknown command {cmd!r}\n{_usage()}", file=sys.stderr)
        return 2
    try:
        mod = importlib.import_module(_COMMANDS[cmd][0])
    except ModuleNotFoundError as exc:
        print(f"navd {cmd}: not available in this build ({exc})", file=sys.stderr)
        return 2
    result: int = mod.main(rest)
    return result


if __name__ == "__main__":
    sys.exit(main())
