# Two entry points (README): `make run` and `make test`. Both create or reuse .venv.
PYTHON ?= python3.11
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-$(shell cat pyproject.toml | cksum | cut -d' ' -f1)

.PHONY: run test bench bench-quick clean

$(PY):
	@command -v $(PYTHON) >/dev/null 2>&1 || { echo "need $(PYTHON) on PATH (set PYTHON=...)"; exit 2; }
	$(PYTHON) -m venv $(VENV)

$(STAMP): $(PY) pyproject.toml
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[test,validate]"
	rm -f $(VENV)/.installed-* && touch $(STAMP)

run: $(STAMP)
	$(VENV)/bin/jaxsss run --out-dir out

# A crashed worker ends the run (--max-worker-restart=0): a replacement would rerun the crashed module's tests, and a
# CI run that lost a worker to an abort hung until its time limit. pytest-timeout (pyproject) bounds any one test.
# Bytecode (the tests' assertion rewriting included) is cached under .venv even where the environment turns it off
# (PYTHONDONTWRITEBYTECODE): each worker's collection took 13 s without it and 7 s with it, and every subprocess and
# notebook kernel compiles jaxsss again.
test: $(STAMP)
	PYTHONDONTWRITEBYTECODE= PYTHONPYCACHEPREFIX=$(CURDIR)/$(VENV)/pycache \
		$(PY) -m pytest -n 2 --dist loadscope --no-loadscope-reorder --max-worker-restart=0 -q tests

bench: $(STAMP)
	$(PY) -m benchmarks.run_all

bench-quick: $(STAMP)
	$(PY) -m benchmarks.run_all --quick

clean:
	rm -rf out .pytest_cache .hypothesis
