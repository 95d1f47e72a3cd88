"""The paper's Models 0, 1 and 2 as registered vision models ``paper-m0``, ``paper-m1``, ``paper-m2``
(paper §3–§5). The chain and its estimators are in :mod:`slmlab.paper.chain`."""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from ..paper.chain import PaperParameters, fit_paper, suspect_rows
from .base import Model, register

__all__ = ["PaperModel", "PaperM0", "PaperM1", "PaperM2"]

_UNITS = {
    **{f"{p}_{s}": u for s in "lr" for p, u in (("lambda", "1/px"), ("a", "1/px"), ("b", "-"), ("c", "px"))},
    "alpha_deg": "degree", "dw2_px": "px", "aD": "1/px", "bD": "-", "cD_px": "px", "thetaX_deg": "degree",
    "EX_mm_per_px": "mm/px", "EY_mm_per_px": "mm/px", "EZ_mm_per_px": "mm/px",
    "KYX": "-", "BYX_mm": "mm", "KYZ": "-", "BYZ_mm": "mm", "KZX": "-", "BZX_mm": "mm", "KZY": "-", "BZY_mm": "mm",
}


class PaperModel(Model):
    """The paper's chain up to Model ``level`` (§3 correction, §4 alignment, θX, Eq 19, compensation).

    Options of :meth:`fit`: ``scale_estimator`` (``'mean-ratio'``, the paper's, or ``'lstsq'``),
    ``distortion_method`` (``'paper-two-step'``, ``'joint'``, or ``None``: the one with the smaller lattice
    misfit) and ``disparity_method`` (``'joint'``, our reading of Eqs 13–16, or ``'single-pass'``, a line per dot and
    then one quadratic, for comparison); all three are named in the model file.
    """

    level: ClassVar[int] = 2
    units = _UNITS

    def __init__(self, params: PaperParameters, **kw):
        super().__init__(**kw)
        self.params = params

    @classmethod
    def fit(cls, cal, *, scale_estimator: str = "mean-ratio", distortion_method: str | None = None,
            disparity_method: str = "joint", **_):
        params, dist, align = fit_paper(cal, level=cls.level, scale_estimator=scale_estimator,
                                        distortion_method=distortion_method, disparity_method=disparity_method)
        q = dist.quality
        suspects = suspect_rows(cal, params)
        return cls(params, options={"scale_estimator": scale_estimator, "distortion_method": dist.chosen,
                                    "disparity_method": disparity_method},
                   calibration={
                       "distortion_lattice_rms_px": {f"{r.view}/{r.stage}": r.lattice_rms_px for r in q.itertuples()},
                       "disparity_path_straightness_px": align.straightness,
                       "suspect_rows": [{"sequence": q_[0], "position": q_[1], "row": q_[2], "col": q_[3],
                                         "residual_mm": q_[4]} for q_ in suspects],
                   })

    def reconstruct(self, w: np.ndarray) -> np.ndarray:
        return self.params.reconstruct(np.atleast_2d(np.asarray(w, float)))

    def parameters_dict(self) -> dict:
        return self.params.as_dict()

    @classmethod
    def from_parameters(cls, parameters, calibration, options):
        return cls(PaperParameters.from_dict(parameters, cls.level), calibration=calibration, options=options)


@register
class PaperM0(PaperModel):
    name = "paper-m0"
    summary = "the paper's initial vision model (Eq 19): corrected, aligned, rotated; X, Y, Z = EX, EY, EZ x image"
    accuracy_rank = 30
    level = 0


@register
class PaperM1(PaperModel):
    name = "paper-m1"
    summary = "the paper's Model 1 (Eq 21): Model 0 + compensation of X and Z linear in Y"
    accuracy_rank = 20
    level = 1


@register
class PaperM2(PaperModel):
    name = "paper-m2"
    summary = "the paper's Model 2 (Eq 22): Model 1 + compensation of X and Y linear in Z"
    accuracy_rank = 10
    level = 2
