# Two commands on a fresh machine: `make demo` and `make test`. Both build .venv when it is missing.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# The filters' loops compiled ahead of time (georef/aot.py). `georef build-kernels` alone decides what is out
# of date, from a hash of the sources each kernel imports (found by reading them) and of the Python, numba, llvmlite
# and numpy versions; with nothing to compile it takes about a second, so it runs every time (FORCE) rather than
# trusting a list of files here that could drift from the imports.
KERNELS := $(VENV)/.kernels

.PHONY: demo test lint bench clean browser geoid tools FORCE

# pip byte-compiles the dependencies on one core (50 of the 80 s the install takes on a 2-core machine, measured
# 2026-11-26); compileall does it on every core (29 s). Skipping it is slower still where PYTHONDONTWRITEBYTECODE
# is set: every process then compiles what it imports, every time.
$(STAMP): pyproject.toml
	test -d $(VENV) || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet --no-compile -e '.[test]'
	$(BIN)/python -m compileall -q -j 0 $(VENV)/lib >/dev/null
	touch $(STAMP)

$(KERNELS): $(STAMP) FORCE
	$(BIN)/georef build-kernels
	touch $(KERNELS)

FORCE:

demo: $(KERNELS)
	$(BIN)/georef process data/POS.txt data/Kamera.txt --config data/flight.toml -o out/eo.csv
	$(BIN)/georef evaluate out/eo.csv data/truth.csv

# The report test renders in Debian's headless Chromium; install it when missing (root, as on CI).
browser:
	@command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1 || \
	  { (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium chromium-driver) \
	    >/dev/null 2>&1 || echo "could not install chromium: the report test will say so"; }

# Orthometric heights and KML need PROJ's EGM96 grid (Debian proj-data: /usr/share/proj/egm96_15.gtx); PROJ's
# network is not used. The height tests fail, naming the grid, when it is missing.
geoid:
	@test -f /usr/share/proj/egm96_15.gtx || test -f /usr/share/proj/us_nga_egm96_15.tif || \
	  { (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq proj-data) \
	    >/dev/null 2>&1 || echo "could not install proj-data: the height and KML tests will fail, naming the grid"; }

# The hand-off tests read the image copies back with exiftool (Debian libimage-exiftool-perl), the consumers'
# own reader of the tags. The committed .pos fixtures were made with Debian rtklib's rnx2rtkp
# (tests/data/rtklib/README.md); only their rebuild needs it.
tools:
	@command -v exiftool >/dev/null 2>&1 || \
	  { (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libimage-exiftool-perl) \
	    >/dev/null 2>&1 || echo "could not install exiftool: the image hand-off tests will fail, naming it"; }

test: $(KERNELS) browser geoid tools
	$(BIN)/ruff check georef cli tests benchmarks examples
	$(BIN)/python -m pytest -q -n auto --dist worksteal --durations=15

bench: $(KERNELS)
	$(BIN)/python benchmarks/bench_pipeline.py

clean:
	rm -rf $(VENV) out .pytest_cache georef/_aot_*
