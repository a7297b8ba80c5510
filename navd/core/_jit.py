"""Typed wrapper around numba's ``njit``, the kernel registry, and the install-time kernels.

The estimator's kernels are plain Python on preallocated numpy arrays; numba compiles them
so a steady-state IMU step costs microseconds instead of the ~0.7 ms of equivalent CPython
array code.  ``NUMBA_DISABLE_JIT=1`` runs the very same code uncompiled (debugging,
coverage).

Compiling the kernels takes seconds (a minute on a Raspberry Pi), so the machine code of the
kernels the daemon needs is made when navd is installed (``python -m navd.core.aot_build``,
run by ``setup.py``, ``make`` and ``navd warmup --build``) and kept in ``navd/core/_aot/``.
It is numba's own compile result, so a kernel served from there is the JIT's code, bit for
bit, behind the same dispatcher (argument types checked, other signatures still compiled on
demand, callable from other kernels).  What is ahead of time is only *when* it was compiled.

Each prebuilt kernel is stamped with a hash of the sources it was compiled from: its own
module, the modules of every kernel it calls, their ``navd`` imports and this file.  A kernel
whose stamp no longer matches (source edited after the build) is not loaded; it is compiled
as before and cached in numba's ordinary cache (``NUMBA_CACHE_DIR`` where the package is
read-only, as under systemd).  ``NAVD_AOT=0`` ignores the prebuilt kernels altogether.
:func:`aot_status` says what was used; nothing here logs (``navd.core`` has no I/O of its
own beyond reading these files).
"""

from __future__ import annotations

import functools
import hashlib
import importlib.metadata
import json
import os
import sys
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any, TypeVar, cast

import numba

F = TypeVar("F", bound=Callable[..., Any])

# the directory holding the ``navd`` package: stamps name files relative to it, so a build in
# one place (a wheel's build directory) is valid where the package is installed
ROOT = Path(__file__).resolve().parents[2]
# NAVD_AOT_DIR: another place for the build (a read-only package built elsewhere, tests)
AOT_DIR = Path(os.environ.get("NAVD_AOT_DIR") or Path(__file__).resolve().with_name("_aot"))
MANIFEST = "manifest.json"
FORMAT = 1

# every kernel made with :func:`jit`, by "module:qualname" (the AOT build compiles from here)
KERNELS: dict[str, Any] = {}

# what the dispatchers' caches did in this process (see aot_status)
_COUNTS = {"aot": 0, "cache": 0, "compiled": 0}


def kernel_key(fn: Callable[..., Any]) -> str:
    return f"{fn.__module__}:{fn.__qualname__}"


def _mode() -> str:
    """"build" (aot_build is compiling: no cache at all), "off" (NAVD_AOT=0) or "on"."""
    v = os.environ.get("NAVD_AOT", "1").strip().lower()
    if v == "build":
        return "build"
    return "off" if v in ("0", "no", "off", "false") else "on"


@functools.cache
def _file_sha(rel: str, mtime_ns: int, size: int) -> str:
    # keyed by mtime and size too, so an edit while the process runs is seen
    return hashlib.sha256((ROOT / rel).read_bytes()).hexdigest()


def file_sha(rel: str) -> str | None:
    """sha256 of ``ROOT/rel``, None when it cannot be read."""
    try:
        st = (ROOT / rel).stat()
        return _file_sha(rel, st.st_mtime_ns, st.st_size)
    except OSError:
        return None


def stamp_of(files: Iterable[str]) -> str | None:
    """The stamp of a kernel compiled from ``files`` (paths relative to ROOT) as they are now."""
    h = hashlib.sha256()
    for rel in sorted(set(files)):
        sha = file_sha(rel)
        if sha is None:
            return None
        h.update(f"{rel}\0{sha}\n".encode())
    return h.hexdigest()


def versions() -> dict[str, str]:
    """What a prebuilt kernel is only valid for (numba refuses other versions' caches too)."""
    return {"numba": numba.__version__, "llvmlite": importlib.metadata.version("llvmlite"),
            "python": f"{sys.version_info[0]}.{sys.version_info[1]}{getattr(sys, 'abiflags', '')}",
            "format": str(FORMAT)}


