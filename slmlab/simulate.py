"""Presets of the virtual CMO microscope and simulated calibration sessions (METHOD.md §0, §6, §7).

A *session* is what the paper images: one stereo pair of the large 27 × 29 plate (the ``grid`` sequence,
§3) and the 7 × 7 plate carried by the stage in equal steps along X, Y and Z (§4–§6). The five calibration
tests of Table 3 and the validation run of §6 are sessions.

The ``paper`` preset, and why each value
---------------------------------------
Image and scale (§0)
    2048 × 2048 px at 3 µm/px: the 27 × 29 plate (5.6 × 5.2 mm) fills the view. Table 1's column-bend
    vertex (``-b/2a`` ≈ 902 px in ``w2``) puts the objective axis's ``w2`` near 902 px.
Convergence (§0, Table 4)
    ``EZ = 0.0125 mm/px`` with 3 µm/px means a disparity of 1/(0.0125) = 80 px per mm of depth, i.e.
    ``2 tan(γ/2) = 0.003/0.0125``: ``γ = 13.69°``.
Perspective distance
    The paper's Model 2 keeps ``E_Z,X`` and ``E_Z,Y`` within ±7.5 µm for 95 % of samples (Fig 16) over a
    2.25 mm Z travel with dots up to 0.9 mm off axis. Perspective adds ``x ΔZ / L`` there, which a linear
    model cannot absorb, so ``L ≳ 0.9 · 2.25 / 0.0075 ≈ 270 mm``: we take ``L = 300 mm`` (0.33 % per mm).
    The ``leica`` preset uses the −1.6 %/mm measured on a real Leica CMO microscope (``L = 62.5 mm``).
The rest: derived so that the paper's estimators return its tables (:func:`derive_paper_preset`)
    The values below are what a damped fixed-point iteration returns when the paper's estimators (the
    disparity by METHOD.md §2's joint fit) are run on Test 1 sets of seeds 1–3 and asked to land on Tables 1,
    2 and 4 (:data:`PRESET_TARGETS`); ``derive_paper_preset()`` reproduces them in a few seconds. Each
    parameter answers for one estimate, through first-order physics:

    * Distortion (Tables 1, 2): the decentring ``p1`` and thin prism ``s1`` of the off-axis zones (opposite
      signs in the two views) set the column bend ``a = (p1 + s1)·pixel`` and the disparity curvature
      ``aD = 2 (3 p1 + s1)·pixel``; Table 2's ``aD = 6.54e-6`` and Table 1's ``|a| ≈ 1.64e-6`` give
      ``p1 = 2.72e-4 /mm``, ``s1 = 2.74e-4 /mm``. The row fan that follows, ``λ = 2 p1·pixel = 1.63e-6``,
      was not fitted and matches the paper's left view (1.61e-6; its right view's −9.96e-6 has no single
      cause in METHOD.md §7 that leaves ``a`` and ``aD`` symmetric: we keep the symmetric physics). A small
      radial term (0.3 px at the corners) is common to both sub-systems.
    * Objective axis (Table 2): the fitted parabola's vertex ``−bD/(2aD)`` = 941 px puts the axis at
      ``w1`` ≈ 1021 px, near the image centre: the right view's 0.1 % larger magnification adds a linear
      disparity trend along ``w1`` that moves the vertex 80 px from the axis. With ``cD = bD²/(4aD)``
      (METHOD.md §2) ``cD`` follows.
    * Cameras (Table 2): the paper measures ``α`` and ``δw2`` *after* §3's correction, which is applied
      about the image's top-left origin (``w2·(1 + λ w1)`` adds a path slope ``λ·w2``, opposite in the two
      views). Camera rotations of ∓0.1516° and a right principal point 3.8 px lower make the estimators
      return ``α = −0.1443°``, ``δw2 = 2.07 px``.
    * Stage (Table 4): to first order ``θX = −rotation``, ``KYX = −y_skew``, ``KYZ = −y_tilt``,
      ``KZX = −z_tilt_x``, ``KZY = −z_tilt_y`` (see :class:`slmlab.microscope.Stage`). But what the
      estimators return also holds optical effects: §3's correction about the top-left origin tilts the
      paths (θX), and the cameras' rotation mismatch, which §4's ``α`` removes only in part, rotates
      ``w1_r`` against ``w2``, so disparity, hence Z, changes along the Y sequence. Finding: the paper's
      ``KYZ = −0.0214`` is only partly a stage tilt: with the stage's Y axis untilted the estimator still
      returns −0.0083 (the optics), and the stage's tilt (``y_tilt = 0.0132``) supplies the rest. A small
      X-axis tilt (0.0003) that no paper term models. Scale
      errors of 1e-4, a 0.3 µm periodic lead error (1 mm lead), 0.3 µm straightness and 0.3 µm positioning
      noise are typical of a good micrometre stage (METHOD.md §7: 0.1–2 µm).
Dot finder
    0.02 px in focus rising to 0.05 px at the edge of the ±1.13 mm depth of field.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pandas as pd

from . import __version__
from .errors import SlmlabError
from .io import IMAGE_COLUMNS, POINT_COLUMNS, SET_FORMAT, TRUTH_COLUMNS, CalibrationSet
from .microscope import CentroidNoise, Microscope, Optics, Plate, Stage, View

__all__ = ["PRESETS", "preset", "Session", "PAPER_TESTS", "paper_test", "validation_session", "simulate_set", "describe", "depth_response", "nominal_vs_paper", "tilted_session", "volume_session", "noise_floor",
           "stage_origin", "zstack_session", "zstack_plate", "zstack_frame", "stepped_target", "target_set",
           "PRESET_TARGETS", "paper_estimates", "derive_paper_preset"]

# --------------------------------------------------------------------------------------------- presets
_P1 = 2.719e-4  # decentring [1/mm]
_S1 = 2.740e-4  # thin prism [1/mm]
_K1 = 3.3e-5  # radial [1/mm²]: 0.3 px at r = 3 mm


def _paper() -> Microscope:
    return Microscope(
        optics=Optics(
            perspective_distance_mm=300.0,
            convergence_deg=13.69,
            pixel_mm=0.003,
            image_size_px=(2048, 2048),
            depth_of_field_mm=1.13,
            inverted=True,
            left=View(decentring_per_mm=_P1, thin_prism_per_mm=_S1, radial_k1_per_mm2=_K1,
                      magnification_ratio=1.0, rotation_deg=-0.1516, principal_point_px=(1021.13, 902.0)),
            right=View(decentring_per_mm=-_P1, thin_prism_per_mm=-_S1, radial_k1_per_mm2=_K1,
                       magnification_ratio=1.001, rotation_deg=0.1516, principal_point_px=(1026.13, 905.81)),
        ),
        stage=Stage(
            rotation_deg=-2.9552, y_skew=0.005227, y_tilt=0.013184, z_tilt_x=0.005822, z_tilt_y=0.015370, x_tilt=0.0003,
            scale_error=(1.0e-4, -0.8e-4, 1.5e-4), straightness_um=(0.3, 0.3, 0.3),
            lead_error_um=0.3, lead_mm=1.0, lead_phase_deg=(10.0, 130.0, 250.0),
            positioning_noise_um=0.3, travel_mm=4.0,
        ),
        noise=CentroidNoise(in_focus_px=0.02, at_dof_edge_px=0.05),
        grid_plate=Plate(27, 29, 0.2, 0.1, fabrication_tolerance_um=0.25, rotation_deg=0.15),
        moving_plate=Plate(7, 7, 0.3, 0.15, fabrication_tolerance_um=0.25, rotation_deg=-2.8, tilt_deg=0.05),
        preset="paper",
    )


def _leica() -> Microscope:
    m = _paper()
    return replace(m, optics=replace(m.optics, perspective_distance_mm=62.5), preset="leica")


def _ideal() -> Microscope:
    """No distortion, (almost) no perspective, a perfect stage aligned with the image, no noise."""
    m = _paper()
    optics = Optics(perspective_distance_mm=1e9, convergence_deg=13.69, pixel_mm=0.003,
                    image_size_px=(2048, 2048), depth_of_field_mm=1.13, inverted=True,
                    left=View(principal_point_px=(1024.0, 1024.0)), right=View(principal_point_px=(1024.0, 1024.0)))
    return replace(m, optics=optics, stage=Stage(), noise=CentroidNoise(0.0, 0.0),
                   grid_plate=replace(m.grid_plate, fabrication_tolerance_um=0.0, rotation_deg=0.0),
                   moving_plate=replace(m.moving_plate, fabrication_tolerance_um=0.0, rotation_deg=0.0, tilt_deg=0.0),
                   preset="ideal")


PRESETS = {
    "paper": (_paper, "optics and stage chosen so that the paper's method lands near its Tables 1, 2 and 4"),
    "leica": (_leica, "the paper preset with the strong perspective of a real Leica CMO (-1.6 %/mm, L = 62.5 mm)"),
    "ideal": (_ideal, "no distortion, no perspective, a perfect stage aligned with the image, noise-free centres"),
}


def preset(name: str = "paper", **changes) -> Microscope:
    """The virtual microscope of a named preset, optionally with top-level parts replaced.

    >>> m = preset("paper")
    >>> m.optics.convergence_deg
    13.69
    """
    if name not in PRESETS:
        raise SlmlabError(f"unknown preset {name!r}; choose one of {', '.join(PRESETS)}")
    m = PRESETS[name][0]()
    return replace(m, **changes) if changes else m


# --------------------------------------------------------------------------------------------- sessions
@dataclass(frozen=True)
class Session:
    """What a calibration session images (paper §6, Table 3).

    Attributes
    ----------
    step_mm
        the stage step ``sd`` of the axis sequences [mm]: one value for all three, or ``(X, Y, Z)``.
    positions
        number of positions ``(NUMX, NUMY, NUMZ)`` of the X, Y, Z sequences.
    grid
        whether the static pair of the 27 × 29 plate (the ``grid`` sequence) is included.
    name
        a label for reports.
    tilt_poses_deg
        poses ``(tilt about x, tilt about y)`` [degree] of the 7 × 7 plate held by hand at the centre stage
        position, as a Halcon or OpenCV user calibrates: the sequence ``T`` (its stage columns are the
        centre position; the tilt is not a stage move).
    """

    step_mm: float | tuple[float, float, float] = 0.1
    positions: tuple[int, int, int] = (42, 30, 32)
    grid: bool = True
    name: str = "test1"
    tilt_poses_deg: tuple[tuple[float, float], ...] = ()
    volume_positions: int = 0
    volume_seed: int = 0

    @property
    def steps_mm(self) -> np.ndarray:
        """The step of the X, Y and Z sequences [mm]."""
        return np.broadcast_to(np.asarray(self.step_mm, dtype=float), (3,)).copy()

    def centre_mm(self) -> np.ndarray:
        """Stage position ``(X, Y, Z)`` at the middle of the three sequences [mm]; it is placed at the
        centre of the field, in focus."""
        if self.volume_positions and not any(self.positions):
            return np.array([-4.1, 2.9, -2.25]) / 2
        span = (np.asarray(self.positions) - 1) * self.steps_mm
        return np.array([-1.0, 1.0, -1.0]) * span / 2

    def stage_positions(self) -> dict[str, np.ndarray]:
        """Commanded stage positions ``(n, 3)`` [mm] of each sequence.

        X runs from 0 to ``-(NUMX-1)·sd``, Y from 0 to ``+(NUMY-1)·sd``, Z from 0 to ``-(NUMZ-1)·sd``
        (METHOD.md §6: X in [−4.1, 0], Y in [0, 2.9], Z in [−2.25, 0]); the other two coordinates sit at the
        middle of their ranges.
        """
        c = self.centre_mm()
        out = {}
        if self.grid:
            out["grid"] = c[None, :]
        for axis, (n, sign) in enumerate(zip(self.positions, (-1.0, 1.0, -1.0))):
            if n == 0:
                continue
            s = np.repeat(c[None, :], n, axis=0)
            s[:, axis] = sign * self.steps_mm[axis] * np.arange(n)
            out["XYZ"[axis]] = s
        if self.tilt_poses_deg:
            out["T"] = np.repeat(c[None, :], len(self.tilt_poses_deg), axis=0)
        if self.volume_positions:
            lo = np.minimum(0.0, 2 * c)
            hi = np.maximum(0.0, 2 * c)
            rng = np.random.default_rng([self.volume_seed, 11])
            v = rng.uniform(lo, hi, size=(self.volume_positions, 3))
            v[0] = c  # position 1, the reference of the displacements: the middle of the workspace
            out["V"] = v
        return out


#: Table 3: step sd [mm] and (NUMX, NUMY, NUMZ) of the five calibration tests.
PAPER_TESTS = {
    1: (0.1, (42, 30, 32)),
    2: (0.2, (21, 15, 16)),
    3: (0.3, (14, 10, 11)),
    4: (0.4, (9, 8, 8)),
    5: (0.5, (9, 7, 7)),
}


def paper_test(k: int) -> Session:
    """Calibration test ``k`` (1–5) of the paper's Table 3."""
    if k not in PAPER_TESTS:
        raise SlmlabError(f"the paper has calibration tests 1 to 5, not {k}")
    step, n = PAPER_TESTS[k]
    return Session(step_mm=step, positions=n, grid=True, name=f"test{k}")


