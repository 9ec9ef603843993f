# One-command entry points for a fresh Debian machine (run as root, or with
# the packages already installed): `make demo`, `make test`.
SHELL := /bin/bash
VENV ?= .venv
PY := $(VENV)/bin/python
DEBS := pocl-opencl-icd ocl-icd-opencl-dev opencl-headers cmake ninja-build g++ pkg-config python3-venv libllvm19 libstb-dev libopenexr-dev clang-15
STAMP_DEPS := $(VENV)/.deps-installed
STAMP_PKG := $(VENV)/.penumbra-installed
# Fuzzing the Python loaders (make fuzz-python; tests/fuzz/): atheris, libFuzzer for Python.
FUZZ_PIP := "atheris>=2.3"
FUZZ_SECONDS ?= 10
# The documentation site (make docs): Sphinx with Markdown pages through myst-parser.
DOCS_PIP := "sphinx>=7" "myst-parser>=2"
# Mitsuba 3's LLVM variant (cross-validation, benchmarks) loads Debian's libLLVM 19.
export DRJIT_LIBLLVM_PATH ?= /usr/lib/x86_64-linux-gnu/libLLVM.so.19.1
SOURCES := $(shell find capi kernels python cmake -type f) CMakeLists.txt pyproject.toml

.PHONY: all deps venv install demo test test-c test-python fuzz fuzz-c fuzz-python docs bench bench-roofline bench-fiv-scaling bench-heightfield-speed bench-heightfield-dynamic bench-rays clean

all: install

# Debian packages, only those missing (needs root for apt-get).
deps:
	@missing=$$(for p in $(DEBS); do dpkg-query -W -f='$${Status}\n' $$p 2>/dev/null | grep -q 'install ok installed' || echo $$p; done); \
	if [ -n "$$missing" ]; then \
	  echo "installing Debian packages:" $$missing; \
	  if [ "$$(id -u)" != 0 ]; then SUDO=sudo; fi; \
	  $$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq $$missing; \
	fi

$(STAMP_DEPS): pyproject.toml | deps
	python3 -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q "scikit-build-core>=0.10" "numpy>=1.24" "pyopencl>=2023.1" "OpenEXR>=3.2" \
	  "libigl>=2.5" "pillow>=10" "tqdm>=4.60" "pytest>=7" "mitsuba>=3.5" "embreex>=2.17" "matplotlib>=3.7" \
	  $(DOCS_PIP) "dask[distributed]>=2024.1" $(FUZZ_PIP)
	touch $@

venv: $(STAMP_DEPS)

$(STAMP_PKG): $(STAMP_DEPS) $(SOURCES)
	$(PY) -m pip install -q --no-build-isolation --no-deps .
	touch $@

install: $(STAMP_PKG)

demo: install
	$(VENV)/bin/penumbra demo --out out/demo

# C library with warnings as errors, under AddressSanitizer + UBSan, through ctest.
test-c: deps
	cmake -S . -B build/asan -G Ninja -DPENUMBRA_SANITIZE=ON -DPENUMBRA_WERROR=ON -DCMAKE_BUILD_TYPE=Debug > /dev/null
	cmake --build build/asan
	cd build/asan && ctest --output-on-failure

test-python: install
	PYOPENCL_CTX=0 $(PY) -m pytest -q tests

# libFuzzer targets of the C entry points that parse bytes or strings
# (tests/fuzz, docs/reliability.md "Fuzzing (C)"): built with clang-15 under
# ASan + UBSan, each run for FUZZ_SECONDS from its committed seed corpus
# (tests/fuzz/corpus/<target>); new inputs go to build/fuzz/corpus/<target>,
# crashes to build/fuzz/crash-<target>-*. Prints executions and coverage.
FUZZ_TARGETS := fuzz_fiv_header fuzz_fiv_load fuzz_config fuzz_params
FUZZ_CC ?= clang-15
fuzz-c: deps
	CC=$(FUZZ_CC) cmake -S . -B build/fuzz -G Ninja -DPENUMBRA_FUZZ=ON -DBUILD_SHARED_LIBS=OFF -DPENUMBRA_TESTS=OFF \
	  -DPENUMBRA_WERROR=ON -DCMAKE_BUILD_TYPE=Debug > /dev/null
	cmake --build build/fuzz --target $(FUZZ_TARGETS)
	@for t in $(FUZZ_TARGETS); do \
	  mkdir -p build/fuzz/corpus/$$t; \
	  LSAN_OPTIONS=suppressions=$(CURDIR)/tests/c/lsan.supp:print_suppressions=0 FUZZ_ARTIFACT_PREFIX=build/fuzz/crash-$$t- \
	    build/fuzz/tests/fuzz/$$t -max_total_time=$(FUZZ_SECONDS) -max_len=4096 -rss_limit_mb=4096 -print_final_stats=1 \
	    -artifact_prefix=build/fuzz/crash-$$t- build/fuzz/corpus/$$t tests/fuzz/corpus/$$t > build/fuzz/$$t.log 2>&1 \
	    || { tail -40 build/fuzz/$$t.log; echo "fuzz-c: $$t failed (input in build/fuzz/crash-$$t-*)"; exit 1; }; \
	  echo "$$t: $$(grep -E '^#[0-9]+.*DONE' build/fuzz/$$t.log | tail -1)"; \
	done

