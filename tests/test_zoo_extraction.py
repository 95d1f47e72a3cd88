"""Rendered images of the zoo's rigs with what real cameras do, and the extractor that reads any plate a person
can see: the degradations one by one (a few, small), the command line from simulate --rig --images to extract,
the known targets, the real samples (PIV Challenge case E, DICe, fluidimage), and the CMO microscope's images
unchanged by the new renderer."""

import hashlib
import subprocess
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from scipy.optimize import least_squares

import slmlab
from slmlab.datasets import converters
from slmlab.images.dots import read_image
from slmlab.images.extract import extract_image, report_summary
from slmlab.images.imageset import extract_set
from slmlab.io import write_set
from slmlab.virtual.designs import simulate_design
from slmlab.studies import realrigs
from slmlab.studies.extraction import (_degradation_row, extraction_by_degradation, plate_in_view_set,
                                       rig_extraction_errors)
from slmlab.virtual import floor
from slmlab.virtual.floor import CELL, fisher_floor, rendered_floor, rendered_floors
from slmlab.virtual.render import (Degradations, render_board_set, render_plate, render_rig_set, render_set,
                                   rendered_truth, rig_degradations)
from slmlab.virtual.rigs import make_rig, random_rig, rig_by_name


def cli(*args):
    return subprocess.run([sys.executable, "-m", "slmlab", *map(str, args)], capture_output=True, text=True, timeout=600)


# SHA-256 of the pixels of the CMO microscope's images as the renderer wrote them before the zoo's renderer
# shared its code (commit 5efe2aa): Test 5, seed 4, position 1 of the grid and Z sequences; a plate; a ChArUco
# board. The pixels, not the PNG files' bytes: the encoder's settings changed in commit 68dd142 (its bytes, not its
# pixels). These were taken from files written with the old settings whose bytes still had the hashes pinned
# before (a check run, /work/scratch/pixhash.py).
CMO_PIXELS = {
    "Z_001_l.png": "c1c1841384e82e2518c5d17b82be5d225a6edcf93f8c70840cf1af040d5a8ed6",
    "Z_001_r.png": "22b1c788c1dcfe956fa5e5e77c901f6a4eb48cae4e7a3c78b28a4157a61e8aed",
    "grid_001_l.png": "a648c81af5a606b21a8290de300443d8fd30a54766378fdf2bcf3f2e8fbde72b",
    "grid_001_r.png": "b4bddd972aecad1e9dcb83828f9014b38081e2cc3f3798bb5d412d184d4409f0",
    "plate": "fb1a82cbbbaf75767c433b9cff0e1b4c973f45c5d7b2cd21362139b9df4dcf50",
    "board Z_001_l.png": "2b961f2e019a606b32bbbe2f0ec3364dda83099ec8420c3f006f4cae408edbd0",
    "board Z_001_r.png": "8ff46245391153cb91b3d6531fae7b841aff680a7c6b417bc63e5f7a17f8fbd3",
}


def _pixels(path) -> str:
    return hashlib.sha256(read_image(path).tobytes()).hexdigest()


def test_the_cmo_microscope_renders_the_same_pixels(tmp_path):
    cal = slmlab.simulate_set(slmlab.preset("paper"), slmlab.paper_test(5), seed=4)
    render_set(cal, tmp_path / "set", sequences=["grid", "Z"], progress=False)
    got = {f.name: _pixels(f) for f in (tmp_path / "set" / "images").glob("*_001_*.png")}
    m = slmlab.preset("paper")
    img, _ = render_plate(m, m.moving_plate, (0.3, -0.2, 0.1), seed=3)
    got["plate"] = hashlib.sha256(img.tobytes()).hexdigest()
    board = {"squares": [16, 12], "square_mm": 0.3, "marker_mm": 0.22, "dictionary": "DICT_6X6_250", "legacy": True}
    b = render_board_set(tmp_path / "board", m, board, [-0.3], seed=2)
    got.update({f"board {f.name}": _pixels(f) for f in (b / "images").glob("*.png")})
    assert got == CMO_PIXELS


# ------------------------------------------------------------------------------------------ the degradations
@pytest.mark.parametrize("rig, degradation, rms_px", [
    ("stereo-piv", "the rig's camera", 0.05),
    ("stereo-dic", "lowest contrast", 0.1),
    ("greenough", "hot pixels", 0.05),
    ("stereo-piv", "12 bit", 0.05),
])
def test_extraction_under_a_degradation_meets_the_targets(rig, degradation, rms_px, tmp_path):
    row = extraction_by_degradation([make_rig(rig)], [degradation], folder=tmp_path).iloc[0]
    assert row["note"] == "" and row["visible_dots"] > 0
    assert row["found_percent"] >= 99 and row["misnumbered"] == 0, row.to_dict()
    assert row["rms_px"] <= rms_px, row.to_dict()


