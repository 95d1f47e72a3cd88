"""The interchange format's reader: every malformed input is one SlmlabError naming the place."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

import slmlab
from slmlab.io import atomic_write_text


def run_cli(*args):
    return subprocess.run([sys.executable, "-m", "slmlab", *args], capture_output=True, text=True, timeout=120)


def rewrite_points(set_dir, edit):
    f = set_dir / "points.csv"
    lines = f.read_text().splitlines()
    lines = edit(lines)
    f.write_text("\n".join(lines) + "\n")


def expect_error(set_dir, *fragments):
    with pytest.raises(slmlab.SlmlabError) as exc:
        slmlab.read_set(set_dir)
    msg = str(exc.value)
    for frag in fragments:
        assert frag in msg, msg
    return msg


def test_missing_folder_and_files(tmp_path, set_dir):
    expect_error(tmp_path / "nope", "not found")
    (set_dir / "meta.json").unlink()
    expect_error(set_dir, "meta.json not found")


def test_file_given_for_folder(set_dir):
    expect_error(set_dir / "points.csv", "is a file")


def test_empty_and_header_only(set_dir):
    f = set_dir / "points.csv"
    header = f.read_text().splitlines()[0]
    f.write_text("")
    expect_error(set_dir, "empty")
    f.write_text(header + "\n")
    expect_error(set_dir, "no data rows")


def set_cell(set_dir, line: int, column: int, value: str):
    """points.csv's cell at file line index ``line`` (0: the header) and ``column`` set to ``value``."""
    def edit(lines):
        cells = lines[line].split(",")
        cells[column] = value
        lines[line] = ",".join(cells)
        return lines
    rewrite_points(set_dir, edit)


def test_non_numeric_value_names_row_and_column(set_dir):
    set_cell(set_dir, 5, 7, "abc")  # wl1
    expect_error(set_dir, "row 6", "column wl1", "not a number")


@pytest.mark.parametrize("value", ["nan", "inf", ""])
def test_non_finite_stage_value(set_dir, value):
    set_cell(set_dir, 3, 2, value)  # stage_x_mm
    expect_error(set_dir, "row 4", "stage_x_mm")


@pytest.mark.parametrize("column, name, value", [(1, "position", "100000000000000000001"), (6, "col", "100000")])
def test_an_index_too_large_for_an_integer_is_named(set_dir, column, name, value):
    """A position of 1e20 overflowed the cast to an integer: NumPy's warning on stderr, then an error about a
    duplicate row that was not one. A column of 100000 would share its key with the next row's first dot."""
    set_cell(set_dir, 3, column, value)
    expect_error(set_dir, "row 4", f"column {name}", "too large for an index")


def test_missing_column(set_dir):
    rewrite_points(set_dir, lambda lines: [line.rsplit(",", 1)[0] for line in lines])
    expect_error(set_dir, "lacks column", "wr2")


def test_binary_file_where_csv_expected(set_dir):
    (set_dir / "points.csv").write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00\x00")
    expect_error(set_dir, "binary")


def test_invalid_and_unknown_meta(set_dir):
    meta = set_dir / "meta.json"
    good = json.loads(meta.read_text())
    meta.write_text("{not json")
    expect_error(set_dir, "invalid JSON")
    meta.write_text(json.dumps({**good, "format": "slmlab-calibration/9"}))
    expect_error(set_dir, "slmlab-calibration/9", "slmlab-calibration/1")
    meta.write_text(json.dumps({**good, "image_size_px": [2048]}))
    expect_error(set_dir, "image_size_px")


def test_disagreeing_duplicates_are_an_error_identical_ones_a_note(set_dir):
    rewrite_points(set_dir, lambda lines: lines + [lines[10]])
    cal = slmlab.read_set(set_dir)
    assert cal.notes and "duplicate" in cal.notes[0]

    def edit(lines):
        cells = lines[10].split(",")
        cells[7] = str(float(cells[7]) + 1) if cells[7] else "1"
        return lines + [",".join(cells)]
    rewrite_points(set_dir, lambda lines: lines[:-1])
    rewrite_points(set_dir, edit)
    expect_error(set_dir, "duplicates row 11")


def test_plate_index_outside_the_plate(set_dir):
    def edit(lines):
        # the last line is a Z-sequence dot of the 7 x 7 plate
        cells = lines[-1].split(",")
        cells[5] = "8"
        lines[-1] = ",".join(cells)
        return lines
    rewrite_points(set_dir, edit)
    expect_error(set_dir, "column row", "outside the moving plate")


