"""Held-out folds of a calibration set and the held-out error of a model on them.

A calibration's error is the error a user will see: on new dots and new positions *inside* the calibrated
volume. The folds hold out rows of the calibration set itself (never test data): positions (planes of a Z
stack), dots, or both crossed, and :func:`held_out_errors` fits a model on the rest and measures it on them.
Used by the default model's choice (:mod:`slmlab.models.auto`), the direct model's degree and the Soloff
model's degrees.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy.spatial import cKDTree

from ..errors import SlmlabError
from ..io import IMAGE_COLUMNS, CalibrationSet
from ..linefit import point_keys
from .base import get_model_class
from .frames import levels, world_positions

__all__ = ["LEAVE_ONE_OUT_MAX", "DOT_FOLDS", "PLANES_FOR_PLANE_FOLDS", "position_folds", "row_folds", "dot_folds",
           "end_planes", "planes_held_out", "fold_description", "position_keys", "held_out_errors", "per_position_offsets",
           "between_depths", "between_arms", "thin_dots"]

#: sequences with at most this many positions are cross-validated one position at a time
LEAVE_ONE_OUT_MAX = 8
#: dots are held out one fifth at a time
DOT_FOLDS = 5
#: a stack (or a known target at several stage positions) has its interior planes held out, crossed with the
#: dots, from this many planes on; with fewer, a model fitted without one of them would be asked something the
#: whole set never asks it (a depth it cannot bend through), so dots are held out within every plane
PLANES_FOR_PLANE_FOLDS = 5


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
    """``(train, test)`` row masks of the held-out fits: what a user will see, inside the calibrated volume.

    * Stage moves of a plate whose place is unknown (``mode == "moves"``): interior positions of each
      sequence (:func:`position_folds`); a new dot's offset could not be known, so dots are not held out.
    * The dots' world positions known (a Z stack, a known target), with at least
      :data:`PLANES_FOR_PLANE_FOLDS` positions per sequence: **crossed** folds, the test rows at held-out
      interior positions *and* held-out dots (every fifth dot, :func:`dot_folds`), the training rows at neither.
      Every plane of a Z stack shows the same dots, so holding out planes alone would never test the map
      between the dots (on the PIV Challenge picks, a 16-dot lattice, a polynomial that overfits across the
      field put dots half a pitch away 0.7 mm off in depth). The end planes, never held out whole where
      interior planes are held out one at a time (:func:`end_planes`), are tested too: each fifth of their dots
      once, in the folds of the first held-out plane (or the first five folds), their plane in the training. A model too stiff in depth misses most at the ends of the stack, which
      interior planes alone never show: on a five-plane ChArUco stack of the Greenough rig the Soloff model
      linear in depth was chosen for Z at 1.28 times the best candidate inside the volume. ``diagonal``: one
      fifth of the dots per position fold in turn (at least five folds), rather than each fifth with each
      position.
    * Fewer positions (one pose, two or three planes): held-out dots within every position. Holding out one
      of two planes would measure an extrapolation over the whole depth from the other, which says nothing of
      the error inside the calibrated volume; the depth is then pinned by the models' own limits (a depth
      degree below the number of planes)."""
    key = dot_folds(pts)
    n_pos = pts.groupby("sequence")["position"].nunique().min()
    if mode == "moves" and n_pos >= 2:
        out = [(~m, m) for m in position_folds(pts)]
    elif not planes_held_out(pts, mode):
        out = [(key != r, key == r) for r in range(DOT_FOLDS)]
    else:
        held = position_folds(pts)
        ends = end_planes(held)              # never held out whole: their dots once, in turn
        if len(held) <= 3 and not diagonal:  # few held-out positions: each with each fifth of the dots
            out = [(~p & (key != r), (p | (ends & (i == 0))) & (key == r))
                   for i, p in enumerate(held) for r in range(DOT_FOLDS)]
        else:  # many (or ``diagonal``): one fifth of the dots per position fold, in turn, every fifth at least once
            n = max(len(held), DOT_FOLDS)
            out = [(~held[k % len(held)] & (key != k % DOT_FOLDS),
                    (held[k % len(held)] | (ends & (k < DOT_FOLDS))) & (key == k % DOT_FOLDS)) for k in range(n)]
    return [(tr, te) for tr, te in out if tr.any() and te.any()]


def end_planes(held: list[np.ndarray]) -> np.ndarray:
    """The rows of positions no fold of ``held`` (:func:`position_folds`) holds out whole: each sequence's first
    and last plane where interior planes are held out one at a time; none where every third plane is."""
    return ~np.logical_or.reduce(held)


def planes_held_out(pts, mode: str) -> bool:
    """Whether :func:`row_folds` holds out whole interior planes (crossed with dots): the dots' world positions
    known and at least :data:`PLANES_FOR_PLANE_FOLDS` stage positions in every sequence. Positions, not depths:
    a two-level plate at three positions has six depths, but a fold without one position loses two of them."""
    n_pos = pts.groupby("sequence")["position"].nunique().min()
    return mode != "moves" and n_pos >= PLANES_FOR_PLANE_FOLDS


def fold_description(pts, mode: str, *, diagonal: bool = False) -> str:
    """One line for the model file: how :func:`row_folds` held rows out of this set."""
    n = len(row_folds(pts, mode, diagonal=diagonal))
    n_pos = pts.groupby("sequence")["position"].nunique().min()
    if mode == "moves" and n_pos >= 2:
        return f"{n} folds of interior stage positions (each dot's offset from the training positions)"
    if not planes_held_out(pts, mode):
        return f"{n} folds of held-out dots within every position ({n_pos} position(s): too few to hold out)"
    ends = ", the end planes' dots in turn" if end_planes(position_folds(pts)).any() else ""
    return f"{n} folds of interior planes crossed with every fifth dot{ends}"


def dot_folds(pts) -> np.ndarray:
    """The fold of each row's dot, ``(row + 2·col) mod 5``: a knight's-move pattern, so that each fold's dots
    are spread over the whole field (not in stripes) and four fifths of them always calibrate."""
    return (pts["row"].to_numpy(np.int64) + 2 * pts["col"].to_numpy(np.int64)) % DOT_FOLDS


def position_keys(pts) -> np.ndarray:
    """Each row's stage position, ``"sequence:position"``: the rows that share one stage error."""
    return (pts["sequence"].astype(str) + ":" + pts["position"].astype(str)).to_numpy()


