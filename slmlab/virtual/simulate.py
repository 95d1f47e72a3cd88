"""Simulated calibration sets: a session's stage positions, the plates' dots seen in both views, with the
stage's errors and the dot finder's noise, and ``truth.csv`` (paper §6; the physics of the simulator).

Everything here asks the microscope only for what any stereo rig can say: where a point lands in each view
(``project``), whether a dot is wholly inside an image (``visible``), the dot finder's noise at a point
(``centroid_sigma_px``), the point seen at the middle of both images in focus (``field_centre_mm``), and
its stage (:class:`slmlab.virtual.microscope.Stage`). The same seed gives byte-identical files.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ..errors import SlmlabError
from ..io import IMAGE_COLUMNS, POINT_COLUMNS, SET_FORMAT, TARGET_COLUMNS, TRUTH_COLUMNS, CalibrationSet
from ..version import __version__
from .microscope import Microscope
from .presets import preset
from .rigs import rig_from_dict
from .sessions import Session, paper_test, tilt_matrix

__all__ = ["stage_origin", "fabricated_plates", "observe", "simulate_set", "noise_floor", "stepped_target",
           "target_set"]


def stage_origin(microscope: Microscope, session: Session) -> np.ndarray:
    """Microscope-frame position of stage zero [mm], chosen so that the session's centre stage position
    (:meth:`Session.centre_mm`) puts the plate centre at the middle of the image, in focus."""
    return microscope.field_centre_mm() - microscope.stage.axes @ session.centre_mm()


def fabricated_plates(microscope: Microscope, rng: np.random.Generator) -> dict:
    """The grid and moving plates as fabricated: nominal dot positions plus a uniform error within the
    tolerance, turned to their mounting. ``{name: (plate, row, col, offsets (n, 3) [mm])}``."""
    plates = {}
    for name, plate in (("grid", microscope.grid_plate), ("moving", microscope.moving_plate)):
        i, j, pts = plate.nominal_points()
        tol = 1e-3 * plate.fabrication_tolerance_um
        pts = pts + np.column_stack([rng.uniform(-tol, tol, (len(pts), 2)), np.zeros(len(pts))])
        plates[name] = (plate, i, j, pts @ plate.orientation().T)
    return plates


def observe(microscope: Microscope, points_mm: np.ndarray, dot_diameter_mm: float,
            rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """What the dot finder returns for dots at microscope-frame points ``(n, 3)`` [mm]: the true centres
    ``(n, 4)`` [px] and the noisy ones (NaN in a view where the dot is not wholly inside the image)."""
    w_true = microscope.project(points_mm)
    sigma = microscope.centroid_sigma_px(points_mm)
    w = w_true + rng.normal(size=w_true.shape) * sigma[:, None]
    vis = microscope.visible(w_true, dot_diameter_mm)
    w[:, 0:2][~vis[:, 0]] = np.nan
    w[:, 2:4][~vis[:, 1]] = np.nan
    return w_true, w


def simulate_set(microscope: Microscope | None = None, session: Session | None = None, seed: int = 0) -> CalibrationSet:
    """Simulate a calibration set: the session's stage positions, the plates' dots seen in both views.

    Parameters
    ----------
    microscope
        the virtual microscope (default: the ``paper`` preset).
    session
        what to image (default: Test 1 of Table 3 with the grid pair).
    seed
        seed of every random draw (plate fabrication, stage positioning, centroid noise): the same seed gives
        byte-identical files.

    Returns
    -------
    CalibrationSet
        ``points`` with noisy centres (NaN where a dot is not wholly inside an image), ``truth`` with the
        noise-free centres and true stage-frame coordinates, and ``meta`` (with the simulator's parameters
        under ``"simulator"``).
    """
    microscope = microscope if microscope is not None else preset("paper")
    session = session if session is not None else paper_test(1)
    plate_rng, stage_rng, noise_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(3))
    origin = stage_origin(microscope, session)
    plates = fabricated_plates(microscope, plate_rng)
    if not session.stage_positions():
        raise SlmlabError("the session images nothing: give it positions along X, Y or Z, the grid pair, "
                          "tilted poses or volume positions")
    frames, truths = [], []
    for seq, commanded in session.stage_positions().items():
        plate, i, j, offsets = plates["grid" if seq == "grid" else "moving"]
        actual = microscope.stage.actual(commanded, stage_rng)
        centre = microscope.stage_to_microscope(actual, origin)  # plate centre per position
        if seq == "T":  # the plate held at a tilt about its centre
            per_pose = np.stack([offsets @ tilt_matrix(*pose).T for pose in session.tilt_poses_deg])
            p = (centre[:, None, :] + per_pose).reshape(-1, 3)
        else:
            p = (centre[:, None, :] + offsets[None, :, :]).reshape(-1, 3)
        w_true, w = observe(microscope, p, plate.dot_diameter_mm, noise_rng)
        world = microscope.microscope_to_stage(p, origin)
        point_rows, truth_rows = _sequence_tables(seq, commanded, i, j, w, w_true, world)
        frames.append(point_rows)
        truths.append(truth_rows)
    points = pd.concat(frames, ignore_index=True)[POINT_COLUMNS]
    truth = pd.concat(truths, ignore_index=True)[TRUTH_COLUMNS]
    return CalibrationSet(points=points, meta=_set_meta(microscope, session, seed, origin), truth=truth)


def _sequence_tables(seq: str, commanded, i, j, w, w_true, world) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The ``points.csv`` and ``truth.csv`` rows of one sequence (positions × dots, position-major)."""
    n_pos, n_dot = len(commanded), len(i)
    key = {"sequence": np.full(n_pos * n_dot, seq), "position": np.repeat(np.arange(1, n_pos + 1), n_dot)}
    stage_cols = np.repeat(commanded, n_dot, axis=0)
    points = pd.DataFrame({
        **key,
        "stage_x_mm": stage_cols[:, 0], "stage_y_mm": stage_cols[:, 1], "stage_z_mm": stage_cols[:, 2],
        "row": np.tile(i, n_pos), "col": np.tile(j, n_pos),
        **{c: w[:, k] for k, c in enumerate(IMAGE_COLUMNS)},
    })
    truth = pd.DataFrame({
        **key, "row": np.tile(i, n_pos), "col": np.tile(j, n_pos),
        **{c: w_true[:, k] for k, c in enumerate(IMAGE_COLUMNS)},
        "X_mm": world[:, 0], "Y_mm": world[:, 1], "Z_mm": world[:, 2],
    })
    return points, truth


