"""The default model: per coordinate, the candidate with the smallest held-out error inside the calibrated
volume, and never a model that is not clearly better than a plain polynomial.

No single map from image to world is best on every rig. On a CMO microscope the direct model's three
combinations ``(v1, v2, D)`` carry everything and it reaches the noise floor; on an oblique stereo-PIV rig
the fourth image coordinate carries information, and a polynomial from world to image per camera (the
Soloff model) may fit the physics better in one coordinate and worse in another; on a rig nobody shaped a
model for, a plain least-squares polynomial in the four image coordinates may beat both. The ``auto`` model
(slmlab's default) lets the calibration set decide, never test data:

0. **The stage's own errors** (:mod:`slmlab.models.stage_errors`): where the dots' world positions are known
   at several stage positions and the pinhole pair describes the rig, each position's offset from its command
   (the same for every dot of the position) is measured from the pinhole pair's residuals and the commanded
   positions are corrected by it before any candidate is fitted; the offsets and why they were or were not
   applied are in the model file (``calibration.selection.stage``).
1. **Candidates** (:data:`CANDIDATES`): the direct model, the Soloff model (where the dots' world positions
   are known) and the plain polynomial of each degree up to 4 (:class:`slmlab.models.reference.PlainPolynomial`;
   on stage moves the same polynomial of the four image coordinates estimated by the direct model's solver,
   the stage's error at each position a random effect: ordinary least squares lets a stage's positioning
   noise into the polynomial's shape, and on the ``paper`` preset costs 15 % in Y over the volume).
   Where the dots' world positions are known and the set has fewer depths than
   :data:`slmlab.models.folds.PLANES_FOR_PLANE_FOLDS`, also the pinhole pair (OpenCV, one 3D view of the
   dots: :mod:`slmlab.models.pinhole`; settings :data:`PINHOLE`), the one candidate whose bend in depth is set
   by physics. Each candidate chooses its own settings (degrees) on the whole set; the direct and Soloff models
   pin their degree in depth below the number of distinct depths (the Soloff model's is at most quadratic, and
   so is the direct model's where a position holds more than one depth: a two-level plate, a stepped target).
2. **Held-out error inside the calibrated volume** (:func:`slmlab.models.folds.row_folds`): held-out dots
   within positions; crossed with held-out interior planes where a stack has enough of them
   (:data:`slmlab.models.folds.PLANES_FOR_PLANE_FOLDS`), the end planes' dots tested too (a candidate too
   stiff in depth misses most there); interior stage positions on stage moves. Never whole
   positions where there are too few to interpolate between: holding out one of two planes measures an
   extrapolation over the full depth, which says nothing of the error inside it. Where step 0 found the stage's
   offsets clearly above their noise, held-out dots within a few positions are measured net of each position's
   own offset (:func:`slmlab.models.folds.per_position_offsets`, :func:`_dots_within_positions`): the stage's
   error there, which a polynomial would otherwise be rewarded for learning from the position's
   other dots; so are they at two or three positions of a target with depth of its own, where (nearly) every
   offset is affine and step 0 corrects little or none (:func:`_deep_target_at_few_positions`). Then nothing
   measured says how a candidate bends between the depths (and just past them), and physics decides
   (:func:`_between_depths_guard`). Where the pinhole pair describes the rig (step 0 found its
   reprojection error within :data:`slmlab.models.stage_errors.FITS` of the Soloff polynomials' scatter, or its
   held-out error in X and Y is within :data:`MARGIN` of the best candidate's), perspective sets the bend (a
   camera's magnification changes between the planes, and with it the image of every depth between them), and
   a candidate's difference from the pinhole there, net of the affine map between the two (a frame, not a
   bend), is an error a user will see on top of its held-out one: in X and Y each candidate is judged by the
   two in quadrature (charged half of it there too, the cubic took Y on the Greenough two-level plate at two
   positions at 3.5x its best candidate inside the volume, and the polynomial of degree 4 X on ``stereo-dic:1``'s at
   1.44x). In Z the pinhole's own error between the depths is as large as the differences it would judge (depth is
   the stereo angle's weak direction): the difference is the two models' together, and a candidate is judged by its
   held-out error in quadrature with :data:`PINHOLE_Z_SHARE` of it (half: its own share), and dropped where it
   differs from the pinhole by more than :data:`PINHOLE_Z_BEND` times the larger held-out error (more than either
   model's own scatter: one of them bends, and the pinhole's bend is perspective's). Without its share in Z, the
   polynomial of degree 4 (held-out Z 4.50 µm, the pinhole 4.52, 3.1 µm apart between the depths) took Z on a
   stereo-DIC two-level plate at two positions at 1.24x the best candidate inside the volume (1.0x with it), and
   the cubic a Greenough Z stack of three planes at 1.21x (``greenough:2``; 1.0x); with the whole difference, the
   pinhole's own bend took Z from the direct model on the stereo-DIC rig's three planes at 1.07x it (notebook 11),
   and on the PIV Challenge's case E (its picks on four planes) from the quadratic at 1.08x it on the other planes
   (with half, the quadratic stays: notebook 10).
   At 1.5 times, a cubic 5.7 µm from the pinhole against held-out errors of 4.4 µm stayed, on a stereo-DIC
   two-level plate in one pose, at 1.10x the pinhole inside the volume. On a stereo-DIC pair
   calibrated on two planes, a model linear in depth puts the midplane 30 µm off in Z against a 4 µm floor; the
   pinhole pair is within 1.2× of the floor. On a two-level plate at two
   stage positions of the Greenough rig, a polynomial of degree 4 learns the stage's error between the two as
   optics (held-out 0.09 µm in X, the pinhole 0.15) and bends 0.29 µm from the pinhole between the depths; the
   Soloff model taken instead is at the floor in the commanded frame, where the polynomial was at 2× (notebook
   11). Where the pinhole does not describe the rig (refraction through a window, a lens a pinhole cannot
   describe), a plain polynomial is dropped where it differs from every depth-pinned candidate (direct,
   soloff) by more than :data:`BETWEEN_DEPTHS` times their held-out errors: a cubic through two planes can put
   the midplane far off while fitting both planes to the noise. That check runs on every set whose folds hold
   out no planes, however many depths it has: a two-level plate at three stage positions has six depths, in
   close pairs, and the polynomial of degree 4, first by held-out dots (0.13 µm in X and Y), was 0.49 and
   0.68 µm off inside the volume of a random Greenough rig (``greenough:1``), 3.6 and 5.9 times the cubic.
   A depth-pinned candidate bends too where its degree in depth is high for the depths' spacing: it is dropped
   where it differs from every other candidate still standing by more than :data:`BETWEEN_DEPTHS` times their
   held-out errors while two of those agree with each other. There the direct model of degree 5 in depth was
   first by held-out dots in Z (1.09 µm against 1.18) and 7.7-9.6 µm from every other candidate between the
   depths; the Soloff model and the cubic, 0.14 µm apart, were 1.15 µm off in the volume, the direct model 3.3
   µm. Held since to a quadratic in depth (:data:`slmlab.models.direct.DEPTH_DEGREE`), the direct model is
   1.14 µm off there and not dropped; the rule stays for any candidate that bends.
   On stage moves (the paper's cross of X, Y and Z sequences) the held-out interior positions lie on the arms;
   between them, where a user measures too, every model extrapolates and nothing is pinned by physics
   (:func:`_between_arms_guard`). There the candidates a choice could fall on (held-out error within
   :data:`BETWEEN_DEPTHS` times the best) vote: one is dropped where it differs from every other of them between
   the arms (each dot's images at two arms' positions superposed about their crossing,
   :func:`slmlab.models.folds.between_arms`) by more than :data:`BETWEEN_DEPTHS` times the larger held-out error
   while two of the others agree. On a random stereo-DIC rig's cross (``stereo-dic:24``) the cubic was first in X
   by held-out positions (2.69 µm, the direct model 2.95, the quartic 2.93) and 3.7 times the best candidate
   between the arms; the direct model and the quartic agreed there within 0.4 µm, the cubic was 4.6 µm from both,
   and the quartic taken instead is at 1.05 times. Over the crosses of 60 random rigs and the three zoo rigs (189
   coordinates) six choices changed, every one nearer the truth (the worst ratio to the best candidate 3.70 ->
   2.25), and none on the CMO presets' five calibration tests.
   A known blind spot, where step 0 does not apply (stage moves, a rig the pinhole pair does not describe):
   held-out dots share their position's stage error (positioning noise, lead and straightness errors: the same
   for every dot of a position), and a held-out plane's own offset goes out with the fold's, so no fold sees
   how much of the stage's per-position error a candidate learns as optics (a polynomial of degree 4 can
   follow all five planes' offsets). Where the stage is much worse than the
   centroids (a stereo microscope on a micrometre stage: 0.3 µm per move against a 0.07 µm floor) that is
   most of the error a user sees in X and Y, the held-out error is confidently wrong (every fold prefers the
   higher degree) and a set with few positions cannot tell the stage from the optics (the direct model's
   variance components put the stage's error at zero on five planes); where it is near the centroids'
   (macro stages on stereo-DIC and PIV rigs) it does not matter. A target with depth of its own says more: on a
   two-level plate at two positions of the Greenough rig the direct model (its random effect per position, the
   plate's two levels at each) takes the stage's error out and reaches the noise floor in X and Y, below the
   floor in the commanded frame; no held-out dot shows it, but measured net of each position's offset the
   direct model is no longer charged for it, and is chosen where it is clearly better on the rest (two or three
   positions). From four positions on a position's offset stays a model's own (on the PIV Challenge's case E,
   extracted, the direct model puts the stage's error per position at 13-15 µm in X and Y: the plate's tilt to the
   traverse, and the checked planes hold a model to the traverse).
3. **Choice**, per coordinate: the plain polynomial with the smallest error as judged in step 2 (the lowest degree
   within :data:`TIE` of the best), unless another candidate is clearly better, by more than :data:`MARGIN`
   of it; then the best of those (within :data:`TIE`, the earlier in :data:`CANDIDATES`).

The choice and its evidence (every candidate's held-out RMS per coordinate, its difference from the pinhole
between the depths where that judged, the folds, what was skipped and why) are in the model file under
``calibration.selection``, and ``evaluate`` prints them.
"""

