# mlsim: `make demo` and `make test` on a fresh machine. Every install step lives here so that CI
# (`.ci/run` -> `make test`) on a clean checkout needs nothing else.
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
# torch is pinned: `pip install torch==2.13.0` takes the machine's local CPU build in seconds, while an
# unpinned torch would pull gigabytes of CUDA packages.
TORCH := torch==2.13.0
# --no-compile, then compileall on every core: pip byte-compiles what it installs on one core (84 s of a fresh
# install on a 2-vCPU EPYC, 157 s in all), compileall -j 0 the same files in 54 s
PIP := $(PY) -m pip --disable-pip-version-check -q
PIP_INSTALL := $(PIP) install --no-compile
PYTEST_ARGS ?=
# the suite on two processes (pytest-xdist), a test file per process: most tests are one thread of
# Python or scipy, and two processes take 1.8 cores where one took 1.4 (661 -> 524 s on 2 cores).
# `make test PYTEST_PROCS=0` runs it in one process. --warm-kernels compiles the numba kernels once, two processes
# at once, before the workers start (tests/warm_kernels.py): on a fresh clone each worker compiled what the other had
# not cached yet (the Cosserat Newton 45 s, the contact's ADMM 40 s).
PYTEST_PROCS ?= 2
# the slowest tests listed at the end of every run (CI's log too): what to make smaller when the suite nears
# its 15 minutes on 2 cores
PYTEST_DURATIONS ?= 30

.PHONY: demo test test-slow bench docs llvm venv clean

demo: $(STAMP)
	$(VENV)/bin/mlsim run scenes/mavig_default.toml --out out/demo

test: $(STAMP)
	$(PY) -m pytest -n $(PYTEST_PROCS) --dist loadfile --warm-kernels --durations=$(PYTEST_DURATIONS) $(PYTEST_ARGS)
	$(MAKE) --no-print-directory docs

# the documentation site into site/ (a warning fails it; about 15 s): docs/, mkdocs.yml, and the
# pages generated from the code (docs/hooks.py -> mlsim.docgen)
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(PY) -m mkdocs build --strict --quiet

test-slow: $(STAMP)
	$(PY) -m pytest -m slow $(PYTEST_ARGS)

# every benchmark but the slow ones (mlsim.docgen.SLOW_BENCHMARKS, each with its reason), which it lists
bench: $(STAMP)
	@for f in $$($(PY) -c "from mlsim.docgen import fast_benchmarks; print(*fast_benchmarks())"); do \
		echo "== benchmarks/$$f"; $(PY) benchmarks/$$f || exit 1; done
	@$(PY) -c "from mlsim.docgen import SLOW_BENCHMARKS as S; print('not run (slow; run each by name):'); print(*(f'  benchmarks/{k}: {v}' for k, v in S.items()), sep='\n')"

venv: $(STAMP)

$(STAMP): pyproject.toml | llvm
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PIP_INSTALL) --upgrade pip setuptools wheel 2>&1 | grep -v "is ignored" || true
	$(PIP_INSTALL) "$(TORCH)" 2>&1 | grep -v "is ignored" || true
	$(PIP_INSTALL) -e ".[test,ray,docs]" 2>&1 | grep -v "is ignored" || true
	@# some packages ship files that are not Python 3 (templates, tests): pip skips them silently, so does this
	$(PY) -m compileall -q -j 0 "$$($(PY) -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')" >/dev/null 2>&1 || true
	$(PY) -c "import torch, mitsuba, pytetwild, trimesh, manifold3d, meshio, pydantic, colour, cv2, kornia, skfem, zarr, ray, threadpoolctl, numba, xdist, mkdocs, material, mkdocstrings_handlers.python, pyarrow, pandas; assert torch.__version__.startswith('2.13.0'), torch.__version__"
	touch $(STAMP)

# Mitsuba's CPU (llvm_*) variants need libLLVM 17 or newer: 14-16 are too old or crash inside the
# path tracer ("Cannot select ... fminimum"). Install it when we can (root), else say what to do.
LLVM_OK = ldconfig -p 2>/dev/null | grep -qE 'libLLVM(-|\.so\.)(1[7-9]|[2-9][0-9])'
llvm:
	@if [ -n "$$DRJIT_LIBLLVM_PATH" ] || $(LLVM_OK); then exit 0; fi; \
	if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
		echo "libLLVM >= 17 not found: installing libllvm19 (Mitsuba's CPU variants need it)"; \
		(apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libllvm19 >/dev/null) \
		  || { echo "error: 'apt-get install -y libllvm19' failed; install libLLVM 17+ by hand or set DRJIT_LIBLLVM_PATH"; exit 1; }; \
		$(LLVM_OK) || { echo "error: libllvm19 installed but not visible to ldconfig; set DRJIT_LIBLLVM_PATH=/path/to/libLLVM.so.19"; exit 1; }; \
	else \
		echo "error: Mitsuba's CPU variants need libLLVM 17 or newer and none was found."; \
		echo "       Install it as root: 'apt-get install -y libllvm19' (Debian/Ubuntu),"; \
		echo "       or point DRJIT_LIBLLVM_PATH at an existing libLLVM.so (17+)."; \
		exit 1; \
	fi

clean:
	rm -rf $(VENV) out site .pytest_cache
