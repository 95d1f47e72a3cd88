"""The plate's markers in one image: what they are and where (the numbering's anchors, :mod:`slmlab.images.lattice`).

1. **Shapes off the lattice** (:func:`off_lattice_markers`): candidates away from every lattice node whose
   outline, read at full resolution against the background at each pixel (:func:`_outlines`), is a triangle,
   a square (:func:`polygon_kind`) or a square frame around a dot.
2. **Shapes joined to a dot** (:func:`joined_markers`): where parallax brings a two-level plate's dot beside a
   marker, the reduced image joins them; a dot of the lattice larger than the others is read apart at full
   resolution (:func:`split_marker`).
3. **Blobs in holes**: on a two-level plate, a solid blob at the centre of a lattice cell (:func:`in_hole`)
   whose shape blur hid stands for either marker (:func:`slmlab.images.lattice.origin_frame` tells them apart
   by their places); where fewer than two were read, holes that stand out of their neighbours
   (:func:`filled_holes`).
4. **Painting out** (:func:`painted_out`): on a two-level plate a solid marker read from its outline is
   replaced by the local background as far as its blurred edge reaches, no nearer a dot than to it, so that it
   does not pull the dot's centre (a filled hole has no outline and is left).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree

from .dots import LOWEST_SIGMA, Candidates, Contrast, gather_patches
from .lattice import LatticeFit, inside_image
from .robust import robust_sigma

__all__ = ["Marker", "polygon_kind", "marker_kind", "split_marker", "marker_outline", "painted_out", "MERGED_AREA",
           "PLAIN_SHARE", "near_median", "local_peak", "HOLE_SIGMAS", "distinct_markers", "in_hole",
           "off_lattice_markers", "joined_markers", "filled_holes"]


@dataclass
class Marker:
    """A marker on the plate: ``kind`` (``'triangle'``, ``'square'``, ``'frame'``: a frame around a dot) and
    its centre ``(w1, w2)`` [px]."""

    kind: str
    centre: tuple[float, float]


def polygon_kind(cnt, area: float, has_hole: bool) -> str | None:
    """``'triangle'``, ``'square'`` or ``'frame'`` (a square outline around a dot) for a contour large
    enough to show its shape (≥ 100 px², read at full resolution); ``None`` for anything else (a dot, dust).

    By two fills that an affine view leaves unchanged: of the smallest enclosing triangle (about 0.9 for a
    triangle, ``π/3√3`` = 0.60 for any ellipse, 0.5 for a square) and of the smallest enclosing rectangle
    (about 1 for a square, ``π/4`` for any ellipse)."""
    if area < 100:
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


def _half_side(con: Contrast, cand: Candidates, k: int, widest: bool = False) -> int:
    """Half the side [px] of the full-resolution patch :func:`_outlines` reads candidate ``k`` on: around its
    outline at its reference level, or (``widest``) at the lowest level it was seen at, where a marker beside it
    is joined to it."""
    return int(np.ceil(max(cand.low_size[k] if widest else cand.size[k]) / 2 + 3 * con.scale))


def _outlines(img: np.ndarray, con: Contrast, cand: Candidates, k: int, level: float, widest: bool = False):
    """The outlines of candidate ``k`` at ``level`` [noise σ] on the full-resolution image (lightly smoothed)
    against the local background and spread at the candidate, on the patch of :func:`_half_side`: the contours
    (full-image pixels) and their hierarchy (:func:`cv2.findContours`, two levels)."""
    half = _half_side(con, cand, k, widest)
    p, base = gather_patches(img, cand.xy[k:k + 1], half)
    # the background and spread at every pixel of the patch (bilinear on the reduced mesh): a window streak
    # or a gradient across a marker would join its outline to the background's
    g = np.arange(-half, half + 1, dtype=np.float32)
    mx, my = np.meshgrid(*(con.to_reduced(np.column_stack([base[0, 0] + g, base[0, 1] + g])).T.astype(np.float32)))
    background, spread = (cv2.remap(m.astype(np.float32), mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
                          for m in (con.background, con.spread))
    z = (cv2.GaussianBlur(p[0].astype(np.float32), (0, 0), 1.0) - background) / spread
    contours, hier = cv2.findContours(((-z if con.dark else z) > level).astype(np.uint8), cv2.RETR_CCOMP,
                                      cv2.CHAIN_APPROX_NONE, offset=tuple(int(v) for v in base[0] - half))
    return contours, (hier[0] if contours else np.empty((0, 4), int))


def _outer(img: np.ndarray, con: Contrast, cand: Candidates, k: int, level: float, widest: bool = False) -> list:
    """The outer outlines of candidate ``k`` at ``level`` (:func:`_outlines`) that the patch does not cut (a
    piece of a neighbour at its edge): each ``(contour, area [px²], centroid [px], solid)``."""
    contours, hier = _outlines(img, con, cand, k, level, widest)
    half = _half_side(con, cand, k, widest)
    lo, hi = np.rint(cand.xy[k]).astype(int) - half, np.rint(cand.xy[k]).astype(int) + half
    parts = []
    for j, hh in enumerate(hier):
        c = contours[j].reshape(-1, 2)
        if hh[3] == -1 and (c > lo).all() and (c < hi).all():
            m = cv2.moments(contours[j].astype(np.float32))
            centre = np.array([m["m10"], m["m01"]]) / max(m["m00"], 1e-9)
            parts.append((contours[j], m["m00"], centre, not (hier[:, 3] == j).any()))
    return parts


def marker_kind(img: np.ndarray, con: Contrast, cand: Candidates, k: int, level: float) -> str | None:
    """Shape of candidate ``k`` (``'triangle'``, ``'square'``, ``'frame'`` or ``None``) by :func:`polygon_kind`
    on its largest outline at ``level`` [noise σ] (:func:`_outlines`): on the reduced image a small dot's
    outline is a polygon of a few pixels, which may pass for a square."""
    contours, hier = _outlines(img, con, cand, k, level)
    if not contours:
        return None
    outer = [c for c, hh in zip(contours, hier) if hh[3] == -1]
    cnt = max(outer, key=cv2.contourArea).astype(np.float32)
    area = cv2.contourArea(cnt)
    holes = [cv2.contourArea(c) for c, hh in zip(contours, hier) if hh[3] != -1]
    return polygon_kind(cnt, area, bool(holes) and max(holes) >= 0.03 * area)


def split_marker(img: np.ndarray, con: Contrast, cand: Candidates, k: int, level: float, node_xy, tol_px: float,
                 dot_area_px: float, widest: bool = False):
    """A solid marker (triangle or square) that the reduced image joined to the dot of candidate ``k``: of the
    separate outlines at ``level`` [noise σ] on the full-resolution image (:func:`_outlines`; with ``widest`` on a
    patch around the blob at the lowest level it was seen at, where the marker was part of it), one is the dot
    (the outline nearest its lattice node ``node_xy`` [px], within ``tol_px``, of at least half the dots'
    area ``dot_area_px`` at their reference level) and the largest other one a solid shape of 0.1-1 of the dot's
    area at that level (not a glyph of a text strip that the lattice crosses): the :class:`Marker`
    :func:`polygon_kind` names, or a ``'blob'`` if it is a quarter of the dot's area or more and 1.5 of its
    radii from it (at the outline's centroid), and its outline (full-image pixels); ``None`` if there is no
    such pair."""
    parts = [(c, area / dot_area_px, centre, solid)
             for c, area, centre, solid in _outer(img, con, cand, k, level, widest)]
    near = [np.hypot(*(p[2] - node_xy)) for p in parts]
    dot = [i for i in np.argsort(near, kind="stable") if near[i] < tol_px and parts[i][1] > 0.5][:1]
    others = [p for i, p in enumerate(parts) if dot and i != dot[0] and 0.1 < p[1] / parts[dot[0]][1] < 1]
    if not others:
        return None
    cnt, share, centre, solid = max(others, key=lambda p: p[1])
    dot_area, dot_centre = parts[dot[0]][1], parts[dot[0]][2]
    kind = polygon_kind(cnt.astype(np.float32), share * dot_area_px, False) if solid else None
    if kind not in ("triangle", "square"):   # a blob: as large as a marker, beside the dot, not a piece of it
        apart = np.hypot(*(centre - dot_centre)) > 1.5 * np.sqrt(dot_area * dot_area_px / np.pi)
        kind = "blob" if solid and share >= 0.25 * dot_area and apart else None
    return None if kind is None else (Marker(kind, (float(centre[0]), float(centre[1]))), cnt)


def marker_outline(img: np.ndarray, con: Contrast, cand: Candidates, k: int, level: float) -> np.ndarray | None:
    """The outline of candidate ``k`` at ``level`` [noise σ] that holds its centre (:func:`_outer`; full-image
    pixels), not a piece of a neighbour beside it; ``None`` if none does."""
    xy = tuple(float(v) for v in cand.xy[k])
    held = [c for c, _, _, _ in _outer(img, con, cand, k, level) if cv2.pointPolygonTest(c, xy, False) >= 0]
    return held[0] if held else None


def painted_out(img: np.ndarray, outlines: list, values: list, grow_px: int, dots_xy: np.ndarray,
                dot_radius_px: float) -> np.ndarray:
    """A copy of ``img`` with the shapes inside ``outlines`` (contours, full-image pixels) set to ``values``
    (the local background), grown by up to ``grow_px`` (their blurred edge) but only over pixels nearer the
    shape than the outline of every dot (centres ``dots_xy`` [px], radius ``dot_radius_px``): a marker beside
    a dot, so that it does not pull the dot's centre."""
    out = img.copy()
    h, w = img.shape
    tree = cKDTree(dots_xy)
    if np.issubdtype(img.dtype, np.integer):   # the background rounded into the image's range
        info = np.iinfo(img.dtype)
        values = [np.clip(np.rint(v), info.min, info.max) for v in values]
    for cnt, value in zip(outlines, values):
        x, y, bw, bh = cv2.boundingRect(cnt)
        x0, y0, x1, y1 = max(x - grow_px, 0), max(y - grow_px, 0), min(x + bw + grow_px, w), min(y + bh + grow_px, h)
        inside = np.full((y1 - y0, x1 - x0), 255, np.uint8)
        cv2.drawContours(inside, [cnt - np.array([x0, y0])], -1, 0, cv2.FILLED)
        to_shape = cv2.distanceTransform(inside, cv2.DIST_L2, 5)
        yy, xx = np.mgrid[y0:y1, x0:x1]
        to_dot = tree.query(np.column_stack([xx.ravel(), yy.ravel()]))[0].reshape(xx.shape) - dot_radius_px
        paint = (to_shape <= grow_px) & (to_shape < to_dot)
        out[y0:y1, x0:x1][paint] = value
    return out


#: a dot on the lattice this much larger than the dots' median area may hold a marker that the reduced image
#: joined to it (a two-level plate's parallax brings the other level's dots beside its markers): it is read at
#: full resolution (:func:`split_marker`)
MERGED_AREA = 1.3


#: a marker is as plain to see as the dots beside it: its peak at least this share of theirs (:func:`local_peak`)
PLAIN_SHARE = 0.3


def near_median(cand: Candidates, fit: LatticeFit, values: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """The median of the candidates' ``values`` ``(n_candidates,)`` over the eight lattice dots nearest each point
    ``xy`` ``(n, 2)`` [px] (a dot of the lattice among them): what the dots around a place are like, where they vary
    across the image (window streaks, a bright region, vignetting change their contrast and so their area at one
    level)."""
    on = np.flatnonzero(fit.on)
    _, j = cKDTree(cand.xy[on]).query(xy, k=min(8, len(on)))
    return np.median(values[on][np.atleast_2d(j.T).T], axis=1)


def local_peak(cand: Candidates, fit: LatticeFit, xy: np.ndarray) -> np.ndarray:
    """The median peak contrast [noise σ] of the eight lattice dots nearest each point ``xy`` ``(n, 2)`` [px]
    (:func:`near_median`): what a marker there is as plain to see as. The dots' peaks vary across an image whose
    noise does (window streaks, a bright region: on greenough:19's two-level plate the dots beside the markers peak
    at 26-32 σ, the median dot at 117 σ, and the markers, at 23-25 σ, were taken for noise)."""
    return near_median(cand, fit, cand.peak, xy)


def distinct_markers(markers: list, radius_px: float) -> list:
    """``markers`` less those within ``radius_px`` of one before them (the same marker read twice: off the
    lattice and split off a dot), a named shape kept before a blob."""
    out: list = []
    for m in sorted(markers, key=lambda m: m.kind == "blob"):
        if all(np.hypot(*np.subtract(m.centre, o.centre)) > radius_px for o in out):
            out.append(m)
    return out


def off_lattice_markers(img: np.ndarray, con: Contrast, cand: Candidates, fit: LatticeFit, reason: np.ndarray,
                        ratio: np.ndarray) -> list:
    """The markers among the candidates off the lattice (their ``reason`` set to the marker's kind): solid
    shapes of about a dot's size away from every lattice node (a plate's markers sit in its holes), as plain
    to see as the dots and apart from them (a shape that parallax brings near a dot is seen apart from it
    only at the higher levels of the sweep), read at their reference level, or at half of it where blur rounds
    a small square's corners there (a dot's outline is an ellipse at any level); and thin outlines (a ring, a
    frame) centred on a dot and larger than it, read at their widest; on a two-level plate, blobs in its holes
    (:func:`_hole_blobs`). ``reason``: why each candidate is off the lattice; ``ratio``: its area over the dots'
    median."""
    markers = []
    dd, _ = cKDTree(cand.xy[fit.on]).query(cand.xy)
    apart = dd > 1.5 * np.sqrt(np.median(cand.area[fit.on]) / np.pi)    # not a piece of a dot
    bright = cand.peak >= PLAIN_SHARE * local_peak(cand, fit, cand.xy)
    off = np.array([str(r).startswith("off the lattice (") for r in reason])
    shapes = (ratio > 0.3) & (ratio < 4) & (cand.area >= 100) & apart & bright & off
    outline = cand.area < 0.4 * cand.size[:, 0] * cand.size[:, 1]          # a ring or frame: mostly hole
    around = (dd < 0.5 * np.sqrt(np.median(cand.area[fit.on]) / np.pi)) & (
        cand.size > 1.2 * np.median(cand.size[fit.on], axis=0)).all(axis=1)
    frames = (cand.hole | outline) & around                                # a frame centred on a dot, larger
    for k in np.flatnonzero((reason != "") & ~cand.border & (shapes | frames)):
        kind = marker_kind(img, con, cand, k, cand.low[k] if frames[k] and not shapes[k] else cand.level[k])
        if kind is None and shapes[k]:   # a small square's corners rounded by blur at half its peak: lower down
            kind = marker_kind(img, con, cand, k, cand.level[k] / 2)
        if (kind == "frame" and frames[k]) or (kind in ("triangle", "square") and shapes[k]):
            markers.append(Marker(kind, tuple(cand.xy[k])))
            reason[k] = f"marker: {kind}"
    return markers + _hole_blobs(cand, fit, reason, ratio, bright & off & ~cand.border)


def _beside_dots(fit: LatticeFit):
    """``beside(xy (2,)) -> bool``: whether a shape split off a dot at ``xy`` [px] may be a marker, nearer a hole
    (:func:`in_hole`'s, either level's plane) than a node of the lattice, where it is the next dot (read near its
    top, a noisy dot's ragged outline may fill its bounding rectangle like a square: on stereo-piv:34, 0.881)."""
    nodes = fit.nodes(grow=1)
    to_node, to_hole = cKDTree(fit.model.predict(nodes)), cKDTree(_holes(fit, nodes + 0.5))
    return lambda xy: bool(to_hole.query(xy)[0] < to_node.query(xy)[0])


def joined_markers(img: np.ndarray, con: Contrast, cand: Candidates, fit: LatticeFit, *, lower: bool = False) -> list:
    """The markers joined to a dot of the lattice on the reduced image (:data:`MERGED_AREA`, at the blob's
    reference level, or with ``lower`` only at the lowest it was seen at, where a marker dimmer than the dots is
    still joined to it: on stereo-dic:20 1.21 and 1.40 times the dots' median; then on a patch around it there,
    and against the dots around it too, :func:`near_median`: on stereo-dic:35's two-level plate under window
    streaks a dot joined to the square was 1.19 times the dots' median at that level, 1.6 times its neighbours'),
    read at full resolution (:func:`split_marker`) at the
    blob's reference level, the dots', and half and three quarters of the peak of the dots beside it
    (:func:`local_peak`; blur narrows the gap between them: the higher levels see it), a named shape before a blob
    in a hole (:func:`in_hole`): each a ``(candidate, marker, outline)``."""
    median = float(np.median(cand.area[fit.on]))
    peak = local_peak(cand, fit, cand.xy)
    level = float(np.median(cand.level[fit.on]))
    found, beside = [], _beside_dots(fit)
    wide = cand.area > MERGED_AREA * median
    if lower:   # joined lower down only, larger than the dots' median or than the dots' around it
        around = np.minimum(np.median(cand.low_area[fit.on]), near_median(cand, fit, cand.low_area, cand.xy))
        wide = ~wide & (cand.low_area > MERGED_AREA * around)
    for k in np.flatnonzero(fit.on & wide & (cand.peak >= PLAIN_SHARE * peak)):
        node = fit.node[k][None]
        at = (fit.model.predict(node)[0], float(fit.tolerance(node)[0]), median, lower)
        levels = [cand.level[k], *sorted({level, 0.5 * peak[k], 0.75 * peak[k]})]
        reads = [split_marker(img, con, cand, k, lv, *at) for lv in levels]
        reads = [r for r in reads if r is not None and beside(r[0].centre)
                 and (r[0].kind != "blob" or in_hole(fit, np.array([r[0].centre]))[0])]
        if reads:   # a shape named at any level before a blob
            found.append((k, *min(reads, key=lambda r: r[0].kind == "blob")))
    return found


def _holes(fit: LatticeFit, cells: np.ndarray) -> np.ndarray:
    """Image positions [px] of a two-level plate's holes at lattice cells ``cells`` (node + 0.5), on the first
    level's plane and then on the second's."""
    return np.vstack([fit.model.base(cells), fit.model.second.base(cells)])


def in_hole(fit: LatticeFit, xy: np.ndarray) -> np.ndarray:
    """Whether points ``xy`` [px] are in a hole of a two-level plate: within a quarter step of the centre of
    a lattice cell on either level's plane (the markers are on the level whose parity the lattice does not yet
    know); never on a one-level plate."""
    if fit.model.second is None:
        return np.zeros(len(xy), bool)
    d, _ = cKDTree(_holes(fit, fit.nodes(grow=1) + 0.5)).query(xy)
    return d < 0.25 * fit.pitch


def _hole_blobs(cand: Candidates, fit: LatticeFit, reason: np.ndarray, ratio: np.ndarray, plain: np.ndarray) -> list:
    """On a two-level plate, the candidates in its holes (:func:`in_hole`) whose shape was not read, of
    0.2-1.5 of a dot's area and as plain to see as the dots: a marker whose corners defocus rounds
    (:func:`slmlab.images.lattice.origin_frame` tells the triangle from the square by their places beside the
    origin dot). Their ``reason`` is set."""
    blob = plain & in_hole(fit, cand.xy) & (ratio > 0.2) & (ratio < 1.5) & ~np.char.startswith(
        reason.astype(str), "marker")
    for k in np.flatnonzero(blob):
        reason[k] = "marker: a blob in a hole (shape not read)"
    return [Marker("blob", tuple(cand.xy[k])) for k in np.flatnonzero(blob)]


#: a filled hole stands out of its neighbour holes by this many times their own robust spread (:func:`filled_holes`)
HOLE_SIGMAS = 6.0


def filled_holes(con: Contrast, cand: Candidates, fit: LatticeFit, dots: tuple, shape: tuple[int, int],
                 read: list) -> list:
    """On a two-level plate where fewer than two markers were ``read``: ``'blob'`` markers at the holes (the centres
    of the lattice's cells whose four dots were found, on either level's plane) whose contrast at their centre
    stands out of their neighbour holes' (a gradient the background mesh lags shifts them all) by at least
    :data:`PLAIN_SHARE` of the peak of the dots beside it (:func:`local_peak`) and by :data:`HOLE_SIGMAS` times the
    robust spread of that difference over the holes looked at (what an empty hole shows: the image's noise there,
    window streaks' edges, a glare's slope; and by the sweep's lowest level), a quarter step from every dot and marker read (``dots``: the lattice's nodes
    and positions [px]; ``shape``: the image's): a marker that blur joins to the dot beside it at every level of the
    sweep. Under everything together on stereo-dic:37 and :40 the square stood out by 7.1 and 9.0 times the holes'
    spread, the emptiest holes' top by at most 5.1 (it was held to :data:`slmlab.images.dots.SEARCH_SIGMA` of the
    reduced image's noise, which the holes' spread is 0.5-0.7 of: the square was missed and the image unnumbered);
    on greenough:32 at 3.9, among the empty holes: lost."""
    nodes, xy = dots
    corners = fit.nodes(grow=1)
    have = {tuple(n) for n in nodes}
    inner = np.array([all((a + i, b + j) in have for i in (0, 1) for j in (0, 1)) for a, b in corners])
    cells = corners[inner] + 0.5        # within the plate: the four dots around the hole found
    holes = _holes(fit, cells)
    keep = inside_image(holes, shape, 2 * np.sqrt(np.median(cand.area[fit.on]) / np.pi))
    keep &= cKDTree(xy).query(holes)[0] > 0.25 * fit.pitch
    if read:
        keep &= cKDTree([m.centre for m in read]).query(holes)[0] > 0.25 * fit.pitch
    if len(holes) < 9:
        return []
    r = np.clip(np.rint(con.to_reduced(holes)).astype(int), 0, np.array(con.z.shape[::-1]) - 1)
    z = con.z[r[:, 1], r[:, 0]]
    above = z - np.median(z[cKDTree(holes).query(holes, k=9)[1][:, 1:]], axis=1)   # over its neighbour holes
    least = max(HOLE_SIGMAS * robust_sigma(above[keep]) if keep.any() else np.inf, LOWEST_SIGMA)
    filled = keep & (above >= np.maximum(PLAIN_SHARE * local_peak(cand, fit, holes), least))
    return [Marker("blob", (float(x), float(y))) for x, y in holes[filled]]
