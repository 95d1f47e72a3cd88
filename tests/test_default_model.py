"""The default model's choice where the set has few depths: between the calibrated depths nothing is measured,
and the pinhole pair (perspective) decides where it fits the rig; where it does not (refraction through a
window), it is no reference and is not chosen. Errors are held against the truth of the zoo's rigs."""

import numpy as np
import pytest

from slmlab.models import calibrate
from slmlab.models.direct import _exponents, _nvar
from slmlab.studies.zoo import compare_models
from slmlab.virtual import designs
from slmlab.virtual.designs import simulate_design
from slmlab.virtual.rigs import rig_by_name

pytestmark = pytest.mark.slow  # zoo calibrations with every candidate (seconds each)


def _table(rig: str, design: str, seed: int):
    return compare_models(rig_by_name(rig), design, seed=seed, models=("auto",)).set_index("model")


@pytest.mark.parametrize("seed", [1, 2])
def test_on_two_planes_of_a_stereo_dic_pair_depth_comes_from_the_pinhole(seed):
    """A model linear in depth cannot follow perspective's bow between two planes; the pinhole pair can, and the
    default takes depth from it: near the floor, and below every plain polynomial (held against the truth)."""
    t = _table("stereo-dic", "zstack-2", seed)
    assert "Z" in t.loc["pinhole", "chosen_for"]
    sel = t.attrs["selection"]  # the direct model bends away from the pinhole between the planes, in the evidence
    assert sel["between_depths_mm"]["direct"][2] > 5 * sel["held_out_rms_mm"]["direct"][2], sel
    assert t.loc["pinhole", "note"].endswith("affine map from Z stack of a plate)")
    polys = t[t.index.str.startswith("polynomial")]
    assert t.loc["auto", "Z_um"] <= 1.3 * t.loc["floor", "Z_um"], t[["X_um", "Y_um", "Z_um"]]
    assert t.loc["auto", "Z_um"] < polys["Z_um"].min()
    assert t.loc["direct", "Z_um"] > 3 * t.loc["auto", "Z_um"]  # what the old choice gave


def test_behind_a_window_the_pinhole_is_no_reference_and_is_not_chosen():
    """Refraction through a flat wall is not a pinhole camera: its reprojection error is several times the Soloff
    polynomials', so it is neither cross-validated, nor a reference between the depths, nor chosen; the default
    stays near the floor."""
    t = _table("stereo-piv", "zstack-2", 1)
    sel = t.attrs["selection"]
    assert "pinhole" not in sel["held_out_rms_mm"] and "pinhole" not in sel["choice"].values()
    assert sel["skipped"]["pinhole"].startswith("not cross-validated: it does not describe the rig")
    # what it would have said: the pinhole's error in the volume is several times the floor's in X and Y
    assert (t.loc["pinhole", ["X_um", "Y_um"]] > 2.5 * t.loc["floor", ["X_um", "Y_um"]]).all()
    assert not sel["between_depths_mm"]  # the pinhole judges nothing
    xyz = ["X_um", "Y_um", "Z_um"]
    ratio = t.loc["auto", xyz].to_numpy(float) / t.loc["floor", xyz].to_numpy(float)
    assert np.all(ratio <= 1.2), ratio


def test_with_enough_planes_the_pinhole_is_not_a_candidate():
    sel = calibrate(simulate_design(rig_by_name("stereo-dic"), "zstack-5", seed=1)).calibration["selection"]
    assert "pinhole" not in sel["held_out_rms_mm"]
    assert sel["skipped"]["pinhole"].startswith("not needed: 5 depths, whose held-out interior planes")


def test_many_depths_at_few_positions_need_no_pinhole_and_say_why():
    """Six depths at three positions hold out no plane, only dots within positions; the pinhole is not a
    candidate there, and the reason given is the depths, not held-out planes that no fold holds out."""
    sel = calibrate(simulate_design(rig_by_name("stereo-dic"), "two-level-3z", seed=1)).calibration["selection"]
    assert "pinhole" not in sel["held_out_rms_mm"]
    assert sel["skipped"]["pinhole"] == ("not needed: 6 depths, the candidates judge each other's bends between "
                                         "them (with direct or soloff among them)")
    assert sel["held_out_by"].startswith("5 folds of held-out dots within every position")


