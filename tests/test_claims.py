"""The committed figures/ (``make reproduce``, full size) still say what the notebooks claim; and the claims
mechanism itself (``tests/claims``): a claim that holds passes, one that fails names its table and row."""

import sys
import types
from pathlib import Path

import pandas as pd
import pytest

import claims
from claims import Tables, claim

FIGURES = Path(__file__).resolve().parent.parent / "figures"


@pytest.mark.parametrize("number", claims.notebooks_with_claims())
def test_committed_tables_hold_the_notebooks_claims(number):
    claims.check(number, FIGURES, "full")


# ------------------------------------------------------------------------------------------ the mechanism
def _demo_check(t: Tables, size: str) -> None:
    """A notebook's claims as a ``tests/claims/nbNN.py`` writes them."""
    name = "ext99_demo"
    claim(t.value(name, "rms_mm", model="direct") <= 1.2 * t.value(name, "rms_mm", model="floor"), name,
          "model=direct", "the default is within 1.2x the floor")
    limit = 0.01 if size == "full" else 0.02
    claim(t.value(name, "rms_mm", model="paper-m2") < limit, name, "model=paper-m2", f"paper-m2 under {limit} mm")


@pytest.fixture
def demo(tmp_path, monkeypatch):
    """``demo(rows)``: a figures folder holding the table ``ext99_demo`` with these rows, checked by notebook
    99's claims (``_demo_check``) through :func:`claims.check`."""
    monkeypatch.setitem(sys.modules, "claims.nb99", types.SimpleNamespace(check=_demo_check))
    monkeypatch.setattr(claims, "notebooks_with_claims", lambda: ["99"])

    def write(rows):
        pd.DataFrame(rows, columns=["model", "rms_mm"]).to_csv(tmp_path / "ext99_demo.csv", index=False)
        return tmp_path

    return write


def test_a_claim_that_holds_passes(demo):
    claims.check("99", demo([("floor", 0.004), ("direct", 0.0045), ("paper-m2", 0.008)]), "full")


def test_a_claim_that_fails_names_its_table_and_row(demo):
    folder = demo([("floor", 0.004), ("direct", 0.0045), ("paper-m2", 0.015)])
    claims.check("99", folder, "small")  # 0.015 mm holds at small size (limit 0.02) ...
    with pytest.raises(AssertionError) as err:
        claims.check("99", folder, "full")  # ... not at full size (0.01)
    assert str(err.value) == "claim no longer holds: paper-m2 under 0.01 mm (table ext99_demo, row model=paper-m2)"


def test_a_missing_table_or_row_is_named(demo, tmp_path):
    with pytest.raises(AssertionError, match=r"table ext99_demo was not written"):
        claims.check("99", tmp_path, "full")
    with pytest.raises(AssertionError, match=r"table ext99_demo: 0 rows where \{'model': 'direct'\}, expected one"):
        claims.check("99", demo([("floor", 0.004), ("paper-m2", 0.008)]), "full")
    with pytest.raises(AssertionError, match=r"table ext99_demo has no column 'rms_um'"):
        Tables(demo([("floor", 0.004)])).value("ext99_demo", "rms_um", model="floor")


def test_a_row_looked_up_by_hand_that_is_missing_names_the_table(demo, monkeypatch):
    def by_hand(t: Tables, size: str) -> None:
        rms = t("ext99_demo").set_index("model")["rms_mm"]
        claim(rms["soloff"] < 0.01, "ext99_demo", "soloff", "soloff under 0.01 mm")

    monkeypatch.setitem(sys.modules, "claims.nb99", types.SimpleNamespace(check=by_hand))
    folder = demo([("floor", 0.004), ("direct", 0.0045)])
    with pytest.raises(AssertionError, match=r"notebook 99's claims could not be read from table ext99_demo in .*KeyError: 'soloff'"):
        claims.check("99", folder, "full")


def test_a_notebook_without_claims_checks_nothing(tmp_path):
    assert "99" not in claims.notebooks_with_claims()
    claims.check("99", tmp_path, "small")  # no tables there, and no claims module: nothing to hold
