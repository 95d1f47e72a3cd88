"""What the notebooks' tables and figures are made of (issue 24): the model comparison in µm with each
element's trend, the verdict against a reference model, the leave-one-plane-out and cross-validation
summaries, reconstructions against the truth, the explorers' preset, and the figures a reader checks by eye."""

from types import SimpleNamespace

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
import pytest

import slmlab
from slmlab import explore, plots
from slmlab.paper import tables
from slmlab.paper.evaluation import Evaluation, element_summary, requirement, s_coefficients
from slmlab.studies import workspace


def _evaluation(scale_z: float, tilt_zx: float = 0.0, noise_mm: float = 0.0, seed: int = 0) -> Evaluation:
    """Residuals of a model whose depth scale is off by ``scale_z`` and whose Z axis leans into X by ``tilt_zx``."""
    rng = np.random.default_rng(seed)
    frames = []
    for seq in "XYZ":
        d = np.repeat(np.linspace(0.1, 2.0, 20) * (-1 if seq != "Y" else 1), 9)
        e = rng.normal(0, noise_mm, (len(d), 3))
        if seq == "Z":
            e[:, 2] += scale_z * d
            e[:, 0] += tilt_zx * d
        frames.append(pd.DataFrame({"sequence": seq, "position": np.repeat(np.arange(2, 22), 9), "row": 1, "col": 1,
                                    "displacement_mm": d, "E_X": e[:, 0], "E_Y": e[:, 1], "E_Z": e[:, 2]}))
    res = pd.concat(frames, ignore_index=True)
    s = s_coefficients(res)
    return Evaluation("fake", res, s, requirement(s), element_summary(res))


def test_the_comparison_table_is_in_micrometres_and_an_axial_trend_is_the_scale_error():
    t = tables.comparison_table({"one percent": _evaluation(0.01, tilt_zx=0.002)}).set_index("element")
    assert t.loc["ZZ", "trend_um_per_mm"] == pytest.approx(10.0)        # 1 % of 1 mm is 10 µm
    assert t.loc["ZX", "trend_um_per_mm"] == pytest.approx(2.0)
    assert t.loc["ZZ", "max_abs_um"] == pytest.approx(1e3 * 0.01 * 2.0)  # 2 mm of travel
    assert t.loc["XX", "max_abs_um"] == 0 and t.loc["XX", "trend_um_per_mm"] == pytest.approx(0.0, abs=1e-9)


def test_against_model_names_the_elements_within_the_reference_and_its_own_worst():
    t = tables.comparison_table({"reference": _evaluation(0.005, noise_mm=1e-4, seed=1),
                                 "better in Z": _evaluation(0.001, noise_mm=1e-4, seed=1),
                                 "worse in Z": _evaluation(0.02, noise_mm=1e-4, seed=1)})
    v = tables.against_model(t, "reference").set_index("model")
    assert v.loc["better in Z", "worst_element"] != "ZZ" or v.loc["better in Z", "ratio"] < 1
    assert "ZZ" in v.loc["better in Z", "within_in"].split() and "ZZ" not in v.loc["worse in Z", "within_in"].split()
    assert v.loc["worse in Z", "reference_worst_max_abs_um"] == pytest.approx(t[t["model"] == "reference"]["max_abs_um"].max())
    assert v.loc["worse in Z", "worst_element"] == "ZZ" and v.loc["worse in Z", "ratio"] == pytest.approx(4.0, rel=0.05)


def test_leave_one_plane_out_summary_is_the_rms_over_planes():
    lopo = pd.DataFrame({"plane": [1, 2, 1, 2], "model": ["a", "a", "b", "b"],
                         "EX_um": [3.0, 4.0, 1.0, 1.0], "EY_um": [0.0, 0.0, 2.0, 2.0], "EZ_um": [1.0, 7.0, 5.0, 5.0],
                         "sX_um": [1.0, 3.0, 1.0, 1.0], "sY_um": 1.0, "sZ_um": 1.0, "inside_95_percent": [90.0, 100.0, 50.0, 50.0]})
    s = workspace.leave_one_plane_out_summary(lopo).set_index("model")
    assert list(s.index) == ["a", "b"]
    assert s.loc["a", "X_um"] == pytest.approx(np.sqrt(12.5)) and s.loc["a", "Z_um"] == pytest.approx(5.0)
    assert s.loc["a", "X_predicted_sigma_um"] == 2.0 and s.loc["a", "inside_95_percent"] == 95.0


def test_cross_validation_summary_carries_each_calibrations_settings():
    diff = pd.DataFrame({"dX_um": [3.0, -3.0], "dY_um": 0.0, "dZ_um": [1.0, 1.0],
                         "predicted_X_um": [1.0, 1.0], "predicted_Y_um": 1.0, "predicted_Z_um": 2.0})
    a, b = SimpleNamespace(describe=lambda: "degrees 5/3/3"), SimpleNamespace(describe=lambda: "degrees 2/3/2")
    s = workspace.cross_validation_summary(a, b, diff).set_index("coordinate")
    assert s.loc["X", "rms_diff_um"] == 3.0 and s.loc["X", "diff_over_predicted"] == 3.0
    assert s.loc["Z", "diff_over_predicted"] == 0.5
    assert (s["settings_a"] == "degrees 5/3/3").all() and (s["settings_b"] == "degrees 2/3/2").all()


