"""Where a calibration set's dots are in the world: the rows a model calibrates on, the plate's frame, the
stage axes, and the check that every world axis is determined.

Three kinds of set (README, "Bring your own measured dot centres"):

``"moves"``
    stage moves of a plate whose place on the stage is unknown (the paper's X, Y, Z sequences, §4–§6): the
    world is the commanded stage position, up to one unknown offset per dot and sequence;
``"zstack"``
    a Z sequence alone of a plate with rows, cols and pitch: the world is the stage plus the plate's
    lattice (:func:`plate_xy`);
``"target"``
    a known-target set (``x_mm, y_mm, z_mm``): the world is the stage plus the dot's place on its target.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ..checks import is_stage_sequence
from ..errors import SlmlabError
from ..io import IMAGE_COLUMNS, STAGE_COLUMNS, CalibrationSet
from ..linefit import point_keys

__all__ = ["STAGE", "plate_xy", "world_positions", "levels", "distinct_levels", "check_axes", "dot_labels"]

STAGE = STAGE_COLUMNS


def plate_xy(row, col, plate: dict) -> np.ndarray:
    """Plate coordinates ``(n, 2)`` [mm] of dots ``[row, col]`` of a plate ``{rows, cols, pitch_mm}``: the
    convention of :meth:`slmlab.virtual.microscope.Plate.nominal_points` (``[1, 1]`` at ``+x, +y``, centred)."""
    p = float(plate["pitch_mm"])
    return np.column_stack([((plate["cols"] + 1) / 2 - np.asarray(col, float)) * p,
                            ((plate["rows"] + 1) / 2 - np.asarray(row, float)) * p])


def world_positions(cal: CalibrationSet, mode: str = "auto"):
    """The rows a model calibrates on and where their dots are in the world.

    Returns ``(rows, world (n, 3) [mm], mode)``:

    ``"target"``
        a known-target set (``x_mm, y_mm, z_mm``): world = commanded stage position + the dot's place on its
        target (a stepped target or a two-level plate in one pose needs no stage motion; with stage motion the
        two add). Rows whose target position is not known are left out.
    ``"zstack"``
        only a Z sequence, of a plate with rows, cols and pitch: world = stage + the plate's lattice
        (:func:`plate_xy`).
    ``"moves"``
        stage moves of a plate whose place on the stage is unknown: world = the commanded stage position, up
        to one unknown offset per dot and sequence.

    Rows need all four image coordinates; the static ``grid`` pair is not used (it is another plate).
    """
    points = cal.points
    sequence = points["sequence"].to_numpy()
    seen = ~np.isnan(points[IMAGE_COLUMNS].to_numpy(float)).any(axis=1)
    if mode not in ("auto", "moves", "zstack", "target"):
        raise SlmlabError(f"unknown mode {mode!r}; use 'auto', 'moves', 'zstack' or 'target'")
    if cal.known_target and mode in ("auto", "target"):
        pts = points[(sequence != "grid") & seen]
        world = cal.world(pts)
        keep = np.isfinite(world).all(axis=1)
        pts, world = pts[keep], world[keep]
        if len(pts) == 0:
            raise SlmlabError("no dot has both image coordinates and a known position on its target (x_mm, y_mm, "
                              "z_mm); for a two-level plate give plates.moving.level_offset_mm", cal.path)
        check_axes(world, "target", cal.path)
        return pts, world, "target"
    if mode == "target":
        raise SlmlabError("mode 'target' needs a known-target set (columns x_mm, y_mm, z_mm)", cal.path)
    rows, lateral = _moving_rows(sequence, seen, points["position"].to_numpy(), points[STAGE].to_numpy(float))
    pts = points[rows]
    if len(pts) == 0:
        raise SlmlabError("needs a sequence with stage motion (X, Y, Z or any label but grid and T) seen at two "
                          "positions in both views, or a known target (x_mm, y_mm, z_mm)", cal.path)
    if mode == "auto":
        mode = "moves" if lateral else "zstack"
    if mode == "moves" and not lateral:
        raise SlmlabError("mode 'moves' needs stage moves in X or Y; a set with a Z sequence only calibrates "
                          "in mode 'zstack' (X, Y from the plate's pitch)", cal.path)
    world = pts[STAGE].to_numpy(float)
    if mode == "zstack":
        plate = cal.plate("Z")
        if plate.get("rows") is None:
            raise SlmlabError("a Z stack of a plate without rows and cols needs x_mm, y_mm, z_mm columns (extract the "
                              "set with 'python -m slmlab extract')", cal.path)
        world = world + np.column_stack([plate_xy(pts["row"], pts["col"], plate), np.zeros(len(pts))])
    check_axes(world, mode, cal.path)
    return pts, world, mode


def _moving_rows(sequence, seen, position, stage) -> tuple[np.ndarray, bool]:
    """Which rows calibrate a set of stage moves: seen in both views (``seen``), of a stage sequence imaged at
    two positions or more; and whether any of those sequences moves the stage in X or Y (``lateral``)."""
    codes, names = pd.factorize(sequence)
    rows = seen.copy()
    lateral = False
    for code, name in enumerate(names):
        this = rows & (codes == code)
        if not is_stage_sequence(name) or len(np.unique(position[this])) < 2:
            rows &= ~this
            continue
        lateral |= bool((np.ptp(stage[this][:, :2], axis=0) > 0).any())
    return rows, lateral


def levels(world: np.ndarray, axis: int = 2) -> np.ndarray:
    """Coordinate ``axis`` of world positions ``(n, 3)`` [mm] to 1 nm, one per row: each dot's depth by default,
    equal where two dots lie at the same depth."""
    return np.round(np.asarray(world)[:, axis], 6)


def distinct_levels(world: np.ndarray, axis: int = 2) -> int:
    """How many distinct values (:func:`levels`) coordinate ``axis`` of world positions ``(n, 3)`` [mm] takes: a
    stack's depths by default, a lattice's columns or rows with ``axis`` 0 or 1."""
    return len(np.unique(levels(world, axis)))


def check_axes(world: np.ndarray, mode: str, path=None) -> None:
    """Each world axis must be determined by the calibration rows (``world``: where their dots are, as
    :func:`world_positions` gives): stage motion along it, or a plate lattice or known target
    that spreads the dots along it. Raise naming the axes that are not, and the remedy."""
    span = np.nanmax(world, axis=0) - np.nanmin(world, axis=0) if len(world) else np.zeros(3)
    missing = [c for c, v in zip("XYZ", span) if not v > 0]
    if not missing:
        return
    how = {"moves": "no sequence moves the stage along it",
           "zstack": "the Z stack's plate and stage do not spread the dots along it",
           "target": "neither the stage nor the target's own x_mm, y_mm, z_mm spread the dots along it"}[mode]
    remedy = ("add a sequence along it (or a Z stack of a plate with rows and cols for X, Y)" if mode == "moves"
              else "add stage positions along it or use a target that spans it")
    raise SlmlabError(f"{', '.join(missing)} cannot be determined: {how}; {remedy}", path)


def dot_labels(pts) -> np.ndarray:
    """One label per row: its dot (``row, col``) on its sequence's plate."""
    return point_keys(pts["row"], pts["col"]).astype(str) + ":" + pts["sequence"].astype(str).to_numpy()