def validation_session() -> Session:
    """The validation run of §6 at Test 1's conditions: X in [−4.1, 0], Y in [0, 2.9], Z in [−2.25, 0] mm.

    The paper gives the ranges, not the steps. X and Y take Test 1's 0.1 mm (42 and 30 positions); 2.25 mm is
    not a multiple of 0.1 mm, so Z takes 0.075 mm (31 positions, close to Test 1's 32).
    """
    return Session(step_mm=(0.1, 0.1, 0.075), positions=(42, 30, 31), grid=False, name="validation")


def volume_session(n_positions: int = 60, seed: int = 0) -> Session:
    """A validation run ``V`` of random stage positions filling the workspace of Test 1's validation
    (X in [−4.1, 0], Y in [0, 2.9], Z in [−2.25, 0] mm), not only the three axes; position 1 is the middle."""
    base = validation_session()
    return replace(base, positions=(0, 0, 0), grid=False, name="volume", volume_positions=n_positions,
                   volume_seed=seed)


def zstack_session(n_positions: int = 31, step_mm: float | None = None) -> Session:
    """A Z stack alone, as a lab with only a Z stage takes it: ``n_positions`` stage positions ``step_mm``
    apart (default: spanning the validation's Z range [−2.25, 0] mm, 31 × 0.075 mm), X and Y fixed at zero.
    Image it with :func:`zstack_plate`'s field-filling plate (``microscope.replace(moving_plate=zstack_plate())``)."""
    if n_positions < 3:
        raise SlmlabError(f"a Z stack needs at least 3 positions, not {n_positions}")
    step = 2.25 / (n_positions - 1) if step_mm is None else float(step_mm)
    return Session(step_mm=(0.1, 0.1, step), positions=(0, 0, n_positions), grid=False, name="zstack")


