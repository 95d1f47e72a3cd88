"""Rendering stereo images of the calibration plates through the virtual microscope (a set's ``images/``).

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

import json
from dataclasses import asdict, dataclass, replace
from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
from tqdm import tqdm

from ..errors import SlmlabError
from ..images.boards import charuco_board
from ..images.imageset import PlateSpec
from ..io import SET_FORMAT, CalibrationSet, atomic_write_bytes, atomic_write_text, json_text, write_csv
from .microscope import Microscope, Plate, from_dict
from .rigs import rig_from_dict
from .sessions import Session, tilt_matrix
from .simulate import stage_origin

__all__ = ["dot_footprints", "footprints", "dot_coverage", "render_view", "render_pair", "render_set", "render_plate",
           "image_name", "write_png", "expose", "render_board", "board_reflectance", "render_board_set",
           "board_orientation", "Degradations", "RIG_LOOKS", "DEGRADATIONS", "rig_degradations", "expected_image",
           "noise_variance", "camera_image", "view_dots", "render_rig_view", "visible_dots", "sensor_rng", "rig_scenes",
           "truth_places_held", "check_renderable", "render_rig_set", "set_camera", "rig_views", "rendered_truth"]


def image_name(sequence: str, position: int, side: str) -> str:
    """File name of one image in ``images/``: ``{sequence}_{position:03d}_{l|r}.png`` (README, "The format")."""
    return f"{sequence}_{position:03d}_{side}.png"


def dot_footprints(microscope: Microscope, points_mm: np.ndarray, plate: Plate, side: str,
                   h_mm: float = 1e-4) -> tuple[np.ndarray, np.ndarray]:
    """Image centres ``(n, 2)`` [px] and local Jacobians ``(n, 2, 2)`` [px/mm] of the plate plane at dots.

    The Jacobian maps a displacement in the plate plane (plate x, y axes, mm) to image pixels.
    """
    return footprints(microscope, points_mm, plate.orientation(), side, h_mm)


def footprints(rig, points_mm: np.ndarray, orientation: np.ndarray, side: str, h_mm: float = 1e-4
               ) -> tuple[np.ndarray, np.ndarray]:
    """Image centres ``(n, 2)`` [px] and local Jacobians ``(n, 2, 2)`` [px/mm] in view ``side`` of any rig
    (its ``project_view``) of a plane whose ``x, y`` axes are the first two columns of ``orientation``, at
    rig-frame points ``(n, 3)`` [mm] (forward differences of ``h_mm``)."""
    r = np.asarray(orientation, float)
    c = rig.project_view(points_mm, side)
    ex = rig.project_view(points_mm + h_mm * r[:, 0], side)
    ey = rig.project_view(points_mm + h_mm * r[:, 1], side)
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


def dot_coverage(size_px: tuple[int, int], centres: np.ndarray, jac_px: np.ndarray, blur_px: np.ndarray,
                 sigma_px: float) -> np.ndarray:
    """How much of each pixel of an image of ``size_px = (width, height)`` the dots cover [0..1, float32]:
    each dot the ellipse ``centre + jac_px · unit disk`` (:func:`_coverage`), convolved with its defocus
    pillbox of radius ``blur_px`` and the diffraction Gaussian of σ ``sigma_px`` (:func:`_psf`); overlapping
    blur adds and is clipped at 1."""
    width, height = size_px
    dots = np.zeros((height, width), np.float32)
    blur, sigma = blur_px, sigma_px
    extent = np.linalg.norm(jac_px, 2, axis=(1, 2)) + 2
    inside = ((centres > -extent[:, None] - blur[:, None] - 4 * sigma).all(axis=1)
              & (centres[:, 0] < width + extent + blur + 4 * sigma) & (centres[:, 1] < height + extent + blur + 4 * sigma))
    if inside.any():
        cov, top_left = _coverage(centres[inside], jac_px[inside], int(np.ceil(extent[inside].max())))
        for patch0, (x0, y0), b in zip(cov, top_left, blur[inside]):
            _add_blurred(dots, patch0, x0, y0, b, sigma)
    np.minimum(dots, 1.0, out=dots)
    return dots


def _add_blurred(image: np.ndarray, patch0: np.ndarray, x0: int, y0: int, blur: float, sigma: float) -> None:
    """Add a coverage patch whose top-left pixel is ``(x0, y0)``, blurred by :func:`_psf`, into ``image``
    (in place; the parts outside the image are dropped)."""
    height, width = image.shape
    k = _psf(int(round(blur * 20)), int(round(sigma * 20)))
    pad = k.shape[0] // 2
    patch = cv2.filter2D(cv2.copyMakeBorder(patch0, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=0),
                         -1, k, borderType=cv2.BORDER_CONSTANT)
    x0, y0 = x0 - pad, y0 - pad
    xa, ya = max(x0, 0), max(y0, 0)
    xb, yb = min(x0 + patch.shape[1], width), min(y0 + patch.shape[0], height)
    if xa < xb and ya < yb:
        image[ya:yb, xa:xb] += patch[ya - y0:yb - y0, xa - x0:xb - x0]


def render_view(microscope: Microscope, points_mm: np.ndarray, plate: Plate, side: str,
                rng: np.random.Generator) -> np.ndarray:
    """One 8-bit image (``height × width``) of the plate's dots at microscope-frame positions ``points_mm``."""
    o, im = microscope.optics, microscope.imaging
    width, height = o.image_size_px
    centres, jac = dot_footprints(microscope, points_mm, plate, side)
    rho = plate.dot_diameter_mm / 2
    blur, sigma = im.blur_px(points_mm[:, 2], o.pixel_mm)
    dots = dot_coverage((width, height), centres, jac * rho, blur, sigma)
    reflectance = 1.0 - np.float32(1.0 - im.dot_dn / im.background_dn) * dots
    return expose(reflectance, im, rng)


def expose(reflectance: np.ndarray, imaging, rng: np.random.Generator) -> np.ndarray:
    """8-bit image of a scene's relative reflectance (1: the bright background) [-]: illumination with
    vignetting, shot noise (Gaussian with the Poisson variance), read noise, quantisation."""
    height, width = reflectance.shape
    gain = imaging.full_well_e / 255.0  # e- per DN
    signal = _illumination(width, height, imaging.vignetting) * np.float32(imaging.background_dn * gain)
    signal *= reflectance.astype(np.float32, copy=False)   # in place: the same operations, the same bits
    noise = rng.standard_normal((height, width), dtype=np.float32)
    spread = signal + np.float32(imaging.read_noise_e ** 2)
    noise *= np.sqrt(spread, out=spread)
    signal += noise
    signal *= np.float32(1.0 / gain)
    np.clip(np.rint(signal, out=signal), 0, 255, out=signal)
    return signal.astype(np.uint8)


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


