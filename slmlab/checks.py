"""Checks that a calibration set can say what a model will be asked to say (run by :func:`slmlab.calibrate`).

A stage file can be wrong in ways no column check sees: a position copied from the row above, a sequence
whose stage never moved while its dots did, an ``X`` sequence that moves along Y. A model fitted anyway
returns a map, and it is silently wrong. These checks compare each sequence's commanded moves with how far
its dots moved in the images; anything wrong is a :class:`slmlab.SlmlabError` that names the sequence, the
position and what to check. (Whether each world axis is determined at all is asked by
:func:`slmlab.models.frames.check_axes`.)
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from .errors import SlmlabError
from .io import IMAGE_COLUMNS, STAGE_COLUMNS, CalibrationSet

__all__ = ["image_motion", "check_stage_file", "MOVED_PX", "STILL_PX", "NOT_STAGE_SEQUENCES", "is_stage_sequence"]

#: dots that moved more than this between two positions [px] did move (centroid noise is ≤ 0.1 px)
MOVED_PX = 1.0
#: dots that moved less than this [px] did not
STILL_PX = 0.05
#: the sequences that are not commanded stage moves (``grid``: the large plate's one pair; ``T``: poses held by
#: hand); every other label is (``X``, ``Y``, ``Z`` along the axes, any other a free set of stage positions)
NOT_STAGE_SEQUENCES = ("grid", "T")


def is_stage_sequence(label) -> bool:
    """Whether the sequence ``label`` names commanded stage positions: ``X``, ``Y``, ``Z`` and any other label
    (a free set of stage positions, ``V`` or another) but :data:`NOT_STAGE_SEQUENCES`."""
    return str(label) not in NOT_STAGE_SEQUENCES


def image_motion(seq: pd.DataFrame) -> pd.DataFrame:
    """Per position of one sequence: the commanded displacement from its first position [mm] (3 columns and
    its length) and the median image displacement [px] of the dots seen at both (the RMS over the four
    image coordinates), with the number of such dots."""
    seq = seq[seq[IMAGE_COLUMNS].notna().all(axis=1)]
    positions = np.sort(seq["position"].unique())
    if len(positions) < 2:
        return pd.DataFrame()
    first = seq[seq["position"] == positions[0]].drop_duplicates(["row", "col"])
    rest = seq[seq["position"] != positions[0]]
    stage0 = first[STAGE_COLUMNS].iloc[0].to_numpy(float)
    stage = rest.groupby("position")[STAGE_COLUMNS].first()
    both = rest.merge(first[["row", "col", *IMAGE_COLUMNS]], on=["row", "col"], suffixes=("", "_0"))
    dw = both[IMAGE_COLUMNS].to_numpy(float) - both[[f"{c}_0" for c in IMAGE_COLUMNS]].to_numpy(float)
    moved = pd.Series(np.sqrt(np.mean(dw ** 2, axis=1)), index=both["position"].to_numpy()).groupby(level=0)
    d_stage = stage.to_numpy(float) - stage0
    out = pd.DataFrame({"position": stage.index.astype(int), "dx_mm": d_stage[:, 0], "dy_mm": d_stage[:, 1],
                        "dz_mm": d_stage[:, 2], "commanded_mm": np.linalg.norm(d_stage, axis=1)})
    out["moved_px"] = moved.median().reindex(stage.index).to_numpy()
    out["dots"] = moved.size().reindex(stage.index).fillna(0).astype(int).to_numpy()
    return out


def check_stage_file(cal: CalibrationSet) -> None:
    """Raise where a sequence's commanded moves contradict its images (module docstring):

    * the dots moved (more than :data:`MOVED_PX`) but the commanded position is the first position's;
    * the stage was commanded to move but the dots did not (less than :data:`STILL_PX`), where the set's other
      positions say how many pixels a millimetre makes;
    * a sequence named ``X``, ``Y`` or ``Z`` that moves mostly along another axis."""
    where = "points.csv" if cal.path is None else cal.path / "points.csv"
    seqs = [s for s in cal.sequences if is_stage_sequence(s)]
    motion = {s: image_motion(cal.sequence(s)) for s in seqs}
    both = pd.concat([m for m in motion.values() if len(m)], ignore_index=True) if any(len(m) for m in motion.values()) \
        else pd.DataFrame()
    ok = (both["commanded_mm"] > 0) & (both["moved_px"] > MOVED_PX) if len(both) else pd.Series(dtype=bool)
    px_per_mm = float(np.median(both.loc[ok, "moved_px"] / both.loc[ok, "commanded_mm"])) if ok.any() else None
    for s, m in motion.items():
        for r in m.itertuples():
            if r.commanded_mm == 0 and r.moved_px > MOVED_PX:
                raise SlmlabError(f"sequence {s}, position {r.position}: the dots moved {r.moved_px:.1f} px from its first "
                                  "position but the commanded stage position is the same; check that position's "
                                  "stage_x_mm, stage_y_mm, stage_z_mm", where)
            if (px_per_mm is not None and r.commanded_mm > 0 and r.moved_px < STILL_PX
                    and px_per_mm * r.commanded_mm > 20 * STILL_PX):
                raise SlmlabError(f"sequence {s}, position {r.position}: the stage was commanded {1e3 * r.commanded_mm:.1f} µm "
                                  f"from its first position but the dots did not move (< {STILL_PX} px, where "
                                  f"{px_per_mm * r.commanded_mm:.1f} px were expected); check the images and the "
                                  "stage positions", where)
        if s in "XYZ" and len(s) == 1:
            span = cal.sequence(s)[STAGE_COLUMNS].agg(lambda v: float(v.max() - v.min())).to_numpy()
            named = "XYZ".index(s)
            if span.max() > 0 and span[named] < 0.5 * span.max():
                along = "XYZ"[int(np.argmax(span))]
                raise SlmlabError(f"sequence {s} moves along {along} ({span[int(np.argmax(span))]:g} mm) more than along "
                                  f"{s} ({span[named]:g} mm); name the sequence after its axis or fix its stage columns",
                                  where)


