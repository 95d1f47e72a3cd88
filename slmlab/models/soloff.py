"""The stereo-PIV/DIC standard: one polynomial per camera from world to image (Soloff, Adrian & Liu 1997).

Each image coordinate is a polynomial in the world coordinates, by default cubic in ``X`` and ``Y`` and
quadratic in ``Z`` (Soloff et al., *Meas. Sci. Technol.* 8:1441, 1997; as Pycaso does for stereo
microscopes, Caron et al., *SoftwareX* 23:101440, 2023):

    ``w = Σ c_ijk · x^i y^j z^k``  over ``i + j + k ≤ 3``, ``k ≤ 2`` (19 terms per image coordinate),

in world coordinates centred and scaled over the calibration set. The four polynomials (two per camera)
are fitted by least squares on dots whose world position is known: a Z stack of a plate of known pitch
(stage ``Z`` plus the plate's lattice), or a known target (stage plus ``x_mm, y_mm, z_mm``; README, "The format").
The fit goes in the direction in which the errors are: the world positions are exact, the image
coordinates noisy, so the least-squares fit is unbiased (a map from image to world, fitted the other way,
regresses on noisy variables).

Reconstruction solves the four equations for the three world coordinates by Gauss–Newton, vectorised over
points, weighted by each image coordinate's residual scatter on the calibration set; it starts from a
quadratic regression of world on image coordinates fitted at calibration time, and converges in two or
three steps. Per-point uncertainty (1σ) comes from the image noise through the Jacobian,
``(JᵀWJ)⁻¹``, plus the coefficients' uncertainty carried the same way.

The degrees (in ``X, Y`` together and in ``Z``) are chosen on held-out positions (planes) of the
calibration set, never on test data, by the geometric mean of the three coordinates' held-out errors (one set
of polynomials serves all three), and capped by the data: a polynomial of degree ``k`` in ``Z`` needs more
than ``k`` distinct depths.
"""

from __future__ import annotations

import numpy as np

from ..errors import SlmlabError
from ..io import IMAGE_COLUMNS, CalibrationSet
from .base import Model, register
from .direct import DEGREE_ROWS
from .folds import row_folds, thin_dots
from .frames import distinct_levels, dot_labels, world_positions
from .reference import quadratic_features

__all__ = ["terms", "SoloffModel", "fit_soloff", "DEGREES"]

#: candidate (degree in X and Y, degree in Z); the first is Soloff's
DEGREES = ((3, 2), (3, 1), (2, 2), (2, 1), (4, 2))


def terms(xy_degree: int = 3, z_degree: int = 2) -> list[tuple[int, int, int]]:
    """Exponents ``(i, j, k)`` of ``x^i y^j z^k`` with ``i + j + k ≤ xy_degree`` and ``k ≤ z_degree``."""
    out = []
    for total in range(xy_degree + 1):
        for k in range(min(total, z_degree) + 1):
            for i in range(total - k, -1, -1):
                out.append((i, total - k - i, k))
    return out


def _powers(xn: np.ndarray, degree: int) -> np.ndarray:
    """``(3, degree + 1, n)`` tables of ``x^p`` per normalised coordinate."""
    p = np.empty((3, degree + 1, len(xn)))
    p[:, 0] = 1.0
    for k in range(1, degree + 1):
        np.multiply(p[:, k - 1], xn.T, out=p[:, k])
    return p


def _design(xn: np.ndarray, exps) -> np.ndarray:
    """Monomials ``(n, m)`` of normalised world coordinates."""
    deg = max(max(e) for e in exps)
    p = _powers(xn, deg)
    return np.stack([p[0, i] * p[1, j] * p[2, k] for i, j, k in exps], axis=1)


