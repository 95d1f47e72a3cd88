"""Figures: drawing only, never computing what the model modules compute.

Every function takes ``ax=None`` (or ``axes=None`` for multi-panel figures) and keyword-only options, draws,
and returns the Axes. Names follow the paper's figures.
"""

from __future__ import annotations

import cv2
import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
from matplotlib.patches import Circle, Polygon, Rectangle

from .io import CalibrationSet
from .outputs import table_digits
from .virtual.microscope import Microscope

__all__ = ["new_figure", "plot_cmo_geometry", "plot_stage_axes_top_view", "plot_stage_sequences",
           "plot_image_tracks", "plot_depth_response", "plot_error_vs_defocus", "plot_plate_index",
           "plot_dots_on_image", "plot_display", "plot_display_quad", "plot_virtual_lines", "plot_disparity",
           "plot_dz_vs_dd", "plot_s_bars", "plot_residual_panels", "plot_scene_side", "plot_located",
           "plot_trajectory", "plot_volumetric_errors", "plot_cross_validation_diff", "plot_accuracy_vs_positions",
           "plot_leave_one_plane_out", "plot_floor_ratios", "plot_pick_differences", "plot_level_map",
           "plot_model_comparison", "plot_recovered_share", "plot_numbering", "plot_point_uncertainty"]

MPL_VERSION = tuple(int(p) for p in matplotlib.__version__.split(".")[:2])
SEQUENCE_COLOURS = {"X": "tab:red", "Y": "tab:green", "Z": "tab:blue", "grid": "0.5", "V": "tab:purple"}
VIEW_COLOURS = {"l": "tab:orange", "r": "tab:cyan"}


def new_figure(nrows: int = 1, ncols: int = 1, *, width_in: float = 6.4, height_in: float = 4.0, **kw):
    """A figure with a fixed size and layout (byte-stable output)."""
    fig, axes = plt.subplots(nrows, ncols, figsize=(width_in, height_in), layout="constrained", **kw)
    return fig, axes


def _ax(ax):
    if ax is None:
        _, ax = new_figure()
    return ax


def _as_drawn(values) -> np.ndarray:
    """Numbers as a figure draws them: to the digits a table carries (:func:`slmlab.outputs.table_digits`).

    Another machine computes the same quantities to within their last bits (its CPU's ``exp``, its BLAS
    kernels); drawn at full precision, a point can then move by a fraction of a pixel and change the
    anti-aliasing of a few pixels, so the PNG is no longer byte-stable. Four significant digits are far finer
    than a pixel of any figure here and far coarser than those last bits."""
    v = np.asarray(values, dtype=float)
    return table_digits(pd.DataFrame({"v": v.ravel()}))["v"].to_numpy().reshape(v.shape)


def plot_cmo_geometry(microscope: Microscope, ax=None, *, exaggerate_z: float = 1.0, show_dof: bool = True):
    """Side view (x–z) of the two views through the common main objective (stand-in for the paper's Figs 2
    and 9): the projection centres at ``(±L tan(γ/2), L)``, the chief rays converging on the focal point,
    the focal plane, the depth of field and the field of view.

    Parameters
    ----------
    microscope
        the virtual microscope.
    exaggerate_z
        vertical scale of the drawing relative to the horizontal one (1: true shape).
    """
    ax = _ax(ax)
    o = microscope.optics
    L = o.perspective_distance_mm
    cl, cr = o.centre_x_mm
    half_field = o.image_size_px[0] * o.pixel_mm / 2
    ez = exaggerate_z
    # objective (a thin lens drawn near the centres) and the two sub-system pupils
    lens_z = 0.85 * L
    lens_half = 1.35 * max(abs(cl), abs(cr))
    ax.plot([-lens_half, lens_half], [lens_z * ez] * 2, color="k", lw=3, solid_capstyle="round")
    ax.text(lens_half, lens_z * ez, "  common main objective", va="center", fontsize=8)
    for side, c in (("l", cl), ("r", cr)):
        col = VIEW_COLOURS[side]
        ax.plot([c], [L * ez], "o", color=col, ms=7)
        ax.text(c + (-4 if side == "l" else 4), L * ez, f"{'left' if side == 'l' else 'right'} view centre ",
                ha="right" if side == "l" else "left", va="center", fontsize=8, color=col)
        for x_edge in (-half_field, 0.0, half_field):
            ax.plot([c, x_edge], [L * ez, 0.0], color=col, lw=1.2 if x_edge == 0 else 0.6,
                    ls="-" if x_edge == 0 else ":")
    ax.axhline(0.0, color="k", lw=0.8)
    ax.text(lens_half, 0.02 * L * ez, "focal plane", ha="left", va="bottom", fontsize=8)
    if show_dof:
        dof = o.depth_of_field_mm * ez
        ax.axhspan(-dof, dof, color="0.85", zorder=0)
    ax.annotate(f"γ = {o.convergence_deg:.2f}°", xy=(0, 0.25 * L * ez), ha="center", fontsize=9)
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("z [mm]" + (f" (×{ez:g})" if ez != 1 else ""))
    ax.set_title(f"Two views through the common main objective (L = {L:g} mm)", fontsize=10)
    ax.set_xlim(-2.2 * lens_half, 2.6 * lens_half)
    ax.set_ylim(-0.05 * L * ez, 1.12 * L * ez)
    return ax


