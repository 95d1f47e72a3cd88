"""Finding the dots of a calibration plate in one image and refining their centres to sub-pixel accuracy
(the paper's §3 input; numbering them is :mod:`slmlab.images.lattice`).

For images as a camera writes them (8 or 16 bit, any format OpenCV reads, dark dots on a bright plate or
bright dots on black), OpenCV throughout:

1. **Polarity**: from the plate's ``"dots"`` key, or decided from the image (:func:`dot_polarity`: the dots
   are the minority class of an Otsu split).
2. **Background and dot level** (illumination, vignetting): a min (max) filter on an 8× reduced image gives
   the background under the dots, a max (min) filter over a larger window the level of the dots (zero for
   dark dots). Pixels beyond ``threshold`` of the way from the background to the dot level are dot pixels.
3. **Blobs**: external contours of the dot mask (``cv2.findContours``). Blobs touching the image border
   (partly visible dots), too small or large against the median, or not round enough are rejected; large
   enough polygons are kept as **markers** (triangles, squares, a frame around a dot), dots with a hole as
   donut markers.
4. **Sub-pixel centres**, two estimators, both flat-fielded by a background plane fitted per dot on a ring
   around it (so vignetting does not pull the centre):

   * ``moments``: intensity-weighted centroid of the dot's contrast (``1 − I/B`` for dark dots, ``I − B``
     for bright ones) inside an anti-aliased circular window, iterated so the window is centred on the
     estimate;
   * ``ellipse``: half-contrast crossings along 48 rays, fitted by an ellipse (algebraic least squares).
     It uses only the dot's edge, so a textured or scratched dot (real plates) does not pull it.

   Measured on rendered sets (``python -m slmlab bench``, notebook 02) ``moments`` is the more accurate on
   uniform dots, and the default.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from ..errors import SlmlabError

__all__ = ["METHODS", "Blobs", "Marker", "read_image", "as_8bit", "dot_polarity", "estimate_background",
           "find_blobs", "refine_moments", "refine_ellipse"]

METHODS = ("moments", "ellipse")


# ------------------------------------------------------------------------------------------ reading
def read_image(path: str | Path) -> np.ndarray:
    """Read an image as a 2-D array of grey levels in its own bit depth (``uint8``, ``uint16`` or ``float32``:
    any format OpenCV reads, PNG and TIFF included); colour images are converted to grey. Missing,
    unreadable or truncated files are a :class:`SlmlabError` that names the file."""
    path = Path(path)
    if not path.exists():
        raise SlmlabError("image not found; check the path (images are named relative to the set's folder)", path)
    if path.is_dir():
        raise SlmlabError("is a folder, not an image; give the image file", path)
    data = np.fromfile(path, dtype=np.uint8)
    img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED | cv2.IMREAD_ANYDEPTH) if data.size else None
    if img is None or img.size == 0:
        raise SlmlabError("cannot be read as an image (unreadable, truncated or not an image); re-export it as "
                          "PNG or TIFF", path)
    if img.ndim == 3:
        if img.shape[2] == 1:
            img = img[:, :, 0]
        else:
            code = cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
            img = cv2.cvtColor(img, code)
    if img.dtype not in (np.uint8, np.uint16):
        img = img.astype(np.float32)
        if not np.isfinite(img).all():
            raise SlmlabError("holds non-finite pixel values; re-export it as an integer image", path)
    return img


def _as_float(img: np.ndarray) -> np.ndarray:
    return img if img.dtype == np.float32 else img.astype(np.float32)


def as_8bit(img: np.ndarray) -> np.ndarray:
    """An 8-bit copy for OpenCV functions that take only 8-bit images: 16-bit and float images are scaled from
    their 0.1 to 99.9 percentile (robust to a few hot pixels)."""
    if img.dtype == np.uint8:
        return img
    f = _as_float(img)
    lo, hi = np.percentile(f[::4, ::4], [0.1, 99.9])
    return cv2.convertScaleAbs(f, alpha=255.0 / max(hi - lo, 1e-6), beta=-lo * 255.0 / max(hi - lo, 1e-6))


def dot_polarity(img: np.ndarray) -> bool:
    """``True`` for dark dots on a bright plate, ``False`` for bright dots on a dark one: the dots are the
    minority class of an Otsu split of the image (a dot plate is mostly background)."""
    small = as_8bit(cv2.resize(img, (max(img.shape[1] // 4, 1), max(img.shape[0] // 4, 1)),
                               interpolation=cv2.INTER_AREA))
    t, _ = cv2.threshold(small, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    return bool(np.mean(small > t) > 0.5)


# ------------------------------------------------------------------------------------------ detection
def estimate_background(img: np.ndarray, *, dark: bool = True, reduce: int = 8, window_px: int = 160) -> np.ndarray:
    """Smooth illumination under the dots [grey levels, float32], by a max (min) filter at 1/``reduce``
    scale over ``window_px`` (larger than a dot)."""
    return _filtered(img, dark, reduce, window_px)


def _filtered(img: np.ndarray, high: bool, reduce: int, window_px: int) -> np.ndarray:
    h, w = img.shape
    small = cv2.resize(_as_float(img), (max(w // reduce, 1), max(h // reduce, 1)), interpolation=cv2.INTER_AREA)
    k = max(3, int(window_px / reduce) | 1)
    kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (k, k))
    small = cv2.dilate(small, kernel) if high else cv2.erode(small, kernel)
    small = cv2.GaussianBlur(small, (0, 0), k / 2)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)


@dataclass
class Marker:
    """A marker on the plate: ``kind`` (``'triangle'``, ``'square'``, ``'frame'``: a frame around a dot) and
    its centre ``(w1, w2)`` [px]."""

    kind: str
    centre: tuple[float, float]


@dataclass
class Blobs:
    """Candidate dots of one image: first-guess centres ``(n, 2)`` [px], areas [px²], equivalent radii [px],
    whether each has a hole (a donut marker), the polygon markers found, and the count of rejected blobs."""

    centres: np.ndarray
    areas: np.ndarray
    radii: np.ndarray
    holes: np.ndarray
    rejected: int = 0
    markers: list = field(default_factory=list)


def find_blobs(img: np.ndarray, *, dark: bool = True, threshold: float = 0.6, background: np.ndarray | None = None,
               min_area_px: float = 12.0) -> Blobs:
    """Dots as external contours of the pixels beyond ``1 − threshold`` of the way from the background to
    the dots' level (for dark dots, whose level is zero: darker than ``threshold`` × background).

    Blobs touching the border, much smaller or larger than the median, or not round are rejected (counted in
    ``rejected``); among the rejected, polygons of about a dot's size are returned as markers.
    """
    f = _as_float(img)
    bg = estimate_background(f, dark=dark) if background is None else background
    if dark:
        mask = f < threshold * bg
    else:  # bright dots on a dark plate: the dots' level varies (illumination, reflectance); take it locally
        fg = _filtered(f, True, 8, 480)
        floor = 0.5 * float(np.percentile((f - bg)[::4, ::4], 99.5))
        mask = f > bg + (1.0 - threshold) * np.maximum(fg - bg, floor)
    mask = mask.astype(np.uint8)
    contours, hierarchy = cv2.findContours(mask, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
    h, w = img.shape
    cents, areas, holes, shapes = [], [], [], []
    rejected = 0
    if hierarchy is not None:
        hier = hierarchy[0]
        for k, cnt in enumerate(contours):
            if hier[k, 3] != -1:  # a hole of another blob
                continue
            x, y, bw, bh = cv2.boundingRect(cnt)
            area = cv2.contourArea(cnt)
            if area < min_area_px or x <= 0 or y <= 0 or x + bw >= w or y + bh >= h:
                rejected += 1
                continue
            fill = area / (bw * bh)
            m = cv2.moments(cnt)
            if m["m00"] <= 0:
                rejected += 1
                continue
            centre = (m["m10"] / m["m00"], m["m01"] / m["m00"])
            hole = _largest_hole(contours, hier, k) >= 0.03 * area  # a donut's or a frame's, not texture
            kind = _polygon_kind(cnt, area, hole)
            if kind is None and 0.6 < fill < 0.95 and 0.5 < bw / bh < 2.0:
                cents.append(centre)
                areas.append(area)
                holes.append(hole)
                continue
            rejected += 1
            if kind is not None:
                shapes.append((kind, centre, area))
    cents = np.asarray(cents, float).reshape(-1, 2)
    areas = np.asarray(areas, float)
    holes = np.asarray(holes, bool)
    markers = []
    if len(areas):
        med = np.median(areas)
        ok = (areas > 0.5 * med) & (areas < 1.6 * med)  # two touching blobs (dust on a dot) are ~2x
        rejected += int((~ok).sum())
        cents, areas, holes = cents[ok], areas[ok], holes[ok]
        markers = [Marker(kind, centre) for kind, centre, area in shapes
                   if (0.3 * med < area < 4.0 * med) or kind == "frame"]
    return Blobs(cents, areas, np.sqrt(areas / np.pi), holes, rejected, markers)


def _largest_hole(contours, hier, k: int) -> float:
    """Area [px²] of the largest hole of contour ``k`` (0 without one)."""
    best, child = 0.0, hier[k, 2]
    while child != -1:
        best = max(best, cv2.contourArea(contours[child]))
        child = hier[child, 0]
    return best


def _polygon_kind(cnt, area: float, has_hole: bool) -> str | None:
    """``'triangle'``, ``'square'`` or ``'frame'`` (a square outline around a dot) for a contour large
    enough to show its shape (≥ 150 px²); ``None`` for anything else (a dot, dust).

    By two fills that an affine view leaves unchanged: of the smallest enclosing triangle (about 0.9 for a
    triangle, ``π/3√3`` = 0.60 for any ellipse, 0.5 for a square) and of the smallest enclosing rectangle
    (about 1 for a square, ``π/4`` for any ellipse)."""
    if area < 150:
        return None
    hull = cv2.convexHull(cnt)
    (_, _), (rw, rh), _ = cv2.minAreaRect(hull)
    rect_fill = area / max(rw * rh, 1e-9)
    square = rect_fill > 0.88 and 0.6 < rw / max(rh, 1e-9) < 1.6
    if has_hole:
        return "frame" if square else None
    tri_area, _ = cv2.minEnclosingTriangle(hull)
    if area / max(tri_area, 1e-9) > 0.78:
        return "triangle"
    return "square" if square else None


# ------------------------------------------------------------------------------------------ sub-pixel
def _gather(img: np.ndarray, base: np.ndarray, half: int) -> np.ndarray:
    """Square patches ``(n, S, S)`` [float32] around integer centres ``base`` (edge-clamped)."""
    h, w = img.shape
    off = np.arange(-half, half + 1)
    rows = np.clip(base[:, 1, None] + off[None, :], 0, h - 1)
    cols = np.clip(base[:, 0, None] + off[None, :], 0, w - 1)
    return img[rows[:, :, None], cols[:, None, :]].astype(np.float32)


@dataclass
class _Flat:
    """Flat-fielded contrast patches ``±(1 − I/B)`` around integer centres ``base``; ``B`` is a plane
    (coefficients ``coef`` on offsets ``ox, oy``) fitted on a ring of integer offsets, the same ring for all
    dots, so one pseudo-inverse serves the whole image."""

    base: np.ndarray
    ox: np.ndarray
    oy: np.ndarray
    contrast: np.ndarray
    coef: np.ndarray


def _flatten(img: np.ndarray, centres: np.ndarray, ring_in: float, dark: bool) -> _Flat:
    half = int(np.ceil(ring_in + 5))
    base = np.rint(centres).astype(int)
    p = _gather(img, base, half)
    off = np.arange(-half, half + 1, dtype=np.float32)
    oy, ox = np.meshgrid(off, off, indexing="ij")
    d = np.hypot(ox, oy)
    ring = (d > ring_in) & (d < ring_in + 4)
    design = np.column_stack([np.ones(int(ring.sum())), ox[ring], oy[ring]])
    coef = p[:, ring] @ np.linalg.pinv(design).T.astype(np.float32)          # (n, 3)
    contrast = _contrast(p, _plane(coef, ox[None], oy[None]), dark)
    return _Flat(base, ox, oy, contrast, coef)


def _contrast(values: np.ndarray, background: np.ndarray, dark: bool) -> np.ndarray:
    """A dot's contrast: ``1 − I/B`` for dark dots (flat-fielded: illumination scales plate and dot alike),
    ``I − B`` for bright dots on a dark plate (whose background is an offset, often near zero)."""
    if dark:
        return 1.0 - values / np.maximum(background, 1.0)
    return values - background


def _plane(coef: np.ndarray, dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
    """Plane ``b0 + bx·dx + by·dy`` per dot; ``dx, dy`` have a leading axis of length ``n`` or 1."""
    shape = (-1,) + (1,) * (max(np.ndim(dx), np.ndim(dy)) - 1)
    return coef[:, 0].reshape(shape) + coef[:, 1].reshape(shape) * dx + coef[:, 2].reshape(shape) * dy


def _profile_radius(flat: _Flat, radius: float) -> float:
    """Radius [px] where the mean radial contrast profile of the dots falls to 2 % of its peak: the dot and
    its defocus blur."""
    d = np.rint(np.hypot(flat.ox, flat.oy)).astype(int).ravel()
    prof = np.bincount(d, weights=flat.contrast.mean(axis=0).ravel()) / np.maximum(np.bincount(d), 1)
    peak = prof[: max(int(radius), 1)].max()
    beyond = np.flatnonzero((np.arange(len(prof)) > radius) & (prof < 0.02 * peak))
    return float(beyond[0]) if len(beyond) else 1.5 * radius


def _flat_for(img, centres, radii, dark) -> tuple[_Flat, float]:
    """Flat-fielded patches sized to the dots: a first pass measures how far the blurred dots reach."""
    r = float(np.median(radii))
    first = _flatten(img, centres, 1.6 * r + 4, dark)
    reach = min(_profile_radius(first, r) + 1.5, 1.6 * r + 3)
    return _flatten(img, centres, reach + 1, dark), reach


def refine_moments(img: np.ndarray, centres: np.ndarray, radii: np.ndarray, *, dark: bool = True,
                   iterations: int = 3) -> np.ndarray:
    """Sub-pixel centres by the intensity-weighted centroid of the flat-fielded contrast ``1 − I/B``.

    ``B`` is a plane fitted per dot on a ring outside the dot and its blur, so vignetting does not pull the
    centre. The window is an anti-aliased disk reaching 1.5 px beyond where the dots' mean radial profile
    falls to 2 % of its peak, re-centred on the estimate each iteration. Returns ``(n, 2)`` [px].
    """
    c = np.asarray(centres, float).copy()
    if len(c) == 0:
        return c
    flat, reach = _flat_for(img, c, radii, dark)
    disk = np.hypot(flat.ox, flat.oy) <= reach + 1.5  # the window never reaches beyond (|c - base| <= 0.5)
    ox, oy = flat.ox[disk], flat.oy[disk]
    con = flat.contrast[:, disk]
    # float32 is ample here: sums of a few thousand terms of size <= reach, relative error ~1e-6 px
    for _ in range(iterations):
        f = (c - flat.base).astype(np.float32)
        win = np.clip(np.float32(reach + 0.5) - np.hypot(ox[None, :] - f[:, 0, None], oy[None, :] - f[:, 1, None]),
                      0.0, 1.0)
        w = con * win
        s = w.sum(axis=1, dtype=np.float64)
        s = np.where(np.abs(s) > 1e-9, s, 1e-9)
        c = flat.base + np.column_stack([w @ ox, w @ oy]).astype(np.float64) / s[:, None]
    return c


def _bilinear(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear samples of ``img`` at ``(x, y)`` [px] (any shape), replicating the border (``cv2.remap``)."""
    f = _as_float(img)
    shape = np.broadcast(x, y).shape
    n = shape[0] if len(shape) > 1 else 1
    mx = np.broadcast_to(x, shape).astype(np.float32).reshape(n, -1)
    my = np.broadcast_to(y, shape).astype(np.float32).reshape(n, -1)
    return cv2.remap(f, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).reshape(shape)


