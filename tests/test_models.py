"""The model registry and model files."""

import json
import subprocess
import sys

import numpy as np
import pytest

import slmlab
from slmlab import models


def test_registry_lists_only_real_models():
    for name, cls in slmlab.available_models().items():
        assert cls.name == name and cls.summary
        assert cls.fit is not slmlab.Model.fit, f"{name} is registered but cannot be fitted"


def test_models_verb_runs():
    r = subprocess.run([sys.executable, "-m", "slmlab", "models"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0


def test_unknown_model_is_a_user_error(paper_set):
    with pytest.raises(slmlab.SlmlabError, match="unknown model"):
        slmlab.calibrate(paper_set, "no-such-model")


class _Scale(slmlab.Model):
    """A toy model for the file round trip (not registered globally)."""

    name = "test-scale"
    summary = "x = k · mean w1 (test only)"
    units = {"k": "mm/px"}

    def __init__(self, k=1.0, **kw):
        super().__init__(**kw)
        self.k = k

    @classmethod
    def fit(cls, cal, **options):
        return cls(k=0.003)

    def reconstruct(self, w):
        w = np.asarray(w, float)
        return self.k * np.column_stack([w[:, 0], w[:, 1], w[:, 2] - w[:, 0]])

    def parameters_dict(self):
        return {"k": self.k}

    @classmethod
    def from_parameters(cls, parameters, calibration, options):
        return cls(k=float(parameters["k"]), calibration=calibration, options=options)


def test_model_file_round_trip_and_version_check(tmp_path, paper_set, monkeypatch):
    monkeypatch.setitem(models.base._REGISTRY, _Scale.name, _Scale)
    m = slmlab.calibrate(paper_set, "test-scale")
    assert m.calibration["positions"] == {"grid": 1, "X": 42, "Y": 30, "Z": 32}
    path = m.save(tmp_path / "m.json")
    d = json.loads(path.read_text())
    assert d["format"] == "slmlab-model/1" and d["model"] == "test-scale" and d["units"]["k"] == "mm/px"
    back = slmlab.load_model(path)
    w = np.array([[1.0, 2.0, 3.0, 4.0]])
    np.testing.assert_array_equal(back.reconstruct(w), m.reconstruct(w))
    d["format"] = "slmlab-model/2"
    path.write_text(json.dumps(d))
    with pytest.raises(slmlab.SlmlabError, match="slmlab-model/2"):
        slmlab.load_model(path)
    path.write_text("{")
    with pytest.raises(slmlab.SlmlabError, match="invalid JSON"):
        slmlab.load_model(path)


def _pinned_case(order, gaps_um, cv_um):
    """Run the default's check of depth-pinned candidates (one coordinate) on made-up held-out errors and
    differences between the depths [µm]; returns what it dropped."""
    from slmlab.models.auto import _drop_bent_pinned
    cv = {c: [1e-3 * cv_um[c]] for c in order}
    judged = {c: list(v) for c, v in cv.items()}
    skipped = {}
    gap2 = lambda a, b: 1e-3 * gaps_um[frozenset((a, b))]  # noqa: E731
    _drop_bent_pinned(judged, skipped, cv, [c for c in order if c in ("direct", "soloff")], 0, gap2, 6)
    return {c for c in order if not np.isfinite(judged[c][0])}, skipped


def test_a_pinned_candidate_is_dropped_only_against_a_consensus_and_in_any_order():
    cv = {"direct": 1.09, "soloff": 1.18, "polynomial-3": 1.18}
    far = {frozenset(("direct", "soloff")): 7.9, frozenset(("direct", "polynomial-3")): 7.9}
    agree = {**far, frozenset(("soloff", "polynomial-3")): 0.14}     # the other two agree: direct bends
    for order in (["direct", "soloff", "polynomial-3"], ["soloff", "polynomial-3", "direct"]):
        dropped, why = _pinned_case(order, agree, cv)
        assert dropped == {"direct"} and why["direct (X)"].startswith("bends between the 6 calibrated depths")
    apart = {**far, frozenset(("soloff", "polynomial-3")): 7.9}      # nobody agrees: nothing to judge by
    assert _pinned_case(["direct", "soloff", "polynomial-3"], apart, cv)[0] == set()
    near = {**agree, frozenset(("direct", "polynomial-3")): 1.5}     # within 1.5x of one other: it stays
    assert _pinned_case(["direct", "soloff", "polynomial-3"], near, cv)[0] == set()
