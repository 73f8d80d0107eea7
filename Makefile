# Two commands on a fresh machine: `make render` and `make test`.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
export WARP_CACHE_PATH := $(CURDIR)/.cache/warp

.PHONY: render test mutate fuzz-signals bench bench-corpus bench-peers bench-newton bench-docs install clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[test,charts]"
	$(PY) -m pip install --quiet -e ".[ray]" || echo "note: Ray could not be installed here; the Ray batch test will skip"
	$(PY) -m pip install --quiet -e ".[newton]" || echo "note: Newton could not be installed here; the Newton bridge tests will skip"
	touch $(STAMP)

install: $(STAMP)

render: $(STAMP)
	mkdir -p out
	$(PY) -m warprt render scenes/showcase.toml -o out/showcase.png -o out/showcase.exr

# the suite in TEST_WORKERS processes (pytest-xdist): a cold kernel cache compiles on every core;
# tests of one xdist_group run in one process (one compile of what they share)
TEST_WORKERS ?= 2
test: $(STAMP)
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadgroup

# mutation testing (not part of `make test`): one-line mistakes in the physics, each must be
# caught by the tests listed for it in tests/mutations.toml
mutate: $(STAMP)
	$(PY) -m tests.mutate $(MUTATE_ARGS)

# SIGINT and SIGTERM at random moments of real runs (not part of `make test`): every run must end
# in one line with the signal's status, leave nothing behind and lose no finished image
FUZZ_ARGS ?= --trials 100
fuzz-signals: $(STAMP)
	$(PY) -m tests.fuzz_signals $(FUZZ_ARGS)

# speed, accuracy and compile cost, then the corpus side by side with Mitsuba 3 where the `peers`
# extra is installed (without it benchmarks.corpus says so in one line and skips)
bench: $(STAMP)
	$(PY) -m benchmarks.run
	$(PY) -m benchmarks.corpus $(CORPUS_ARGS)

# the corpus alone (31 scenes, training and validation halves; e.g. CORPUS_ARGS="--split train --quick")
bench-corpus: $(STAMP)
	$(PY) -m pip install --quiet -e ".[peers]"
	$(PY) -m benchmarks.corpus $(CORPUS_ARGS)

# warprt against Mitsuba 3 on the six scenes of benchmarks.peers (the optional `peers` extra);
# Mitsuba's fast llvm_ad_rgb variant also needs the LLVM shared library (e.g. apt-get install
# libllvm19), else it falls back to scalar_rgb
bench-peers: $(STAMP)
	$(PY) -m pip install --quiet -e ".[peers]"
	$(PY) -m benchmarks.peers $(PEERS_ARGS)

# warprt against Newton's SensorTiledCamera on Newton's kind of scene (the optional `newton` extra)
bench-newton: $(STAMP)
	$(PY) -m benchmarks.newton_bench $(NEWTON_ARGS)

# docs/benchmarks.md's tables again from the results committed under docs/benchmarks/ (runs no
# benchmark; each benchmark also does this after a full run)
bench-docs: $(STAMP)
	$(PY) -m benchmarks.docs

clean:
	rm -rf out .cache .pytest_cache
