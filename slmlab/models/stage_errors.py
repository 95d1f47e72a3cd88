"""Each stage position's own error, measured by the pinhole pair where it describes the rig.

A stage puts each commanded position a little elsewhere: positioning noise, lead and straightness errors,
the same for every dot of that position. A flexible map from image to world learns them as optics (a
polynomial of degree 4 follows the offsets of four depths), and no held-out dot or plane tells them apart
(:mod:`slmlab.models.auto`, step 2). A physical model can: a pinhole pair sees a plate that moved rigidly
off its command as a rigid offset of every dot of that position, not as a change of the cameras. So where the
pinhole pair describes the rig (its reprojection error per point within :data:`FITS` of the Soloff polynomials'
scatter: a Greenough microscope or a stereo-DIC pair; not refraction through a window), each position's offset
is the mean of its dots' pinhole residuals (world position the pinhole reconstructs, minus the commanded one),
estimated on the set, refitted :data:`ITERATIONS` times, and the commanded world positions are corrected by it
before any candidate is fitted. The frame stays the commanded one: the part of the offsets that an affine map
of the commanded positions describes is the frame (the stage's axes, and how the target sits on them) and
stays. A target with depth of its own (a two-level plate) would say more, but on the PIV Challenge's case E
the part it would add is a tilt of about 3 mrad between the plate and the traverse (offsets in a straight line
from +10 to −10 µm over its seven planes), which the commanded frame, the user's, keeps; correcting it took
the model away from the commanded positions of the planes it was checked on. So with two positions nothing is
corrected, and with three only their curvature. Offsets not clearly above their own noise
(:data:`SIGNIFICANCE` times their standard error) are left alone.

On the Greenough rig of notebook 11 (0.3 µm per move against a 0.07 µm floor) this puts the default within
1.03× of the floor in the commanded frame in X and Y on every Z stack of three planes or more (before: up to
1.55×), and a two-level plate at three positions below it (0.65× and 0.84× in X and Y, the direct model;
before: 1.52×); two positions leave nothing outside the frame to correct, but the check that the pinhole pair
describes the rig is reported (``pinhole_fits``): the default lets it judge how candidates bend between depths.
Where the pinhole pair does not describe the rig (refraction through a window) or on stage moves, nothing
changes.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ..errors import SlmlabError
from ..io import IMAGE_COLUMNS, CalibrationSet
from .base import get_model_class
from .folds import position_keys, thin_dots
from .frames import distinct_levels, world_positions

__all__ = ["FITS", "MISFIT", "ITERATIONS", "SIGNIFICANCE", "ROWS", "CHECK_ROWS", "corrected_for_stage"]

#: the pinhole pair describes the rig where, the offsets taken out, its reprojection error per point is at most
#: this many times the Soloff polynomials' scatter per point on the same corrected rows (tighter than the
#: choice's own test: a pinhole that misfits by a little would pass its misfit for stage error)
FITS = 1.2
#: ... and one this many times above them before any correction is not tried at all (the choice's own test,
#: :data:`slmlab.models.auto.PINHOLE_MISFIT`)
MISFIT = 2.0
#: the offsets are measured this many times (at least 2), the pinhole pair refitted on the corrected positions
#: each time after the first
ITERATIONS = 2
#: offsets are corrected only where their RMS is more than this many times their standard error
SIGNIFICANCE = 3.0
#: the pinhole and Soloff fits that measure the offsets use at most this many rows (every k-th dot) ...
ROWS = 2000
#: ... and those that first check whether the pinhole pair is anywhere near the rig, this many
CHECK_ROWS = 400


def corrected_for_stage(cal: CalibrationSet, mode: str, pinhole_options: dict) -> tuple[CalibrationSet, dict]:
    """``(set, report)``: ``cal`` with its commanded world positions corrected by each stage position's
    offset (module docstring), as a known target, or ``cal`` itself where that does not apply; ``report``:
    ``applied`` (bool), ``why`` (one line), ``pinhole_fits`` where it was tested (the pinhole pair, the offsets
    taken out, within :data:`FITS` of the Soloff polynomials' scatter: it describes the rig's optics) and,
    where measured, ``offsets_um`` per position
    ``{"sequence:position": [x, y, z]}`` and their ``rms_um`` and ``standard_error_um`` per coordinate."""
    pts, world, mode = world_positions(cal, mode)
    keys = position_keys(pts)
    pinhole_options = {**pinhole_options, "spread": False}   # its fits' σ(f) is never read here
    if mode == "moves" or len(np.unique(keys)) < 2:
        return cal, {"applied": False, "why": "no stage positions whose dots' world positions are known"}
    try:
        check = CalibrationSet(pts[thin_dots(pts, CHECK_ROWS)].reset_index(drop=True), cal.meta, path=cal.path)
        if why := _does_not_fit(check, get_model_class("pinhole").fit(check, **pinhole_options), MISFIT,
                                _depth_degree(world)):
            return cal, {"applied": False, "why": why, "pinhole_fits": False}  # far off: a window, say
        sub = CalibrationSet(pts[thin_dots(pts, ROWS)].reset_index(drop=True), cal.meta, path=cal.path)
        total, se = _offsets(sub, mode, get_model_class("pinhole").fit(sub, **pinhole_options))
        for _ in range(ITERATIONS - 1):  # refitted on the corrected positions
            moved = _with_offsets(sub, mode, total)
            pinhole = get_model_class("pinhole").fit(moved, **pinhole_options)
            more, se = _offsets(moved, "target", pinhole)
            total = total + more
        why = _does_not_fit(moved, pinhole, FITS)  # the offsets taken out, close to the polynomials
    except SlmlabError as exc:
        return cal, {"applied": False, "why": f"the positions' offsets could not be measured: {exc.reason}",
                     "pinhole_fits": False}
    if why:
        return cal, {"applied": False, "why": why, "pinhole_fits": False}
    rms = np.sqrt(np.mean(total.to_numpy() ** 2, axis=0))
    report = {"pinhole_fits": True, "offsets_um": {k: [round(1e3 * v, 4) for v in row] for k, row in total.iterrows()},
              "rms_um": [round(1e3 * v, 4) for v in rms], "standard_error_um": [round(1e3 * v, 4) for v in se]}
    if not np.any(rms > SIGNIFICANCE * se):
        return cal, {"applied": False, "why": "no offset clearly above its noise", **report}
    return _with_offsets(cal, mode, total), {
        "applied": True, "why": ("each position's offset from the pinhole pair's residuals, net of an affine map of "
                                 "the commanded positions: RMS "
                                 + ", ".join(f"{c} {1e3 * v:.3g} um" for c, v in zip("XYZ", rms))), **report}


def _depth_degree(world: np.ndarray) -> list[int]:
    """The Soloff degrees of the first, quick check: cubic across the field, quadratic in depth (less with
    fewer depths)."""
    return [3, int(min(2, distinct_levels(world) - 1))]


def _does_not_fit(sub: CalibrationSet, pinhole, limit: float, degree=None) -> str:
    """Why the pinhole pair fitted on ``sub`` does not describe the rig: its reprojection error per point more
    than ``limit`` times the Soloff polynomials' scatter on the same rows (of ``degree``, else their own
    choice); or ``""``."""
    soloff = get_model_class("soloff").fit(sub, **({} if degree is None else {"degree": degree}))
    sigma = np.asarray(soloff.calibration["image_residual_sigma_px"], float)
    soloff_px = float(np.sqrt(np.maximum(sigma[0::2] ** 2 + sigma[1::2] ** 2, 0)).max())
    pinhole_px = float(pinhole.calibration["stereo_rms_px"])
    if pinhole_px <= limit * soloff_px:
        return ""
    return (f"the pinhole pair does not describe the rig closely enough to tell a position's offset from the "
            f"optics (reprojection {pinhole_px:.3g} px per point against the soloff polynomials' {soloff_px:.3g} px)")


def _offsets(sub: CalibrationSet, mode: str, pinhole) -> tuple[pd.DataFrame, np.ndarray]:
    """Each position's mean residual [mm] of the fitted ``pinhole`` pair, net of the frame (an affine map of
    the commanded stage positions), and the offsets' typical standard error (3,) [mm]."""
    pts, world, _ = world_positions(sub, mode)
    r = pinhole.reconstruct(pts[IMAGE_COLUMNS].to_numpy(float)) - world
    keys = position_keys(pts)
    groups = pd.DataFrame(r, columns=list("XYZ")).groupby(keys)
    means, count = groups.mean(), groups.size().to_numpy(float)
    within = np.sqrt(groups.var(ddof=1).mean().to_numpy())
    stage = pts[["stage_x_mm", "stage_y_mm", "stage_z_mm"]].groupby(keys).first().loc[means.index].to_numpy(float)
    design = np.column_stack([stage, np.ones(len(stage))])
    coef, *_ = np.linalg.lstsq(design, means.to_numpy(), rcond=None)
    return means - design @ coef, within / np.sqrt(np.median(count))


def _with_offsets(cal: CalibrationSet, mode: str, offsets: pd.DataFrame) -> CalibrationSet:
    """``cal`` with each position's world position moved by its offset [mm]: as a known target (``x_mm, y_mm,
    z_mm``: the corrected world position less the commanded stage position; rows no model calibrates on, such
    as a static ``grid`` pair, keep what they had), the stage columns unchanged."""
    pts, world, _ = world_positions(cal, mode)
    keys = position_keys(pts)
    known = np.isin(keys, offsets.index)
    moved = world.copy()
    moved[known] += offsets.loc[keys[known]].to_numpy()
    out = cal.points.copy()
    stage = pts[["stage_x_mm", "stage_y_mm", "stage_z_mm"]].to_numpy(float)
    for k, c in enumerate(("x_mm", "y_mm", "z_mm")):
        if c not in out:
            out[c] = np.nan
        out.loc[pts.index, c] = moved[:, k] - stage[:, k]
    return CalibrationSet(out, cal.meta, path=cal.path)
