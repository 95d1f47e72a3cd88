"""The micro-gripping application (paper §2, Figs 1–2): locate, reconstruct, close the loop.

A gripper carried by the 3-DOF stage approaches a copper wire of 100 µm diameter on a small object (a hub
with three wires at 120°; rotating the object by 120° brings the next wire in front of the gripper), grips it
at a chosen position, drags it and releases it on a pad.

Scene (microscope frame, mm): the object and the pad are fixed; the wires lie in a plane near the focal plane
and the chosen one runs along the image columns. The gripper arrives from +x, its jaws opening vertically,
so from above it is one tapered silhouette ending in a tip a few tens of µm wide; its *tip point* is the
middle of the tip's end, at the jaws' mid-height.

Loop: render both views → locate the gripper by template matching (a model rendered from a reference view,
``cv2.matchTemplate`` on an image pyramid, then ``cv2.findTransformECC`` on a crop around the match for
sub-pixel accuracy; the tip point follows by that transform; the model is re-rendered each look at the pose
the commanded moves predict, so its appearance follows the local distortion and defocus and only a
translation is left to find) and the wire, once,
before the gripper covers it, in a region of interest computed from
the hub's position (hub found as the largest round dark blob; wire pixels fitted by ``cv2.fitLine``); the
gripping position is the point of the wire at the chosen distance from the hub in the left view, and where the
right view's wire crosses the same aligned image row → reconstruct tip and gripping position with the vision
model → move the stage by their difference (the stage has its own errors) → repeat until the reconstructed
offset is within tolerance → close, drag, release.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import cv2
import numpy as np
import pandas as pd

from .errors import SlmlabError
from .models import calibrate
from .virtual.microscope import Microscope
from .virtual.presets import preset
from .virtual.render import expose
from .virtual.sessions import paper_test
from .virtual.simulate import simulate_set

__all__ = ["Scene", "render_scene", "GripperModel", "build_gripper_model", "locate_gripper", "locate_wire",
           "locate_pad", "Episode", "run_episode", "model_origin_offset", "row_map", "grip", "wire_mask",
           "episode_scene", "episodes_table"]


@dataclass(frozen=True)
class Scene:
    """The gripping scene (microscope frame, mm).

    Attributes
    ----------
    hub_centre_mm, hub_radius_mm
        the object's hub (a disk) in the wire plane.
    wire_diameter_mm, wire_length_mm
        the copper wires.
    object_rotation_deg
        rotation of the object; wire ``k`` points at ``object_rotation_deg + 120·k`` degrees from the −y axis.
    wire
        the wire to grip (0, 1, 2).
    grip_distance_mm
        where to grip: distance from the hub centre along the wire.
    tip_width_mm, gripper_length_mm, gripper_width_mm
        the gripper silhouette: a bar from +x tapering to a tip of ``tip_width_mm``.
    gripper_tip_start_mm
        where the tip starts, relative to the gripping position [mm] (the first move must close this gap).
    pad_centre_mm, pad_size_mm
        the release pad.
    """

    hub_centre_mm: tuple[float, float, float] = (-0.3, 1.0, 0.0)
    hub_radius_mm: float = 0.25
    wire_diameter_mm: float = 0.1
    wire_length_mm: float = 1.6
    object_rotation_deg: float = 0.0
    wire: int = 0
    grip_distance_mm: float = 1.0
    tip_width_mm: float = 0.04
    gripper_length_mm: float = 2.0
    gripper_width_mm: float = 0.5
    gripper_tip_start_mm: tuple[float, float, float] = (0.9, 0.25, 0.35)
    pad_centre_mm: tuple[float, float, float] = (1.4, -1.2, 0.0)
    pad_size_mm: float = 0.6

    def wire_direction(self, k: int | None = None) -> np.ndarray:
        a = np.radians(self.object_rotation_deg + 120.0 * (self.wire if k is None else k))
        return np.array([np.sin(a), -np.cos(a), 0.0])

    def grip_point(self) -> np.ndarray:
        """True gripping position: on the wire's axis, ``grip_distance_mm`` from the hub centre [mm]."""
        return np.asarray(self.hub_centre_mm) + self.grip_distance_mm * self.wire_direction()


