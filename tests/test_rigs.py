"""The zoo of virtual stereo rigs (slmlab.virtual.rigs) and its calibration designs (slmlab.virtual.designs):
the physics each rig claims, checked against independent geometry, and sets that read back."""

import json
from dataclasses import replace

import numpy as np
import pytest

import slmlab
from slmlab.virtual.designs import DESIGNS, simulate_design, validation_set
from slmlab.virtual.microscope import CentroidNoise
from slmlab.virtual.rig_checks import fermat_crossings
from slmlab.virtual.rigs import RANGES, RIG_CLASSES, RIGS, make_rig, random_rig, rig_from_dict
from slmlab.virtual.simulate import noise_floor

KINDS = tuple(RIG_CLASSES)
_PRESETS = {}


def preset_rig(name):
    """The named rig, built once per test session (rigs are frozen)."""
    if name not in _PRESETS:
        _PRESETS[name] = make_rig(name)
    return _PRESETS[name]


def field_points(rig, n=300, seed=0, z_scale=1.0):
    """Random rig-frame points in the common field over ±depth."""
    fw, fh = rig.field_mm()
    rng = np.random.default_rng(seed)
    return rig.field_centre_mm() + rng.uniform(-1, 1, (n, 3)) * [fw / 2, fh / 2, z_scale * rig.depth_mm()]


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_triangulation_inverts_projection(kind, seed):
    rig = random_rig(kind, seed)
    p = field_points(rig, seed=seed)
    w = rig.project(p)
    assert rig.visible(w, 0.0).all()
    np.testing.assert_allclose(rig.triangulate(w), p, rtol=0, atol=1e-9)


@pytest.mark.parametrize("kind", KINDS)
def test_random_rigs_stay_within_their_stated_ranges(kind):
    r = RANGES[kind]
    for seed in range(4):
        rig = random_rig(kind, seed)
        assert r["half_angle_deg"][0] <= rig.half_angle_deg <= r["half_angle_deg"][1]
        axes = [rig.camera(s).rotation[2] for s in "lr"]
        convergence = np.degrees(np.arccos(axes[0] @ axes[1]))
        if kind == "greenough":  # each objective 2.5-4° from the vertical (±0.1° error): convergence 5-8°
            assert 4.8 <= convergence <= 8.2
            assert r["working_distance_mm"][0] <= rig.working_distance_mm <= r["working_distance_mm"][1]
            assert r["object_pixel_mm"][0] <= rig.object_pixel_mm <= r["object_pixel_mm"][1]
            assert r["field_mm"][0] <= rig.image_size_px[0] * rig.object_pixel_mm <= r["field_mm"][1]
        else:
            assert rig.focal_mm in r["focal_mm"]
            assert r["f_number"][0] <= rig.f_number <= r["f_number"][1]
        if kind == "stereo-dic":
            assert r["standoff_mm"][0] <= rig.standoff_mm <= r["standoff_mm"][1]
        if kind == "stereo-piv":
            assert r["wall_thickness_mm"][0] <= rig.wall_thickness_mm <= r["wall_thickness_mm"][1]
            assert r["water_depth_mm"][0] <= rig.water_depth_mm <= r["water_depth_mm"][1]
        width, height = rig.image_size_px
        assert 1.8e6 <= width * height <= 4.1e6 or kind == "greenough"


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_refraction_obeys_fermat(seed):
    """The air part of each chief ray (from the transverse invariant) against a generic minimisation of the
    optical path length over where the ray crosses the wall's two faces."""
    rig = random_rig("stereo-piv", seed)
    p = field_points(rig, n=8, seed=seed)
    for side in "lr":
        cam = rig.camera(side)
        d = rig.chief_rays(p, cam)[0] @ cam.rotation  # rig-frame unit direction from the pupil
        for k, q in enumerate(p):
            x = fermat_crossings(rig, q, side)
            rho = np.hypot(*(cam.centre[:2] - q[:2]))
            h_air = cam.centre[2] - rig.water_depth_mm - rig.wall_thickness_mm
            sin_air = (rho - x[1]) / np.hypot(rho - x[1], h_air)
            assert np.hypot(d[k, 0], d[k, 1]) == pytest.approx(sin_air, abs=1e-12)


def test_rays_traced_into_the_water_pass_through_the_point():
    """Forward tracing (Snell's law face by face, from the image) meets the inverse (the invariant solved
    from the point)."""
    rig = preset_rig("stereo-piv")
    p = field_points(rig, n=200)
    w = rig.project(p)
    for side, k in (("l", 0), ("r", 2)):
        o, d = rig.rays(w[:, k:k + 2], side)
        miss = np.linalg.norm(np.cross(p - o, d), axis=1)
        assert miss.max() < 1e-9


def test_scheimpflug_in_air_is_the_classical_condition():
    """Without refraction (every index 1), the fitted sensor plane is the Scheimpflug plane: tilted by
    tan τ = (v / s) tan θ from the lens plane, and the plane z = 0 is sharp everywhere."""
    rig = replace(preset_rig("stereo-piv"), glass_index=1.0, water_index=1.0)
    for side in "lr":
        cam = rig.camera(side)
        e = rig.left if side == "l" else rig.right
        theta = np.radians(rig.half_angle_deg + e.angle_error_deg)
        s = rig.standoff_mm * (1 + e.distance_error)
        v = rig.focal_mm * s / (s - rig.focal_mm)
        tau = np.arctan2(np.hypot(cam.normal[0], cam.normal[1]), cam.normal[2])
        assert np.tan(tau) == pytest.approx(v / s * np.tan(theta), rel=1e-9)
        assert cam.x0[2] == pytest.approx(v, rel=1e-9)
        defocus, astig = rig.blur_components_px(field_points(rig, z_scale=0.0), side)
        assert defocus.max() < 1e-9 and astig.max() < 1e-9