@pytest.mark.slow  # rigs drawn at random, none of them shaped on (seconds each)
@pytest.mark.parametrize("rig, degradation, rms_px, method", [
    ("stereo-piv:6", "the rig's camera", 0.05, None), ("stereo-piv:7", "the rig's camera", 0.05, None),
    ("greenough:5", "the rig's camera", 0.05, "symmetry"), ("stereo-dic:5", "the rig's camera", 0.05, None),
    ("greenough:5", "bright region", 0.05, "fit"), ("stereo-piv:4", "all together", 0.05, None),
    ("stereo-piv:7", "streaks", 0.05, "fit"), ("stereo-piv:4", "streaks", 0.05, "fit"),
])
def test_rigs_drawn_at_random_have_every_visible_dot_found_and_numbered(rig, degradation, rms_px, method, tmp_path):
    """Rigs drawn at random (seeds beyond notebook 11's 1-3): every visible dot found and none numbered wrongly,
    and the centres within the 0.05 px target. greenough:5's camera sees its plate far out of focus and at low
    contrast at the ends of its depth: 0.074 px by the centroid, 0.040 px by the point of symmetry, which auto
    takes there. Beside greenough:5's bright region the model fit is at 0.030 px, losing one dot in a saturated
    surround; auto lets it compete with one dot fewer (AUTO_FIT_SLACK; without that it took the point of
    symmetry, 0.16 px: three dots beside the glare 1.2-1.4 px off). Window streaks across a PIV rig's bright
    dots show on its dark plate by a few grey levels, read along strips through the dots; the model fit divides
    the dots by their gain and is taken: stereo-piv:7's streaks 0.012 px (the edge fits 0.038). On stereo-piv:4 the
    fit, started from a circle of the sweep's size (11.2 px for 8.9), threw 17 dots of one image off the lattice and
    that image was the edge fit's (0.042 px); started from the dots' profile, it is taken on all four (0.008 px).
    Everything together on stereo-piv:4: 0.030 px, with the hot pixels on its dots cleaned where the camera's
    other image shows them too (0.056 px without, 0.082 before the fit was tried)."""
    row = extraction_by_degradation([rig_by_name(rig)], [degradation], folder=tmp_path).iloc[0]
    assert row["note"] == "" and row["visible_dots"] > 0
    assert row["found_percent"] >= 99 and row["misnumbered"] == 0, row.to_dict()
    assert rms_px is None or row["rms_px"] <= rms_px, row.to_dict()
    assert method is None or row["method"] == method, row.to_dict()


@st.composite
def cameras(draw) -> Degradations:
    """A camera none of the zoo's tables holds: polarity, bit depth, plate level, contrast and read noise drawn,
    and each of the other degradations on or off, at a drawn strength (up to the zoo's own strongest)."""
    dark, bits = draw(st.booleans()), draw(st.sampled_from([8, 8, 12, 16]))
    scale = 2.0 ** (bits - 8)
    background = draw(st.floats(120.0, 230.0)) if dark else draw(st.floats(5.0, 40.0))
    contrast = draw(st.floats(25.0, 150.0))
    contrast = min(contrast, background - 5.0) if dark else contrast
    on = lambda lo, hi: draw(st.one_of(st.just(0.0), st.floats(lo, hi)))  # noqa: E731
    return Degradations(bits=bits, dark=dark, background_dn=background * scale, contrast_dn=contrast * scale,
                        read_noise_dn=draw(st.floats(0.5, 3.0)) * scale, defocus_px=on(0.5, 5.0),
                        focus_angle_deg=draw(st.floats(0.0, 180.0)), shot_dn_per_e=on(0.05, 0.5) * scale,
                        hot_pixel_fraction=on(1e-4, 2e-3), gradient=on(0.05, 0.8),
                        gradient_angle_deg=draw(st.floats(0.0, 360.0)), vignetting=on(0.05, 0.6),
                        bright_region=on(0.5, 2.0), streaks=on(0.05, 0.35), text_strip_px=int(on(20.0, 50.0)))


#: stereo-piv:11 under such a camera: dark dots at 35 DN, window streaks and a bright region lost every other
#: column near the plate's middle to the sweep, the lattice grew at twice the pitch and the local search
#: extrapolated past the columns beside the glare (74.9 % found, one image unnumbered). As drawn: with the levels
#: rounded to three digits the sweep keeps those columns (99.9 % found without the half step)
HALF_LOST = Degradations(dark=True, background_dn=143.38601481193888, contrast_dn=35.25487260270841,
                         defocus_px=2.0954315242596815, focus_angle_deg=27.606120410906463,
                         read_noise_dn=0.7570208256805201, vignetting=0.2212408791291072,
                         bright_region=1.5068139281449133, streaks=0.3039790545979545, text_strip_px=36)


#: the thorough profile's first find: stereo-piv:5216 under a clean camera, a row of clear dots the sweep missed
#: and the local search took for noise (98.9 % found; :data:`slmlab.images.dots.STRONG_SHARE` says why)
CROWDED = Degradations(bits=8, dark=False, background_dn=5.0, contrast_dn=79.0, read_noise_dn=0.5)


#: the thorough profile's find: greenough:7201 under dark dots 25 DN below a 222 DN plate, window streaks and a
#: text strip. The strip set the sweep's top level, its second at 9 σ lost 30 of 49 dots ("no dots found"); a
#: bright streak down a column of dots was read from the quartile nearer zero and hid them
#: (:func:`slmlab.images.dots._ladder`, :func:`slmlab.images.dots.column_offsets`). Another streak saturates half
#: of a column of dots, which were taken at their crescents' centres, 5.8 px off (under this test's 0.3 of a
#: pitch): now fitted on what is left of them (:func:`slmlab.images.centres.refine_fit`), 0.05 px RMS in all
STREAKS_AND_STRIP = Degradations(dark=True, background_dn=222.0, contrast_dn=25.0, read_noise_dn=1.25, streaks=0.23,
                                 text_strip_px=25)
#: the same camera without its strip, the thorough profile's find on greenough:10: a saturating streak's edge across
#: a column of dots, whose centres were 1-1.4 px off (four lost: 95.9 % found), now 0.039 px RMS in all
SATURATING_STREAK = replace(STREAKS_AND_STRIP, text_strip_px=0)
#: the found dots' RMS error [px] may exceed twice the rendered images' information floor by this much: 0.042 px at
#: most over 96 random rigs under random cameras (each kind's seeds 11-30 with the plate at two Z positions, 11-22
#: on a two-level plate); greenough:7201's crescents were 0.73
ACCURACY_SLACK_PX = 0.05


