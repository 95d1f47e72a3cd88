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


def fit_polynomial(cal: CalibrationSet, degree: int, mode: str = "auto") -> dict:
    """The plain polynomial of ``degree`` on ``cal`` (module docstring): ``centre_px``, ``scale_px``, ``coef``
    ``(m, 3)`` [mm per normalised monomial], ``sigma_mm`` (3,) (one point's scatter about the fit, per
    coordinate), ``inverse`` ``(m, m)`` (the inverse normal matrix: ``sigma² · inverse`` is the coefficients'
    covariance), and ``mode``."""
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
    if mode == "moves":
        groups = pts.groupby(["sequence", "row", "col"], sort=False).ngroup().to_numpy()
        a, y, free = _centred(phi[:, 1:], groups), _centred(world, groups), int(groups.max()) + 1
        slopes, *_ = np.linalg.lstsq(a, y, rcond=None)
        first = (pts["position"].to_numpy() == pts.groupby("sequence")["position"].transform("min").to_numpy())
        coef = np.vstack([np.mean(world[first] - phi[first, 1:] @ slopes, axis=0), slopes])
        inverse = np.zeros((n_terms, n_terms))
        inverse[1:, 1:] = np.linalg.pinv(a.T @ a)
        resid = y - a @ slopes
    else:
        coef, *_ = np.linalg.lstsq(phi, world, rcond=None)
        inverse, resid, free = np.linalg.pinv(phi.T @ phi), world - phi @ coef, 0
    dof = max(len(w) - n_terms - free, 1)
    sigma = np.sqrt(np.sum(resid ** 2, axis=0) / dof)
    return {"centre_px": centre, "scale_px": scale, "coef": coef, "sigma_mm": sigma, "inverse": inverse, "mode": mode}


def _centred(a: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """``a`` less its mean per group (the within-group estimator's design)."""
    count = np.bincount(groups).astype(float)
    sums = np.stack([np.bincount(groups, a[:, k]) for k in range(a.shape[1])], axis=1)
    return a - (sums / count[:, None])[groups]


@register
class PlainPolynomial(Model):
    """World coordinates as one least-squares polynomial of total degree ``degree`` (1–4) in the four image
    coordinates (module docstring). Per-point 1σ: one point's scatter about the fit and the coefficients'
    covariance (ordinary least squares: no stage error modelled, no growth with defocus)."""

    name = "polynomial"
    summary = ("reference: one least-squares polynomial of degree 1-4 (option degree, default 2) from the four "
               "image coordinates to each world coordinate; on stage moves, one offset per dot")
    accuracy_rank = 55
    units = {"degree": "-", "centre_px": "px", "scale_px": "px", "coef": "mm per normalised monomial",
             "sigma_mm": "mm", "inverse": "1 / normalised monomial^2"}
    fixed_degree: int | None = None

    def __init__(self, centre_px, scale_px, coef, degree: int = 2, sigma_mm=None, inverse=None, **kw):
        super().__init__(**kw)
        self.centre_px, self.scale_px = np.asarray(centre_px, float), np.asarray(scale_px, float)
        self.coef, self.degree = np.asarray(coef, float), int(degree)
        self.sigma_mm = None if sigma_mm is None else np.asarray(sigma_mm, float)
        self.inverse = None if inverse is None else np.asarray(inverse, float)

    @classmethod
    def fit(cls, cal: CalibrationSet, *, degree: int = 2, mode: str = "auto", **_):
        degree = cls.fixed_degree or degree
        f = fit_polynomial(cal, degree, mode)
        return cls(f["centre_px"], f["scale_px"], f["coef"], degree, f["sigma_mm"], f["inverse"],
                   options={"mode": f["mode"], "degree": degree})

    def describe(self) -> str:
        return f"{self.name} (degree {self.degree})"

    def fixed_options(self) -> dict:
        return {"degree": self.degree}

    def _features(self, w: np.ndarray) -> np.ndarray:
        return polynomial_features(np.asarray(w, float).reshape(-1, 4), self.degree, self.centre_px, self.scale_px)

    def reconstruct(self, w: np.ndarray) -> np.ndarray:
        return self._features(w) @ self.coef

    def calibration_sigma(self, w: np.ndarray) -> np.ndarray:
        """1σ ``(n, 3)`` [mm] of the fitted polynomial at ``w`` (the coefficients' covariance alone)."""
        phi = self._features(w)
        if self.sigma_mm is None or self.inverse is None:
            return np.full((len(phi), 3), np.nan)
        lever = np.einsum("ij,jk,ik->i", phi, self.inverse, phi)
        return np.sqrt(np.maximum(lever, 0.0))[:, None] * self.sigma_mm[None, :]

    def uncertainty(self, w: np.ndarray) -> np.ndarray:
        """1σ ``(n, 3)`` [mm] of one reconstructed point: its scatter about the fit and the calibration's."""
        cal = self.calibration_sigma(w)
        return np.sqrt(cal ** 2 + (np.nan if self.sigma_mm is None else self.sigma_mm) ** 2)

    def parameters_dict(self) -> dict:
        out = {"degree": self.degree, "centre_px": self.centre_px.tolist(), "scale_px": self.scale_px.tolist(),
               "coef": self.coef.tolist()}
        if self.sigma_mm is not None:
            out.update(sigma_mm=self.sigma_mm.tolist(), inverse=self.inverse.tolist())
        return out

    @classmethod
    def from_parameters(cls, p, calibration, options):
        return cls(p["centre_px"], p["scale_px"], p["coef"], int(p.get("degree", cls.fixed_degree or 2)),
                   p.get("sigma_mm"), p.get("inverse"), calibration=calibration, options=options)


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
        f = fit_polynomial(cal, 2, mode)
        return cls(f["centre_px"], f["scale_px"], f["coef"], 2, f["sigma_mm"], f["inverse"],
                   options={"mode": f["mode"]})

    def describe(self) -> str:
        return self.name
