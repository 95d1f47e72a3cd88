"""The initial vision model and residual compensation (paper §5.1, §5.3, §5.4, Eqs 17–32).

The paper's chain, applied to measured image coordinates ``wl1, wl2, wr1, wr2`` [px]:

1. §3 image distortion correction of each view (:mod:`slmlab.paper.distortion`);
2. §4 alignment: the right view rotated by ``α`` and shifted by ``δw2``; the disparity ``D = w1_r − w1_l``
   corrected for its distortion (:mod:`slmlab.paper.alignment`), in these aligned coordinates;
3. rotation of both views by ``θX`` (Eqs 23–25) so that the stage X axis runs along ``w1``;
4. **Model 0** (Eq 19): ``X = EX·(w1_l + w1_r)/2``, ``Y = EY·(w2_l + w2_r)/2``, ``Z = EZ·D``;
5. **Model 1** (Eq 21): ``X1 = X + KYX·Y + BYX``, ``Y1 = Y``, ``Z1 = Z + KYZ·Y + BYZ``;
6. **Model 2** (Eq 22): ``X2 = X1 + KZX·Z1 + BZX``, ``Y2 = Y1 + KZY·Z1 + BZY``, ``Z2 = Z1``.

Estimation uses displacements relative to position 1 of each sequence (the stage's commanded moves are the
ground truth): ``θX = −mean atan(k)`` of the X-sequence path slopes of both views; ``EX``, ``EY``, ``EZ`` the
mean of the ratios ``ΔX_A/Δv_X``, ``ΔY_A/Δv_Y``, ``ΔZ_A/ΔD`` over points and positions ``n ≥ 2`` (Eqs 26–28,
the paper's estimator) or, optionally, the least-squares slopes; the ``K, B`` terms from least-squares lines
of the residual displacements of the Y sequence (Model 1) and of the Z sequence after Model 1 (Model 2).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from .alignment import (DISPARITY_METHODS, AlignmentResult, DisparityCorrection, estimate_alignment, path_angles,
                        rotate, sequence_coordinates)
from .distortion import DistortionResult, ViewCorrection, estimate_distortion
from ..errors import SlmlabError
from ..io import CalibrationSet

__all__ = ["SCALE_ESTIMATORS", "PaperParameters", "fit_paper", "displacements", "COMPENSATION_NAMES", "suspect_rows"]

SCALE_ESTIMATORS = ("mean-ratio", "lstsq")
COMPENSATION_NAMES = ("KYX", "BYX_mm", "KYZ", "BYZ_mm", "KZX", "BZX_mm", "KZY", "BZY_mm")


@dataclass
class PaperParameters:
    """Every parameter of the paper's chain (names as in a model file, README "The format"), with the model level."""

    left: ViewCorrection
    right: ViewCorrection
    alpha_deg: float
    dw2_px: float
    disparity: DisparityCorrection
    thetaX_deg: float
    EX_mm_per_px: float
    EY_mm_per_px: float
    EZ_mm_per_px: float
    K: dict = field(default_factory=lambda: {k: 0.0 for k in COMPENSATION_NAMES})
    level: int = 2

    # ------------------------------------------------------------------ the chain
    def image_stage(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(v_X, v_Y, D)`` [px]: steps 1–3 of the chain (corrected, aligned, rotated; corrected disparity)."""
        w = np.asarray(w, float)
        l1, l2 = self.left.apply(w[:, 0], w[:, 1])
        r1, r2 = self.right.apply(w[:, 2], w[:, 3])
        r1, r2 = rotate(r1, r2, np.radians(self.alpha_deg))
        r2 = r2 + self.dw2_px
        d = self.disparity.apply(r1 - l1, l1)
        t = np.radians(self.thetaX_deg)
        l1, l2 = rotate(l1, l2, t)
        r1, r2 = rotate(r1, r2, t)
        return (l1 + r1) / 2, (l2 + r2) / 2, d

    def linear_map(self, level: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(M, o)`` with world ``= M @ (w1_l + w1_r, w2_l + w2_r, D) + o`` after steps 1–2 of the chain:
        the θX rotation, Model 0's scales and the compensation of Models 1–2 are all linear."""
        level = self.level if level is None else level
        c, s = np.cos(np.radians(self.thetaX_deg)), np.sin(np.radians(self.thetaX_deg))
        m = np.array([[0.5 * self.EX_mm_per_px * c, -0.5 * self.EX_mm_per_px * s, 0.0],
                      [0.5 * self.EY_mm_per_px * s, 0.5 * self.EY_mm_per_px * c, 0.0],
                      [0.0, 0.0, self.EZ_mm_per_px]])
        o = np.zeros(3)
        k = self.K
        if level >= 1:
            c1 = np.array([[1.0, k["KYX"], 0.0], [0.0, 1.0, 0.0], [0.0, k["KYZ"], 1.0]])
            m, o = c1 @ m, c1 @ o + [k["BYX_mm"], 0.0, k["BYZ_mm"]]
        if level >= 2:
            c2 = np.array([[1.0, 0.0, k["KZX"]], [0.0, 1.0, k["KZY"]], [0.0, 0.0, 1.0]])
            m, o = c2 @ m, c2 @ o + [k["BZX_mm"], k["BZY_mm"], 0.0]
        return m, o

    def reconstruct(self, w: np.ndarray, level: int | None = None, *, chunk: int = 1 << 14) -> np.ndarray:
        """World coordinates ``(n, 3)`` [mm] by Model ``level`` (default: this model's level).

        Vectorised in cache-sized chunks, in place: steps 1–2 of the chain elementwise on the chunk's four
        contiguous coordinate rows, the rest one 3 × 3 linear map (:meth:`linear_map`), also elementwise (no BLAS
        call, so no CPU-dependent kernel). Equal to :meth:`reconstruct_stepwise` to rounding.
        """
        w = np.asarray(w, float)
        m, o = self.linear_map(level)
        L, R, D = self.left, self.right, self.disparity
        ca, sa = np.cos(np.radians(self.alpha_deg)), np.sin(np.radians(self.alpha_deg))
        out = np.empty((len(w), 3))
        buf, res = np.empty((4, chunk)), np.empty((3, chunk))
        t_full, u_full = np.empty(chunk), np.empty(chunk)
        for a in range(0, len(w), chunk):
            n = min(chunk, len(w) - a)
            b, t, u = buf[:, :n], t_full[:n], u_full[:n]
            np.copyto(b, w[a:a + n].T)
            l1, l2, r1, r2 = b
            np.multiply(l1, l2, out=t); t *= L.lam; l2 += t                      # Eq 3: w2' = w2 (1 + λ w1)
            np.multiply(l2, L.a, out=t); t += L.b; t *= l2; t += L.c; l1 += t   # Eq 6
            np.multiply(r1, r2, out=t); t *= R.lam; r2 += t
            np.multiply(r2, R.a, out=t); t += R.b; t *= r2; t += R.c; r1 += t
            np.multiply(r1, ca, out=t); np.multiply(r2, sa, out=u); t -= u      # Eq 9: rotate by α
            np.multiply(r1, sa, out=u); r2 *= ca; r2 += u; r2 += self.dw2_px     # Eq 12: + δw2
            r1[:] = t
            np.multiply(l1, D.aD, out=u); u += D.bD; u *= l1; u += D.cD_px     # Eq 16: the disparity's
            np.subtract(r1, l1, out=t); t -= u                                  # distortion removed: D in t
            l1 += r1
            l2 += r2
            for k in range(3):                                                  # world = M (Σw1, Σw2, D) + o
                rk = res[k, :n]
                rk.fill(o[k])
                for j, v in enumerate((l1, l2, t)):
                    if m[k, j] != 0.0:
                        np.multiply(v, m[k, j], out=u)
                        rk += u
            out[a:a + n] = res[:, :n].T
        return out

    def reconstruct_stepwise(self, w: np.ndarray, level: int | None = None) -> np.ndarray:
        """The chain step by step as the paper writes it (slower; the reference for :meth:`reconstruct`)."""
        level = self.level if level is None else level
        vx, vy, d = self.image_stage(w)
        x, y, z = self.EX_mm_per_px * vx, self.EY_mm_per_px * vy, self.EZ_mm_per_px * d
        k = self.K
        if level >= 1:
            x = x + k["KYX"] * y + k["BYX_mm"]
            z = z + k["KYZ"] * y + k["BYZ_mm"]
        if level >= 2:
            x = x + k["KZX"] * z + k["BZX_mm"]
            y = y + k["KZY"] * z + k["BZY_mm"]
        return np.column_stack([x, y, z])

    def as_dict(self) -> dict:
        d = {**self.left.as_dict("l"), **self.right.as_dict("r"),
             "alpha_deg": self.alpha_deg, "dw2_px": self.dw2_px, "aD": self.disparity.aD, "bD": self.disparity.bD,
             "cD_px": self.disparity.cD_px, "thetaX_deg": self.thetaX_deg, "EX_mm_per_px": self.EX_mm_per_px,
             "EY_mm_per_px": self.EY_mm_per_px, "EZ_mm_per_px": self.EZ_mm_per_px}
        d.update({k: (v if self.level >= (1 if k[1] == "Y" else 2) else 0.0) for k, v in self.K.items()})
        return {k: float(v) for k, v in d.items()}

    @classmethod
    def from_dict(cls, p: dict, level: int) -> "PaperParameters":
        views = [ViewCorrection(float(p[f"lambda_{s}"]), float(p[f"a_{s}"]), float(p[f"b_{s}"]), float(p[f"c_{s}"]))
                 for s in "lr"]
        return cls(views[0], views[1], float(p["alpha_deg"]), float(p["dw2_px"]),
                   DisparityCorrection(float(p["aD"]), float(p["bD"]), float(p["cD_px"])), float(p["thetaX_deg"]),
                   float(p["EX_mm_per_px"]), float(p["EY_mm_per_px"]), float(p["EZ_mm_per_px"]),
                   {k: float(p[k]) for k in COMPENSATION_NAMES}, level)


# ------------------------------------------------------------------------------------------ displacements
def displacements(df: pd.DataFrame, values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Displacements relative to position 1 of each grid point of one sequence.

    Parameters
    ----------
    df
        the sequence's rows (``position, row, col, stage_*_mm``).
    values
        ``(n, k)`` per-row quantities (image or world coordinates).

    Returns
    -------
    d_values, d_stage, keep
        ``Δvalues (m, k)``, commanded ``Δstage (m, 3)`` [mm] for the rows of positions ``n ≥ 2`` whose grid
        point is also seen at position 1, and the boolean mask of those rows in ``df``.
    """
    values = np.asarray(values, float).reshape(len(df), -1)
    key = df["row"].to_numpy() * 100000 + df["col"].to_numpy()
    pos = df["position"].to_numpy()
    first = pos == pos.min()
    ref_keys, ref_idx = key[first], np.flatnonzero(first)
    lookup = dict(zip(ref_keys.tolist(), ref_idx.tolist()))
    ref = np.array([lookup.get(k, -1) for k in key.tolist()])
    keep = (~first) & (ref >= 0) & np.isfinite(values).all(axis=1)
    stage = df[["stage_x_mm", "stage_y_mm", "stage_z_mm"]].to_numpy(float)
    return values[keep] - values[ref[keep]], stage[keep] - stage[ref[keep]], keep


def _scale(d_true: np.ndarray, d_image: np.ndarray, estimator: str, what: str) -> float:
    ok = np.abs(d_image) > 1e-9
    if ok.sum() == 0 or np.allclose(d_true[ok], 0):
        raise SlmlabError(f"the {what} sequence has no motion: cannot estimate its scale (§5, Eqs 26–28); "
                          "it needs at least two distinct stage positions")
    if estimator == "mean-ratio":
        return float(np.mean(d_true[ok] / d_image[ok]))
    return float(np.dot(d_true, d_image) / np.dot(d_image, d_image))


def _line(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    if len(x) < 2 or np.ptp(x) == 0:
        raise SlmlabError("too few distinct displacements to fit a compensation line (§5.3, Eqs 29–32); image more "
                          "positions along Y and Z")
    k, b = np.polyfit(x, y, 1)
    return float(k), float(b)


def fit_paper(cal: CalibrationSet, *, level: int = 2, scale_estimator: str = "mean-ratio",
              distortion_method: str | None = None, disparity_method: str = "joint",
              ) -> tuple[PaperParameters, DistortionResult, AlignmentResult]:
    """Fit the paper's chain up to Model ``level`` on a calibration set with ``grid``, X, Y, Z sequences.

    Parameters
    ----------
    scale_estimator
        ``'mean-ratio'`` (the paper's, Eqs 26–28) or ``'lstsq'`` (least-squares slope through the origin).
    distortion_method
        ``'paper-two-step'`` or ``'joint'`` for §3; ``None`` keeps the one with the smaller lattice misfit.
    disparity_method
        ``'joint'`` (our reading of Eqs 13–16: lines and quadratic fitted together, ``cD`` at the
        vertex; the default) or ``'single-pass'`` (per-point lines, then one quadratic
        through their residuals, which recovers only part of the curvature: notebook 03), for comparison.
    """
    if disparity_method not in DISPARITY_METHODS:
        raise SlmlabError(f"unknown disparity method {disparity_method!r}; use one of {', '.join(DISPARITY_METHODS)}")
    if scale_estimator not in SCALE_ESTIMATORS:
        raise SlmlabError(f"unknown scale estimator {scale_estimator!r}; use one of {', '.join(SCALE_ESTIMATORS)}")
    for s in ("X", "Y", "Z"):
        n = cal.sequence(s)["position"].nunique()
        if n < 2:
            raise SlmlabError(f"the {s} sequence has {n} position{'s' if n != 1 else ''}; the paper's models need "
                              "X, Y and Z sequences of at least 2 (better 3 or more) positions", cal.path)
    dist = estimate_distortion(cal.sequence("grid"),
                               methods=("paper-two-step", "joint") if distortion_method is None else (distortion_method,))
    align = estimate_alignment(cal, dist.apply, disparity_method)

    def chain(df):
        w = dist.apply(df[["wl1", "wl2", "wr1", "wr2"]].to_numpy(float))
        return align.align(w)

    seqs = {s: sequence_coordinates(cal, s) for s in ("X", "Y", "Z")}
    aligned = {s: (df, chain(df)) for s, df in seqs.items()}
    # θX (Eqs 23–25): path angles of the aligned X sequence, both views
    xdf, xw = aligned["X"]
    tmp = xdf[["row", "col"]].copy()
    tmp[["l1", "l2", "r1", "r2"]] = xw
    ang = np.r_[path_angles(tmp, "l1", "l2").to_numpy(), path_angles(tmp, "r1", "r2").to_numpy()]
    theta = -float(np.mean(ang))
    params = PaperParameters(dist.left, dist.right, float(np.degrees(align.alpha_rad)), align.dw2_px,
                             align.disparity[disparity_method], float(np.degrees(theta)), 1.0, 1.0, 1.0, level=level)
    # Model 0 scales (Eqs 26–28)
    stage_v = {}
    for s, (df, _) in aligned.items():
        stage_v[s] = np.column_stack(params.image_stage(df[["wl1", "wl2", "wr1", "wr2"]].to_numpy(float)))
    dvx, dsx, _ = displacements(seqs["X"], stage_v["X"])
    dvy, dsy, _ = displacements(seqs["Y"], stage_v["Y"])
    dvz, dsz, _ = displacements(seqs["Z"], stage_v["Z"])
    params.EX_mm_per_px = _scale(dsx[:, 0], dvx[:, 0], scale_estimator, "X")
    params.EY_mm_per_px = _scale(dsy[:, 1], dvy[:, 1], scale_estimator, "Y")
    params.EZ_mm_per_px = _scale(dsz[:, 2], dvz[:, 2], scale_estimator, "Z")
    # Model 1 from the Y sequence, Model 2 from the Z sequence after Model 1 (Eqs 29–32)
    K = {k: 0.0 for k in COMPENSATION_NAMES}
    if level >= 1:
        dp, da, _ = displacements(seqs["Y"], params.reconstruct(seqs["Y"][["wl1", "wl2", "wr1", "wr2"]].to_numpy(float), 0))
        K["KYX"], K["BYX_mm"] = _line(dp[:, 1], da[:, 0] - dp[:, 0])
        K["KYZ"], K["BYZ_mm"] = _line(dp[:, 1], da[:, 2] - dp[:, 2])
        params.K = dict(K)
    if level >= 2:
        dp, da, _ = displacements(seqs["Z"], params.reconstruct(seqs["Z"][["wl1", "wl2", "wr1", "wr2"]].to_numpy(float), 1))
        K["KZX"], K["BZX_mm"] = _line(dp[:, 2], da[:, 0] - dp[:, 0])
        K["KZY"], K["BZY_mm"] = _line(dp[:, 2], da[:, 1] - dp[:, 1])
    params.K = K
    return params, dist, align


def suspect_rows(cal: CalibrationSet, params: PaperParameters, *, k: float = 8.0, floor_mm: float = 0.02) -> list:
    """Rows whose displacement residual under the fitted model is far out of line with the rest: larger than
    ``k`` robust standard deviations (MAD) of their sequence and than ``floor_mm`` — typically misindexed or
    mismatched dots. Returns ``[(sequence, position, row, col, residual_mm), ...]``."""
    out = []
    for s in ("X", "Y", "Z"):
        df = sequence_coordinates(cal, s)
        if df["position"].nunique() < 2:
            continue
        dp, da, keep = displacements(df, params.reconstruct(df[["wl1", "wl2", "wr1", "wr2"]].to_numpy(float)))
        e = np.linalg.norm(dp - da, axis=1)
        mad = 1.4826 * np.median(np.abs(e - np.median(e)))
        bad = e > max(np.median(e) + k * mad, floor_mm)
        rows = df[keep][bad]
        out += [(s, int(r.position), int(r.row), int(r.col), float(v)) for r, v in zip(rows.itertuples(), e[bad])]
    return out
