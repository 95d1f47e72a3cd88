"""Finding the dots of a calibration plate in one image (the paper's §3 input; their sub-pixel centres are
:mod:`slmlab.images.centres`, their numbering :mod:`slmlab.images.lattice`).

Nothing here depends on one threshold, one dot size or roundness, so that any plate a person can see is found
(8, 12 or 16 bit, dark dots on a bright plate or bright dots on black, oblique ellipses, defocus, low contrast,
gradients, vignetting, bright out-of-focus regions, streaks, hot pixels, a camera's text strip):

1. **Local contrast** (:func:`local_contrast`): the image is reduced by a whole factor to at most
   :data:`SWEEP_SIDE_PX` a side (less where the plate's pitch would be too fine for the sweep there:
   :func:`slmlab.images.extract._detect_fine`) and smoothed (Gaussian, 1 reduced px); on a mesh of cells (1/16 of the
   image's smaller side) the background is the cells' median and the spread the half-width of the dot-free
   side of their histogram (median minus 16th percentile for bright dots); both meshes are median-filtered
   over 3 × 3 cells and interpolated. Window streaks, narrower than a cell, are the background's columns
   (:func:`column_offsets`): where the offsets both quartiles of a column agree on stand out of the noise, the
   offsets read on the dots' free side are taken out, the mesh again less them, and they join the background.
   ``z = ±(I − background) / spread`` is the contrast in noise units, dots positive, whatever the illumination,
   offset, bit depth, streaks or a bright region beside the plate.
2. **Threshold sweep** (:func:`sweep`), OpenCV's SimpleBlobDetector idea on ``z`` instead of the raw image
   (whose one level per image a bright region or a gradient defeats): :data:`LEVELS` levels from
   :data:`LOWEST_SIGMA` σ to the 99.95th percentile of ``z`` (geometric, and one at :data:`SECOND_LEVEL` × the
   lowest, whatever sets the top); each level's connected components
   are tracked to the level below by containment (their centroid pixel), or by the nearest centroid for
   rings. A blob seen at two levels or more is a candidate, and on a two-level plate so is one split off a
   larger blob at one level only, with an outline that can show a shape (a marker beside a dot); its outline
   is read at the highest level at or below half its peak. Which candidates are the plate's dots is decided by their lattice
   (:func:`slmlab.images.lattice.fit_lattice`), not by their size or shape; which are markers, by
   :mod:`slmlab.images.markers`.
3. **Hot pixels** (:func:`clean_hot_pixels`) are replaced by their 5 × 5 median once the dots' size is known:
   outside the dots, and inside them too where the camera's other images show the same pixel standing out
   (:func:`camera_hot_pixels`).
4. **Local search** (:func:`search_missing`): a node the lattice predicts but the sweep missed is searched
   on its own local background by a matched filter of the dots' size, and taken only if it stands out of
   the noise and looks like the plate's own dots.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial import cKDTree

from ..errors import SlmlabError
from .overlay import outside_nil, overlay_rows, picture_rows, within
from .robust import mad, masked_median, median_by_sort

__all__ = ["grey_image", "LOWEST_SIGMA", "LEVELS", "SECOND_LEVEL", "SPLIT_AREA_PX", "NCC_MIN", "NCC_STRONG", "SEARCH_SIGMA",
           "STRONG_SHARE", "STRONG_SIGMA",
           "SWEEP_SIDE_PX", "STREAK_BANDS", "STREAK_QUARTILES", "STREAK_SHARE", "read_image",
           "as_float", "as_8bit", "dot_polarity",
           "gather_patches", "Contrast", "ContrastMesh", "reduction", "local_contrast", "local_contrasts", "column_offsets", "Candidates", "sweep",
           "HOT_SHARE", "hot_pixel_flags", "hot_images_needed", "camera_hot_pixels", "clean_hot_pixels", "search_missing"]

#: the sweep's lowest level [noise σ of the smoothed, reduced image]
LOWEST_SIGMA = 3.0
#: the number of levels of the sweep
LEVELS = 6
#: the sweep has a level at this many times its lowest (:func:`_ladder`)
SECOND_LEVEL = 2.0
#: on a two-level plate, a blob seen at one level only that split off a larger blob there is a candidate if its
#: area [px², full resolution] is at least this, the least a marker's outline needs to show its shape
#: (:func:`slmlab.images.markers.polygon_kind`): the levels are a factor 3 apart, so a marker that parallax
#: brings within a few pixels of a dot is apart from it at one level only
SPLIT_AREA_PX = 100
#: least normalised cross-correlation with the dots' template of a dot found by the local search
NCC_MIN = 0.5
#: the local search takes a dot whose matched filter peaks at this many times its ring's spread (and at a fifth
#: of the found dots' median peak)
SEARCH_SIGMA = 5.0
#: ... or at :data:`STRONG_SIGMA` only, where it is at least this share of the found dots' median peak and
#: correlates with their template by :data:`NCC_STRONG`: the ring's spread is not the camera's noise alone
#: (stereo-piv:5216 under a clean camera, dots 79 DN over a read noise of 0.5 DN: a row of them at 0.77 of the
#: found dots' strength, NCC 0.89-0.95, at 4.2-4.8 σ; stereo-piv:11 beside its bright region: 0.67-0.99, NCC
#: 0.89-0.96, 4.1-4.7 σ)
STRONG_SHARE = 0.5
#: the least significance of such a strong dot [ring spreads]
STRONG_SIGMA = 3.0
#: the least normalised cross-correlation with the dots' template of such a strong dot
NCC_STRONG = 0.8
#: a camera's hot pixels are those that stand out in at least this share of its images, and in two: 2 of 2, 3 of 3
#: or 4, 6 of 7, 10 of 13 (:func:`camera_hot_pixels`). Case E's Z stacks (seven planes, a dot covering 7-8 % of the
#: image): pixels standing out in all seven lie on a dot 0.5-1.1 % of the time, in six 5-10 %, in five 12-15 %, in two
#: to four 18-41 % (the dots' texture in neighbouring planes, where the dots barely move)
HOT_SHARE = 0.75
#: the largest side of the reduced image the sweep runs on [px]
SWEEP_SIDE_PX = 700
#: window streaks are measured per band of rows: this many bands down the image (:func:`column_offsets`)
STREAK_BANDS = 8
#: ... a column's offset is read from these quantiles of its pixels in the band (:func:`column_offsets`)
STREAK_QUARTILES = (0.25, 0.75)
#: the mesh statistics are taken again less the columns' offsets where more than this share of them is beyond
#: the noise (the rendered zoo's window streaks: 0.21-0.31 of the columns; clean plates up to 0.11, from a
#: plate's own edge along the columns; noise alone: about 0.001); below it the second pass would change little
STREAK_SHARE = 0.15


# ------------------------------------------------------------------------------------------ reading
def read_image(path: str | Path) -> np.ndarray:
    """Read an image as a 2-D array of grey levels in its own bit depth (``uint8``, ``uint16`` or ``float32``:
    any format OpenCV reads, PNG and TIFF included); colour images are converted to grey. Missing,
    unreadable or truncated files are a :class:`SlmlabError` that names the file."""
    path = Path(path)
    if not path.exists():
        raise SlmlabError("image not found; check the path (images are named relative to the set's folder)", path)
    if path.is_dir():
        raise SlmlabError("is a folder, not an image; give the image file", path)
    data = np.fromfile(path, dtype=np.uint8)
    img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED | cv2.IMREAD_ANYDEPTH) if data.size else None
    if img is None or img.size == 0:
        raise SlmlabError("cannot be read as an image (unreadable, truncated or not an image); re-export it as "
                          "PNG or TIFF", path)
    if img.ndim == 3:
        if img.shape[2] == 1:
            img = img[:, :, 0]
        else:
            code = cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
            img = cv2.cvtColor(img, code)
    return grey_image(img, path)


def grey_image(img: np.ndarray, path: str | Path | None = None) -> np.ndarray:
    """An image array as the extractor reads it: 2-D grey levels, ``uint8`` and ``uint16`` as they are, any other
    real type (``float64``, signed integers) as ``float32``, which OpenCV's filters take. Not 2-D, empty or with
    non-finite values is a :class:`SlmlabError` (naming ``path``, the file it came from, if given)."""
    img = np.asarray(img)
    if img.ndim != 2 or img.size == 0 or not (np.issubdtype(img.dtype, np.number) or img.dtype == bool) \
            or np.iscomplexobj(img):
        raise SlmlabError(f"an image must be a 2-D array of grey levels; got shape {img.shape}, type {img.dtype}",
                          path)
    if img.dtype not in (np.uint8, np.uint16):
        img = img.astype(np.float32)
        if not np.isfinite(img).all():
            raise SlmlabError("holds non-finite pixel values; re-export it as an integer image", path)
    return img


def as_float(img: np.ndarray) -> np.ndarray:
    """The image as ``float32`` (no copy if it is one)."""
    return img if img.dtype == np.float32 else img.astype(np.float32)


def as_8bit(img: np.ndarray) -> np.ndarray:
    """An 8-bit copy for OpenCV functions that take only 8-bit images: 16-bit and float images are scaled from
    their 0.1 to 99.9 percentile (robust to a few hot pixels)."""
    if img.dtype == np.uint8:
        return img
    f = as_float(img)
    lo, hi = np.percentile(f[::4, ::4], [0.1, 99.9])
    return cv2.convertScaleAbs(f, alpha=255.0 / max(hi - lo, 1e-6), beta=-lo * 255.0 / max(hi - lo, 1e-6))


def dot_polarity(img: np.ndarray) -> bool:
    """``True`` for dark dots on a bright plate, ``False`` for bright dots on a dark one: the dots are the
    minority class of an Otsu split of the image (a dot plate is mostly background)."""
    small = as_8bit(cv2.resize(img, (max(img.shape[1] // 4, 1), max(img.shape[0] // 4, 1)),
                               interpolation=cv2.INTER_AREA))
    t, _ = cv2.threshold(small, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    return bool(np.mean(small > t) > 0.5)


def gather_patches(img: np.ndarray, centre: np.ndarray, half: int) -> tuple[np.ndarray, np.ndarray]:
    """Square patches ``(n, S, S)`` of ``img`` around the integer points nearest ``centre`` (edge-clamped)
    and those integer points ``(n, 2)``."""
    base = np.rint(centre).astype(int).reshape(-1, 2)
    h, w = img.shape
    if len(base) and (base >= 0).all() and (base[:, 0] < w).all() and (base[:, 1] < h).all():
        # windows of the image (padded by its edge pixels where a patch leaves it): a copy per patch row,
        # the same pixels as clamping every index, ten times faster
        x, y = base[:, 0], base[:, 1]
        inside = x.min() >= half and y.min() >= half and x.max() < w - half and y.max() < h - half
        src = img if inside else np.pad(img, half, mode="edge")
        x, y = (x - half, y - half) if inside else (x, y)
        return np.lib.stride_tricks.sliding_window_view(src, (2 * half + 1, 2 * half + 1))[y, x], base
    off = np.arange(-half, half + 1)
    rows = np.clip(base[:, 1, None] + off[None, :], 0, h - 1)
    cols = np.clip(base[:, 0, None] + off[None, :], 0, w - 1)
    return img[rows[:, :, None], cols[:, None, :]], base


# ------------------------------------------------------------------------------------------ contrast
@dataclass
class Contrast:
    """Local contrast of the reduced image.

    Attributes
    ----------
    z
        ``±(I − background) / spread`` of the reduced, smoothed image [noise σ], dots positive.
    scale
        reduction factor: full-resolution pixels per reduced pixel.
    background, spread
        the interpolated mesh statistics on the reduced image [grey levels].
    signed
        the reduced, smoothed image, negated for dark dots (dots positive) [grey levels].
    dark
        the dots are darker than the plate.
    picture
        the reduced image's rows ``[a, b)`` the picture fills, beyond a camera's text overlay
        (:func:`slmlab.images.overlay.overlay_rows`; ``z`` is nil beyond them), or ``None``: all of them.
    overlay
        the full-resolution rows the overlay covers at the top and at the bottom
        (:func:`slmlab.images.overlay.overlay_rows`).
    """

    z: np.ndarray
    scale: int
    background: np.ndarray
    spread: np.ndarray
    signed: np.ndarray
    dark: bool = False
    picture: tuple[int, int] | None = None
    overlay: tuple[int, int] = (0, 0)

    def again(self, img: np.ndarray) -> "Contrast":
        """The contrast of ``img``, an image like the one this was taken of (the same with hot pixels
        replaced), on this one's mesh: the mesh's medians and spreads do not see a few pixels."""
        small, r = _reduced(img, self.scale)
        z = outside_nil((small - self.background) / self.spread, self.picture)
        return Contrast(-z if self.dark else z, r, self.background, self.spread, -small if self.dark else small,
                        self.dark, self.picture, self.overlay)

    def to_full(self, xy: np.ndarray) -> np.ndarray:
        """Reduced-image coordinates ``(n, 2)`` → full-resolution ones [px] (pixel centres at integers)."""
        return np.asarray(xy, float) * self.scale + (self.scale - 1) / 2

    def to_reduced(self, xy: np.ndarray) -> np.ndarray:
        """Full-resolution coordinates ``(n, 2)`` [px] → reduced-image ones."""
        return (np.asarray(xy, float) - (self.scale - 1) / 2) / self.scale


def reduction(shape: tuple[int, int]) -> int:
    """Reduction factor of the sweep image: the image's larger side over :data:`SWEEP_SIDE_PX`, rounded up."""
    return max(1, int(np.ceil(max(shape) / SWEEP_SIDE_PX)))


