"""Window streaks read along the columns through each dot (:mod:`slmlab.images.centres` flat-fields each dot's
columns by them, :func:`slmlab.images.centres.flatten`).

A streak on a window in front of the plate dims or brightens whole columns of the image, plate and dots alike,
fading slowly along them. A dot's own patch holds only a few pixels per column beside the dot, too few to read a
streak in noise; a strip as wide as the patch and about twice as tall holds several times more, once every dot is
masked (:func:`clear_of_dots`). Each column's level above the dot and below it (:func:`strip_columns`) tells a
streak, which runs through both, from texture and noise, which do not.
"""

from __future__ import annotations

import cv2
import numpy as np

from .robust import masked_median, midmean

__all__ = ["STRIP_HALVES", "STRIP_APART", "clear_of_dots", "strip_columns", "clipped_band"]

#: a dot's columns are read on a strip this many times its patch's half side above and below it
#: (:func:`strip_columns`; the patch alone, a few pixels per column beside the dot, lost streaks of 10 grey levels
#: in noise of 8; 3 read strong streaks on a clean image worse, the fade along them and the plate's edge farther
#: off, by 10-30 %)
STRIP_HALVES = 2
#: where a column's level above the dot and below it differ by more than this many times the columns' spread
#: of that difference, something else is on one side and the column is left out
STRIP_APART = 5.0


def clear_of_dots(shape: tuple[int, int], centres: np.ndarray, reach: float) -> np.ndarray:
    """The pixels ``shape`` of an image farther than ``reach`` + 1 px from every dot centre ``(n, 2)`` [px] (the
    plate between the dots, where :func:`strip_columns` reads window streaks)."""
    free = np.ones(shape, np.uint8)
    r = int(np.ceil(reach + 1))
    c = np.asarray(centres, float).reshape(-1, 2)
    for x, y in np.rint(c[np.isfinite(c).all(axis=1)]).astype(int):
        cv2.circle(free, (int(x), int(y)), r, 0, -1)
    return free.view(bool)   # 0 and 1 bytes: a bool view, no copy


