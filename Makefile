# slmlab: two commands for a machine that has only Python.
#   make reproduce   set up .venv, run every notebook (full size), rewrite figures/
#   make test        set up .venv, run the unit tests and every notebook (small size)
#   make lab         JupyterLab on the notebooks
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: reproduce test lab bench clean venv

venv: $(STAMP)

$(STAMP): environment.txt pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -r environment.txt
	$(PY) -m pip install --quiet --no-deps -e .
	$(PY) -m ipykernel install --sys-prefix --name python3 >/dev/null
	touch $(STAMP)

reproduce: $(STAMP)
	SLMLAB_SIZE=full SLMLAB_FIGURES=$(CURDIR)/figures $(PY) -m slmlab.notebooks --timing .reproduce_seconds --jobs 2 notebooks/*.ipynb
	$(PY) -m slmlab bench --markdown figures/table6_speed.md --reproduce-seconds-file .reproduce_seconds

test: $(STAMP)
	SLMLAB_SIZE=small $(PY) -m pytest -q

lab: $(STAMP)
	$(VENV)/bin/jupyter lab --notebook-dir=notebooks

bench: $(STAMP)
	$(PY) -m slmlab bench

clean:
	rm -rf $(VENV) .pytest_cache