def held_out_errors(cal: CalibrationSet, name: str, options: dict | None = None, folds=None, *,
                    by_position: bool = False) -> np.ndarray:
    """Held-out RMS [mm] per coordinate of model ``name`` on ``cal`` (module docstring, step 2); ``folds``:
    ``(train, test)`` row masks (default :func:`row_folds`); each fold's model is fitted without its parameters'
    spread (``spread=False``: the pinhole's σ(f); the other models ignore it). The errors are net of one common
    offset, or with
    ``by_position`` of each held-out position's own (:func:`per_position_offsets`)."""
    pts, world, mode = world_positions(cal, (options or {}).get("mode", "auto"))
    folds = row_folds(pts, mode) if folds is None else folds
    if not folds:
        raise SlmlabError("no held-out fold has both training and test rows: too few dots or positions", cal.path)
    position = position_keys(pts)
    cls = get_model_class(name)
    errs = []
    for train_rows, held in folds:
        train = CalibrationSet(pts[train_rows].copy(), cal.meta, path=cal.path)
        model = cls.fit(train, **{**(options or {}), "spread": False})   # nobody reads a fold's σ
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
        elif by_position:
            e = e - per_position_offsets(e, position[held])
        else:
            e = e - np.median(e, axis=0)
        errs.append(e)
    e = np.vstack(errs)
    return np.sqrt(np.mean(e ** 2, axis=0))


def per_position_offsets(e: np.ndarray, position: np.ndarray) -> np.ndarray:
    """Each row's position's median of the errors ``e`` (n, 3): what held-out dots within positions should be
    measured net of. Every dot of a stage position shares that position's error (the stage put the plate a
    little off its command), which no model can know at a position it has not seen. A model that learned it
    from the position's other dots, as optics, would be rewarded for it by an error net of one common offset
    (a polynomial of degree 4 follows the offsets of a few positions), and a model that keeps it out of the
    optics (the direct model's stage errors, a random effect) penalised: on a two-level plate at three
    positions of the Greenough rig the direct model ranked last in X by that measure (0.155 µm against 0.113
    for the 4th-degree polynomial) and is first inside the volume (0.074 against 0.124, notebook 11)."""
    return pd.DataFrame(e).groupby(position).transform("median").to_numpy()


