"""The zoo: how well each model calibrates each virtual rig (:mod:`slmlab.virtual.rigs`) from each design
(:mod:`slmlab.virtual.designs`), against the truth floor and the best plain polynomial.

* :func:`stage_free`: the default's ratios again with the rig's stage made perfect: what the stage's errors,
  which no held-out dot or plane can see, cost it.
* :func:`random_zoo`: the default's ratios on rigs drawn at random (``KIND:SEED``), beyond the presets the
  notebook shows.
* :func:`compare_models`: a rig, a design (:mod:`slmlab.virtual.designs`) and a held-out validation set of
  random points in the calibrated volume; per coordinate RMS error (net of one common offset, in the frame
  the design calibrates in) of each model (:func:`slmlab.calibrate`), of plain least-squares polynomials of
  degree 1–4 in the four image coordinates (:class:`slmlab.models.reference.PlainPolynomial`), and of the true model on the same
  noisy centres (the floor), and in the frame the calibration's commanded positions teach it
  (:func:`commanded_frame_floor`: what the stage's errors leave to a perfect model).
"""

from __future__ import annotations

import time

import numpy as np
import pandas as pd

from ..errors import SlmlabError
from ..io import IMAGE_COLUMNS
from ..linefit import point_keys
from ..models import calibrate
from ..models.frames import world_positions
from ..models.reference import DEGREES
from ..outputs import table_digits
from ..virtual.designs import DESIGNS, design_frame, simulate_design, validation_set
from ..virtual.rig_checks import physics_checks
from ..virtual.rigs import RIG_CLASSES, random_rig
from .realrigs import rms_after_offset
from .workspace import perfect_stage

__all__ = ["MODELS", "POLY_DEGREES", "TARGETS", "FRAME_FLOOR_TARGET", "rig_table", "commanded_frame_floor",
           "compare_models", "run_zoo", "random_zoo", "ratio_table", "target_summary", "stage_free"]

MODELS = ("auto", "pinhole")
POLY_DEGREES = DEGREES


def rig_table(rigs) -> pd.DataFrame:
    """One row per rig: its kind, field and calibrated depth, the noise floor's scale and the physics checks
    (:func:`slmlab.virtual.rig_checks.physics_checks`): the projection's round trip, the defocus and astigmatism
    on the focal plane, and, behind a wall, Snell's law against Fermat's principle."""
    rows = []
    for rig in rigs:
        c = physics_checks(rig, n_points=500)
        rows.append({"rig": rig.preset, "kind": rig.kind, "field_mm": f"{c['field_w_mm']:.3g} x {c['field_h_mm']:.3g}",
                     "depth_mm": c["depth_mm"], "px_per_mm": c["px_per_mm"],
                     "round_trip_mm": c["round_trip_max_mm"],
                     "defocus_on_focal_plane_px": max(c["defocus_z0_max_px_l"], c["defocus_z0_max_px_r"]),
                     "astigmatism_px": max(c["astigmatism_z0_max_px_l"], c["astigmatism_z0_max_px_r"]),
                     "snell_vs_fermat_mm": max(c.get("snell_vs_fermat_max_mm_l", np.nan),
                                               c.get("snell_vs_fermat_max_mm_r", np.nan)),
                     "centroid_sigma_px": f"{c['centroid_sigma_px_min']:.3f}-{c['centroid_sigma_px_max']:.3f}"})
    return pd.DataFrame(rows)


