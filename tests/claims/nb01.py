"""Notebook 01: the virtual microscope against the paper's numbers, the dots' tracks, perspective."""

from __future__ import annotations

from . import Tables, claim


def check(t: Tables, size: str) -> None:
    name = "ext01_simulator_nominal_vs_paper"
    d = t(name).set_index("parameter")["relative_difference_percent"]
    far = sorted(d.index[d.abs() > 10])
    claim(far == ["KYZ"], name, "KYZ", "only KYZ's nominal value is more than 10 % from the paper's")
    claim(d["KYZ"] < -30, name, "KYZ", "KYZ's nominal value is far below the paper's (the optics supply the rest)")

    name = "ext01_image_tracks"
    r = t(name).set_index(["sequence", "view"])
    zl, zr = r.loc[("Z", "left"), "dw1_px_per_mm"], r.loc[("Z", "right"), "dw1_px_per_mm"]
    claim(zl * zr < 0, name, "Z", "along Z the two views' dots move in opposite directions along w1")
    claim(abs((zr - zl) - 80.0) < 2.0, name, "Z", "the disparity changes by about 80 px per mm of depth (EZ = 0.0125 mm/px)")
    for view in ("left", "right"):
        claim(r.loc[("X", view), "dw1_px_per_mm"] < -320, name, f"X, {view}", "stage +X moves the dots left, ~333 px/mm")
        claim(r.loc[("Y", view), "dw2_px_per_mm"] < -320, name, f"Y, {view}", "stage +Y moves the dots up (inverted image)")
        x = r.loc[("X", view)]
        claim(2.5 < abs(x["dw2_px_per_mm"] / x["dw1_px_per_mm"]) * 57.2958 < 3.5, name, f"X, {view}",
              "the X tracks are tilted about 3° from the image rows")

    name = "ext01_perspective"
    p = t(name).set_index("preset")
    claim(0.3 < p.loc["paper", "magnification_change_percent_per_mm"] < 0.4, name, "paper",
          "the paper preset's magnification changes by about 1/L = 0.33 % per mm")
    claim(p.loc["leica", "magnification_change_percent_per_mm"] > 4 * p.loc["paper", "magnification_change_percent_per_mm"],
          name, "leica", "the Leica-like preset's perspective is several times the paper preset's")
    claim(p.loc["paper", "sideways_shift_um"] < 10 < 25 < p.loc["leica", "sideways_shift_um"], name, "sideways_shift_um",
          "a corner dot moves sideways a few µm over the Z travel on the paper preset, tens of µm on the Leica-like one")