def plot_stage_axes_top_view(microscope: Microscope, ax=None, *, exaggerate: float = 10.0):
    """Top view of the image axes and the stage axes (paper Fig 9b): the stage is rotated by ``-θX`` and
    its Y axis skewed; departures from orthogonality are drawn ``exaggerate`` times larger."""
    ax = _ax(ax)
    axes = microscope.stage.axes
    # exaggerate the departure from the ideal (rotated orthonormal) frame
    rot = axes[:, 0] / np.linalg.norm(axes[:, 0])
    ideal_y = np.array([-rot[1], rot[0], 0.0])
    ax.annotate("", xy=(1, 0), xytext=(0, 0), arrowprops=dict(arrowstyle="->", color="k"))
    ax.annotate("", xy=(0, 1), xytext=(0, 0), arrowprops=dict(arrowstyle="->", color="k"))
    ax.text(1.02, 0, "microscope x\n(−w1)", fontsize=8, va="center")
    ax.text(0, 1.04, "microscope y (−w2)", fontsize=8, ha="center")
    yx = ideal_y + exaggerate * (axes[:, 1] - ideal_y)
    for vec, name in ((rot, "stage X"), (yx, f"stage Y (skew ×{exaggerate:g})")):
        ax.annotate("", xy=(vec[0], vec[1]), xytext=(0, 0),
                    arrowprops=dict(arrowstyle="->", color="tab:red", lw=1.5))
        ax.text(vec[0] * 1.05, vec[1] * 1.05 - 0.06, name, color="tab:red", fontsize=8)
    theta = np.degrees(np.arctan2(rot[1], rot[0]))
    ax.set_title(f"Stage X at {theta:+.2f}° from the image rows (θX = {-theta:.2f}°)", fontsize=10)
    ax.set_aspect("equal")
    ax.set_xlim(-0.3, 1.5)
    ax.set_ylim(-0.3, 1.2)
    ax.axis("off")
    return ax


def plot_stage_sequences(cal: CalibrationSet, ax=None, *, sequences=("X", "Y", "Z")):
    """The commanded stage positions of the axis sequences in 3D (stand-in for the paper's Fig 11).
    ``ax`` must be a 3D Axes if given."""
    if ax is None:
        fig = plt.figure(figsize=(5.0, 4.2), layout="constrained")
        ax = fig.add_subplot(projection="3d")
    for s in sequences:
        df = cal.sequence(s).drop_duplicates("position")
        if df.empty:
            continue
        ax.plot(df["stage_x_mm"], df["stage_y_mm"], df["stage_z_mm"], "o-", ms=2.5, lw=0.8,
                color=SEQUENCE_COLOURS.get(s, "k"), label=f"{s} sequence ({len(df)} positions)")
        first = df.iloc[0]
        ax.scatter([first["stage_x_mm"]], [first["stage_y_mm"]], [first["stage_z_mm"]], color="k", s=12)
    ax.set_xlabel("stage X [mm]")
    ax.set_ylabel("stage Y [mm]")
    ax.set_zlabel("stage Z [mm]")
    ax.legend(fontsize=7, loc="upper left")
    ax.set_title("Stage sequences (black: position 1)", fontsize=10)
    return ax


def plot_image_tracks(cal: CalibrationSet, axes=None, *, sequences=("X", "Y", "Z"), every: int = 1,
                      depth_sequence: str = "Z"):
    """Image-plane tracks of the dots along the axis sequences (paper Fig 9b, Fig 11), left and right view.

    Top row: each dot's path over the positions of the lateral sequences (``sequences`` but
    ``depth_sequence``), the whole image; position 1 marked. Bottom row: the ``depth_sequence`` alone, zoomed
    on the plate, each path an arrow from position 1 to the last position: the two views' dots move in
    opposite directions along ``w1`` as depth changes (the disparity), which the lateral tracks would hide at
    full-image scale. ``every`` thins the dots drawn (1: all 49)."""
    if axes is None:
        _, axes = new_figure(2, 2, width_in=9.0, height_in=8.6, height_ratios=[1.35, 1])
    width, height = cal.image_size_px
    depth = cal.sequence(depth_sequence) if depth_sequence in sequences else cal.sequence(depth_sequence).iloc[:0]
    for c, (side, c1, c2) in enumerate((("l", "wl1", "wl2"), ("r", "wr1", "wr2"))):
        name = "left" if side == "l" else "right"
        top, bottom = axes[0, c], axes[1, c]
        for s in sequences:
            if s == depth_sequence:
                continue
            for n, (_, g) in enumerate(_tracks(cal.sequence(s), every)):
                top.plot(g[c1], g[c2], "-", lw=0.6, color=SEQUENCE_COLOURS[s], label=f"{s} sequence" if n == 0 else None)
                top.plot(g[c1].iloc[:1], g[c2].iloc[:1], ".", ms=2, color="k")
        top.set_xlim(0, width)
        top.set_ylim(height, 0)
        top.set_aspect("equal")
        top.set_xlabel("w1 [px]")
        top.set_ylabel("w2 [px]")
        top.set_title(f"({'ab'[c]}) {name} image: lateral sequences", fontsize=10)
        if top.get_legend_handles_labels()[0]:
            top.legend(fontsize=7, loc="lower left")
        for n, (_, g) in enumerate(_tracks(depth, every)):
            bottom.annotate("", xy=(g[c1].iloc[-1], g[c2].iloc[-1]), xytext=(g[c1].iloc[0], g[c2].iloc[0]),
                            arrowprops=dict(arrowstyle="->", color=SEQUENCE_COLOURS.get(depth_sequence, "k"), lw=0.9))
            bottom.plot(g[c1].iloc[:1], g[c2].iloc[:1], ".", ms=3, color="k")
        bottom.set_title(f"({'cd'[c]}) {name} image, {depth_sequence} sequence: first (dot) → last position", fontsize=10)
        bottom.set_xlabel("w1 [px]")
        bottom.set_ylabel("w2 [px]")
    if len(depth):
        w1 = depth[["wl1", "wr1"]].to_numpy(float)
        w2 = depth[["wl2", "wr2"]].to_numpy(float)
        pad = 0.06 * (np.nanmax(w1) - np.nanmin(w1))
        for ax in axes[1]:
            ax.set_xlim(np.nanmin(w1) - pad, np.nanmax(w1) + pad)
            ax.set_ylim(np.nanmax(w2) + pad, np.nanmin(w2) - pad)
            ax.set_aspect("equal")
    return axes


