"""Third-party calibration data in slmlab's interchange format (folders from :func:`slmlab.datasets.fetch`).

The 4th International PIV Challenge's case E (Kähler et al., Exp. Fluids 57:97, 2016; images and point lists
via fluidimage) is a real stereo rig imaging a two-level dot plate (15 mm pitch, bright dots on black, a
square and a triangle marker) at seven known Z positions, 1 mm apart: a Z stack alone. Two ways in:

* :func:`pivchallenge_set`: the challenge's own picks, UVMAT ``GeometryCalib`` XML files (``X Y Z u v`` per
  ``PointCoord``, X, Y, Z in ``CoordUnit``), one per camera and plane, on the plate's first level. UVMAT
  writes pixel coordinates from 1 (MATLAB): the first pixel's centre is ``u = 1``, slmlab's ``w1 = 0``
  (README, "The format"). The conversion subtracts that one pixel (checked on the images: the picks sit
  1.03 ± 0.14 px and 0.99 ± 0.14 px from slmlab's edge-based centres in camera 1).
* :func:`pivchallenge_image_set`: a set of the images themselves, as a camera wrote them (16-bit TIFF), for
  ``python -m slmlab extract``: ``stage.csv`` naming them, ``meta.json`` describing the plate.

Conversion only: nothing is fitted here, and nothing is tuned to these data.

Conventions (README, "The format"): the first camera is the left view, the second the right; ``u`` (column) is
``w1`` and ``v`` (row) is ``w2``; the Z positions, sorted, are the positions of sequence ``Z``. The picks'
plate rows and columns are numbered so that slmlab's plate convention (:func:`slmlab.models.frames.plate_xy`:
``x = ((cols + 1)/2 − col)·pitch``, ``y = ((rows + 1)/2 − row)·pitch``) gives back the data's own X and Y,
with the plate's centre as the commanded stage X, Y. The extracted images carry the plate's own frame
instead (``x_mm, y_mm, z_mm``, origin at the dot between the markers), which is the picks' frame.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
import pandas as pd

from ..errors import SlmlabError
from ..io import POINT_COLUMNS, SET_FORMAT, CalibrationSet, atomic_write_text, json_text

__all__ = ["read_uvmat_points", "zstack_set_from_points", "pivchallenge_set", "pivchallenge_picks",
           "pivchallenge_image_set", "dice_image_set", "chessboard_image_set", "PIV_CHALLENGE_DIR", "DICE_DIR",
           "CHESSBOARD_DIR", "UVMAT_PIXEL_ORIGIN"]

PIV_CHALLENGE_DIR = "pivchallenge4-caseE-stereo-calib"
_UNITS_MM = {"mm": 1.0, "cm": 10.0, "m": 1000.0}
#: UVMAT's pixel coordinate of the first pixel's centre (MATLAB counts from 1); slmlab's is 0
UVMAT_PIXEL_ORIGIN = 1.0
_POINT = re.compile(r"<PointCoord[^>]*>\s*([^<]+?)\s*</PointCoord>", re.S)
_UNIT = re.compile(r"<CoordUnit>\s*(\w+)\s*</CoordUnit>", re.S)


def read_uvmat_points(path: str | Path) -> pd.DataFrame:
    """One UVMAT ``GeometryCalib`` point list: columns ``X_mm, Y_mm, Z_mm, u_px, v_px``."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8", errors="strict")
    except (OSError, UnicodeDecodeError) as exc:
        raise SlmlabError(f"cannot read a UVMAT point list ({exc.__class__.__name__})", path) from None
    unit = _UNIT.search(text)
    scale = _UNITS_MM.get(unit.group(1).lower() if unit else "mm")
    if scale is None:
        raise SlmlabError(f"unknown CoordUnit {unit.group(1)!r}; expected mm, cm or m", path)
    rows = []
    for k, m in enumerate(_POINT.finditer(text), 1):
        vals = m.group(1).split()
        try:
            x, y, z, u, v = (float(t) for t in vals)
        except ValueError:
            raise SlmlabError(f"PointCoord {k} is not 'X Y Z u v': {m.group(1)!r}", path) from None
        rows.append((x * scale, y * scale, z * scale, u, v))
    if not rows:
        raise SlmlabError("has no PointCoord entries; is it a UVMAT GeometryCalib file?", path)
    return pd.DataFrame(rows, columns=["X_mm", "Y_mm", "Z_mm", "u_px", "v_px"])