# The whole of `make test` must stay under 15 minutes on 2 cores: the fuzz
# step adds one clang build of the library (~2 min) and FUZZ_SECONDS (10 s)
# per target (4 targets).
test: test-c fuzz-c test-python

# The full soak (docs/reliability.md): 10,000 frames of a dynamic scene in
# one process, in Python (RSS and heap bounds; 1.5-5 min at 64x48 on 2 shared
# cores) and in C under ASan/LSan (~3 min; SOAK_C_FRAMES=N runs another count).
# make test runs the short versions (pytest tests/test_soak.py, ctest soak).
SOAK_FRAMES ?= 10000
SOAK_C_FRAMES ?= $(SOAK_FRAMES)
.PHONY: soak soak-python soak-c
soak: soak-python soak-c

soak-python: install
	mkdir -p build
	PYOPENCL_CTX=0 $(PY) tests/soak/soak.py --frames $(SOAK_FRAMES) --progress --json build/soak-python.json

soak-c: deps
	cmake -S . -B build/asan -G Ninja -DPENUMBRA_SANITIZE=ON -DPENUMBRA_WERROR=ON -DCMAKE_BUILD_TYPE=Debug > /dev/null
	cmake --build build/asan --target test_soak
	LSAN_OPTIONS=suppressions=$(CURDIR)/tests/c/lsan.supp:print_suppressions=0 build/asan/tests/c/test_soak $(SOAK_C_FRAMES)

# The documentation site, warnings as errors: docs/*.md, the Python API from the
# docstrings, the gallery (docs/sphinx/; images made by docs/sphinx/make_gallery.py).
# A venv made before Sphinx joined the pip line gets it here.
docs: install
	@$(PY) -c "import sphinx, myst_parser" 2>/dev/null || $(PY) -m pip install -q $(DOCS_PIP)
	$(PY) -m sphinx -E -W --keep-going -q -b html -c docs/sphinx docs build/docs/html
	@echo "documentation in build/docs/html/sphinx/index.html"

# Speed against error on the standard scenes (bench/scenes; test data from $PENUMBRA_DATA, default ../shared/data):
# reports in bench/results/<scene>/, and the table in README.md refreshed.
# BENCH_WORKERS=N runs the scenes on a local Dask cluster of N workers, one scene per
# worker (docs/farm.md): ratios stay within one run, but workers share the cores.
BENCH_SCENES := $(wildcard bench/scenes/*.toml)
BENCH_WORKERS ?=
bench: install bench-roofline
	@if [ -n "$(BENCH_WORKERS)" ]; then \
	  $(VENV)/bin/penumbra bench $(BENCH_SCENES) --out bench/results --readme README.md --workers $(BENCH_WORKERS); \
	else for s in $(BENCH_SCENES); do \
	  $(VENV)/bin/penumbra bench $$s --out bench/results/$$(basename $$s .toml) --readme README.md || exit 1; \
	done; fi
	$(MAKE) bench-heightfield-speed bench-fiv-scaling bench-rays

# The heightfield passes against a pinned commit (HF_BASELINE, built once under build/bench-baseline/),
# in alternating subprocess rounds on the terrain scenes: bench/results/heightfield_speed/.
HF_BASELINE ?= 9b774a1
bench-heightfield-speed: install
	$(PY) bench/heightfield_speed.py --baseline $(HF_BASELINE)

# Dynamic terrain: what a 5 % crater can change (numpy model) and the partial update against a
# full frame in one process (257²): bench/results/heightfield_dynamic/.
bench-heightfield-dynamic: install
	$(PY) bench/heightfield_dynamic.py all --size 257 --rounds 3

# The machine's peak FMA FLOP/s and memory bandwidth under the OpenCL runtime in use, the
# roofline docs/performance.md measures every kernel against: bench/results/roofline/.
bench-roofline: install
	@mkdir -p bench/results/roofline
	$(PY) bench/roofline.py --json bench/results/roofline/roofline.json

# Ray throughput of the 4-wide and binary BVH walks against Embree on the same rays, in
# interleaved rounds (docs/performance.md "Ray casting"): bench/results/rays/.
bench-rays: install
	@mkdir -p bench/results/rays
	$(PY) bench/ray_profile.py --rounds 11 --json bench/results/rays/ray_profile.json | tee bench/results/rays/ray_profile.txt

# fiv's per-frame cost against the number of occluders (1, 10, 30, 60 bunnies, 512x512),
# next to the paper's Table 2: bench/results/fiv_scaling/.
bench-fiv-scaling: install
	$(VENV)/bin/penumbra bench --fiv-scaling --out bench/results/fiv_scaling

# Each Python loader's fuzz target (EXR, HDR, NPY, PNG, OBJ, PLY, OFF, STL, scene TOML) for
# FUZZ_SECONDS seconds from its seed corpus (tests/fuzz/corpus/); new inputs and findings go to
# build/fuzz-python/<target>/. A venv made before atheris joined the pip line gets it here.
fuzz-python: install
	@$(PY) -c "import atheris" 2>/dev/null || $(PY) -m pip install -q $(FUZZ_PIP)
	$(PY) tests/fuzz/fuzz_loaders.py --seconds $(FUZZ_SECONDS) --out build/fuzz-python

# Every fuzz target, C and Python, for FUZZ_SECONDS each (e.g. make fuzz FUZZ_SECONDS=600).
fuzz: fuzz-c fuzz-python

clean:
	rm -rf build out
