"""Notebook 04: Model 0's parameters, Fig 10, the scale estimators, Fig 12 beside the paper."""

from __future__ import annotations

from . import Tables, claim


def check(t: Tables, size: str) -> None:
    name = "ext04_initial_model"
    m = t(name).set_index("parameter")["ours_vs_paper_percent"]
    claim(abs(m["thetaX_deg"]) < 0.5, name, "thetaX_deg", "θX on the paper's (by construction)")
    for p in ("EX_mm_per_px", "EY_mm_per_px"):
        claim(abs(m[p]) < 0.3, name, p, "the pixel: within 0.3 % of the paper's")
    claim(-1.0 < m["EZ_mm_per_px"] < -0.2, name, "EZ_mm_per_px", "EZ comes out a fraction of a per cent below the paper's")

    name = "ext04_depth_line"
    line = t(name).iloc[0]
    claim(line["rms_off_line_um"] < 10, name, "rms", "the samples lie on the line within a few µm RMS")
    claim(line["max_off_line_um"] < 0.01 * 1e3 * line["dZ_range_mm"], name, "max", "within 1 % of the Z range at most")

    name = "ext04_scale_estimators"
    d = t(name)["difference_percent"]
    claim(d.abs().max() < 0.5, name, "all", "mean of ratios and least squares agree within half a per cent")

    name = "ext04_model0_S_vs_paper"
    f = t(name)
    per = f.drop_duplicates("element").set_index("element")
    ours_fail = set(per.index[~per["ours_passes"].astype(bool)])
    paper_fail = set(per.index[per["paper_passes"].astype(str) == "False"])
    claim(ours_fail == paper_fail == {"YX", "YZ", "ZX", "ZY"}, name, "requirement",
          "Model 0 fails the same four elements as the paper's: E_Y,X, E_Y,Z, E_Z,X, E_Z,Y")
    s = f.set_index(["element", "interval"])
    for k in (("YX", "RA3"), ("ZX", "RA3"), ("ZY", "RA3")):
        claim(10 <= abs(s.loc[k, "difference_points"]) <= 20, name, " ".join(k),
              "the radial elements of the Y and Z sequences differ from the paper's by 11 to 19 points")
    claim(s.loc[("XZ", "RA2"), "ours_percent"] >= s.loc[("XZ", "RA2"), "paper_percent"], name, "XZ RA2",
          "E_X,Z is small: S at RA2 at least the paper's")
    claim(-5 < s.loc[("YZ", "RA5"), "difference_points"] < 0, name, "YZ RA5", "Fig 12(b): S_Y,Z at RA5 a few points below the paper's")
    for k in (("XX", "RA1"), ("YY", "RA2")):
        claim(s.loc[k, "ours_percent"] == 100, name, " ".join(k), "the axial elements are small")
