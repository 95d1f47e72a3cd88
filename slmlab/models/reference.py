"""Plain reference polynomials: world coordinates as one least-squares polynomial in the four image
coordinates ``wl1, wl2, wr1, wr2``.

What anyone would fit first, with no physics: the yardstick that the project's own models are held against
(notebooks 09–11), and one of the default model's candidates (:mod:`slmlab.models.auto`). Where the dots'
world positions are known (a Z stack, a known target) the fit is ordinary least squares; on stage moves of a
plate whose place on the stage is unknown (the paper's sequences) each dot and sequence has its own offset,
eliminated by centring (the within-group estimator), and the frame's origin is put where the direct model
puts it (the first moving sequence's first position).
"""

from __future__ import annotations

from itertools import combinations_with_replacement

import numpy as np

from ..errors import SlmlabError
from ..io import IMAGE_COLUMNS, CalibrationSet
from .base import Model, register
from .frames import world_positions

__all__ = ["DEGREES", "polynomial_features", "quadratic_features", "fit_polynomial", "PlainPolynomial",
           "QuadraticReference"]

#: the degrees a plain polynomial may have
DEGREES = (1, 2, 3, 4)


def polynomial_features(w: np.ndarray, degree: int, centre, scale) -> np.ndarray:
    """Monomials of total degree up to ``degree`` (the constant first, then by degree in
    ``combinations_with_replacement`` order) of the normalised image coordinates ``(w − centre)/scale``
    ``(n, 4)``."""
    u = (np.asarray(w, float) - centre) / scale
    cols = [np.ones(len(u))]
    for d in range(1, degree + 1):
        for combo in combinations_with_replacement(range(u.shape[1]), d):
            col = u[:, combo[0]].copy()
            for k in combo[1:]:
                col *= u[:, k]
            cols.append(col)
    return np.column_stack(cols)


def quadratic_features(w: np.ndarray, centre, scale) -> np.ndarray:
    """Quadratic monomials (with the constant) of normalised image coordinates ``(n, 4)``: 15 columns."""
    return polynomial_features(w, 2, centre, scale)


def fit_polynomial(cal: CalibrationSet, degree: int, mode: str = "auto") -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
    """``(centre_px, scale_px, coef, mode)`` of the plain polynomial of ``degree`` on ``cal`` (module
    docstring); ``coef`` ``(m, 3)`` [mm per normalised monomial]."""
    if degree not in DEGREES:
        raise SlmlabError(f"the plain polynomial's degree must be one of {', '.join(map(str, DEGREES))}, not {degree!r}")
    pts, world, mode = world_positions(cal, mode)
    w = pts[IMAGE_COLUMNS].to_numpy(float)
    n_terms = len(polynomial_features(w[:1], degree, 0.0, 1.0)[0])
    if len(w) <= n_terms:
        raise SlmlabError(f"{len(w)} dots seen in both views: a plain polynomial of degree {degree} needs more than "
                          f"{n_terms}", cal.path)
    centre, scale = w.mean(axis=0), np.maximum(w.std(axis=0), 1e-9)
    phi = polynomial_features(w, degree, centre, scale)
    if mode != "moves":
        coef, *_ = np.linalg.lstsq(phi, world, rcond=None)
        return centre, scale, coef, mode
    groups = pts.groupby(["sequence", "row", "col"], sort=False).ngroup().to_numpy()
    count = np.bincount(groups).astype(float)

    def centred(a):
        sums = np.stack([np.bincount(groups, a[:, k]) for k in range(a.shape[1])], axis=1)
        return a - (sums / count[:, None])[groups]

    slopes, *_ = np.linalg.lstsq(centred(phi[:, 1:]), centred(world), rcond=None)
    first = (pts["position"].to_numpy() == pts.groupby("sequence")["position"].transform("min").to_numpy())
    const = np.mean(world[first] - phi[first, 1:] @ slopes, axis=0)
    return centre, scale, np.vstack([const, slopes]), mode


@register
class PlainPolynomial(Model):
    """World coordinates as one least-squares polynomial of total degree ``degree`` (1–4) in the four image
    coordinates (module docstring)."""

    name = "polynomial"
    summary = ("reference: one least-squares polynomial of degree 1-4 (option degree, default 2) from the four "
               "image coordinates to each world coordinate; on stage moves, one offset per dot")
    accuracy_rank = 55
    units = {"degree": "-", "centre_px": "px", "scale_px": "px", "coef": "mm per normalised monomial"}
    fixed_degree: int | None = None

    def __init__(self, centre_px, scale_px, coef, degree: int = 2, **kw):
        super().__init__(**kw)
        self.centre_px, self.scale_px = np.asarray(centre_px, float), np.asarray(scale_px, float)
        self.coef, self.degree = np.asarray(coef, float), int(degree)

    @classmethod
    def fit(cls, cal: CalibrationSet, *, degree: int = 2, mode: str = "auto", **_):
        degree = cls.fixed_degree or degree
        centre, scale, coef, mode = fit_polynomial(cal, degree, mode)
        return cls(centre, scale, coef, degree, options={"mode": mode, "degree": degree})

    def describe(self) -> str:
        return f"{self.name} (degree {self.degree})"

    def fixed_options(self) -> dict:
        return {"degree": self.degree}

    def reconstruct(self, w: np.ndarray) -> np.ndarray:
        w = np.asarray(w, float).reshape(-1, 4)
        return polynomial_features(w, self.degree, self.centre_px, self.scale_px) @ self.coef

    def parameters_dict(self) -> dict:
        return {"degree": self.degree, "centre_px": self.centre_px.tolist(), "scale_px": self.scale_px.tolist(),
                "coef": self.coef.tolist()}

    @classmethod
    def from_parameters(cls, p, calibration, options):
        return cls(p["centre_px"], p["scale_px"], p["coef"], int(p.get("degree", cls.fixed_degree or 2)),
                   calibration=calibration, options=options)


@register
class QuadraticReference(PlainPolynomial):
    """The plain polynomial of degree 2, on dots whose world positions are known (the reference of
    notebooks 09 and 10)."""

    name = "quadratic"
    summary = ("reference: one least-squares quadratic from the four image coordinates to each world "
               "coordinate (needs known world positions: a Z stack or a known target)")
    accuracy_rank = 60
    fixed_degree = 2

    @classmethod
    def fit(cls, cal: CalibrationSet, *, mode: str = "auto", **_):
        if world_positions(cal, mode)[2] == "moves":
            raise SlmlabError("the quadratic reference needs each dot's world position (a Z stack or a known "
                              "target)", cal.path)
        centre, scale, coef, mode = fit_polynomial(cal, 2, mode)
        return cls(centre, scale, coef, 2, options={"mode": mode})

    def describe(self) -> str:
        return self.name

    def parameters_dict(self) -> dict:
        return {"centre_px": self.centre_px.tolist(), "scale_px": self.scale_px.tolist(), "coef": self.coef.tolist()}