def commanded_frame_floor(rig, cal, w: np.ndarray) -> np.ndarray:
    """The true model's triangulation of image points ``w`` (n, 4) [px], in the frame a perfect model of the
    optics learns from calibration set ``cal``: the best affine map (least squares over every calibration dot)
    from the true triangulation of the calibration's noisy centres to the world positions the set commands
    (:func:`slmlab.models.frames.world_positions`: the stage's commanded positions, plus the dot's place on its
    plate or target; on stage moves net of one offset per dot and sequence). Returns ``(n, 3)`` [mm], up to one
    offset.

    Every model here takes its frame from the commanded positions, and the stage puts each position a little
    elsewhere (positioning noise, lead and straightness errors, the same for every dot of a position). With few
    positions their errors tilt and stretch the frame a perfect model would learn; the floor (the true model in
    the true frame) does not see it. It is large wherever the stage errs systematically (lead, straightness),
    not only with few positions. It is not a strict floor: a model can also learn, as part of its map, the
    stage's errors that no affine map describes (on stage moves the default is below it in places). For a flat
    plate moved in depth the stage's moves are all that say where depth points. A target with depth of its
    own (a two-level plate, a stepped target) carries a frame of its own at every position, and a model that
    used it could go below this floor; the default measures each position's offset with the pinhole pair where
    it describes the rig (:mod:`slmlab.models.stage_errors`) but keeps the commanded frame, so this floor is
    also its own. The realised stage errors of this set,
    not their expectation (:func:`slmlab.studies.workspace.commanded_frame_limit` gives that for the
    microscope's sessions)."""
    pts, world, mode = world_positions(cal)
    p = rig.triangulate(pts[IMAGE_COLUMNS].to_numpy(float))
    q = rig.triangulate(np.asarray(w, float))
    if mode == "moves":  # one unknown offset per dot and sequence: centred out
        key = pd.Series(point_keys(pts["row"], pts["col"]).astype(str)) + pts["sequence"].astype(str).to_numpy()
        _, g = np.unique(key.to_numpy(), return_inverse=True)
        g, n = g.ravel(), np.bincount(g.ravel())
        centred = [a - np.stack([np.bincount(g, a[:, k]) / n for k in range(3)], axis=1)[g] for a in (p, world)]
        lin, *_ = np.linalg.lstsq(centred[0], centred[1], rcond=None)
        return q @ lin
    lin, *_ = np.linalg.lstsq(np.column_stack([p, np.ones(len(p))]), world, rcond=None)
    return np.column_stack([q, np.ones(len(q))]) @ lin


def compare_models(rig, design: str, *, seed: int = 1, models=MODELS, n_validation: int = 1500) -> pd.DataFrame:
    """Per coordinate RMS error [µm] on a held-out validation set inside the calibrated volume
    (:func:`slmlab.virtual.designs.validation_set`) of the default model calibrated on ``design``, of each of its
    candidates as fitted on the whole set (the direct and Soloff models, the plain polynomials of degree 1–4:
    ``polynomial-d``), of the other ``models`` named (``pinhole-f``: the pinhole model started from the rig's
    true focal length) and of the true model on the same noisy centres (``floor``), in the design's frame net
    of one common offset, and the same in the frame the set's commanded positions teach a perfect model
    (``frame floor``: :func:`commanded_frame_floor`). ``note``: the model's settings, or why it could not calibrate; ``chosen_for``: the
    coordinates the default took from that candidate; ``attrs["selection"]``: the default's evidence (its
    model file's ``calibration.selection``)."""
    cal = simulate_design(rig, design, seed=seed)
    val = validation_set(rig, cal, n_validation, seed=seed + 1000)
    frame = design_frame(rig, design)
    w = val.points[IMAGE_COLUMNS].to_numpy(float)
    truth = val.truth[["X_mm", "Y_mm", "Z_mm"]].to_numpy(float) @ frame.T
    origin = np.asarray(val.meta["simulator"]["stage_origin_mm"])
    rows = [("floor", rig.microscope_to_stage(rig.triangulate(w), origin) @ frame.T, "", ""),
            ("frame floor", commanded_frame_floor(rig, cal, w), "the true model in the commanded frame", "")]
    default = calibrate(cal)
    rows.append(("auto", default.reconstruct(w), default.describe(), ""))
    for label, m in getattr(default, "candidates", {}).items():
        chosen = "".join(c for c, k in zip("XYZ", default.choice) if k == label)
        rows.append((label, m.reconstruct(w), m.describe(), chosen))
    runs = [(name, name, {}) for name in models if name != "auto"]
    if "pinhole" in models:  # the pinhole model again, told the true focal length as a start (a user knows the lens)
        cam = rig.camera("l")
        runs.append(("pinhole-f", "pinhole", {"f_guess_px": float(cam.x0[2] / cam.pixel_mm)}))
    for label, name, options in runs:
        try:
            model = calibrate(cal, name, **options)
            rows.append((label, model.reconstruct(w), model.describe(), ""))
        except SlmlabError as exc:
            rows.append((label, None, f"error: {exc.reason}", ""))
    out = []
    for name, p, note, chosen in rows:
        e = 1e3 * rms_after_offset(p - truth) if p is not None else np.full(3, np.nan)
        out.append({"rig": rig.preset, "design": design, "model": name, "X_um": e[0], "Y_um": e[1], "Z_um": e[2],
                    "note": note, "chosen_for": chosen})
    table = pd.DataFrame(out)
    table.attrs["selection"] = default.calibration.get("selection", {})
    return table


