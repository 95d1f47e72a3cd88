"""Beyond the paper: a direct polynomial mapping from image coordinates to the stage frame.

The paper's chain is linear after its corrections, so what a CMO microscope does beyond them (perspective: a
disparity ``∝ z/(L − z)`` and a magnification that changes with depth; the disparity curvature the paper's
procedure misses; residual camera rotation) is left in its residuals. This model maps
``(v1, v2, D) = ((w1_l + w1_r)/2, (w2_l + w2_r)/2, w1_r − w1_l)`` to stage coordinates with a polynomial
of total degree ``k`` fitted by least squares on the calibration set's stage moves, with **one unknown offset
per dot and sequence** (eliminated by centring each dot's rows), so no absolute plate position is needed.

* The degree is chosen on held-out positions (every third position of each sequence), never on test data.
* Outliers (mismatched or misindexed dots) are down-weighted by iteratively reweighted least squares (Huber
  weights on the residual norm, then rejection beyond 10 robust sigmas); the rejected rows are reported.
* Per-point uncertainty ``sX, sY, sZ`` [mm] (1σ): centroid noise propagated through the polynomial's
  Jacobian, the coefficients' covariance, and the stage's repeatability measured by the fit's residuals.
"""

from __future__ import annotations

from itertools import combinations_with_replacement

import numpy as np

from .errors import SlmlabError
from .io import CalibrationSet, IMAGE_COLUMNS
from .linefit import point_keys
from .models import Model, register

__all__ = ["features", "fit_direct", "DirectModel"]

SCALE = np.array([1024.0, 1024.0, 100.0])
CENTRE = np.array([1024.0, 1024.0, 0.0])


def _exponents(degree: int) -> list[tuple[int, int, int]]:
    out = []
    for d in range(1, degree + 1):
        for combo in combinations_with_replacement(range(3), d):
            out.append(tuple(combo.count(k) for k in range(3)))
    return out


def _variables(w: np.ndarray) -> np.ndarray:
    w = np.asarray(w, float)
    v = np.column_stack([(w[:, 0] + w[:, 2]) / 2, (w[:, 1] + w[:, 3]) / 2, w[:, 2] - w[:, 0]])
    return (v - CENTRE) / SCALE


def features(w: np.ndarray, degree: int) -> np.ndarray:
    """Monomials of the normalised ``(v1, v2, D)`` up to total ``degree`` (no constant) ``(n, m)``.

    Built from power tables (``v**k`` by repeated multiplication, then two products per monomial) into a
    preallocated array: no ``pow`` calls, no temporary per monomial."""
    v = _variables(w)
    n = len(v)
    powers = np.empty((3, degree + 1, n))
    powers[:, 0] = 1.0
    for k in range(1, degree + 1):
        np.multiply(powers[:, k - 1], v.T, out=powers[:, k])
    return _features_t(powers, degree).T


def _features_t(powers: np.ndarray, degree: int) -> np.ndarray:
    """Monomial-major features ``(m, n)``, each row written contiguously, from power tables."""
    exps = _exponents(degree)
    out = np.empty((len(exps), powers.shape[2]))
    for row, (a, b, c) in enumerate(exps):
        np.multiply(powers[0, a], powers[1, b], out=out[row])
        if c:
            out[row] *= powers[2, c]
    return out


def _rows(cal: CalibrationSet, sequences=("X", "Y", "Z", "V")):
    pts = cal.points[cal.points["sequence"].isin(sequences)]
    pts = pts[pts[IMAGE_COLUMNS].notna().all(axis=1)]
    moving = pts.groupby("sequence")["position"].transform("nunique") >= 2
    pts = pts[moving]
    if len(pts) == 0:
        raise SlmlabError("the direct model needs sequences with stage motion (X, Y, Z or V) seen in both views",
                          cal.path)
    seq_code = pts["sequence"].map({s: k for k, s in enumerate(sorted(pts["sequence"].unique()))}).to_numpy()
    groups = point_keys(pts["row"], pts["col"]) * 16 + seq_code
    return pts, groups


def _centre(x: np.ndarray, inv: np.ndarray, n_groups: int, wts: np.ndarray) -> np.ndarray:
    sw = np.bincount(inv, wts, n_groups)
    means = np.stack([np.bincount(inv, wts * x[:, k], n_groups) for k in range(x.shape[1])], axis=1) / sw[:, None]
    return x - means[inv]


