"""Notebook 11: the zoo's rigs and their physics (:func:`check_rigs`), the default on every rig and design
(:func:`check_zoo`), and extraction on every rig (:func:`check_extraction`)."""

from __future__ import annotations

import numpy as np

from . import Tables, claim

TARGET_FOUND, TARGET_RMS = 99.0, 0.05


def check(t: Tables, size: str) -> None:
    check_rigs(t, size)
    check_zoo(t, size)
    check_stage_free(t, size)
    check_extraction(t, size)


def check_rigs(t: Tables, size: str) -> None:
    """Section "The rigs": the true model's round trip and Snell's law against Fermat's principle agree to far
    below a micrometre (1e-9 mm)."""
    name = "ext11_rigs"
    rigs = t(name)
    for r in rigs.itertuples():
        claim(abs(r.round_trip_mm) <= 1e-9, name, r.rig, "the true model's triangulation comes back to the point")
        claim(np.isnan(r.snell_vs_fermat_mm) or abs(r.snell_vs_fermat_mm) <= 1e-9, name, r.rig,
              "the refraction traced by Snell's law is Fermat's least-time path")


def check_zoo(t: Tables, size: str) -> None:
    """Sections "Every rig, every design" and "Where the default loses": the targets' counts are those of the
    per-cell table; the default's median ratio to the best plain polynomial (hindsight) is 1 and to its own best
    candidate within 5 %; every cell more than 5 % above the best polynomial is listed with its choice; at full
    size (README, Known limits) the floor's and the polynomial's targets are met in about 70-80 % of the cells,
    the candidates' in over 85 % and the floor in the commanded frame's in over 90 %, most cells that miss
    the floor's are cells where no candidate, chosen with hindsight, reaches it (the direct model reaches below the
    floor in the commanded frame on two-level plates, and is taken there: :func:`check_unchosen_direct`), and the
    floor in the commanded
    frame (the stage's share) is nowhere below the floor and is met in more cells."""
    ratios, targets, losses = t("ext11_default_ratios"), t("ext11_targets").set_index("ratio"), t("ext11_losses")
    for key in ("vs_floor", "vs_polynomial", "vs_candidates", "vs_frame_floor"):
        values = ratios[[f"{c}_{key}" for c in "XYZ"]].to_numpy().ravel()
        claim(int(targets.loc[key, "cells"]) == len(values), "ext11_targets", key, "one cell per rig, design and axis")
        below, at = int((values < targets.loc[key, "target"]).sum()), int((values == targets.loc[key, "target"]).sum())
        claim(below <= int(targets.loc[key, "met"]) <= below + at, "ext11_targets", key,  # (ratios to 4 digits)
              f"the count met is the per-cell table's ({below} below the target, {at} at it to four digits)")
    claim(targets.loc["vs_polynomial", "median"] <= 1.01, "ext11_targets", "vs_polynomial",
          "the default's median ratio to the best plain polynomial is 1")
    claim(targets.loc["vs_candidates", "median"] <= 1.05, "ext11_targets", "vs_candidates",
          "the default's median ratio to its own best candidate is within 5 %")
    over = {(r.rig, r.design, c) for r in ratios.itertuples() for c in "XYZ" if getattr(r, f"{c}_vs_polynomial") > 1.05}
    claim(over == set(zip(losses["rig"], losses["design"], losses["axis"])), "ext11_losses", "cells",
          "every cell more than 5 % above the best polynomial is listed, and no other")
    check_unchosen_direct(t, size)
    if size == "full":
        for key, (lo, hi) in {"vs_floor": (0.6, 0.8), "vs_polynomial": (0.6, 0.8), "vs_candidates": (0.85, 1.0),
                              "vs_frame_floor": (0.9, 1.0)}.items():
            share = targets.loc[key, "met"] / targets.loc[key, "cells"]
            claim(lo <= share <= hi, "ext11_targets", key, f"{lo:.0%} to {hi:.0%} of the cells meet it ({share:.2f}; "
                  "README, Known limits)")
        errors = t("ext11_zoo_errors")
        cand = errors[~errors["model"].isin(["floor", "frame floor", "auto"])].groupby(["rig", "design"])[["X_um", "Y_um", "Z_um"]].min()
        floor = errors[errors["model"] == "floor"].set_index(["rig", "design"])[["X_um", "Y_um", "Z_um"]]
        best = (cand / floor).stack()
        auto = (errors[errors["model"] == "auto"].set_index(["rig", "design"])[["X_um", "Y_um", "Z_um"]] / floor).stack()
        miss = auto > 1.2
        claim((best[miss] > 1.2).sum() > 0.5 * miss.sum(), "ext11_zoo_errors", "floor",
              f"most cells that miss the floor's target ({int(miss.sum())}) are out of every candidate's reach "
              f"({int((best[miss] > 1.2).sum())})")
        frame = errors[errors["model"] == "frame floor"].set_index(["rig", "design"])[["X_um", "Y_um", "Z_um"]]
        claim(bool((frame >= 0.98 * floor).to_numpy().all()), "ext11_zoo_errors", "frame floor",
              "the stage's errors only add to the floor: the floor in the commanded frame is nowhere below it")
        claim(targets.loc["vs_frame_floor", "met"] > targets.loc["vs_floor", "met"], "ext11_targets", "vs_frame_floor",
              "more cells are within 1.2x the floor in the commanded frame than within 1.2x the floor: the stage's share")


