# Everything bootstraps its own virtual environment, so a fresh machine needs only python3.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: run demo test lint bench clean kernels venv

$(STAMP): pyproject.toml setup.py
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e '.[test]'
	touch $(STAMP)

venv: $(STAMP)

# The estimator's kernels compiled ahead of time (navd/core/_aot; pip install builds them,
# setup.py): rebuilt here when a source under navd/core or numba changed since, so a run or
# the tests never start from stale ones (which navd would skip and JIT-compile, slowly).
# A failed build does not stop the tests (tests/test_aot.py fails on it instead).
kernels: $(STAMP)
	$(BIN)/python -m navd.core.aot_build --if-stale --quiet || \
	  echo "navd: kernels not prebuilt (see above); navd compiles them when it starts"

run demo: kernels
	$(BIN)/navd demo

# the allocation and wall-clock tests alone in this process: tracemalloc counts every thread,
# and an xdist worker's execnet thread allocates when more tests arrive (a 7.6 kB peak in CI);
# a timing bound measured beside another worker measures that worker too
test: kernels
	$(BIN)/python -m pytest -q -n auto --maxprocesses 4 -m "not alloc and not realtime"
	$(BIN)/python -m pytest -q -m "alloc or realtime"

bench: kernels
	$(BIN)/python benchmarks/table1.py --runs 3
	$(BIN)/python benchmarks/throughput.py

clean:
	rm -rf $(VENV) navd/core/_aot
