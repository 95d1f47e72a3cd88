"""Numbering an image that cannot be numbered alone from the images of its view that were, and the stage
(:mod:`slmlab.images.imageset`'s tracking).

An image whose plate is cut (its markers out of view, a glare over an edge) has a lattice whose indices are
right up to one integer shift. Where the plate lies under a fixed image point, in the set's numbering, is an
affine function of the stage's translation (the point's line of sight is fixed; the plate moves rigidly
along it), so the images of the same view and plate that were numbered alone show how it moves
(:func:`stage_motion`), along the stage directions they span. That motion predicts the plate's numbering
under a dot of the unnumbered image, and the shift is the lattice shift nearest the prediction
(:func:`track`). A plate that moves more than half a pitch from one position to the next is tracked as
well as one that moves little.

The prediction is refused (the image is left unnumbered, with why) where it is more than
:data:`TRACK_UNCERTAINTY` from a lattice shift once what the numbered images cannot tell is added: their
misfit to an affine motion, and the stage travel along directions they do not span, taken as at most one
plate unit of motion per plate unit of travel (a view within 45° of the plate's normal).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .lattice import PlateLattice

__all__ = ["TRACK_UNCERTAINTY", "Numbered", "StageMotion", "stage_motion", "track"]

#: the largest distance [plate units: the pitch, or half of it on a two-level plate] of a predicted plate
#: position from a lattice shift, its uncertainty included, at which an image is numbered by tracking (half a
#: unit would be a guess between two shifts; the lattice locates to a few hundredths)
TRACK_UNCERTAINTY = 0.25
#: stage directions spanned by fewer millimetres than this are not learned
_SPAN_MM = 1e-4


@dataclass(frozen=True)
class Numbered:
    """An image numbered alone: ``name`` (for the notes), its stage position ``stage_mm`` ``(3,)`` [mm], its
    :class:`PlateLattice` and ``to_set``: the integer affine map ``(2, 3)`` from its lattice indices
    ``i1, i2`` to the set's numbering: ``row, col`` (``frame`` ``'plate'``) or ``xu, yu`` (``'origin'``)."""

    name: str
    stage_mm: np.ndarray
    lattice: PlateLattice
    to_set: np.ndarray
    frame: str = "plate"

    def under(self, point_px) -> np.ndarray:
        """The set's numbering (fractional) [plate units] of the plate under image point ``point_px``."""
        i = self.lattice.locate(point_px)
        return self.to_set @ np.array([i[0], i[1], 1.0])


@dataclass(frozen=True)
class StageMotion:
    """How the plate moves in one view with the stage: under image point ``point_px`` [px] the plate's
    numbering is ``q0 + rate @ (s − s0)`` [plate units] at stage position ``s`` [mm]; ``rate`` ``(2, 3)``
    [plate units / mm] is learned along ``spanned`` (orthonormal rows, stage directions the numbered images
    span), ``residual`` is their largest misfit [plate units] and ``unit_mm`` the plate unit [mm]."""

    point_px: np.ndarray
    s0: np.ndarray
    q0: np.ndarray
    rate: np.ndarray
    spanned: np.ndarray
    residual: float
    unit_mm: float

    def predict(self, stage_mm) -> tuple[np.ndarray, float]:
        """The plate's numbering under :attr:`point_px` at ``stage_mm`` [plate units], and its uncertainty:
        the misfit plus the travel [mm] along unlearned directions in plate units (module docstring)."""
        d = np.asarray(stage_mm, float) - self.s0
        unlearned = d - self.spanned.T @ (self.spanned @ d)
        return self.q0 + self.rate @ d, self.residual + float(np.linalg.norm(unlearned)) / self.unit_mm


def stage_motion(numbered: list[Numbered], point_px, unit_mm: float) -> StageMotion:
    """:class:`StageMotion` under ``point_px`` [px] learned from images of one view and plate numbered alone
    (at least one; with one, or all at one stage position, no motion is learned): the least-squares affine
    map from their stage positions [mm] to the plate's numbering under the point, along the directions their
    positions span. ``unit_mm``: the plate unit [mm]."""
    s = np.array([n.stage_mm for n in numbered], float)
    q = np.array([n.under(point_px) for n in numbered])
    s0, q0 = s.mean(axis=0), q.mean(axis=0)
    _, sv, vt = np.linalg.svd(s - s0, full_matrices=False)
    spanned = vt[sv > _SPAN_MM]
    x = (s - s0) @ spanned.T                                   # coordinates along the spanned directions
    coef = np.linalg.lstsq(x, q - q0, rcond=None)[0] if len(spanned) else np.zeros((0, 2))
    rate = coef.T @ spanned
    residual = float(np.abs(q - q0 - (s - s0) @ rate.T).max())
    return StageMotion(np.asarray(point_px, float), s0, q0, rate, spanned, residual, unit_mm)


def _nearest_shift(f: np.ndarray, two_level: bool) -> np.ndarray:
    """The lattice shift nearest the fractional shift ``f`` ``(2,)``: integers, of even sum on a two-level
    plate (its dots are the nodes of even ``i1 + i2``)."""
    cands = np.floor(f).astype(int) + np.array([(0, 0), (1, 0), (0, 1), (1, 1)])   # the nearest is a corner
    if two_level:
        cands = cands[(cands.sum(axis=1) % 2) == 0]
    return cands[np.argmin(np.hypot(*(cands - f).T))]


def track(lattice: PlateLattice, stage_mm, numbered: list[Numbered], unit_mm: float
          ) -> tuple[np.ndarray | None, Numbered | None, str]:
    """The shift ``(2,)`` of an unnumbered image's lattice indices ``i1, i2`` that numbers it like
    ``numbered`` (images of its view and plate numbered alone, nearest first; the first one's map takes the
    shifted indices to the set's numbering), from the :func:`stage_motion` they show, predicted under the
    image's middle dot at ``stage_mm`` [mm]. Returns the shift, the image whose map numbers it and how, or
    ``None``, ``None`` and why the prediction is refused (module docstring)."""
    k = int(np.argmin(np.hypot(lattice.i1 - np.median(lattice.i1), lattice.i2 - np.median(lattice.i2))))
    own = np.array([lattice.i1[k], lattice.i2[k]], float)
    point = lattice.predict(own[0], own[1])
    motion = stage_motion(numbered, point, unit_mm)
    q, unc = motion.predict(stage_mm)
    ref = numbered[0]
    lin, off = ref.to_set[:, :2], ref.to_set[:, 2]
    f = np.linalg.solve(lin, q - off) - own                     # in this image's index axes
    shift = _nearest_shift(f, lattice.two_level)
    miss = float(np.hypot(*(f - shift)))
    what = (f"{miss:.2f} from a lattice shift, uncertain by {unc:.2f} (plate units), learned from "
            f"{len(numbered)} image(s) numbered alone along {len(motion.spanned)} stage direction(s)")
    if miss + unc > TRACK_UNCERTAINTY:
        return None, None, (f"the plate's position predicted from the stage motion is {what}: more than "
                            f"TRACK_UNCERTAINTY ({TRACK_UNCERTAINTY} plate units) together")
    return shift.astype(int), ref, f"by the stage motion: {what}"
