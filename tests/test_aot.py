"""Install-time kernels (navd/core/_aot, issue 18): the prebuilt kernels compute exactly what
the JIT computes, a kernel whose source changed after the build is compiled instead of
loaded, and NAVD_AOT=0 ignores the build.

Each case runs in its own interpreter with an empty numba cache (NUMBA_CACHE_DIR pointed at
a fresh directory), so what a process used is what it loaded from the build or compiled.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]

# Random drive through a default estimator (turns, biases, noisy fixes, one delayed), then
# Python-facing kernels on random arguments; prints the state buffer, the outputs and what
# the kernels came from.
_PROBE = r"""
import json, sys
import numpy as np
from navd.core import _jit, earth, rotation
from navd.core.estimator import Estimator
from navd.core.output import attitude_outputs
from navd.types import GnssSample, ImuSample

rng = np.random.default_rng(int(sys.argv[1]))
est = Estimator()
dt = 10_000
for k in range(1, 1201):
    t = k * dt
    w = rng.normal(0.0, 0.02, 3) * dt * 1e-6
    f = (rng.normal(0.0, 0.3, 3) + (0.0, 0.0, -9.8)) * dt * 1e-6
    est.push(ImuSample(t, dt, *w, *f))
    if k % 10 == 3 and k > 20:
        tv = t - int(rng.integers(0, 80_000))
        v = rng.normal(0.0, 1.0, 3) + (8.0, 3.0, 0.0)
        est.push(GnssSample(tv, 0.6 + tv * 1e-12, 1.9, 400.0 + rng.normal(), *v, 2.0, 3.0, 0.1))
sol = est.solution()
out = {"buf": est._buf.tolist(), "sol": [float(x) for x in (sol.roll_rad, sol.pitch_rad,
                                                            sol.yaw_rad)]}
m = np.empty((3, 3))
calls = []
for _ in range(50):
    r, p, y = rng.uniform(-3.0, 3.0, 3)
    rotation.euler_to_mat_into(m, r, p, y)
    cov = np.diag(rng.uniform(1e-6, 1e-2, 15))
    M = np.empty((3, 3))
    calls.append(list(rotation.mat_to_quat(m)) + list(rotation.mat_to_euler(m))
                 + list(attitude_outputs(m, cov, M)) + list(earth.radii(r / 2.0))
                 + [earth.gravity(p / 2.0, y * 1000.0)] + m.ravel().tolist())
out["calls"] = calls
# a kernel compiled now that calls prebuilt ones (as a new kernel would)
import numba

@numba.njit
def composed(m, r, p, y):
    rotation.euler_to_mat_into(m, r, p, y)
    return rotation.mat_to_quat(m), earth.radii(p)

