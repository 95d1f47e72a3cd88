"""Numbering the dots of one image on the plate's lattice (the paper's §3 input: every dot's ``[i, j]``).

1. **The lattice** (:func:`fit_lattice`), fitted, not counted: a seed candidate whose eight lattice neighbours
   exist with similar areas (searched in bands of area, so that hot pixels or text do not hide the dots) gives
   two lattice steps; the lattice grows from it, up to three lines per side at a time while a line holds dots
   at ≥ 30 % of its nodes, under a model refitted each time (:class:`LatticeModel`: affine, then a homography
   plus a quadratic or cubic polynomial of the lattice coordinates, with outliers removed at the end), so
   that gaps, lost dots and clutter do not stop it. A one-level lattice with candidates at the midpoints of
   a half step at 30 % of its nodes or more skips every other line (they were lost near the seed): it is refined
   to the half step and grown on (:func:`_half_step`). The indices are turned to the plate's own axes
   (:func:`_unshear`: steep perspective can make a diagonal the shorter step). A **two-level** plate (rows
   alternating between two depths, offset by half a pitch) is one lattice rotated by 45° in the image, whose
   two classes of node parity are the two levels; each level, a plane at its own depth, gets its own model
   (the parallax between them varies across the field).
2. **Plate units** (:func:`plate_lattice`, :class:`PlateLattice`): ``i1`` along the lattice axis nearer
   ``+w1``, ``i2`` along the one nearer ``+w2``; on a two-level plate half pitches along the plate's axes.
3. **Absolute indices**: from the plate's size (:func:`number_plate`: the window of ``rows × cols`` lines
   holding most dots, without a line the image shows empty: :data:`EDGE_SITES`), or from markers (an L of
   donuts as on DICe targets, :func:`donut_indices`; a square and a triangle as on stereo-PIV plates, or a
   frame around the origin dot, :func:`origin_frame`). Images that cannot be anchored alone are tracked from
   the images of the same view that were, by the stage motion (:mod:`slmlab.images.tracking`).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from itertools import combinations, permutations

import cv2
import numpy as np
import pandas as pd
from scipy.spatial import cKDTree

__all__ = ["LatticeModel", "fit_model", "robust_model", "LatticeFit", "fit_lattice", "inside_image", "PlateLattice",
           "plate_lattice", "number_plate", "donut_indices", "origin_frame", "lattice_residual_px"]

#: the eight lattice neighbours of a node, as multiples of the steps (u, v)
_COMBOS = np.array([(1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (1, -1), (-1, 1), (-1, -1)], float)


# ------------------------------------------------------------------------------------------ the model
@dataclass
class LatticeModel:
    """Image position of lattice node ``(a, b)``: a homography of ``(a, b)`` plus a polynomial correction
    (distortion) of degree ``degree`` in the normalised lattice coordinates; on a two-level plate the nodes
    of odd ``a + b`` (the second level, a plane at another depth) have a model of their own, ``second``.

    Attributes
    ----------
    h
        the homography ``(3, 3)`` from ``(a, b, 1)`` to image pixels.
    coef
        polynomial correction coefficients ``(m, 2)`` [px] (empty for none).
    degree
        degree of the correction (0: none).
    centre, half
        normalisation of ``a, b`` for the polynomial.
    second
        the model of the odd nodes (``None`` but on two-level plates).
    """

    h: np.ndarray
    coef: np.ndarray
    degree: int
    centre: np.ndarray
    half: np.ndarray
    second: "LatticeModel | None" = None

    def terms(self, ab: np.ndarray) -> np.ndarray:
        """Monomials of degree 2 … ``degree`` of the normalised lattice coordinates ``(n, m)``."""
        s = (ab - self.centre) / self.half
        e = _exponents(self.degree)
        ones = np.ones((len(ab), 1))
        px = np.cumprod(np.hstack([ones, np.repeat(s[:, :1], self.degree, axis=1)]), axis=1)
        py = np.cumprod(np.hstack([ones, np.repeat(s[:, 1:], self.degree, axis=1)]), axis=1)
        return px[:, e[:, 0]] * py[:, e[:, 1]]

    def base(self, ab: np.ndarray) -> np.ndarray:
        """Image positions ``(n, 2)`` [px] of lattice points ``ab`` on the first level's model."""
        ab = np.asarray(ab, float).reshape(-1, 2)
        p = np.column_stack([ab, np.ones(len(ab))]) @ self.h.T
        w = p[:, :2] / p[:, 2:3]
        return w + self.terms(ab) @ self.coef if self.degree >= 2 else w

    def predict(self, ab: np.ndarray) -> np.ndarray:
        """Image positions ``(n, 2)`` [px] of lattice nodes ``ab`` ``(n, 2)`` (the odd ones on ``second``)."""
        ab = np.asarray(ab, float).reshape(-1, 2)
        w = self.base(ab)
        if self.second is not None:
            odd = _odd(ab)
            w[odd] = self.second.base(ab[odd])
        return w

    def steps(self, ab: np.ndarray) -> np.ndarray:
        """Local lattice steps ``(n, 2, 2)`` [px]: image displacement of one unit of ``a`` (``[:, :, 0]``)
        and of ``b`` (``[:, :, 1]``), by central differences (on the first level's model)."""
        ab = np.asarray(ab, float).reshape(-1, 2)
        w = self.base(np.vstack([ab + [0.5, 0], ab - [0.5, 0], ab + [0, 0.5], ab - [0, 0.5]])).reshape(4, -1, 2)
        return np.stack([w[0] - w[1], w[2] - w[3]], axis=2)

    def shifted(self, offset) -> "LatticeModel":
        """The same model moved by ``offset`` ``(2,)`` [px] in the image (a translation after the homography)."""
        t = np.array([[1.0, 0.0, offset[0]], [0.0, 1.0, offset[1]], [0.0, 0.0, 1.0]])
        return LatticeModel(t @ self.h, self.coef, self.degree, self.centre, self.half)


@functools.lru_cache(maxsize=8)
def _exponents(degree: int) -> np.ndarray:
    """Exponents ``(m, 2)`` of the monomials of degree 2 … ``degree`` in ``a, b`` (:meth:`LatticeModel.terms`)."""
    e = np.array([(i, j) for i in range(degree + 1) for j in range(degree + 1 - i) if i + j >= 2], int).reshape(-1, 2)
    e.flags.writeable = False
    return e


def _odd(ab: np.ndarray) -> np.ndarray:
    """Whether each node ``(a, b)`` has an odd ``a + b`` (the second level of a two-level plate)."""
    s = np.rint(ab[:, 0] + ab[:, 1])
    return (np.abs(ab[:, 0] + ab[:, 1] - s) < 1e-6) & (s % 2 == 1)