def test_cli_bad_input_is_exit_2_and_one_line(tmp_path, set_dir):
    (set_dir / "meta.json").write_text("[]")
    r = run_cli("calibrate", str(set_dir), "--out", str(tmp_path / "m.json"))
    assert r.returncode == 2
    assert r.stderr.startswith("slmlab: error: ") and r.stderr.count("\n") == 1
    assert "Traceback" not in r.stderr


def test_cli_missing_argument_is_exit_2_and_one_line():
    r = run_cli("calibrate")
    assert r.returncode == 2 and r.stderr.count("\n") == 1


def test_atomic_write_keeps_the_good_file(tmp_path, monkeypatch):
    target = tmp_path / "model.json"
    atomic_write_text(target, "good\n")

    def boom(src, dst):
        raise OSError("disk full")
    monkeypatch.setattr(os, "replace", boom)
    with pytest.raises(slmlab.SlmlabError, match="cannot be written: disk full"):   # the system's refusal, said
        atomic_write_text(target, "half")
    assert target.read_text() == "good\n"
    assert [p.name for p in tmp_path.iterdir()] == ["model.json"]


def test_output_through_a_link_and_never_onto_a_device_or_pipe(tmp_path):
    """A symbolic link is written through (the link kept); a pipe or a device is refused, not replaced by a file
    (as root, --out /dev/full once replaced the device node)."""
    (tmp_path / "target.json").write_text("old\n")
    (tmp_path / "link.json").symlink_to("target.json")
    atomic_write_text(tmp_path / "link.json", "new\n")
    assert (tmp_path / "link.json").is_symlink() and (tmp_path / "target.json").read_text() == "new\n"
    (tmp_path / "loop").symlink_to("loop")
    with pytest.raises(slmlab.SlmlabError, match="leads nowhere"):
        atomic_write_text(tmp_path / "loop", "x")
    os.mkfifo(tmp_path / "pipe")
    for path in (tmp_path / "pipe", "/dev/null"):
        with pytest.raises(slmlab.SlmlabError, match="not a regular file"):
            atomic_write_text(path, "x")
    assert (tmp_path / "pipe").exists() and not (tmp_path / "pipe").is_file()


def test_cli_system_refusals_and_a_negative_seed_are_exit_2_and_one_line(tmp_path):
    for args in (["simulate", str(tmp_path / "s"), "--seed", "-1"], ["simulate", "/proc/slmlab-no-such"],
                 ["simulate", str(tmp_path / ("x" * 300))]):
        r = run_cli(*args)
        assert r.returncode == 2 and r.stderr.startswith("slmlab: error: ") and r.stderr.count("\n") == 1, r.stderr
        assert ".tmp" not in r.stderr and (args[1] in r.stderr or "seed" in r.stderr), r.stderr   # the user's path


def test_output_in_a_missing_folder(tmp_path):
    with pytest.raises(slmlab.SlmlabError, match="does not exist"):
        atomic_write_text(tmp_path / "no" / "file.txt", "x")


def test_read_points_passes_other_columns_through(tmp_path):
    f = tmp_path / "p.csv"
    f.write_text("id,wl1,wl2,wr1,wr2\na,1,2,3,4\nb,,,,\n")
    df = slmlab.read_points(f)
    assert list(df["id"]) == ["a", "b"] and df["wl1"].isna().tolist() == [False, True]


def test_tables_keep_the_digits_their_numbers_carry(tmp_path, monkeypatch):
    """Issue 17: four significant digits, rounding noise as exact zeros, the paper's columns as reported; a
    last-bit difference (another machine's summation order) writes the same bytes."""
    import numpy as np
    import pandas as pd

    from slmlab.outputs import savetable, table_digits

    df = pd.DataFrame({"name": ["a", "b", "c"], "ours": [0.123456789, -1.5e-12, 12345.678],
                       "paper": [0.1234567, 0.0, 12345.678], "n": [1, 2, 3], "tiny": [3.2e-7, 1.2e-7, np.nan]})
    t = table_digits(df)
    assert t["ours"].tolist() == [0.1235, 0.0, 12350.0]
    assert t["paper"].tolist() == df["paper"].tolist() and t["n"].tolist() == [1, 2, 3]
    assert t["tiny"].iloc[:2].tolist() == [3.2e-7, 1.2e-7] and np.isnan(t["tiny"].iloc[2])
    monkeypatch.setenv("SLMLAB_FIGURES", str(tmp_path))
    savetable(df, "t")
    first = (tmp_path / "t.md").read_bytes(), (tmp_path / "t.csv").read_bytes()
    savetable(df.assign(ours=df["ours"] * (1 + 4e-16)), "t")
    assert ((tmp_path / "t.md").read_bytes(), (tmp_path / "t.csv").read_bytes()) == first
    assert b"e-12" not in first[0]