from __future__ import annotations

import inspect

import numpy as np
import pandas as pd

from ..errors import SlmlabError
from ..io import CalibrationSet
from .base import Model, get_model_class, register
from .direct import check_options
from .folds import (PLANES_FOR_PLANE_FOLDS, between_arms, between_depths, fold_description, held_out_errors, planes_held_out,
                    row_folds, thin_dots)
from .frames import distinct_levels, world_positions
from .reference import DEGREES as POLYNOMIAL_DEGREES
from .stage_errors import corrected_for_stage

__all__ = ["CANDIDATES", "PINHOLE", "PINHOLE_MISFIT", "TIE", "MARGIN", "BETWEEN_DEPTHS", "PINHOLE_Z_BEND",
           "PINHOLE_Z_SHARE", "FORGIVEN_POSITIONS", "COMPARISON_ROWS", "candidate_list", "choose", "selection_table",
           "AutoModel"]

#: the candidates, in order of preference ("polynomial": the plain polynomial of every allowed degree)
CANDIDATES = ("direct", "soloff", "pinhole", "polynomial")
#: the pinhole candidate's settings: OpenCV's rational and thin-prism distortion terms (a general lens; the
#: pinhole model's own choice among its variants would cost four more fits), each OpenCV fit stopped after this
#: many steps (a pair that has not converged by then does not fit the rig, and its held-out error says so)
PINHOLE = {"variant": "thin-prism", "iterations": 100}
#: a pinhole pair whose reprojection error is more than this many times the Soloff polynomials' image residual
#: (per point, both coordinates) does not describe the rig (refraction through a window, say), and is not
#: cross-validated: its held-out error would only say so again, at five more OpenCV fits
PINHOLE_MISFIT = 2.0
#: within this share of the best held-out error, candidates are equally good
TIE = 0.02
#: a candidate other than the plain polynomial wins only where it is better than it by more than this share
MARGIN = 0.05
#: a plain polynomial that disagrees between the calibrated depths with every depth-pinned candidate (direct,
#: soloff) by more than this many times the larger of their held-out errors bends where nothing was measured;
#: so does a depth-pinned candidate that disagrees so with every other one, two of which agree within it
BETWEEN_DEPTHS = 1.5
#: where the pinhole pair judges, a candidate whose Z differs from it between the depths by more than this many
#: times the larger of their held-out errors bends where nothing was measured
PINHOLE_Z_BEND = 1.0
#: where the pinhole pair judges, this share of a candidate's difference from it in Z between the depths counts
#: as its error (in quadrature with its held-out one): the pinhole's own depth there is as uncertain, and the
#: difference is the two models' together
PINHOLE_Z_SHARE = 0.5
#: at most this many stage positions of a target with depth of its own, held-out dots are measured net of their
#: position's offset (:func:`_deep_target_at_few_positions`)
FORGIVEN_POSITIONS = 3
#: the held-out comparison runs on at most this many rows (every k-th dot): its ranking, not the fits, needs them
COMPARISON_ROWS = 4000