def strip_columns(img: np.ndarray, base: np.ndarray, half: int, coef: np.ndarray, free: np.ndarray,
                  ring: np.ndarray, sat: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Window streaks: each column's offset ``(n, S)`` [grey levels] from the plane ``coef`` of the patches at
    ``base`` (side ``S = 2·half + 1``), the mean of its levels above and below the dot (:func:`_strip_levels`), each
    less its line across the columns weighted by the column's pixels of the plane's ring ``ring`` ``(S,)``, or
    ``(n, S)`` where the patches' planes were read on rings of their own (:func:`slmlab.images.centres.flatten`) (the
    plane took in the streaks' mean and slope there, and a row's level the streaks' share of it). A patch alone
    holds a few pixels per column beside its dot (at 8 grey levels of noise a streak of 10 went unread). A column
    whose two levels differ by more than :data:`STRIP_APART` times the columns' spread of that difference holds
    something else on one side (a marker, another dot, a glint); the lines are fitted again without such columns
    (their weight tilted every other column's), and the columns then left out are judged again and read on their
    other side (:func:`_one_side`); a column masked to a few pixels takes its neighbours' offset (:func:`_filled`);
    a column saturated above the dot and below it (:func:`clipped_band`) is read as it is (its offset at least what
    it shows) and left out of that spread (a clipped band's columns, equal above and below, made it nil and every
    other column an outlier). Per patch also the mean square
    of the offsets over their noise variance (from the difference above less below, which a streak leaves out,
    and at least a grey level's: about 1 without streaks) and the correlation of the offsets above with those
    below (a streak runs through both; texture and noise do not)."""
    (up0, k_up), (down0, k_down), clipped = _strip_levels(img, base, half, coef, free, sat)
    seen = (k_up >= 4) & (k_down >= 4)
    ok, x = seen.copy(), np.arange(-half, half + 1)
    quantum = np.sqrt(2 / 12 / np.maximum(masked_median(np.minimum(k_up, k_down), ok, 1), 1))   # 1 grey level
    for _ in range(2):   # again without the columns left out: an object on one side tilted every column's line
        up, down = (v - _line(np.where(ok, v, 0.0), x, ring * ok) for v in (up0, down0))
        d = up - down
        centre = midmean(d, ok, 1)[0][:, None]
        spread = np.maximum(1.4826 * masked_median(np.abs(d - centre), ok & ~clipped, 1), quantum)
        ok &= clipped | (np.abs(d - centre) <= STRIP_APART * spread[:, None])
    column = _filled(np.where(ok, 0.5 * (up + down), 0.0), ok)
    column = np.where(seen & ~ok, _one_side(up - 0.5 * centre, down + 0.5 * centre, column), column)
    chi = (np.where(ok, column, 0.0) ** 2).sum(axis=1) / np.maximum(ok.sum(axis=1), 1) / (0.25 * spread ** 2)
    up, down = np.where(ok, up, 0.0), np.where(ok, down, 0.0)
    up, down = (np.where(ok, v - v.sum(axis=1, keepdims=True) / np.maximum(ok.sum(axis=1, keepdims=True), 1), 0.0)
                for v in (up, down))
    rho = (up * down).sum(axis=1) / np.sqrt((up * up).sum(axis=1) * (down * down).sum(axis=1) + 1e-12)
    return column.astype(np.float32), chi, rho


def _strip_levels(img: np.ndarray, base: np.ndarray, half: int, coef: np.ndarray, free: np.ndarray, sat: float
                  ) -> tuple:
    """Each column's level ``(n, S)`` above the dot and below it, with how many pixels, on a strip as wide as the
    patch (``S = 2·half + 1``) and :data:`STRIP_HALVES` times ``half`` above and below it, on the pixels ``free`` of
    every dot (:func:`clear_of_dots`): each pixel less the plane ``coef``, each row less its level (the background's
    curve along the column), then the columns' :func:`slmlab.images.robust.midmean`; and which columns hold a
    pixel at ``sat`` (saturated) above the dot and below it (:func:`clipped_band`: a glint on one side, taken for a
    clipped band, left the dot no streak at all)."""
    h, w = img.shape
    reach = STRIP_HALVES * half
    oy, ox = np.arange(-reach, reach + 1), np.arange(-half, half + 1)
    ys, xs = base[:, 1, None] + oy, base[:, 0, None] + ox
    if len(base) and (ys >= 0).all() and (ys < h).all() and (xs >= 0).all() and (xs < w).all():   # windows of the image
        at = (base[:, 1] - reach, base[:, 0] - half)
        values, use = (np.lib.stride_tricks.sliding_window_view(a, (len(oy), len(ox)))[at] for a in (img, free))
    else:   # a strip beyond the image: its pixels there not used
        yc, xc = np.clip(ys, 0, h - 1)[:, :, None], np.clip(xs, 0, w - 1)[:, None, :]
        values, use = img[yc, xc], free[yc, xc] & (ys[:, :, None] == yc) & (xs[:, None, :] == xc)
    clipped = clipped_band(use & (values >= sat), oy)
    res = values.astype(np.float32) - (coef[:, 0, None, None] + coef[:, 1, None, None] * ox[None, None, :]
                                       + coef[:, 2, None, None] * oy[None, :, None]).astype(np.float32)
    res -= midmean(res, use, 2)[0][:, :, None].astype(np.float32)
    res, use = np.ascontiguousarray(res.transpose(0, 2, 1)), np.ascontiguousarray(use.transpose(0, 2, 1))
    up, down = (midmean(res[:, :, side], use[:, :, side], 2) for side in (oy < 0, oy > 0))
    return up, down, clipped


def clipped_band(saturated: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """Which columns ``(n, S)`` of patches or strips ``saturated`` ``(n, R, S)`` (their saturated pixels, at ``rows``
    ``(R,)`` [px] from the dot) saturate above the dot and below it: a clipped band runs through it; a glint on
    one side is something else."""
    return saturated[:, rows < 0].any(axis=1) & saturated[:, rows > 0].any(axis=1)


def _filled(column: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Each row of ``column`` ``(n, S)`` where not ``ok``, linearly between its nearest ``ok`` columns (the nearest
    beyond the last), zero where none is: a column the dot and its neighbours above and below mask to a few pixels
    lies inside a streak as wide as the window's blur (left at zero, a dense plate's middle column moved a fit
    0.3 px on greenough:7201)."""
    out = column.copy()
    x = np.arange(column.shape[1])
    for i in np.flatnonzero(~ok.all(axis=1) & ok.any(axis=1)):
        out[i] = np.interp(x, x[ok[i]], column[i, ok[i]])
    return out


def _line(v: np.ndarray, x: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """The weighted least-squares line ``(n, S)`` in ``x`` ``(S,)`` of ``v`` ``(n, S)`` (weights ``(n, S)``)."""
    design = np.stack([np.ones(len(x)), np.asarray(x, np.float64)])                        # (2, S)
    normal = np.einsum("ks,ns,ls->nkl", design, weight, design) + 1e-9 * np.eye(2)
    beta = np.linalg.solve(normal, np.einsum("ks,ns->nk", design, weight * v)[..., None])[..., 0]
    return beta @ design


def _one_side(up: np.ndarray, down: np.ndarray, filled: np.ndarray) -> np.ndarray:
    """A column's offset read on one side of the dot, where something else sits on the other: of its level above
    ``up`` and below ``down`` (each ``(n, S)``, brought to their mean by half the columns' usual difference above
    less below), the one nearer ``filled``, its neighbours' (:func:`_filled`). A streak's fine structure under a
    glint beside the dot is kept: filled in from its neighbours over the glint's nine columns, a bright dot's model
    fit moved 0.07-0.14 px."""
    return np.where(np.abs(up - filled) <= np.abs(down - filled), up, down)
