# Two commands set everything up on a machine with only Python 3.11 and pip:
#   make demo   create .venv, install graphcal, calibrate the bundled demo network
#               (graph method, with ADS-B and from cross-radar observations alone), then
#               the same network with primary and Mode A/C radars (demo_identity.toml)
#   make test   same set-up, then make lint and the whole test suite (one worker a core)
#   make lint   ruff, and import-linter's layer contracts (pyproject.toml)
#   make docs   same set-up, then the manual and API reference into site/ (mkdocs --strict)
#   make bench  same set-up, then the benchmarks: bench_graph (graph vs scipy, 10-radar
#               network), bench_selection (selection on 131k observations), bench_speed (the
#               whole command against a plain scipy fit, 40k and 1M plots, and 1M with
#               --window 1h), bench_memory (17 h against 2 h) and drift_steps (biases over
#               time); about half an hour on 2 cores
#   make papers same set-up, then the paper 000/002 reproductions (covariance, fusion, noise)
# bench and papers write their figures to $(BENCH_RESULTS), by default benchmarks/results/latest/
# (ignored by git); `make bench BENCH_RESULTS=benchmarks/results` replaces the tracked figures
# that the manual quotes.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
BENCH_RESULTS ?= benchmarks/results/latest

.PHONY: demo test lint docs bench papers install clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet -e ".[test,docs]"
	$(BIN)/python -m compileall -q graphcal
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(BIN)/graphcal simulate scenarios/demo_network.toml --out demo-out --seed 1 --overwrite
	$(BIN)/graphcal calibrate demo-out
	$(BIN)/graphcal calibrate demo-out --no-adsb
	$(BIN)/graphcal simulate scenarios/demo_identity.toml --out demo-identity-out --seed 1 --overwrite
	$(BIN)/graphcal calibrate demo-identity-out

test: lint
	$(BIN)/python -m pytest -n auto

bench: export GRAPHCAL_BENCH_RESULTS = $(abspath $(BENCH_RESULTS))
bench: $(STAMP)
	mkdir -p $(BENCH_RESULTS)
	$(BIN)/python -m benchmarks.bench_graph
	$(BIN)/python -m benchmarks.bench_selection
	$(BIN)/python -m benchmarks.bench_speed
	$(BIN)/python -m benchmarks.bench_speed --sizes 1M --window 1h --repeats 3 \
		--json $(BENCH_RESULTS)/bench_speed_window.json
	$(BIN)/python -m benchmarks.bench_speed --sizes 40k --pairwise --repeats 5 \
		--json $(BENCH_RESULTS)/bench_speed_pairwise.json
	$(BIN)/python -m benchmarks.bench_speed --sizes 40k --pairwise --no-adsb --repeats 5 \
		--json $(BENCH_RESULTS)/bench_speed_pairwise_no_adsb.json
	$(BIN)/python -m benchmarks.bench_memory
	$(BIN)/python -m benchmarks.bench_memory --function benchmarks.bench_memory:calibrate_batch \
		--json $(BENCH_RESULTS)/bench_memory_batch.json
	$(BIN)/python -m benchmarks.trajectory_study --seeds 30 --json $(BENCH_RESULTS)/trajectory_study.json
	$(BIN)/python -m benchmarks.drift_steps

papers: export GRAPHCAL_BENCH_RESULTS = $(abspath $(BENCH_RESULTS))
papers: $(STAMP)
	mkdir -p $(BENCH_RESULTS)
	$(BIN)/python -m benchmarks.paper002_covariance
	$(BIN)/python -m benchmarks.paper002_fusion
	$(BIN)/python -m benchmarks.noise_estimation --seeds 8

lint: $(STAMP)
	$(BIN)/ruff check graphcal tests benchmarks
	$(BIN)/lint-imports

docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --site-dir site

clean:
	rm -rf $(VENV) build *.egg-info site
