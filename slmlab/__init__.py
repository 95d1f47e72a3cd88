"""slmlab: a research workbench for stereo light microscope (SLM) vision modelling.

Reproduces Wang, Zhao, Wang, "Microscopic vision modeling method by direct mapping analysis for
micro-gripping system with stereo light microscope", Micron 83 (2016) 93-109, on a physical virtual CMO
stereo microscope, and goes beyond it.

The package in wings (in the spirit of mrcal: modules by concept, the everyday names re-exported here):

``slmlab.virtual``   the virtual CMO microscope: optics, stage, presets, sessions, simulated and rendered sets
``slmlab.images``    images to dot centres: finding, refining and numbering dots; OpenCV's boards; image sets
``slmlab.paper``     the paper's method, §3–§6: distortion, alignment and disparity, Models 0–2, RA/S evaluation
``slmlab.models``    the vision models as plug-ins: the paper's, the pinhole baseline, direct, soloff, the default
``slmlab.studies``   studies end to end: the paper's tables over repeats, the workspace, extraction, real rigs
``slmlab.datasets``  third-party real data, fetched by name and checked (``slmlab.datasets.fetch(name)``)

>>> import slmlab
>>> cal = slmlab.simulate_set(slmlab.preset("paper"), seed=1)     # a virtual calibration set
>>> sorted(cal.sequences)
['X', 'Y', 'Z', 'grid']
"""

from .version import __version__
from .errors import SlmlabError
from .io import CalibrationSet, read_points, read_set, write_csv, write_set
from .models import Model, available_models, calibrate, default_model_name, load_model
from .outputs import SHARED_DIR, figures_dir, notebook_size, savefig, savetable
from .paper.evaluation import evaluate
from .paper.reference import paper_reference
from .virtual.microscope import CentroidNoise, Microscope, Optics, Plate, Stage, View
from .virtual.presets import PRESETS, preset
from .virtual.sessions import PAPER_TESTS, Session, paper_test, validation_session
from .virtual.simulate import simulate_set
from . import datasets, images, models, paper, studies, virtual  # noqa: E402  (the wings, as slmlab.<wing>)

__all__ = [
    "__version__", "SlmlabError",
    "CalibrationSet", "read_set", "write_set", "read_points", "write_csv",
    "Microscope", "Optics", "View", "Stage", "Plate", "CentroidNoise",
    "Model", "available_models", "calibrate", "default_model_name", "load_model",
    "PRESETS", "PAPER_TESTS", "Session", "preset", "paper_test", "validation_session", "simulate_set",
    "SHARED_DIR", "figures_dir", "notebook_size", "paper_reference", "savefig", "savetable", "evaluate",
]