# ------------------------------------------------------------------------------------------ rendering
def _polygon_layer(microscope, side, outline_mm, size, margin_px: int = 0):
    """Anti-aliased coverage [0, 1] of a planar polygon given by 3D vertices, through the view's projection, on
    the polygon's bounding box grown by ``margin_px`` (clipped to the image of ``size``): the layer and the
    ``(row, col)`` slices of the image it covers (empty slices if the polygon is outside the image)."""
    w = microscope.project_view(outline_mm, side)
    x0, y0 = np.floor(w.min(axis=0)).astype(int) - margin_px - 2
    x1, y1 = np.ceil(w.max(axis=0)).astype(int) + margin_px + 3
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, size[0]), min(y1, size[1])
    box = (slice(y0, max(y1, y0)), slice(x0, max(x1, x0)))
    layer = np.zeros((max(y1 - y0, 0), max(x1 - x0, 0)), np.uint8)
    if layer.size:   # the same pixels as drawn on the whole image: the box moves the vertices by whole pixels
        cv2.fillPoly(layer, [np.round((w - [x0, y0]) * 16).astype(np.int32)], 255, lineType=cv2.LINE_AA, shift=4)
    return layer.astype(np.float32) / 255.0, box


def _rect(centre, direction, length, width, n=24):
    """Outline of a strip from ``centre`` along ``direction`` (many vertices, so distortion bends it)."""
    d = np.asarray(direction, float)
    d /= np.linalg.norm(d)
    perp = np.array([-d[1], d[0], 0.0])
    t = np.linspace(0, length, n)
    a = centre + t[:, None] * d + width / 2 * perp
    b = centre + t[::-1, None] * d - width / 2 * perp
    return np.vstack([a, b])


def gripper_outline(tip_mm: np.ndarray, scene: Scene) -> np.ndarray:
    """The gripper silhouette: a bar along +x tapering over its first 0.6 mm to the tip."""
    tip = np.asarray(tip_mm, float)
    taper = 0.6
    y0, hw, tw = tip[1], scene.gripper_width_mm / 2, scene.tip_width_mm / 2
    xs = tip[0] + np.array([0.0, taper, scene.gripper_length_mm])
    top = [(xs[0], y0 + tw), (xs[1], y0 + hw), (xs[2], y0 + hw)]
    bottom = [(xs[2], y0 - hw), (xs[1], y0 - hw), (xs[0], y0 - tw)]
    pts = []
    for (x0, ya), (x1, yb) in zip(top + bottom, (top + bottom)[1:]):
        for s in np.linspace(0, 1, 8, endpoint=False):
            pts.append((x0 + s * (x1 - x0), ya + s * (yb - ya), tip[2]))
    pts.append((*bottom[-1], tip[2]))
    return np.asarray(pts)


LEVELS = {"pad": 0.55, "hub": 0.25, "wire": 0.42, "gripper": 0.12}


