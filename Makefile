# The two fresh-machine commands (see README): `make demo` and `make test`.
# Each creates .venv and installs what it needs on first use.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python

.PHONY: demo test lint

$(VENV)/.installed: pyproject.toml
	@# pyrealsense2 needs Debian's libusb-1.0-0; install it when we can (root with apt).
	@if ! ldconfig -p | grep -q 'libusb-1.0.so.0'; then \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	    apt-get update -qq && apt-get install -y -qq --no-install-recommends libusb-1.0-0; \
	  else echo "note: libusb-1.0-0 is missing: the RealSense tests will be skipped"; fi; fi
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[dev]'
	touch $@

# The recorder never overwrites a file, so the demo clears its own previous output first.
demo: $(VENV)/.installed
	rm -f out.mcap out-[0-9][0-9][0-9].mcap
	$(VENV)/bin/lpc up --source sim --duration 10 --record out.mcap
	$(VENV)/bin/lpc info out.mcap

lint: $(VENV)/.installed
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

# pytest exits 5 when it collects nothing: say so plainly instead of failing obscurely.
test: lint
	$(PY) -m pytest; rc=$$?; \
	if [ $$rc -eq 5 ]; then echo "pytest collected no tests"; exit 0; fi; exit $$rc
