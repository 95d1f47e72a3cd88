"""Studies of real rigs and known targets (notebook 10): images as a camera wrote them, to 3D.

* :func:`extraction_vs_picks`: extracted dot centres beside the centres someone else picked on the same
  images (the PIV Challenge's UVMAT point lists);
* :func:`compare_on_planes`: calibrations on some planes of a Z stack, errors on the others;
* :func:`twin_limit`: what any model could reach on a rig whose only error is the picks' own scatter, by a
  simulated twin of it (the true map known);
* :func:`charuco_stack`: a ChArUco board Z stack through the virtual microscope, extracted and calibrated;
* :func:`known_targets`: known 3D targets in one pose, with and without stage moves, and the pinhole model on one.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from ..images.imageset import extract_set
from ..io import IMAGE_COLUMNS, CalibrationSet, read_set, write_csv
from ..models import calibrate
from ..models.frames import dot_labels, plate_xy, world_positions
from ..models.soloff import SoloffModel, fit_soloff
from ..virtual.render import board_orientation, render_board_set
from ..virtual.sessions import Session, zstack_frame
from ..virtual.simulate import stage_origin, stepped_target, target_set
from .workspace import volumetric_comparison

__all__ = ["extraction_vs_picks", "dots_per_image", "compare_on_planes", "twin_limit", "charuco_stack",
           "known_targets", "rms_after_offset", "measure_level_offset"]

VIEWS = (("l", "u1_px", "v1_px", "left"), ("r", "u2_px", "v2_px", "right"))


def rms_after_offset(e: np.ndarray) -> np.ndarray:
    """RMS per coordinate of errors ``(n, 3)`` after removing their mean (one common offset) [same unit]."""
    e = np.asarray(e, float)
    return np.sqrt(np.mean((e - e.mean(axis=0)) ** 2, axis=0))


def extraction_vs_picks(points: pd.DataFrame, picks: pd.DataFrame, *, within_px: float = 1.5):
    """Extracted centres (``points``: ``x_mm, y_mm, stage_z_mm`` and ``wl1 … wr2``) beside picked ones
    (``picks``: ``X_mm, Y_mm, Z_mm, u1_px, v1_px, u2_px, v2_px``, slmlab's pixel convention), matched by the
    plate position. Returns a summary per view (picks, found within ``within_px``, RMS and mean difference
    [px], largest) and the differences ``view, X_mm, Y_mm, Z_mm, du_px, dv_px`` (pick minus extracted)."""
    rows, diffs = [], []
    for side, u, v, name in VIEWS:
        p = picks.dropna(subset=[u]).merge(points.dropna(subset=[f"w{side}1"]), how="left",
                                           left_on=["X_mm", "Y_mm", "Z_mm"], right_on=["x_mm", "y_mm", "stage_z_mm"])
        du, dv = p[u] - p[f"w{side}1"], p[v] - p[f"w{side}2"]
        ok = np.hypot(du, dv) < within_px
        rows.append({"view": name, "picks": len(p), "found_within_px": int(ok.sum()),
                     "found_percent": 100.0 * ok.mean(),
                     "rms_difference_px": float(np.sqrt(np.mean(np.r_[du[ok], dv[ok]] ** 2))),
                     "mean_du_px": float(du[ok].mean()), "mean_dv_px": float(dv[ok].mean()),
                     "largest_px": float(np.hypot(du, dv)[ok].max())})
        diffs.append(pd.DataFrame({"view": name, "X_mm": p["X_mm"], "Y_mm": p["Y_mm"], "Z_mm": p["Z_mm"],
                                   "du_px": du, "dv_px": dv})[ok.to_numpy()])
    summary = pd.DataFrame(rows)
    both = pd.concat(diffs, ignore_index=True)
    total = {"view": "both", "picks": int(summary["picks"].sum()), "found_within_px": int(summary["found_within_px"].sum()),
             "found_percent": 100.0 * summary["found_within_px"].sum() / summary["picks"].sum(),
             "rms_difference_px": float(np.sqrt(np.mean(np.r_[both["du_px"], both["dv_px"]] ** 2))),
             "mean_du_px": float(both["du_px"].mean()), "mean_dv_px": float(both["dv_px"].mean()),
             "largest_px": float(np.hypot(both["du_px"], both["dv_px"]).max())}
    return pd.concat([summary, pd.DataFrame([total])], ignore_index=True), both


def dots_per_image(points: pd.DataFrame) -> pd.DataFrame:
    """Dots found per stage position and view, in both views, and per level where a plate has two."""
    g = points.groupby(["sequence", "position"], sort=False)
    out = pd.DataFrame({"left": g["wl1"].count(), "right": g["wr1"].count(),
                        "both": g.apply(lambda d: int(d[IMAGE_COLUMNS].notna().all(axis=1).sum()), include_groups=False)})
    if "level" in points.columns:
        lv = pd.to_numeric(points["level"])
        for k in sorted(lv.dropna().unique()):
            out[f"level_{int(k)}"] = points[lv == k].groupby(["sequence", "position"], sort=False).size()
    return out.fillna(0).astype(int).reset_index()


def _truth(cal: CalibrationSet, rows: pd.DataFrame) -> np.ndarray:
    if cal.known_target:
        return cal.world(rows)
    xy = plate_xy(rows["row"], rows["col"], cal.plate(rows["sequence"].iloc[0])) + rows[["stage_x_mm", "stage_y_mm"]].to_numpy()
    return np.column_stack([xy, rows["stage_z_mm"].to_numpy()])


def compare_on_planes(cal: CalibrationSet, variants: dict, calibrate_on, check: CalibrationSet | None = None,
                      check_on=None, reference: str | None = None) -> pd.DataFrame:
    """Each variant (``{label: calibrate options}``, e.g. ``{"model": "soloff"}``) calibrated on the
    positions ``calibrate_on`` of ``cal``, checked on the positions ``check_on`` of ``check`` (default: the
    other positions of ``cal``) against their known world positions: RMS per coordinate [µm] after one common
    offset, the model's settings, and each coordinate's ratio to the ``reference`` variant's."""
    check = cal if check is None else check
    train = CalibrationSet(cal.points[cal.points["position"].isin(list(calibrate_on))].copy(), cal.meta, path=cal.path)
    test = check.points[~check.points["position"].isin(list(calibrate_on)) if check_on is None
                        else check.points["position"].isin(list(check_on))]
    test = test.dropna(subset=IMAGE_COLUMNS)
    truth = _truth(check, test)
    keep = np.isfinite(truth).all(axis=1)
    test, truth = test[keep], truth[keep]
    rows = []
    for label, options in variants.items():
        model = calibrate(train, **options)
        e = model.reconstruct(test[IMAGE_COLUMNS].to_numpy(float)) - truth
        r = 1e3 * rms_after_offset(e)
        rows.append({"model": label, "settings": model.describe(), **{f"{c}_um": r[k] for k, c in enumerate("XYZ")}})
    out = pd.DataFrame(rows)
    if reference is not None:
        ref = out.set_index("model").loc[reference]
        for c in "XYZ":
            out[f"{c}_vs_reference"] = out[f"{c}_um"] / ref[f"{c}_um"]
    return out


def twin_limit(picks: CalibrationSet, calibrate_on, check_on, *, replicas: int = 20, seed: int = 0,
               variants: dict | None = None) -> pd.DataFrame:
    """What a model can reach on a rig like this one, whose only error is the picks' own scatter: a simulated
    twin. Its true map is a Soloff polynomial (cubic in X, Y, quadratic in Z) fitted to all the picks; its
    picks are that map's image coordinates plus Gaussian noise of the scatter measured within dots across
    planes on the real picks. Each replica calibrates every variant on ``calibrate_on`` and checks it on
    ``check_on`` (RMS after one offset); the **oracle** reconstructs the checks with the true map itself
    (weighted least squares on the four equations, the lowest error possible). Returns, per variant, the
    mean RMS [µm] per coordinate over the replicas and its ratio to the reference (the first variant)."""
    pts, world, _ = world_positions(picks)
    w_real = pts[IMAGE_COLUMNS].to_numpy(float)
    truth_map = SoloffModel(fit_soloff(world, w_real, 3, 2, dots=dot_labels(pts)))
    sigma = np.sqrt(np.maximum(truth_map.noise_poly[:, 0], 1e-12))
    w_true = truth_map.project(world)
    variants = variants or {"quadratic (reference)": {"model": "quadratic"}, "default": {}}
    rng = np.random.default_rng(seed)
    acc: dict[str, list] = {k: [] for k in [*variants, "oracle (the true map)"]}
    cal_rows = pts["position"].isin(list(calibrate_on)).to_numpy()
    chk_rows = pts["position"].isin(list(check_on)).to_numpy()
    for _ in range(replicas):
        w = w_true + rng.normal(size=w_true.shape) * sigma
        sim = pts.copy()
        sim[IMAGE_COLUMNS] = w
        train = CalibrationSet(sim[cal_rows].copy(), picks.meta)
        for label, options in variants.items():
            e = calibrate(train, **options).reconstruct(w[chk_rows]) - world[chk_rows]
            acc[label].append(1e3 * rms_after_offset(e))
        acc["oracle (the true map)"].append(1e3 * rms_after_offset(truth_map.reconstruct(w[chk_rows]) - world[chk_rows]))
    rows = [{"model": k, **{f"{c}_um": float(np.mean(v, axis=0)[n]) for n, c in enumerate("XYZ")}} for k, v in acc.items()]
    out = pd.DataFrame(rows)
    ref = out.iloc[0]
    for c in "XYZ":
        out[f"{c}_vs_reference"] = out[f"{c}_um"] / ref[f"{c}_um"]
    out.attrs["noise_px"] = sigma
    return out


def charuco_stack(microscope, board: dict, calibrate_z_mm, check_z_mm, folder: str | Path, *, seed: int = 1):
    """A ChArUco board Z stack through the virtual microscope, written to ``folder``, extracted (OpenCV's
    detector), calibrated with the default model as a known target, and checked on a second stack at other
    depths. Returns ``(table, sets)``: the corners found and their RMS error against the rendered truth [px],
    and the check's RMS error [µm] per coordinate and over the noise floor (the true model triangulating the
    same extracted corners), both in the board's frame; ``sets`` the two calibration sets."""
    folder = Path(folder)
    sets, merged = {}, {}
    for name, z, s in (("calibration", calibrate_z_mm, seed), ("check", check_z_mm, seed + 1)):
        d = render_board_set(folder / name, microscope, board, z, seed=s)
        pts, _ = extract_set(d, progress=False)
        write_csv(d / "points.csv", pts)
        sets[name] = read_set(d)
        truth = pd.read_csv(d / "truth.csv")
        merged[name] = pts.merge(truth, on=["sequence", "position", "row", "col"], how="right", suffixes=("", "_t"))
    rows = []
    for name, m in merged.items():
        e = np.concatenate([(m[c] - m[c + "_t"]).to_numpy() for c in IMAGE_COLUMNS])
        rows.append({"stack": name, "planes": int(m["position"].nunique()), "corners": len(m),
                     "found_percent": 100.0 * m[IMAGE_COLUMNS].notna().all(axis=1).mean(),
                     "corner_rms_px": float(np.sqrt(np.nanmean(e ** 2))), "corner_max_px": float(np.nanmax(np.abs(e)))})
    model = calibrate(sets["calibration"])
    check = merged["check"].dropna(subset=IMAGE_COLUMNS)
    frame = zstack_frame(microscope, orientation=board_orientation(microscope))
    origin = stage_origin(microscope, Session(positions=(0, 0, 0), grid=False))
    w = check[IMAGE_COLUMNS].to_numpy(float)
    truth = check[["X_mm", "Y_mm", "Z_mm"]].to_numpy() @ frame.T
    floor = 1e3 * rms_after_offset(microscope.microscope_to_stage(microscope.triangulate(w), origin) @ frame.T - truth)
    ours = 1e3 * rms_after_offset(model.reconstruct(w) - truth)
    table = pd.DataFrame(rows)
    calib = pd.DataFrame([{"model": model.describe(), **{f"{c}_um": ours[k] for k, c in enumerate("XYZ")},
                           **{f"{c}_floor_um": floor[k] for k, c in enumerate("XYZ")},
                           **{f"{c}_vs_floor": ours[k] / floor[k] for k, c in enumerate("XYZ")}}])
    return table, calib, sets


def known_targets(microscope, val, *, seed: int = 3) -> pd.DataFrame:
    """Known 3D targets calibrating the default model: a stepped target (five heights over ±1 mm) in one pose,
    a two-level plate (rows 0.6 mm apart) in one pose, and the stepped target at three stage Z positions; then
    the pinhole model (OpenCV, from a DLT: :mod:`slmlab.models.pinhole`) on the stepped target in one pose. RMS
    displacement error over the noise floor on the volume run ``val``, per coordinate."""
    lattice = stepped_target(steps_mm=(0.0,))
    cases = {"stepped target, one pose": (stepped_target(), [[0.0, 0.0, 0.0]]),
             "two-level plate, one pose": (lattice.assign(z_mm=np.where(lattice["row"] % 2 == 0, -0.6, 0.0)),
                                           [[0.0, 0.0, 0.0]]),
             "stepped target at 3 stage Z positions": (stepped_target(), [[0.0, 0.0, z] for z in (-0.5, 0.0, 0.5)])}
    sets = {label: target_set(microscope, target, stage, seed=seed) for label, (target, stage) in cases.items()}
    runs = [(label, calibrate(cal)) for label, cal in sets.items()]
    runs.append(("stepped target, one pose (pinhole)", calibrate(sets["stepped target, one pose"], "pinhole")))
    rows = []
    for label, model in runs:
        t = volumetric_comparison({label: model}, val).set_index("model").loc[label]
        rows.append({"calibration": label, "model": model.describe(),
                     **{f"{c}_vs_floor": float(t[f"{c}_vs_floor"]) for c in "XYZ"}})
    return pd.DataFrame(rows)


def measure_level_offset(points: pd.DataFrame, model) -> dict:
    """The depth of a two-level plate's second level in its frame [mm], measured from a Z stack: every
    extracted dot seen in both views (``level`` 0 or 1) is reconstructed by ``model`` (calibrated on the first
    level, whose z is 0), and per plane the median Z of the second level's dots less that of the first's is
    one estimate. Planes where the second level would leave the calibrated depth range (extrapolation) are
    left out, after a first estimate from all planes. Returns ``offset_mm`` (the median over planes),
    ``spread_mm`` (their standard deviation), ``planes`` (per-plane values) and ``dots`` per level."""
    both = points.dropna(subset=["wl1", "wl2", "wr1", "wr2"])
    if "level" not in both.columns or not (both["level"] == 1).any():
        raise ValueError("no second-level dots: extract a two-level plate (plates.moving.levels = 2)")
    z = model.reconstruct(both[["wl1", "wl2", "wr1", "wr2"]].to_numpy(float))[:, 2]
    both = both.assign(Z=z)
    per = both.groupby(["position", "level"])["Z"].median().unstack("level").dropna()
    stage = both.groupby("position")["stage_z_mm"].first().loc[per.index]
    d = per[1] - per[0]
    first = float(np.median(d))
    lo, hi = float(both.loc[both["level"] == 0, "stage_z_mm"].min()), float(both.loc[both["level"] == 0, "stage_z_mm"].max())
    inside = (stage + first >= lo) & (stage + first <= hi)
    use = d[inside] if inside.sum() >= 2 else d
    return {"offset_mm": float(np.median(use)), "spread_mm": float(np.std(use, ddof=1)) if len(use) > 1 else float("nan"),
            "planes": {int(k): float(v) for k, v in use.items()},
            "dots": {int(k): int(v) for k, v in both["level"].value_counts().sort_index().items()}}