def candidate_list(candidates, pts, world: np.ndarray, mode: str) -> tuple[list[tuple[str, str, dict]], dict]:
    """``[(label, model name, fixed options)]`` of the candidates that apply to the set, in order of
    preference, and ``{label: why not}`` of those that do not. The pinhole pair is not needed with
    :data:`slmlab.models.folds.PLANES_FOR_PLANE_FOLDS` depths or more: then either whole interior planes are held
    out (as many stage positions), or the target's own depth interleaves the positions' (a two-level plate at
    three or four positions), where the depth-pinned candidates judge how the polynomials bend between them
    (:func:`_between_depths_guard`). On the PIV Challenge's case E (a two-level plate at four positions, eight
    depths) the pinhole pair as a judge there took Z, 1.35x worse than the Soloff model on the other planes of
    the extraction.
    ``"polynomial"`` expands to ``polynomial-1`` … ``polynomial-4``; ``"polynomial-3"`` names one degree."""
    out, skipped = [], {}
    for c in candidates:
        name, _, deg = c.partition("-")
        if c == "auto":
            raise SlmlabError("the auto model cannot be its own candidate")
        if name == "polynomial":  # on stage moves estimated with the stage's error per position as a random
            # effect (the direct model's solver on the four image coordinates: the same polynomials)
            for d in ([int(deg)] if deg else POLYNOMIAL_DEGREES):
                out.append((f"polynomial-{d}", *(("direct", {"variables": 4, "degree": d}) if mode == "moves"
                                                  else ("polynomial", {"degree": d}))))
            continue
        get_model_class(c)
        if c in ("soloff", "pinhole") and mode == "moves":
            skipped[c] = "needs the dots' world positions (a Z stack or a known target)"
        elif c == "pinhole" and (depths := distinct_levels(world)) >= PLANES_FOR_PLANE_FOLDS:
            skipped[c] = (f"not needed: {depths} depths, "
                          + ("whose held-out interior planes measure how each candidate bends between them"
                             if planes_held_out(pts, mode) else
                             "the candidates judge each other's bends between them (with direct or soloff "
                             "among them)"))
        else:
            out.append((c, c, dict(PINHOLE) if c == "pinhole" else {}))
    return out, skipped