@functools.lru_cache(maxsize=1)
def manifest() -> dict[str, Any] | None:
    """The prebuilt kernels' manifest, None when there is none or it is for other versions."""
    try:
        m = json.loads((AOT_DIR / MANIFEST).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(m, dict) or m.get("versions") != versions():
        return None
    return m


def _cache_classes(directory: Path, stamp: str | None) -> type:
    """A numba FunctionCache class reading/writing ``directory`` with a content stamp.

    numba's own locators stamp a cache with the source file's mtime and size, which an
    install does not preserve, and only the kernel's own file; this one uses the hash of
    everything the kernel was compiled from.
    """
    from numba.core import caching

    class Locator(caching._CacheLocator):
        def __init__(self, py_func: Callable[..., Any], py_file: str) -> None:
            self._py_file = py_file
            self._lineno = py_func.__code__.co_firstlineno
            # one directory per module: numba names the files by file stem and function
            self._dir = directory / py_func.__module__

        def ensure_cache_path(self) -> None:
            self._dir.mkdir(parents=True, exist_ok=True)

        def get_cache_path(self) -> str:
            return str(self._dir)

        def get_source_stamp(self) -> str | None:
            return stamp

        def get_disambiguator(self) -> str:
            return str(self._lineno)

        @classmethod
        def from_function(cls, py_func: Callable[..., Any], py_file: str) -> Locator:
            return cls(py_func, py_file)

    class Impl(caching.CompileResultCacheImpl):
        _locator_classes = [Locator]  # noqa: RUF012 - numba's own class attribute

    class Cache(caching.FunctionCache):
        _impl_class = Impl

        def load_overload(self, sig: Any, target_context: Any) -> Any:
            # numba's load first refreshes the whole target context: it imports and
            # installs every typing and lowering registry (~0.1 s, as long as importing
            # numba, 0.4 s on a Pi), which only compiling needs.  Loading machine code needs
            # the runtime's symbols (NRT), which this initialises; any compile still
            # refreshes first.
            from numba.core.runtime.nrt import rtsys

            rtsys.initialize(target_context)
            return cast(Any, self)._load_overload(sig, target_context)

    return Cache


def prebuilt_cache(py_func: Callable[..., Any], directory: Path, stamp: str | None) -> Any:
    """numba cache object for ``py_func`` in ``directory`` (used by the build to save)."""
    return _cache_classes(directory, stamp)(py_func)


class _Layered:
    """A dispatcher cache: the prebuilt kernel if its stamp matches, else numba's own cache.

    Compiled code is saved to numba's cache only (the package may be read-only).
    """

    def __init__(self, aot: Any, user: Any) -> None:
        self._aot = aot
        self._user = user

    @property
    def cache_path(self) -> str:
        return cast(str, self._user.cache_path)

    def load_overload(self, sig: Any, target_context: Any) -> Any:
        try:
            cres = self._aot.load_overload(sig, target_context)
        except Exception:  # a damaged or foreign file: compile instead
            cres = None
        if cres is not None:
            _COUNTS["aot"] += 1
            return cres
        return _count_user(self._user.load_overload(sig, target_context))

    def save_overload(self, sig: Any, cres: Any) -> None:
        self._user.save_overload(sig, cres)

    def enable(self) -> None:
        self._user.enable()

    def disable(self) -> None:
        self._user.disable()

    def flush(self) -> None:
        self._user.flush()


class _Counting(_Layered):
    """numba's own cache, counting hits and compiles (no prebuilt kernel for this one)."""

    def __init__(self, user: Any) -> None:
        super().__init__(None, user)

    def load_overload(self, sig: Any, target_context: Any) -> Any:
        return _count_user(self._user.load_overload(sig, target_context))


def _count_user(cres: Any) -> Any:
    _COUNTS["cache" if cres is not None else "compiled"] += 1
    return cres


def jit(fn: F) -> F:
    """Compile ``fn`` in nopython mode, cached, without the GIL held; register it."""
    mode = _mode()
    # a build compiles afresh without any cache: it reads the typing of what it compiled
    disp: Any = numba.njit(cache=mode != "build", nogil=True)(fn)
    if not isinstance(disp, numba.core.registry.CPUDispatcher):  # NUMBA_DISABLE_JIT=1
        return cast(F, disp)
    key = kernel_key(fn)
    KERNELS[key] = disp
    if mode == "build":
        return cast(F, disp)
    m = manifest() if mode == "on" else None
    entry = m["kernels"].get(key) if m is not None else None
    d = cast(Any, disp)  # numba's dispatcher keeps its cache in ``_cache``
    try:
        if entry is not None:
            aot = prebuilt_cache(fn, AOT_DIR, stamp_of(entry["files"]))
            d._cache = _Layered(aot, d._cache)
        else:
            d._cache = _Counting(d._cache)
    except Exception:  # numba's cache internals moved: plain JIT with numba's cache
        pass
    return cast(F, disp)


def stale_kernels() -> list[str]:
    """Prebuilt kernels whose sources changed since the build (they are compiled instead)."""
    m = manifest()
    if m is None:
        return []
    return sorted(k for k, e in m["kernels"].items() if stamp_of(e["files"]) != e["stamp"])


def aot_status() -> dict[str, Any]:
    """What the kernels of this process came from.

    ``state``: "off" (NAVD_AOT=0), "absent" (no build, or one for other numba/Python
    versions), "fresh" (every prebuilt kernel matches its sources) or "stale" (some do not:
    ``stale`` names them); ``aot``/``cache``/``compiled``: kernels loaded from the build,
    from numba's cache, compiled in this process.
    """
    mode = _mode()
    out: dict[str, Any] = dict(_COUNTS)
    if mode != "on":
        out["state"] = "off" if mode == "off" else "build"
        return out
    m = manifest()
    if m is None:
        out["state"] = "absent"
        return out
    stale = stale_kernels()
    out["state"] = "stale" if stale else "fresh"
    out["stale"] = stale
    out["prebuilt"] = len(m["kernels"])
    return out


def describe_status(s: dict[str, Any]) -> str:
    """One log line for :func:`aot_status`."""
    counts = f"{s['aot']} prebuilt, {s['cache']} from numba's cache, {s['compiled']} compiled"
    if s["state"] == "stale":
        names = ", ".join(k.split(":")[1] for k in s["stale"][:6])
        more = f" and {len(s['stale']) - 6} more" if len(s["stale"]) > 6 else ""
        return (f"kernels: {counts}; {len(s['stale'])} prebuilt kernels are stale (source "
                f"edited after the build: {names}{more}), compiled by the JIT instead; "
                f"rebuild: python -m navd.core.aot_build")
    if s["state"] == "absent":
        return (f"kernels: {counts}; no prebuilt kernels for this numba/Python "
                f"(python -m navd.core.aot_build makes them)")
    if s["state"] == "off":
        return f"kernels: {counts}; prebuilt kernels off (NAVD_AOT=0)"
    return f"kernels: {counts}"
