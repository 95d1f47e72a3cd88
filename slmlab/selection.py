"""The default model: per coordinate, the candidate with the smallest held-out error on the calibration set.

No single map from image to world is best on every rig. On a CMO microscope the direct model's three
combinations ``(v1, v2, D)`` carry everything and it reaches the noise floor; on an oblique stereo-PIV rig
the fourth image coordinate carries information, and a polynomial from world to image per camera (the
Soloff model) may fit the physics better in one coordinate and worse in another. The ``auto`` model
(slmlab's default) lets the calibration set decide, never test data:

1. **Folds** (:func:`row_folds`): the set's stage positions (planes of a Z stack) are held out in turn:
   the interior ones one at a time where a sequence has at most :data:`LEAVE_ONE_OUT_MAX` positions (a
   calibration is used within its range, so each sequence's first and last position always calibrate), else
   every third position in three folds. Where the dots' world positions are known, the folds are crossed
   with every fifth dot, so that the test rows are new in depth and across the field alike. A target imaged
   in one pose holds out every fifth dot.
2. **Held-out error** (:func:`held_out_errors`) of each candidate fitted on the rest, per coordinate: the
   reconstruction of the held-out rows against their world position, net of one common offset (a Z stack or
   a known target), or of one offset per dot and sequence estimated on the training positions (stage moves
   of a plate whose place on the stage is unknown).
3. **Choice**: per coordinate, the candidate with the smallest held-out RMS; within 2 % of the best the
   earlier candidate in :data:`CANDIDATES` is kept (the direct model first). The chosen candidates are then
   fitted on the whole set.

Candidates that cannot calibrate the set are skipped (the Soloff model needs the dots' world positions, so
stage moves of a plate with an unknown place leave the direct model alone, with no held-out fits at all).
"""

from __future__ import annotations

import numpy as np

from .errors import SlmlabError
from .io import IMAGE_COLUMNS, CalibrationSet
from .linefit import point_keys
from .models import Model, get_model_class, register

__all__ = ["CANDIDATES", "LEAVE_ONE_OUT_MAX", "position_folds", "row_folds", "held_out_errors", "AutoModel"]

#: the candidates, in order of preference
CANDIDATES = ("direct", "soloff")
#: sequences with at most this many positions are cross-validated one position at a time
LEAVE_ONE_OUT_MAX = 8
#: dots are held out one fifth at a time
DOT_FOLDS = 5
TIE = 0.02


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
    from .direct import world_positions

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


