"""Reading and writing slmlab's interchange format (README, "Bring your own measured dot centres"):
calibration sets, point tables, and atomic writes.

A calibration set is a folder with ``points.csv`` (one row per sequence, stage position and grid point),
``meta.json`` (format version, image size, plates), optionally ``images/`` and, for simulated sets,
``truth.csv``. Everything a user can get wrong raises :class:`slmlab.SlmlabError` naming the file, the
row or column, and the remedy.
"""

from __future__ import annotations

import json
import math
import os
import re
import shutil
import tempfile
from contextlib import contextmanager
from dataclasses import dataclass, field
from io import StringIO
from pathlib import Path

import numpy as np
import pandas as pd

from .errors import SlmlabError

__all__ = [
    "SET_FORMAT",
    "KEY_COLUMNS",
    "STAGE_COLUMNS",
    "IMAGE_COLUMNS",
    "POINT_COLUMNS",
    "TARGET_COLUMNS",
    "CalibrationSet",
    "read_set",
    "write_set",
    "read_points",
    "write_csv",
    "atomic_write_text",
    "atomic_write_bytes",
    "atomic_folder",
    "IMAGE_NAME",
    "SET_FILES",
    "simulated_set_files",
    "json_text",
    "read_csv_text",
    "read_meta",
    "require_columns",
    "sequence_position_stage",
]

SET_FORMAT = "slmlab-calibration/1"
KEY_COLUMNS = ["sequence", "position", "row", "col"]
STAGE_COLUMNS = ["stage_x_mm", "stage_y_mm", "stage_z_mm"]
IMAGE_COLUMNS = ["wl1", "wl2", "wr1", "wr2"]
POINT_COLUMNS = ["sequence", "position", *STAGE_COLUMNS, "row", "col", *IMAGE_COLUMNS]
TRUTH_COLUMNS = [*KEY_COLUMNS, *IMAGE_COLUMNS, "X_mm", "Y_mm", "Z_mm"]
#: optional columns of a known-target set: a dot's position in its target's own frame [mm]
TARGET_COLUMNS = ["x_mm", "y_mm", "z_mm"]
PATTERNS = ("dots", "chessboard", "circles", "asymmetric-circles", "charuco")
FLOAT_FORMAT = "%.10g"
_UMASK = os.umask(0)
os.umask(_UMASK)


@dataclass
class CalibrationSet:
    """A calibration set in memory.

    Attributes
    ----------
    points
        one row per (sequence, position, grid point) with the columns of ``POINT_COLUMNS`` (image
        coordinates NaN where a dot was not found) [px, mm].
    meta
        the content of ``meta.json``.
    truth
        for simulated sets: noise-free image coordinates and true stage-frame coordinates, else ``None``.
    path
        the folder it was read from, if any.
    notes
        what was dropped or repaired while reading, one sentence each (shown to the user).
    """

    points: pd.DataFrame
    meta: dict
    truth: pd.DataFrame | None = None
    path: Path | None = None
    notes: list[str] = field(default_factory=list)

    # -------------------------------------------------------------- convenience views
    @property
    def image_size_px(self) -> tuple[int, int]:
        w, h = self.meta["image_size_px"]
        return int(w), int(h)

    @property
    def sequences(self) -> list[str]:
        """Sequence labels in order of first appearance."""
        return [str(s) for s in pd.unique(self.points["sequence"])]

    def sequence(self, name: str) -> pd.DataFrame:
        """The rows of one sequence (an empty frame if absent)."""
        return self.points[self.points["sequence"] == name]

    def plate(self, sequence: str) -> dict:
        """The plate description (rows, cols, pitch_mm, dot_diameter_mm) of a sequence."""
        return self.meta["plates"]["grid" if sequence == "grid" else "moving"]

    @property
    def known_target(self) -> bool:
        """Whether the set gives each dot's position in its target's frame (``x_mm, y_mm, z_mm``)."""
        return all(c in self.points.columns for c in TARGET_COLUMNS)

    def world(self, rows: pd.DataFrame | None = None) -> np.ndarray:
        """World positions ``(n, 3)`` [mm] of the dots of a known-target set: the commanded stage position
        plus the dot's position on its target (NaN where it is not known)."""
        df = self.points if rows is None else rows
        return df[STAGE_COLUMNS].to_numpy(float) + df[TARGET_COLUMNS].to_numpy(float)

    def image_coordinates(self, sequence: str | None = None) -> np.ndarray:
        """``(n, 4)`` array ``wl1, wl2, wr1, wr2`` [px] of one sequence (or all rows)."""
        df = self.points if sequence is None else self.sequence(sequence)
        return df[IMAGE_COLUMNS].to_numpy(float)

    def summary(self) -> dict:
        """A short JSON-able description (for model files)."""
        seq = {s: int(self.sequence(s)["position"].nunique()) for s in self.sequences}
        return {
            "path": None if self.path is None else str(self.path),
            "source": self.meta.get("source", ""),
            "image_size_px": list(self.image_size_px),
            "positions": seq,
            "rows": int(len(self.points)),
            "rows_with_all_coordinates": int(self.points[IMAGE_COLUMNS].notna().all(axis=1).sum()),
            "known_target": self.known_target,
        }