def _is_polynomial(label: str) -> bool:
    return label.startswith("polynomial")


def choose(cv: dict[str, list[float]], order: list[str]) -> list[str]:
    """Per coordinate, the label chosen from the held-out errors ``cv`` (module docstring, step 3); ``order``:
    the labels in order of preference."""
    choice = []
    for k in range(3):
        polys = [c for c in order if _is_polynomial(c) and c in cv]
        others = [c for c in order if not _is_polynomial(c) and c in cv]

        def best(labels):
            low = min(cv[c][k] for c in labels)
            return next(c for c in labels if cv[c][k] <= low * (1 + TIE))
        if not polys or not others:
            choice.append(best(polys or others))
            continue
        p, o = best(polys), best(others)
        choice.append(o if cv[o][k] < (1 - MARGIN) * cv[p][k] else p)
    return choice


def selection_table(model: Model) -> pd.DataFrame | None:
    """The default's evidence as a table: per candidate, its settings, held-out RMS per coordinate [µm], where the
    pinhole pair judged between the depths its RMS difference from it there (``off_pinhole_{c}_um``, net of the
    affine map between them) and which coordinates chose it (``None`` for a model that chose nothing)."""
    sel = model.calibration.get("selection") if isinstance(model.calibration, dict) else None
    if not sel or not sel.get("held_out_rms_mm"):
        return None
    rows, gaps = [], sel.get("between_depths_mm") or {}
    for label, v in sel["held_out_rms_mm"].items():
        chosen = "".join(c for c, k in sel["choice"].items() if k == label)
        bend = {f"off_pinhole_{c}_um": 1e3 * gaps[label][k] for k, c in enumerate("XYZ")} if label in gaps else {}
        rows.append({"candidate": label, "settings": sel.get("described", {}).get(label, label),
                     **{f"held_out_{c}_um": 1e3 * v[k] for k, c in enumerate("XYZ")}, **bend,
                     "chosen_for": chosen or "-"})
    return pd.DataFrame(rows)