def _mesh_statistics(small: np.ndarray, cell: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Background (median) and the spreads for bright and for dark dots (the half-width of the dot-free side of
    the histogram: median minus the 16th percentile for bright dots, 84th minus median for dark ones) per cell
    of ``cell`` px, median-filtered over 3 × 3 cells and interpolated to the image [grey levels]. One
    partition serves both polarities."""
    hs, ws = small.shape
    nr, nc = max(1, hs // cell), max(1, ws // cell)
    y0, x0 = (hs - nr * cell) // 2, (ws - nc * cell) // 2
    st = max(1, cell // 24)  # every st-th pixel of a cell: ~600 samples per cell
    block = small[y0:y0 + nr * cell, x0:x0 + nc * cell].reshape(nr, cell, nc, cell)[:, ::st, :, ::st]
    block = block.transpose(0, 2, 1, 3).reshape(nr, nc, -1)
    n = block.shape[-1]
    ks = [int(0.1587 * n), n // 2, int(0.8413 * n)]
    p = np.sort(block, axis=-1)[..., ks]      # (a full sort of ~1000 values beats a partition at three ranks)
    mesh = [np.ascontiguousarray(m, dtype=np.float32) for m in (p[..., 1], p[..., 1] - p[..., 0], p[..., 2] - p[..., 1])]
    if min(nr, nc) >= 3:
        mesh = [cv2.medianBlur(m, 3) for m in mesh]
    lo, hi = np.percentile(small[::4, ::4], [0.1, 99.9])
    spread_all = float(hi - lo)
    mesh[1:] = [np.maximum(sd, max(1e-3 * spread_all, 0.05 * float(np.median(sd)), 1e-6)) for sd in mesh[1:]]

    def up(m):  # cell values at cell centres, linear in between, replicated beyond the outer centres
        m = cv2.resize(m, (nc * cell, nr * cell), interpolation=cv2.INTER_LINEAR)
        return cv2.copyMakeBorder(m, y0, hs - y0 - nr * cell, x0, ws - x0 - nc * cell, cv2.BORDER_REPLICATE)
    return tuple(up(m) for m in mesh)


def _reduced(img: np.ndarray, scale: int | None = None) -> tuple[np.ndarray, int]:
    """The image reduced by ``scale`` (by default :func:`reduction`; area average) and smoothed (Gaussian, 1
    reduced px), and the factor."""
    h, w = img.shape
    r = reduction(img.shape) if scale is None else max(1, int(scale))
    # crop to whole blocks so that the reduction is exactly r (reduced pixel i covers pixels r·i … r·i + r − 1)
    if r > 1 and (img.dtype == np.uint8 or (img.dtype == np.uint16 and r <= 15)):
        small = _block_means(img[:h // r * r, :w // r * r], r)
    else:
        f = img if img.dtype == np.float32 else img.astype(np.float32)
        small = cv2.resize(f[:h // r * r, :w // r * r], (w // r, h // r), interpolation=cv2.INTER_AREA) if r > 1 else f
    return cv2.GaussianBlur(small, (0, 0), 1.0), r


def _block_means(img: np.ndarray, r: int) -> np.ndarray:
    """The mean of each ``r`` × ``r`` block of an 8- or 16-bit image of whole blocks, as float32: the numbers
    ``cv2.resize``'s area average gives the image as float32 (block sums of whole grey levels, exact below 2²⁴, times
    the float32 ``1/r²``), summed in integers without a float copy of the image (1 against 3 ms at 2048²), by strided
    adds of whole rows, then columns (a sum over the axes of the image reshaped into blocks took 18 ms)."""
    acc = np.uint16 if img.dtype == np.uint8 and r <= 16 else np.uint32
    rows = img[0::r].astype(acc)
    for k in range(1, r):
        rows += img[k::r]
    sums = rows[:, 0::r].copy()
    for k in range(1, r):
        sums += rows[:, k::r]
    return sums.astype(np.float32) * np.float32(1.0 / (r * r))


@dataclass
class ContrastMesh:
    """What the local contrast of an image (:func:`local_contrasts`) does not owe to the dots' polarity: the
    reduced, smoothed image, its reduction factor, the mesh's cell [reduced px], background and spreads (for
    bright and for dark dots) and the columns' streak offsets (:func:`column_offsets`)."""

    small: np.ndarray
    scale: int
    cell: int
    background: np.ndarray
    spreads: tuple
    streaks: tuple
    picture: tuple[int, int] | None = None
    overlay: tuple[int, int] = (0, 0)
    _again: dict = field(default_factory=dict, repr=False)

    @classmethod
    def of(cls, img: np.ndarray, scale: int | None = None) -> "ContrastMesh":
        """The mesh of ``img`` reduced by ``scale`` (by default :func:`reduction`)."""
        small, r = _reduced(img, scale)
        cell = max(8, int(min(img.shape) / 16 / r))
        overlay = overlay_rows(img)
        picture = picture_rows(overlay, r, small.shape[0], cell)   # a camera's text strip left out
        overlay = overlay if picture is not None else (0, 0)
        bg, *sds = within(small, picture, _mesh_statistics, cell)
        return cls(small, r, cell, bg, tuple(sds), within(small - bg, picture, column_offsets), picture, overlay)

    def streaky(self, dark: bool) -> bool:
        """Whether more than :data:`STREAK_SHARE` of the columns' offsets that both quartiles agree on stand out
        of the noise (the spread for ``dark`` or bright dots): window streaks, which move a whole column."""
        return bool(np.mean(np.abs(self.streaks[2][::8]) > median_by_sort(self.spreads[int(dark)])) > STREAK_SHARE)

    def contrast(self, dark: bool, sided: bool = True) -> Contrast:
        """The local contrast for dark or bright dots; on a streaky image (:meth:`streaky`) the columns' offsets
        read on the dots' free side (``sided``) or where both quartiles agree (:func:`column_offsets`) join the
        background, the mesh taken again less them."""
        b, sd = self.background, self.spreads[int(dark)]
        if self.streaky(dark):
            k = int(dark) if sided and not np.array_equal(self.streaks[int(dark)], self.streaks[2]) else 2
            if k not in self._again:   # both polarities share the mesh less the agreed offsets
                self._again[k] = within(self.small - self.streaks[k], self.picture, _mesh_statistics, self.cell)
            again = self._again[k]
            b, sd = again[0] + self.streaks[k], again[1 + int(dark)]
        z = outside_nil((self.small - b) / sd, self.picture)
        return Contrast(-z if dark else z, self.scale, b, sd, -self.small if dark else self.small, dark, self.picture,
                        self.overlay)