q, rr = composed(m, 0.3, -0.2, 2.0)
out["composed"] = list(q) + list(rr)
out["status"] = _jit.aot_status()
out["radii"] = list(earth.radii(0.5))
print(json.dumps(out))
"""


def _run(env_extra: dict[str, str], tmp: Path, root: Path = REPO, seed: int = 7) -> Any:
    cache = tmp / f"numba-{len(list(tmp.glob('numba-*')))}"
    cache.mkdir()
    env = {**os.environ, "PYTHONPATH": str(root), "NUMBA_CACHE_DIR": str(cache), **env_extra}
    env.pop("NUMBA_DISABLE_JIT", None)
    r = subprocess.run([sys.executable, "-c", _PROBE, str(seed)], env=env, cwd=tmp,
                       capture_output=True, text=True, timeout=600, check=False)
    assert r.returncode == 0, r.stderr[-3000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


@pytest.fixture(scope="module")
def build(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("aot") / "_aot"
    env = {**os.environ, "PYTHONPATH": str(REPO),
           "NUMBA_CACHE_DIR": str(tmp_path_factory.mktemp("numba-build"))}
    r = subprocess.run([sys.executable, "-m", "navd.core.aot_build", "--out", str(out)],
                       env=env, capture_output=True, text=True, timeout=900, check=False)
    assert r.returncode == 0, r.stderr[-3000:]
    return out


@pytest.fixture(scope="module")
def jit_run(build: Path, tmp_path_factory: pytest.TempPathFactory) -> Any:
    """The reference: the same probe with the build present but NAVD_AOT=0."""
    return _run({"NAVD_AOT_DIR": str(build), "NAVD_AOT": "0"}, tmp_path_factory.mktemp("jit"))


def test_build_lists_the_estimator_kernels(build: Path) -> None:
    """GIVEN a build, THEN its manifest holds the estimator's entry kernels, each stamped
    with files that include its own module and the kernels it calls."""
    m = json.loads((build / "manifest.json").read_text())
    k = m["kernels"]
    for name in ("navd.core.state:imu_step", "navd.core.state:update",
                 "navd.core.output:attitude_outputs", "navd.core.rotation:euler_to_mat_into"):
        assert name in k, sorted(k)
    files = k["navd.core.state:imu_step"]["files"]
    for f in ("navd/core/state.py", "navd/core/kalman.py", "navd/core/strapdown.py",
              "navd/core/rotation.py", "navd/core/_jit.py"):
        assert f in files, files
    assert "navd/core/estimator.py" not in files  # not a kernel module: edits do not matter


def test_prebuilt_kernels_equal_the_jit(build: Path, jit_run: Any, tmp_path: Path) -> None:
    """GIVEN an empty numba cache and the build, WHEN a random drive and random kernel calls
    run, THEN nothing is compiled, and every number equals the JIT's bit for bit; with
    NAVD_AOT=0 the same build is ignored (every kernel compiled)."""
    aot = _run({"NAVD_AOT_DIR": str(build)}, tmp_path)
    assert aot["status"]["state"] == "fresh", aot["status"]
    assert aot["status"]["compiled"] == 0 and aot["status"]["aot"] >= 10, aot["status"]
    # NAVD_AOT=0 with the same build present: nothing loaded from it, everything compiled
    assert jit_run["status"]["state"] == "off" and jit_run["status"]["aot"] == 0
    assert jit_run["status"]["compiled"] >= 10, jit_run["status"]
    np.testing.assert_array_equal(np.array(aot["buf"]), np.array(jit_run["buf"]))
    np.testing.assert_array_equal(np.array(aot["sol"]), np.array(jit_run["sol"]))
    np.testing.assert_array_equal(np.array(aot["calls"]), np.array(jit_run["calls"]))
    np.testing.assert_array_equal(np.array(aot["composed"]), np.array(jit_run["composed"]))
    assert np.isfinite(np.array(aot["buf"])).all()


def test_stale_kernel_is_compiled_not_loaded(build: Path, jit_run: Any, tmp_path: Path) -> None:
    """GIVEN a source tree whose earth.radii was edited after the build (its result doubled),
    WHEN it runs with that build, THEN the kernels depending on earth.py are reported stale
    and compiled (the edit takes effect), the others are still loaded from the build."""
    tree = tmp_path / "tree"
    shutil.copytree(REPO / "navd", tree / "navd",
                    ignore=shutil.ignore_patterns("__pycache__", "_aot", "*.nbi", "*.nbc"))
    src = tree / "navd/core/earth.py"
    text = src.read_text()
    marker = "    return r_m, r_n\n"
    assert text.count(marker) == 1, "earth.radii changed shape; update this test"
    src.write_text(text.replace(marker, "    return 2.0 * r_m, 2.0 * r_n\n"))
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    res = _run({"NAVD_AOT_DIR": str(build)}, run_dir, root=tree)
    st = res["status"]
    assert st["state"] == "stale", st
    assert "navd.core.earth:radii" in st["stale"] and "navd.core.state:imu_step" in st["stale"]
    assert "navd.core.rotation:mat_to_quat" not in st["stale"], st["stale"]
    assert st["compiled"] >= 1 and st["aot"] >= 1, st
    np.testing.assert_allclose(res["radii"], 2.0 * np.array(jit_run["radii"]), rtol=1e-15)


def test_navd_warmup_reports_the_prebuilt_kernels(build: Path, tmp_path: Path) -> None:
    """GIVEN the build and an empty numba cache, WHEN `navd warmup --strict --json` runs,
    THEN it exits 0 and reports the kernels as loaded from the build, none compiled."""
    env = {**os.environ, "PYTHONPATH": str(REPO), "NUMBA_CACHE_DIR": str(tmp_path / "nc"),
           "NAVD_AOT_DIR": str(build)}
    env.pop("NAVD_AOT", None)
    r = subprocess.run([sys.executable, "-m", "navd", "warmup", "--strict", "--json"],
                       env=env, cwd=tmp_path, capture_output=True, text=True, timeout=600,
                       check=False)
    assert r.returncode == 0, r.stdout + r.stderr[-3000:]
    st = json.loads(r.stdout.strip().splitlines()[-1])
    assert st["state"] == "fresh" and st["aot"] >= 10 and st["compiled"] == 0, st
