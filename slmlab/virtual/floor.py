"""The information floor of a dot centre: the Cramér-Rao bound on extracting a rendered dot's image centre,
given the camera's noise (notebook 11, the extraction beside its floor).

No centre estimator can beat the information its pixels carry. A dot whose noise-free image ``E(p; c)`` [DN]
depends on its centre ``c`` [px], seen with independent Gaussian noise of variance ``σ²(p)`` per pixel, has the
Fisher information

    F = Σ_p ∇_c E(p) ∇_c E(p)ᵀ / σ²(p),

and every unbiased estimator of ``c`` has a covariance of at least ``F⁻¹`` (the Cramér-Rao bound). Here ``E`` is
the rendering itself (:func:`slmlab.virtual.render.expected_image` of :func:`slmlab.virtual.render.dot_coverage`),
its gradient taken by moving the dots ±:data:`SHIFT_PX` (the rendering's own edges, not the image's finite
differences, which would halve a sharp edge's slope); ``σ²`` is the camera's shot, read and quantisation noise
(:func:`slmlab.virtual.render.noise_variance`). Each dot's sum runs over the pixels nearer its centre than
:data:`CELL` of the distance to the next dot. Pixels the camera clips (saturated by a bright region, or black)
carry nothing, and neither do hot pixels or the text strip.

The bound knows the dot's shape, the plate's level and the light; a real estimator must find them as well.
For a point-symmetric dot on a flat plate, the level and contrast move the image evenly about the centre and
the centre oddly, so they cost nothing. The plate's local tilt is odd too, and so a second bound, **with the
light unknown** (:func:`fisher_floor`'s ``amplitude``), adds to the Fisher matrix, over the same cells, the
dot's contrast and a plane of background under it (level and two slopes) as unknowns, and keeps the centre's
block of the inverse: what an unbiased estimator that must measure the dot's light from its own pixels cannot
beat. It is 10-14 % above the first on the Greenough rig (0.0535 px per coordinate with every degradation at
once, against 0.048: a 0.05 px target there is below what such an estimator can reach; notebook 11), less on
the stereo-DIC and stereo-PIV rigs (2-10 %), whose cameras' dots sit farther apart than they blur. Both bounds are per
dot and for unbiased estimators: a lattice fitted through many dots, or a biased estimator, is not bound by
them. A gradient of light, the neighbours' blur, streaks across the dot and a bright region beside it break
the symmetry further: there both are optimistic.
"""

from __future__ import annotations

import copy

import numpy as np
import pandas as pd
from scipy.spatial import cKDTree

from ..io import CalibrationSet
from .render import Degradations, dot_coverage, expected_image, noise_variance, rig_views, set_camera, view_dots
from .rigs import rig_from_dict

__all__ = ["SHIFT_PX", "CELL", "BATCH_PX", "fisher_floor", "view_coverage", "view_floor", "rendered_floors",
           "rendered_floor"]

#: the dots are moved by ± this much [px] for the rendering's gradient
SHIFT_PX = 0.05
#: a dot's information is summed over the pixels within this share of the distance to its nearest neighbour
CELL = 0.45
#: pixels per batch of dots in :func:`fisher_floor` (bounds its memory: about 50 bytes a pixel)
BATCH_PX = 2 ** 20


def _box_px(radius: np.ndarray, shape: tuple[int, int]) -> int:
    """The side [px] of a box that holds the cell of radius ``radius`` [px] of any dot in an image of ``shape``."""
    return min(2 * int(np.ceil(radius.max())) + 2, max(shape))


def _cells(centres_px: np.ndarray, radius: np.ndarray, shape: tuple[int, int]):
    """The pixels of each dot's cell (module docstring), as one box per dot (:func:`_box_px`, from the cell's
    corner or the image's edge): the boxes' pixel coordinates ``xx, yy`` ``(n, b, b)`` (clipped into the image)
    and which of them are in the cell ``(n, b, b)``."""
    h, w = shape
    grid = np.arange(_box_px(radius, shape))
    x0 = np.maximum(np.floor(centres_px[:, 0] - radius).astype(int), 0)
    y0 = np.maximum(np.floor(centres_px[:, 1] - radius).astype(int), 0)
    xx, yy = np.broadcast_arrays(x0[:, None, None] + grid[None, None, :], y0[:, None, None] + grid[None, :, None])
    cell = (xx < w) & (yy < h) & (np.hypot(xx - centres_px[:, 0, None, None], yy - centres_px[:, 1, None, None])
                                  <= radius[:, None, None])
    return np.minimum(xx, w - 1), np.minimum(yy, h - 1), cell


