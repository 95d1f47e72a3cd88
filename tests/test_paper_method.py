"""The paper's method (§3–§5) on simulators whose truth is known: what it must recover, it recovers."""

import json
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

import slmlab
from slmlab.paper.alignment import estimate_alignment
from slmlab.paper.distortion import estimate_distortion, quality
from slmlab.paper.evaluation import RESIDUAL_INTERVALS_MM, s_coefficients, requirement
from slmlab.virtual.microscope import CentroidNoise, View
from slmlab.paper.chain import fit_paper

SIGMA = 0.02


def microscope(**optics_views):
    """The paper preset with the given views (distortion etc.), no radial term unless given."""
    m = slmlab.preset("paper")
    return replace(m, optics=replace(m.optics, **optics_views))


def only_decentring(scale=1.0):
    """The paper preset's decentring and thin prism (times ``scale``), no radial distortion."""
    m = slmlab.preset("paper")
    views = [replace(v, radial_k1_per_mm2=0.0, decentring_per_mm=scale * v.decentring_per_mm,
                     thin_prism_per_mm=scale * v.thin_prism_per_mm) for v in (m.optics.left, m.optics.right)]
    return microscope(left=views[0], right=views[1])


def undistorted(rot_l=-0.2, rot_r=0.1, pp_r=(950.0, 899.0)):
    return microscope(left=View(rotation_deg=rot_l, principal_point_px=(941.0, 902.0)),
                      right=View(rotation_deg=rot_r, principal_point_px=pp_r))


# ------------------------------------------------------------------------------------------ §3
def test_distortion_correction_makes_rows_parallel_and_columns_straight():
    # a third of the paper's distortion: Eq 6's single quadratic leaves a second-order bend that grows as
    # the distortion squared; here it is well below the noise, so the columns must come out straight to it
    m = only_decentring(1 / 3)
    cal = slmlab.simulate_set(m, seed=3)
    g = cal.sequence("grid")
    # what a straight column's dots scatter by: centroid noise and the plate's ±0.25 µm fabrication error
    tol_px = m.grid_plate.fabrication_tolerance_um * 1e-3 / m.optics.pixel_mm
    noise = np.hypot(SIGMA, tol_px / np.sqrt(3))
    res = estimate_distortion(g)
    for side in "lr":
        i, j = g["row"].to_numpy(), g["col"].to_numpy()
        w1, w2 = g[f"w{side}1"].to_numpy(), g[f"w{side}2"].to_numpy()
        before = quality(i, j, w1, w2)
        after = quality(i, j, *res.view(side).apply(w1, w2))
        assert after["column_straightness_px"] < 1.2 * noise
        assert after["column_straightness_px"] < 0.5 * before["column_straightness_px"]
        assert after["row_slope_spread"] < 0.05 * before["row_slope_spread"]
        assert abs(after["row_spacing_trend"]) < 0.02 * abs(before["row_spacing_trend"])
    # the two estimators agree and the opposite signs of the two views come out
    t = res.table().set_index(["method", "view"])
    assert np.sign(t.loc[("joint", "l"), "a"]) == -np.sign(t.loc[("joint", "r"), "a"])
    assert t.loc[("joint", "l"), "lambda"] == pytest.approx(t.loc[("paper-two-step", "l"), "lambda"], rel=0.02)


def test_distortion_parameters_follow_the_physics():
    """First order: column bend a = (p1 + s1)·pixel, row fan λ = 2·p1·pixel, opposite in the two views."""
    m = only_decentring()
    res = estimate_distortion(slmlab.simulate_set(m, seed=4).sequence("grid"))
    for side in "lr":
        v = m.optics.view(side)
        assert res.view(side).a == pytest.approx((v.decentring_per_mm + v.thin_prism_per_mm) * m.optics.pixel_mm, rel=0.06)
        assert res.view(side).lam == pytest.approx(2 * v.decentring_per_mm * m.optics.pixel_mm, rel=0.06)


# ------------------------------------------------------------------------------------------ §4
def test_alpha_and_dw2_recovered_on_an_undistorted_microscope():
    rot_l, rot_r, pp_r = -0.2, 0.1, (950.0, 899.0)
    m = undistorted(rot_l, rot_r, pp_r)
    cal = slmlab.simulate_set(m, seed=5)
    a = estimate_alignment(cal, lambda w: w)
    n = 49
    assert np.degrees(a.alpha_rad) == pytest.approx(rot_l - rot_r, abs=max(4 * np.degrees(a.alpha_std_rad) / np.sqrt(n), 1e-4))
    al = np.radians(rot_l - rot_r)
    expected = 902.0 - (np.sin(al) * pp_r[0] + np.cos(al) * pp_r[1])
    assert a.dw2_px == pytest.approx(expected, abs=0.02)


