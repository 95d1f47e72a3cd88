"""Calibration targets that OpenCV detects itself: chessboards, circle grids and ChArUco boards.

Where OpenCV has the detector, slmlab uses it (:func:`detect_board`) and only turns its output into the
interchange format:

``chessboard``
    inner corners ``rows × cols`` of a chessboard of square ``pitch_mm``: ``cv2.findChessboardCornersSB``
    (the sector-based detector, sub-pixel accurate by design), else ``cv2.findChessboardCorners`` refined by
    ``cv2.cornerSubPix``.
``circles``, ``asymmetric-circles``
    ``cv2.findCirclesGrid`` (symmetric or asymmetric grid), with a blob detector set for the plate's polarity.
``charuco``
    a ChArUco board (``cv2.aruco.CharucoDetector``): a chessboard whose white squares carry ArUco markers, so
    that every corner is numbered by the board itself, in every view, however much of the board is seen.
    Stereo-microscope labs use them for that reason (e.g. Pycaso on a Leica CMO microscope). The plate's
    ``board`` gives ``squares`` ``[x, y]``, ``marker_mm``, ``dictionary`` (an OpenCV name such as
    ``"DICT_6X6_250"``) and ``legacy`` (the layout of OpenCV before 4.6, where the first square is black).

Chessboards and circle grids are symmetric under a half turn: their corners are ordered so that ``[1, 1]``
is the one nearest the image's top left and rows run along ``+w1``, the same rule in both views. ChArUco
corner ``k`` of a board of ``x`` squares across is ``[k // (x − 1) + 1, k % (x − 1) + 1]``, at the board's
own coordinates (``x_mm`` along its rows, ``y_mm`` up the board, ``z_mm = 0``): a known-target set.
"""

from __future__ import annotations

import cv2
import numpy as np
import pandas as pd

from ..errors import SlmlabError
from .dots import as_8bit, dot_polarity, read_image
from .extract import ImageDots, empty_dots_table

__all__ = ["detect_board", "charuco_board", "chessboard_views", "DICTIONARIES"]

DICTIONARIES = sorted(n for n in dir(cv2.aruco) if n.startswith("DICT_"))


def charuco_board(spec, path=None) -> "cv2.aruco.CharucoBoard":
    """The OpenCV ChArUco board of a plate spec (lengths in mm). Only detection needs it, so its details are
    checked here (``path``: the ``meta.json`` to name in the message), not when a set of points is read.
    ``dictionary`` defaults to ``DICT_6X6_250``, ``marker_mm`` to 0.7 of the square."""
    b = spec.board
    if not b:
        raise SlmlabError(f"plates.{spec.name} is a ChArUco board: detecting it in images needs plates.{spec.name}"
                          ".board = {squares: [x, y], marker_mm, dictionary, legacy}", path)
    name = str(b.get("dictionary", "DICT_6X6_250"))
    if name not in DICTIONARIES:
        raise SlmlabError(f"plates.{spec.name}.board.dictionary {name!r} is not an OpenCV ArUco dictionary; "
                          f"use one of {', '.join(DICTIONARIES[:6])}, ...", path)
    squares = b.get("squares")
    if not (isinstance(squares, (list, tuple)) and len(squares) == 2
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) and v >= 2 and float(v).is_integer()
                    for v in squares)):
        raise SlmlabError(f"plates.{spec.name}.board.squares must be [x, y], the board's squares across and down",
                          path)
    marker = b.get("marker_mm", 0.7 * spec.pitch_mm)
    if not (isinstance(marker, (int, float)) and not isinstance(marker, bool) and 0 < marker < spec.pitch_mm):
        raise SlmlabError(f"plates.{spec.name}.board.marker_mm must be positive and smaller than pitch_mm", path)
    marker = float(marker)
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))
    board = cv2.aruco.CharucoBoard((int(squares[0]), int(squares[1])), spec.pitch_mm, marker, dictionary)
    board.setLegacyPattern(bool(b.get("legacy", False)))
    return board


def _empty(note: str) -> ImageDots:
    return ImageDots(empty_dots_table(), 0, 0, 0, note)


def _grid_table(corners: np.ndarray, rows: int, cols: int) -> pd.DataFrame:
    """Corners ``(rows·cols, 2)`` in OpenCV's order, reordered by the half-turn rule (module docstring)."""
    g = corners.reshape(rows, cols, 2)
    if g[0, -1, 0] < g[0, 0, 0]:
        g = g[:, ::-1]
    if g[-1, 0, 1] < g[0, 0, 1]:
        g = g[::-1]
    r, c = np.meshgrid(np.arange(1, rows + 1), np.arange(1, cols + 1), indexing="ij")
    return pd.DataFrame({"i1": c.ravel() - 1, "i2": r.ravel() - 1, "w1": g[:, :, 0].ravel(), "w2": g[:, :, 1].ravel(),
                         "marker": False, "level": 0, "row": r.ravel(), "col": c.ravel()})


