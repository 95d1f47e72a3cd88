"""What each notebook claims, held against the tables it writes.

One module per notebook, ``nbNN.py`` (``NN`` the notebook's number), with a function
``check(tables: Tables, size: str) -> None`` that asserts every headline claim of that notebook's narrative
from its tables, through :meth:`Tables.row` / :meth:`Tables.value` / :func:`claim`, so that a claim that stops
holding fails with the table and the row named. ``size`` is ``"small"`` (the notebook just ran under
``make test``) or ``"full"`` (the committed ``figures/`` of ``make reproduce``); a claim whose number depends
on the size asserts what is true at that size.

A row or a column looked up by hand (``t(name).set_index(...).loc[...]``) that is not there fails as a claim
too, naming the table read last. The checks run twice: after each notebook's small run
(``tests/test_notebooks.py``) and on the committed ``figures/`` (``tests/test_claims.py``); they read only, so
they run on any number of pytest-xdist workers.
"""

from __future__ import annotations

import importlib
from pathlib import Path

import pandas as pd

__all__ = ["Tables", "claim", "check", "notebooks_with_claims"]


class Tables:
    """The tables a notebook wrote (``NAME.csv`` in ``folder``), read as pandas DataFrames."""

    def __init__(self, folder: str | Path):
        self.folder = Path(folder)
        self.last = None  # the table read last: named when a claim fails other than through claim()

    def __call__(self, name: str) -> pd.DataFrame:
        self.last = name
        path = self.folder / f"{name}.csv"
        assert path.exists(), f"table {name} was not written (looked for {path})"
        return pd.read_csv(path)

    def row(self, name: str, **where) -> pd.Series:
        """The one row of table ``name`` whose columns equal ``where`` (e.g. ``model="paper-m2"``)."""
        df = self(name)
        sel = pd.Series(True, index=df.index)
        for col, val in where.items():
            assert col in df.columns, f"table {name} has no column {col!r} (columns: {', '.join(df.columns)})"
            sel &= df[col] == val
        assert sel.sum() == 1, f"table {name}: {int(sel.sum())} rows where {where}, expected one"
        return df[sel].iloc[0]

    def value(self, name: str, column: str, **where) -> float:
        """One cell of table ``name``: column ``column`` of the row selected by ``where``."""
        r = self.row(name, **where)
        assert column in r.index, f"table {name} has no column {column!r}"
        return r[column]


def claim(ok: bool, table: str, row: str, what: str) -> None:
    """Assert a claim, naming the table, the row and what was claimed when it fails."""
    assert ok, f"claim no longer holds: {what} (table {table}, row {row})"


def notebooks_with_claims() -> list[str]:
    """The notebook numbers (``"01"``, ...) that have a claims module."""
    return sorted(p.stem[2:] for p in Path(__file__).parent.glob("nb[0-9][0-9].py"))


def check(number: str, folder: str | Path, size: str) -> None:
    """Run notebook ``number``'s claims on the tables in ``folder`` (written at ``size``)."""
    if number not in notebooks_with_claims():
        return
    tables = Tables(folder)
    try:
        importlib.import_module(f"claims.nb{number}").check(tables, size)
    except (KeyError, IndexError, ValueError, TypeError) as exc:  # a row or column looked up by hand is missing
        raise AssertionError(f"notebook {number}'s claims could not be read from table {tables.last} in {folder}: "
                             f"{type(exc).__name__}: {exc}") from exc