@register
class AutoModel(Model):
    """Per coordinate, the candidate with the smallest held-out error, where it is clearly better than a plain
    polynomial (module docstring)."""

    name = "auto"
    summary = ("slmlab's default: per coordinate, the candidate (direct, soloff, pinhole, plain polynomials) with "
               "the smallest error on held-out dots and planes inside the calibrated volume, a plain polynomial "
               "unless another is clearly better; the choice and its evidence are in the model file")
    accuracy_rank = 1
    units = {"models": "each candidate's own parameters and units"}

    def __init__(self, choice: list[str], models: dict[str, Model], candidates: dict[str, Model] | None = None, **kw):
        super().__init__(**kw)
        self.choice = list(choice)
        self.models = models
        #: every candidate as fitted on the whole set (in memory only: the file keeps the chosen ones)
        self.candidates = dict(candidates or models)

    @classmethod
    def fit(cls, cal: CalibrationSet, *, candidates=CANDIDATES, mode: str = "auto", degree=None,
            variables="auto", length_reference: str = "stage", stage_scale_sigma: float = 0.0,
            centroid_noise_px: float = 0.02, **_):
        """Fit every candidate that can calibrate ``cal``, choose per coordinate by held-out error.

        ``candidates``: model names, in order of preference (``"polynomial"`` for the plain polynomials of
        every allowed degree, ``"polynomial-3"`` for one). The other options go to the candidates that take
        them (:class:`slmlab.models.direct.DirectModel`, :class:`slmlab.models.soloff.SoloffModel`);
        ``degree`` is the direct model's (one whole number, or three: X, Y, Z)."""
        check_options(degree=degree, length_reference=length_reference, stage_scale_sigma=stage_scale_sigma,
                      variables=variables)  # a user's mistake is said, not skipped with a candidate
        given = {"mode": mode, "variables": variables, "length_reference": length_reference,
                 "stage_scale_sigma": stage_scale_sigma, "centroid_noise_px": centroid_noise_px}
        pts, world, mode = world_positions(cal, mode)
        cal, stage = corrected_for_stage(cal, mode, PINHOLE)
        if stage["applied"]:  # every candidate calibrates on the corrected positions, a known target
            given["mode"] = "target"
            pts, world, _ = world_positions(cal, "target")
        cands, skipped = candidate_list([str(c) for c in np.atleast_1d(candidates)], pts, world, mode)
        if not cands:
            raise SlmlabError(f"none of the candidates {', '.join(map(str, np.atleast_1d(candidates)))} can "
                              "calibrate this set", cal.path)
        options = {label: {**_options_for(name, given, degree), **fixed} for label, name, fixed in cands}
        fitted = _fit_candidates(cal, cands, options, skipped)
        cv = _held_out(cal, cands, fitted, options, skipped, stage["applied"]) if len(fitted) > 1 else {}
        judged, gaps = _between_depths_guard(pts, world, mode, fitted, cv, skipped, stage.get("pinhole_fits", False))
        order = [label for label, _, _ in cands if label in fitted]
        choice = choose(judged, order) if cv else [order[0]] * 3
        models = {c: fitted[c] for c in dict.fromkeys(choice)}
        for m in models.values():
            m.calibration = {**cal.summary(), **m.calibration}
        # the model chosen for most coordinates lends its report (degrees, scatter, rejected rows, ...)
        primary = models[max(models, key=choice.count)]
        selection = {"choice": dict(zip("XYZ", choice)), "mode": mode, "held_out_rms_mm": cv,
                     "described": {c: m.describe() for c, m in fitted.items()},
                     "held_out_by": ("not needed: one candidate" if len(cv) < 2 else
                                     f"{fold_description(pts, mode, diagonal=True)}, on {len(_thinned(cal).points)} rows"),
                     "rule": ("per coordinate the plain polynomial with the smallest held-out RMS"
                              + (" (in quadrature with its difference from the pinhole between the depths, "
                                 f"in Z {PINHOLE_Z_SHARE:.0%} of it)"
                                 if gaps else "")
                              + f", unless another candidate is lower by more than {MARGIN:.0%}; "
                                f"ties within {TIE:.0%}"),
                     "between_depths_mm": gaps, "skipped": skipped, "stage": stage}
        return cls(choice, models, fitted,
                   options={**primary.options, "candidates": [str(c) for c in np.atleast_1d(candidates)]},
                   calibration={**primary.calibration, "selection": selection})

    def describe(self) -> str:
        parts = [f"{''.join(c for c, k in zip('XYZ', self.choice) if k == n)}: "
                 + (m.describe() if n.partition("-")[0] == m.name else f"{n} as {m.describe()}")
                 for n, m in self.models.items()]
        return "auto (" + "; ".join(parts) + ")"

    def reconstruct(self, w: np.ndarray) -> np.ndarray:
        w = np.asarray(w, float).reshape(-1, 4)
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
        """1σ ``(n, 3)`` [mm] of each coordinate from the model chosen for it (NaN where that model gives
        none: the plain polynomial)."""
        return self._per_coordinate("uncertainty", w)

    def calibration_sigma(self, w: np.ndarray) -> np.ndarray:
        """1σ ``(n, 3)`` [mm] of the calibration alone (the coefficients' covariance) of each coordinate, from
        the model chosen for it (NaN where that model gives none)."""
        return self._per_coordinate("calibration_sigma", w)

    def _per_coordinate(self, method: str, w: np.ndarray) -> np.ndarray:
        w = np.asarray(w, float).reshape(-1, 4)
        out = np.full((len(w), 3), np.nan)
        for name, m in self.models.items():
            if hasattr(m, method):
                s = getattr(m, method)(w)
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
                "models": {n: {"model": m.name, "parameters": m.parameters_dict(), "options": m.options,
                               "calibration": m.calibration} for n, m in self.models.items()}}

    @classmethod
    def from_parameters(cls, parameters, calibration, options):
        models = {}
        for n, d in parameters["models"].items():
            models[n] = get_model_class(d.get("model", n)).from_parameters(d["parameters"], d.get("calibration") or {},
                                                                           d.get("options") or {})
        choice = [str(c) for c in parameters["choice"]]
        if len(choice) != 3 or any(c not in models for c in choice):
            raise ValueError("choice must name a fitted model for each of X, Y, Z")
        return cls(choice, models, calibration=calibration, options=options)


def _options_for(name: str, given: dict, degree) -> dict:
    """The options of ``auto`` that candidate ``name``'s ``fit`` takes (``degree`` is the direct model's)."""
    params = inspect.signature(get_model_class(name).fit).parameters
    out = {k: v for k, v in given.items() if k in params}
    if degree is not None and name == "direct":
        out["degree"] = degree
    return out


