# Set-up and entry points. Needs only Python 3.11 on the machine. The system parts
# the tests use (PortAudio, espeak-ng, Chromium, the AVR toolchain, simavr) are
# provisioned by `make test` without root into .deps/ (plumbing/provision.py: apt
# download-only + dpkg-deb -x, else PyPI wheels; system copies are used where
# present); `make system-deps` (root) installs them system-wide instead.
# HFAM_DEPS=provision ignores system copies, HFAM_MISSING_DEPS=skip turns a
# missing part's test failures into skips (see plumbing/sysdeps.py).
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
# byte-code of the packages only the tests, the analysis and pip itself import: compiled by `make test`
# and `make bench`, not by `make demo` (which never imports them; ~6 s of a fresh clone's first demo), nor
# before the tests' numba warm-up starts. The second line: the test extra's own libraries (a third of the
# byte-code the venv's first compile made)
COMPILED := $(VENV)/.compiled
LATER  := /site-packages/(pandas|statsmodels|patsy|pyarrow|playwright|_pytest|pytest|pluggy|pygments|narwhals|pip|setuptools|pkg_resources|$\
	sklearn|xarray|pydantic|pydantic_core|seaborn|joblib|pingouin|forcedimension_core|xdist|pylsl|psignifit|execnet|tabulate|cloudpickle|json_tricks|questplus)/
# the third-party packages' own test suites (a third to a half of numpy's, scipy's, numba's and matplotlib's
# files; ~3 s of the first compile on 2 cores): nothing here imports them
THEIRTESTS := /site-packages/.*/tests/

.PHONY: demo test bench venv deps system-deps clean gallery artefacts jitwarm0 jitwarm1

PYTHON_OK = @test -n "$(PYTHON)" && $(PYTHON) -c "import sys; sys.exit(sys.version_info < (3, 11))" || { echo "error: Python >= 3.11 not found (set PYTHON=/path/to/python3.11)"; exit 1; }

$(STAMP): pyproject.toml
	$(PYTHON_OK)
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	@# wheels only (no surprise source builds), installed by uv (from PyPI: the same releases pip picks, in ~6 s
	@# against pip's ~34 s of CPU on a 2-core machine, which unpacks and resolves in one Python process); where
	@# uv cannot be had or cannot reach the index (a lab's own pip mirror, no network), pip installs instead.
	@# Neither byte-compiles (pip's own compiling is serial): compileall does it on every core instead (~6 s
	@# on 2 cores, then ~6 s more for $(COMPILED)). It cannot be left to first use: where
	@# PYTHONDONTWRITEBYTECODE is set (as on this project's CI machines) nothing is ever written, and every
	@# process would recompile scipy, pandas and matplotlib (~3 s per `devices identify`, per demo worker)
	{ $(PY) -m pip install --quiet uv && $(VENV)/bin/uv pip install --quiet --python $(PY) --only-binary=:all: -e '.[test]'; } \
	    || { echo "note: uv could not install the packages; pip installs them (slower)"; \
	         $(PY) -c "import pip, sys; sys.exit(tuple(map(int, pip.__version__.split('.')[:2])) < (22, 0))" \
	             || $(PY) -m pip install --quiet --upgrade pip; \
	         $(PY) -m pip install --quiet --only-binary=:all: --no-compile -e '.[test]'; }
	$(PY) -m compileall -q -j 0 -x '$(LATER)|$(THEIRTESTS)' $$($(PY) -c "import sysconfig; print(sysconfig.get_path('purelib'))") \
	    plumbing psychophysics analysis devices renderer stimuli study benchmarks figstyle > /dev/null
	touch $(STAMP)

$(COMPILED): $(STAMP)
	$(PY) -m compileall -q -j 0 -x '$(THEIRTESTS)' $$($(PY) -c "import sysconfig; print(sysconfig.get_path('purelib'))") > /dev/null
	@# the tests too: each xdist worker imports all of them, and so do the processes they start
	$(PY) -m compileall -q -j 0 tests > /dev/null
	@# and pytest's own rewritten test modules, which no worker writes where PYTHONDONTWRITEBYTECODE is set
	@# (each would rewrite every module: 5.5 s of CPU per worker; tests/support/rewrite.py)
	$(PY) -m tests.support.rewrite > /dev/null
	touch $(COMPILED)

venv: $(STAMP)

demo: $(STAMP)
	@# the README's demo, repeatable: it replaces its own out/demo (and says so); `python -m renderer demo`
	@# itself refuses an --out that holds earlier results unless --force
	$(PY) -m renderer demo --device sim:onedof --force

# on TEST_WORKERS processes (pytest-xdist; auto: up to two per core, as the running processes and memory
# allow): modules are the units of work, costly ones first, the numba cache filled once while the workers
# start (tests/support/parallel.py); TEST_WORKERS=0 runs in one process
TEST_WORKERS ?= auto
test:
	@# the venv and the system parts are independent (the provisioning needs only the standard library): on a
	@# fresh clone they are made side by side, the parts' download and unpacking beside pip's install, and
	@# numba's cache of the project's kernels beside the byte-code (~30 s of CPU that the tests' workers
	@# would otherwise wait for after collecting)
	@$(MAKE) --no-print-directory -j 5 --output-sync=target $(COMPILED) deps jitwarm0 jitwarm1
	$(PY) -m pytest -q -n $(TEST_WORKERS)

# numba's on-disk cache of the kernels the tests run, in two halves side by side (tests/support/jitwarm.py);
# a few milliseconds when it is filled. With the tests' settings (no ahead-of-time build, one BLAS thread). A
# failure only costs time: each test's process then compiles what it calls
jitwarm0 jitwarm1: $(STAMP)
	@HFAM_SIM_AOT=off OPENBLAS_NUM_THREADS=1 $(PY) -m tests.support.jitwarm --part $(subst jitwarm,,$@) --if-needed \
	    || echo "warning: numba warm-up part $(subst jitwarm,,$@) failed; the tests compile their kernels themselves"

# once (stamp .deps/stamp.json); afterwards a check of a few milliseconds. Run by the Python that makes the
# venv (it needs only the standard library), so it does not wait for the venv
deps:
	$(PYTHON_OK)
	@$(PYTHON) -m plumbing.provision

bench: $(STAMP) $(COMPILED)
	$(PY) -m benchmarks

# every shipped artefact derived from the sim, rebuilt and stamped (plumbing/artefacts.py): the default HFAM
# library, then the docs gallery (a simulated 16-subject study's report and the sim demo) and the README's
# figures; tests/plumbing/test_artefacts.py fails when one no longer matches the code that made it. About 5 minutes.
artefacts: $(STAMP) $(COMPILED)
	$(PY) -m plumbing.artefacts rebuild

# the gallery alone (docs/gallery/, docs/img/), stamped
gallery: $(STAMP) $(COMPILED)
	$(PY) -m plumbing.artefacts rebuild gallery

# Debian packages: PortAudio for sounddevice, espeak-ng for the study's spoken cues,
# Chromium for the browser tests, the AVR toolchain to build the reference firmware.
system-deps:
	apt-get update -qq
	DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libportaudio2 espeak-ng chromium gcc-avr binutils-avr avr-libc \
	    simavr libsimavr2 libsimavr-dev libsimavrparts1 gcc libc6-dev make

clean:
	rm -rf $(VENV) build *.egg-info .deps
