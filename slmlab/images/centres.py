"""Sub-pixel centres of a plate's dots (the paper's §3 input), five estimators on flat-fielded patches.

Each dot's patch is flat-fielded by a background plane fitted on a ring outside the dot and its blur
(:func:`flatten`), so that vignetting, a gradient or a bright region beside the dot does not pull its centre;
where window streaks cross the image's dots (:func:`streak_mask`) each column of the patch is flat-fielded too, by its
own offset from the plane, read along a strip through the dot with every dot masked
(:mod:`slmlab.images.streaks`). How far the blurred dots reach is measured once per image on a sample
of them (:func:`dot_reach`).

* ``moments`` (:func:`refine_moments`): intensity-weighted centroid of the flat-fielded contrast inside an
  anti-aliased circular window, re-centred each iteration. Uses every pixel of the dot and its blur: precise
  far out of focus, but pulled by texture, scratches and streaks across the dot, and noisy at low contrast.
* ``ellipse`` (:func:`refine_ellipse`): half-contrast crossings along 48 rays, fitted by a conic.
* ``edges`` (:func:`refine_edges`): every half-contrast crossing between neighbouring pixels, the outermost
  in each of :data:`SECTORS` directions fitted by a conic twice without outliers: the outline seen from
  outside, so a textured or streaked dot, a hot speck or a donut's hole does not pull it; as accurate as
  ``ellipse`` or more and several times faster.
* ``fit`` (:func:`refine_fit`): a model of the dot (a blurred ellipse whose depth varies as a plane) on a
  quadratic background, fitted by least squares to every pixel within the dot's reach, saturated pixels
  censored: where the background is not flat under the dot (a steep bright region beside it, saturation
  around it) it follows the background the others extrapolate from a ring; 5-20 times slower than the others (the
  441 dots of the stereo-DIC bench image, 1024²: 0.14 s, moments 0.02 s; the 961 of its 2048² image: 0.61 s, 0.03 s).
* ``symmetry`` (:func:`refine_symmetry`): the point about which the flat-fielded contrast is most nearly
  point-symmetric, every pixel weighted by its slope: no model of the dot, the least noisy where noise limits
  (low contrast, few electrons), and on the paper's microscope the most precise at every depth (notebook 02;
  on the stereo-PIV rig's Scheimpflug views, whose blurred dots are not quite symmetric, less precise than
  ``moments`` where noise does not limit: 0.010 px against 0.007, clean); pulled by texture
  less than ``moments``, more than the edge fits. About twice the time of ``moments`` (441 dots of a
  1024 × 1024 stereo-DIC image: 0.022 s, edges 0.018 s, moments 0.010 s, on a slow machine).

:func:`refine` applies one of them by name, and refines again the dots that moved far from their first
guess (a coarse position from the local search).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree
from scipy.special import erfc

from .dots import as_float, gather_patches
from .streaks import clear_of_dots, clipped_band, strip_columns

__all__ = ["METHODS", "SECTORS", "STREAKINESS", "COHERENCE", "COHERENCE_SHARE", "coherent", "DEPTH_SLOPE",
           "STREAK_SHARE", "STREAK_EFFECT", "FIT_NONLINEAR", "FIT_PARAMETERS",
           "STREAK_DEPTH", "Flat", "flatten", "profile_radius", "dot_reach", "flat_patches", "streak_mask",
           "saturation", "saturated_dots", "outline_cut", "uneven_background", "light_pull_px", "refine_moments",
           "fit_dots", "refine_fit", "refine_ellipse", "refine_edges", "refine_symmetry", "refine"]

#: the centre estimators, by name
METHODS = ("moments", "ellipse", "edges", "fit", "symmetry")
#: the columns around a dot are flat-fielded one by one (window streaks, :func:`flatten`) above this mean
#: square of their offsets over its noise expectation (about 1 without streaks; window streaks across the
#: dot: 3-100 on the rendered zoo)
STREAKINESS = 2.0
#: ... and the columns' offsets above the dot correlate with those below it (:func:`coherent`) by at least this
#: (chance, over the 30-50 columns of a strip: about 0.15 either way; real plates' texture, JPEG blocks and
#: neighbours: 0.0-0.4) ...
COHERENCE = 0.5
#: ... and by at least this share of what a streak as strong as the offsets would give, ``(χ - 1) / (χ + 1)`` for
#: their mean square χ over its noise expectation (a streak is alike above and below; each side carries twice the
#: mean's noise). A fixed 0.8 asked for streaks four times the noise: greenough:43's under everything together,
#: χ 3.6-12 and coherence 0.49-0.75 as that predicts, went unread, and whole columns of dots 0.6-1.0 px off.
COHERENCE_SHARE = 0.8
#: ... and, for bright dots on a dark plate, none of them changes the plate's light by more than this share of it
#: (the model fit divides the dots by the streaks' gain, :func:`_streak_gain`): a window's streaks dim or brighten
#: what is behind them (the rendered zoo's bands: up to 0.35, times a fade of up to 1.5; a dot whose largest
#: offset is beyond it keeps none); the PIV Challenge's case E has column structure of up to
#: 0.4 of its near-black plate's level around its bright dots, and lines one pixel wide far above it
STREAK_DEPTH = 0.5
#: ... on an image where at least this share of the dots is so crossed (:func:`streak_mask`; the rendered zoo's
#: streaks: 0.1-0.5 of the dots; the real sample images: up to 0.08, case E's camera lines and edges)
STREAK_SHARE = 0.1
#: ... counting a bright dot only where its columns' offsets reach this share of its contrast: the estimators take
#: them off it (:func:`_contrast`), and less moves no centre. Case E's 16-bit dots, 45 000 grey levels over a plate
#: at 44, keep column structure of 2-70 grey levels (0.00005-0.0015 of their contrast; its centres the same to
#: 0.0001 px without it), the rendered zoo's window streaks 0.01-0.06 of a PIV rig's dots'
STREAK_EFFECT = 0.005
#: angular sectors of a dot's outline in :func:`refine_edges` (the outermost crossing of each is used)
SECTORS = 64


@dataclass
class Flat:
    """Flat-fielded contrast patches ``±(1 − I/B)`` around integer centres ``base``; ``B`` is a plane
    (coefficients ``coef`` on offsets ``ox, oy``) fitted on a ring of integer offsets, the same ring for all
    dots, so one pseudo-inverse serves the whole image; with ``columns``, plus each column's offset from the
    plane along a strip through the dot (``column`` ``(n, S)`` [grey levels]: window streaks,
    :func:`slmlab.images.streaks.strip_columns`) where the dot's
    ``streakiness`` ``(n,)``, the mean square of those offsets over their noise variance (about 1 or less
    without streaks), is above :data:`STREAKINESS` and their ``coherence`` ``(n,)``, the correlation of
    the offsets above the dot with those below it, is that of a streak (:func:`coherent`; else zero).
    ``bounds`` ``(n, 4)``: the offsets of the image's first and last columns and rows from ``base`` (pixels beyond
    them are the edge's copies: the plane of a dot whose ring leaves the image is fitted on the ring's pixels on
    it, and :func:`_centroid`'s window is kept symmetric inside them)."""

    base: np.ndarray
    ox: np.ndarray
    oy: np.ndarray
    contrast: np.ndarray
    coef: np.ndarray
    column: np.ndarray | None = None
    streakiness: np.ndarray | None = None
    coherence: np.ndarray | None = None
    bounds: np.ndarray | None = None


#: a dot's background ring clear of its neighbours (:func:`_ring_crowd`) is used if at least this share of the ring
#: is left (else the whole ring: a plane from one sector would extrapolate its slope across the dot)
RING_CLEAR_SHARE = 0.25
#: a dot whose ring reaches its neighbours (:func:`_crowded`) and that moved more than this from its first guess [px]
#: is refined again from where it moved to (:func:`refine`; every dot, as ever, beyond 2 px): cleared of the
#: neighbours about a guess 2.6 px off, a dense plate's ring lay on the dot's own blur, and it ended 3.3 px off
CROWD_AGAIN_PX = 0.5


def coherent(chi: np.ndarray, rho: np.ndarray) -> np.ndarray:
    """Whether columns' offsets of mean square ``chi`` over their noise expectation, correlated ``rho`` above the
    dot with below it, run through it as a window streak does: ``rho`` at least :data:`COHERENCE` and
    :data:`COHERENCE_SHARE` of ``(chi - 1) / (chi + 1)``, a streak's of that strength (:func:`flatten`)."""
    chi = np.asarray(chi, float)
    return np.asarray(rho) >= np.maximum(COHERENCE, COHERENCE_SHARE * (chi - 1) / (chi + 1))


