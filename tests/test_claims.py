"""The committed figures/ (``make reproduce``, full size) still say what the notebooks claim."""

from pathlib import Path

import pytest

import claims

FIGURES = Path(__file__).resolve().parent.parent / "figures"


@pytest.mark.parametrize("number", claims.notebooks_with_claims())
def test_committed_tables_hold_the_notebooks_claims(number):
    claims.check(number, FIGURES, "full")
