"""The numbers the paper reports (Tables 1–4, Figs 12, 16, 17, §6's headline), kept in
``data/paper_reference.json`` so that every notebook and table can set ours beside them."""

from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path

__all__ = ["DATA_DIR", "paper_reference"]

#: the repository's ``data/`` folder (small reference files shipped with the code)
DATA_DIR = Path(__file__).resolve().parents[2] / "data"


@lru_cache(maxsize=1)
def _reference() -> dict:
    return json.loads((DATA_DIR / "paper_reference.json").read_text(encoding="utf-8"))


def paper_reference(*keys: str):
    """Numbers the paper reports (``data/paper_reference.json``), optionally a nested entry.

    >>> paper_reference("table4", "thetaX_deg", "mean")
    3.0347
    """
    d = _reference()
    for k in keys:
        d = d[k]
    return d
