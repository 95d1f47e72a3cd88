"""Numbering the dots of one image on the plate's lattice (the paper's §3 input: every dot's ``[i, j]``).

1. **Indexing** (:func:`index_lattice`): the lattice directions from nearest-neighbour vectors (any
   rotation), a breadth-first walk over the lattice that follows its local spacing (distortion,
   perspective), then a quadratic lattice model that recovers dots the walk missed and drops blobs that are
   off the lattice (spurious). A **two-level** plate (rows alternating between two depths, offset by half a
   pitch) is one lattice rotated by 45° in the image; its indices are turned into half-pitch plate units,
   where the two levels are the two parities (:func:`plate_lattice`).
2. **Absolute indices**: from the plate's size and where the lattice runs out of the image (whole plate in
   view, :func:`absolute_indices`), or from markers (a donut L as on DICe targets,
   :func:`donut_indices`; a square and a triangle as on stereo-PIV plates, or a frame around the origin dot,
   :func:`origin_frame`). Images that cannot be anchored alone are anchored from a neighbouring image of the
   same view by :mod:`slmlab.images.imageset`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from itertools import permutations

import numpy as np
import pandas as pd
from scipy.spatial import cKDTree

__all__ = ["Lattice", "index_lattice", "PlateLattice", "plate_lattice", "absolute_indices", "donut_indices",
           "origin_frame", "lattice_residual_px"]


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


def absolute_indices(pl: PlateLattice, rows: int, cols: int, image_size: tuple[int, int], margin_px: float):
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


def donut_indices(pl: PlateLattice, holes: np.ndarray, origin: tuple[int, int]):
    """Plate ``[row, col]`` from three donut markers forming an L on the lattice (DICe targets): the corner
    marker is ``origin``, columns count towards the marker on its row, rows towards the marker on its
    column."""
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


def origin_frame(pl: PlateLattice, markers: list):
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
