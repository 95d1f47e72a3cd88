"""Residual evaluation of a vision model (paper §5.2–§5.3, Figs 12–17).

For each axis sequence AXIS ∈ {X, Y, Z}, position ``t ≥ 2`` and grid point: the true displacement
``ΔP_A = P_A(t) − P_A(1)`` is the stage's commanded move; the measured one ``ΔP_P = P_P(t) − P_P(1)`` is the
model's reconstruction; the residual ``E = ΔP_P − ΔP_A`` has three components, giving nine *residual elements*
``E_AXIS,COMP`` (``XX, XY, XZ, YX, …, ZZ``); ``XX, YY, ZZ`` are axial, the others radial. The *validate scale
coefficient* ``S = K/G`` of an element at interval ``RAk`` is the share of its samples within ``±A_k``. The
paper's requirement: S ≥ 95 % at RA3 for X and Y components, at RA5 for Z components.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from ..errors import SlmlabError
from ..io import CalibrationSet
from .chain import displacements

__all__ = ["RESIDUAL_INTERVALS_MM", "ELEMENTS", "residuals", "s_coefficients", "requirement", "element_summary",
           "Evaluation", "evaluate"]

#: §5.3: half-widths of the residual intervals RA1–RA5 [mm]
RESIDUAL_INTERVALS_MM = {"RA1": 0.005, "RA2": 0.0075, "RA3": 0.01, "RA4": 0.0125, "RA5": 0.015}
ELEMENTS = [a + c for a in "XYZ" for c in "XYZ"]
REQUIRED_INTERVAL = {"X": "RA3", "Y": "RA3", "Z": "RA5"}
REQUIRED_S_PERCENT = 95.0


def residuals(reconstruct, cal: CalibrationSet, sequences=("X", "Y", "Z")) -> pd.DataFrame:
    """Residual displacements of every sample of the axis sequences.

    Parameters
    ----------
    reconstruct
        a function ``(n, 4) → (n, 3)`` [px → mm] (e.g. ``model.reconstruct``).
    cal
        the calibration or validation set.

    Returns
    -------
    DataFrame
        ``sequence, position, row, col``, the commanded displacement along the sequence's axis
        ``displacement_mm``, and the residual components ``E_X, E_Y, E_Z`` [mm]. Rows with a missing dot (at
        ``t`` or at position 1) are skipped.
    """
    frames = []
    for seq in sequences:
        df = cal.sequence(seq)
        if df.empty:
            continue
        df = df[df[["wl1", "wl2", "wr1", "wr2"]].notna().all(axis=1)]
        if df["position"].nunique() < 2:
            continue
        p = reconstruct(df[["wl1", "wl2", "wr1", "wr2"]].to_numpy(float))
        dp, da, keep = displacements(df, p)
        e = dp - da
        axis = "XYZ".index(seq) if seq in "XYZ" else 0
        frames.append(pd.DataFrame({
            "sequence": seq, "position": df["position"].to_numpy()[keep], "row": df["row"].to_numpy()[keep],
            "col": df["col"].to_numpy()[keep], "displacement_mm": da[:, axis],
            "E_X": e[:, 0], "E_Y": e[:, 1], "E_Z": e[:, 2]}))
    if not frames:
        raise SlmlabError("no X, Y or Z sequence with 2 or more positions seen in both views: nothing to evaluate; evaluate on a "
                          "set with stage sequences",
                          cal.path)
    return pd.concat(frames, ignore_index=True)


def _element_values(res: pd.DataFrame, element: str) -> np.ndarray:
    return res.loc[res["sequence"] == element[0], f"E_{element[1]}"].to_numpy()


def s_coefficients(res: pd.DataFrame) -> pd.DataFrame:
    """``S`` [%] of each residual element (rows ``XX … ZZ``) at each interval (columns ``RA1 … RA5``)."""
    out = {}
    for el in ELEMENTS:
        v = _element_values(res, el)
        if len(v):
            out[el] = {k: 100.0 * float(np.mean(np.abs(v) <= a + 1e-12)) for k, a in RESIDUAL_INTERVALS_MM.items()}
    return pd.DataFrame(out).T.rename_axis("element")


def requirement(s: pd.DataFrame) -> pd.DataFrame:
    """The paper's requirement per element: the interval it is judged at, its S there, and pass/fail."""
    rows = []
    for el in s.index:
        ra = REQUIRED_INTERVAL[el[1]]
        rows.append({"element": el, "interval": ra, "S_percent": float(s.loc[el, ra]),
                     "passes": bool(s.loc[el, ra] >= REQUIRED_S_PERCENT)})
    return pd.DataFrame(rows)


def element_summary(res: pd.DataFrame) -> pd.DataFrame:
    """Per element: number of samples, mean, RMS and maximum absolute residual [mm]."""
    rows = []
    for el in ELEMENTS:
        v = _element_values(res, el)
        if len(v):
            rows.append({"element": el, "samples": len(v), "mean_mm": float(np.mean(v)),
                         "rms_mm": float(np.sqrt(np.mean(v ** 2))), "max_abs_mm": float(np.max(np.abs(v)))})
    return pd.DataFrame(rows)


@dataclass
class Evaluation:
    """Residuals, S coefficients, the requirement and a per-element summary of one model on one set."""

    model: str
    residuals: pd.DataFrame
    s: pd.DataFrame
    requirement: pd.DataFrame
    summary: pd.DataFrame

    def as_json(self) -> dict:
        return {
            "model": self.model,
            "residual_intervals_mm": RESIDUAL_INTERVALS_MM,
            "S_percent": {el: {k: float(v) for k, v in row.items()} for el, row in self.s.iterrows()},
            "requirement": self.requirement.to_dict(orient="records"),
            "elements": self.summary.to_dict(orient="records"),
            "all_pass": bool(self.requirement["passes"].all()),
        }

    def text(self) -> str:
        s = self.s.reset_index()
        table = s.merge(self.summary[["element", "rms_mm", "max_abs_mm"]], on="element")
        table = table.merge(self.requirement[["element", "interval", "passes"]], on="element")
        lines = [f"model {self.model}: S coefficients [%], RMS and max residual [mm], requirement (S >= 95 %)"]
        lines.append(table.to_string(index=False, float_format=lambda v: f"{v:.4g}"))
        lines.append("all elements meet the requirement" if self.requirement["passes"].all()
                     else f"{int((~self.requirement['passes']).sum())} element(s) miss the requirement")
        return "\n".join(lines)


def evaluate(model, cal: CalibrationSet) -> Evaluation:
    """Evaluate a model (anything with ``reconstruct`` and ``name``) on the axis sequences of a set."""
    res = residuals(model.reconstruct, cal)
    s = s_coefficients(res)
    return Evaluation(getattr(model, "name", "model"), res, s, requirement(s), element_summary(res))
