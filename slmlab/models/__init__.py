"""The vision models: a registry of plug-ins that map image coordinates to the world.

``base``
    the :class:`Model` base class, the registry, :func:`calibrate` and model files;
``frames``, ``folds``
    where a set's dots are in the world, and the held-out folds every data-driven choice is made on;
``paper``
    the paper's Models 0–2 (§5), adapters of :mod:`slmlab.paper.chain`;
``pinhole``
    the traditional pinhole stereo model (OpenCV), the paper's §6.3 comparison;
``direct``, ``soloff``, ``reference``
    beyond the paper: a direct polynomial map, the Soloff model of stereo-PIV, plain reference polynomials;
``auto``
    the default: per coordinate, the candidate with the smallest held-out error.

Importing this package registers every model.
"""

from .base import (MODEL_FORMAT, Model, available_models, calibrate, default_model_name, get_model_class,
                   load_model, one_thread, register)
from . import auto, direct, paper, pinhole, reference, soloff  # noqa: F401,E402  (each registers its models)

__all__ = ["MODEL_FORMAT", "Model", "available_models", "calibrate", "default_model_name", "get_model_class",
           "load_model", "one_thread", "register", "auto", "direct", "paper", "pinhole", "reference", "soloff"]
