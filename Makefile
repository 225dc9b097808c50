# Two commands do all the set-up on a fresh machine: `make demo` and `make test`.
# Each creates .venv (CPython 3.11 or 3.12) with the pinned requirements if it is missing.
SHELL := /bin/bash
PYTHON ?= $(shell command -v python3.11 || command -v python3.12 || command -v python3)
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.pulsejet-installed
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST

.PHONY: venv demo test bench clean

venv: $(STAMP)

$(STAMP): requirements.txt setup.py setup.cfg
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --disable-pip-version-check -q -r requirements.txt
	$(PY) -m pip install --disable-pip-version-check -q --no-deps -e .
	# pip's editable install does not run setup.py develop, whose hook warms numba's cache:
	# compile the shipped scenes' kernels once here, so no node compiles at its first start
	$(PY) -m pulsejet_sim.engine.warmup --quiet
	# and the offline recording's layout kernel, so the first `pulsejet run` does not compile it
	$(PY) -c 'from pulsejet_sim.bag.publications import warm_kernel; warm_kernel()'
	touch $(STAMP)

demo: $(STAMP)
	$(PY) -m pulsejet_sim.ros.demo $(DEMO_ARGS)

test: $(STAMP)
	$(PY) -m pytest -q $(PYTEST_ARGS)

bench: $(STAMP)
	$(PY) -m benchmarks.performance.bench_lumped

clean:
	rm -rf $(VENV) build install log runs