def refine_ellipse(img: np.ndarray, centres: np.ndarray, radii: np.ndarray, *, dark: bool = True,
                   rays: int = 48, iterations: int = 2) -> np.ndarray:
    """Sub-pixel centres from an ellipse fitted to the half-contrast crossings along ``rays`` rays.

    The contrast ``1 − I/B`` is flat-fielded as in :func:`refine_moments`; along each ray the first
    crossing of half the dot's inner contrast is found by linear interpolation; the conic through the
    crossings (algebraic least squares) gives the centre. Returns ``(n, 2)`` [px].
    """
    c = np.asarray(centres, float).copy()
    if len(c) == 0:
        return c
    r = float(np.median(radii))
    flat, reach = _flat_for(img, c, radii, dark)
    img = _as_float(img)  # once, for the samples of every iteration
    t = np.linspace(0, 2 * np.pi, rays, endpoint=False)
    steps = np.linspace(0.0, 1.0, 96)
    rad = steps * reach
    ox = np.cos(t)[None, :, None] * rad[None, None, :]                          # (1, R, S) offsets
    oy = np.sin(t)[None, :, None] * rad[None, None, :]
    core = max(2, int(0.5 * len(steps) * r / reach))
    for _ in range(iterations):
        f = c - flat.base
        vals = _bilinear(img, c[:, 0, None, None] + ox, c[:, 1, None, None] + oy)
        con = _contrast(vals, _plane(flat.coef, ox + f[:, 0, None, None], oy + f[:, 1, None, None]), dark)
        level = 0.5 * np.median(con[:, :, :core], axis=(1, 2))
        below = con < level[:, None, None]
        below[:, :, 0] = False
        first = np.argmax(below, axis=2)                                        # (n, R)
        ok = below.any(axis=2) & (first > 0)
        k1 = np.maximum(first - 1, 0)
        g0 = np.take_along_axis(con, k1[..., None], axis=2)[..., 0]
        g1 = np.take_along_axis(con, first[..., None], axis=2)[..., 0]
        frac = np.clip((g0 - level[:, None]) / np.where(g0 != g1, g0 - g1, 1.0), 0, 1)
        rr = (steps[k1] + frac * (steps[1] - steps[0])) * reach
        c = c + _ellipse_centres(np.cos(t)[None, :] * rr, np.sin(t)[None, :] * rr, ok)
    return c


def _ellipse_centres(x: np.ndarray, y: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Centres of the conics ``x² + B xy + C y² + D x + E y + F = 0`` fitted to points ``(n, R)``."""
    a = np.stack([x * y, y * y, x, y, np.ones_like(x)], axis=-1) * ok[..., None]
    rhs = -(x * x) * ok
    ata = np.einsum("nrk,nrl->nkl", a, a) + 1e-9 * np.eye(5)
    atb = np.einsum("nrk,nr->nk", a, rhs)
    B, C, D, E, _ = np.linalg.solve(ata, atb[..., None])[..., 0].T
    den = 4 * C - B * B
    den = np.where(np.abs(den) > 1e-12, den, 1e-12)
    return np.column_stack([(B * E - 2 * C * D) / den, (B * D - 2 * E) / den])


# ------------------------------------------------------------------------------------------ indexing


# ------------------------------------------------------------------------------------------ sets


