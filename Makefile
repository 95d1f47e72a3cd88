# slmlab: two commands for a machine that has only Python.
#   make reproduce   set up .venv, fetch the datasets, run every notebook (full size), rewrite figures/
#   make data        fetch the third-party datasets into the cache (SHA-256 checked); see 'python -m slmlab data list'
#   make test        set up .venv, run the unit tests and every notebook (small size), property tests at 40
#                    examples (the same every run), on every core; then the browser test alone
#   make test-thorough  the same with 300 new examples per property test
#   make lab         JupyterLab on the notebooks
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: reproduce test test-thorough lab bench clean venv data

venv: $(STAMP)

$(STAMP): environment.txt pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -r environment.txt
	$(PY) -m pip install --quiet --no-deps -e .
	$(PY) -m ipykernel install --sys-prefix --name python3 >/dev/null
	touch $(STAMP)

data: $(STAMP)
	$(PY) -m slmlab data fetch

# the datasets first: one missing fails here, in one line with its remedy, before any notebook runs;
# the notebooks write into a fresh folder; only when all succeed does it replace figures/ (no stale files,
# and a failed run leaves figures/ as it was)
reproduce: $(STAMP)
	$(PY) -m slmlab data fetch
	rm -rf .figures.new && mkdir .figures.new
	SLMLAB_SIZE=full SLMLAB_FIGURES=$(CURDIR)/.figures.new $(PY) -m slmlab.run_notebooks --timing .reproduce_seconds --durations .notebook_seconds.json --jobs 2 notebooks/*.ipynb
	find figures -maxdepth 1 -type f ! -name table6_speed.md -delete
	mv .figures.new/* figures/ && rmdir .figures.new
	$(PY) -m slmlab bench --markdown figures/table6_speed.md --reproduce-seconds-file .reproduce_seconds

# the tests: on TEST_JOBS workers (pytest-xdist; auto = one per core), a group of tests that share an expensive
# fixture on one worker (xdist_group marks); the browser test afterwards on its own (JupyterLab and Chromium
# beside a notebook kernel would only slow both down)
TEST_JOBS ?= auto
PYTEST := SLMLAB_SIZE=small $(PY) -m pytest -q

test: $(STAMP)
	$(PYTEST) -n $(TEST_JOBS) --dist loadgroup -m "not browser"
	$(PYTEST) -m browser

test-thorough: $(STAMP)
	SLMLAB_HYPOTHESIS_PROFILE=thorough $(MAKE) --no-print-directory test

lab: $(STAMP)
	$(VENV)/bin/jupyter lab --notebook-dir=notebooks

bench: $(STAMP)
	$(PY) -m slmlab bench

clean:
	rm -rf $(VENV) .pytest_cache