def _fit_candidates(cal: CalibrationSet, cands, options: dict, skipped: dict) -> dict[str, Model]:
    """Each candidate fitted on the whole set (choosing its own settings); one that cannot calibrate the set
    is skipped with its reason, unless none can."""
    fitted: dict[str, Model] = {}
    for label, name, _ in cands:
        try:
            fitted[label] = get_model_class(name).fit(cal, **options[label])
        except SlmlabError as exc:
            skipped[label] = exc.reason
    if not fitted:
        raise SlmlabError("no candidate model can calibrate this set: "
                          + "; ".join(f"{k}: {v}" for k, v in skipped.items()), cal.path)
    return fitted


def _thinned(cal: CalibrationSet) -> CalibrationSet:
    """The set with every k-th dot of its moving sequences, at most :data:`COMPARISON_ROWS` rows of them."""
    moving = (cal.points["sequence"] != "grid").to_numpy()
    keep = ~moving
    keep[moving] = thin_dots(cal.points[moving], COMPARISON_ROWS)
    return CalibrationSet(cal.points[keep].reset_index(drop=True), cal.meta, path=cal.path)


def _held_out(cal: CalibrationSet, cands, fitted: dict, options: dict, skipped: dict, stage_errs: bool = False
              ) -> dict[str, list[float]]:
    """Held-out RMS [mm] per coordinate of every fitted candidate, as chosen on the whole set, on the same
    folds of the (thinned) set (module docstring, step 2); ``stage_errs``: step 0 found the positions' offsets
    clearly above their noise (:func:`_dots_within_positions`), or the set is a deep target at few positions
    (:func:`_deep_target_at_few_positions`): then held-out dots are measured net of their position's offset."""
    sub = _thinned(cal)
    pts, world, mode = world_positions(sub)
    folds = row_folds(pts, mode, diagonal=True)
    by_position = (stage_errs or _deep_target_at_few_positions(pts, world)) and _dots_within_positions(pts, mode)
    cv = {}
    for label, name, _ in cands:
        if label not in fitted:
            continue
        if label == "pinhole" and (why := _pinhole_misfit(fitted)):
            skipped[label] = why
            continue
        try:
            cv[label] = [float(v) for v in held_out_errors(sub, name, {**options[label], **fitted[label].fixed_options()},
                                                           folds, by_position=by_position)]
        except SlmlabError as exc:
            skipped[label] = f"not cross-validated: {exc.reason}"
    return cv


def _dots_within_positions(pts, mode: str) -> bool:
    """Whether the folds hold out dots within every one of several positions (the dots' world positions known,
    fewer positions than held-out planes need). Where the stage step (0) found the positions' offsets clearly
    above their noise, their errors are then measured net of each position's own offset
    (:func:`slmlab.models.folds.per_position_offsets`): the stage errs at this set's precision, and what it
    leaves at a position is the stage's, which a model that learns it as optics from the position's other dots
    would otherwise be rewarded for. Where it found none, a position's offset in a model's held-out errors is
    the model's own: on the PIV Challenge's case E (four planes, a stage true to its commands) forgiving it
    took the direct model in Y, 1.4x worse on the other planes than the Soloff model taken otherwise."""
    several = pts.groupby("sequence")["position"].nunique().max() >= 2
    return mode != "moves" and several and not planes_held_out(pts, mode)


def _deep_target_at_few_positions(pts, world: np.ndarray) -> bool:
    """Whether a target with depth of its own (more distinct depths than stage positions: a two-level plate, a
    stepped target) was imaged at two or three stage positions (at most :data:`FORGIVEN_POSITIONS`). Between two
    positions every offset from the commanded move is affine, and between three all but one combination of them,
    so the stage step (0) corrects little or none of it and the commanded frame stands; the target's own depth at
    each position still says where the position was, and a model that keeps each position's offset out of the
    optics (the direct model's random effect) learns the stage's error from it, while a polynomial learns it as
    optics from the position's other dots and is rewarded for that by every held-out dot. Measured net of each
    position's own offset (:func:`_dots_within_positions`), the two are judged on their optics alone. On the
    two-level plate at two positions of 33 rigs (each kind's preset and seeds 11-20) the default came within 1.05x
    its best candidate inside the volume in 28 and 23 of them in X and Y (14 and 13 before; up to 5.0x before, the
    direct model at the noise floor), at three positions in 27 and 30 (19 and 23), no coordinate of any rig worse
    by more than 2 %; on the PIV Challenge's case E calibrated on two or three of its planes and checked on the
    others (16 checks), 14 as they were, Y -2.3 % and +2.7 % in the other two. From four positions on (case E's
    alternate planes) a position's offset stays the model's own: forgiven, it took the direct model in Y at 1.4x
    the Soloff model on the other planes."""
    positions = pts.groupby("sequence")["position"].nunique().max()
    return positions <= FORGIVEN_POSITIONS and distinct_levels(world) > positions


