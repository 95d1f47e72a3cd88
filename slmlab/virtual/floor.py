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
the centre oddly, so they cost nothing. The plate's local tilt is odd too: with the dot's amplitude and a
background plane added to the Fisher matrix (over the same cells), the bound rises by 12 % on the Greenough
rig in noise, 10 % at its lowest contrast, 6 % and 2 % on the stereo-DIC and stereo-PIV rigs in noise (their
cameras' dots sit farther apart than they blur), and the point of symmetry is then within 1.09x of it on the
Greenough rig. The bound is per dot and for unbiased estimators: a lattice fitted through many dots, or a
biased estimator, is not bound by it. A gradient of light, the neighbours' blur, streaks across the dot and a
bright region beside it break the symmetry further: there the floor is optimistic. On the Greenough rig with every degradation at once the floor is 0.048 px per
coordinate (notebook 11): a 0.05 px target is then at the floor itself.
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
                 centres_px: np.ndarray) -> np.ndarray:
    """Cramér-Rao floor ``(n, 2)`` [px] of each dot's image centre (standard deviation per coordinate, module
    docstring): ``grad_x, grad_y`` ``(h, w)`` the noise-free image's change per pixel of the dots' move in ``x``
    and ``y`` [DN/px], ``variance`` ``(h, w)`` each pixel's noise [DN²], ``usable`` ``(h, w)`` the pixels that
    carry information, ``centres_px`` ``(n, 2)`` the true centres. A dot without information is ``inf``."""
    h, w = variance.shape
    c = np.asarray(centres_px, float)
    radius = CELL * (cKDTree(c).query(c, k=2)[0][:, 1] if len(c) > 1 else np.full(len(c), max(h, w)))
    weight = np.where(usable, 1.0 / variance, 0.0)
    terms = (grad_x * grad_x * weight, grad_x * grad_y * weight, grad_y * grad_y * weight)
    out = np.full((len(c), 2), np.inf)
    for k, ((x, y), r) in enumerate(zip(c, radius)):
        x0, x1 = max(int(np.floor(x - r)), 0), min(int(np.ceil(x + r)) + 1, w)
        y0, y1 = max(int(np.floor(y - r)), 0), min(int(np.ceil(y + r)) + 1, h)
        if x0 >= x1 or y0 >= y1:
            continue
        yy, xx = np.mgrid[y0:y1, x0:x1]
        cell = np.hypot(xx - x, yy - y) <= r
        fxx, fxy, fyy = (t[y0:y1, x0:x1][cell].sum() for t in terms)
        det = fxx * fyy - fxy * fxy
        if det > 0:
            out[k] = np.sqrt([fyy / det, fxx / det])
    return out


def view_floor(rig, points_mm: np.ndarray, orientation: np.ndarray, dot_diameter_mm: float, side: str,
               deg: Degradations, sensor: np.random.Generator) -> np.ndarray:
    """Cramér-Rao floor ``(n, 2)`` [px] of the centres of dots rendered by
    :func:`slmlab.virtual.render.render_rig_view` (the same arguments; ``sensor``: the camera's stream, for its
    streaks and hot pixels; the bright region is placed beside the dots). A plate's markers are left out: they
    carry no dot's centre, and lie in the holes between the dots' cells."""
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
    return fisher_floor(*grads, noise_variance(radiance, deg), usable, centres)


def rendered_floor(cal: CalibrationSet, deg: Degradations | None = None) -> pd.DataFrame:
    """The Cramér-Rao floor of every dot of a rendered rig set in every image (:func:`view_floor`):
    ``sequence, position, view, row, col, floor1_px, floor2_px`` (per coordinate), keyed as
    :func:`slmlab.virtual.render.rendered_truth`; NaN for a board's corners (a ChArUco design: no dots).
    ``deg``: the camera, by default the one the set was rendered with
    (:func:`slmlab.virtual.render.set_camera`)."""
    rig = rig_from_dict(cal.meta["simulator"]["microscope"])
    deg = deg or set_camera(cal)
    frames = []
    for keys, _, p, axes, diam, side, sensor in rig_views(cal, rig):
        f = view_floor(rig, p, axes, diam, side, deg, sensor) if diam > 0 else np.full((len(keys), 2), np.nan)
        frames.append(keys.assign(floor1_px=f[:, 0], floor2_px=f[:, 1]))
    return pd.concat(frames, ignore_index=True)
