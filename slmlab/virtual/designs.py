"""Calibration designs for any virtual rig, scaled to its field and depth (:mod:`slmlab.virtual.rigs`).

Each design is what a lab would image to calibrate the rig, scaled from the paper's CMO sessions by the
rig's common field (:meth:`~slmlab.virtual.rigs.StereoRig.field_mm`, ``W × H``) and the depth its designs
span (:meth:`~slmlab.virtual.rigs.StereoRig.depth_mm`, ``±d``):

``zstack-2``, ``zstack-3``, ``zstack-5``, ``zstack-7``, ``zstack-13``
    a field-filling dot plate (25 dots across the smaller side, mounted 0.4° rotated and 0.05° tilted) at
    2, 3, 5, 7 or 13 equally spaced stage Z positions over ``[-d, +d]``.
``stage-sequences``
    the paper's X, Y and Z axis sequences (paper §6) with Test 2's counts (21, 15, 16 positions) and the
    grid pair, scaled: X spans 94 % and Y 67 % of the room the moving plate leaves in the field (Test 1's
    4.1 and 2.9 mm of 4.3 mm on the CMO microscope), Z spans 2.74 ``d`` (3.1 mm over its ±1.13 mm).
``stepped-target``
    a stepped 3D target in one pose (:func:`slmlab.virtual.simulate.stepped_target`): 31 dots across the smaller
    side, five heights over ±0.9 ``d``.
``two-level``, ``two-level-2z``, ``two-level-3z``
    a two-level plate (the stereo-PIV convention: rows alternating between two depths, the
    second level's rows offset by half a pitch, numbered in half pitches, with a ``level`` column and
    ``levels``/``level_offset_mm`` in ``meta.json``), the second level behind the first by as much as
    puts its dots a quarter of a pitch off the first level's cell centres in either view, at most ``0.6 d``
    (:func:`two_level_offset_mm`), in one pose, or at 2 (``±d/2``) or 3 (``-d/2, 0, +d/2``) stage Z positions.
``charuco-stack``
    a ChArUco board's inner corners as a known target (points mode: ``x_mm, y_mm, z_mm`` in the board's
    frame), at 5 stage Z positions over ``[-d, +d]``.

Known targets are mounted with their axes along the stage's (as :func:`slmlab.virtual.simulate.target_set`), so a
model calibrated on them reconstructs in the stage frame, as one calibrated on stage moves does; a Z stack
of a dot plate reconstructs in the plate's frame (:func:`design_frame`).

Every design is simulated by the one simulator of the CMO microscope (:func:`slmlab.virtual.simulate.simulate_set`,
:func:`slmlab.virtual.simulate.target_set`), which asks a rig only what any rig can say; its noise floor is
:func:`slmlab.virtual.simulate.noise_floor`.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd
from scipy.spatial import ConvexHull, Delaunay, QhullError

from ..errors import SlmlabError
from ..io import IMAGE_COLUMNS, CalibrationSet
from .rigs import sized_plate
from .sessions import Session, zstack_frame
from .simulate import simulate_set, stepped_target, target_set

__all__ = ["ZSTACK_PLANES", "DESIGNS", "paper_sequences", "zstack_design", "two_level_target", "TWO_LEVEL_PARALLAX",
           "two_level_offset_mm", "charuco_corners", "known_target_set", "simulate_design", "design_frame", "validation_set"]

ZSTACK_PLANES = (2, 3, 5, 7, 13)
#: the designs by name, with a line each
DESIGNS = {
    **{f"zstack-{n}": f"a field-filling dot plate at {n} stage Z positions over ±depth" for n in ZSTACK_PLANES},
    "stage-sequences": "the paper's X, Y, Z axis sequences (Test 2's counts) and the grid pair, scaled",
    "stepped-target": "a stepped 3D target (five heights over ±0.9 depth) in one pose",
    "two-level": "a two-level plate (second level at a quarter pitch's parallax, at most 0.6 depth, behind) "
                 "in one pose",
    "two-level-2z": "the two-level plate at 2 stage Z positions (±depth/2)",
    "two-level-3z": "the two-level plate at 3 stage Z positions (-depth/2, 0, +depth/2)",
    "charuco-stack": "a ChArUco board's inner corners (a known target) at 5 stage Z positions over ±depth",
}
#: Test 1 of the paper on the CMO microscope: X and Y spans over the room the 7 × 7 plate leaves in the
#: 6.144 mm field (4.1 and 2.9 of 4.344 mm), and the Z span over the half depth of field (3.1 / 1.13 mm)
PAPER_SPAN = (4.1 / 4.344, 2.9 / 4.344, 3.1 / 1.13)
PAPER_COUNTS = (21, 15, 16)


# --------------------------------------------------------------------------------------------- designs
def paper_sequences(rig) -> Session:
    """The paper's axis sequences scaled to ``rig`` (module docstring)."""
    fw, fh = rig.field_mm()
    p = rig.moving_plate
    room = np.array([fw - (p.cols - 1) * p.pitch_mm - p.dot_diameter_mm,
                     fh - (p.rows - 1) * p.pitch_mm - p.dot_diameter_mm, rig.depth_mm()])
    if (room[:2] <= 0).any():
        raise SlmlabError(f"the {rig.preset} rig's moving plate is larger than its field; give it a smaller plate")
    span = np.asarray(PAPER_SPAN) * room
    steps = span / (np.asarray(PAPER_COUNTS) - 1)
    return Session(step_mm=tuple(float(v) for v in steps), positions=PAPER_COUNTS, grid=True, name="stage-sequences")


