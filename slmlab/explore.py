"""Interactive exploration with ipywidgets: turn the microscope's and the method's knobs, see the paper's
figures respond.

Three explorers, each a function returning its widget (a ``VBox``); the computing behind each is a plain
function (:func:`microscope_state`, :func:`model_state`, :func:`step_state`) that tests call directly.

* Sliders update on release (``continuous_update=False``): one recomputation per gesture, the ipywidgets way
  of debouncing a drag.
* Figures are ``matplotlib.figure.Figure`` objects (not pyplot: nothing leaks into global state), redrawn in
  place and shown as PNG in an ``Image`` widget, so the explorers work in JupyterLab, in a headless kernel
  and in plain Python alike.
* Every widget box carries ``state`` (the last computed result), ``controls`` (name → widget) and
  ``update()`` (recompute and redraw now), for driving them programmatically.
"""

from __future__ import annotations

import time
from dataclasses import replace
from functools import lru_cache, partial

import cv2
import numpy as np
import pandas as pd
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from .errors import SlmlabError
from .models import calibrate, default_model_name
from .paper.alignment import disparity_table, estimate_alignment
from .paper.chain import fit_paper
from .paper.distortion import estimate_distortion
from .paper.evaluation import RESIDUAL_INTERVALS_MM, evaluate
from .paper.tables import TABLE4_NAMES
from .virtual.presets import preset
from .virtual.sessions import Session, paper_test, validation_session
from .virtual.simulate import simulate_set

__all__ = ["microscope_knobs", "microscope_state", "model_state", "step_state", "explore_microscope", "explore_models", "explore_steps",
           "draw_microscope", "draw_models", "draw_steps"]


# ------------------------------------------------------------------------------------------ helpers
#: the explorers' figures are drawn at this resolution [dots per inch]: the widget shows them at it
WIDGET_DPI = 72


def _figure(width_in: float, height_in: float):
    # a fixed layout: constrained layout would be re-solved on every redraw (most of an update's time); drawn at
    # the widget's resolution, so that an update draws once, at one resolution (:func:`_png`)
    fig = Figure(figsize=(width_in, height_in), dpi=WIDGET_DPI)
    fig.subplots_adjust(left=0.07, right=0.98, bottom=0.1, top=0.92, wspace=0.35, hspace=0.55)
    FigureCanvasAgg(fig)
    return fig


def _png(fig) -> bytes:
    """The figure drawn (at its own resolution, :data:`WIDGET_DPI`) as PNG bytes for the widget: the canvas's
    pixels encoded by OpenCV, the same pixels as ``savefig`` at that resolution in 8 % less time (0.137 against
    0.148 s an update of the paper models' explorer)."""
    fig.canvas.draw()
    ok, buf = cv2.imencode(".png", cv2.cvtColor(np.asarray(fig.canvas.buffer_rgba()), cv2.COLOR_RGBA2BGR))
    if not ok:  # pragma: no cover - OpenCV failure
        raise SlmlabError("could not encode the figure as PNG")
    return buf.tobytes()


def _box(controls: dict, compute, draw, fig, title: str):
    """Assemble controls, a status line and the figure image; wire the observers."""
    import ipywidgets as W  # only where a widget is shown: the *_state and draw_* functions work without it

    image = W.Image(format="png")
    status = W.HTML()
    box = W.VBox([W.HTML(f"<b>{title}</b>"), W.HBox(list(controls.values()), layout=W.Layout(flex_flow="row wrap")),
                  status, image])
    box.controls, box.figure = controls, fig

    def update(*_):
        t0 = time.perf_counter()
        box.state = compute(**{k: c.value for k, c in controls.items()})
        draw(box.state, fig)
        image.value = _png(fig)
        box.last_update_s = time.perf_counter() - t0
        status.value = f"<small>updated in {1e3 * box.last_update_s:.0f} ms</small>"

    for c in controls.values():
        c.observe(update, names="value")
    box.update = update
    update()
    return box


