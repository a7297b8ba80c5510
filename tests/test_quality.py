"""Static checks are part of the test run: ruff and mypy --strict on navd/ and firmware_sim/."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", *args], cwd=ROOT, capture_output=True,
                          text=True, timeout=600)


def test_ruff_clean() -> None:
    """GIVEN the repository,
    WHEN ruff checks navd, firmware_sim, tests and benchmarks,
    THEN it reports nothing (exit code 0)."""
    r = _run("ruff", "check", "navd", "firmware_sim", "tests", "benchmarks")
    assert r.returncode == 0, r.stdout + r.stderr


def test_mypy_strict_clean() -> None:
    """GIVEN the repository,
    WHEN mypy --strict checks navd and firmware_sim,
    THEN it reports nothing (exit code 0)."""
    r = _run("mypy", "--strict", "navd", "firmware_sim")
    assert r.returncode == 0, r.stdout + r.stderr
