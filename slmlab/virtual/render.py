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
from .sessions import Session, tilt_matrix
from .simulate import stage_origin

__all__ = ["dot_footprints", "render_view", "render_pair", "render_set", "render_plate", "image_name", "write_png",
           "expose", "render_board", "render_board_set", "board_orientation"]


def image_name(sequence: str, position: int, side: str) -> str:
    """File name of one image in ``images/``: ``{sequence}_{position:03d}_{l|r}.png`` (README, "The format")."""
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
    width, height = microscope.optics.image_size_px
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
    return (rows[j0] * (1 - fy.T) + rows[j0 + 1] * fy.T).astype(np.float32)


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
    width, height = o.image_size_px
    step = 8
    xy = _plate_points_of_pixels(microscope, centre_mm, orientation, side, step)
    bw, bh = board_size_mm
    tx = (xy[..., 0] + bw / 2) * texture_px_per_mm - 0.5        # texture columns (pixel centres at integers)
    ty = (bh / 2 - xy[..., 1]) * texture_px_per_mm - 0.5        # texture rows (y up the board, rows down)
    mx, my = _upsample(tx, step, width, height), _upsample(ty, step, width, height)
    footprint = max(int(round(texture_px_per_mm * o.pixel_mm)), 1)   # texture px per image px
    tex = cv2.blur(texture.astype(np.float32) / 255.0, (footprint, footprint)) if footprint > 1 else \
        texture.astype(np.float32) / 255.0
    refl = cv2.remap(tex, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=1.0)
    blur, sigma = im.blur_px(np.array([centre_mm[2]]), o.pixel_mm)
    k = _psf(int(round(blur[0] * 20)), int(round(sigma * 20)))
    refl = cv2.filter2D(refl, -1, k, borderType=cv2.BORDER_REPLICATE)
    dark = im.dot_dn / im.background_dn
    return expose(dark + (1.0 - dark) * refl, im, rng)


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
