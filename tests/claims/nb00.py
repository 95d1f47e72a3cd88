"""Notebook 00, the index: every figure and table of the paper mapped to a notebook and a file, every deviation
pointing at a notebook and a file that exist."""

from __future__ import annotations

import re
from pathlib import Path

from . import Tables, claim

NOTEBOOKS = Path(__file__).resolve().parents[2] / "notebooks"
PAPER_ITEMS = [f"Fig {k}" for k in range(1, 18)] + [f"Table {k}" for k in range(1, 5)]
FILE_NAME = re.compile(r"^(fig\d\d|table\d|ext\d\d)_[A-Za-z0-9_]+\.(png|md)$")


def _notebook_exists(number: str) -> bool:
    return any(NOTEBOOKS.glob(f"{number}_*.ipynb"))


def check(t: Tables, size: str) -> None:
    index = t("index_paper_figures_and_tables")
    listed = set(index["paper"])
    for item in PAPER_ITEMS:
        claim(item in listed, "index_paper_figures_and_tables", item, f"{item} of the paper is mapped to a notebook")
    for table in ("index_paper_figures_and_tables", "index_deviations"):
        for r in t(table).itertuples():
            nb, f = f"{int(r.notebook):02d}", r.file
            claim(_notebook_exists(nb), table, f, f"notebook {nb} exists")
            claim(bool(FILE_NAME.match(f)), table, f, "the file is named as figures/ names it (figNN_, tableN_, extNN_)")
            if size == "full":  # the committed figures/ hold every notebook's files
                claim((t.folder / f).exists(), table, f, f"{f} is in figures/")
