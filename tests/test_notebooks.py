"""Every notebook runs top to bottom in a fresh kernel, with the small-size parameter (none left out), and what it
claims holds of the tables it wrote (``tests/claims``).

The notebooks are ``slow`` but for two cheap ones that keep the quick tier (``pytest -m "not slow"``) running the
notebook machinery, the plots, the tables and a notebook's claims after its small run."""

import json
import os
import warnings
from pathlib import Path

import pytest

import claims
from slmlab.run_notebooks import expected_seconds, longest_first, main, run_notebook

NOTEBOOKS = sorted((Path(__file__).resolve().parent.parent / "notebooks").glob("*.ipynb"))
QUICK = ("01_system_and_virtual_microscope", "04_initial_vision_model")  # each a few seconds at small size


def test_there_are_notebooks():
    assert NOTEBOOKS, "no notebook found in notebooks/"


def test_the_quick_notebooks_are_there():
    assert set(QUICK) <= {p.stem for p in NOTEBOOKS}, f"QUICK names a notebook that is not in notebooks/: {QUICK}"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebooks_are_committed_valid_and_without_outputs(path):
    import nbformat   # (the notebook tools: loaded by the tests that need them)
    with warnings.catch_warnings():
        warnings.simplefilter("error")   # nbformat's MissingIDFieldWarning, say: valid today, an error tomorrow
        nb = nbformat.reads(path.read_text(encoding="utf-8"), as_version=4)
        nbformat.validate(nb)
    ids = [c.get("id") for c in nb.cells]
    assert all(ids) and len(set(ids)) == len(ids), f"{path.name}: every cell needs its own id"
    assert not any(c.get("outputs") or c.get("execution_count") for c in nb.cells if c.cell_type == "code"), \
        f"{path.name} is committed with outputs"


def test_notebooks_start_longest_first_and_their_durations_are_recorded(tmp_path):
    names = [Path(n) for n in ("a.ipynb", "b.ipynb", "c.ipynb", "d.ipynb")]
    order = longest_first(names, {"a.ipynb": 3.0, "b.ipynb": 40.0, "c.ipynb": 12.0})
    assert [p.name for p in order] == ["d.ipynb", "b.ipynb", "c.ipynb", "a.ipynb"]  # never timed, then longest
    nb = tmp_path / "tiny.ipynb"
    nb.write_text(json.dumps({"cells": [{"cell_type": "code", "id": "c1", "metadata": {}, "execution_count": None,
                                         "outputs": [], "source": "x = 1"}],
                              "metadata": {}, "nbformat": 4, "nbformat_minor": 5}))
    record = tmp_path / "durations.json"
    record.write_text("not json")  # a damaged record is no record: name order, then rewritten
    assert main(["--durations", str(record), "--timing", str(tmp_path / "t"), str(nb)]) == 0
    assert set(json.loads(record.read_text())) == {"tiny.ipynb"}
    assert float((tmp_path / "t").read_text()) >= json.loads(record.read_text())["tiny.ipynb"] - 0.05


def test_a_first_run_starts_the_notebooks_their_metadata_expects_to_be_longest():
    """A fresh clone has no record: without the hint the longest notebook (11) started last, after the others in
    name order, and make reproduce took 553 s; the same durations longest first schedule to 443 s."""
    hints = expected_seconds(NOTEBOOKS)
    longest = max(hints, key=hints.get)
    assert longest == "11_any_rig.ipynb"
    assert longest_first(NOTEBOOKS, hints)[0].name == longest
    assert longest_first(NOTEBOOKS, {**hints, "00_index.ipynb": 1e4})[0].name == "00_index.ipynb"  # a record wins


@pytest.mark.notebook
@pytest.mark.parametrize("path", [pytest.param(p, id=p.stem, marks=() if p.stem in QUICK else pytest.mark.slow)
                                  for p in NOTEBOOKS])
def test_notebook_runs(path, tmp_path):
    run_notebook(path, env={"SLMLAB_SIZE": os.environ.get("SLMLAB_SIZE", "small"),
                            "SLMLAB_FIGURES": str(tmp_path / "figures")})
    written = [*(tmp_path / "figures").glob("*.png"), *(tmp_path / "figures").glob("*.csv")]
    assert written, "the notebook wrote no figure and no table"
    claims.check(path.stem[:2], tmp_path / "figures", os.environ.get("SLMLAB_SIZE", "small"))
