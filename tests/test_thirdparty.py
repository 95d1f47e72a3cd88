"""Third-party point lists in the interchange format: UVMAT GeometryCalib files and matched stereo points."""

import numpy as np
import pandas as pd
import pytest

import slmlab
from slmlab.datasets import converters
from slmlab.models.frames import plate_xy

XML = """<?xml version="1.0" ?>
<tag><GeometryCalib><CoordUnit> {unit} </CoordUnit><SourceCalib>
{points}
</SourceCalib></GeometryCalib></tag>"""


def write_xml(path, rows, unit="cm"):
    pts = "\n".join(f'<PointCoord i="{k}">\n {" ".join(map(str, r))}\n</PointCoord>' for k, r in enumerate(rows, 1))
    path.write_text(XML.format(unit=unit, points=pts))
    return path


def test_uvmat_points_are_read_in_millimetres(tmp_path):
    df = converters.read_uvmat_points(write_xml(tmp_path / "a.xml", [(-1.5, 6, -0.3, 36.2, 96.9), (0, 6, -0.3, 214.9, 95.5)]))
    assert list(df.columns) == ["X_mm", "Y_mm", "Z_mm", "u_px", "v_px"]
    assert np.allclose(df.iloc[0], [-15.0, 60.0, -3.0, 36.2, 96.9])


@pytest.mark.parametrize("rows, unit, match", [
    ([], "cm", "no PointCoord"),
    ([(1, 2, 3, 4)], "cm", "PointCoord 1"),
    ([(1, 2, 3, 4, 5)], "inch", "CoordUnit"),
])
def test_bad_uvmat_files_are_one_clear_error(tmp_path, rows, unit, match):
    with pytest.raises(slmlab.SlmlabError, match=match):
        converters.read_uvmat_points(write_xml(tmp_path / "b.xml", rows, unit))


def lattice(z_values, pitch=15.0, n=3):
    x, y, z = np.meshgrid(np.arange(n) * pitch, np.arange(n) * pitch - pitch, z_values, indexing="ij")
    x, y, z = x.ravel(), y.ravel(), z.ravel()
    return pd.DataFrame({"X_mm": x, "Y_mm": y, "Z_mm": z, "u1_px": 10 * x, "v1_px": -10 * y,
                         "u2_px": 10 * x + 5 * z, "v2_px": -10 * y + 6 * z})


def test_matched_points_become_a_z_sequence_whose_plate_gives_back_x_and_y():
    common = lattice([-1.0, 0.0, 1.0, 2.0])
    cal = slmlab.datasets.converters.zstack_set_from_points(common)
    assert set(cal.points["sequence"]) == {"Z"} and sorted(cal.points["position"].unique()) == [1, 2, 3, 4]
    xy = plate_xy(cal.points["row"], cal.points["col"], cal.plate("Z")) + cal.points[["stage_x_mm", "stage_y_mm"]].to_numpy()
    back = pd.DataFrame({"X_mm": xy[:, 0], "Y_mm": xy[:, 1], "u1_px": cal.points["wl1"]})
    assert np.allclose(np.sort(back["X_mm"] * 1000 + back["u1_px"]), np.sort(common["X_mm"] * 1000 + common["u1_px"]))


def test_points_off_one_lattice_or_too_few_planes_are_refused():
    with pytest.raises(slmlab.SlmlabError, match="3 planes"):
        converters.zstack_set_from_points(lattice([0.0, 1.0]))
    bad = lattice([0.0, 1.0, 2.0])
    bad.loc[0, "X_mm"] = 7.0
    with pytest.raises(slmlab.SlmlabError, match="lattice"):
        converters.zstack_set_from_points(bad)
    with pytest.raises(slmlab.SlmlabError, match="u2_px"):
        converters.zstack_set_from_points(lattice([0.0, 1.0, 2.0]).drop(columns="u2_px"))
