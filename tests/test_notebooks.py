"""Every notebook runs top to bottom in a fresh kernel, with the small-size parameter (none left out), and what it
claims holds of the tables it wrote (``tests/claims``).

The notebooks are ``slow`` but for two cheap ones that keep the quick tier (``pytest -m "not slow"``) running the
notebook machinery, the plots, the tables and a notebook's claims after its small run."""

import os
from pathlib import Path

import pytest

import claims
from slmlab.run_notebooks import run_notebook

NOTEBOOKS = sorted((Path(__file__).resolve().parent.parent / "notebooks").glob("*.ipynb"))
QUICK = ("01_system_and_virtual_microscope", "04_initial_vision_model")  # each a few seconds at small size


def test_there_are_notebooks():
    assert NOTEBOOKS, "no notebook found in notebooks/"


def test_the_quick_notebooks_are_there():
    assert set(QUICK) <= {p.stem for p in NOTEBOOKS}, f"QUICK names a notebook that is not in notebooks/: {QUICK}"


@pytest.mark.notebook
@pytest.mark.parametrize("path", [pytest.param(p, id=p.stem, marks=() if p.stem in QUICK else pytest.mark.slow)
                                  for p in NOTEBOOKS])
def test_notebook_runs(path, tmp_path):
    run_notebook(path, env={"SLMLAB_SIZE": os.environ.get("SLMLAB_SIZE", "small"),
                            "SLMLAB_FIGURES": str(tmp_path / "figures")})
    written = [*(tmp_path / "figures").glob("*.png"), *(tmp_path / "figures").glob("*.csv")]
    assert written, "the notebook wrote no figure and no table"
    claims.check(path.stem[:2], tmp_path / "figures", os.environ.get("SLMLAB_SIZE", "small"))