def test_through_the_wall_the_sheet_is_in_focus_but_for_astigmatism():
    piv, dic = preset_rig("stereo-piv"), preset_rig("stereo-dic")
    for side in "lr":
        defocus, astig = piv.blur_components_px(field_points(piv, z_scale=0.0), side)
        assert defocus.max() < 0.05 < astig.max()
        # an untilted sensor (stereo-DIC) sees the oblique plane out of focus towards the field's sides
        assert dic.blur_components_px(field_points(dic, z_scale=0.0), side)[0].max() > 10 * defocus.max()
        # and blur grows off the sheet
        assert piv.blur_px(field_points(piv), side)[0].max() > astig.max()


def test_greenough_views_see_the_object_plane_with_keystone():
    """Each image plane is perpendicular to its own objective's axis: a row of equal steps on z = 0 images with
    steps that grow towards the objective's side, oppositely in the two views."""
    rig = preset_rig("greenough")
    fw, _ = rig.field_mm()
    x = np.linspace(-0.4, 0.4, 9) * fw
    w = rig.project(np.column_stack([x, np.zeros_like(x), np.zeros_like(x)]))
    trend = [np.polyfit(x[1:], np.diff(w[:, k]), 1)[0] for k in (0, 2)]
    assert trend[0] < 0 < trend[1]


def test_centroid_noise_grows_with_defocus():
    rig = preset_rig("greenough")
    c = rig.field_centre_mm()
    z = np.linspace(0, 2 * rig.depth_of_field_mm(), 5)
    sigma = rig.centroid_sigma_px(c + np.column_stack([0 * z, 0 * z, z]))
    assert np.all(np.diff(sigma) > 0)
    assert sigma[0] == pytest.approx(rig.noise.in_focus_px, rel=1e-3)
    assert sigma[2] == pytest.approx(rig.noise.at_dof_edge_px, rel=0.02)


@pytest.mark.parametrize("name", list(RIGS))
def test_rigs_rebuild_from_their_dict(name):
    rig = preset_rig(name)
    back = rig_from_dict(json.loads(json.dumps(rig.as_dict())))
    assert back == rig and rig.as_dict()["rig"] == rig.kind
    p = field_points(rig, n=10)
    assert np.array_equal(back.project(p), rig.project(p))
    cmo = slmlab.preset("paper")
    assert rig_from_dict(cmo.as_dict()) == cmo


# each design on one rig, each rig on several designs (to keep the suite fast)
CASES = list(zip(DESIGNS, ["greenough", "stereo-dic", "stereo-piv", "greenough", "stereo-dic", "greenough",
                           "stereo-piv", "stereo-dic", "stereo-piv", "greenough", "stereo-dic"]))
assert len(CASES) == len(DESIGNS), "give every design a rig"


@pytest.mark.parametrize("design, name", CASES)
def test_designs_write_sets_that_read_back(tmp_path, design, name):
    rig = preset_rig(name)
    cal = simulate_design(rig, design, seed=3)
    back = slmlab.read_set(slmlab.write_set(tmp_path / "set", cal))
    assert back.points[slmlab.io.IMAGE_COLUMNS].notna().all(axis=1).mean() > 0.9
    assert len(back.truth) == len(back.points) and not back.notes
    assert back.meta["simulator"]["design"] == design
    rebuilt = rig_from_dict(back.meta["simulator"]["microscope"])
    assert rebuilt.replace(moving_plate=rig.moving_plate) == rig
    if design.startswith("two-level"):
        plate = back.meta["plates"]["moving"]
        assert plate["levels"] == 2 and set(back.points["level"].astype(int)) == {0, 1}
        z = back.points.loc[back.points["level"].astype(int) == 1, "z_mm"]
        assert np.allclose(z, plate["level_offset_mm"])
    if design in ("stepped-target", "charuco-stack") or design.startswith("two-level"):
        assert back.known_target
    # the world positions of the truth agree with where the set says the dots are
    world = back.world() if back.known_target else None
    if world is not None:
        shift = back.truth[["X_mm", "Y_mm", "Z_mm"]].to_numpy() - world
        assert np.ptp(shift, axis=0).max() < 5e-3 * max(rig.field_mm())


@pytest.mark.parametrize("name", list(RIGS))
def test_same_seed_same_bytes(tmp_path, name):
    rig = preset_rig(name)
    design = {"greenough": "zstack-3", "stereo-dic": "stage-sequences", "stereo-piv": "two-level-2z"}[name]
    files = []
    for k, seed in enumerate((7, 7, 8)):
        d = slmlab.write_set(tmp_path / f"s{k}", simulate_design(rig, design, seed=seed))
        files.append({f: (d / f).read_bytes() for f in ("points.csv", "meta.json", "truth.csv")})
    assert files[0] == files[1]
    assert files[0]["points.csv"] != files[2]["points.csv"]


def test_noise_floor_of_a_noiseless_rig_is_the_truth():
    rig = replace(preset_rig("stereo-piv"), noise=CentroidNoise(0.0, 0.0),
                  stage=replace(preset_rig("stereo-piv").stage, positioning_noise_um=0.0))
    cal = simulate_design(rig, "zstack-3", seed=1)
    np.testing.assert_allclose(noise_floor(cal), cal.truth[["X_mm", "Y_mm", "Z_mm"]].to_numpy(), atol=1e-9)
    val = validation_set(rig, cal, n_points=50, seed=2)
    np.testing.assert_allclose(noise_floor(val), val.truth[["X_mm", "Y_mm", "Z_mm"]].to_numpy(), atol=1e-9)
