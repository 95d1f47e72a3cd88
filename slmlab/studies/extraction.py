"""Extraction accuracy against the truth of rendered sets: every rendered dot's extracted centre beside the
true one, found and correctly numbered shares, and the error against defocus (notebook 02, the virtual CMO
microscope); and the zoo's rigs under every degradation a real camera adds (notebook 11,
:func:`extraction_by_degradation`)."""

from __future__ import annotations

import re
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.spatial import cKDTree

from ..errors import SlmlabError
from ..io import KEY_COLUMNS, CalibrationSet, read_set, write_set
from ..images.centres import METHODS
from ..images.dots import read_image
from ..images.extract import extract_image_methods
from ..images.imageset import TRACKED, extract_set
from ..virtual.designs import simulate_design
from ..virtual.floor import rendered_floors
from ..virtual.microscope import from_dict
from ..virtual.render import DEGRADATIONS, render_rig_set, rendered_truth, rig_degradations, set_camera
from ..virtual.sessions import Session
from ..virtual.simulate import simulate_set

__all__ = ["extraction_errors", "extraction_summary", "extract_folder", "error_by_defocus", "measured_centres",
           "rig_extraction_errors", "plate_in_view_set", "extraction_by_degradation"]


def extraction_errors(points: pd.DataFrame, cal) -> pd.DataFrame:
    """Extracted centres against a simulated set's truth: one row per dot and view seen in the truth image.

    Columns: ``sequence, position, row, col, view, z_mm`` (height above the focal plane), ``visible`` (the whole
    dot is inside the image), ``found`` (extracted and indexed at this ``[row, col]``), ``err1, err2`` [px]
    (extracted minus true centre). A dot indexed at the wrong place shows as a large error. A set rendered on a
    zoo rig goes to :func:`rig_extraction_errors`.
    """
    sim = cal.meta["simulator"]
    if "rig" in sim["microscope"]:
        return rig_extraction_errors(points, cal)
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
    """Per-dot extraction errors of a rendered simulated set for several centre methods (by default every one of
    :data:`slmlab.images.centres.METHODS`: moments, ellipse, edges, the model fit and the point of symmetry),
    each image's dots found once and refined by each (:func:`slmlab.images.extract.extract_image_methods`).

    Returns :func:`extraction_errors` rows of the chosen sequences with a ``method`` column (for the error
    against defocus figure and the choice of the default method).
    """
    set_dir = Path(set_dir)
    cal = read_set(set_dir)
    rows = {m: [] for m in methods}
    for seq in sequences:
        plate = cal.plate(seq)
        for pos in sorted(cal.sequence(seq)["position"].unique()):
            for side in "lr":
                img = read_image(set_dir / "images" / f"{seq}_{pos:03d}_{side}.png")
                found = extract_image_methods(img, int(plate["rows"]), int(plate["cols"]), methods=methods)
                for method, dots in found.items():
                    t = dots.table.rename(columns={"w1": f"w{side}1", "w2": f"w{side}2"})
                    t = t[["row", "col", f"w{side}1", f"w{side}2"]]
                    t.insert(0, "sequence", seq)
                    t.insert(1, "position", pos)
                    rows[method].append(t.set_index(["sequence", "position", "row", "col"]))
    sub = cal.truth["sequence"].isin(sequences)
    frames = []
    for method in methods:
        pts = pd.concat(rows[method]).groupby(level=[0, 1, 2, 3]).first().reset_index()
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


# ------------------------------------------------------------------------------------------ any rig
def _symmetries(rows: int, cols: int) -> list:
    """The maps ``(row, col) → (row, col)`` of a ``rows × cols`` plate onto itself (4, or 8 if square): a
    plate numbered by its size alone is numbered up to them (``[1, 1]`` at the image's top left)."""
    maps = [lambda r, c: (r, c), lambda r, c: (rows + 1 - r, c), lambda r, c: (r, cols + 1 - c),
            lambda r, c: (rows + 1 - r, cols + 1 - c)]
    if rows == cols:
        maps += [lambda r, c: (c, r), lambda r, c: (rows + 1 - c, r), lambda r, c: (c, cols + 1 - r),
                 lambda r, c: (rows + 1 - c, cols + 1 - r)]
    return maps


