# The two commands of the README:  `make run` (the whole paper)  and  `make test` (the test suite).
# Both create ./.venv and install the tested versions (constraints.txt) into it first.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
CORES ?= 2
# torch comes from PyTorch's CPU-only index (no GPU libraries); `make TORCH_INDEX= install` takes pip's default build
TORCH_INDEX ?= https://download.pytorch.org/whl/cpu

.PHONY: install run workflow test test-fast test-slurm sanitize bench timing report snapshot verdict clean \
	run-depth run-objects run-network run-sample snapshot-depth snapshot-objects snapshot-network snapshot-sample \
	snapshot-all

install: $(VENV)/.installed

# pip upgrades itself only when older than 22 (an editable install from pyproject.toml needs 21.3).
# --no-compile: pip writes no bytecode for every installed file (half of the install's CPU); Python compiles
# the modules a run imports, once, on their first import.
$(VENV)/.installed: pyproject.toml constraints.txt
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -c 'import sys, pip; sys.exit(int(pip.__version__.split(".")[0]) < 22)' \
		|| $(BIN)/python -m pip install --quiet --upgrade pip
	$(if $(TORCH_INDEX),$(BIN)/python -m pip install --quiet --no-compile --no-deps -c constraints.txt --index-url $(TORCH_INDEX) torch)
	$(BIN)/python -m pip install --quiet --no-compile -c constraints.txt -e '.[experiments,workflow,test,baselines]'
	touch $@

# The install and the workflow, timed together (workflow/scripts/timed.py prints wall and CPU time at the end).
run:
	@$(PYTHON) workflow/scripts/timed.py "make run" $(MAKE) --no-print-directory workflow

# PYTHONDONTWRITEBYTECODE= : the jobs write the bytecode of what they import (the install writes none), so only the
# first job to import a module compiles it; where the variable is set, every job would compile everything again.
workflow: install
	PYTHONDONTWRITEBYTECODE= PATH="$(abspath $(BIN)):$$PATH" $(BIN)/snakemake --profile profiles/default --cores $(CORES) $(SNAKEMAKE_ARGS)

# The runs of the opt-in snapshots: config.yaml with the snapshot's overlay merged over it (Tables 5-7 switched on;
# the real sample's own config, which writes to results/apollocar3d-sample/). `PARTS` in workflow/scripts/provenance.py
# names the same files (tests/workflow/test_provenance.py checks it). Each runs what the default run has not run yet.
OVERLAY_depth := profiles/snapshots/depth.yaml
OVERLAY_objects := profiles/snapshots/objects.yaml
OVERLAY_network := profiles/snapshots/network.yaml
OVERLAY_sample := data/apollocar3d-sample/config.yaml
run-depth run-objects run-network run-sample:
	@$(PYTHON) workflow/scripts/timed.py "make $@" $(MAKE) --no-print-directory workflow \
		SNAKEMAKE_ARGS="--configfile $(OVERLAY_$(@:run-%=%))"

# The tests and the library's `>>>` docstring examples (pyproject.toml: testpaths, --doctest-modules).
# The workflow tests run Snakemake in temporary directories: whatever results/ holds, they see none of it.
# On $(CORES) pytest-xdist workers, a test file to a worker (its fixtures, a workflow run among them, are built
# once), the files of the longest fixtures first (tests/conftest.py). Plain `pytest` runs the same in one process.
test: install
	PATH="$(abspath $(BIN)):$$PATH" $(BIN)/pytest -n $(CORES) --dist loadfile --no-loadscope-reorder

# The quick loop while editing the library: every test that runs no workflow, starts no notebook kernel and builds
# no kernel cache (markers `workflow`, `slow`, `slurm`; pyproject.toml). `make test` runs them all.
test-fast: install
	PATH="$(abspath $(BIN)):$$PATH" $(BIN)/pytest -n $(CORES) -m 'not workflow and not slow and not slurm' -q

# The .test config on a one-node SLURM cluster that the test starts and stops (tests/workflow/test_slurm.py):
# needs root and the slurm-wlm and munge packages; about 35 minutes on two cores. `make test` leaves it out.
# One process (no -n): its one cluster and the local run it compares with are built once.
test-slurm: install
	PATH="$(abspath $(BIN)):$$PATH" $(BIN)/pytest -m slurm tests/workflow/test_slurm.py

# The compiled kernel built with AddressSanitizer and UndefinedBehaviorSanitizer (in a cache folder of its own),
# loaded into Python with the ASan runtime preloaded, and the kernel's tests and the property test of its callers
# run against it: any access outside a tensor or any undefined behaviour aborts the run with the sanitizer's report.
SANITIZE_CC ?= gcc -fsanitize=address,undefined -fno-omit-frame-pointer -fno-sanitize-recover=undefined
SANITIZE_CACHE ?= $(or $(TMPDIR),/tmp)/sdm-sanitize-cache
SANITIZE_TESTS ?= tests/mapping/test_native.py tests/mapping/test_kernel_bindings.py \
	tests/mapping/test_kernel_checks.py tests/mapping/test_kernel_properties.py
sanitize: install
	SDM_CACHE_DIR="$(SANITIZE_CACHE)" CC="$(SANITIZE_CC)" LD_PRELOAD="$$(gcc -print-file-name=libasan.so)" \
	ASAN_OPTIONS=detect_leaks=0:halt_on_error=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
	sh -c '$(BIN)/python tests/sanitized_kernel.py && $(BIN)/pytest -p no:cacheprovider --capture=sys -q $(SANITIZE_TESTS)'

# The CPU figures, then the GPU section (benchmarks/speed/bench_gpu.py: it says so and stops where CUDA is missing).
bench: install
	$(BIN)/python benchmarks/speed/bench_sdm.py
	$(BIN)/python benchmarks/speed/bench_gpu.py

# docs/results/timing.md, rewritten whole: `make run`, `make bench` and `make test` run one after another on a fresh
# clone of HEAD (install included), each with its CPU time, wall time and the load average while it ran, then the
# run's CPU and wall time per stage and per job (benchmarks/tools/timing.py; about 30 minutes on 2 cores).
timing:
	$(PYTHON) benchmarks/tools/timing.py

report: install
	PATH="$(abspath $(BIN)):$$PATH" $(BIN)/snakemake --profile profiles/default --report report.html

# After `make run`: results/ -> docs/results/ (the committed snapshot, with its PROVENANCE.json), then the README's
# verdict assembled from every snapshot. After `make run-<name>`: that run's files -> docs/results/<name>/.
snapshot:
	$(PYTHON) workflow/scripts/snapshot.py take
snapshot-depth snapshot-objects snapshot-network snapshot-sample:
	$(PYTHON) workflow/scripts/snapshot.py take --part $(@:snapshot-%=%)
# After `make run` and every `make run-<name>`: all five snapshots taken together, at one commit, one verdict.
snapshot-all:
	$(PYTHON) workflow/scripts/snapshot.py take --part default --part sample --part objects --part network --part depth

# The README's verdict assembled again from the snapshots (no run, no copy).
verdict:
	$(PYTHON) workflow/scripts/snapshot.py verdict

clean:
	rm -rf results benchmarks/calibration report.html .snakemake
