"""The model registry, the :class:`Model` base class and model files.

Every vision model (the paper's Models 0–2, the pinhole baseline, the project's own) is a subclass of
:class:`Model` registered under a name. ``calibrate`` fits one on a calibration set, ``reconstruct`` maps
``(n, 4)`` image coordinates ``wl1, wl2, wr1, wr2`` [px] to ``(n, 3)`` world coordinates [mm], and a model
round-trips through a JSON file that carries its name, a format version, every parameter with its unit and
the calibration set's summary. Model files are plain JSON: loading one executes nothing.
"""

from __future__ import annotations

import ctypes
import glob
import json
import os
from pathlib import Path
from typing import ClassVar

import cv2
import numpy as np
import scipy

from ..checks import check_stage_file
from ..errors import SlmlabError
from ..io import CalibrationSet, atomic_write_text, json_text

__all__ = ["MODEL_FORMAT", "Model", "register", "available_models", "default_model_name", "get_model_class", "one_thread",
           "calibrate", "load_model"]

MODEL_FORMAT = "slmlab-model/1"

_REGISTRY: dict[str, type["Model"]] = {}


class Model:
    """Base class of the vision models.

    Subclasses set ``name``, ``summary``, ``accuracy_rank`` (lower is more accurate; the default model is
    the registered one with the lowest rank) and implement :meth:`fit`, :meth:`reconstruct`,
    :meth:`parameters_dict` and :meth:`from_parameters`.
    """

    name: ClassVar[str] = ""
    summary: ClassVar[str] = ""
    accuracy_rank: ClassVar[int] = 100
    #: unit of each parameter, by name (written to the model file)
    units: ClassVar[dict[str, str]] = {}

    def __init__(self, calibration: dict | None = None, options: dict | None = None):
        self.calibration = calibration or {}
        self.options = options or {}

    # ---------------------------------------------------------------- to implement
    @classmethod
    def fit(cls, cal: CalibrationSet, **options) -> "Model":  # pragma: no cover - abstract
        raise NotImplementedError

    def reconstruct(self, w: np.ndarray) -> np.ndarray:  # pragma: no cover - abstract
        """World coordinates ``(n, 3)`` [mm] of image coordinates ``(n, 4)`` = ``wl1, wl2, wr1, wr2`` [px]."""
        raise NotImplementedError

    def parameters_dict(self) -> dict:  # pragma: no cover - abstract
        """Every parameter as JSON-able values (numbers or lists of numbers), by name."""
        raise NotImplementedError

    @classmethod
    def from_parameters(cls, parameters: dict, calibration: dict, options: dict) -> "Model":  # pragma: no cover
        raise NotImplementedError

    def describe(self) -> str:
        """One line: the model and the settings the data chose (for tables and notes)."""
        return self.name

    def fixed_options(self) -> dict:
        """Options of :meth:`fit` that reproduce this model's data-chosen settings (its degrees, ...), so that
        held-out fits compare models as chosen on the whole set (:mod:`slmlab.models.auto`)."""
        return {}

    # ---------------------------------------------------------------- files
    def to_dict(self) -> dict:
        return {
            "format": MODEL_FORMAT,
            "model": self.name,
            "units": {"image": "px", "world": "mm", **self.units},
            "parameters": self.parameters_dict(),
            "options": self.options,
            "calibration": self.calibration,
        }

    def save(self, path: str | os.PathLike) -> Path:
        """Write the model file (JSON) atomically; a failed write never replaces a good file."""
        path = Path(path)
        atomic_write_text(path, json_text(self.to_dict()))
        return path

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.name!r}>"


def register(cls: type[Model]) -> type[Model]:
    """Class decorator: add a model to the registry under ``cls.name``."""
    if not cls.name:
        raise ValueError("a registered model needs a name")
    _REGISTRY[cls.name] = cls
    return cls


def available_models() -> dict[str, type[Model]]:
    """The registered models by name, most accurate first."""
    return dict(sorted(_REGISTRY.items(), key=lambda kv: (kv[1].accuracy_rank, kv[0])))


def default_model_name() -> str:
    """Name of the most accurate registered model (what ``calibrate`` uses without ``--model``)."""
    return next(iter(available_models()))


