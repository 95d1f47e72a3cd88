"""Image distortion correction (paper §3, Eqs 1–6, Table 1, Figs 4–6).

Input: one stereo pair of the 27 × 29 plate (the ``grid`` sequence), rows roughly along ``w1``. Per view:

* **Row correction** (Eq 3): ``w1' = w1``, ``w2' = w2 · (1 + λ·w1)``: the rows fan out (their spacing grows with
  ``w1``); multiplying ``w2`` by a factor linear in ``w1`` makes them parallel.
* **Column correction** (Eqs 4–6): fit each row-corrected column with a line ``w1' = k_j·w2' + b_j``; the
  fitting error ``E = (k_j·w2' + b_j) − w1'`` of all columns is fitted by one quadratic
  ``E ≈ a·w2'² + b·w2' + c``; then ``w1'' = w1' + a·w2'² + b·w2' + c``, ``w2'' = w2'``.

``Φ = (λ, a, b, c)`` per view, "estimated by nonlinear optimization" in the paper, which does not say against
what. Two estimators (our decision; README, "The method in our words"):

``paper-two-step``
    λ from the row lines: a row ``w2 = k_i·w1 + b_i`` becomes, to first order, a line of slope
    ``k_i + λ·b_i``; parallel rows need ``k_i + λ b_i`` constant, so ``λ = −`` the slope of the regression of
    the row slopes on the row intercepts (the virtual lines of Fig 5). Then ``a, b, c`` from the column lines.
``joint``
    ``λ`` and ``a`` minimise the least-squares misfit of the corrected dots to an affine lattice
    ``o + i·u + j·v`` (parallel, equally spaced rows; straight, equally spaced columns). ``b·w2' + c`` is affine
    and absorbed by the lattice, so ``b, c`` keep the paper's convention: the column-line residual, less
    ``a·w2'²``, fitted by a line.

Every fit takes incomplete rows and columns (dots outside the field are missing).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np
import pandas as pd
from scipy.optimize import least_squares

from ..errors import SlmlabError
from ..linefit import group_lines
from .reference import paper_reference

__all__ = ["ViewCorrection", "DistortionResult", "display_rows", "display_columns", "row_lines", "column_residuals",
           "estimate_two_step", "estimate_joint", "lattice_misfit", "quality", "estimate_distortion",
           "virtual_line_spacing", "table1", "display_frames"]

MIN_DOTS_PER_LINE = 3


@dataclass(frozen=True)
class ViewCorrection:
    """``Φ = (λ, a, b, c)`` of one view (paper Eqs 3, 6).

    Attributes
    ----------
    lam
        ``λ`` of the row correction [1/px].
    a, b, c
        the column correction quadratic ``a·w2'² + b·w2' + c``: ``a`` [1/px], ``b`` [-], ``c`` [px].
    """

    lam: float = 0.0
    a: float = 0.0
    b: float = 0.0
    c: float = 0.0

    def apply(self, w1, w2) -> tuple[np.ndarray, np.ndarray]:
        """Corrected ``(w1'', w2'')`` [px] of image coordinates ``(w1, w2)`` [px] (Eqs 3 and 6)."""
        w1 = np.asarray(w1, float)
        w2p = np.asarray(w2, float) * (1.0 + self.lam * w1)
        return w1 + self.a * w2p ** 2 + self.b * w2p + self.c, w2p

    def as_dict(self, side: str) -> dict:
        return {f"lambda_{side}": self.lam, f"a_{side}": self.a, f"b_{side}": self.b, f"c_{side}": self.c}


# -------------------------------------------------------------------------------------- line fits
def _valid(*arrays):
    ok = np.ones(len(arrays[0]), bool)
    for a in arrays:
        ok &= np.isfinite(np.asarray(a, float))
    return ok


def row_lines(i, w1, w2) -> pd.DataFrame:
    """Least-squares line ``w2 = k·w1 + b`` of every row with at least 3 dots: ``row, k, b, n``."""
    ok = _valid(w1, w2)
    fit = group_lines(np.asarray(i)[ok], np.asarray(w1, float)[ok], np.asarray(w2, float)[ok], min_n=MIN_DOTS_PER_LINE)
    v = fit.valid
    return pd.DataFrame({"row": fit.labels[v], "k": fit.k[v], "b": fit.b[v], "n": fit.n[v]})


def column_residuals(j, w1, w2) -> np.ndarray:
    """Per dot: the fitting error ``E = (k_j·w2 + b_j) − w1`` of its column's line ``w1 = k_j·w2 + b_j``
    (Eq 4–5); NaN for dots of columns with fewer than 3 dots."""
    j, w1, w2 = np.asarray(j), np.asarray(w1, float), np.asarray(w2, float)
    e = np.full(len(j), np.nan)
    ok = _valid(w1, w2)
    if ok.any():
        e[ok] = -group_lines(j[ok], w2[ok], w1[ok], min_n=MIN_DOTS_PER_LINE).residuals
    return e


def _column_quadratic(j, w1p, w2p, a: float | None = None) -> tuple[float, float, float]:
    e = column_residuals(j, w1p, w2p)
    ok = np.isfinite(e)
    if ok.sum() < 3:
        raise SlmlabError("too few dots in complete columns to fit the column correction (§3, Eq 5); image the grid "
                          "plate so that it fills both views")
    if a is None:
        a, b, c = np.polyfit(w2p[ok], e[ok], 2)
    else:
        b, c = np.polyfit(w2p[ok], e[ok] - a * w2p[ok] ** 2, 1)
    return float(a), float(b), float(c)


# -------------------------------------------------------------------------------------- estimators
def estimate_two_step(i, j, w1, w2) -> ViewCorrection:
    """The paper's estimate: ``λ`` from the regression of row slopes on row intercepts (Fig 5), then
    ``a, b, c`` from the column lines of the row-corrected dots (Eqs 4–5)."""
    lines = row_lines(i, w1, w2)
    if len(lines) < 3:
        raise SlmlabError("fewer than 3 rows with 3 or more dots: cannot estimate the row correction (§3, Eq 3); image "
                          "the grid plate so that it fills both views")
    lam = -float(np.polyfit(lines["b"], lines["k"], 1)[0])
    w1 = np.asarray(w1, float)
    w2p = np.asarray(w2, float) * (1 + lam * w1)
    return ViewCorrection(lam, *_column_quadratic(j, w1, w2p))


def lattice_misfit(i, j, w1, w2) -> np.ndarray:
    """Residuals ``(n, 2)`` [px] of the least-squares affine lattice ``o + i·u + j·v`` through the dots."""
    ok = _valid(w1, w2)
    m = np.column_stack([np.ones(ok.sum()), np.asarray(i)[ok], np.asarray(j)[ok]]).astype(float)
    y = np.column_stack([np.asarray(w1, float)[ok], np.asarray(w2, float)[ok]])
    coef, *_ = np.linalg.lstsq(m, y, rcond=None)
    return y - m @ coef


def estimate_joint(i, j, w1, w2, start: ViewCorrection | None = None) -> ViewCorrection:
    """``λ, a`` minimising the affine-lattice misfit of the corrected dots; ``b, c`` by the paper's
    convention (the column-line residual less ``a·w2'²``, fitted by a line)."""
    start = start or estimate_two_step(i, j, w1, w2)
    scale = 1e-6

    w1a, w2a = np.asarray(w1, float), np.asarray(w2, float)

    def resid(x):
        return lattice_misfit(i, j, *ViewCorrection(x[0] * scale, x[1] * scale).apply(w1a, w2a)).ravel()

    def jac(x):
        # the misfit is a fixed linear projection of the corrected dots (the lattice indices do not move), so its
        # derivative is the projection of theirs: w1'' = w1 + a·w2'², w2' = w2·(1 + λ·w1)
        w2p = w2a * (1.0 + x[0] * scale * w1a)
        d_lam = lattice_misfit(i, j, 2 * x[1] * scale * w2p * w2a * w1a, w2a * w1a).ravel()
        d_a = lattice_misfit(i, j, w2p ** 2, np.where(np.isfinite(w2p), 0.0, np.nan)).ravel()
        return np.column_stack([d_lam, d_a]) * scale

    # an analytic Jacobian and a stop at the floating-point floor (not scipy's default 1e-8 with finite
    # differences): otherwise the last bits of the input, which differ between CPUs, move λ in its seventh digit
    sol = least_squares(resid, [start.lam / scale, start.a / scale], jac=jac, method="lm", x_scale=1.0,
                        xtol=1e-15, ftol=1e-15, gtol=1e-15)
    lam, a = sol.x * scale
    w1 = np.asarray(w1, float)
    w2p = np.asarray(w2, float) * (1 + lam * w1)
    return ViewCorrection(float(lam), *_column_quadratic(j, w1, w2p, a=float(a)))


# -------------------------------------------------------------------------------------- quality
def quality(i, j, w1, w2) -> dict:
    """How well rows are parallel and equally spaced and columns straight [px or px/px].

    Returns
    -------
    dict
        ``row_slope_spread`` (std of the row slopes [-]), ``row_spacing_trend`` (change of the spacing of
        adjacent rows per pixel of ``w1`` [px/px], from the row lines), ``column_straightness_px`` (RMS of the
        column-line residuals [px]), ``lattice_rms_px`` (RMS of the affine-lattice misfit per coordinate).
    """
    lines = row_lines(i, w1, w2).sort_values("row")
    dk = np.diff(lines["k"]) / np.diff(lines["row"])
    e = column_residuals(j, w1, w2)
    return {
        "row_slope_spread": float(np.std(lines["k"])),
        "row_spacing_trend": float(np.mean(dk)) if len(dk) else float("nan"),
        "column_straightness_px": float(np.sqrt(np.nanmean(e ** 2))),
        "lattice_rms_px": float(np.sqrt(np.mean(lattice_misfit(i, j, w1, w2) ** 2))),
    }


def virtual_line_spacing(i, w1, w2, rows=(1, 2, 3, 4, 5), w1_px=None) -> pd.DataFrame:
    """Spacing ``L_{k→1}`` [px] between the lines of rows ``k`` and of the first row as a function of
    ``w1`` (paper Fig 5), from the measured row lines; the rows' intercepts set to 0 (lines through the origin)
    so only the slope difference shows, as in the paper's virtual lines."""
    lines = row_lines(i, w1, w2).set_index("row")
    rows = [r for r in rows if r in lines.index]
    if w1_px is None:
        w1_px = np.linspace(0, np.nanmax(w1), 50)
    base = lines.loc[rows[0], "k"]
    out = {"w1_px": w1_px}
    for r in rows[1:]:
        out[f"L_{r}_to_{rows[0]}"] = (lines.loc[r, "k"] - base) * w1_px
    return pd.DataFrame(out)


# -------------------------------------------------------------------------------------- display transform
_DISPLAY_LABELS = {"first": "{across} − {across}[first dot] + {k}·s",
                   "chord": "{across} − chord + {k}·s",
                   "levelled": "{across} − {across}[first dot] − tilt·Δ{along} + {k}·s"}


def _display(df: pd.DataFrame, line: str, along: str, across: str, spacing_px: float, reference: str):
    df = df.sort_values([line, "col" if line == "row" else "row"])
    g = df.groupby(line)
    if reference in ("first", "levelled"):
        base = g[across].transform("first")
        if reference == "levelled":  # less the view's mean tilt: one rotation of the whole image
            slopes = [np.polyfit(d[along], d[across], 1)[0] for _, d in g if len(d) >= 2]
            base = base + (float(np.mean(slopes)) if slopes else 0.0) * (df[along] - g[along].transform("first"))
    elif reference == "chord":  # the straight line through the line's first and last dots
        a0, a1 = g[along].transform("first"), g[along].transform("last")
        b0, b1 = g[across].transform("first"), g[across].transform("last")
        base = b0 + (b1 - b0) * (df[along] - a0) / (a1 - a0).where(a1 != a0, 1.0)
    else:
        raise ValueError(f"reference must be 'first', 'levelled' or 'chord', not {reference!r}")
    out = df.assign(x=df[along], y=df[across] - base + df[line] * spacing_px)
    k = "i" if line == "row" else "j"
    out.attrs["y_label"] = _DISPLAY_LABELS[reference].format(across=across, along=along, k=k) + " [px]"
    out.attrs["spacing_px"] = spacing_px
    return out


def display_rows(i, j, w1, w2, spacing_px: float, reference: str = "first") -> pd.DataFrame:
    """Eq 1: each row ``i`` as ``(w1, w2 − w2[i, 1] + i·s)`` (deformations made visible, Fig 4a–b).

    The first dot of the row stands in for ``[i, 1]`` when that one is missing. ``reference='levelled'`` also
    subtracts the view's mean row tilt times ``w1 − w1[i, 1]``: a rotation of the whole image, which is no
    distortion (§4's α and §5's θX take it up), so that the rows' fan (their tilts differ row by row)
    shows. ``reference='chord'`` subtracts the line through the row's end dots instead (shows bending hidden
    by a tilt). The frame's ``attrs['y_label']`` says which."""
    df = pd.DataFrame({"row": i, "col": j, "w1": w1, "w2": w2})[_valid(w1, w2)]
    return _display(df, "row", "w1", "w2", spacing_px, reference)


def display_columns(i, j, w1, w2, spacing_px: float, reference: str = "first") -> pd.DataFrame:
    """Eq 2: each column ``j`` as ``(w2, w1 − w1[1, j] + j·s)`` (Fig 4c–d); see :func:`display_rows`."""
    df = pd.DataFrame({"row": i, "col": j, "w1": w1, "w2": w2})[_valid(w1, w2)]
    return _display(df, "col", "w2", "w1", spacing_px, reference)


# -------------------------------------------------------------------------------------- both views
@dataclass
class DistortionResult:
    """Φ of both views by both estimators, the one chosen, and the quality before and after.

    Attributes
    ----------
    estimates
        ``{method: {side: ViewCorrection}}``, methods ``'paper-two-step'`` and ``'joint'``.
    chosen
        the method used downstream: the one with the smaller affine-lattice misfit after correction.
    quality
        DataFrame: one row per (view, stage) with stage ``'raw'`` or a method name.
    """

    estimates: dict
    chosen: str
    quality: pd.DataFrame = field(repr=False)

    @property
    def left(self) -> ViewCorrection:
        return self.estimates[self.chosen]["l"]

    @property
    def right(self) -> ViewCorrection:
        return self.estimates[self.chosen]["r"]

    def view(self, side: str) -> ViewCorrection:
        return self.estimates[self.chosen][side]

    def apply(self, w: np.ndarray) -> np.ndarray:
        """Corrected ``(n, 4)`` image coordinates ``wl1, wl2, wr1, wr2`` [px]."""
        w = np.asarray(w, float)
        l1, l2 = self.left.apply(w[:, 0], w[:, 1])
        r1, r2 = self.right.apply(w[:, 2], w[:, 3])
        return np.column_stack([l1, l2, r1, r2])

    def parameters(self) -> dict:
        return {**self.left.as_dict("l"), **self.right.as_dict("r")}

    def table(self) -> pd.DataFrame:
        """Φ per view and method (Table 1 layout)."""
        rows = []
        for method, views in self.estimates.items():
            for side, vc in views.items():
                rows.append({"method": method, "view": side, **{k: v for k, v in asdict(vc).items()}})
        return pd.DataFrame(rows).rename(columns={"lam": "lambda"})


def estimate_distortion(grid: pd.DataFrame, methods=("paper-two-step", "joint")) -> DistortionResult:
    """Estimate Φ of both views from the ``grid`` rows of a calibration set (columns ``row, col, wl1, wl2,
    wr1, wr2``) by the given estimators (default both); keep the one with the smaller lattice misfit
    (summed over views)."""
    if grid.empty:
        raise SlmlabError("the calibration set has no 'grid' sequence: §3's distortion correction needs one "
                          "stereo pair of the large plate")
    i, j = grid["row"].to_numpy(), grid["col"].to_numpy()
    estimates: dict = {m: {} for m in methods}
    qual = []
    for side in "lr":
        w1, w2 = grid[f"w{side}1"].to_numpy(float), grid[f"w{side}2"].to_numpy(float)
        two = estimate_two_step(i, j, w1, w2)
        if "paper-two-step" in estimates:
            estimates["paper-two-step"][side] = two
        if "joint" in estimates:
            estimates["joint"][side] = estimate_joint(i, j, w1, w2, start=two)
        qual.append({"view": side, "stage": "raw", **quality(i, j, w1, w2)})
        for method in estimates:
            qual.append({"view": side, "stage": method, **quality(i, j, *estimates[method][side].apply(w1, w2))})
    q = pd.DataFrame(qual)
    misfit = q[q["stage"] != "raw"].groupby("stage")["lattice_rms_px"].sum()
    return DistortionResult(estimates, str(misfit.idxmin()), q)


def table1(result: DistortionResult, noise_free: DistortionResult | None = None, microscope=None) -> pd.DataFrame:
    """Table 1: Φ per view with its unit, ours (the chosen estimator and the paper's two-step) next to the
    paper's values, with the estimate on noise-free centres and, from the simulator's optics, the first-order
    values ``λ = 2·p1·pixel``, ``a = (p1 + s1)·pixel`` beside them. The paper prints a fifth value per view
    without a symbol: it is the row ``unlabelled``, the paper's value only."""
    ref = paper_reference("table1")
    units = {"lambda": "1/px", "a": "1/px", "b": "-", "c": "px", "unlabelled": "?"}
    rows = []
    for side, name in (("l", "left"), ("r", "right")):
        for par, attr in (("lambda", "lam"), ("a", "a"), ("b", "b"), ("c", "c"), ("unlabelled", None)):
            row = {"view": name, "parameter": par, "unit": units[par], "paper": ref[name][par]}
            if attr is None:
                rows.append(row)
                continue
            row.update({"ours": getattr(result.view(side), attr),
                        "ours_two_step": getattr(result.estimates["paper-two-step"][side], attr)})
            if noise_free is not None:
                row["noise_free"] = getattr(noise_free.view(side), attr)
            if microscope is not None:
                v, px = microscope.optics.view(side), microscope.optics.pixel_mm / microscope.optics.view(side).magnification_ratio
                first = {"lambda": 2 * v.decentring_per_mm * px, "a": (v.decentring_per_mm + v.thin_prism_per_mm) * px}
                row["first_order_physics"] = first.get(par, np.nan)
            rows.append(row)
    df = pd.DataFrame(rows)
    df["ours_vs_paper_percent"] = 100 * (df["ours"] / df["paper"] - 1)
    return df


def display_frames(grid: pd.DataFrame, result: DistortionResult | None = None, spacing_px: float = 3.0,
                   column_spacing_px: float = 3.0, row_reference: str = "levelled",
                   column_reference: str = "chord") -> dict:
    """The display transform of both views' rows and columns (Figs 4 and 6), raw or corrected by
    ``result``: ``{('rows'|'cols', 'l'|'r'): DataFrame with x, y}``.

    The rows' fan is a few pixels across the image and each view is rotated by a few tenths of a degree:
    by default the rows are levelled (each view's mean tilt subtracted, :func:`display_rows`) and stacked
    3 px apart, so that the fan shows in both views and a corrected view's rows lie flat. The columns'
    bend (a pixel or two) would be hidden by the same rotation: they take the chord reference."""
    out = {}
    i, j = grid["row"].to_numpy(), grid["col"].to_numpy()
    for side in "lr":
        w1, w2 = grid[f"w{side}1"].to_numpy(float), grid[f"w{side}2"].to_numpy(float)
        if result is not None:
            w1, w2 = result.view(side).apply(w1, w2)
        out[("rows", side)] = display_rows(i, j, w1, w2, spacing_px, row_reference)
        out[("cols", side)] = display_columns(i, j, w1, w2, column_spacing_px, column_reference)
    return out