def test_a_table_caption_is_the_first_line_of_its_markdown_only(tmp_path, monkeypatch):
    """Issue 24: every table in figures/ says what it is and which notebook wrote it, as the first line of its
    .md; the .csv stays the table alone (the same bytes as without a caption)."""
    import pandas as pd

    from slmlab.outputs import savetable

    df = pd.DataFrame({"parameter": ["a", "b"], "ours": [1.5, -2.25]})
    monkeypatch.setenv("SLMLAB_FIGURES", str(tmp_path))
    savetable(df, "plain")
    savetable(df, "captioned", caption="Two numbers,\n   for a test (notebook 00).")
    md = (tmp_path / "captioned.md").read_text().splitlines()
    assert md[0] == "*Two numbers, for a test (notebook 00).*" and md[1] == ""
    assert md[2:] == (tmp_path / "plain.md").read_text().splitlines()
    assert (tmp_path / "captioned.csv").read_bytes() == (tmp_path / "plain.csv").read_bytes()


def test_a_set_of_points_reads_without_what_only_extraction_needs(set_dir):
    """dot_diameter_mm and a ChArUco board's details are checked by extraction, not by the reader; what is
    given is still checked."""
    meta = set_dir / "meta.json"
    good = json.loads(meta.read_text())
    plates = {k: {kk: vv for kk, vv in v.items() if kk != "dot_diameter_mm"} for k, v in good["plates"].items()}
    meta.write_text(json.dumps({**good, "plates": plates}))
    assert "dot_diameter_mm" not in slmlab.read_set(set_dir).plate("X")
    plates["moving"]["pattern"] = "charuco"
    meta.write_text(json.dumps({**good, "plates": plates}))
    assert slmlab.read_set(set_dir).plate("X")["pattern"] == "charuco"
    plates["moving"]["board"] = "DICT_6X6_250"
    meta.write_text(json.dumps({**good, "plates": plates}))
    expect_error(set_dir, "plates.moving.board must be an object")
    plates["moving"]["board"], plates["moving"]["dot_diameter_mm"] = {"squares": [8, 8]}, -1
    meta.write_text(json.dumps({**good, "plates": plates}))
    expect_error(set_dir, "plates.moving.dot_diameter_mm must be a positive number")


@pytest.mark.slow
def test_reconstruct_says_which_uncertainty_the_model_cannot_give(tmp_path):
    """Where the default took a coordinate from the pinhole pair, which gives no per-point uncertainty, that
    coordinate's uncertainty column is empty (sZ_mm in all 677 rows, without a word): reconstruct says so. The
    columns stay, for every reader of reconstruct's output."""
    import pandas as pd
    s, m, out = tmp_path / "s", tmp_path / "m.json", tmp_path / "r.csv"
    for args in (["simulate", s, "--rig", "stereo-dic:1234", "--design", "two-level"], ["calibrate", s, "--out", m],
                 ["reconstruct", m, s / "points.csv", "--out", out]):
        r = run_cli(*map(str, args))
        assert r.returncode == 0, r.stderr
    sel = json.loads(m.read_text())["calibration"]["selection"]["choice"]
    df = pd.read_csv(out)
    empty = [c for c in ("sX_mm", "sY_mm", "sZ_mm") if df[c].isna().all()]
    assert [f"s{c}_mm" for c, k in sel.items() if k == "pinhole"] == empty and empty, (sel, empty)
    assert f"note: {', '.join(empty)} left empty" in r.stdout, r.stdout
    assert np.isfinite(df[["X_mm", "Y_mm", "Z_mm"]].to_numpy()).all()


