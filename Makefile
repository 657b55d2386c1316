# stid: the two commands a newcomer needs are `make demo` and `make test`.
# Everything is installed into a local virtual environment (.venv) from PyPI.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp

.PHONY: demo test bench venv vectors c-test clean

$(STAMP): pyproject.toml
	@echo "Creating $(VENV) and installing stid with its test tools (first run only)..."
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet -e '.[test]'
	@touch $@

venv: $(STAMP)

demo: $(STAMP)
	$(BIN)/python -m hil_sim.demo

test: $(STAMP)
	$(BIN)/python -m pytest -q

bench: $(STAMP)
	$(BIN)/python -m benchmarks.run

c-test:
	$(MAKE) -C firmware/c test

vectors: $(STAMP)
	$(BIN)/python firmware/vectors/make_vectors.py

clean:
	rm -rf $(VENV) firmware/c/build out demo_out .pytest_cache
