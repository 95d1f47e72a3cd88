"""Checks of the rigs' physics (:mod:`slmlab.virtual.rigs`): the projection's round trip, the focus across the
field, and the exact refraction against Fermat's principle.

* :func:`physics_checks`: the true model's triangulation of exact projections, the defocus and astigmatic
  blur across the field on ``z = 0`` (the Scheimpflug focus of the stereo-PIV rig), and, for a rig behind a
  wall, the refraction against a brute-force minimisation of the optical path length
  (:func:`fermat_crossings`).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize

from .rigs import refraction_invariant

__all__ = ["fermat_crossings", "physics_checks"]


def fermat_crossings(rig, point_mm: np.ndarray, side: str) -> np.ndarray:
    """Where the ray from a point in the water to a stereo-PIV camera's pupil crosses the wall's inner and
    outer faces, in the plane of incidence (lateral distances from the point [mm]), by minimising the
    optical path length ``n_w |P G| + n_g |G E| + |E C|`` over the two crossings (SciPy's exact trust-region
    minimiser with the path length's gradient and Hessian, then three Newton steps on the gradient to reach
    machine precision; no use of Snell's law)."""
    c = rig.camera(side).centre
    p = np.asarray(point_mm, float)
    rho = float(np.hypot(*(c[:2] - p[:2])))
    h = np.array([rig.water_depth_mm - p[2], rig.wall_thickness_mm, c[2] - rig.water_depth_mm - rig.wall_thickness_mm])
    n = np.array([rig.water_index, rig.glass_index, 1.0])

    def parts(x):
        seg = np.diff(np.concatenate([[0.0], x, [rho]]))
        return seg, np.hypot(seg, h)

    def opl(x):
        seg, length = parts(x)
        return float((n * length).sum())

    def grad(x):
        seg, length = parts(x)
        g = n * seg / length
        return g[:-1] - g[1:]

    def hess(x):
        _, length = parts(x)
        k = n * h * h / length ** 3
        return np.array([[k[0] + k[1], -k[1]], [-k[1], k[1] + k[2]]])
    x = minimize(opl, rho * np.cumsum(h)[:2] / h.sum(), jac=grad, hess=hess, method="trust-exact").x
    for _ in range(3):
        x = x - np.linalg.solve(hess(x), grad(x))
    return x


def _snell_crossings(rig, point_mm, side) -> np.ndarray:
    """The same crossings from the rig's own refraction (the transverse invariant)."""
    c = rig.camera(side).centre
    p = np.asarray(point_mm, float)
    rho = np.hypot(*(c[:2] - p[:2]))
    h = np.array([rig.water_depth_mm - p[2], rig.wall_thickness_mm, c[2] - rig.water_depth_mm - rig.wall_thickness_mm])
    n = np.array([rig.water_index, rig.glass_index, 1.0])
    q = refraction_invariant(np.array([rho]), h[None, :], n)[0]
    return np.cumsum(h * q / np.sqrt(n * n - q * q))[:2]


def physics_checks(rig, n_points: int = 2000, seed: int = 0) -> dict:
    """Round trip, focus and (behind a wall) refraction checks of a rig on random points in its common field
    over ``±depth_mm`` (module docstring). Lengths in mm, blur in px."""
    rng = np.random.default_rng(seed)
    fw, fh = rig.field_mm()
    c, d = rig.field_centre_mm(), rig.depth_mm()
    p = c + rng.uniform(-1, 1, (n_points, 3)) * [fw / 2, fh / 2, d]
    out = {"rig": rig.preset, "field_w_mm": fw, "field_h_mm": fh, "depth_mm": d,
           "depth_of_field_mm": rig.depth_of_field_mm(), "px_per_mm": rig.px_per_mm(),
           "round_trip_max_mm": float(np.abs(rig.triangulate(rig.project(p)) - p).max())}
    plane = p * [1, 1, 0]
    for side in "lr":
        defocus, astig = rig.blur_components_px(plane, side)
        out[f"defocus_z0_max_px_{side}"] = float(defocus.max())
        out[f"astigmatism_z0_max_px_{side}"] = float(astig.max())
        out[f"blur_at_depth_max_px_{side}"] = float(rig.blur_px(p, side)[0].max())
        if hasattr(rig, "wall_thickness_mm"):
            diff = [np.abs(fermat_crossings(rig, q, side) - _snell_crossings(rig, q, side)).max() for q in p[:20]]
            out[f"snell_vs_fermat_max_mm_{side}"] = float(max(diff))
    sigma = rig.centroid_sigma_px(p)
    out["centroid_sigma_px_min"], out["centroid_sigma_px_max"] = float(sigma.min()), float(sigma.max())
    return out
