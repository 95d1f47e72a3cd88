"""The traditional pinhole stereo model (OpenCV): calibration, conditioning, stage maps, real images."""

import json

import numpy as np
import pytest

import slmlab
from slmlab import cli
from slmlab.models.pinhole import VARIANTS, calibrate_stereo, orthogonal_map
from slmlab.studies.workspace import perfect_stage, volumetric_comparison
from slmlab.virtual.sessions import volume_session
from slmlab.virtual.simulate import stepped_target, target_set
from slmlab.images.boards import chessboard_views
from slmlab.models.frames import world_positions
from slmlab.virtual.designs import simulate_design
from slmlab.virtual.rigs import rig_by_name
from slmlab.virtual.sessions import tilted_session


@pytest.fixture(scope="session")
def small_sets():
    m = slmlab.preset("paper")
    cal = slmlab.simulate_set(m, tilted_session(12, with_sequences=slmlab.paper_test(5)), seed=21)
    val = slmlab.simulate_set(m, slmlab.validation_session(), seed=22)
    return cal, val


def test_pinhole_model_file_round_trip_and_reports(small_sets, tmp_path):
    cal, val = small_sets
    m = slmlab.calibrate(cal, "pinhole", variant="standard", views_from=("X", "Y", "Z"))
    assert m.options["variant"] == "standard" and m.options["stage_map"] == "affine"
    assert np.isfinite(m.calibration["focal_std_px"]).all() and m.calibration["stereo_option"]
    back = slmlab.load_model(m.save(tmp_path / "p.json"))
    saved = json.loads((tmp_path / "p.json").read_text())
    assert set(saved["parameters"]) <= set(saved["units"]), set(saved["parameters"]) - set(saved["units"])  # each its unit
    w = val.sequence("Z")[["wl1", "wl2", "wr1", "wr2"]].dropna().to_numpy()
    np.testing.assert_allclose(back.reconstruct(w), m.reconstruct(w), atol=1e-9)


@pytest.mark.slow  # calibrates every pinhole variant
def test_variant_is_chosen_on_held_back_positions(small_sets):
    cal, _ = small_sets
    m = slmlab.calibrate(cal, "pinhole", views_from=("X", "Y", "Z"))
    scores = m.calibration["held_back_rms_mm"]
    assert set(scores) == set(VARIANTS)
    assert m.options["variant"] == min(scores, key=scores.get)


def test_the_paper_finding_holds_for_x_motion_in_depth(small_sets):
    """The pinhole model's E_X,Z is several times that of the direct mapping on the same data (how many
    times depends on the views OpenCV gets: notebook 06)."""
    cal, val = small_sets
    pin = slmlab.evaluate(slmlab.calibrate(cal, "pinhole", variant="standard", views_from=("X", "Y", "Z")), val)
    m2 = slmlab.evaluate(slmlab.calibrate(cal, "paper-m2", disparity_method="joint"), val)
    p, q = pin.summary.set_index("element"), m2.summary.set_index("element")
    assert p.loc["XZ", "max_abs_mm"] > 3 * q.loc["XZ", "max_abs_mm"]
    assert p.loc["XZ", "rms_mm"] > 3 * q.loc["XZ", "rms_mm"]


@pytest.mark.slow  # two pinhole calibrations (seconds each)
def test_a_rigid_stage_map_cannot_absorb_the_depth_scale_but_reads_a_mirror_image_the_right_way_round(small_sets):
    """The virtual microscope's image is a mirror image of the stage (its axes run along +x, +y seen from
    above), so the rigid camera-to-stage map is a reflection; a rotation forced on it read Y backwards (YY
    errors of twice the Y travel)."""
    cal, val = small_sets
    kw = dict(variant="standard", views_from=("X", "Y", "Z"))
    affine = slmlab.evaluate(slmlab.calibrate(cal, "pinhole", stage_map="affine", **kw), val).summary.set_index("element")
    rigid_model = slmlab.calibrate(cal, "pinhole", stage_map="rigid", **kw)
    rigid = slmlab.evaluate(rigid_model, val).summary.set_index("element")
    assert rigid.loc["ZZ", "rms_mm"] > 3 * affine.loc["ZZ", "rms_mm"]
    assert np.linalg.det(rigid_model.a) == pytest.approx(-1.0)
    y_travel = np.ptp(val.sequence("Y")["stage_y_mm"])
    assert rigid.loc["YY", "max_abs_mm"] < 0.01 * y_travel, rigid.loc["YY"]


