"""Where things live, notebook size, and writing figures and tables by their paper name.

Notebooks never build paths themselves: the reference numbers come from :func:`paper_reference`, figures and
tables go through :func:`savefig` and :func:`savetable` (in the spirit of ThinkBayes2's ``savefig``), which
write into ``$SLMLAB_FIGURES`` when it is set (``make reproduce`` sets it to ``figures/``; ``make test``
to a temporary folder) and write nothing otherwise, so an interactive session never edits ``figures/``.
"""

from __future__ import annotations

import json
import os
from functools import lru_cache
from pathlib import Path

import pandas as pd

from .io import atomic_write_bytes, atomic_write_text

__all__ = ["REPO_ROOT", "DATA_DIR", "SHARED_DIR", "figures_dir", "notebook_size", "paper_reference", "savefig",
           "savetable", "markdown_table"]

REPO_ROOT = Path(__file__).resolve().parent.parent
DATA_DIR = REPO_ROOT / "data"
#: ``../shared`` beside the repository (real data, when present)
SHARED_DIR = Path(os.environ.get("SLMLAB_SHARED", REPO_ROOT.parent / "shared"))


def figures_dir() -> Path | None:
    """The folder figures and tables are written to (``$SLMLAB_FIGURES``), or ``None``: do not write."""
    d = os.environ.get("SLMLAB_FIGURES")
    if not d:
        return None
    path = Path(d)
    path.mkdir(parents=True, exist_ok=True)
    return path


def notebook_size() -> str:
    """``'small'`` under ``make test`` (``SLMLAB_SIZE=small``), ``'full'`` otherwise."""
    size = os.environ.get("SLMLAB_SIZE", "full").strip().lower()
    return "small" if size == "small" else "full"


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


def savefig(fig, name: str, *, dpi: int = 110) -> Path | None:
    """Write ``fig`` as ``{name}.png`` into :func:`figures_dir` (if set), byte-stable for the same content:
    Agg renderer, no software version or date in the metadata."""
    out = figures_dir()
    if out is None:
        return None
    from io import BytesIO

    buf = BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, metadata={"Software": None})
    path = out / f"{name}.png"
    atomic_write_bytes(path, buf.getvalue())
    return path


def _fmt(v) -> str:
    if isinstance(v, float):
        if v != v:
            return ""
        return f"{v:.6g}"
    return str(v)


def markdown_table(df: pd.DataFrame) -> str:
    """A GitHub-flavoured Markdown table of ``df`` (index not included), numbers with 6 significant digits."""
    cols = [str(c) for c in df.columns]
    lines = ["| " + " | ".join(cols) + " |", "|" + "|".join("---" for _ in cols) + "|"]
    for row in df.itertuples(index=False):
        lines.append("| " + " | ".join(_fmt(v) for v in row) + " |")
    return "\n".join(lines) + "\n"


def savetable(df: pd.DataFrame, name: str) -> Path | None:
    """Write a table as ``{name}.csv`` and ``{name}.md`` into :func:`figures_dir` (if set)."""
    out = figures_dir()
    if out is None:
        return None
    atomic_write_text(out / f"{name}.csv", df.to_csv(index=False, float_format="%.6g", lineterminator="\n"))
    atomic_write_text(out / f"{name}.md", markdown_table(df))
    return out / f"{name}.csv"