@register
class AutoModel(Model):
    """Per coordinate, the candidate model with the smallest held-out error on the calibration set."""

    name = "auto"
    summary = ("slmlab's default: per coordinate, the candidate (direct, soloff) with the smallest error on "
               "held-out positions or planes of the calibration set; the choice is in the model file")
    accuracy_rank = 1
    units = {"models": "each candidate's own parameters and units"}

    def __init__(self, choice: list[str], models: dict[str, Model], **kw):
        super().__init__(**kw)
        self.choice = list(choice)
        self.models = models

    @classmethod
    def fit(cls, cal: CalibrationSet, *, candidates=CANDIDATES, mode: str = "auto", degree=None,
            variables="auto", length_reference: str = "stage", stage_scale_sigma: float = 0.0,
            centroid_noise_px: float = 0.02, **_):
        """Fit every candidate that can calibrate ``cal``, choose per coordinate by held-out error.

        ``candidates``: model names, in order of preference. The other options go to the candidates that
        take them (:class:`slmlab.direct.DirectModel`, :class:`slmlab.soloff.SoloffModel`); ``degree`` is the
        direct model's (one whole number, or three: X, Y, Z)."""
        import inspect

        from .direct import world_positions

        candidates = [str(c) for c in np.atleast_1d(candidates)]
        for c in candidates:
            get_model_class(c)
            if c == "auto":
                raise SlmlabError("the auto model cannot be its own candidate")
        given = {"mode": mode, "variables": variables, "length_reference": length_reference,
                 "stage_scale_sigma": stage_scale_sigma, "centroid_noise_px": centroid_noise_px}

        def options_for(name: str) -> dict:
            params = inspect.signature(get_model_class(name).fit).parameters
            out = {k: v for k, v in given.items() if k in params}
            if degree is not None and name == "direct":
                out["degree"] = degree
            return out

        _, _, mode = world_positions(cal, mode)
        usable = [c for c in candidates if not (c == "soloff" and mode == "moves")]
        if not usable:
            raise SlmlabError(f"none of the candidates {', '.join(candidates)} can calibrate this set", cal.path)
        cv: dict[str, list[float]] = {}
        skipped: dict[str, str] = {c: "needs the dots' world positions (a Z stack or a known target)"
                                   for c in candidates if c not in usable}
        fitted: dict[str, Model] = {}
        for c in usable:  # each candidate chooses its own settings (degrees, ...) on the whole set
            try:
                fitted[c] = get_model_class(c).fit(cal, **options_for(c))
            except SlmlabError as exc:
                if len(usable) == 1:
                    raise
                skipped[c] = exc.reason
        usable = [c for c in usable if c in fitted]
        if not usable:
            raise SlmlabError("no candidate model can calibrate this set: "
                              + "; ".join(f"{k}: {v}" for k, v in skipped.items()), cal.path)
        if len(usable) > 1:  # then they are compared, as chosen, on held-out positions
            pts, _, _ = world_positions(cal)
            folds = row_folds(pts, mode)
            for c in usable:
                try:
                    cv[c] = [float(v) for v in held_out_errors(cal, c, {**options_for(c), **fitted[c].fixed_options()},
                                                               folds)]
                except SlmlabError as exc:
                    skipped[c] = f"not cross-validated: {exc.reason}"
            usable = [c for c in usable if c in cv] or usable[:1]
        choice = []
        for k in range(3):
            if len(usable) == 1:
                choice.append(usable[0])
                continue
            best = min(cv[c][k] for c in usable)
            choice.append(next(c for c in usable if cv[c][k] <= best * (1 + TIE)))
        models = {c: fitted[c] for c in dict.fromkeys(choice)}
        for m in models.values():
            m.calibration = {**cal.summary(), **m.calibration}
        # the model chosen for most coordinates lends its report (degrees, scatter, rejected rows, ...)
        primary = models[max(models, key=choice.count)]
        selection = {"choice": dict(zip("XYZ", choice)), "mode": mode, "held_out_rms_mm": cv,
                     "held_out_by": ("not needed: one candidate" if len(cv) < 2 else
                                     f"{len(row_folds(world_positions(cal)[0], mode))} folds of positions "
                                     + ("(whole positions)" if mode == "moves" else "crossed with every fifth dot")),
                     "skipped": skipped}
        return cls(choice, models, options={**primary.options, "candidates": candidates},
                   calibration={**primary.calibration, "selection": selection})

    def describe(self) -> str:
        parts = [f"{''.join(c for c, k in zip('XYZ', self.choice) if k == n)}: {m.describe()}"
                 for n, m in self.models.items()]
        return "auto (" + "; ".join(parts) + ")"

    def reconstruct(self, w: np.ndarray) -> np.ndarray:
        w = np.atleast_2d(np.asarray(w, float))
        if len(self.models) == 1:
            return next(iter(self.models.values())).reconstruct(w)
        out = np.empty((len(w), 3))
        for name, m in self.models.items():
            p = m.reconstruct(w)
            for k, c in enumerate(self.choice):
                if c == name:
                    out[:, k] = p[:, k]
        return out

    def uncertainty(self, w: np.ndarray) -> np.ndarray:
        """1σ ``(n, 3)`` [mm] of each coordinate from the model chosen for it."""
        w = np.atleast_2d(np.asarray(w, float))
        out = np.full((len(w), 3), np.nan)
        for name, m in self.models.items():
            if hasattr(m, "uncertainty"):
                s = m.uncertainty(w)
                for k, c in enumerate(self.choice):
                    if c == name:
                        out[:, k] = s[:, k]
        return out

    def __getattr__(self, item):
        # the chosen direct model's extras (frame, calibration_sigma, ...) where there is one
        models = self.__dict__.get("models") or {}
        if len(models) == 1:
            return getattr(next(iter(models.values())), item)
        raise AttributeError(item)

    def parameters_dict(self) -> dict:
        return {"choice": self.choice,
                "models": {n: {"parameters": m.parameters_dict(), "options": m.options, "calibration": m.calibration}
                           for n, m in self.models.items()}}

    @classmethod
    def from_parameters(cls, parameters, calibration, options):
        models = {}
        for n, d in parameters["models"].items():
            models[n] = get_model_class(n).from_parameters(d["parameters"], d.get("calibration") or {},
                                                            d.get("options") or {})
        choice = [str(c) for c in parameters["choice"]]
        if len(choice) != 3 or any(c not in models for c in choice):
            raise ValueError("choice must name a fitted model for each of X, Y, Z")
        return cls(choice, models, calibration=calibration, options=options)