def _pinhole_misfit(fitted: dict) -> str:
    """Why the fitted pinhole pair does not describe the rig (:data:`PINHOLE_MISFIT`), or ``""``: its RMS
    reprojection error per point (OpenCV's, both image coordinates) against the Soloff polynomials' residual
    scatter per point (the root sum of squares of a camera's two coordinates, the larger camera)."""
    if "soloff" not in fitted:
        return ""
    sigma = np.asarray(fitted["soloff"].calibration["image_residual_sigma_px"], float)
    soloff_px = float(np.sqrt(np.maximum(sigma[0::2] ** 2 + sigma[1::2] ** 2, 0)).max())
    pinhole_px = float(fitted["pinhole"].calibration["stereo_rms_px"])
    if pinhole_px <= PINHOLE_MISFIT * soloff_px:
        return ""
    return (f"not cross-validated: it does not describe the rig (reprojection {pinhole_px:.3g} px per point against "
            f"the soloff polynomials' {soloff_px:.3g} px)")


def _between_depths_guard(pts, world, mode: str, fitted: dict, cv: dict, skipped: dict, describes: bool = False
                          ) -> tuple[dict[str, list[float]], dict[str, list[float]]]:
    """``(judged, gaps)``: the error [mm] each candidate is chosen by, per coordinate, and (where the pinhole pair
    judges) each candidate's RMS difference [mm] from it between the calibrated depths
    (:func:`slmlab.models.folds.between_depths`). Where a set has two depths or more and held-out dots are all
    its folds hold out (:func:`slmlab.models.folds.planes_held_out`: too few stage positions, however many depths
    a two-level plate gives them), nothing measured says how a candidate bends between the depths (module
    docstring, step 2). The pinhole pair judges it where it describes the rig: ``describes`` (the stage
    step found it within :data:`slmlab.models.stage_errors.FITS` of the Soloff polynomials' scatter, its
    optics, whatever the stage's errors) or its held-out error in X and Y within :data:`MARGIN` of the best
    candidate's. Perspective sets its bend, and a candidate's difference from it there is an error the user
    will see on top of its held-out one: in X and Y they add in quadrature; in Z, where the pinhole's own error
    between the depths is as large, :data:`PINHOLE_Z_SHARE` of it adds in quadrature, and a candidate is dropped
    where it differs by more than :data:`PINHOLE_Z_BEND` times the larger held-out error. Otherwise a plain
    polynomial is dropped where it disagrees with every depth-pinned candidate (direct, soloff) by more than
    :data:`BETWEEN_DEPTHS` times the larger held-out error (:func:`_drop_if_bent`), and a depth-pinned candidate
    where it disagrees so with every other candidate standing while two of those agree (module docstring,
    step 2). On stage moves the arms take the depths' place (:func:`_between_arms_guard`)."""
    if mode == "moves":
        return _between_arms_guard(pts, fitted, cv, skipped), {}
    judged = {c: list(e) for c, e in cv.items()}
    depths = distinct_levels(world)
    where = f"the {depths} calibrated depths"
    pinned = [c for c in ("direct", "soloff") if c in cv]
    if depths < 2 or planes_held_out(pts, mode) or not (pinned or "pinhole" in cv):
        return judged, {}
    w = between_depths(pts, world)
    if not len(w):
        return judged, {}
    gap = _gap({c: fitted[c].reconstruct(w) for c in cv})
    if "pinhole" in cv and (describes or all(cv["pinhole"][k] <= (1 + MARGIN) * min(e[k] for e in cv.values())
                                             for k in (0, 1))):
        gaps = {c: [0.0 if c == "pinhole" else gap(c, "pinhole", k) for k in range(3)] for c in cv}
        share = (1.0, 1.0, PINHOLE_Z_SHARE)  # X, Y: the whole difference; Z: the candidate's share of it
        for c in cv:
            judged[c] = [float(np.hypot(e, s * g)) for e, g, s in zip(cv[c], gaps[c], share)]
            if c != "pinhole":  # Z: a bend beyond both models' scatter drops it
                _drop_if_bent(judged, skipped, cv, c, 2, {"pinhole": gaps[c][2]}, where, PINHOLE_Z_BEND)
        return judged, gaps
    for k in range(3):
        for label in [c for c in cv if _is_polynomial(c)] if pinned else []:
            _drop_if_bent(judged, skipped, cv, label, k, {r: gap(label, r, k) for r in pinned}, where)
        _drop_bent_pinned(judged, skipped, cv, pinned, k, lambda a, b: max(gap(a, b, k), gap(b, a, k)), where)
    return judged, {}