def flatten(img: np.ndarray, centres: np.ndarray, ring_in: float, dark: bool, columns: np.ndarray | None = None,
            crop: int | None = None, clipped_alone: bool = False, clear_of: np.ndarray | None = None) -> Flat:
    """:class:`Flat` patches of ``img`` around ``centres`` ``(n, 2)`` [px], the background fitted outside
    ``ring_in`` [px] (a plane on a 4 px ring; on its pixels clear of the dots at ``clear_of`` ``(m, 2)`` [px], every
    dot of the image, where the ring reaches them: :func:`_ring_crowd`; with ``columns``, the image's pixels clear
    of every dot (:func:`slmlab.images.streaks.clear_of_dots`), plus per column its offset from the plane along a strip through
    the dot, where the offsets stand out of the noise alike above and below it and, for bright dots, change the
    plate's light by at most :data:`STREAK_DEPTH`: window streaks run along the columns,
    :func:`slmlab.images.streaks.strip_columns`); ``crop``: the contrast (and ``ox, oy``, ``column``) only within
    this many pixels of the centre (the ring and the columns are measured on the whole patch all the same);
    ``clipped_alone``: a dot whose patch saturates outside it reads its columns on the patch
    (:func:`_clipped_patches_alone`; the model fit's)."""
    half = int(np.ceil(ring_in + 5))
    p, base = gather_patches(img, centres, half)
    p = p.astype(np.float32)
    off = np.arange(-half, half + 1, dtype=np.float32)
    oy, ox = np.meshgrid(off, off, indexing="ij")
    d = np.hypot(ox, oy)
    ring = (d > ring_in) & (d < ring_in + 4)
    design = np.column_stack([np.ones(int(ring.sum())), ox[ring], oy[ring]])
    coef = p[:, ring] @ np.linalg.pinv(design).T.astype(np.float32)          # (n, 3)
    h, w = img.shape
    bounds = np.column_stack([-base[:, 0], w - 1 - base[:, 0], -base[:, 1], h - 1 - base[:, 1]])
    cut = (bounds[:, [0, 2]] > -half).any(axis=1) | (bounds[:, [1, 3]] < half).any(axis=1)
    crowd = (_ring_crowd(np.asarray(clear_of, float).reshape(-1, 2), base, ox[ring], oy[ring], ring_in)
             if clear_of is not None else np.zeros((len(base), int(ring.sum())), bool))
    weight = ring.sum(axis=0)   # each column's pixels of the ring the plane is read on (the streaks' lines)
    crowded, clear = _clear_rings(crowd, bounds, ox[ring], oy[ring])
    if len(crowded):             # all at once: on a dense plate every dot's ring reaches its neighbours
        coef[crowded] = _masked_planes(design, p[crowded][:, ring], clear)
        weight = np.broadcast_to(weight, (len(base), len(off))).copy()
        weight[crowded] = clear.astype(np.float64) @ (np.rint(ox[ring] + half).astype(int)[:, None]
                                                      == np.arange(len(off))[None, :])
    for k in np.flatnonzero(cut & ~np.isin(np.arange(len(base)), crowded)):
        seen = ((ox[ring] >= bounds[k, 0]) & (ox[ring] <= bounds[k, 1]) & (oy[ring] >= bounds[k, 2])
                & (oy[ring] <= bounds[k, 3]))
        if seen.sum() >= 12:   # the ring on the image, not the edge's copies (which repeat the dot's blur)
            coef[k] = np.linalg.lstsq(design[seen], p[k][ring][seen], rcond=None)[0]
    column, chi, rho = None, None, None
    if columns is not None:   # the columns are measured on a strip as wide as the whole patch
        sat = saturation(img)
        column, chi, rho = strip_columns(img, base, half, coef, columns, weight, sat)
        if clipped_alone:
            column = _clipped_patches_alone(column, p, _plane(coef, ox[None], oy[None]), d > ring_in, sat)
        light = dark | (np.abs(column).max(axis=1) <= STREAK_DEPTH * np.maximum(coef[:, 0], 1.0))
        column[(chi <= STREAKINESS) | ~coherent(chi, rho) | ~light] = 0.0
    if crop is not None and crop < half:
        sl = slice(half - crop, half + crop + 1)
        p, ox, oy = p[:, sl, sl], ox[sl, sl], oy[sl, sl]
        column = None if column is None else column[:, sl]
    con = _contrast(p, _plane(coef, ox[None], oy[None]), dark, None if column is None else column[:, None, :])
    return Flat(base, ox, oy, con, coef, column, chi, rho, bounds)


def _ring_crowd(dots: np.ndarray, base: np.ndarray, rx: np.ndarray, ry: np.ndarray, ring_in: float) -> np.ndarray:
    """Which pixels ``(n, R)`` of each patch's background ring (offsets ``rx, ry`` ``(R,)`` [px] from its centre pixel
    ``base`` ``(n, 2)``) lie on another of the ``dots`` ``(m, 2)`` [px]: within ``ring_in`` − 1 px of it, the reach of
    its blur (:func:`flat_patches` puts the ring 1 px beyond the reach), the patch's own dot (within a pixel of its
    centre pixel) apart. On a dense plate (dots of 4 px radius at a pitch of 14-16 px), or where the blur reaches far
    (window streaks widen the dots' radial profile), the ring lay on the neighbours, and a plate's outer dots and
    those whose neighbours are not evenly spaced were pulled (moments 0.13 px RMS at a pitch of 14, the edges 0.04).
    All ``False`` where no ring reaches another dot, the usual case: then nothing changes."""
    crowd = np.zeros((len(base), len(rx)), bool)
    dots = dots[np.isfinite(dots).all(axis=1)]
    if len(dots) < 2 or len(rx) == 0 or len(base) == 0:
        return crowd
    clear = ring_in - 1.0
    near = cKDTree(dots).query_ball_point(base.astype(float), float(np.hypot(rx, ry).max()) + clear)
    k = np.repeat(np.arange(len(base)), [len(js) for js in near])
    if len(k) == 0:
        return crowd
    off = dots[np.concatenate(near).astype(int)] - base[k]
    other = np.hypot(*off.T) > 1.0                   # not the patch's own dot
    k, off = k[other], off[other]
    np.logical_or.at(crowd, k, np.hypot(rx[None, :] - off[:, :1], ry[None, :] - off[:, 1:]) < clear)
    return crowd


def _clear_rings(crowd: np.ndarray, bounds: np.ndarray, rx: np.ndarray, ry: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The dots whose ring reaches another dot (``crowd`` ``(n, R)``, :func:`_ring_crowd`) and keeps enough pixels
    clear of them and on the image (``bounds``, :class:`Flat`): at least :data:`RING_CLEAR_SHARE` of the ring and 12;
    their indices ``(m,)`` and those pixels ``(m, R)``."""
    crowded = np.flatnonzero(crowd.any(axis=1))
    b = bounds[crowded]
    clear = ((rx >= b[:, :1]) & (rx <= b[:, 1:2]) & (ry >= b[:, 2:3]) & (ry <= b[:, 3:])) & ~crowd[crowded]
    ok = clear.sum(axis=1) >= max(12, RING_CLEAR_SHARE * len(rx))
    return crowded[ok], clear[ok]


def _masked_planes(design: np.ndarray, values: np.ndarray, use: np.ndarray) -> np.ndarray:
    """Least-squares planes ``(m, 3)`` of ``values`` ``(m, R)`` at the ring's ``design`` ``(R, 3)``, each on its own
    pixels ``use`` ``(m, R)``: the normal equations of every dot solved at once."""
    w = use.astype(np.float64)
    normal = np.einsum("mr,ri,rj->mij", w, design, design)
    rhs = np.einsum("mr,ri->mi", w * values.astype(np.float64), design)
    return np.linalg.solve(normal, rhs[..., None])[..., 0]


def _clipped_patches_alone(column: np.ndarray, p: np.ndarray, plane: np.ndarray, outside: np.ndarray, sat: float
                           ) -> np.ndarray:
    """The columns' offsets ``(n, S)``, those of a dot whose patch ``p`` ``(n, S, S)`` saturates outside it
    (``outside`` ``(S, S)``) in a column above and below it (a saturating streak; not a spot on one side) read on the
    patch alone: the mean of each column's pixels there less the ``plane``. A
    streak that saturates fades along the column, so a strip clips over other rows than the patch; read on the
    strip, the model fit put dots half under a saturating band 0.25 px off (0.03 on the patch), and read on the
    strip less a line without the clipped columns, it lost a dot beside one on greenough:10. For the model fit alone
    (its moments start and :func:`_streak_gain`): the other estimators, so read, took greenough's window streaks
    from 0.007 px to 0.021."""
    clipped = clipped_band((p >= sat) & outside[None], np.arange(p.shape[1]) - p.shape[1] // 2).any(axis=1)
    if not clipped.any():
        return column
    out = outside[None] & np.ones(p[clipped].shape, bool)
    local = ((p[clipped] - plane[clipped]) * out).sum(axis=1) / np.maximum(out.sum(axis=1), 1)
    column = column.copy()
    column[clipped] = local
    return column


def _contrast(values: np.ndarray, plane: np.ndarray, dark: bool, column: np.ndarray | None = None) -> np.ndarray:
    """A dot's contrast on the background ``B`` = ``plane`` + ``column`` (window streaks' offsets, or ``None``):
    ``1 − I/B`` for dark dots (flat-fielded: illumination scales plate and dot alike), ``I − B`` for bright dots on
    a dark plate (whose background is an offset, often near zero). Dividing bright dots by a streak's gain ``B/plane``
    as well took the PIV Challenge's case E, whose dark plate holds its own column structure around the dots,
    from 0.061 to 0.121 px lattice residual in one image (two dots lost); the model fit divides by it
    (:func:`_streak_gain`)."""
    background = plane if column is None else plane + column
    if dark:
        return 1.0 - values / np.maximum(background, 1.0)
    return values - background


def _plane(coef: np.ndarray, dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
    """Plane ``b0 + bx·dx + by·dy`` per dot; ``dx, dy`` have a leading axis of length ``n`` or 1."""
    shape = (-1,) + (1,) * (max(np.ndim(dx), np.ndim(dy)) - 1)
    return coef[:, 0].reshape(shape) + coef[:, 1].reshape(shape) * dx + coef[:, 2].reshape(shape) * dy


def _radial_profile(flat: Flat) -> np.ndarray:
    """The dots' mean flat-fielded contrast at each whole-pixel distance from the patches' centres."""
    d = np.rint(np.hypot(flat.ox, flat.oy)).astype(int).ravel()
    return np.bincount(d, weights=flat.contrast.mean(axis=0).ravel()) / np.maximum(np.bincount(d), 1)


def profile_radius(flat: Flat, radius: float) -> float:
    """Radius [px] where the mean radial contrast profile of the dots falls to 2 % of its peak: the dot and
    its defocus blur."""
    prof = _radial_profile(flat)
    peak = prof[: max(int(radius), 1)].max()
    beyond = np.flatnonzero((np.arange(len(prof)) > radius) & (prof < 0.02 * peak))
    return float(beyond[0]) if len(beyond) else 1.5 * radius


def refine_moments(img: np.ndarray, centres: np.ndarray, radii: np.ndarray, *, dark: bool = True,
                   iterations: int = 3, reach: float | None = None, columns: np.ndarray | None = None,
                   clipped_alone: bool = False, clear_of: np.ndarray | None = None) -> np.ndarray:
    """Sub-pixel centres by the intensity-weighted centroid of the flat-fielded contrast ``1 − I/B``.

    ``B`` is a plane fitted per dot on a ring outside the dot and its blur, so vignetting does not pull the
    centre (with ``columns``, each column flat-fielded too: :func:`flatten`). The window is an anti-aliased
    disk reaching 1.5 px beyond where the dots' mean radial profile falls to 2 % of its peak, re-centred on
    the estimate each iteration. Returns ``(n, 2)`` [px].
    """
    c = np.asarray(centres, float).copy()
    if len(c) == 0:
        return c
    flat, reach = flat_patches(img, c, radii, dark, reach, columns, clipped_alone=clipped_alone, clear_of=clear_of)
    con, ox, oy = _on_disk(flat.contrast, flat, reach)
    for _ in range(iterations):
        c = flat.base + _centroid(con, ox, oy, c - flat.base, reach, flat.bounds)
    return c


def _on_disk(contrast: np.ndarray, flat: Flat, reach: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The contrast ``(n, P)`` and offsets ``ox, oy`` ``(P,)`` of the pixels :func:`_centroid`'s window can
    reach: within ``reach + 1.5`` of the patch's centre pixel (the window never reaches beyond while
    ``|c - base| <= 0.5``)."""
    disk = np.hypot(flat.ox, flat.oy) <= reach + 1.5
    return contrast[:, disk], flat.ox[disk], flat.oy[disk]


