"""Beyond the paper: the default model against the noise floor over the whole workspace (notebook 09).

Random stage positions filling the validation's volume (not only the three axes), what each of the stage's
errors costs, calibration from a Z stack alone, per-point uncertainty and its coverage, mrcal-style
cross-validation differences, and accuracy against the number of calibration positions. Every study draws
its sets from the virtual microscope with seeds derived from one base seed.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd
from scipy.stats import norm

from ..io import IMAGE_COLUMNS, CalibrationSet
from ..models import calibrate
from ..models.frames import plate_xy
from ..paper.chain import displacements
from ..virtual.microscope import Microscope
from ..virtual.sessions import paper_test, volume_session, zstack_frame, zstack_plate, zstack_session
from ..virtual.simulate import noise_floor, simulate_set

__all__ = ["volume_rows", "volume_run", "volumetric_comparison", "uncertainty_coverage", "volumetric_errors",
           "STAGE_ERRORS", "perfect_stage", "stage_error_budget", "zstack_comparison", "leave_one_plane_out",
           "leave_one_plane_out_summary",
           "workspace_grid", "cross_validation_diff", "cross_validation_summary", "subsample_positions", "accuracy_vs_positions",
           "commanded_frame_limit", "reconstruction_against_truth"]


def volume_rows(val) -> pd.DataFrame:
    """The volume run's ``V`` rows seen in both views."""
    return val.points[val.points["sequence"] == "V"].dropna(subset=["wl1", "wl2", "wr1", "wr2"])


def volume_run(microscope: Microscope, n_volume: int, seed: int):
    """The volume run of the studies below (``n_volume`` random positions), seeded from ``seed``."""
    return simulate_set(microscope, volume_session(n_volume, seed=seed + 4), seed=seed + 6)


def volumetric_comparison(models: dict, val, frame: np.ndarray | None = None) -> "pd.DataFrame":
    """RMS displacement error [µm] per coordinate on a volumetric run ``V`` (relative to its position 1,
    against the truth) for each model ``{name: model}`` and for the simulator's own true-model
    triangulation (the noise floor). ``frame``: a 3 × 3 matrix taking stage-frame displacements to the
    models' frame (for a Z-stack calibration, :func:`slmlab.virtual.sessions.zstack_frame`)."""
    v = volume_rows(val)
    m = np.eye(3) if frame is None else np.asarray(frame, float)
    truth = val.truth.loc[v.index, ["X_mm", "Y_mm", "Z_mm"]].to_numpy() @ m.T
    dt, _, _ = displacements(v, truth)
    w = v[["wl1", "wl2", "wr1", "wr2"]].to_numpy(float)
    rows = []
    floor = noise_floor(val)[val.points.index.get_indexer(v.index)] @ m.T
    for name, p in [("noise floor (true model)", floor)] + [(n, m.reconstruct(w)) for n, m in models.items()]:
        dp, _, _ = displacements(v, p)
        e = 1e3 * np.sqrt(np.mean((dp - dt) ** 2, axis=0))
        rows.append({"model": name, "X_um": e[0], "Y_um": e[1], "Z_um": e[2]})
    df = pd.DataFrame(rows)
    f = df.iloc[0]
    for c in ("X", "Y", "Z"):
        df[f"{c}_vs_floor"] = df[f"{c}_um"] / f[f"{c}_um"]
    return df


def uncertainty_coverage(model, val, share: float = 95.0, frame: np.ndarray | None = None) -> dict:
    """Share [%] of absolute errors (after removing the frame's constant offset) inside the model's
    ``share`` % intervals, per coordinate, on the run's V sequence (``frame`` as in
    :func:`volumetric_comparison`)."""
    v = volume_rows(val)
    w = v[["wl1", "wl2", "wr1", "wr2"]].to_numpy(float)
    m = np.eye(3) if frame is None else np.asarray(frame, float)
    e = model.reconstruct(w) - val.truth.loc[v.index, ["X_mm", "Y_mm", "Z_mm"]].to_numpy() @ m.T
    e -= e.mean(axis=0)
    z = norm.ppf(0.5 + share / 200)
    inside = np.abs(e) <= z * model.uncertainty(w)
    return {c: float(100 * inside[:, k].mean()) for k, c in enumerate("XYZ")}