def _view_errors(ext: pd.DataFrame, truth: pd.DataFrame, plate: dict) -> pd.DataFrame:
    """One view's truth rows with the extracted centre of the dot numbered as each (``err1, err2`` [px],
    ``found``). A board's corners are matched by their ids (``row, col``), a known target's dots by their place
    on it (``x_mm, y_mm``); a plate numbered by
    its size by the one symmetry of the plate (:func:`_symmetries`) that puts most of them within a pixel of
    their truth: the simulator numbers ``[1, 1]`` at the plate's ``+x, +y``, the extractor at the image's top
    left, and which symmetry that is depends on the rig's view, not on the extraction."""
    key = ["sequence", "position"]
    if plate.get("pattern", "dots") != "dots":         # a board numbers its corners by its own ids
        m = truth.merge(ext[key + ["row", "col", "e1", "e2"]], how="left", on=key + ["row", "col"])
    elif "x_mm" in truth.columns:
        cols = key + ["x_mm", "y_mm"]
        m = truth.merge(ext[cols + ["e1", "e2"]].round({"x_mm": 6, "y_mm": 6}), how="left",
                        on=cols, validate="one_to_one") if len(ext) else truth.assign(e1=np.nan, e2=np.nan)
    else:
        best = None
        for f in _symmetries(int(plate["rows"]), int(plate["cols"])):
            r, c = f(ext["row"].to_numpy(), ext["col"].to_numpy())
            cand = truth.merge(ext[key].assign(row=r, col=c, e1=ext["e1"].to_numpy(), e2=ext["e2"].to_numpy()),
                               how="left", on=key + ["row", "col"])
            good = int((np.hypot(cand["e1"] - cand["w1"], cand["e2"] - cand["w2"]) < 1.0).sum())
            if best is None or good > best[0]:
                best = (good, cand)
        m = best[1]
    m["found"] = m[["e1", "e2"]].notna().all(axis=1)
    m["err1"], m["err2"] = m["e1"] - m["w1"], m["e2"] - m["w2"]
    return m.drop(columns=["e1", "e2"])


def rig_extraction_errors(points: pd.DataFrame, cal: CalibrationSet) -> pd.DataFrame:
    """:func:`extraction_errors` of a set rendered on a zoo rig (:func:`slmlab.virtual.render.render_rig_set`):
    one row per dot and view of the rendered truth (:func:`slmlab.virtual.render.rendered_truth`: ``visible``
    for the camera it was rendered with, ``z_mm`` in the rig frame), ``found`` and ``err1, err2`` [px] of the
    dot extracted at its number (:func:`_view_errors`), and ``spacing_px``: its distance to the nearest other
    dot in that image (a centre farther than 0.3 of it is another dot: the dot is misnumbered)."""
    truth = rendered_truth(cal)
    frames = []
    for side in "lr":
        t = truth[truth["view"] == side].reset_index(drop=True)
        e = points.dropna(subset=[f"w{side}1"]).rename(columns={f"w{side}1": "e1", f"w{side}2": "e2"})
        plate = cal.meta["plates"]["moving"]
        frames.append(_view_errors(e, t, plate))
    out = pd.concat(frames, ignore_index=True)
    out["spacing_px"] = np.nan
    for _, idx in out.groupby(["sequence", "position", "view"]).indices.items():
        w = out.loc[idx, ["w1", "w2"]].to_numpy()
        out.loc[idx, "spacing_px"] = cKDTree(w).query(w, k=2)[0][:, 1] if len(w) > 1 else np.nan
    return out


def _degradation_row(errors: pd.DataFrame, floor: pd.DataFrame) -> dict:
    """One row of :func:`extraction_by_degradation` from :func:`rig_extraction_errors` and the set's
    :func:`slmlab.virtual.floor.rendered_floors`."""
    vis = errors[errors["visible"]].merge(floor, on=["sequence", "position", "view", "row", "col"], how="left",
                                          validate="many_to_one")
    dist = np.hypot(vis["err1"], vis["err2"])
    good = vis["found"] & (dist < 0.3 * vis["spacing_px"])
    e = np.r_[vis.loc[good, "err1"], vis.loc[good, "err2"]]
    f = np.r_[vis.loc[good, "floor1_px"], vis.loc[good, "floor2_px"]]
    light = np.r_[vis.loc[good, "light_floor1_px"], vis.loc[good, "light_floor2_px"]]
    return {"images": int(vis.groupby(["sequence", "position", "view"]).ngroups), "visible_dots": int(len(vis)),
            "found_percent": float(100 * good.mean()) if len(vis) else float("nan"),
            "misnumbered": int((vis["found"] & ~good).sum()),
            "rms_px": float(np.sqrt(np.mean(e ** 2))) if len(e) else float("nan"),
            "floor_px": float(np.sqrt(np.mean(f ** 2))) if len(f) else float("nan"),
            "light_floor_px": float(np.sqrt(np.mean(light ** 2))) if len(light) else float("nan"),
            "max_px": float(dist[good].max()) if good.any() else float("nan")}


