"""Figures: drawing only, never computing what the model modules compute.

Every function takes ``ax=None`` (or ``axes=None`` for multi-panel figures) and keyword-only options, draws,
and returns the Axes. Names follow the paper's figures.
"""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np

from .io import CalibrationSet
from .microscope import Microscope

__all__ = ["new_figure", "plot_cmo_geometry", "plot_stage_axes_top_view", "plot_stage_sequences",
           "plot_image_tracks", "plot_depth_response", "plot_error_vs_defocus", "plot_plate_index",
           "plot_dots_on_image"]

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


def plot_image_tracks(cal: CalibrationSet, axes=None, *, sequences=("X", "Y", "Z"), every: int = 1):
    """Image-plane tracks of the dots along the axis sequences, left and right view side by side.

    Each dot's path over the positions of a sequence is a line; position 1 is marked. ``every`` thins the
    dots drawn (1: all 49).
    """
    if axes is None:
        _, axes = new_figure(1, 2, width_in=9.0, height_in=4.4, sharex=True, sharey=True)
    width, height = cal.image_size_px
    for ax, (side, c1, c2) in zip(axes, (("l", "wl1", "wl2"), ("r", "wr1", "wr2"))):
        for s in sequences:
            df = cal.sequence(s)
            if df.empty:
                continue
            keys = df[["row", "col"]].drop_duplicates().to_numpy()[::every]
            for n, (i, j) in enumerate(keys):
                g = df[(df["row"] == i) & (df["col"] == j)].sort_values("position")
                ax.plot(g[c1], g[c2], "-", lw=0.6, color=SEQUENCE_COLOURS[s], label=f"{s} sequence" if n == 0 else None)
                ax.plot(g[c1].iloc[:1], g[c2].iloc[:1], ".", ms=2, color="k")
        ax.set_xlim(0, width)
        ax.set_ylim(height, 0)
        ax.set_aspect("equal")
        ax.set_xlabel("w1 [px]")
        ax.set_title(f"{'left' if side == 'l' else 'right'} image", fontsize=10)
    axes[0].set_ylabel("w2 [px]")
    axes[0].legend(fontsize=7, loc="lower left")
    return axes


def plot_depth_response(responses: dict, axes=None):
    """Disparity and relative magnification against depth for one or more microscopes.

    Parameters
    ----------
    responses
        label -> DataFrame of :func:`slmlab.simulate.depth_response`.
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
    (``by_depth`` from :func:`slmlab.extract.error_by_defocus`); the targets and the depth of field drawn."""
    ax = _ax(ax)
    for method, d in by_depth.groupby("method"):
        ax.plot(d["z_bin_mm"], d["rms_px"], "o-", ms=3, label=method)
    ax.axvspan(-depth_of_field_mm, depth_of_field_mm, color="0.92", zorder=0, label="depth of field")
    ax.axhline(targets[0], color="tab:green", ls="--", lw=0.8, label=f"target in focus ({targets[0]} px)")
    ax.axhline(targets[1], color="tab:red", ls="--", lw=0.8, label=f"target over the depth of field ({targets[1]} px)")
    ax.set_xlabel("z above the focal plane [mm]")
    ax.set_ylabel("centre RMS error per coordinate [px]")
    ax.set_ylim(0, max(0.06, float(by_depth["rms_px"].max()) * 1.1))
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
    import cv2

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