def zstack_plate(rotation_deg: float = 0.4, tilt_deg: float = 0.05) -> Plate:
    """A 31 × 31 dot plate at 0.2 mm pitch (6 × 6 mm): it fills the 6.1 mm field, so that a Z stack of it
    alone samples the whole workspace. Mounted by hand: rotated ``rotation_deg`` in its plane and tilted
    ``tilt_deg`` [degree]."""
    return Plate(31, 31, 0.2, 0.1, fabrication_tolerance_um=0.25, rotation_deg=rotation_deg, tilt_deg=tilt_deg)


def zstack_frame(microscope: Microscope, plate: Plate | None = None, orientation: np.ndarray | None = None) -> np.ndarray:
    """The 3 × 3 matrix taking stage-frame displacements [mm] to the frame a Z-stack calibration reconstructs
    in: the plate's x and y axes (:meth:`Plate.nominal_points`, or the columns of ``orientation``, e.g. a
    board's, :func:`slmlab.render.board_orientation`) and the Z stage's direction, as axes."""
    r = (plate or microscope.moving_plate).orientation() if orientation is None else np.asarray(orientation, float)
    basis = np.column_stack([r[:, 0], r[:, 1], microscope.stage.axes[:, 2]])
    return np.linalg.solve(basis, microscope.stage.axes)