def write_png(path: str | Path, image: np.ndarray, *, compress: bool = True) -> None:
    """Write an 8-bit image as PNG atomically (no metadata: the bytes depend only on the pixels). Run-length
    deflate on the horizontal-difference filter: a third of the time of zlib's level 1 on a noisy 2048 px image
    (26 against 77 ms), the files a little smaller. Without ``compress`` (an image written to be read back at
    once, in a temporary folder) stored unfiltered and uncompressed: twice the size, a tenth of the time to
    write and to read (2.6 and 2.3 ms against 24 and 16 ms on a noisy 1696 × 1730 image), the same pixels."""
    params = ([cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_RLE, cv2.IMWRITE_PNG_FILTER,
               cv2.IMWRITE_PNG_FILTER_SUB] if compress else
              [cv2.IMWRITE_PNG_COMPRESSION, 0, cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_NONE])
    ok, buf = cv2.imencode(".png", image, params)
    if not ok:  # pragma: no cover - OpenCV failure
        raise SlmlabError("could not encode the image as PNG", path)
    atomic_write_bytes(path, buf.tobytes())


def _image_rng(seed: int, sequence: str, position: int, side: str) -> np.random.Generator:
    key = [int(seed), 3, *sequence.encode("utf-8"), int(position), 0 if side == "l" else 1]
    return np.random.default_rng(key)


def render_set(cal: CalibrationSet, out_dir: str | Path, *, progress: bool | None = None,
               sequences: list[str] | None = None, compress: bool = True) -> list[Path]:
    """Render every stereo pair of a *simulated* set into ``out_dir/images/``.

    Uses the simulator's parameters, seed and stage origin stored in ``cal.meta["simulator"]`` and the true
    dot positions of ``cal.truth``, so the rendered centres are exactly those of ``truth.csv``. A set simulated
    on a zoo rig is rendered by its cameras (:func:`render_rig_set`, every sequence). ``compress``:
    :func:`write_png`'s (off for a set written only to be read back at once).
    """
    sim = cal.meta.get("simulator")
    if sim is None or cal.truth is None:
        raise SlmlabError("only simulated sets (with truth.csv and meta.json's 'simulator') can be rendered", cal.path)
    if "rig" in sim["microscope"]:
        return render_rig_set(cal, out_dir, progress=progress, compress=compress)
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
            write_png(path, img, compress=compress)
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
    i, j, pts = plate.nominal_points()
    keep = np.ones(len(i), bool)
    for r, c in drop or []:
        keep &= ~((i == r) & (j == c))
    p = np.asarray(centre_mm, float) + pts[keep] @ plate.orientation().T
    img = render_view(microscope, p, plate, side, np.random.default_rng(seed))
    w = microscope.project_view(p, side)
    return img, pd.DataFrame({"row": i[keep], "col": j[keep], "w1": w[:, 0], "w2": w[:, 1]})


# ------------------------------------------------------------------------------------------------ boards
def _plate_points_of_pixels(microscope: Microscope, centre_mm, orientation, side: str, step_px: int = 8,
                            iterations: int = 6):
    """Plate-frame coordinates ``(x, y)`` [mm] of a coarse grid of image pixels (every ``step_px``) of view
    ``side``: where each pixel's ray meets the plate plane, by Newton on :meth:`Microscope.project_view`."""
    width, height = microscope.image_size_px
    us, vs = np.arange(0, width + step_px, step_px, dtype=float), np.arange(0, height + step_px, step_px, dtype=float)
    u, v = np.meshgrid(us, vs)
    target = np.column_stack([u.ravel(), v.ravel()])
    c, r = np.asarray(centre_mm, float), np.asarray(orientation, float)

    def proj(xy):
        return microscope.project_view(c + xy[:, :1] * r[:, 0] + xy[:, 1:2] * r[:, 1], side)

    h = 1e-4
    p0 = proj(np.zeros((1, 2)))
    jac = np.column_stack([(proj(np.array([[h, 0.0]])) - p0)[0] / h, (proj(np.array([[0.0, h]])) - p0)[0] / h])
    xy = (target - p0) @ np.linalg.inv(jac).T
    for _ in range(iterations):
        f = proj(xy)
        j1, j2 = (proj(xy + [h, 0.0]) - f) / h, (proj(xy + [0.0, h]) - f) / h
        det = j1[:, 0] * j2[:, 1] - j1[:, 1] * j2[:, 0]
        d = target - f
        xy = xy + np.column_stack([(j2[:, 1] * d[:, 0] - j2[:, 0] * d[:, 1]) / det,
                                   (-j1[:, 1] * d[:, 0] + j1[:, 0] * d[:, 1]) / det])
    return xy.reshape(len(vs), len(us), 2)


def _upsample(coarse: np.ndarray, step: int, width: int, height: int) -> np.ndarray:
    """A map known on nodes every ``step`` px (node ``k`` at pixel ``k·step``), at every pixel, by separable
    bilinear interpolation in floating point (``float32`` result)."""
    def weights(n):
        s = np.arange(n) / step
        i0 = np.minimum(np.floor(s).astype(int), coarse.shape[0 if n == height else 1] - 2)
        return i0, (s - i0)[None, :]
    i0, fx = weights(width)
    rows = coarse[:, i0] * (1 - fx) + coarse[:, i0 + 1] * fx               # (rows of nodes, width)
    j0, fy = weights(height)
    out = rows[j0]                          # in place: the same operations, the same bits
    out *= 1 - fy.T
    below = rows[j0 + 1]
    below *= fy.T
    out += below
    return out.astype(np.float32)


def render_board(microscope: Microscope, texture: np.ndarray, texture_px_per_mm: float, board_size_mm,
                 centre_mm, orientation, side: str, rng: np.random.Generator) -> np.ndarray:
    """One 8-bit image of a printed planar target (a ChArUco board, ...) through the virtual microscope.

    ``texture`` is the target's reflectance image (8-bit, white = 255), ``texture_px_per_mm`` its sampling,
    ``board_size_mm`` its ``(width, height)``; the target's centre sits at microscope-frame ``centre_mm``
    with its ``x`` (along the texture's rows) and ``y`` (up the texture) axes along the columns of
    ``orientation``. Each image pixel's ray is traced to the target plane (the same projection and
    distortion as the dots, inverted by Newton on a coarse grid and interpolated), the texture is
    area-integrated over the pixel's footprint, blurred by the defocus at the target's centre (pillbox and
    diffraction Gaussian, as the dots) and exposed with vignetting, shot and read noise (:func:`expose`)."""
    o, im = microscope.optics, microscope.imaging
    footprint = max(int(round(texture_px_per_mm * o.pixel_mm)), 1)   # texture px per image px
    blur, sigma = im.blur_px(np.array([centre_mm[2]]), o.pixel_mm)
    refl = board_reflectance(microscope, texture, texture_px_per_mm, board_size_mm, centre_mm, orientation, side,
                             footprint, float(blur[0]), sigma)
    dark = im.dot_dn / im.background_dn
    return expose(dark + (1.0 - dark) * refl, im, rng)