def render_scene(microscope: Microscope, scene: Scene, tip_mm, side: str, rng: np.random.Generator,
                 parts=("pad", "hub", "wire", "gripper"), noise: bool = True) -> np.ndarray:
    """One 8-bit view of the scene with the gripper tip at ``tip_mm`` (microscope frame). Each part is drawn
    through the view's projection and distortion, blurred by its own defocus, and the whole is exposed with
    the microscope's vignetting and noise (``noise=False``: the clean reflectance, for templates)."""
    o, im = microscope.optics, microscope.imaging
    size = o.image_size_px
    refl = np.ones(size[::-1], np.float32)
    hub = np.asarray(scene.hub_centre_mm, float)
    t = np.linspace(0, 2 * np.pi, 72, endpoint=False)
    hub_outline = hub + scene.hub_radius_mm * np.column_stack([np.cos(t), np.sin(t), np.zeros_like(t)])
    shapes = {
        "pad": (_rect(np.asarray(scene.pad_centre_mm) - [scene.pad_size_mm / 2, 0, 0], [1, 0, 0], scene.pad_size_mm,
                      scene.pad_size_mm, 4), scene.pad_centre_mm[2]),
        "hub": (hub_outline, hub[2]),
        "gripper": (gripper_outline(tip_mm, scene), float(np.asarray(tip_mm)[2])),
    }
    for part in parts:
        if part == "wire":
            for k in range(3):
                outline = _rect(hub, scene.wire_direction(k), scene.wire_length_mm, scene.wire_diameter_mm)
                _composite(refl, microscope, side, outline, size, LEVELS["wire"], hub[2])
            continue
        outline, z = shapes[part]
        _composite(refl, microscope, side, outline, size, LEVELS[part], z)
    if not noise:
        return np.clip(np.rint(refl * im.background_dn), 0, 255).astype(np.uint8)
    return expose(refl, im, rng)


def _composite(refl, microscope, side, outline_mm, size, level, z_mm) -> None:
    """Lay a part of reflectance ``level`` (its outline at depth ``z_mm``) over ``refl`` (in place), blurred by
    its defocus: a Gaussian standing in for pillbox ⊗ diffraction, on the part's box grown by the kernel's
    reach (the layer is zero beyond it, so the blur there is the blur over the whole image)."""
    radius, sigma = microscope.imaging.blur_px(z_mm, microscope.optics.pixel_mm)
    s = float(np.hypot(sigma, float(radius) / 2))
    reach = int(np.ceil(4 * s)) + 1 if s > 0.3 else 0           # OpenCV's kernel for float images: ±4σ
    coverage, box = _polygon_layer(microscope, side, outline_mm, size, reach)
    if coverage.size == 0:
        return
    cov = cv2.GaussianBlur(coverage, (0, 0), s) if s > 0.3 else coverage
    refl[box] = refl[box] * (1 - cov) + level * cov


# ------------------------------------------------------------------------------------------ locating
@dataclass
class GripperModel:
    """A template of the gripper per view, rendered from a reference pose, with the tip point inside it."""

    templates: dict
    tip_in_template: dict
    reference_tip_px: dict


def build_gripper_model(microscope: Microscope, scene: Scene, reference_tip_mm, half: int = 110,
                        behind_px: int = 25) -> GripperModel:
    """Render the gripper alone at a reference pose in each view and crop a template of its tapered body
    *behind* the tip (``behind_px`` back): the tip itself is where it meets the wire, so it is kept out of
    the template and located by the template's affine transform instead."""
    temps, tips, refs = {}, {}, {}
    for side in "lr":
        img = render_scene(microscope, scene, reference_tip_mm, side, None, parts=("gripper",), noise=False)
        tip = microscope.project_view(np.atleast_2d(reference_tip_mm), side)[0]
        back = microscope.project_view(np.atleast_2d(np.asarray(reference_tip_mm) + [0.3, 0, 0]), side)[0] - tip
        toward_body = np.sign(back[0]) if back[0] != 0 else -1.0
        if toward_body < 0:
            x1 = int(round(tip[0])) - behind_px
            x0 = x1 - 2 * half
        else:
            x0 = int(round(tip[0])) + behind_px
        y0 = int(round(tip[1])) - half
        temps[side] = img[y0:y0 + 2 * half, x0:x0 + 2 * half].astype(np.float32)
        tips[side] = tip - [x0, y0]
        refs[side] = tip
    return GripperModel(temps, tips, refs)


def wire_mask(shape, line, half_width_px: float = 30.0) -> np.ndarray:
    """8-bit mask, 0 within ``half_width_px`` of a line ``(point, unit direction)`` [px], 255 elsewhere."""
    (mu, d) = line
    ys, xs = np.arange(shape[0], dtype=np.float32)[:, None], np.arange(shape[1], dtype=np.float32)[None, :]
    dist = np.abs((xs - mu[0]) * d[1] - (ys - mu[1]) * d[0])          # broadcast: no coordinate images
    return np.where(dist > half_width_px, 255, 0).astype(np.uint8)


