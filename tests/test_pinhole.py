"""The traditional pinhole stereo model (OpenCV): calibration, conditioning, stage maps, real images."""

import numpy as np
import pytest

import slmlab
from slmlab.models.pinhole import VARIANTS, calibrate_stereo
from slmlab.images.boards import chessboard_views
from slmlab.virtual.sessions import tilted_session


@pytest.fixture(scope="module")
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


def test_a_rigid_stage_map_cannot_absorb_the_depth_scale(small_sets):
    cal, val = small_sets
    kw = dict(variant="standard", views_from=("X", "Y", "Z"))
    affine = slmlab.evaluate(slmlab.calibrate(cal, "pinhole", stage_map="affine", **kw), val).summary.set_index("element")
    rigid = slmlab.evaluate(slmlab.calibrate(cal, "pinhole", stage_map="rigid", **kw), val).summary.set_index("element")
    assert rigid.loc["ZZ", "rms_mm"] > 3 * affine.loc["ZZ", "rms_mm"]


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