def tilted_session(n_poses: int = 16, max_tilt_deg: float = 20.0, *, with_sequences: Session | None = None,
                   seed: int = 0) -> Session:
    """A session in which the 7 × 7 plate is also held at ``n_poses`` tilts (sequence ``T``), about both axes,
    up to ``max_tilt_deg`` (the plate stays within the depth of field), besides the axis sequences of
    ``with_sequences`` (default: Test 1) that map the cameras to the stage."""
    rng = np.random.default_rng(seed)
    ang = rng.uniform(0, 2 * np.pi, n_poses)
    mag = max_tilt_deg * np.sqrt(rng.uniform(0.3, 1.0, n_poses))
    poses = tuple((float(m * np.cos(a)), float(m * np.sin(a))) for m, a in zip(mag, ang))
    base = with_sequences or paper_test(1)
    return replace(base, tilt_poses_deg=poses, name=f"{base.name}+tilted")


def _tilt(tx_deg: float, ty_deg: float) -> np.ndarray:
    a, b = np.radians(tx_deg), np.radians(ty_deg)
    rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    return ry @ rx


def stage_origin(microscope: Microscope, session: Session) -> np.ndarray:
    """Microscope-frame position of stage zero [mm], chosen so that the session's centre stage position
    (:meth:`Session.centre_mm`) puts the plate centre at the middle of the image, in focus."""
    o = microscope.optics
    width, height = o.image_size_px
    m = 1.0 / o.pixel_mm * (-1.0 if o.inverted else 1.0)
    pp = (np.asarray(o.left.principal_point_px) + np.asarray(o.right.principal_point_px)) / 2
    field_centre = np.array([((width - 1) / 2 - pp[0]) / m, ((height - 1) / 2 - pp[1]) / m, 0.0])
    return field_centre - microscope.stage.axes @ session.centre_mm()


