"""Dot extraction from one image: find the dots of a calibration plate, refine their centres to sub-pixel
accuracy and index them on the plate's lattice (DATA_FORMAT.md ``extract``; the paper's §3 input).

Pipeline for one image (OpenCV throughout), for images as a camera writes them (8 or 16 bit, any format
OpenCV reads, dark dots on a bright plate or bright dots on black):

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
5. **Indexing**: the lattice directions from nearest-neighbour vectors (any rotation), a breadth-first walk
   over the lattice that follows its local spacing (distortion, perspective), then a quadratic lattice model
   that recovers dots the walk missed and drops blobs that are off the lattice (spurious). A **two-level**
   plate (rows alternating between two depths, offset by half a pitch) is one lattice rotated by 45° in the
   image; its indices are turned into half-pitch plate units, where the two levels are the two parities.
6. **Absolute indices** (:func:`anchor_image`): from the plate's size and where the lattice runs out of the
   image (whole plate in view), or from markers (a donut L as on DICe targets; a square and a triangle as on
   stereo-PIV plates; a frame around the origin dot). Images that cannot be anchored alone are anchored from
   a neighbouring image of the same view by :mod:`slmlab.imageset`.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
from scipy.spatial import cKDTree

from .errors import SlmlabError

__all__ = ["Blobs", "ImageDots", "Marker", "read_image", "dot_polarity", "estimate_background", "find_blobs",
           "refine_moments", "refine_ellipse", "index_lattice", "plate_lattice", "anchor_image", "extract_image",
           "extract_set", "extraction_errors", "extraction_summary", "extract_folder", "error_by_defocus",
           "extract_stereo_pairs", "measured_centres", "lattice_residual_px", "choose_method", "IMAGE_NAME",
           "METHODS"]

IMAGE_NAME = re.compile(r"^(?P<sequence>.+)_(?P<position>\d{3,})_(?P<side>[lr])\.png$")
METHODS = ("moments", "ellipse")
#: ``method="auto"`` takes the ellipse estimator only where its centres lie this much more smoothly on the
#: lattice than the moments' (real, textured dots); otherwise moments, the more accurate on uniform dots
AUTO_ELLIPSE_RATIO = 0.7


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
@dataclass
class Lattice:
    """Relative lattice coordinates of the indexed blobs: ``a`` along the rows (≈ w1), ``b`` along the
    columns (≈ w2), and the quadratic model ``(a, b) → (w1, w2)``."""

    a: np.ndarray
    b: np.ndarray
    coef: np.ndarray
    pitch_px: float

    def predict(self, a, b) -> np.ndarray:
        a, b = np.asarray(a, float), np.asarray(b, float)
        m = np.stack([np.ones_like(a), a, b, a * a, a * b, b * b], axis=-1)
        return m @ self.coef


def _lattice_basis(c: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    tree = cKDTree(c)
    d, nn = tree.query(c, k=min(5, len(c)))
    pitch = float(np.median(d[:, 1]))
    vec = (c[nn[:, 1:]] - c[:, None, :]).reshape(-1, 2)
    length = np.hypot(vec[:, 0], vec[:, 1])
    vec = vec[(length > 0.75 * pitch) & (length < 1.3 * pitch)]
    ang = np.arctan2(vec[:, 1], vec[:, 0])
    phi = np.angle(np.mean(np.exp(4j * ang))) / 4  # lattice orientation, modulo 90°
    axes = []
    for direction in (phi, phi + np.pi / 2):
        dirv = np.array([np.cos(direction), np.sin(direction)])
        proj = vec @ dirv
        sel = np.abs(np.abs(proj) / np.hypot(vec[:, 0], vec[:, 1]) - 1) < 0.06
        v = vec[sel] * np.sign(proj[sel])[:, None]
        axes.append(np.median(v, axis=0) if len(v) else dirv * pitch)
    u, v = axes
    # u: the axis closer to the image rows (w1), pointing to +w1; v towards +w2
    if abs(u[0]) < abs(v[0]):
        u, v = v, u
    u = u if u[0] > 0 else -u
    v = v if v[1] > 0 else -v
    return u, v, pitch


def index_lattice(c: np.ndarray, *, tolerance: float = 0.3) -> tuple[Lattice | None, np.ndarray]:
    """Relative lattice indices of blob centres ``(n, 2)`` [px].

    Returns the lattice (or ``None`` with fewer than 4 blobs) and a boolean mask of the blobs on it.
    """
    n = len(c)
    on = np.zeros(n, bool)
    if n < 4:
        return None, on
    u, v, pitch = _lattice_basis(c)
    tree = cKDTree(c)
    a = np.zeros(n, int)
    b = np.zeros(n, int)
    seed = int(np.argmin(np.hypot(*(c - np.median(c, axis=0)).T)))
    on[seed] = True
    # breadth-first walk, one KD-tree query per frontier; each dot carries the local steps (u, v) it was
    # reached with, so the walk follows gradual changes of spacing and direction (distortion, perspective)
    frontier = np.array([seed])
    lu, lv = np.tile(u, (n, 1)), np.tile(v, (n, 1))
    moves = np.array([(1, 0), (-1, 0), (0, 1), (0, -1)])
    tol = tolerance * pitch
    while len(frontier):
        nxt = []
        for mult in (1, 2):
            src = np.repeat(frontier, 4)
            mv = np.tile(moves, (len(frontier), 1))
            step = lu[src] * mv[:, :1] + lv[src] * mv[:, 1:]
            dist, m = tree.query(c[src] + mult * step)
            for k, mm, (da, db), dd in zip(src, m, mv, dist):
                if dd < tol * mult and not on[mm]:
                    on[mm] = True
                    a[mm], b[mm] = a[k] + mult * da, b[k] + mult * db
                    actual = (c[mm] - c[k]) / mult
                    lu[mm] = actual * da if da else lu[k]
                    lv[mm] = actual * db if db else lv[k]
                    nxt.append(mm)
        frontier = np.array(nxt, int)
    lat = None
    for _ in range(3):  # refine with a quadratic lattice model, recover and reject
        aa, bb = a[on].astype(float), b[on].astype(float)
        m = np.stack([np.ones_like(aa), aa, bb, aa * aa, aa * bb, bb * bb], axis=-1)
        if on.sum() < 8:
            m = m[:, :3]
        coef, *_ = np.linalg.lstsq(m, c[on], rcond=None)
        if coef.shape[0] == 3:
            coef = np.vstack([coef, np.zeros((3, 2))])
        lat = Lattice(a, b, coef, pitch)
        ga, gb = np.meshgrid(np.arange(a[on].min() - 1, a[on].max() + 2), np.arange(b[on].min() - 1, b[on].max() + 2))
        pred = lat.predict(ga.ravel(), gb.ravel())
        dist, m_idx = tree.query(pred)
        hit = dist < 0.25 * pitch
        new_on = np.zeros(n, bool)
        new_on[m_idx[hit]] = True
        a[m_idx[hit]], b[m_idx[hit]] = ga.ravel()[hit], gb.ravel()[hit]
        if (new_on == on).all():
            break
        on = new_on
    lat.a, lat.b = a, b
    return lat, on


@dataclass
class PlateLattice:
    """The dots on the lattice in plate units, oriented with the image.

    ``i1, i2`` are integer lattice coordinates of the on-lattice blobs ``index`` (into the blob arrays):
    ``i1`` grows along the lattice axis nearer ``+w1``, ``i2`` along the one nearer ``+w2``. The unit is the
    plate's pitch, or half of it on a two-level plate, whose two levels are then the two classes of ``i1``
    (and ``i2``) parity; the other lattice nodes (mixed parity) are holes, where such plates put their
    markers. ``lattice`` is the fitted lattice model of :func:`index_lattice`.
    """

    i1: np.ndarray
    i2: np.ndarray
    index: np.ndarray
    two_level: bool
    lattice: Lattice
    _ab: np.ndarray = field(repr=False, default=None)

    def to_ab(self, i1, i2) -> tuple[np.ndarray, np.ndarray]:
        """Lattice-model coordinates ``(a, b)`` of plate-unit coordinates (fractional allowed)."""
        m = self._ab  # (2, 2): (i1, i2) = m @ (a, b)
        inv = np.linalg.inv(m)
        i = np.stack([np.asarray(i1, float), np.asarray(i2, float)])
        ab = inv @ i.reshape(2, -1)
        return ab[0].reshape(np.shape(i1)), ab[1].reshape(np.shape(i1))

    def predict(self, i1, i2) -> np.ndarray:
        """Image positions ``(…, 2)`` [px] of plate-unit coordinates."""
        return self.lattice.predict(*self.to_ab(i1, i2))

    def locate(self, point) -> tuple[float, float]:
        """Plate-unit coordinates (fractional) of an image point [px], by Newton on the lattice model."""
        p = np.asarray(point, float)
        on = self.lattice.predict(self.lattice.a[self.index], self.lattice.b[self.index])
        k = int(np.argmin(np.hypot(*(on - p).T)))
        x = np.array([self.i1[k], self.i2[k]], float)
        for _ in range(4):
            f = self.predict(x[0], x[1])
            h = 1e-3
            jac = np.column_stack([(self.predict(x[0] + h, x[1]) - f) / h, (self.predict(x[0], x[1] + h) - f) / h])
            x = x + np.linalg.solve(jac, p - f)
        return float(x[0]), float(x[1])


def plate_lattice(lat: Lattice, on: np.ndarray, *, two_level: bool = False) -> PlateLattice:
    """:class:`PlateLattice` of an indexed lattice (:func:`index_lattice`). On a two-level plate the dots form
    one lattice rotated by 45°, whose steps ``u, v`` are half-diagonals of the plate's cell: a dot at
    ``a·u + b·v`` is at ``(a + b, a − b)`` half-pitches along the plate axes ``(u + v)/2`` and ``(u − v)/2``."""
    idx = np.flatnonzero(on)
    a, b = lat.a[idx].astype(float), lat.b[idx].astype(float)
    d = lat.coef[1:3]  # image steps of one unit of a and of b (at the lattice model's origin), rows u, v
    if two_level:
        axes = np.array([(d[0] + d[1]) / 2, (d[0] - d[1]) / 2])
        m = np.array([[1.0, 1.0], [1.0, -1.0]])
    else:
        axes = d.copy()
        m = np.eye(2)
    if abs(axes[0][0]) < abs(axes[1][0]):  # axis 1 is the one nearer w1
        axes, m = axes[::-1], m[::-1]
    if axes[0][0] < 0:
        m[0] = -m[0]
    if axes[1][1] < 0:
        m[1] = -m[1]
    i = m @ np.stack([a, b])
    return PlateLattice(np.rint(i[0]).astype(int), np.rint(i[1]).astype(int), idx, two_level, lat, m)


def _absolute(pl: PlateLattice, rows: int, cols: int, image_size: tuple[int, int], margin_px: float):
    """Plate ``[row, col]`` (1-based) of a whole plate of ``rows × cols`` dots in view (or cut by the image on
    one side of each axis): ``None`` and a reason if ambiguous."""
    w, h = image_size
    out = []
    for idx, other, count, axis in ((pl.i1, pl.i2, cols, 0), (pl.i2, pl.i1, rows, 1)):
        lo, hi = idx.min(), idx.max()
        span = hi - lo + 1
        if span > count:
            return None, f"{span} lattice lines seen where the plate has {count}"
        if span == count:
            out.append(idx - lo + 1)
            continue
        others = np.arange(other.min(), other.max() + 1)

        def outside(k):
            if axis == 0:
                p = pl.predict(np.full(len(others), k), others)
            else:
                p = pl.predict(others, np.full(len(others), k))
            return bool(np.any((p[:, 0] < margin_px) | (p[:, 0] > w - 1 - margin_px)
                               | (p[:, 1] < margin_px) | (p[:, 1] > h - 1 - margin_px)))
        before, after = outside(lo - 1), outside(hi + 1)
        if before and not after:
            out.append(idx - hi + count)
        elif after and not before:
            out.append(idx - lo + 1)
        else:
            return None, "the plate is cut on both sides or not at all, but dots are missing"
    return (out[1], out[0]), ""


def _donut_indices(pl: PlateLattice, holes: np.ndarray, origin: tuple[int, int]):
    """Plate ``[row, col]`` from three donut markers forming an L on the lattice (DICe targets): the corner
    marker is ``origin``, columns count towards the marker on its row, rows towards the marker on its
    column."""
    from itertools import permutations

    idx = np.flatnonzero(holes[pl.index])
    for k0, kx, ky in permutations(idx, 3):
        if pl.i2[kx] == pl.i2[k0] and pl.i1[ky] == pl.i1[k0] and kx != ky:
            s1 = np.sign(pl.i1[kx] - pl.i1[k0])
            s2 = np.sign(pl.i2[ky] - pl.i2[k0])
            col = s1 * (pl.i1 - pl.i1[k0]) + origin[1]
            row = s2 * (pl.i2 - pl.i2[k0]) + origin[0]
            return (row, col), ""
    return None, f"{len(idx)} donut marker(s) found but no three of them form an L on the lattice"


_UNITS = [np.array(v) for v in ((1, 0), (0, 1), (-1, 0), (0, -1))]


def _origin_frame(pl: PlateLattice, markers: list):
    """Plate-frame coordinates ``(x, y)`` [plate units] of the on-lattice dots from the plate's markers, and how.

    * a **square and a triangle** (stereo-PIV plates): the origin is the dot in the corner of the lattice
      cell the two markers span such that, seen from the camera, ``+x`` points from the origin to the
      triangle and ``+y`` to the square, 90° counter-clockwise from ``+x`` (a right-handed plate frame whose
      ``z`` points towards the camera); the other corner is the mirror image and is not a solution;
    * a **frame** around a dot: that dot is the origin, ``+x`` along the image's ``w1`` and ``+y`` against
      ``w2`` (up in the image).
    """
    kinds = {}
    for m in markers:
        kinds.setdefault(m.kind, []).append(m)
    if len(kinds.get("triangle", [])) == 1 and len(kinds.get("square", [])) == 1:
        t = np.rint(pl.locate(kinds["triangle"][0].centre)).astype(int)
        s = np.rint(pl.locate(kinds["square"][0].centre)).astype(int)
        dots = set(zip(pl.i1.tolist(), pl.i2.tolist()))
        for ex in _UNITS:
            n = t - ex
            ey = s - n
            # counter-clockwise on screen (w2 down): (d1, d2) -> (d2, -d1)
            if np.array_equal(ey, np.array([ex[1], -ex[0]])):
                if pl.two_level and (n[0] + n[1]) % 2:
                    continue
                rel = np.stack([pl.i1 - n[0], pl.i2 - n[1]], axis=1)
                how = ("square and triangle markers" + ("" if tuple(n) in dots else " (origin dot not seen)"))
                return (rel @ ex, rel @ ey), how
        return None, "a square and a triangle marker were found but do not span one lattice cell"
    frames = kinds.get("frame", [])
    if len(frames) == 1:
        n = np.rint(pl.locate(frames[0].centre)).astype(int)
        return ((pl.i1 - n[0]), -(pl.i2 - n[1])), "a frame around the origin dot"
    if markers:
        found = ", ".join(f"{len(v)} {k}" for k, v in kinds.items())
        return None, f"markers found ({found}) but not a square and a triangle, nor one frame"
    return None, "no markers found"


def lattice_residual_px(table: pd.DataFrame) -> float:
    """How smoothly the centres of one image lie on their lattice [px]: the RMS residual (per coordinate,
    net of the fitted parameters) of a cubic in the lattice coordinates ``i1, i2`` fitted to ``w1, w2``, per
    level. Distortion and perspective are smooth and absorbed; what is left is the centres' own scatter, and
    a centre estimator's error that varies from dot to dot (texture, dust, scratches on real plates)."""
    sse, dof = 0.0, 0
    for _, s in table.groupby("level"):
        if len(s) < 12:
            continue
        x, y = s["i1"].to_numpy(float), s["i2"].to_numpy(float)
        x, y = (x - x.mean()) / max(x.std(), 1.0), (y - y.mean()) / max(y.std(), 1.0)
        a = np.column_stack([x ** i * y ** j for i in range(4) for j in range(4 - i)])
        w = s[["w1", "w2"]].to_numpy(float)
        coef, *_ = np.linalg.lstsq(a, w, rcond=None)
        sse += float(np.sum((w - a @ coef) ** 2))
        dof += 2 * (len(s) - a.shape[1])
    return float(np.sqrt(sse / dof)) if dof > 0 else float("nan")


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
        ``col = −xu`` up to one shift for the whole set: :mod:`slmlab.imageset` numbers them), or ``None``
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