def test_the_orthogonal_map_is_a_rotation_or_a_reflection_whichever_fits():
    rng = np.random.default_rng(0)
    src = rng.normal(size=(50, 3))
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    for a in (q * np.sign(np.linalg.det(q)), -q * np.sign(np.linalg.det(q))):   # det +1, then det -1
        np.testing.assert_allclose(orthogonal_map(src, src @ a.T + 1e-9 * rng.normal(size=src.shape)), a, atol=1e-6)


def test_tilted_plate_calibration(small_sets):
    cal, val = small_sets
    assert cal.sequence("T")["position"].nunique() == 12
    m = slmlab.calibrate(cal, "pinhole")  # tilted views by default when the set has them
    assert m.options["views_from"] == ["T"]
    assert m.calibration["stereo_rms_px"] < 5
    assert np.isfinite(slmlab.evaluate(m, val).summary["rms_mm"]).all()


def test_real_chessboard_stereo_rms_is_well_under_a_pixel(dataset_folder):
    lefts = sorted((dataset_folder("opencv-stereo-chessboard") / "images").glob("left*.jpg"))
    views, size = chessboard_views([(str(p), str(p).replace("left", "right")) for p in lefts])
    assert len(views) >= 10
    assert calibrate_stereo(views, size, "standard", f_guess_px=size[0]).rms_px < 0.6


@pytest.mark.slow  # extracts the 14 DICe image pairs
def test_real_dot_target_stereo_rms_is_well_under_a_pixel(dataset_folder):
    from slmlab.images.extract import extract_stereo_pairs

    lefts = sorted((dataset_folder("dice-calb-sys2") / "images").glob("*_0.jpeg"))
    counts = extract_stereo_pairs([(p, p.with_name(p.name.replace("_0.", "_1."))) for p in lefts], 8, 10)
    views = []
    for m in counts.attrs["tables"].values():
        obj = np.column_stack([m["col"] * 3.5, m["row"] * 3.5, np.zeros(len(m))]).astype(np.float32)
        views.append({"obj": obj, "l": m[["w1_l", "w2_l"]].to_numpy(np.float32), "r": m[["w1_r", "w2_r"]].to_numpy(np.float32)})
    assert calibrate_stereo(views, (2448, 2048), "standard", f_guess_px=4896).rms_px < 0.8


# ----------------------------------------------------------------------------------- known 3D targets
@pytest.fixture(scope="session")
def stepped():
    """The virtual stepped target (five heights over ±1 mm) in one pose, and a volume run to check on, on the
    paper preset with a perfect stage (the known-target floor of notebook 10)."""
    m = perfect_stage(slmlab.preset("paper"))
    return m, target_set(m, stepped_target(), [[0.0, 0.0, 0.0]], seed=3), \
        slmlab.simulate_set(m, volume_session(12, seed=5), seed=7)


@pytest.mark.slow  # pinhole calibrations (seconds each)
def test_pinhole_calibrates_a_one_pose_stepped_target_to_the_floor(stepped, tmp_path):
    _, cal, val = stepped
    d = slmlab.write_set(tmp_path / "set", cal)
    assert cli.main(["calibrate", str(d), "--model", "pinhole", "--out", str(tmp_path / "p.json")]) == 0
    model = slmlab.load_model(tmp_path / "p.json")
    assert model.calibration["image_mirrored"] and model.calibration["held_back"] == "every 3rd dot"
    scores = model.calibration["held_back_rms_mm"]
    assert model.options["variant"] == min(scores, key=scores.get)
    row = volumetric_comparison({"pinhole": model}, val).set_index("model").loc["pinhole"]
    assert max(row[f"{c}_vs_floor"] for c in "XYZ") <= 1.5, row