def volumetric_errors(models: dict, val, frames: dict | None = None, *, floor: bool = True) -> dict:
    """Per sample of V: the stage Z of the position and the displacement error magnitude [µm], per model
    (``frames``: per model name, a matrix as in :func:`volumetric_comparison`), first the noise floor's (the
    simulator's true-model triangulation of the same centres) where ``floor``."""
    v = volume_rows(val)
    truth0 = val.truth.loc[v.index, ["X_mm", "Y_mm", "Z_mm"]].to_numpy()
    w = v[["wl1", "wl2", "wr1", "wr2"]].to_numpy(float)
    recon = {"noise floor (true model)": noise_floor(val)[val.points.index.get_indexer(v.index)]} if floor else {}
    recon.update({name: m.reconstruct(w) for name, m in models.items()})
    out = {}
    for name, p in recon.items():
        frame = (frames or {}).get(name)
        truth = truth0 if frame is None else truth0 @ np.asarray(frame).T
        dt, _, keep = displacements(v, truth)
        z = v["stage_z_mm"].to_numpy()[keep]
        dp, _, _ = displacements(v, p)
        out[name] = pd.DataFrame({"Z_mm": z, "error_um": 1e3 * np.linalg.norm(dp - dt, axis=1)})
    return out


STAGE_ERRORS = ("scale_error", "lead_error_um", "straightness_um", "positioning_noise_um")


def perfect_stage(microscope: Microscope, keep: tuple[str, ...] = ()) -> Microscope:
    """The microscope with a stage free of scale, lead, straightness and positioning errors, except those
    named in ``keep`` (its axes' skew and tilts stay: they are part of the stage frame)."""
    st = microscope.stage
    zero = {"scale_error": (0.0, 0.0, 0.0), "lead_error_um": 0.0, "straightness_um": (0.0, 0.0, 0.0),
            "positioning_noise_um": 0.0}
    return replace(microscope, stage=replace(st, **{k: v for k, v in zero.items() if k not in keep}))


def stage_error_budget(microscope: Microscope, n_volume: int, seed: int = 1) -> pd.DataFrame:
    """What each of the stage's errors costs the default model: calibrated on Test 1 and validated on a
    volume run, with the stage perfect, with one error at a time, and with all of them. Per row: the RMS
    displacement error over the noise floor per coordinate and the 95 % intervals' coverage [%]."""
    cases = [("perfect stage", ())] + [(f"only {k}", (k,)) for k in STAGE_ERRORS] + [("all (paper preset)", STAGE_ERRORS)]
    rows = []
    for label, keep in cases:
        m = perfect_stage(microscope, keep)
        cal = simulate_set(m, paper_test(1), seed=seed)
        val = volume_run(m, n_volume, seed)
        model = calibrate(cal)
        t = volumetric_comparison({"direct": model}, val).set_index("model").loc["direct"]
        cov = uncertainty_coverage(model, val)
        rows.append({"stage": label, **{f"{c}_vs_floor": t[f"{c}_vs_floor"] for c in "XYZ"},
                     **{f"{c}_coverage_percent": cov[c] for c in "XYZ"}})
    return pd.DataFrame(rows)


