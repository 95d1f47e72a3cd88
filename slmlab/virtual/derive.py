"""The ``paper`` preset derived from the paper's own numbers, and the simulator's nominal values beside them.

The preset's distortion, camera mounting and stage are found so that the paper's estimators (§3–§5), run on
simulated calibration tests, return its Tables 1, 2 and 4 (:func:`derive_paper_preset`). This is the one
part of the virtual microscope that depends on the paper's method, and why the agreements with those tables
hold by construction.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd

from ..paper.chain import fit_paper
from ..paper.reference import paper_reference
from .microscope import Microscope, describe
from .presets import preset
from .sessions import paper_test
from .simulate import simulate_set

__all__ = ["PRESET_TARGETS", "paper_estimates", "derive_paper_preset", "nominal_vs_paper"]


def nominal_vs_paper(microscope: Microscope) -> pd.DataFrame:
    """The model parameters the microscope implies to first order, beside the paper's values (Table 4, §5.1).

    These are the simulator's *nominal* values, from its geometry alone; what the paper's method estimates
    from simulated data (which also holds optical effects, see the ``paper`` preset's notes) is computed in
    notebooks 04–05.
    """
    d = describe(microscope).set_index("quantity")["value"]
    t4 = paper_reference("table4")
    rows = [
        ("thetaX_deg", d["θX (nominal)"], t4["thetaX_deg"]["mean"]),
        ("EX_mm_per_px", d["EX, EY (nominal)"], t4["EX_mm_per_px"]["mean"]),
        ("EY_mm_per_px", d["EX, EY (nominal)"], t4["EY_mm_per_px"]["mean"]),
        ("EZ_mm_per_px", d["EZ (nominal)"], t4["EZ_mm_per_px"]["mean"]),
        ("KYX", d["KYX ≈ -y_skew"], t4["KYX"]["mean"]),
        ("KYZ", d["KYZ ≈ -y_tilt"], t4["KYZ"]["mean"]),
        ("KZX", d["KZX ≈ -z_tilt_x"], t4["KZX"]["mean"]),
        ("KZY", d["KZY ≈ -z_tilt_y"], t4["KZY"]["mean"]),
    ]
    df = pd.DataFrame(rows, columns=["parameter", "simulator_nominal", "paper"])
    df["simulator_nominal"] = df["simulator_nominal"].astype(float)
    df["relative_difference_percent"] = 100 * (df["simulator_nominal"] / df["paper"] - 1)
    return df


#: what the paper's estimators must return on the ``paper`` preset (Tables 1, 2, 4): the targets of
#: :func:`derive_paper_preset`
PRESET_TARGETS = {"aD": 6.5365e-6, "a_abs": (1.73e-6 + 1.54e-6) / 2, "vertex_px": 0.0123 / (2 * 6.5365e-6),
                  "alpha_deg": -0.1443, "dw2_px": 2.0731, "thetaX_deg": 3.0347, "KYX": -0.0051, "KYZ": -0.0214,
                  "KZX": -0.0057, "KZY": -0.0143}


def paper_estimates(microscope: Microscope, seeds=(1, 2, 3)) -> dict:
    """Mean over Test 1 sets (one per seed) of what the paper's estimators return (the disparity by the joint
    fit of Eqs 13–16): the keys of :data:`PRESET_TARGETS`."""
    acc: dict[str, list] = {k: [] for k in PRESET_TARGETS}
    for s in seeds:
        p, dist, align = fit_paper(simulate_set(microscope, paper_test(1), seed=s))
        d = p.disparity
        vals = {"aD": d.aD, "a_abs": (abs(p.left.a) + abs(p.right.a)) / 2, "vertex_px": -d.bD / (2 * d.aD),
                "alpha_deg": p.alpha_deg, "dw2_px": p.dw2_px, "thetaX_deg": p.thetaX_deg,
                **{k: p.K[k] for k in ("KYX", "KYZ", "KZX", "KZY")}}
        for k, v in vals.items():
            acc[k].append(v)
    return {k: float(np.mean(v)) for k, v in acc.items()}


def derive_paper_preset(start: Microscope | None = None, *, seeds=(1, 2, 3), iterations: int = 20,
                        damping: float = 0.9, tolerance: float = 2e-3, verbose: bool = False):
    """The ``paper`` preset's optics and stage, found so that the paper's estimators return Tables 1, 2 and
    4 (:data:`PRESET_TARGETS`), by a damped fixed-point iteration from ``start`` (default: the preset).

    Each parameter answers for one estimate, through the first-order physics of the module docstring:
    decentring ``p1`` and thin prism ``s1`` for ``aD = 2(3p1 + s1)·pixel`` and Table 1's
    ``|a| = (p1 + s1)·pixel`` (opposite signs in the two views); the principal points' ``w1`` for the
    parabola's vertex ``−bD/(2·aD)``; the cameras' rotations (``∓r``) for ``α ≈ −2r + c``; the right principal
    point's ``w2`` for ``δw2``; the stage's rotation for ``θX ≈ −rotation + c`` and its skew and tilts for the
    four ``K ≈ −(direction cosine) + c``. Returns the microscope and the last estimates; stops when every
    estimate is within ``tolerance`` (relative) of its target."""
    m = start or preset("paper")
    px = m.optics.pixel_mm
    for it in range(iterations):
        est = paper_estimates(m, seeds)
        err = {k: est[k] / PRESET_TARGETS[k] - 1 for k in PRESET_TARGETS}
        if verbose:
            print(it, {k: f"{v:+.4f}" for k, v in err.items()})
        if max(abs(v) for v in err.values()) < tolerance:
            break
        o, st = m.optics, m.stage
        p1, s1 = o.left.decentring_per_mm, o.left.thin_prism_per_mm
        # [aD, |a|] = pixel · [[6, 2], [1, 1]] @ [p1, s1]
        d = np.linalg.solve(px * np.array([[6.0, 2.0], [1.0, 1.0]]),
                            [PRESET_TARGETS["aD"] - est["aD"], PRESET_TARGETS["a_abs"] - est["a_abs"]])
        p1, s1 = p1 + damping * d[0], s1 + damping * d[1]
        shift = damping * (PRESET_TARGETS["vertex_px"] - est["vertex_px"])
        r = o.right.rotation_deg + damping * (est["alpha_deg"] - PRESET_TARGETS["alpha_deg"]) / 2
        ppl, ppr = o.left.principal_point_px, o.right.principal_point_px
        left = replace(o.left, decentring_per_mm=p1, thin_prism_per_mm=s1, rotation_deg=-r,
                       principal_point_px=(ppl[0] + shift, ppl[1]))
        right = replace(o.right, decentring_per_mm=-p1, thin_prism_per_mm=-s1, rotation_deg=r,
                        principal_point_px=(ppr[0] + shift, ppr[1] - damping * (PRESET_TARGETS["dw2_px"] - est["dw2_px"])))
        stage = replace(st, rotation_deg=st.rotation_deg - damping * (PRESET_TARGETS["thetaX_deg"] - est["thetaX_deg"]),
                        y_skew=st.y_skew - damping * (PRESET_TARGETS["KYX"] - est["KYX"]),
                        y_tilt=st.y_tilt - damping * (PRESET_TARGETS["KYZ"] - est["KYZ"]),
                        z_tilt_x=st.z_tilt_x - damping * (PRESET_TARGETS["KZX"] - est["KZX"]),
                        z_tilt_y=st.z_tilt_y - damping * (PRESET_TARGETS["KZY"] - est["KZY"]))
        m = replace(m, optics=replace(o, left=left, right=right), stage=stage)
    return m, est
