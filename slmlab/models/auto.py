"""The default model: per coordinate, the candidate with the smallest held-out error on the calibration set.

No single map from image to world is best on every rig. On a CMO microscope the direct model's three
combinations ``(v1, v2, D)`` carry everything and it reaches the noise floor; on an oblique stereo-PIV rig
the fourth image coordinate carries information, and a polynomial from world to image per camera (the
Soloff model) may fit the physics better in one coordinate and worse in another. The ``auto`` model
(slmlab's default) lets the calibration set decide, never test data:

1. **Folds** (:func:`slmlab.models.folds.row_folds`): the set's stage positions (planes of a Z stack) are held out in turn:
   the interior ones one at a time where a sequence has at most :data:`slmlab.models.folds.LEAVE_ONE_OUT_MAX` positions (a
   calibration is used within its range, so each sequence's first and last position always calibrate), else
   every third position in three folds. Where the dots' world positions are known, the folds are crossed
   with every fifth dot, so that the test rows are new in depth and across the field alike. A target imaged
   in one pose holds out every fifth dot.
2. **Held-out error** (:func:`slmlab.models.folds.held_out_errors`) of each candidate fitted on the rest, per coordinate: the
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

import inspect

import numpy as np

from ..errors import SlmlabError
from ..io import CalibrationSet
from .base import Model, get_model_class, register
from .folds import held_out_errors, row_folds
from .frames import world_positions

__all__ = ["CANDIDATES", "TIE", "AutoModel"]

#: the candidates, in order of preference
CANDIDATES = ("direct", "soloff")
TIE = 0.02


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
        take them (:class:`slmlab.models.direct.DirectModel`, :class:`slmlab.models.soloff.SoloffModel`); ``degree`` is the
        direct model's (one whole number, or three: X, Y, Z)."""
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
