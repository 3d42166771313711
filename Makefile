# Two commands do all the set-up: `make demo` and `make test`.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: demo test docs dist lint bench clean

# The interop tests' OPC UA server on node-opcua (another stack than asyncua), pinned by
# its lockfile and installed with npm ci; test-only, never part of the package.
PLC_SERVER := tests/czmpc/runtime/plc_server
PLC_STAMP := $(PLC_SERVER)/node_modules/.package-lock.json

$(PLC_STAMP): $(PLC_SERVER)/package-lock.json
	cd $(PLC_SERVER) && npm ci --no-audit --no-fund --loglevel=error

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[dev,docs,opcua,dask,pandas,control]"
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/czmpc demo --out out/demo

# CI runs `make test` only (.ci/run), so the documentation site is built here too.
# tools/run_suite.sh: the suite on two workers (pytest-xdist) and the docs build, both at
# nice 10, while the wall-clock loops against a served plant (marker realtime) run at
# normal priority, so that the niced jobs never delay a loop period.
test: $(STAMP) $(PLC_STAMP)
	$(VENV)/bin/ruff check sysid sim czmpc benchmarks tests docs
	$(VENV)/bin/mypy sysid sim czmpc benchmarks
	bash tools/run_suite.sh $(PY)

# The documentation site: warnings are errors, every gallery example is executed.
# Output: docs/_build/html/index.html
docs: $(STAMP)
	$(VENV)/bin/sphinx-build -b html -W --keep-going -q docs docs/_build/html

# The sdist and the wheel, in dist/.
dist: $(STAMP)
	$(PY) -m build --outdir dist .

# Every benchmark (benchmarks/, not part of the package); each rewrites its own section of
# BENCHMARKS.md with the command and the machine. SIPPY (a benchmark-only peer) is
# installed from the 'bench' extra.
bench: $(STAMP)
	$(PY) -m pip install --quiet -e ".[dev,bench]"
	$(PY) -m benchmarks.identify --repeats 5 --with-sippy --out out/bench/identify
	$(PY) -m benchmarks.mpc_step --repeats 5
	$(PY) -m benchmarks.codegen_step --repeats 5 --fuzz-cases 400
	$(PY) -m benchmarks.codegen_step --solver daqp --repeats 5
	$(PY) -m benchmarks.tracking --out out/bench/tracking
	$(PY) -m benchmarks.value_case --out out/bench/value
	$(PY) -m benchmarks.robustness --full --out out/bench/robustness
	$(PY) -m benchmarks.health
	$(PY) -m benchmarks.commission_length --record-benchmarks --out out/bench/commission
	$(PY) -m benchmarks.campaign_throughput --workers 2 --record

clean:
	rm -rf $(VENV) out dist docs/_build docs/api/generated docs/auto_examples $(PLC_SERVER)/node_modules