def check_unchosen_direct(t: Tables, size: str) -> None:
    """Section "Where the default loses", the line on a candidate below the floor in the commanded frame, not
    chosen: in each two-level cell where the best candidate is the direct model, below 0.9x that floor, and the
    default more than 5 % above it, the default keeps the commanded frame (within 1.05x its floor) and the direct
    model is within 1.1x the noise floor; at full size there is no such cell (README, Known limits: at two or three
    positions of a two-level plate held-out dots are measured net of their position's offset, and the default takes
    the direct model where it is best; before, the Greenough rig's plate at two positions was such a cell)."""
    errors, ratios = t("ext11_zoo_errors"), t("ext11_default_ratios").set_index(["rig", "design"])
    cand = errors[~errors["model"].isin(["floor", "frame floor", "auto"])]
    frame = errors[errors["model"] == "frame floor"].set_index(["rig", "design"])
    floor = errors[errors["model"] == "floor"].set_index(["rig", "design"])
    cells = 0
    for (rig, design), g in cand[cand["design"].str.startswith("two-level")].groupby(["rig", "design"]):
        for c in "XYZ":
            best = g.loc[g[f"{c}_um"].idxmin()]
            if (best["model"] == "direct" and best[f"{c}_um"] < 0.9 * frame.loc[(rig, design), f"{c}_um"]
                    and ratios.loc[(rig, design), f"{c}_vs_candidates"] > 1.05):
                cells += 1
                claim(best[f"{c}_um"] <= 1.1 * floor.loc[(rig, design), f"{c}_um"], "ext11_zoo_errors",
                      f"{rig} {design} {c}", "the direct model within 1.1x the noise floor")
                claim(ratios.loc[(rig, design), f"{c}_vs_frame_floor"] <= 1.05, "ext11_default_ratios",
                      f"{rig} {design} {c}", "the default keeps the commanded frame (within 1.05x its floor)")
    if size == "full":
        claim(cells == 0, "ext11_zoo_errors", "two-level", "no two-level cell where the direct model, below the floor "
              "in the commanded frame, is left unchosen (README, Known limits)")