def test_candidates_that_bend_between_close_depths_are_dropped():
    """A two-level plate at three positions of a random Greenough rig: six depths in close pairs, no plane held
    out. The polynomial of degree 4 is first by held-out dots within positions in X and Y and bends between the
    depths (3.6 and 5.9 times the cubic in X and Y inside the volume); the other candidates catch it, and the
    default is within 5 % of the best plain polynomial in every coordinate. The direct model, of degree 5 in
    depth through those six depths before it was held to a quadratic, was first by held-out dots in Z and 2.9
    times the cubic; quadratic, it bends no more and is not dropped (the rule that dropped it is held on
    made-up numbers in test_models)."""
    t = _table("greenough:1", "two-level-3z", 1)
    sel = t.attrs["selection"]
    assert {"polynomial-4 (X)", "polynomial-4 (Y)"} <= set(sel["skipped"]), sel["skipped"]
    assert sel["skipped"]["polynomial-4 (X)"].startswith("bends between the 6 calibrated depths")
    best = t.loc[t.index.str.startswith("polynomial"), ["X_um", "Y_um", "Z_um"]].min()
    assert (t.loc["auto", ["X_um", "Y_um"]] <= 1.05 * best[["X_um", "Y_um"]]).all(), (t.loc["auto"], best)
    assert "direct (Z)" not in sel["skipped"] and t.loc["direct", "Z_um"] <= 1.05 * best["Z_um"], sel["skipped"]
    assert t.loc["auto", "Z_um"] <= 1.05 * best["Z_um"], (t.loc["auto"], best)


@pytest.mark.parametrize("seed", [1, 2])
def test_a_position_s_stage_error_is_not_a_candidate_s_merit(seed):
    """A two-level plate at three positions of the Greenough rig (stage noise several times the floor): held-out
    dots within a position share its stage error, which a polynomial learns from the others as optics and the
    direct model keeps out as a random effect. Measured net of each position's offset, the default is within
    1.12x its best candidate in X and Y (held against the truth; before: 1.69x in X on seed 1, a 4th-degree
    polynomial). Not 1.05x: on seed 2 the direct model is 4 % better than the cubic in Y on held-out dots, not
    the 5 % a candidate needs to beat a plain polynomial, and 1.11x better in the volume."""
    t = _table("greenough", "two-level-3z", seed)
    xy = ["X_um", "Y_um"]
    cands = t.drop(index=["floor", "frame floor", "auto"])[xy].min()
    assert (t.loc["auto", xy] <= 1.12 * cands).all(), t[xy]
    assert (t.loc["auto", xy] <= 1.2 * t.loc["floor", xy]).all(), t[xy]


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_two_positions_of_a_two_level_plate_on_a_micrometre_stage(seed):
    """Two positions of a two-level plate on the Greenough rig's stage (0.3 um per move against a 0.07 um floor):
    the target's own depth disagrees with the stage's move, a flexible candidate learns the disagreement as optics
    (the best held-out dots) and bends between the depths. The pinhole pair describes the optics (step 0), judges
    the bend, and the default is within 1.05x the floor in the commanded frame in X and Y (before: 2.05x on seed
    1, a polynomial of degree 4). The direct model, quadratic in depth (each position's two levels share its
    stage error, its random effect), tells the stage's error from the optics and is within 1.1x the noise floor
    itself, below the floor in the commanded frame; the default does not take it: held-out dots within the
    positions share their position's error and cannot show it (a known gap, notebook 11)."""
    t = _table("greenough", "two-level-2z", seed)
    sel, xy = t.attrs["selection"], ["X_um", "Y_um"]
    assert sel["stage"]["pinhole_fits"] and sel["between_depths_mm"]
    assert (t.loc["auto", xy] <= 1.05 * t.loc["frame floor", xy]).all(), t[xy]
    assert (t.loc["direct", xy] <= 1.1 * t.loc["floor", xy]).all(), t[xy]


