# mlsemreg_ros: `make demo` runs the demo, `make test` runs the whole test suite.
# Both create .venv and install everything first (Debian packages too, as root).
VENV ?= .venv
PY := $(VENV)/bin/python
export ROS_DOMAIN_ID ?= 42
export RMW_IMPLEMENTATION ?= rmw_fastrtps_cpp
# large clouds between processes: a 64 MiB shared-memory segment (docs/field_moving.md)
export FASTRTPS_DEFAULT_PROFILES_FILE ?= $(CURDIR)/config/fastdds.xml
export FASTDDS_DEFAULT_PROFILES_FILE ?= $(FASTRTPS_DEFAULT_PROFILES_FILE)

.PHONY: setup test test-fast demo bench bench-node eval-pairs params lint format clean

setup:
	@bash scripts/bootstrap.sh

test: setup
	$(PY) -m pytest -q test

# the quick subset (under a minute): everything but the tests marked slow
test-fast: setup
	$(PY) -m pytest -q -m "not slow" test

lint: setup
	$(VENV)/bin/ruff check mlsemreg_ros test setup.py
	$(VENV)/bin/pre-commit run --all-files
	$(PY) -m pytest -q test/test_flake8.py test/test_pep257.py test/test_copyright.py

format: setup
	$(VENV)/bin/ruff format mlsemreg_ros test setup.py launch

demo: setup
	$(VENV)/bin/mlsemreg demo

# regenerate config/params.yaml and docs/parameters.md
params: setup
	$(VENV)/bin/mlsemreg params

bench: setup
	$(VENV)/bin/mlsemreg bench --json results/bench.json

bench-node: setup
	$(VENV)/bin/mlsemreg bench-node

eval-pairs: setup
	$(VENV)/bin/mlsemreg eval-pairs ../shared/data/kitti_pairs_dev --json results/eval_pairs.json

clean:
	rm -rf build install log results .pytest_cache