# ------------------------------------------------------------------------------------------ 1: the microscope
def microscope_knobs(preset_name: str = "paper") -> dict:
    """The knobs of :func:`microscope_state` as a preset has them (the sliders' starting values)."""
    m = preset(preset_name)
    return {"convergence_deg": m.optics.convergence_deg, "perspective_mm": m.optics.perspective_distance_mm,
            "distortion_scale": 1.0, "stage_skew": m.stage.y_skew, "stage_tilt": m.stage.y_tilt,
            "centroid_noise_px": m.noise.in_focus_px, "positioning_noise_um": m.stage.positioning_noise_um}


def microscope_state(*, preset_name: str = "paper", convergence_deg: float | None = None,
                     perspective_mm: float | None = None, distortion_scale: float = 1.0, stage_skew: float | None = None,
                     stage_tilt: float | None = None, centroid_noise_px: float | None = None,
                     positioning_noise_um: float | None = None, seed: int = 1, session: Session | None = None) -> dict:
    """Simulate a set with the given knobs (``None``: the preset's value, :func:`microscope_knobs`) and run
    §3–§4 on it: stereo angle [degree], perspective distance [mm], decentred distortion (× the preset's), the
    stage's Y skew and tilt [-], centroid noise in focus [px] (it grows with defocus in the preset's proportion),
    positioning noise [µm].

    Returns ``cal``, ``distortion``, ``alignment``, ``disparity`` (the X sequence's disparities) and
    ``table``: Table 1–2 estimates beside what the simulator's optics imply to first order.
    """
    given = {"convergence_deg": convergence_deg, "perspective_mm": perspective_mm, "stage_skew": stage_skew,
             "stage_tilt": stage_tilt, "centroid_noise_px": centroid_noise_px, "positioning_noise_um": positioning_noise_um}
    k = {**microscope_knobs(preset_name), **{n: v for n, v in given.items() if v is not None}}
    m = preset(preset_name)
    o = m.optics
    views = [replace(v, decentring_per_mm=distortion_scale * v.decentring_per_mm,
                     thin_prism_per_mm=distortion_scale * v.thin_prism_per_mm) for v in (o.left, o.right)]
    growth = m.noise.at_dof_edge_px / m.noise.in_focus_px if m.noise.in_focus_px else 2.5
    m = replace(m, optics=replace(o, convergence_deg=k["convergence_deg"], perspective_distance_mm=k["perspective_mm"],
                                  left=views[0], right=views[1]),
                stage=replace(m.stage, y_skew=k["stage_skew"], y_tilt=k["stage_tilt"],
                              positioning_noise_um=k["positioning_noise_um"]),
                noise=replace(m.noise, in_focus_px=k["centroid_noise_px"], at_dof_edge_px=growth * k["centroid_noise_px"]))
    cal = simulate_set(m, session or paper_test(5), seed=seed)
    dist = estimate_distortion(cal.sequence("grid"))
    align = estimate_alignment(cal, dist.apply)
    px = o.pixel_mm
    rows = []
    for side in "lr":
        v = m.optics.view(side)
        rows.append((f"lambda_{side}", dist.view(side).lam, 2 * v.decentring_per_mm * px))
        rows.append((f"a_{side}", dist.view(side).a, (v.decentring_per_mm + v.thin_prism_per_mm) * px))
    l = m.optics.left
    rows += [("alpha_deg", float(np.degrees(align.alpha_rad)), m.optics.left.rotation_deg - m.optics.right.rotation_deg),
             ("dw2_px", align.dw2_px, np.nan),
             ("aD (joint fit)", align.disparity["joint"].aD,
              2 * (3 * l.decentring_per_mm + l.thin_prism_per_mm) * px),
             ("aD (single pass)", align.disparity["single-pass"].aD, np.nan)]
    table = pd.DataFrame(rows, columns=["parameter", "estimate", "simulator_first_order"])
    return {"microscope": m, "cal": cal, "distortion": dist, "alignment": align,
            "disparity": disparity_table(cal, dist.apply, align, sequences=("X",)), "table": table}