@pytest.mark.parametrize("rig, design", [("greenough:12", "two-level-2z"), ("greenough:13", "two-level-2z"),
                                         ("greenough:14", "two-level-3z")])
def test_at_few_positions_of_a_deep_target_a_position_s_offset_is_not_held_against_a_model(rig, design):
    """A two-level plate at two or three stage positions of random Greenough rigs (stage noise several times the
    floor): the plate's own depth tells each position's stage error, which the direct model keeps out of the optics
    as a random effect and a polynomial learns as optics. Held-out dots measured net of their position's offset
    (:func:`slmlab.models.auto._deep_target_at_few_positions`), the default takes the direct model and is within
    1.05x its best candidate inside the volume in X and Y (before: a cubic or the Soloff model, 4.6x in Y on
    greenough:12 at two positions, 2.3x in X on greenough:13, 3.5x in X on greenough:14 at three), and within 1.2x
    the noise floor."""
    t = _table(rig, design, int(rig.split(":")[1]))
    xy = ["X_um", "Y_um"]
    cands = t.drop(index=["floor", "frame floor", "auto"])[xy].min()
    assert (t.loc["auto", xy] <= 1.05 * cands).all(), t[xy]
    assert (t.loc["auto", xy] <= 1.2 * t.loc["floor", xy]).all(), t[xy]


@pytest.mark.parametrize("design, diagonal", [("zstack-5", False), ("zstack-7", False), ("zstack-7", True)])
def test_crossed_folds_test_every_dot_of_the_end_planes_once(design, diagonal):
    """The planes held out whole are interior; the end planes' dots are tested too, each once, with their
    plane in the training (a candidate too stiff in depth misses most at the ends). No test row is trained on."""
    from slmlab.models.folds import position_folds, row_folds
    from slmlab.models.frames import world_positions
    pts, _, mode = world_positions(simulate_design(rig_by_name("stereo-dic"), design, seed=1), "auto")
    folds = row_folds(pts, mode, diagonal=diagonal)
    tested = np.sum([te for _, te in folds], axis=0)
    ends = ~np.logical_or.reduce(position_folds(pts))
    assert ends.any() and np.all(tested[ends] == 1)
    assert all(not (tr & te).any() for tr, te in folds)
    for tr, te in folds:  # an end plane tested is in the training, by its other dots
        for pos in np.unique(pts.loc[te & ends, "position"]):
            assert (tr & (pts["position"] == pos).to_numpy()).any()


def test_a_thinned_set_keeps_every_fold_of_dots():
    """Every k-th dot of a 27 × 48 lattice (k = 5) fell in one fold of ``(row + 2·col) mod 5``: a random stereo-PIV
    rig's 13-plane stack had no crossed fold with both training and test rows, and ``calibrate`` crashed. Thinned
    within each fold, the five folds keep a fifth of the dots each, and every kept dot keeps all its positions."""
    import pandas as pd
    from slmlab.models.folds import dot_folds, thin_dots
    rows, cols = np.meshgrid(np.arange(1, 28), np.arange(1, 49), indexing="ij")
    one = pd.DataFrame({"row": rows.ravel(), "col": cols.ravel()})
    pts = pd.concat([one.assign(position=p) for p in (1, 2)], ignore_index=True)
    keep = thin_dots(pts, 520)                          # k = 5
    counts = np.bincount(dot_folds(pts[keep]), minlength=5)
    assert counts.min() > 0 and counts.max() - counts.min() <= 2, counts
    assert keep.sum() <= 520 + 2 * 5
    kept = pts[keep].groupby(["row", "col"])["position"].nunique()
    assert (kept == 2).all()


@pytest.mark.parametrize("seed", [1, 2])
def test_a_model_too_stiff_in_depth_is_not_chosen_for_z_on_a_charuco_stack(seed):
    """A five-plane ChArUco stack of the Greenough rig: tested on interior planes alone, the Soloff model linear in
    depth looked best in Z and was 1.28x the best candidate inside the volume (seed 1). With the end planes'
    dots tested too, the default's Z is within 5 % of its best candidate and no worse than the best plain
    polynomial (held against the truth)."""
    t = _table("greenough", "charuco-stack", seed)
    cands = t.drop(index=["floor", "frame floor", "auto"])
    polys = cands[cands.index.str.startswith("polynomial")]
    assert t.loc["auto", "Z_um"] <= 1.05 * cands["Z_um"].min(), t[["X_um", "Y_um", "Z_um"]]
    assert t.loc["auto", "Z_um"] <= polys["Z_um"].min(), t[["X_um", "Y_um", "Z_um"]]


