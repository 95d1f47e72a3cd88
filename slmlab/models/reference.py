"""Plain reference polynomials: world coordinates as one least-squares polynomial in the four image
coordinates ``wl1, wl2, wr1, wr2``.

What anyone would fit first, with no physics: the yardstick that the project's own models are held against
(notebooks 09–10). It needs each dot's world position (a Z stack or a known target).
"""

from __future__ import annotations

import numpy as np

from ..errors import SlmlabError
from ..io import IMAGE_COLUMNS, CalibrationSet
from .base import Model, register
from .frames import world_positions

__all__ = ["quadratic_features", "QuadraticReference"]


def quadratic_features(w: np.ndarray, centre, scale) -> np.ndarray:
    """Quadratic monomials (with the constant) of normalised image coordinates ``(n, 4)``: 15 columns."""
    u = (np.asarray(w, float) - centre) / scale
    cols = [np.ones(len(u))] + [u[:, k] for k in range(4)]
    cols += [u[:, a] * u[:, b] for a in range(4) for b in range(a, 4)]
    return np.column_stack(cols)


@register
class QuadraticReference(Model):
    """World coordinates as one least-squares quadratic in the four image coordinates (15 terms each),
    fitted on dots whose world positions are known."""

    name = "quadratic"
    summary = ("reference: one least-squares quadratic from the four image coordinates to each world "
               "coordinate (needs known world positions: a Z stack or a known target)")
    accuracy_rank = 60
    units = {"centre_px": "px", "scale_px": "px", "coef": "mm per normalised quadratic monomial"}

    def __init__(self, centre_px, scale_px, coef, **kw):
        super().__init__(**kw)
        self.centre_px, self.scale_px = np.asarray(centre_px, float), np.asarray(scale_px, float)
        self.coef = np.asarray(coef, float)

    @classmethod
    def fit(cls, cal: CalibrationSet, *, mode: str = "auto", **_):
        pts, world, mode = world_positions(cal, mode)
        if mode == "moves":
            raise SlmlabError("the quadratic reference needs each dot's world position (a Z stack or a known "
                              "target)", cal.path)
        w = pts[IMAGE_COLUMNS].to_numpy(float)
        if len(w) <= 15:
            raise SlmlabError(f"{len(w)} dots seen in both views: the quadratic reference needs more than 15", cal.path)
        centre, scale = w.mean(axis=0), np.maximum(w.std(axis=0), 1e-9)
        coef, *_ = np.linalg.lstsq(quadratic_features(w, centre, scale), world, rcond=None)
        return cls(centre, scale, coef, options={"mode": mode})

    def reconstruct(self, w: np.ndarray) -> np.ndarray:
        return quadratic_features(np.atleast_2d(np.asarray(w, float)), self.centre_px, self.scale_px) @ self.coef

    def parameters_dict(self) -> dict:
        return {"centre_px": self.centre_px.tolist(), "scale_px": self.scale_px.tolist(), "coef": self.coef.tolist()}

    @classmethod
    def from_parameters(cls, p, calibration, options):
        return cls(p["centre_px"], p["scale_px"], p["coef"], calibration=calibration, options=options)
