"""Studies over repeated simulations and calibration tests (paper §6, Tables 2–4; METHOD.md §6).

Each study draws fresh simulated sets with seeds derived from one base seed, fits the paper's chain and
collects its parameters, so that a table can show our mean ± spread beside the paper's reported values.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from .evaluation import ELEMENTS, Evaluation
from .microscope import Microscope
from .paths import paper_reference
from .simulate import PAPER_TESTS, Session, simulate_set
from .vision import fit_paper

__all__ = ["TABLE4_NAMES", "repeat_fits", "table2", "table3", "table4", "headline_precision", "comparison_table",
           "z_calibration_samples", "volumetric_comparison", "uncertainty_coverage", "volumetric_errors"]

TABLE4_NAMES = ["thetaX_deg", "EX_mm_per_px", "EY_mm_per_px", "EZ_mm_per_px", "KYX", "BYX_mm", "KYZ", "BYZ_mm",
                "KZX", "BZX_mm", "KZY", "BZY_mm"]


def repeat_fits(microscope: Microscope, sessions: list[Session], seed: int, **fit_options) -> pd.DataFrame:
    """Fit the paper's chain (Model 2) on one fresh set per session; one row of parameters per set."""
    seeds = np.random.SeedSequence(seed).generate_state(len(sessions))
    rows = []
    for s, sd in zip(sessions, seeds):
        params, dist, align = fit_paper(simulate_set(microscope, s, seed=int(sd)), **fit_options)
        rows.append({"session": s.name, "seed": int(sd), **params.as_dict(),
                     "alpha_std_over_points_deg": float(np.degrees(align.alpha_std_rad)),
                     "dw2_std_over_samples_px": align.dw2_std_px,
                     "aD_joint": align.disparity["joint"].aD, "bD_joint": align.disparity["joint"].bD})
    return pd.DataFrame(rows)


def table2(fits: pd.DataFrame) -> pd.DataFrame:
    """Table 2: α, δw2, aD, bD, cD, mean ± std over the repeated fits, beside the paper's values."""
    ref = paper_reference("table2")
    rows = []
    for name, key in (("alpha_deg", "alpha_deg"), ("dw2_px", "dw2_px"), ("aD", "aD"), ("bD", "bD"), ("cD_px", "cD_px")):
        r = ref[key]
        paper_mean, paper_std = (r["mean"], r["std"]) if isinstance(r, dict) else (r, np.nan)
        rows.append({"parameter": name, "ours_mean": fits[name].mean(), "ours_std_over_runs": fits[name].std(ddof=1),
                     "paper": paper_mean, "paper_std": paper_std})
    rows.append({"parameter": "aD (joint fit)", "ours_mean": fits["aD_joint"].mean(),
                 "ours_std_over_runs": fits["aD_joint"].std(ddof=1), "paper": np.nan, "paper_std": np.nan})
    df = pd.DataFrame(rows)
    df["ours_vs_paper_percent"] = 100 * (df["ours_mean"] / df["paper"] - 1)
    return df


def table3(sets: dict) -> pd.DataFrame:
    """Table 3: the five calibration tests (step and positions), with the samples each set provides."""
    rows = []
    for k, (step, n) in PAPER_TESTS.items():
        cal = sets.get(k)
        row = {"test": k, "step_mm": step, "NUMX": n[0], "NUMY": n[1], "NUMZ": n[2]}
        if cal is not None:
            both = cal.points[["wl1", "wr1"]].notna().all(axis=1)
            for s in "XYZ":
                row[f"dots_{s}"] = int((both & (cal.points["sequence"] == s)).sum())
        rows.append(row)
    return pd.DataFrame(rows)


def table4(fits: pd.DataFrame) -> pd.DataFrame:
    """Table 4: the twelve parameters over the calibration tests, mean, std and the largest relative deviation
    of a test from the mean [%], beside the paper's mean ± std."""
    ref = paper_reference("table4")
    rows = []
    for name in TABLE4_NAMES:
        v = fits[name].to_numpy()
        mean = float(np.mean(v))
        rows.append({"parameter": name, "ours_mean": mean, "ours_std": float(np.std(v, ddof=1)),
                     "ours_max_rel_dev_percent": float(100 * np.max(np.abs(v / mean - 1))) if mean else np.nan,
                     "paper_mean": ref[name]["mean"], "paper_std": ref[name]["std"],
                     "ours_vs_paper_percent": 100 * (mean / ref[name]["mean"] - 1)})
    return pd.DataFrame(rows)


def headline_precision(ev: Evaluation, share: float = 95.0) -> dict:
    """The half-width [mm] of the interval holding ``share`` % of each component's residuals over the three
    sequences: the paper's headline (0.01 / 0.01 / 0.015 mm) in our terms."""
    res = ev.residuals
    return {c: float(np.percentile(np.abs(res[f"E_{c}"]), share)) for c in "XYZ"}