@pytest.mark.slow  # rigs and cameras drawn at random, rendered and extracted (seconds each)
@settings(max_examples=max(4, settings.default.max_examples // 10))  # 4 at the quick profile, 30 thorough
@given(kind=st.sampled_from(["greenough", "stereo-dic", "stereo-piv"]), seed=st.integers(10, 10_000),
       camera=cameras())
@example(kind="stereo-piv", seed=11, camera=HALF_LOST)
@example(kind="stereo-piv", seed=5216, camera=CROWDED)
@example(kind="greenough", seed=7201, camera=STREAKS_AND_STRIP)
@example(kind="greenough", seed=10, camera=SATURATING_STREAK)
def test_a_camera_drawn_at_random_on_a_rig_drawn_at_random_has_every_visible_dot_found_and_numbered(
        kind, seed, camera, tmp_path_factory):
    """Every visible dot of the rig's plate (whole in view, two Z positions) found and none numbered wrongly
    under any camera: the degradations together in any mix, not one at a time as in the zoo's table. The found
    dots within twice the images' information floor and :data:`ACCURACY_SLACK_PX`."""
    vis, row, notes = _extracted_under(kind, seed, camera, tmp_path_factory.mktemp("camera"))
    good = vis["found"] & (np.hypot(vis["err1"], vis["err2"]) < 0.3 * vis["spacing_px"])
    assert len(vis) and good.mean() >= 0.99 and (vis["found"] & ~good).sum() == 0, (good.mean(), notes)
    assert row["rms_px"] <= 2 * row["floor_px"] + ACCURACY_SLACK_PX, row


def _extracted_under(kind: str, seed: int, camera: Degradations, folder):
    """The visible dots' errors, the zoo's row (:func:`_degradation_row`) and extract's notes for rig ``kind:seed``'s
    plate in view at two Z positions, rendered under ``camera`` in ``folder``."""
    cal = plate_in_view_set(random_rig(kind, seed), seed)
    d = write_set(folder / "set", cal)
    render_rig_set(cal, d, camera, progress=False, compress=False)
    rendered = slmlab.read_set(d)
    pts, notes = extract_set(d, progress=False)
    e = rig_extraction_errors(pts, rendered)
    return e[e["visible"]], _degradation_row(e, rendered_floor(rendered)), notes


#: greenough:24 under a 16-bit camera with a saturating glare beside the plate and window streaks: the glare
#: saturates whole columns around the dots beside it, as a streak would
GLARE_AND_STREAKS = Degradations(bits=16, dark=True, background_dn=41148.0, contrast_dn=34722.0, defocus_px=4.43,
                                 read_noise_dn=527.0, gradient=0.674, bright_region=1.285, streaks=0.225)


@pytest.mark.slow
def test_a_glare_among_window_streaks_is_not_taken_for_a_saturating_streak(tmp_path):
    """The fit counts a column for nothing only where it saturates above and below the dot, and not more than half
    the patch's columns do (:data:`slmlab.images.centres.CLIPPED_SHARE`); a glare's saturated pixels are censored.
    With every column that saturates anywhere counted for nothing, this camera's dots beside the glare were
    0.37-0.47 px off (0.058 px RMS in all); now 0.014 px."""
    vis, row, notes = _extracted_under("greenough", 24, GLARE_AND_STREAKS, tmp_path)
    assert row["found_percent"] >= 99 and row["misnumbered"] == 0, (row, notes)
    assert row["rms_px"] <= 0.03, row


def test_an_image_whose_estimator_drops_dots_the_model_fit_keeps_is_the_fit_s(tmp_path):
    """A view's estimator is chosen on its first image; where the model fit was tried there and lost, a later image
    on which the chosen estimator drops dots as off the lattice that the fit keeps is taken by the fit, and a note
    says so (:func:`slmlab.images.imageset._or_fit`). greenough:7201's second left image: a clipped window streak
    takes half of two dots, their ellipse fits 0.5 px off the lattice (dropped: 98.9 % found in the set); the fit
    censors the clipped pixels and keeps them. Its first image is the chosen estimator's."""
    from slmlab.images.imageset import _or_fit, plate_spec
    from slmlab.io import read_meta
    cal = plate_in_view_set(random_rig("greenough", 7201), 7201)
    d = write_set(tmp_path / "set", cal)
    render_rig_set(cal, d, STREAKS_AND_STRIP, progress=False, compress=False)
    spec = plate_spec(read_meta(d / "meta.json"), "moving")
    kw = dict(dark=True, marker_origin=spec.marker_origin, two_level=False, camera_hot=None)
    for name, lost in (("Z_001_l.png", 0), ("Z_002_l.png", 2)):
        img, notes = read_image(d / "images" / name), []
        ellipse = extract_image(img, spec.rows, spec.cols, method="ellipse", **kw)
        got = _or_fit(img, spec, "ellipse", kw, d / "images" / name, notes)
        assert len(got.table) == len(ellipse.table) + lost and len(notes) == (lost > 0), (name, notes)
    assert "centres by fit on Z_002_l.png (ellipse lost 2 of its dots off the lattice)" in notes[0]


def test_beside_a_saturating_glare_auto_takes_the_fit_the_lattice_cannot_judge(tmp_path):
    """The Greenough rig with everything together: a bright region saturates beside the plate. Its pull on the
    dots near it is smooth over the plate, so the lattice's cubic absorbs it and the point of symmetry lay as
    smoothly on the lattice as the fit (0.081 px against 0.084 in the left view) while 0.13 px from the truth
    against 0.074: auto took it there, 0.086 px RMS over the set. Where the dots' patches saturate the fit is taken
    unless clearly rougher (AUTO_FIT_RATIO)."""
    row = extraction_by_degradation([make_rig("greenough")], ["all together"], folder=tmp_path).iloc[0]
    assert row["method"] == "fit" and row["found_percent"] == 100 and row["misnumbered"] == 0, row.to_dict()
    assert row["rms_px"] < 0.08, row.to_dict()


def test_a_plate_cut_by_a_glare_is_numbered_alone_or_not_at_all(tmp_path):
    # two of the four images lose the plate's edge column to the glare; the edge beyond the other side is
    # seen empty (numbered alone), and a hidden line is not taken for an empty one (tracked across 0.9 pitch
    # from the other Z position, they were numbered one column off: 125 dots misnumbered)
    row = extraction_by_degradation([make_rig("stereo-dic")], ["all together"], folder=tmp_path).iloc[0]
    assert row["misnumbered"] == 0 and row["found_percent"] > 85 and row["tracked_images"] == 0, row.to_dict()


def test_the_report_says_what_was_found_and_rejected_and_why(tmp_path):
    d = tmp_path / "piv"
    assert cli("simulate", d, "--rig", "stereo-piv", "--design", "zstack-2", "--images").returncode == 0
    r = extract_image(read_image(d / "images" / "Z_001_l.png"), 27, 41, dark=False, method="edges")
    rep = r.report
    assert set(rep.columns) == {"candidate", "w1", "w2", "area_px", "levels", "peak_sigma", "status", "reason"}
    assert (rep["status"] == "dot").sum() + (rep["status"] == "recovered").sum() >= len(r.table)
    rejected = rep[rep["status"] == "rejected"]
    assert len(rejected) and rejected["reason"].str.len().gt(0).all()
    line = report_summary(rep)
    assert "dots on the lattice" in line and "rejected:" in line


# ------------------------------------------------------------------------------------------ the command line
@pytest.mark.slow  # the command line three times, on rendered images
def test_simulate_a_rig_with_images_then_extract_through_the_command_line(tmp_path):
    d = tmp_path / "piv"
    r = cli("simulate", d, "--rig", "stereo-piv", "--design", "zstack-2", "--images", "--seed", "3")
    assert r.returncode == 0, r.stderr
    stage = pd.read_csv(d / "stage.csv")
    assert list(stage.columns[-2:]) == ["left_image", "right_image"] and len(stage) == 2
    assert all((d / p).exists() for p in np.r_[stage["left_image"], stage["right_image"]])
    before = slmlab.read_set(d)
    r = cli("extract", d)
    assert r.returncode == 0, r.stderr
    assert "against truth.csv" in r.stdout and "rejected:" in r.stderr
    errors = rig_extraction_errors(slmlab.read_set(d).points, before)
    vis = errors[errors["visible"]]
    good = vis["found"] & (np.hypot(vis["err1"], vis["err2"]) < 0.3 * vis["spacing_px"])
    assert good.mean() >= 0.99
    e = np.r_[vis.loc[good, "err1"], vis.loc[good, "err2"]]
    assert np.sqrt(np.mean(e ** 2)) <= 0.05
    (d / "points.csv").write_text("sequence,position\nZ,1\n")   # a points.csv extract replaces need not be valid:
    r = cli("extract", d)                                       # it failed after all its work, in six lines
    assert r.returncode == 0 and "wrote" in r.stdout, r.stderr


def test_a_stepped_target_is_not_rendered_and_nothing_is_written(tmp_path):
    r = cli("simulate", tmp_path / "s", "--rig", "greenough", "--design", "stepped-target", "--images")
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "stepped target" in r.stderr
    assert not (tmp_path / "s").exists()


@pytest.mark.slow  # simulate --images, then extract
@pytest.mark.parametrize("rig, design", [("stereo-piv", "two-level-2z"), ("stereo-dic", "charuco-stack")])
def test_known_targets_render_and_extract_to_their_truth(rig, design, tmp_path):
    d = tmp_path / "set"
    assert cli("simulate", d, "--rig", rig, "--design", design, "--images").returncode == 0
    before = slmlab.read_set(d)
    pts, notes = extract_set(d, progress=False)
    assert any("markers" in n or "marker ids" in n for n in notes), notes
    errors = rig_extraction_errors(pts, before)
    vis = errors[errors["visible"]]
    good = vis["found"] & (np.hypot(vis["err1"], vis["err2"]) < 0.3 * vis["spacing_px"])
    assert good.mean() >= 0.97 and (vis["found"] & ~good).sum() == 0, (good.mean(), (vis["found"] & ~good).sum())
    e = np.r_[vis.loc[good, "err1"], vis.loc[good, "err2"]]
    assert np.sqrt(np.mean(e ** 2)) <= 0.1


def test_a_two_level_plate_s_small_square_is_read_where_blur_rounds_its_corners(tmp_path):
    """The Greenough two-level plate at two positions under a clean camera: its square (0.6 of a dot's diameter a
    side) has its corners rounded by blur at its half-peak outline in one image of four (rectangle fill 0.865
    against the 0.88 a square needs), which was left unnumbered (74.5 % found); read again at half that level
    (0.907) it is a square. Under the rig's own camera, with shot noise, its outline is ragged at its reference
    level and half of it (0.835, 0.811), a square only at a quarter (0.895), where neighbouring dots may join a
    shape; that image is still lost: a limit, not tested here."""
    cal = simulate_design(rig_by_name("greenough"), "two-level-2z", seed=1)
    d = write_set(tmp_path / "set", cal)
    render_rig_set(cal, d, rig_degradations("greenough", "clean"), progress=False, compress=False)
    before = slmlab.read_set(d)
    pts, notes = extract_set(d, progress=False)
    assert any("by square and triangle markers (4)" in n for n in notes), notes
    vis = rig_extraction_errors(pts, before)
    vis = vis[vis["visible"]]
    assert vis["found"].mean() >= 0.99, vis["found"].mean()


@pytest.mark.slow  # rigs drawn at random (seconds each)
@pytest.mark.parametrize("rig, design, degradation", [
    ("stereo-dic:35", "two-level", "streaks"), ("stereo-piv:32", "two-level-2z", "the rig's camera"),
    ("stereo-piv:34", "two-level-2z", "the rig's camera"), ("stereo-dic:37", "two-level-2z", "all together"),
    ("stereo-dic:32", "two-level", "all together"), ("greenough:35", "two-level-2z", "all together"),
])
def test_a_two_level_plate_s_markers_are_read_among_its_dots_and_only_there(rig, design, degradation, tmp_path):
    """Two-level plates on rigs drawn at random (a stress of seeds 31-40; none shaped on), each with one image of
    two or four left unnumbered before: stereo-dic:35's square joined to the dot beside it on the edge of a window
    streak, 1.19 times the dots' median area at the lowest level and so not read apart (1.6 times its neighbours':
    :func:`slmlab.images.markers.near_median`); stereo-piv:32's text strip under the plate's last row read as a
    square and three blobs (the strip is now found and left out: :func:`slmlab.images.overlay.overlay_rows`); on
    stereo-piv:34 a noisy dot next to a hot pixel read near its top as a square (a shape at a lattice node is the
    next dot); stereo-dic:37's square under everything together, joined to its dot at every level, 7.1 times the
    empty holes' spread (held to 5 σ of the reduced image before, 7.4 of that spread). Under everything together
    on stereo-dic:32 and greenough:35 a dim dot beyond the lattice at the image's edge read as a square, the
    plate's square as a blob in its hole: the read shapes spanned no cell and the image was left unnumbered (50 %
    and 74.5 % found); where no pair of read shapes spans a cell, the blobs stand in for one."""
    row = extraction_by_degradation([rig_by_name(rig)], [degradation], design=design, folder=tmp_path).iloc[0]
    assert row["note"] == "" and row["misnumbered"] == 0, row.to_dict()
    assert row["found_percent"] >= 99, row.to_dict()


@pytest.mark.slow  # the command line four times, on rendered images
def test_extract_run_again_on_a_known_target_set_compares_by_number_or_says_it_cannot(tmp_path):
    """``extract`` writes points.csv over the simulated one, which held the true places of a two-level plate's dots.
    Run again on a points.csv that has every dot of truth.csv, in its order, the comparison is by number, as the first
    time; on one that lost dots (here: five rows taken out) the places of the lost ones are gone: it says so and
    exits 0. It used to crash on a positional index, or join the truth to the wrong rows."""
    d = tmp_path / "set"
    assert cli("simulate", d, "--rig", "stereo-piv", "--design", "two-level", "--images").returncode == 0
    first = cli("extract", d)
    assert first.returncode == 0 and "against truth.csv" in first.stdout, first.stderr[-500:]
    line = first.stdout.splitlines()[-1]
    extracted = pd.read_csv(d / "points.csv")
    again = cli("extract", d)
    assert again.returncode == 0, again.stderr[-500:]
    assert again.stdout.splitlines()[-1] == line and "100.00 %" in line, (line, again.stdout)
    pd.testing.assert_frame_equal(pd.read_csv(d / "points.csv"), extracted)   # the same dots, written again
    extracted.iloc[:-5].to_csv(d / "points.csv", index=False)
    lost = cli("extract", d)
    assert lost.returncode == 0, lost.stderr[-500:]
    assert "against truth.csv" not in lost.stdout and "not compared with truth.csv" in lost.stderr


# ------------------------------------------------------------------------------------------ real samples
def test_case_e_against_the_challenge_picks(dataset_folder):
    piv = dataset_folder("pivchallenge-case-e")
    d = converters.pivchallenge_image_set(piv, Path(tempfile.mkdtemp()) / "caseE")
    pts, notes = extract_set(d, progress=False)
    vs, _ = realrigs.extraction_vs_picks(pts, converters.pivchallenge_picks(piv, common=False))
    both = vs.set_index("view").loc["both"]
    # before the robust extractor: 360 of 364 picks within 1.5 px, 0.227 px RMS
    assert both["found_within_px"] >= 360 and both["rms_difference_px"] <= 0.227, both.to_dict()


def test_fluidimage_tomopiv_images_are_found_and_anchored_by_their_frame(dataset_folder):
    folder = dataset_folder("fluidimage-tomopiv")
    images = sorted(folder.glob("cam*/*.tif"))
    assert len(images) == 20
    for path in images:
        r = extract_image(read_image(path), dark=None, anchor="markers", method="edges")
        assert not r.dark and r.frame == "origin" and "frame" in r.how, (path.name, r.note)
        assert len(r.table) >= 49, (path.name, len(r.table))


def test_dice_images_keep_their_dots(dataset_folder):
    pts, notes = extract_set(converters.dice_image_set(dataset_folder("dice-calb-sys2"), Path(tempfile.mkdtemp()) / "d"),
                             progress=False)
    counts = realrigs.dots_per_image(pts)
    # the extractor before this one numbered 1055 + 1107 dots in DICe's 10 x 8 boxes; dots whose outline comes
    # within a pixel or two of the image edge are now left out
    assert len(counts) == 14 and counts["both"].min() >= 72
    assert counts[["left", "right"]].sum().sum() >= 0.99 * (1055 + 1107)
    assert any("an L of donut markers (28)" in n for n in notes), notes


# ------------------------------------------------------------------------------------------ the information floor
def test_the_floor_of_a_gaussian_spot_is_the_textbook_one():
    """A Gaussian spot ``A exp(-r²/2s²)`` in white noise σ: the Cramér-Rao bound per coordinate is
    ``σ/A · sqrt(2/π)``, whatever ``s``; a least-squares fit of the known spot reaches it in noise."""
    amplitude, noise, s = 40.0, 3.0, 2.5
    centres = np.array([[20.3, 19.6], [60.8, 21.1], [40.1, 58.4]])
    yy, xx = np.mgrid[0:80, 0:80].astype(float)

    def image(c):
        return sum(amplitude * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / (2 * s * s)) for x, y in c)
    gx = sum(amplitude * (xx - x) / s ** 2 * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / (2 * s * s)) for x, y in centres)
    gy = sum(amplitude * (yy - y) / s ** 2 * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / (2 * s * s)) for x, y in centres)
    got = fisher_floor(gx, gy, np.full(xx.shape, noise ** 2), np.ones(xx.shape, bool), centres)
    assert np.allclose(got, noise / amplitude * np.sqrt(2 / np.pi), rtol=0.01), got
    rng = np.random.default_rng(3)
    clean, est = image(centres[:1]), []
    for _ in range(200):
        noisy = clean + noise * rng.standard_normal(clean.shape)
        est.append(least_squares(lambda c: (image([c]) - noisy).ravel(), centres[0] + 0.2).x)
    spread = np.std(np.array(est), axis=0)
    assert np.allclose(spread, got[0], rtol=0.15), (spread, got[0])