def _gap(recon: dict[str, np.ndarray]):
    """``gap(a, b, k) -> float``: the RMS difference [mm] of candidate ``b``'s coordinate ``k`` from candidate
    ``a``'s reconstructions ``recon`` of the same image points, net of the affine map between the two (a frame,
    not a bend)."""
    def gap(a: str, b: str, k: int) -> float:
        ok = np.isfinite(recon[a]).all(axis=1) & np.isfinite(recon[b][:, k])   # a point one cannot reconstruct
        if ok.sum() < 5:                                                        # says nothing of a bend
            return float("nan")
        x = np.column_stack([recon[a][ok], np.ones(int(ok.sum()))])
        coef, *_ = np.linalg.lstsq(x, recon[b][ok, k], rcond=None)
        return float(np.sqrt(np.mean((x @ coef - recon[b][ok, k]) ** 2)))
    return gap


def _between_arms_guard(pts, fitted: dict, cv: dict, skipped: dict) -> dict[str, list[float]]:
    """The error [mm] each candidate is chosen by on stage moves, per coordinate: its held-out one, or infinity
    where it bends between the arms of the moves (module docstring, step 2). Held-out interior positions lie on
    the arms; a user measures between them too, where every model extrapolates and nothing is pinned by physics.
    Among the candidates whose held-out error is within :data:`BETWEEN_DEPTHS` times the best (those a choice
    could fall on), one is dropped where it differs from every other of them between the arms
    (:func:`slmlab.models.folds.between_arms`) by more than :data:`BETWEEN_DEPTHS` times the larger held-out
    error while two of those agree with each other (:func:`_drop_bent_pinned`): a majority, not a reference."""
    judged = {c: list(e) for c, e in cv.items()}
    w = between_arms(pts)
    if len(cv) < 3 or not len(w):
        return judged
    gap = _gap({c: fitted[c].reconstruct(w) for c in cv})
    for k in range(3):
        low = min(e[k] for e in cv.values())
        near = [c for c in cv if cv[c][k] <= BETWEEN_DEPTHS * low]
        _drop_bent_pinned(judged, skipped, cv, near, k, lambda a, b: max(gap(a, b, k), gap(b, a, k)),
                          "the arms of the stage's moves", near)
    return judged


def _drop_bent_pinned(judged: dict, skipped: dict, cv: dict, pinned: list[str], k: int, gap2, where: str,
                      voters: list[str] | None = None):
    """Drop for coordinate ``k`` each depth-pinned candidate that differs between the depths (``where``: between
    what, for the reason) from every other candidate standing (of ``voters``, if given; ``gap2(a, b)``: their RMS
    difference there, both ways) by more than :data:`BETWEEN_DEPTHS` times the larger held-out error, where two
    of those others agree within it (module docstring, step 2). Every pinned candidate is judged against the
    same candidates, so the order of the candidates does not matter."""
    standing = [r for r in (cv if voters is None else voters) if np.isfinite(judged[r][k])]
    if not any(c in standing for c in pinned):
        return
    gaps = {a: {} for a in standing}
    for i, a in enumerate(standing):  # each pair once: the difference is taken both ways already
        for b in standing[i + 1:]:
            gaps[a][b] = gaps[b][a] = gap2(a, b)
    drop = []
    for label in [c for c in pinned if c in standing]:
        others = [r for r in standing if r != label]
        agree = any(not _bent(gaps[a][b], cv[a][k], cv[b][k]) for i, a in enumerate(others) for b in others[i + 1:])
        if agree and all(_bent(gaps[label][r], cv[label][k], cv[r][k]) for r in others):
            drop.append(label)
    for label in drop:
        _drop_if_bent(judged, skipped, cv, label, k, gaps[label], where)


def _drop_if_bent(judged: dict, skipped: dict, cv: dict, label: str, k: int, gaps: dict[str, float], where: str,
                  limit: float = BETWEEN_DEPTHS):
    """Drop ``label`` for coordinate ``k`` (``judged`` to infinity, the reason in ``skipped``) where it differs
    between the depths (``where``: between what, for the reason) from every reference in ``gaps``
    (``{reference: RMS difference [mm]}``) by more than ``limit`` times the larger of the two held-out errors."""
    if all(_bent(g, cv[label][k], cv[r][k], limit) for r, g in gaps.items()):
        judged[label][k] = float("inf")
        skipped[f"{label} ({'XYZ'[k]})"] = (f"bends between {where}: "
                                           + ", ".join(f"{1e3 * g:.3g} um from {r}" for r, g in gaps.items())
                                           + f", held-out {1e3 * cv[label][k]:.3g} um (theirs from "
                                           + f"{1e3 * min(cv[r][k] for r in gaps):.3g} um)")


def _bent(gap_mm: float, a_mm: float, b_mm: float, limit: float = BETWEEN_DEPTHS) -> bool:
    """Whether two candidates with held-out errors ``a_mm`` and ``b_mm`` differ between the depths by
    ``gap_mm``, more than ``limit`` times the larger: one of them bends where nothing was measured."""
    return gap_mm > limit * max(a_mm, b_mm)