def check_stage_free(t: Tables, size: str) -> None:
    """Section "The stage's share": both stages were run on the same designs, and with the stage made perfect
    the default meets the floor's target in more cells than as built (the narrative's headline); at full size
    in at least four fifths of them (README, Known limits)."""
    name = "ext11_stage_free"
    sf = t(name)
    claim(set(sf["stage"]) == {"as built", "perfect"}, name, "stage", "the rig as built and with a perfect stage")
    designs = {s: set(g["design"]) for s, g in sf.groupby("stage")}
    claim(designs["as built"] == designs["perfect"], name, "design", "the same designs under both stages")
    cols = [f"{c}_vs_floor" for c in "XYZ"]
    met = {s: int((g[cols] <= 1.2 * (1 + 1e-9)).to_numpy().sum()) for s, g in sf.groupby("stage")}
    claim(met["perfect"] > met["as built"], name, "stage=perfect",
          f"a perfect stage meets the floor's target in more cells ({met['perfect']}) than the stage as built "
          f"({met['as built']})")
    if size == "full":
        cells = 3 * len(designs["perfect"])
        claim(met["perfect"] >= 0.8 * cells, name, "stage=perfect",
              f"with a perfect stage at least four fifths of the cells meet the floor's target ({met['perfect']} of {cells})")


def check_extraction(t: Tables, size: str) -> None:
    """Section "Extraction on every rig": every rig's clean images and its own camera meet both targets (the
    narrative's first line); everything together still pulls the centres above the clean images' RMS (its line
    on streaks)."""
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
        together = g[g["degradation"] == "all together"]
        clean = float(g.loc[g["degradation"] == "clean", "rms_px"].iloc[0])
        claim((together["rms_px"] > clean).all(), name, rig,
              "everything together (streaks, a bright region, noise, defocus) still pulls the centres (RMS above the "
              "clean images')")
    claim(int(ex["misnumbered"].sum()) == 0, name, "misnumbered",
          "no dot numbered wrongly in any cell (the narrative's numbering line)")
    claim("floor_px" in ex.columns and (ex["floor_px"] > 0).all(), name, "floor_px", "every cell has its floor")
    claim((ex["rms_px"] >= ex["floor_px"]).all(), name, "floor_px",
          "no cell's centres beat their Cramér-Rao floor (the floor line's 'no cell beats it')")
    clean = ex[ex["degradation"] == "clean"].set_index("rig")["rms_px"]
    noisy = ex[ex["degradation"].isin(["low contrast", "lowest contrast", "noise", "12 bit", "16 bit",
                                       "the rig's camera"]) & (ex["floor_px"] >= 2 * ex["rig"].map(clean))]
    claim((len(noisy) > 0 or size != "full") and (noisy["rms_px"] <= 1.5 * noisy["floor_px"]).all(), name, "floor_px",
          "where noise dominates (the floor at least twice the rig's clean RMS), within 1.5x of the floor (the "
          "floor line's range; the README's 1.2-1.5x)")
    together = ex[(ex["degradation"] == "all together") & (ex["rig"] == "greenough")]
    floor = float(together["floor_px"].iloc[0]) if len(together) == 1 else float("nan")
    claim(size != "full" or 0.8 * TARGET_RMS < floor < TARGET_RMS, name,
          "greenough", "the Greenough rig with everything together has a floor near the 0.05 px target (the floor "
          "module's docstring, 0.048 px, and the notebook's miss line)")
    rise = ex["light_floor_px"] / ex["floor_px"]
    claim(((rise >= 1.0) & (rise <= 1.15)).all() and (size != "full" or (
        rise[ex["rig"] == "greenough"].between(1.09, 1.15).all() and rise[ex["rig"] != "greenough"].max() <= 1.11)),
        name, "light_floor_px", "the floor with the light unknown is 0-15 % above the floor with it known in every "
        "cell (more unknowns, less to know); 10-14 % on the Greenough rig, 2-10 % on the others (the floor module's "
        "docstring, the README)")
    light = float(together["light_floor_px"].iloc[0]) if len(together) == 1 else float("nan")
    claim(size != "full" or TARGET_RMS < light < 1.2 * floor, name, "greenough",
          "the Greenough rig with everything together: the 0.05 px target is below the floor with the light unknown "
          "(the floor module's docstring, 0.0535 px, 10-14 % above the floor; the notebook's miss line)")
    if size == "full":
        claim(set(ex["rig"]) == {"greenough", "stereo-dic", "stereo-piv"} and ex["degradation"].nunique() == 15,
              name, "rigs", "every rig under every degradation")
        claim(np.isfinite(ex["rms_px"]).sum() >= 40, name, "rms_px", "almost every cell extracted")