def zstack_set_from_points(common: pd.DataFrame, image_size_px=(1024, 1024), dot_diameter_mm: float = 1.0,
                           source: str = "") -> CalibrationSet:
    """A Z-stack calibration set from matched stereo points: columns ``X_mm, Y_mm, Z_mm`` (the plate's
    lattice and the stage's Z) and ``u1_px, v1_px, u2_px, v2_px`` (first and second camera)
    [mm, px]. ``dot_diameter_mm`` only describes the plate (meta.json)."""
    need = ["X_mm", "Y_mm", "Z_mm", "u1_px", "v1_px", "u2_px", "v2_px"]
    missing = [c for c in need if c not in common.columns]
    if missing:
        raise SlmlabError(f"matched points lack the column(s) {', '.join(missing)}")
    df = common[need].astype(float).dropna(subset=["X_mm", "Y_mm", "Z_mm"])
    df = df[df[["u1_px", "v1_px"]].notna().all(axis=1) | df[["u2_px", "v2_px"]].notna().all(axis=1)]
    xs, ys, zs = (np.unique(df[c].round(9)) for c in ("X_mm", "Y_mm", "Z_mm"))
    steps = np.concatenate([np.diff(xs), np.diff(ys)])
    if len(zs) < 3 or len(steps) == 0:
        raise SlmlabError("a Z stack needs at least 3 planes and a lattice of at least 2 × 2 points")
    pitch = float(steps.min())
    if not np.allclose(steps / pitch, np.round(steps / pitch), atol=1e-6):
        raise SlmlabError(f"the X, Y positions are not on one lattice (smallest spacing {pitch:g} mm)")
    cols = int(round((xs[-1] - xs[0]) / pitch)) + 1
    rows = int(round((ys[-1] - ys[0]) / pitch)) + 1
    cx, cy = (xs[0] + xs[-1]) / 2, (ys[0] + ys[-1]) / 2
    pts = pd.DataFrame({
        "sequence": "Z",
        "position": np.searchsorted(zs, df["Z_mm"].round(9).to_numpy()) + 1,
        "stage_x_mm": cx, "stage_y_mm": cy, "stage_z_mm": df["Z_mm"].to_numpy(),
        "row": np.rint((rows + 1) / 2 - (df["Y_mm"].to_numpy() - cy) / pitch).astype(int),
        "col": np.rint((cols + 1) / 2 - (df["X_mm"].to_numpy() - cx) / pitch).astype(int),
        "wl1": df["u1_px"].to_numpy(), "wl2": df["v1_px"].to_numpy(),
        "wr1": df["u2_px"].to_numpy(), "wr2": df["v2_px"].to_numpy(),
    })[POINT_COLUMNS].sort_values(["position", "row", "col"], kind="stable").reset_index(drop=True)
    plate = {"rows": rows, "cols": cols, "pitch_mm": pitch, "dot_diameter_mm": float(dot_diameter_mm)}
    meta = {"format": SET_FORMAT, "image_size_px": [int(v) for v in image_size_px],
            "plates": {"grid": plate, "moving": plate}, "source": source}
    return CalibrationSet(points=pts, meta=meta)