def plate_in_view_set(rig, seed: int = 1) -> CalibrationSet:
    """The rig's own moving plate (whole in view, with room around it: :func:`slmlab.virtual.rigs.with_plates`) at
    two stage Z positions ``±depth/2``: what :func:`extraction_by_degradation` renders by default."""
    d = rig.depth_mm()
    session = Session(step_mm=(0.0, 0.0, d), positions=(0, 0, 2), grid=False, name="plate in view, 2 Z positions")
    return simulate_set(rig, session, seed=seed)


def _extract_degraded(cal: CalibrationSet, folder: Path, camera, method: str) -> tuple:
    """A set rendered with ``camera`` into ``folder`` and extracted as a user would: its
    :func:`rig_extraction_errors`, ``extract``'s notes (one, ``not extracted: ...``, where it refused) and the
    rendered set as read back."""
    d = write_set(folder, cal)
    render_rig_set(cal, d, camera, progress=False, compress=False)
    rendered = read_set(d)
    try:
        pts, notes = extract_set(d, method=method, progress=False)
    except SlmlabError as exc:
        pts, notes = rendered.points.iloc[:0], [f"not extracted: {exc.reason}"]
    return rig_extraction_errors(pts, rendered), notes, rendered


def extraction_by_degradation(rigs, degradations=tuple(DEGRADATIONS), *, design: str | None = None, seed: int = 1,
                              method: str = "auto", folder: str | Path | None = None) -> pd.DataFrame:
    """Extraction on every rig of the zoo under every degradation (:data:`slmlab.virtual.render.DEGRADATIONS`):
    each rig's set simulated once (``design``, :func:`slmlab.virtual.designs.simulate_design`, or by default its
    moving plate whole in view at two Z positions, :func:`plate_in_view_set`), rendered with each degradation
    (:func:`slmlab.virtual.render.render_rig_set`, PNG stored uncompressed: written to be read back at once) into
    ``folder`` (a temporary one by default), extracted as a user would (:func:`slmlab.images.imageset.extract_set`,
    ``method``) and held against the truth (:func:`rig_extraction_errors`). One row per degradation and rig:

    * ``images``, ``visible_dots`` (whole in the image, above a text strip);
    * ``found_percent`` (found and numbered as the truth, within 0.3 of the dot spacing), ``misnumbered``;
    * ``rms_px`` (per coordinate) and ``max_px`` (the largest centre error) of the found dots, and ``floor_px``,
      the RMS of their Cramér-Rao floors per coordinate (:func:`slmlab.virtual.floor.rendered_floors`: what no
      estimator can beat under that camera's noise), and ``light_floor_px``, the same with the dots' light unknown
      (each dot's contrast and a plane of background under it: what an estimator that measures them from the
      dot's own pixels cannot beat);
    * the centre ``method``: each view's choice and any image's other one (the runner-up where the fit lost dots
      there, the fit where the chosen one dropped dots the fit kept; :func:`slmlab.images.imageset.extract_set`),
      ``tracked_images``: how many images could not be numbered alone and were tracked by the stage motion of the
      images that were (:func:`slmlab.images.tracking.track`; where that is ambiguous the image is left out), and
      ``note``: why a set could not be extracted
      (``extract``'s one-line error; then nothing is found)."""
    if folder is None:  # a temporary folder, removed afterwards
        with tempfile.TemporaryDirectory(prefix="slmlab-extraction-") as tmp:
            return extraction_by_degradation(rigs, degradations, design=design, seed=seed, method=method, folder=tmp)
    base = Path(folder)
    base.mkdir(parents=True, exist_ok=True)
    rows = []
    for rig in rigs:
        cal = plate_in_view_set(rig, seed) if design is None else simulate_design(rig, design, seed=seed)
        done = [_extract_degraded(cal, base / f"{rig.preset}-{k:02d}", rig_degradations(rig.kind, name), method)
                for k, name in enumerate(degradations)]
        floors = rendered_floors(done[0][2], [set_camera(rendered) for _, _, rendered in done]) if done else []
        for name, (errors, notes, _), floor in zip(degradations, done, floors):
            chosen = sorted({n.split("centres by ")[1].split(" ")[0] for n in notes if "centres by " in n})
            tracked = sum(int(k) for n in notes for k in re.findall(re.escape(TRACKED) + r" \((\d+)\)", n))
            rows.append({"degradation": name, "rig": rig.preset, **_degradation_row(errors, floor),
                         "method": "/".join(chosen) or method, "tracked_images": tracked,
                         "note": next((n for n in notes if n.startswith("not extracted")), "")})
    return pd.DataFrame(rows)
