"""Dot extraction: find the dots of a calibration plate in an image, refine their centres to sub-pixel
accuracy and index them ``[row, col]`` on the plate (DATA_FORMAT.md ``extract``; the paper's §3 input).

Pipeline for one image (OpenCV throughout):

1. **Background** (illumination and vignetting): a max filter, for dark dots, on an 8× reduced image,
   smoothed and enlarged back. Pixels darker than ``threshold`` × background are dot pixels.
2. **Blobs**: external contours of the dot mask (``cv2.findContours``); blobs touching the image border
   (partly visible dots), too small or large against the median, or not round enough are rejected.
3. **Sub-pixel centres**, two estimators, both flat-fielded by a background plane fitted per dot on a ring
   around it (so vignetting does not pull the centre):

   * ``moments``: intensity-weighted centroid of ``1 − I/B`` inside an anti-aliased circular window,
     iterated so the window is centred on the estimate;
   * ``ellipse``: half-contrast crossings along 48 rays, fitted by an ellipse (algebraic least squares).

   Measured on rendered sets (``python -m slmlab bench``, notebook 02) ``moments`` is the more accurate, and
   the default.
4. **Indexing**: the lattice directions from nearest-neighbour vectors (any rotation), a breadth-first walk
   over the lattice that follows its local spacing (distortion, perspective), then a quadratic lattice model
   that recovers dots the walk missed and drops blobs that are off the lattice (spurious). Absolute indices:
   when fewer rows (columns) are seen than the plate has, the side where the lattice runs out of the image is
   the side the missing ones are on; when that cannot be told, the image is reported as not indexed.
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

__all__ = ["Blobs", "ImageDots", "read_image", "estimate_background", "find_blobs", "refine_moments",
           "refine_ellipse", "index_lattice", "extract_image", "extract_set", "extraction_errors",
           "extraction_summary", "extract_folder", "error_by_defocus", "extract_stereo_pairs", "measured_centres",
           "IMAGE_NAME"]

IMAGE_NAME = re.compile(r"^(?P<sequence>.+)_(?P<position>\d{3,})_(?P<side>[lr])\.png$")
METHODS = ("moments", "ellipse")


# ------------------------------------------------------------------------------------------ reading
def read_image(path: str | Path) -> np.ndarray:
    """Read an image as 8-bit grey levels; unreadable or truncated files are a :class:`SlmlabError`."""
    path = Path(path)
    if not path.exists():
        raise SlmlabError("image not found", path)
    if path.is_dir():
        raise SlmlabError("is a folder, not an image", path)
    data = np.fromfile(path, dtype=np.uint8)
    img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    if img is None:
        raise SlmlabError("cannot be read as an image (unreadable or truncated); re-render or re-export it", path)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    if img.dtype != np.uint8:
        img = cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    return img


# ------------------------------------------------------------------------------------------ detection
def estimate_background(img: np.ndarray, *, dark: bool = True, reduce: int = 8, window_px: int = 160) -> np.ndarray:
    """Smooth illumination under the dots [grey levels, float32], by a max (min) filter at 1/``reduce``
    scale over ``window_px`` (larger than a dot)."""
    h, w = img.shape
    small = cv2.resize(img, (max(w // reduce, 1), max(h // reduce, 1)), interpolation=cv2.INTER_AREA)
    k = max(3, int(window_px / reduce) | 1)
    kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (k, k))
    small = cv2.dilate(small, kernel) if dark else cv2.erode(small, kernel)
    small = cv2.GaussianBlur(small.astype(np.float32), (0, 0), k / 2)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)


@dataclass
class Blobs:
    """Candidate dots of one image: first-guess centres ``(n, 2)`` [px], areas [px²], equivalent radii [px]
    and whether each has a hole (a donut marker)."""

    centres: np.ndarray
    areas: np.ndarray
    radii: np.ndarray
    holes: np.ndarray
    rejected: int = 0


def find_blobs(img: np.ndarray, *, dark: bool = True, threshold: float = 0.6, background: np.ndarray | None = None,
               min_area_px: float = 12.0) -> Blobs:
    """Dots as external contours of the pixels darker (brighter) than ``threshold`` × background.

    Blobs touching the border, much smaller or larger than the median, or not round are rejected (counted in
    ``rejected``).
    """
    bg = estimate_background(img, dark=dark) if background is None else background
    if dark:
        mask = cv2.compare(img, np.clip(threshold * bg, 0, 255).astype(np.uint8), cv2.CMP_LT)
    else:
        mask = cv2.compare(img, np.clip(bg + (1 - threshold) * (255 - bg), 0, 255).astype(np.uint8), cv2.CMP_GT)
    contours, hierarchy = cv2.findContours(mask, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
    h, w = img.shape
    cents, areas, holes = [], [], []
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
            if not (0.6 < fill < 0.95 and 0.5 < bw / bh < 2.0):
                rejected += 1
                continue
            m = cv2.moments(cnt)
            cents.append((m["m10"] / m["m00"], m["m01"] / m["m00"]))
            areas.append(area)
            holes.append(hier[k, 2] != -1)
    cents = np.asarray(cents, float).reshape(-1, 2)
    areas = np.asarray(areas, float)
    holes = np.asarray(holes, bool)
    if len(areas):
        med = np.median(areas)
        ok = (areas > 0.5 * med) & (areas < 1.6 * med)  # two touching blobs (dust on a dot) are ~2x
        rejected += int((~ok).sum())
        cents, areas, holes = cents[ok], areas[ok], holes[ok]
    return Blobs(cents, areas, np.sqrt(areas / np.pi), holes, rejected)


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
    b = np.maximum(_plane(coef, ox[None], oy[None]), 1.0)
    contrast = (1.0 - p / b) if dark else (p / b - 1.0)
    return _Flat(base, ox, oy, contrast, coef)


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
    h, w = img.shape
    x = np.clip(x, 0, w - 1.001)
    y = np.clip(y, 0, h - 1.001)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - x0, y - y0
    f = img.astype(np.float32) if img.dtype != np.float32 else img
    return ((1 - fx) * (1 - fy) * f[y0, x0] + fx * (1 - fy) * f[y0, x0 + 1]
            + (1 - fx) * fy * f[y0 + 1, x0] + fx * fy * f[y0 + 1, x0 + 1])


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
    t = np.linspace(0, 2 * np.pi, rays, endpoint=False)
    steps = np.linspace(0.0, 1.0, 96)
    rad = steps * reach
    ox = np.cos(t)[None, :, None] * rad[None, None, :]                          # (1, R, S) offsets
    oy = np.sin(t)[None, :, None] * rad[None, None, :]
    core = max(2, int(0.5 * len(steps) * r / reach))
    for _ in range(iterations):
        f = c - flat.base
        vals = _bilinear(img, c[:, 0, None, None] + ox, c[:, 1, None, None] + oy)
        b = np.maximum(_plane(flat.coef, ox + f[:, 0, None, None], oy + f[:, 1, None, None]), 1.0)
        con = (1.0 - vals / b) if dark else (vals / b - 1.0)
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


def _absolute(lat: Lattice, on: np.ndarray, rows: int, cols: int, image_size: tuple[int, int], margin_px: float):
    """Turn relative lattice indices into plate ``[row, col]`` (1-based); ``None`` if ambiguous."""
    w, h = image_size
    a, b = lat.a[on], lat.b[on]
    out = []
    for idx, other, count in ((a, b, cols), (b, a, rows)):
        lo, hi = idx.min(), idx.max()
        span = hi - lo + 1
        if span > count:
            return None, f"{span} lattice lines seen where the plate has {count}"
        if span == count:
            out.append(idx - lo + 1)
            continue
        others = np.arange(other.min(), other.max() + 1)

        def outside(k):
            if idx is a:
                p = lat.predict(np.full(len(others), k), others)
            else:
                p = lat.predict(others, np.full(len(others), k))
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


def _marker_indices(lat: Lattice, on: np.ndarray, holes: np.ndarray, origin: tuple[int, int]):
    """Plate ``[row, col]`` from three marker dots (donuts) forming an L on the lattice: the corner marker is
    ``origin``, columns count towards the marker on its row, rows towards the marker on its column."""
    from itertools import permutations

    idx = np.flatnonzero(on & holes)
    for k0, kx, ky in permutations(idx, 3):
        if lat.b[kx] == lat.b[k0] and lat.a[ky] == lat.a[k0] and kx != ky:
            sa = np.sign(lat.a[kx] - lat.a[k0])
            sb = np.sign(lat.b[ky] - lat.b[k0])
            col = sa * (lat.a[on] - lat.a[k0]) + origin[1]
            row = sb * (lat.b[on] - lat.b[k0]) + origin[0]
            return (row, col), ""
    return None, f"{len(idx)} marker dot(s) found but no three of them form an L on the lattice"


@dataclass
class ImageDots:
    """Dots found in one image: ``table`` with ``row, col, w1, w2, marker``; counts and a note."""

    table: pd.DataFrame
    found: int
    rejected: int
    spurious: int
    note: str = ""
    lattice: Lattice | None = field(default=None, repr=False)


def extract_image(img: np.ndarray, rows: int, cols: int, *, method: str = "moments", dark: bool = True,
                  dot_diameter_px: float | None = None, anchor: str = "plate",
                  marker_origin: tuple[int, int] = (2, 2)) -> ImageDots:
    """Find, refine and index the dots of a ``rows × cols`` plate in one 8-bit image.

    Parameters
    ----------
    img
        grey-level image.
    rows, cols
        the plate's size.
    method
        ``'moments'`` (default) or ``'ellipse'`` (see :func:`refine_moments`, :func:`refine_ellipse`).
    dark
        dark dots on a bright plate.
    dot_diameter_px
        expected dot diameter [px] if known (for the border margin of the indexing).
    anchor
        ``'plate'``: absolute indices from the plate's size and where the lattice leaves the image;
        ``'markers'``: from three donut markers forming an L (targets that overfill the field, e.g. DICe's),
        the corner marker at ``marker_origin`` ``(row, col)``.
    """
    if method not in METHODS:
        raise SlmlabError(f"unknown centre method {method!r}; use one of {', '.join(METHODS)}")
    blobs = find_blobs(img, dark=dark)
    empty = pd.DataFrame({"row": pd.Series(dtype=int), "col": pd.Series(dtype=int), "w1": pd.Series(dtype=float),
                          "w2": pd.Series(dtype=float), "marker": pd.Series(dtype=bool)})
    if len(blobs.centres) < 4:
        return ImageDots(empty, len(blobs.centres), blobs.rejected, 0, "fewer than 4 dots found")
    refine = refine_moments if method == "moments" else refine_ellipse
    centres = refine(img, blobs.centres, blobs.radii, dark=dark)
    lat, on = index_lattice(centres)
    spurious = int((~on).sum())
    radius = (dot_diameter_px / 2) if dot_diameter_px else float(np.median(blobs.radii))
    if anchor == "markers":
        ij, note = _marker_indices(lat, on, blobs.holes, marker_origin)
    else:
        ij, note = _absolute(lat, on, rows, cols, (img.shape[1], img.shape[0]), radius + 2)
    if ij is None:
        return ImageDots(empty, len(centres), blobs.rejected, spurious, note, lat)
    table = pd.DataFrame({"row": ij[0].astype(int), "col": ij[1].astype(int), "w1": centres[on, 0],
                          "w2": centres[on, 1], "marker": blobs.holes[on]})
    table = table.sort_values(["row", "col"]).reset_index(drop=True)
    return ImageDots(table, len(centres), blobs.rejected, spurious, note, lat)


# ------------------------------------------------------------------------------------------ sets
def extract_set(set_dir: str | Path, *, method: str = "moments", progress: bool | None = None) -> tuple[pd.DataFrame, list[str]]:
    """Extract every image of ``set_dir/images/`` into the rows of ``points.csv``.

    The stage positions are taken from the set's existing ``points.csv`` (re-extraction) or from
    ``stage.csv`` (columns ``sequence, position, stage_x_mm, stage_y_mm, stage_z_mm``). Returns the new
    points table and notes (images not indexed, spurious blobs dropped).
    """
    from tqdm import tqdm

    from .io import IMAGE_COLUMNS, POINT_COLUMNS, _read_meta, read_set

    set_dir = Path(set_dir)
    images = set_dir / "images"
    if not images.is_dir():
        raise SlmlabError("has no images/ folder; render one with 'simulate --images' or add "
                          "{sequence}_{position:03d}_{l|r}.png files", set_dir)
    meta = _read_meta(set_dir / "meta.json")
    files = sorted(p for p in images.iterdir() if IMAGE_NAME.match(p.name))
    if not files:
        raise SlmlabError("images/ holds no file named {sequence}_{position:03d}_{l|r}.png", images)
    if (set_dir / "points.csv").exists():
        stage = read_set(set_dir).points[["sequence", "position", "stage_x_mm", "stage_y_mm", "stage_z_mm"]]
    elif (set_dir / "stage.csv").exists():
        stage = pd.read_csv(set_dir / "stage.csv")
    else:
        raise SlmlabError("needs the stage positions: a points.csv to re-extract, or stage.csv with sequence, "
                          "position, stage_x_mm, stage_y_mm, stage_z_mm", set_dir)
    stage = stage.drop_duplicates(["sequence", "position"]).set_index(["sequence", "position"])
    pairs: dict[tuple[str, int], dict[str, Path]] = {}
    for f in files:
        m = IMAGE_NAME.match(f.name)
        pairs.setdefault((m["sequence"], int(m["position"])), {})[m["side"]] = f
    notes, frames = [], []
    size = None
    for (seq, pos), sides in tqdm(sorted(pairs.items()), desc="extracting", unit="pair",
                                  disable=None if progress is None else not progress):
        if (seq, pos) not in stage.index:
            raise SlmlabError(f"no stage position for sequence {seq}, position {pos}", set_dir / "points.csv")
        plate = meta["plates"]["grid" if seq == "grid" else "moving"]
        per_side = {}
        for side in "lr":
            if side not in sides:
                notes.append(f"{seq} position {pos}: no {side} image")
                continue
            img = read_image(sides[side])
            if size is None:
                size = img.shape
            elif img.shape != size:
                raise SlmlabError(f"is {img.shape[1]} × {img.shape[0]} px but the other images are "
                                  f"{size[1]} × {size[0]}; all images of a set must have one size", sides[side])
            dots = extract_image(img, int(plate["rows"]), int(plate["cols"]), method=method)
            if dots.note:
                notes.append(f"{sides[side].name}: not indexed ({dots.note})")
            if dots.spurious:
                notes.append(f"{sides[side].name}: {dots.spurious} blob(s) off the lattice dropped")
            per_side[side] = dots.table.set_index(["row", "col"])[["w1", "w2"]]
        i, j = np.meshgrid(np.arange(1, int(plate["rows"]) + 1), np.arange(1, int(plate["cols"]) + 1), indexing="ij")
        df = pd.DataFrame({"row": i.ravel(), "col": j.ravel()}).set_index(["row", "col"])
        for side in "lr":
            t = per_side.get(side)
            df[f"w{side}1"] = t["w1"].reindex(df.index) if t is not None else np.nan
            df[f"w{side}2"] = t["w2"].reindex(df.index) if t is not None else np.nan
        df = df.reset_index()
        st = stage.loc[(seq, pos)]
        df.insert(0, "sequence", seq)
        df.insert(1, "position", pos)
        for c in ("stage_x_mm", "stage_y_mm", "stage_z_mm"):
            df[c] = float(st[c])
        frames.append(df[POINT_COLUMNS])
    points = pd.concat(frames, ignore_index=True)
    points = points[points[IMAGE_COLUMNS].notna().any(axis=1)].reset_index(drop=True)
    return points, notes


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