def test_the_floor_with_the_light_unknown_is_the_whole_fisher_matrixs():
    """A Gaussian spot of contrast ``a`` on a background plane ``b0 + bx x + by y``, in white noise: the bound on
    its centre with the light unknown is the centre's block of the inverse of the six parameters' Fisher matrix
    (here by central differences of the whole model over the dot's cell), above the bound with the light known
    (the slopes, odd about the centre as the centre's own change is, trade against it)."""
    noise, s, (x0, y0) = 2.0, 3.0, (12.4, 11.7)   # a spot that fills much of its cell, as a blurred dot does
    yy, xx = np.mgrid[0:24, 0:24].astype(float)
    cell = np.hypot(xx - x0, yy - y0) <= CELL * 24

    def model(t):
        cx, cy, b0, bx, by, a = t
        return b0 + bx * xx + by * yy + a * np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2 * s * s))
    theta = np.array([x0, y0, 100.0, 0.5, -0.3, 35.0])
    steps = np.array([1e-4, 1e-4, 1e-3, 1e-5, 1e-5, 1e-3])
    jac = np.array([((model(theta + e) - model(theta - e)) / (2 * e.sum()))[cell] for e in np.diag(steps)])
    expected = np.sqrt(np.diag(np.linalg.inv(jac @ jac.T / noise ** 2))[:2])
    spot = np.exp(-((xx - x0) ** 2 + (yy - y0) ** 2) / (2 * s * s))
    gx, gy = 35.0 * spot * (xx - x0) / s ** 2, 35.0 * spot * (yy - y0) / s ** 2
    args = (gx, gy, np.full(xx.shape, noise ** 2), np.ones(xx.shape, bool), np.array([[x0, y0]]))
    known, unknown = fisher_floor(*args)[0], fisher_floor(*args, amplitude=spot)[0]
    assert np.allclose(unknown, expected, rtol=1e-4), (unknown, expected)
    assert (unknown > 1.05 * known).all(), (unknown, known)


