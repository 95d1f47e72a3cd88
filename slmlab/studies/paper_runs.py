"""The paper's estimates over repeated simulations (Tables 2–4, §4's disparity correction).

Each study draws fresh simulated sets from the virtual microscope, with seeds derived from one base seed,
fits the paper's chain and collects its parameters, so that a table (:mod:`slmlab.paper.tables`) can show
our mean ± spread beside the paper's reported values.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd

from ..io import IMAGE_COLUMNS
from ..models import calibrate
from ..paper.alignment import estimate_alignment, recovered_share, sequence_coordinates
from ..paper.chain import fit_paper
from ..paper.distortion import estimate_distortion
from ..paper.evaluation import evaluate
from ..paper.tables import depth_error_profile
from ..virtual.microscope import Microscope
from ..virtual.sessions import Session, paper_test, validation_session
from ..virtual.simulate import simulate_set

__all__ = ["repeat_fits", "disparity_recovery", "depth_error_causes", "DEPTH_ERROR_CASES"]


def repeat_fits(microscope: Microscope, sessions: list[Session], seed: int, **fit_options) -> pd.DataFrame:
    """Fit the paper's chain (Model 2) on one fresh set per session; one row of parameters per set."""
    seeds = np.random.SeedSequence(seed).generate_state(len(sessions))
    rows = []
    for s, sd in zip(sessions, seeds):
        params, dist, align = fit_paper(simulate_set(microscope, s, seed=int(sd)), **fit_options)
        rows.append({"session": s.name, "seed": int(sd), **params.as_dict(),
                     "alpha_std_over_points_deg": float(np.degrees(align.alpha_std_rad)),
                     "dw2_std_over_samples_px": align.dw2_std_px,
                     **{f"{k}_single_pass": getattr(align.disparity["single-pass"], a)
                        for k, a in (("aD", "aD"), ("bD", "bD"), ("cD_px", "cD_px"))}})
    return pd.DataFrame(rows)


def disparity_recovery(microscope: Microscope, cases, seed: int = 1) -> pd.DataFrame:
    """How much of the disparity's curvature the single pass of Eqs 13–16 recovers (a line per dot, then one
    quadratic through all their residuals), over
    layouts: each case ``(positions along X, plate pitch [mm])`` is a Test 1 session with that many X
    positions 0.1 mm apart and the 7 × 7 plate at that pitch. Per case: the ratio of the plate's width to a
    dot's path length on the image, the single pass's ``aD`` over the joint fit's (recovered), and the
    pooled-regression attenuation ``Var(t²)/(Var(t²) + 4·σm²·σt²)`` (predicted)."""
    rows = []
    for n_x, pitch in cases:
        m = replace(microscope, moving_plate=replace(microscope.moving_plate, pitch_mm=float(pitch)))
        cal = simulate_set(m, Session(step_mm=0.1, positions=(int(n_x), 15, 16), name=f"x{n_x}"), seed=seed)
        dist = estimate_distortion(cal.sequence("grid"))
        align = estimate_alignment(cal, dist.apply)
        xs = sequence_coordinates(cal, "X", dist.apply)
        xs[["wl1", "wl2", "wr1", "wr2"]] = align.align(xs[["wl1", "wl2", "wr1", "wr2"]].to_numpy(float))
        r = recovered_share(xs)
        rows.append({"positions_X": int(n_x), "pitch_mm": float(pitch),
                     "plate_width_over_path_length": r["plate_width_over_path_length"],
                     "recovered_share": r["recovered"], "predicted_share": r["predicted"]})
    return pd.DataFrame(rows)


#: the microscopes of :func:`depth_error_causes`: the preset as it is, without perspective, with a fifth of
#: its decentred distortion
DEPTH_ERROR_CASES = ("as is", "without perspective (L → ∞)", "decentred distortion × 0.2")


def _case(microscope: Microscope, case: str) -> Microscope:
    o = microscope.optics
    if case == DEPTH_ERROR_CASES[1]:
        return replace(microscope, optics=replace(o, perspective_distance_mm=1e9))
    if case == DEPTH_ERROR_CASES[2]:
        views = [replace(v, decentring_per_mm=0.2 * v.decentring_per_mm, thin_prism_per_mm=0.2 * v.thin_prism_per_mm)
                 for v in (o.left, o.right)]
        return replace(microscope, optics=replace(o, left=views[0], right=views[1]))
    return microscope


def depth_error_causes(microscope: Microscope, model: str = "paper-m2", *, calibration_seed: int = 1,
                       validation_seed: int = 101) -> pd.DataFrame:
    """What shapes ``E_Z,Z`` along the validation's Z sequence (Fig 15): ``model`` calibrated on Test 1 and
    evaluated on the §6 validation run, on the microscope as it is, without perspective (its central
    projection's depth dependence removed) and with a fifth of its decentred distortion.

    Per case: the estimated ``EZ`` [mm/px]; of ``E_Z,Z``, the mean over the plate mid-way along the run and
    at its end, the spread across the plate and its slope along the plate's x at the end
    (:func:`slmlab.paper.tables.depth_error_profile`), and the largest magnitude [µm]; of ``E_Z,X`` and
    ``E_Z,Y``, the spread across the plate at the end (perspective moves off-axis dots sideways by
    ``x·ΔZ/L``, which one slope ``KZX`` or ``KZY`` for all dots cannot follow)."""
    rows = []
    for case in DEPTH_ERROR_CASES:
        m = _case(microscope, case)
        fitted = calibrate(simulate_set(m, paper_test(1), seed=calibration_seed), model)
        ev = evaluate(fitted, simulate_set(m, validation_session(), seed=validation_seed))
        p = depth_error_profile(ev, m.moving_plate.pitch_mm)
        last = p["displacement_mm"].abs().idxmax()
        lateral = {c: depth_error_profile(ev, m.moving_plate.pitch_mm, component=c).loc[last] for c in "XY"}
        end = p.loc[last]
        mid = p.loc[(p["displacement_mm"] - p["displacement_mm"].min() / 2).abs().idxmin()]
        rows.append({"microscope": case, "EZ_mm_per_px": fitted.parameters_dict()["EZ_mm_per_px"],
                     "mid_displacement_mm": mid["displacement_mm"], "mean_mid_um": mid["mean_um"],
                     "end_displacement_mm": end["displacement_mm"], "mean_end_um": end["mean_um"],
                     "spread_end_um": end["spread_um"], "across_plate_end_um_per_mm": end["across_plate_um_per_mm"],
                     "max_abs_um": float(p["max_abs_um"].max()),
                     **{f"spread_end_Z{c}_um": float(lateral[c]["spread_um"]) for c in "XY"}})
    return pd.DataFrame(rows)
