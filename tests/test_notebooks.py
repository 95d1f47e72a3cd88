"""Every notebook runs top to bottom in a fresh kernel, with the small-size parameter (none left out), and what it
claims holds of the tables it wrote (``tests/claims``)."""

import os
from pathlib import Path

import pytest

import claims
from slmlab.run_notebooks import run_notebook

NOTEBOOKS = sorted((Path(__file__).resolve().parent.parent / "notebooks").glob("*.ipynb"))


def test_there_are_notebooks():
    assert NOTEBOOKS, "no notebook found in notebooks/"


@pytest.mark.notebook
@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_runs(path, tmp_path):
    run_notebook(path, env={"SLMLAB_SIZE": os.environ.get("SLMLAB_SIZE", "small"),
                            "SLMLAB_FIGURES": str(tmp_path / "figures")})
    written = [*(tmp_path / "figures").glob("*.png"), *(tmp_path / "figures").glob("*.csv")]
    assert written, "the notebook wrote no figure and no table"
    claims.check(path.stem[:2], tmp_path / "figures", os.environ.get("SLMLAB_SIZE", "small"))
