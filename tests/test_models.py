"""The model registry and model files."""

import json
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

import slmlab
from slmlab import models
from slmlab.io import IMAGE_COLUMNS


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
    _drop_bent_pinned(judged, skipped, cv, [c for c in order if c in ("direct", "soloff")], 0, gap2, "the 6 calibrated depths")
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


def _cross(linear: np.ndarray, arms: dict, dots: int = 4) -> pd.DataFrame:
    """Stage moves of a plate along ``arms`` (sequence -> commanded positions ``(n, 3)`` [mm]) through an affine
    imaging ``linear`` ``(4, 3)`` [px/mm] (image = linear @ (stage + dot's offset)): the points' rows."""
    rows = []
    for seq, stage in arms.items():
        for p, s in enumerate(stage, 1):
            for r in range(dots):
                for c in range(dots):
                    w = linear @ (np.asarray(s, float) + [0.1 * c, 0.1 * r, 0.0])
                    rows.append({"sequence": seq, "position": p, "stage_x_mm": s[0], "stage_y_mm": s[1],
                                 "stage_z_mm": s[2], "row": r + 1, "col": c + 1, **dict(zip(IMAGE_COLUMNS, w))})
    return pd.DataFrame(rows)


def test_between_the_arms_of_stage_moves_images_superpose_two_arms_inside_the_cross():
    """With affine imaging the superposed images are exactly those of the plate moved by both arms: each
    synthesised point's stage position (solved back, one dot) lies off both arms and inside the cross's hull;
    with the moves along one direction there is nothing between arms."""
    from slmlab.models.folds import between_arms
    rng = np.random.default_rng(3)
    linear = rng.normal(0.0, 50.0, (4, 3))
    t = np.linspace(-1.0, 1.0, 9)[:, None]
    centre = np.array([3.0, 4.0, 5.0])                         # the crossing's own image counts (w_p + w_q - w_b)
    arms = {"X": centre + t * [2.0, 0.0, 0.0], "Z": centre + t * [0.0, 0.0, 0.5]}
    q = between_arms(_cross(linear, arms, dots=1))
    s, *_ = np.linalg.lstsq(linear, q.T, rcond=None)          # each point's stage position [mm]
    np.testing.assert_allclose(linear @ s, q.T, atol=1e-9)     # the image of that position
    s = s - centre[:, None]
    assert len(q) == 4 * 3      # per quadrant the quarter-steps (1, 1), (1, 2), (2, 1): within 0.9 of the ends
    assert np.all(np.abs(s[0]) > 0.2) and np.all(np.abs(s[2]) > 0.05) and np.allclose(s[1], 0.0, atol=1e-9)
    assert np.all(np.abs(s[0]) / 2.0 + np.abs(s[2]) / 0.5 <= 0.9 + 1e-9)
    assert between_arms(_cross(linear, {"X": arms["X"]})).shape == (0, 4)