def fit_soloff(world: np.ndarray, w: np.ndarray, xy_degree: int = 3, z_degree: int = 2, dots=None) -> dict:
    """Least-squares fit of the four image coordinates ``w (n, 4)`` [px] as polynomials of ``world (n, 3)``
    [mm]. Rows with a missing image coordinate are left out of that camera's fit only. Returns the model's
    parameters (``centre_mm``, ``scale_mm``, ``exponents``, ``coef (m, 4)``, ``sigma_px (4,)`` the residual
    scatter, ``noise_poly (4, 3)`` one point's variance [px²] as a quadratic in the normalised depth, the
    coefficients' ``(ΦᵀΦ)⁻¹`` per camera, and the regression start ``start``).

    ``dots``: a label per row (the dot); where dots recur at several positions (a Z stack) one point's
    scatter is measured within dots, so that the plate's own errors (the same in every plane) are not taken
    for a measurement's noise."""
    world, w = np.asarray(world, float), np.asarray(w, float)
    ok_world = np.isfinite(world).all(axis=1)
    world, w = world[ok_world], w[ok_world]
    dots = None if dots is None else np.asarray(dots)[ok_world]
    lo, hi = world.min(axis=0), world.max(axis=0)
    centre, scale = (lo + hi) / 2, np.maximum((hi - lo) / 2, 1e-9)
    exps = terms(xy_degree, z_degree)
    a = _design((world - centre) / scale, exps)
    coef = np.zeros((len(exps), 4))
    sigma = np.zeros(4)
    inv = []
    for cam in (0, 1):
        cols = slice(2 * cam, 2 * cam + 2)
        ok = np.isfinite(w[:, cols]).all(axis=1)
        if ok.sum() <= len(exps):
            raise SlmlabError(f"the {'left' if cam == 0 else 'right'} view has {int(ok.sum())} dots with a known "
                              f"position, too few for a polynomial of {len(exps)} terms; image more dots or planes")
        gram = a[ok].T @ a[ok]
        lam, vec = np.linalg.eigh(gram)
        keep = lam > 1e-12 * lam[-1]
        gi = (vec[:, keep] / lam[keep]) @ vec[:, keep].T
        coef[:, cols] = gi @ (a[ok].T @ w[ok, cols])
        res = w[ok, cols] - a[ok] @ coef[:, cols]
        sigma[cols] = np.sqrt(np.sum(res ** 2, axis=0) / max(ok.sum() - len(exps), 1))
        inv.append(gi)
    both = np.isfinite(w).all(axis=1)
    wc, ws = w[both].mean(axis=0), np.maximum(w[both].std(axis=0), 1e-9)
    start, *_ = np.linalg.lstsq(quadratic_features(w[both], wc, ws), world[both], rcond=None)
    sigma = np.maximum(sigma, 1e-6)
    noise = _noise_poly(a @ coef - w, (world[:, 2] - centre[2]) / scale[2], dots, sigma, len(exps))
    return {"centre_mm": centre, "scale_mm": scale, "exponents": exps, "coef": coef, "sigma_px": sigma,
            "noise_poly": noise, "gram_inverse": inv, "start": {"centre_px": wc, "scale_px": ws, "coef": start}}


def _noise_poly(res: np.ndarray, zn: np.ndarray, dots, sigma: np.ndarray, m: int) -> np.ndarray:
    """One point's variance [px²] per image coordinate as ``a + b·zn + c·zn²`` ``(4, 3)``: fitted to the
    squared residuals within dots (net of each dot's mean over positions) where dots recur, else constant at
    the residual variance; floored at a quarter of its mean."""
    out = np.zeros((4, 3))
    out[:, 0] = sigma ** 2
    if dots is None:
        return out
    labels, inv = np.unique(dots, return_inverse=True)
    inv = inv.ravel()
    for c in range(4):
        ok = np.isfinite(res[:, c])
        n_d = np.bincount(inv[ok], minlength=len(labels))
        if (n_d >= 2).sum() < 10:
            continue
        mean = np.bincount(inv[ok], res[ok, c], len(labels)) / np.maximum(n_d, 1)
        keep = ok & (n_d[inv] >= 2)
        within = (res[keep, c] - mean[inv[keep]]) ** 2 * (n_d[inv[keep]] / (n_d[inv[keep]] - 1))
        z = zn[keep]
        coef, *_ = np.linalg.lstsq(np.column_stack([np.ones_like(z), z, z * z]), within, rcond=None)
        out[c] = coef
    return out


def _noise_sigma(noise_poly: np.ndarray, zn: np.ndarray) -> np.ndarray:
    """One point's σ ``(4, n)`` [px] at normalised depths ``zn (n,)`` (floored at half the mean σ)."""
    var = noise_poly @ np.stack([np.ones_like(zn), zn, zn * zn])
    floor = 0.25 * np.maximum(noise_poly[:, 0], 1e-12)[:, None]
    return np.sqrt(np.maximum(var, floor))


