"""Beyond the paper: the direct model reaches the noise floor over the whole workspace (volumetric check)."""

import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

import slmlab
from slmlab.datasets import converters
from slmlab.studies import workspace
from slmlab.models.direct import DEPTH_DEGREE, LEGACY_FRAME, DirectModel, _depth_cap
from slmlab.models.frames import plate_xy
from slmlab.virtual.simulate import noise_floor
from slmlab.virtual.sessions import volume_session, zstack_frame, zstack_plate, zstack_session
from slmlab.paper.chain import displacements


def perfect_stage():
    return workspace.perfect_stage(slmlab.preset("paper"))


def displacement_rms(val, positions_mm):
    """RMS [µm] per coordinate of displacement errors on V against the truth."""
    v = val.points[val.points["sequence"] == "V"]
    ok = v[["wl1", "wl2", "wr1", "wr2"]].notna().all(axis=1).to_numpy()
    v = v[ok]
    truth = val.truth.loc[v.index, ["X_mm", "Y_mm", "Z_mm"]].to_numpy()
    dp, _, _ = displacements(v, positions_mm[ok])
    dt, _, _ = displacements(v, truth)
    return 1e3 * np.sqrt(np.mean((dp - dt) ** 2, axis=0))


@pytest.fixture(scope="session")
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


def test_the_default_reaches_the_noise_floor_over_the_volume_on_stage_moves(volume):
    cal, val = volume
    model = slmlab.calibrate(cal)
    sel = model.calibration["selection"]
    assert model.name == "auto" and set(sel["choice"].values()) <= set(sel["held_out_rms_mm"])
    assert "soloff" in sel["skipped"]   # a plate whose place on the stage is unknown
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


@pytest.mark.slow  # calibrate and reconstruct on the command line
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


# ----------------------------------------------------------------------------- uncertainty, cross-validation
def test_uncertainty_intervals_hold_what_they_promise_on_a_perfect_stage(volume):
    cal, val = volume
    coverage = workspace.uncertainty_coverage(slmlab.calibrate(cal), val)
    assert all(abs(coverage[c] - 95) <= 2 for c in "XYZ"), coverage


@pytest.mark.slow  # two calibrations and their difference over the workspace
def test_independent_calibrations_differ_about_as_much_as_predicted():
    m = perfect_stage()
    a, b = (slmlab.calibrate(slmlab.simulate_set(m, slmlab.paper_test(2), seed=s)) for s in (11, 12))
    d = workspace.cross_validation_diff(a, b, workspace.workspace_grid(m, slmlab.paper_test(2), n_xy=9))
    for c in "XYZ":
        ratio = np.sqrt(np.mean(d[f"d{c}_um"] ** 2)) / np.sqrt(np.mean(d[f"predicted_{c}_um"] ** 2))
        assert 0.4 < ratio < 2.5, (c, ratio)


def test_model_files_without_a_fitted_frame_still_load(tmp_path, volume):
    """Files written before the frame was fitted (fixed normalisation, disparity along w1) reconstruct as
    they did."""
    cal, _ = volume
    model = slmlab.calibrate(cal, "direct", degree=2, variables=3)
    legacy = DirectModel(model.degree, np.zeros_like(model.coef), model.const)
    assert legacy.frame == LEGACY_FRAME
    w = cal.points[["wl1", "wl2", "wr1", "wr2"]].dropna().to_numpy()[:5]
    assert np.allclose(legacy.reconstruct(w), model.const)
    path = legacy.save(tmp_path / "old.json")
    assert np.allclose(slmlab.load_model(path).reconstruct(w), model.const)


