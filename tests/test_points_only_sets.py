"""Sets of points from another tool (DATA_FORMAT.md): what only extraction needs is not asked of them, and
every model that can use such a set calibrates from it on the command line."""

import json
import subprocess
import sys

import numpy as np
import pytest

import slmlab
from slmlab import CalibrationSet
from slmlab.studies.workspace import perfect_stage
from slmlab.virtual.simulate import stepped_target, target_set

#: models that use a known-target Z stack, and the paper's, which need X, Y, Z sequences and the grid pair
USERS = ("auto", "direct", "soloff", "quadratic", "pinhole")
PAPER = ("paper-m0", "paper-m1", "paper-m2")


def cli(*args):
    return subprocess.run([sys.executable, "-m", "slmlab", *map(str, args)], capture_output=True, text=True, timeout=600)


@pytest.fixture(scope="session")
def charuco_points(tmp_path_factory):
    """ChArUco corners as another tool writes them: a flat 11 × 15 board of 0.3 mm squares at four stage Z
    positions, known-target columns, a plate that says ``"pattern": "charuco"`` without the board's details
    and without ``dot_diameter_mm``, no images."""
    m = perfect_stage(slmlab.preset("paper"))
    board = stepped_target(rows=11, cols=15, pitch_mm=0.3, steps_mm=(0.0,))
    cal = target_set(m, board, [[0.0, 0.0, z] for z in (-0.45, -0.15, 0.15, 0.45)], seed=4, sequence="Z")
    meta = {**{k: v for k, v in cal.meta.items() if k != "simulator"},
            "plates": {"moving": {"pattern": "charuco", "pitch_mm": 0.3}}}
    d = slmlab.write_set(tmp_path_factory.mktemp("charuco") / "set", CalibrationSet(cal.points, meta))
    return d, cal


@pytest.mark.parametrize("model", USERS + PAPER)
def test_a_points_only_charuco_set_calibrates_with_every_model_that_can_use_it(model, charuco_points, tmp_path):
    d, cal = charuco_points
    r = cli("calibrate", d, "--model", model, "--out", tmp_path / "m.json")
    if model in PAPER:
        assert r.returncode == 2 and r.stderr.count("\n") == 1 and "X sequence" in r.stderr, r.stderr
        return
    assert r.returncode == 0, r.stderr
    pts = cal.points.dropna(subset=["wl1", "wl2", "wr1", "wr2"])
    e = slmlab.load_model(tmp_path / "m.json").reconstruct(pts[["wl1", "wl2", "wr1", "wr2"]].to_numpy())
    e = e - cal.truth.loc[pts.index, ["X_mm", "Y_mm", "Z_mm"]].to_numpy()
    rms_um = 1e3 * np.sqrt(np.mean((e - e.mean(axis=0)) ** 2, axis=0))
    # the corners' own noise gives about 0.05 µm in X, Y and 0.43 µm in Z on this board
    assert (rms_um < [0.1, 0.1, 0.6]).all(), rms_um


def test_the_points_only_meta_json_has_none_of_the_imaging_details(charuco_points):
    d, _ = charuco_points
    plate = json.loads((d / "meta.json").read_text())["plates"]["moving"]
    assert plate["pattern"] == "charuco" and "board" not in plate and "dot_diameter_mm" not in plate


@pytest.mark.parametrize("label", ["V", "K", "stack"])
def test_any_sequence_label_but_grid_and_t_is_a_free_set_of_stage_positions(tmp_path, label):
    """The format names X, Y, Z for the axis sequences and 'any other label (e.g. V)' a free set of stage
    positions: a Z stack relabelled calibrates as the Z stack does (only V did: K and stack were refused)."""
    from slmlab.virtual.designs import simulate_design
    from slmlab.virtual.rigs import rig_by_name
    cal = simulate_design(rig_by_name("greenough:97"), "zstack-2", seed=1)
    relabelled = CalibrationSet(cal.points.assign(sequence=cal.points["sequence"].replace("Z", label)), cal.meta)
    w = cal.points[["wl1", "wl2", "wr1", "wr2"]].dropna().to_numpy()[::50]
    np.testing.assert_allclose(slmlab.calibrate(relabelled, "direct").reconstruct(w),
                               slmlab.calibrate(cal, "direct").reconstruct(w), atol=1e-9)