def test_disparity_correction_flattens_the_x_paths():
    cal = slmlab.simulate_set(slmlab.preset("paper"), seed=6)
    dist = estimate_distortion(cal.sequence("grid"))
    a = estimate_alignment(cal, dist.apply)
    noise_d = np.sqrt(2) * SIGMA  # disparity is the difference of two centres
    assert a.straightness["joint"] < 2 * noise_d < 0.1 * a.straightness["raw"]
    assert a.straightness["single-pass"] < a.straightness["raw"]  # the sign check did its job
    # the correction is a pure parabola about its vertex, as the paper's Table 2 (cD = bD^2 / 4 aD)
    j = a.disparity["joint"]
    assert j.cD_px == pytest.approx(j.bD ** 2 / (4 * j.aD), rel=1e-12)
    # the joint fit recovers the physical curvature 2 (3 p1 + s1) · pixel (opposite views add up)
    v = slmlab.preset("paper").optics.left
    assert a.disparity["joint"].aD == pytest.approx(2 * (3 * v.decentring_per_mm + v.thin_prism_per_mm) * 0.003, rel=0.05)


def test_missing_dots_do_not_break_any_fit():
    cal = slmlab.simulate_set(slmlab.preset("paper"), seed=7)
    full, _, _ = fit_paper(cal)
    rng = np.random.default_rng(0)
    pts = cal.points.copy()
    drop = rng.random(len(pts)) < 0.1
    drop |= (pts["sequence"] == "grid") & (pts["col"] <= 2)          # plate cut at the edge
    drop |= (pts["sequence"] == "X") & (pts["col"] == 7) & (pts["position"] > 30)
    pts.loc[drop, ["wl1", "wl2"]] = np.nan
    holey = slmlab.CalibrationSet(pts, cal.meta)
    part, _, _ = fit_paper(holey)
    f, p = full.as_dict(), part.as_dict()
    assert p["thetaX_deg"] == pytest.approx(f["thetaX_deg"], abs=0.01)
    for k in ("EX_mm_per_px", "EY_mm_per_px", "EZ_mm_per_px"):
        assert p[k] == pytest.approx(f[k], rel=2e-3)
    assert p["alpha_deg"] == pytest.approx(f["alpha_deg"], abs=0.01)


# ------------------------------------------------------------------------------------------ §5
def ideal(noise=SIGMA, **stage):
    m = slmlab.preset("ideal")
    return replace(m, noise=CentroidNoise(noise, noise), stage=replace(m.stage, **stage))


def test_model0_recovers_scales_and_thetax_on_an_ideal_microscope():
    m = ideal()
    p, _, _ = fit_paper(slmlab.simulate_set(m, seed=8), level=0)
    t = np.tan(np.radians(m.optics.convergence_deg) / 2)
    assert p.EX_mm_per_px == pytest.approx(-0.003, rel=1e-3)
    assert p.EY_mm_per_px == pytest.approx(-0.003, rel=1e-3)
    assert p.EZ_mm_per_px == pytest.approx(0.003 / (2 * t), rel=2e-3)
    assert p.thetaX_deg == pytest.approx(0.0, abs=2e-3)
    m2 = ideal(rotation_deg=-2.5)
    p2, _, _ = fit_paper(slmlab.simulate_set(m2, seed=8), level=0)
    assert p2.thetaX_deg == pytest.approx(2.5, abs=2e-3)


@pytest.mark.parametrize("stage_term, K, value", [("y_skew", "KYX", 0.01), ("y_tilt", "KYZ", 0.02),
                                                  ("z_tilt_x", "KZX", 0.006), ("z_tilt_y", "KZY", -0.015)])
def test_each_compensation_term_is_recovered_from_its_stage_skew(stage_term, K, value):
    p, _, _ = fit_paper(slmlab.simulate_set(ideal(**{stage_term: value}), seed=9), level=2)
    assert p.K[K] == pytest.approx(-value, rel=0.03)
    for other in ("KYX", "KYZ", "KZX", "KZY"):
        if other != K:
            assert abs(p.K[other]) < 0.03 * abs(value)


