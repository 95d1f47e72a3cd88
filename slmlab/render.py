"""Rendering stereo images of the calibration plates (METHOD.md §7, images; DATA_FORMAT.md ``images/``).

Each dot is a disk on the plate. Its image is found with the *same* projection and distortion as points
mode: the centre maps to :meth:`Microscope.project_view` of the dot centre, and the disk to the ellipse given
by the projection's local Jacobian there (distortion varies by less than 0.002 px across a dot, so the local
affine map is exact to well below the centroid noise, and the rendered dot is point-symmetric about the
``truth.csv`` centre). The image is then formed as a camera would:

1. **area coverage** of each pixel by the ellipse (anti-aliased by integrating the pixel's box against the
   locally straight edge, not by point sampling);
2. **defocus**: convolution with a pillbox of radius ``|z|·NA`` (geometric blur) and a Gaussian of
   σ = 0.21 λ/NA (diffraction), per dot;
3. illumination with **vignetting**, dark dots on a bright plate;
4. **shot noise** (Gaussian with the Poisson variance), **read noise**, **8-bit quantisation**.

Every image draws from its own random stream keyed by (seed, sequence, position, view), so any subset of a
set renders to the same bytes.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np

from .errors import SlmlabError
from .io import CalibrationSet, atomic_write_bytes
from .microscope import Microscope, Plate, from_dict

__all__ = ["dot_footprints", "render_view", "render_pair", "render_set", "render_plate", "image_name", "write_png",
           "expose"]


def image_name(sequence: str, position: int, side: str) -> str:
    """File name of one image in ``images/`` (DATA_FORMAT.md)."""
    return f"{sequence}_{position:03d}_{side}.png"


def dot_footprints(microscope: Microscope, points_mm: np.ndarray, plate: Plate, side: str,
                   h_mm: float = 1e-4) -> tuple[np.ndarray, np.ndarray]:
    """Image centres ``(n, 2)`` [px] and local Jacobians ``(n, 2, 2)`` [px/mm] of the plate plane at dots.

    The Jacobian maps a displacement in the plate plane (plate x, y axes, mm) to image pixels.
    """
    r = plate.orientation()
    c = microscope.project_view(points_mm, side)
    ex = microscope.project_view(points_mm + h_mm * r[:, 0], side)
    ey = microscope.project_view(points_mm + h_mm * r[:, 1], side)
    jac = np.stack([(ex - c) / h_mm, (ey - c) / h_mm], axis=2)
    return c, jac


@lru_cache(maxsize=256)
def _psf(radius_px_q: int, sigma_px_q: int) -> np.ndarray:
    """Defocus PSF: anti-aliased pillbox of radius ``radius/20`` px convolved with a Gaussian of σ ``sigma/20``
    px, normalised to unit sum (cached by quantised radius)."""
    radius, sigma = radius_px_q / 20.0, sigma_px_q / 20.0
    half = int(np.ceil(radius + 4 * sigma + 1))
    y, x = np.mgrid[-half:half + 1, -half:half + 1].astype(float)
    if radius > 0.5:
        k = np.clip(radius + 0.5 - np.hypot(x, y), 0.0, 1.0)
    else:
        k = np.zeros_like(x)
        k[half, half] = 1.0
    if sigma > 0:
        g = np.exp(-0.5 * (np.arange(-half, half + 1) / sigma) ** 2)
        k = cv2.sepFilter2D(k, cv2.CV_64F, g / g.sum(), g / g.sum(), borderType=cv2.BORDER_CONSTANT)
    return (k / k.sum()).astype(np.float32)


def _coverage(centres: np.ndarray, jac_px: np.ndarray, half: int) -> tuple[np.ndarray, np.ndarray]:
    """Area coverage of square patches by the ellipses ``centre + jac_px · unit disk`` (vectorised over dots).

    ``jac_px`` ``(n, 2, 2)`` maps the unit disk to pixels. Returns the patches ``(n, S, S)`` and their
    top-left pixels ``(n, 2)`` (column, row).
    """
    top_left = np.floor(centres).astype(int) - half
    size = 2 * half + 2
    grid = np.arange(size, dtype=float)
    dx = (top_left[:, 0] - centres[:, 0])[:, None, None] + grid[None, None, :]
    dy = (top_left[:, 1] - centres[:, 1])[:, None, None] + grid[None, :, None]
    inv = np.linalg.inv(jac_px)[:, :, :, None, None]
    u = inv[:, 0, 0] * dx + inv[:, 0, 1] * dy
    v = inv[:, 1, 0] * dx + inv[:, 1, 1] * dy
    r = np.hypot(u, v)
    rs = np.maximum(r, 1e-9)
    # |grad r| in pixel units: r is the norm of A^-1 (p - c); grad = A^-T (u, v) / r
    gx = (inv[:, 0, 0] * u + inv[:, 1, 0] * v) / rs
    gy = (inv[:, 0, 1] * u + inv[:, 1, 1] * v) / rs
    dist = (r - 1.0) / np.maximum(np.hypot(gx, gy), 1e-12)  # signed distance to the edge [px]
    return np.clip(0.5 - dist, 0.0, 1.0).astype(np.float32), top_left


def render_view(microscope: Microscope, points_mm: np.ndarray, plate: Plate, side: str,
                rng: np.random.Generator) -> np.ndarray:
    """One 8-bit image (``height × width``) of the plate's dots at microscope-frame positions ``points_mm``."""
    o, im = microscope.optics, microscope.imaging
    width, height = o.image_size_px
    centres, jac = dot_footprints(microscope, points_mm, plate, side)
    rho = plate.dot_diameter_mm / 2
    blur, sigma = im.blur_px(points_mm[:, 2], o.pixel_mm)
    dots = np.zeros((height, width), np.float32)
    jp = jac * rho
    extent = np.linalg.norm(jp, 2, axis=(1, 2)) + 2
    inside = ((centres > -extent[:, None] - blur[:, None] - 4 * sigma).all(axis=1)
              & (centres[:, 0] < width + extent + blur + 4 * sigma) & (centres[:, 1] < height + extent + blur + 4 * sigma))
    if inside.any():
        cov, top_left = _coverage(centres[inside], jp[inside], int(np.ceil(extent[inside].max())))
        for patch0, (x0, y0), b in zip(cov, top_left, blur[inside]):
            k = _psf(int(round(b * 20)), int(round(sigma * 20)))
            pad = k.shape[0] // 2
            patch = cv2.filter2D(cv2.copyMakeBorder(patch0, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=0),
                                 -1, k, borderType=cv2.BORDER_CONSTANT)
            x0, y0 = x0 - pad, y0 - pad
            xa, ya = max(x0, 0), max(y0, 0)
            xb, yb = min(x0 + patch.shape[1], width), min(y0 + patch.shape[0], height)
            if xa < xb and ya < yb:
                dots[ya:yb, xa:xb] += patch[ya - y0:yb - y0, xa - x0:xb - x0]
    np.minimum(dots, 1.0, out=dots)
    reflectance = 1.0 - np.float32(1.0 - im.dot_dn / im.background_dn) * dots
    return expose(reflectance, im, rng)


