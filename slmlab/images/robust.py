"""Robust statistics of images' pixels: medians of integer values by counting them, the median absolute deviation,
and the robust σ taken from it (:mod:`slmlab.images.dots`' hot pixels, :mod:`slmlab.images.overlay`,
:mod:`slmlab.images.markers`)."""

from __future__ import annotations

import numpy as np

__all__ = ["median_of_integers", "mad", "robust_sigma"]


def median_of_integers(v: np.ndarray) -> float:
    """``np.median`` of integer values ``v`` (any dtype), by counting them: the same number, without a sort."""
    v = np.asarray(v).astype(np.int64, copy=False).ravel()
    lo = int(v.min())
    cum = np.cumsum(np.bincount(v - lo))
    n = len(v)
    at = np.searchsorted(cum, [(n - 1) // 2, n // 2], side="right") + lo   # the middle order statistic(s)
    return float(at.mean())


def mad(d: np.ndarray, *, integers: bool) -> float:
    """The median absolute deviation of ``d`` from its median; of ``integers`` (differences of 8- or 16-bit
    images) by :func:`median_of_integers`, in half units where the median falls between two of them."""
    if not integers or len(d) == 0:
        return float(np.median(np.abs(d - np.median(d))))
    twice = 2 * np.asarray(d).astype(np.int64)
    m2 = int(round(2 * median_of_integers(d)))
    return median_of_integers(np.abs(twice - m2)) / 2


def robust_sigma(values: np.ndarray) -> float:
    """The robust σ of ``values`` (any shape): 1.4826 times their median absolute deviation."""
    return 1.4826 * mad(np.asarray(values, np.float64).ravel(), integers=False)
