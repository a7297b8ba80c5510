"""Compile the estimator's kernels at install time into ``navd/core/_aot/`` (see ``_jit``).

    python -m navd.core.aot_build [--out DIR] [--if-stale] [--quiet]

The kernels built are the ones a start of the estimator needs: every kernel registered with
``navd.core._jit.jit`` that a short synthetic drive through the default estimator compiles
(the same kind of drive as the daemon's warm-up), with the signatures it compiled them for.
A kernel added later is picked up by the next build without a list to edit; until then it is
compiled by the JIT.  The build needs numpy and numba only (it runs in pip's isolated build
environment), and it never fails an install: a failed build leaves no ``_aot`` and navd
compiles its kernels when it starts, as without a build.

``--if-stale`` rebuilds only when the build is missing, was made by another numba/Python, or
any source file under ``navd/core`` changed since (``make`` runs this before tests and runs).
"""

from __future__ import annotations

import argparse
import ast
import json
import math
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

# The drive: straight at 10 m/s, then a turn, fixes 50 ms late (the delayed-fix path).
_DT_US = 10_000
_R_EARTH = 6.37e6


def _exercise() -> None:
    """Push a synthetic drive through a default estimator so its kernels get compiled, and
    through one with a yaw bank (the multirotor profile's, core/aiding/yaw_bank.py), whose
    daemon must not wait for numba either."""
    from navd.config import NavConfig, load_config
    from navd.core.estimator import Estimator

    est = Estimator()
    t_us = _drive(est)
    exercise_lane(est, t_us)
    banked = NavConfig.from_tables(load_config(None, ["yaw_bank.enabled=on"])).estimator
    _drive(Estimator(banked))


def _drive(est: Any) -> int:
    """The synthetic drive through ``est``; returns the last IMU stamp, us."""
    from navd.types import GnssSample, ImuSample

    lat0, lon0, speed = 0.6, 1.9, 10.0
    for k in range(1, 1501):
        t_us = k * _DT_US
        turn = 0.1 if k > 800 else 0.0  # rad/s: heading aiding sees a turn, course moves
        est.push(ImuSample(t_us, _DT_US, 0.0, 0.0, turn * _DT_US * 1e-6, 0.0, 0.0,
                           -9.8 * _DT_US * 1e-6))
        if k % 10 == 5 and k > 10:
            tv = t_us - 50_000
            psi = max(0.0, (tv - 8_000_000) * 1e-6 * turn) if k > 800 else 0.0
            vn, ve = speed * math.cos(psi), speed * math.sin(psi)
            est.push(GnssSample(tv, lat0 + speed * tv * 1e-6 / _R_EARTH, lon0, 400.0, vn, ve,
                                0.0, 2.0, 3.0, 0.1))
        if k % 20 == 0:
            est.solution()
    return k * _DT_US


def exercise_lane(est: Any, t_us: int) -> None:
    """The batch lane's kernels (navd.core.highres_batch, navd.core.imu_block) with the
    argument types the daemon passes (the decoder's and the UDP reader's arrays), through
    ``est`` (navigating, newest IMU stamp ``t_us``; four more samples are pushed).  Also
    the daemon's warm-up, so that they are loaded (or compiled) before READY."""
    import numpy as np

    from navd.core import highres_batch as hb
    from navd.core.imu_block import ImuBlock

    block = ImuBlock()
    for k in range(4):
        block.t_us[k] = t_us + (k + 1) * _DT_US
        block.dt_us[k] = _DT_US
        block.inc[k] = (0.0, 0.0, 0.0, 0.0, 0.0, -9.8 * _DT_US * 1e-6)
    block.n = 4
    est.push_imu_block(block, t_us + 2 * _DT_US, t_us, 1_000_000, 100_000)
    data = bytearray(b"\xfd\x3f\x00\x00\x00\x01\x01\x69\x00\x00" + bytes(65))
    offs = np.array([0, len(data)], np.int64)
    lane = np.zeros(hb.LANE_STATE, np.int64)
    hb.decode_run(np.frombuffer(data, np.uint8), offs, 0, 1, lane, np.ones(2),
                  np.zeros(64, np.uint8), np.zeros(6), block.t_us, block.dt_us, block.inc, 0)
    exercise_udp_rx()


def exercise_udp_rx() -> None:
    """The compiled UDP reader (navd.core.udp_rx) with the argument types its transport
    passes; told to stop before it starts, it returns at once without a system call."""
    import numpy as np

    from navd.core import udp_rx

    ctl = np.zeros(udp_rx.CTL_SIZE, np.int64)
    ctl[udp_rx.C_STOP] = 1
    bufs = [np.frombuffer(bytearray(64), np.uint8) for _ in range(2)]
    offs = np.zeros((2, 3), np.int64)
    addr = np.zeros((2, 2, udp_rx.ADDR_BYTES), np.uint8)
    udp_rx.rx_loop(-1, -1, -1, bufs[0], bufs[1], offs[0], offs[1], addr[0], addr[1],
                   np.zeros((2, udp_rx.META_SIZE), np.int64), ctl, 16)


