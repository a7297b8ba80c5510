"""The ``navd`` command: a table of subcommands, each ``navd.cli.<name>.main(argv)``."""

from __future__ import annotations

import importlib
import sys

_COMMANDS = {
    "replay": ("navd.cli.replay", "run the estimator over recorded CSV data or flight logs"),
    "run": ("navd.cli.run", "run the daemon (sources, estimator, sinks from config)"),
    "demo": ("navd.cli.demo", "simulator -> MAVLink -> daemon -> Zenoh, live errors vs truth"),
    "dov-grid": ("navd.cli.dov_grid", "deflection-of-the-vertical grid from a gravity model"),
    "report": ("navd.cli.report", "HTML evaluation (figures, RMS/percentiles) of a replay"),
    "warmup": ("navd.cli.warmup", "load or compile the estimator kernels; were the install-"
                                  "time ones used"),
}

# top-level module of an optional dependency -> the extra (pyproject.toml) that installs it
_OPTIONAL = {"matplotlib": "plot", "netCDF4": "dov", "gravitas": "dov", "pyulog": "logs"}


def _usage() -> str:
    lines = ["usage: navd COMMAND [options]", "       navd --version", "", "commands:"]
    lines += [f"  {name:<8} {desc}" for name, (_, desc) in _COMMANDS.items()]
    lines += ["", "`navd COMMAND --help` describes each command's options."]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if not args or args[0] in ("-h", "--help"):
        print(_usage())
        return 0 if args else 2
    if args[0] in ("-V", "--version"):
        # the installed package's version, as pyproject.toml declares it
        from navd import __version__

        print(f"navd {__version__}")
        return 0
    cmd, rest = args[0], args[1:]
    if cmd not in _COMMANDS:
        print(f"navd: unknown command {cmd!r}\n{_usage()}", file=sys.stderr)
        return 2
    try:
        mod = importlib.import_module(_COMMANDS[cmd][0])
    except ModuleNotFoundError as exc:
        # only a missing optional extra is a property of this installation; anything else
        # (navd's own modules, a core dependency) is a bug and keeps its traceback
        extra = _OPTIONAL.get((exc.name or "").partition(".")[0])
        if extra is None:
            raise
        print(f"navd {cmd}: needs the optional package {exc.name!r}: "
              f"pip install 'navd[{extra}]'", file=sys.stderr)
        return 2
    result: int = mod.main(rest)
    return result


if __name__ == "__main__":
    sys.exit(main())
