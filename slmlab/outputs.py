"""What a notebook writes, and at which size: figures and tables by their paper name.

Notebooks never build paths themselves: figures and tables go through :func:`savefig` and :func:`savetable`
(in the spirit of ThinkBayes2's ``savefig``), which
write into ``$SLMLAB_FIGURES`` when it is set (``make reproduce`` sets it to ``figures/``; ``make test``
to a temporary folder) and write nothing otherwise, so an interactive session never edits ``figures/``.
"""

from __future__ import annotations

import os
from io import BytesIO
from pathlib import Path

import numpy as np
import pandas as pd

from .io import atomic_write_bytes, atomic_write_text

__all__ = ["REPO_ROOT", "SHARED_DIR", "figures_dir", "notebook_size", "savefig", "savetable", "markdown_caption", "markdown_table",
           "table_digits", "TABLE_DIGITS"]

REPO_ROOT = Path(__file__).resolve().parent.parent
#: ``../shared`` beside the repository; kept for compatibility: real data come from :func:`slmlab.datasets.fetch`
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


def savefig(fig, name: str, *, dpi: int = 110) -> Path | None:
    """Write ``fig`` as ``{name}.png`` into :func:`figures_dir` (if set), byte-stable for the same content:
    Agg renderer, no software version or date in the metadata."""
    out = figures_dir()
    if out is None:
        return None
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


#: significant digits of a computed number in a table: what a fit on simulated or measured data carries, and
#: few enough that a table does not change with the machine (summation order moves the sixth digit)
TABLE_DIGITS = 4


def _is_reference(column: str) -> bool:
    """Columns that hold the paper's own numbers (``paper``, ``paper_std``, ...): kept as reported."""
    return column == "paper" or column.startswith("paper_")


def table_digits(df: pd.DataFrame, digits: int = TABLE_DIGITS) -> pd.DataFrame:
    """The table as it is written: every computed float rounded to ``digits`` significant digits, and exact
    zeros where a value is rounding noise (below 1e-12, or below 1e-9 of its column's largest magnitude);
    the paper's reference columns, integers and text unchanged."""
    out = df.copy()
    for col in out.columns:
        if _is_reference(str(col)) or not pd.api.types.is_float_dtype(out[col]):
            continue
        v = out[col].to_numpy(float, copy=True)
        finite = np.isfinite(v)
        big = np.abs(v[finite]).max() if finite.any() else 0.0
        v[finite & ((np.abs(v) < 1e-12) | (np.abs(v) <= 1e-9 * big))] = 0.0
        nz = finite & (v != 0)
        mag = np.floor(np.log10(np.abs(v[nz])))
        scale = 10.0 ** (digits - 1 - mag)
        v[nz] = np.round(v[nz] * scale) / scale
        out[col] = v
    return out


def savetable(df: pd.DataFrame, name: str, *, caption: str | None = None) -> Path | None:
    """Write a table as ``{name}.csv`` and ``{name}.md`` into :func:`figures_dir` (if set), its numbers to the
    digits they carry (:func:`table_digits`), so that ``make reproduce`` writes the same bytes on any machine.

    ``caption`` (one line: what the table is and which notebook wrote it) is the first line of the ``.md``,
    above the table; the ``.csv`` holds the table only."""
    out = figures_dir()
    if out is None:
        return None
    df = table_digits(df)
    atomic_write_text(out / f"{name}.csv", df.to_csv(index=False, float_format="%.6g", lineterminator="\n"))
    atomic_write_text(out / f"{name}.md", markdown_caption(caption) + markdown_table(df))
    return out / f"{name}.csv"


def markdown_caption(caption: str | None) -> str:
    """The caption line of a table's ``.md``: ``*caption*`` (its whitespace, line breaks included, collapsed to
    single spaces: one line) and a blank line; nothing without a caption."""
    text = " ".join(str(caption or "").split())
    return f"*{text}*\n\n" if text else ""
