# Every target uses the project's own virtual environment in .venv.
PYTHON ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
BASE := $(VENV)/.installed-base
STAMP := $(VENV)/.installed
WARMUP_RECORD := $(VENV)/warm-up
DEMO_OUT := out/demo
HALL := datasets/hall
CI_OUT := out/ci

.PHONY: setup demo ci-example test kernels browser fuzz bench bench-real bench-sweep bench-slam bench-peers calibrate figures lint hall readme-real clean

# Setup installs segloc (editable), compiles the kernels a first run uses, then adds the extras
# of the tests, lint and benchmarks (dev), of --method icp|correlative (peers) and of segloc
# sweep (sweep); make demo needs the first two steps only ($(BASE)). The packages that build
# segloc (pyproject.toml's [build-system] requires, BUILD_REQUIRES) go into the venv with pip,
# and both installs build in it (--no-build-isolation) instead of each setting up a build
# environment of its own (3–4 s each). pip installs quietly
# without compiling the modules' bytecode (--no-compile), which compileall then does on every
# core, segloc_cli's own included and the installed packages' own test suites left out, as
# nothing imports them (COMPILE_BYTECODE: pip compiles one module at a time, over half of its
# install time).
# The bytecode is not left to be written on first import: where PYTHONDONTWRITEBYTECODE is
# set, as in many container images, nothing would write it, and every process would compile
# each module it imports from source again (about 3 s of a segloc localize's 4.5 s). setuptools'
# notice that the install is an editable one (which pip passes on as a warning) is filtered
# out, its other warnings are not. The warm-up compiles the kernels of make demo
# and of a first default localize into numba's cache, saying how many and showing its
# progress, so that no first run waits for them; the other options' kernels (--global,
# --seen-through drop) compile on their first use, which says so. A failure there only costs
# that wait; tests/test_warmup.py catches it, from the record the warm-up keeps of what it
# compiled and said ($(WARMUP_RECORD)), so that the suite need not compile it all again.
PIP_INSTALL := PYTHONWARNINGS='ignore:Editable installation:UserWarning' $(BIN)/python -m pip install --quiet --no-compile --no-build-isolation
BUILD_REQUIRES = $$($(BIN)/python -c 'import tomllib; print(*tomllib.load(open("pyproject.toml", "rb"))["build-system"]["requires"])')
COMPILE_BYTECODE := $(BIN)/python -m compileall -q -j 0 -x 'site-packages/.+/tests?/' $(VENV)/lib segloc_cli >/dev/null || \
	echo "warning: some modules' bytecode was not compiled ahead; Python compiles them when it imports them" >&2
setup: $(STAMP)

$(BASE): pyproject.toml
	@command -v $(PYTHON) >/dev/null 2>&1 || { echo "error: $(PYTHON) not found; install Python 3.11 or run 'make PYTHON=python3 ...'" >&2; exit 2; }
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip $(BUILD_REQUIRES)
	$(PIP_INSTALL) -e .
	$(COMPILE_BYTECODE)
	$(BIN)/python -m segloc_cli.runs.warmup --record $(WARMUP_RECORD) || echo "warning: warm-up failed" >&2
	@touch $(BASE)

$(STAMP): $(BASE)
	$(PIP_INSTALL) -e '.[dev,peers,sweep]'
	$(COMPILE_BYTECODE)
	@touch $(STAMP)

# Build the hall's map from its mapping run, localize the 10 test scans (none of them in the
# map) from the paper's initial errors and print Table 1; fail above the paper's 1 cm / 0.2°.
demo: $(BASE)
	@mkdir -p $(DEMO_OUT)
	$(BIN)/segloc map build $(HALL)/mapping/log.mcap --survey $(HALL)/mapping/survey.csv --out $(DEMO_OUT)/map.json --force
	$(BIN)/segloc localize $(HALL)/log.mcap --map $(DEMO_OUT)/map.json --out $(DEMO_OUT)/estimates.csv --force
	$(BIN)/segloc evaluate $(DEMO_OUT)/estimates.csv --survey $(HALL)/survey.csv --fail-above-cm 1 --fail-above-deg 0.2

# Two ROS 2 bags of AMCL's /amcl_pose, simulated over the hall's surveyed poses with known
# errors: a main branch's run and a pull request's 4 cm worse, for README's "Score my
# localizer in CI" (examples/amcl_bags.py; each run replaces the bags of the last).
ci-example: $(STAMP)
	$(BIN)/python examples/amcl_bags.py --survey $(HALL)/survey.csv --out $(CI_OUT) --force

# Every kernel in numba's cache, those of the options setup leaves to their first use included
# (--global, --seen-through drop...), so that the processes of the tests and benchmarks load
# them instead of each compiling its own; a few seconds when they are all cached already.
kernels: $(STAMP)
	$(BIN)/python -m segloc_cli.runs.warmup --all --record $(WARMUP_RECORD)-all || echo "warning: warm-up failed" >&2