def draw_microscope(state: dict, fig) -> None:
    """Left: the dots' image-plane tracks (left view); right: the X sequence's disparity parabola."""
    fig.clear()
    a, b = fig.subplots(1, 2)
    cal = state["cal"]
    for s, colour in (("X", "tab:red"), ("Y", "tab:green"), ("Z", "tab:blue")):
        d = cal.sequence(s)
        d = d[(d["row"] % 3 == 1) & (d["col"] % 3 == 1)]
        for _, g in d.groupby(["row", "col"]):
            a.plot(g["wl1"], g["wl2"], "-", lw=0.8, color=colour)
    w, h = cal.image_size_px
    a.set_xlim(0, w)
    a.set_ylim(h, 0)
    a.set_aspect("equal")
    a.set_title("image-plane tracks (left view)", fontsize=9, y=1.0)   # y: see draw_models
    d = state["disparity"]
    b.plot(d["w1_l"], d["D0"], ",", color="tab:purple")
    j = state["alignment"].disparity["joint"]
    ww = np.linspace(d["w1_l"].min(), d["w1_l"].max(), 100)
    level = np.mean(d["D0"] - (j.aD * d["w1_l"] ** 2 + j.bD * d["w1_l"]))
    b.plot(ww, level + j.aD * ww ** 2 + j.bD * ww, "k-", lw=1)
    b.set_xlabel("w1 [px]")
    b.set_ylabel("disparity D0 [px]")
    b.set_title("disparity along X (joint-fit parabola)", fontsize=9, y=1.0)


def explore_microscope(preset_name: str = "paper", seed: int = 1, **defaults):
    """The virtual microscope's knobs, starting from the preset's values (or ``defaults``); live: image-plane
    tracks, the disparity parabola, Table 1–2 estimates beside the simulator's first-order values (under the
    figure, in ``box.table``)."""
    import ipywidgets as W  # only where a widget is shown: the *_state and draw_* functions work without it

    start = {**microscope_knobs(preset_name), **defaults}

    def slider(lo, hi, step, desc):
        return W.FloatSlider(value=start[desc], min=lo, max=hi, step=step, description=desc,
                             continuous_update=False, style={"description_width": "initial"})
    controls = {
        "convergence_deg": slider(8.0, 20.0, 0.1, "convergence_deg"),
        "perspective_mm": slider(50.0, 1000.0, 10.0, "perspective_mm"),
        "distortion_scale": slider(0.0, 3.0, 0.1, "distortion_scale"),
        "stage_skew": slider(-0.02, 0.02, 0.0005, "stage_skew"),
        "stage_tilt": slider(-0.04, 0.04, 0.001, "stage_tilt"),
        "centroid_noise_px": slider(0.0, 0.2, 0.005, "centroid_noise_px"),
        "positioning_noise_um": slider(0.0, 3.0, 0.1, "positioning_noise_um"),
    }
    table = W.HTML()

    def draw(state, fig):
        draw_microscope(state, fig)
        table.value = state["table"].to_html(index=False, float_format=lambda v: f"{v:.4g}")
    box = _box(controls, partial(microscope_state, preset_name=preset_name, seed=seed), draw, _figure(10, 4),
               f"The virtual microscope, preset {preset_name} (§3–§4 on a Test 5 set)")
    box.children = (*box.children, table)
    box.table = table
    return box


# ------------------------------------------------------------------------------------------ 2: the models
@lru_cache(maxsize=4)
def _model_sets(seed: int, preset_name: str = "paper"):
    m = preset(preset_name)
    return simulate_set(m, paper_test(1), seed=seed), simulate_set(m, validation_session(), seed=seed + 100)


@lru_cache(maxsize=16)
def _evaluation(model: str, seed: int, preset_name: str = "paper"):
    cal, val = _model_sets(seed, preset_name)
    name = default_model_name() if model == "default" else model
    options = {"variant": "standard"} if name == "pinhole" else {}
    return evaluate(calibrate(cal, name, **options), val)