def zstack_design(rig, planes: int):
    """The rig with a field-filling plate as its moving plate, and the Z-stack session of ``planes``
    positions over ``[-d, +d]``."""
    fw, fh = rig.field_mm()
    tol = rig.moving_plate.fabrication_tolerance_um
    plate = sized_plate(0.95 * fw, 0.95 * fh, dots=25, tolerance_um=tol, rotation_deg=0.4, tilt_deg=0.05)
    step = 2 * rig.depth_mm() / (planes - 1)
    return replace(rig, moving_plate=plate), Session(step_mm=(0.0, 0.0, step), positions=(0, 0, planes), grid=False,
                                                      name=f"zstack-{planes}")


def two_level_target(width_mm: float, height_mm: float, pitch_mm: float, offset_mm: float) -> pd.DataFrame:
    """A two-level plate covering ``width_mm × height_mm``: level 0 at ``z = 0`` on a square lattice of pitch
    ``pitch_mm``, level 1 at ``z = offset_mm`` offset by half a pitch in ``x`` and ``y``. Numbered in half
    pitches (``xu, yu``: both even on level 0, both odd on level 1; ``level = xu mod 2``) with ``[1, 1]`` at
    ``+x, +y``: ``row, col, x_mm, y_mm, z_mm, level``."""
    a, b = int(width_mm / pitch_mm), int(height_mm / pitch_mm)
    xu, yu = np.meshgrid(np.arange(-a, a + 1), np.arange(-b, b + 1))
    xu, yu = xu.ravel(), yu.ravel()
    keep = (xu - yu) % 2 == 0
    xu, yu = xu[keep], yu[keep]
    level = xu % 2
    return pd.DataFrame({"row": yu.max() - yu + 1, "col": xu.max() - xu + 1, "x_mm": xu * pitch_mm / 2,
                         "y_mm": yu * pitch_mm / 2, "z_mm": np.where(level == 1, offset_mm, 0.0), "level": level}
                        ).sort_values(["row", "col"], ignore_index=True)