def board_reflectance(rig, texture: np.ndarray, texture_px_per_mm: float, board_size_mm, centre_mm, orientation,
                      side: str, footprint_px: int, blur_px: float, sigma_px: float) -> np.ndarray:
    """The reflectance [0..1, float32] each image pixel of view ``side`` of any rig sees of a printed target
    (:func:`render_board`): rays traced to the target plane, the texture area-integrated over
    ``footprint_px`` texture pixels per image pixel, blurred by the defocus ``blur_px`` and ``sigma_px``."""
    width, height = rig.image_size_px
    step = 8
    xy = _plate_points_of_pixels(rig, centre_mm, orientation, side, step)
    bw, bh = board_size_mm
    tx = (xy[..., 0] + bw / 2) * texture_px_per_mm - 0.5        # texture columns (pixel centres at integers)
    ty = (bh / 2 - xy[..., 1]) * texture_px_per_mm - 0.5        # texture rows (y up the board, rows down)
    mx, my = _upsample(tx, step, width, height), _upsample(ty, step, width, height)
    tex = cv2.blur(texture.astype(np.float32) / 255.0, (footprint_px, footprint_px)) if footprint_px > 1 else \
        texture.astype(np.float32) / 255.0
    refl = cv2.remap(tex, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=1.0)
    k = _psf(int(round(blur_px * 20)), int(round(sigma_px * 20)))
    return cv2.filter2D(refl, -1, k, borderType=cv2.BORDER_REPLICATE)


def board_orientation(microscope: Microscope, tilt_deg=(0.0, 0.0)) -> np.ndarray:
    """The 3 × 3 rotation (plate frame to microscope frame, columns: the board's x, y axes and its normal) of a
    printed board laid so that the left camera reads it the right way round. The virtual microscope's image
    is a mirror image of the focal plane (its inverted optics, as the paper's ``EX`` and ``EY``, both
    negative, imply), which a dot plate never shows but an ArUco code does: where the view is mirrored the
    board's y axis is turned over."""
    r = tilt_matrix(*tilt_deg)
    p0 = microscope.project_view(np.zeros((1, 3)), "l")[0]
    j = np.column_stack([microscope.project_view(1e-3 * r[:, k][None, :], "l")[0] - p0 for k in (0, 1)])
    # image w2 points down: a view that is not mirrored has a negative Jacobian determinant
    return r @ np.diag([1.0, -1.0, -1.0]) if np.linalg.det(j) > 0 else r


def render_board_set(out_dir: str | Path, microscope: Microscope, board: dict, stage_z_mm, *, seed: int = 0,
                     tilt_deg=(0.0, 0.0), texture_px_per_mm: float = 1000.0) -> Path:
    """A Z stack of a ChArUco board through the virtual microscope, written as a set to extract: PNG pairs in
    ``images/``, ``stage.csv`` naming them, ``meta.json`` (``pattern: charuco``) and ``truth.csv`` (every
    corner's true image centres and its stage-frame position, as a simulated set's ``truth.csv``).

    ``board``: ``squares [x, y]``, ``square_mm``, ``marker_mm``, ``dictionary``, ``legacy`` (OpenCV's). The
    board's centre is at the middle of the field, in focus, at stage zero; each position moves the stage
    along Z (the paper preset's stage, with its axes and errors)."""
    out = Path(out_dir)
    (out / "images").mkdir(parents=True, exist_ok=True)
    spec = PlateSpec("moving", None, None, float(board["square_mm"]), pattern="charuco",
                     board={k: board[k] for k in ("squares", "marker_mm", "dictionary", "legacy") if k in board})
    cb = charuco_board(spec)
    sx, sy = (int(v) for v in board["squares"])
    size_mm = (sx * spec.pitch_mm, sy * spec.pitch_mm)
    texture = cb.generateImage((int(round(size_mm[0] * texture_px_per_mm)), int(round(size_mm[1] * texture_px_per_mm))),
                               marginSize=0)
    corners = np.asarray(cb.getChessboardCorners(), float)          # OpenCV: x right, y down, from the corner
    plate_xy = np.column_stack([corners[:, 0] - size_mm[0] / 2, size_mm[1] / 2 - corners[:, 1]])
    orient = board_orientation(microscope, tilt_deg)
    z = np.asarray(stage_z_mm, float)
    commanded = np.column_stack([np.zeros_like(z), np.zeros_like(z), z])
    origin = stage_origin(microscope, Session(positions=(0, 0, 0), grid=False))
    rng_stage = np.random.default_rng([seed, 21])
    actual = microscope.stage.actual(commanded, rng_stage)
    rows = ["sequence,position,stage_x_mm,stage_y_mm,stage_z_mm,left_image,right_image"]
    truth = []
    per_row = sx - 1
    for k, (cmd, act) in enumerate(zip(commanded, actual), 1):
        centre = microscope.stage_to_microscope(act[None, :], origin)[0]
        pts = centre + np.column_stack([plate_xy, np.zeros(len(plate_xy))]) @ orient.T
        w = microscope.project(pts)
        world = microscope.microscope_to_stage(pts, origin)
        ids = np.arange(len(plate_xy))
        truth.append(pd.DataFrame({"sequence": "Z", "position": k, "row": ids // per_row + 1, "col": ids % per_row + 1,
                                   "wl1": w[:, 0], "wl2": w[:, 1], "wr1": w[:, 2], "wr2": w[:, 3],
                                   "X_mm": world[:, 0], "Y_mm": world[:, 1], "Z_mm": world[:, 2]}))
        for side in "lr":
            img = render_board(microscope, texture, texture_px_per_mm, size_mm, centre, orient, side,
                               _image_rng(seed, "Z", k, side))
            write_png(out / "images" / image_name("Z", k, side), img)
        rows.append(f"Z,{k},{cmd[0]:.6f},{cmd[1]:.6f},{cmd[2]:.6f},images/{image_name('Z', k, 'l')},"
                    f"images/{image_name('Z', k, 'r')}")
    plate = {"pattern": "charuco", "pitch_mm": spec.pitch_mm, "board": spec.board}
    meta = {"format": SET_FORMAT, "image_size_px": list(microscope.optics.image_size_px), "plates": {"moving": plate},
            "source": f"slmlab virtual CMO microscope, preset {microscope.preset}: a ChArUco board Z stack, seed {seed}"}
    atomic_write_text(out / "stage.csv", "\n".join(rows) + "\n")
    atomic_write_text(out / "meta.json", json_text(meta))
    write_csv(out / "truth.csv", pd.concat(truth, ignore_index=True))
    return out


