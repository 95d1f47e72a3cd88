"""Simulated calibration sets: content, determinism, and the command line."""

import subprocess
import sys

import numpy as np
import pytest

import slmlab


def test_session_matches_table3_and_method_ranges(paper_set):
    ref = slmlab.paper_reference("table3", "tests")
    for row in ref:
        s = slmlab.paper_test(row["test"])
        assert s.step_mm == row["step_mm"]
        assert s.positions == (row["NUMX"], row["NUMY"], row["NUMZ"])
    v = slmlab.paper_reference("validation")
    pos = slmlab.validation_session().stage_positions()
    assert [pos["X"][:, 0].min(), pos["X"][:, 0].max()] == pytest.approx(v["X_range_mm"])
    assert [pos["Y"][:, 1].min(), pos["Y"][:, 1].max()] == pytest.approx(v["Y_range_mm"])
    assert [pos["Z"][:, 2].min(), pos["Z"][:, 2].max()] == pytest.approx(v["Z_range_mm"])
    counts = paper_set.points.groupby("sequence")["position"].nunique()
    assert counts.to_dict() == {"X": 42, "Y": 30, "Z": 32, "grid": 1}
    assert len(paper_set.sequence("grid")) == 27 * 29


def test_axis_sequences_move_only_their_axis(paper_set):
    for axis, col in zip("XYZ", ["stage_x_mm", "stage_y_mm", "stage_z_mm"]):
        df = paper_set.sequence(axis)
        others = [c for c in ["stage_x_mm", "stage_y_mm", "stage_z_mm"] if c != col]
        assert df[others].nunique().max() == 1
        assert df.loc[df["position"] == 1, col].iloc[0] == 0.0


def test_truth_is_consistent_with_points(paper_set):
    p, t = paper_set.points, paper_set.truth
    assert (p[["sequence", "position", "row", "col"]].to_numpy() == t[["sequence", "position", "row", "col"]].to_numpy()).all()
    seen = p[["wl1", "wl2", "wr1", "wr2"]].notna().to_numpy()
    diff = np.abs(p[["wl1", "wl2", "wr1", "wr2"]].to_numpy() - t[["wl1", "wl2", "wr1", "wr2"]].to_numpy())[seen]
    assert diff.max() < 0.5
    # world displacements along the X sequence follow the stage within micrometres
    x = paper_set.sequence("X")
    tx = t.loc[x.index]
    n_pos = x["position"].max()
    true_x = tx["X_mm"].to_numpy().reshape(n_pos, 49)  # rows are position-major
    d_true = true_x - true_x[0]
    d_cmd = x["stage_x_mm"].to_numpy().reshape(n_pos, 49)
    assert np.max(np.abs(d_true - d_cmd)) < 3e-3


def test_same_seed_same_bytes_other_seed_other_bytes(tmp_path):
    m = slmlab.preset("paper")
    a = slmlab.write_set(tmp_path / "a", slmlab.simulate_set(m, seed=7))
    b = slmlab.write_set(tmp_path / "b", slmlab.simulate_set(m, seed=7))
    c = slmlab.write_set(tmp_path / "c", slmlab.simulate_set(m, seed=8))
    for f in ("points.csv", "truth.csv", "meta.json"):
        assert (a / f).read_bytes() == (b / f).read_bytes()
    assert (a / "points.csv").read_bytes() != (c / "points.csv").read_bytes()


def test_written_set_reads_back(set_dir, paper_set):
    cal = slmlab.read_set(set_dir)
    assert cal.notes == []
    np.testing.assert_allclose(cal.points[["wl1", "wl2", "wr1", "wr2"]].to_numpy(),
                               paper_set.points[["wl1", "wl2", "wr1", "wr2"]].to_numpy(), rtol=0, atol=1e-6)
    assert cal.meta["plates"]["moving"] == {"rows": 7, "cols": 7, "pitch_mm": 0.3, "dot_diameter_mm": 0.15}
    assert cal.truth is not None and len(cal.truth) == len(cal.points)


def run_cli(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "slmlab", *args], capture_output=True, text=True, cwd=cwd, timeout=120)


def test_cli_simulate_is_byte_identical_for_a_seed(tmp_path):
    for d in ("a", "b"):
        r = run_cli("simulate", str(tmp_path / d), "--preset", "paper", "--seed", "3")
        assert r.returncode == 0, r.stderr
    for f in ("points.csv", "truth.csv", "meta.json"):
        assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes()
    cal = slmlab.read_set(tmp_path / "a")
    assert set(cal.sequences) == {"grid", "X", "Y", "Z"}


def test_cli_simulate_validation_and_other_tests(tmp_path):
    r = run_cli("simulate", str(tmp_path / "v"), "--validation", "--seed", "1")
    assert r.returncode == 0, r.stderr
    cal = slmlab.read_set(tmp_path / "v")
    assert cal.points.groupby("sequence")["position"].nunique().to_dict() == {"X": 42, "Y": 30, "Z": 31}
    r = run_cli("simulate", str(tmp_path / "t5"), "--test", "5")
    assert r.returncode == 0, r.stderr
    assert slmlab.read_set(tmp_path / "t5").points.groupby("sequence")["position"].nunique()["X"] == 9


@pytest.mark.slow  # three command-line runs
def test_unknown_preset_and_bad_test_are_user_errors(tmp_path):
    r = run_cli("simulate", str(tmp_path / "x"), "--preset", "nope")
    assert r.returncode == 2 and "unknown preset" in r.stderr and r.stderr.count("\n") == 1
    r = run_cli("simulate", str(tmp_path / "x"), "--test", "9")
    assert r.returncode == 2 and r.stderr.count("\n") == 1
    r = run_cli("simulate", str(tmp_path / "missing" / "x"))
    assert r.returncode == 2 and "does not exist" in r.stderr