def run_zoo(rigs, designs=tuple(DESIGNS), *, seed: int = 1, models=MODELS, n_validation: int = 1500) -> pd.DataFrame:
    """:func:`compare_models` for every rig and design (the pinhole model only where it applies: the
    stage-sequence design), one table; ``seconds`` the time each design took (minutes on two cores)."""
    frames = []
    for rig in rigs:
        for design in designs:
            start = time.perf_counter()
            use = models if design == "stage-sequences" else tuple(m for m in models if m != "pinhole")
            df = compare_models(rig, design, seed=seed, models=use, n_validation=n_validation)
            frames.append(df.assign(seconds=time.perf_counter() - start))
    return pd.concat(frames, ignore_index=True)


def random_zoo(seeds, kinds=tuple(RIG_CLASSES), designs=tuple(DESIGNS), *, n_validation: int = 1500) -> pd.DataFrame:
    """The default's :func:`ratio_table` on rigs drawn at random: for each of ``kinds`` and ``seeds``, the rig
    ``KIND:SEED`` (:func:`slmlab.virtual.rigs.random_rig`) calibrated from each of ``designs``, simulated with that
    seed (:func:`compare_models`, the default alone). ``rig`` names the rig as ``rig_by_name`` reads it
    (``stereo-dic:24``); ``held_out_rms_um``: the default's cross-validated error of each candidate per coordinate
    (its model file's evidence), to set beside the ratios. About 3 s per rig and design on two cores;
    :func:`target_summary` counts the cells that meet each target."""
    frames = []
    for kind in kinds:
        for seed in seeds:
            rig = random_rig(kind, int(seed))
            for design in designs:
                found = compare_models(rig, design, seed=int(seed), models=("auto",), n_validation=n_validation)
                held = found.attrs["selection"].get("held_out_rms_mm", {})
                frames.append(ratio_table(found).assign(
                    rig=f"{kind}:{seed}", held_out_rms_um="; ".join(
                        f"{k} " + "/".join(f"{1e3 * v:.3g}" for v in e) for k, e in held.items())))
    return pd.concat(frames, ignore_index=True)