# On one worker more than there are cores (pytest-xdist), once every kernel is compiled, the 30
# slowest tests listed at the end: a fifth of the suite's time goes on waiting (for serial
# lines, signals, processes starting and stopping), which the extra worker fills with tests.
# Tests marked with an xdist_group run on one worker (--dist loadgroup): those sharing
# kernels that only they compile. The HTML report's test opens it in Debian's headless
# Chromium; as root (CI) it is installed when missing, elsewhere that one test is skipped and
# says why. That install (mostly download, about half a minute) runs beside the setup and the
# kernels' compiling rather than after them.
CORES := import os; print(len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count())
TEST_WORKERS ?= $$(( $$($(BIN)/python -c '$(CORES)') + 1 ))
test:
	@$(MAKE) --no-print-directory -j2 kernels browser
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadgroup --durations=30

browser:
	@if ! command -v chromium >/dev/null 2>&1 && [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
		echo "installing Debian's chromium for the HTML report's test"; \
		{ apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null; } || \
		echo "warning: chromium not installed; the HTML report's browser test is skipped" >&2; \
	fi

# Every reader's fuzz suite at FUZZ_EXAMPLES cases per test (make test runs a few dozen), and
# every kernel compiled with numba's bounds checks on hostile scans and maps (make test skips
# it: the compiling alone takes over a minute); hypothesis prints how many cases each test ran
# and how long they took.
FUZZ_EXAMPLES ?= 10000
fuzz: $(STAMP)
	SEGLOC_FUZZ_EXAMPLES=$(FUZZ_EXAMPLES) $(BIN)/python -m pytest -q -p no:cacheprovider \
		--hypothesis-show-statistics tests/test_fuzz_*.py

# pytest-benchmark over benchmarks/: time per pose, accuracy, and the speed figures of
# test_bench_speed.py (the real logs from DATASETS, defined below; missing ones are skipped).
bench: kernels
	SEGLOC_DATASETS=$(DATASETS) $(BIN)/python -m pytest benchmarks -q --benchmark-only -s --benchmark-columns=median,min,max,rounds --benchmark-sort=name --benchmark-warmup=on

# Real public logs (not shipped): both protocols on intel, aces, fr079, mit-csail.
DATASETS ?= ../shared/datasets
bench-real: kernels
	$(BIN)/python benchmarks/real_logs.py --datasets $(DATASETS) --out benchmarks/results-real.md

# Every page of README.md and docs/ that reads the real logs, each top to bottom in a folder
# beside them (linked as ../shared/datasets, the path the pages' commands read them from),
# those blocks included; make test runs the others. tests/test_readme_commands.py says how
# each block is checked.
readme-real: kernels
	@if [ ! -d "$(DATASETS)" ]; then \
		echo "readme-real: skipped: no public logs at $(DATASETS) (give DATASETS=FOLDER holding intel/, mit-csail/)"; \
	else \
		set -x; SEGLOC_README_DATASETS=$(abspath $(DATASETS)) $(BIN)/python -m pytest -q -n 0 \
			tests/test_readme_commands.py -k top_to_bottom; \
	fi

# segloc sweep on the real logs' held-out scans (3 search windows × 2 seeds), on 1 and 2 workers.
bench-sweep: kernels
	$(BIN)/python benchmarks/sweep_real.py --datasets $(DATASETS) --out benchmarks/results-sweep.md

# map build with no survey (segment SLAM) on each raw log, its poses scored on every relation
# beside Cartographer's and Graph Mapping's published rows: benchmarks/results-slam.md.
bench-slam: kernels
	$(BIN)/python benchmarks/slam_real.py --datasets $(DATASETS) --out benchmarks/results-slam.md

# Fit the verdict's confidence model on simulated rooms and the real logs' calibration splits
# (scans the benchmarks do not score): segloc_cli/method/confidence_model.json and
# benchmarks/results-calibration.md.
calibrate: kernels
	$(BIN)/python benchmarks/calibrate.py --datasets $(DATASETS)

# Every method (two-stage, ICP, correlative) on the same seeded trials per initial-error bin,
# on the hall and the real logs: benchmarks/results-peers.md and benchmarks/peers-trials.csv.
bench-peers: kernels
	$(BIN)/python benchmarks/peers.py --datasets $(DATASETS)

# The hall's figures into benchmarks/figures/hall/, and success against initial error
# from benchmarks/peers-trials.csv (written by bench-peers).
figures: $(STAMP)
	$(BIN)/python benchmarks/figures.py

# ruff (rules and format) over the code, and mypy over the package ([tool.mypy] in pyproject.toml).
lint: $(STAMP)
	$(BIN)/ruff check segloc_cli tests benchmarks examples
	$(BIN)/ruff format --check segloc_cli tests benchmarks examples
	$(BIN)/mypy

# Regenerate the shipped hall dataset (see datasets/hall/README.md).
hall: $(BASE)
	bash $(HALL)/regenerate.sh

clean:
	rm -rf out .pytest_cache .benchmarks
