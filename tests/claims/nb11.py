"""Notebook 11: the zoo's rigs (the lead's sections may add their checks to :func:`check`), and extraction on every
rig (:func:`check_extraction`)."""

from __future__ import annotations

import numpy as np

from . import Tables, claim

TARGET_FOUND, TARGET_RMS = 99.0, 0.05


def check(t: Tables, size: str) -> None:
    check_extraction(t, size)


def check_extraction(t: Tables, size: str) -> None:
    """Section "Extraction on every rig": every rig's clean images and its own camera meet both targets (the
    narrative's first line); window streaks pull the centres (its last line)."""
    name = "ext11_extraction_by_degradation"
    ex = t(name)
    claim({"degradation", "rig", "images", "visible_dots", "found_percent", "misnumbered", "rms_px", "max_px"}
          <= set(ex.columns), name, "columns", "the table has its columns")
    claim((ex["images"] > 0).all() and (ex["visible_dots"] > 0).all(), name, "images", "every cell rendered dots")
    for rig, g in ex.groupby("rig"):
        own = g[g["degradation"].isin(["clean", "the rig's camera"])]
        claim(len(own) == 2, name, rig, "the clean images and the rig's own camera were both run")
        claim(((own["found_percent"] >= TARGET_FOUND) & (own["misnumbered"] == 0) & (own["rms_px"] <= TARGET_RMS)).all(),
              name, rig, "the rig's clean images and its own camera meet both targets")
        streaks = g[g["degradation"].isin(["streaks", "all together"])]
        clean = float(g.loc[g["degradation"] == "clean", "rms_px"].iloc[0])
        claim((streaks["rms_px"] > clean).all(), name, rig, "window streaks pull the centres (RMS above the clean images')")
    if size == "full":
        claim(set(ex["rig"]) == {"greenough", "stereo-dic", "stereo-piv"} and ex["degradation"].nunique() == 15,
              name, "rigs", "every rig under every degradation")
        claim(np.isfinite(ex["rms_px"]).sum() >= 40, name, "rms_px", "almost every cell extracted")
