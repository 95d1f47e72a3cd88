"""Image alignment and disparity distortion correction (paper §4, Eqs 7–16, Table 2, Figs 7–8).

Input: the X, Y, Z sequences of the 7 × 7 plate after §3's correction (:mod:`slmlab.paper.distortion`).

* **Rotation α** (Eqs 7–9): along the X sequence each grid point traces a path in each view; the slope ``k`` of
  ``w2`` on ``w1`` (least squares over the positions) gives the path angle ``atan(k)``;
  ``α = mean(angle_l − angle_r)``. The right view is rotated about the image origin so that its paths take the
  left view's direction: ``w1 ← w1·cos α − w2·sin α``, ``w2 ← w1·sin α + w2·cos α``.
* **Offset δw2** (Eqs 10–12): the mean of ``w2_l − w2_r`` over all points and positions, per sequence (X, Y, Z),
  then the mean of the three; ``w2_r ← w2_r + δw2``.
* **Disparity** ``D = w1_r − w1_l``. Along the X sequence (constant Z) it is a parabola in ``w1`` (Fig 7a).
* **Disparity distortion** (Eqs 13–16, our reading; README, "The method in our words"): the per-point lines and
  the quadratic are fitted together, ``D0[i,j,n] = d[i,j] + aD·w1_l² + bD·w1_l`` over the X sequence (one
  constant per grid point, ``aD`` and ``bD`` shared: the identifiable joint fit), and ``cD = bD²/(4·aD)``, so
  that the correction ``D = D0 − (aD·w1_l² + bD·w1_l + cD)`` is a pure parabola about its vertex
  ``w0 = −bD/(2·aD)`` and vanishes there (the paper's Table 2 obeys this to 0.1 %). The sign is checked by its
  effect: the corrected paths must be straight (Fig 8).
* The single pass, the text's steps taken one after the other, kept for comparison only
  (``disparity_method="single-pass"``): per grid point a line
  ``D0 ≈ k_D·w1_l + b_D`` along its X path, then one quadratic through all their residuals. The lines absorb
  the straight part of each dot's own stretch of the parabola, so one pass recovers only part of the
  curvature (:func:`recovered_share`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from ..errors import SlmlabError
from ..io import CalibrationSet
from ..linefit import group_lines, point_keys

__all__ = ["rotate", "path_angles", "estimate_alpha", "estimate_dw2", "DisparityCorrection", "DISPARITY_METHODS",
           "fit_disparity_single_pass", "fit_disparity_joint", "path_straightness", "AlignmentResult",
           "estimate_alignment", "sequence_coordinates", "disparity_table", "recovered_share", "vertex_check"]

MIN_POSITIONS = 3
#: the disparity estimators: our reading of Eqs 13–16, the joint fit (the default), and the single pass (for comparison)
DISPARITY_METHODS = ("joint", "single-pass")


def rotate(w1, w2, angle_rad: float) -> tuple[np.ndarray, np.ndarray]:
    """Rotate image coordinates about the image origin (Eq 9): ``w1·cos − w2·sin``, ``w1·sin + w2·cos``."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    w1, w2 = np.asarray(w1, float), np.asarray(w2, float)
    return w1 * c - w2 * s, w1 * s + w2 * c


def sequence_coordinates(cal: CalibrationSet, sequence: str, correct=None) -> pd.DataFrame:
    """The rows of one sequence with image coordinates ``wl1, wl2, wr1, wr2`` [px], corrected by
    ``correct`` (a function ``(n, 4) → (n, 4)``) if given; rows with a missing coordinate dropped."""
    df = cal.sequence(sequence)
    df = df[df[["wl1", "wl2", "wr1", "wr2"]].notna().all(axis=1)].copy()
    if correct is not None and len(df):
        df[["wl1", "wl2", "wr1", "wr2"]] = correct(df[["wl1", "wl2", "wr1", "wr2"]].to_numpy(float))
    return df