def comparison_table(evaluations: dict[str, Evaluation]) -> pd.DataFrame:
    """Per model and residual element: max and RMS [mm], and S at RA3 and RA5 [%]."""
    rows = []
    for name, ev in evaluations.items():
        summ = ev.summary.set_index("element")
        for el in ELEMENTS:
            if el in summ.index:
                rows.append({"model": name, "element": el, "max_abs_mm": summ.loc[el, "max_abs_mm"],
                             "rms_mm": summ.loc[el, "rms_mm"], "S_RA3_percent": ev.s.loc[el, "RA3"],
                             "S_RA5_percent": ev.s.loc[el, "RA5"]})
    return pd.DataFrame(rows)


def z_calibration_samples(cal, params) -> pd.DataFrame:
    """Fig 10: the Z sequence's stage displacements ``ΔZ_A`` [mm] against the corrected disparity increments
    ``ΔD`` [px] (relative to position 1)."""
    from .alignment import sequence_coordinates
    from .vision import displacements

    df = sequence_coordinates(cal, "Z")
    _, _, d = params.image_stage(df[["wl1", "wl2", "wr1", "wr2"]].to_numpy(float))
    dd, ds, keep = displacements(df, d[:, None])
    return pd.DataFrame({"position": df["position"].to_numpy()[keep], "dD_px": dd[:, 0], "dZ_A_mm": ds[:, 2]})


def volumetric_comparison(models: dict, val) -> "pd.DataFrame":
    """RMS displacement error [µm] per coordinate on a volumetric run ``V`` (relative to its position 1,
    against the truth) for each model ``{name: model}`` and for the simulator's own true-model
    triangulation (the noise floor)."""
    from .simulate import noise_floor
    from .vision import displacements

    v = val.points[val.points["sequence"] == "V"]
    ok = v[["wl1", "wl2", "wr1", "wr2"]].notna().all(axis=1).to_numpy()
    v = v[ok]
    truth = val.truth.loc[v.index, ["X_mm", "Y_mm", "Z_mm"]].to_numpy()
    dt, _, _ = displacements(v, truth)
    w = v[["wl1", "wl2", "wr1", "wr2"]].to_numpy(float)
    rows = []
    floor = noise_floor(val)[ok]
    for name, p in [("noise floor (true model)", floor)] + [(n, m.reconstruct(w)) for n, m in models.items()]:
        dp, _, _ = displacements(v, p)
        e = 1e3 * np.sqrt(np.mean((dp - dt) ** 2, axis=0))
        rows.append({"model": name, "X_um": e[0], "Y_um": e[1], "Z_um": e[2]})
    df = pd.DataFrame(rows)
    f = df.iloc[0]
    for c in ("X", "Y", "Z"):
        df[f"{c}_vs_floor"] = df[f"{c}_um"] / f[f"{c}_um"]
    return df


def uncertainty_coverage(model, val, share: float = 95.0) -> dict:
    """Share [%] of absolute errors (after removing the frame's constant offset) inside the model's
    ``share`` % intervals, per coordinate, on the run's V sequence."""
    from scipy.stats import norm

    v = val.points[val.points["sequence"] == "V"].dropna(subset=["wl1", "wl2", "wr1", "wr2"])
    w = v[["wl1", "wl2", "wr1", "wr2"]].to_numpy(float)
    e = model.reconstruct(w) - val.truth.loc[v.index, ["X_mm", "Y_mm", "Z_mm"]].to_numpy()
    e -= e.mean(axis=0)
    z = norm.ppf(0.5 + share / 200)
    inside = np.abs(e) <= z * model.uncertainty(w)
    return {c: float(100 * inside[:, k].mean()) for k, c in enumerate("XYZ")}


def volumetric_errors(models: dict, val) -> dict:
    """Per sample of V: the stage Z of the position and the displacement error magnitude [µm], per model."""
    from .vision import displacements

    v = val.points[val.points["sequence"] == "V"].dropna(subset=["wl1", "wl2", "wr1", "wr2"])
    truth = val.truth.loc[v.index, ["X_mm", "Y_mm", "Z_mm"]].to_numpy()
    dt, st, keep = displacements(v, truth)
    z = v["stage_z_mm"].to_numpy()[keep]
    out = {}
    for name, m in models.items():
        dp, _, _ = displacements(v, m.reconstruct(v[["wl1", "wl2", "wr1", "wr2"]].to_numpy(float)))
        out[name] = pd.DataFrame({"Z_mm": z, "error_um": 1e3 * np.linalg.norm(dp - dt, axis=1)})
    return out
