# Set-up and entry points. Needs only Python 3.11 on the machine; the Debian
# packages the study audio, browser tests and firmware build use are installed
# by `make system-deps` (root; .ci/run calls it).
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: demo test bench venv system-deps clean gallery

$(STAMP): pyproject.toml
	@test -n "$(PYTHON)" && $(PYTHON) -c "import sys; sys.exit(sys.version_info < (3, 11))" || { echo "error: Python >= 3.11 not found (set PYTHON=/path/to/python3.11)"; exit 1; }
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	touch $(STAMP)

venv: $(STAMP)

demo: $(STAMP)
	$(PY) -m renderer demo --device sim

test: $(STAMP)
	@$(PY) -c "import sounddevice" 2>/dev/null || echo "note: PortAudio (libportaudio2) missing: masking-audio tests will fail; run 'make system-deps' as root"
	$(PY) -m pytest -q

bench: $(STAMP)
	$(PY) -m benchmarks

# the figure gallery of the docs (docs/gallery/): a synthetic study's report and the sim demo
gallery: $(STAMP)
	$(PY) -m figstyle.gallery --out docs/gallery

# Debian packages: PortAudio for sounddevice, espeak-ng for the study's spoken cues,
# Chromium for the browser tests, the AVR toolchain to build the reference firmware.
system-deps:
	apt-get update -qq
	DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libportaudio2 espeak-ng chromium chromium-driver gcc-avr binutils-avr avr-libc

clean:
	rm -rf $(VENV) build *.egg-info
