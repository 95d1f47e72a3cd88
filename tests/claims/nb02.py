"""Notebook 02: dot extraction against truth, §3's correction and Table 1, the real DICe pairs."""

from __future__ import annotations

import numpy as np

from . import Tables, claim

TARGETS_PX = (0.03, 0.05)


def check(t: Tables, size: str) -> None:
    name = "ext02_extraction_accuracy"
    a = t(name).set_index("method")
    for m in a.index:
        claim(a.loc[m, "found_and_indexed_percent"] == 100 and a.loc[m, "misindexed"] == 0, name, m,
              "every visible dot found and numbered, none misnumbered")
        claim(a.loc[m, "rms_in_focus_px"] <= TARGETS_PX[0] and a.loc[m, "rms_depth_of_field_px"] <= TARGETS_PX[1], name, m,
              "within the targets: 0.03 px in focus, 0.05 px over the depth of field")
    dof = a["rms_depth_of_field_px"]
    claim(dof["symmetry"] < dof["moments"] < dof[["ellipse", "edges"]].min(), name, "symmetry, moments",
          "over the depth of field the point of symmetry is better than the centroid, the centroid than the edge fits")
    if "fit" in dof.index:
        claim(dof["symmetry"] <= dof["fit"], name, "symmetry, fit",
              "the point of symmetry, with no model of the dot, is as good as the model fit over the depth of field")

    name = "ext02_extraction_error_by_depth"
    d = t(name)
    edge = d[d["z_bin_mm"].abs() == d["z_bin_mm"].abs().max()].groupby("method")["rms_px"].mean()
    claim(edge["ellipse"] > 1.5 * edge["moments"], name, "the ends of the Z sweep",
          "far out of focus the edge-based ellipse is much worse than the centroid")
    claim(edge[["ellipse", "edges"]].min() > edge[["moments", "symmetry"]].max(), name, "the ends of the Z sweep",
          "far out of focus the centroid and the point of symmetry degrade less than the edge-based estimators")

    name = "ext02_distortion_quality"
    q = t(name).set_index(["centres", "view", "stage"])
    for view in "lr":
        raw = q.loc[("extracted", view, "raw")]
        for est in ("paper-two-step", "joint"):
            after, clean = q.loc[("extracted", view, est)], q.loc[("noise-free", view, est)]
            row = f"{view}, {est}"
            claim(after["row_slope_spread"] < raw["row_slope_spread"] / 10, name, row, "after correction the rows are parallel")
            claim(after["column_straightness_px"] < 0.1 < 0.3 < raw["column_straightness_px"], name, row,
                  "the columns are straight to a few hundredths of a pixel after, several tenths before")
            claim(abs(after["column_straightness_px"] - clean["column_straightness_px"]) < 0.2 * after["column_straightness_px"],
                  name, row, "what is left of the columns' bend is not the dot finder's noise (the noise-free centres leave as much)")
            claim(abs(after["row_spacing_trend"]) < abs(raw["row_spacing_trend"]) / 100, name, row, "the rows' fan is gone")
            claim(0.5 < after["lattice_rms_px"] < raw["lattice_rms_px"], name, row,
                  "the spacing along the rows is not corrected: the affine-lattice misfit falls only a little")
    claim(q.loc[("extracted", "l", "raw"), "row_spacing_trend"] * q.loc[("extracted", "r", "raw"), "row_spacing_trend"] < 0,
          name, "raw", "the rows fan out oppositely in the two views")

    name = "table1_distortion_parameters"
    t1 = t(name).set_index(["view", "parameter"])
    for view in ("left", "right"):
        claim(abs(t1.loc[(view, "a"), "ours_vs_paper_percent"]) < 10, name, f"{view}, a", "a within 10 % of the paper's")
        claim(abs(t1.loc[(view, "b"), "ours_vs_paper_percent"]) < 25, name, f"{view}, b", "b within 25 % of the paper's")
        for p in ("a", "b"):
            claim(np.sign(t1.loc[(view, p), "ours"]) == np.sign(t1.loc[(view, p), "paper"]), name, f"{view}, {p}",
                  "the paper's signs, alternating between the views")
        claim(np.isnan(t1.loc[(view, "unlabelled"), "ours"]) and t1.loc[(view, "unlabelled"), "paper"] > 0, name,
              f"{view}, unlabelled", "the paper's fifth value is listed, not reproduced")
    lam_l, lam_r = t1.loc[("left", "lambda"), "ours"], t1.loc[("right", "lambda"), "ours"]
    claim(abs(lam_l + lam_r) < 0.05 * abs(lam_l), name, "lambda", "our λ are of equal size and opposite sign")
    claim(abs(t1.loc[("right", "lambda"), "paper"] / t1.loc[("left", "lambda"), "paper"]) > 5, name, "lambda",
          "the paper's right λ is six times its left one")

    name = "ext02_real_dot_target_counts"
    if not (t.folder / f"{name}.csv").exists():
        claim(size == "small", name, "-", "the DICe section ran (make reproduce fetches the data first)")
        return
    c = t(name)
    claim(len(c) == 14, name, "pairs", "all 14 DICe pairs extracted")
    claim(c[["left", "right"]].max().max() <= 80, name, "left, right", "at most DICe's 80 dots per image (its 10 x 8 box)")
    claim(c["both"].min() >= 70, name, "both", "at least 70 dots in both views of every pair")