def _solve(phi, stage, groups, *, iterations: int = 8, mask=None):
    """Weighted least squares with per-group offsets (centred out): Huber reweighting first (a robust
    start), then rejection beyond 10 robust sigmas (inliers keep full weight, gross outliers get none)."""
    labels, inv = np.unique(groups, return_inverse=True)
    inv = inv.ravel()
    wts = np.ones(len(phi))
    for it in range(iterations):
        pc, sc = _centre(phi, inv, len(labels), wts), _centre(stage, inv, len(labels), wts)
        sq = np.sqrt(wts)[:, None]
        if mask is None:
            coef, *_ = np.linalg.lstsq(pc * sq, sc * sq, rcond=None)
        else:  # each coordinate with its own monomials (its own degree)
            coef = np.zeros((phi.shape[1], 3))
            for k in range(3):
                coef[mask[:, k], k] = np.linalg.lstsq(pc[:, mask[:, k]] * sq, sc[:, k] * sq[:, 0], rcond=None)[0]
        r = np.linalg.norm(sc - pc @ coef, axis=1)
        scale = 1.4826 * np.median(r) + 1e-12
        if it < 3:
            new = np.minimum(1.0, 3.0 * scale / np.maximum(r, 1e-15))      # Huber
        else:
            new = (r < 10.0 * scale).astype(float)                         # reject beyond 10 robust sigmas
        if it >= 3 and np.allclose(new, wts, atol=1e-4):
            break
        wts = new
    offsets = np.stack([np.bincount(inv, wts * (stage - phi @ coef)[:, k], len(labels)) for k in range(3)], 1)
    offsets /= np.bincount(inv, wts, len(labels))[:, None]
    return coef, wts, r, labels, inv, offsets


def fit_direct(cal: CalibrationSet, degree: int | None = None, max_degree: int = 5):
    """Fit the direct model; ``degree=None`` chooses it on held-out positions. Returns a dict with ``coef``,
    ``degree``, ``cv`` (held-out RMS per degree), ``weights``, ``residual_rms_mm`` and ``cov``."""
    pts, groups = _rows(cal)
    w = pts[IMAGE_COLUMNS].to_numpy(float)
    stage = pts[["stage_x_mm", "stage_y_mm", "stage_z_mm"]].to_numpy(float)
    cv = {}
    if degree is None:  # one degree per coordinate, each on its own held-out error (Z's noise would
        held = (pts["position"].to_numpy() % 3 == 0)  # otherwise push X and Y to overfit)
        for d in range(1, max_degree + 1):
            phi = features(w, d)
            coef, _, _, labels, inv, off = _solve(phi[~held], stage[~held], groups[~held])
            lookup = dict(zip(labels.tolist(), range(len(labels))))
            idx = np.array([lookup.get(g, -1) for g in groups[held].tolist()])
            ok = idx >= 0
            e = phi[held][ok] @ coef + off[idx[ok]] - stage[held][ok]
            n = np.linalg.norm(e, axis=1)
            inlier = n <= np.median(n) + 5 * 1.4826 * np.median(np.abs(n - np.median(n)))  # robust to outliers
            cv[d] = np.sqrt(np.mean(e[inlier] ** 2, axis=0))
        degrees = [min(cv, key=lambda d: cv[d][k]) for k in range(3)]
        cv = {d: [float(x) for x in v] for d, v in cv.items()}
    else:
        degrees = list(np.broadcast_to(np.asarray(degree, int), (3,)))
    phi = features(w, max(degrees))
    mask = np.array([[sum(e) <= dk for dk in degrees] for e in _exponents(max(degrees))])  # (m, 3)
    coef, wts, r, labels, inv, off = _solve(phi, stage, groups, mask=mask)
    good = wts > 0.1
    res = _centre(stage, inv, len(labels), wts) - _centre(phi, inv, len(labels), wts) @ coef
    n_per_group = np.bincount(inv, minlength=len(labels))[inv]
    # residual spread per coordinate, corrected for the offsets fitted per dot
    sigma = np.sqrt(np.mean(res[good] ** 2, axis=0) * np.mean(n_per_group / np.maximum(n_per_group - 1, 1)))
    pc = _centre(phi, inv, len(labels), wts) * np.sqrt(wts)[:, None]
    cov = np.linalg.pinv(pc.T @ pc)  # times sigma_k^2 per coordinate (of the largest degree's monomials)
    # absolute frame: the first moving sequence's first position, plate centre at its commanded position
    first = pts["position"].to_numpy() == pts.groupby("sequence")["position"].transform("min").to_numpy()
    const = np.mean(stage[first] - phi[first] @ coef, axis=0)
    suspects = pts[~good][["sequence", "position", "row", "col"]].assign(weight=wts[~good])
    return {"coef": coef, "const": const, "degree": max(degrees), "degrees": [int(d) for d in degrees], "cv": cv,
            "weights": wts, "sigma_mm": sigma, "cov": cov, "suspects": suspects}