def get_model_class(name: str) -> type[Model]:
    models = available_models()
    if name not in models:
        raise SlmlabError(f"unknown model {name!r}; the models are: {', '.join(models)} "
                          "(see 'python -m slmlab models')")
    return models[name]


class one_thread:
    """Calibration on one thread: OpenCV's own threads, and the OpenBLAS libraries NumPy, SciPy and OpenCV
    bundle (found beside them; best effort elsewhere), restored afterwards. Parallel reductions add in an order that depends on the number
    of threads, and an ill-conditioned fit (a near-telecentric pinhole pair) amplifies the last bits; one set
    must give one model file, whatever the machine's number of cores."""

    _blas = None

    @classmethod
    def _openblas(cls):
        if cls._blas is None:
            found = []
            paths = []
            for package in (np, scipy, cv2):  # NumPy's and SciPy's OpenBLAS, and the one OpenCV's LAPACK uses
                paths += glob.glob(os.path.join(os.path.dirname(package.__file__), os.pardir, "*.libs", "*openblas*"))
            for path in sorted(set(os.path.realpath(p) for p in paths)):
                try:
                    lib = ctypes.CDLL(path)
                except OSError:
                    continue
                for prefix in ("scipy_openblas", "openblas"):
                    for suffix in ("64_", ""):
                        get, put = f"{prefix}_get_num_threads{suffix}", f"{prefix}_set_num_threads{suffix}"
                        if hasattr(lib, get) and hasattr(lib, put):
                            found.append((getattr(lib, get), getattr(lib, put)))
            cls._blas = found
        return cls._blas

    def __enter__(self):
        self.cv = cv2.getNumThreads()
        cv2.setNumThreads(1)
        self.blas = [(get, put, get()) for get, put in self._openblas()]
        for _, put, _ in self.blas:
            put(1)
        return self

    def __exit__(self, *exc):
        cv2.setNumThreads(self.cv)
        for _, put, n in self.blas:
            put(n)


def calibrate(cal: CalibrationSet, model: str | None = None, **options) -> Model:
    """Fit a vision model on a calibration set.

    Parameters
    ----------
    cal
        the calibration set (see :func:`slmlab.read_set`).
    model
        a registered model name; ``None`` for the most accurate one.
    **options
        model-specific options (e.g. the scale estimator of the paper's models).
    """
    cls = get_model_class(model or default_model_name())
    check_stage_file(cal)
    with one_thread():
        fitted = cls.fit(cal, **options)
    fitted.calibration = {**cal.summary(), "notes": list(cal.notes), **fitted.calibration}
    return fitted


def load_model(path: str | os.PathLike) -> Model:
    """Read a model file written by :meth:`Model.save` (plain JSON; nothing is executed)."""
    path = Path(path)
    if not path.exists():
        raise SlmlabError("model file not found; write one with 'python -m slmlab calibrate SET --out MODEL.json'", path)
    if path.is_dir():
        raise SlmlabError("is a folder; give the model's JSON file", path)
    try:
        d = json.loads(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise SlmlabError("is not a text file; a model file is JSON", path) from None
    except json.JSONDecodeError as exc:
        raise SlmlabError(f"invalid JSON at line {exc.lineno} ({exc.msg}); recalibrate to rewrite it", path) from None
    if not isinstance(d, dict) or d.get("format") != MODEL_FORMAT:
        fmt = d.get("format") if isinstance(d, dict) else None
        raise SlmlabError(f"format is {fmt!r}, this slmlab reads {MODEL_FORMAT!r}; recalibrate with this version", path)
    name = d.get("model")
    try:
        cls = get_model_class(str(name))
    except SlmlabError as exc:
        raise SlmlabError(exc.reason, path) from None
    params = d.get("parameters")
    if not isinstance(params, dict):
        raise SlmlabError("has no 'parameters' object; recalibrate to rewrite it", path)
    try:
        return cls.from_parameters(params, d.get("calibration") or {}, d.get("options") or {})
    except (KeyError, TypeError, ValueError) as exc:
        raise SlmlabError(f"parameters of model {name!r} are incomplete or malformed ({exc}); recalibrate", path) from None
