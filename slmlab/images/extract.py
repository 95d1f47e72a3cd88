"""Dot extraction from one image: find the dots of a calibration plate, refine their centres to sub-pixel
accuracy and number them on the plate's lattice (the command line's ``extract``; the paper's §3 input).

For one image (8 or 16 bit, any format OpenCV reads, dark dots on a bright plate or bright dots on black):
polarity, blobs and markers and sub-pixel centres (:mod:`slmlab.images.dots`), then the lattice and the
plate's ``[row, col]`` (:mod:`slmlab.images.lattice`). The result is an :class:`ImageDots` table; a whole
set of images is extracted by :mod:`slmlab.images.imageset`.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from ..errors import SlmlabError
from .dots import METHODS, dot_polarity, find_blobs, read_image, refine_ellipse, refine_moments
from .lattice import (PlateLattice, absolute_indices, donut_indices, index_lattice, lattice_residual_px,
                      origin_frame, plate_lattice)

__all__ = ["IMAGE_NAME", "AUTO_ELLIPSE_RATIO", "ImageDots", "empty_dots_table", "extract_image", "choose_method",
           "extract_stereo_pairs"]


IMAGE_NAME = re.compile(r"^(?P<sequence>.+)_(?P<position>\d{3,})_(?P<side>[lr])\.png$")


#: ``method="auto"`` takes the ellipse estimator only where its centres lie this much more smoothly on the
#: lattice than the moments' (real, textured dots); otherwise moments, the more accurate on uniform dots
AUTO_ELLIPSE_RATIO = 0.7


def choose_method(img: np.ndarray, rows=None, cols=None, **kw) -> tuple[str, dict]:
    """The centre estimator for a plate's images (``method="auto"``): both estimators on one image, compared
    by :func:`lattice_residual_px`; ``ellipse`` only if it is below :data:`AUTO_ELLIPSE_RATIO` times the
    moments' residual. Returns the method and the residual [px] of each."""
    res = {m: lattice_residual_px(extract_image(img, rows, cols, method=m, **kw).table) for m in METHODS}
    ok = all(np.isfinite(v) for v in res.values())
    return ("ellipse" if ok and res["ellipse"] < AUTO_ELLIPSE_RATIO * res["moments"] else "moments"), res


@dataclass
class ImageDots:
    """Dots found in one image.

    Attributes
    ----------
    table
        one row per dot on the lattice: ``i1, i2`` (image-lattice coordinates, :class:`PlateLattice`),
        ``w1, w2`` [px], ``marker`` (a donut), ``level`` (0, or 1 on a two-level plate's second level), and,
        once anchored, ``row, col``; with an origin-anchored frame also ``xu, yu`` (plate-frame coordinates
        in plate units from the origin dot).
    frame
        ``'plate'`` (``row, col`` are the plate's own indices), ``'origin'`` (``row = −yu``,
        ``col = −xu`` up to one shift for the whole set: :mod:`slmlab.images.imageset` numbers them), or ``None``
        (not anchored: ``note`` says why).
    how
        how the indices were anchored (for the notes).
    """

    table: pd.DataFrame
    found: int
    rejected: int
    spurious: int
    note: str = ""
    lattice: PlateLattice | None = field(default=None, repr=False)
    frame: str | None = None
    how: str = ""
    markers: list = field(default_factory=list)
    dark: bool = True


_EMPTY = {"i1": int, "i2": int, "w1": float, "w2": float, "marker": bool, "level": int, "row": int, "col": int}


def empty_dots_table() -> pd.DataFrame:
    """An :class:`ImageDots` table without rows, with its columns and types."""
    return pd.DataFrame({k: pd.Series(dtype=t) for k, t in _EMPTY.items()})