@register
class DirectModel(Model):
    """Direct polynomial mapping ``(v1, v2, D) → stage`` fitted on displacements (beyond the paper)."""

    name = "direct"
    summary = "direct polynomial mapping (v1, v2, D) -> stage frame fitted on stage moves, degree by held-out positions"
    accuracy_rank = 5
    units = {"coef": "mm per normalised monomial", "const": "mm", "centroid_noise_px": "px", "sigma_mm": "mm"}

    def __init__(self, degree, coef, const, cov=None, sigma_mm=(0.0, 0.0, 0.0), centroid_noise_px=0.02, **kw):
        super().__init__(**kw)
        self.degree, self.coef, self.const = int(degree), np.asarray(coef, float), np.asarray(const, float)
        self.cov = None if cov is None else np.asarray(cov, float)
        self.sigma_mm = np.broadcast_to(np.asarray(sigma_mm, float), (3,)).copy()
        self.centroid_noise_px = float(centroid_noise_px)

    @classmethod
    def fit(cls, cal, *, degree: int | None = None, centroid_noise_px: float = 0.02, **_):
        f = fit_direct(cal, degree)
        return cls(f["degree"], f["coef"], f["const"], f["cov"], f["sigma_mm"], centroid_noise_px,
                   options={"degree_chosen_by": "held-out positions" if degree is None else "user"},
                   calibration={"held_out_rms_mm_by_degree": {str(k): v for k, v in f["cv"].items()},
                                "degree_per_coordinate": f["degrees"],
                                "residual_sigma_mm": [float(v) for v in f["sigma_mm"]],
                                "down_weighted_rows": f["suspects"].to_dict(orient="records")})

    def reconstruct(self, w: np.ndarray) -> np.ndarray:
        w = np.atleast_2d(np.asarray(w, float))
        out = np.empty((len(w), 3))
        ct = np.ascontiguousarray(self.coef.T)  # (3, m): with monomial-major features, one fast BLAS product
        for a in range(0, len(w), 1 << 15):
            f = features(w[a:a + (1 << 15)], self.degree).T  # (m, n), contiguous
            out[a:a + (1 << 15)] = (ct @ f).T + self.const
        return out

    def uncertainty(self, w: np.ndarray) -> np.ndarray:
        """1σ ``(n, 3)`` [mm] per point: the calibration's residual spread per coordinate (centroid noise and
        stage repeatability as the calibration saw them) and the coefficients' covariance. The centroid noise's
        growth with defocus is not modelled: Z is under-covered far from focus (notebook 09)."""
        w = np.atleast_2d(np.asarray(w, float))
        phi = features(w, self.degree)
        lev = np.einsum("ni,ij,nj->n", phi, self.cov, phi)[:, None] if self.cov is not None else 0.0
        return np.sqrt(self.sigma_mm[None, :] ** 2 * (1.0 + lev))

    def parameters_dict(self) -> dict:
        return {"degree": self.degree, "coef": self.coef.tolist(), "const": self.const.tolist(),
                "cov": None if self.cov is None else self.cov.tolist(), "sigma_mm": self.sigma_mm.tolist(),
                "centroid_noise_px": self.centroid_noise_px}

    @classmethod
    def from_parameters(cls, p, calibration, options):
        return cls(p["degree"], p["coef"], p["const"], p.get("cov"), p.get("sigma_mm", 0.0),
                   p.get("centroid_noise_px", 0.02), calibration=calibration, options=options)