@register
class SoloffModel(Model):
    """One polynomial per camera, world → image (Soloff et al. 1997), reconstructed by Gauss–Newton."""

    name = "soloff"
    summary = ("stereo-PIV/DIC standard: per-camera polynomial world -> image (cubic in X, Y, quadratic in Z), "
               "Gauss-Newton reconstruction; calibrates from a Z stack or a known target")
    accuracy_rank = 8
    units = {"coef": "px per normalised monomial", "centre_mm": "mm", "scale_mm": "mm", "sigma_px": "px",
             "noise_poly": "px^2 per power of the normalised depth",
             "gram_inverse": "1 per normalised monomial^2", "start": "mm per normalised quadratic monomial"}

    def __init__(self, p: dict, **kw):
        super().__init__(**kw)
        self.centre = np.asarray(p["centre_mm"], float)
        self.scale = np.asarray(p["scale_mm"], float)
        self.exps = [tuple(int(v) for v in e) for e in p["exponents"]]
        self.coef = np.asarray(p["coef"], float)
        self.sigma = np.asarray(p["sigma_px"], float)
        self.noise_poly = (np.column_stack([self.sigma ** 2, np.zeros((4, 2))]) if p.get("noise_poly") is None
                           else np.asarray(p["noise_poly"], float))
        self.gram_inverse = [np.asarray(g, float) for g in p["gram_inverse"]]
        s = p["start"]
        self.start = {"centre_px": np.asarray(s["centre_px"], float), "scale_px": np.asarray(s["scale_px"], float),
                      "coef": np.asarray(s["coef"], float)}

    # ------------------------------------------------------------------ fitting
    @classmethod
    def fit(cls, cal: CalibrationSet, *, degree=None, mode: str = "auto", **_):
        """Fit on a set whose dots' world positions are known (a Z stack of a plate of known pitch, or a known
        target). ``degree``: ``[xy, z]`` (default: chosen on held-out positions among :data:`DEGREES`);
        ``mode``: as :func:`slmlab.models.frames.world_positions`."""
        pts, world, mode = world_positions(cal, mode)
        if mode == "moves":
            raise SlmlabError("the soloff model needs each dot's world position: a Z stack of a plate with rows, "
                              "cols and pitch, or a known-target set (x_mm, y_mm, z_mm); this set has stage moves "
                              "of a plate whose place on the stage is unknown (use the direct model)", cal.path)
        w = pts[IMAGE_COLUMNS].to_numpy(float)
        n_z, n_xy = distinct_levels(world), min(distinct_levels(world, k) for k in (0, 1))
        cv = {}
        if degree is None:
            options = [d for d in DEGREES if d[1] < n_z and d[0] < n_xy]
            if not options:
                raise SlmlabError(f"the set has {n_z} distinct depth(s) and {n_xy} distinct lateral positions; the "
                                  "soloff model needs at least 2 depths and 3 lateral positions", cal.path)
            cv = _held_out(pts, world, w, options)
            # one set of polynomials serves all three coordinates, whose errors differ several-fold (depth
            # is the weak one of any stereo rig): compare the geometric mean of their held-out errors
            best = min(cv, key=lambda d: (float(np.mean(np.log(np.maximum(cv[d], 1e-12)))), DEGREES.index(d)))
        else:
            best = tuple(int(v) for v in np.atleast_1d(degree))
            if len(best) != 2 or best[0] < 1 or best[1] < 0 or best[1] > best[0] or best[0] > 5:
                raise SlmlabError(f"degree must be [xy, z] with 1 <= xy <= 5 and 0 <= z <= xy, not {degree!r}")
            if best[1] >= n_z:
                raise SlmlabError(f"a degree of {best[1]} in Z needs more than {best[1]} distinct depths; the set has "
                                  f"{n_z}", cal.path)
        p = fit_soloff(world, w, *best, dots=dot_labels(pts))
        model = cls(p, options={"degree": list(best), "degree_chosen_by": "held-out positions" if degree is None
                                else "user", "mode": mode},
                    calibration={"held_out_rms_mm_by_degree": {f"{a},{b}": [float(v) for v in e]
                                                               for (a, b), e in cv.items()},
                                 "image_residual_sigma_px": [float(v) for v in p["sigma_px"]],
                                 "frame": ("the target's frame plus the stage's moves" if mode == "target" else
                                           "plate axes (x = ((cols+1)/2 - col) pitch, y = ((rows+1)/2 - row) "
                                           "pitch) and the Z stage's direction"),
                                 "distinct_depths": int(n_z)})
        return model

    # ------------------------------------------------------------------ the map
    def project(self, world: np.ndarray) -> np.ndarray:
        """Image coordinates ``(n, 4)`` [px] of world points ``(n, 3)`` [mm]."""
        return _design((np.atleast_2d(world) - self.centre) / self.scale, self.exps) @ self.coef

    def _stacked(self) -> np.ndarray:
        """``(16, m)``: the coefficients of the four image coordinates and of their derivatives by ``x, y, z``
        (normalised), on the same monomials. The term set is closed under differentiation (lowering an
        exponent keeps ``i + j + k ≤ xy`` and ``k ≤ z``), so one product with the monomials gives values and
        Jacobian at once."""
        if getattr(self, "_stack", None) is None:
            index = {e: n for n, e in enumerate(self.exps)}
            out = np.zeros((4, len(self.exps), 4))
            out[0] = self.coef
            for n, e in enumerate(self.exps):
                for axis in range(3):
                    if e[axis]:
                        lower = list(e)
                        lower[axis] -= 1
                        out[axis + 1, index[tuple(lower)]] += e[axis] * self.coef[n]
            self._stack = np.ascontiguousarray(out.transpose(0, 2, 1).reshape(16, len(self.exps)))
        return self._stack

    def _monomials(self, x: np.ndarray) -> np.ndarray:
        """Monomial-major ``(m, n)`` of normalised points ``x (3, n)``, each row contiguous."""
        deg = max(max(e) for e in self.exps)
        p = np.empty((3, deg + 1, x.shape[1]))
        p[:, 0] = 1.0
        for k in range(1, deg + 1):
            np.multiply(p[:, k - 1], x, out=p[:, k])
        out = np.empty((len(self.exps), x.shape[1]))
        for row, (i, j, k) in enumerate(self.exps):
            np.multiply(p[0, i], p[1, j], out=out[row])
            if k:
                out[row] *= p[2, k]
        return out

    def _evaluate(self, x: np.ndarray):
        """Image coordinates ``(4, n)``, weights ``(4, n)`` (one over one point's σ at its depth) and the
        weighted Jacobian ``(3, 4, n)`` at normalised points ``(3, n)``."""
        f = self._stacked() @ self._monomials(x)
        wt = 1.0 / _noise_sigma(self.noise_poly, x[2])
        return f[0:4], wt, f[4:16].reshape(3, 4, -1) * wt[None]

    def _solve(self, w: np.ndarray, max_iterations: int = 8, tolerance: float = 1e-4):
        """Normalised world points ``(3, n)`` by weighted Gauss–Newton on the four equations, from the
        regression start, until the largest step is below ``tolerance`` (normally two steps). The error left
        after a step is of the order of the step squared: below 1e-8 of the calibrated half-range."""
        s = self.start
        x = np.ascontiguousarray(((quadratic_features(w, s["centre_px"], s["scale_px"]) @ s["coef"] - self.centre)
                                  / self.scale).T)
        wT = np.ascontiguousarray(w.T)
        for _ in range(max_iterations):
            f, wt, j = self._evaluate(x)
            r = (wT - f) * wt
            step = _solve3(j, r)
            x += step
            if not step.size or np.abs(step).max() < tolerance:  # (no point: nothing to solve)
                break
        return x

    def reconstruct(self, w: np.ndarray) -> np.ndarray:
        w = np.atleast_2d(np.asarray(w, float))
        out = np.empty((len(w), 3))
        for lo in range(0, len(w), 1 << 15):
            out[lo:lo + (1 << 15)] = self._solve(w[lo:lo + (1 << 15)]).T * self.scale + self.centre
        return out

    def uncertainty(self, w: np.ndarray) -> np.ndarray:
        """1σ ``(n, 3)`` [mm]: one point's scatter at its depth (measured within dots on the calibration set)
        through the Jacobian, ``(JᵀWJ)⁻¹``, plus the coefficients' uncertainty carried the same way (with the
        calibration's whole residual scatter, the plate's own errors included)."""
        w = np.atleast_2d(np.asarray(w, float))
        x = self._solve(w)
        _, wt, j = self._evaluate(x)
        jac = j.transpose(2, 1, 0)                                       # (n, 4, 3), weighted
        cov = np.linalg.inv(np.einsum("nik,nil->nkl", jac, jac))         # normalised units, noise part
        g = np.einsum("nkl,nil->nki", cov, jac)                          # (n, 3, 4): dx per weighted residual
        a = self._monomials(x).T
        q = np.stack([np.einsum("ni,ij,nj->n", a, self.gram_inverse[c], a) for c in (0, 1)], axis=1)
        cal = np.repeat(q, 2, axis=1) * (self.sigma[None, :] * wt.T) ** 2   # in weighted units
        var = np.diagonal(cov, axis1=1, axis2=2) + np.einsum("nki,ni->nk", g ** 2, cal)
        return np.sqrt(var) * self.scale

    def describe(self) -> str:
        xy = max(i + j for i, j, _ in self.exps)
        z = max(k for _, _, k in self.exps)
        return f"soloff, degree {xy} in X, Y and {z} in Z"

    def fixed_options(self) -> dict:
        return {"degree": list(self.options["degree"])} if "degree" in self.options else {}

    def parameters_dict(self) -> dict:
        return {"centre_mm": self.centre.tolist(), "scale_mm": self.scale.tolist(),
                "exponents": [list(e) for e in self.exps], "coef": self.coef.tolist(),
                "sigma_px": self.sigma.tolist(), "noise_poly": self.noise_poly.tolist(),
                "gram_inverse": [g.tolist() for g in self.gram_inverse],
                "start": {k: v.tolist() for k, v in self.start.items()}}

    @classmethod
    def from_parameters(cls, parameters, calibration, options):
        return cls(parameters, calibration=calibration, options=options)