def extract_image(img: np.ndarray, rows: int | None = None, cols: int | None = None, *, method: str = "moments",
                  dark: bool | None = True, dot_diameter_px: float | None = None, anchor: str = "auto",
                  marker_origin: tuple[int, int] = (2, 2), two_level: bool = False) -> ImageDots:
    """Find, refine and index the dots of a plate in one image (any bit depth).

    Parameters
    ----------
    img
        grey-level image (``uint8``, ``uint16`` or ``float32``).
    rows, cols
        the plate's size, or ``None`` for a plate larger than the field (then markers anchor the indices).
    method
        ``'moments'`` (default) or ``'ellipse'`` (see :func:`refine_moments`, :func:`refine_ellipse`).
    dark
        dark dots on a bright plate (``True``), bright dots on a dark plate (``False``), or ``None``: decided
        from the image (:func:`dot_polarity`).
    dot_diameter_px
        expected dot diameter [px] if known (for the border margin of the plate-size anchor).
    anchor
        ``'auto'``: markers where the plate has them (a donut L, a square and a triangle, a frame around a
        dot), else the plate's size; ``'plate'``: from the plate's size and where the lattice leaves the image;
        ``'markers'``: from markers only.
    marker_origin
        ``(row, col)`` of the corner donut of an L of donuts.
    two_level
        a two-level plate (rows alternating between two depths, offset by half a pitch): indices in half
        pitches and a ``level`` per dot.
    """
    if method not in METHODS:
        raise SlmlabError(f"unknown centre method {method!r}; use one of {', '.join(METHODS)}")
    if anchor not in ("auto", "plate", "markers"):
        raise SlmlabError(f"unknown anchor {anchor!r}; use 'auto', 'plate' or 'markers'")
    if dark is None:
        dark = dot_polarity(img)
    blobs = find_blobs(img, dark=dark)
    if len(blobs.centres) < 4:
        return ImageDots(empty_dots_table(), len(blobs.centres), blobs.rejected, 0,
                         f"{len(blobs.centres)} dot(s) found, at least 4 are needed", markers=blobs.markers, dark=dark)
    refine = refine_moments if method == "moments" else refine_ellipse
    centres = refine(img, blobs.centres, blobs.radii, dark=dark)
    lat, on = index_lattice(centres)
    spurious = int((~on).sum())
    pl = plate_lattice(lat, on, two_level=two_level)
    k = pl.index
    level = ((pl.i1 % 2) if two_level else np.zeros(len(k), int)).astype(int)
    table = pd.DataFrame({"i1": pl.i1, "i2": pl.i2, "w1": centres[k, 0], "w2": centres[k, 1],
                          "marker": blobs.holes[k], "level": level})
    radius = (dot_diameter_px / 2) if dot_diameter_px else float(np.median(blobs.radii))
    table, frame, how, note = _anchor(table, pl, blobs, rows, cols, anchor=anchor, marker_origin=marker_origin,
                                      two_level=two_level, image_size=(img.shape[1], img.shape[0]),
                                      margin_px=radius + 2)
    return ImageDots(table, len(centres), blobs.rejected, spurious, note if frame is None else "", pl, frame, how,
                     blobs.markers, dark)


def _anchor(table: pd.DataFrame, pl: PlateLattice, blobs, rows, cols, *, anchor: str, marker_origin, two_level: bool,
            image_size: tuple[int, int], margin_px: float):
    """The plate's ``[row, col]`` of one image's lattice: from an L of donut markers, from a square and a
    triangle or a frame (an origin frame), or from the plate's size (:mod:`slmlab.images.lattice`). Returns
    the table (with ``row, col``, sorted, where anchored), the frame (``'plate'``, ``'origin'`` or ``None``),
    how it was anchored, and why not."""
    k = pl.index
    frame, how, note = None, "", ""
    donuts = int(blobs.holes[k].sum())
    sized = rows is not None and cols is not None
    # polygon markers give an origin, for a plate whose size is unknown; a donut L numbers any plate
    use_markers = anchor == "markers" or (anchor == "auto" and (donuts >= 3 or (blobs.markers and not sized)))
    if use_markers and donuts >= 3:
        ij, note = donut_indices(pl, blobs.holes, marker_origin)
        if ij is not None:
            table["row"], table["col"], frame, how = ij[0], ij[1], "plate", "an L of donut markers"
    elif use_markers:
        xy, msg = origin_frame(pl, blobs.markers)
        if xy is None:
            note = msg
        else:
            frame, how = "origin", msg
            if two_level:  # the origin's level is level 0
                table["level"] = (xy[0] % 2).astype(int)
            table["xu"], table["yu"] = xy[0].astype(int), xy[1].astype(int)
            table["row"], table["col"] = -table["yu"], -table["xu"]
    if frame is None and (sized or not note) and anchor != "markers":
        if not sized:
            note = ("no markers found and the plate's rows and cols are not given (a plate larger than the "
                    "field needs markers, or neighbouring images to track it from)")
        else:
            ij, note = absolute_indices(pl, rows, cols, image_size, margin_px)
            if ij is not None:
                table["row"], table["col"], frame, how = ij[0], ij[1], "plate", "the plate's size"
    if frame is None:
        table["row"] = pd.Series(dtype=int)
        table["col"] = pd.Series(dtype=int)
    else:
        table = table.sort_values(["row", "col"], kind="stable").reset_index(drop=True)
    return table, frame, how, note


def extract_stereo_pairs(pairs: list[tuple[Path, Path]], rows: int, cols: int, *, anchor: str = "markers") -> pd.DataFrame:
    """Extract real stereo pairs (left, right image paths): dots found and indexed per image, and common.

    Returns a DataFrame ``pair, left, right, common, note``; the per-pair tables are in the ``.attrs``.
    """
    out, tables = [], {}
    for left, right in pairs:
        views = [extract_image(read_image(p), rows, cols, anchor=anchor) for p in (left, right)]
        m = views[0].table.merge(views[1].table, on=["row", "col"], suffixes=("_l", "_r"))
        tables[Path(left).stem] = m
        out.append((Path(left).stem, len(views[0].table), len(views[1].table), len(m),
                    "; ".join(v.note for v in views if v.note)))
    df = pd.DataFrame(out, columns=["pair", "left", "right", "common", "note"])
    df.attrs["tables"] = tables
    return df