# ---------------------------------------------------------------------------------------- atomic writes
def _check_parent(path: Path) -> None:
    parent = path.parent
    if not parent.exists():
        raise SlmlabError(f"the folder {parent} does not exist; create it or choose another output path", path)
    if path.exists() and path.is_dir():
        raise SlmlabError("is a folder; give a file name for the output", path)
    if path.exists() and not path.is_file():
        raise SlmlabError("is not a regular file (a device or a pipe); give a file name for the output", path)


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` via a temporary file in the same folder and a rename.

    A failed or interrupted write never leaves a partial file nor replaces a good one. A symbolic link is
    written through (its target replaced, the link kept); a device or a pipe is refused. Where the system refuses
    the write (no permission, no space, a name too long), :class:`SlmlabError` says why.
    """
    path = Path(path)
    if path.is_symlink():
        try:
            path = path.resolve(strict=False)
        except (RuntimeError, OSError):   # a loop of links (Python 3.11 raises RuntimeError)
            raise SlmlabError("is a symbolic link that leads nowhere (a loop); give a file name for the output",
                              path) from None
    _check_parent(path)
    try:
        _replace_with(path, data)
    except OSError as exc:
        raise _refused(exc, path) from None


def _replace_with(path: Path, data: bytes) -> None:
    """:func:`atomic_write_bytes`' temporary file and rename."""
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp makes 0600; give the file the mode a plain open would
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def _refused(exc: OSError, path: Path) -> SlmlabError:
    """The system's refusal to write ``path`` (no permission, no space, a name too long), as a user's error."""
    return SlmlabError(f"cannot be written: {exc.strerror or exc}", path)


#: how ``simulate --images`` names a rendered image in a set's ``images/`` folder (and ``extract`` reads one there)
IMAGE_NAME = re.compile(r"^(?P<sequence>.+)_(?P<position>\d{3,})_(?P<side>[lr])\.png$")

#: the files of a set that are the set's own (beside its images)
SET_FILES = ("points.csv", "truth.csv", "stage.csv", "meta.json")


@contextmanager
def atomic_folder(path: str | os.PathLike):
    """A set's folder written whole or not at all: yields a temporary folder (beside ``path``, or in it where it is
    a folder already), removed where the block
    fails (no space, a file-size limit, an interrupted render: a half set is never left); when the block ends, it is
    renamed to ``path``, or, where ``path`` is an empty folder or holds a set slmlab simulated before
    (:func:`simulated_set_files`), that set's own files are removed and the new ones moved in (a file of the user's
    beside them stays). Any other folder is refused before anything is written: a set simulated there would be
    mixed with what it holds."""
    path = Path(path)
    if not path.parent.exists() or (path.exists() and not path.is_dir()):   # write_set says what is wrong
        yield path
        return
    old = simulated_set_files(path) if path.exists() else None
    try:   # inside a folder that exists (its parent may not be the user's to write in), else beside it
        tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent if old is None else path))
    except OSError as exc:
        raise _refused(exc, path) from None
    try:
        yield tmp
        os.chmod(tmp, 0o777 & ~_UMASK)   # mkdtemp makes 0700; give the folder the mode a plain mkdir would
        if old is None:
            os.replace(tmp, path)
        else:
            _replace_files(path, old, tmp)
    except SlmlabError as exc:   # named where the user asked for it, not in the temporary folder
        shutil.rmtree(tmp, ignore_errors=True)
        where = exc.path and str(exc.path).replace(str(tmp), str(path), 1)
        raise SlmlabError(exc.reason, where) from None
    except OSError as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        raise _refused(exc, path) from None
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def simulated_set_files(path: Path) -> list[Path]:
    """The files of the set slmlab simulated in the folder ``path`` (its ``meta.json`` holds a ``simulator``
    record): :data:`SET_FILES`, and in its own ``images/`` (not a link) the files named as :data:`IMAGE_NAME` and
    those its ``stage.csv`` names there; nothing for an empty folder. Any other folder is a :class:`SlmlabError`."""
    entries = list(path.iterdir())
    if not entries:
        return []
    try:
        meta = json.loads((path / "meta.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        meta = None
    if not (isinstance(meta, dict) and isinstance(meta.get("simulator"), dict)):
        raise SlmlabError("holds files but no simulated set; simulate into a new or empty folder (a set simulated "
                          "here would be mixed with them)", path)
    own = [path / n for n in SET_FILES if (path / n).is_file()]
    images = path / "images"
    if images.is_dir() and not images.is_symlink():
        named = set()
        try:
            stage = pd.read_csv(path / "stage.csv", dtype=str) if (path / "stage.csv").is_file() else pd.DataFrame()
            named = {Path(v).name for c in ("left_image", "right_image") if c in stage for v in stage[c].dropna()
                     if Path(v).parent == Path("images")}
        except (OSError, ValueError, pd.errors.ParserError):
            pass
        own += [f for f in images.iterdir() if f.is_file() and (IMAGE_NAME.match(f.name) or f.name in named)]
    return own


def _replace_files(path: Path, old: list[Path], new: Path) -> None:
    """The old set's files ``old`` in ``path`` removed, the new set's in the folder ``new`` moved in, ``new`` removed."""
    for f in old:
        f.unlink()
    for f in sorted(new.rglob("*")):
        if f.is_file():
            to = path / f.relative_to(new)
            to.parent.mkdir(exist_ok=True)
            os.replace(f, to)
    images = path / "images"
    if images.is_dir() and not images.is_symlink() and not any(images.iterdir()):
        images.rmdir()
    shutil.rmtree(new, ignore_errors=True)


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    """Write UTF-8 ``text`` atomically (see :func:`atomic_write_bytes`)."""
    atomic_write_bytes(path, text.encode("utf-8"))


def write_csv(path: str | os.PathLike, df: pd.DataFrame) -> None:
    """Write a table as CSV atomically, floats with 10 significant digits, ``\\n`` line ends."""
    atomic_write_text(path, df.to_csv(index=False, float_format=FLOAT_FORMAT, lineterminator="\n"))


def json_text(obj) -> str:
    """Stable JSON text: sorted keys, two-space indent, trailing newline."""
    return json.dumps(obj, indent=2, sort_keys=True, allow_nan=False) + "\n"


# ---------------------------------------------------------------------------------------- reading CSV
def read_csv_text(path: Path, what: str) -> pd.DataFrame:
    """Read a CSV file as strings, turning every way it can be unreadable into a SlmlabError."""
    if not path.exists():
        raise SlmlabError(f"{what} not found; a calibration set needs points.csv and meta.json (see README, 'The format')", path)
    if path.is_dir():
        raise SlmlabError(f"is a folder, but {what} must be a CSV file", path)
    raw = path.read_bytes()
    if not raw.strip():
        raise SlmlabError(f"{what} is empty; it needs a header row and at least one data row", path)
    if b"\x00" in raw[:4096]:
        raise SlmlabError(f"{what} is a binary file, not CSV text; export the points as comma-separated text", path)
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise SlmlabError(f"{what} is not UTF-8 text (byte {exc.start}); save it as UTF-8 CSV", path) from None
    try:
        df = pd.read_csv(StringIO(text), dtype=str, keep_default_na=False, skipinitialspace=True)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, ValueError) as exc:
        msg = str(exc).strip().splitlines()[-1] if str(exc).strip() else type(exc).__name__
        raise SlmlabError(f"{what} is not valid CSV ({msg}); check the delimiter (commas) and quoting", path) from None
    df.columns = [str(c).strip() for c in df.columns]
    if len(df) == 0:
        raise SlmlabError(f"{what} has a header but no data rows; add at least one row", path)
    return df


#: the largest index a points file may hold (a position, row or column; beyond it no plate or stage is meant, and
#: the keys that join a row and a column, or a sequence and a position, would run into each other)
INDEX_LIMIT = 99_999


def _numeric(df: pd.DataFrame, col: str, path: Path, *, allow_empty: bool, integer: bool = False,
             minimum: float | None = None) -> np.ndarray:
    """Parse one text column as numbers; name the first bad row (file line) and the column."""
    text = df[col].astype(str).str.strip()
    empty = text.eq("") | text.str.lower().isin(["nan", "na", "null", "none"])
    vals = pd.to_numeric(text.where(~empty, None), errors="coerce").to_numpy(float)
    bad = ~empty & np.isnan(vals)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise SlmlabError(f"row {k + 2}, column {col}: {df[col].iloc[k]!r} is not a number; fix or remove the row", path)
    if empty.any() and not allow_empty:
        k = int(np.flatnonzero(empty.to_numpy())[0])
        raise SlmlabError(f"row {k + 2}, column {col}: missing or NaN value; every row needs a finite {col}", path)
    nonfinite = ~empty.to_numpy() & ~np.isfinite(vals)
    if nonfinite.any():
        k = int(np.flatnonzero(nonfinite)[0])
        raise SlmlabError(f"row {k + 2}, column {col}: {df[col].iloc[k]!r} is not finite; use a finite number"
                          + (" or leave it empty" if allow_empty else ""), path)
    if integer:
        frac = ~np.isnan(vals) & (vals != np.round(vals))
        if frac.any():
            k = int(np.flatnonzero(frac)[0])
            raise SlmlabError(f"row {k + 2}, column {col}: {df[col].iloc[k]!r} is not a whole number", path)
        huge = ~np.isnan(vals) & (np.abs(vals) > INDEX_LIMIT)
        if huge.any():   # beyond it the cast to an integer overflows (NumPy's warning, then a misleading error)
            k = int(np.flatnonzero(huge)[0])
            raise SlmlabError(f"row {k + 2}, column {col}: {df[col].iloc[k]!r} is too large for an index "
                              f"(at most {INDEX_LIMIT})", path)
    if minimum is not None:
        low = ~np.isnan(vals) & (vals < minimum)
        if low.any():
            k = int(np.flatnonzero(low)[0])
            raise SlmlabError(f"row {k + 2}, column {col}: {df[col].iloc[k]!r} is below {minimum:g}; indices start at 1", path)
    return vals


#: a stage position beyond this is no stage's [mm] (a file in µm, most likely)
STAGE_LIMIT_MM = 1e4


def _check_plausible(df: pd.DataFrame, meta: dict | None, path: Path) -> None:
    """Values that are numbers but cannot be what the columns say: image coordinates far outside the image
    (more than one image size beyond its edges) and stage positions beyond :data:`STAGE_LIMIT_MM`."""
    if meta is not None:
        w, h = meta["image_size_px"]
        for c, size in (("wl1", w), ("wr1", w), ("wl2", h), ("wr2", h)):
            if c not in df.columns:
                continue
            v = df[c].to_numpy(float)
            bad = np.isfinite(v) & ((v < -size) | (v > 2 * size))
            if bad.any():
                k = int(np.flatnonzero(bad)[0])
                raise SlmlabError(f"row {k + 2}, column {c}: {v[k]:g} px is far outside the {w} × {h} image; "
                                  "fix the value or leave it empty", path)
    for c in STAGE_COLUMNS + TARGET_COLUMNS:
        if c not in df.columns:
            continue
        v = df[c].to_numpy(float)
        bad = np.isfinite(v) & (np.abs(v) > STAGE_LIMIT_MM)
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            raise SlmlabError(f"row {k + 2}, column {c}: {v[k]:g} mm is beyond any stage (over {STAGE_LIMIT_MM:g} "
                              "mm); are the positions in µm? give them in mm", path)


def sequence_position_stage(df: pd.DataFrame, path) -> pd.DataFrame:
    """The columns every stage-position table shares (``points.csv``, ``stage.csv``): ``sequence`` (a
    non-empty label), ``position`` (an integer from 1) and ``stage_x_mm, stage_y_mm, stage_z_mm``, checked."""
    out = pd.DataFrame({"sequence": df["sequence"].astype(str).str.strip()})
    if (out["sequence"] == "").any():
        k = int(np.flatnonzero(out["sequence"].to_numpy() == "")[0])
        raise SlmlabError(f"row {k + 2}, column sequence: empty label; use grid, X, Y, Z or another name", path)
    out["position"] = _numeric(df, "position", path, allow_empty=False, integer=True, minimum=1).astype(int)
    for c in STAGE_COLUMNS:
        out[c] = _numeric(df, c, path, allow_empty=False)
    return out


def require_columns(df: pd.DataFrame, cols: list[str], path: Path, what: str) -> None:
    missing = [c for c in cols if c not in df.columns]
    if missing:
        raise SlmlabError(f"{what} lacks column{'s' if len(missing) > 1 else ''} {', '.join(missing)}; "
                          f"the header must name {', '.join(cols)}", path)


def read_points(path: str | os.PathLike) -> pd.DataFrame:
    """Read a table of points to reconstruct: any CSV with columns ``wl1, wl2, wr1, wr2`` [px].

    Other columns pass through unchanged (as text). Empty image coordinates become NaN.
    """
    path = Path(path)
    df = read_csv_text(path, "the points file")
    require_columns(df, IMAGE_COLUMNS, path, "the points file")
    for c in IMAGE_COLUMNS:
        df[c] = _numeric(df, c, path, allow_empty=True)
    return df


# ---------------------------------------------------------------------------------------- sets
def read_meta(path: Path) -> dict:
    """``meta.json``, validated for every verb: what a set of points needs (format, image size, plates and their
    pitch, rows and cols where given). What only finding the plates in images needs (``dot_diameter_mm``, a
    ChArUco board's details) is checked by extraction where it is missing, and here only where it is given."""
    if not path.exists():
        raise SlmlabError("meta.json not found; a calibration set needs it beside points.csv (see README, 'The format')", path)
    if path.is_dir():
        raise SlmlabError("is a folder, but meta.json must be a JSON file", path)
    try:
        meta = json.loads(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise SlmlabError("is not UTF-8 text; meta.json must be JSON", path) from None
    except json.JSONDecodeError as exc:
        raise SlmlabError(f"invalid JSON at line {exc.lineno}, column {exc.colno} ({exc.msg}); fix the file", path) from None
    if not isinstance(meta, dict):
        raise SlmlabError("must hold a JSON object with format, image_size_px and plates", path)
    fmt = meta.get("format")
    if fmt != SET_FORMAT:
        raise SlmlabError(f"format is {fmt!r}, this slmlab reads {SET_FORMAT!r}; convert the set or upgrade slmlab", path)
    size = meta.get("image_size_px")
    if (not isinstance(size, list) or len(size) != 2
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and v > 0 and float(v).is_integer()
                       for v in size)):
        raise SlmlabError("image_size_px must be [width, height] in whole pixels, e.g. [2048, 2048]", path)
    plates = meta.get("plates")
    if not isinstance(plates, dict) or not plates:
        raise SlmlabError("plates must describe the 'grid' and/or 'moving' plate (rows, cols, pitch_mm, dot_diameter_mm)", path)
    for name, plate in plates.items():
        if not isinstance(plate, dict):
            raise SlmlabError(f"plates.{name} must be an object with rows, cols, pitch_mm, dot_diameter_mm", path)
        # dot_diameter_mm and a ChArUco board's details are needed only to find the plate in images: checked by
        # extraction (slmlab.images.imageset.check_extractable), not here, so that a set of points reads without them
        for key, integer, required in (("rows", True, False), ("cols", True, False), ("pitch_mm", False, True),
                                       ("dot_diameter_mm", False, False)):
            v = plate.get(key)
            if v is None and not required:
                continue
            if not _positive(v, integer):
                raise SlmlabError(f"plates.{name}.{key} must be a positive {'whole number' if integer else 'number'}"
                                  + ("" if required else " (or left out)"), path)
        if ("rows" in plate) != ("cols" in plate):
            raise SlmlabError(f"plates.{name} gives only one of rows and cols; give both, or neither for a plate "
                              "larger than the field", path)
        dots = plate.get("dots")
        if dots is not None and dots not in ("dark", "bright"):
            raise SlmlabError(f"plates.{name}.dots must be 'dark' or 'bright' (or left out: decided from the image)", path)
        pattern = plate.get("pattern", "dots")
        if pattern not in PATTERNS:
            raise SlmlabError(f"plates.{name}.pattern {pattern!r} is not one of {', '.join(PATTERNS)}", path)
        levels = plate.get("levels", 1)
        if levels not in (1, 2):
            raise SlmlabError(f"plates.{name}.levels must be 1 or 2 (a two-level plate)", path)
        off = plate.get("level_offset_mm")
        if off is not None and not (isinstance(off, (int, float)) and not isinstance(off, bool) and math.isfinite(off)):
            raise SlmlabError(f"plates.{name}.level_offset_mm must be a number: the second level's z in the plate's "
                              "frame [mm]", path)
        origin = plate.get("marker_origin")
        if origin is not None and not (isinstance(origin, list) and len(origin) == 2
                                       and all(_positive(v, True) for v in origin)):
            raise SlmlabError(f"plates.{name}.marker_origin must be [row, col] of the corner donut", path)
        if plate.get("board") is not None and not isinstance(plate["board"], dict):
            raise SlmlabError(f"plates.{name}.board must be an object {{squares: [x, y], marker_mm, dictionary, "
                              "legacy}} (or left out where points.csv is given)", path)
    return meta


def _positive(v, integer: bool) -> bool:
    ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0
    return bool(ok and (not integer or float(v).is_integer()))


def read_set(path: str | os.PathLike) -> CalibrationSet:
    """Read a calibration set folder (``points.csv``, ``meta.json``, optional ``truth.csv``).

    Validates the format (README, "Bring your own measured dot centres") and raises :class:`SlmlabError` on
    anything malformed. Exact duplicate rows are dropped and reported in ``notes``; duplicates that disagree
    are an error.
    """
    path = Path(path)
    if not path.exists():
        raise SlmlabError("calibration set folder not found; give the folder that holds points.csv and meta.json", path)
    if not path.is_dir():
        raise SlmlabError("is a file; give the calibration set's folder (with points.csv and meta.json)", path)
    meta = read_meta(path / "meta.json")
    pfile = path / "points.csv"
    out, given = _point_columns(read_csv_text(pfile, "points.csv"), meta, pfile)
    _check_plate_indices(out, meta, bool(given), path)
    out, notes = _drop_duplicates(out, given, pfile)
    _check_one_stage_position(out, pfile)
    truth = _read_truth(path / "truth.csv")
    return CalibrationSet(points=out, meta=meta, truth=truth, path=path, notes=notes)


def _point_columns(df: pd.DataFrame, meta: dict, pfile: Path) -> tuple[pd.DataFrame, list[str]]:
    """``points.csv``'s columns parsed and checked: the key, stage and image columns, the known-target
    columns that are given, and any extra column as text. Returns the table and the target columns given."""
    require_columns(df, POINT_COLUMNS, pfile, "points.csv")
    out = sequence_position_stage(df, pfile)
    for c in ("row", "col"):
        out[c] = _numeric(df, c, pfile, allow_empty=False, integer=True, minimum=1).astype(int)
    for c in IMAGE_COLUMNS:
        out[c] = _numeric(df, c, pfile, allow_empty=True)
    _check_plausible(out, meta, pfile)
    given = [c for c in TARGET_COLUMNS if c in df.columns]
    if given and len(given) < 3:
        missing = [c for c in TARGET_COLUMNS if c not in given]
        raise SlmlabError(f"has {', '.join(given)} but not {', '.join(missing)}; a known-target set gives all three "
                          "of x_mm, y_mm, z_mm (the dot's position in its target's frame)", pfile)
    for c in given:  # empty where a dot's place is not known (e.g. a two-level plate without level_offset_mm)
        out[c] = _numeric(df, c, pfile, allow_empty=True)
    if given:
        _check_plausible(out[given], None, pfile)
    extra = [c for c in df.columns if c not in POINT_COLUMNS and c not in TARGET_COLUMNS]
    for c in extra:
        out[c] = df[c]
    return out, given


def _check_plate_indices(out: pd.DataFrame, meta: dict, known_target: bool, path: Path) -> None:
    """Every sequence has its plate in ``meta.json``, and every ``row, col`` lies on it (a plate without a
    size needs the known-target columns)."""
    plates = meta["plates"]
    pfile = path / "points.csv"
    for is_grid, name in ((True, "grid"), (False, "moving")):
        rows = out[(out["sequence"] == "grid") == is_grid]
        if rows.empty:
            continue
        if name not in plates:
            raise SlmlabError(f"sequence{'s' if not is_grid else ''} {'grid' if is_grid else 'other than grid'} "
                              f"need plates.{name} in meta.json", path / "meta.json")
        if plates[name].get("rows") is None:
            if not known_target:
                raise SlmlabError(f"plates.{name} has no rows and cols (a plate larger than the field), so its "
                                  "frame comes from x_mm, y_mm, z_mm columns, which points.csv lacks; give the "
                                  "plate's size or extract the set with 'python -m slmlab extract'", path / "meta.json")
            continue
        for c, lim in (("row", plates[name]["rows"]), ("col", plates[name]["cols"])):
            bad = rows[c] > lim
            if bad.any():
                k = int(rows.index[bad.to_numpy()][0])
                raise SlmlabError(f"row {k + 2}, column {c}: {rows[c][k]} is outside the {name} plate "
                                  f"({plates[name]['rows']} × {plates[name]['cols']}); fix the index or meta.json", pfile)


def _drop_duplicates(out: pd.DataFrame, given: list[str], pfile: Path) -> tuple[pd.DataFrame, list[str]]:
    """Exact duplicate rows dropped (and said in the notes); duplicates that disagree are an error."""
    key = out[KEY_COLUMNS]
    dup = key.duplicated(keep=False)
    if not dup.any():
        return out, []
    for _, g in out[dup].groupby(KEY_COLUMNS, sort=False):
        vals = g[STAGE_COLUMNS + IMAGE_COLUMNS + given].to_numpy(float)
        same = np.all((vals == vals[0]) | (np.isnan(vals) & np.isnan(vals[0])))
        if not same:
            k = int(g.index[1])
            raise SlmlabError(f"row {k + 2}: duplicates row {int(g.index[0]) + 2} (same sequence, position, row, col) "
                              "with different values; keep one of them", pfile)
    n = int(key.duplicated().sum())
    out = out[~key.duplicated()].reset_index(drop=True)
    return out, [f"{n} exact duplicate row{'s' if n > 1 else ''} dropped from points.csv"]


def _check_one_stage_position(out: pd.DataFrame, pfile: Path) -> None:
    """Every row of one (sequence, position) carries the same commanded stage position."""
    spread = out.groupby(["sequence", "position"], sort=False)[STAGE_COLUMNS].agg(lambda v: v.max() - v.min())
    bad = spread.max(axis=1) > 1e-9
    if bad.any():
        s, p = bad.index[bad.to_numpy()][0]
        raise SlmlabError(f"sequence {s}, position {p}: rows disagree on the stage position; "
                          "every row of one position must carry the same stage_x_mm, stage_y_mm, stage_z_mm", pfile)


def _read_truth(tfile: Path) -> pd.DataFrame | None:
    """``truth.csv`` of a simulated set, or ``None`` where there is none."""
    if not tfile.exists():
        return None
    tdf = read_csv_text(tfile, "truth.csv")
    require_columns(tdf, TRUTH_COLUMNS, tfile, "truth.csv")
    truth = pd.DataFrame({"sequence": tdf["sequence"].astype(str).str.strip()})
    for c in ("position", "row", "col"):
        truth[c] = _numeric(tdf, c, tfile, allow_empty=False, integer=True, minimum=1).astype(int)
    for c in TRUTH_COLUMNS[4:]:
        truth[c] = _numeric(tdf, c, tfile, allow_empty=False)
    return truth


def write_set(path: str | os.PathLike, cal: CalibrationSet) -> Path:
    """Write a calibration set folder (created if missing; its parent must exist). Files are atomic."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise SlmlabError("exists and is a file; give a folder for the calibration set", path)
    if not path.parent.exists():
        raise SlmlabError(f"the folder {path.parent} does not exist; create it first", path)
    path.mkdir(exist_ok=True)
    cols = POINT_COLUMNS + [c for c in TARGET_COLUMNS if c in cal.points.columns]
    write_csv(path / "points.csv", cal.points[cols + [c for c in cal.points.columns if c not in cols]])
    if cal.truth is not None:
        write_csv(path / "truth.csv", cal.truth[TRUTH_COLUMNS])
    atomic_write_text(path / "meta.json", json_text(cal.meta))
    return path