def _centroid(con: np.ndarray, ox: np.ndarray, oy: np.ndarray, f: np.ndarray, reach: float,
              bounds: np.ndarray | None = None) -> np.ndarray:
    """One centroid step of :func:`refine_moments`: the centroid ``(n, 2)`` [px from each patch's centre pixel]
    of contrasts ``con`` ``(n, P)`` at pixel offsets ``ox, oy`` ``(P,)`` within an anti-aliased disk of radius
    ``reach + 0.5`` [px] around ``f`` ``(n, 2)``; where the disk leaves the image (``bounds``, :class:`Flat`),
    also within a box about ``f`` as far as the nearer edge on each axis: a window symmetric about the estimate,
    so that the blur the edge cuts off one side is left off the other too and a symmetric dot's centroid is not
    pulled (the edge's copied pixels pulled a defocused dot a pixel inside the edge 0.09 px towards it on
    stereo-dic:2024). float32
    is ample here: sums of a few thousand terms of size <= reach, relative error ~1e-6 px."""
    f = f.astype(np.float32)
    win = np.clip(np.float32(reach + 0.5) - np.hypot(ox[None, :] - f[:, 0, None], oy[None, :] - f[:, 1, None]),
                  0.0, 1.0)
    if bounds is not None:
        half = np.minimum(np.abs(f[:, [0, 0, 1, 1]] - bounds), np.float32(reach + 1.5))   # to each edge [px]
        mx, my = half[:, :2].min(axis=1), half[:, 2:].min(axis=1)
        cut = np.flatnonzero((mx < reach + 1) | (my < reach + 1))
        if len(cut):
            win[cut] *= (np.clip(mx[cut, None] + 0.5 - np.abs(ox[None, :] - f[cut, 0, None]), 0.0, 1.0)
                         * np.clip(my[cut, None] + 0.5 - np.abs(oy[None, :] - f[cut, 1, None]), 0.0, 1.0))
    w = con * win
    s = w.sum(axis=1, dtype=np.float64)
    s = np.where(np.abs(s) > 1e-9, s, 1e-9)
    return np.column_stack([w @ ox, w @ oy]).astype(np.float64) / s[:, None]