# --------------------------------------------------------------------------------------------- simulation
def simulate_set(microscope: Microscope | None = None, session: Session | None = None, seed: int = 0) -> CalibrationSet:
    """Simulate a calibration set: the session's stage positions, the plates' dots seen in both views.

    Parameters
    ----------
    microscope
        the virtual microscope (default: the ``paper`` preset).
    session
        what to image (default: Test 1 of Table 3 with the grid pair).
    seed
        seed of every random draw (plate fabrication, stage positioning, centroid noise): the same seed gives
        byte-identical files.

    Returns
    -------
    CalibrationSet
        ``points`` with noisy centres (NaN where a dot is not wholly inside an image), ``truth`` with the
        noise-free centres and true stage-frame coordinates, and ``meta`` (with the simulator's parameters
        under ``"simulator"``).
    """
    microscope = microscope if microscope is not None else preset("paper")
    session = session if session is not None else paper_test(1)
    plate_rng, stage_rng, noise_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(3))
    origin = stage_origin(microscope, session)
    o = microscope.optics

    # fabricated plates: nominal dot positions plus a uniform error within the tolerance
    plates = {}
    for name, plate in (("grid", microscope.grid_plate), ("moving", microscope.moving_plate)):
        i, j, pts = plate.nominal_points()
        tol = 1e-3 * plate.fabrication_tolerance_um
        pts = pts + np.column_stack([plate_rng.uniform(-tol, tol, (len(pts), 2)), np.zeros(len(pts))])
        plates[name] = (plate, i, j, pts @ plate.orientation().T)

    frames, truths = [], []
    if not session.stage_positions():
        raise SlmlabError("the session images nothing: give it positions along X, Y or Z, the grid pair, "
                          "tilted poses or volume positions")
    for seq, commanded in session.stage_positions().items():
        plate, i, j, offsets = plates["grid" if seq == "grid" else "moving"]
        actual = microscope.stage.actual(commanded, stage_rng)
        centre = microscope.stage_to_microscope(actual, origin)  # plate centre per position
        n_pos, n_dot = len(commanded), len(i)
        if seq == "T":  # the plate held at a tilt about its centre
            per_pose = np.stack([offsets @ _tilt(*pose).T for pose in session.tilt_poses_deg])
            p = (centre[:, None, :] + per_pose).reshape(-1, 3)
        else:
            p = (centre[:, None, :] + offsets[None, :, :]).reshape(-1, 3)
        w_true = microscope.project(p)
        sigma = microscope.noise.sigma_px(p[:, 2], o.depth_of_field_mm)
        w = w_true + noise_rng.normal(size=w_true.shape) * sigma[:, None]
        vis = microscope.visible(w_true, plate.dot_diameter_mm)
        w[:, 0:2][~vis[:, 0]] = np.nan
        w[:, 2:4][~vis[:, 1]] = np.nan
        key = {
            "sequence": np.full(n_pos * n_dot, seq),
            "position": np.repeat(np.arange(1, n_pos + 1), n_dot),
        }
        stage_cols = np.repeat(commanded, n_dot, axis=0)
        frames.append(pd.DataFrame({
            **key,
            "stage_x_mm": stage_cols[:, 0], "stage_y_mm": stage_cols[:, 1], "stage_z_mm": stage_cols[:, 2],
            "row": np.tile(i, n_pos), "col": np.tile(j, n_pos),
            **{c: w[:, k] for k, c in enumerate(IMAGE_COLUMNS)},
        }))
        world = microscope.microscope_to_stage(p, origin)
        truths.append(pd.DataFrame({
            **key, "row": np.tile(i, n_pos), "col": np.tile(j, n_pos),
            **{c: w_true[:, k] for k, c in enumerate(IMAGE_COLUMNS)},
            "X_mm": world[:, 0], "Y_mm": world[:, 1], "Z_mm": world[:, 2],
        }))
    points = pd.concat(frames, ignore_index=True)[POINT_COLUMNS]
    truth = pd.concat(truths, ignore_index=True)[TRUTH_COLUMNS]
    meta = {
        "format": SET_FORMAT,
        "image_size_px": list(o.image_size_px),
        "plates": {"grid": microscope.grid_plate.as_meta(), "moving": microscope.moving_plate.as_meta()},
        "source": f"slmlab {__version__} virtual CMO microscope, preset {microscope.preset}, "
                  f"session {session.name}, seed {seed}",
        "simulator": {
            "microscope": microscope.as_dict(),
            "session": {"name": session.name, "step_mm": [float(v) for v in session.steps_mm],
                        "positions": list(session.positions), "grid": session.grid,
                        "tilt_poses_deg": [list(p) for p in session.tilt_poses_deg]},
            "seed": int(seed),
            "stage_origin_mm": [float(v) for v in origin],
        },
    }
    return CalibrationSet(points=points, meta=meta, truth=truth)