def zstack_comparison(microscope: Microscope, n_volume: int, *, n_planes: int = 31, seed: int = 1):
    """The default model calibrated from a Z stack alone (a field-filling plate, ``n_planes`` positions over
    the validation's Z range) beside the same model calibrated on Test 1's three axes, on one volume run, and
    the Soloff model alone on the same Z stack (one of the default's candidates; the default chooses between
    them by held-out planes of the stack, which cannot show the stage's systematic errors).
    Errors are compared in the Z stack's frame (:func:`slmlab.virtual.sessions.zstack_frame`) for the Z-stack models.
    Returns ``(table, zstack_model, val, frame)``: per model, RMS displacement error [µm] and over the floor,
    and the 95 % intervals' coverage [%]."""
    mz = microscope.replace(moving_plate=zstack_plate())
    zcal = simulate_set(mz, zstack_session(n_planes), seed=seed)
    zmodel = calibrate(zcal)
    moves = calibrate(simulate_set(microscope, paper_test(1), seed=seed))
    val = volume_run(microscope, n_volume, seed)
    frame = zstack_frame(mz)
    rows = []
    soloff = calibrate(zcal, "soloff")
    for label, model, fr in (("Z stack alone", zmodel, frame), ("X, Y, Z sequences (Test 1)", moves, None),
                             ("Z stack alone, soloff model", soloff, frame)):
        t = volumetric_comparison({label: model}, val, frame=fr).set_index("model").loc[label]
        cov = uncertainty_coverage(model, val, frame=fr)
        rows.append({"calibration": label, "positions": int(model.calibration.get("positions", zmodel.calibration["positions"]).get("Z", 0)) if label.startswith("Z")
                     else int(sum(model.calibration["positions"].get(k, 0) for k in "XYZ")),
                     "model": model.describe(),
                     **{f"{c}_um": t[f"{c}_um"] for c in "XYZ"}, **{f"{c}_vs_floor": t[f"{c}_vs_floor"] for c in "XYZ"},
                     **{f"{c}_coverage_percent": cov[c] for c in "XYZ"}})
    return pd.DataFrame(rows), zmodel, val, frame


def leave_one_plane_out(cal, variants: dict[str, dict]) -> pd.DataFrame:
    """Leave-one-plane-out validation of Z-stack calibrations on a set with known X, Y, Z per dot (a real
    Z stack): for each plane, calibrate on the others with each variant's options (``{label: options}``)
    and reconstruct the left-out plane. Per plane and variant: the settings the calibration chose, RMS error
    [µm] per coordinate (``EX_um`` …), mean predicted 1σ [µm] (``sX_um`` …), and the share of errors inside
    the 95 % intervals [%]."""
    pts = cal.points.dropna(subset=["wl1", "wl2", "wr1", "wr2"])
    rows = []
    for plane in sorted(pts["position"].unique()):
        train = CalibrationSet(pts[pts["position"] != plane].copy(), cal.meta)
        test = pts[pts["position"] == plane]
        xy = plate_xy(test["row"], test["col"], cal.plate("Z")) + test[["stage_x_mm", "stage_y_mm"]].to_numpy()
        truth = np.column_stack([xy, test["stage_z_mm"].to_numpy()])
        w = test[["wl1", "wl2", "wr1", "wr2"]].to_numpy(float)
        for label, options in variants.items():
            model = calibrate(train, **options)
            e = model.reconstruct(w) - truth
            sig = model.uncertainty(w) if hasattr(model, "uncertainty") else np.full_like(e, np.nan)
            rows.append({"plane": int(plane), "Z_mm": float(test["stage_z_mm"].iloc[0]), "model": label,
                         "settings": model.describe(),
                         **{f"E{c}_um": 1e3 * float(np.sqrt(np.mean(e[:, k] ** 2))) for k, c in enumerate("XYZ")},
                         **{f"s{c}_um": 1e3 * float(np.mean(sig[:, k])) for k, c in enumerate("XYZ")},
                         "inside_95_percent": float(100 * np.mean(np.abs(e) <= 1.959964 * sig))})
    return pd.DataFrame(rows)


def leave_one_plane_out_summary(lopo: pd.DataFrame) -> pd.DataFrame:
    """Per variant of :func:`leave_one_plane_out` (in its order): the RMS over the planes of the left-out
    errors [µm] per coordinate, the mean predicted 1σ [µm], and the mean share inside the 95 % intervals [%]."""
    g = lopo.groupby("model", sort=False)
    out = pd.DataFrame({f"{c}_um": g[f"E{c}_um"].apply(lambda v: float(np.sqrt(np.mean(v ** 2)))) for c in "XYZ"})
    for c in "XYZ":
        out[f"{c}_predicted_sigma_um"] = g[f"s{c}_um"].mean()
    out["inside_95_percent"] = g["inside_95_percent"].mean()
    return out.reset_index()