def _set_meta(microscope: Microscope, session: Session, seed: int, origin: np.ndarray) -> dict:
    """``meta.json`` of a simulated set, with the simulator's parameters under ``"simulator"``."""
    return {
        "format": SET_FORMAT,
        "image_size_px": list(microscope.image_size_px),
        "plates": {"grid": microscope.grid_plate.as_meta(), "moving": microscope.moving_plate.as_meta()},
        "source": f"slmlab {__version__} virtual {getattr(microscope, 'kind', 'CMO microscope')}, preset {microscope.preset}, "
                  f"session {session.name}, seed {seed}",
        "simulator": {
            "microscope": microscope.as_dict(),
            "session": {"name": session.name, "step_mm": [float(v) for v in session.steps_mm],
                        "positions": list(session.positions), "grid": session.grid,
                        "tilt_poses_deg": [list(p) for p in session.tilt_poses_deg]},
            "seed": int(seed),
            "stage_origin_mm": [float(v) for v in origin],
        },
    }


def noise_floor(cal: CalibrationSet) -> np.ndarray:
    """The simulator's own true-model triangulation of a simulated set's noisy centres, in the stage frame
    ``(n, 3)`` [mm] (NaN where a dot is missing): what no calibrated model can beat."""
    sim = cal.meta["simulator"]
    m = rig_from_dict(sim["microscope"])
    w = cal.points[IMAGE_COLUMNS].to_numpy(float)
    out = np.full((len(w), 3), np.nan)
    ok = np.isfinite(w).all(axis=1)
    out[ok] = m.microscope_to_stage(m.triangulate(w[ok]), np.asarray(sim["stage_origin_mm"]))
    return out


