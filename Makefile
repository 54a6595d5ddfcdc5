# servotune: the two commands are `make demo` and `make test`.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test test-slow test-wheel test-study lint format bench clean fuzz lock

# Installs the exact versions of requirements.lock (hashes checked), then servotune itself without
# dependencies: every machine runs the same numpy, scipy, casadi, numba... (README, "Reproducible
# results"). `make UNLOCKED=1 ...` installs from pyproject.toml's ranges instead (the newest
# releases a library user would get); `make lock` refreshes the lock.
LOCK := requirements.lock
UNLOCKED ?=

$(STAMP): pyproject.toml $(LOCK)
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
ifeq ($(UNLOCKED),)
	$(BIN)/python -m pip install --quiet --require-hashes -r $(LOCK)
	# setuptools' notice that an editable install imports from this folder is what we want:
	# silenced by its text (any other build warning still shows)
	PYTHONWARNINGS="ignore:Editable installation" $(BIN)/python -m pip install --quiet --no-deps --no-build-isolation -e .
else
	PYTHONWARNINGS="ignore:Editable installation" $(BIN)/python -m pip install --quiet -e ".[dev]"
endif
	$(BIN)/python -m ipykernel install --sys-prefix --name python3 >/dev/null
	# numba's kernels compiled once, with progress (about 2 minutes on 2 cores; later runs load them)
	$(BIN)/servotune warmup
	touch $(STAMP)

# Refresh requirements.lock: the newest releases within pyproject.toml's ranges (runtime and dev),
# every file's hash, for CPython 3.11 on x86-64 Linux. Review the diff, run `make test`, commit.
lock: $(STAMP)
	$(BIN)/python -m pip install --quiet "uv>=0.5"
	$(BIN)/uv pip compile pyproject.toml --extra dev --generate-hashes --upgrade \
		--python-version 3.11 --python-platform x86_64-manylinux_2_28 -o $(LOCK)

demo: $(STAMP)
	$(BIN)/servotune demo plants/pc-dual-servo.toml --out reports

lint: $(STAMP)
	$(BIN)/ruff check servotune tests bench
	$(BIN)/ruff format --check servotune tests bench

format: $(STAMP)
	$(BIN)/ruff format servotune tests bench
	$(BIN)/ruff check --fix servotune tests bench

# One BLAS thread per process while testing: two pytest workers already use both cores, and
# OpenBLAS's own threads, left spinning after scipy's expm, starved the numpy work after it
# (tests/identify/test_modes.py 46–138 s threaded against 12–17 s on one thread).
test test-slow test-wheel test-study: export OPENBLAS_NUM_THREADS = 1

# both cores (pytest-xdist); a file's tests stay on one worker, so module fixtures run once.
# The kernels are compiled first, once, if an edit of servotune's sources made them stale
# (otherwise the first tests would each compile what they use). PYTEST_ARGS adds options
# (e.g. make test PYTEST_ARGS="--durations=30").
test: lint
	$(BIN)/servotune warmup
	$(BIN)/python -m pytest -m "not slow and not wheel and not study" -n 2 --dist loadfile $(PYTEST_ARGS)

# A pip user's first hour (tests/test_wheel.py): the built wheel in a fresh venv outside the
# repository runs the README's chain from an empty directory (about 4 minutes: numba compiles
# the installed package's kernels afresh). .ci/run runs it after make test.
test-wheel: $(STAMP)
	$(BIN)/python -m pytest -m wheel

# Studies in real HAL that hold its one session for minutes (docs/decisions.md#8-test-time:
# marker `study`): the live autotune repeated over five noise seeds (about 2.5 minutes), and
# the live autotune loading the verified runtime component, kept and rolled back (about 1.5).
# .ci/run runs them after make test.
test-study: $(STAMP)
	$(BIN)/python -m pytest -m study

# The big statistical runs (docs/decisions.md#8-test-time: marker `slow`, not part of
# `make test`), e.g. the identifier's coverage over 250 closed-loop logs (tests/identify).
test-slow: $(STAMP)
	$(BIN)/python -m pytest -m slow

# Fuzz the file readers (tests/io/test_fuzz_readers.py) with the hypothesis profile "fuzz": rounds
# of FUZZ_EXAMPLES random inputs per test (36 tests; 2000 examples: a round of about 5 minutes
# on 2 cores) until FUZZ_MINUTES have passed, so 15 to 20 minutes by default; stops at the first
# failing round. Not part of `make test` (which runs the same tests with the short deterministic
# "ci" profile, about 10 s).
FUZZ_MINUTES ?= 15
FUZZ_EXAMPLES ?= 2000
fuzz: $(STAMP)
	@end=$$(( $$(date +%s) + $(FUZZ_MINUTES) * 60 )); round=0; \
	while [ $$(date +%s) -lt $$end ]; do \
		round=$$((round + 1)); echo "make fuzz: round $$round"; \
		HYPOTHESIS_PROFILE=fuzz FUZZ_EXAMPLES=$(FUZZ_EXAMPLES) $(BIN)/python -m pytest -q \
			-m fuzz tests/io/test_fuzz_readers.py --hypothesis-show-statistics || exit 1; \
	done; echo "make fuzz: $$round rounds, no failure"

bench: $(STAMP)
	$(BIN)/python bench/bench.py --out reports/bench.json

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache build *.egg-info
	find . -name __pycache__ -type d -prune -exec rm -rf {} +