def workspace_grid(microscope: Microscope, session, *, n_xy: int = 25, depths_mm=(-1.0, 0.0, 1.0),
                   margin_mm: float = 0.3) -> pd.DataFrame:
    """Noise-free stereo image coordinates of a grid of points over the workspace: ``n_xy × n_xy`` points
    across the field at each depth (relative to focus), seen by both views. Columns ``depth_mm, x_mm, y_mm``
    (microscope frame) and ``wl1, wl2, wr1, wr2`` [px]: the query points of :func:`cross_validation_diff`."""
    o = microscope.optics
    half = np.array(o.image_size_px) * o.pixel_mm / 2 - margin_mm
    x, y = np.meshgrid(np.linspace(-half[0], half[0], n_xy), np.linspace(-half[1], half[1], n_xy))
    frames = []
    for z in depths_mm:
        p = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, z)])
        w = microscope.project(p)
        ok = microscope.visible(w, microscope.moving_plate.dot_diameter_mm).all(axis=1)
        frames.append(pd.DataFrame({"depth_mm": z, "x_mm": p[ok, 0], "y_mm": p[ok, 1],
                                    **{c: w[ok, k] for k, c in enumerate(["wl1", "wl2", "wr1", "wr2"])}}))
    return pd.concat(frames, ignore_index=True)


def cross_validation_diff(model_a, model_b, grid: pd.DataFrame) -> pd.DataFrame:
    """mrcal-style cross-validation: two calibrations from independent data reconstruct the same image
    points; their difference [µm] (less its mean over the grid, a frame offset) beside what the models
    predict for it, ``√(σa² + σb²)`` of the calibrations alone. Adds ``dX_um, dY_um, dZ_um`` and
    ``predicted_{X,Y,Z}_um`` to ``grid``."""
    w = grid[["wl1", "wl2", "wr1", "wr2"]].to_numpy(float)
    d = model_a.reconstruct(w) - model_b.reconstruct(w)
    d -= d.mean(axis=0)
    pred = np.sqrt(model_a.calibration_sigma(w) ** 2 + model_b.calibration_sigma(w) ** 2)
    out = grid.copy()
    for k, c in enumerate("XYZ"):
        out[f"d{c}_um"] = 1e3 * d[:, k]
        out[f"predicted_{c}_um"] = 1e3 * pred[:, k]
    return out


def cross_validation_summary(model_a, model_b, diff: pd.DataFrame) -> pd.DataFrame:
    """Per coordinate, the RMS over the grid of :func:`cross_validation_diff`'s difference and of its
    prediction [µm], their ratio, and the settings each calibration chose (where they differ, so do the maps
    away from the calibration's own positions)."""
    rows = [{"coordinate": c, "rms_diff_um": float(np.sqrt(np.mean(diff[f"d{c}_um"] ** 2))),
             "rms_predicted_um": float(np.sqrt(np.mean(diff[f"predicted_{c}_um"] ** 2)))} for c in "XYZ"]
    out = pd.DataFrame(rows)
    out["diff_over_predicted"] = out["rms_diff_um"] / out["rms_predicted_um"]
    out["settings_a"], out["settings_b"] = model_a.describe(), model_b.describe()
    return out


def subsample_positions(cal, every: int):
    """The calibration set with every ``every``-th position of each moving sequence (the first always kept),
    renumbered 1, 2, …; static sequences (``grid``) unchanged."""
    pts = cal.points
    moving = pts["sequence"].isin(["X", "Y", "Z", "V"])
    keep = ~moving | ((pts["position"] - 1) % every == 0)
    out = pts[keep].copy()
    out.loc[moving[keep], "position"] = (out.loc[moving[keep], "position"] - 1) // every + 1
    return CalibrationSet(out.reset_index(drop=True), cal.meta)