def fit_model(ab: np.ndarray, w: np.ndarray, *, degree: int | None = None, two_level: bool = False) -> LatticeModel:
    """Least-squares :class:`LatticeModel` of nodes ``ab`` seen at ``w`` [px]: affine below 6 nodes or a
    span under 3, else a homography, plus a polynomial correction of ``degree`` (by default: quadratic from 25
    nodes and a span of 5, cubic from 60 and 8). On a ``two_level`` plate each level has its own model once
    each holds 8 nodes over a span of 3; before that the second level is the first moved by the median
    offset of its nodes."""
    ab, w = np.asarray(ab, float), np.asarray(w, float)
    odd = _odd(ab) if two_level else np.zeros(len(ab), bool)
    if not (odd.any() and (~odd).any()):
        return _fit_base(ab, w, degree)
    if min(odd.sum(), (~odd).sum()) >= 8 and min(np.ptp(ab[odd], axis=0).min(), np.ptp(ab[~odd], axis=0).min()) >= 3:
        model = _fit_base(ab[~odd], w[~odd], degree)
        model.second = _fit_base(ab[odd], w[odd], degree)
        return model
    offset = np.zeros(2)
    for _ in range(3):
        model = _fit_base(ab, w - odd[:, None] * offset, degree)
        offset = np.median(w[odd] - model.base(ab[odd]), axis=0)
    model.second = model.shifted(offset)
    return model


def _fit_base(ab: np.ndarray, w: np.ndarray, degree: int | None) -> LatticeModel:
    """:func:`fit_model` of one plane (one level)."""
    span = ab.max(axis=0) - ab.min(axis=0) if len(ab) else np.zeros(2)
    centre = (ab.max(axis=0) + ab.min(axis=0)) / 2 if len(ab) else np.zeros(2)
    half = np.maximum(span / 2, 1.0)
    if len(ab) < 6 or span.min() < 3:
        a = np.column_stack([ab, np.ones(len(ab))])
        sol, *_ = np.linalg.lstsq(a, w, rcond=None)
        h = np.vstack([sol.T, [0, 0, 1]])
    else:
        h, _ = cv2.findHomography(ab.astype(np.float64), w.astype(np.float64), 0)
    model = LatticeModel(h, np.zeros((0, 2)), 0, centre, half)
    if degree is None:
        degree = 3 if (len(ab) >= 60 and span.min() >= 8) else 2 if (len(ab) >= 25 and span.min() >= 5) else 0
    if degree >= 2:
        model.degree = degree
        t = model.terms(ab)
        model.degree = 0
        coef, *_ = np.linalg.lstsq(t, w - model.base(ab), rcond=None)
        model.coef, model.degree = coef, degree
    return model


def robust_model(ab: np.ndarray, w: np.ndarray, pitch: float, *, two_level: bool = False
                 ) -> tuple[LatticeModel, np.ndarray]:
    """:func:`fit_model` with outliers removed: nodes off the fit by more than 4 × the residuals' MAD (and
    0.05 pitch) are dropped and the model refitted, twice. Returns the model and the inlier mask."""
    keep = np.ones(len(ab), bool)
    for _ in range(3):
        model = fit_model(ab[keep], w[keep], two_level=two_level)
        r = np.hypot(*(w - model.predict(ab)).T)
        lim = max(4 * 1.4826 * float(np.median(r[keep])), 0.05 * pitch)
        new = r < lim
        if (new == keep).all() or new.sum() < 4:
            break
        keep = new
    return model, keep


# ------------------------------------------------------------------------------------------ the seed
@dataclass
class _Seed:
    """A seed candidate ``k`` and its steps ``u, v`` [px], with the offset ``p`` [px] of its four axis
    neighbours (±u, ±v) from a plain lattice: the second level's parallax on a two-level plate, a little
    curvature otherwise."""

    k: int
    u: np.ndarray
    v: np.ndarray
    p: np.ndarray


def _predicted_neighbours(x0: np.ndarray, u: np.ndarray, v: np.ndarray, p: np.ndarray) -> np.ndarray:
    """The eight neighbours ``(n, 8, 2)`` [px] of points ``x0`` ``(n, 2)`` for steps ``u, v`` and the axis
    neighbours' offset ``p`` (all ``(n, 2)``)."""
    odd = (np.abs(_COMBOS[:, 0] + _COMBOS[:, 1]) % 2 == 1)[None, :, None]
    return (x0[:, None, :] + _COMBOS[None, :, :1] * u[:, None, :] + _COMBOS[None, :, 1:] * v[:, None, :]
            + odd * p[:, None, :])


def _central_steps(tree: cKDTree, xy: np.ndarray, x0: np.ndarray, u: np.ndarray, v: np.ndarray):
    """Steps ``u, v`` as half the difference of the opposite neighbours (where both are found within 0.6 of
    a step), and the offset ``p`` of those neighbours from a plain lattice: half their sum. A two-level
    plate's other level is offset by its parallax, which the differences cancel and the sums measure."""
    step = np.minimum(np.hypot(*u.T), np.hypot(*v.T))
    out = []
    for s in (u, v):
        d, j = tree.query(x0 - s)
        back = xy[j] - x0
        have = d < 0.6 * step
        out.append((np.where(have[:, None], (s - back) / 2, s), np.where(have[:, None], (s + back) / 2, 0.0), have))
    (uc, pu, hu), (vc, pv, hv) = out
    p = np.where((hu & hv)[:, None], (pu + pv) / 2, 0.0)
    return uc, vc, p


#: the 28 pairs of a node's eight nearest neighbours, and the pairs of those pairs that share no neighbour
_PAIRS = np.array(list(combinations(range(8), 2)))
_PP = np.array([(i, j) for i, j in combinations(range(len(_PAIRS)), 2) if not set(_PAIRS[i]) & set(_PAIRS[j])])