def _empty_table() -> pd.DataFrame:
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
        return ImageDots(_empty_table(), len(blobs.centres), blobs.rejected, 0,
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
    frame, how, note = None, "", ""
    donuts = int(blobs.holes[k].sum())
    sized = rows is not None and cols is not None
    # polygon markers give an origin, for a plate whose size is unknown; a donut L numbers any plate
    use_markers = anchor == "markers" or (anchor == "auto" and (donuts >= 3 or (blobs.markers and not sized)))
    if use_markers and donuts >= 3:
        ij, note = _donut_indices(pl, blobs.holes, marker_origin)
        if ij is not None:
            table["row"], table["col"], frame, how = ij[0], ij[1], "plate", "an L of donut markers"
    elif use_markers:
        xy, msg = _origin_frame(pl, blobs.markers)
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
            radius = (dot_diameter_px / 2) if dot_diameter_px else float(np.median(blobs.radii))
            ij, note = _absolute(pl, rows, cols, (img.shape[1], img.shape[0]), radius + 2)
            if ij is not None:
                table["row"], table["col"], frame, how = ij[0], ij[1], "plate", "the plate's size"
    if frame is None:
        table["row"] = pd.Series(dtype=int)
        table["col"] = pd.Series(dtype=int)
    else:
        table = table.sort_values(["row", "col"], kind="stable").reset_index(drop=True)
    return ImageDots(table, len(centres), blobs.rejected, spurious, note if frame is None else "", pl, frame, how,
                     blobs.markers, dark)


# ------------------------------------------------------------------------------------------ sets
def extract_set(set_dir: str | Path, *, method: str = "auto", progress: bool | None = None):
    """Extract every image of a set into the rows of ``points.csv``: see :func:`slmlab.imageset.extract_set`."""
    from .imageset import extract_set as _extract_set

    return _extract_set(set_dir, method=method, progress=progress)


def extraction_errors(points: pd.DataFrame, cal) -> pd.DataFrame:
    """Extracted centres against a simulated set's truth: one row per dot and view seen in the truth image.

    Columns: ``sequence, position, row, col, view, z_mm`` (height above the focal plane), ``visible`` (the whole
    dot is inside the image), ``found`` (extracted and indexed at this ``[row, col]``), ``err1, err2`` [px]
    (extracted minus true centre). A dot indexed at the wrong place shows as a large error.
    """
    from .microscope import from_dict

    sim = cal.meta["simulator"]
    m = from_dict(sim["microscope"])
    truth = cal.truth
    z = m.stage_to_microscope(truth[["X_mm", "Y_mm", "Z_mm"]].to_numpy(), np.asarray(sim["stage_origin_mm"]))[:, 2]
    key = ["sequence", "position", "row", "col"]
    merged = truth[key].copy()
    ext = points.set_index(key)
    frames = []
    for side in "lr":
        tw = truth[[f"w{side}1", f"w{side}2"]].to_numpy()
        diam = cal.meta["plates"]["moving"]["dot_diameter_mm"]
        diam_grid = cal.meta["plates"]["grid"]["dot_diameter_mm"]
        d = np.where(truth["sequence"].to_numpy() == "grid", diam_grid, diam)
        margin = d / m.optics.pixel_mm / 2 + 2
        w, h = m.optics.image_size_px
        vis = (tw[:, 0] >= margin) & (tw[:, 0] <= w - 1 - margin) & (tw[:, 1] >= margin) & (tw[:, 1] <= h - 1 - margin)
        e = ext.reindex(pd.MultiIndex.from_frame(truth[key]))[[f"w{side}1", f"w{side}2"]].to_numpy()
        f = merged.copy()
        f["view"] = side
        f["z_mm"] = z
        f["visible"] = vis
        f["found"] = np.isfinite(e).all(axis=1)
        f["err1"], f["err2"] = e[:, 0] - tw[:, 0], e[:, 1] - tw[:, 1]
        frames.append(f)
    return pd.concat(frames, ignore_index=True)


def extraction_summary(errors: pd.DataFrame, *, depth_of_field_mm: float = 1.13, in_focus_mm: float = 0.2,
                       misindexed_px: float = 1.0) -> dict:
    """Headline numbers of :func:`extraction_errors`: found and correctly indexed share of visible dots,
    centre RMS in focus (``|z| <= in_focus_mm``) and over the depth of field [px]."""
    vis = errors[errors["visible"]]
    err = np.hypot(vis["err1"], vis["err2"])
    good = vis["found"] & (err < misindexed_px)
    per_coord = lambda sel: float(np.sqrt(np.nanmean(np.r_[vis.loc[sel, "err1"], vis.loc[sel, "err2"]] ** 2)))  # noqa: E731
    focus = good & (vis["z_mm"].abs() <= in_focus_mm)
    dof = good & (vis["z_mm"].abs() <= depth_of_field_mm)
    return {
        "visible": int(len(vis)),
        "found_and_indexed_percent": float(100 * good.mean()) if len(vis) else float("nan"),
        "misindexed": int((vis["found"] & (err >= misindexed_px)).sum()),
        "rms_in_focus_px": per_coord(focus) if focus.any() else float("nan"),
        "rms_depth_of_field_px": per_coord(dof) if dof.any() else float("nan"),
        "extra_found": int((errors["found"] & ~errors["visible"]).sum()),
    }


def extract_folder(set_dir: str | Path, sequences: list[str], *, methods=METHODS) -> pd.DataFrame:
    """Per-dot extraction errors of a rendered simulated set for several centre methods.

    Returns :func:`extraction_errors` rows of the chosen sequences with a ``method`` column (for the error
    against defocus figure and the choice of the default method).
    """
    from .io import read_set

    set_dir = Path(set_dir)
    cal = read_set(set_dir)
    frames = []
    for method in methods:
        rows = []
        for seq in sequences:
            plate = cal.plate(seq)
            for pos in sorted(cal.sequence(seq)["position"].unique()):
                for side in "lr":
                    img = read_image(set_dir / "images" / f"{seq}_{pos:03d}_{side}.png")
                    t = extract_image(img, int(plate["rows"]), int(plate["cols"]), method=method).table
                    t = t.rename(columns={"w1": f"w{side}1", "w2": f"w{side}2"})[["row", "col", f"w{side}1", f"w{side}2"]]
                    t.insert(0, "sequence", seq)
                    t.insert(1, "position", pos)
                    rows.append(t.set_index(["sequence", "position", "row", "col"]))
        pts = pd.concat(rows).groupby(level=[0, 1, 2, 3]).first().reset_index()
        sub = cal.truth["sequence"].isin(sequences)
        from .io import CalibrationSet

        err = extraction_errors(pts, CalibrationSet(pts, cal.meta, cal.truth[sub].reset_index(drop=True)))
        err.insert(0, "method", method)
        frames.append(err)
    return pd.concat(frames, ignore_index=True)


def error_by_defocus(errors: pd.DataFrame, *, bin_mm: float = 0.25) -> pd.DataFrame:
    """Centre RMS per coordinate [px] of found, correctly indexed, visible dots, by method and depth bin."""
    e = errors[errors["visible"] & errors["found"]].copy()
    e = e[np.hypot(e["err1"], e["err2"]) < 1.0]
    e["z_bin_mm"] = np.round(e["z_mm"] / bin_mm) * bin_mm
    g = e.groupby(["method", "z_bin_mm"])
    return pd.DataFrame({
        "rms_px": g.apply(lambda d: float(np.sqrt(np.mean(np.r_[d["err1"], d["err2"]] ** 2))), include_groups=False),
        "dots": g.size(),
    }).reset_index()


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


def measured_centres(errors: pd.DataFrame, truth: pd.DataFrame, sequence: str, position: int, view: str,
                     method: str = "moments") -> pd.DataFrame:
    """The extracted centres ``row, col, w1, w2`` [px] of one image, rebuilt from :func:`extract_folder`'s
    errors and the truth (extracted = true + error)."""
    e = errors[(errors["method"] == method) & (errors["sequence"] == sequence) & (errors["position"] == position)
               & (errors["view"] == view) & errors["found"]].set_index(["row", "col"])
    t = truth[(truth["sequence"] == sequence) & (truth["position"] == position)].set_index(["row", "col"])
    t = t.loc[e.index]
    return pd.DataFrame({"w1": t[f"w{view}1"] + e["err1"], "w2": t[f"w{view}2"] + e["err2"]}).reset_index()