def _tracks(df, every: int):
    """Each dot's rows of a sequence, in position order: ``(row, col), rows`` for every ``every``-th dot."""
    if df.empty:
        return []
    keys = df[["row", "col"]].drop_duplicates().to_numpy()[::every]
    groups = dict(tuple(df.sort_values("position").groupby(["row", "col"])))
    return [((i, j), groups[(i, j)]) for i, j in keys]


def plot_depth_response(responses: dict, axes=None):
    """Disparity and relative magnification against depth for one or more microscopes.

    Parameters
    ----------
    responses
        label -> DataFrame of :func:`slmlab.virtual.microscope.depth_response`.
    """
    if axes is None:
        _, axes = new_figure(1, 2, width_in=9.0, height_in=3.6)
    for label, df in responses.items():
        z = df["z_mm"].to_numpy()
        d = df["disparity_px"].to_numpy()
        i0 = int(np.argmin(np.abs(z)))
        rate = np.gradient(d, z)[i0]
        axes[0].plot(z, d - (d[i0] + rate * (z - z[i0])), label=f"{label} ({rate:.2f} px/mm at focus)")
        mag = df["magnification_l_px_per_mm"].to_numpy()
        axes[1].plot(z, 100 * (mag / mag[i0] - 1), label=label)
    axes[0].set_xlabel("z above the focal plane [mm]")
    axes[0].set_ylabel("disparity − its tangent at focus [px]")
    axes[0].set_title("Disparity is not exactly linear in depth", fontsize=10)
    axes[1].set_xlabel("z above the focal plane [mm]")
    axes[1].set_ylabel("magnification change [%]")
    axes[1].set_title("Perspective: magnification grows towards the objective", fontsize=10)
    for ax in axes:
        ax.axhline(0, color="0.6", lw=0.6)
        ax.legend(fontsize=7)
    return axes


def plot_error_vs_defocus(by_depth, ax=None, *, depth_of_field_mm: float = 1.13, targets=(0.03, 0.05)):
    """Centre RMS error [px] against height above the focal plane, one line per method
    (``by_depth`` from :func:`slmlab.images.extract.error_by_defocus`); the targets and the depth of field drawn."""
    ax = _ax(ax)
    for method, d in by_depth.groupby("method"):
        ax.plot(_as_drawn(d["z_bin_mm"]), _as_drawn(d["rms_px"]), "o-", ms=3, label=method)
    ax.axvspan(-depth_of_field_mm, depth_of_field_mm, color="0.92", zorder=0, label="depth of field")
    ax.axhline(targets[0], color="tab:green", ls="--", lw=0.8, label=f"target in focus ({targets[0]} px)")
    ax.axhline(targets[1], color="tab:red", ls="--", lw=0.8, label=f"target over the depth of field ({targets[1]} px)")
    ax.set_xlabel("z above the focal plane [mm]")
    ax.set_ylabel("centre RMS error per coordinate [px]")
    ax.set_ylim(0, max(0.06, float(_as_drawn(by_depth["rms_px"]).max()) * 1.1))
    ax.legend(fontsize=7)
    ax.set_title("Dot centre error against defocus (rendered images vs truth)", fontsize=10)
    return ax


def plot_plate_index(rows: int, cols: int, ax=None, *, show: int = 5):
    """The index definition of the calibration plate (paper Fig 3a): dot ``A[i,j]`` in row ``i``, column
    ``j``; ``A11`` top left, ``AM1`` bottom left, ``A1N`` top right. Draws a ``show × show`` corner."""
    ax = _ax(ax)
    i, j = np.meshgrid(np.arange(show), np.arange(show), indexing="ij")
    ax.scatter(j.ravel(), i.ravel(), s=120, color="k")
    labels = {(0, 0): "A$_{11}$", (show - 1, 0): "A$_{M1}$", (0, show - 1): "A$_{1N}$", (show - 1, show - 1): "A$_{MN}$"}
    for (r, c), txt in labels.items():
        ax.text(c, r - 0.38, txt, ha="center", va="bottom", fontsize=10)
    ax.text((show - 1) / 2, -1.1, f"{cols} columns (j = 1..N)", ha="center", fontsize=9)
    ax.text(-1.0, (show - 1) / 2, f"{rows} rows\n(i = 1..M)", ha="right", va="center", fontsize=9)
    ax.set_xlim(-2.4, show)
    ax.set_ylim(show, -1.6)
    ax.set_aspect("equal")
    ax.axis("off")
    ax.set_title("(a) grid point indices", fontsize=10)
    return ax