def ratio_table(results: pd.DataFrame, model: str = "auto") -> pd.DataFrame:
    """Per rig and design, ``model``'s error (default: the default model) per coordinate over the noise floor
    (``{c}_vs_floor``), over the best plain polynomial of degree 1–4 chosen with hindsight on the truth
    (``{c}_vs_polynomial``) and over the best of the default's own candidates chosen the same way
    (``{c}_vs_candidates``: every candidate it fitted, the pinhole pair among them where it was one);
    ``choice``: what the default took for each coordinate. Rounded as the tables are
    written (:func:`slmlab.outputs.table_digits`), so that a target is met or missed as the table shows it: a
    ratio of 1.00004 (the chosen candidate, reconstructed beside the others) is a tie, not a loss."""
    rows = []
    for (rig, design), g in results.groupby(["rig", "design"], sort=False):
        g = g.set_index("model")
        polys = [m for m in g.index if m.startswith("polynomial-")]
        own = [m for m in g.index if m not in ("floor", "auto") and g.loc[m, "chosen_for"] is not None
               and m in polys + ["direct", "soloff", "pinhole"] and np.isfinite(g.loc[m, "X_um"])]
        row = {"rig": rig, "design": design,
               "choice": ", ".join(f"{c}: {k}" for k in own for c in str(g.loc[k, "chosen_for"] or "")
                                   if c in "XYZ") if model == "auto" else model}
        for c in "XYZ":
            v = g.loc[model, f"{c}_um"]
            row[f"{c}_um"] = v
            row[f"{c}_vs_floor"] = v / g.loc["floor", f"{c}_um"]
            if "frame floor" in g.index:
                row[f"{c}_vs_frame_floor"] = v / g.loc["frame floor", f"{c}_um"]
            row[f"{c}_vs_polynomial"] = v / g.loc[polys, f"{c}_um"].min()
            row[f"{c}_vs_candidates"] = v / g.loc[own, f"{c}_um"].min()
        rows.append(row)
    return table_digits(pd.DataFrame(rows))


#: the issue's targets for the default on every rig and design, per coordinate
TARGETS = {"vs_floor": 1.2, "vs_polynomial": 1.0, "vs_candidates": 1.05}
#: the floor's target again, against the floor in the commanded frame (:func:`commanded_frame_floor`): what is
#: left to the model once the stage's errors have had their share
FRAME_FLOOR_TARGET = 1.2


def target_summary(ratios: pd.DataFrame) -> pd.DataFrame:
    """How many rig × design × coordinate cells meet each target (:data:`TARGETS`, and
    :data:`FRAME_FLOOR_TARGET` where ``ratios`` has the floor in the commanded frame), the worst cell and the
    median ratio."""
    rows = []
    extra = {"vs_frame_floor": FRAME_FLOOR_TARGET} if "X_vs_frame_floor" in ratios else {}
    for key, limit in {**TARGETS, **extra}.items():
        cells = ratios.melt(id_vars=["rig", "design"], value_vars=[f"{c}_{key}" for c in "XYZ"])
        worst = cells.loc[cells["value"].idxmax()]
        rows.append({"ratio": key, "target": limit, "cells": len(cells),
                     "met": int((cells["value"] <= limit * (1 + 1e-9)).sum()),
                     "median": float(cells["value"].median()), "worst": float(worst["value"]),
                     "worst_at": f"{worst['rig']}, {worst['design']}, {worst['variable'][0]}"})
    return pd.DataFrame(rows)


def stage_free(rig, designs, *, seed: int = 1, n_validation: int = 1500, as_built: pd.DataFrame | None = None
               ) -> pd.DataFrame:
    """The default's :func:`ratio_table` on ``rig`` as built and with its stage made perfect (no scale, lead,
    straightness or positioning errors: :func:`slmlab.studies.workspace.perfect_stage`; the optics, the dots'
    noise and the seeds unchanged), for each of ``designs``; column ``stage``: ``"as built"`` or
    ``"perfect"``. Every dot of a stage position shares that position's error, so neither a held-out dot
    nor a held-out plane of a set with few positions tells it from the optics: this shows what it costs.
    ``as_built``: the rig's rows of an earlier :func:`ratio_table` (same seed and validation size), not
    computed again."""
    designs = list(designs)
    if as_built is None or not set(designs) <= set(as_built.loc[as_built["rig"] == rig.preset, "design"]):
        as_built = ratio_table(run_zoo([rig], designs, seed=seed, models=("auto",), n_validation=n_validation))
    built = as_built[(as_built["rig"] == rig.preset) & as_built["design"].isin(designs)]
    perfect = ratio_table(run_zoo([perfect_stage(rig)], designs, seed=seed, models=("auto",), n_validation=n_validation))
    out = pd.concat([built.assign(stage="as built"), perfect.assign(stage="perfect")], ignore_index=True)
    return out[["stage", *built.columns]]