def model_state(*, model: str = "paper-m2", interval: str = "RA3", seed: int = 1, preset_name: str = "paper") -> dict:
    """Evaluation of one model (calibrated on Test 1 of the preset's microscope, validated on a fresh run;
    cached) at one interval: ``residuals``, ``s`` (S coefficients) and ``interval_mm``."""
    ev = _evaluation(model, seed, preset_name)
    return {"model": model, "residuals": ev.residuals, "s": ev.s, "interval": interval,
            "interval_mm": RESIDUAL_INTERVALS_MM[interval], "requirement": ev.requirement}


def draw_models(state: dict, fig) -> None:
    """3 × 3 residual panels (Figs 13–15 style) with ±interval, and S at the interval (Figs 12/16 style).

    The axes are made once; later calls only update the artists' data (most of an update's time otherwise). The
    titles are placed at the top of their axes (``y=1.0``), where matplotlib would put them too (no tick labels or
    offset text above): left to it, it measures every axis's tick labels again on each draw to see whether they
    reach above."""
    res, a = state["residuals"], state["interval_mm"]
    art = getattr(fig, "_slmlab_artists", None)
    if art is None:
        fig.subplots_adjust(hspace=0.8, wspace=0.3, bottom=0.09)
        gs = fig.add_gridspec(3, 4)
        art = {"panels": {}, "bars": {}}
        for r, seq in enumerate("XYZ"):
            for c, comp in enumerate("XYZ"):
                ax = fig.add_subplot(gs[r, c])
                line, = ax.plot([], [], ",", color="tab:blue")
                hi = ax.axhline(0, color="tab:red", ls="--", lw=0.8)
                lo = ax.axhline(0, color="tab:red", ls="--", lw=0.8)
                ax.set_title(f"E$_{{{seq},{comp}}}$ [µm]", fontsize=8, y=1.0)
                ax.tick_params(labelsize=6)  # every panel its own scale, so every panel its own labels
                ax.set_xlabel(f"Δ{seq} [mm]", fontsize=7, labelpad=1)
                ax.xaxis.set_major_locator(MaxNLocator(3))
                ax.yaxis.set_major_locator(MaxNLocator(4))
                art["panels"][seq + comp] = (ax, line, hi, lo)
            ax = fig.add_subplot(gs[r, 3])
            bars = ax.bar(range(3), [0, 0, 0], color=["tab:red", "tab:green", "tab:blue"])
            ax.axhline(95, color="0.4", ls="--", lw=0.8)
            ax.set_xticks(range(3), [f"S$_{{{seq},{c}}}$" for c in "XYZ"], fontsize=7)
            ax.set_ylim(0, 105)
            ax.set_title("", fontsize=8, y=1.0)
            ax.tick_params(labelsize=6)
            art["bars"][seq] = (ax, bars)
        fig._slmlab_artists = art
    for el, (ax, line, hi, lo) in art["panels"].items():
        d = res[res["sequence"] == el[0]]
        y = 1e3 * d[f"E_{el[1]}"].to_numpy()
        line.set_data(d["displacement_mm"].to_numpy(), y)
        hi.set_ydata([1e3 * a, 1e3 * a])
        lo.set_ydata([-1e3 * a, -1e3 * a])
        top = max(float(np.abs(y).max()) if len(y) else 0.0, 1e3 * a) * 1.1
        x = d["displacement_mm"].to_numpy()
        if len(x):
            ax.set_xlim(min(x.min(), 0), max(x.max(), 0) + 1e-9)
        ax.set_ylim(-top, top)
    s = state["s"]
    for seq, (ax, bars) in art["bars"].items():
        for bar, comp in zip(bars, "XYZ"):
            bar.set_height(s.loc[seq + comp, state["interval"]] if seq + comp in s.index else 0)
        ax.set_title(f"S at {state['interval']} [%]", fontsize=8)
    fig.suptitle(f"{state['model']}: residual elements and S coefficients", fontsize=9)