@pytest.mark.parametrize("seed", [1, 2])
def test_a_two_level_plate_in_one_pose_takes_depth_from_the_pinhole(seed, monkeypatch):
    """A stereo-DIC two-level plate in one pose (two depths), its second level 0.6 of the rig's depth behind
    (5.9 mm; the zoo's plate is shallower, 3.7 mm, so that its markers stay readable: here only its points
    count): a cubic in the four image coordinates that differs from the pinhole between the depths by more than
    either's held-out scatter bends where nothing was measured, and is dropped for Z (at 1.5 times that scatter
    it stayed, at 1.10x the pinhole inside the volume on seed 1). The default's Z is within 5 % of its best
    candidate (held against the truth)."""
    monkeypatch.setattr(designs, "TWO_LEVEL_PARALLAX", 1.0)   # deep enough that 0.6 of the depth bounds it
    t = _table("stereo-dic", "two-level", seed)
    sel = t.attrs["selection"]
    cands = t.drop(index=["floor", "frame floor", "auto"])
    assert t.loc["auto", "Z_um"] <= 1.05 * cands["Z_um"].min(), t[["X_um", "Y_um", "Z_um"]]
    if seed == 1:
        assert sel["choice"]["Z"] == "pinhole" and "polynomial-3 (Z)" in sel["skipped"], sel


def test_with_every_third_plane_held_out_no_end_plane_is_claimed():
    """Beyond eight planes every third plane is held out whole, the end planes among them: none is left to
    test by its dots, and the model file does not say so."""
    from slmlab.models.folds import end_planes, fold_description, position_folds
    from slmlab.models.frames import world_positions
    pts, _, mode = world_positions(simulate_design(rig_by_name("stereo-dic"), "zstack-13", seed=1), "auto")
    assert not end_planes(position_folds(pts)).any()
    assert "end planes" not in fold_description(pts, mode)
    pts5, _, mode5 = world_positions(simulate_design(rig_by_name("stereo-dic"), "zstack-5", seed=1), "auto")
    assert fold_description(pts5, mode5).endswith("the end planes' dots in turn")


def test_a_stage_error_estimate_that_feeds_on_itself_is_not_kept():
    """A 13-plane stack of a random Greenough rig: each position is one depth, so only the positions' means show
    how Y changes with depth. The direct model's estimate of the stage's error per position in Y grew at every
    iteration (0.23, 0.40, 0.56 ... 3.5 um), down-weighting those means until Y took a shear of 0.7 % of depth:
    1.8 um RMS inside the volume, which the default chose (10.6x the best plain polynomial). An estimate that
    is still rising when the iterations end is not kept; the first one is (the direct model's Y 0.20 um RMS)."""
    direct = calibrate(simulate_design(rig_by_name("greenough:3"), "zstack-13", seed=1), "direct")
    assert direct.calibration["stage_error_per_position_mm"][1] < 0.3e-3  # the first estimate, 0.23 um
    t = _table("greenough:3", "zstack-13", 1)
    polys = t.loc[t.index.str.startswith("polynomial"), ["X_um", "Y_um"]].min()
    for model in ("direct", "auto"):  # 1.2x in Y, where the default still takes the direct model: not 10x
        assert (t.loc[model, ["X_um", "Y_um"]] <= 1.3 * polys).all(), t[["X_um", "Y_um", "Z_um"]]


