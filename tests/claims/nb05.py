"""Notebook 05: Tables 3-4, Figs 13-16, what shapes Fig 15's E_Z,Z, the headline."""

from __future__ import annotations

import numpy as np

from . import Tables, claim

PAPER_POSITIONS = {1: (42, 30, 32), 2: (21, 15, 16), 3: (14, 10, 11), 4: (9, 8, 8), 5: (9, 7, 7)}


def check(t: Tables, size: str) -> None:
    name = "table3_calibration_tests"
    for k, n in PAPER_POSITIONS.items():
        r = t.row(name, test=k)
        claim((r["NUMX"], r["NUMY"], r["NUMZ"]) == n, name, str(k), "the paper's steps and positions")
        claim(all(r[f"dots_{s}"] >= 0.95 * 49 * m for s, m in zip("XYZ", n)), name, str(k),
              "nearly every dot of the 7 x 7 plate seen in both views at every position")

    name = "table4_parameters"
    t4 = t(name).set_index("parameter")
    rel = 100 * t4["ours_minus_paper"] / t4["paper_mean"].abs()
    for p in ("thetaX_deg", "KYX", "KYZ", "KZX", "KZY"):
        claim(abs(rel[p]) < 1.5, name, p, "θX and the K terms on the paper's means (by construction)")
    claim(-1.0 < rel["EZ_mm_per_px"] < -0.2, name, "EZ_mm_per_px", "EZ a fraction of a per cent below the paper's")
    for b in ("BYX", "BYZ", "BZX", "BZY"):
        claim(t4.loc[b, "unit"] == "µm" and np.isnan(t4.loc[b, "ours_relative_error_percent"]), name, b,
              "B in µm, with an absolute spread and no relative error")
        claim(abs(t4.loc[b, "ours_mean"]) < t4.loc[b, "ours_std"] < 1.0, name, b, "our B are zero within their spread (< 1 µm)")
        claim(abs(t4.loc[b, "paper_mean"]) >= 1.0, name, b, "the paper's B are 1.1-4.2 µm")

    name = "ext05_depth_error_causes"
    c = t(name).set_index("microscope")
    asis, flat, weak = c.loc["as is"], c.loc["without perspective (L → ∞)"], c.loc["decentred distortion × 0.2"]
    claim(asis["mean_end_um"] > 5 and abs(asis["mean_mid_um"]) < 2, name, "as is",
          "Fig 15: E_Z,Z near zero mid-way, several µm at the end of the Z run")
    claim(abs(flat["mean_end_um"]) < 1 and abs(flat["mean_mid_um"]) < 1, name, "without perspective",
          "without perspective the rise is gone")
    claim(weak["across_plate_end_um_per_mm"] < 0.4 * asis["across_plate_end_um_per_mm"], name, "distortion × 0.2",
          "the spread across the plate scales with the decentred distortion")
    claim(abs(flat["across_plate_end_um_per_mm"] / asis["across_plate_end_um_per_mm"] - 1) < 0.1, name, "without perspective",
          "the spread across the plate is not perspective")
    for comp in ("ZX", "ZY"):
        claim(flat[f"spread_end_{comp}_um"] < 0.2 * asis[f"spread_end_{comp}_um"], name, comp,
              "the fans of E_Z,X and E_Z,Y are perspective")

    name = "ext05_depth_error_profile"
    p = t(name)
    claim(p.loc[p["displacement_mm"].abs() <= 1.0, "mean_um"].abs().max() < 2, name, "|dZ| <= 1 mm",
          "Fig 15: E_Z,Z flat to about 1 mm of Z travel")

    name = "ext05_model2_S"
    s = t(name).set_index("element")
    claim(set(s.index[s["RA2"] < 95]) == {"ZZ"}, name, "RA2", "every element but E_Z,Z at or above 95 % at RA2")
    claim(s.loc["ZZ", "RA4"] >= 89.8 and s.loc["ZZ", "RA5"] >= 96.3, name, "ZZ", "S_Z,Z at RA4 and RA5 at least the paper's")

    name = "ext05_headline_precision"
    h = t(name).set_index("model")
    m2 = h.loc["paper-m2"]
    claim(m2["X_um"] <= 10 and m2["Y_um"] <= 10 and m2["Z_um"] <= 15 and bool(m2["all_elements_pass"]), name, "paper-m2",
          "Model 2 meets the requirement, within the paper's 10 / 10 / 15 µm")
    sp = h.loc["paper-m2, single-pass disparity"]
    claim(sp["Z_um"] > 15 and not bool(sp["all_elements_pass"]), name, "single pass", "the single pass misses it in Z")
    for m in ("paper-m0", "paper-m1"):
        claim(not bool(h.loc[m, "all_elements_pass"]), name, m, "Models 0 and 1 miss the requirement")

    name = "ext05_scale_estimator_headline"
    e = t(name)["EZ_mm_per_px"].to_numpy()
    claim(abs(e[1] / e[0] - 1) < 0.005, name, "EZ", "least squares and the mean of ratios give EZ within half a per cent")
