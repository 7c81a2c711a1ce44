# The two commands of the README: `make demo` and `make test`. Both create the virtual
# environment when it is missing and install volucal with everything it needs.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.volucal-installed

.PHONY: demo test gui package bench lint clean

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[gui,test,dev]'
	@touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/volucal demo --out demo-output

# pytest's exit code 5 (no test collected) is a failure: a test run must run tests.
test: $(STAMP)
	@QT_QPA_PLATFORM=offscreen PYQTGRAPH_QT_LIB=PySide6 $(PY) -m pytest $(PYTEST_ARGS); \
	status=$$?; if [ $$status -eq 5 ]; then echo "make test: no tests were collected" >&2; exit 1; fi; \
	exit $$status

gui: $(STAMP)
	$(VENV)/bin/volucal gui

# One-folder desktop build (PyInstaller), then its smoke test: --help, demo, report, gui.
package: $(STAMP)
	$(PY) -m PyInstaller --noconfirm --clean --distpath packaging/dist --workpath packaging/build packaging/volucal.spec
	QT_QPA_PLATFORM=offscreen $(PY) packaging/smoke_test.py packaging/dist/volucal

bench: $(STAMP)
	for b in benchmarks/bench_*.py; do $(PY) $$b || exit 1; done

lint: $(STAMP)
	$(VENV)/bin/ruff check .

clean:
	rm -rf $(VENV) demo-output build dist *.egg-info
