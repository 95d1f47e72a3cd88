"""Virtual instruments with truth: the physics the paper's method, and every model, is tested against.

``microscope``
    the CMO stereo microscope (paper §2): two central projections through a common main objective,
    decentred distortion of opposite sign in the two views, perspective; cameras, stage and its errors,
    plates, the dot finder's noise;
``rigs``
    a zoo of other stereo rigs drawn from physics (a Greenough microscope, a stereo-DIC pair, a stereo-PIV
    pair behind a wall into water), answering the same questions as the microscope;
``presets``, ``sessions``, ``designs``
    named microscopes (``paper``, ``leica``, ``ideal``), what a calibration images (Table 3, §6), and the
    designs any rig can be calibrated with (Z stacks, stage sequences, known targets);
``simulate``, ``render``, ``floor``
    calibration sets with ``truth.csv``, their images, and the information floor of each rendered dot's centre
    (the Cramér-Rao bound under the camera's noise);
``derive``
    the ``paper`` preset derived from the paper's Tables 1, 2 and 4 (the one part that uses the paper's
    method); ``rig_checks`` the rigs' physics checked (round trip, focus, Snell against Fermat).
"""

from .microscope import CentroidNoise, Microscope, Optics, Plate, Stage, View
from .presets import PRESETS, preset
from .sessions import PAPER_TESTS, Session, paper_test, validation_session
from .simulate import simulate_set

__all__ = ["CentroidNoise", "Microscope", "Optics", "Plate", "Stage", "View", "PRESETS", "preset", "PAPER_TESTS",
           "Session", "paper_test", "validation_session", "simulate_set"]