def explore_models(preset_name: str = "paper", seed: int = 1, **defaults):
    """Model level (0, 1, 2, pinhole, default) and residual interval, on the preset's microscope; live: the
    nine residual elements and the S coefficients."""
    import ipywidgets as W  # only where a widget is shown: the *_state and draw_* functions work without it

    controls = {
        "model": W.ToggleButtons(options=["paper-m0", "paper-m1", "paper-m2", "pinhole", "default"],
                                 value=defaults.get("model", "paper-m2"), description="model"),
        "interval": W.ToggleButtons(options=list(RESIDUAL_INTERVALS_MM), value=defaults.get("interval", "RA3"),
                                    description="interval"),
    }
    return _box(controls, partial(model_state, preset_name=preset_name, seed=seed), draw_models, _figure(9.5, 6.0),
                f"The paper's models on a validation run (preset {preset_name})")


# ------------------------------------------------------------------------------------------ 3: the step study
def step_state(*, step_mm: float = 0.3, positions: int = 10, repeats: int = 3, seed: int = 1,
               preset_name: str = "paper") -> dict:
    """The twelve parameters over ``repeats`` fresh calibrations of the preset's microscope at one step [mm]
    and number of positions per axis: ``fits`` (one row per repeat) and ``spread`` (mean, std, relative std
    per parameter)."""
    m = preset(preset_name)
    session = Session(step_mm=step_mm, positions=(positions, positions, positions), grid=True, name="study")
    seeds = np.random.SeedSequence(seed).generate_state(repeats)
    # §3 by the paper's two-step estimate only: the study is about §5's twelve parameters, and the joint
    # lattice refinement would double the time of an update
    fits = pd.DataFrame([fit_paper(simulate_set(m, session, seed=int(s)), distortion_method="paper-two-step")[0].as_dict()
                         for s in seeds])[TABLE4_NAMES]
    spread = pd.DataFrame({"parameter": TABLE4_NAMES, "mean": fits.mean().to_numpy(), "std": fits.std(ddof=1).to_numpy()})
    spread["relative_std_percent"] = 100 * spread["std"] / spread["mean"].abs()
    return {"fits": fits, "spread": spread, "step_mm": step_mm, "positions": positions}


def draw_steps(state: dict, fig) -> None:
    """The twelve parameters' spread over the repeats (relative std [%], log scale)."""
    s = state["spread"]
    art = getattr(fig, "_slmlab_artists", None)
    if art is None:  # axes and bars made once; later updates only change the bars (the redraw is most of it)
        fig.subplots_adjust(left=0.22)
        ax = fig.add_subplot()
        bars = ax.barh(s["parameter"], s["relative_std_percent"], color="tab:blue")
        ax.invert_yaxis()
        ax.tick_params(labelsize=7)
        ax.set_xlabel("std / |mean| over repeated calibrations [%]")
        art = fig._slmlab_artists = (ax, bars)
    ax, bars = art
    for bar, v in zip(bars, s["relative_std_percent"]):
        bar.set_width(v)
    ax.set_xlim(0, 1.1 * float(s["relative_std_percent"].max()))
    ax.set_title(f"step {state['step_mm']:.2f} mm, {state['positions']} positions per axis", fontsize=9, y=1.0)


def explore_steps(preset_name: str = "paper", seed: int = 1, **defaults):
    """Interval distance and number of positions, on the preset's microscope; live: the twelve parameters'
    spread."""
    import ipywidgets as W  # only where a widget is shown: the *_state and draw_* functions work without it

    controls = {
        "step_mm": W.FloatSlider(value=defaults.get("step_mm", 0.3), min=0.1, max=0.5, step=0.05, description="step_mm",
                                 continuous_update=False),
        "positions": W.IntSlider(value=defaults.get("positions", 10), min=4, max=30, description="positions",
                                 continuous_update=False),
    }
    return _box(controls, partial(step_state, preset_name=preset_name, seed=seed), draw_steps, _figure(7, 4),
                f"The step study (Tables 3–4, preset {preset_name})")