def _bilinear(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear samples of ``img`` at ``(x, y)`` [px] (any shape), replicating the border (``cv2.remap``)."""
    f = as_float(img)
    shape = np.broadcast(x, y).shape
    n = shape[0] if len(shape) > 1 else 1
    mx = np.broadcast_to(x, shape).astype(np.float32).reshape(n, -1)
    my = np.broadcast_to(y, shape).astype(np.float32).reshape(n, -1)
    return cv2.remap(f, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).reshape(shape)


def refine_ellipse(img: np.ndarray, centres: np.ndarray, radii: np.ndarray, *, dark: bool = True,
                   rays: int = 48, iterations: int = 2, reach: float | None = None, columns: np.ndarray | None = None,
                   clear_of: np.ndarray | None = None
                   ) -> np.ndarray:
    """Sub-pixel centres from an ellipse fitted to the half-contrast crossings along ``rays`` rays.

    The contrast ``1 − I/B`` is flat-fielded as in :func:`refine_moments`; along each ray the first
    crossing of half the dot's inner contrast is found by linear interpolation; the conic through the
    crossings (algebraic least squares) gives the centre. Returns ``(n, 2)`` [px].
    """
    c = np.asarray(centres, float).copy()
    if len(c) == 0:
        return c
    r = float(np.median(radii))
    flat, reach = flat_patches(img, c, radii, dark, reach, columns, clear_of=clear_of)
    img = as_float(img)  # once, for the samples of every iteration
    t = np.linspace(0, 2 * np.pi, rays, endpoint=False)
    steps = np.linspace(0.0, 1.0, 96)
    rad = steps * reach
    ox = np.cos(t)[None, :, None] * rad[None, None, :]                          # (1, R, S) offsets
    oy = np.sin(t)[None, :, None] * rad[None, None, :]
    core = max(2, int(0.5 * len(steps) * r / reach))
    for _ in range(iterations):
        f = c - flat.base
        vals = _bilinear(img, c[:, 0, None, None] + ox, c[:, 1, None, None] + oy)
        plane = _plane(flat.coef, ox + f[:, 0, None, None], oy + f[:, 1, None, None])
        col = None if flat.column is None else _column_at(   # linearly between the pixels' columns
            flat.column, np.broadcast_to(ox + f[:, 0, None, None], plane.shape))
        con = _contrast(vals, plane, dark, col)
        level = 0.5 * np.median(con[:, :, :core], axis=(1, 2))
        below = con < level[:, None, None]
        below[:, :, 0] = False
        first = np.argmax(below, axis=2)                                        # (n, R)
        ok = below.any(axis=2) & (first > 0)
        k1 = np.maximum(first - 1, 0)
        g0 = np.take_along_axis(con, k1[..., None], axis=2)[..., 0]
        g1 = np.take_along_axis(con, first[..., None], axis=2)[..., 0]
        frac = np.clip((g0 - level[:, None]) / np.where(g0 != g1, g0 - g1, 1.0), 0, 1)
        rr = (steps[k1] + frac * (steps[1] - steps[0])) * reach
        c = c + _ellipse_centres(np.cos(t)[None, :] * rr, np.sin(t)[None, :] * rr, ok)
    return c


def _column_at(column: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Column offsets ``(n, S)`` (:attr:`Flat.column`, columns at offsets ``−S//2 … S//2``) at offsets ``x``
    ``(n, ...)`` [px], linearly interpolated (replicated beyond)."""
    s = column.shape[1]
    u = np.clip(x + s // 2, 0, s - 1.000001).reshape(len(x), -1)
    i = np.floor(u).astype(int)
    t = u - i
    v = np.take_along_axis(column, i, axis=1) * (1 - t) + np.take_along_axis(column, i + 1, axis=1) * t
    return v.reshape(x.shape)


def _ellipse_centres(x: np.ndarray, y: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Centres of the conics ``x² + B xy + C y² + D x + E y + F = 0`` fitted to points ``(n, R)``."""
    a = np.stack([x * y, y * y, x, y, np.ones_like(x)], axis=-1) * ok[..., None]
    rhs = -(x * x) * ok
    ata = np.einsum("nrk,nrl->nkl", a, a) + 1e-9 * np.eye(5)
    atb = np.einsum("nrk,nr->nk", a, rhs)
    return _conic_centre(np.linalg.solve(ata, atb[..., None])[..., 0])


def _crossings(g, ox, oy):
    """Half-contrast crossings between horizontally and vertically adjacent pixels of the patches ``g``
    (contrast minus the level): dot index, x, y (offsets from the patch centre) [px]."""
    out = []
    n, s, _ = g.shape
    flat, above = g.reshape(-1), (g > 0).reshape(-1)
    for step in (1, s):                  # the neighbour to the right, then below (flat indices)
        q = np.flatnonzero(above[:-step] != above[step:])
        k, rem = np.divmod(q, s * s)
        i, j = np.divmod(rem, s)
        keep = (j < s - 1) if step == 1 else (i < s - 1)   # not across a patch's right or bottom edge
        q, k, i, j = q[keep], k[keep], i[keep], j[keep]
        a = flat[q]
        t = a / (a - flat[q + step])
        x = ox[i, j] + (t if step == 1 else 0)
        y = oy[i, j] + (t if step == s else 0)
        out.append((k, x, y))
    k, x, y = (np.concatenate(v) for v in zip(*out))
    order = np.argsort(k, kind="stable")
    return k[order], x[order], y[order]


def _conic_fit(k: np.ndarray, x: np.ndarray, y: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares conics ``x² + Bxy + Cy² + Dx + Ey + F = 0`` through the points ``x, y`` of each dot
    ``k`` (sorted by dot; each dot's rows laid side by side, zero-padded, so that one batched product gives
    every dot's normal equations). Returns ``(B, C, D, E, F)`` ``(n, 5)`` and whether each dot had at least 6
    points."""
    count = np.bincount(k, minlength=n)
    ok = count >= 6
    rows = np.zeros((n, max(int(count.max(initial=0)), 1), 6))
    if len(x):
        slot = np.arange(len(k)) - np.r_[0, np.cumsum(count)[:-1]][k]
        rows[k, slot] = np.column_stack([x * y, y * y, x, y, np.ones_like(x), -x * x])
    full = rows.transpose(0, 2, 1) @ rows
    ata, atb = full[:, :5, :5], full[:, :5, 5]
    ata[~ok] = np.eye(5)
    return np.linalg.solve(ata, atb[..., None])[..., 0], ok


def _conic_centre(coef: np.ndarray) -> np.ndarray:
    """Centres ``(n, 2)`` of the conics ``x² + Bxy + Cy² + Dx + Ey + F = 0`` of coefficients ``(n, 5)``."""
    B, C, D, E, _ = coef.T
    den = 4 * C - B * B
    den = np.where(np.abs(den) > 1e-12, den, 1e-12)
    return np.column_stack([(B * E - 2 * C * D) / den, (B * D - 2 * E) / den])


def _conic_distance(coef: np.ndarray, k: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """First-order distance [px] of points ``x, y`` of dots ``k`` from their dot's conic."""
    B, C, D, E, F = coef[k].T
    q = x * x + B * x * y + C * y * y + D * x + E * y + F
    return q / np.maximum(np.hypot(2 * x + B * y + D, B * x + 2 * C * y + E), 1e-9)


def _robust_conic(k: np.ndarray, x: np.ndarray, y: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Conics ``(n, 5)`` fitted to each dot's points, refitted without the points farther than three times
    the dot's RMS distance (plus 0.05 px) from the first fit (a hot pixel or a scratch on the outline), and
    whether each dot had 6 points at least."""
    coef, ok = _conic_fit(k, x, y, n)
    d = _conic_distance(coef, k, x, y)
    rms = np.sqrt(np.bincount(k, d * d, minlength=n) / np.maximum(np.bincount(k, minlength=n), 1))
    keep = np.abs(d) < 3 * rms[k] + 0.05
    return _conic_fit(k[keep], x[keep], y[keep], n)


def dot_reach(img: np.ndarray, centres: np.ndarray, radii: np.ndarray, dark: bool) -> float:
    """How far the dots and their blur reach from their centres [px]: where their mean flat-fielded radial
    profile falls to 2 % of its peak, plus 1.5 px (slmlab's rule in ``refine_moments``), measured on at most
    16 of them; at most 1.6 radii + 3 px."""
    r = float(np.median(radii))
    sample = centres[np.linspace(0, len(centres) - 1, min(len(centres), 16)).astype(int)]
    return min(profile_radius(flatten(img, sample, 1.6 * r + 4, dark), r) + 1.5, 1.6 * r + 3)


def flat_patches(img: np.ndarray, centres: np.ndarray, radii: np.ndarray, dark: bool, reach: float | None = None,
                 columns: np.ndarray | None = None, beyond: int | None = None, clipped_alone: bool = False,
                 clear_of: np.ndarray | None = None):
    """Flat-fielded contrast patches (:func:`flatten`, ``columns`` too) on a ring just outside the dots'
    reach, measured by :func:`dot_reach` unless given [px]; and the reach. ``beyond``: the contrast only
    within the reach plus this many pixels (the whole patch if ``None``). The ring keeps clear of the dots at
    ``clear_of`` (by default ``centres``: all of the image's, as :func:`refine` gives them) where it reaches them, but
    for the model fit (``clipped_alone``)."""
    reach = dot_reach(img, centres, radii, dark) if reach is None else reach
    crop = None if beyond is None else int(np.ceil(reach)) + beyond
    # the model fit's patches (``clipped_alone``) keep the whole ring: its own quadratic background reads every pixel
    # of the dot's reach, the ring only starts it
    return flatten(img, centres, reach + 1, dark, columns, crop, clipped_alone=clipped_alone,
                   clear_of=None if clipped_alone else (centres if clear_of is None else clear_of)), reach



def refine_edges(img: np.ndarray, centres: np.ndarray, radii: np.ndarray, *, dark: bool = True,
                 iterations: int = 1, reach: float | None = None, columns: np.ndarray | None = None,
                 clear_of: np.ndarray | None = None) -> np.ndarray:
    """Sub-pixel centres ``(n, 2)`` [px] from a conic fitted to the dots' half-contrast crossings.

    The contrast is flat-fielded (:func:`flatten`: a plane fitted per dot on a ring outside the dot and its
    blur); the level is half the median contrast of the dot's core; every
    pair of horizontally or vertically adjacent pixels on either side of it gives a crossing (linear
    interpolation). Of those between 0.3 of the radius and the blur's reach from the current centre, the
    outermost in each of :data:`SECTORS` directions (the outline seen from outside, not the crossings of
    dips inside the dot: a streak, texture, a donut's hole) are fitted by a conic; then in each direction
    the crossing nearest that conic (not a hot speck beyond the outline) is taken and fitted again. Each
    fit is repeated without the points off its first pass; all ``iterations`` times. Like :func:`refine_ellipse` it uses only the
    dot's outline (noise in the background and texture or streaks across the dot pull it less than a
    centroid), but it takes every crossing on the pixel grid instead of 48 interpolated rays: as accurate
    on the rendered family and about ten times faster. ``reach`` [px]: the dots' reach if known
    (:func:`dot_reach`); ``columns``: each column flat-fielded too (window streaks, :func:`flatten`)."""
    c = np.asarray(centres, float).copy()
    if len(c) == 0:
        return c
    # crossings within the reach + 2 px
    flat, reach = flat_patches(img, c, radii, dark, reach, columns, beyond=2, clear_of=clear_of)
    r = float(np.median(radii))
    core = np.hypot(flat.ox, flat.oy) <= max(0.5 * r, 1.0)
    level = 0.5 * np.median(flat.contrast[:, core], axis=1)
    k, x, y = _crossings(flat.contrast - level[:, None, None], flat.ox, flat.oy)
    f = c - flat.base
    for _ in range(iterations):
        dx, dy = x - f[k, 0], y - f[k, 1]
        d = np.hypot(dx, dy)
        use = np.flatnonzero((d > 0.3 * r) & (d < reach))
        ku, ang = k[use], np.arctan2(dy[use], dx[use])
        first = use[_best_per_sector(ku, ang, -d[use], SECTORS)]            # the outermost crossings
        coef, ok = _robust_conic(k[first], dx[first], dy[first], len(c))
        # then, per sector, the crossing nearest that outline (not a hot speck or a scratch beyond it)
        off = np.abs(_conic_distance(coef, ku, dx[use], dy[use]))
        best = use[_best_per_sector(ku, ang, np.where(ok[ku], off, -d[use]), SECTORS)]
        coef, ok = _robust_conic(k[best], dx[best], dy[best], len(c))
        cen = np.where(ok[:, None], _conic_centre(coef), np.nan)
        f = np.where(np.isfinite(cen), f + cen, f)
    return flat.base + f


def _best_per_sector(k: np.ndarray, angle: np.ndarray, score: np.ndarray, sectors: int) -> np.ndarray:
    """Indices (sorted by dot) of the point of lowest ``score`` of each dot ``k`` in each of ``sectors``
    equal angular sectors [rad]."""
    sec = np.minimum(((angle + np.pi) / (2 * np.pi) * sectors).astype(int), sectors - 1)
    key = k * sectors + sec
    size = int(key.max(initial=-1)) + 1
    low = np.full(size, np.inf)
    np.fmin.at(low, key, score)                          # each sector's lowest score (NaN ignored), no sort
    first = np.full(size, len(key))
    win = np.flatnonzero(score == low[key])
    np.minimum.at(first, key[win], win)                  # of ties, the first point
    chosen = np.zeros(len(key), bool)
    chosen[first[first < len(key)]] = True
    return np.flatnonzero(chosen)


# ------------------------------------------------------------------------------------------ model fit
#: the fitted dot model's non-linear parameters: centre ``cx, cy`` [px], the symmetric matrix ``s11, s12, s22``
#: [1/px] that maps an offset from the centre onto the unit circle (the outline), the blur ``w`` [radii];
#: then the linear ones: the background's quadratic surface (6) and the dot's depth, a plane (3) [grey levels]
FIT_NONLINEAR = 6
#: how far a fitted centre may move from its start and still be taken: this many pixels, or this share of the
#: dot's radius if more (a fit that strays to a neighbouring dot moves by a pitch, several radii)
FIT_MOVE_PX, FIT_MOVE_RADII = 2.0, 0.25
#: the fit's Levenberg-Marquardt steps at most (most dots stop after 3 to 8; 30 took a dot beside a Greenough rig's
#: glare from 0.2 to 0.7 px off, where the twelfth step had not yet reached the wrong minimum)
FIT_ITERATIONS = 12
#: a column around a dot is clipped where at least this share of its pixels outside the dot saturate, above the dot
#: and below it, and at most this share of the patch's columns are (:func:`_streak_gain`): a streak that saturates
#: the plate along it. Not a glare beside the dot or all around it, whose saturated pixels the fit's background and
#: censoring describe (with every column that saturates anywhere counted for nothing, dots beside a glare on a
#: Greenough rig's 16-bit image went from 0.08 to 0.4 px)
CLIPPED_SHARE = 0.5
#: a dot half in a clipped streak has its outline held to the median of this many nearest dots seen whole
FIT_NEIGHBOURS = 6
#: and is taken if at least this share of the pixels inside that outline was seen (not in a clipped column): not a
#: dot wholly in a band, fitted on nothing (a dot 0.19 seen was placed so that the fit kept every dot of the
#: stereo-DIC rig's "all together" images; at 0.25 it lost it, and the edge fit taken there was 0.059 px, not 0.043)
FIT_SEEN = 0.1
FIT_PARAMETERS = FIT_NONLINEAR + 6 + 3
#: the spread of a Gaussian prior on each of the dot's depth slopes (over the patch's half side), a share of its
#: depth (:func:`fit_dots`): light that gradients and vignetting change by a few per cent over a dot's patch (window
#: streaks' gain is divided out first, :func:`_streak_gain`). Fitted freely, the slopes traded against the centre in
#: noise: greenough:43 under the zoo's "noise" 0.146 px RMS (floor 0.041), 0.085 with this prior. A spread of 0.02
#: took it to 0.059 but bright dots under everything together (stereo-piv:31, :37) to 1.3-1.6 times what free
#: slopes gave, and dark ones under streaks (greenough:31, :37, two-level plates) to 1.2-1.3 times: their depth
#: varies by more there; with 0.05 they are at 0.97-1.13 times
DEPTH_SLOPE = 0.05
_DEPTH, _SLOPES = FIT_NONLINEAR + 6, slice(FIT_NONLINEAR + 7, FIT_PARAMETERS)


def _dot_model(theta: np.ndarray, x: np.ndarray, y: np.ndarray, h: float, jacobian: bool = True
               ) -> tuple[np.ndarray, np.ndarray | None]:
    """A blurred elliptical dot on a curved background, ``I = B(x, y) + A(x, y)·Φ((1 − q)/w)``, at offsets
    ``x, y`` ``(P,)`` [px] for parameters ``theta`` ``(n, 15)`` (:data:`FIT_NONLINEAR`): ``q = |S (x − c)|`` (1 on
    the outline), ``Φ`` the normal CDF (a blurred edge), ``B`` a quadratic and ``A`` a plane in ``x/h, y/h``
    [grey levels]. Returns the values ``(n, P)`` and, with ``jacobian``, their Jacobian ``(n, 15, P)``."""
    cx, cy, s11, s12, s22, w = (theta[:, k, None] for k in range(FIT_NONLINEAR))
    # in place where a temporary would be (n, P): the same operations in the same order (only the factors of a
    # product swapped), so the same bits
    ux, uy = x[None] - cx, y[None] - cy
    v1 = s11 * ux
    v1 += s12 * uy
    v2 = s12 * ux
    v2 += s22 * uy
    q = v1 * v1
    q += v2 * v2
    np.sqrt(q, out=q)
    q += 1e-9
    t = np.subtract(1.0, q)
    t /= w
    dot = np.divide(-t, np.sqrt(2.0))
    dot = erfc(dot, out=dot)
    dot *= 0.5
    xs, ys = x / h, y / h
    surface = np.stack([np.ones_like(xs), xs, ys, xs * xs, xs * ys, ys * ys])         # (6, P)
    a = theta[:, FIT_NONLINEAR + 6:] @ surface[:3]                                     # the depth A (n, P)
    value = theta[:, FIT_NONLINEAR:FIT_NONLINEAR + 6] @ surface
    value += a * dot
    if not jacobian:
        return value, None
    g = t * t
    g *= -0.5
    np.exp(g, out=g)
    np.multiply(a, g, out=g)
    g /= np.sqrt(2 * np.pi) * w                                                        # −dI/dq
    gq = g / q
    jac = np.empty((len(value), FIT_PARAMETERS, value.shape[1]))                  # parameters before pixels
    tmp = np.empty_like(value)
    np.multiply(gq, _sum_of_products(v1, s11, v2, s12, tmp), out=jac[:, 0])        # written in place
    np.multiply(gq, _sum_of_products(v1, s12, v2, s22, tmp), out=jac[:, 1])
    np.negative(gq, out=tmp)
    np.multiply(tmp, v1, out=jac[:, 2])
    jac[:, 2] *= ux
    np.multiply(tmp, v2, out=jac[:, 4])
    jac[:, 4] *= uy
    np.multiply(v1, uy, out=jac[:, 3])
    jac[:, 3] += v2 * ux
    jac[:, 3] *= tmp
    np.negative(g, out=tmp)
    np.multiply(tmp, t, out=jac[:, 5])
    jac[:, FIT_NONLINEAR:FIT_NONLINEAR + 6] = surface
    np.multiply(dot[:, None, :], surface[None, :3], out=jac[:, FIT_NONLINEAR + 6:])
    return value, jac


def _sum_of_products(a, b, c, d, out):
    """``a·b + c·d`` into ``out`` (the order of numpy's ``a * b + c * d``)."""
    np.multiply(a, b, out=out)
    out += c * d
    return out


def _fit_start(p: np.ndarray, x: np.ndarray, y: np.ndarray, h: float, weight: np.ndarray, centre: np.ndarray,
               radius: float, blur: float, outline: np.ndarray | None = None) -> np.ndarray:
    """Starting parameters ``(n, 15)``: the outline a circle of ``radius`` [px] at ``centre`` (offsets, [px])
    blurred by ``blur`` [px], or ``outline`` ``(n, 4)`` (:func:`fit_dots`); the linear parameters by weighted least
    squares for that outline."""
    n = len(p)
    theta = np.zeros((n, FIT_PARAMETERS))
    theta[:, :2] = centre
    theta[:, 2] = theta[:, 4] = 1.0 / radius
    theta[:, 5] = blur / radius
    if outline is not None:
        theta[:, 2:FIT_NONLINEAR] = outline
    _, jac = _dot_model(theta, x, y, h)
    lin = jac[:, FIT_NONLINEAR:]
    wl = lin * weight[:, None, :]
    ata = wl @ lin.transpose(0, 2, 1) + 1e-9 * np.eye(FIT_PARAMETERS - FIT_NONLINEAR)
    theta[:, FIT_NONLINEAR:] = np.linalg.solve(ata, wl @ p[..., None])[..., 0]
    return theta


def _fit_cost(theta, p, x, y, h, weight, censored, jacobian=True, unit=False
              ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """Weighted residuals ``(n, P)``, Jacobian (with ``jacobian``) and cost ``(n,)`` of :func:`_dot_model`
    against patches ``p``; a ``censored`` (saturated) pixel counts only where the model is below it; ``unit``:
    every weight is 1."""
    value, jac = _dot_model(theta, x, y, h, jacobian)
    r = value - p
    if unit and not censored.any():   # unit weights: nothing to scale (the same bits)
        return r, jac, np.einsum("np,np->n", r, r)
    wt = np.where(censored & (r > 0), 0.0, weight)
    if jac is not None:
        jac *= wt[:, None, :]
    return r * wt, jac, np.einsum("np,np->n", r * wt, r)


def fit_dots(p: np.ndarray, x: np.ndarray, y: np.ndarray, weight: np.ndarray, start: np.ndarray, radius: float,
             blur: float, censored: np.ndarray, iterations: int = FIT_ITERATIONS, outline: np.ndarray | None = None
             ) -> tuple[np.ndarray, np.ndarray]:
    """Levenberg-Marquardt fits of :func:`_dot_model` to patches ``p`` ``(n, P)`` at offsets ``x, y`` [px] with
    pixel ``weight`` ``(P,)`` or ``(n, P)``, all dots at once (one 15 × 15 system per dot and iteration), from the circle of
    ``radius`` and ``blur`` [px] at ``start`` ``(n, 2)`` [px]; ``censored`` ``(n, P)`` pixels (saturated) count only
    where the model is below them. Returns
    the parameters ``(n, 15)`` and whether each fit converged to a dot (a finite, positive-definite outline
    within :data:`FIT_MOVE_PX` or :data:`FIT_MOVE_RADII` of the dot's radius of the start, whichever is more:
    a large dot beside a steep glare has its moments' start pulled by more than 2 px; :func:`_converged`).
    ``outline`` ``(n, 4)``: each dot's outline and blur (``s11, s12, s22, w``) held, its centre, background and depth
    fitted alone, and taken where its outline holds its start. The depth's slopes have a Gaussian prior
    (:data:`DEPTH_SLOPE`, weighed against the fit's own residual variance, again at each step: :func:`_slope_prior`)."""
    h = float(np.abs(x).max())
    w = np.broadcast_to(weight, p.shape)
    unit = bool((np.asarray(weight) == 1.0).all())   # once, not at every step
    theta = _fit_start(p, x, y, h, np.where(censored, 0.0, w), start, radius, blur, outline)
    lam = np.full(len(p), 1e-4)
    active = np.arange(len(p))                # the dots still moving (each iteration works on those alone)
    for _ in range(iterations):
        i = active
        r, jac, cost = _fit_cost(theta[i], p[i], x, y, h, w[i], censored[i], unit=unit)
        if outline is not None:
            jac[:, 2:FIT_NONLINEAR] = 0.0
        jtj = jac @ jac.transpose(0, 2, 1)                                         # batched BLAS
        diag = np.einsum("nkk->nk", jtj) + 1e-12
        if outline is not None:
            diag[:, 2:FIT_NONLINEAR] = 1.0
        grad = jac @ r[..., None]
        mu = _slope_prior(theta[i], cost, w[i])
        cost = cost + mu * (theta[i, _SLOPES] ** 2).sum(axis=1)
        jtj[:, _SLOPES, _SLOPES] += mu[:, None, None] * np.eye(2)
        grad[:, _SLOPES, 0] += mu[:, None] * theta[i, _SLOPES]
        step = np.linalg.solve(jtj + lam[i, None, None] * diag[:, :, None] * np.eye(FIT_PARAMETERS), -grad)[..., 0]
        trial = _fit_cost(theta[i] + step, p[i], x, y, h, w[i], censored[i], jacobian=False, unit=unit)[2]
        trial = trial + mu * ((theta[i, _SLOPES] + step[:, _SLOPES]) ** 2).sum(axis=1)
        better = np.isfinite(trial) & (trial < cost)
        theta[i[better]] += step[better]
        lam[i] = np.where(better, lam[i] / 3, lam[i] * 4)
        # done: a centre that moved by less than 1e-3 px, or a fit that no longer improves
        active = i[~((better & (np.abs(step[:, :2]).max(axis=1) < 1e-3)) | (lam[i] > 1e6))]
        if len(active) == 0:
            break
    return theta, _converged(theta, start, radius, held=outline is not None)


def _slope_prior(theta: np.ndarray, cost: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """The weight ``(n,)`` of the prior on the depth slopes (:data:`DEPTH_SLOPE`) in :func:`fit_dots`' cost: the
    residual variance per pixel that carries weight over the prior's variance."""
    seen = np.maximum((weight > 0).sum(axis=1), 1)
    return cost / seen / (DEPTH_SLOPE * np.maximum(np.abs(theta[:, _DEPTH]), 1e-6)) ** 2


def _converged(theta: np.ndarray, start: np.ndarray, radius: float, held: bool = False) -> np.ndarray:
    """Whether each fit of :func:`fit_dots` converged to a dot: a finite, positive-definite outline within
    :data:`FIT_MOVE_PX` or :data:`FIT_MOVE_RADII` of ``radius`` [px] of its ``start``; with the outline ``held``
    (not fitted, its neighbours'), one whose outline holds its start (a crescent's centroid is far off: 0.8 of the
    radius on greenough:7201, less than half of each dot in view)."""
    s11, s12, s22 = theta[:, 2], theta[:, 3], theta[:, 4]
    shape = np.isfinite(theta).all(axis=1) & (s11 > 0) & (s11 * s22 - s12 * s12 > 0) & (theta[:, 5] > 0)
    if held:   # the start inside the dot it found
        return shape & (_outline_distance(theta, start[:, :1], start[:, 1:])[:, 0] < 1.0)
    return shape & (np.hypot(*(start - theta[:, :2]).T) < max(FIT_MOVE_PX, FIT_MOVE_RADII * radius))


def _outline_distance(theta: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``|S (x − c)|`` ``(n, P)`` of points ``x, y`` [px] (``(P,)``, or ``(n, P)`` one set per dot) for the outlines of
    :func:`fit_dots`' parameters ``theta`` ``(n, 15)``: 1 on the outline, below 1 inside it."""
    ux, uy = x - theta[:, :1], y - theta[:, 1:2]
    s11, s12, s22 = theta[:, 2:3], theta[:, 3:4], theta[:, 4:5]
    return np.hypot(s11 * ux + s12 * uy, s12 * ux + s22 * uy)


def saturation(img: np.ndarray) -> float:
    """The level of a saturated pixel [grey levels]: the image's full scale (255 for 8 bit; for 16-bit
    images ``2^k − 1`` for the least bit depth ``k`` that holds the image) if some pixel reaches it, else
    ``inf`` (a float image, or one whose brightest pixel is below its full scale)."""
    top = float(img.max())
    if img.dtype == np.uint8:
        full = 255.0
    elif img.dtype == np.uint16:
        full = float(2 ** max(8, int(np.ceil(np.log2(top + 1)))) - 1)
    else:
        return float("inf")
    return top if top >= full else float("inf")


def saturated_dots(img: np.ndarray, centres: np.ndarray, reach: float, *, regions: bool = False) -> np.ndarray:
    """Whether each dot ``(n,)`` at ``centres`` ``(n, 2)`` [px] has a saturated pixel (:func:`saturation`) in its
    patch, within ``reach`` + 2 px of it along either axis (``reach`` [px]: :func:`dot_reach`); with ``regions``,
    one with a saturated neighbour above, below or beside it: a clipped region (a glare beside the dot, a streak
    that clips the plate), not a lone pixel that noise took to full scale (under the zoo's heavy noise on the
    Greenough rig's 8-bit plate at 200 DN a few do)."""
    c = np.asarray(centres, float)
    sat = saturation(img)
    if not np.isfinite(sat):   # nothing reaches full scale
        return np.zeros(len(c), bool)
    clipped = img >= sat
    if regions:   # on the image, so that a patch's edge padding does not pair a border pixel with its copy
        v, h = clipped[1:] & clipped[:-1], clipped[:, 1:] & clipped[:, :-1]
        clipped = np.zeros_like(clipped)
        clipped[1:] |= v
        clipped[:-1] |= v
        clipped[:, 1:] |= h
        clipped[:, :-1] |= h
    p, _ = gather_patches(clipped, c, int(np.ceil(reach + 2)))
    return p.any(axis=(1, 2))


def outline_cut(img: np.ndarray, centres: np.ndarray, radii: np.ndarray, dark: bool,
                overlay: tuple[int, int] = (0, 0)) -> np.ndarray:
    """Whether each dot's outline ``(n,)`` reaches the picture's edge: a pixel of its first or last column, or of
    its first or last row clear of a camera's text ``overlay`` (rows at the top and bottom), within 1.4 ``radii``
    + 2 px of the dot's centre ``(n, 2)`` [px] holds at least half the dot's contrast (the 90th percentile within
    0.8 of its radius: a donut's ring counts; flat-fielded as the centre estimators read it, :func:`flatten`, on a
    ring that stays between the dots of a dense plate; the mean of three pixels along the edge, so that one noisy
    pixel does not cut a dot), or the centre is off the picture.

    What is cut is read on the image, not assumed from a radius and a margin: a dot whose outline lies a pixel
    inside the edge is whole (its centre estimators see all of it but some of its blur), while an oblique ellipse
    whose long axis meets the edge is cut though its mean radius is inside."""
    c = np.asarray(centres, float).reshape(-1, 2)
    r = np.broadcast_to(np.asarray(radii, float), (len(c),))
    h, w = img.shape
    top, bottom = overlay[0], h - 1 - overlay[1]
    reach = 1.4 * r + 2   # an oblique ellipse reaches beyond its mean radius (axes 1.33 r at 16:9)
    cut = ~((c[:, 0] >= 0) & (c[:, 0] <= w - 1) & (c[:, 1] >= top) & (c[:, 1] <= bottom))
    near = np.flatnonzero(~cut & ((c[:, 0] - reach <= 0) | (c[:, 0] + reach >= w - 1) | (c[:, 1] - reach <= top)
                                  | (c[:, 1] + reach >= bottom)))
    if len(near) == 0:
        return cut
    rmax = float(np.max(r[near]))
    gap = float(np.median(cKDTree(c).query(c, k=2)[0][:, 1])) if len(c) > 2 else np.inf   # the dots' spacing
    flat = flatten(img, c[near], max(rmax + 2, min(1.6 * rmax + 4, gap - rmax - 6)), dark)   # a ring between dots
    inner = np.hypot(flat.ox, flat.oy) <= np.maximum(0.8 * r[near], 1.0)[:, None, None]
    half = 0.5 * np.array([np.percentile(con[m], 90) for con, m in zip(flat.contrast, inner)])   # a donut's too
    x = flat.base[:, 0, None, None] + flat.ox[None].astype(int)
    y = flat.base[:, 1, None, None] + flat.oy[None].astype(int)
    seen = (x >= 0) & (x <= w - 1) & (y >= top) & (y <= bottom)
    con = np.where(seen, flat.contrast, np.nan)
    along_y = (con + np.roll(con, 1, axis=1) + np.roll(con, -1, axis=1)) / 3     # along the left and right edges
    along_x = (con + np.roll(con, 1, axis=2) + np.roll(con, -1, axis=2)) / 3     # along the top and bottom rows
    edge_y, edge_x = (x == 0) | (x == w - 1), (y == top) | (y == bottom)
    within = np.hypot(x - c[near, 0, None, None], y - c[near, 1, None, None]) <= reach[near, None, None]
    high = ((edge_y & (np.nan_to_num(along_y, nan=-np.inf) >= half[:, None, None]))
            | (edge_x & (np.nan_to_num(along_x, nan=-np.inf) >= half[:, None, None])))
    cut[near] = (high & within & seen).any(axis=(1, 2))
    return cut


def uneven_background(img: np.ndarray, centres: np.ndarray, radii: np.ndarray, dark: bool,
                      reach: float | None = None) -> bool:
    """Whether the background under the image's dots ``(n, 2)`` [px] is one the ring-flattened estimators
    extrapolate badly: saturated pixels within the dots' reach + 2 px of a dot (:func:`saturated_dots`: a bright
    region beside it) or window streaks across the dots (:func:`streak_mask`); where :func:`refine_fit` is
    worth its time. ``reach`` [px]: :func:`dot_reach`, measured unless given."""
    c = np.asarray(centres, float)
    if len(c) == 0:
        return False
    reach = dot_reach(img, c, radii, dark) if reach is None else reach
    return bool(saturated_dots(img, c, reach).any()) or streak_mask(img, c, radii, dark, reach) is not None


def light_pull_px(img: np.ndarray, centres: np.ndarray, radii: np.ndarray, dark: bool,
                  reach: float | None = None) -> float:
    """How far [px] the light's slope across bright dots pulls their whole-dot centres (``moments``, and less
    ``symmetry``): the median over (at most 64 of) the dots ``(n, 2)`` [px] of ``|a| r² / 4``, the centroid's shift
    on a disk of radius ``r`` whose brightness is ``1 + a·x`` along its slope ``a`` [1/px]. Each dot's slope is that
    of a plane fitted to the flat-fielded contrast of its core (:func:`flatten`; within 0.7 ``r`` of its centroid,
    the offsets taken from there: about the patch's centre pixel, a peaked core half a pixel off reads as a slope),
    over its brightness there; the light is smooth, so ``a`` is those slopes' smooth field over the plate (each
    component a least-squares plane in the dots' places, a quadratic from 12 dots): a dot's texture or noise, which
    slopes it at random, is not the light's. The PIV Challenge's case E reads 0.24 px so (0.31-0.37 dot by dot; its
    moments lie 0.21 px off the lattice, its edges 0.06: ``auto`` took an edge estimator there already). Nil
    for dark dots: their contrast ``1 − I/B`` divides the light out, where a bright dot's ``I − B`` keeps it
    (:func:`_contrast`), and below 4 dots.

    The lattice residual cannot see this pull: it is smooth across the plate, so the lattice's model takes it up
    (stereo-piv:77's 5 × 5 plate of 150 px bright dots under a gradient: moments 0.47 px off the truth, the fit
    0.002, both 0.015 px off their lattices)."""
    c = np.asarray(centres, float)
    if dark or len(c) < 4:
        return 0.0
    sample = np.unique(np.linspace(0, len(c) - 1, min(len(c), 64)).astype(int))
    r = np.broadcast_to(np.asarray(radii, float), (len(c),))[sample]
    reach = dot_reach(img, c, radii, dark) if reach is None else reach
    flat = flatten(img, c[sample], reach + 1, dark)
    f = _centroid(*_on_disk(flat.contrast, flat, reach), c[sample] - flat.base, reach, flat.bounds)
    dx = (flat.ox[None] - f[:, 0, None, None]).reshape(len(sample), -1)          # offsets from each centroid
    dy = (flat.oy[None] - f[:, 1, None, None]).reshape(len(sample), -1)
    m = (np.hypot(dx, dy) <= 0.7 * r[:, None]).astype(float)
    con = flat.contrast.reshape(len(sample), -1).astype(float)
    terms = (np.ones_like(dx), dx, dy)                                            # a plane per core, at once
    normal = np.stack([np.stack([(m * a * b).sum(axis=1) for b in terms], -1) for a in terms], -2)
    rhs = np.stack([(m * a * con).sum(axis=1) for a in terms], -1)
    enough = (m.sum(axis=1) >= 6) & (np.abs(np.linalg.det(normal)) > 1e-9)
    slope = np.full((len(sample), 2), np.nan)
    if enough.any():
        b = np.linalg.solve(normal[enough], rhs[enough][..., None])[..., 0]
        slope[enough] = np.where(b[:, :1] > 0, b[:, 1:] / np.where(b[:, :1] > 0, b[:, :1], 1.0), np.nan)
    ok = np.isfinite(slope).all(axis=1)
    if ok.sum() < 4:
        return 0.0
    at = c[sample] - c[sample].mean(axis=0)
    x, y = at[:, 0] / max(float(np.ptp(at[:, 0])), 1.0), at[:, 1] / max(float(np.ptp(at[:, 1])), 1.0)
    terms = np.column_stack([np.ones_like(x), x, y] + ([x * x, x * y, y * y] if ok.sum() >= 12 else []))
    field = terms @ np.linalg.lstsq(terms[ok], slope[ok], rcond=None)[0]
    return float(np.median(np.hypot(*field[ok].T) * r[ok] ** 2 / 4))


def refine_fit(img: np.ndarray, centres: np.ndarray, radii: np.ndarray, *, dark: bool = True,
               iterations: int = FIT_ITERATIONS, reach: float | None = None, columns: np.ndarray | None = None
               ) -> np.ndarray:
    """Sub-pixel centres ``(n, 2)`` [px] by a least-squares fit of a model of the dot and its background to
    the pixels within the dots' reach + 2 px (:func:`fit_dots`, :func:`_dot_model`): a blurred ellipse whose
    depth varies as a plane on a quadratic background, started from the :func:`refine_moments` centre.

    Least-squares matching of a target model, as photogrammetry measures its targets (Luhmann, Robson, Kyle and Boehm,
    *Close-Range Photogrammetry and 3D Imaging*, 3rd ed., 2019, on target centres). Where the background is not
    flat under a dot (a steep out-of-focus bright region beside it, a curved one) the fitted surface follows it,
    where a ring outside the dot only extrapolates a plane; saturated pixels (:func:`saturation`) are censored (a
    dot whose surroundings saturate keeps its unsaturated core and edges); with ``columns`` the patch is first
    divided by its columns' gain (window streaks, :func:`_streak_gain`). A column saturated along a streak, its
    gain measured on clipped pixels, counts for nothing (a streak that saturates the plate hides how bright it is, and what its
    saturated pixels bound), nor do the edge's copies beyond the image, and a dot that loses pixels so is fitted again with its outline held to its
    neighbours' (:func:`_neighbours_outline`), from the first fit's centre (or its moments' start, the centroid of
    what is left): what it has left, an edge and part of its core, then places it, and it is taken where its outline
    holds its start (:func:`_converged`) and at least :data:`FIT_SEEN` of the pixels inside it were seen; else the
    first fit stands. A fit that fails (not finite, not an ellipse, beyond those limits)
    keeps the moments' centre. ``reach`` [px]: :func:`dot_reach`. Tens of times slower than ``moments`` (a 15 × 15
    system per dot and iteration, 3 to :data:`FIT_ITERATIONS` iterations)."""
    return _fit_centres(img, centres, radii, dark, iterations, reach, columns)[0]


def _fit_centres(img: np.ndarray, centres: np.ndarray, radii: np.ndarray, dark: bool, iterations: int,
                 reach: float | None, columns: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`refine_fit`'s centres ``(n, 2)`` [px], and which dots were fitted with their outline held ``(n,)``."""
    c = np.asarray(centres, float).copy()
    if len(c) == 0:
        return c, np.zeros(0, bool)
    reach = dot_reach(img, c, radii, dark) if reach is None else reach
    start = refine_moments(img, c, radii, dark=dark, reach=reach, columns=columns, clipped_alone=True)
    half = int(np.ceil(reach + 2))
    p, base = gather_patches(img, start, half)
    p = p.astype(np.float64)
    sat = saturation(img)
    censored = p >= sat
    weight = np.ones_like(p)
    if columns is not None:
        p, weight = _streak_gain(img, p, start, reach, dark, sat, columns)
    off = np.arange(-half, half + 1, dtype=np.float64)
    oy, ox = np.meshgrid(off, off, indexing="ij")
    h, w = img.shape
    copies = ~(((base[:, 0, None, None] + ox >= 0) & (base[:, 0, None, None] + ox <= w - 1))
               & ((base[:, 1, None, None] + oy >= 0) & (base[:, 1, None, None] + oy <= h - 1)))
    weight = np.where(copies, 0.0, weight)   # the edge's copies beyond the image are not seen
    disk = np.hypot(ox, oy) <= reach + 2
    r, blur = _profile_outline(img, start, reach, dark) or (float(np.median(radii)),
                                                            max(0.5 * (reach - 1.5 - float(np.median(radii))), 0.7))
    p, x, y, weight, censored = p[:, disk], ox[disk], oy[disk], weight[:, disk], censored[:, disk]
    theta, ok = fit_dots(p, x, y, weight, start - base, r, blur, censored, iterations)
    centre = np.where(ok[:, None], theta[:, :2], start - base)
    part = ((weight == 0) & (np.hypot(x - centre[:, :1], y - centre[:, 1:]) < r + blur)).any(axis=1)
    held = np.zeros(len(c), bool)
    if part.any() and (~part & ok).sum() >= 3:   # a dot half in a clipped streak: fitted again, its outline held
        th, fine = fit_dots(p[part], x, y, weight[part], centre[part], r, blur, censored[part], iterations,
                            outline=_neighbours_outline(theta, start, ~part & ok, part))
        fine &= _seen(th, x, y, weight[part]) >= FIT_SEEN
        theta[part] = np.where(fine[:, None], th, theta[part])   # where it fails, the first fit stands
        ok[part] |= fine
        held[part] = fine
    return np.where(ok[:, None], base + theta[:, :2], start), held


def _profile_outline(img: np.ndarray, centres: np.ndarray, reach: float, dark: bool) -> tuple[float, float] | None:
    """The dots' radius and blur [px] (a start for :func:`fit_dots`) from the mean flat-fielded radial profile of at
    most 16 of them (:func:`flatten`): where it falls to half its peak, and half the distance from 84 % to 16 % (a
    Gaussian edge's σ); ``None`` if it does not fall so within ``reach`` [px]. The sweep's area at half the peak,
    read on the reduced, smoothed image, made the PIV rig's dots 11.2 px for 8.9, and a fit started so sharp and large
    left 29 of 441 dots 0.1-0.7 px off."""
    sample = centres[np.linspace(0, len(centres) - 1, min(len(centres), 16)).astype(int)]
    prof = _radial_profile(flatten(img, sample, reach + 1, dark))[: int(reach) + 1]
    prof = prof / max(float(prof[: max(int(reach) // 2, 1)].max()), 1e-12)
    def crossing(level):   # the first radius where the profile falls below level, linearly between pixels
        k = np.flatnonzero(prof < level)
        if len(k) == 0 or k[0] == 0:
            return None
        i = k[0]
        return i - 1 + (prof[i - 1] - level) / (prof[i - 1] - prof[i])
    radius, inner, outer = crossing(0.5), crossing(0.84), crossing(0.16)
    if radius is None or inner is None or outer is None or radius < 1.0:
        return None
    return float(radius), float(max(0.5 * (outer - inner), 0.5))


def _seen(theta: np.ndarray, x: np.ndarray, y: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """The share ``(n,)`` of the pixels inside each fitted outline (:func:`fit_dots`) that carry weight."""
    inside = _outline_distance(theta, x[None], y[None]) < 1.0
    return (inside & (weight > 0)).sum(axis=1) / np.maximum(inside.sum(axis=1), 1)


def _neighbours_outline(theta: np.ndarray, at: np.ndarray, whole: np.ndarray, part: np.ndarray) -> np.ndarray:
    """The outline and blur ``(m, 4)`` (:func:`fit_dots`) of each dot of ``part``: the median of those of the
    :data:`FIT_NEIGHBOURS` nearest (``at`` ``(n, 2)`` [px]) of the dots fitted ``whole`` (the outline varies over
    the field: oblique views, defocus)."""
    idx = np.flatnonzero(whole)
    _, near = cKDTree(at[idx]).query(at[part], k=min(FIT_NEIGHBOURS, len(idx)))
    return np.median(theta[idx[near.reshape(int(part.sum()), -1)], 2:FIT_NONLINEAR], axis=1)


def _streak_gain(img: np.ndarray, p: np.ndarray, start: np.ndarray, reach: float, dark: bool,
                 sat: float, free: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Patches ``p`` ``(n, S, S)`` around ``start`` divided by their columns' gain under window streaks (the plane plus
    the column offsets of :func:`flatten`, over the plane), and pixel weights: 0 in a column whose offset was
    measured on saturated pixels, along a streak (:data:`CLIPPED_SHARE`: its gain, and what its saturated pixels
    bound, unknown), else 1; ``sat``: :func:`saturation`."""
    half = p.shape[1] // 2
    flat = flatten(img, start, reach + 1, dark, columns=free, clipped_alone=True)
    k = flat.ox.shape[0] // 2 - half
    level = np.maximum(flat.coef[:, 0], 1.0)[:, None]
    big, _ = gather_patches(img, start, flat.ox.shape[0] // 2)
    full = big >= sat
    outside = np.hypot(flat.ox, flat.oy) > reach + 1
    col = flat.column[:, k:k + 2 * half + 1]
    clipped = np.ones(big.shape[::2], bool)                                                    # (n, S')
    for side in (outside & (flat.oy < 0), outside & (flat.oy > 0)):   # saturated along it, above and below the dot
        clipped &= (full & side).sum(axis=1) >= CLIPPED_SHARE * np.maximum(side.sum(axis=0), 1)
    clipped &= clipped.mean(axis=1, keepdims=True) <= CLIPPED_SHARE   # a band through the patch, not a glare around
    clipped = clipped[:, k:k + 2 * half + 1]                                                     # (n, S)
    gain = np.maximum(1.0 + np.where(clipped, 0.0, col) / level, 0.25)   # a dark object over both halves
    return p / gain[:, None, :], np.broadcast_to(np.where(clipped, 0.0, 1.0)[:, None, :], p.shape).copy()


def _asymmetry(stack: np.ndarray, f: np.ndarray, ux: np.ndarray, uy: np.ndarray, jacobian: bool = False):
    """``r(u) = A(f + u) − A(f − u)`` ``(n, P)`` of patches ``stack`` ``(n, S, S)`` (``A`` bilinear), ``f``
    ``(n, 2)`` [px from each patch's centre pixel, within ``S // 2 - max|u| - 2``], ``u = (ux, uy)`` ``(P,)``
    whole pixels: each patch shifted once by its fraction of a pixel, then read at whole pixels. Exact in float
    arithmetic (``cv2.remap`` rounds the fraction to 1/32 px, a 0.01 px floor for a centre estimator). With
    ``jacobian``, also ``∂r/∂f`` along x and y: central differences of the shifted patch, which are the
    patch's central differences shifted the same way. Only the square of the patches that the offsets read is
    shifted (near convergence every centre is within a pixel of its patch's middle: two thirds of the patch)."""
    whole = np.floor(f)
    k = whole.astype(np.int64) + stack.shape[1] // 2
    if len(k):   # the rows and columns read: k ± (max|u| + 1 for the differences), and the bilinear sample's next
        r = int(max(np.abs(ux).max(initial=0), np.abs(uy).max(initial=0))) + int(jacobian)
        lo, hi = max(int(k.min()) - r, 0), min(int(k.max()) + r + 2, stack.shape[1])
        stack, k = stack[:, lo:hi, lo:hi], k - lo
    n, s, _ = stack.shape
    t = (f - whole).astype(stack.dtype)
    tx, ty = t[:, 0, None, None], t[:, 1, None, None]
    rows = stack[:, :, :-1] + tx * (stack[:, :, 1:] - stack[:, :, :-1])
    shifted = (rows[:, :-1] + ty * (rows[:, 1:] - rows[:, :-1])).reshape(-1)
    at = ((np.arange(n) * (s - 1) + k[:, 1]) * (s - 1) + k[:, 0])[:, None]
    off = uy.astype(np.int64) * (s - 1) + ux.astype(np.int64)
    plus, minus = at + off, at - off
    r = np.take(shifted, plus) - np.take(shifted, minus)
    if not jacobian:
        return r
    jac = tuple(0.5 * (np.take(shifted, plus + e) - np.take(shifted, plus - e) - np.take(shifted, minus + e)
                       + np.take(shifted, minus - e)) for e in (1, s - 1))
    return r, jac


def _half_disk(reach: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Integer offsets ``u`` of one half of a disk of radius ``reach`` [px] (one of each pair ``±u``) and their
    anti-aliased weights (1 inside, falling to 0 over the last pixel)."""
    k = int(np.ceil(reach + 1))
    uy, ux = np.mgrid[-k:k + 1, -k:k + 1].astype(np.float64)
    w = np.clip(reach + 0.5 - np.hypot(ux, uy), 0.0, 1.0)
    keep = ((uy > 0) | ((uy == 0) & (ux > 0))) & (w > 0)
    return ux[keep], uy[keep], w[keep]


def refine_symmetry(img: np.ndarray, centres: np.ndarray, radii: np.ndarray, *, dark: bool = True,
                    iterations: int = 4, reach: float | None = None, columns: np.ndarray | None = None,
                    clear_of: np.ndarray | None = None) -> np.ndarray:
    """Sub-pixel centres as the points of symmetry of the flat-fielded contrast ``C``: Gauss-Newton on
    ``Σ_u w(u) r(u)²``, ``r(u) = C(c + u) − C(c − u)``, over the pixel offsets ``u`` of a disk reaching as far as
    the dots' blur (:func:`dot_reach`), bilinear samples, the Jacobian from their central differences.

    A dot seen through a lens, round or oblique, sharp or blurred, is point-symmetric about its centre to
    first order; no model of its shape or profile is assumed. Every pixel of the dot and its blur counts,
    weighted by the local slope, so in white noise it comes near the Cramér-Rao bound of a symmetric target,
    where the centroid of :func:`refine_moments`, which weights the flat inside as much as the edge, does not
    (at low contrast in noise, 20-40 % nearer the truth: ``tests/test_extract.py``). From one centroid step:
    steps with the Jacobian at each estimate until no centre moves more than 0.1 px (at most ``iterations``),
    then at most as many with the last Jacobian kept (each three times cheaper; where the asymmetry vanishes
    does not depend on it, and in noise a Jacobian 0.1 px old moves the centre by far less than the noise),
    until none moves more than 0.001 px. Not weighted robustly: Tukey's biweight on the asymmetries set a hot
    pixel aside, but where the blurred dot itself is not quite symmetric (a Scheimpflug view) it moved the
    centre by 0.005 px more than it helped. The contrast ``1 − I/B`` is flat-fielded as in
    :func:`refine_moments`; the image's §3 dot centres feed the paper's line fitting and Eqs. (1)–(3). A dot
    whose patch holds a non-finite pixel gets NaN. Returns ``(n, 2)`` [px].
    """
    c = np.asarray(centres, float).copy()
    if len(c) == 0:
        return c
    flat, reach = flat_patches(img, c, radii, dark, reach, columns, clear_of=clear_of)
    bad = ~np.isfinite(flat.contrast).all(axis=(1, 2))             # a NaN pixel: that dot's centre is NaN
    con = np.where(bad[:, None, None], np.float32(0), flat.contrast)
    ux, uy, w = _half_disk(reach)
    room = con.shape[1] // 2 - int(np.ceil(reach + 1)) - 1        # how far a centre may move inside its patch
    f = _centroid(*_on_disk(con, flat, reach), c - flat.base, reach, flat.bounds)
    f = np.clip(f, -room, room)                                   # one centroid step: nearer than the detection's
    w = _seen_pairs(w, ux, uy, f, flat.bounds)
    for _ in range(iterations):                       # Gauss-Newton, the Jacobian at each estimate
        step, normal = _symmetry_step(con, f, ux, uy, w, None)
        f = np.clip(f + step, -room, room)
        if np.abs(step).max() <= 0.1:
            break
    for _ in range(iterations):                       # the last normal equations kept: where r = 0 does not change
        step, _ = _symmetry_step(con, f, ux, uy, w, normal)
        f = np.clip(f + step, -room, room)
        if np.abs(step).max() < 1e-3:
            break
    return np.where(bad[:, None], np.nan, flat.base + f)


def _seen_pairs(w: np.ndarray, ux: np.ndarray, uy: np.ndarray, f: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    """:func:`refine_symmetry`'s weights ``w`` ``(P,)`` of the offset pairs ``±(ux, uy)``, as ``(n, P)`` without the
    pairs of which one pixel (within a pixel's margin of the estimate ``f`` ``(n, 2)`` from the patch's centre) is
    beyond the image's edge (``bounds``, :class:`Flat`): there the patch holds the edge's copies, not the dot; ``w``
    itself where no dot's pairs leave the image."""
    near = np.minimum(np.abs(f[:, [0, 0, 1, 1]] - bounds), 1e9)
    mx, my = near[:, :2].min(axis=1) - 1, near[:, 2:].min(axis=1) - 1    # a pixel short: the estimate moves
    cut = (np.abs(ux).max(initial=0) > mx) | (np.abs(uy).max(initial=0) > my)
    if not cut.any():
        return w
    keep = (np.abs(ux)[None, :] <= mx[:, None]) & (np.abs(uy)[None, :] <= my[:, None])
    return np.where(cut[:, None], w[None, :] * keep, w[None, :])


def _symmetry_step(con: np.ndarray, f: np.ndarray, ux: np.ndarray, uy: np.ndarray, w: np.ndarray,
                   normal: tuple | None) -> tuple[np.ndarray, tuple]:
    """One Gauss-Newton step ``(n, 2)`` [px] of :func:`refine_symmetry` from patch offsets ``f`` ``(n, 2)``, and
    the normal equations used: the weighted Jacobian ``w·∂r/∂x, w·∂r/∂y`` ``(n, P)`` and the matrix's terms and
    determinant ``(n,)`` (held at 1e-12 where it is smaller in magnitude), at ``f`` unless ``normal`` (those of a
    Jacobian kept) is given."""
    if normal is None:
        r, (jx, jy) = _asymmetry(con, f, ux, uy, jacobian=True)
        wx, wy = w * jx, w * jy
        a11, a12, a22 = (wx * jx).sum(1), (wx * jy).sum(1), (wy * jy).sum(1)
        det = a11 * a22 - a12 * a12
        normal = (wx, wy, a11, a12, a22, np.where(np.abs(det) > 1e-12, det, 1e-12))
    else:
        r = _asymmetry(con, f, ux, uy)
    wx, wy, a11, a12, a22, det = normal
    b1, b2 = (wx * r).sum(1), (wy * r).sum(1)
    step = -np.column_stack([a22 * b1 - a12 * b2, a11 * b2 - a12 * b1]) / det[:, None]
    return np.clip(step, -1.0, 1.0), normal


def streak_mask(img: np.ndarray, centres: np.ndarray, radii: np.ndarray, dark: bool, reach: float
                ) -> np.ndarray | None:
    """Whether window streaks cross the image's dots ``(n, 2)`` [px], and where to read them: the pixels clear of
    every dot (:func:`slmlab.images.streaks.clear_of_dots`) if at least :data:`STREAK_SHARE` of the dots (of at
    most 32 spread over the list) have columns that differ by more than noise (:data:`STREAKINESS`), alike above
    and below the dot (:func:`coherent`), along strips through them (:func:`flatten`, patches reaching ``reach``
    [px]), bright dots by at least :data:`STREAK_EFFECT` of their contrast; else ``None``."""
    if len(centres) == 0:
        return None
    free = clear_of_dots(img.shape, centres, reach)
    sample = centres[np.linspace(0, len(centres) - 1, min(len(centres), 32)).astype(int)]
    flat = flatten(img, sample, reach + 1, dark, columns=free)
    crossed = flat.column.any(axis=1)
    if not dark:   # an offset too small beside the dot's contrast to move its centre
        peak = flat.contrast.reshape(len(sample), -1).max(axis=1)
        crossed &= np.abs(flat.column).max(axis=1) >= STREAK_EFFECT * peak
    return free if np.mean(crossed) >= STREAK_SHARE else None


def refine(img: np.ndarray, centres: np.ndarray, radii: np.ndarray, *, dark: bool, method: str) -> np.ndarray:
    """Sub-pixel centres ``(n, 2)`` [px] by the estimator ``method`` (:data:`METHODS`), the dots' reach measured once
    (:func:`dot_reach`); on an image crossed by window streaks (:func:`streak_mask`) the columns of each dot they
    cross are flat-fielded one by one (:func:`flatten`); dots that moved more than two pixels from ``centres`` (a
    coarse first guess), and those whose rings reach the neighbours (:func:`_crowded`) that moved more than
    :data:`CROWD_AGAIN_PX`, are refined again from where they moved to, flat-fielded on a ring around their new place
    clear of every dot where it now is (not a dot ``fit`` with its outline held, half in a clipped streak: its
    moments there would start it from the visible part's centroid again, without the neighbours that hold its
    outline)."""
    c = np.asarray(centres, float)
    if len(c) == 0:
        return c.reshape(0, 2).copy()
    fn = {"moments": refine_moments, "ellipse": refine_ellipse, "edges": refine_edges, "fit": refine_fit,
          "symmetry": refine_symmetry}[method]
    reach = dot_reach(img, c, radii, dark)
    columns = streak_mask(img, c, radii, dark, reach)
    if method == "fit":
        xy, held = _fit_centres(img, c, radii, dark, FIT_ITERATIONS, reach, columns)
    else:
        xy, held = fn(img, c, radii, dark=dark, reach=reach, columns=columns), np.zeros(len(c), bool)
    moved = np.hypot(*(xy - c).T)
    again = (moved > 2.0) & ~held
    if method != "fit":   # a ring cleared of the neighbours about a first guess this far off lay on the dot's own blur
        again |= (moved > CROWD_AGAIN_PX) & _crowded(c, reach)
    if again.any():   # the ring cleared of every dot where they are now, not of the few alone
        kw = {} if method == "fit" else {"clear_of": xy.copy()}
        xy[again] = fn(img, xy[again], radii[again], dark=dark, reach=reach, columns=columns, **kw)
    return xy


def _crowded(centres: np.ndarray, reach: float) -> np.ndarray:
    """Which dots' background rings (1 to 5 px beyond ``reach`` [px], :func:`flat_patches`) reach another dot's
    blur (within ``reach`` of it): :func:`_ring_crowd`'s dots, from the centres alone (a NaN centre: not)."""
    c = np.asarray(centres, float).reshape(-1, 2)
    ok = np.isfinite(c).all(axis=1)
    out = np.zeros(len(c), bool)
    if ok.sum() < 2:
        return out
    d = cKDTree(c[ok]).query(c[ok], k=2)[0][:, 1]
    out[ok] = d < (reach + 5) + reach      # the ring's outer edge, and the neighbour's blur
    return out