def accuracy_vs_positions(microscope: Microscope, n_volume: int, everies=(1, 2, 3, 4, 6, 8), *, seed: int = 1,
                          models=("direct", "paper-m2")) -> pd.DataFrame:
    """How accuracy scales with the number of calibration positions: Test 1 thinned to every k-th position,
    each model calibrated on it and validated on one volume run. Per row: positions, model, the settings it
    chose (:meth:`slmlab.models.base.Model.describe`: degrees and variables), RMS displacement error [µm] and
    over the floor per coordinate."""
    full = simulate_set(microscope, paper_test(1), seed=seed)
    val = volume_run(microscope, n_volume, seed)
    rows = []
    for k in everies:
        cal = subsample_positions(full, k)
        n = int(cal.points[cal.points["sequence"].isin(["X", "Y", "Z"])].groupby("sequence")["position"].nunique().sum())
        for name in models:
            model = calibrate(cal, name)
            t = volumetric_comparison({name: model}, val).set_index("model").loc[name]
            rows.append({"every": k, "positions": n, "model": name, "settings": model.describe(),
                         **{f"{c}_um": t[f"{c}_um"] for c in "XYZ"}, **{f"{c}_vs_floor": t[f"{c}_vs_floor"] for c in "XYZ"}})
    return pd.DataFrame(rows)


def commanded_frame_limit(microscope: Microscope, session, val, *, repeats: int = 20, seed: int = 0) -> dict:
    """What no calibration on a session's commanded stage moves can beat, in the stage's true frame.

    A perfect model can at best learn the commanded frame: here, the best linear map from the stage's actual
    positions to the commanded ones over the session's positions (each repeat draws the stage's errors
    afresh). Applied to the volume run's true displacements, its RMS error [µm] per coordinate adds to the
    noise floor's; returns ``frame_um`` and ``floor_um`` (per coordinate) and ``attainable_vs_floor``
    ``= √(floor² + frame²) / floor``. It ignores the stage's non-linear errors a model would also learn,
    so the true limit is higher."""
    positions = session.stage_positions()
    cmd = np.concatenate([positions[k] for k in positions if k in ("X", "Y", "Z", "V")])
    v = volume_rows(val)
    dt, _, _ = displacements(v, val.truth.loc[v.index, ["X_mm", "Y_mm", "Z_mm"]].to_numpy())
    floor = volumetric_comparison({}, val).iloc[0][["X_um", "Y_um", "Z_um"]].to_numpy(float)
    rng = np.random.default_rng(seed)
    errors = []
    for _ in range(repeats):
        actual = microscope.stage.actual(cmd, rng)
        lin, *_ = np.linalg.lstsq(np.column_stack([actual, np.ones(len(actual))]), cmd, rcond=None)
        errors.append(np.mean((dt @ lin[:3] - dt) ** 2, axis=0))
    frame = 1e3 * np.sqrt(np.mean(errors, axis=0))
    return {"frame_um": frame, "floor_um": floor, "attainable_vs_floor": np.sqrt(floor ** 2 + frame ** 2) / floor}


def reconstruction_against_truth(reconstructed: pd.DataFrame, truth: pd.DataFrame, share: float = 95.0) -> pd.DataFrame:
    """Points as ``reconstruct`` writes them (``X_mm, Y_mm, Z_mm`` and the 1σ ``sX_mm, sY_mm, sZ_mm``) against a
    simulated set's truth (``truth.csv``'s ``X_mm, Y_mm, Z_mm``), matched on ``sequence, position, row, col``.
    Per coordinate: points, RMS error after one common offset (the model's frame origin) [µm], mean predicted
    1σ [µm], and the share of errors inside the ``share`` % intervals [%]."""
    key = ["sequence", "position", "row", "col"]
    m = reconstructed.dropna(subset=["X_mm", "Y_mm", "Z_mm"]).merge(truth[key + ["X_mm", "Y_mm", "Z_mm"]], on=key,
                                                                     suffixes=("", "_true"))
    z = norm.ppf(0.5 + share / 200)
    rows = []
    for c in "XYZ":
        e = (m[f"{c}_mm"] - m[f"{c}_mm_true"]).to_numpy()
        e = e - e.mean()
        sig = m[f"s{c}_mm"].to_numpy()
        rows.append({"coordinate": c, "points": len(m), "rms_error_um": 1e3 * float(np.sqrt(np.mean(e ** 2))),
                     "mean_sigma_um": 1e3 * float(np.mean(sig)), f"inside_{share:g}_percent": float(100 * np.mean(np.abs(e) <= z * sig))})
    return pd.DataFrame(rows)