def between_depths(pts, world: np.ndarray, *, beyond: float = 0.25) -> np.ndarray:
    """Image coordinates ``(m, 4)`` [px] between each dot and its nearest neighbour across the target (in world
    ``x, y``) at the next depth up (the same dot on the next plane of a Z stack, the neighbouring dot of the
    other level of a two-level plate): halfway, and for the outermost pair of depths also ``beyond`` of the way
    past each end (a calibration is used a little past its last plane). Not images of known points (the image of a midpoint is not the midpoint
    of the images, to second order), but the same inputs for every model: where two models that both fit the
    calibrated depths disagree there, one of them bends between the depths in a way nothing measured."""
    w = pts[IMAGE_COLUMNS].to_numpy(float)
    z = levels(world)
    depths = np.unique(z)
    out = []
    for k, (lo, hi) in enumerate(zip(depths[:-1], depths[1:])):
        a, b = z == lo, z == hi
        d, j = cKDTree(world[b, :2]).query(world[a, :2])
        near = d <= 1.5 * np.median(d) + 1e-12
        wa, wb = w[a][near], w[b][j[near]]
        ts = [0.5] + ([-beyond] if k == 0 else []) + ([1 + beyond] if k == len(depths) - 2 else [])
        out += [wa + t * (wb - wa) for t in ts]
    return np.vstack(out) if out else np.empty((0, 4))


def between_arms(pts, *, reach: float = 0.9, max_points: int = 20_000) -> np.ndarray:
    """Image coordinates ``(m, 4)`` [px] between the arms of a plate's stage moves (the paper's X, Y and Z
    sequences, crossing near one position): each dot's image at the crossing ``b`` moved by one arm's
    displacement and by another's at least 60° from it, superposed (``w_p + w_q - w_b``), where the two together
    reach at most ``reach`` of the way to the arms' ends along their directions (inside the cross's hull, where
    a user measures and no calibrated position lies). Not images of known points (perspective's cross terms are
    second order), but the same inputs for every model, as :func:`between_depths`'s: where models that all fit
    the arms disagree there, one of them bends between the arms in a way nothing measured. At most about
    ``max_points`` (every ``k``-th pair of positions); empty where the moves keep to one direction."""
    keys = pts["sequence"].astype(str).to_numpy() + ":" + pts["position"].astype(str).to_numpy()
    pos, at = np.unique(keys, return_inverse=True)
    dots, dot = np.unique(point_keys(pts["row"], pts["col"]), return_inverse=True)
    w = np.full((len(pos), len(dots), 4), np.nan)
    w[at.ravel(), dot.ravel()] = pts[IMAGE_COLUMNS].to_numpy(float)
    stage = np.zeros((len(pos), 3))
    stage[at.ravel()] = pts[["stage_x_mm", "stage_y_mm", "stage_z_mm"]].to_numpy(float)
    b = int(np.argmin(np.linalg.norm(stage - np.median(stage, axis=0), axis=1)))
    d = stage - stage[b]
    n = np.linalg.norm(d, axis=1)
    u = d / np.maximum(n, 1e-12)[:, None]
    moved = n > 1e-9 * max(float(n.max()), 1e-12)
    along = np.abs(u @ u.T) > 0.99                      # the same direction (either way along an arm)
    ends = np.array([n[along[i] & moved].max() if moved[i] else 1.0 for i in range(len(pos))])
    i, j = np.triu_indices(len(pos), 1)
    keep = moved[i] & moved[j] & (np.abs((u[i] * u[j]).sum(axis=1)) <= 0.5) & (n[i] / ends[i] + n[j] / ends[j] <= reach)
    i, j = i[keep], j[keep]
    if len(i) == 0:
        return np.empty((0, 4))
    step = max(1, int(np.ceil(len(i) * len(dots) / max_points)))
    q = (w[i[::step]] + w[j[::step]] - w[b][None]).reshape(-1, 4)
    return q[np.isfinite(q).all(axis=1)]


def thin_dots(pts, max_rows: int) -> np.ndarray:
    """A row mask keeping every ``k``-th dot (all its positions) of each held-out dot fold (:func:`dot_folds`), the
    smallest ``k`` that leaves about ``max_rows`` rows: a deterministic subsample, spread over the field, for
    held-out comparisons, with every fold of dots in it. Every ``k``-th dot of the whole list can fall in one fold:
    on a random stereo-PIV rig's 13-plane stack (``stereo-piv:11``, 27 × 48 dots, 5 kept in 25) every kept dot had
    ``(row + 2·col) mod 5 = 3``, no crossed fold had both training and test rows, and ``calibrate`` crashed."""
    keys = point_keys(pts["row"], pts["col"])
    uniq, first, idx = np.unique(keys, return_index=True, return_inverse=True)
    k = max(1, int(np.ceil(len(pts) / max_rows)))
    fold = dot_folds(pts)[first]
    rank = np.empty(len(uniq), np.int64)  # each dot's place among the dots of its fold, in the keys' order
    for r in np.unique(fold):
        rank[fold == r] = np.arange(int((fold == r).sum()))
    return (rank % k == 0)[idx.ravel()]