# ------------------------------------------------------------------------------------------------ any rig
@dataclass(frozen=True)
class Degradations:
    """What a real camera adds to the optics of a rig's image (:func:`render_rig_view`). The rig itself gives
    the dots' perspective (oblique ellipses) and their defocus (varying across the field and with depth:
    its ``blur_px``); these are the camera's and the set-up's.

    Attributes
    ----------
    bits
        bit depth of the image (8, 12 or 16; 12-bit images are written in 16-bit PNGs, as cameras do).
    dark
        dark dots on a bright plate (``True``) or bright dots on a dark one.
    background_dn, contrast_dn
        grey level of the plate, and how far a dot's centre is from it (darker or brighter) [DN].
    defocus_px
        extra defocus (a pillbox radius) at the image corner farthest from a line of best focus through the
        image centre, growing linearly across the field (a camera slightly out of focus or tilted) [px].
    focus_angle_deg
        direction across which that defocus grows [degree].
    read_noise_dn, shot_dn_per_e
        Gaussian read noise [DN]; gain for shot noise [DN per electron] (0: none).
    hot_pixel_fraction
        share of pixels stuck between half and full scale (the same pixels in every image of a view).
    gradient, gradient_angle_deg
        relative illumination change from one image edge to the other, and its direction [-, degree].
    vignetting
        relative illumination loss at the image corners (quadratic) [-].
    bright_region
        peak of a bright out-of-focus region (a blurred disk beside the plate, additive), in units of the
        dots' contrast [-].
    streaks
        depth of vertical window streaks (a multiplicative modulation; the same in every image of a view) [-].
    text_strip_px
        height of a camera text strip over the image's bottom rows [px].
    """

    bits: int = 8
    dark: bool = False
    background_dn: float = 13.0
    contrast_dn: float = 137.0
    defocus_px: float = 0.0
    focus_angle_deg: float = 30.0
    read_noise_dn: float = 1.0
    shot_dn_per_e: float = 0.0
    hot_pixel_fraction: float = 0.0
    gradient: float = 0.0
    gradient_angle_deg: float = 20.0
    vignetting: float = 0.0
    bright_region: float = 0.0
    streaks: float = 0.0
    text_strip_px: int = 0


#: each rig kind's camera as a lab would have it: a microscope's backlit plate with vignetting; a DIC pair's
#: printed target under uneven light; a PIV pair's bright dots through a window, with a bright region
#: beside the plate, streaks and the camera's text strip, 60-80 grey levels over 13 (the held-out rig)
RIG_LOOKS = {
    "microscope": Degradations(dark=True, background_dn=200.0, contrast_dn=160.0, read_noise_dn=1.5,
                               shot_dn_per_e=0.3, vignetting=0.3, gradient=0.1),
    "greenough": Degradations(dark=True, background_dn=200.0, contrast_dn=160.0, read_noise_dn=1.5,
                              shot_dn_per_e=0.3, vignetting=0.3, gradient=0.1),
    "stereo-dic": Degradations(dark=True, background_dn=190.0, contrast_dn=160.0, read_noise_dn=1.5,
                               shot_dn_per_e=0.3, gradient=0.3, vignetting=0.25, hot_pixel_fraction=1e-4),
    "stereo-piv": Degradations(dark=False, background_dn=13.0, contrast_dn=70.0, read_noise_dn=1.5,
                               shot_dn_per_e=0.2, gradient=0.25, vignetting=0.15, bright_region=1.6, streaks=0.1,
                               text_strip_px=36, hot_pixel_fraction=2e-4),
}
#: the degradations one at a time (changes of a clean camera of the rig's polarity), the rig's own camera
#: (``RIG_LOOKS``), and all together
DEGRADATIONS = {
    "clean": {},
    "defocus": {"defocus_px": 5.0},
    "low contrast": {"contrast_dn": 60.0, "read_noise_dn": 1.5},
    "lowest contrast": {"contrast_dn": 20.0, "read_noise_dn": 1.5},
    "noise": {"read_noise_dn": 6.0, "shot_dn_per_e": 0.5},
    "12 bit": {"bits": 12, "contrast_dn": 60.0 * 16, "read_noise_dn": 1.5 * 16},
    "16 bit": {"bits": 16, "contrast_dn": 60.0 * 256, "read_noise_dn": 1.5 * 256},
    "hot pixels": {"hot_pixel_fraction": 2e-3},
    "gradient": {"gradient": 0.8},
    "vignetting": {"vignetting": 0.6},
    "bright region": {"bright_region": 1.5},
    "streaks": {"streaks": 0.35},
    "text strip": {"text_strip_px": 40},
    "the rig's camera": None,
    "all together": {"defocus_px": 4.0, "contrast_dn": 60.0, "read_noise_dn": 2.0, "shot_dn_per_e": 0.3,
                     "hot_pixel_fraction": 1e-3, "gradient": 0.5, "vignetting": 0.4, "bright_region": 1.5,
                     "streaks": 0.3, "text_strip_px": 40},
}


def rig_degradations(kind: str, degradation: str | None = None) -> Degradations:
    """The camera of a rig ``kind`` (:data:`RIG_LOOKS`), or one of :data:`DEGRADATIONS` on a clean camera of
    that kind's polarity (plate and dot levels, bit depth, read noise 1 DN, nothing else)."""
    own = RIG_LOOKS.get(kind, RIG_LOOKS["microscope"])
    if degradation is None or degradation == "the rig's camera":
        return own
    if degradation not in DEGRADATIONS:
        raise SlmlabError(f"unknown degradation {degradation!r}; choose one of {', '.join(DEGRADATIONS)}")
    clean = Degradations(dark=own.dark, background_dn=own.background_dn, contrast_dn=150.0 - 13.0 if not own.dark
                         else own.contrast_dn)
    change = dict(DEGRADATIONS[degradation])
    if change.get("bits", 8) != 8:
        change["background_dn"] = clean.background_dn * 2 ** (change["bits"] - 8)
    return replace(clean, **change)


def _extra_defocus(centres: np.ndarray, size_px, deg: Degradations) -> np.ndarray:
    """Per-dot extra defocus radius [px] (:attr:`Degradations.defocus_px`): zero on the line of best focus
    through the image centre, growing linearly to ``defocus_px`` at the farthest image corner."""
    if not deg.defocus_px:
        return np.zeros(len(centres))
    w, h = size_px
    a = np.radians(deg.focus_angle_deg)
    n = np.array([np.cos(a), np.sin(a)])
    c0 = np.array([(w - 1) / 2, (h - 1) / 2])
    far = np.max(np.abs(np.array([[-1, -1], [-1, 1], [1, -1], [1, 1]]) * c0 @ n))
    return deg.defocus_px * np.abs((centres - c0) @ n) / far