def local_contrasts(img: np.ndarray, polarities=(False, True)) -> list[Contrast]:
    """The local-contrast image of ``img`` (module docstring, step 1), one per polarity in ``polarities``
    (``dark``: True or False). The reduction, the mesh and the columns' quartiles do not depend on the polarity
    and are computed once (:class:`ContrastMesh`); on a streaky image each polarity reads its streaks from the
    dots' free side, and its mesh is taken again less them."""
    mesh = ContrastMesh.of(img)
    return [mesh.contrast(dark) for dark in polarities]


def local_contrast(img: np.ndarray, *, dark: bool) -> Contrast:
    """The local-contrast image of ``img`` (module docstring, step 1) for dark or bright dots."""
    return local_contrasts(img, (dark,))[0]


def column_offsets(residual: np.ndarray, bands: int = STREAK_BANDS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Window streaks: each column's offset ``(h, w)`` [grey levels] of ``residual`` (an image less its mesh
    background), per band of rows (:data:`STREAK_BANDS` bands down the image, at least 16 rows each), linear
    between the bands' middles; ``(for bright dots, for dark dots, agreed)``. A streak moves all of a column's
    pixels, a dot only those on its own side. A column's offset is that of its 1st and 3rd quartiles
    (:data:`STREAK_QUARTILES`, each less its median over the band's columns) that is nearer zero where they agree in
    sign (``agreed``), so that neither dark nor bright dots, up to three quarters of a column over a band, pass for
    a streak (a column through dot centres on a clean plate moves by a fraction of the noise). For dots of a known
    polarity, where the two disagree, it is that of the quartile on the dots' free side (the 3rd for dark dots, the
    1st for bright ones) if that moved more than the other: a bright streak down a column of dark dots moves the
    3rd quartile, and the dots pull the 1st below (on ``greenough:7201`` by 16 of the streak's 20 grey levels; read
    as agreed, the streak was lost and its dots with it). Where the dots moved more (PIV Challenge case E's large
    bright dots, over half of a column), a streak of the other sign would be the dots' own shadow. Where the
    polarity is not known, ``agreed``: read on one side, a column of dots passes for a streak of the other polarity,
    which builds a lattice between the dots. A median cell of the mesh, 1/16 of the image, spread a streak
    narrower than itself over its neighbours and lost the dots beside it to the spread it added."""
    h, w = residual.shape
    n = max(1, min(bands, h // 16))
    edges = np.linspace(0, h, n + 1).astype(int)
    prof = np.empty((3, n, w), np.float32)
    for i, (a, b) in enumerate(zip(edges[:-1], edges[1:])):
        cols = np.ascontiguousarray(residual[a:b:2].T)   # every other row: half the time, as good
        k = [int(q * (cols.shape[1] - 1)) for q in STREAK_QUARTILES]
        lo, hi = np.sort(cols, axis=1)[:, k].T
        lo, hi = lo - np.median(lo), hi - np.median(hi)
        agree = lo * hi > 0
        prof[2, i] = np.where(agree, np.where(np.abs(lo) < np.abs(hi), lo, hi), 0.0)
        prof[0, i] = np.where(agree | (np.abs(lo) <= np.abs(hi)), prof[2, i], lo)   # bright dots: free side low
        prof[1, i] = np.where(agree | (np.abs(hi) <= np.abs(lo)), prof[2, i], hi)   # dark dots: free side high
    return tuple(cv2.resize(p, (w, h), interpolation=cv2.INTER_LINEAR) for p in prof)


# ------------------------------------------------------------------------------------------ sweep
@dataclass
class Candidates:
    """Blobs kept over the threshold sweep, in full-resolution pixels.

    Attributes
    ----------
    xy
        centroids ``(n, 2)`` [px] at the blob's reference level (the highest at or below half its peak).
    area
        area at the reference level [px²].
    size
        bounding box ``(n, 2)`` (width, height) at the reference level [px].
    levels
        number of consecutive sweep levels the blob was seen at.
    peak
        its peak contrast: the highest level it was seen at, or the contrast at its centroid if higher
        [noise σ].
    border, hole
        the blob touches the image border; its centroid is outside it (a ring: a donut marker).
    level
        the reference level [noise σ].
    born
        the sweep level index the blob was first seen at (0: a blob of its own at the lowest level; higher:
        split off a larger blob, such as a fragment of a textured dot).
    low
        the level it was first seen at [noise σ] (its widest outline: for thin markers).
    low_area, low_size
        its area [px²] and bounding box ``(n, 2)`` [px] at that level.
    noise
        blobs seen at one level only (not candidates; counted), but those split off a larger blob
        (:data:`SPLIT_AREA_PX`).
    """

    xy: np.ndarray
    area: np.ndarray
    size: np.ndarray
    levels: np.ndarray
    peak: np.ndarray
    border: np.ndarray
    hole: np.ndarray
    level: np.ndarray
    born: np.ndarray
    low: np.ndarray
    low_area: np.ndarray
    low_size: np.ndarray
    noise: int = 0

    def __len__(self) -> int:
        return len(self.xy)


def _ladder(z: np.ndarray, levels: int) -> tuple[np.ndarray, np.ndarray]:
    """Geometric threshold ladder from :data:`LOWEST_SIGMA` to the 99.95th percentile of ``z`` (at least
    4 × the lowest) [noise σ], with a level at :data:`SECOND_LEVEL` × the lowest added where the second is above
    it, and which levels may be a blob's reference level (not the added one: the outlines and areas the dots are
    refined from stay those of the geometric ladder). A blob that reaches the added level is seen at two levels, a
    candidate, however high the image's top (a camera's text strip or a glare sets it, not the dots: on
    ``greenough:7201`` the second level was at 9 σ and 30 of the 49 dots, at 6-9 σ, were noise)."""
    top = float(np.percentile(z[::3, ::3], 99.95))
    top = min(max(top, 4 * LOWEST_SIGMA), 1e4)
    ts = LOWEST_SIGMA * (top / LOWEST_SIGMA) ** (np.arange(levels) / (levels - 1))
    ref = np.ones(len(ts), bool)
    if levels < 2 or ts[1] <= SECOND_LEVEL * LOWEST_SIGMA:
        return ts, ref
    return np.insert(ts, 1, SECOND_LEVEL * LOWEST_SIGMA), np.insert(ref, 1, False)


@dataclass
class _Level:
    """The blobs of one sweep level: centroids ``(m, 2)``, stats ``(m, 5)``, track ids ``(m,)``, and the
    label image with the map from its labels to the blobs (``-1``: too small, dropped)."""

    xy: np.ndarray
    st: np.ndarray
    ids: np.ndarray
    labels: np.ndarray
    index: np.ndarray


def _components(z: np.ndarray, t: float, min_area: int = 2) -> _Level:
    """Components of ``z > t`` with at least ``min_area`` px (track ids not yet set)."""
    # Grana's block-based labelling: twice as fast here as the default's statistics pass
    _, labels, st, cen = cv2.connectedComponentsWithStatsWithAlgorithm(cv2.compare(z, float(t), cv2.CMP_GT), 8,
                                                                      cv2.CV_32S, cv2.CCL_BBDT)
    keep = st[:, cv2.CC_STAT_AREA] >= min_area
    keep[0] = False
    index = np.full(len(st), -1)
    index[keep] = np.arange(int(keep.sum()))
    return _Level(cen[keep], st[keep], np.full(int(keep.sum()), -1), labels, index)


def _own_centroid(cur: _Level) -> np.ndarray:
    """Whether each blob's centroid pixel belongs to it (not so for a ring, a frame or a crescent)."""
    h, w = cur.labels.shape
    cx = np.clip(np.rint(cur.xy[:, 0]).astype(int), 0, w - 1)
    cy = np.clip(np.rint(cur.xy[:, 1]).astype(int), 0, h - 1)
    return cur.index[cur.labels[cy, cx]] == np.arange(len(cur.xy))