def pivchallenge_picks(folder: str | Path, cameras=("Camera_01", "Camera_03"), *, common: bool = True
                       ) -> pd.DataFrame:
    """The PIV Challenge case E picks of both cameras (``{camera}/img_{i}.xml``), in slmlab's pixel
    convention: columns ``X_mm, Y_mm, Z_mm, u1_px, v1_px, u2_px, v2_px``, one row per plate point and plane;
    with ``common=False`` also the points only one camera picked (the other's columns empty)."""
    folder = Path(folder)
    frames = []
    for cam in cameras:
        files = sorted((folder / cam).glob("img_*.xml"), key=lambda p: int(re.sub(r"\D", "", p.stem) or 0))
        if not files:
            raise SlmlabError(f"no UVMAT point lists {cam}/img_*.xml", folder)
        f = pd.concat([read_uvmat_points(f) for f in files], ignore_index=True)
        f[["u_px", "v_px"]] -= UVMAT_PIXEL_ORIGIN
        frames.append(f)
    key = ["X_mm", "Y_mm", "Z_mm"]
    for f in frames:
        f[key] = f[key].round(6)
    both = frames[0].merge(frames[1], on=key, suffixes=("1", "2"), how="inner" if common else "outer")
    both = both.rename(columns={"u_px1": "u1_px", "v_px1": "v1_px", "u_px2": "u2_px", "v_px2": "v2_px"})
    return both.sort_values(["Z_mm", "Y_mm", "X_mm"], ascending=[True, False, True], kind="stable").reset_index(drop=True)


def pivchallenge_set(folder: str | Path, cameras=("Camera_01", "Camera_03"), *, common: bool = True) -> CalibrationSet:
    """The PIV Challenge case E Z stack as a calibration set, from its UVMAT point lists: the points both
    cameras picked (``common=False``: every camera's picks, a view's columns empty where it has none);
    raises :class:`SlmlabError` if absent."""
    both = pivchallenge_picks(folder, cameras, common=common)
    # the dots are about 35 px across at about 11.9 px/mm (camera 1): 3 mm
    return zstack_set_from_points(both, (1024, 1024), dot_diameter_mm=3.0,
                                  source=f"4th PIV Challenge case E (Kähler et al. 2016) via fluidimage, "
                                         f"{cameras[0]} (left) and {cameras[1]} (right), UVMAT point lists")


def pivchallenge_image_set(folder: str | Path, out_dir: str | Path, *, level_offset_mm: float | None = None,
                           cameras=(("Camera_01", 1), ("Camera_03", 3))) -> Path:
    """Write a calibration set of the PIV Challenge case E images themselves into ``out_dir`` (created):
    ``stage.csv`` naming the 16-bit TIFFs (paths relative to ``out_dir``; nothing is copied) at Z = −3 … +3
    mm, and ``meta.json`` describing the plate: 15 mm pitch, bright dots, two levels (rows alternating
    between two depths, offset by half a pitch), larger than the field (no rows or cols: its square and
    triangle markers anchor the numbering). ``level_offset_mm``: the second level's z in the plate's frame,
    if known (:func:`slmlab.studies.realrigs.measure_level_offset` measures it)."""
    folder, out_dir = Path(folder).resolve(), Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rows = ["sequence,position,stage_x_mm,stage_y_mm,stage_z_mm,left_image,right_image"]
    for k in range(1, 8):
        names = [os.path.relpath(folder / cam / f"E_camera_{n}_z_{k}.tif", out_dir.resolve()) for cam, n in cameras]
        for name in names:
            if not (out_dir / name).exists():
                raise SlmlabError(f"case E image {name} not found", out_dir / name)
        rows.append(f"Z,{k},0,0,{k - 4},{names[0]},{names[1]}")
    plate = {"pitch_mm": 15.0, "dot_diameter_mm": 3.0, "dots": "bright", "levels": 2}
    if level_offset_mm is not None:
        plate["level_offset_mm"] = float(level_offset_mm)
    meta = {"format": SET_FORMAT, "image_size_px": [1024, 1024], "plates": {"moving": plate},
            "source": "4th PIV Challenge case E (Kähler et al. 2016) via fluidimage: the calibration images, "
                      f"{cameras[0][0]} (left) and {cameras[1][0]} (right)"}
    atomic_write_text(out_dir / "stage.csv", "\n".join(rows) + "\n")
    atomic_write_text(out_dir / "meta.json", json_text(meta))
    return out_dir


