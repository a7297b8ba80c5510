"""``firmware-sim``: generate replay files from a scenario.

    firmware-sim generate --scenario car480 --seed 1 --out runs/car480-1 [--plot]
                          [--set gnss.jumps.enabled=true --set duration_s=60] [--force]
    firmware-sim list

The run is written into a hidden temporary directory beside ``--out`` and renamed into place
only when every file is complete, so a failure never leaves a half-written output folder.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import tomllib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from firmware_sim.scenario import ScenarioError, builtin_scenarios, load_scenario

EXIT_USAGE = 2


def parse_set(items: Sequence[str]) -> dict[str, Any]:
    """``key=value`` pairs; values are TOML (``60``, ``true``, ``[1, 2]``, ``"x"``), else text."""
    out: dict[str, Any] = {}
    for item in items:
        key, sep, raw = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise ScenarioError(f"--set {item!r}: expected key=value")
        try:
            value: Any = tomllib.loads(f"v = {raw.strip()}")["v"]
        except tomllib.TOMLDecodeError:
            value = raw.strip()
        out[key] = value
    return out


def _non_empty_dir(p: Path) -> bool:
    return p.is_dir() and any(p.iterdir())


def _install(tmp: Path, out: Path) -> None:
    """Move the finished ``tmp`` directory to ``out`` (replacing an old run, if any)."""
    if not out.exists() or (out.is_dir() and not any(out.iterdir())):
        os.replace(tmp, out)
        return
    old = Path(tempfile.mkdtemp(prefix=f".{out.name}.old-", dir=out.parent))
    os.replace(out, old / out.name)
    os.replace(tmp, out)
    shutil.rmtree(old, ignore_errors=True)


def cmd_generate(args: argparse.Namespace) -> int:
    from firmware_sim.run import generate

    out = Path(args.out)
    if out.exists() and not out.is_dir():
        print(f"firmware-sim: --out {out} exists and is not a directory", file=sys.stderr)
        return EXIT_USAGE
    if _non_empty_dir(out) and not args.force:
        print(f"firmware-sim: --out {out} is not empty (use --force to replace it)",
              file=sys.stderr)
        return EXIT_USAGE
    # validate everything before touching the file system
    sc = load_scenario(args.scenario, parse_set(args.set))
    run = generate(sc, args.seed, progress=not args.quiet)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.tmp-", dir=out.parent))
    try:
        # mkdtemp makes the directory private (0700); the result is an ordinary output folder
        umask = os.umask(0)
        os.umask(umask)
        tmp.chmod(0o777 & ~umask)
        run.write_csv(tmp, progress=not args.quiet)
        if args.plot:
            from firmware_sim.plot import plot_track

            plot_track(run, tmp / "track.png")
        _install(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    if not args.quiet:
        n_out = int(run.gnss["outlier"].sum())
        print(f"{sc.name}: {run.imu_t_us.shape[0]} IMU samples, {run.gnss['t_us'].shape[0]} "
              f"GNSS epochs ({n_out} with velocity jumps) -> {out}", file=sys.stderr)
    return 0


def cmd_list(_: argparse.Namespace) -> int:
    for name in builtin_scenarios():
        sc = load_scenario(name)
        print(f"{name:12s} {sc.duration:8.0f} s  {sc.description}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="firmware-sim", description=__doc__.splitlines()[0]
                                if __doc__ else None)
    sub = p.add_subparsers(dest="command", required=True)
    g = sub.add_parser("generate", help="simulate a scenario and write imu/gnss/truth CSVs")
    g.add_argument("--scenario", required=True, help="built-in name or path to a .toml file")
    g.add_argument("--seed", type=int, required=True, help="non-negative integer seed")
    g.add_argument("--out", required=True, help="output directory (created)")
    g.add_argument("--plot", action="store_true", help="also write track.png")
    g.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scenario field by dotted key, e.g. gnss.rate_hz=5")
    g.add_argument("--force", action="store_true", help="replace a non-empty --out")
    g.add_argument("--quiet", action="store_true", help="no progress bar or summary")
    g.set_defaults(func=cmd_generate)
    ls = sub.add_parser("list", help="list the built-in scenarios")
    ls.set_defaults(func=cmd_list)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if getattr(args, "seed", 0) < 0:
        print("firmware-sim: --seed must be >= 0", file=sys.stderr)
        return EXIT_USAGE
    try:
        rc: int = args.func(args)
    except ScenarioError as e:
        print(f"firmware-sim: {e}", file=sys.stderr)
        return EXIT_USAGE
    return rc


if __name__ == "__main__":
    sys.exit(main())