def detect_board(img: np.ndarray, spec) -> ImageDots:
    """Detect a board (``spec.pattern``: ``chessboard``, ``circles``, ``asymmetric-circles`` or
    ``charuco``) in one image of any bit depth. Returns :class:`slmlab.images.extract.ImageDots`: ``frame``
    ``'plate'`` for chessboards and symmetric grids (their rows and cols number them), ``'board'`` for
    ChArUco boards and asymmetric grids (with ``x_mm, y_mm, z_mm``); ``found`` is 0 where nothing was found."""
    img8 = as_8bit(img)
    pattern = spec.pattern
    if pattern in ("chessboard", "circles", "asymmetric-circles"):
        if spec.rows is None or spec.cols is None:
            raise SlmlabError(f"plates.{spec.name}: a {pattern} needs rows and cols (inner corners or circles)")
        size = (spec.cols, spec.rows)
    if pattern == "chessboard":
        ok, corners = cv2.findChessboardCornersSB(img8, size, flags=cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_EXHAUSTIVE)
        if not ok:
            ok, corners = cv2.findChessboardCorners(img8, size, flags=cv2.CALIB_CB_ADAPTIVE_THRESH
                                                    | cv2.CALIB_CB_NORMALIZE_IMAGE)
            if ok:
                crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)
                corners = cv2.cornerSubPix(img8, corners, (11, 11), (-1, -1), crit)
        if not ok:
            return _empty(f"OpenCV found no {spec.cols} × {spec.rows} chessboard")
        t = _grid_table(corners.reshape(-1, 2).astype(float), spec.rows, spec.cols)
        return ImageDots(t, len(t), 0, 0, "", None, "plate", "OpenCV's chessboard detector")
    if pattern in ("circles", "asymmetric-circles"):
        dark = spec.dark if spec.dark is not None else dot_polarity(img)
        params = cv2.SimpleBlobDetector_Params()
        params.blobColor = 0 if dark else 255
        params.filterByArea, params.minArea, params.maxArea = True, 10, 0.05 * img8.size
        det = cv2.SimpleBlobDetector_create(params)
        flags = cv2.CALIB_CB_SYMMETRIC_GRID if pattern == "circles" else cv2.CALIB_CB_ASYMMETRIC_GRID
        ok, centres = cv2.findCirclesGrid(img8, size, flags=flags, blobDetector=det)
        if not ok:
            return _empty(f"OpenCV found no {spec.cols} × {spec.rows} {pattern} grid")
        c = centres.reshape(-1, 2).astype(float)
        if pattern == "circles":
            t = _grid_table(c, spec.rows, spec.cols)
            return ImageDots(t, len(t), 0, 0, "", None, "plate", "OpenCV's circle-grid detector", dark=dark)
        # asymmetric: OpenCV's layout, circle (i, j) at ((2j + i % 2)·p/2, i·p/2); i is the row
        i, j = np.divmod(np.arange(len(c)), spec.cols)
        t = pd.DataFrame({"i1": 2 * j + i % 2, "i2": i, "w1": c[:, 0], "w2": c[:, 1], "marker": False, "level": 0,
                          "row": i + 1, "col": 2 * j + i % 2 + 1, "x_mm": (2 * j + i % 2) * spec.pitch_mm / 2,
                          "y_mm": -i * spec.pitch_mm / 2, "z_mm": 0.0})
        return ImageDots(t, len(t), 0, 0, "", None, "board", "OpenCV's circle-grid detector", dark=dark)
    if pattern == "charuco":
        board = charuco_board(spec)
        detector = cv2.aruco.CharucoDetector(board)
        corners, ids, _, marker_ids = detector.detectBoard(img8)
        if ids is None or len(ids) == 0:
            inverted = detector.detectBoard(255 - img8)  # a board printed bright on dark
            corners, ids = inverted[0], inverted[1]
        if ids is None or len(ids) == 0:
            return _empty("OpenCV found no ChArUco corner")
        ids = ids.ravel().astype(int)
        c = corners.reshape(-1, 2).astype(float)
        per_row = int(board.getChessboardSize()[0]) - 1
        xyz = np.asarray(board.getChessboardCorners(), float)[ids]
        r, k = np.divmod(ids, per_row)
        t = pd.DataFrame({"i1": k, "i2": r, "w1": c[:, 0], "w2": c[:, 1], "marker": False, "level": 0,
                          "row": r + 1, "col": k + 1, "x_mm": xyz[:, 0], "y_mm": -xyz[:, 1], "z_mm": 0.0})
        t = t.sort_values(["row", "col"]).reset_index(drop=True)
        return ImageDots(t, len(t), 0, 0, "", None, "board", "the ChArUco board's own marker ids")
    raise SlmlabError(f"plates.{spec.name}.pattern {pattern!r} is not one of dots, chessboard, circles, "
                      "asymmetric-circles, charuco")


def chessboard_views(pairs: list[tuple[str, str]], pattern=(9, 6), square: float = 1.0) -> tuple[list[dict], tuple]:
    """Planar views from stereo chessboard images (OpenCV's sample): inner corners by
    ``cv2.findChessboardCorners`` refined by ``cv2.cornerSubPix``; pairs where either view fails are skipped."""
    objp = np.zeros((pattern[0] * pattern[1], 3), np.float32)
    objp[:, :2] = np.mgrid[0:pattern[0], 0:pattern[1]].T.reshape(-1, 2) * square
    views, size = [], None
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.001)
    for left, right in pairs:
        pts = {}
        for side, path in (("l", left), ("r", right)):
            img = read_image(path)
            size = (img.shape[1], img.shape[0])
            ok, c = cv2.findChessboardCorners(img, pattern)
            if not ok:
                break
            pts[side] = cv2.cornerSubPix(img, c, (11, 11), (-1, -1), crit).reshape(-1, 2)
        if len(pts) == 2:
            views.append({"sequence": "chessboard", "position": len(views) + 1, "obj": objp, **pts})
    return views, size
