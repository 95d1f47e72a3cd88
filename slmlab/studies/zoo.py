"""The zoo: how well each model calibrates each virtual rig (:mod:`slmlab.virtual.rigs`) from each design
(:mod:`slmlab.virtual.designs`), against the truth floor and the best plain polynomial.

* :func:`compare_models`: a rig, a design (:mod:`slmlab.virtual.designs`) and a held-out validation set of
  random points in the calibrated volume; per coordinate RMS error (net of one common offset, in the frame
  the design calibrates in) of each model (:func:`slmlab.calibrate`), of plain least-squares polynomials of
  degree 1–4 in the four image coordinates (:class:`slmlab.models.reference.PlainPolynomial`), and of the true model on the same
  noisy centres (the floor).
"""

from __future__ import annotations

import time

import numpy as np
import pandas as pd

from ..errors import SlmlabError
from ..io import IMAGE_COLUMNS
from ..models import calibrate
from ..models.reference import DEGREES
from ..virtual.designs import DESIGNS, design_frame, simulate_design, validation_set
from .realrigs import rms_after_offset

__all__ = ["MODELS", "POLY_DEGREES", "compare_models", "run_zoo", "ratio_table"]

MODELS = ("auto", "direct", "soloff", "quadratic", "pinhole")
POLY_DEGREES = DEGREES


def compare_models(rig, design: str, *, seed: int = 1, models=MODELS, n_validation: int = 1500) -> pd.DataFrame:
    """Per coordinate RMS error [µm] on a held-out validation set (:func:`validation_set`) of each model
    calibrated on ``design`` (``pinhole-f``: the pinhole model started from the rig's true focal length), of
    plain polynomials of degree :data:`POLY_DEGREES` and of the true model (the
    floor), in the design's frame net of one common offset; ``error``: why a model could not calibrate."""
    cal = simulate_design(rig, design, seed=seed)
    val = validation_set(rig, cal, n_validation, seed=seed + 1000)
    frame = design_frame(rig, design)
    w = val.points[IMAGE_COLUMNS].to_numpy(float)
    truth = val.truth[["X_mm", "Y_mm", "Z_mm"]].to_numpy(float) @ frame.T
    origin = np.asarray(val.meta["simulator"]["stage_origin_mm"])
    floor = rig.microscope_to_stage(rig.triangulate(w), origin) @ frame.T
    rows = [("floor", floor, "")]
    cam = rig.camera("l")
    runs = [(name, name, {}) for name in models]
    if "pinhole" in models:  # the pinhole model again, told the true focal length as a start (a user knows the lens)
        runs.append(("pinhole-f", "pinhole", {"f_guess_px": float(cam.x0[2] / cam.pixel_mm)}))
    for label, name, options in runs:
        try:
            model = calibrate(cal, name, **options)
            rows.append((label, model.reconstruct(w), model.describe()))
        except SlmlabError as exc:
            rows.append((label, None, f"error: {exc}"))
    for degree in POLY_DEGREES:
        rows.append((f"poly{degree}", calibrate(cal, "polynomial", degree=degree).reconstruct(w), ""))
    out = []
    for name, p, note in rows:
        e = 1e3 * rms_after_offset(p - truth) if p is not None else np.full(3, np.nan)
        out.append({"rig": rig.preset, "design": design, "model": name, "X_um": e[0], "Y_um": e[1], "Z_um": e[2],
                    "note": note})
    return pd.DataFrame(out)


def run_zoo(rigs, designs=tuple(DESIGNS), *, seed: int = 1, models=MODELS, n_validation: int = 1500) -> pd.DataFrame:
    """:func:`compare_models` for every rig and design (the pinhole model only where it applies: the
    stage-sequence design), one table; ``seconds`` the time each design took (minutes on two cores)."""
    frames = []
    for rig in rigs:
        for design in designs:
            start = time.perf_counter()
            use = models if design == "stage-sequences" else tuple(m for m in models if m != "pinhole")
            df = compare_models(rig, design, seed=seed, models=use, n_validation=n_validation)
            frames.append(df.assign(seconds=time.perf_counter() - start))
    return pd.concat(frames, ignore_index=True)


def ratio_table(results: pd.DataFrame) -> pd.DataFrame:
    """Per rig, design and model: RMS over the floor and over the best plain polynomial (per coordinate)."""
    rows = []
    for (rig, design), g in results.groupby(["rig", "design"], sort=False):
        g = g.set_index("model")
        floor = g.loc["floor"]
        polys = g.loc[[m for m in g.index if m.startswith("poly")]]
        for model, r in g.iterrows():
            if model == "floor" or model.startswith("poly"):
                continue
            row = {"rig": rig, "design": design, "model": model}
            for c in "XYZ":
                row[f"{c}_vs_floor"] = r[f"{c}_um"] / floor[f"{c}_um"]
                row[f"{c}_vs_poly"] = r[f"{c}_um"] / polys[f"{c}_um"].min()
            rows.append(row)
    return pd.DataFrame(rows)
