"""Physics of the virtual CMO microscope, checked against the geometry it claims."""

from dataclasses import replace

import numpy as np
import pytest

import slmlab
from slmlab.virtual.microscope import View


def undistorted(m: slmlab.Microscope) -> slmlab.Microscope:
    """The same microscope without distortion, camera rotation or magnification mismatch."""
    o = m.optics
    return replace(m, optics=replace(o, left=View(principal_point_px=o.left.principal_point_px),
                                     right=View(principal_point_px=o.right.principal_point_px)))


@pytest.mark.parametrize("name", ["paper", "leica"])
def test_disparity_grows_with_depth_as_the_geometry_implies(name):
    m = undistorted(slmlab.preset(name))
    o = m.optics
    L, t = o.perspective_distance_mm, np.tan(np.radians(o.convergence_deg) / 2)
    z = np.linspace(-1.5, 1.5, 13)
    w = m.project(np.column_stack([np.zeros_like(z), np.zeros_like(z), z]))
    d = (w[:, 2] - w[:, 0]) - (o.right.principal_point_px[0] - o.left.principal_point_px[0])
    # central projection from (±L t, 0, L) onto z = 0: disparity 2 t L z / (L - z), in pixels
    expected = 2 * t * L * z / (L - z) / o.pixel_mm
    np.testing.assert_allclose(d, expected, rtol=1e-9, atol=1e-9)
    # and the rate at focus is the one that gives the paper's EZ
    rate = np.gradient(d, z)[len(z) // 2]
    assert rate == pytest.approx(2 * t / o.pixel_mm, rel=1e-3)
    # perspective: disparity is not exactly linear in z (stronger above the focal plane)
    assert d[-1] > -d[0]


def test_disparity_is_nearly_linear_in_depth_with_full_distortion():
    m = slmlab.preset("paper")
    z = np.array([-1.0, 0.0, 1.0])
    w = m.project(np.column_stack([np.zeros(3), np.zeros(3), z]))
    d = w[:, 2] - w[:, 0]
    rate = (d[2] - d[0]) / 2
    t = np.tan(np.radians(m.optics.convergence_deg) / 2)
    assert rate == pytest.approx(2 * t / m.optics.pixel_mm, rel=3e-3)


def test_decentred_distortion_has_opposite_sign_in_the_two_views():
    m = slmlab.preset("paper")
    o = m.optics
    # a column of points in the focal plane on the objective axis: x = 0
    y = np.linspace(-2.5, 2.5, 41)
    pts = np.column_stack([np.zeros_like(y), y, np.zeros_like(y)])
    curv = {}
    for side, k in (("l", 0), ("r", 2)):
        w = m.project(pts)[:, k:k + 2]
        curv[side] = np.polyfit(w[:, 1], w[:, 0], 2)[0]
    assert np.sign(curv["l"]) == -np.sign(curv["r"])
    # the y² coefficient of Δx is (p1 + s1) in mm; in pixels (inverted image) the column bends by
    # -(p1 + s1)/m · w2², m = pixels per mm
    for side in "lr":
        v = o.view(side)
        expected = -(v.decentring_per_mm + v.thin_prism_per_mm) * o.pixel_mm / v.magnification_ratio
        assert curv[side] == pytest.approx(expected, rel=0.05)
    # rows fan out linearly (Eq 3): the slope of a row grows with its distance from the axis, oppositely
    x = np.linspace(-2.5, 2.5, 41)
    slopes = {}
    for side, k in (("l", 0), ("r", 2)):
        s = []
        for yy in (-2.0, 2.0):
            w = m.project(np.column_stack([x, np.full_like(x, yy), np.zeros_like(x)]))[:, k:k + 2]
            s.append(np.polyfit(w[:, 0], w[:, 1], 1)[0])
        slopes[side] = s[1] - s[0]
    assert np.sign(slopes["l"]) == -np.sign(slopes["r"]) != 0


@pytest.mark.parametrize("name", ["paper", "leica"])
def test_magnification_changes_with_depth_as_perspective_says(name):
    m = undistorted(slmlab.preset(name))
    L = m.optics.perspective_distance_mm
    z = np.array([-1.0, 0.0, 1.0])
    a = np.column_stack([np.zeros(3), np.zeros(3), z])
    b = a + [0.0, 1.0, 0.0]  # 1 mm along y: no disparity direction
    wa, wb = m.project(a), m.project(b)
    mag = np.abs(wb[:, 1] - wa[:, 1])
    np.testing.assert_allclose(mag / mag[1], L / (L - z), rtol=1e-12)
    # the rate at focus: about 0.33 %/mm for the paper preset, 1.6 %/mm for the Leica-like one
    assert (mag[2] - mag[0]) / 2 / mag[1] * 100 == pytest.approx(100 / L, rel=1e-3)


def test_triangulation_inverts_projection():
    m = slmlab.preset("paper")
    rng = np.random.default_rng(3)
    p = rng.uniform([-2.5, -2.5, -1.5], [2.5, 2.5, 1.5], size=(500, 3))
    back = m.triangulate(m.project(p))
    assert np.max(np.abs(back - p)) < 1e-9


def test_stage_axes_carry_the_paper_compensation_terms():
    st = slmlab.preset("paper").stage
    axes = st.axes
    # undo the rotation about z: the stage X axis then lies along x
    rot = np.arctan2(axes[1, 0], axes[0, 0])
    assert np.degrees(rot) == pytest.approx(st.rotation_deg, abs=1e-9)
    c, s = np.cos(-rot), np.sin(-rot)
    a = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]) @ axes
    assert a[0, 1] / a[1, 1] == pytest.approx(st.y_skew, rel=1e-9)
    assert a[2, 1] / a[1, 1] == pytest.approx(st.y_tilt, rel=1e-9)
    assert a[0, 2] / a[2, 2] == pytest.approx(st.z_tilt_x, rel=1e-9)
    assert a[1, 2] / a[2, 2] == pytest.approx(st.z_tilt_y, rel=1e-9)


def test_stage_errors_are_micrometre_sized_and_noise_is_random():
    st = slmlab.preset("paper").stage
    s = np.column_stack([np.linspace(0, -4, 41), np.zeros(41), np.zeros(41)])
    err = st.actual(s) - s
    assert 0 < np.max(np.abs(err)) < 2e-3  # below 2 µm
    a = st.actual(s, np.random.default_rng(1))
    b = st.actual(s, np.random.default_rng(2))
    assert 0 < np.std(a - b) < 1e-3


def test_centroid_noise_grows_with_defocus(paper_set):
    p, t = paper_set.points, paper_set.truth
    z = paper_set.sequence("Z")
    err = (p.loc[z.index, ["wl1", "wl2", "wr1", "wr2"]].to_numpy() - t.loc[z.index, ["wl1", "wl2", "wr1", "wr2"]].to_numpy())
    pos = z["position"].to_numpy()
    n = pos.max()
    middle = np.abs(pos - (n + 1) / 2) <= 2
    ends = (pos <= 2) | (pos >= n - 1)
    s_mid, s_end = np.nanstd(err[middle]), np.nanstd(err[ends])
    m = slmlab.preset("paper")
    assert s_mid == pytest.approx(m.noise.in_focus_px, rel=0.15)
    assert s_end > 1.8 * s_mid


def test_dots_outside_the_field_are_lost():
    m = slmlab.preset("paper")
    w = m.project(np.array([[0.0, 0.0, 0.0], [3.3, 0.0, 0.0], [-3.3, 0.0, 0.0]]))
    vis = m.visible(w, 0.15)
    assert vis[0].all() and not vis[1:].all()
