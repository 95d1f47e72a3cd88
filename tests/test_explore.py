"""The explorers: their compute functions respond to their knobs, the widgets drive them, nothing leaks."""

import matplotlib.pyplot as plt
import pytest

from slmlab import explore


def test_microscope_state_follows_its_knobs():
    base = explore.microscope_state()
    more = explore.microscope_state(distortion_scale=2.0)
    assert more["alignment"].disparity["joint"].aD == pytest.approx(2 * base["alignment"].disparity["joint"].aD, rel=0.1)
    wide = explore.microscope_state(convergence_deg=18.0)
    z = lambda s: s["cal"].sequence("Z")  # noqa: E731
    span = lambda s: float((z(s)["wr1"] - z(s)["wl1"]).max() - (z(s)["wr1"] - z(s)["wl1"]).min())  # noqa: E731
    assert span(wide) > 1.2 * span(base)  # a wider stereo angle: more disparity per mm of depth
    t = base["table"].set_index("parameter")
    assert t.loc["aD (joint fit)", "estimate"] == pytest.approx(t.loc["aD (joint fit)", "simulator_first_order"], rel=0.1)


def test_model_state_and_step_state():
    m0, m1 = explore.model_state(model="paper-m0"), explore.model_state(model="paper-m1")
    assert m1["s"].loc["YZ", "RA5"] > m0["s"].loc["YZ", "RA5"]
    assert explore.model_state(interval="RA1")["interval_mm"] == 0.005
    few = explore.step_state(positions=4)
    assert list(few["spread"]["parameter"])[:2] == ["thetaX_deg", "EX_mm_per_px"] and len(few["fits"]) == 3


def test_widgets_respond_and_nothing_leaks():
    before = set(plt.get_fignums())
    box = explore.explore_microscope()
    state = box.state
    box.controls["stage_skew"].value = 0.015
    assert box.state is not state and box.last_update_s > 0
    assert box.children[-2].value  # the figure image holds a PNG
    models = explore.explore_models()
    first = models.children[-1].value
    models.controls["model"].value = "paper-m0"
    assert models.children[-1].value != first
    assert set(plt.get_fignums()) == before


@pytest.mark.parametrize("make", [explore.explore_models, explore.explore_microscope, explore.explore_steps])
def test_titles_placed_where_matplotlib_would_place_them(make):
    """The explorers place their titles themselves (``y=1.0``, no re-measuring of the tick labels on each draw):
    drawn again with matplotlib's own placement (``_autotitlepos``), the figure's pixels are the same."""
    import numpy as np
    box = make()
    fig = box.figure
    fig.canvas.draw()
    placed = np.asarray(fig.canvas.buffer_rgba()).copy()
    assert all(ax._autotitlepos is False for ax in fig.axes)
    for ax in fig.axes:
        ax._autotitlepos = True
    fig.canvas.draw()
    assert np.array_equal(np.asarray(fig.canvas.buffer_rgba()), placed)