def core_files() -> dict[str, str]:
    """sha256 of every source file of ``navd.core`` (what ``--if-stale`` compares)."""
    from navd.core._jit import ROOT, file_sha

    out: dict[str, str] = {}
    for p in sorted((ROOT / "navd" / "core").rglob("*.py")):
        rel = p.relative_to(ROOT).as_posix()
        sha = file_sha(rel)
        if sha is not None:
            out[rel] = sha
    return out


def _navd_imports(rel: str) -> set[str]:
    """Files of the ``navd`` modules that ``rel`` imports (constants are frozen into kernels)."""
    from navd.core._jit import ROOT

    tree = ast.parse((ROOT / rel).read_text())
    mods: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            mods.add(node.module)
            mods.update(f"{node.module}.{a.name}" for a in node.names)
        elif isinstance(node, ast.Import):
            mods.update(a.name for a in node.names)
    out: set[str] = set()
    for m in mods:
        if m.split(".")[0] != "navd":
            continue
        base = ROOT.joinpath(*m.split("."))
        for cand in (base.with_suffix(".py"), base / "__init__.py"):
            if cand.is_file():
                out.add(cand.relative_to(ROOT).as_posix())
    return out


def _source_rel(fn: Any) -> str:
    from navd.core._jit import ROOT

    return Path(fn.__code__.co_filename).resolve().relative_to(ROOT).as_posix()


def closure_files(disp: Any) -> set[str]:
    """The files a dispatcher's compiled code depends on: its module, the modules of every
    kernel it calls (through their typing), those modules' navd imports, and ``_jit``."""
    from numba.core import types

    seen: set[int] = set()
    files = {"navd/core/_jit.py"}
    todo = [disp]
    while todo:
        d = todo.pop()
        if id(d) in seen:
            continue
        seen.add(id(d))
        files.add(_source_rel(d.py_func))
        for cres in d.overloads.values():
            ann = cres.type_annotation
            if ann is None:
                raise RuntimeError(f"{d.py_func.__qualname__}: no typing (loaded from a cache?)")
            for t in ann.typemap.values():
                if isinstance(t, types.Dispatcher):
                    todo.append(t.dispatcher)
    for rel in list(files):
        files |= _navd_imports(rel)
    return files


def build(out: Path) -> dict[str, Any]:
    """Compile and write the prebuilt kernels to ``out`` (replaced as a whole); the manifest."""
    os.environ["NAVD_AOT"] = "build"
    from navd.core import _jit

    t0 = time.perf_counter()
    _exercise()
    t_compile = time.perf_counter() - t0
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".aot-", dir=out.parent))
    try:
        kernels: dict[str, Any] = {}
        for key, disp in sorted(_jit.KERNELS.items()):
            if not disp.overloads:
                continue
            try:
                files = sorted(closure_files(disp))
            except Exception as exc:  # its sources cannot be told: leave it to the JIT
                print(f"navd kernels: {key} not prebuilt: {exc}", file=sys.stderr)
                continue
            stamp = _jit.stamp_of(files)
            cache = _jit.prebuilt_cache(disp.py_func, tmp, stamp)
            for sig, cres in disp.overloads.items():
                cache.save_overload(sig, cres)
            kernels[key] = {"files": files, "stamp": stamp,
                            "signatures": [str(s) for s in disp.overloads]}
        m = {"versions": _jit.versions(), "kernels": kernels, "core_files": core_files(),
             "compile_s": round(t_compile, 2)}
        (tmp / _jit.MANIFEST).write_text(json.dumps(m, indent=1, sort_keys=True) + "\n")
        if out.exists():
            shutil.rmtree(out)
        tmp.rename(out)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return m


def is_stale(out: Path) -> str:
    """Why the build in ``out`` should be remade ("" when it need not)."""
    from navd.core import _jit

    try:
        m = json.loads((out / _jit.MANIFEST).read_text())
    except (OSError, ValueError):
        return "no build"
    if m.get("versions") != _jit.versions():
        return f"built for {m.get('versions')}, running {_jit.versions()}"
    now = core_files()
    changed = sorted(k for k in set(now) | set(m.get("core_files", {}))
                     if now.get(k) != m["core_files"].get(k))
    return f"changed since the build: {', '.join(changed)}" if changed else ""


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m navd.core.aot_build",
                                 description="compile navd's kernels into navd/core/_aot")
    ap.add_argument("--out", type=Path, default=None,
                    help="output directory (default: navd/core/_aot beside this file)")
    ap.add_argument("--if-stale", action="store_true",
                    help="do nothing when the build matches the sources and numba")
    ap.add_argument("--quiet", action="store_true")
    a = ap.parse_args(argv)
    from navd.core._jit import AOT_DIR

    out = a.out if a.out is not None else AOT_DIR
    if a.if_stale:
        why = is_stale(out)
        if not why:
            if not a.quiet:
                print(f"navd kernels: {out} is up to date")
            return 0
        print(f"navd kernels: rebuilding ({why[:300]})", file=sys.stderr)
    t0 = time.perf_counter()
    m = build(out)
    if not a.quiet:
        print(f"navd kernels: {len(m['kernels'])} kernels, "
              f"{sum(len(k['signatures']) for k in m['kernels'].values())} signatures "
              f"compiled into {out} in {time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