def _solve3(j: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Gauss–Newton steps ``(3, n)``: ``(JᵀJ)⁻¹ Jᵀr`` per point, from ``J (3, 4, n)`` and ``r (4, n)``, with the
    symmetric 3 × 3 normal matrices inverted in closed form (cofactors), elementwise over points."""
    a = np.einsum("kin,lin->kln", j, j)
    b = np.einsum("kin,in->kn", j, r)
    c00 = a[1, 1] * a[2, 2] - a[1, 2] * a[1, 2]
    c01 = a[0, 2] * a[1, 2] - a[0, 1] * a[2, 2]
    c02 = a[0, 1] * a[1, 2] - a[0, 2] * a[1, 1]
    c11 = a[0, 0] * a[2, 2] - a[0, 2] * a[0, 2]
    c12 = a[0, 1] * a[0, 2] - a[0, 0] * a[1, 2]
    c22 = a[0, 0] * a[1, 1] - a[0, 1] * a[0, 1]
    det = a[0, 0] * c00 + a[0, 1] * c01 + a[0, 2] * c02
    det = np.where(np.abs(det) > 1e-300, det, 1e-300)
    return np.stack([c00 * b[0] + c01 * b[1] + c02 * b[2],
                     c01 * b[0] + c11 * b[1] + c12 * b[2],
                     c02 * b[0] + c12 * b[1] + c22 * b[2]]) / det


def _held_out(pts, world, w, options) -> dict:
    """Held-out RMS [mm] per coordinate of each degree option, on crossed folds of planes and dots
    (:func:`slmlab.models.folds.row_folds`); errors net of one common offset."""
    folds = row_folds(pts, "target")
    if len(pts) > DEGREE_ROWS:  # the degrees are chosen on every k-th dot: a ranking, not the fit, needs them
        keep = thin_dots(pts, DEGREE_ROWS)
        folds = [(tr & keep, te & keep) for tr, te in folds]
    labels = np.unique(dot_labels(pts), return_inverse=True)[1].ravel()  # sorted like the labels: the same bits
    out = {}
    for d in options:
        errs = []
        for train, held in folds:
            try:
                p = fit_soloff(world[train], w[train], *d, dots=labels[train])
            except SlmlabError:
                errs = None
                break
            m = SoloffModel(p)
            ok = np.isfinite(w[held]).all(axis=1) & np.isfinite(world[held]).all(axis=1)
            if ok.any():
                e = m.reconstruct(w[held][ok]) - world[held][ok]
                errs.append(e - np.median(e, axis=0))
        if errs:
            e = np.vstack(errs)
            out[d] = np.sqrt(np.mean(e ** 2, axis=0))
    if not out:
        raise SlmlabError("too few positions to calibrate the soloff model with held-out planes; give degree=[xy, z]")
    return out