def stepped_target(rows: int = 31, cols: int = 31, pitch_mm: float = 0.2, steps_mm=(-1.0, -0.5, 0.0, 0.5, 1.0),
                   ) -> "pd.DataFrame":
    """A stepped 3D dot target: a ``rows × cols`` lattice of pitch ``pitch_mm`` whose dots stand on
    ``len(steps_mm)`` heights ``steps_mm`` [mm] in a knight's-move pattern (step ``(row + 2·col) mod n``),
    so that height does not follow ``x`` or ``y`` (a staircase across the field would confound them, and
    one pose could not tell depth from position). Returns ``row, col, x_mm, y_mm, z_mm`` in the target's
    frame (the plate convention of README, "The format", for ``x, y``)."""
    i, j = np.meshgrid(np.arange(1, rows + 1), np.arange(1, cols + 1), indexing="ij")
    i, j = i.ravel(), j.ravel()
    band = (i + 2 * j) % len(steps_mm)
    return pd.DataFrame({"row": i, "col": j, "x_mm": ((cols + 1) / 2 - j) * pitch_mm,
                         "y_mm": ((rows + 1) / 2 - i) * pitch_mm, "z_mm": np.asarray(steps_mm, float)[band]})


def target_set(microscope: Microscope, target: "pd.DataFrame", stage_mm, *, seed: int = 0, sequence: str = "K",
               dot_diameter_mm: float = 0.1, plate: dict | None = None, origin_mm=None) -> CalibrationSet:
    """A known-target calibration set (README, "The format"): the dots of ``target`` (``row, col, x_mm, y_mm,
    z_mm`` in the target's frame, its axes along the stage's; other columns, such as a two-level plate's
    ``level``, pass through to ``points.csv``) imaged at the commanded stage positions ``stage_mm`` ``(k, 3)``
    [mm] (one row for a single pose), with the stage's errors and the dot finder's noise. The target's origin
    is at stage zero, placed at ``origin_mm`` (default: the field's centre, in focus, as a session centred
    there places it); ``dot_diameter_mm`` sets the visibility margin, ``plate`` the ``meta.json`` entry
    (default: the pitch and the dot diameter). ``truth`` holds the true centres and stage-frame positions."""
    stage_mm = np.atleast_2d(np.asarray(stage_mm, float))
    stage_rng, noise_rng = (np.random.default_rng(s) for s in np.random.SeedSequence([seed, 5]).spawn(2))
    origin = (stage_origin(microscope, Session(positions=(0, 0, 0), grid=False)) if origin_mm is None
              else np.asarray(origin_mm, float))
    local = target[TARGET_COLUMNS].to_numpy(float)
    extra = [c for c in target.columns if c not in ("row", "col", *TARGET_COLUMNS)]
    frames, truths = [], []
    actual = microscope.stage.actual(stage_mm, stage_rng)
    for k, (cmd, act) in enumerate(zip(stage_mm, actual), 1):
        world = act + local
        p = microscope.stage_to_microscope(world, origin)
        w_true, w = observe(microscope, p, dot_diameter_mm, noise_rng)
        key = {"sequence": sequence, "position": k, "row": target["row"].to_numpy(), "col": target["col"].to_numpy()}
        frames.append(pd.DataFrame({**key, "stage_x_mm": cmd[0], "stage_y_mm": cmd[1], "stage_z_mm": cmd[2],
                                    **{c: w[:, n] for n, c in enumerate(IMAGE_COLUMNS)},
                                    **{c: local[:, n] for n, c in enumerate(TARGET_COLUMNS)},
                                    **{c: target[c].to_numpy() for c in extra}}))
        truths.append(pd.DataFrame({**key, **{c: w_true[:, n] for n, c in enumerate(IMAGE_COLUMNS)},
                                    "X_mm": world[:, 0], "Y_mm": world[:, 1], "Z_mm": world[:, 2]}))
    points = pd.concat(frames, ignore_index=True)[[*POINT_COLUMNS, *TARGET_COLUMNS, *extra]]
    if plate is None:
        xs = np.unique(local[:, 0])
        plate = {"pitch_mm": float(abs(np.diff(xs)).min()) if len(xs) > 1 else 1.0, "dot_diameter_mm": dot_diameter_mm}
    meta = {"format": SET_FORMAT, "image_size_px": list(microscope.image_size_px), "plates": {"moving": plate},
            "source": f"slmlab {__version__} virtual {getattr(microscope, 'kind', 'microscope')}, preset "
                      f"{microscope.preset}: a known target, seed {seed}",
            "simulator": {"microscope": microscope.as_dict(), "seed": int(seed),
                          "stage_origin_mm": [float(v) for v in origin]}}
    return CalibrationSet(points=points, meta=meta, truth=pd.concat(truths, ignore_index=True)[TRUTH_COLUMNS])