# --------------------------------------------------------------------------------------------- reports
def describe(microscope: Microscope) -> pd.DataFrame:
    """What the microscope's parameters imply, with units: the quantities the paper estimates (θX, EX, EZ,
    K terms to first order), the perspective and the noise floor of METHOD.md §7."""
    o, st, nz = microscope.optics, microscope.stage, microscope.noise
    t = np.tan(np.radians(o.convergence_deg) / 2)
    rows = [
        ("object pixel", 1e3 * o.pixel_mm, "µm/px", "optics.pixel_mm"),
        ("image size", f"{o.image_size_px[0]} × {o.image_size_px[1]}", "px", "optics.image_size_px"),
        ("convergence γ", o.convergence_deg, "degree", "optics.convergence_deg"),
        ("perspective distance L", o.perspective_distance_mm, "mm", "optics.perspective_distance_mm"),
        ("magnification change with depth", 100.0 / o.perspective_distance_mm, "%/mm", "1/L"),
        ("disparity per mm of depth", 2 * t / o.pixel_mm, "px/mm", "2 tan(γ/2) / pixel"),
        ("EZ (nominal)", o.pixel_mm / (2 * t), "mm/px", "pixel / (2 tan(γ/2))"),
        ("EX, EY (nominal)", -o.pixel_mm if o.inverted else o.pixel_mm, "mm/px", "inverted image"),
        ("θX (nominal)", -st.rotation_deg, "degree", "-stage.rotation_deg"),
        ("KYX ≈ -y_skew", -st.y_skew, "-", "stage.y_skew"),
        ("KYZ ≈ -y_tilt", -st.y_tilt, "-", "stage.y_tilt"),
        ("KZX ≈ -z_tilt_x", -st.z_tilt_x, "-", "stage.z_tilt_x"),
        ("KZY ≈ -z_tilt_y", -st.z_tilt_y, "-", "stage.z_tilt_y"),
        ("depth of field", f"±{o.depth_of_field_mm:g}", "mm", "optics.depth_of_field_mm"),
        ("centroid noise in focus", nz.in_focus_px, "px", "noise.in_focus_px"),
        ("noise floor σX in focus", 1e3 * o.pixel_mm * nz.in_focus_px / np.sqrt(2), "µm", "pixel·σc/√2"),
        ("noise floor σZ in focus", 1e3 * o.pixel_mm / (2 * t) * np.sqrt(2) * nz.in_focus_px, "µm", "EZ·√2·σc"),
        ("stage positioning noise", st.positioning_noise_um, "µm", "stage.positioning_noise_um"),
    ]
    return pd.DataFrame(rows, columns=["quantity", "value", "unit", "from"])