def test_the_floor_in_batches_is_each_dots_own_sum(monkeypatch):
    """The floor's batches (a box per dot, :data:`slmlab.virtual.floor.BATCH_PX`, made small here so that the
    dots fall in several) hold each dot's sum over its own cell and nothing else: the same as summing one dot at a
    time over the pixels nearer it than CELL of its nearest neighbour, also for dots cut by the image's edge or
    outside it, and for pixels that carry nothing."""
    rng = np.random.default_rng(5)
    h, w = 50, 70
    gx, gy, amp = (rng.normal(size=(h, w)) for _ in range(3))
    variance = rng.uniform(1.0, 4.0, (h, w))
    usable = rng.uniform(size=(h, w)) > 0.1
    centres = np.array([[10.2, 12.7], [31.5, 10.1], [52.9, 14.4], [1.3, 40.2], [69.6, 48.8], [35.0, 30.0],
                        [-30.0, 25.0]])
    monkeypatch.setattr(floor, "BATCH_PX", 300)
    got = fisher_floor(gx, gy, variance, usable, centres), fisher_floor(gx, gy, variance, usable, centres, amp)
    yy, xx = np.mgrid[0:h, 0:w].astype(float)
    dist = np.hypot(*(centres[:, None] - centres[None]).transpose(2, 0, 1))
    np.fill_diagonal(dist, np.inf)
    for k, ((x, y), r) in enumerate(zip(centres, CELL * dist.min(axis=1))):
        cell = (np.hypot(xx - x, yy - y) <= r) & usable
        rows = [gx[cell], gy[cell], np.ones(cell.sum()), (xx[cell] - x) / r, (yy[cell] - y) / r, amp[cell]]
        for light, found in ((2, got[0][k]), (6, got[1][k])):
            if not cell.any():
                assert np.isinf(found).all(), (k, found)
                continue
            jac = np.array(rows[:light])
            expected = np.sqrt(np.diag(np.linalg.inv(jac / variance[cell] @ jac.T))[:2])
            assert np.allclose(found, expected, rtol=1e-9), (k, light, found, expected)