def test_thinning_positions_renumbers_each_sequence():
    cal = slmlab.simulate_set(perfect_stage(), slmlab.paper_test(5), seed=1)
    thin = workspace.subsample_positions(cal, 3)
    for s in "XYZ":
        n = cal.sequence(s)["position"].nunique()
        assert sorted(thin.sequence(s)["position"].unique()) == list(range(1, (n - 1) // 3 + 2))
    assert len(thin.sequence("grid")) == len(cal.sequence("grid"))


# ----------------------------------------------------------------------------- Z stack alone
@pytest.fixture(scope="session")
def zstack():
    m = perfect_stage()
    mz = m.replace(moving_plate=zstack_plate())
    cal = slmlab.simulate_set(mz, zstack_session(11), seed=1)
    val = slmlab.simulate_set(m, volume_session(20, seed=5), seed=7)
    return cal, val, zstack_frame(mz)


@pytest.mark.slow  # the default's selection on a z stack, against the floor over a volume
def test_a_z_stack_alone_calibrates_to_the_noise_floor(zstack):
    cal, val, frame = zstack
    assert set(cal.points["sequence"]) == {"Z"}
    model = slmlab.calibrate(cal)
    assert model.name == "auto" and model.calibration["selection"]["mode"] == "zstack"
    t = workspace.volumetric_comparison({"z": model}, val, frame=frame).set_index("model").loc["z"]
    assert all(t[f"{c}_vs_floor"] <= 1.2 for c in "XYZ"), t
    # in the stage frame instead, the plate's mounting rotation shows as large X, Y errors: the frame matters
    wrong = workspace.volumetric_comparison({"z": model}, val).set_index("model").loc["z"]
    assert wrong["X_vs_floor"] > 5


def test_mode_moves_on_a_z_stack_is_a_clear_error(zstack):
    cal, _, _ = zstack
    with pytest.raises(slmlab.SlmlabError, match="zstack"):
        slmlab.calibrate(cal, mode="moves")


def test_the_disparity_direction_is_found_from_the_data(volume):
    cal, _ = volume
    u = slmlab.calibrate(cal).frame["direction"]
    assert abs(u[0]) > 0.999   # a CMO microscope: depth moves the disparity along w1


# ----------------------------------------------------------------------------- the real Z stack
@pytest.fixture(scope="session")
def piv(dataset_folder):
    return dataset_folder("pivchallenge-case-e")


def uvmat_common_points(folder) -> pd.DataFrame:
    """The points both cameras picked, as the UVMAT lists give them (pixels from 1): ``X_mm, Y_mm, Z_mm,
    u_cam1_px, v_cam1_px, u_cam3_px, v_cam3_px``, read file by file and merged on the world point."""
    key = ["X_mm", "Y_mm", "Z_mm"]
    cams = []
    for cam in ("Camera_01", "Camera_03"):
        t = pd.concat([converters.read_uvmat_points(p) for p in sorted((folder / cam).glob("img_*.xml"))])
        t[key] = t[key].round(6)
        n = cam[-1]
        cams.append(t.rename(columns={"u_px": f"u_cam{n}_px", "v_px": f"v_cam{n}_px"}))
    return cams[0].merge(cams[1], on=key)


def test_the_piv_challenge_point_lists_convert_to_the_interchange_format(tmp_path, piv):
    cal = converters.pivchallenge_set(piv)
    csv = uvmat_common_points(piv)
    assert len(cal.points) == len(csv) == 112
    assert sorted(cal.points["position"].unique()) == list(range(1, 8))
    back = slmlab.read_set(slmlab.write_set(tmp_path / "piv", cal))
    xy = plate_xy(back.points["row"], back.points["col"], back.plate("Z")) + back.points[["stage_x_mm", "stage_y_mm"]].to_numpy()
    # UVMAT counts pixels from 1 (MATLAB), slmlab from 0
    origin = converters.UVMAT_PIXEL_ORIGIN
    merged = pd.DataFrame({"X_mm": xy[:, 0], "Y_mm": xy[:, 1], "Z_mm": back.points["stage_z_mm"],
                           "u_cam1_px": back.points["wl1"] + origin, "v_cam3_px": back.points["wr2"] + origin})
    joined = merged.round(6).merge(csv.round(6), on=["X_mm", "Y_mm", "Z_mm", "u_cam1_px", "v_cam3_px"])
    assert len(joined) == 112      # every converted point is one of the lists' common points, at its own X, Y, Z


def test_the_real_z_stack_calibrates_and_its_uncertainty_is_the_right_size(piv):
    cal = converters.pivchallenge_set(piv)
    direct = slmlab.calibrate(cal, "direct")
    assert direct.options["mode"] == "zstack" and abs(direct.frame["direction"][1]) > 0.99  # oblique camera: rows
    lopo = workspace.leave_one_plane_out(cal, {"default": {}, "linear": {"model": "direct", "degree": 1}})
    rms = lopo.groupby("model")[["EX_um", "EY_um", "EZ_um"]].apply(lambda g: np.sqrt((g ** 2).mean()))
    assert (rms.loc["linear"] > 3 * rms.loc["default"]).all(), rms   # the initial linear model is not enough
    d = lopo[lopo["model"] == "default"]
    for c in "XYZ":
        ratio = np.sqrt(np.mean(d[f"E{c}_um"] ** 2)) / np.mean(d[f"s{c}_um"])
        assert 0.5 < ratio < 2.0, (c, ratio)


def test_the_grid_plate_measures_the_stages_scale_error():
    m = workspace.perfect_stage(slmlab.preset("paper"), keep=("scale_error",))
    cal = slmlab.simulate_set(m, slmlab.paper_test(1), seed=1)
    val = slmlab.simulate_set(m, volume_session(20, seed=5), seed=7)
    default = slmlab.calibrate(cal)
    measured = default.calibration["stage_xy_scale_error_vs_plate"]
    assert abs(measured[0] - m.stage.scale_error[0]) < 2e-5, measured
    plate = slmlab.calibrate(cal, length_reference="plate")
    t = workspace.volumetric_comparison({"stage": default, "plate": plate}, val).set_index("model")
    assert t.loc["plate", "X_vs_floor"] < 1.2 < t.loc["stage", "X_vs_floor"], t


@pytest.mark.slow  # four command-line calibrations
def test_calibrate_takes_model_options_on_the_command_line(tmp_path, volume):
    cal, _ = volume
    d = slmlab.write_set(tmp_path / "cal", cal)
    out = tmp_path / "m.json"
    ok = subprocess.run([sys.executable, "-m", "slmlab", "calibrate", d, "--out", out, "--model", "direct",
                         "--option", "degree=[3,3,2]", "--option", "length_reference=plate"], timeout=300)
    assert ok.returncode == 0
    model = slmlab.load_model(out)
    assert model.options["length_reference"] == "plate" and model.calibration["degree_per_coordinate"] == [3, 3, 2]
    for bad in ("degre=3", "degree=9", "length_reference=ruler"):
        r = subprocess.run([sys.executable, "-m", "slmlab", "calibrate", d, "--out", tmp_path / "x.json",
                            "--option", bad], capture_output=True, text=True, timeout=300)
        assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, (bad, r.stderr)
        assert not (tmp_path / "x.json").exists()


def test_the_commanded_frame_limit_is_the_floor_on_a_perfect_stage_and_above_it_otherwise(volume):
    _, val = volume
    perfect = workspace.commanded_frame_limit(perfect_stage(), slmlab.paper_test(1), val, repeats=3)
    assert np.allclose(perfect["attainable_vs_floor"], 1.0, atol=1e-6)
    noisy = workspace.perfect_stage(slmlab.preset("paper"), keep=("positioning_noise_um",))
    limit = workspace.commanded_frame_limit(noisy, slmlab.paper_test(1), val, repeats=3)
    assert (limit["attainable_vs_floor"][:2] > 1.1).all(), limit


def test_the_variance_cache_changes_no_result_and_hands_out_copies(paper_set):
    from slmlab.models import direct
    from slmlab.io import json_text

    direct._VARIANCE_CACHE.clear()
    cold = json_text(slmlab.calibrate(paper_set).to_dict())
    assert direct._VARIANCE_CACHE, "the default's fits should have filled the cache"
    (s_e2, _), precision = next(iter(direct._VARIANCE_CACHE.values()))
    before = (s_e2.copy(), precision.copy())
    warm = json_text(slmlab.calibrate(paper_set).to_dict())  # every estimate from the cache
    assert warm == cold
    (s_e2, _), precision = next(iter(direct._VARIANCE_CACHE.values()))
    assert np.array_equal(s_e2, before[0]) and np.array_equal(precision, before[1])  # nobody changed them


@pytest.mark.parametrize("mode, depths_by_position, cap", [
    ("zstack", {1: [0.0], 2: [0.1], 3: [0.2], 4: [0.3], 5: [0.4]}, 5),          # one depth per position: no cap
    ("target", {1: [0.0], 2: [0.1], 3: [0.2], 4: [0.3]}, 4),                    # a board stack, the same
    ("target", {1: [0.0, 0.3], 2: [0.2, 0.5]}, DEPTH_DEGREE + 1),               # a two-level plate at two positions
    ("target", {1: [0.0, 0.1, 0.2, 0.3, 0.4]}, DEPTH_DEGREE + 1),              # a stepped target in one pose
    ("target", {1: [0.0, 0.5]}, 2),                                            # a two-level plate in one pose
    ("target", {1: [0.0], 1_000_001: [0.0, 0.3], 2_000_001: [0.1], 2_000_002: [0.2], 2_000_003: [0.4]},
     DEPTH_DEGREE + 1),                                                        # in one of several sequences
    ("moves", {1: [0.0], 2: [0.1]}, 6),                                        # stage moves: max_degree + 1
])
def test_the_depth_cap_is_quadratic_only_where_a_position_holds_several_depths(mode, depths_by_position, cap):
    rows = [(p, z) for p, zs in depths_by_position.items() for z in zs for _ in range(3)]
    positions = np.array([p for p, _ in rows])
    target = np.column_stack([np.zeros(len(rows)), np.zeros(len(rows)), [z for _, z in rows]])
    assert _depth_cap(target, positions, mode, max_degree=5) == cap