def path_angles(df: pd.DataFrame, c1: str, c2: str) -> pd.Series:
    """Angle [rad] of each grid point's path: ``atan`` of the least-squares slope of ``c2`` on ``c1`` over the
    positions (Eq 7), for grid points seen at ≥ 3 positions; indexed by ``(row, col)``."""
    fit = group_lines(point_keys(df["row"], df["col"]), df[c1].to_numpy(), df[c2].to_numpy(), min_n=MIN_POSITIONS)
    lab = fit.labels[fit.valid]
    index = pd.MultiIndex.from_arrays([lab // 100_000, lab % 100_000], names=["row", "col"])
    return pd.Series(np.arctan(fit.k[fit.valid]), index=index, dtype=float)


def estimate_alpha(xseq: pd.DataFrame) -> tuple[float, float, int]:
    """``α`` [rad] (Eq 8), its standard deviation over grid points [rad], and the number of grid points."""
    a = path_angles(xseq, "wl1", "wl2") - path_angles(xseq, "wr1", "wr2")
    a = a.dropna()
    if len(a) == 0:
        raise SlmlabError("no grid point is seen at 3 or more positions of the X sequence in both views: "
                          "cannot estimate α (§4, Eq 8); image the plate at more X positions, inside both views")
    return float(a.mean()), float(a.std(ddof=1)) if len(a) > 1 else 0.0, len(a)


def estimate_dw2(sequences: dict[str, pd.DataFrame]) -> tuple[float, dict[str, float], float]:
    """``δw2`` [px] (Eqs 10–12): the mean over sequences of the mean of ``w2_l − w2_r``; the per-sequence
    values; the standard deviation of ``w2_l − w2_r`` over all samples [px]."""
    per = {}
    allv = []
    for name, df in sequences.items():
        if len(df):
            d = (df["wl2"] - df["wr2"]).to_numpy()
            per[name] = float(d.mean())
            allv.append(d)
    if not per:
        raise SlmlabError("no X, Y or Z sequence seen in both views: cannot estimate δw2 (§4, Eq 12); add X, Y and Z "
                          "sequences whose dots both views see")
    return float(np.mean(list(per.values()))), per, float(np.std(np.concatenate(allv), ddof=1))


@dataclass(frozen=True)
class DisparityCorrection:
    """The disparity distortion ``aD·w1² + bD·w1 + cD`` subtracted from ``D0 = w1_r − w1_l`` (Eq 16).

    Attributes
    ----------
    aD, bD, cD_px
        [1/px], [-], [px].
    method
        ``'joint'`` (our reading of Eqs 13–16, the default) or ``'single-pass'`` (a line per dot, then one
        quadratic through all residuals; for comparison).
    """

    aD: float
    bD: float
    cD_px: float
    method: str = "joint"

    def apply(self, d0, w1_left) -> np.ndarray:
        """Corrected disparity [px]."""
        w = np.asarray(w1_left, float)
        return np.asarray(d0, float) - (self.aD * w * w + self.bD * w + self.cD_px)


def path_straightness(df: pd.DataFrame, disparity: np.ndarray) -> float:
    """RMS [px] of the per-grid-point line fits ``D ≈ k·w1_l + b`` along a sequence: how far the disparity
    paths are from straight."""
    fit = group_lines(point_keys(df["row"], df["col"]), df["wl1"].to_numpy(), np.asarray(disparity, float),
                      min_n=MIN_POSITIONS)
    r = fit.residuals[np.isfinite(fit.residuals)]
    return float(np.sqrt(np.mean(r ** 2))) if len(r) else float("nan")


def fit_disparity_single_pass(xseq: pd.DataFrame) -> DisparityCorrection:
    """The single pass of Eqs 13–15 (for comparison only): per-point lines along the X paths, one quadratic
    through all their residuals; the sign that straightens the paths is kept. It recovers only part of the
    curvature (:func:`recovered_share`)."""
    d0 = (xseq["wr1"] - xseq["wl1"]).to_numpy()
    w = xseq["wl1"].to_numpy()
    res = group_lines(point_keys(xseq["row"], xseq["col"]), w, d0, min_n=MIN_POSITIONS).residuals
    ok = np.isfinite(res)
    if ok.sum() < 3:
        raise SlmlabError("too few X-sequence samples to fit the disparity distortion (§4, Eq 15); image the plate at "
                          "more X positions")
    aD, bD, cD = np.polyfit(w[ok], res[ok], 2)
    plus = DisparityCorrection(float(aD), float(bD), float(cD), "single-pass")
    minus = DisparityCorrection(-float(aD), -float(bD), -float(cD), "single-pass")
    s_plus = path_straightness(xseq, plus.apply(d0, w))
    s_minus = path_straightness(xseq, minus.apply(d0, w))
    return plus if s_plus <= s_minus else minus


def fit_disparity_joint(xseq: pd.DataFrame) -> DisparityCorrection:
    """The disparity distortion by our reading of Eqs 13–16: the joint fit
    ``D0 = d[i,j] + aD·w1² + bD·w1`` (one constant per grid point, ``aD, bD`` shared), and
    ``cD = bD²/(4·aD)``: the correction vanishes at the parabola's vertex. Of the two signs, the one that
    straightens the paths is kept (it is the fitted one: the joint fit removes the parabola)."""
    d0 = (xseq["wr1"] - xseq["wl1"]).to_numpy()
    w = xseq["wl1"].to_numpy()
    keys = xseq[["row", "col"]].to_numpy()
    _, point = np.unique(keys, axis=0, return_inverse=True)
    point = point.ravel()
    n_pts = point.max() + 1
    w0 = np.mean(w)  # centre w1 for conditioning; undone below
    m = np.zeros((len(w), n_pts + 2))
    m[np.arange(len(w)), point] = 1.0
    m[:, n_pts] = (w - w0) ** 2
    m[:, n_pts + 1] = w - w0
    coef, *_ = np.linalg.lstsq(m, d0, rcond=None)
    a, b1 = coef[n_pts], coef[n_pts + 1]
    # a (w - w0)^2 + b1 (w - w0) = a w^2 + (b1 - 2 a w0) w + const (the constant goes to the d[i,j])
    a, b = float(a), float(b1 - 2 * a * w0)
    if a == 0:
        raise SlmlabError("the X sequence's disparity shows no curvature: the joint fit of Eqs 13-16 has no vertex; check "
                          "that the X sequence moves the plate across the field")
    plus = DisparityCorrection(a, b, b * b / (4 * a), "joint")
    minus = DisparityCorrection(-a, -b, -b * b / (4 * a), "joint")
    s_plus, s_minus = path_straightness(xseq, plus.apply(d0, w)), path_straightness(xseq, minus.apply(d0, w))
    return plus if s_plus <= s_minus else minus


def recovered_share(xseq: pd.DataFrame) -> dict:
    """How much of the disparity's curvature one pass recovers: the single pass's ``aD`` over
    the joint fit's, beside the pooled-regression attenuation ``Var(t²) / (Var(t²) + 4·σm²·σt²)`` for the
    dots' path offsets ``t = w1 − m`` about their path centres ``m`` (pooled over dots), and the ratio of the
    plate's width on the image (the spread of the path centres, ``2·σm``) to a path's length (``2·√3·σt``,
    a uniform path)."""
    w = xseq["wl1"].to_numpy(float)
    keys = xseq[["row", "col"]].to_numpy()
    _, point = np.unique(keys, axis=0, return_inverse=True)
    point = point.ravel()
    m = (np.bincount(point, w) / np.bincount(point))[point]
    t = w - m
    var_t2 = np.var(t * t)
    s_m2, s_t2 = np.var(np.unique(m)), np.mean(t * t)
    predicted = var_t2 / (var_t2 + 4 * s_m2 * s_t2)
    single, joint = fit_disparity_single_pass(xseq), fit_disparity_joint(xseq)
    return {"recovered": single.aD / joint.aD, "predicted": float(predicted),
            "plate_width_over_path_length": float(np.sqrt(s_m2) / np.sqrt(3 * s_t2)),
            "aD_single_pass": single.aD, "aD_joint": joint.aD}


def vertex_check(aD: float, bD: float, cD_px: float) -> dict:
    """``cD`` against ``bD²/(4·aD)``, the value at which the correction vanishes at the parabola's vertex
    (our reading of Eq 16; the paper's Table 2 obeys it to 0.1 %): both, their relative difference and the vertex
    ``w0 = −bD/(2·aD)`` [px]."""
    at_vertex = bD * bD / (4 * aD)
    return {"cD_px": cD_px, "bD2_over_4aD_px": at_vertex, "relative_difference": cD_px / at_vertex - 1,
            "vertex_px": -bD / (2 * aD)}


@dataclass
class AlignmentResult:
    """§4's parameters and diagnostics.

    Attributes
    ----------
    alpha_rad, alpha_std_rad
        rotation of the right view and its spread over grid points [rad].
    dw2_px, dw2_by_sequence, dw2_std_px
        vertical offset of the right view [px], per sequence, and the spread of ``w2_l − w2_r`` [px].
    disparity
        ``{'joint': DisparityCorrection, 'single-pass': DisparityCorrection}``; ``method`` names the one the
        chain uses.
    straightness
        RMS of the per-point disparity lines along X [px]: ``raw``, ``joint``, ``single-pass``.
    """

    alpha_rad: float
    alpha_std_rad: float
    dw2_px: float
    dw2_by_sequence: dict
    dw2_std_px: float
    disparity: dict
    straightness: dict = field(default_factory=dict)
    method: str = "joint"

    def align(self, w: np.ndarray) -> np.ndarray:
        """Rotate the right view by α and shift it by δw2 (``(n, 4)`` corrected coordinates → aligned)."""
        w = np.array(w, float)
        w[:, 2], w[:, 3] = rotate(w[:, 2], w[:, 3], self.alpha_rad)
        w[:, 3] += self.dw2_px
        return w

    def parameters(self) -> dict:
        d = self.disparity[self.method]
        return {"alpha_deg": float(np.degrees(self.alpha_rad)), "dw2_px": self.dw2_px, "aD": d.aD, "bD": d.bD,
                "cD_px": d.cD_px}

    def table(self) -> pd.DataFrame:
        """Table 2 layout: α, δw2, aD, bD, cD (the joint fit of Eqs 13–16), and the single pass's aD, bD, cD
        for comparison."""
        j, p = self.disparity["joint"], self.disparity["single-pass"]
        return pd.DataFrame([
            {"parameter": "alpha_deg", "value": np.degrees(self.alpha_rad), "spread": np.degrees(self.alpha_std_rad)},
            {"parameter": "dw2_px", "value": self.dw2_px, "spread": self.dw2_std_px},
            {"parameter": "aD", "value": j.aD, "spread": np.nan},
            {"parameter": "bD", "value": j.bD, "spread": np.nan},
            {"parameter": "cD_px", "value": j.cD_px, "spread": np.nan},
            {"parameter": "aD (single pass)", "value": p.aD, "spread": np.nan},
            {"parameter": "bD (single pass)", "value": p.bD, "spread": np.nan},
            {"parameter": "cD_px (single pass)", "value": p.cD_px, "spread": np.nan},
        ])


def estimate_alignment(cal: CalibrationSet, correct, method: str = "joint") -> AlignmentResult:
    """§4 on a calibration set: ``correct`` is §3's correction ``(n, 4) → (n, 4)``; ``method`` the disparity
    estimator the chain uses (both are fitted and reported)."""
    if method not in DISPARITY_METHODS:
        raise SlmlabError(f"unknown disparity method {method!r}; use one of {', '.join(DISPARITY_METHODS)}")
    seqs = {s: sequence_coordinates(cal, s, correct) for s in ("X", "Y", "Z")}
    if len(seqs["X"]) == 0:
        raise SlmlabError("the calibration set has no X sequence seen in both views: §4 needs one; add an X sequence", cal.path)
    alpha, alpha_std, _ = estimate_alpha(seqs["X"])
    rotated = {}
    for s, df in seqs.items():
        df = df.copy()
        df["wr1"], df["wr2"] = rotate(df["wr1"], df["wr2"], alpha)
        rotated[s] = df
    dw2, per, dw2_std = estimate_dw2(rotated)
    xs = rotated["X"].copy()
    xs["wr2"] += dw2
    joint = fit_disparity_joint(xs)
    single = fit_disparity_single_pass(xs)
    d0, w = (xs["wr1"] - xs["wl1"]).to_numpy(), xs["wl1"].to_numpy()
    straight = {"raw": path_straightness(xs, d0), "joint": path_straightness(xs, joint.apply(d0, w)),
                "single-pass": path_straightness(xs, single.apply(d0, w))}
    return AlignmentResult(alpha, alpha_std, dw2, per, dw2_std, {"joint": joint, "single-pass": single}, straight,
                           method)


def disparity_table(cal: CalibrationSet, correct, align: AlignmentResult, sequences=("X", "Y")) -> pd.DataFrame:
    """Per sample of the sequences: ``w1_l, w2_l`` [px] of the aligned coordinates, the distorted disparity
    ``D0`` and the corrected ``D_joint`` (Eq 16 with the joint fit's parameters) and ``D_single_pass`` [px]
    (Figs 7–8)."""
    frames = []
    for s in sequences:
        df = sequence_coordinates(cal, s, correct)
        if df.empty:
            continue
        w = align.align(df[["wl1", "wl2", "wr1", "wr2"]].to_numpy(float))
        d0 = w[:, 2] - w[:, 0]
        frames.append(pd.DataFrame({
            "sequence": s, "position": df["position"].to_numpy(), "row": df["row"].to_numpy(),
            "col": df["col"].to_numpy(), "w1_l": w[:, 0], "w2_l": w[:, 1], "D0": d0,
            "D_joint": align.disparity["joint"].apply(d0, w[:, 0]),
            "D_single_pass": align.disparity["single-pass"].apply(d0, w[:, 0])}))
    return pd.concat(frames, ignore_index=True)
