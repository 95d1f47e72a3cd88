"""The zoo's checks: the rigs' physics, and how well each model calibrates each rig from each design.

* :func:`physics_checks`: projection round trip (the true model's triangulation of exact projections), the
  defocus and astigmatic blur across the field on ``z = 0`` (the Scheimpflug focus of the stereo-PIV rig),
  and, for a rig behind a wall, the exact refraction against a brute-force minimisation of the optical path
  length (Fermat's principle, :func:`fermat_crossings`).
* :func:`compare_models`: a rig, a design (:mod:`slmlab.virtual.designs`) and a held-out validation set of
  random points in the calibrated volume; per coordinate RMS error (net of one common offset, in the frame
  the design calibrates in) of each model (:func:`slmlab.calibrate`), of plain least-squares polynomials of
  degree 1–4 in the four image coordinates (:func:`fit_plain_polynomial`), and of the true model on the same
  noisy centres (the floor).
"""

from __future__ import annotations

from itertools import combinations_with_replacement

import numpy as np
import pandas as pd
from scipy.optimize import minimize

from ..direct import world_positions
from ..errors import SlmlabError
from ..io import IMAGE_COLUMNS, CalibrationSet
from ..models import calibrate
from ..realrig import rms_after_offset
from .designs import DESIGNS, design_frame, simulate_design, validation_set
from .rigs import refraction_invariant

__all__ = ["MODELS", "POLY_DEGREES", "monomials", "fit_plain_polynomial", "fermat_crossings", "physics_checks",
           "compare_models", "run_zoo", "ratio_table"]

MODELS = ("auto", "direct", "soloff", "quadratic", "pinhole")
POLY_DEGREES = (1, 2, 3, 4)


def monomials(u: np.ndarray, degree: int) -> np.ndarray:
    """All monomials of the columns of ``u (n, k)`` up to total ``degree``, the constant first ``(n, m)``."""
    cols = [np.ones(len(u))]
    for d in range(1, degree + 1):
        cols += [np.prod(u[:, list(c)], axis=1) for c in combinations_with_replacement(range(u.shape[1]), d)]
    return np.column_stack(cols)


def fit_plain_polynomial(cal: CalibrationSet, degree: int):
    """A least-squares polynomial of total ``degree`` from the four image coordinates (normalised over the
    set) to each world coordinate, fitted on the set's world positions
    (:func:`slmlab.direct.world_positions`); for stage moves of a plate whose place is unknown, with one
    free offset per dot and sequence (the within-group estimator). Returns ``reconstruct(w) -> (n, 3)``."""
    pts, world, mode = world_positions(cal)
    w = pts[IMAGE_COLUMNS].to_numpy(float)
    centre, scale = w.mean(axis=0), w.std(axis=0)
    m = monomials((w - centre) / scale, degree)
    if mode == "moves":
        groups = pts.groupby(["sequence", "row", "col"]).ngroup().to_numpy()
        count = np.bincount(groups)

        def demean(a):
            sums = np.zeros((groups.max() + 1, a.shape[1]))
            np.add.at(sums, groups, a)
            return a - (sums / count[:, None])[groups]
        coef = np.linalg.lstsq(demean(m[:, 1:]), demean(world), rcond=None)[0]
        coef = np.vstack([np.zeros((1, 3)), coef])
    else:
        coef = np.linalg.lstsq(m, world, rcond=None)[0]
    return lambda x: monomials((np.atleast_2d(x) - centre) / scale, degree) @ coef


# --------------------------------------------------------------------------------------------- physics
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


# --------------------------------------------------------------------------------------------- models
def compare_models(rig, design: str, *, seed: int = 1, models=MODELS, n_validation: int = 1500) -> pd.DataFrame:
    """Per coordinate RMS error [µm] on a held-out validation set (:func:`validation_set`) of each model
    calibrated on ``design`` (``pinhole-f``: the pinhole model started from the rig's true focal length), of
    plain polynomials of degree :data:`POLY_DEGREES` and of the true model (the
    floor), in the design's frame net of one common offset; ``error``: why a model could not calibrate."""
    cal = simulate_design(rig, design, seed=seed)
    val = validation_set(rig, cal, n_validation, seed=seed + 1000)
    frame = design_frame(rig, design)
    w = val.points[IMAGE_COLUMNS].to_numpy(float)
    truth = val.truth[["X_mm", "Y_mm", "Z_mm"]].to_numpy(float) @ frame.T
    origin = np.asarray(val.meta["simulator"]["stage_origin_mm"])
    floor = rig.microscope_to_stage(rig.triangulate(w), origin) @ frame.T
    rows = [("floor", floor, "")]
    cam = rig.camera("l")
    runs = [(name, name, {}) for name in models]
    if "pinhole" in models:  # the pinhole model again, told the true focal length as a start (a user knows the lens)
        runs.append(("pinhole-f", "pinhole", {"f_guess_px": float(cam.x0[2] / cam.pixel_mm)}))
    for label, name, options in runs:
        try:
            model = calibrate(cal, name, **options)
            rows.append((label, model.reconstruct(w), model.describe()))
        except SlmlabError as exc:
            rows.append((label, None, f"error: {exc}"))
    for degree in POLY_DEGREES:
        rows.append((f"poly{degree}", fit_plain_polynomial(cal, degree)(w), ""))
    out = []
    for name, p, note in rows:
        e = 1e3 * rms_after_offset(p - truth) if p is not None else np.full(3, np.nan)
        out.append({"rig": rig.preset, "design": design, "model": name, "X_um": e[0], "Y_um": e[1], "Z_um": e[2],
                    "note": note})
    return pd.DataFrame(out)


def run_zoo(rigs, designs=tuple(DESIGNS), *, seed: int = 1, models=MODELS, n_validation: int = 1500) -> pd.DataFrame:
    """:func:`compare_models` for every rig and design (the pinhole model only where it applies: the
    stage-sequence design), one table; ``seconds`` the time each design took (minutes on two cores)."""
    import time

    frames = []
    for rig in rigs:
        for design in designs:
            start = time.perf_counter()
            use = models if design == "stage-sequences" else tuple(m for m in models if m != "pinhole")
            df = compare_models(rig, design, seed=seed, models=use, n_validation=n_validation)
            frames.append(df.assign(seconds=time.perf_counter() - start))
    return pd.concat(frames, ignore_index=True)


def ratio_table(results: pd.DataFrame) -> pd.DataFrame:
    """Per rig, design and model: RMS over the floor and over the best plain polynomial (per coordinate)."""
    rows = []
    for (rig, design), g in results.groupby(["rig", "design"], sort=False):
        g = g.set_index("model")
        floor = g.loc["floor"]
        polys = g.loc[[m for m in g.index if m.startswith("poly")]]
        for model, r in g.iterrows():
            if model == "floor" or model.startswith("poly"):
                continue
            row = {"rig": rig, "design": design, "model": model}
            for c in "XYZ":
                row[f"{c}_vs_floor"] = r[f"{c}_um"] / floor[f"{c}_um"]
                row[f"{c}_vs_poly"] = r[f"{c}_um"] / polys[f"{c}_um"].min()
            rows.append(row)
    return pd.DataFrame(rows)
