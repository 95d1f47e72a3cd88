"""Held-out folds of a calibration set and the held-out error of a model on them.

A calibration's error is the error a user will see: on new dots and new positions *inside* the calibrated
volume. The folds hold out rows of the calibration set itself (never test data): positions (planes of a Z
stack), dots, or both crossed, and :func:`held_out_errors` fits a model on the rest and measures it on them.
Used by the default model's choice (:mod:`slmlab.models.auto`), the direct model's degree and the Soloff
model's degrees.
"""

from __future__ import annotations

import numpy as np

from ..io import IMAGE_COLUMNS, CalibrationSet
from ..linefit import point_keys
from .base import get_model_class
from .frames import world_positions

__all__ = ["LEAVE_ONE_OUT_MAX", "DOT_FOLDS", "position_folds", "row_folds", "dot_folds", "held_out_errors"]


#: sequences with at most this many positions are cross-validated one position at a time
LEAVE_ONE_OUT_MAX = 8


#: dots are held out one fifth at a time
DOT_FOLDS = 5


def position_folds(pts) -> list[np.ndarray]:
    """Boolean masks of held-out positions (module docstring, step 1)."""
    seq_pos = pts.groupby("sequence")["position"].nunique()
    pos = pts["position"].to_numpy()
    if seq_pos.max() <= LEAVE_ONE_OUT_MAX:  # interior positions one at a time: a calibration is used within
        seq = pts["sequence"].astype(str).to_numpy()  # its range, so its ends always calibrate
        first = pts.groupby("sequence")["position"].transform("min").to_numpy()
        last = pts.groupby("sequence")["position"].transform("max").to_numpy()
        interior = (pos > first) & (pos < last)
        keys = np.char.add(np.char.add(seq, ":"), pos.astype(str))
        folds = [keys == k for k in sorted(set(keys[interior]))]
        return folds or [keys == k for k in sorted(set(keys))]
    return [m for m in (pos % 3 == r for r in range(3)) if m.any() and (~m).any()]


def row_folds(pts, mode: str, *, diagonal: bool = False) -> list[tuple[np.ndarray, np.ndarray]]:
    """``(train, test)`` row masks of the held-out fits (module docstring, step 1).

    With stage moves of a plate whose place is unknown (``mode == "moves"``) whole positions are held out:
    a new dot's offset could not be known. Where the dots' world positions are known (a Z stack, a known
    target) the folds are **crossed**: the test rows are at held-out positions *and* held-out dots (every
    fifth dot, :func:`dot_folds`), and the training rows at neither. Every plane of a Z stack shows the same dots, so holding
    out planes alone would never test the map between the dots; a polynomial that overfits across the
    field passes such a test (on the PIV Challenge picks, a 16-dot lattice, it put dots half a pitch away
    0.7 mm off in depth). A target in one pose holds out dots only."""
    key = dot_folds(pts)
    if pts.groupby("sequence")["position"].nunique().min() < 2:
        out = [(key != r, key == r) for r in range(DOT_FOLDS)]
    elif mode == "moves":
        out = [(~m, m) for m in position_folds(pts)]
    else:
        held = position_folds(pts)
        if len(held) <= 3 and not diagonal:  # few held-out positions: each with each fifth of the dots
            out = [(~p & (key != r), p & (key == r)) for p in held for r in range(DOT_FOLDS)]
        else:  # many (or ``diagonal``): one fifth of the dots per position fold, in turn
            out = [(~p & (key != k % DOT_FOLDS), p & (key == k % DOT_FOLDS)) for k, p in enumerate(held)]
    return [(tr, te) for tr, te in out if tr.any() and te.any()]


def dot_folds(pts) -> np.ndarray:
    """The fold of each row's dot, ``(row + 2·col) mod 5``: a knight's-move pattern, so that each fold's dots
    are spread over the whole field (not in stripes) and four fifths of them always calibrate."""
    return (pts["row"].to_numpy(np.int64) + 2 * pts["col"].to_numpy(np.int64)) % DOT_FOLDS


def held_out_errors(cal: CalibrationSet, name: str, options: dict | None = None, folds=None) -> np.ndarray:
    """Held-out RMS [mm] per coordinate of model ``name`` on ``cal`` (module docstring, step 2); ``folds``:
    ``(train, test)`` row masks (default :func:`row_folds`)."""
    pts, world, mode = world_positions(cal, (options or {}).get("mode", "auto"))
    folds = row_folds(pts, mode) if folds is None else folds
    cls = get_model_class(name)
    errs = []
    for train_rows, held in folds:
        train = CalibrationSet(pts[train_rows].copy(), cal.meta, path=cal.path)
        model = cls.fit(train, **(options or {}))
        w = pts[held][IMAGE_COLUMNS].to_numpy(float)
        e = model.reconstruct(w) - world[held]
        if mode == "moves":  # one offset per dot and sequence, from the training positions
            wt = pts[train_rows][IMAGE_COLUMNS].to_numpy(float)
            off = model.reconstruct(wt) - world[train_rows]
            tr = pts[train_rows]
            key_t = point_keys(tr["row"], tr["col"]).astype(str) + tr["sequence"].to_numpy()
            key_h = point_keys(pts[held]["row"], pts[held]["col"]).astype(str) + pts[held]["sequence"].to_numpy()
            lookup = {k: off[key_t == k].mean(axis=0) for k in np.unique(key_h) if (key_t == k).any()}
            known = np.array([k in lookup for k in key_h])
            e = e[known] - np.array([lookup[k] for k in key_h[known]]).reshape(-1, 3)
        else:
            e = e - np.median(e, axis=0)
        errs.append(e)
    e = np.vstack(errs)
    return np.sqrt(np.mean(e ** 2, axis=0))