def test_a_new_set_is_written_whole_or_not_at_all(tmp_path):
    """Under a file-size limit simulate left a folder holding points.csv alone (and a traceback): the set is
    written in a temporary folder beside it and renamed when whole, the error one line naming the set's file."""
    out = tmp_path / "sp"
    r = subprocess.run(["bash", "-c", f"ulimit -f 200; exec {sys.executable} -m slmlab simulate {out} --rig "
                        "stereo-piv:7 --design zstack-2"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and f"{out}/" in r.stderr, r.stderr
    assert list(tmp_path.iterdir()) == []
    assert run_cli("simulate", str(out), "--rig", "stereo-piv:7", "--design", "zstack-2").returncode == 0
    assert {p.name for p in out.iterdir()} == {"points.csv", "truth.csv", "meta.json"}
    assert oct(out.stat().st_mode & 0o777) == oct(0o777 & ~_umask())


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@pytest.mark.slow  # the command line three times, once with images
def test_a_set_simulated_again_into_its_folder_replaces_it_and_no_other_folder_is_taken(tmp_path):
    """A set simulated with images and then again without: the old stage.csv and images stayed beside the new
    points and truth, and ``extract`` numbered half the dots wrongly against them. The old simulated set's own
    files go (a file of the user's beside them stays); a folder holding anything but a simulated set is refused in
    one line, and nothing is written into it."""
    out = tmp_path / "set"
    assert run_cli("simulate", str(out), "--rig", "greenough:3", "--design", "zstack-3", "--images").returncode == 0
    (out / "notes.txt").write_text("mine\n")
    r = run_cli("simulate", str(out), "--rig", "greenough:3", "--design", "zstack-2", "--seed", "5")
    assert r.returncode == 0, r.stderr
    assert {p.name for p in out.iterdir()} == {"points.csv", "truth.csv", "meta.json", "notes.txt"}
    assert json.loads((out / "meta.json").read_text())["simulator"]["design"] == "zstack-2"
    other = tmp_path / "other"
    other.mkdir()
    (other / "data.csv").write_text("a\n1\n")
    r = run_cli("simulate", str(other), "--rig", "greenough:3", "--design", "zstack-2")
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "no simulated set" in r.stderr, r.stderr
    assert [p.name for p in other.iterdir()] == ["data.csv"]


@pytest.mark.slow  # the command line four times
def test_calibrate_and_reconstruct_do_not_write_over_their_inputs(tmp_path):
    """``calibrate --out`` onto the set's own points.csv replaced it with the model (and the set could no longer be
    read); ``reconstruct --out`` onto the model file likewise. Both are refused in one line, the inputs untouched."""
    out = tmp_path / "set"
    assert run_cli("simulate", str(out), "--rig", "greenough:3", "--design", "zstack-3").returncode == 0
    before = (out / "points.csv").read_bytes()
    r = run_cli("calibrate", str(out), "--model", "quadratic", "--out", str(tmp_path / "set" / ".." / "set" / "points.csv"))
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "--out is the input points.csv" in r.stderr, r.stderr
    assert (out / "points.csv").read_bytes() == before
    model = tmp_path / "m.json"
    assert run_cli("calibrate", str(out), "--model", "quadratic", "--out", str(model)).returncode == 0
    saved = model.read_bytes()
    r = run_cli("reconstruct", str(model), str(out / "points.csv"), "--out", str(model))
    assert r.returncode == 2 and "--out is the input m.json" in r.stderr and model.read_bytes() == saved, r.stderr


@pytest.mark.parametrize("extra", [["--preset", "leica"], ["--test", "3"], ["--validation"]])
def test_the_cmo_microscope_s_options_beside_a_rig_are_refused_not_ignored(tmp_path, extra):
    """``--rig`` with ``--preset``, ``--test`` or ``--validation`` wrote the rig's set as if they were not there."""
    r = run_cli("simulate", str(tmp_path / "s"), "--rig", "greenough", "--design", "zstack-2", *extra)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and f"{extra[0]} is the CMO microscope's" in r.stderr
    assert not (tmp_path / "s").exists()


@pytest.mark.slow  # the command line three times, once with images
def test_a_microscope_set_simulated_again_loses_its_old_images_and_a_failed_one_keeps_the_old_set(tmp_path):
    """The CMO microscope's images carry no stage.csv: simulated again without images, the old 48 stayed in
    images/ and extract read them (33 % found, 2156 misindexed, from the review). They go now, a file of the
    user's in images/ stays; and a simulation that fails (a file-size limit) leaves the old set as it was."""
    out = tmp_path / "cmo"
    assert run_cli("simulate", str(out), "--test", "5", "--seed", "4", "--images").returncode == 0
    (out / "images" / "mine.png").write_bytes(b"not a set's image")
    assert run_cli("simulate", str(out), "--test", "3", "--seed", "9").returncode == 0
    assert [p.name for p in (out / "images").iterdir()] == ["mine.png"]
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    r = subprocess.run(["bash", "-c", f"ulimit -f 100; exec {sys.executable} -m slmlab simulate {out} --test 2"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} == before
    assert [p.name for p in tmp_path.iterdir()] == ["cmo"]       # no temporary folder left beside it
    assert not [p.name for p in out.iterdir() if p.name.startswith(".")]   # nor in it