def _track(prev: _Level | None, cur: _Level) -> None:
    """Set the track ids of a level's blobs (``-1`` for new ones) from the level below. A blob whose centroid
    pixel is its own continues the blob of the level below holding that pixel (thresholds nest, so that one
    contains it; if it split, its largest part continues it); other blobs (rings, crescents) continue the
    nearest blob not yet continued, within 0.6 of its radius (at least 1.5 px)."""
    if prev is None or len(cur.xy) == 0 or len(prev.xy) == 0:
        return
    h, w = cur.labels.shape
    cx = np.clip(np.rint(cur.xy[:, 0]).astype(int), 0, w - 1)
    cy = np.clip(np.rint(cur.xy[:, 1]).astype(int), 0, h - 1)
    parent = np.where(_own_centroid(cur), prev.index[prev.labels[cy, cx]], -1)
    order = np.flatnonzero(parent >= 0)
    order = order[np.argsort(-cur.st[order, cv2.CC_STAT_AREA], kind="stable")]
    _, first = np.unique(parent[order], return_index=True)
    win = order[first]
    cur.ids[win] = prev.ids[parent[win]]
    taken = np.zeros(len(prev.xy), bool)
    taken[parent[win]] = True
    free = np.flatnonzero(~taken)
    rest = np.flatnonzero(cur.ids < 0)
    if len(free) == 0 or len(rest) == 0:
        return
    d, j = cKDTree(prev.xy[free]).query(cur.xy[rest])
    ok = np.flatnonzero(d < np.maximum(1.5, 0.6 * np.sqrt(prev.st[free[j], cv2.CC_STAT_AREA] / np.pi)))
    ok = ok[np.argsort(d[ok], kind="stable")]
    _, first = np.unique(j[ok], return_index=True)
    cur.ids[rest[ok[first]]] = prev.ids[free[j[ok[first]]]]


