"""Every registered model reconstructs no point, one point and a single quadruple without fuss (issue 25: the
pinhole model raised on an empty array)."""

import numpy as np
import pytest

import slmlab
from slmlab.models import available_models
from slmlab.virtual.simulate import stepped_target, target_set

#: options that keep the slow searches short (the pinhole's variant search)
OPTIONS = {"pinhole": {"variant": "standard"}}


@pytest.fixture(scope="session")
def target():
    """A small stepped target in one pose: every model that needs world positions calibrates on it."""
    return target_set(slmlab.preset("paper"), stepped_target(rows=15, cols=15, pitch_mm=0.3), [[0.0, 0.0, 0.0]], seed=2)


def calibrated(name, paper_set, target):
    try:
        return slmlab.calibrate(paper_set, name, **OPTIONS.get(name, {})), paper_set
    except slmlab.SlmlabError:  # needs world positions (soloff, quadratic)
        return slmlab.calibrate(target, name, **OPTIONS.get(name, {})), target


@pytest.mark.parametrize("name", list(available_models()))
def test_empty_and_near_empty_inputs(name, paper_set, target):
    model, cal = calibrated(name, paper_set, target)
    w = cal.points[["wl1", "wl2", "wr1", "wr2"]].dropna().to_numpy()
    for arr, n in ((np.empty((0, 4)), 0), (w[:1], 1), (w[0], 1), (w[:2], 2)):
        out = model.reconstruct(arr)
        assert out.shape == (n, 3) and np.isfinite(out).all(), (name, arr.shape)
        if hasattr(model, "uncertainty"):
            s = model.uncertainty(arr)
            assert s.shape == (n, 3) and np.isfinite(s).all(), (name, arr.shape)