@pytest.mark.parametrize("declared, expected", [(1.0, 95.0), (0.5, 67.3)])  # ±1.96·σ/2 holds 2Φ(0.98) − 1
def test_reconstruction_against_truth_removes_the_offset_and_checks_the_intervals(declared, expected):
    rng = np.random.default_rng(3)
    n, sigma_mm = 20000, 2e-4
    truth = pd.DataFrame({"sequence": "Z", "position": np.arange(n) // 100 + 1, "row": np.arange(n) % 10 + 1,
                          "col": np.arange(n) // 10 % 10 + 1, "X_mm": rng.uniform(-2, 2, n), "Y_mm": rng.uniform(-2, 2, n),
                          "Z_mm": rng.uniform(-1, 1, n)})
    rec = truth.copy()
    for c, offset in zip("XYZ", (1.0, -2.0, 0.5)):   # the model's frame has another origin
        rec[f"{c}_mm"] += offset + rng.normal(0, sigma_mm, n)
        rec[f"s{c}_mm"] = declared * sigma_mm
    rec = rec.sample(frac=1.0, random_state=1)          # matched on the keys, not the order
    t = workspace.reconstruction_against_truth(rec, truth).set_index("coordinate")
    assert (t["points"] == n).all()
    assert t["rms_error_um"].to_numpy() == pytest.approx(1e3 * sigma_mm, rel=0.03)
    assert t["inside_95_percent"].to_numpy() == pytest.approx(expected, abs=1.0)


def test_the_explorers_start_from_the_preset():
    leica = explore.microscope_knobs("leica")
    assert leica["perspective_mm"] == slmlab.preset("leica").optics.perspective_distance_mm == 62.5
    assert explore.microscope_knobs("paper")["stage_tilt"] == slmlab.preset("paper").stage.y_tilt
    state = explore.microscope_state(preset_name="leica", distortion_scale=0.0)
    assert state["microscope"].optics.perspective_distance_mm == 62.5
    assert state["microscope"].stage.y_tilt == slmlab.preset("leica").stage.y_tilt


def test_figures_a_reader_checks_by_eye():
    errors = {name: pd.DataFrame({"Z_mm": 0.0, "error_um": np.full(10, k + 1.0)}) for k, name in enumerate("abc")}
    ax = plots.plot_volumetric_errors(errors)
    assert [t.get_text() for t in ax.get_yticklabels()] == ["a", "b", "c"] and ax.get_xscale() == "log"
    plt.close(ax.figure)
    image = np.full((400, 600), 200, np.uint8)
    table = pd.DataFrame({"row": [1, 1, 2, 2], "col": [1, 2, 1, 2], "w1": [100.0, 150, 100, 150], "w2": [200.0, 200, 250, 250]})
    ax = plots.plot_numbering(image, table)
    lo, hi = ax.get_xlim()
    assert 80 < lo < 100 and 150 < hi < 170                              # zoomed on the dots, not the whole image
    assert {t.get_text() for t in ax.texts} >= {"1,1", "1,2", "2,1", "2,2"}
    plt.close(ax.figure)
    table = pd.DataFrame({"model": ["q", "d"], "X_um": [1.0, 2.0], "Y_um": [1.0, 2.0], "Z_um": [3.0, 4.0]})
    ax = plots.plot_model_comparison(table, reference="q")
    bbox = ax.get_legend().get_window_extent()
    assert bbox.x0 >= ax.get_window_extent().x1 - 1                       # the legend beside the axes, over no bar
    plt.close(ax.figure)


def test_residual_panels_draw_the_z_components_own_requirement():
    """Figs 13-15: RA3 (±10 µm) in every panel, as the paper draws it; in the Z components' column also RA5
    (±15 µm), what the paper requires of Z, so a Z element between the two is seen to meet it."""
    res = pd.DataFrame({"sequence": np.repeat(list("XYZ"), 4), "displacement_mm": np.tile([0.0, 1, 2, 3], 3),
                        **{f"E_{c}": np.full(12, 0.012) for c in "XYZ"}})
    axes = plots.plot_residual_panels(res, interval_mm=0.01, z_interval_mm=0.015)
    for r in range(3):
        for c in range(3):
            levels = sorted({round(line.get_ydata()[0], 6) for line in axes[r, c].lines[1:]})
            assert levels == ([-15.0, -10.0, 10.0, 15.0] if c == 2 else [-10.0, 10.0]), (r, c, levels)
    plt.close(axes[0, 0].figure)
