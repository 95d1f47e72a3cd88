"""slmlab: a research workbench for stereo light microscope (SLM) vision modelling.

Reproduces Wang, Zhao, Wang, "Microscopic vision modeling method by direct mapping analysis for
micro-gripping system with stereo light microscope", Micron 83 (2016) 93-109, on a physical virtual CMO
stereo microscope, and goes beyond it.

The flat API (in the spirit of mrcal): modules by concept, re-exported here.

>>> import slmlab
>>> cal = slmlab.simulate_set(slmlab.preset("paper"), seed=1)     # a virtual calibration set
>>> sorted(cal.sequences)
['X', 'Y', 'Z', 'grid']
"""

__version__ = "0.1.0"

from .errors import SlmlabError  # noqa: E402
from .io import CalibrationSet, read_points, read_set, write_csv, write_set  # noqa: E402
from .microscope import CentroidNoise, Microscope, Optics, Plate, Stage, View  # noqa: E402
from .models import Model, available_models, calibrate, default_model_name, load_model  # noqa: E402
from .simulate import (PAPER_TESTS, PRESETS, Session, paper_test, preset, simulate_set,  # noqa: E402
                       validation_session)
from .paths import SHARED_DIR, figures_dir, notebook_size, paper_reference, savefig, savetable  # noqa: E402
from . import direct, paper_models, pinhole, selection, soloff  # noqa: E402,F401  (registers the models)
from .evaluation import evaluate  # noqa: E402

__all__ = [
    "__version__", "SlmlabError",
    "CalibrationSet", "read_set", "write_set", "read_points", "write_csv",
    "Microscope", "Optics", "View", "Stage", "Plate", "CentroidNoise",
    "Model", "available_models", "calibrate", "default_model_name", "load_model",
    "PRESETS", "PAPER_TESTS", "Session", "preset", "paper_test", "validation_session", "simulate_set",
    "SHARED_DIR", "figures_dir", "notebook_size", "paper_reference", "savefig", "savetable", "evaluate",
]
