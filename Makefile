# Two commands: `make demo` and `make test`. Each creates .venv and installs the project if needed
# (with the simulator's [sim] extra, the test tools and the [view] extra, whose bridge the tests drive).
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test test-load test-slow reproduce reproduce-quick bench bench-graph bench-cli bench-curve bench-bag bench-sim bench-import bench-grid bench-estimation bench-estimator bench-loop bench-loop-viewer bench-bridge bench-emulated-load clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[sim,test,view]'
	touch $(STAMP)

# One closed-loop run on the simulated rig (rig_sim, estimator, grip_controller, supervisor as
# separate processes, lock-step), then its figure from the run summary (an earlier run's summary
# is removed first; a figure that cannot be drawn is reported and never changes the run's
# result). Exit 1 is the run ending on the paper's failure condition, a result of the
# experiment, reported as such; a crash or fault (any other code) fails the demo.
DEMO_SUMMARY := runs/stabilize_summary.json
DEMO_FIGURE := runs/stabilize_run.png
demo: $(STAMP)
	@rm -f $(DEMO_SUMMARY); $(BIN)/launch stabilize.yaml summary:=$(DEMO_SUMMARY); code=$$?; \
	if [ -f $(DEMO_SUMMARY) ]; then \
	  $(BIN)/slip run plot $(DEMO_SUMMARY) -o $(DEMO_FIGURE) || echo "demo: no figure (the run's result stands)"; fi; \
	if [ $$code -eq 1 ]; then \
	  echo "demo: the graph ran; the run ended on the paper's failure condition (a result of the experiment on the simulated rig; docs/validation.md gives how often at the fitted point)"; \
	  exit 0; fi; exit $$code

# make test: everything but the tests marked slow (tens of seconds each), two workers (each test
# has its own graph directory and ports, so tests do not see each other); make test-slow: those.
test: $(STAMP)
	$(BIN)/python -m pytest -q -m "not slow" -n 2

# make test-load: `make test`'s selection LOAD_RUNS times (default 3) under `nice -n 10` beside two
# CPU hogs at normal priority (busy Python loops, one per core of the 2-core development machine),
# which it stops at the end; so the tests get less CPU than the hogs. It fails if any run fails.
# Tests wait for events, never for a fixed time, so load only slows them.
LOAD_RUNS ?= 3
test-load: $(STAMP)
	@hogs=""; for i in 1 2; do $(BIN)/python -c 'while True: pass' & hogs="$$hogs $$!"; done; \
	trap 'kill $$hogs' EXIT INT TERM; status=0; \
	for run in $$(seq $(LOAD_RUNS)); do \
	  echo "test-load: run $$run of $(LOAD_RUNS) under nice -n 10 beside two CPU hogs (pids$$hogs)"; \
	  nice -n 10 $(BIN)/python -m pytest -q -m "not slow" -n 2 || status=1; done; \
	exit $$status

test-slow: $(STAMP)
	$(BIN)/python -m pytest -q -m slow

# make reproduce: every result of the paper on the simulated rig (`slip reproduce all`: every
# experiment in dependency order, one progress line each, a final table; docs/ and its measured
# times rewritten; JOINT=1 adds the validation's joint uncertainty set). make reproduce-quick: the
# quick previews (runs/all-quick; no tracked file changes: `slip reproduce all --quick --record-quick-times`
# records their times in docs/).
reproduce: $(STAMP)
	$(BIN)/slip reproduce all $(if $(JOINT),--joint)

reproduce-quick: $(STAMP)
	$(BIN)/slip reproduce all --quick

clean:
	rm -rf $(VENV) .pytest_cache .hypothesis

# Benchmarks print ratios measured side by side in one run; results go to docs/performance.md.
bench: bench-graph bench-cli bench-curve bench-bag bench-sim bench-estimator bench-loop

# with the zenoh reference peer (the [bench] extra) beside the graph and raw pyzmq
bench-graph: $(STAMP)
	$(BIN)/pip install --quiet -e '.[bench]'
	$(BIN)/python bench/bench_graph.py

# start-up of `slip topic --help` and `slip topic list` beside `slip --help` (every module)
bench-cli: $(STAMP)
	$(BIN)/python bench/bench_cli.py

bench-curve: $(STAMP)
	$(BIN)/python bench/bench_curve.py

bench-bag: $(STAMP)
	$(BIN)/python bench/bench_bag.py --dir .

bench-sim: $(STAMP)
	$(BIN)/python bench/bench_sim.py

# slip dataset --from-recordings: one 450-period recording read in log vs file order, converted,
# and imported on one process vs all cores
bench-import: $(STAMP)
	$(BIN)/python bench/bench_import.py

# SVR grid search in process vs a forked pool of 2 (`slip reproduce --jobs`), interleaved
bench-grid: $(STAMP)
	$(BIN)/python bench/bench_grid.py

# the estimation study's pieces (windows, SVR grids) against main, alternating; DATA=runs/data: the full sets
bench-estimation: $(STAMP)
	$(BIN)/python bench/bench_estimation.py $(if $(DATA),--data $(DATA))

bench-estimator: $(STAMP)
	$(BIN)/python bench/bench_estimator.py

bench-loop: $(STAMP)
	$(BIN)/python bench/bench_loop.py

# bench-loop with and without the viewer bridge and a Foxglove client that never reads, alternated
# ROUNDS times; prints the p99 ratio (docs/performance.md, "Live view")
# (VARIANTS: more, e.g. "stalled:idle stalled@main": the package at git revision main)
ROUNDS ?= 5
VARIANTS ?= stalled:idle
bench-loop-viewer: $(STAMP)
	$(BIN)/python bench/bench_loop_viewer.py --rounds $(ROUNDS) --variants $(VARIANTS)

# the viewer bridge's own CPU per lock-step period with a stalled client, in process; AGAINST=REV
# also measures src/ at git revision REV, alternated (docs/performance.md, "Live view")
bench-bridge: $(STAMP)
	$(BIN)/python bench/bench_bridge.py $(if $(AGAINST),--against $(AGAINST))

# the emulated launch (rig:=emulated steps:=20) EMU_RUNS times beside EMU_HOGS busy-loop CPU hogs
# (stopped at the end): the pass count (docs/emulated.md, "Under load"; needs ur-rtde)
EMU_RUNS ?= 10
EMU_HOGS ?= 2
bench-emulated-load: $(STAMP)
	$(BIN)/python bench/bench_emulated_load.py --runs $(EMU_RUNS) --hogs $(EMU_HOGS)
