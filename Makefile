# One-command set-up and entry points; every target is idempotent.
# `make setup` installs exact versions from requirements.lock (pip constraints: the lock pins
# every dependency, the build tools included); pyproject.toml keeps the ranges for people who
# install dynid as a library. `make lock` refreshes the lock from pyproject.toml.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
LOCK   := requirements.lock
EXTRAS := test,plot,sdp,montecarlo,learning,parquet,ros,docs
# the constraints reach pip's isolated build environment too (setuptools, wheel)
PIP    := PIP_CONSTRAINT=$(CURDIR)/$(LOCK) $(BIN)/python -m pip
# test workers: 2 by default (CI machines have 2 cores), one test module per worker at a time
# (a module fixture runs once); TEST_WORKERS=0 runs everything in one process
TEST_WORKERS ?= 2

.PHONY: setup demo test test-robust docs docs-clean bench lock clean

setup: $(STAMP)

$(STAMP): pyproject.toml $(LOCK)
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(PIP) install --quiet pip
	$(PIP) install --quiet -e '.[$(EXTRAS)]'
	$(BIN)/python -m pip check
	touch $(STAMP)

# torch: resolved from its CPU build (no CUDA packages in the lock), which these machines keep in
# pip's find-links folder; TORCH_WHEELS=<folder with torch's CPU wheel> elsewhere. The lock pins
# the version without the local label (torch==X, not X+cpu): pip's constraint then accepts the CPU
# build where one is available and the PyPI build elsewhere. A lock that pulled CUDA packages is refused.
TORCH_WHEELS ?= $(PIP_FIND_LINKS)

lock:
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet uv
	$(BIN)/uv pip compile --quiet pyproject.toml requirements-tools.in $(foreach e,$(subst $(comma), ,$(EXTRAS)),--extra $(e)) \
		--python-version 3.11 --annotation-style line --custom-compile-command "make lock" \
		$(if $(TORCH_WHEELS),--find-links $(TORCH_WHEELS)) -o $(LOCK).new
	sed -i -E 's/^(torch==[^+ ]+)\+cpu/\1/' $(LOCK).new
	if grep -qE '^(nvidia-|triton)' $(LOCK).new; then rm -f $(LOCK).new; \
		echo "make lock: torch resolved to its CUDA build; set TORCH_WHEELS to a folder with torch's CPU wheel" >&2; exit 1; fi
	mv $(LOCK).new $(LOCK)
	rm -f $(STAMP)

demo: setup
	$(BIN)/dynid demo --out out/demo

test: setup
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile

# the numerically sensitive tests (marker numerics) under other BLAS kernels, one thread, numpy
# without its widest SIMD paths, solver tolerances x0.01 and x10, another data seed (tests/robust.py)
test-robust: setup
	TEST_WORKERS=$(TEST_WORKERS) $(BIN)/python tests/robust.py

# the documentation (docs/): Sphinx with the docs extra (part of EXTRAS, so `make setup` installed it from
# the lock); the config reference and the API stubs are generated, the tutorials executed, at build time;
# every warning is an error. Output: docs/_build/html. A clean build: `make docs-clean docs`.
DOCS_OPTS ?=
docs: setup
	$(BIN)/python -m sphinx -b html -W --keep-going -q $(DOCS_OPTS) docs docs/_build/html

docs-clean:
	rm -rf docs/_build docs/auto_tutorials docs/reference/api/generated docs/sg_execution_times.rst

# every bench script that checks a target runs, a failing one does not stop the others; the list of
# failing scripts ends the run (exit 1)
BENCH_SCRIPTS := regressor_throughput identify_scaling closed_loop_throughput simulate_hexapod \
	simulate_vs_mujoco design_time montecarlo_scaling control_loop_time fleet_scaling vs_figaroh
bench: setup
	@fail=; for s in $(BENCH_SCRIPTS); do echo "== bench/$$s.py"; $(BIN)/python bench/$$s.py || fail="$$fail $$s"; done; \
	if [ -n "$$fail" ]; then echo "make bench: FAIL:$$fail" >&2; exit 1; fi

clean:
	rm -rf $(VENV) out build src/*.egg-info .pytest_cache docs/_build docs/auto_tutorials docs/reference/api/generated

comma := ,