def charuco_corners(squares: tuple[int, int], square_mm: float) -> pd.DataFrame:
    """Inner corners of a ChArUco board of ``squares = (x, y)`` squares of ``square_mm``, numbered as OpenCV
    numbers them (corner ``k`` is ``[k // (x − 1) + 1, k % (x − 1) + 1]``) at the board's own coordinates
    (:mod:`slmlab.boards`): ``row, col, x_mm, y_mm, z_mm``."""
    sx, sy = squares
    k = np.arange((sx - 1) * (sy - 1))
    row, col = k // (sx - 1) + 1, k % (sx - 1) + 1
    return pd.DataFrame({"row": row, "col": col, "x_mm": (col - sx / 2) * square_mm,
                         "y_mm": (sy / 2 - row) * square_mm, "z_mm": 0.0})


def known_target_set(rig, target: pd.DataFrame, stage_mm, *, seed: int = 0, plate: dict | None = None,
                     dot_diameter_mm: float | None = None) -> CalibrationSet:
    """:func:`slmlab.virtual.simulate.target_set` on ``rig`` with the target's origin (and stage zero) on
    :meth:`field_centre_mm`; ``dot_diameter_mm`` defaults to half the target's pitch."""
    xs = np.unique(target["x_mm"].to_numpy(float))
    pitch = float(np.diff(xs).min()) if len(xs) > 1 else 1.0
    dot = pitch / 2 if dot_diameter_mm is None else dot_diameter_mm
    return target_set(rig, target, stage_mm, seed=seed, dot_diameter_mm=dot, plate=plate,
                      origin_mm=rig.field_centre_mm())


#: a two-level plate's second level is as deep as puts its dots this share of a pitch off the first level's cell
#: centres (its parallax at the rig's half angle, in air), at most 0.6 of the rig's depth: a plate made for the
#: rig, as two-level plates are made for the viewing angles they serve. Deeper, the square marker (half a pitch
#: from the origin dot) meets the other level's dot that parallax brings beside it: on the stereo-DIC rig at
#: 0.3 of a pitch they touch at every level and the plate cannot be numbered; at 0.6 of the depth (0.4 of a
#: pitch there) the dot covers the square
TWO_LEVEL_PARALLAX = 0.25


def two_level_offset_mm(rig, pitch_mm: float) -> float:
    """The second level's depth [mm] behind the first on a two-level plate of ``pitch_mm`` for ``rig``
    (:data:`TWO_LEVEL_PARALLAX`)."""
    depth = 0.6 * rig.depth_mm()
    half_angle = getattr(rig, "half_angle_deg", None)
    if half_angle is None:
        return depth
    return min(depth, TWO_LEVEL_PARALLAX * pitch_mm / np.tan(np.radians(half_angle)))


def _z(values) -> np.ndarray:
    return np.column_stack([np.zeros(len(values)), np.zeros(len(values)), values])


def simulate_design(rig, design: str, seed: int = 0) -> CalibrationSet:
    """The calibration set of a named design (:data:`DESIGNS`) on ``rig`` (``meta.simulator.design`` names
    it)."""
    if design not in DESIGNS:
        raise SlmlabError(f"unknown design {design!r}; choose one of {', '.join(DESIGNS)}")
    fw, fh = rig.field_mm()
    d = rig.depth_mm()
    tol = rig.moving_plate.fabrication_tolerance_um
    if design.startswith("zstack-"):
        cal = simulate_set(*zstack_design(rig, int(design.split("-")[1])), seed=seed)
    elif design == "stage-sequences":
        cal = simulate_set(rig, paper_sequences(rig), seed=seed)
    elif design == "stepped-target":
        plate = sized_plate(0.95 * fw, 0.95 * fh, dots=31, tolerance_um=tol)
        target = stepped_target(plate.rows, plate.cols, plate.pitch_mm, tuple(np.linspace(-0.9, 0.9, 5) * d))
        cal = known_target_set(rig, target, [[0.0, 0.0, 0.0]], seed=seed)
    elif design.startswith("two-level"):
        pitch = sized_plate(0.95 * fw, 0.95 * fh, dots=15).pitch_mm
        offset = float(f"{-two_level_offset_mm(rig, pitch):.2g}")
        target = two_level_target(0.95 * fw, 0.95 * fh, pitch, offset)
        z = {"two-level": [0.0], "two-level-2z": [-d / 2, d / 2], "two-level-3z": [-d / 2, 0.0, d / 2]}[design]
        plate = {"pitch_mm": pitch, "dot_diameter_mm": pitch / 4, "dots": "bright", "levels": 2,
                 "level_offset_mm": offset}
        cal = known_target_set(rig, target, _z(z), seed=seed, plate=plate, dot_diameter_mm=pitch / 4)
    else:  # charuco-stack
        square = sized_plate(0.9 * fw, 0.9 * fh, dots=9).pitch_mm
        squares = (int(0.9 * fw / square), int(0.9 * fh / square))
        plate = {"pattern": "charuco", "pitch_mm": square,
                 "board": {"squares": list(squares), "marker_mm": 0.7 * square, "dictionary": "DICT_6X6_250",
                           "legacy": False}}
        cal = known_target_set(rig, charuco_corners(squares, square), _z(np.linspace(-d, d, 5)), seed=seed,
                               plate=plate, dot_diameter_mm=square)
    cal.meta["simulator"]["design"] = design
    cal.meta["source"] += f" (design {design})"
    return cal