def sweep(con: Contrast, *, levels: int = LEVELS, split: bool = False) -> Candidates:
    """Blobs stable over a threshold sweep of the local contrast (module docstring, step 2); with ``split`` (a
    two-level plate, whose markers parallax brings beside a dot) also those split off a larger blob at one level
    only (:data:`SPLIT_AREA_PX`)."""
    ts, ref_ok = _ladder(con.z, levels)
    recs, prev, next_id = [], None, 0
    for k, t in enumerate(ts):
        cur = _components(con.z, t)
        _track(prev, cur)
        new = cur.ids < 0
        cur.ids[new] = next_id + np.arange(int(new.sum()))
        next_id += int(new.sum())
        recs.append(np.column_stack([cur.ids, np.full(len(cur.ids), k), cur.xy, cur.st, _own_centroid(cur)]))
        prev = cur
        if len(cur.xy) == 0:   # the levels nest: nothing above a level that holds no blob
            break
    rec = np.vstack(recs) if recs else np.empty((0, 10))
    return _summarise(rec, ts, con, split, ref_ok)


def _summarise(rec: np.ndarray, ts: np.ndarray, con: Contrast, split: bool = False,
               ref_ok: np.ndarray | None = None) -> Candidates:
    """Per-track candidates from the sweep's records ``(id, level, cx, cy, x, y, w, h, area, own centroid)``;
    ``ref_ok``: the levels that may be a reference level (:func:`_ladder`)."""
    rec = rec[np.lexsort((rec[:, 1], rec[:, 0]))]
    ids, start, count = np.unique(rec[:, 0].astype(int), return_index=True, return_counts=True)
    first = rec[start, 1].astype(int)
    last = first + count - 1
    s = con.scale
    # split off a larger blob (born above the lowest level, its centroid its own: not a ring), large enough
    split = split & (first > 0) & (rec[start, 9] == 1) & (rec[start, 8] * s * s >= SPLIT_AREA_PX)
    noise = int(((count < 2) & ~split).sum())
    keep = (count >= 2) | split
    start, first, last, count = start[keep], first[keep], last[keep], count[keep]
    # the peak: the highest level passed, or the contrast at the last level's centroid if higher; the
    # reference level is the highest at or below half of it (the outline a little outside the half level)
    top = rec[start + count - 1]
    hs, ws = con.z.shape
    cx, cy = np.clip(np.rint(top[:, 2]).astype(int), 0, ws - 1), np.clip(np.rint(top[:, 3]).astype(int), 0, hs - 1)
    peak = np.maximum(ts[last], con.z[cy, cx])
    eligible = np.flatnonzero(np.ones(len(ts), bool) if ref_ok is None else ref_ok)
    ref = np.clip(eligible[np.maximum(np.searchsorted(ts[eligible], peak / 2, side="right") - 1, 0)], first, last)
    r = rec[start + ref - first]
    area = r[:, 8]
    x, y, w, h = r[:, 4], r[:, 5], r[:, 6], r[:, 7]
    a, b = con.picture or (0, hs)   # a camera's text strip is the picture's edge
    border = (x <= 0) | (y <= a) | (x + w >= ws) | (y + h >= b)
    hole = r[:, 9] == 0
    return Candidates(con.to_full(r[:, 2:4]), area * s * s, np.column_stack([w, h]) * s, count, peak,
                      border, hole, ts[ref], first, ts[first], rec[start, 8] * s * s, rec[start, 6:8] * s, noise)