def test_floors_for_many_cameras_are_each_cameras_own():
    """:func:`rendered_floors` draws a view's coverage once for the cameras that blur it alike: its tables are
    bit for bit those of :func:`rendered_floor` for each camera, whether it shares the blur or not."""
    cal = plate_in_view_set(rig_by_name("greenough"), 1)
    cams = [rig_degradations("greenough", name) for name in ("noise", "defocus", "low contrast", "the rig's camera")]
    for together, camera in zip(rendered_floors(cal, cams), cams):
        pd.testing.assert_frame_equal(together, rendered_floor(cal, camera), check_exact=True)


def test_a_rendered_dots_floor_falls_with_contrast_and_has_none_where_clipped():
    """Read noise alone: twice the contrast, half the floor (the gradient scales with the contrast and the
    light's gain, the noise does not); a plate clipped at full scale leaves the dots' cores (a higher floor), an
    image clipped everywhere carries no information (an infinite floor); a ChArUco board has no dots (NaN)."""
    rig = rig_by_name("greenough")
    cal = plate_in_view_set(rig, 1)
    quiet = replace(rig_degradations("greenough", "clean"), read_noise_dn=4.0)
    low = rendered_floor(cal, replace(quiet, contrast_dn=30.0))
    high = rendered_floor(cal, replace(quiet, contrast_dn=60.0))
    ratio = low[["floor1_px", "floor2_px"]].to_numpy() / high[["floor1_px", "floor2_px"]].to_numpy()
    assert np.all(np.isfinite(ratio)) and np.allclose(ratio, 2.0, rtol=0.01), (ratio.min(), ratio.max())
    clipped = rendered_floor(cal, replace(quiet, background_dn=400.0))  # the plate clipped, the dots' cores not
    assert (clipped[["floor1_px", "floor2_px"]].to_numpy() > 2 * high[["floor1_px", "floor2_px"]].to_numpy()).all()
    blind = rendered_floor(cal, replace(quiet, background_dn=600.0))  # the plate and the dots clipped
    assert np.isinf(blind[["floor1_px", "floor2_px"]].to_numpy()).all()
    board = rendered_floor(simulate_design(make_rig("stereo-dic"), "charuco-stack", seed=1))
    assert len(board) and board[["floor1_px", "floor2_px"]].isna().all().all()   # a board has no dots