def plot_dots_on_image(image, table, ax=None, *, title: str = "", reduce: int = 4):
    """An image (shown at 1/``reduce`` scale) with the extracted dots connected row by row (red) and
    column by column (blue), as in the paper's Fig 3b–c. ``table`` has ``row, col, w1, w2``."""
    ax = _ax(ax)
    small = cv2.resize(image, (image.shape[1] // reduce, image.shape[0] // reduce), interpolation=cv2.INTER_AREA)
    ax.imshow(small, cmap="gray", vmin=0, vmax=255, extent=(-0.5, image.shape[1] - 0.5, image.shape[0] - 0.5, -0.5))
    for key, colour in (("row", "tab:red"), ("col", "tab:blue")):
        other = "col" if key == "row" else "row"
        for _, g in table.groupby(key):
            g = g.sort_values(other)
            ax.plot(g["w1"], g["w2"], "-", color=colour, lw=0.5)
    ax.set_xlabel("w1 [px]")
    ax.set_ylabel("w2 [px]")
    ax.set_title(title, fontsize=10)
    return ax


# ------------------------------------------------------------------------------------------ §3–§6 figures
def plot_display(df, ax=None, *, by: str = "row", title: str = "", xlabel: str = "", ylabel: str = ""):
    """Lines of the display transform (Eqs 1–2, Figs 4 and 6): one polyline per ``by`` group of ``x, y``."""
    ax = _ax(ax)
    other = "col" if by == "row" else "row"
    for _, g in df.groupby(by):
        g = g.sort_values(other)
        ax.plot(_as_drawn(g["x"]), _as_drawn(g["y"]), ".-", ms=1.5, lw=0.5, color="tab:red" if by == "row" else "tab:blue")
    ax.set_title(title, fontsize=9)
    ax.set_xlabel(xlabel, fontsize=8)
    ax.set_ylabel(ylabel, fontsize=8)
    ax.tick_params(labelsize=7)
    return ax


def plot_display_quad(frames: dict, axes=None, *, suptitle: str = ""):
    """The four panels of Fig 4 / Fig 6: rows and columns of the left and right images.
    ``frames`` maps ``('rows'|'cols', 'l'|'r')`` to display-transformed DataFrames."""
    if axes is None:
        fig, axes = new_figure(2, 2, width_in=9.0, height_in=7.0)
    letters = iter("abcd")
    for r, kind in enumerate(("rows", "cols")):
        for c, side in enumerate("lr"):
            name = f"({next(letters)}) {kind[:-1] if kind == 'rows' else 'column'}s of grid points, {'left' if side == 'l' else 'right'} image"
            frame = frames[(kind, side)]
            default = "w2 − w2[i,1] + i·s [px]" if kind == "rows" else "w1 − chord + j·s [px]"
            plot_display(frame, axes[r, c], by="row" if kind == "rows" else "col", title=name,
                         xlabel="w1 [px]" if kind == "rows" else "w2 [px]", ylabel=frame.attrs.get("y_label", default))
    if suptitle:
        axes[0, 0].figure.suptitle(suptitle, fontsize=10)
    return axes


def plot_virtual_lines(df, ax=None):
    """Fig 5: the spacing ``L_{k→1}`` between row lines (through the origin) and the first one, against ``w1``."""
    ax = _ax(ax)
    for c in df.columns[1:]:
        k = c.split("_")[1]
        ax.plot(df["w1_px"], df[c], label=f"L$_{{{k}\\to 1}}$")
    ax.set_xlabel("w1 [px]")
    ax.set_ylabel("spacing of the row lines' slopes × w1 [px]")
    ax.set_title("Spacing of virtual lines (rows through the origin), left image", fontsize=10)
    ax.legend(fontsize=7)
    return ax


def plot_disparity(table, axes=None, *, column: str = "D0", fits: dict | None = None, title: str = "",
                   ylabel: str = "disparity D = w1_r − w1_l [px]"):
    """Figs 7–8: disparity against ``w1`` along the X sequence (a) and against ``w2`` along the Y sequence (b).

    ``column`` is the table's disparity to draw (``D0`` as measured, or a corrected one), labelled ``ylabel``;
    ``fits`` maps a label to a function ``w1 → D`` drawn over panel (a) (the fitted parabolas)."""
    if axes is None:
        _, axes = new_figure(1, 2, width_in=10.0, height_in=3.8)
    x = table[table["sequence"] == "X"]
    y = table[table["sequence"] == "Y"]
    axes[0].scatter(_as_drawn(x["w1_l"]), _as_drawn(x[column]), s=1.5, c=x["row"] * 10 + x["col"], cmap="viridis",
                    rasterized=True)
    for label, fn in (fits or {}).items():
        w = np.linspace(*_as_drawn([x["w1_l"].min(), x["w1_l"].max()]), 200)
        axes[0].plot(w, _as_drawn(fn(w)), lw=1.2, label=label)
    if fits:
        axes[0].legend(fontsize=7)
    axes[0].set_xlabel("w1 (left) [px]")
    axes[0].set_ylabel(ylabel)
    axes[0].set_title("(a) X sequence: disparity against w1", fontsize=9)
    if len(y):
        axes[1].scatter(_as_drawn(y["w2_l"]), _as_drawn(y[column]), s=1.5, c=y["row"] * 10 + y["col"], cmap="viridis",
                        rasterized=True)
    axes[1].set_xlabel("w2 (left) [px]")
    axes[1].set_ylabel(ylabel)
    axes[1].set_title("(b) Y sequence: disparity against w2", fontsize=9)
    if title:
        axes[0].figure.suptitle(title, fontsize=10)
    return axes


def plot_dz_vs_dd(samples, ez_mm_per_px: float, ax=None):
    """Fig 10: the stage's ``ΔZ_A`` against the disparity increment ``ΔD``, with the line ``ΔZ = EZ·ΔD``."""
    ax = _ax(ax)
    ax.plot(samples["dD_px"], samples["dZ_A_mm"], ".", ms=2, color="tab:blue", label="Z-sequence samples")
    d = np.linspace(samples["dD_px"].min(), samples["dD_px"].max(), 2)
    ax.plot(d, ez_mm_per_px * d, "-", color="tab:red", lw=1, label=f"ΔZ = EZ·ΔD, EZ = {ez_mm_per_px:.5f} mm/px")
    ax.set_xlabel("disparity increment ΔD [px]")
    ax.set_ylabel("stage displacement ΔZ_A [mm]")
    ax.legend(fontsize=7)
    ax.set_title("Depth is linear in the disparity increment", fontsize=10)
    return ax


def plot_s_bars(s_table, axes=None, *, reference: dict | None = None, title: str = ""):
    """Figs 12 and 16: S coefficients [%] over RA1–RA5 as bars, one panel per sequence (X, Y, Z), the
    paper's reported values marked (``reference``: ``{element: {interval: percent}}``).

    The bars' colours are the residual's component (X, Y, Z), the same in every panel; one legend for the
    figure, below the panels, so that no bar is hidden behind it."""
    if axes is None:
        _, axes = new_figure(1, 3, width_in=12.0, height_in=3.9, sharey=True)
    intervals = list(s_table.columns)
    xs = np.arange(len(intervals))
    width = 0.26
    colours = {"X": "tab:red", "Y": "tab:green", "Z": "tab:blue"}
    for ax, seq in zip(axes, "XYZ"):
        for k, comp in enumerate("XYZ"):
            el = seq + comp
            if el not in s_table.index:
                continue
            ax.bar(xs + (k - 1) * width, _as_drawn(s_table.loc[el].to_numpy()), width, color=colours[comp])
            for ra, val in ((reference or {}).get(el) or {}).items():
                if ra in intervals:
                    i = intervals.index(ra)
                    ax.plot(xs[i] + (k - 1) * width, val, "k_", ms=12, mew=2)
        ax.axhline(95, color="0.4", ls="--", lw=0.8)
        ax.set_xticks(xs, intervals)
        ax.set_ylim(0, 105)
        ax.set_title(f"({'abc'['XYZ'.index(seq)]}) {seq} sequence: S$_{{{seq}X}}$, S$_{{{seq}Y}}$, S$_{{{seq}Z}}$",
                     fontsize=9)
    axes[0].set_ylabel("S [%]")
    handles = [plt.Rectangle((0, 0), 1, 1, color=colours[c]) for c in "XYZ"]
    labels = [f"{c} component of the residual" for c in "XYZ"]
    if reference:  # the paper's values are in the legend only where they are drawn
        handles.append(plt.Line2D([], [], color="k", marker="_", ms=12, mew=2, ls=""))
        labels.append("the paper's reported value")
    handles.append(plt.Line2D([], [], color="0.4", ls="--", lw=0.8))
    labels.append("95 %")
    axes[0].figure.legend(handles, labels, loc="outside lower center", ncols=5, fontsize=8, frameon=False)
    if title:
        axes[0].figure.suptitle(title, fontsize=10)
    return axes


def plot_residual_panels(res, axes=None, *, interval_mm: float = 0.01, z_interval_mm: float | None = None,
                         title: str = "", ylim_mm: float | None = None):
    """Figs 13–15 and 17: the nine residual elements against the displacement along the sequence's axis,
    3 × 3 panels (rows: X, Y, Z sequences; columns: X, Y, Z components), the ±interval (RA3, dashed) drawn in
    every panel as in the paper; ``z_interval_mm``: also the Z components' own requirement (§6: RA5), dotted in
    their column, so that a Z element inside it but outside RA3 is seen to meet it."""
    if axes is None:
        _, axes = new_figure(3, 3, width_in=10.0, height_in=8.0, sharex="row")
    for r, seq in enumerate("XYZ"):
        d = res[res["sequence"] == seq]
        for c, comp in enumerate("XYZ"):
            ax = axes[r, c]
            ax.plot(d["displacement_mm"], 1e3 * d[f"E_{comp}"], ".", ms=1.2, color="tab:blue", rasterized=True)
            for sign in (1, -1):
                ax.axhline(sign * 1e3 * interval_mm, color="tab:red", lw=0.8, ls="--",
                           label=f"±{1e3 * interval_mm:g} µm" if sign > 0 else None)
                if comp == "Z" and z_interval_mm is not None:
                    ax.axhline(sign * 1e3 * z_interval_mm, color="tab:purple", lw=0.9, ls=":",
                               label=f"±{1e3 * z_interval_mm:g} µm (Z requirement)" if sign > 0 else None)
            if r == 0 and comp == "Z" and z_interval_mm is not None:
                ax.legend(fontsize=6, loc="upper right", framealpha=0.8)
            if ylim_mm is not None:
                ax.set_ylim(-1e3 * ylim_mm, 1e3 * ylim_mm)
            ax.set_title(f"E$_{{{seq},{comp}}}$", fontsize=9)
            ax.tick_params(labelsize=7)
            if c == 0:
                ax.set_ylabel("residual [µm]", fontsize=8)
            ax.set_xlabel(f"Δ{seq} [mm]", fontsize=8)
    if title:
        axes[0, 0].figure.suptitle(title, fontsize=10)
    return axes


# ------------------------------------------------------------------------------------------ §2 figures
def plot_scene_side(scene, ax=None):
    """Fig 1a: side view (x–z) of the gripping scene: hub, the wire's cross-section, the gripper's jaws
    straddling it (above and below), the pad [mm]."""
    ax = _ax(ax)
    g = scene.grip_point()
    r = scene.wire_diameter_mm / 2
    ax.add_patch(Rectangle((scene.hub_centre_mm[0] - scene.hub_radius_mm, g[2] - 0.15), 2 * scene.hub_radius_mm, 0.3,
                           color="0.35", label="object hub"))
    ax.add_patch(Circle((g[0], g[2]), r, color="#b87333", label="copper wire (Ø 100 µm)"))
    for sgn in (1, -1):
        y = g[2] + sgn * (r + 0.01)
        ax.add_patch(Polygon([(g[0] - 0.02, y), (g[0] + 0.6, y + sgn * 0.12), (g[0] + 2.0, y + sgn * 0.12),
                              (g[0] + 2.0, y + sgn * 0.02)], closed=True, color="0.1",
                             label="gripper jaws" if sgn > 0 else None))
    p = scene.pad_centre_mm
    ax.add_patch(Rectangle((p[0] - scene.pad_size_mm / 2, p[2] - 0.2), scene.pad_size_mm, 0.2, color="0.6", label="pad"))
    ax.set_xlim(min(scene.hub_centre_mm[0], p[0]) - 0.6, g[0] + 2.1)
    ax.set_ylim(g[2] - 0.6, g[2] + 0.6)
    ax.set_aspect("equal")
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("z [mm]")
    ax.legend(fontsize=7, loc="upper left")
    ax.set_title("(a) side view", fontsize=10)
    return ax


def plot_located(image, tip_px, grip_px, line, ax=None, *, title: str = "", half_px: int = 450):
    """An image of the gripping scene with the located tip (red) and the wire's centreline and gripping
    position (cyan) marked, cropped around them."""
    ax = _ax(ax)
    c = (np.asarray(tip_px) + np.asarray(grip_px)) / 2
    x0, y0 = int(max(c[0] - half_px, 0)), int(max(c[1] - half_px, 0))
    crop = image[y0:y0 + 2 * half_px, x0:x0 + 2 * half_px]
    ax.imshow(crop, cmap="gray", vmin=0, vmax=255, extent=(x0 - 0.5, x0 + crop.shape[1] - 0.5, y0 + crop.shape[0] - 0.5, y0 - 0.5))
    mu, d = line
    t = np.array([-400, 400])
    ax.plot(mu[0] + t * d[0], mu[1] + t * d[1], "-", color="tab:cyan", lw=0.8, label="wire centreline")
    ax.plot(*grip_px, "o", mfc="none", mec="tab:cyan", ms=9, label="gripping position")
    ax.plot(*tip_px, "+", color="tab:red", ms=12, mew=2, label="gripper tip")
    ax.set_xlabel("w1 [px]")
    ax.set_ylabel("w2 [px]")
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=7, loc="lower left")
    return ax


def plot_trajectory(trajectory_mm, target_mm, ax=None):
    """The gripper tip's path over the look-and-move iterations, in the x–y plane, with the target."""
    ax = _ax(ax)
    t = np.asarray(trajectory_mm)
    ax.plot(t[:-1, 0], t[:-1, 1], "o-", ms=4, color="tab:red", label="tip after each move")
    ax.plot(t[-2:, 0], t[-2:, 1], "--", color="0.5", label="drag to the pad")
    ax.plot(target_mm[0], target_mm[1], "x", color="tab:cyan", ms=10, mew=2, label="gripping position")
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("y [mm]")
    ax.set_aspect("equal")
    ax.legend(fontsize=7)
    ax.set_title("(c) the loop's trajectory", fontsize=10)
    return ax


def plot_volumetric_errors(errors: dict, ax=None):
    """Displacement error magnitude [µm] over the validation positions, one box per model (``errors``: name →
    DataFrame with ``error_um``, as :func:`slmlab.studies.workspace.volumetric_errors` returns; first at the
    top): the box holds the middle half, the whiskers 5–95 %, the line the median; log scale."""
    if ax is None:
        _, ax = new_figure(width_in=8.0, height_in=0.45 * len(errors) + 1.2)
    names = list(errors)
    horizontal = {"orientation": "horizontal"} if MPL_VERSION >= (3, 10) else {"vert": False}  # renamed in 3.10
    ax.boxplot([errors[n]["error_um"].to_numpy() for n in names], **horizontal, whis=(5, 95), widths=0.6,
               flierprops={"marker": ".", "ms": 2, "alpha": 0.4}, medianprops={"color": "k"})
    ax.set_yticks(range(1, len(names) + 1), names, fontsize=8)
    ax.invert_yaxis()
    ax.set_xscale("log")
    ax.set_xlabel("|displacement error| [µm]   (box: the middle half; whiskers: 5–95 %)")
    ax.grid(axis="x", which="both", color="0.9", lw=0.5)
    ax.set_title("Errors over the whole workspace (random stage positions)", fontsize=10)
    return ax


def plot_cross_validation_diff(diff, axes=None, *, width_in: float = 9.0):
    """mrcal-style cross-validation diffs over the field (``diff`` from
    :func:`slmlab.studies.workspace.cross_validation_diff`): ``|ΔX, ΔY|`` (top) and ``|ΔZ|`` (bottom) [µm] between two
    independent calibrations, one column per depth, one colour scale per row."""
    depths = sorted(diff["depth_mm"].unique())
    if axes is None:
        _, axes = new_figure(2, len(depths), width_in=width_in, height_in=5.4, sharex=True, sharey=True)
    axes = np.atleast_2d(axes)
    rows = [("|ΔX, ΔY| [µm]", np.hypot(diff["dX_um"], diff["dY_um"])), ("|ΔZ| [µm]", np.abs(diff["dZ_um"]))]
    for r, (label, values) in enumerate(rows):
        vmax = float(np.percentile(values, 99))
        for c, depth in enumerate(depths):
            sel = (diff["depth_mm"] == depth).to_numpy()
            ax = axes[r, c]
            sc = ax.scatter(diff["x_mm"][sel], diff["y_mm"][sel], c=values[sel], s=14, marker="s", vmin=0,
                            vmax=vmax, cmap="viridis")
            ax.set_aspect("equal")
            if r == 0:
                ax.set_title(f"depth {depth:+.1f} mm", fontsize=9)
            if r == 1:
                ax.set_xlabel("x [mm]")
            if c == 0:
                ax.set_ylabel("y [mm]")
        ax.figure.colorbar(sc, ax=list(axes[r]), label=label, shrink=0.9)
    return axes


def plot_accuracy_vs_positions(table, axes=None):
    """RMS displacement error over the noise floor against the number of calibration positions, per
    coordinate (``table``: :func:`slmlab.studies.workspace.accuracy_vs_positions` rows with a ``case`` column), log
    scale. The legend sits below the panels, over no line; a case with a perfect stage is drawn thinner, on top,
    so that where a model's two lines coincide (the paper's, whose error is not the stage's) both show."""
    if axes is None:
        _, axes = new_figure(1, 3, width_in=9.5, height_in=3.7, sharey=True)
    for ax, c in zip(axes, "XYZ"):
        for (case, model), d in table.groupby(["case", "model"], sort=False):
            d = d.sort_values("positions")
            thin = "perfect" in case
            ax.plot(d["positions"], d[f"{c}_vs_floor"], ls="-" if model == "direct" else "--", ms=3,
                    lw=1.2 if thin else 2.6, zorder=3 if thin else 2,
                    marker="o" if model == "direct" else ("x" if thin else "s"), label=f"{model}, {case}")
        ax.axhline(1.2, color="0.5", lw=0.8, ls=":")
        ax.set_yscale("log")
        ax.set_xscale("log")
        ticks = sorted(table["positions"].unique())
        ax.set_xticks(ticks, [str(t) for t in ticks], fontsize=7)
        ax.minorticks_off()
        ax.set_xlabel("calibration positions")
        ax.set_title(c, fontsize=10)
    axes[0].set_ylabel("RMS error / noise floor")
    handles, labels = axes[0].get_legend_handles_labels()
    axes[0].figure.legend(handles, labels, loc="outside lower center", ncols=len(labels), fontsize=7, frameon=False)
    return axes


def plot_leave_one_plane_out(table, axes=None):
    """Real Z stack, leave one plane out: RMS error [µm] of the left-out plane per coordinate, per variant
    (solid), and the default model's mean predicted 1σ (dashed)."""
    if axes is None:
        _, axes = new_figure(1, 3, width_in=9.5, height_in=3.7, sharex=True)
    for ax, c in zip(axes, "XYZ"):
        for label, d in table.groupby("model", sort=False):
            ax.plot(d["Z_mm"], d[f"E{c}_um"], "o-", ms=3, label=f"{label}: RMS error")
        first = table[table["model"] == table["model"].iloc[0]]
        ax.plot(first["Z_mm"], first[f"s{c}_um"], "k--", lw=1, label=f"{first['model'].iloc[0]}: predicted 1σ")
        ax.set_xlabel("left-out plane Z [mm]")
        ax.set_title(c, fontsize=10)
        ax.set_ylim(bottom=0)
    axes[0].set_ylabel("left-out plane: RMS error, 1σ [µm]")
    handles, labels = axes[0].get_legend_handles_labels()   # one legend under the panels, over no line
    axes[0].figure.legend(handles, labels, loc="outside lower center", ncols=min(len(labels), 3), fontsize=7)
    return axes


def plot_floor_ratios(table, ax=None, *, by=("microscope", "calibration")):
    """RMS displacement error over the noise floor per coordinate, one group of bars per coordinate and one
    bar per row of ``table`` (labelled by the columns ``by``); the dotted line is 1.2 × the floor."""
    ax = _ax(ax)
    n = len(table)
    width = 0.8 / n
    for i, (_, row) in enumerate(table.iterrows()):
        ax.bar(np.arange(3) + (i - (n - 1) / 2) * width, [row[f"{c}_vs_floor"] for c in "XYZ"], width,
               label=", ".join(str(row[b]) for b in by))
    ax.axhline(1.0, color="k", lw=0.8)
    ax.axhline(1.2, color="0.5", lw=0.8, ls=":")
    ax.set_xticks(range(3), ["X", "Y", "Z"])
    ax.set_ylabel("RMS displacement error / noise floor")
    ax.legend(fontsize=7)
    return ax


# ------------------------------------------------------------------------------------------ real rigs (notebook 10)
def plot_pick_differences(diffs, axes=None, *, limit_px: float = 1.5):
    """Picked minus extracted centre ``(du, dv)`` [px] of every matched dot, one panel per view, with the RMS
    circle (solid) and the matching radius (dotted)."""
    views = list(dict.fromkeys(diffs["view"]))
    if axes is None:
        _, axes = new_figure(1, len(views), width_in=3.4 * len(views), height_in=3.3, sharex=True, sharey=True)
    axes = np.atleast_1d(axes)
    t = np.linspace(0, 2 * np.pi, 200)
    for ax, v in zip(axes, views):
        d = diffs[diffs["view"] == v]
        ax.plot(d["du_px"], d["dv_px"], ".", ms=3, alpha=0.6)
        rms = float(np.sqrt(np.mean(np.r_[d["du_px"], d["dv_px"]] ** 2)))
        ax.plot(rms * np.cos(t), rms * np.sin(t), "k-", lw=0.8, label=f"RMS {rms:.2f} px")
        ax.plot(limit_px * np.cos(t), limit_px * np.sin(t), "k:", lw=0.8, label=f"{limit_px} px")
        ax.set_aspect("equal")
        ax.set_title(f"{v} view ({len(d)} dots)", fontsize=10)
        ax.set_xlabel("Δu [px]")
        ax.legend(fontsize=7, loc="upper right")
    axes[0].set_ylabel("Δv [px]")
    return axes


def plot_level_map(image, table, ax=None, *, title: str = "", reduce: int = 2):
    """One image of a two-level plate with its extracted dots, coloured by level (0 blue, 1 orange); the
    origin dot (``x_mm = y_mm = 0``) ringed. ``table``: ``w1, w2, level`` and optionally ``x_mm, y_mm``."""
    ax = _ax(ax)
    small = cv2.resize(image, (image.shape[1] // reduce, image.shape[0] // reduce), interpolation=cv2.INTER_AREA)
    lo, hi = np.percentile(small, [1, 99.5])
    ax.imshow(small, cmap="gray", vmin=lo, vmax=hi, extent=(-0.5, image.shape[1] - 0.5, image.shape[0] - 0.5, -0.5))
    for lv, colour in ((0, "tab:blue"), (1, "tab:orange")):
        d = table[table["level"] == lv]
        ax.plot(d["w1"], d["w2"], "o", ms=4, mfc="none", mec=colour, mew=1.2, label=f"level {lv} ({len(d)})")
    if {"x_mm", "y_mm"} <= set(table.columns):
        o = table[(table["x_mm"] == 0) & (table["y_mm"] == 0)]
        ax.plot(o["w1"], o["w2"], "o", ms=11, mfc="none", mec="tab:red", mew=1.5, label="origin dot")
    ax.set_xlabel("w1 [px]")
    ax.set_ylabel("w2 [px]")
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=7, loc="lower right")
    return ax


def plot_model_comparison(table, ax=None, *, reference: str | None = None, title: str = ""):
    """RMS error [µm] per coordinate of each model (a row of ``table``: ``model, X_um, Y_um, Z_um``), one group
    of bars per coordinate, on a log scale; the ``reference`` model's values dotted across each group; the
    legend beside the axes, where it hides no bar."""
    if ax is None:
        _, ax = new_figure(width_in=9.5, height_in=4.0)
    n = len(table)
    width = 0.8 / n
    for i, (_, row) in enumerate(table.iterrows()):
        ax.bar(np.arange(3) + (i - (n - 1) / 2) * width, [row[f"{c}_um"] for c in "XYZ"], width, label=row["model"])
    if reference is not None:
        ref = table.set_index("model").loc[reference]
        for k, c in enumerate("XYZ"):
            ax.plot([k - 0.45, k + 0.45], [ref[f"{c}_um"]] * 2, "k:", lw=1)
    ax.set_yscale("log")
    ax.set_xticks(range(3), ["X", "Y", "Z"])
    ax.set_ylabel("RMS error after one offset [µm]")
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    return ax


def plot_recovered_share(table, ax=None):
    """The share of the disparity's curvature the single pass recovers against the ratio of the plate's width
    to a dot's path length (points: measured on simulated sets; crosses: the pooled-regression attenuation of
    :func:`slmlab.paper.alignment.recovered_share`)."""
    ax = _ax(ax)
    t = table.sort_values("plate_width_over_path_length")
    ax.plot(t["plate_width_over_path_length"], t["recovered_share"], "o", label="single pass / joint fit (measured)")
    ax.plot(t["plate_width_over_path_length"], t["predicted_share"], "x", ms=8, color="k",
            label="Var(t²) / (Var(t²) + 4 σm² σt²)")
    ax.axhline(1.0, color="0.6", lw=0.8)
    ax.set_xlabel("plate width / path length on the image")
    ax.set_ylabel("share of the curvature recovered")
    ax.set_ylim(0, 1.05)
    ax.legend(fontsize=7)
    return ax


# ------------------------------------------------------------------------------------------ your microscope (notebook 12)
def plot_numbering(image, table, ax=None, *, title: str = "", every: int = 1):
    """An image, zoomed on the extracted dots, with the dots marked and labelled ``row,col`` (every ``every``-th
    row and column), the first row and column drawn as arrows from dot ``[1, 1]``: the numbering to check by
    eye. ``table`` has ``row, col, w1, w2`` [px]."""
    ax = _ax(ax)
    lo, hi = np.percentile(image, [1, 99.5])
    ax.imshow(image, cmap="gray", vmin=lo, vmax=hi)
    ax.plot(table["w1"], table["w2"], "o", ms=5, mfc="none", mec="tab:orange", mew=1.0)
    shown = table[((table["row"] - 1) % every == 0) & ((table["col"] - 1) % every == 0)]
    for _, r in shown.iterrows():
        ax.annotate(f"{int(r['row'])},{int(r['col'])}", (r["w1"], r["w2"]), xytext=(9, 9), textcoords="offset points",
                    fontsize=7, color="navy", bbox={"boxstyle": "round,pad=0.1", "fc": "white", "ec": "none", "alpha": 0.8})
    first = table.set_index(["row", "col"])
    if (1, 1) in first.index:
        o = first.loc[(1, 1), ["w1", "w2"]].to_numpy(float)
        for key, colour, label in (((1, 2), "tab:red", "along a row (col + 1)"), ((2, 1), "tab:cyan", "along a column (row + 1)")):
            if key in first.index:
                d = first.loc[key, ["w1", "w2"]].to_numpy(float) - o
                ax.annotate("", o + 1.8 * d, o, arrowprops={"arrowstyle": "->", "color": colour, "lw": 1.5})
                ax.plot([], [], "-", color=colour, label=label)
        ax.plot(*o, "o", ms=11, mfc="none", mec="tab:red", mew=1.5, label="dot [1, 1]")
        ax.legend(fontsize=7, loc="lower right")
    span = max(np.ptp(table["w1"]), np.ptp(table["w2"]), 1.0)
    ax.set_xlim(table["w1"].min() - 0.12 * span, table["w1"].max() + 0.12 * span)  # the plate, not the whole image
    ax.set_ylim(table["w2"].max() + 0.12 * span, table["w2"].min() - 0.12 * span)
    ax.set_xlabel("w1 [px]")
    ax.set_ylabel("w2 [px]")
    ax.set_title(title, fontsize=10)
    return ax


def plot_point_uncertainty(points, ax=None):
    """Per-point 1σ [µm] of reconstructed points (``reconstruct``'s ``sX_mm, sY_mm, sZ_mm``) against their
    reconstructed depth ``Z_mm`` [mm], one colour per coordinate."""
    ax = _ax(ax)
    for c, colour in zip("XYZ", ("tab:red", "tab:green", "tab:blue")):
        ax.plot(points["Z_mm"], 1e3 * points[f"s{c}_mm"], ".", ms=2, color=colour, label=f"σ{c}")
    ax.set_yscale("log")
    ax.set_xlabel("reconstructed Z [mm]")
    ax.set_ylabel("predicted 1σ per point [µm]")
    ax.legend(fontsize=8, markerscale=4)
    return ax


def plot_ratio_grid(ratios, key: str, ax=None, *, limit: float = 1.0, title: str = "", vmax: float = 3.0):
    """One rig × design × coordinate grid of a ratio (``ratios``: :func:`slmlab.studies.zoo.ratio_table`;
    ``key``: ``"vs_floor"``, ``"vs_polynomial"`` or ``"vs_candidates"``), each cell coloured on a log scale
    from 1/``vmax`` to ``vmax`` and labelled with its value; cells above ``limit`` are outlined."""
    ax = _ax(ax)
    labels = [f"{r} · {d}" for r, d in zip(ratios["rig"], ratios["design"])]
    values = ratios[[f"{c}_{key}" for c in "XYZ"]].to_numpy(float)
    ax.imshow(np.log(np.clip(values, 1 / vmax, vmax)), cmap="RdYlGn_r", vmin=-np.log(vmax), vmax=np.log(vmax),
              aspect="auto")
    for (i, j), v in np.ndenumerate(values):
        dark = abs(np.log(np.clip(v, 1 / vmax, vmax))) > 0.6 * np.log(vmax)   # white on the deepest colours
        ax.text(j, i, f"{v:.2f}", ha="center", va="center", fontsize=6, color="w" if dark else "k")
        if v > limit * (1 + 1e-9):
            ax.add_patch(Rectangle((j - 0.5, i - 0.5), 1, 1, fill=False, lw=1.2, edgecolor="k"))
    ax.set_xticks(range(3), ["X", "Y", "Z"])
    ax.set_yticks(range(len(labels)), labels, fontsize=6)
    ax.set_title(title, fontsize=9)
    return ax