# ------------------------------------------------------------------------------------------ hot pixels
#: the eight neighbours (row, column offsets), and for each direction the two of them along it
_NEIGHBOURS = np.array([(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)])
_ALONG = [(3, 4), (1, 6), (0, 7), (2, 5)]


def _off_median(img: np.ndarray, med: np.ndarray, sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns of the pixels more than 8 σ off their 3 × 3 median, and of every pixel of the image's
    border (whose median counts it more than once): the only pixels that can stand out of their neighbours
    (a pixel above all eight is above its median, one of them)."""
    off = cv2.compare(cv2.absdiff(img, med), 8 * sigma, cv2.CMP_GT)
    off[[0, -1], :], off[:, [0, -1]] = 255, 255
    return sparse_nonzero(off)


def sparse_nonzero(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns of the nonzero bytes of a ``uint8`` ``mask`` (few of them), in row-major order, as
    ``cv2.findNonZero`` gives them: the mask read eight bytes at a time, only the words that hold one looked into
    (2 ms on a 2048² image with 8000 of them; ``findNonZero`` took 6)."""
    flat = np.ascontiguousarray(mask).reshape(-1)
    n8 = len(flat) // 8 * 8
    words = np.flatnonzero(flat[:n8].view(np.uint64))
    idx = (words[:, None] * 8 + np.arange(8)).ravel()
    idx = np.concatenate([idx[flat[idx] != 0], n8 + np.flatnonzero(flat[n8:])])
    ys, xs = np.divmod(idx, mask.shape[1])
    return ys.astype(int), xs.astype(int)


def _neighbours(img: np.ndarray, ys: np.ndarray, xs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The eight neighbours ``(8, n)`` of pixels ``ys, xs`` (as float) and which of them are inside the image
    (neighbours first: the reductions over them then run along the pixels, which is several times faster)."""
    y, x = ys[None, :] + _NEIGHBOURS[:, :1], xs[None, :] + _NEIGHBOURS[:, 1:]
    h, w = img.shape
    inside = (y >= 0) & (y < h) & (x >= 0) & (x < w)
    return img[np.clip(y, 0, h - 1), np.clip(x, 0, w - 1)].astype(np.float64), inside


def _stand_out(v: np.ndarray, nb: np.ndarray, inside: np.ndarray, sigma: float) -> np.ndarray:
    """Which pixels of values ``v`` ``(n,)`` exceed all their neighbours ``nb`` ``(8, n)`` (those ``inside`` the
    image) by more than 8 noise σ and by more than the neighbours' own range, or fall below them so."""
    hi, lo = np.where(inside, nb, -np.inf).max(axis=0), np.where(inside, nb, np.inf).min(axis=0)
    up, down, span = v - hi, lo - v, hi - lo
    return ((up > 8 * sigma) & (up > span)) | ((down > 8 * sigma) & (down > span))


def _hot_pairs(v: np.ndarray, nb: np.ndarray, inside: np.ndarray, sign: np.ndarray, sigma: float) -> np.ndarray:
    """Which pixels of values ``v`` (more than 8 σ off their 3 × 3 median, on the side ``sign``: +1 above, −1
    below) are of adjacent hot (dead) pairs: they exceed (fall below) their neighbours ``nb`` ``(8, n)`` but the
    two along one direction by more than 8 σ and by more than those neighbours' range."""
    hit = np.zeros(len(v), bool)
    signed = nb * sign[None, :]
    for pair in _ALONG:
        rest = np.delete(signed, pair, axis=0)
        ok = np.delete(inside, pair, axis=0)
        top, bottom = np.where(ok, rest, -np.inf).max(axis=0), np.where(ok, rest, np.inf).min(axis=0)
        up = v * sign - top
        hit |= (up > 8 * sigma) & (up > top - bottom) & ok.all(axis=0)
    return hit


def hot_pixel_flags(img: np.ndarray) -> np.ndarray:
    """Flat indices (sorted) of the pixels of ``img`` that stand out like a hot (or dead) pixel, inside the dots
    too: a pixel exceeding all eight neighbours by more than 8 noise σ and by more than their own range (dead:
    the same, below), and where the image has such pixels, adjacent pairs (:func:`_hot_pairs`). The noise σ is
    the robust spread of the image less its 3 × 3 median, over the pixels above the image's black floor (a
    dark-field image is mostly zeros, which would make it nil). Works in the image's own type, so 8- and 16-bit
    images are not converted."""
    med = cv2.medianBlur(img, 3)
    sub = med[::4, ::4]
    d, lit = img[::4, ::4].astype(np.float32) - sub, sub > sub.min()
    d = d[lit] if np.count_nonzero(lit) > 100 else d.ravel()
    sigma = 1.4826 * mad(d, integers=img.dtype != np.float32) + 1e-6
    if img.dtype != np.float32:
        sigma = max(sigma, 1.0)                  # at least one grey level
    ys, xs = _off_median(img, med, sigma)
    nb, inside = _neighbours(img, ys, xs)
    v = img[ys, xs].astype(np.float64)
    hot = _stand_out(v, nb, inside, sigma)
    if hot.any():
        hot |= _hot_pairs(v, nb, inside, np.sign(v - med[ys, xs].astype(np.float64)), sigma)
    return np.sort(ys[hot].astype(np.int64) * img.shape[1] + xs[hot])


def hot_images_needed(images: int) -> int:
    """In how many of a camera's ``images`` a pixel must stand out to be the camera's hot pixel: at least
    :data:`HOT_SHARE` of them, and two."""
    return max(2, int(np.ceil(HOT_SHARE * images)))


def camera_hot_pixels(flagged: list[np.ndarray], shape: tuple[int, int]) -> np.ndarray:
    """A camera's hot pixels, a boolean mask of its images' ``shape`` ``(h, w)``: the pixels :func:`hot_pixel_flags`
    flags (``flagged``: each image's flat indices, row × w + column) in :func:`hot_images_needed` of its images.
    A hot pixel is the sensor's and stands out in every image but where a dot's edge hides it; a
    dot's texture moves with the plate. Inside a dot a hot pixel and the dot's texture look alike in one image
    (:func:`clean_hot_pixels` leaves both there), the camera's other images tell them apart. Not where the
    plate stays put in three quarters of the images (repeated exposures, a Z stack whose dots do not move in the image):
    its dots' texture then stands out in the same places too and is replaced as the camera's."""
    mask = np.zeros(shape, bool)
    if len(flagged) < 2:
        return mask
    u, count = np.unique(np.concatenate(flagged), return_counts=True)
    mask.flat[u[count >= hot_images_needed(len(flagged))]] = True
    return mask


def clean_hot_pixels(img: np.ndarray, dot_radius_px: float, dots: np.ndarray | None = None,
                     camera: np.ndarray | None = None) -> tuple[np.ndarray, int]:
    """The image with hot (and dead) pixels replaced by the median of their 5 × 5 neighbourhood, and how many.

    The pixels :func:`hot_pixel_flags` flags, except those inside the ``dots`` (first centres ``(n, 2)`` [px], radius
    ``dot_radius_px``), and the ``camera``'s known hot pixels (a mask of the image's shape,
    :func:`camera_hot_pixels`) wherever they are. In one image a pixel inside a dot is left alone: the texture of a real dot is not a hot
    pixel (the PIV Challenge's case E: several hundred pixels inside its dots stand out so in each image), and
    the centre estimators see past most specks on a dot. Only for dots of radius ≥ 2.5 px, whose own peak never
    stands out of its neighbours like that."""
    if camera is not None and np.shape(camera) != img.shape:
        raise SlmlabError(f"the camera's hot-pixel mask has shape {np.shape(camera)} but the image {img.shape}; take "
                          "the mask (camera_hot_pixels) from images of this camera")
    if dot_radius_px < 2.5:
        return img, 0
    flat = hot_pixel_flags(img)
    h, w = img.shape
    ys, xs = np.divmod(flat, w)
    if dots is not None and len(dots) and len(flat):  # outside every dot: farther than its radius from its integer centre
        d, _ = cKDTree(np.rint(dots)).query(np.column_stack([xs, ys]))
        flat = flat[d > np.ceil(dot_radius_px)]
    if camera is not None:
        flat = np.union1d(flat, np.flatnonzero(camera))
    if len(flat) == 0:
        return img, 0
    ys, xs = np.divmod(flat, w)
    out = img.copy()                           # the 5 × 5 median (a pair's partner does not pull it)
    o = np.arange(-2, 3)
    win = img[np.clip(ys[:, None, None] + o[None, :, None], 0, h - 1), np.clip(xs[:, None, None] + o[None, None, :], 0, w - 1)]
    out[ys, xs] = np.median(win.reshape(len(ys), -1), axis=1).astype(img.dtype)
    return out, len(ys)


# ------------------------------------------------------------------------------------------ local search
def _box_means(p: np.ndarray, k: int) -> np.ndarray:
    """Means of patches ``p`` ``(n, S, S)`` over boxes of side ``2k + 1``, at the ``S − 2k`` positions where
    the box fits (integral images)."""
    cs = np.pad(p.cumsum(1).cumsum(2), ((0, 0), (1, 0), (1, 0)))
    w, n = 2 * k + 1, p.shape[1] - 2 * k
    return (cs[:, w:, w:] - cs[:, :n, w:] - cs[:, w:, :n] + cs[:, :n, :n]) / w ** 2


def _local_peaks(con: Contrast, at: np.ndarray, tol: np.ndarray, radius: float, spacing: float | np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Dot evidence near image points ``at`` ``(m, 2)`` [px], each on its own local background.

    Around each point a square reaching a dot's diameter and 4 px beyond the search window, but not to the
    next dot along the image's axes (``spacing``: the distance to the nearest dot, ``(m,)`` or one for all
    [px]; the square's side from their median), is taken from the reduced, smoothed image; its background
    (:func:`_less_background`, outside the search window and the dot) is subtracted; the rest is averaged over a
    box of the dot's size (a matched filter). Returns the filter's highest value within ``tol`` [px] of each
    point [grey levels], its significance (over the robust spread of the filter on the square beyond the dot, and
    short of the nearest dots where that leaves a quarter of it: the square's corners reach a lattice's diagonal
    neighbours, whose light, read as spread, took a two-level plate's plain corner dots on a stereo-PIV rig's
    oblique view to 2-3 of it) and where it is [px]."""
    r = con.scale
    rd, tr = radius / r, np.asarray(tol, float) / r
    apart = np.broadcast_to(np.asarray(spacing, float), (len(at),)) / r
    inner = int(np.ceil(rd + 3 + tr.max()))                      # the search window and the dot
    half = max(min(int(np.median(apart) - rd - 1), inner + int(np.ceil(rd)) + 4), inner)
    p, base = gather_patches(con.signed, con.to_reduced(at), half)
    off = np.arange(-half, half + 1, dtype=np.float32)
    oy, ox = np.meshgrid(off, off, indexing="ij")
    res = _less_background(p, ox, oy, inner)        # the dot, wherever the prediction's error puts it
    k = max(1, int(round(0.8 * rd)))
    box = _box_means(res, k)
    o2 = off[k:len(off) - k]
    dy, dx = np.meshgrid(o2, o2, indexing="ij")
    pr = con.to_reduced(at)
    ex, ey = (base[:, 0] - pr[:, 0])[:, None, None] + dx, (base[:, 1] - pr[:, 1])[:, None, None] + dy
    d = np.hypot(dx, dy)
    ring2 = d > rd + 1 + k
    if ring2.sum() < 8:
        ring2 = d >= np.sort(d.ravel())[-8]
    # short of the nearest dots (their disk and the box's reach along a diagonal), where that leaves a quarter
    short = ring2[None] & (d[None] < (apart - rd - 1 - k * np.sqrt(2))[:, None, None])
    enough = short.sum(axis=(1, 2)) >= 0.25 * ring2.sum()
    ring2 = np.where(enough[:, None, None], short, ring2[None]).reshape(len(at), -1)
    flat_box = box.reshape(len(at), -1)
    centre = masked_median(flat_box, ring2, 1)
    spread = 1.4826 * masked_median(np.abs(flat_box - centre[:, None]), ring2, 1) + 1e-6
    flat = np.where(np.hypot(ex, ey) <= tr[:, None, None], box, -np.inf).reshape(len(at), -1)
    j = np.argmax(flat, axis=1)
    peak = flat[np.arange(len(at)), j]
    jy, jx = np.divmod(j, len(o2))
    where = np.column_stack([base[:, 0] + o2[jx], base[:, 1] + o2[jy]]).astype(float)
    return peak, peak / spread, con.to_full(where)


def _less_background(p: np.ndarray, ox: np.ndarray, oy: np.ndarray, band: float) -> np.ndarray:
    """Patches ``(n, S, S)`` less their local background: each column's mean over the rows farther than
    ``band`` from the middle (above and below a dot: a vertical window streak or a gradient across the
    columns goes, a gradient along them cancels), or, with fewer than two such rows on each side, a plane
    fitted outside a disk of radius ``band`` and then each column's median of what is left over all its rows
    (a streak goes, and the dot, less than half of any column, does not pull it far; a plane alone left a
    streak beside the dot as spread and lost the dots along it)."""
    rows = np.abs(oy[:, 0]) > band
    if rows.sum() >= 4:
        return p - p[:, rows, :].mean(axis=1, keepdims=True)
    ring = np.hypot(ox, oy) > band
    design = np.column_stack([np.ones(int(ring.sum())), ox[ring], oy[ring]])
    coef = p[:, ring] @ np.linalg.pinv(design).T.astype(np.float32)
    res = p - (coef[:, 0, None, None] + coef[:, 1, None, None] * ox + coef[:, 2, None, None] * oy)
    return res - np.median(res, axis=1, keepdims=True)


def _flat_disks(con: Contrast, at: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Reduced-image patches around points ``at`` [px], less their background outside the dot (radius
    ``radius`` [px] plus 1.5 reduced px: :func:`_less_background`), and the mask of the dot's disk (plus 2
    reduced px)."""
    rd = radius / con.scale
    half = int(np.ceil(rd + 4))
    p, _ = gather_patches(con.signed, con.to_reduced(at), half)
    off = np.arange(-half, half + 1, dtype=np.float32)
    oy, ox = np.meshgrid(off, off, indexing="ij")
    return _less_background(p, ox, oy, rd + 1.5), np.hypot(ox, oy) <= rd + 2


def _template_match(con: Contrast, at: np.ndarray, dots: np.ndarray, radius: float) -> np.ndarray:
    """Normalised cross-correlation [-1, 1] of the flat-fielded disk around each point ``at`` with the
    mean of those around the found ``dots`` (a template of the plate's own dots, blur and all)."""
    ref, disk = _flat_disks(con, dots, radius)
    t = ref.mean(axis=0)[disk]
    t = (t - t.mean()) / (np.linalg.norm(t - t.mean()) + 1e-12)
    p, _ = _flat_disks(con, at, radius)
    p = p[:, disk]
    p = p - p.mean(axis=1, keepdims=True)
    return (p @ t) / (np.linalg.norm(p, axis=1) + 1e-12)


def search_missing(con: Contrast, predicted: np.ndarray, tol: np.ndarray, dots: np.ndarray, radius: float,
                   spacing: float | np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Look for dots at ``predicted`` image positions ``(m, 2)`` [px] (module docstring, step 4) by
    :func:`_local_peaks`: a dot is there if the matched filter's peak within ``tol`` [px] is at least
    :data:`SEARCH_SIGMA` times its local spread, a fifth of the median peak of the found ``dots`` ``(n, 2)`` [px]
    measured the same way, not on the window's rim (a slope, not a dot), and correlated with the found dots'
    mean appearance by at least :data:`NCC_MIN` (:func:`_template_match`); or, if at least :data:`STRONG_SIGMA`
    times its local spread and :data:`STRONG_SHARE` of that median peak, correlated by :data:`NCC_STRONG`.
    ``spacing``: the distance from each predicted position to its nearest neighbour on the lattice, ``(m,)`` or
    one for all [px]. Returns found mask, positions [px] and significance."""
    if len(predicted) == 0:
        return np.empty(0, bool), np.empty((0, 2)), np.empty(0)
    ref_at = dots[np.linspace(0, len(dots) - 1, min(len(dots), 16)).astype(int)]
    ref, _, _ = _local_peaks(con, ref_at, np.full(len(ref_at), float(con.scale)), radius, np.median(spacing))
    peak, sig, where = _local_peaks(con, predicted, tol, radius, spacing)
    inner = np.hypot(*(where - predicted).T) < np.maximum(np.asarray(tol) - con.scale, 0.5 * con.scale)
    typical = float(np.median(ref))
    plain = (sig >= SEARCH_SIGMA) & (peak >= 0.2 * typical)
    ok = (plain | ((sig >= STRONG_SIGMA) & (peak >= STRONG_SHARE * typical))) & inner
    if ok.any():   # and it looks like the plate's dots (a template of them), not a streak or a glyph
        ok[ok] = _template_match(con, where[ok], ref_at, radius) >= np.where(plain[ok], NCC_MIN, NCC_STRONG)
    return ok, where, sig


