"""How well a model reconstructs a known target's shape: ``evaluate`` on a set without stage sequences.

The paper's evaluation (§5.2–§5.3, :mod:`slmlab.paper.evaluation`) compares reconstructed displacements with the
stage's commanded moves, so it needs X, Y or Z sequences. A *known-target* set (a stepped target, a two-level
plate, a ChArUco board, a plate numbered by its markers) carries instead each dot's place on the target,
``x_mm, y_mm, z_mm``. Its check here: per pose (a sequence's position), the target's known points are moved
rigidly (a rotation and a translation, no scale: the Kabsch solution, SciPy's ``Rotation.align_vectors``) onto
the model's reconstruction of them, and the residual is what is left, in the target's own axes. The six degrees of
freedom of the pose are taken out; the model's scale, shear and distortion are not.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from .errors import SlmlabError
from .io import IMAGE_COLUMNS, TARGET_COLUMNS, CalibrationSet

__all__ = ["MIN_TARGET_POINTS", "target_residuals", "TargetCheck", "check_target"]

#: the fewest points of a pose the check aligns (fewer leave a rigid fit little to check)
MIN_TARGET_POINTS = 6


def target_residuals(reconstruct, cal: CalibrationSet) -> pd.DataFrame:
    """Residuals of the known target's points after each pose's rigid alignment (module docstring).

    ``reconstruct``: ``(n, 4) → (n, 3)`` [px → mm]. Returns ``sequence, position, row, col`` and ``E_x, E_y, E_z``
    [mm] (reconstruction less the aligned target point, along the target's ``x, y, z``), for the rows seen in both
    views with a target place, in poses of at least :data:`MIN_TARGET_POINTS` such rows that are not all on one
    line. A set without target places, or without such a pose, is a :class:`slmlab.SlmlabError`."""
    pts = cal.points
    if not set(TARGET_COLUMNS) <= set(pts.columns):
        raise SlmlabError("no X, Y or Z sequence with 2 or more positions seen in both views, and no target places "
                          "(x_mm, y_mm, z_mm): nothing to evaluate; evaluate on a set with stage sequences or a "
                          "known target", cal.path)
    use = pts[np.isfinite(pts[IMAGE_COLUMNS + TARGET_COLUMNS].to_numpy(float)).all(axis=1)]
    frames = []
    for (seq, pos), pose in use.groupby(["sequence", "position"], sort=True):
        q = pose[TARGET_COLUMNS].to_numpy(float)
        if len(pose) < MIN_TARGET_POINTS or np.linalg.matrix_rank(q - q.mean(axis=0), tol=1e-9) < 2:
            continue
        p = np.asarray(reconstruct(pose[IMAGE_COLUMNS].to_numpy(float)), float)
        ok = np.isfinite(p).all(axis=1)
        if ok.sum() < MIN_TARGET_POINTS:
            continue
        rot, _ = Rotation.align_vectors(p[ok] - p[ok].mean(axis=0), q[ok] - q[ok].mean(axis=0))
        e = rot.inv().apply(p[ok] - p[ok].mean(axis=0)) - (q[ok] - q[ok].mean(axis=0))
        frames.append(pd.DataFrame({"sequence": seq, "position": pose["position"].to_numpy()[ok],
                                    "row": pose["row"].to_numpy()[ok], "col": pose["col"].to_numpy()[ok],
                                    "E_x": e[:, 0], "E_y": e[:, 1], "E_z": e[:, 2]}))
    if not frames:
        raise SlmlabError(f"no pose of the known target has {MIN_TARGET_POINTS} or more points seen in both views "
                          "off one line: nothing to evaluate", cal.path)
    return pd.concat(frames, ignore_index=True)


@dataclass
class TargetCheck:
    """A model's residuals on a known target (:func:`target_residuals`) and their summary per axis."""

    model: str
    residuals: pd.DataFrame

    def summary(self) -> pd.DataFrame:
        """Per target axis: points, RMS and maximum absolute residual [mm]."""
        r = self.residuals
        return pd.DataFrame([{"axis": a, "points": len(r), "rms_mm": float(np.sqrt(np.mean(r[f"E_{a}"] ** 2))),
                              "max_abs_mm": float(np.max(np.abs(r[f"E_{a}"])))} for a in "xyz"])

    def as_json(self) -> dict:
        poses = self.residuals[["sequence", "position"]].drop_duplicates()
        return {"model": self.model, "known_target": {"poses": len(poses), "points": len(self.residuals),
                                                      "axes": self.summary().to_dict(orient="records")}}

    def text(self) -> str:
        poses = len(self.residuals[["sequence", "position"]].drop_duplicates())
        lines = [f"model {self.model} on the known target ({poses} pose(s), each aligned rigidly onto the model's "
                 "reconstruction; no stage sequence for RA1-RA5): residual per target axis [mm]",
                 self.summary().to_string(index=False, float_format=lambda v: f"{v:.4g}")]
        return "\n".join(lines)


def check_target(model, cal: CalibrationSet) -> TargetCheck:
    """:class:`TargetCheck` of ``model`` (anything with ``reconstruct`` and ``name``) on the known target of ``cal``."""
    return TargetCheck(getattr(model, "name", "model"), target_residuals(model.reconstruct, cal))
