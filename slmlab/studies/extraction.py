"""Extraction accuracy against the virtual microscope's truth (notebook 02): every rendered dot's extracted
centre beside the true one, found and correctly numbered shares, and the error against defocus."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from ..io import KEY_COLUMNS, CalibrationSet, read_set
from ..images.centres import METHODS
from ..images.dots import read_image
from ..images.extract import extract_image
from ..virtual.microscope import from_dict

__all__ = ["extraction_errors", "extraction_summary", "extract_folder", "error_by_defocus", "measured_centres"]


def extraction_errors(points: pd.DataFrame, cal) -> pd.DataFrame:
    """Extracted centres against a simulated set's truth: one row per dot and view seen in the truth image.

    Columns: ``sequence, position, row, col, view, z_mm`` (height above the focal plane), ``visible`` (the whole
    dot is inside the image), ``found`` (extracted and indexed at this ``[row, col]``), ``err1, err2`` [px]
    (extracted minus true centre). A dot indexed at the wrong place shows as a large error.
    """
    sim = cal.meta["simulator"]
    m = from_dict(sim["microscope"])
    truth = cal.truth
    z = m.stage_to_microscope(truth[["X_mm", "Y_mm", "Z_mm"]].to_numpy(), np.asarray(sim["stage_origin_mm"]))[:, 2]
    key = ["sequence", "position", "row", "col"]
    merged = truth[key].copy()
    ext = points.set_index(key)
    frames = []
    for side in "lr":
        tw = truth[[f"w{side}1", f"w{side}2"]].to_numpy()
        diam = cal.meta["plates"]["moving"]["dot_diameter_mm"]
        diam_grid = cal.meta["plates"]["grid"]["dot_diameter_mm"]
        d = np.where(truth["sequence"].to_numpy() == "grid", diam_grid, diam)
        margin = d / m.optics.pixel_mm / 2 + 2
        w, h = m.optics.image_size_px
        vis = (tw[:, 0] >= margin) & (tw[:, 0] <= w - 1 - margin) & (tw[:, 1] >= margin) & (tw[:, 1] <= h - 1 - margin)
        e = ext.reindex(pd.MultiIndex.from_frame(truth[key]))[[f"w{side}1", f"w{side}2"]].to_numpy()
        f = merged.copy()
        f["view"] = side
        f["z_mm"] = z
        f["visible"] = vis
        f["found"] = np.isfinite(e).all(axis=1)
        f["err1"], f["err2"] = e[:, 0] - tw[:, 0], e[:, 1] - tw[:, 1]
        frames.append(f)
    return pd.concat(frames, ignore_index=True)


def extraction_summary(errors: pd.DataFrame, *, depth_of_field_mm: float = 1.13, in_focus_mm: float = 0.2,
                       misindexed_px: float = 1.0) -> dict:
    """Headline numbers of :func:`extraction_errors`: found and correctly indexed share of visible dots,
    centre RMS in focus (``|z| <= in_focus_mm``) and over the depth of field [px]."""
    vis = errors[errors["visible"]]
    err = np.hypot(vis["err1"], vis["err2"])
    good = vis["found"] & (err < misindexed_px)
    per_coord = lambda sel: float(np.sqrt(np.nanmean(np.r_[vis.loc[sel, "err1"], vis.loc[sel, "err2"]] ** 2)))  # noqa: E731
    focus = good & (vis["z_mm"].abs() <= in_focus_mm)
    dof = good & (vis["z_mm"].abs() <= depth_of_field_mm)
    return {
        "visible": int(len(vis)),
        "found_and_indexed_percent": float(100 * good.mean()) if len(vis) else float("nan"),
        "misindexed": int((vis["found"] & (err >= misindexed_px)).sum()),
        "rms_in_focus_px": per_coord(focus) if focus.any() else float("nan"),
        "rms_depth_of_field_px": per_coord(dof) if dof.any() else float("nan"),
        "extra_found": int((errors["found"] & ~errors["visible"]).sum()),
    }


def extract_folder(set_dir: str | Path, sequences: list[str], *, methods=METHODS) -> pd.DataFrame:
    """Per-dot extraction errors of a rendered simulated set for several centre methods.

    Returns :func:`extraction_errors` rows of the chosen sequences with a ``method`` column (for the error
    against defocus figure and the choice of the default method).
    """
    set_dir = Path(set_dir)
    cal = read_set(set_dir)
    frames = []
    for method in methods:
        rows = []
        for seq in sequences:
            plate = cal.plate(seq)
            for pos in sorted(cal.sequence(seq)["position"].unique()):
                for side in "lr":
                    img = read_image(set_dir / "images" / f"{seq}_{pos:03d}_{side}.png")
                    t = extract_image(img, int(plate["rows"]), int(plate["cols"]), method=method).table
                    t = t.rename(columns={"w1": f"w{side}1", "w2": f"w{side}2"})[["row", "col", f"w{side}1", f"w{side}2"]]
                    t.insert(0, "sequence", seq)
                    t.insert(1, "position", pos)
                    rows.append(t.set_index(["sequence", "position", "row", "col"]))
        pts = pd.concat(rows).groupby(level=[0, 1, 2, 3]).first().reset_index()
        sub = cal.truth["sequence"].isin(sequences)
        err = extraction_errors(pts, CalibrationSet(pts, cal.meta, cal.truth[sub].reset_index(drop=True)))
        err.insert(0, "method", method)
        frames.append(err)
    return pd.concat(frames, ignore_index=True)


def error_by_defocus(errors: pd.DataFrame, *, bin_mm: float = 0.25) -> pd.DataFrame:
    """Centre RMS per coordinate [px] of found, correctly indexed, visible dots, by method and depth bin."""
    e = errors[errors["visible"] & errors["found"]].copy()
    e = e[np.hypot(e["err1"], e["err2"]) < 1.0]
    e["z_bin_mm"] = np.round(e["z_mm"] / bin_mm) * bin_mm
    g = e.groupby(["method", "z_bin_mm"])
    return pd.DataFrame({
        "rms_px": g.apply(lambda d: float(np.sqrt(np.mean(np.r_[d["err1"], d["err2"]] ** 2))), include_groups=False),
        "dots": g.size(),
    }).reset_index()


def measured_centres(errors: pd.DataFrame, truth: pd.DataFrame, sequence: str, position: int, view: str,
                     method: str = "moments") -> pd.DataFrame:
    """The extracted centres ``row, col, w1, w2`` [px] of one image, rebuilt from :func:`extract_folder`'s
    errors and the truth (extracted = true + error)."""
    e = errors[(errors["method"] == method) & (errors["sequence"] == sequence) & (errors["position"] == position)
               & (errors["view"] == view) & errors["found"]].set_index(["row", "col"])
    t = truth[(truth["sequence"] == sequence) & (truth["position"] == position)].set_index(["row", "col"])
    t = t.loc[e.index]
    return pd.DataFrame({"w1": t[f"w{view}1"] + e["err1"], "w2": t[f"w{view}2"] + e["err2"]}).reset_index()