@pytest.mark.parametrize("rig, degradation", [("greenough", "noise"), ("stereo-piv", "lowest contrast")])
def test_no_estimator_beats_the_floor_and_ours_is_near_it_in_noise(rig, degradation, tmp_path):
    """The extraction's RMS against the truth is above the Cramér-Rao floor of the same dots (a floor that
    estimators beat would be wrong) and, where noise is what limits it, within 1.5x of it."""
    row = extraction_by_degradation([rig_by_name(rig)], [degradation], folder=tmp_path).iloc[0]
    assert row["floor_px"] < row["rms_px"] < 1.5 * row["floor_px"], row.to_dict()


@pytest.mark.slow  # rigs drawn at random, rendered and extracted (seconds each)
@settings(max_examples=max(4, settings.default.max_examples // 10))  # 4 at the quick profile, 30 thorough
@given(kind=st.sampled_from(["greenough", "stereo-dic", "stereo-piv"]), seed=st.integers(10, 10_000),
       contrast=st.floats(20.0, 150.0), read=st.floats(0.5, 6.0), shot=st.floats(0.0, 0.5))
def test_on_rigs_drawn_at_random_the_floor_is_finite_falls_with_noise_and_is_not_beaten(kind, seed, contrast,
                                                                                        read, shot, tmp_path):
    rig = random_rig(kind, seed)
    cal = plate_in_view_set(rig, 1)
    camera = replace(rig_degradations(kind, "clean"), contrast_dn=contrast, read_noise_dn=read, shot_dn_per_e=shot)
    d = write_set(tmp_path / f"{kind}-{seed}-{contrast:.3f}-{read:.3f}-{shot:.3f}", cal)
    render_rig_set(cal, d, camera, progress=False, compress=False)
    rendered = slmlab.read_set(d)
    floor = rendered_floor(rendered)                       # the camera the set was rendered with
    quieter = rendered_floor(rendered, replace(camera, read_noise_dn=read / 2, shot_dn_per_e=shot / 4))
    cols = ["floor1_px", "floor2_px"]
    vis = rendered_truth(rendered)["visible"].to_numpy()
    f, q = floor[cols].to_numpy()[vis], quieter[cols].to_numpy()[vis]
    assert len(f) and np.isfinite(f).all() and (f > 0).all()
    assert (q < f).all()                                   # less noise, a lower floor: every dot
    pts, _ = extract_set(d, progress=False)
    e = rig_extraction_errors(pts, rendered).merge(floor, on=["sequence", "position", "view", "row", "col"])
    good = e["visible"] & e["found"] & (np.hypot(e["err1"], e["err2"]) < 0.3 * e["spacing_px"])
    assert good.sum() >= 0.99 * e["visible"].sum()
    rms = np.sqrt(np.mean(np.r_[e.loc[good, "err1"], e.loc[good, "err2"]] ** 2))
    assert rms >= np.sqrt(np.mean(e.loc[good, cols].to_numpy() ** 2)), rms   # no estimator beats it


def _two_level_errors(rig, camera, seed, tmp_path):
    """The two-level plate at two positions (``two-level-2z``) on ``rig`` under ``camera``, rendered and
    extracted: the notes and the visible dots' errors against the truth (``good``: found at their number)."""
    cal = simulate_design(rig, "two-level-2z", seed=seed)
    d = write_set(tmp_path / "set", cal)
    render_rig_set(cal, d, camera, progress=False, compress=False)
    pts, notes = extract_set(d, progress=False)
    errors = rig_extraction_errors(pts, slmlab.read_set(d))
    vis = errors[errors["visible"]].copy()
    vis["dist"] = np.hypot(vis["err1"], vis["err2"])
    vis["good"] = vis["found"] & (vis["dist"] < 0.3 * vis["spacing_px"])
    return notes, vis


@pytest.mark.parametrize("rig", ["stereo-dic", "stereo-piv"])
def test_a_two_level_plate_whose_parallax_brings_a_dot_beside_the_square_is_read_whole(rig, tmp_path):
    """The presets' two-level plates under a clean camera, the second level at a quarter pitch's parallax: a
    second-level dot sits a few pixels from the square marker. Before: the seed was not found ("no dots found"
    on the stereo-DIC rig, the opposite neighbours' mirror falling halfway between two dots), the reduced image
    joined the square to the dot (its area 1.6 of a dot's, taken as the dot) or kept it at one sweep level only
    (noise), the plate's corners (the lattice's lines are its diagonals) were left unsearched, and the dot
    beside the square was 0.18-0.32 px off, pulled by it. Now every visible dot is found at its number, within
    0.05 px, and every image is numbered by both markers."""
    notes, vis = _two_level_errors(rig_by_name(rig), rig_degradations(rig, "clean"), 1, tmp_path)
    assert any("numbering anchored in 4 image(s) by square and triangle markers (4)" in n for n in notes), notes
    assert vis["good"].all() and vis["dist"].max() < 0.05, (vis["good"].mean(), vis["dist"].max())


#: cameras drawn by the stress of two-level plates under random cameras (random_rig(kind, seed), two-level-2z)
#: that left images unnumbered: a square joined to a dot at every level of the sweep by 2.6 px of defocus; a
#: square of 84 px², too small to show its corners; both markers rounded by 4.2 px of defocus into blobs; markers
#: as plain as the dots beside them but at a fifth of the median dot's peak under streaks and a glare, and a
#: square read in the glare far from them; a square joined to a dot at the lower levels only, 1.21 times a dot
#: at the blob's own; a square beside a dot seen apart at one level, its patch around the dot's outline there
TWO_LEVEL_CAMERAS = {
    ("stereo-dic", 13): Degradations(background_dn=28.54308569538692, contrast_dn=80.94606342291328,
                                     defocus_px=2.619645637574393, focus_angle_deg=151.78735054256188,
                                     read_noise_dn=2.28028373434398, vignetting=0.049796550865058915),
    ("stereo-dic", 12): Degradations(dark=True, background_dn=146.22800615090432, contrast_dn=132.55008480837984,
                                     focus_angle_deg=87.72051079454454, read_noise_dn=1.7343160336272145,
                                     hot_pixel_fraction=0.001940411747210212, bright_region=0.9931671696634813),
    ("greenough", 14): Degradations(dark=True, background_dn=218.7761287683544, contrast_dn=149.0725800521488,
                                    defocus_px=4.216637312384123, focus_angle_deg=33.09448156460209,
                                    read_noise_dn=1.778484310124298, bright_region=1.0078436652926719),
    ("greenough", 19): Degradations(dark=True, background_dn=171.3572580675969, contrast_dn=128.5939934833036,
                                    focus_angle_deg=93.4857508949433, read_noise_dn=1.0306625112383034,
                                    shot_dn_per_e=0.09523246603109908, bright_region=0.9331913770925311,
                                    streaks=0.3280952938701499, text_strip_px=31),
    ("stereo-dic", 20): Degradations(bits=16, background_dn=1958.2072936156428, contrast_dn=29022.944912182586,
                                     defocus_px=2.447345578720355, focus_angle_deg=156.56805609297996,
                                     read_noise_dn=184.812878202791, gradient=0.6995252312165219,
                                     gradient_angle_deg=269.74975110368365, vignetting=0.5318692890485981),
    ("stereo-piv", 11): HALF_LOST,
}


@pytest.mark.slow  # four images of 2048 × 1536 per case, rendered and extracted
@pytest.mark.parametrize("kind, seed", list(TWO_LEVEL_CAMERAS))
def test_a_two_level_plate_s_markers_are_read_where_blur_joins_them_to_a_dot_or_rounds_them(kind, seed, tmp_path):
    """Two-level plates of random rigs whose markers blur joins to the dot beside them or rounds into blobs
    (:data:`TWO_LEVEL_CAMERAS`). A marker joined to a dot is read apart at full resolution, at levels up to three
    quarters of the dots' peak, against the background at each of its pixels; a solid blob in a hole whose shape was
    not read stands for either marker, told apart by its place beside the origin dot and the level whose plane the
    markers lie on. Every image is numbered, none wrongly, and 99 % of the visible dots are found."""
    notes, vis = _two_level_errors(random_rig(kind, seed), TWO_LEVEL_CAMERAS[(kind, seed)], seed, tmp_path)
    assert any("numbering anchored in 4 image(s)" in n for n in notes), notes
    assert (vis["found"] & ~vis["good"]).sum() == 0 and vis["good"].mean() >= 0.99, vis["good"].mean()


@pytest.mark.parametrize("size, dots", [((1600, 1200), 51), ((2448, 2048), 15)])
def test_a_fine_plate_on_a_large_sensor_is_found_whole_and_numbered(size, dots):
    """The sweep's reduction is set by the image's size: a clean 51 x 51 plate at a pitch of 21.6 px on a
    1600 x 1200 sensor came out with 8 % of its dots, numbered wrongly and without a word; a 15 x 15 plate at
    20 px on a 2448 x 2048 sensor without any. Looked for again less reduced (``FINE_PITCH_REDUCED_PX``), every
    dot is found, on its true centre, and the numbering spans the plate."""
    from slmlab.images.extract import choose_method
    from slmlab.virtual.render import footprints, render_rig_view
    from slmlab.virtual.rigs import with_plates
    from slmlab.virtual.sessions import Session
    from slmlab.virtual.simulate import simulate_set
    share = 0.9 if dots == 51 else 14 * 20 / 2048
    rig = with_plates(make_rig("greenough", image_size=size), moving_dots=dots, moving_share=share, tolerance_um=0.0)
    cal = simulate_set(rig, Session(positions=(0, 0, 1), grid=False), seed=0)
    p = rig.stage_to_microscope(cal.truth[["X_mm", "Y_mm", "Z_mm"]].to_numpy(),
                                np.asarray(cal.meta["simulator"]["stage_origin_mm"]))
    axes = rig.moving_plate.orientation()[:, :2]
    deg = rig_degradations(rig.kind, "clean")
    img = render_rig_view(rig, p, axes, rig.moving_plate.dot_diameter_mm, "l", deg, np.random.default_rng(1),
                          np.random.default_rng(2))
    truth, _ = footprints(rig, p, axes, "l")
    found = choose_method(img, dots, dots, dark=deg.dark).dots.table      # auto, as extract_set's
    assert len(found) == dots * dots and found["i1"].nunique() == dots and found["i2"].nunique() == dots
    d = np.hypot(*(found[["w1", "w2"]].to_numpy()[:, None, :] - truth[None, :, :]).transpose(2, 0, 1)).min(axis=1)
    assert np.sqrt(np.mean(d ** 2) / 2) < 0.05, np.sqrt(np.mean(d ** 2) / 2)