def _streaks(w: int, h: int, depth: float, rng: np.random.Generator) -> np.ndarray:
    """Vertical window streaks ``(h, w)`` [-]: a relative modulation, a sum of narrow column bands of random
    sign, width 2..20 px and depth up to ``depth``, each fading slowly along the column."""
    x = np.arange(w, dtype=np.float32)
    y = np.arange(h, dtype=np.float32) / h
    out = np.zeros((h, w), np.float32)
    for _ in range(max(3, w // 60)):
        x0, width = rng.uniform(0, w), rng.uniform(2, 20)
        amp = depth * rng.uniform(-1, 1)
        col = np.exp(-0.5 * ((x - x0) / width) ** 2).astype(np.float32)
        fade = (1 + 0.5 * np.sin(2 * np.pi * (rng.uniform(0.3, 1.5) * y + rng.uniform(0, 1)))).astype(np.float32)
        band = np.flatnonzero(col)  # the columns the band reaches (elsewhere it adds zero: the same sum)
        lo, hi = (band[0], band[-1] + 1) if len(band) else (0, 0)
        out[:, lo:hi] += np.float32(amp) * fade[:, None] * col[None, lo:hi]
    return out


def _bright_region(w: int, h: int, dots_px: np.ndarray, amplitude_dn: float) -> np.ndarray:
    """A bright out-of-focus region ``(h, w)`` [DN]: a disk of radius 1/8 of the smaller image side, blurred
    over a third of its radius, just right of the plate's rightmost dots (over them if the plate fills the
    field), a little below their middle."""
    r = min(w, h) / 8
    right = float(dots_px[:, 0].max()) if len(dots_px) else w / 2
    cx = min(right + 0.9 * r, w - 0.3 * r)
    cy = (float(np.median(dots_px[:, 1])) if len(dots_px) else h / 2) + 0.15 * h
    k = max(1, int(r // 16))  # drawn and blurred on a grid k times coarser (the blur's σ = r/3 spans 5k px
    hs, ws = -(-h // k), -(-w // k)  # there), then resized: a full-size blur over σ ≈ 60 px took 0.5 s per image
    yy, xx = np.mgrid[0:hs, 0:ws].astype(np.float32) * np.float32(k) + np.float32((k - 1) / 2)
    disk = np.clip((np.float32(r - 0.5) - np.hypot(xx - np.float32(cx), yy - np.float32(cy))) / np.float32(k) + 0.5, 0, 1)
    blur = cv2.resize(cv2.GaussianBlur(disk, (0, 0), r / 3 / k), (ws * k, hs * k), interpolation=cv2.INTER_LINEAR)
    blur = blur[:h, :w]
    return np.float32(amplitude_dn) * blur / max(float(blur.max()), 1e-6)


def _text_strip(img: np.ndarray, height_px: int, full_dn: float) -> None:
    """A camera text strip over the bottom ``height_px`` rows (in place): a dark band with bright text."""
    h, w = img.shape
    band = np.zeros((height_px, w), np.float32)
    text = "CAM 1  2014-07-12 10:32:11.125  f/8  1/250 s  #000123  EXP 4000 us  GAIN 0 dB  FRAME 12"
    scale = height_px / 45
    cv2.putText(band, text, (8, int(height_px * 0.72)), cv2.FONT_HERSHEY_SIMPLEX, scale, float(full_dn),
                max(1, int(round(2 * scale))), cv2.LINE_AA)
    img[h - height_px:] = band


def _light(deg: Degradations, w: int, h: int, sensor: np.random.Generator, dots_px: np.ndarray):
    """The camera's noise-free light: the gain ``(h, w)`` on the scene (illumination gradient, vignetting,
    window streaks) and the additive bright region ``(h, w)`` [DN] (or ``None``); draws the streaks from
    ``sensor`` (before the hot pixels)."""
    a = np.radians(deg.gradient_angle_deg)
    x = (np.arange(w, dtype=np.float32) - (w - 1) / 2) / ((w - 1) / 2)
    y = (np.arange(h, dtype=np.float32) - (h - 1) / 2) / ((h - 1) / 2)
    gain = _illumination(w, h, deg.vignetting) + np.float32(deg.gradient / 2) * (
        np.float32(np.cos(a)) * x[None, :] + np.float32(np.sin(a)) * y[:, None])
    if deg.streaks:
        gain *= 1.0 + _streaks(w, h, deg.streaks, sensor)
    region = _bright_region(w, h, dots_px, deg.bright_region * deg.contrast_dn) if deg.bright_region else None
    return gain, region


def expected_image(coverage: np.ndarray, deg: Degradations, sensor: np.random.Generator, dots_px: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The camera's noise-free image of a dot coverage image (:func:`dot_coverage`) [DN, ``float32``, before
    clipping and quantisation]: the plate's and the dots' levels, illumination (gradient, vignetting), window
    streaks and a bright region beside the plate (``dots_px``: the dots' image centres) (:func:`_light`); the
    light's gain on the plate and dots ``(h, w)`` (the bright region adds to it); and the flat indices of the
    camera's hot pixels (or ``None``). Draws from ``sensor`` (the same in every image of
    the camera: seed it per view) what :func:`camera_image` draws, in the same order."""
    h, w = coverage.shape
    sign = -1.0 if deg.dark else 1.0
    gain, region = _light(deg, w, h, sensor, dots_px)
    hot = sensor.choice(h * w, int(deg.hot_pixel_fraction * h * w), replace=False) if deg.hot_pixel_fraction else None
    # in place, full-image arrays being the cost (the same operations, so the same bits)
    radiance = coverage * np.float32(sign * deg.contrast_dn)
    radiance += np.float32(deg.background_dn)
    radiance *= gain
    if region is not None:
        radiance += region
    return radiance, gain, hot


def noise_variance(radiance: np.ndarray, deg: Degradations) -> np.ndarray:
    """Each pixel's noise variance [DN²] in :func:`camera_image` around the noise-free ``radiance``
    (:func:`expected_image`): shot noise (the Poisson variance, ``shot_dn_per_e`` DN per electron), read noise
    and the quantisation's 1/12."""
    return deg.shot_dn_per_e * np.maximum(radiance, 0.0) + deg.read_noise_dn ** 2 + 1.0 / 12.0


def camera_image(coverage: np.ndarray, deg: Degradations, rng: np.random.Generator, sensor: np.random.Generator,
                 dots_px: np.ndarray) -> np.ndarray:
    """The camera's image (``uint8``, or ``uint16`` above 8 bits) of a dot coverage image (:func:`dot_coverage`)
    with the :class:`Degradations`: its noise-free image (:func:`expected_image`), shot and read noise, hot
    pixels, a text strip, quantisation. ``rng`` draws this image's noise; ``sensor`` what is the same in every
    image of the camera (its streaks and hot pixels: seed it per view)."""
    h, w = coverage.shape
    full = float(2 ** deg.bits - 1)
    radiance, _, hot = expected_image(coverage, deg, sensor, dots_px)
    if deg.shot_dn_per_e:
        noise = rng.standard_normal((h, w), dtype=np.float32)
        spread = np.maximum(radiance, 0)
        spread *= np.float32(deg.shot_dn_per_e)
        radiance += noise * np.sqrt(spread, out=spread)
    noise = rng.standard_normal((h, w), dtype=np.float32)
    noise *= np.float32(deg.read_noise_dn)
    radiance += noise
    if hot is not None:
        radiance.ravel()[hot] = sensor.uniform(0.5, 1.0, len(hot)).astype(np.float32) * np.float32(full)
    if deg.text_strip_px:
        _text_strip(radiance, deg.text_strip_px, full)
    np.clip(np.rint(radiance, out=radiance), 0, full, out=radiance)
    return radiance.astype(np.uint8 if deg.bits == 8 else np.uint16)


def _polygon_coverage(image: np.ndarray, vertices_px: np.ndarray, blur: float, sigma: float, oversample: int = 8
                      ) -> None:
    """Add a filled polygon (a plate's marker) with image vertices ``(k, 2)`` [px] into a coverage image (in
    place, clipped at 1): area coverage by ``oversample``² sub-pixels, blurred as the dots are."""
    x0, y0 = np.floor(vertices_px.min(axis=0)).astype(int) - 1
    x1, y1 = np.ceil(vertices_px.max(axis=0)).astype(int) + 2
    canvas = np.zeros(((y1 - y0) * oversample, (x1 - x0) * oversample), np.uint8)
    pts = np.rint((vertices_px - [x0 - 0.5, y0 - 0.5]) * oversample - 0.5).astype(np.int32)
    cv2.fillPoly(canvas, [pts], 255)
    patch = cv2.resize(canvas.astype(np.float32) / 255.0, (x1 - x0, y1 - y0), interpolation=cv2.INTER_AREA)
    _add_blurred(image, patch, int(x0), int(y0), blur, sigma)
    np.minimum(image, 1.0, out=image)


def view_dots(rig, points_mm: np.ndarray, orientation: np.ndarray, dot_diameter_mm: float, side: str,
              deg: Degradations) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """What :func:`dot_coverage` draws of dots at rig-frame points ``(n, 3)`` [mm] on a plane of ``orientation``
    in view ``side``: their image centres ``(n, 2)`` [px], ellipses (``(n, 2, 2)``, the unit disk to pixels:
    :func:`footprints`), defocus radii ``(n,)`` [px] (the rig's blur at their depth and place plus the camera's,
    :attr:`Degradations.defocus_px`) and the diffraction σ [px]."""
    centres, jac = footprints(rig, points_mm, orientation, side)
    blur, sigma = rig.blur_px(points_mm, side)
    blur = np.asarray(blur, float) + _extra_defocus(centres, tuple(rig.image_size_px), deg)
    return centres, jac * dot_diameter_mm / 2, blur, sigma


def render_rig_view(rig, points_mm: np.ndarray, orientation: np.ndarray, dot_diameter_mm: float, side: str,
                    deg: Degradations, rng: np.random.Generator, sensor: np.random.Generator,
                    markers: list | None = None) -> np.ndarray:
    """One camera image of dots at rig-frame points ``(n, 3)`` [mm] on a plane of ``orientation`` (columns: its
    ``x, y`` axes) through any rig (its ``project_view`` and ``blur_px``, as :class:`slmlab.virtual.rigs.StereoRig`
    and the CMO microscope answer): each dot the ellipse the local Jacobian makes of it (:func:`footprints`),
    defocused by the rig's blur at its depth and place plus the camera's (:attr:`Degradations.defocus_px`),
    then the camera's degradations (:func:`camera_image`). ``markers``: polygons on the plate, each ``(k, 3)``
    rig-frame vertices [mm] (a square and a triangle, as stereo-PIV plates have)."""
    size = tuple(rig.image_size_px)
    centres, ellipses, blur, sigma = view_dots(rig, points_mm, orientation, dot_diameter_mm, side, deg)
    cov = dot_coverage(size, centres, ellipses, blur, sigma)
    for vertices in markers or []:
        mid = np.asarray(vertices, float).mean(axis=0, keepdims=True)
        b, _ = rig.blur_px(mid, side)
        px = rig.project_view(np.asarray(vertices, float), side)
        if np.isfinite(px).all() and _inside_px(px, size):
            _polygon_coverage(cov, px, float(b[0]) + float(_extra_defocus(px.mean(axis=0)[None], size, deg)[0]), sigma)
    return camera_image(cov, deg, rng, sensor, centres)


def _inside_px(px: np.ndarray, size_px) -> bool:
    """Whether all points ``(k, 2)`` [px] are inside an image of ``size_px = (width, height)``."""
    w, h = size_px
    return bool(((px[:, 0] >= 0) & (px[:, 0] <= w - 1) & (px[:, 1] >= 0) & (px[:, 1] <= h - 1)).all())


def visible_dots(rig, points_mm: np.ndarray, orientation: np.ndarray, dot_diameter_mm: float, side: str,
                 deg: Degradations, sensor: np.random.Generator | None = None) -> tuple[np.ndarray, np.ndarray]:
    """True image centres ``(n, 2)`` [px] of dots rendered by :func:`render_rig_view`, and which of them are
    visible: the whole ellipse at least 1 px inside the image and above the text strip, and, with the
    camera's ``sensor`` stream, at least a quarter of the dot's contrast left between the noise-free dot and
    plate levels once clipped to full scale (a bright region can saturate both)."""
    w, h = rig.image_size_px
    c, jac = footprints(rig, points_mm, orientation, side)
    jp = jac * dot_diameter_mm / 2
    hx, hy = np.hypot(jp[:, 0, 0], jp[:, 0, 1]), np.hypot(jp[:, 1, 0], jp[:, 1, 1])
    vis = ((c[:, 0] - hx >= 1) & (c[:, 0] + hx <= w - 2) & (c[:, 1] - hy >= 1)
           & (c[:, 1] + hy <= h - 2 - deg.text_strip_px))
    if sensor is not None and vis.any():
        gain, region = _light(deg, w, h, sensor, c)
        y, x = np.clip(np.rint(c[:, 1]).astype(int), 0, h - 1), np.clip(np.rint(c[:, 0]).astype(int), 0, w - 1)
        g, add = gain[y, x], (0.0 if region is None else region[y, x])
        full = float(2 ** deg.bits - 1)
        plate = np.clip(deg.background_dn * g + add, 0, full)
        dot = np.clip((deg.background_dn + (-1 if deg.dark else 1) * deg.contrast_dn) * g + add, 0, full)
        vis &= np.abs(plate - dot) >= 0.25 * deg.contrast_dn * g
    return c, vis


def sensor_rng(seed: int, side: str) -> np.random.Generator:
    """The random stream of what one camera shows in every image (streaks, hot pixels)."""
    return np.random.default_rng([int(seed), 22, 0 if side == "l" else 1])


def _target_axes(rig) -> np.ndarray:
    """Orthonormal ``3 × 2`` axes (columns) of a known target mounted along the stage's x and y axes."""
    a = np.asarray(rig.stage.axes, float)
    x = a[:, 0] / np.linalg.norm(a[:, 0])
    y = a[:, 1] - (a[:, 1] @ x) * x
    return np.column_stack([x, y / np.linalg.norm(y)])


def _two_level_markers(plate: dict, origin_world: np.ndarray, to_rig) -> list:
    """A two-level plate's square and triangle (rig-frame vertices [mm]) in the holes beside its origin dot:
    the triangle half a pitch along ``+x``, the square half a pitch along ``+y`` (the stereo-PIV convention
    :func:`slmlab.images.lattice.origin_frame` reads), each about half a dot's area (so that the parallax of
    an oblique view does not bring them into the second level's dots beside them), on the first level."""
    unit, d = plate["pitch_mm"] / 2, plate["dot_diameter_mm"]
    t = np.radians([90.0, 210.0, 330.0])
    triangle = np.column_stack([unit + 0.55 * d * np.cos(t), 0.55 * d * np.sin(t)])
    square = np.array([[-0.3, -0.3], [0.3, -0.3], [0.3, 0.3], [-0.3, 0.3]]) * d + [0.0, unit]
    return [to_rig(origin_world + np.column_stack([v, np.zeros(len(v))])) for v in (triangle, square)]


def truth_places_held(cal: CalibrationSet) -> bool:
    """Whether ``points.csv`` still holds the true places of a known target's dots (``x_mm, y_mm, z_mm``) for
    :func:`rendered_truth`: every dot of ``truth.csv``, in its order, numbered alike (the simulated file; or one
    ``extract`` wrote over it that numbered them all so: the truth is then matched to it by number). Always where the
    plate is not a known target (its truth needs no places)."""
    if "x_mm" not in cal.points.columns:
        return True
    keys = ["sequence", "position", "row", "col"]
    pts, truth = cal.points, cal.truth
    return len(pts) == len(truth) and bool((pts[keys].to_numpy() == truth[keys].to_numpy()).all())


def _known_places(cal: CalibrationSet) -> np.ndarray:
    """A known target's place ``x_mm, y_mm, z_mm`` of each dot of ``cal.truth``, row by row from ``points.csv``
    where :func:`truth_places_held`; :class:`SlmlabError` where not (the places of the dots an extraction lost are
    gone)."""
    if not truth_places_held(cal):
        raise SlmlabError("points.csv is not the simulated one beside truth.csv (written by extract?): the true "
                          "places of a known target's dots are in the simulated points.csv; simulate the set again")
    return cal.points[["x_mm", "y_mm", "z_mm"]].to_numpy(float)


def rig_scenes(cal: CalibrationSet, rig):
    """Per stage position ``(sequence, position)``: the rig-frame dots ``(n, 3)`` [mm], the plate's axes
    ``(3, 2)``, its dot diameter [mm], its ``meta.json`` name and its markers (a two-level plate's)."""
    sim = cal.meta["simulator"]
    origin = np.asarray(sim["stage_origin_mm"])
    known = "x_mm" in cal.points.columns
    truth = cal.truth
    local_all = _known_places(cal) if known else None
    for (seq, pos), idx in truth.groupby(["sequence", "position"], sort=False).indices.items():
        world = truth.iloc[idx][["X_mm", "Y_mm", "Z_mm"]].to_numpy(float)
        p = rig.stage_to_microscope(world, origin)
        name = "grid" if seq == "grid" else "moving"
        plate = cal.meta["plates"][name]
        markers = []
        if known:
            axes = _target_axes(rig)
            local = local_all[idx]
            if int(plate.get("levels", 1)) == 2:
                markers = _two_level_markers(plate, (world - local)[0],
                                             lambda w: rig.stage_to_microscope(w, origin))
        else:
            axes = (rig.grid_plate if name == "grid" else rig.moving_plate).orientation()[:, :2]
        yield seq, int(pos), p, axes, float(plate.get("dot_diameter_mm", 0.0)), name, markers


def check_renderable(cal: CalibrationSet) -> None:
    """Raise :class:`SlmlabError` (before anything is written) for a simulated set whose images would not be
    extractable: a stepped target's heights are not described by ``meta.json``."""
    if (cal.meta.get("simulator") or {}).get("design") == "stepped-target":
        raise SlmlabError("the stepped target's dots sit at five heights that meta.json cannot describe, so its "
                          "images could not be extracted into its known target; render another design (a Z stack, "
                          "the stage sequences, a two-level plate or a ChArUco stack) or leave out --images")


def render_rig_set(cal: CalibrationSet, out_dir: str | Path, deg: Degradations | None = None, *,
                   progress: bool | None = None, compress: bool = True) -> list[Path]:
    """Render every stereo pair of a set simulated on a zoo rig (:func:`slmlab.virtual.designs.simulate_design`)
    into ``out_dir/images/`` as the rig's cameras would (:func:`render_rig_view`; ``deg``: the camera, by default
    the rig kind's, :data:`RIG_LOOKS`), write ``stage.csv`` naming the images and give the plates' polarity in
    ``meta.json``, so that ``extract`` reads them. The dots are rendered at ``truth.csv``'s positions, so their
    true image centres are ``truth.csv``'s; the camera is recorded in ``meta.json`` (``simulator.camera``). A
    ChArUco design renders the board (:func:`board_reflectance`); a stepped target is refused
    (:class:`SlmlabError`): ``meta.json`` cannot describe its heights, so its images could not be extracted into
    its known target. ``compress``: :func:`write_png`'s."""
    sim = cal.meta.get("simulator")
    if sim is None or cal.truth is None:
        raise SlmlabError("only simulated sets (with truth.csv and meta.json's 'simulator') can be rendered", cal.path)
    check_renderable(cal)
    rig = rig_from_dict(sim["microscope"])
    deg = deg or rig_degradations(rig.kind)
    out = Path(out_dir)
    (out / "images").mkdir(parents=True, exist_ok=True)
    seed = int(sim["seed"])
    if cal.meta["plates"]["moving"].get("pattern") == "charuco":
        written = _render_rig_boards(cal, rig, deg, out, seed, progress, compress)
    else:
        written = []
        scenes = list(rig_scenes(cal, rig))
        for seq, pos, p, axes, diam, _, markers in tqdm(scenes, desc="rendering stereo pairs", unit="pair",
                                                          disable=None if progress is None else not progress):
            for side in "lr":
                img = render_rig_view(rig, p, axes, diam, side, deg, _image_rng(seed, seq, pos, side),
                                      sensor_rng(seed, side), markers)
                write_png(out / "images" / image_name(seq, pos, side), img, compress=compress)
                written.append(out / "images" / image_name(seq, pos, side))
    meta = json.loads(json_text(cal.meta))
    for name in meta["plates"]:
        if meta["plates"][name].get("pattern", "dots") == "dots":
            meta["plates"][name]["dots"] = "dark" if deg.dark else "bright"
    meta["simulator"]["camera"] = asdict(deg)
    atomic_write_text(out / "meta.json", json_text(meta))
    _write_stage(cal, out)
    return written


def _write_stage(cal: CalibrationSet, out: Path) -> None:
    """``stage.csv`` naming each position's rendered images (``images/{sequence}_{position:03d}_{l|r}.png``)."""
    rows = ["sequence,position,stage_x_mm,stage_y_mm,stage_z_mm,left_image,right_image"]
    for r in cal.points.drop_duplicates(["sequence", "position"]).itertuples(index=False):
        rows.append(f"{r.sequence},{r.position},{r.stage_x_mm:.6f},{r.stage_y_mm:.6f},{r.stage_z_mm:.6f},"
                    f"images/{image_name(r.sequence, r.position, 'l')},images/{image_name(r.sequence, r.position, 'r')}")
    atomic_write_text(out / "stage.csv", "\n".join(rows) + "\n")


def _render_rig_boards(cal: CalibrationSet, rig, deg: Degradations, out: Path, seed: int, progress,
                       compress: bool = True) -> list[Path]:
    """The ChArUco design's images: the board (OpenCV's drawing, sampled at five texture pixels per image
    pixel) at each stage position, its centre the target's origin, its axes the stage's (as the simulator
    mounts a known target: with the stage's skew and scale errors, so that the corners are ``truth.csv``'s),
    traced through the rig (:func:`board_reflectance`) and exposed as printed ink on a bright board by the
    rig's camera."""
    plate = cal.meta["plates"]["moving"]
    spec = PlateSpec("moving", None, None, float(plate["pitch_mm"]), pattern="charuco", board=dict(plate["board"]))
    sx, sy = (int(v) for v in plate["board"]["squares"])
    size_mm = (sx * spec.pitch_mm, sy * spec.pitch_mm)
    ppmm = 5.0 * rig.px_per_mm()                   # an odd footprint: the box filter is centred
    texture = charuco_board(spec).generateImage((int(round(size_mm[0] * ppmm)), int(round(size_mm[1] * ppmm))),
                                                marginSize=0)
    ink = deg if deg.dark else replace(deg, dark=True, background_dn=deg.background_dn + deg.contrast_dn)
    axes = np.asarray(rig.stage.axes, float)      # the target's frame is the stage's, skew and scale errors too
    origin = np.asarray(cal.meta["simulator"]["stage_origin_mm"])
    written = []
    keys = cal.points.drop_duplicates(["sequence", "position"])[["sequence", "position"]].itertuples(index=False)
    for seq, pos in tqdm(list(keys), desc="rendering stereo pairs", unit="pair",
                         disable=None if progress is None else not progress):
        sel = (cal.truth["sequence"] == seq) & (cal.truth["position"] == pos)
        world = cal.truth.loc[sel, ["X_mm", "Y_mm", "Z_mm"]].to_numpy(float)
        local = cal.points.loc[sel, ["x_mm", "y_mm", "z_mm"]].to_numpy(float)
        centre = rig.stage_to_microscope((world - local)[:1], origin)[0]
        for side in "lr":
            blur, sigma = rig.blur_px(centre[None], side)
            refl = board_reflectance(rig, texture, ppmm, size_mm, centre, axes, side, 5, float(blur[0]), sigma)
            img = camera_image(1.0 - refl, ink, _image_rng(seed, seq, int(pos), side), sensor_rng(seed, side),
                               np.empty((0, 2)))
            write_png(out / "images" / image_name(seq, int(pos), side), img, compress=compress)
            written.append(out / "images" / image_name(seq, int(pos), side))
    return written


def set_camera(cal: CalibrationSet) -> Degradations:
    """The camera a rig set's images were rendered with (``meta.json``'s ``simulator.camera``, written by
    :func:`render_rig_set`), or the rig kind's (:data:`RIG_LOOKS`)."""
    sim = cal.meta["simulator"]
    if "camera" in sim:
        return Degradations(**sim["camera"])
    return rig_degradations(sim["microscope"].get("rig", "microscope"))


def rig_views(cal: CalibrationSet, rig):
    """Every view of every stage position of a set simulated on ``rig``, in :func:`render_rig_set`'s order:
    ``(keys, idx, points_mm, axes, dot_diameter_mm, side, sensor)``: the frame ``sequence, position, view, row,
    col`` of its dots, their rows in ``truth.csv``, the rig-frame dots ``(n, 3)`` [mm], the plate's axes, its dot
    diameter [mm], the view and the camera's stream (:func:`sensor_rng`)."""
    groups = cal.truth.groupby(["sequence", "position"], sort=False).indices
    seed = int(cal.meta["simulator"]["seed"])
    rows, cols = cal.truth["row"].to_numpy(), cal.truth["col"].to_numpy()
    for seq, pos, p, axes, diam, _, _ in rig_scenes(cal, rig):
        idx = groups[(seq, pos)]
        for side in "lr":
            keys = pd.DataFrame({"sequence": seq, "position": pos, "view": side, "row": rows[idx], "col": cols[idx]})
            yield keys, idx, p, axes, diam, side, sensor_rng(seed, side)


def rendered_truth(cal: CalibrationSet) -> pd.DataFrame:
    """Every dot of a rendered rig set in every image, as :func:`render_rig_set` drew it (:func:`rig_views`):
    ``sequence, position, view, row, col, w1, w2`` [px] (the true centre), ``visible`` (:func:`visible_dots`, for
    the camera the set was rendered with, its streaks and bright region too), ``z_mm`` (rig frame, the focal
    plane at 0) and, for a known target, ``x_mm, y_mm`` (its place on the target)."""
    rig = rig_from_dict(cal.meta["simulator"]["microscope"])
    deg = set_camera(cal)
    frames = []
    places = _known_places(cal) if "x_mm" in cal.points.columns else None
    for keys, idx, p, axes, diam, side, sensor in rig_views(cal, rig):
        c, vis = visible_dots(rig, p, axes, diam, side, deg, sensor)
        f = keys.assign(w1=c[:, 0], w2=c[:, 1], visible=vis, z_mm=p[:, 2])
        if places is not None:
            f["x_mm"], f["y_mm"] = places[idx, 0], places[idx, 1]
        frames.append(f)
    return pd.concat(frames, ignore_index=True)
