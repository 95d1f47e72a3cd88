"""A camera's text overlay: the band of rows at an image's top or bottom that a camera draws its text on
(:func:`overlay_rows`), the picture's rows beside it that the contrast mesh is taken on (:func:`picture_rows`,
:func:`within`, :func:`outside_nil`: :class:`slmlab.images.dots.ContrastMesh`), and the image with the band painted
over by the plate's background for the centres (:func:`overlay_painted`)."""

from __future__ import annotations

import cv2
import numpy as np

from .robust import robust_sigma

__all__ = ["OVERLAY_ROWS", "OVERLAY_SHARE", "overlay_rows", "picture_rows", "outside_nil", "within", "overlay_painted"]

#: a camera's text overlay covers at least this many rows and at most this share of an image's rows, at its top or
#: bottom (:func:`overlay_rows`)
OVERLAY_ROWS = 8
OVERLAY_SHARE = 0.1


def overlay_rows(img: np.ndarray) -> tuple[int, int]:
    """How many rows at the top and at the bottom of ``img`` a camera's text overlay covers (0 where none): a band
    of :data:`OVERLAY_ROWS` rows or more reaching the edge, at most :data:`OVERLAY_SHARE` of them, whose rows'
    medians are one value within 0.5 % of the image's range (its 1st to 99th percentile: an overlay's fill, drawn on
    the picture: no noise, no fall-off of the light; its text covers less than half a row), the band's median in
    each eighth of its width too (a synthetic plate tilted over a flat background fills less than half of its first
    rows: DICe's dot_06_0), beyond a step to the picture's rows next to it of twice their pixels' noise (dots over
    less than half a row move its median by less than 1.4 σ: a flat plate's rows have one median too, down to its
    first row of dots, 190 DN then 189 on stereo-dic:39 at its lowest contrast, under 1.5 DN of noise) and ten times
    their medians' own (and twice the fill's tolerance). The mesh beside a dark strip under a bright plate took its
    median and spread from both (on greenough:31 the plate's last two rows of dots, 30 of 1640, were at 0.0 σ and
    lost); its glyphs were read as markers (stereo-piv:32: a black strip under a plate at 12 DN)."""
    h = img.shape[0]
    most = int(OVERLAY_SHARE * h)
    n = most + 16
    sub = img[:, ::4]
    if most < OVERLAY_ROWS or sub.shape[1] < 8:
        return 0, 0
    lo, hi = np.percentile(sub[::4], [1, 99])
    span = max(float(hi) - float(lo), 1e-6)
    same = 0.005 * span
    cut = []
    for rows in (sub[:n], sub[::-1][:n]):
        m = np.median(rows, axis=1).astype(np.float64)
        off = np.abs(m - m[0]) > same
        k = int(np.argmax(off)) if off.any() else n
        picture = m[k:k + 16]
        if not OVERLAY_ROWS <= k <= most or len(picture) < 16:
            cut.append(0)
            continue
        step = np.abs(picture[:3] - m[0]).min()
        across = [np.median(c) for c in np.array_split(rows[:k], 8, axis=1)]   # the fill all along
        band = np.abs(np.asarray(across, np.float64) - m[0]).max() <= same
        least = max(2 * _row_noise(rows[k:k + 16]), 10 * _row_noise(picture[:, None]), 2 * same)
        cut.append(k if band and step >= least else 0)
    return cut[0], cut[1]


def _row_noise(rows: np.ndarray) -> float:
    """The noise σ of ``rows`` ``(n, w)`` (a picture's pixels, or ``(n, 1)``: its rows' medians): the robust spread
    of the differences of adjacent rows over √2, which a smooth fall-off of the light does not add to."""
    return robust_sigma(np.diff(rows.astype(np.float32), axis=0)) / np.sqrt(2)


def picture_rows(cut: tuple[int, int], scale: int, rows: int, cell: int) -> tuple[int, int] | None:
    """The reduced image's rows ``[a, b)`` clear of overlays ``cut`` (:func:`overlay_rows`, full-resolution rows)
    at reduction ``scale``, the smoothing's reach (4 reduced rows: its kernel's half) beyond them too; ``None``
    where there are none, or where fewer than a mesh ``cell`` of rows would be left."""
    grow = [int(np.ceil(c / scale)) + 4 if c else 0 for c in cut]
    return None if not any(cut) or rows - grow[0] - grow[1] < cell else (grow[0], rows - grow[1])


def outside_nil(z: np.ndarray, picture: tuple[int, int] | None) -> np.ndarray:
    """``z`` (in place) nil outside the ``picture`` rows (:func:`picture_rows`)."""
    if picture is not None:
        z[:picture[0]], z[picture[1]:] = 0, 0
    return z


def within(small: np.ndarray, picture: tuple[int, int] | None, stat, *args):
    """``stat(small, *args)`` (arrays the shape of ``small``) taken on the ``picture`` rows only, their edge rows
    replicated over the rest."""
    if picture is None:
        return stat(small, *args)
    a, b = picture
    return tuple(cv2.copyMakeBorder(m, a, small.shape[0] - b, 0, 0, cv2.BORDER_REPLICATE)
                 for m in stat(np.ascontiguousarray(small[a:b]), *args))


def overlay_painted(img: np.ndarray, con) -> np.ndarray:
    """``img`` with a camera's text overlay (``con.overlay``, :func:`overlay_rows`; ``con`` its
    :class:`slmlab.images.dots.Contrast`) painted over by the plate's background in the picture's row next to it
    (``con.background``, each column's): the centres of the dots just above a dark strip under a bright plate would
    take its edge for theirs (on greenough:31, 0.8 px). A copy; the image itself where there is no overlay."""
    if not any(con.overlay):
        return img
    out = img.copy()
    h, w = img.shape
    a, b = con.picture
    for rows, edge in ((slice(0, con.overlay[0]), a), (slice(h - con.overlay[1], h), b - 1)):
        line = cv2.resize(con.background[edge:edge + 1], (w, 1), interpolation=cv2.INTER_LINEAR)
        if np.issubdtype(img.dtype, np.integer):
            line = np.clip(np.rint(line), np.iinfo(img.dtype).min, np.iinfo(img.dtype).max)
        out[rows] = line.astype(img.dtype)
    return out
