"""A calibration set's images, extracted into one ``points.csv`` (the command line's ``extract``).

Where the images are
    ``stage.csv`` with columns ``sequence, position, stage_x_mm, stage_y_mm, stage_z_mm, left_image,
    right_image`` names them (paths relative to the set's folder; any format and bit depth OpenCV reads), as
    a camera wrote them; or, for simulated sets, ``images/{sequence}_{position:03d}_{l|r}.png`` with the stage
    positions from ``points.csv`` (re-extraction) or from a ``stage.csv`` without image columns.

How each plate is found
    From its entry in ``meta.json`` (:func:`plate_spec`): the ``pattern`` (``dots``, the default, found by
    :mod:`slmlab.images.extract`; ``chessboard``, ``circles``, ``asymmetric-circles`` and ``charuco`` by OpenCV's own
    detectors, :mod:`slmlab.images.boards`), the dots' polarity (``"dots": "dark" | "bright"``, else decided per
    image), and for two-level plates their ``level_offset_mm``.

A camera's hot pixels
    Each camera's images of dots are read first (and kept for their extraction, as memory allows): a pixel that
    stands out of its neighbours in three quarters of them, and in two, is the sensor's
    (:func:`slmlab.images.dots.camera_hot_pixels`) and is replaced in each of them, inside the dots too, where one
    image alone cannot tell it from the dot's texture (where the dots are found and at least 2.5 px in radius).

One numbering for the whole set
    The same dot gets the same ``[row, col]`` in every image and in both views. A plate whose ``rows`` and
    ``cols`` are given and which is wholly in view is numbered by its size; a plate with markers by them (an
    L of donuts; a square and a triangle; a frame around the origin dot: :mod:`slmlab.images.lattice`);
    an image that cannot be numbered alone (a plate larger than the field whose markers it does not show, a
    plate cut on both sides) is **tracked**: the images of the same view numbered alone show how the plate
    moves with the stage, which predicts its numbering (:mod:`slmlab.images.tracking`); where that
    prediction is ambiguous the image is left out, and the notes say why. A plate
    anchored by an origin (markers) has no size: its dots are numbered from 1 over the whole set, and their
    positions in the plate's own frame are written as ``x_mm, y_mm, z_mm`` (a known-target set).

Every error a user can cause (a missing or unreadable image, images of different sizes, an image without
dots, a plate whose numbering cannot be anchored) is a :class:`slmlab.SlmlabError` naming the file and the
remedy, raised before anything is written.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from tqdm import tqdm

from ..errors import SlmlabError
from ..io import (IMAGE_COLUMNS, IMAGE_NAME, PATTERNS, POINT_COLUMNS, STAGE_COLUMNS, read_csv_text, read_meta, read_set,
                  require_columns, sequence_position_stage)
from .boards import charuco_board, detect_board
from .dots import camera_hot_pixels, hot_images_needed, hot_pixel_flags, read_image
from .extract import (AUTO_FIT_SLACK, ImageDots, choose_method, extract_image, extract_image_methods,
                      report_summary)
from .tracking import Numbered, track

__all__ = ["PATTERNS", "PlateSpec", "plate_spec", "check_extractable", "ImagePair", "image_pairs", "extract_set",
           "STAGE_FILE", "TRACKED", "KEEP_IMAGES_BYTES"]

#: how the notes name an image numbered by tracking (``... by TRACKED (k)``: k images;
#: :mod:`slmlab.images.tracking`)
TRACKED = "tracked by the stage motion from the images numbered alone"

STAGE_FILE = "stage.csv"
#: the images read to find the cameras' hot pixels are kept for their extraction up to this many bytes (:class:`_Images`)
KEEP_IMAGES_BYTES = 256 * 2 ** 20


@dataclass(frozen=True)
class PlateSpec:
    """What the extractor needs to know about one plate (from ``meta.json``; :func:`plate_spec`).

    Attributes
    ----------
    name
        ``'grid'`` or ``'moving'``.
    rows, cols
        the plate's size in dots (corners for boards), or ``None`` for a plate larger than the field.
    pitch_mm
        dot spacing along a row [mm] (square size for boards).
    dark
        dark dots on a bright plate, bright dots on a dark one, or ``None``: decided from each image.
    pattern
        one of :data:`PATTERNS`.
    levels
        1, or 2 for a two-level plate (rows alternating between two depths, offset by half a pitch).
    level_offset_mm
        ``z`` of the second level in the plate's frame [mm] (``None`` if not given).
    marker_origin
        ``[row, col]`` of the corner donut of an L of donut markers.
    board
        the board's description for ``charuco`` (squares, square and marker size, dictionary, legacy layout).
    """

    name: str
    rows: int | None
    cols: int | None
    pitch_mm: float
    dark: bool | None = None
    pattern: str = "dots"
    levels: int = 1
    level_offset_mm: float | None = None
    marker_origin: tuple[int, int] = (2, 2)
    board: dict = field(default_factory=dict)

    @property
    def unit_mm(self) -> float:
        """The spacing of the numbering [mm]: the pitch, or half of it on a two-level plate."""
        return self.pitch_mm / 2 if self.levels == 2 else self.pitch_mm


def plate_spec(meta: dict, name: str) -> PlateSpec:
    """The :class:`PlateSpec` of plate ``name`` (``'grid'`` or ``'moving'``) of a validated ``meta.json``."""
    p = meta["plates"][name]
    dots = p.get("dots")
    levels = int(p.get("levels", 2 if p.get("level_offset_mm") is not None else 1))
    origin = p.get("marker_origin", [2, 2])
    return PlateSpec(name, None if p.get("rows") is None else int(p["rows"]),
                     None if p.get("cols") is None else int(p["cols"]), float(p["pitch_mm"]),
                     None if dots is None else dots == "dark", p.get("pattern", "dots"), levels,
                     None if p.get("level_offset_mm") is None else float(p["level_offset_mm"]),
                     (int(origin[0]), int(origin[1])), dict(p.get("board", {})))


def check_extractable(meta: dict, spec: PlateSpec, path: Path) -> None:
    """What only finding a plate in images needs, which :func:`slmlab.io.read_meta` leaves to extraction (a set
    whose ``points.csv`` is given does without): ``dot_diameter_mm`` of a dot plate, a ChArUco board's
    ``board`` (:func:`slmlab.images.boards.charuco_board`). ``path``: the ``meta.json``, named in the message."""
    if spec.pattern == "dots" and meta["plates"][spec.name].get("dot_diameter_mm") is None:
        raise SlmlabError(f"plates.{spec.name}.dot_diameter_mm is missing; extracting dots from images needs it: "
                          "give the dots' diameter in mm", path)
    if spec.pattern == "charuco":
        charuco_board(spec, path)


@dataclass(frozen=True)
class ImagePair:
    """One stage position of a sequence and its two images (``None`` where a view has no image)."""

    sequence: str
    position: int
    stage_mm: tuple[float, float, float]
    left: Path | None
    right: Path | None
    source: str  # where the pair was named (for messages): 'stage.csv row k' or 'images/'


# ------------------------------------------------------------------------------------------- the set's images
def _stage_table(path: Path) -> pd.DataFrame:
    """``stage.csv``, validated like ``points.csv`` (every bad cell named by row and column)."""
    df = read_csv_text(path, STAGE_FILE)
    require_columns(df, ["sequence", "position", *STAGE_COLUMNS], path, STAGE_FILE)
    out = sequence_position_stage(df, path)
    named = [c for c in ("left_image", "right_image") if c in df.columns]
    if len(named) == 1:   # a misspelled header would leave a view without images and say nothing
        other = ({"left_image", "right_image"} - set(named)).pop()
        raise SlmlabError(f"has {named[0]} but no {other} column; give both (leave a cell empty where a view has "
                          "no image)", path)
    for c in named:
        out[c] = df[c].astype(str).str.strip()
    dup = out.duplicated(["sequence", "position"], keep="first")
    if dup.any():
        k = int(np.flatnonzero(dup.to_numpy())[0])
        raise SlmlabError(f"row {k + 2}: sequence {out['sequence'][k]}, position {out['position'][k]} appears twice; "
                          "give each stage position one row", path)
    return out


def image_pairs(set_dir: str | Path) -> list[ImagePair]:
    """The stereo pairs of a set: from ``stage.csv``'s ``left_image, right_image`` columns if it has them,
    else from ``images/`` (simulated sets' names) with the stage positions of ``points.csv`` or
    ``stage.csv``."""
    set_dir = Path(set_dir)
    stage_file = set_dir / STAGE_FILE
    stage = _stage_table(stage_file) if stage_file.exists() else None
    if stage is not None and {"left_image", "right_image"} & set(stage.columns):
        pairs = []
        for k, r in enumerate(stage.itertuples(index=False)):
            paths = []
            for col in ("left_image", "right_image"):
                name = getattr(r, col, "")
                name = "" if name is None or str(name).lower() in ("", "nan", "none") else str(name)
                paths.append(set_dir / name if name else None)
            if paths == [None, None]:
                raise SlmlabError(f"row {k + 2}: no left_image or right_image; name at least one image", stage_file)
            pairs.append(ImagePair(r.sequence, int(r.position), (r.stage_x_mm, r.stage_y_mm, r.stage_z_mm),
                                   paths[0], paths[1], f"{STAGE_FILE} row {k + 2}"))
        return pairs
    images = set_dir / "images"
    if not images.is_dir():
        raise SlmlabError("has no images: give stage.csv with left_image and right_image columns (images as a "
                          "camera wrote them), or an images/ folder of {sequence}_{position:03d}_{l|r}.png "
                          "('simulate --images' renders one)", set_dir)
    files = sorted(p for p in images.iterdir() if IMAGE_NAME.match(p.name))
    if not files:
        raise SlmlabError("images/ holds no file named {sequence}_{position:03d}_{l|r}.png; or name the images "
                          "in stage.csv (left_image, right_image)", images)
    if (set_dir / "points.csv").exists():
        stage = read_set(set_dir).points[["sequence", "position", *STAGE_COLUMNS]]
        where = set_dir / "points.csv"
    elif stage is not None:
        where = stage_file
    else:
        raise SlmlabError("needs the stage positions: a points.csv to re-extract, or stage.csv with sequence, "
                          "position, stage_x_mm, stage_y_mm, stage_z_mm", set_dir)
    stage = stage.drop_duplicates(["sequence", "position"]).set_index(["sequence", "position"])
    found: dict[tuple[str, int], dict[str, Path]] = {}
    for f in files:
        m = IMAGE_NAME.match(f.name)
        found.setdefault((m["sequence"], int(m["position"])), {})[m["side"]] = f
    pairs = []
    for (seq, pos), sides in sorted(found.items()):
        if (seq, pos) not in stage.index:
            raise SlmlabError(f"no stage position for sequence {seq}, position {pos} (image {next(iter(sides.values())).name})",
                              where)
        st = stage.loc[(seq, pos)]
        pairs.append(ImagePair(seq, pos, tuple(float(st[c]) for c in STAGE_COLUMNS), sides.get("l"), sides.get("r"), "images/"))
    return pairs


# ------------------------------------------------------------------------------------------- extraction
@dataclass
class _Found:
    pair: ImagePair
    side: str
    path: Path
    dots: ImageDots
    spec: PlateSpec


def _integer_map(table: pd.DataFrame, src: tuple[str, str], dst: tuple[str, str]) -> np.ndarray | None:
    """The integer affine map ``(2, 3)`` taking columns ``src`` to ``dst`` on a table where it is exact."""
    if len(table) < 3:
        return None
    a = np.column_stack([table[src[0]], table[src[1]], np.ones(len(table))]).astype(float)
    b = table[list(dst)].to_numpy(float)
    if np.linalg.matrix_rank(a) < 3:  # collinear dots: no unique map
        return None
    sol, *_ = np.linalg.lstsq(a, b, rcond=None)
    m = np.rint(sol.T)
    return m if np.allclose(a @ m.T, b) else None


def extract_set(set_dir: str | Path, *, method: str = "auto", progress: bool | None = None
                ) -> tuple[pd.DataFrame, list[str]]:
    """Extract every image of a set into the rows of ``points.csv`` (module docstring).

    ``method``: the centre estimator of dot plates (one of :data:`slmlab.images.centres.METHODS`, or
    ``'auto'``: chosen per plate and view on its first image by :func:`slmlab.images.extract.choose_method`,
    and named in the notes; where that is the model ``fit``, an image on which it loses dots is taken by the
    runner-up, :func:`_fit_or`, and where the fit was tried but not chosen, an image on which the chosen estimator
    drops dots the fit keeps is taken by the fit, :func:`_or_fit`).

    Returns the points table (``POINT_COLUMNS``; plus ``x_mm, y_mm, z_mm`` for plates anchored by markers and
    ``level`` for two-level plates) and notes: how each plate's numbering was anchored, what the images'
    reports found and rejected per plate and view, views without an image. Raises :class:`SlmlabError` before anything is written.
    """
    set_dir = Path(set_dir)
    if not set_dir.is_dir():
        raise SlmlabError("calibration set folder not found; give the folder that holds meta.json and the images",
                          set_dir)
    meta = read_meta(set_dir / "meta.json")
    pairs = image_pairs(set_dir)
    specs = {}
    for pr in pairs:
        name = "grid" if pr.sequence == "grid" else "moving"
        if name not in meta["plates"]:
            raise SlmlabError(f"sequence {pr.sequence} needs plates.{name} in meta.json", set_dir / "meta.json")
        if name not in specs:
            specs[name] = plate_spec(meta, name)
            check_extractable(meta, specs[name], set_dir / "meta.json")
    notes: list[str] = []
    for pr in pairs:
        for side, path in (("l", pr.left), ("r", pr.right)):
            if path is None:
                notes.append(f"{pr.sequence} position {pr.position}: no {'left' if side == 'l' else 'right'} image")
    found = _find_in_images(pairs, specs, tuple(meta["image_size_px"]), method, progress, notes)
    _number_unanchored(found, notes)
    known_target = _one_numbering(found, specs, notes, set_dir)
    return _points_table(pairs, found, specs, known_target, set_dir), notes


def _find_in_images(pairs: list[ImagePair], specs: dict, image_size: tuple, method: str, progress, notes: list
                    ) -> list[_Found]:
    """Phase 1: every image read (one size for the set, the size ``meta.json`` gives) and its dots or board
    corners found and, where the image itself allows, numbered; the centre estimator chosen per plate and view
    on its first image where ``method`` is ``'auto'`` (the model fit checked on every image, :func:`_fit_or`)."""
    found: list[_Found] = []
    todo = [(pr, side, path) for pr in pairs for side, path in (("l", pr.left), ("r", pr.right)) if path is not None]
    chosen: dict[tuple[str, str], str] = {}
    runner_up: dict[tuple[str, str], str] = {}
    fit_tried: set[tuple[str, str]] = set()
    images = _Images(image_size)
    hot, counts = _camera_hot(todo, specs, images)
    for side, mask in hot.items():
        if mask.any():
            notes.append(f"{_VIEW[side]} camera: {int(mask.sum())} hot pixel(s) stand out in at least "
                         f"{hot_images_needed(counts[side])} of its {counts[side]} images of dots; "
                         "replaced in those images, inside the dots too (where the dots are found and at least 2.5 px "
                         "in radius)")
    for pr, side, path in tqdm(todo, desc="extracting", unit="image", disable=None if progress is None else not progress):
        img = images.read(path)
        spec = _spec(specs, pr)
        if spec.pattern == "dots":
            kw = dict(dark=spec.dark, marker_origin=spec.marker_origin, two_level=spec.levels == 2, camera_hot=hot[side])
            if method == "auto" and (spec.name, side) not in chosen:
                chosen[(spec.name, side)], res, dots, runner_up[(spec.name, side)] = choose_method(
                    img, spec.rows, spec.cols, **kw)
                if np.isfinite(res.get("fit", np.nan)):
                    fit_tried.add((spec.name, side))
                notes.append(f"plate {spec.name}, {_VIEW[side]} view: centres by {chosen[(spec.name, side)]} "
                             "(lattice residual " + ", ".join(f"{v:.3f} px by {k}" for k, v in res.items())
                             + f", on {path.name})")
            elif method == "auto" and chosen[(spec.name, side)] == "fit":
                dots = _fit_or(img, spec, runner_up[(spec.name, side)], kw, path, notes)
            elif method == "auto" and (spec.name, side) in fit_tried:
                dots = _or_fit(img, spec, chosen[(spec.name, side)], kw, path, notes)
            else:
                dots = extract_image(img, spec.rows, spec.cols, method=chosen.get((spec.name, side), method), **kw)
        else:
            dots = detect_board(img, spec)
        if dots.found == 0:
            what = "dots" if spec.pattern == "dots" else f"{spec.pattern} corners"
            hint = ("check plates.{0}.dots (dark or bright) in meta.json, the focus and exposure"
                    if spec.pattern == "dots" else "check plates.{0} (pattern, size, board) in meta.json and the focus")
            raise SlmlabError(f"no {what} found ({pr.source}); {hint.format(spec.name)}, or leave the image out", path)
        found.append(_Found(pr, side, path, dots, spec))
    _report_notes(found, notes)
    return found


_VIEW = {"l": "left", "r": "right"}


class _Images:
    """A set's images as extraction reads them: each checked against ``meta.json``'s ``image_size_px`` (the
    first read against it, the rest as one size for the set); an image read with ``keep`` is held for the
    next read of it, up to :data:`KEEP_IMAGES_BYTES` in all (the rest are read again)."""

    def __init__(self, image_size: tuple):
        self.size, self.first, self.kept, self.held = tuple(image_size), True, {}, 0

    def read(self, path: Path, keep: bool = False) -> np.ndarray:
        if path in self.kept:
            img = self.kept.pop(path)
            self.held -= img.nbytes
            return img
        img = read_image(path)
        w, h = self.size
        if (img.shape[1], img.shape[0]) != (w, h):
            why = (f"meta.json's image_size_px is {w} × {h}; correct image_size_px" if self.first else
                   f"the other images are {w} × {h} px; all images of a set must have one size")
            raise SlmlabError(f"is {img.shape[1]} × {img.shape[0]} px but {why}", path)
        self.first = False
        if keep and self.held + img.nbytes <= KEEP_IMAGES_BYTES:
            self.kept[path] = img
            self.held += img.nbytes
        return img


def _spec(specs: dict, pr: ImagePair) -> PlateSpec:
    """The plate an image pair shows: the static grid's, or the moving plate's."""
    return specs["grid" if pr.sequence == "grid" else "moving"]


def _camera_hot(todo: list, specs: dict, images: _Images) -> tuple[dict, dict]:
    """Each camera's hot pixels (a mask, :func:`slmlab.images.dots.camera_hot_pixels`) from its images of dot
    plates, each read once for it (and kept for its extraction), and how many images that was per camera: a pixel
    that stands out in three quarters of them is the sensor's, and is replaced in each, inside the dots too (one
    image alone cannot tell a hot pixel on a dot from the dot's texture)."""
    flagged: dict[str, dict] = {"l": {}, "r": {}}
    for pr, side, path in todo:
        if _spec(specs, pr).pattern == "dots" and path not in flagged[side]:
            flagged[side][path] = hot_pixel_flags(images.read(path, keep=True))
    hot = {side: camera_hot_pixels(list(f.values()), images.size[::-1]) for side, f in flagged.items()}
    return hot, {side: len(f) for side, f in flagged.items()}


def _fit_or(img: np.ndarray, spec: PlateSpec, other: str, kw: dict, path: Path, notes: list) -> ImageDots:
    """An image of a view whose centres are by the model ``fit`` (chosen on its first image): the fit's dots,
    unless it lost more than :data:`slmlab.images.extract.AUTO_FIT_SLACK` of the dots the ``other`` estimator
    keeps (the rule's choice without the fit on the first image, :class:`slmlab.images.extract.Choice`): a
    narrow window streak across some dots of one image can throw their fits off the lattice (stereo-piv:4's
    streaks: 17 of 441 dots lost, 0.12 px RMS against the edge fit's 0.066 on the dots kept); then that image
    is the other's, and a note says so."""
    both = extract_image_methods(img, spec.rows, spec.cols, methods=("fit", other), **kw)
    if len(both["fit"].table) >= len(both[other].table) - AUTO_FIT_SLACK:
        return both["fit"]
    notes.append(f"plate {spec.name}: centres by {other} on {path.name} (the fit lost "
                 f"{len(both[other].table) - len(both['fit'].table)} of its dots)")
    return both[other]


def _or_fit(img: np.ndarray, spec: PlateSpec, chosen: str, kw: dict, path: Path, notes: list) -> ImageDots:
    """An image of a view whose centres are by ``chosen``, not the model fit, where the fit was tried on its first
    image (an uneven background, or textured dots): the chosen estimator's dots, unless it dropped some as off the
    lattice after refinement and the fit keeps more dots (:func:`_fit_or`'s mirror; a dot half in a clipped window
    streak is pulled off the lattice by the estimators that flatten on a ring, not by the fit, which censors the
    clipped pixels: greenough:7201, two dots of one image 0.5 px off by the ellipse fits, placed by the fit); then
    that image is the fit's, and a note says so."""
    dots = extract_image(img, spec.rows, spec.cols, method=chosen, **kw)
    if not dots.report["reason"].str.contains("off the lattice after refinement", regex=False).any():
        return dots
    fit = extract_image(img, spec.rows, spec.cols, method="fit", **kw)
    if len(fit.table) <= len(dots.table):
        return dots
    notes.append(f"plate {spec.name}: centres by fit on {path.name} ({chosen} lost "
                 f"{len(fit.table) - len(dots.table)} of its dots off the lattice)")
    return fit


def _report_notes(found: list[_Found], notes: list) -> None:
    """One note per dot plate and view: what the images' reports (:attr:`ImageDots.report`) found and
    rejected, and why (:func:`slmlab.images.extract.report_summary`)."""
    groups: dict[tuple[str, str], list[_Found]] = {}
    for f in found:
        if f.spec.pattern == "dots":
            groups.setdefault((f.spec.name, f.side), []).append(f)
    for (name, side), fs in groups.items():
        rep = pd.concat([f.dots.report for f in fs], ignore_index=True)
        hot, noise = sum(f.dots.hot_pixels for f in fs), sum(f.dots.noise_blobs for f in fs)
        notes.append(f"plate {name}, {_VIEW[side]} view, {len(fs)} image(s): {report_summary(rep)}; "
                     f"{noise} one-level noise blobs ignored and {hot} hot pixels replaced")


def _numbered_alone(found: list[_Found]) -> dict[tuple[str, str], list[Numbered]]:
    """The images numbered alone (dot plates), per plate and view, as :class:`slmlab.images.tracking.Numbered`
    (those whose lattice indices map to the numbering by an exact integer affine map)."""
    out: dict[tuple[str, str], list[Numbered]] = {}
    for f in found:
        if f.dots.frame is None or f.spec.pattern != "dots" or f.dots.lattice is None:
            continue
        m = _integer_map(f.dots.table, ("i1", "i2"), _SET_COLUMNS[f.dots.frame])
        if m is not None:
            out.setdefault((f.spec.name, f.side), []).append(Numbered(f.path.name, np.asarray(f.pair.stage_mm, float),
                                                                      f.dots.lattice, m, f.dots.frame))
    return out


_SET_COLUMNS = {"origin": ("xu", "yu"), "plate": ("row", "col")}


def _tracked_table(f: _Found, shift: np.ndarray, ref: Numbered) -> pd.DataFrame:
    """``f``'s dots numbered by its lattice indices shifted by ``shift`` and ``ref``'s map to the set's
    numbering."""
    frame = ref.frame
    t = f.dots.table.copy()
    t["i1"] += shift[0]
    t["i2"] += shift[1]
    cols = _SET_COLUMNS[frame]
    mapped = np.column_stack([t["i1"], t["i2"], np.ones(len(t))]) @ ref.to_set.T
    t[cols[0]], t[cols[1]] = np.rint(mapped[:, 0]).astype(int), np.rint(mapped[:, 1]).astype(int)
    if frame == "origin":
        t["row"], t["col"] = -t["yu"], -t["xu"]
        if f.spec.levels == 2:
            t["level"] = (t["xu"] % 2).astype(int)
    return t


def _number_unanchored(found: list[_Found], notes: list) -> None:
    """Phase 2: images that could not be numbered alone are tracked (:func:`slmlab.images.tracking.track`:
    by the stage motion that the images of the same plate and view numbered alone show); an image whose
    tracking is refused is left out, with why in the notes; how each plate's numbering was anchored goes to
    the notes. Raises :class:`SlmlabError` where no image of a plate could be numbered alone."""
    alone = _numbered_alone(found)
    how: dict[str, dict[str, int]] = {}
    for f in list(found):
        if f.dots.frame is not None:
            how.setdefault(f.spec.name, {}).setdefault(f.dots.how, 0)
            how[f.spec.name][f.dots.how] += 1
            continue
        if not any(g.dots.frame is not None and g.spec.name == f.spec.name for g in found):
            raise SlmlabError(f"cannot number the dots of this image ({f.dots.note or 'no lattice'}; {f.pair.source}): "
                              "give the plate's rows and cols in meta.json if the whole plate is in view, use a plate "
                              "with markers, or image it beside an image that shows them", f.path)
        refs = sorted(alone.get((f.spec.name, f.side), []) if f.spec.pattern == "dots" else [],
                      key=lambda n: float(np.linalg.norm(n.stage_mm - np.asarray(f.pair.stage_mm, float))))
        shift, ref, why = (None, None, f"no {_VIEW[f.side]} image of plate {f.spec.name} was numbered alone"
                           ) if not refs or f.dots.lattice is None else track(f.dots.lattice, f.pair.stage_mm, refs,
                                                                              f.spec.unit_mm)
        if shift is None:
            notes.append(f"{f.pair.sequence} position {f.pair.position}, {_VIEW[f.side]} view ({f.path.name}): "
                         f"left unnumbered ({f.dots.note or 'no lattice'}) and not tracked: {why}")
            found.remove(f)
            continue
        f.dots.table, f.dots.frame = _tracked_table(f, shift, ref), ref.frame
        f.dots.how = f"tracked from {ref.name} {why}"
        how.setdefault(f.spec.name, {}).setdefault(TRACKED, 0)
        how[f.spec.name][TRACKED] += 1
    for name, kinds in how.items():
        total = sum(kinds.values())
        notes.append(f"plate {name}: numbering anchored in {total} image(s) by "
                     + "; ".join(f"{k} ({v})" for k, v in kinds.items()))


def _one_numbering(found: list[_Found], specs: dict, notes: list, set_dir: Path) -> bool:
    """Phase 3: one numbering for the set. Origin-anchored plates are numbered from 1 over all their images
    and get their plate-frame ``x_mm, y_mm, z_mm``. Returns whether the set is a known-target set."""
    known_target = False
    for name, spec in specs.items():
        mine = [f for f in found if f.spec.name == name]
        frames = {f.dots.frame for f in mine}
        if len(frames) > 1:
            raise SlmlabError(f"plate {name}: some images are numbered by the plate's size and others by markers; "
                              "give rows and cols for a plate wholly in view, or leave them out", set_dir / "meta.json")
        if frames == {"origin"}:
            known_target = True
            xu = np.concatenate([f.dots.table["xu"].to_numpy() for f in mine])
            yu = np.concatenate([f.dots.table["yu"].to_numpy() for f in mine])
            x_max, y_max = int(xu.max()), int(yu.max())
            for f in mine:
                t = f.dots.table
                t["col"], t["row"] = x_max - t["xu"] + 1, y_max - t["yu"] + 1
                t["x_mm"], t["y_mm"] = t["xu"] * spec.unit_mm, t["yu"] * spec.unit_mm
                if spec.levels == 2:
                    offset = np.nan if spec.level_offset_mm is None else spec.level_offset_mm
                    t["z_mm"] = np.where(t["level"] == 1, offset, 0.0)
                else:
                    t["z_mm"] = 0.0
            if spec.levels == 2 and spec.level_offset_mm is None:
                notes.append(f"plate {name}: two levels but no level_offset_mm in meta.json; the second level's "
                             "dots have no z_mm and are left out of calibrations until it is given")
        elif frames == {"board"}:
            known_target = True
    return known_target


def _points_table(pairs: list[ImagePair], found: list[_Found], specs: dict, known_target: bool, set_dir: Path
                  ) -> pd.DataFrame:
    """Phase 4: one row per (sequence, position, dot), both views merged on the dot's numbering."""
    extra = ["x_mm", "y_mm", "z_mm"] if known_target else []
    levels = any(s.levels == 2 for s in specs.values())
    frames_out = []
    by_pair: dict[tuple[str, int], dict[str, _Found]] = {}
    for f in found:
        by_pair.setdefault((f.pair.sequence, f.pair.position), {})[f.side] = f
    for pr in pairs:
        sides = by_pair.get((pr.sequence, pr.position), {})
        spec = _spec(specs, pr)
        merged = None
        for side in "lr":
            if side not in sides:
                continue
            t = sides[side].dots.table
            keep = ["row", "col", "w1", "w2"] + [c for c in (*extra, "level") if c in t.columns]
            t = t[keep].rename(columns={"w1": f"w{side}1", "w2": f"w{side}2"})
            merged = t if merged is None else merged.merge(t, on=[c for c in keep if c not in ("w1", "w2")],
                                                           how="outer")
        if merged is None:
            continue
        for c in IMAGE_COLUMNS:
            if c not in merged.columns:
                merged[c] = np.nan
        if spec.rows is not None and spec.cols is not None and spec.pattern == "dots":
            merged = merged[merged["row"].between(1, spec.rows) & merged["col"].between(1, spec.cols)]
        merged.insert(0, "sequence", pr.sequence)
        merged.insert(1, "position", pr.position)
        for c, v in zip(STAGE_COLUMNS, pr.stage_mm):
            merged[c] = float(v)
        cols = POINT_COLUMNS + [c for c in extra if c in merged.columns] + (["level"] if levels and "level" in merged.columns else [])
        frames_out.append(merged.sort_values(["row", "col"], kind="stable")[cols])
    if not frames_out:
        raise SlmlabError("no dots were extracted from any image", set_dir)
    points = pd.concat(frames_out, ignore_index=True)
    points = points[points[IMAGE_COLUMNS].notna().any(axis=1)].reset_index(drop=True)
    points[["row", "col"]] = points[["row", "col"]].astype(int)
    return points