def _cos(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cosine of the angle between the vectors ``a`` and ``b`` ``(…, 2)`` (along their last axis)."""
    return (a * b).sum(-1) / np.maximum(np.hypot(a[..., 0], a[..., 1]) * np.hypot(b[..., 0], b[..., 1]), 1e-9)


def _paired_steps(vec: np.ndarray, length: np.ndarray, hypotheses: int = 3):
    """Steps ``u, v`` and the other level's offset ``p`` (each ``(n, hypotheses, 2)`` [px]) of a two-level
    plate from the vectors ``vec`` ``(n, 8, 2)`` to each node's eight nearest neighbours (``length``
    ``(n, 8)``), and whether each was found ``(n, hypotheses)``. The other level's four nearest dots are two
    opposite pairs about the node moved by the parallax, ``±u + p`` and ``±v + p``: two pairs of neighbours
    sharing a midpoint (within 0.2 of the nearest neighbour's distance: perspective moves it), with
    differences 55°-125° apart. The ``hypotheses`` such with the shortest steps are returned, shortest first
    (the node's own level gives pairs ``±(u ± v)`` about the node; pairs can share a midpoint by chance;
    :func:`_seed` keeps the one its neighbours confirm). Unlike :func:`_central_steps`, which looks for ``-u``
    where ``+u`` is mirrored, this holds for any parallax up to half a pitch."""
    a, b = vec[:, _PAIRS[:, 0]], vec[:, _PAIRS[:, 1]]
    mid, half = (a + b) / 2, (a - b) / 2
    size = np.hypot(half[..., 0], half[..., 1])
    m1, m2, h1, h2 = mid[:, _PP[:, 0]], mid[:, _PP[:, 1]], half[:, _PP[:, 0]], half[:, _PP[:, 1]]
    s1, s2 = size[:, _PP[:, 0]], size[:, _PP[:, 1]]
    cos = np.abs(_cos(h1, h2))
    near = np.hypot(*(m1 - m2).transpose(2, 0, 1)) < 0.2 * length[:, :1]
    ok = near & (cos < 0.57) & (np.maximum(s1, s2) < 3.0 * np.minimum(s1, s2))
    cost = np.where(ok, s1 + s2, np.inf)
    best = np.argsort(cost, axis=1, kind="stable")[:, :hypotheses]
    rows = np.arange(len(vec))[:, None]
    return (h1[rows, best], h2[rows, best], (m1[rows, best] + m2[rows, best]) / 2,
            np.isfinite(cost[rows, best]))


def _seed(xy: np.ndarray, area: np.ndarray, tries: int = 256, two_level: bool = False) -> _Seed | None:
    """The candidate whose eight lattice neighbours (±u, ±v, ±u±v) all exist with areas within a factor 2,
    and its steps ``u, v`` [px] (from the nearest neighbour and the nearest one 55°-125° from it, at most
    three times longer: views down to 20° from the plate; :func:`_central_steps`; on a two-level plate the
    shortest of :func:`_paired_steps`' hypotheses with six, as a lattice of every other node of the plate's
    has eight; of equally supported seeds those whose plate axes ``u ± v`` are the least sheared, within 0.1
    in cosine: at a parallax near a quarter pitch a basis sheared by half a cell fits too, and on a two-level plate
    those holding the most of the candidates around them, :func:`_most_held`); among equally supported
    seeds the one nearest their median position. Tried on the ``tries`` candidates nearest the median
    position (a plate's inner dots); ``None`` if none has six."""
    n = len(xy)
    if n < 9:
        return None
    tree = cKDTree(xy)
    idx = np.argsort(np.hypot(*(xy - np.median(xy, axis=0)).T), kind="stable")[:tries]
    _, nn = tree.query(xy[idx], k=min(9, n))
    vec = xy[nn[:, 1:]] - xy[idx, None, :]
    length = np.hypot(vec[..., 0], vec[..., 1])
    if two_level:
        u, v, p, has_v = _paired_steps(vec, length)
        idx = np.repeat(idx, u.shape[1])
        u, v, p, has_v = u.reshape(-1, 2), v.reshape(-1, 2), p.reshape(-1, 2), has_v.ravel()
    else:
        u = vec[:, 0]
        cos = np.abs((vec * u[:, None, :]).sum(-1)) / np.maximum(length * length[:, :1], 1e-9)
        ok = (cos < 0.57) & (length < 3.0 * length[:, :1])
        has_v = ok.any(axis=1)
        v = vec[np.arange(len(idx)), np.argmax(ok, axis=1)]
        u, v, p = _central_steps(tree, xy, xy[idx], u, v)
    d, j = tree.query(_predicted_neighbours(xy[idx], u, v, p).reshape(-1, 2))
    d, j = d.reshape(len(idx), 8), j.reshape(len(idx), 8)
    ratio = area[j] / area[idx, None]
    step = np.minimum(np.hypot(*u.T), np.hypot(*v.T))[:, None]
    hit = (d < 0.2 * step) & (ratio > 0.5) & (ratio < 2.0)
    score = np.where(has_v, hit.sum(axis=1), 0)
    if two_level and len(score) > len(nn):   # each node's shortest hypothesis with six, else its best
        per = score.reshape(len(nn), -1)
        pick = np.where((per >= 6).any(axis=1), np.argmax(per >= 6, axis=1), np.argmax(per, axis=1))
        keep = np.arange(len(nn)) * per.shape[1] + pick
        idx, u, v, p, score = idx[keep], u[keep], v[keep], p[keep], score[keep]
    if score.max() < 6:
        return None
    best = np.flatnonzero(score == score.max())
    if two_level:   # a parallax near a quarter pitch also fits a basis sheared by half a cell: the least sheared
        cos = np.abs(_cos(u[best] + v[best], u[best] - v[best]))
        best = best[cos <= cos.min() + 0.1]
    step = np.minimum(np.hypot(*u[best].T), np.hypot(*v[best].T))
    if two_level and step.max() > 1.2 * step.min():   # one level alone, steps √2 longer, has eight neighbours too
        return _by_middle(xy, _most_held(xy, area, [_Seed(int(idx[k]), u[k], v[k], p[k]) for k in best]))[0]
    k = best[_middle_order(xy, idx[best])[0]]   # (every inner dot of a plate ties: one seed made, not hundreds)
    return _Seed(int(idx[k]), u[k], v[k], p[k])


def _middle_order(xy: np.ndarray, k: np.ndarray) -> np.ndarray:
    """The order of candidates ``k`` by their distance from their median position (the plate's inner dots first;
    ties in their given order)."""
    return np.argsort(np.hypot(*(xy[k] - np.median(xy[k], axis=0)).T), kind="stable")


def _by_middle(xy: np.ndarray, seeds: list) -> list:
    """``seeds`` ordered by their candidate's distance from their median position (:func:`_middle_order`)."""
    return [seeds[i] for i in _middle_order(xy, np.array([s.k for s in seeds]))]


#: on a two-level plate, seeds whose lattices hold within this share of the best share of the candidates around
#: them are equally good (:func:`_most_held`)
HELD_SLACK = 0.1


def _most_held(xy: np.ndarray, area: np.ndarray, seeds: list, tries: int = 32) -> list:
    """Of equally supported two-level ``seeds``, those (among the ``tries`` nearest their median position) whose
    lattices hold the largest share of the candidates around them (:func:`_held`, within :data:`HELD_SLACK`).
    Where a few dots near the middle are lost, a node can lack the other level's four nearest dots and take a
    lattice of its own level alone, whose steps are the plate's axes: it has all eight neighbours too, but holds
    only half of the dots around it (stereo-dic:34: 348 of 697 dots, the other level all taken for blobs in
    holes). Weighed only where the seeds' steps differ by more than a fifth (such a lattice's are √2 longer)."""
    seeds = _by_middle(xy, seeds)[:tries]
    held, around = _held_many(xy, area, seeds)
    share = held / np.maximum(around, 1)
    return [s for s, f in zip(seeds, share) if f >= share.max() - HELD_SLACK]


#: a seed's lattice is counted within this many steps of it (:func:`_held`), where its affine steps still hold
#: under strong perspective
SEED_REACH = 2


def _banded_seed(xy: np.ndarray, area: np.ndarray, two_level: bool = False) -> _Seed | None:
    """:func:`_seed` among candidates of similar area: in overlapping bands of a factor 6 of area (so that
    many small blobs, hot pixels or text, do not hide the lattice of the dots), tried from the most
    populated band down until a seed has all eight neighbours and its lattice holds at least half of the
    candidates of its area around it (:func:`_held`); the best-supported seed, ties to the one whose lattice
    holds the most. A band of clutter and the smaller of the dots can hold a lattice of every third line with all
    eight neighbours (stereo-dic:17 beside a glare: 27 of the 81 dots, numbered three columns off)."""
    if len(xy) < 9:
        return None
    la = np.log2(np.maximum(area, 1e-3))
    bands = [np.flatnonzero((la >= lo) & (la < lo + np.log2(6)))
             for lo in np.arange(np.floor(la.min()), la.max() + 1e-9, 1.0)]
    best, best_rank = None, (-1, -1)
    for sel in sorted((b for b in bands if len(b) >= 9), key=len, reverse=True):
        s = _seed(xy[sel], area[sel], two_level=two_level)
        if s is None:
            continue
        s.k = int(sel[s.k])
        held, around = _held(xy, area, s)
        rank = (_support(xy, area, s), held)
        if rank > best_rank:
            best, best_rank = s, rank
        if rank[0] == 8 and held and 2 * held >= around:
            break
    return best


def _held(xy: np.ndarray, area: np.ndarray, s: _Seed, reach: int = SEED_REACH) -> tuple[int, int]:
    """``(held, around)``: how many candidates with an area within a factor 2 of seed ``s``'s lie on its lattice
    (within 0.2 of a step of a node, the odd nodes offset by ``s.p``), and how many lie around it, within
    ``reach`` steps of it (where its affine steps hold)."""
    held, around = _held_many(xy, area, [s], reach)
    return int(held[0]), int(around[0])


def _held_many(xy: np.ndarray, area: np.ndarray, seeds: list, reach: int = SEED_REACH) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_held` of each of ``seeds`` ``(m,)``, all at once."""
    if not seeds:
        return np.zeros(0, int), np.zeros(0, int)
    basis = np.stack([np.column_stack([s.u, s.v]) for s in seeds])                           # (m, 2, 2)
    flat = np.abs(np.linalg.det(basis)) < 1e-9
    inverse = np.linalg.inv(np.where(flat[:, None, None], np.eye(2), basis))
    k = np.array([s.k for s in seeds])
    step = np.array([min(np.hypot(*s.u), np.hypot(*s.v)) for s in seeds])[:, None]
    similar = (area[None] > area[k, None] / 2) & (area[None] < 2 * area[k, None])               # (m, n)
    held, around = np.zeros(similar.shape, bool), np.zeros(similar.shape, bool)
    for parity, offset in ((0, np.zeros((len(seeds), 2))), (1, np.array([s.p for s in seeds]))):
        q = np.einsum("mij,mnj->mni", inverse, xy[None] - (xy[k] + offset)[:, None])             # (m, n, 2)
        node = np.rint(q)
        near = np.abs(node).max(axis=2) <= reach
        around |= near
        miss = np.einsum("mij,mnj->mni", basis, q - node)
        held |= near & (np.hypot(miss[..., 0], miss[..., 1]) < 0.2 * step) & (np.abs(node.sum(axis=2)) % 2 == parity)
    return np.where(flat, 0, (held & similar).sum(axis=1)), np.where(flat, 0, (around & similar).sum(axis=1))


def _support(xy: np.ndarray, area: np.ndarray, s: _Seed) -> int:
    """How many of the eight lattice neighbours of seed ``s`` exist with an area within a factor 2."""
    p = _predicted_neighbours(xy[s.k][None], s.u[None], s.v[None], s.p[None])[0]
    d = np.hypot(xy[:, None, 0] - p[None, :, 0], xy[:, None, 1] - p[None, :, 1])
    ok = ((d < 0.2 * min(np.hypot(*s.u), np.hypot(*s.v))) & (area[:, None] > area[s.k] / 2)
          & (area[:, None] < 2 * area[s.k]))
    return int(ok.any(axis=0).sum())


# ------------------------------------------------------------------------------------------ growth
@dataclass
class LatticeFit:
    """A lattice fitted to candidates.

    Attributes
    ----------
    model
        the :class:`LatticeModel` of the nodes.
    node
        lattice node ``(a, b)`` of each candidate ``(n, 2)`` (valid where ``on``).
    on
        candidates on the lattice.
    box
        ``(amin, amax, bmin, bmax)``: the nodes the lattice spans.
    pitch
        median lattice step [px].
    """

    model: LatticeModel
    node: np.ndarray
    on: np.ndarray
    box: tuple[int, int, int, int]
    pitch: float

    def nodes(self, grow: int = 0) -> np.ndarray:
        """All nodes ``(m, 2)`` of the box, grown by ``grow`` on every side."""
        a0, a1, b0, b1 = self.box
        ga, gb = np.meshgrid(np.arange(a0 - grow, a1 + grow + 1), np.arange(b0 - grow, b1 + grow + 1), indexing="ij")
        return np.column_stack([ga.ravel(), gb.ravel()])

    def tolerance(self, ab: np.ndarray) -> np.ndarray:
        """Capture radius at nodes ``ab`` [px]: 0.3 of the shorter local step."""
        s = self.model.steps(ab)
        return 0.3 * np.minimum(np.hypot(*s[:, :, 0].T), np.hypot(*s[:, :, 1].T))

    def spacing(self, ab: np.ndarray) -> np.ndarray:
        """Distance from nodes ``ab`` to their nearest neighbours [px]: the nearest of the eight around each (an
        oblique view shears a lattice until a diagonal is the shortest; a two-level plate's parallax brings the
        other level's dots nearer)."""
        ab = np.asarray(ab).reshape(-1, 2)
        around = np.array([(0, 0), (1, 0), (0, 1), (1, 1), (1, -1), (-1, 0), (0, -1), (-1, -1), (-1, 1)])
        w = self.model.predict((ab[None] + around[:, None]).reshape(-1, 2)).reshape(len(around), len(ab), 2)
        return np.hypot(*(w[1:] - w[:1]).transpose(2, 0, 1)).min(axis=0)


def inside_image(w: np.ndarray, shape: tuple[int, int], margin, overlay: tuple[int, int] = (0, 0)) -> np.ndarray:
    """Points ``w`` ``(n, 2)`` [px] at least ``margin`` [px] (one, or one per point) inside an image of ``shape``,
    and clear of a camera's text ``overlay`` (its rows at the top and bottom,
    :func:`slmlab.images.overlay.overlay_rows`)."""
    h, wd = shape
    return ((w[:, 0] >= margin) & (w[:, 1] >= margin + overlay[0]) & (w[:, 0] <= wd - 1 - margin)
            & (w[:, 1] <= h - 1 - margin - overlay[1]))


def _assign(fit: LatticeFit, nodes: np.ndarray, tree: cKDTree, area: np.ndarray, ref_area: float,
            shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Nodes ``nodes`` that capture a candidate: the nearest of the three nearest within the tolerance whose
    area is within a factor 4 of ``ref_area`` (a frame around a dot shares its centroid), each candidate
    taken by its nearest node only. Returns node and candidate indices."""
    p = fit.model.predict(nodes)
    d, j = tree.query(p, k=min(3, tree.n))
    d, j = d.reshape(len(p), -1), j.reshape(len(p), -1)
    ok = (d < fit.tolerance(nodes)[:, None]) & similar_area(area[np.minimum(j, tree.n - 1)], ref_area)
    first = np.argmax(ok, axis=1)
    d, j = d[np.arange(len(p)), first], j[np.arange(len(p)), first]
    hit = np.flatnonzero(ok.any(axis=1) & inside_image(p, shape, 0))
    hit = hit[np.argsort(d[hit], kind="stable")]
    _, first = np.unique(j[hit], return_index=True)
    hit = hit[first]
    return hit, j[hit]


def _grow_sides(fit: LatticeFit, nodes: np.ndarray, hit_nodes: np.ndarray, shape, reach: int
                ) -> tuple[int, int, int, int]:
    """The box grown on each side by the lines beyond it (up to ``reach``), one after the other, while each
    holds candidates at ≥ 2 and ≥ 30 % of its nodes predicted inside the image."""
    a0, a1, b0, b1 = fit.box
    got = np.zeros(len(nodes), bool)
    got[hit_nodes] = True
    inside = inside_image(fit.model.predict(nodes), shape, 0)
    a, b = nodes[:, 0], nodes[:, 1]
    inner_b, inner_a = (b >= b0) & (b <= b1), (a >= a0) & (a <= a1)
    grown = []
    for line, inner, sign in ((a, inner_b, -1), (a, inner_b, 1), (b, inner_a, -1), (b, inner_a, 1)):
        edge = {(-1, 0): a0, (1, 0): a1, (-1, 1): b0, (1, 1): b1}[(sign, len(grown) // 2)]
        t = 0
        while t < reach:
            m = (line == edge + sign * (t + 1)) & inner
            if got[m].sum() < max(2, 0.3 * (m & inside).sum()):
                break
            t += 1
        grown.append(edge + sign * t)
    return tuple(grown)


def _span(v: np.ndarray) -> tuple[int, int]:
    """Smallest and largest of the integer indices ``v``."""
    return int(v.min()), int(v.max())


def _unshear(nodes: np.ndarray, two_level: bool = False) -> np.ndarray:
    """The nodes in the lattice basis along the plate's own axes. Any two lattice steps that span the
    lattice index it; where perspective shears it strongly, a diagonal can be shorter than an axis step and
    the seed may take it. A plate's dots fill a rectangle in its own axes only, so of the bases within two
    shears of the found one, the one whose bounding box of the nodes is smallest is taken (the found one
    on a tie). On a two-level plate the plate's axes are the diagonals ``a ± b`` of the lattice (the
    rectangle is measured there), and only shears that keep the parity of ``a + b`` (the level) are
    tried."""
    best, best_area = nodes, None
    shears = range(-2, 3, 2) if two_level else range(-2, 3)
    for k1 in shears:
        for k2 in shears:
            u = np.array([[1, k1], [0, 1]]) @ np.array([[1, 0], [k2, 1]])
            n = nodes @ u.T
            e = np.column_stack([n[:, 0] + n[:, 1], n[:, 0] - n[:, 1]]) if two_level else n
            area = (np.ptp(e[:, 0]) + 1) * (np.ptp(e[:, 1]) + 1)
            if best_area is None or area < best_area or (area == best_area and k1 == k2 == 0):
                best, best_area = n, area
    return best


#: a grown lattice is taken to skip every other line where candidates sit at the midpoints of a half step at
#: ≥ this share of its box's nodes (:func:`_half_step`), as a line beyond the box is the plate's where it holds
#: dots at ≥ 30 % of its nodes (noise blobs at 0.1 of a step from a third of the midpoints would be hundreds per
#: lattice cell)
HALF_STEP_SHARE = 0.3
#: a candidate's area within this range of times the lattice's reference area is a dot of the plate
#: (:func:`similar_area`: a frame around a dot shares its centroid)
AREA_RANGE = (0.25, 4.0)


def similar_area(area: np.ndarray, ref_area: float) -> np.ndarray:
    """Whether each area [px²] is within :data:`AREA_RANGE` times ``ref_area``."""
    ratio = np.asarray(area, float) / ref_area
    return (ratio > AREA_RANGE[0]) & (ratio < AREA_RANGE[1])


def fit_lattice(cand, shape: tuple[int, int], *, two_level: bool = False) -> LatticeFit | None:
    """Fit a lattice to candidate blobs (``cand``: ``xy`` [px], ``area`` [px²] and ``border``, as
    :class:`slmlab.images.dots.Candidates`; module docstring, step 1), indexed along the plate's axes
    (:func:`_unshear`); ``None`` if no seed is found. ``two_level``: the plate's second level is offset by
    its parallax (:class:`LatticeModel`). A one-level lattice that skips every other line is refined to the
    half step and grown on (:func:`_half_step`; again while it holds candidates at half steps, up to three
    times). ``None`` too where the seed's lattice grows to fewer than nine candidates."""
    use = np.flatnonzero(~cand.border)
    xy, area = cand.xy[use], cand.area[use]
    s = _banded_seed(xy, area, two_level)
    if s is None:
        return None
    h = np.array([[s.u[0], s.v[0], xy[s.k, 0]], [s.u[1], s.v[1], xy[s.k, 1]], [0, 0, 1.0]])
    start = LatticeModel(h, np.zeros((0, 2)), 0, np.zeros(2), np.ones(2))
    start.second = start.shifted(s.p) if two_level else None
    fit = LatticeFit(start, np.zeros((len(xy), 2), int), np.zeros(len(xy), bool), (-1, 1, -1, 1),
                     float(min(np.hypot(*s.u), np.hypot(*s.v))))
    ab, j = _grow(fit, xy, area, float(area[s.k]), shape, two_level)
    if len(j) < 9:   # a seed whose steps hold nothing beyond its neighbours (a wrong polarity's clutter)
        return None
    for _ in range(0 if two_level else 3):
        finer = _half_step(fit, ab, j, xy, area)
        if finer is None:
            break
        ab, j = finer
        fit.model, fit.box = fit_model(ab.astype(float), xy[j]), (*_span(ab[:, 0]), *_span(ab[:, 1]))
        ab, j = _grow(fit, xy, area, float(np.median(area[j])), shape, two_level)
    fit.on[j] = True
    fit.node[j] = _unshear(ab, two_level)
    fit.model, _ = robust_model(fit.node[j].astype(float), xy[j], fit.pitch, two_level=two_level)
    fit.box = (*_span(fit.node[j][:, 0]), *_span(fit.node[j][:, 1]))
    steps = fit.model.steps(fit.node[j])
    fit.pitch = float(np.median(np.minimum(np.hypot(*steps[:, :, 0].T), np.hypot(*steps[:, :, 1].T))))
    node = np.zeros((len(cand.xy), 2), int)
    on = np.zeros(len(cand.xy), bool)
    node[use], on[use] = fit.node, fit.on
    fit.node, fit.on = node, on
    return fit


#: the half steps :func:`_half_step` tries, in lattice units, and the matrices taking a node ``(a, b)`` to the
#: finer lattice of each (steps ``(u/2, v)``, ``(u, v/2)``, ``((u + v)/2, v)``, ``((u − v)/2, v)``)
_HALVES = np.array([(0.5, 0.0), (0.0, 0.5), (0.5, 0.5), (0.5, -0.5)])
_FINER = np.array([[[2, 0], [0, 1]], [[1, 0], [0, 2]], [[2, 0], [-1, 1]], [[2, 0], [1, 1]]])


def _half_step(fit: LatticeFit, ab: np.ndarray, j: np.ndarray, xy: np.ndarray, area: np.ndarray):
    """The lattice's nodes ``ab`` and candidates ``j`` on the finer lattice if it skips every other line, else
    ``None``. Where every other line of dots was lost around the plate's middle (a window streak over alternate
    columns, say), the seed's eight neighbours are all found on a lattice twice as wide along a step or a
    diagonal, and the lattice grows on every other line. Where candidates of a dot's area sit within 0.2 of a
    half step of the midpoints ``(a, b) + h`` (``h``: :data:`_HALVES`) at ≥ :data:`HALF_STEP_SHARE` of the
    box's nodes whose midpoints lie within the candidates' extent (nine at least), the best half step's finer
    lattice takes the nodes (:data:`_FINER`) and those candidates. One-level plates only: a two-level plate's
    second level is offset from the midpoints by its parallax."""
    nodes = fit.nodes().astype(float)
    at, tree = fit.model.predict(nodes), cKDTree(xy)
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    ref, taken = float(np.median(area[j])), np.zeros(len(xy), bool)
    taken[j] = True
    found = []
    for h in _HALVES:
        p = fit.model.predict(nodes + h)
        inside = np.flatnonzero(np.all((p >= lo) & (p <= hi), axis=1))
        d, k = tree.query(p[inside])
        hit = (d < 0.2 * np.hypot(*(p - at)[inside].T)) & similar_area(area[k], ref) & ~taken[k]
        found.append((hit.mean() if len(inside) >= 9 else 0.0, nodes[inside[hit]] + h, k[hit]))
    best = int(np.argmax([f[0] for f in found]))
    share, mid, k = found[best]
    if share < HALF_STEP_SHARE:
        return None
    k, first = np.unique(k, return_index=True)
    finer = np.rint(np.vstack([ab, mid[first]]) @ _FINER[best].T).astype(int)
    return finer, np.r_[j, k]


def _grow(fit: LatticeFit, xy: np.ndarray, area: np.ndarray, ref_area: float, shape, two_level: bool):
    """Grow the lattice from its seed (module docstring, step 1) until neither its box nor its dots change:
    each round predicts the box's nodes and up to three lines beyond it, captures candidates there
    (:func:`_assign`), grows the box by the lines that hold dots (:func:`_grow_sides`) and refits the model.
    Returns the captured nodes ``(m, 2)`` and candidates."""
    tree, last = cKDTree(xy), None
    for _ in range(400):
        reach = 3 if fit.model.degree or len(fit.model.coef) or (fit.box[1] - fit.box[0] >= 4) else 1
        nodes = fit.nodes(grow=reach)
        hit, j = _assign(fit, nodes, tree, area, ref_area, shape)
        box = _grow_sides(fit, nodes, hit, shape, reach)
        a0, a1, b0, b1 = box
        inb = (nodes[hit, 0] >= a0) & (nodes[hit, 0] <= a1) & (nodes[hit, 1] >= b0) & (nodes[hit, 1] <= b1)
        hit, j = hit[inb], j[inb]
        if len(j) < 9:   # fewer than a seed and its eight neighbours: no lattice (:func:`fit_lattice`)
            break
        fit.model = fit_model(nodes[hit].astype(float), xy[j], two_level=two_level)
        fit.box, ref_area = box, float(np.median(area[j]))
        state = (box, tuple(j))
        if state == last:
            break
        last = state
    return nodes[hit], j


# ------------------------------------------------------------------------------------------ plate units
@dataclass
class PlateLattice:
    """The dots on the lattice in plate units, oriented with the image.

    ``i1, i2`` are integer lattice coordinates of the dots: ``i1`` grows along the lattice axis nearer
    ``+w1``, ``i2`` along the one nearer ``+w2``. The unit is the plate's pitch, or half of it on a two-level
    plate, whose two levels are then the two classes of ``i1`` (and ``i2``) parity; the other lattice nodes
    (mixed parity) are holes, where such plates put their markers. ``model`` is the fitted
    :class:`LatticeModel` of the image lattice ``(a, b)``, and ``m`` the integer matrix taking ``(a, b)`` to
    ``(i1, i2)``.
    """

    i1: np.ndarray
    i2: np.ndarray
    two_level: bool
    model: LatticeModel
    m: np.ndarray = field(repr=False)

    def to_ab(self, i1, i2) -> tuple[np.ndarray, np.ndarray]:
        """Lattice-model coordinates ``(a, b)`` of plate-unit coordinates (fractional allowed)."""
        i = np.stack([np.asarray(i1, float), np.asarray(i2, float)])
        ab = np.linalg.inv(self.m) @ i.reshape(2, -1)
        return ab[0].reshape(np.shape(i1)), ab[1].reshape(np.shape(i1))

    def predict(self, i1, i2, odd: bool | None = None) -> np.ndarray:
        """Image positions ``(…, 2)`` [px] of plate-unit coordinates; ``odd``: all on the plane of the dots of
        odd (``True``) or even ``i1`` (``False``) of a two-level plate, not each on its own (a one-level plate
        has one plane)."""
        a, b = self.to_ab(i1, i2)
        ab = np.column_stack([np.ravel(a), np.ravel(b)])
        level = self.model.second if odd and self.model.second is not None else self.model
        w = self.model.predict(ab) if odd is None else level.base(ab)
        return w.reshape(*np.shape(a), 2)

    def locate(self, point, odd: bool | None = None) -> tuple[float, float]:
        """Plate-unit coordinates (fractional) of an image point [px], by Newton on the lattice model (on one
        level's plane, ``odd`` as in :meth:`predict`)."""
        p = np.asarray(point, float)
        on = self.predict(self.i1, self.i2)
        k = int(np.argmin(np.hypot(*(on - p).T)))
        x = np.array([self.i1[k], self.i2[k]], float)
        h = 1e-3
        for _ in range(4):   # the point and its two forward steps in one prediction
            f, fa, fb = self.predict(x[0] + np.array([0.0, h, 0.0]), x[1] + np.array([0.0, 0.0, h]), odd)
            jac = np.column_stack([(fa - f) / h, (fb - f) / h])
            x = x + np.linalg.solve(jac, p - f)
        return float(x[0]), float(x[1])


def plate_lattice(model: LatticeModel, ab: np.ndarray, *, two_level: bool = False) -> PlateLattice:
    """:class:`PlateLattice` of dots at lattice nodes ``ab`` ``(n, 2)`` of ``model``. On a two-level plate the
    dots form one lattice rotated by 45°, whose steps ``u, v`` are half-diagonals of the plate's cell: a dot at
    ``a·u + b·v`` is at ``(a + b, a − b)`` half-pitches along the plate axes ``(u + v)/2`` and ``(u − v)/2``.
    The axes are read at the middle of the dots (local steps of the model)."""
    ab = np.asarray(ab, int).reshape(-1, 2)
    mid = (ab.min(axis=0) + ab.max(axis=0)) / 2 if len(ab) else np.zeros(2)
    d = model.steps(mid[None])[0].T           # rows: image step of one unit of a, of b
    if two_level:
        axes, m = np.array([(d[0] + d[1]) / 2, (d[0] - d[1]) / 2]), np.array([[1, 1], [1, -1]])
    else:
        axes, m = d.copy(), np.eye(2, dtype=int)
    if abs(axes[0][0]) < abs(axes[1][0]):  # axis 1 is the one nearer w1
        axes, m = axes[::-1], m[::-1].copy()
    if axes[0][0] < 0:
        m[0] = -m[0]
    if axes[1][1] < 0:
        m[1] = -m[1]
    i = ab @ m.T
    return PlateLattice(i[:, 0].astype(int), i[:, 1].astype(int), two_level, model, m)


#: an empty plate line is evidence of the plate's edge where the image shows this many of its sites empty
#: (all of them on a shorter line): a glare may hide the rest of a real edge line, and a line of hidden dots
#: shows none of its sites empty (its dots are candidates, or the image there is unlike the plate's)
EDGE_SITES = 3


def _line_seen(pl: PlateLattice, axis: int, k: int, other: tuple[int, int], seen) -> bool:
    """Whether the plate line ``i[axis] = k`` (``other``: the range of the other index) is shown empty by the
    image (``seen``: where a site is seen to hold no dot) at :data:`EDGE_SITES` of its sites at least (all
    of a shorter line): a line that is seen empty is not part of the plate."""
    o = np.arange(other[0], other[1] + 1)
    k = np.full(len(o), k)
    shown = seen(pl.predict(k, o) if axis == 0 else pl.predict(o, k))
    return int(shown.sum()) >= min(EDGE_SITES, len(o))


def _window(pl: PlateLattice, n: int, axis: int, seen) -> tuple[int | None, str]:
    """First index of the ``n`` plate lines along ``axis``: the window holding most dots, less any line it
    holds that would be seen yet is empty; ``None`` and why if two windows tie (the plate's position along
    that axis is ambiguous)."""
    i, j = (pl.i1, pl.i2) if axis == 0 else (pl.i2, pl.i1)
    other = (int(j.min()), int(j.max()))
    lo, hi = int(i.min()), int(i.max())
    starts = np.arange(hi - n + 1, lo + 1) if hi - lo + 1 <= n else np.arange(lo, hi - n + 2)
    counts = np.bincount(i - lo, minlength=hi - lo + 1)
    scores = []
    for s in starts:
        held = sum(counts[k - lo] for k in range(s, s + n) if lo <= k <= hi)
        empty = sum(1 for k in range(s, s + n) if not (lo <= k <= hi and counts[k - lo])
                    and _line_seen(pl, axis, k, other, seen))
        scores.append(held - 1000 * empty)
    scores = np.asarray(scores)
    best = np.flatnonzero(scores == scores.max())
    if len(best) > 1:
        return None, f"the plate's {n} lines along i{axis + 1} fit {len(best)} positions (cut by the image)"
    return int(starts[best[0]]), ""


def number_plate(pl: PlateLattice, rows: int, cols: int, seen):
    """Plate ``[row, col]`` (1-based) of the dots of a plate of ``rows × cols`` (whole in view, or cut by the
    image; any dots lost): ``col`` along ``i1`` unless the lattice fits the plate only the other way round (a
    non-square plate turned by 90°). ``seen(points (n, 2) [px])``: where the image shows a site empty (inside
    it, not lost in a saturated or otherwise unlike region, no blob there): an empty line seen so at
    :data:`EDGE_SITES` sites is evidence of the plate's edge, elsewhere not.
    Returns ``(row, col)`` (``None`` if ambiguous), a mask of the dots inside the plate, a note (why not, or
    how), and the plate's window ``(i1 min, i1 max, i2 min, i2 max)``."""
    i = np.column_stack([pl.i1, pl.i2])
    spans = i.max(axis=0) - i.min(axis=0) + 1
    swap = rows != cols and (spans[0] > cols or spans[1] > rows) and spans[0] <= rows and spans[1] <= cols
    n1, n2 = (rows, cols) if swap else (cols, rows)
    s1, why1 = _window(pl, n1, 0, seen)
    s2, why2 = _window(pl, n2, 1, seen)
    if s1 is None or s2 is None:
        return None, np.ones(len(i), bool), why1 or why2, None
    inside = (i[:, 0] >= s1) & (i[:, 0] < s1 + n1) & (i[:, 1] >= s2) & (i[:, 1] < s2 + n2)
    a, b = i[:, 0] - s1 + 1, i[:, 1] - s2 + 1
    note = "turned by 90°: rows along i1" if swap else ""
    return ((a, b) if swap else (b, a)), inside, note, (s1, s1 + n1 - 1, s2, s2 + n2 - 1)


# ------------------------------------------------------------------------------------------ markers
def donut_indices(pl: PlateLattice, holes: np.ndarray, origin: tuple[int, int]):
    """Plate ``[row, col]`` from three donut markers (``holes``: a flag per dot of ``pl``) forming an L on
    the lattice (DICe targets): the corner marker is ``origin``, columns count towards the marker on its
    row, rows towards the marker on its column."""
    idx = np.flatnonzero(holes)
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
    """Plate-frame coordinates ``(x, y)`` [plate units] of the dots from the plate's markers, and how.

    * a **square and a triangle** (stereo-PIV plates): the origin is the dot in the corner of the lattice
      cell the two markers span such that, seen from the camera, ``+x`` points from the origin to the
      triangle and ``+y`` to the square, 90° counter-clockwise from ``+x`` (a right-handed plate frame whose
      ``z`` points towards the camera); the other corner is the mirror image and is not a solution. On a
      two-level plate a **blob** in a hole (a marker whose shape defocus hid) stands for either: of the pairs
      that span a cell so, the one reading the most shapes, and of those the one whose markers lie nearest
      their holes (at most half as far as the next: two blobs span a cell from a dot of either level); where
      triangles and squares were read, they alone, and one pair of them only (a square read in a glare far
      from the plate's origin does not hide the pair that spans its cell); where only one of the two shapes was
      read, or no pair of those read spans a cell (stereo-dic:32 under everything together: a dim dot beyond the
      lattice at the image's top read as a square, the plate's square read as a blob), the blobs stand in, as
      above;
    * a **frame** around a dot: that dot is the origin, ``+x`` along the image's ``w1`` and ``+y`` against
      ``w2`` (up in the image).
    """
    kinds = {}
    for m in markers:
        kinds.setdefault(m.kind, []).append(m)
    blobs = kinds.get("blob", []) if pl.two_level else []
    triangles, squares = kinds.get("triangle", []), kinds.get("square", [])
    shapes = bool(triangles) and bool(squares)
    if shapes:   # read shapes: they alone; where no pair of them spans a cell, the blobs may stand for one
        frame, why = _marker_pair(pl, triangles, squares, blobs=False)
        if frame is None and not why and blobs:
            frame, why = _marker_pair(pl, triangles + blobs, squares + blobs, blobs=True)
        return frame, why or ("no pair of the square(s) and triangle(s) found spans one lattice cell"
                              if len(triangles) + len(squares) > 2 else
                              "a square and a triangle marker were found but do not span one lattice cell")
    if (triangles + blobs) and (squares + blobs):
        frame, why = _marker_pair(pl, triangles + blobs, squares + blobs, blobs=True)
        if frame is not None or why:
            return frame, why
    frames = kinds.get("frame", [])
    if len(frames) == 1:
        n = np.rint(pl.locate(frames[0].centre)).astype(int)
        return ((pl.i1 - n[0]), -(pl.i2 - n[1])), "a frame around the origin dot"
    if markers:
        found = ", ".join(f"{len(v)} {k}" for k, v in kinds.items())
        return None, f"markers found ({found}) but not a square and a triangle, nor one frame"
    return None, "no markers found"


def _marker_pair(pl: PlateLattice, xs: list, ys: list, *, blobs: bool):
    """``(frame, how)``: the origin frame of the one pair of markers from ``xs`` (``+x``) and ``ys`` (``+y``) that
    spans a lattice cell (:func:`origin_frame`), or ``(None, why)`` where several do, or ``(None, "")`` where none
    does. With ``blobs`` among them, of the pairs reading the most shapes the one whose markers lie nearest their
    holes, at most half as far as the next."""
    found = [(int(t.kind == "triangle") + int(s.kind == "square"), *cell) for t in xs for s in ys
             if t is not s and (cell := _cell_frame(pl, t, s)) is not None]
    most = max((n for n, _, _ in found), default=0)
    best = sorted(((off, frame) for n, off, frame in found if n == most), key=lambda f: f[0])
    if len(best) == 1 or (blobs and len(best) > 1 and best[0][0] < 0.5 * best[1][0]):
        return best[0][1]
    if not best:
        return None, ""
    return None, (f"{len(best)} pairs of the markers found span a lattice cell, their markers as near their "
                  "holes: which is the plate's is not told" if blobs else
                  f"{len(best)} pair(s) of the square(s) and triangle(s) found span one lattice cell")


def _cell_frame(pl: PlateLattice, triangle, square):
    """The origin frame of :func:`origin_frame` if markers ``triangle`` (``+x``) and ``square`` (``+y``) span a
    lattice cell so, and how far the markers lie from the holes they were rounded to [plate units]; ``None``
    if they do not. On a two-level plate they are located on each level's plane in turn (the parallax moves
    the other's by up to half a unit), the origin on that level; the plane they lie nearer holes on is taken
    (they are on the origin's level)."""
    found = []
    for odd in (False, True) if pl.two_level else (None,):
        at = np.array([pl.locate(m.centre, odd) for m in (triangle, square)])
        t, s = np.rint(at).astype(int)
        off = float(np.abs(at - np.rint(at)).sum())
        for ex in _UNITS:
            n = t - ex
            frame = _origin_at(pl, n, ex, s - n, triangle, square) if odd is None or n[0] % 2 == odd else None
            if frame is not None:
                found.append((off, frame))
    return min(found, key=lambda f: f[0], default=None)


def _origin_at(pl: PlateLattice, n, ex, ey, triangle, square):
    """The origin frame at origin ``n`` with ``+x`` along ``ex`` if ``ey`` is 90° counter-clockwise from it on
    screen (w2 down: ``(d1, d2) -> (d2, -d1)``) and ``n`` is a dot's place, else ``None``."""
    if not np.array_equal(ey, np.array([ex[1], -ex[0]])) or (pl.two_level and (n[0] + n[1]) % 2):
        return None
    rel = np.stack([pl.i1 - n[0], pl.i2 - n[1]], axis=1)
    dots = set(zip(pl.i1.tolist(), pl.i2.tolist()))
    blobs = sum(m.kind == "blob" for m in (triangle, square))
    how = ("square and triangle markers" + (f" ({blobs} told by its place)" if blobs else "")
           + ("" if tuple(n) in dots else " (origin dot not seen)"))
    return (rel @ ex, rel @ ey), how


def lattice_residual_px(table: pd.DataFrame) -> float:
    """How smoothly the centres of one image lie on their lattice [px]: the RMS residual (per coordinate,
    net of the fitted parameters) of a cubic in the lattice coordinates ``i1, i2`` fitted to ``w1, w2``, per
    level. Distortion and perspective are smooth and mostly absorbed; what is left is the centres' own
    scatter, and a centre estimator's error that varies from dot to dot (texture, dust, scratches on real
    plates). (A homography plus a cubic absorbs strong perspective better on large plates, but on the dozen
    dots of a level of a real two-level plate it leaves several times more than the cubic: measured on the
    PIV Challenge's case E.)"""
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