def test_a_target_that_is_not_mirrored_calibrates_too_and_one_mirrored_view_is_refused(stepped):
    """The virtual microscope's image is a mirror image of the world; flip one image axis in both views and it
    is not: the pinhole calibrates either way, to the same accuracy. One view flipped alone is refused."""
    _, cal, _ = stepped
    h = cal.image_size_px[1]
    flipped = cal.points.assign(wl2=h - 1 - cal.points["wl2"], wr2=h - 1 - cal.points["wr2"])
    plain = slmlab.calibrate(cal, "pinhole", variant="thin-prism")
    model = slmlab.calibrate(slmlab.CalibrationSet(flipped, cal.meta), "pinhole", variant="thin-prism")
    assert plain.calibration["image_mirrored"] and not model.calibration["image_mirrored"]
    pts = flipped.dropna(subset=["wl1", "wl2", "wr1", "wr2"])
    e = model.reconstruct(pts[["wl1", "wl2", "wr1", "wr2"]].to_numpy()) - cal.world(pts)
    assert np.sqrt(np.mean(e ** 2)) < 1e-3
    one = cal.points.assign(wl2=h - 1 - cal.points["wl2"])
    with pytest.raises(slmlab.SlmlabError, match="mirror image of the other"):
        slmlab.calibrate(slmlab.CalibrationSet(one, cal.meta), "pinhole", variant="standard")


def test_a_flat_target_in_one_pose_is_refused_for_the_real_reason(stepped):
    m, _, _ = stepped
    flat = stepped_target(rows=11, cols=11, steps_mm=(0.0,))
    with pytest.raises(slmlab.SlmlabError, match="Z cannot be determined"):
        slmlab.calibrate(target_set(m, flat, [[0.0, 0.0, 0.0]]), "pinhole")
    tilted = flat.assign(z_mm=0.1 * flat["x_mm"])          # a plane, but not the focal plane
    with pytest.raises(slmlab.SlmlabError, match="lie in one plane"):
        slmlab.calibrate(target_set(m, tilted, [[0.0, 0.0, 0.0]]), "pinhole")
    # the same board at two stage Z positions is a 3D target: no stage map needed, none asked for
    two = slmlab.calibrate(target_set(m, flat, [[0.0, 0.0, -0.3], [0.0, 0.0, 0.3]]), "pinhole", variant="thin-prism")
    assert two.calibration["world_from"].endswith("2 stage position(s)")


@pytest.mark.parametrize("bad", [0, -3, 2.5, "many", None, float("inf")])
def test_the_iterations_option_is_a_whole_number_of_at_least_one(stepped, bad):
    _, cal, _ = stepped
    with pytest.raises(slmlab.SlmlabError, match="iterations must be a whole number"):
        slmlab.calibrate(cal, "pinhole", variant="standard", iterations=bad)


@pytest.mark.slow  # pinhole calibrations (seconds each)
def test_a_z_stack_of_two_planes_calibrates_as_one_3d_view():
    """A Z stack of a plate of known lattice gives every dot's world position, like a known target: the pinhole
    pair calibrates on two planes (as plate views it would need three), in the plate's frame, and gives the
    calibration dots back to about the stereo-DIC pair's noise floor (1 µm in X, Y; 4 µm in Z)."""
    cal = simulate_design(rig_by_name("stereo-dic"), "zstack-2", seed=3)
    model = slmlab.calibrate(cal, "pinhole", variant="thin-prism")
    assert model.calibration["world_from"].startswith("Z stack of a plate: one view of")
    rows, world, mode = world_positions(cal)
    assert mode == "zstack"
    e = model.reconstruct(rows[["wl1", "wl2", "wr1", "wr2"]].to_numpy(float)) - world
    assert np.all(np.sqrt(np.mean(e ** 2, axis=0)) < [0.002, 0.002, 0.008]), e


def test_a_pinhole_pair_that_triangulates_to_nothing_is_a_candidate_that_cannot_calibrate():
    """A hand-made two-level set whose views no pinhole pair describes triangulated to NaN, and the affine map to
    the world ended in NumPy's LinAlgError (a traceback from calibrate): it is a SlmlabError, which the default
    takes as a candidate that cannot calibrate the set."""
    from slmlab.models.pinhole import fit_world_map
    p = np.zeros((10, 3))
    p[3] = np.nan
    with pytest.raises(slmlab.SlmlabError, match="triangulates 1 of 10 dots to no point"):
        fit_world_map(p, np.ones((10, 3)))
