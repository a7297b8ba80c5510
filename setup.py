"""Build hook: compile navd's estimator kernels when navd is built or installed.

Everything else about the package is in pyproject.toml.  After the sources are in place
(the wheel's build directory, or the source tree for ``pip install -e .``) this runs
``python -m navd.core.aot_build``, which writes numba's compiled kernels to
``navd/core/_aot`` so that the first start of navd does not spend seconds (a minute on a
Raspberry Pi) compiling them (docs/design.md §9, "Kernels at install time").  A failure never
fails the install: navd then compiles its kernels when it starts, as it always did.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

from setuptools import Distribution, setup
from setuptools.command.build_py import build_py

HERE = Path(__file__).resolve().parent


def build_kernels(src_root: Path) -> None:
    out = src_root / "navd" / "core" / "_aot"
    if os.environ.get("NAVD_AOT", "1").strip().lower() in ("0", "no", "off", "false"):
        print("navd: NAVD_AOT=0, kernels not compiled at install", file=sys.stderr)
        return
    with tempfile.TemporaryDirectory() as cache:
        # keep PYTHONPATH: pip's isolated build environment (with numba) is on it
        path = os.pathsep.join(p for p in (str(src_root), os.environ.get("PYTHONPATH")) if p)
        env = {**os.environ, "PYTHONPATH": path, "NUMBA_CACHE_DIR": cache}
        env.pop("NAVD_AOT_DIR", None)
        r = subprocess.run([sys.executable, "-m", "navd.core.aot_build", "--out", str(out)],
                           env=env, cwd=src_root, capture_output=True, text=True, check=False)
    sys.stderr.write(r.stdout + r.stderr[-4000:])
    if r.returncode != 0:
        print("navd: WARNING: compiling the kernels at install failed (above); navd will "
              "compile them when it starts", file=sys.stderr)


class BuildPyWithKernels(build_py):
    def run(self) -> None:
        super().run()
        # editable installs import from the source tree, so the kernels go there
        build_kernels(HERE if getattr(self, "editable_mode", False)
                      else Path(self.build_lib).resolve())


class BinaryDistribution(Distribution):
    """The compiled kernels are for this CPU and this Python: a platform wheel."""

    def has_ext_modules(self) -> bool:
        return True


setup(cmdclass={"build_py": BuildPyWithKernels}, distclass=BinaryDistribution)