def depth_response(microscope: Microscope, z_mm: np.ndarray, *, x_mm: float = 0.0, y_mm: float = 0.0,
                   baseline_mm: float = 1.0) -> pd.DataFrame:
    """Disparity and magnification of each view against depth, measured by projecting points.

    For each height ``z`` a point at ``(x, y, z)`` and one ``baseline_mm`` further along x are projected.

    Returns
    -------
    DataFrame
        ``z_mm``, ``disparity_px`` (``w1_r − w1_l`` of the first point), ``magnification_l_px_per_mm``,
        ``magnification_r_px_per_mm`` (image length of the baseline divided by its length).
    """
    z = np.asarray(z_mm, dtype=float)
    a = np.column_stack([np.full_like(z, x_mm), np.full_like(z, y_mm), z])
    b = a + [baseline_mm, 0.0, 0.0]
    wa, wb = microscope.project(a), microscope.project(b)
    return pd.DataFrame({
        "z_mm": z,
        "disparity_px": wa[:, 2] - wa[:, 0],
        "magnification_l_px_per_mm": np.hypot(*(wb[:, 0:2] - wa[:, 0:2]).T) / baseline_mm,
        "magnification_r_px_per_mm": np.hypot(*(wb[:, 2:4] - wa[:, 2:4]).T) / baseline_mm,
    })


def nominal_vs_paper(microscope: Microscope) -> pd.DataFrame:
    """The model parameters the microscope implies to first order, beside the paper's values (Table 4, §5.1).

    These are the simulator's *nominal* values, from its geometry alone; what the paper's method estimates
    from simulated data (which also holds optical effects, see the ``paper`` preset's notes) is computed in
    notebooks 04–05.
    """
    from .paths import paper_reference

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


def noise_floor(cal: CalibrationSet) -> np.ndarray:
    """The simulator's own true-model triangulation of a simulated set's noisy centres, in the stage frame
    ``(n, 3)`` [mm] (NaN where a dot is missing): what no calibrated model can beat."""
    from .microscope import from_dict

    sim = cal.meta["simulator"]
    m = from_dict(sim["microscope"])
    w = cal.points[IMAGE_COLUMNS].to_numpy(float)
    out = np.full((len(w), 3), np.nan)
    ok = np.isfinite(w).all(axis=1)
    out[ok] = m.microscope_to_stage(m.triangulate(w[ok]), np.asarray(sim["stage_origin_mm"]))
    return out


def stepped_target(rows: int = 31, cols: int = 31, pitch_mm: float = 0.2, steps_mm=(-1.0, -0.5, 0.0, 0.5, 1.0),
                   ) -> "pd.DataFrame":
    """A stepped 3D dot target: a ``rows × cols`` lattice of pitch ``pitch_mm`` whose dots stand on
    ``len(steps_mm)`` heights ``steps_mm`` [mm] in a knight's-move pattern (step ``(row + 2·col) mod n``),
    so that height does not follow ``x`` or ``y`` (a staircase across the field would confound them, and
    one pose could not tell depth from position). Returns ``row, col, x_mm, y_mm, z_mm`` in the target's
    frame (the plate convention of DATA_FORMAT.md for ``x, y``)."""
    i, j = np.meshgrid(np.arange(1, rows + 1), np.arange(1, cols + 1), indexing="ij")
    i, j = i.ravel(), j.ravel()
    band = (i + 2 * j) % len(steps_mm)
    return pd.DataFrame({"row": i, "col": j, "x_mm": ((cols + 1) / 2 - j) * pitch_mm,
                         "y_mm": ((rows + 1) / 2 - i) * pitch_mm, "z_mm": np.asarray(steps_mm, float)[band]})