def expose(reflectance: np.ndarray, imaging, rng: np.random.Generator) -> np.ndarray:
    """8-bit image of a scene's relative reflectance (1: the bright background) [-]: illumination with
    vignetting, shot noise (Gaussian with the Poisson variance), read noise, quantisation."""
    height, width = reflectance.shape
    gain = imaging.full_well_e / 255.0  # e- per DN
    signal = _illumination(width, height, imaging.vignetting) * np.float32(imaging.background_dn * gain)
    signal = signal * reflectance.astype(np.float32, copy=False)
    noise = rng.standard_normal((height, width), dtype=np.float32)
    signal += noise * np.sqrt(signal + np.float32(imaging.read_noise_e ** 2))
    signal *= np.float32(1.0 / gain)
    return np.clip(np.rint(signal), 0, 255).astype(np.uint8)


@lru_cache(maxsize=4)
def _illumination(width: int, height: int, vignetting: float) -> np.ndarray:
    """Relative illumination: 1 at the centre, ``1 - vignetting`` at the corners (quadratic fall-off)."""
    x2 = ((np.arange(width, dtype=np.float32) - (width - 1) / 2) / ((width - 1) / 2)) ** 2
    y2 = ((np.arange(height, dtype=np.float32) - (height - 1) / 2) / ((height - 1) / 2)) ** 2
    out = np.float32(1.0) - np.float32(vignetting / 2) * (y2[:, None] + x2[None, :])
    out.setflags(write=False)
    return out


