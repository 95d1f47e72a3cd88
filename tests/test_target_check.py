"""A model's check on a known target (slmlab.target_check): ``evaluate`` on a set without stage sequences."""
import json
import subprocess
import sys

import numpy as np
import pytest

import slmlab
from slmlab.target_check import target_residuals
from slmlab.virtual.designs import simulate_design
from slmlab.virtual.rigs import rig_by_name


@pytest.fixture(scope="module")
def stepped():
    return simulate_design(rig_by_name("stereo-dic:4"), "stepped-target", seed=1)


def _truth_reconstruction(cal, scale=1.0, shift_mm=(0.0, 0.0, 0.0)):
    """A 'model' that answers each dot's true place [mm], scaled about the origin and shifted."""
    t = cal.truth.set_index(["sequence", "position", "row", "col"])
    keys = list(map(tuple, cal.points[["sequence", "position", "row", "col"]].to_numpy()))
    xyz = t.loc[keys][["X_mm", "Y_mm", "Z_mm"]].to_numpy()
    lookup = {tuple(w): p for w, p in zip(cal.points[["wl1", "wl2", "wr1", "wr2"]].to_numpy(float), xyz)}
    return lambda w: np.array([lookup[tuple(r)] for r in w]) * scale + np.asarray(shift_mm)


def test_the_true_places_leave_nothing_and_a_scale_error_its_share_of_the_target(stepped):
    """The true places, moved anywhere, align onto the target with nothing left (the pose is taken out); a scale
    error of 1e-3 is left as 1e-3 of each point's distance from the target's centre (the RMS of that distance along
    each axis: the rigid fit does not take out scale)."""
    r = target_residuals(_truth_reconstruction(stepped, shift_mm=(3.0, -2.0, 40.0)), stepped)
    assert len(r) == len(stepped.points) and np.abs(r[["E_x", "E_y", "E_z"]].to_numpy()).max() < 1e-9
    r = target_residuals(_truth_reconstruction(stepped, scale=1.001), stepped)
    q = stepped.points[["x_mm", "y_mm", "z_mm"]].to_numpy(float)
    spread = np.sqrt(((q - q.mean(axis=0)) ** 2).mean(axis=0))
    rms = np.sqrt((r[["E_x", "E_y", "E_z"]].to_numpy() ** 2).mean(axis=0))
    assert np.allclose(rms, 1e-3 * spread, rtol=0.02), (rms, 1e-3 * spread)


def test_evaluate_on_a_known_target_set_reports_its_shape_and_a_set_of_neither_is_refused(tmp_path, stepped):
    """``evaluate`` refused a known-target set ('no X, Y or Z sequence'); it now reports the target's residual per
    axis (text and --json). A set with neither stage sequences nor target places is still one line, exit 2."""
    run = lambda *a: subprocess.run([sys.executable, "-m", "slmlab", *a], capture_output=True, text=True, timeout=300)
    out = tmp_path / "kt"
    assert run("simulate", str(out), "--rig", "stereo-dic:4", "--design", "stepped-target").returncode == 0
    assert run("calibrate", str(out), "--model", "quadratic", "--out", str(tmp_path / "m.json")).returncode == 0
    r = run("evaluate", str(tmp_path / "m.json"), str(out))
    assert r.returncode == 0 and "on the known target (1 pose(s)" in r.stdout, r.stdout + r.stderr
    j = json.loads(run("evaluate", str(tmp_path / "m.json"), str(out), "--json").stdout)
    axes = {a["axis"]: a for a in j["known_target"]["axes"]}
    assert j["known_target"]["points"] == len(stepped.points) and 0 < axes["z"]["rms_mm"] < 0.05
    cal = slmlab.read_set(out)
    cal.points = cal.points.drop(columns=["x_mm", "y_mm", "z_mm"])
    with pytest.raises(slmlab.SlmlabError, match="no target places"):
        target_residuals(lambda w: np.zeros((len(w), 3)), cal)