#: a fixed number of ECC iterations, no ε stop: a stop on the correlation's increment ends one iteration
#: sooner or later with the CPU's float32 rounding (AVX-512 or AVX2), and moves the tip by a hundredth of a pixel
ECC_CRITERIA = (cv2.TERM_CRITERIA_COUNT, 40, 0.0)
#: how far [px] beyond the matched template the ECC refinement may look: it moves the template by a few pixels
ECC_MARGIN_PX = 48


def locate_gripper(image: np.ndarray, model: GripperModel, side: str, expected_px=None, search_px: int = 400,
                   mask: np.ndarray | None = None, motion: str = "translation") -> np.ndarray:
    """Image position [px] of the gripper's tip point: pyramid template matching, then an ECC refinement
    (pixels where ``mask`` is 0 — e.g. the wire — ignored); the tip follows by the fitted affine transform.

    ``motion``: ``'translation'`` when the model was rendered at the predicted pose (only a shift is left,
    and the tip, which lies outside the template, is not moved by spurious scale or shear), ``'affine'`` for
    a model from a distant reference pose."""
    tpl = model.templates[side]
    img = image.astype(np.float32)
    h, w = img.shape
    th, tw = tpl.shape
    if expected_px is None:
        x_lo, y_lo, x_hi, y_hi = 0, 0, w, h
    else:
        e = np.asarray(expected_px) - model.tip_in_template[side]
        x_lo, y_lo = max(int(e[0]) - search_px, 0), max(int(e[1]) - search_px, 0)
        x_hi, y_hi = min(int(e[0]) + tw + search_px, w), min(int(e[1]) + th + search_px, h)
    roi = img[y_lo:y_hi, x_lo:x_hi]
    k = 4
    small = cv2.resize(roi, (roi.shape[1] // k, roi.shape[0] // k), interpolation=cv2.INTER_AREA)
    tsmall = cv2.resize(tpl, (tw // k, th // k), interpolation=cv2.INTER_AREA)
    r = cv2.matchTemplate(small, tsmall, cv2.TM_CCOEFF_NORMED)
    _, score, _, loc = cv2.minMaxLoc(r)
    cx, cy = x_lo + loc[0] * k, y_lo + loc[1] * k
    # full-resolution refinement around the coarse hit
    x0, y0 = max(cx - 2 * k, 0), max(cy - 2 * k, 0)
    patch = img[y0:y0 + th + 4 * k, x0:x0 + tw + 4 * k]
    r = cv2.matchTemplate(patch, tpl, cv2.TM_CCOEFF_NORMED)
    _, score, _, loc = cv2.minMaxLoc(r)
    if score < 0.5:   # before the refinement: no ECC on a gripper that is not there
        raise SlmlabError(f"gripper not found in the {side} image (template match {score:.2f})")
    warp = _refine_ecc(tpl, img, (x0 + loc[0], y0 + loc[1]), mask, motion)
    t = model.tip_in_template[side]
    return warp[:, :2] @ t + warp[:, 2]


def _refine_ecc(tpl, img, corner_px, mask, motion):
    """``cv2.findTransformECC`` of the template placed at integer ``corner_px`` in ``img``, on a crop of the
    image around it (``ECC_MARGIN_PX`` beyond the template): ECC blurs and differentiates its whole input
    image, most of a call on a 2048 px image (a 220 px template, 40 iterations: 86 ms a call on the whole image,
    35 ms on the crop; the same warp to float32 rounding). Returns the 2 × 3 warp [px] in the image's pixels
    (the matched placement if ECC fails: OpenCV writes its iterations into the array it is given, so it is given
    a copy)."""
    th, tw = tpl.shape
    cx, cy = max(int(corner_px[0]) - ECC_MARGIN_PX, 0), max(int(corner_px[1]) - ECC_MARGIN_PX, 0)
    crop = (slice(cy, cy + th + 2 * ECC_MARGIN_PX), slice(cx, cx + tw + 2 * ECC_MARGIN_PX))
    warp = np.array([[1, 0, corner_px[0] - cx], [0, 1, corner_px[1] - cy]], np.float32)
    try:
        _, warp = cv2.findTransformECC(tpl, np.ascontiguousarray(img[crop]), warp.copy(),
                                       cv2.MOTION_AFFINE if motion == "affine" else cv2.MOTION_TRANSLATION,
                                       ECC_CRITERIA, None if mask is None else np.ascontiguousarray(mask[crop]), 5)
    except cv2.error:
        pass
    return warp.astype(np.float64) + [[0, 0, cx], [0, 0, cy]]   # in float64: no rounding at x ~ 2000 px


def _dark_blobs(image, level_fraction):
    bg = cv2.GaussianBlur(image, (0, 0), 40)
    mask = (image.astype(np.float32) < level_fraction * np.maximum(bg.astype(np.float32), 1)).astype(np.uint8)
    return mask


def row_map(cal):
    """A model-free stereo correspondence learnt from a calibration set: ``w2_r`` as a quadratic in
    ``(w1_l, w2_l, D)`` (``D = w1_r − w1_l``) fitted on every dot seen in both views. Returns a function
    ``(w1_l, w2_l, D) → w2_r`` [px]."""
    pts = cal.points[cal.points[["wl1", "wl2", "wr1", "wr2"]].notna().all(axis=1)]
    a, b = pts["wl1"].to_numpy() / 1000, pts["wl2"].to_numpy() / 1000
    d = (pts["wr1"] - pts["wl1"]).to_numpy() / 100

    def design(a, b, d):
        return np.column_stack([np.ones_like(a), a, b, d, a * a, a * b, b * b, a * d, b * d, d * d])
    coef, *_ = np.linalg.lstsq(design(a, b, d), pts["wr2"].to_numpy(), rcond=None)
    return lambda w1l, w2l, disp: float((design(np.atleast_1d(w1l / 1000), np.atleast_1d(w2l / 1000),
                                                np.atleast_1d(disp / 100)) @ coef)[0])


def locate_wire(image: np.ndarray, microscope: Microscope, scene: Scene, side: str, *, row_px: float | None = None):
    """The chosen wire in one view: the hub centre [px] (largest round dark blob near the object's
    expected position), the wire's centreline (point, unit direction) from ``cv2.fitLine`` on the dark
    pixels of a region of interest along the wire, and the gripping point [px]: at ``grip_distance_mm`` from
    the hub along the wire (left view) or where the wire crosses image row ``row_px`` (right view)."""
    hub_mm = np.atleast_2d(scene.hub_centre_mm)
    hub_exp = microscope.project_view(hub_mm, side)[0]
    px_per_mm = 1.0 / microscope.optics.pixel_mm
    r_hub = scene.hub_radius_mm * px_per_mm
    # hub: the dark disk near its expected place (the object does not move)
    x0, y0 = int(hub_exp[0] - 3 * r_hub), int(hub_exp[1] - 3 * r_hub)
    roi = image[y0:y0 + int(6 * r_hub), x0:x0 + int(6 * r_hub)]
    mask = cv2.threshold(roi, 0, 255, cv2.THRESH_BINARY_INV + cv2.THRESH_OTSU)[1]
    mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (31, 31)))
    n, lab, stats, cents = cv2.connectedComponentsWithStats(mask)
    if n < 2:
        raise SlmlabError(f"object hub not found in the {side} image")
    k = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    hub_px = cents[k] + [x0, y0]
    # wire: ROI along the expected direction, beyond the hub
    d_img = microscope.project_view(hub_mm + 0.5 * scene.wire_direction(), side)[0] - hub_exp
    d_img /= np.linalg.norm(d_img)
    start = hub_px + d_img * (r_hub + 40)
    stop = hub_px + d_img * (scene.wire_length_mm * px_per_mm - 40)
    half_w = 60
    pts = []
    ys, xs = np.mgrid[int(min(start[1], stop[1])) - half_w:int(max(start[1], stop[1])) + half_w,
                      int(min(start[0], stop[0])) - half_w:int(max(start[0], stop[0])) + half_w]
    ys, xs = np.clip(ys, 0, image.shape[0] - 1), np.clip(xs, 0, image.shape[1] - 1)
    rel = np.stack([xs - start[0], ys - start[1]], -1)
    along = rel @ d_img
    across = rel @ np.array([-d_img[1], d_img[0]])
    inside = (along > 0) & (along < np.linalg.norm(stop - start)) & (np.abs(across) < half_w)
    # float64 throughout: float32 sums over tens of thousands of pixels depend on the CPU's vector width
    vals = image[ys, xs].astype(np.float64)
    bg = np.percentile(vals[inside], 90)
    dark = inside & (vals < 0.75 * bg)
    wts = np.clip(bg - vals, 0, None) * dark
    pts = np.column_stack([xs[dark], ys[dark]]).astype(np.float64)
    if len(pts) < 50:
        raise SlmlabError(f"wire not found in the {side} image")
    # centreline: weighted least squares line (weights: darkness), via the weighted covariance
    wv = wts[dark]
    mu = (pts * wv[:, None]).sum(0) / wv.sum()
    cov = ((pts - mu) * wv[:, None]).T @ (pts - mu) / wv.sum()
    evals, evecs = np.linalg.eigh(cov)
    direction = evecs[:, 1] * np.sign(evecs[:, 1] @ d_img)
    if row_px is None:
        proj = microscope.project_view(np.atleast_2d(scene.grip_point()), side)[0]  # expected place only
        t = (proj - mu) @ direction
    else:
        t = (row_px - mu[1]) / direction[1]
    return hub_px, (mu, direction), mu + t * direction


# ------------------------------------------------------------------------------------------ episode
@dataclass
class Episode:
    """What one gripping episode did and how well (µm)."""

    tip_error_um: float
    target_error_um: float
    final_offset_um: float
    gripped: bool
    iterations: int
    pad_offset_um: float
    location_error_px: dict = field(default_factory=dict)
    trajectory_mm: list = field(default_factory=list)
    first_look: dict = field(default_factory=dict, repr=False)

    def as_dict(self) -> dict:
        return {"tip_error_um": self.tip_error_um, "target_error_um": self.target_error_um,
                "final_offset_um": self.final_offset_um, "gripped": self.gripped, "iterations": self.iterations,
                "pad_offset_um": self.pad_offset_um, "location_error_px": self.location_error_px}


def _corresponding_point(grip_l, mu, direction, hub_l, hub_r, rows) -> np.ndarray:
    """The right-view point of the wire's line that corresponds to the left gripping point: where the line
    meets the row predicted by the learnt correspondence ``rows`` (or, without it, the hub's row offset)."""
    if rows is None:
        row = grip_l[1] - (hub_l[1] - hub_r[1])
        return mu + (row - mu[1]) / direction[1] * direction
    p = mu + (grip_l[1] - mu[1]) / direction[1] * direction
    for _ in range(4):  # the row depends (weakly) on the disparity: iterate
        row = rows(grip_l[0], grip_l[1], p[0] - grip_l[0])
        p = mu + (row - mu[1]) / direction[1] * direction
    return p


def run_episode(model, microscope: Microscope, scene: Scene, *, seed: int = 0, tolerance_um: float = 2.0,
                max_iterations: int = 6, grip_tolerance_um: float = 20.0, origin_offset_mm=None,
                stage_origin_mm=(0.0, 0.0, 0.0), rows=None, keep_images: bool = False) -> Episode:
    """One look-and-move episode: approach, grip, drag, release.

    ``model`` is a calibrated vision model in the stage frame; ``origin_offset_mm`` is its constant offset
    from the true stage frame (estimated on its calibration set), removed only to *report* absolute
    reconstruction errors — the loop itself uses differences, as a real system would. ``stage_origin_mm``
    is the microscope-frame position of stage zero of the model's calibration (the truth's frame).
    ``rows`` is the stereo correspondence learnt by :func:`row_map` on the calibration set.
    """
    rng = np.random.default_rng(seed)
    stage = microscope.stage
    axes = stage.axes
    offset = np.zeros(3) if origin_offset_mm is None else np.asarray(origin_offset_mm, float)
    target = scene.grip_point()
    tip0 = target + np.asarray(scene.gripper_tip_start_mm)
    commanded = np.zeros(3)     # stage coordinates relative to the start
    tip_of = lambda s: tip0 + axes @ (stage.actual(np.atleast_2d(s), rng)[0])  # noqa: E731
    tip = tip_of(commanded)
    traj = [tip.copy()]
    loc_err = {}
    origin = np.asarray(stage_origin_mm, float)
    to_stage = lambda p: np.linalg.solve(axes, p - origin)  # noqa: E731  (microscope → stage frame)
    errs = (np.nan, np.nan)
    first_look: dict = {}
    it = 0
    grip_l = grip_r = None
    for it in range(1, max_iterations + 1):
        imgs = {s: render_scene(microscope, scene, tip, s, rng) for s in "lr"}
        # model-based tracking: the gripper model is re-rendered where the commanded moves should have put it
        predicted = tip0 + axes @ commanded
        gmodel = build_gripper_model(microscope, scene, predicted)
        if grip_l is None:  # the object does not move: locate the wire once, before the gripper covers it
            hub_l, line_l, grip_l = locate_wire(imgs["l"], microscope, scene, "l")
            hub_r, line_r, _ = locate_wire(imgs["r"], microscope, scene, "r")
            grip_r = _corresponding_point(grip_l, *line_r, hub_l, hub_r, rows)
            masks = {"l": wire_mask(imgs["l"].shape, line_l), "r": wire_mask(imgs["r"].shape, line_r)}
        tips = {s: locate_gripper(imgs[s], gmodel, s, expected_px=gmodel.reference_tip_px[s], mask=masks[s])
                for s in "lr"}
        if keep_images and not first_look:
            first_look.update(images=imgs, tips=tips, grips={"l": grip_l, "r": grip_r},
                              lines={"l": line_l, "r": line_r})
        w = np.array([[*tips["l"], *tips["r"]], [*grip_l, *grip_r]])
        xyz = model.reconstruct(w)
        true_px = {s: microscope.project_view(np.vstack([tip, target]), s) for s in "lr"}
        loc_err = {f"tip_{s}": float(np.hypot(*(tips[s] - true_px[s][0]))) for s in "lr"}
        loc_err.update({"grip_l": float(np.hypot(*(grip_l - true_px["l"][1]))),
                        "grip_r": float(np.hypot(*(grip_r - true_px["r"][1])))})
        true_stage = [to_stage(tip), to_stage(target)]
        errs = (1e3 * np.linalg.norm(xyz[0] - offset - true_stage[0]), 1e3 * np.linalg.norm(xyz[1] - offset - true_stage[1]))
        move = xyz[1] - xyz[0]
        if 1e3 * np.linalg.norm(move) <= tolerance_um:
            break
        commanded = commanded + move
        tip = tip_of(commanded)
        traj.append(tip.copy())
    final = 1e3 * float(np.linalg.norm(tip - target))
    gripped = final <= grip_tolerance_um
    # drag and release: the pad is located in both views (centroid of its square), reconstructed, and the
    # gripped point moved above it, at the wire's height
    pad_px = [locate_pad(imgs[s], microscope, scene, s) for s in "lr"]
    pad_xyz = model.reconstruct(np.array([[*pad_px[0], *pad_px[1]]]))[0]
    goal = pad_xyz + [0.0, 0.0, xyz[1][2] - pad_xyz[2]]
    commanded = commanded + (goal - xyz[1])
    released = tip_of(commanded)
    traj.append(released.copy())
    pad = np.asarray(scene.pad_centre_mm, float)
    pad_offset = 1e3 * float(np.linalg.norm((released - (tip - target))[:2] - pad[:2]))
    return Episode(float(errs[0]), float(errs[1]), final, bool(gripped), it, pad_offset, loc_err,
                   [list(map(float, p)) for p in traj], first_look)


def locate_pad(image: np.ndarray, microscope: Microscope, scene: Scene, side: str) -> np.ndarray:
    """Centre [px] of the pad: centroid of the pixels at the pad's grey level in a region around its expected
    place (the pad does not move)."""
    c = microscope.project_view(np.atleast_2d(scene.pad_centre_mm), side)[0]
    half = int(scene.pad_size_mm / microscope.optics.pixel_mm)
    x0, y0 = max(int(c[0]) - half, 0), max(int(c[1]) - half, 0)
    roi = image[y0:y0 + 2 * half, x0:x0 + 2 * half]
    mask = cv2.threshold(roi, 0, 255, cv2.THRESH_BINARY_INV + cv2.THRESH_OTSU)[1]
    m = cv2.moments(mask, binaryImage=True)
    if m["m00"] == 0:
        raise SlmlabError(f"pad not found in the {side} image")
    return np.array([m["m10"] / m["m00"] + x0, m["m01"] / m["m00"] + y0])


def model_origin_offset(model, cal) -> np.ndarray:
    """The model's constant offset from the true stage frame [mm]: the mean of reconstructed minus true
    coordinates over a simulated calibration set (for reporting absolute errors only)."""
    if cal.truth is None:
        return np.zeros(3)
    pts = cal.points[cal.points[["wl1", "wl2", "wr1", "wr2"]].notna().all(axis=1)]
    truth = cal.truth.loc[pts.index, ["X_mm", "Y_mm", "Z_mm"]].to_numpy()
    return (model.reconstruct(pts[["wl1", "wl2", "wr1", "wr2"]].to_numpy()) - truth).mean(axis=0)


def episode_scene(seed: int) -> Scene:
    """The scene of episode ``seed``: object rotated a little, gripper starting somewhere in front of it."""
    rng = np.random.default_rng([seed, 7])
    return replace(Scene(), object_rotation_deg=float(rng.uniform(-8, 8)), wire=0,
                   gripper_tip_start_mm=tuple(rng.uniform([0.6, -0.3, 0.2], [1.0, 0.3, 0.5])),
                   grip_distance_mm=float(rng.uniform(0.8, 1.2)))


def grip(seed: int = 0, model_name: str | None = None, *, preset_name: str = "paper", calibration_seed: int = 1,
         calibrated=None, **episode_options) -> Episode:
    """One episode end to end: simulate a Test 1 calibration set, calibrate ``model_name`` (default: the
    most accurate model), rotate the object to a wire chosen by the seed, and run the loop."""
    m = preset(preset_name)
    if calibrated is None:
        cal = simulate_set(m, paper_test(1), seed=calibration_seed)
        model = calibrate(cal, model_name)
    else:  # (model, calibration set) already at hand
        model, cal = calibrated
    scene = episode_scene(seed)
    return run_episode(model, m, scene, seed=seed, origin_offset_mm=model_origin_offset(model, cal),
                       stage_origin_mm=cal.meta["simulator"]["stage_origin_mm"], rows=row_map(cal), **episode_options)


def episodes_table(models: dict, seeds, **kw):
    """Episodes over seeds for several calibrated models ``{name: (model, calibration set)}``: one row each."""
    rows = []
    for name, calibrated in models.items():
        for seed in seeds:
            ep = grip(int(seed), calibrated=calibrated, **kw)
            rows.append({"model": name, "seed": int(seed), **{k: v for k, v in ep.as_dict().items()
                                                              if k != "location_error_px"},
                         "max_location_error_px": max(ep.location_error_px.values())})
    return pd.DataFrame(rows)
