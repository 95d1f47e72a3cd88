"""Beyond the paper: the direct model reaches the noise floor over the whole workspace (volumetric check)."""

import subprocess
import sys
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

import slmlab
from slmlab.simulate import noise_floor, volume_session
from slmlab.vision import displacements


def perfect_stage():
    m = slmlab.preset("paper")
    return replace(m, stage=replace(m.stage, scale_error=(0, 0, 0), lead_error_um=0.0, straightness_um=(0, 0, 0),
                                    positioning_noise_um=0.0))


def displacement_rms(val, positions_mm):
    """RMS [µm] per coordinate of displacement errors on V against the truth."""
    v = val.points[val.points["sequence"] == "V"]
    ok = v[["wl1", "wl2", "wr1", "wr2"]].notna().all(axis=1).to_numpy()
    v = v[ok]
    truth = val.truth.loc[v.index, ["X_mm", "Y_mm", "Z_mm"]].to_numpy()
    dp, _, _ = displacements(v, positions_mm[ok])
    dt, _, _ = displacements(v, truth)
    return 1e3 * np.sqrt(np.mean((dp - dt) ** 2, axis=0))


@pytest.fixture(scope="module")
def volume():
    m = perfect_stage()
    cal = slmlab.simulate_set(m, slmlab.paper_test(1), seed=1)
    val = slmlab.simulate_set(m, volume_session(30, seed=5), seed=7)
    return cal, val


def reconstruct_all(model, val):
    w = val.points[["wl1", "wl2", "wr1", "wr2"]].to_numpy(float)
    out = np.full((len(w), 3), np.nan)
    ok = np.isfinite(w).all(axis=1)
    out[ok] = model.reconstruct(w[ok])
    return out


def test_direct_is_the_default_and_reaches_the_noise_floor_over_the_volume(volume):
    cal, val = volume
    model = slmlab.calibrate(cal)
    assert model.name == "direct"
    floor = displacement_rms(val, noise_floor(val))
    ours = displacement_rms(val, reconstruct_all(model, val))
    paper = displacement_rms(val, reconstruct_all(slmlab.calibrate(cal, "paper-m2"), val))
    assert (ours <= 1.2 * floor).all(), (ours, floor)
    assert (paper > 5 * ours).all()


def test_outliers_are_down_weighted_and_reported(volume):
    cal, val = volume
    pts = cal.points.copy()
    rng = np.random.default_rng(0)
    rows = pts.index[pts["sequence"].isin(["X", "Y", "Z"])]
    bad = rng.choice(rows, size=int(0.02 * len(rows)), replace=False)
    pts.loc[bad, "wl1"] += 25.0
    model = slmlab.calibrate(slmlab.CalibrationSet(pts, cal.meta), "direct")
    floor = displacement_rms(val, noise_floor(val))
    assert (displacement_rms(val, reconstruct_all(model, val)) <= 2 * floor).all()
    flagged = pd.DataFrame(model.calibration["down_weighted_rows"])
    assert len(flagged) >= 0.9 * len(bad)


def test_reconstruct_adds_uncertainty_columns(tmp_path, volume):
    cal, val = volume
    d = slmlab.write_set(tmp_path / "cal", cal)
    out, model = tmp_path / "xyz.csv", tmp_path / "m.json"
    assert subprocess.run([sys.executable, "-m", "slmlab", "calibrate", d, "--out", model], timeout=300).returncode == 0
    pts = tmp_path / "pts.csv"
    val.sequence("V").to_csv(pts, index=False)
    assert subprocess.run([sys.executable, "-m", "slmlab", "reconstruct", model, pts, "--out", out], timeout=300).returncode == 0
    df = pd.read_csv(out)
    assert {"sX_mm", "sY_mm", "sZ_mm"} <= set(df.columns)
    assert (df[["sX_mm", "sY_mm", "sZ_mm"]].dropna() > 0).all().all()
