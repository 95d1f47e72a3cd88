"""Extraction of images as a camera writes them: stage.csv, bit depth, polarity, markers, two-level plates,
plates larger than the field, OpenCV's boards, and every way a user's images can be wrong (README, "The format")."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest

import slmlab
from slmlab.datasets import converters
from slmlab.studies import realrigs, workspace
from slmlab.images.extract import AUTO_EDGE_RATIO, extract_image
from slmlab.images.dots import read_image
from slmlab.images.imageset import TRACKED, extract_set
from slmlab.images.lattice import fit_model, plate_lattice
from slmlab.images.tracking import TRACK_UNCERTAINTY, Numbered, track
from slmlab.virtual.render import board_orientation, render_board_set, render_plate
from slmlab.virtual.sessions import Session, zstack_frame
from slmlab.virtual.simulate import stage_origin


def cli(*args):
    return subprocess.run([sys.executable, "-m", "slmlab", *map(str, args)], capture_output=True, text=True, timeout=300)


def one_line_error(r, *fragments):
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    assert r.stderr.startswith("slmlab: error: ") and r.stderr.count("\n") == 1, r.stderr
    for f in fragments:
        assert f in r.stderr, r.stderr


def write_image(path, img):
    ok, buf = cv2.imencode(path.suffix, img)
    assert ok
    path.write_bytes(buf.tobytes())


@pytest.fixture(scope="session")
def plate_images():
    """Three positions of the 7 × 7 plate, rendered, with their truth."""
    m = slmlab.preset("paper")
    return [render_plate(m, m.moving_plate, (0.1 * k, -0.05 * k, -0.2 * k), seed=k) for k in range(3)]


def make_set(d, plate_images, *, ext=".png", convert=lambda img: img, plate=None):
    """A set folder whose stage.csv names the images (left = right = the same render, shifted)."""
    d.mkdir()
    (d / "cam").mkdir()
    rows = ["sequence,position,stage_x_mm,stage_y_mm,stage_z_mm,left_image,right_image"]
    for k, (img, _) in enumerate(plate_images, 1):
        for side, im in (("l", img), ("r", np.roll(img, 7, axis=1))):
            write_image(d / "cam" / f"{k}_{side}{ext}", convert(im))
        rows.append(f"Z,{k},0,0,{-0.2 * (k - 1):g},cam/{k}_l{ext},cam/{k}_r{ext}")
    (d / "stage.csv").write_text("\n".join(rows) + "\n")
    meta = {"format": "slmlab-calibration/1", "image_size_px": [2048, 2048],
            "plates": {"moving": plate or {"rows": 7, "cols": 7, "pitch_mm": 0.3, "dot_diameter_mm": 0.15}}}
    (d / "meta.json").write_text(json.dumps(meta))
    return d


def test_sixteen_bit_tiffs_named_in_stage_csv_give_the_same_dots_as_pngs(tmp_path, plate_images):
    png, _ = extract_set(make_set(tmp_path / "png", plate_images), progress=False)
    tif, _ = extract_set(make_set(tmp_path / "tif", plate_images, ext=".tif",
                                  convert=lambda im: im.astype(np.uint16) * 257), progress=False)
    assert len(png) == len(tif) == 3 * 49
    diff = png[["wl1", "wl2", "wr1", "wr2"]].to_numpy() - tif[["wl1", "wl2", "wr1", "wr2"]].to_numpy()
    assert np.abs(diff).max() < 1e-3      # the same grey levels, scaled: the same centres
    truth = plate_images[0][1].set_index(["row", "col"])
    first = png[png["position"] == 1].set_index(["row", "col"])
    e = first[["wl1", "wl2"]].to_numpy() - truth.loc[first.index, ["w1", "w2"]].to_numpy()
    assert np.sqrt(np.mean(e ** 2)) < 0.03


def test_bright_dots_are_recognised_from_the_image_or_the_plate(tmp_path, plate_images):
    img, truth = plate_images[1]
    for dark in (None, False):
        t = extract_image(255 - img, 7, 7, dark=dark).table.merge(truth, on=["row", "col"])
        assert len(t) == 49
        assert np.sqrt(np.mean(np.r_[t["w1_x"] - t["w1_y"], t["w2_x"] - t["w2_y"]] ** 2)) < 0.03
    plate = {"rows": 7, "cols": 7, "pitch_mm": 0.3, "dot_diameter_mm": 0.15, "dots": "bright"}
    pts, _ = extract_set(make_set(tmp_path / "bright", plate_images, convert=lambda im: 255 - im, plate=plate),
                         progress=False)
    assert len(pts) == 3 * 49


BAD_INPUT = {
    "missing image": (lambda d: (d / "cam" / "2_r.png").unlink(), ["2_r.png", "not found"]),
    "unreadable image": (lambda d: (d / "cam" / "1_l.png").write_bytes(b"\x89PNG\r\n\x1a\n broken"), ["1_l.png", "cannot be read"]),
    "images of different sizes": (lambda d: write_image(d / "cam" / "3_l.png", np.full((900, 900), 200, np.uint8)),
                                  ["3_l.png", "one size"]),
    "an image with no dots": (lambda d: write_image(d / "cam" / "2_l.png", np.full((2048, 2048), 200, np.uint8)),
                              ["2_l.png", "no dots found", "dark or bright"]),
    "a plate larger than the field without markers": (
        lambda d: (d / "meta.json").write_text((d / "meta.json").read_text().replace('"rows": 7, "cols": 7, ', "")),
        ["cannot number the dots", "markers"]),
    "image size unlike meta.json": (
        lambda d: (d / "meta.json").write_text((d / "meta.json").read_text().replace("[2048, 2048]", "[1024, 1024]")),
        ["image_size_px"]),
    "a dot plate without dot_diameter_mm": (
        lambda d: (d / "meta.json").write_text((d / "meta.json").read_text().replace(', "dot_diameter_mm": 0.15', "")),
        ["meta.json", "plates.moving.dot_diameter_mm is missing", "extracting dots"]),
    "a ChArUco plate without its board": (
        lambda d: (d / "meta.json").write_text((d / "meta.json").read_text().replace('"pitch_mm"', '"pattern": "charuco", "pitch_mm"')),
        ["meta.json", "plates.moving.board", "squares"]),
    "a stage.csv row without images": (
        lambda d: (d / "stage.csv").write_text((d / "stage.csv").read_text().replace("cam/3_l.png,cam/3_r.png", ",")),
        ["stage.csv", "row 4"]),
}


@pytest.mark.parametrize("case", list(BAD_INPUT), ids=list(BAD_INPUT))
def test_bad_images_are_one_line_errors_and_nothing_is_written(case, tmp_path, plate_images):
    d = make_set(tmp_path / "set", plate_images)
    (d / "points.csv").write_text("keep me\n")
    corrupt, fragments = BAD_INPUT[case]
    corrupt(d)
    one_line_error(cli("extract", d), *fragments)
    assert (d / "points.csv").read_text() == "keep me\n"


# ----------------------------------------------------------------------------------- the real case E images
@pytest.fixture(scope="session")
def piv(dataset_folder):
    return dataset_folder("pivchallenge-case-e")


@pytest.fixture(scope="session")
def case_e(tmp_path_factory, piv):
    d = converters.pivchallenge_image_set(piv, tmp_path_factory.mktemp("caseE") / "set", level_offset_mm=-3.0)
    points, notes = extract_set(d, progress=False)
    return d, points, notes


def test_case_e_images_meet_the_extraction_targets(case_e, piv):
    _, pts, notes = case_e
    picks = converters.pivchallenge_picks(piv, common=False)
    found, diffs, total = 0, [], 0
    for side, u, v in (("l", "u1_px", "v1_px"), ("r", "u2_px", "v2_px")):
        p = picks.dropna(subset=[u]).merge(pts.dropna(subset=[f"w{side}1"]), how="left",
                                            left_on=["X_mm", "Y_mm", "Z_mm"], right_on=["x_mm", "y_mm", "stage_z_mm"])
        d = np.hypot(p[u] - p[f"w{side}1"], p[v] - p[f"w{side}2"])
        ok = d < 1.5
        total += len(p)
        found += int(ok.sum())
        diffs.append(np.r_[(p[u] - p[f"w{side}1"])[ok], (p[v] - p[f"w{side}2"])[ok]])
    diff = np.concatenate(diffs)
    assert found / total >= 0.95, (found, total)
    assert np.sqrt(np.mean(diff ** 2)) <= 0.35
    per_image = pd.concat([pts.groupby("position")[c].count() for c in ("wl1", "wr1")])
    assert per_image.min() >= 20 and len(per_image) == 14
    assert any("square and triangle" in n for n in notes)


def test_case_e_dots_are_textured_so_auto_takes_an_edge_fit(case_e):
    """The case E dots are scratched and unevenly lit (notebook 10): on each view's first image the centroid's
    centres lie most roughly on the lattice, the point of symmetry's less, the edge fit's less still (below
    AUTO_EDGE_RATIO of the centroid's: textured), so the model fit is tried too; it lies a little more smoothly
    (0.05 and 0.19 px against 0.06 and 0.23), not below AUTO_EDGE_RATIO of the edge fit's, and auto keeps the
    edge fit."""
    import re
    _, _, notes = case_e
    chosen = [n for n in notes if "view: centres by " in n]
    assert len(chosen) == 2, notes
    for note in chosen:
        res = {m: float(v) for v, m in re.findall(r"([0-9.]+) px by (\w+)", note)}
        assert note.split("centres by ")[1].startswith("edges"), note
        assert res["edges"] < res["symmetry"] < res["moments"] and res["edges"] < AUTO_EDGE_RATIO * res["moments"], note
        assert AUTO_EDGE_RATIO * res["edges"] <= res["fit"] < res["edges"], note


def test_case_e_numbering_is_one_across_the_stack_and_both_views(case_e):
    _, pts, _ = case_e
    # each dot's track through the stack is a straight line in each view: a misnumbered image would jump a pitch
    for side in "lr":
        for _, g in pts.dropna(subset=[f"w{side}1"]).groupby(["row", "col"]):
            if len(g) >= 3:
                for c in (f"w{side}1", f"w{side}2"):
                    fit = np.polyfit(g["stage_z_mm"], g[c], 1)
                    assert np.abs(np.polyval(fit, g["stage_z_mm"]) - g[c]).max() < 1.0
    # the two levels alternate by rows, and every dot has one plate position in every image
    assert set(pts["level"]) == {0, 1}
    assert (pts.groupby(["row", "col"])[["x_mm", "y_mm", "z_mm"]].nunique() == 1).all().all()
    assert np.allclose(pts.loc[pts["level"] == 1, "z_mm"], -3.0)


def test_case_e_without_markers_in_one_image_is_tracked_from_its_neighbours(case_e, piv, tmp_path):
    d, pts, _ = case_e
    src = read_image(piv / "Camera_01" / "E_camera_1_z_4.tif")
    img = src.copy()
    for x, y in ((219, 721), (309, 815)):            # paint out the square and the triangle
        cv2.circle(img, (x, y), 30, 0, -1)
    cam = tmp_path / "E_camera_1_z_4_no_markers.tif"
    write_image(cam, img)
    s = tmp_path / "set"
    shutil.copytree(d, s)
    stage = (s / "stage.csv").read_text().splitlines()
    stage = [line.replace(line.split(",")[5], str(cam)) if line.startswith("Z,4,") else line for line in stage]
    (s / "stage.csv").write_text("\n".join(stage) + "\n")
    tracked, notes = extract_set(s, progress=False)
    assert any("tracked" in n for n in notes), notes
    a = pts[pts["position"] == 4].set_index(["row", "col"])["wl1"].dropna()
    b = tracked[tracked["position"] == 4].set_index(["row", "col"])["wl1"].dropna()
    common = a.index.intersection(b.index)
    assert len(common) >= 55 and np.abs(a[common] - b[common]).max() < 0.05


def test_case_e_defocused_is_numbered_by_its_markers_places_as_it_is_sharp(case_e, tmp_path):
    """The real case E plate blurred by a Gaussian of 7 px (a strong defocus): its markers' corners round off and
    some read as blobs. Before the blobs in holes were read (a3b110d), 7 of the 14 images were numbered: the left
    view's were left ("no markers found", "1 square"). Each blob stands for the marker its place beside the
    origin dot says: all 14 are numbered, and every dot found in both sets carries the same number (within
    2 px of its place in the sharp images; neighbouring dots are about 125 px apart)."""
    d, pts, _ = case_e
    s = tmp_path / "set"
    shutil.copytree(d, s)
    stage = pd.read_csv(s / "stage.csv")
    for c in ("left_image", "right_image"):
        names = []
        for f in stage[c]:
            img = read_image((d / f).resolve())
            out = s / (Path(f).stem + "_blurred.tif")
            blurred = cv2.GaussianBlur(img.astype(np.float32), (0, 0), 7.0)
            write_image(out, np.clip(np.rint(blurred), 0, np.iinfo(img.dtype).max).astype(img.dtype))
            names.append(out.name)
        stage[c] = names
    stage.to_csv(s / "stage.csv", index=False)
    blurred, notes = extract_set(s, progress=False)
    assert any("numbering anchored in 14 image(s)" in n for n in notes), notes
    both = pts.merge(blurred, on=["position", "row", "col"], suffixes=("", "_blurred"))
    for side in "lr":
        shift = np.hypot(both[f"w{side}1"] - both[f"w{side}1_blurred"], both[f"w{side}2"] - both[f"w{side}2_blurred"])
        assert shift.notna().sum() > 150 and shift.max() < 2.0, (side, shift.notna().sum(), shift.max())


# ----------------------------------------------------------------------------------- other real samples
@pytest.mark.slow  # extracts the 14 DICe image pairs
def test_dice_dot_target_pairs_through_extract(tmp_path, dataset_folder):
    pts, notes = extract_set(converters.dice_image_set(dataset_folder("dice-calb-sys2"), tmp_path / "dice"), progress=False)
    assert pts["position"].nunique() == 14 and any("donut" in n for n in notes)
    for _, g in pts.dropna(subset=["wl1", "wr1"]).groupby("position"):
        assert len(g) >= 60
        _, inl = cv2.findFundamentalMat(g[["wl1", "wl2"]].to_numpy(), g[["wr1", "wr2"]].to_numpy(), cv2.FM_RANSAC, 2.0, 0.999)
        assert inl.mean() >= 0.95   # the same [row, col] in both views is the same dot


def test_opencv_chessboard_pairs_through_extract(tmp_path, dataset_folder):
    folder = dataset_folder("opencv-stereo-chessboard")
    pts, _ = extract_set(converters.chessboard_image_set(folder, tmp_path / "c"), progress=False)
    counts = pts.dropna(subset=["wl1", "wr1"]).groupby("position").size()
    assert len(counts) == 13 and (counts == 54).all()


@pytest.mark.slow  # renders and calibrates a ChArUco stack
def test_a_virtual_charuco_stack_is_found_numbered_and_calibrates_to_the_floor(tmp_path):
    m = workspace.perfect_stage(slmlab.preset("paper"))
    board = {"squares": [16, 12], "square_mm": 0.3, "marker_mm": 0.22, "dictionary": "DICT_6X6_250", "legacy": True}
    sets = {}
    for name, z, seed in (("cal", np.linspace(-0.6, 0.6, 7), 1), ("val", [-0.45, 0.15, 0.45], 2)):
        d = render_board_set(tmp_path / name, m, board, z, seed=seed)
        pts, notes = extract_set(d, progress=False)
        truth = pd.read_csv(d / "truth.csv")
        merged = pts.merge(truth, on=["sequence", "position", "row", "col"], suffixes=("", "_t"))
        assert len(merged) == len(truth)                          # every corner numbered by its id
        e = np.r_[[merged[c] - merged[c + "_t"] for c in ("wl1", "wl2", "wr1", "wr2")]].ravel()
        # at the edge of the depth of field a marker may not decode, and the corners beside it drop out
        assert np.isfinite(e).mean() >= 0.99
        e = e[np.isfinite(e)]
        assert np.sqrt(np.mean(e ** 2)) < 0.05 and np.abs(e).max() < 0.3
        slmlab.io.write_csv(d / "points.csv", pts)
        sets[name] = (slmlab.read_set(d), merged)
    cal, (_, val) = sets["cal"][0], sets["val"]
    assert cal.known_target
    model = slmlab.calibrate(cal)
    frame = zstack_frame(m, orientation=board_orientation(m))
    origin = stage_origin(m, Session(positions=(0, 0, 0), grid=False))
    w = val[["wl1", "wl2", "wr1", "wr2"]].to_numpy()
    truth = val[["X_mm", "Y_mm", "Z_mm"]].to_numpy() @ frame.T
    floor = m.microscope_to_stage(m.triangulate(w), origin) @ frame.T - truth
    ours = model.reconstruct(w) - truth
    rms = lambda e: np.sqrt(np.mean((e - e.mean(axis=0)) ** 2, axis=0))  # noqa: E731
    assert (rms(ours) <= 1.2 * rms(floor)).all(), (rms(ours), rms(floor))


# ----------------------------------------------------------------------------------- tracking by the stage motion
def _lattice_at(stage_mm, first=(0, 0), n=7):
    """A :class:`PlateLattice` of a 7 × 7 plate seen at ``stage_mm``: (row, col) at ``O + (col − 1) u +
    (row − 1) v + R s`` [px], R = 40 px / mm of Z along w1 (two thirds of a pitch), −25 along w2; indices
    from ``first`` (each image numbers its own lattice from anywhere), and its map to (row, col)."""
    u, v, rate = np.array([60.0, 2.0]), np.array([-2.0, 62.0]), np.array([[0.0, 0.0, 40.0], [0.0, 0.0, -25.0]])
    r, c = np.meshgrid(np.arange(1, n + 1), np.arange(1, n + 1), indexing="ij")
    r, c = r.ravel(), c.ravel()
    w = np.array([500.0, 400.0]) + (c - 1)[:, None] * u + (r - 1)[:, None] * v + rate @ np.asarray(stage_mm, float)
    ab = np.column_stack([c - 1 + first[0], r - 1 + first[1]])
    pl = plate_lattice(fit_model(ab.astype(float), w), ab)
    to_set = np.array([[0, 1, 1 - first[1]], [1, 0, 1 - first[0]]], float)   # (row, col) from (i1, i2)
    return pl, to_set


def test_an_image_is_tracked_by_the_stage_motion_across_more_than_half_a_pitch():
    numbered = []
    for z in (0.0, -1.0, -2.0):
        pl, m = _lattice_at((0, 0, z), first=(int(3 * z), 5))
        numbered.append(Numbered(f"Z {z}", np.array([0, 0, z]), pl, m))
    target, truth = _lattice_at((0, 0, -3.0), first=(-4, 2))      # 0.67 pitch from the nearest along w1
    shift, ref, how = track(target, (0, 0, -3.0), numbered[::-1], 0.3)
    assert ref is numbered[-1] and "stage motion" in how
    got = np.column_stack([target.i1 + shift[0], target.i2 + shift[1], np.ones(len(target.i1))]) @ ref.to_set.T
    want = np.column_stack([target.i1, target.i2, np.ones(len(target.i1))]) @ truth.T
    assert np.array_equal(got, want)


def test_tracking_without_the_stage_motion_is_refused_not_guessed():
    pl, m = _lattice_at((0, 0, 0.0))
    target, _ = _lattice_at((0, 0, -1.0), first=(2, 2))
    shift, ref, why = track(target, (0, 0, -1.0), [Numbered("Z 0", np.zeros(3), pl, m)], 0.3)
    assert shift is None and ref is None and "TRACK_UNCERTAINTY" in why and "1 image(s)" in why
    # two images along Z say nothing of a move along X
    numbered = [Numbered(f"Z {z}", np.array([0, 0, z]), *_lattice_at((0, 0, z))) for z in (0.0, -1.0)]
    shift, _, why = track(target, (0.5, 0, -1.0), numbered, 0.3)
    assert shift is None and f"{0.5 / 0.3:.2f}" in why
    assert TRACK_UNCERTAINTY < 0.5


@pytest.fixture(scope="session")
def moving_plate_images():
    """Four positions of the 7 × 7 plate moved by two thirds of its pitch (0.2 mm) along X from one to the
    next, with their truth; the stage table's X is the plate's move."""
    m = slmlab.preset("paper")
    return [render_plate(m, m.moving_plate, (0.2 * k, 0.0, 0.0), seed=k) for k in range(4)]


def test_a_plate_cut_on_both_sides_is_tracked_across_more_than_half_a_pitch(tmp_path, moving_plate_images):
    d = make_set(tmp_path / "set", moving_plate_images)
    stage = (d / "stage.csv").read_text().splitlines()
    stage = [stage[0]] + [f"Z,{k},{0.2 * (k - 1):g},0,0,cam/{k}_l.png,cam/{k}_r.png" for k in range(1, 5)]
    (d / "stage.csv").write_text("\n".join(stage) + "\n")
    img, truth = moving_plate_images[3]
    cut = img.copy()
    pitch = float(np.median(np.diff(np.sort(truth.loc[truth["row"] == 1, "w1"]))))
    for x in (truth["w1"].min(), truth["w1"].max() + pitch):    # glare over the first column and beyond the last
        cut[:, int(x - pitch / 2):int(x + pitch / 2)] = 255
    for side, im in (("l", cut), ("r", np.roll(cut, 7, axis=1))):
        write_image(d / "cam" / f"4_{side}.png", im)
    pts, notes = extract_set(d, progress=False)
    assert any(f"{TRACKED} (2)" in n for n in notes), notes
    got = pts[pts["position"] == 4].set_index(["row", "col"])["wl1"]
    want = truth.set_index(["row", "col"])["w1"]
    assert len(got) >= 42 and np.abs(got - want.reindex(got.index)).max() < 0.5


def test_a_plate_cut_by_a_glare_is_numbered_from_the_one_edge_the_image_shows_empty(moving_plate_images):
    img, truth = moving_plate_images[0]
    cut = img.copy()
    pitch = float(np.median(np.diff(np.sort(truth.loc[truth["row"] == 1, "w1"]))))
    x0, x1, y = truth["w1"].min(), truth["w1"].max() + pitch, truth["w2"].max() - 2 * pitch
    cut[:, int(x0 - pitch / 2):int(x0 + pitch / 2)] = 255            # the first column lost in a glare
    cut[int(y):, int(x1 - pitch / 2):int(x1 + pitch / 2)] = 255      # and two sites of the line beyond the last
    dots = extract_image(cut, 7, 7)
    assert dots.frame == "plate", dots.note
    got = dots.table.merge(truth, on=["row", "col"], suffixes=("", "_true"))
    assert len(got) == 42 and np.abs(got["w1"] - got["w1_true"]).max() < 0.5


@pytest.mark.slow  # six calibrations with every candidate on the full extraction
def test_case_e_calibrated_on_its_extraction_the_default_is_no_worse_than_the_quadratic(case_e, tmp_path):
    """Calibrated on the extracted planes 1, 3, 5, 7 (a two-level plate: eight depths at four positions, a stage
    true to its commands), checked on the extracted planes 2, 4, 6: the default no worse than the plain
    quadratic in any coordinate, and within 15 % of the better of the Soloff and direct models (Z: the
    quadratic held out 2 % worse than the Soloff model, not the 5 % a candidate needs to beat a plain
    polynomial, and is 1.13x it here). A default that forgave each position's offset in the held-out errors,
    or let the pinhole pair judge between eight depths, took the pinhole in Z: 1.2x the quadratic."""
    d, pts, _ = case_e
    s = tmp_path / "set"
    shutil.copytree(d, s)
    slmlab.write_csv(s / "points.csv", pts)
    full = slmlab.read_set(s)
    models = {"quadratic": {"model": "quadratic"}, "default": {}, "direct": {"model": "direct"},
              "soloff": {"model": "soloff"}}
    t = realrigs.compare_on_planes(full, models, [1, 3, 5, 7], check=full, check_on=[2, 4, 6]).set_index("model")
    xyz = ["X_um", "Y_um", "Z_um"]
    assert (t.loc["default", xyz] <= t.loc["quadratic", xyz] * (1 + 1e-9)).all(), t[xyz]
    assert (t.loc["default", xyz] <= 1.15 * t.loc[["direct", "soloff"], xyz].min()).all(), t[xyz]


def test_a_set_s_images_are_read_once_checked_and_kept_within_the_budget(tmp_path, monkeypatch):
    """extract_set's reader: the first image read is checked against meta.json's size, the others as one size
    for the set; an image read for the cameras' hot pixels is kept for its extraction (read from memory once,
    then forgotten) while the kept images fit in KEEP_IMAGES_BYTES, and read again beyond it."""
    from slmlab.images import imageset
    paths = {}
    for name, size in (("a", (40, 30)), ("b", (40, 30)), ("c", (30, 40))):
        paths[name] = tmp_path / f"{name}.png"
        cv2.imwrite(str(paths[name]), np.full(size, 7, np.uint8))
    monkeypatch.setattr(imageset, "KEEP_IMAGES_BYTES", 40 * 30)
    images = imageset._Images((30, 40))
    with pytest.raises(slmlab.SlmlabError, match="correct image_size_px"):
        images.read(paths["c"])
    a = images.read(paths["a"], keep=True)
    assert images.held == a.nbytes and paths["a"] in images.kept
    images.read(paths["b"], keep=True)                     # beyond the budget: not kept
    assert paths["b"] not in images.kept
    assert images.read(paths["a"]) is a and images.held == 0 and not images.kept
    with pytest.raises(slmlab.SlmlabError, match="one size"):
        images.read(paths["c"])


def test_a_stage_file_naming_one_view_s_images_only_is_refused(tmp_path):
    """A misspelled header (``left`` for ``left_image``) left the left view without images: extract exited 0
    with every wl empty. One of the two columns alone is an error that names the missing one."""
    from slmlab.images.imageset import image_pairs
    (tmp_path / "stage.csv").write_text("sequence,position,stage_x_mm,stage_y_mm,stage_z_mm,left,right_image\n"
                                        "Z,1,0,0,0,a.png,b.png\n")
    with pytest.raises(slmlab.SlmlabError, match="has right_image but no left_image column"):
        image_pairs(tmp_path)
