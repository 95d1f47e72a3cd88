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

import numpy as np
import pandas as pd
from scipy.spatial import cKDTree

from ..io import CalibrationSet
from .render import Degradations, dot_coverage, expected_image, noise_variance, rig_views, set_camera, view_dots
from .rigs import rig_from_dict

__all__ = ["SHIFT_PX", "CELL", "fisher_floor", "view_floor", "rendered_floor"]

#: the dots are moved by ± this much [px] for the rendering's gradient
SHIFT_PX = 0.05
#: a dot's information is summed over the pixels within this share of the distance to its nearest neighbour
CELL = 0.45


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
    c = np.asarray(centres_px, float)
    radius = CELL * (cKDTree(c).query(c, k=2)[0][:, 1] if len(c) > 1 else np.full(len(c), max(h, w)))
    weight = np.where(usable, 1.0 / variance, 0.0)
    out = np.full((len(c), 2), np.inf)
    for k, ((x, y), r) in enumerate(zip(c, radius)):
        x0, x1 = max(int(np.floor(x - r)), 0), min(int(np.ceil(x + r)) + 1, w)
        y0, y1 = max(int(np.floor(y - r)), 0), min(int(np.ceil(y + r)) + 1, h)
        if x0 >= x1 or y0 >= y1:
            continue
        yy, xx = np.mgrid[y0:y1, x0:x1]
        cell = np.hypot(xx - x, yy - y) <= r
        box = (slice(y0, y1), slice(x0, x1))
        rows = [grad_x[box][cell], grad_y[box][cell]]
        if amplitude is not None:   # the light's unknowns: background level and slopes (over the cell), contrast
            rows += [np.ones(int(cell.sum())), (xx[cell] - x) / r, (yy[cell] - y) / r, amplitude[box][cell]]
        jac = np.array(rows, float)
        info = (jac * weight[box][cell]) @ jac.T
        if np.linalg.det(info[:2, :2]) <= 0:
            continue   # no information on the centre
        if amplitude is None:
            out[k] = np.sqrt(np.diag(np.linalg.inv(info)))
            continue
        d = np.sqrt(np.maximum(np.diag(info), 1e-300))   # unit-free: the matrix scaled to a unit diagonal
        scaled = info / np.outer(d, d)
        if np.linalg.cond(scaled) > 1e10:
            continue   # nothing tells the light from the centre (a cell with no background in view)
        out[k] = np.sqrt(np.diag(np.linalg.inv(scaled))[:2]) / d[:2]
    return out


def view_floor(rig, points_mm: np.ndarray, orientation: np.ndarray, dot_diameter_mm: float, side: str,
               deg: Degradations, sensor: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Cramér-Rao floors ``(n, 2)`` [px] of the centres of dots rendered by
    :func:`slmlab.virtual.render.render_rig_view` (the same arguments; ``sensor``: the camera's stream, for its
    streaks and hot pixels; the bright region is placed beside the dots): with the light known, and with it
    unknown (:func:`fisher_floor`'s ``amplitude``). A plate's markers are left out: they carry no dot's centre,
    and lie in the holes between the dots' cells."""
    size = tuple(rig.image_size_px)
    centres, ellipses, blur, sigma = view_dots(rig, points_mm, orientation, dot_diameter_mm, side, deg)
    cover = dot_coverage(size, centres, ellipses, blur, sigma)
    radiance, gain, hot = expected_image(cover, deg, sensor, centres)
    slope = np.float32(deg.contrast_dn / (2 * SHIFT_PX))
    grads = []
    for step in ((SHIFT_PX, 0.0), (0.0, SHIFT_PX)):
        ahead = dot_coverage(size, centres + step, ellipses, blur, sigma)
        ahead -= dot_coverage(size, centres - step, ellipses, blur, sigma)
        grads.append(ahead * slope * gain)
    full = float(2 ** deg.bits - 1)
    usable = (radiance > 0.5) & (radiance < full - 0.5)
    if hot is not None:
        usable.ravel()[hot] = False
    if deg.text_strip_px:
        usable[-deg.text_strip_px:] = False
    variance = noise_variance(radiance, deg)
    return (fisher_floor(*grads, variance, usable, centres),
            fisher_floor(*grads, variance, usable, centres, amplitude=cover * gain))


def rendered_floor(cal: CalibrationSet, deg: Degradations | None = None) -> pd.DataFrame:
    """The Cramér-Rao floors of every dot of a rendered rig set in every image (:func:`view_floor`):
    ``sequence, position, view, row, col, floor1_px, floor2_px`` (per coordinate, the light known) and
    ``light_floor1_px, light_floor2_px`` (the light unknown), keyed as :func:`slmlab.virtual.render.rendered_truth`;
    NaN for a board's corners (a ChArUco design: no dots). ``deg``: the camera, by default the one the set was
    rendered with (:func:`slmlab.virtual.render.set_camera`)."""
    rig = rig_from_dict(cal.meta["simulator"]["microscope"])
    deg = deg or set_camera(cal)
    frames = []
    for keys, _, p, axes, diam, side, sensor in rig_views(cal, rig):
        none = np.full((len(keys), 2), np.nan)
        f, light = view_floor(rig, p, axes, diam, side, deg, sensor) if diam > 0 else (none, none)
        frames.append(keys.assign(floor1_px=f[:, 0], floor2_px=f[:, 1], light_floor1_px=light[:, 0],
                                  light_floor2_px=light[:, 1]))
    return pd.concat(frames, ignore_index=True)
