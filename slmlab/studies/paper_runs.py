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
from ..paper.alignment import estimate_alignment, recovered_share, sequence_coordinates
from ..paper.chain import fit_paper
from ..paper.distortion import estimate_distortion
from ..virtual.microscope import Microscope
from ..virtual.sessions import Session
from ..virtual.simulate import simulate_set

__all__ = ["repeat_fits", "disparity_recovery"]


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
    """How much of the disparity's curvature the first reading's single pass recovers (METHOD.md §2), over
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