def test_the_direct_model_is_at_most_quadratic_in_depth_where_the_depths_are_known():
    """A two-level plate at two stage positions of a random stereo-PIV rig: four depths, each position's stage
    error shared by both of its levels. Cubic in depth, the direct model followed those errors as optics (the
    default took it at 1.39x the best plain polynomial in X and Y); quadratic (the Soloff model's Z), it is below
    the best plain polynomial in X and Y, and the default is no worse than that polynomial."""
    cal = simulate_design(rig_by_name("stereo-piv:3"), "two-level-2z", seed=1)
    direct = calibrate(cal, "direct")
    exps = _exponents(int(np.max(direct.degree)), _nvar(direct.frame))
    assert len(exps) == len(direct.coef)
    cubic = np.array([e[2] >= 3 for e in exps])
    assert not np.any(np.asarray(direct.coef)[cubic]), "a power of D above 2"
    assert np.any(np.asarray(direct.coef)[np.array([e[2] == 2 for e in exps])])
    t = _table("stereo-piv:3", "two-level-2z", 1)
    polys = t.loc[t.index.str.startswith("polynomial"), ["X_um", "Y_um"]].min()
    assert (t.loc["direct", ["X_um", "Y_um"]] < polys).all(), t[["X_um", "Y_um", "Z_um"]]
    assert (t.loc["auto", ["X_um", "Y_um"]] <= 1.02 * polys).all(), t[["X_um", "Y_um", "Z_um"]]


@pytest.mark.parametrize("rig, design, seed", [("stereo-dic", "two-level-2z", 1), ("greenough:2", "zstack-3", 1),
                                               ("stereo-dic", "zstack-3", 1)])
def test_in_z_a_candidate_pays_half_its_difference_from_the_pinhole(rig, design, seed):
    """Few depths, the pinhole pair judging: in Z a candidate's difference from it between the depths is the two
    models' together, and half of it counts as the candidate's error. Without it, the polynomial of degree 4 took
    Z on the stereo-DIC two-level plate at two positions (held-out 4.50 um against the pinhole's 4.52, 3.1 um apart
    between the depths) at 1.24x the best candidate inside the volume and 1.12x the best plain polynomial, and
    the cubic took a Greenough stack of three planes (greenough:2) at 1.21x and 1.17x. Charged the whole
    difference, the pinhole's own bend took Z from the direct model on the stereo-DIC rig's three planes at 1.07x.
    Now the default's Z is within 5 % of its best candidate and no worse than the best plain polynomial in all
    three (held against the truth)."""
    t = _table(rig, design, seed)
    assert t.attrs["selection"]["between_depths_mm"]  # the pinhole judged
    cands = t.drop(index=["floor", "frame floor", "auto"])
    polys = cands[cands.index.str.startswith("polynomial")]
    assert t.loc["auto", "Z_um"] <= 1.05 * cands["Z_um"].min(), t[["X_um", "Y_um", "Z_um"]]
    assert t.loc["auto", "Z_um"] <= polys["Z_um"].min(), t[["X_um", "Y_um", "Z_um"]]


def test_on_stage_moves_a_candidate_that_bends_between_the_arms_is_outvoted():
    """The paper's cross of stage sequences on a random stereo-DIC rig: held-out interior positions lie on the
    arms, where the cubic is first in X (2.69 µm against the direct model's 2.95 and the quartic's 2.93); between
    the arms, where a user measures too, it was 3.7 times the best candidate. There the direct model and the
    quartic agree (0.4 µm apart) and the cubic is 4.6 µm from both: it is dropped, and the default is within 5 %
    of its best candidate and of the best plain polynomial in every coordinate (held against the truth)."""
    t = _table("stereo-dic:24", "stage-sequences", 24)
    sel = t.attrs["selection"]
    assert sel["skipped"]["polynomial-3 (X)"].startswith("bends between the arms of the stage's moves"), sel["skipped"]
    cands = t.loc[[c for c in sel["held_out_rms_mm"]], ["X_um", "Y_um", "Z_um"]].min()
    polys = t.loc[t.index.str.startswith("polynomial"), ["X_um", "Y_um", "Z_um"]].min()
    assert (t.loc["auto", ["X_um", "Y_um", "Z_um"]] <= 1.05 * cands).all(), (t.loc["auto"], cands)
    assert (t.loc["auto", ["X_um", "Y_um", "Z_um"]] <= 1.05 * polys).all(), (t.loc["auto"], polys)