def test_s_coefficients_by_hand():
    e = np.array([0.001, -0.004, 0.006, -0.009, 0.011, 0.014, -0.02])
    res = pd.DataFrame({"sequence": "X", "position": np.arange(2, 9), "row": 1, "col": 1,
                        "displacement_mm": 0.0, "E_X": e, "E_Y": 0.0, "E_Z": e * 2})
    s = s_coefficients(res)
    assert list(s.loc["XX"]) == pytest.approx([100 * k / 7 for k in (2, 3, 4, 5, 6)])
    assert list(s.loc["XY"]) == [100.0] * 5
    assert list(s.loc["XZ"]) == pytest.approx([100 * k / 7 for k in (1, 1, 2, 3, 3)])
    r = requirement(s).set_index("element")
    assert r.loc["XX", "interval"] == "RA3" and r.loc["XZ", "interval"] == "RA5"
    assert not r.loc["XX", "passes"] and r.loc["XY", "passes"]
    assert RESIDUAL_INTERVALS_MM == slmlab.paper_reference("residual_intervals_mm")


def test_paper_models_improve_in_order_on_a_validation_run():
    m = slmlab.preset("paper")
    cal = slmlab.simulate_set(m, seed=10)
    val = slmlab.simulate_set(m, slmlab.validation_session(), seed=11)
    rms = {}
    for name in ("paper-m0", "paper-m1", "paper-m2"):
        ev = slmlab.evaluate(slmlab.calibrate(cal, name), val)
        rms[name] = ev.summary.set_index("element")["rms_mm"]
    # Model 1 fixes the Y-sequence radial errors, Model 2 the Z-sequence ones
    assert rms["paper-m1"]["YX"] < 0.2 * rms["paper-m0"]["YX"] and rms["paper-m1"]["YZ"] < 0.2 * rms["paper-m0"]["YZ"]
    assert rms["paper-m2"]["ZX"] < 0.6 * rms["paper-m1"]["ZX"] and rms["paper-m2"]["ZY"] < 0.3 * rms["paper-m1"]["ZY"]


def run_cli(*args):
    return subprocess.run([sys.executable, "-m", "slmlab", *args], capture_output=True, text=True, timeout=300)


@pytest.mark.slow  # three command-line runs
def test_cli_calibrate_reconstruct_evaluate(tmp_path, set_dir):
    model = tmp_path / "m2.json"
    assert run_cli("calibrate", str(set_dir), "--model", "paper-m2", "--out", str(model)).returncode == 0
    d = json.loads(model.read_text())
    names = ["lambda_l", "a_l", "b_l", "c_l", "lambda_r", "a_r", "b_r", "c_r", "alpha_deg", "dw2_px", "aD", "bD",
             "cD_px", "thetaX_deg", "EX_mm_per_px", "EY_mm_per_px", "EZ_mm_per_px", "KYX", "BYX_mm", "KYZ", "BYZ_mm",
             "KZX", "BZX_mm", "KZY", "BZY_mm"]
    assert sorted(d["parameters"]) == sorted(names) and d["options"]["distortion_method"] in ("joint", "paper-two-step")
    assert all(n in d["units"] for n in names)
    pts = tmp_path / "pts.csv"
    slmlab.read_set(set_dir).sequence("Z").to_csv(pts, index=False)
    out = tmp_path / "xyz.csv"
    assert run_cli("reconstruct", str(model), str(pts), "--out", str(out)).returncode == 0
    xyz = pd.read_csv(out)
    back = slmlab.load_model(model).reconstruct(xyz[["wl1", "wl2", "wr1", "wr2"]].to_numpy())
    np.testing.assert_allclose(xyz[["X_mm", "Y_mm", "Z_mm"]].to_numpy(), back, atol=1e-9)
    r = run_cli("evaluate", str(model), str(set_dir), "--json")
    assert r.returncode == 0
    ev = json.loads(r.stdout)
    assert set(ev["S_percent"]) == {a + c for a in "XYZ" for c in "XYZ"}


def test_evaluate_skips_rows_with_missing_dots(set_dir):
    cal = slmlab.read_set(set_dir)
    model = slmlab.calibrate(cal, "paper-m0")
    pts = cal.points.copy()
    pts.loc[pts.index[::7], "wr1"] = np.nan
    ev = slmlab.evaluate(model, slmlab.CalibrationSet(pts, cal.meta))
    assert ev.summary["samples"].sum() < slmlab.evaluate(model, cal).summary["samples"].sum()


def test_fast_reconstruction_equals_the_stepwise_chain(paper_set):
    params, _, _ = fit_paper(paper_set)
    w = paper_set.points[["wl1", "wl2", "wr1", "wr2"]].dropna().to_numpy()
    for level in (0, 1, 2):
        np.testing.assert_allclose(params.reconstruct(w, level, chunk=1000), params.reconstruct_stepwise(w, level),
                                   rtol=0, atol=1e-12)
