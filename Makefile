# One-command set-up and entry points; every target is idempotent.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: setup demo test bench clean

setup: $(STAMP)

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test,plot,sdp,montecarlo]'
	touch $(STAMP)

demo: setup
	$(BIN)/dynid demo --out out/demo

test: setup
	$(BIN)/python -m pytest -q

bench: setup
	$(BIN)/python bench/regressor_throughput.py
	$(BIN)/python bench/identify_scaling.py
	$(BIN)/python bench/closed_loop_throughput.py
	$(BIN)/python bench/simulate_hexapod.py
	$(BIN)/python bench/design_time.py
	$(BIN)/python bench/montecarlo_scaling.py

clean:
	rm -rf $(VENV) out build src/*.egg-info .pytest_cache