def design_frame(rig, design: str) -> np.ndarray:
    """3 × 3 matrix taking stage-frame displacements [mm] to the frame a model calibrated on ``design``
    reconstructs in: the plate's frame (its x, y axes and the stage's Z direction) for a dot-plate Z stack
    (:func:`slmlab.virtual.sessions.zstack_frame`), the stage frame for stage sequences and known targets."""
    if design.startswith("zstack-"):
        plated, _ = zstack_design(rig, 3)
        return zstack_frame(plated, plated.moving_plate)
    return np.eye(3)


def validation_set(rig, cal: CalibrationSet, n_points: int = 1500, seed: int = 100) -> CalibrationSet:
    """A held-out set of ``n_points`` random points inside the volume ``cal`` calibrated: the convex hull of its
    dots seen in both views (rig frame), shrunk by 5 % towards its centroid, seen whole in both views, imaged
    as one pose of a known target (sequence ``K``) with the rig's noise. The hull, not the bounding box: a
    calibration on the paper's cross of stage sequences is used between its arms, not in the box's empty
    corners, where every model extrapolates."""
    seen = cal.points[IMAGE_COLUMNS].notna().all(axis=1).to_numpy() & (cal.points["sequence"] != "grid").to_numpy()
    world = cal.truth.loc[seen, ["X_mm", "Y_mm", "Z_mm"]].to_numpy(float)
    p = rig.stage_to_microscope(world, np.asarray(cal.meta["simulator"]["stage_origin_mm"]))
    centre = p.mean(axis=0)
    try:
        shrunk = centre + 0.95 * (p - centre)
        hull = Delaunay(shrunk[ConvexHull(shrunk).vertices])   # the hull's corners span it: a triangulation of
        # thousands of dots took a quarter of a second per set
    except QhullError:
        raise SlmlabError("the calibrated dots span no volume (one plane): nothing to validate inside") from None
    lo, hi = hull.points.min(axis=0), hull.points.max(axis=0)
    rng = np.random.default_rng([seed, 17])
    out = np.empty((0, 3))
    for _ in range(200):
        q = rng.uniform(lo, hi, size=(4 * n_points, 3))
        q = q[(hull.find_simplex(q) >= 0) & rig.visible(rig.project(q), 0.0).all(axis=1)]
        out = np.vstack([out, q])[:n_points]
        if len(out) == n_points:
            break
    local = rig.microscope_to_stage(out, rig.field_centre_mm())
    target = pd.DataFrame({"row": np.arange(1, len(out) + 1), "col": 1, "x_mm": local[:, 0], "y_mm": local[:, 1],
                           "z_mm": local[:, 2]})
    return known_target_set(rig, target, [[0.0, 0.0, 0.0]], seed=seed, dot_diameter_mm=0.0)