def target_set(microscope: Microscope, target: "pd.DataFrame", stage_mm, *, seed: int = 0, sequence: str = "K",
               dot_diameter_mm: float = 0.1) -> CalibrationSet:
    """A known-target calibration set (DATA_FORMAT.md): the dots of ``target`` (``row, col, x_mm, y_mm, z_mm``
    in the target's frame, its axes along the stage's) imaged at the commanded stage positions ``stage_mm``
    ``(k, 3)`` [mm] (one row for a single pose), with the stage's errors and the dot finder's noise; the
    target's origin is at the field's centre, in focus, at stage zero. ``truth`` holds the true centres and
    stage-frame positions."""
    stage_mm = np.atleast_2d(np.asarray(stage_mm, float))
    stage_rng, noise_rng = (np.random.default_rng(s) for s in np.random.SeedSequence([seed, 5]).spawn(2))
    origin = stage_origin(microscope, Session(positions=(0, 0, 0), grid=False))
    local = target[["x_mm", "y_mm", "z_mm"]].to_numpy(float)
    frames, truths = [], []
    actual = microscope.stage.actual(stage_mm, stage_rng)
    for k, (cmd, act) in enumerate(zip(stage_mm, actual), 1):
        world = act + local
        p = microscope.stage_to_microscope(world, origin)
        w_true = microscope.project(p)
        sigma = microscope.noise.sigma_px(p[:, 2], microscope.optics.depth_of_field_mm)
        w = w_true + noise_rng.normal(size=w_true.shape) * sigma[:, None]
        vis = microscope.visible(w_true, dot_diameter_mm)
        w[:, 0:2][~vis[:, 0]] = np.nan
        w[:, 2:4][~vis[:, 1]] = np.nan
        key = {"sequence": sequence, "position": k, "row": target["row"].to_numpy(), "col": target["col"].to_numpy()}
        frames.append(pd.DataFrame({**key, "stage_x_mm": cmd[0], "stage_y_mm": cmd[1], "stage_z_mm": cmd[2],
                                    **{c: w[:, n] for n, c in enumerate(IMAGE_COLUMNS)},
                                    "x_mm": local[:, 0], "y_mm": local[:, 1], "z_mm": local[:, 2]}))
        truths.append(pd.DataFrame({**key, **{c: w_true[:, n] for n, c in enumerate(IMAGE_COLUMNS)},
                                    "X_mm": world[:, 0], "Y_mm": world[:, 1], "Z_mm": world[:, 2]}))
    points = pd.concat(frames, ignore_index=True)[[*POINT_COLUMNS, "x_mm", "y_mm", "z_mm"]]
    plate = {"pitch_mm": float(abs(np.diff(np.unique(local[:, 0]))).min()), "dot_diameter_mm": dot_diameter_mm}
    meta = {"format": SET_FORMAT, "image_size_px": list(microscope.optics.image_size_px), "plates": {"moving": plate},
            "source": f"slmlab {__version__} virtual microscope, preset {microscope.preset}: a known target, seed {seed}",
            "simulator": {"microscope": microscope.as_dict(), "seed": int(seed),
                          "stage_origin_mm": [float(v) for v in origin]}}
    return CalibrationSet(points=points, meta=meta, truth=pd.concat(truths, ignore_index=True)[TRUTH_COLUMNS])


#: what the paper's estimators must return on the ``paper`` preset (Tables 1, 2, 4): the targets of
#: :func:`derive_paper_preset`
PRESET_TARGETS = {"aD": 6.5365e-6, "a_abs": (1.73e-6 + 1.54e-6) / 2, "vertex_px": 0.0123 / (2 * 6.5365e-6),
                  "alpha_deg": -0.1443, "dw2_px": 2.0731, "thetaX_deg": 3.0347, "KYX": -0.0051, "KYZ": -0.0214,
                  "KZX": -0.0057, "KZY": -0.0143}


def paper_estimates(microscope: Microscope, seeds=(1, 2, 3)) -> dict:
    """Mean over Test 1 sets (one per seed) of what the paper's estimators return (the joint disparity fit,
    METHOD.md §2): the keys of :data:`PRESET_TARGETS`."""
    from .vision import fit_paper

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
