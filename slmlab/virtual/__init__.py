"""The virtual CMO stereo microscope: the physics the paper's method is tested against (paper §2, §6).

``microscope``
    optics (two central projections through a common main objective, decentred distortion of opposite sign
    in the two views, perspective), cameras, stage and its errors, plates, the dot finder's noise;
``presets``, ``sessions``
    named microscopes (``paper``, ``leica``, ``ideal``) and what a calibration images (Table 3, §6);
``simulate``, ``render``
    calibration sets with ``truth.csv``, and their images;
``derive``
    the ``paper`` preset derived from the paper's Tables 1, 2 and 4 (the one part that uses the paper's
    method).
"""

from .microscope import CentroidNoise, Microscope, Optics, Plate, Stage, View
from .presets import PRESETS, preset
from .sessions import PAPER_TESTS, Session, paper_test, validation_session
from .simulate import simulate_set

__all__ = ["CentroidNoise", "Microscope", "Optics", "Plate", "Stage", "View", "PRESETS", "preset", "PAPER_TESTS",
           "Session", "paper_test", "validation_session", "simulate_set"]
