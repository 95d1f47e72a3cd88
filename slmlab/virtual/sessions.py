"""Calibration sessions: what the virtual microscope images (paper §4–§6, Table 3).

A *session* is what the paper images: one stereo pair of the large 27 × 29 plate (the ``grid`` sequence,
§3) and the 7 × 7 plate carried by the stage in equal steps along X, Y and Z (§4–§6). The five calibration
tests of Table 3 and the validation run of §6 are sessions; so are the designs beyond the paper (a volume of
random positions, a Z stack alone, a plate held at tilts).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..errors import SlmlabError
from .microscope import Microscope, Plate

__all__ = ["Session", "PAPER_TESTS", "paper_test", "validation_session", "volume_session", "zstack_session",
           "zstack_plate", "zstack_frame", "tilted_session", "tilt_matrix"]


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
        (paper §6.2: X in [−4.1, 0], Y in [0, 2.9], Z in [−2.25, 0]); the other two coordinates sit at the
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
    board's, :func:`slmlab.virtual.render.board_orientation`) and the Z stage's direction, as axes."""
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


def tilt_matrix(tx_deg: float, ty_deg: float) -> np.ndarray:
    """3 × 3 rotation tilting a plate by ``tx_deg`` about x, then ``ty_deg`` about y [degree]."""
    a, b = np.radians(tx_deg), np.radians(ty_deg)
    rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    return ry @ rx