DICE_DIR = "dice-calb-sys2-dot-target"
CHESSBOARD_DIR = "opencv-stereo-chessboard-9x6"


def _free_pose_set(out_dir: Path, pairs: list[tuple[Path, Path]], plate: dict, size_px, source: str) -> Path:
    """A set of stereo pairs in free poses (no known stage moves): sequence ``T`` (as the simulator's held
    poses), every position at stage zero, images named by ``stage.csv`` relative to ``out_dir``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rows = ["sequence,position,stage_x_mm,stage_y_mm,stage_z_mm,left_image,right_image"]
    for k, (left, right) in enumerate(pairs, 1):
        names = [os.path.relpath(Path(p).resolve(), out_dir.resolve()) for p in (left, right)]
        rows.append(f"T,{k},0,0,0,{names[0]},{names[1]}")
    meta = {"format": SET_FORMAT, "image_size_px": [int(v) for v in size_px], "plates": {"moving": plate},
            "source": source}
    atomic_write_text(out_dir / "stage.csv", "\n".join(rows) + "\n")
    atomic_write_text(out_dir / "meta.json", json_text(meta))
    return out_dir


def dice_image_set(folder: str | Path, out_dir: str | Path) -> Path:
    """DICe's real stereo dot-target pairs (``CalB-sys2-00NN_{0,1}.jpeg``) as a set to extract: black dots at
    3.5 mm with three donut markers in an L; free hand-held poses.

    The target is larger than the field; DICe uses the 10 × 8 dots of a box around the markers
    (``stereo_marker_dots_input.xml``: ``num_cal_fiducials_x = 10``, ``_y = 8``, the corner donut at
    ``cal_origin_x = cal_origin_y = 2`` counted from 0, the other donuts 6 and 4 dots from it counted
    inclusively). In slmlab's plate numbering, from 1, that box is rows 1–8, columns 1–10 with the corner
    donut at ``[3, 3]``; ``extract`` keeps the dots inside it, as DICe does."""
    folder = Path(folder)
    lefts = sorted((folder / "images").glob("CalB-sys2-*_0.jpeg"))
    if not lefts:
        raise SlmlabError("no DICe images images/CalB-sys2-*_0.jpeg", folder)
    pairs = [(p, p.with_name(p.name.replace("_0.", "_1."))) for p in lefts]
    plate = {"rows": 8, "cols": 10, "pitch_mm": 3.5, "dot_diameter_mm": 1.75, "dots": "dark", "marker_origin": [3, 3]}
    return _free_pose_set(out_dir, pairs, plate, (2448, 2048), "DICe CalB-sys2 stereo dot target (Sandia), "
                          "cameras 0 (left) and 1 (right)")


def chessboard_image_set(folder: str | Path, out_dir: str | Path) -> Path:
    """OpenCV's stereo chessboard samples (``left01..14``, ``right01..14``, 9 × 6 inner corners) as a set to
    extract with ``pattern: chessboard``; free hand-held poses, square size 1 (arbitrary units)."""
    folder = Path(folder)
    lefts = sorted((folder / "images").glob("left*.jpg"))
    if not lefts:
        raise SlmlabError("no chessboard images images/left*.jpg", folder)
    pairs = [(p, p.with_name(p.name.replace("left", "right"))) for p in lefts]
    plate = {"rows": 6, "cols": 9, "pitch_mm": 1.0, "pattern": "chessboard"}
    return _free_pose_set(out_dir, pairs, plate, (640, 480), "OpenCV stereo chessboard samples (via DICe)")