def _floor_from_info(info: np.ndarray, light: bool) -> np.ndarray:
    """Each dot's floor ``(n, 2)`` [px] from its Fisher matrices ``(n, k, k)``: the centre's block of the
    inverse, ``inf`` where the centre has no information or (``light``) nothing tells the light from it."""
    out = np.full((len(info), 2), np.inf)
    ok = np.linalg.det(info[:, :2, :2]) > 0
    if not light:
        out[ok] = np.sqrt(np.diagonal(np.linalg.inv(info[ok]), axis1=1, axis2=2))
        return out
    d = np.sqrt(np.maximum(np.diagonal(info, axis1=1, axis2=2), 1e-300))  # unit-free: scaled to a unit diagonal
    scaled = info / (d[:, :, None] * d[:, None, :])
    ok[ok] = np.linalg.cond(scaled[ok]) <= 1e10   # else: a cell with no background in view
    out[ok] = np.sqrt(np.diagonal(np.linalg.inv(scaled[ok]), axis1=1, axis2=2)[:, :2]) / d[ok, :2]
    return out


def fisher_floor(grad_x: np.ndarray, grad_y: np.ndarray, variance: np.ndarray, usable: np.ndarray,
                 centres_px: np.ndarray, amplitude: np.ndarray | None = None) -> np.ndarray:
    """Cramér-Rao floor ``(n, 2)`` [px] of each dot's image centre (standard deviation per coordinate, module
    docstring): ``grad_x, grad_y`` ``(h, w)`` the noise-free image's change per pixel of the dots' move in ``x``
    and ``y`` [DN/px], ``variance`` ``(h, w)`` each pixel's noise [DN²], ``usable`` ``(h, w)`` the pixels that
    carry information, ``centres_px`` ``(n, 2)`` the true centres. With ``amplitude`` ``(h, w)``, the image's
    change per unit of the dots' contrast [DN/DN], the floor with the light unknown: each dot's contrast and a plane
    of background under it (level and slopes) estimated with its centre, the bound the centre's block of the
    inverse 6 × 6 Fisher matrix. A dot without information is ``inf``."""
    h, w = variance.shape
    c = np.asarray(centres_px, float).reshape(-1, 2)
    radius = CELL * (cKDTree(c).query(c, k=2)[0][:, 1] if len(c) > 1 else np.full(len(c), max(h, w)))
    out = np.full((len(c), 2), np.inf)
    batch = max(1, BATCH_PX // _box_px(radius, (h, w)) ** 2) if len(c) else 1
    for s in range(0, len(c), batch):
        part = slice(s, s + batch)
        xx, yy, cell = _cells(c[part], radius[part], (h, w))
        rows = [grad_x[yy, xx], grad_y[yy, xx]]
        if amplitude is not None:   # the light's unknowns: background level and slopes (over the cell), contrast
            r = radius[part, None, None]
            rows += [np.ones(xx.shape), (xx - c[part, 0, None, None]) / r, (yy - c[part, 1, None, None]) / r,
                     amplitude[yy, xx]]
        jac = np.stack(rows, axis=1).astype(float).reshape(len(xx), len(rows), -1)
        wt = np.where(cell & usable[yy, xx], 1.0 / variance[yy, xx], 0.0).reshape(len(xx), 1, -1)
        info = np.einsum("nip,njp->nij", jac * wt, jac)
        out[part] = _floor_from_info(info, amplitude is not None)
    return out


def view_coverage(size: tuple[int, int], centres: np.ndarray, ellipses: np.ndarray, blur: np.ndarray,
                  sigma: float) -> tuple:
    """What :func:`view_floor` needs of a view's dots as :func:`slmlab.virtual.render.view_dots` gives them (in an
    image of ``size = (width, height)``), which most degradations share: the dots' centres ``(n, 2)`` [px],
    their coverage image (:func:`slmlab.virtual.render.dot_coverage`) and its change as the dots move by
    ``±SHIFT_PX`` in ``x`` and in ``y`` (two ``(h, w)`` images [coverage per 2·SHIFT_PX])."""
    cover = dot_coverage(size, centres, ellipses, blur, sigma)
    moves = []
    for step in ((SHIFT_PX, 0.0), (0.0, SHIFT_PX)):
        ahead = dot_coverage(size, centres + step, ellipses, blur, sigma)
        ahead -= dot_coverage(size, centres - step, ellipses, blur, sigma)
        moves.append(ahead)
    return centres, cover, moves


def view_floor(rig, points_mm: np.ndarray, orientation: np.ndarray, dot_diameter_mm: float, side: str,
               deg: Degradations, sensor: np.random.Generator, coverage: tuple | None = None
               ) -> tuple[np.ndarray, np.ndarray]:
    """Cramér-Rao floors ``(n, 2)`` [px] of the centres of dots rendered by
    :func:`slmlab.virtual.render.render_rig_view` (the same arguments; ``sensor``: the camera's stream, for its
    streaks and hot pixels; the bright region is placed beside the dots): with the light known, and with it
    unknown (:func:`fisher_floor`'s ``amplitude``). A plate's markers are left out: they carry no dot's centre,
    and lie in the holes between the dots' cells. ``coverage``: the view's :func:`view_coverage` for ``deg``,
    if already drawn."""
    if coverage is None:
        coverage = view_coverage(tuple(rig.image_size_px), *view_dots(rig, points_mm, orientation,
                                                                      dot_diameter_mm, side, deg))
    centres, cover, moves = coverage
    radiance, gain, hot = expected_image(cover, deg, sensor, centres)
    slope = np.float32(deg.contrast_dn / (2 * SHIFT_PX))
    grads = [move * slope * gain for move in moves]
    full = float(2 ** deg.bits - 1)
    usable = (radiance > 0.5) & (radiance < full - 0.5)
    if hot is not None:
        usable.ravel()[hot] = False
    if deg.text_strip_px:
        usable[-deg.text_strip_px:] = False
    variance = noise_variance(radiance, deg)
    return (fisher_floor(*grads, variance, usable, centres),
            fisher_floor(*grads, variance, usable, centres, amplitude=cover * gain))


def rendered_floors(cal: CalibrationSet, degs: list[Degradations]) -> list[pd.DataFrame]:
    """The Cramér-Rao floors of every dot of a rendered rig set in every image (:func:`view_floor`), one table
    per camera of ``degs``: ``sequence, position, view, row, col, floor1_px, floor2_px`` (per coordinate, the
    light known) and ``light_floor1_px, light_floor2_px`` (the light unknown), keyed as
    :func:`slmlab.virtual.render.rendered_truth`; NaN for a board's corners (a ChArUco design: no dots). Each
    view's coverage is drawn once for all the cameras that blur it alike (:func:`view_coverage`)."""
    rig = rig_from_dict(cal.meta["simulator"]["microscope"])
    frames = [[] for _ in degs]
    for keys, _, p, axes, diam, side, sensor in rig_views(cal, rig):
        none = np.full((len(keys), 2), np.nan)
        drawn = {}
        for k, deg in enumerate(degs):
            f, light = none, none
            if diam > 0:
                dots = view_dots(rig, p, axes, diam, side, deg)
                key = dots[2].tobytes()   # the blur: the rest of the view's dots is the same for every camera
                if key not in drawn:
                    drawn[key] = view_coverage(tuple(rig.image_size_px), *dots)
                f, light = view_floor(rig, p, axes, diam, side, deg, copy.deepcopy(sensor), coverage=drawn[key])
            frames[k].append(keys.assign(floor1_px=f[:, 0], floor2_px=f[:, 1], light_floor1_px=light[:, 0],
                                         light_floor2_px=light[:, 1]))
    return [pd.concat(f, ignore_index=True) for f in frames]


def rendered_floor(cal: CalibrationSet, deg: Degradations | None = None) -> pd.DataFrame:
    """:func:`rendered_floors` for one camera ``deg``, by default the one the set was rendered with
    (:func:`slmlab.virtual.render.set_camera`)."""
    return rendered_floors(cal, [deg or set_camera(cal)])[0]
