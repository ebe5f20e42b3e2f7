# The two commands a new user needs: `make demo` and `make test`. Both create .venv and install
# everything from this repository's own files; nothing is installed by hand.
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-$(shell cat pyproject.toml | cksum | cut -d' ' -f1)

.PHONY: demo test accuracy install browser compose proto lint bench clean rewritten-tests

# Bytecode is written at each module's first import, not by pip for every file of every dependency
# at install: the system and its tests import about a fifth of their 11,000 files, and compiling
# them all took 26 of the install's 65 s on two cores. So make's commands write it whatever
# PYTHONDONTWRITEBYTECODE says (where that is set, nothing would ever be compiled, and each process
# would compile what it imports again), and the install imports every module of ours once
# (BYTECODE, below), so that a command started by hand where it is set finds them compiled too.
unexport PYTHONDONTWRITEBYTECODE

$(STAMP): pyproject.toml
	test -x $(PY) || python3 -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q --no-compile -e '.[dev,vision,plots,foxglove]'
	rm -f $(VENV)/.installed-*
	touch $@

# Fusion's compiled kernels (the tracking filter's and `tiplog fusion attitude`'s) into numba's
# cache at install, not at the first start or run, where they take 40-90 s on two cores
# (services/fusion/live/warmup.py). numba keys its cache on each kernel file's modification time;
# this target re-runs when a file of the filter's core or the attitude filter changes.
# The tracking filter's and the attitude filter's are two processes, so that `make -j2` compiles
# them side by side.
KERNELS := $(VENV)/.kernels-ready
KERNELS_FUSION := $(VENV)/.kernels-fusion
KERNELS_ATTITUDE := $(VENV)/.kernels-attitude
$(KERNELS_FUSION): $(STAMP) $(wildcard services/fusion/eskf/*.py services/fusion/eskf/kernels/*.py services/fusion/eskf/models/*.py)
	$(PY) -m services.fusion.live.warmup --only fusion
	touch $@
$(KERNELS_ATTITUDE): $(STAMP) services/fusion/attitude/filter.py services/fusion/attitude/offline.py
	$(PY) -m services.fusion.live.warmup --only attitude
	touch $@
$(KERNELS): $(KERNELS_FUSION) $(KERNELS_ATTITUDE)
	touch $@

# The bytecode of every module the system imports, written once the dependencies are installed
# (pip compiles none of them: above); also a check that every module of ours imports.
BYTECODE := $(VENV)/.bytecode-ready
$(BYTECODE): $(STAMP)
	$(PY) scripts/import_all.py
	touch $@

install: $(STAMP) $(KERNELS) $(BYTECODE)

# Debian's Chromium for the browser tests (never a downloaded browser build).
browser:
	bash scripts/install-debian.sh /usr/bin/chromium chromium "the browser tests"

# Debian's docker-compose, to check compose.yaml in the tests (no container engine needed).
compose:
	bash scripts/install-debian.sh docker-compose docker-compose "the compose check"

# The demo's calibration, made as a user makes one before a session (docs/calibration.md): a fit
# block on the bench, then `tiplog calibrate block`. Without it fusion would take the bench's
# as-calibrated constants, which carry the paper's hand-eye error; the demo's seed draws its camera
# rotation 0.69 deg off, and every tangent plane then disagrees with the filter (docs/fusion-live.md).
# About 10 s, once.
DEMO_CAL := build/demo/calibration.yaml
$(DEMO_CAL): $(STAMP) $(wildcard services/bench/*.py services/bench/sensors/*.py services/bench/robot/*.py tiplog/calibration/*.py tiplog/calibration/fits/*.py)
	mkdir -p $(dir $@)
	$(VENV)/bin/tiplog sim generate --scenario fit --seed 1 --out $(dir $@)fit.mcap --force --quiet
	$(VENV)/bin/tiplog calibrate block $(dir $@)fit.mcap --out $@ --force > $(dir $@)calibrate.log
	@echo "demo calibration: $@ (the block's figures: $(dir $@)calibrate.log)"

demo: $(STAMP) $(KERNELS) $(BYTECODE) $(DEMO_CAL)
	$(VENV)/bin/tiplog up -c config/demo.yaml --calibration $(DEMO_CAL)

# The TypeScript MCAP reader (@mcap/core) for the recorder's interoperability test; pinned by
# its package-lock.json. Without npm the test skips and says why.
MCAP_NODE := tests/services/recorder/mcap_node
$(MCAP_NODE)/node_modules/.installed: $(MCAP_NODE)/package-lock.json
	if command -v npm >/dev/null; then cd $(MCAP_NODE) && npm ci --no-audit --no-fund && touch node_modules/.installed; \
	else echo "npm not found: the TypeScript MCAP reader test will be skipped"; fi

# The suite on TEST_WORKERS processes (pytest-xdist). Most tests wait on subprocesses, the bus and
# sleeps more than they compute, hence more workers than a two-core machine has cores. loadgroup:
# the tests that start a whole system run on one worker in turn (WHOLE_SYSTEM in
# tests/conftest.py); the few that assert a wall-clock deadline, and the demo watched in the browser
# (which alone keeps both cores busy), run alone afterwards (marked `realtime`).
# `python -m pytest -q` still runs the whole suite in one process.
TEST_WORKERS ?= 4
# The files that hold a realtime test: the second run imports those alone (collecting the whole
# suite again to pick them out takes 10 s).
REALTIME_FILES = $(shell grep -rl 'mark\.realtime' tests --include='test_*.py')
test: $(STAMP) browser compose $(MCAP_NODE)/node_modules/.installed
	$(MAKE) --no-print-directory -j2 $(KERNELS) $(BYTECODE) rewritten-tests
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadgroup -m "not realtime"
	$(PY) -m pytest -q -m realtime $(REALTIME_FILES)

# pytest's rewritten test modules (its assertion rewriting) into their __pycache__ once, on the
# core the kernels' compiler leaves free, with the bytecode of everything the tests import:
# otherwise each of the workers, starting together, rewrites every test file (12 of its 18 s of
# collection) and compiles the same modules.
rewritten-tests: $(STAMP)
	@out=$$($(PY) -m pytest -q --collect-only -p no:cacheprovider 2>&1) \
		|| { echo "$$out" | tail -40; exit 1; }

# The long accuracy checks against the bench's truth (benchmarks/accuracy_checks: each generates
# minutes of bench sessions), apart from `make test`.
accuracy: $(STAMP) $(KERNELS)
	$(PY) -m pytest -q -n $(TEST_WORKERS) benchmarks/accuracy_checks

# Regenerate tiplog/v1 from proto/ (tests fail when the committed code differs).
proto: $(STAMP)
	$(PY) -m grpc_tools.protoc -I proto --python_out=. --pyi_out=. proto/tiplog/v1/*.proto

lint: $(STAMP)
	$(VENV)/bin/ruff check tiplog services tests benchmarks

bench: $(STAMP)
	$(PY) -m benchmarks

clean:
	rm -rf $(VENV) .pytest_cache