def render_pair(microscope: Microscope, points_mm: np.ndarray, plate: Plate, rng_left: np.random.Generator,
                rng_right: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Left and right 8-bit images of dots at microscope-frame positions ``points_mm`` [mm]."""
    return (render_view(microscope, points_mm, plate, "l", rng_left),
            render_view(microscope, points_mm, plate, "r", rng_right))


def write_png(path: str | Path, image: np.ndarray) -> None:
    """Write an 8-bit image as PNG atomically (no metadata: the bytes depend only on the pixels)."""
    ok, buf = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:  # pragma: no cover - OpenCV failure
        raise SlmlabError("could not encode the image as PNG", path)
    atomic_write_bytes(path, buf.tobytes())


def _image_rng(seed: int, sequence: str, position: int, side: str) -> np.random.Generator:
    key = [int(seed), 3, *sequence.encode("utf-8"), int(position), 0 if side == "l" else 1]
    return np.random.default_rng(key)


def render_set(cal: CalibrationSet, out_dir: str | Path, *, progress: bool | None = None,
               sequences: list[str] | None = None) -> list[Path]:
    """Render every stereo pair of a *simulated* set into ``out_dir/images/``.

    Uses the simulator's parameters, seed and stage origin stored in ``cal.meta["simulator"]`` and the true
    dot positions of ``cal.truth``, so the rendered centres are exactly those of ``truth.csv``.
    """
    from tqdm import tqdm

    sim = cal.meta.get("simulator")
    if sim is None or cal.truth is None:
        raise SlmlabError("only simulated sets (with truth.csv and meta.json's 'simulator') can be rendered", cal.path)
    microscope = from_dict(sim["microscope"])
    origin = np.asarray(sim["stage_origin_mm"])
    seed = int(sim["seed"])
    images = Path(out_dir) / "images"
    images.mkdir(parents=True, exist_ok=True)
    truth = cal.truth
    keys = truth[["sequence", "position"]].drop_duplicates()
    if sequences is not None:
        keys = keys[keys["sequence"].isin(sequences)]
    written = []
    groups = truth.groupby(["sequence", "position"], sort=False).indices
    for seq, pos in tqdm(list(keys.itertuples(index=False, name=None)), desc="rendering stereo pairs",
                         unit="pair", disable=None if progress is None else not progress):
        rows = truth.iloc[groups[(seq, pos)]]
        p = microscope.stage_to_microscope(rows[["X_mm", "Y_mm", "Z_mm"]].to_numpy(), origin)
        plate = microscope.grid_plate if seq == "grid" else microscope.moving_plate
        left, right = render_pair(microscope, p, plate, _image_rng(seed, seq, pos, "l"), _image_rng(seed, seq, pos, "r"))
        for side, img in (("l", left), ("r", right)):
            path = images / image_name(seq, int(pos), side)
            write_png(path, img)
            written.append(path)
    return written


def render_plate(microscope: Microscope, plate: Plate, centre_mm=(0.0, 0.0, 0.0), *, side: str = "l", seed: int = 0,
                 drop: list[tuple[int, int]] | None = None):
    """One image of a whole plate centred at microscope-frame ``centre_mm``, with its truth.

    Parameters
    ----------
    drop
        ``[(row, col), ...]`` dots left off the plate (missing dots).

    Returns
    -------
    image, truth
        the 8-bit image and a DataFrame ``row, col, w1, w2`` [px] of every rendered dot's true centre.
    """
    import pandas as pd

    i, j, pts = plate.nominal_points()
    keep = np.ones(len(i), bool)
    for r, c in drop or []:
        keep &= ~((i == r) & (j == c))
    p = np.asarray(centre_mm, float) + pts[keep] @ plate.orientation().T
    img = render_view(microscope, p, plate, side, np.random.default_rng(seed))
    w = microscope.project_view(p, side)
    return img, pd.DataFrame({"row": i[keep], "col": j[keep], "w1": w[:, 0], "w2": w[:, 1]})
