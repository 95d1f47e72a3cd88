"""The traditional pinhole stereo model (paper §6.3, Fig 17), with OpenCV standing in for Halcon.

A Halcon or OpenCV user treats every image of the 7 × 7 plate as a view of a planar target with known dot
coordinates: ``cv2.calibrateCamera`` per camera, then ``cv2.stereoCalibrate`` for the pair. Points are then
undistorted and triangulated (``cv2.undistortPoints``, ``cv2.triangulatePoints``) in the left camera's
frame, and mapped into the stage frame by a map fitted on the calibration set's stage moves.

Why a CMO microscope is hard for it
-----------------------------------
* Each view projects onto a plane parallel to the focal plane from a centre about ``L·tan(γ/2)`` off the
  objective axis: as a pinhole camera its principal point lies thousands of pixels outside the image, and its
  distortion is centred on the objective axis, not on that principal point. OpenCV's polynomial distortion,
  centred on the principal point it estimates, has to approximate it.
* The working distance is long (weak perspective): focal length and distance trade off; with fronto-parallel
  views only (a stage that translates the plate) they are barely separable. We start from a sensible guess
  (``f = L / pixel``), keep it as a guess, and report the conditioning (the standard deviation of ``f``).

Distortion variants (recorded in the model file): ``standard`` (k1, k2, p1, p2, k3), ``rational`` (+ k4–k6),
``thin-prism`` (+ s1–s4), ``tilted`` (+ τx, τy). By default the one with the smallest displacement error on
held-back stage positions of the calibration set is kept.

Known 3D targets and Z stacks
-----------------------------
A known-target set (``x_mm, y_mm, z_mm``: the README's "The format") gives every dot's world position, the
stage position plus its place on the target; so does a Z stack of a plate of known lattice (nothing else
moving), the stage's Z plus the plate's lattice (:func:`slmlab.models.frames.world_positions`). The cameras do
not move, so all its dots, over every stage position, are **one view** of one non-planar target in the world
frame (a stepped target in one pose; a flat board at two or more stage Z positions), as PTV tools calibrate: a
DLT (the 3 × 4 projection matrix by linear least squares, :func:`dlt`) per camera, decomposed by
``cv2.decomposeProjectionMatrix`` into the intrinsic guess that ``cv2.calibrateCamera`` needs for a non-planar
target (``CALIB_USE_INTRINSIC_GUESS``; refined in stages: no distortion, the standard terms, then the
variant's), then ``cv2.stereoCalibrate`` with the intrinsics refined jointly or fixed, the lower RMS kept
(:func:`calibrate_target`). No stage map is fitted: the target places the cameras in the world, by a map
fitted on its dots' world positions (:func:`fit_world_map`). A single pose of a flat target is refused: one
view of a plane cannot separate focal length from distance. The variant is chosen on every 3rd dot held back.
On the virtual stepped target (±1 mm of depth: ±0.3 % of magnification at L = 300 mm, pixels across the field,
far above the dots' noise) the ``thin-prism`` variant reaches the noise floor: the CMO's distortion about the
objective axis, written about a principal point thousands of pixels away, is a radial term plus quadratic
(decentring and thin-prism) terms, which OpenCV's ``p1, p2, s1, s3`` cover; the standard terms alone leave
2–4 × the floor. The focal length itself stays loosely determined (a few % off ``L / pixel``, traded against the
distance) and OpenCV's σ(f) does not show it.

Two details of the CMO microscope that OpenCV's conventions do not expect:

* OpenCV requires an initial principal point inside the image, and a CMO view's lies thousands of pixels
  outside it: each camera's image points are shifted so that the principal point is at the image centre while
  OpenCV works, and ``K`` is shifted back after (exact: a pinhole's image translates with its principal point).
* A microscope's image may be a mirror image of the world (the virtual CMO microscope's is: its image axes run
  along the stage's ``+x, +y`` seen from above). No pinhole with positive focal lengths sees a mirror image of a
  3D target, so such a target is given to OpenCV mirrored (``z`` negated; recorded as ``image_mirrored``) and
  the map to the world undoes it. A planar view needs no such care (the plate is simply seen from behind).
  The maps to the stage or world are therefore orthogonal of either handedness where they are rigid.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import pandas as pd

from ..errors import SlmlabError
from ..io import CalibrationSet
from ..paper.chain import displacements
from .base import Model, one_thread, register
from .frames import check_axes, dot_labels, world_positions

__all__ = ["VARIANTS", "STAGE_MAPS", "StereoPinhole", "plate_views", "calibrate_stereo", "fit_stage_map",
           "PinholeModel", "views_table", "dlt", "dlt_intrinsics", "target_view", "calibrate_target",
           "fit_world_map", "orthogonal_map"]

VARIANTS = {
    "standard": 0,
    "rational": cv2.CALIB_RATIONAL_MODEL,
    "thin-prism": cv2.CALIB_RATIONAL_MODEL | cv2.CALIB_THIN_PRISM_MODEL,
    "tilted": cv2.CALIB_RATIONAL_MODEL | cv2.CALIB_THIN_PRISM_MODEL | cv2.CALIB_TILTED_MODEL,
}
STAGE_MAPS = ("affine", "rigid")
MIN_DOTS = 12


@dataclass
class StereoPinhole:
    """A calibrated stereo pinhole pair (left camera frame), OpenCV conventions; lengths in the target's
    units (mm for plates)."""

    K1: np.ndarray
    d1: np.ndarray
    K2: np.ndarray
    d2: np.ndarray
    R: np.ndarray
    T: np.ndarray
    rms_px: float
    variant: str
    f_std_px: tuple[float, float] = (np.nan, np.nan)
    stereo_option: str = ""

    def triangulate(self, w: np.ndarray) -> np.ndarray:
        """Left-camera-frame points ``(n, 3)`` of image quadruples ``(n, 4)`` [px]."""
        w = np.asarray(w, float).reshape(-1, 4)
        if not len(w):  # OpenCV returns None for no points
            return np.empty((0, 3))
        ul = cv2.undistortPoints(w[:, None, 0:2], self.K1, self.d1).reshape(-1, 2)
        ur = cv2.undistortPoints(w[:, None, 2:4], self.K2, self.d2).reshape(-1, 2)
        p1 = np.hstack([np.eye(3), np.zeros((3, 1))])
        p2 = np.hstack([self.R, self.T.reshape(3, 1)])
        x = cv2.triangulatePoints(p1, p2, ul.T, ur.T)
        return (x[:3] / x[3]).T

    def as_dict(self) -> dict:
        return {"K1": self.K1.tolist(), "d1": self.d1.ravel().tolist(), "K2": self.K2.tolist(),
                "d2": self.d2.ravel().tolist(), "R": self.R.tolist(), "T": self.T.ravel().tolist(),
                "rms_px": self.rms_px, "variant": self.variant, "f_std_px": _json_std(self.f_std_px),
                "stereo_option": self.stereo_option}

    @classmethod
    def from_dict(cls, d: dict) -> "StereoPinhole":
        a = lambda k: np.asarray(d[k], float)  # noqa: E731
        return cls(a("K1"), a("d1"), a("K2"), a("d2"), a("R"), a("T"), float(d["rms_px"]), str(d["variant"]),
                   tuple(np.nan if v is None else float(v) for v in d.get("f_std_px", (None, None))),
                   str(d.get("stereo_option", "")))


def _json_std(std) -> list:
    """Standard deviations for a model file: ``None`` (JSON null) where OpenCV's covariance is singular (the
    views do not determine the parameter: a telecentric view, for one) or was not computed (the model's
    options say ``spread: false``)."""
    return [float(v) if np.isfinite(v) else None for v in std]


def plate_views(cal: CalibrationSet, sequences=("X", "Y", "Z", "T"), max_views: int | None = 24) -> list[dict]:
    """One planar-target view per (sequence, position) with at least 12 dots seen in both images: object
    points ``(col−1)·pitch, (row−1)·pitch, 0`` [mm] and the two images' points [px]. At most ``max_views``,
    evenly spread over the positions (a Halcon user calibrates from a few dozen images, not a hundred
    near-identical ones)."""
    views = []
    for seq in sequences:
        df = cal.sequence(seq)
        if df.empty:
            continue
        pitch = float(cal.plate(seq)["pitch_mm"])
        for pos, g in df.groupby("position"):
            g = g[g[["wl1", "wl2", "wr1", "wr2"]].notna().all(axis=1)]
            if len(g) < MIN_DOTS:
                continue
            obj = np.column_stack([(g["col"] - 1) * pitch, (g["row"] - 1) * pitch, np.zeros(len(g))])
            views.append({"sequence": seq, "position": int(pos), "obj": obj.astype(np.float32),
                          "l": g[["wl1", "wl2"]].to_numpy(np.float32), "r": g[["wr1", "wr2"]].to_numpy(np.float32)})
    if max_views is not None and len(views) > max_views:
        keep = np.unique(np.round(np.linspace(0, len(views) - 1, max_views)).astype(int))
        views = [views[k] for k in keep]
    return views


def calibrate_stereo(views: list[dict], image_size: tuple[int, int], variant: str = "standard", *,
                     f_guess_px: float | None = None, fix_focal: bool = False, spread: bool = True) -> StereoPinhole:
    """``cv2.calibrateCamera`` per camera (with an intrinsic guess), then ``cv2.stereoCalibrate`` (intrinsics
    fixed). ``f_guess_px``: the initial focal length (default: the image width); ``fix_focal`` keeps it;
    ``spread``: σ(f) computed (:func:`_calibrate_camera`)."""
    if variant not in VARIANTS:
        raise SlmlabError(f"unknown pinhole distortion variant {variant!r}; use one of {', '.join(VARIANTS)}")
    if len(views) < 3:
        raise SlmlabError(f"only {len(views)} usable plate views (>= {MIN_DOTS} dots in both images); "
                          "the pinhole model needs at least 3")
    w, h = image_size
    f = f_guess_px or float(w)
    k0 = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1.0]])
    flags = cv2.CALIB_USE_INTRINSIC_GUESS | VARIANTS[variant] | (cv2.CALIB_FIX_FOCAL_LENGTH if fix_focal else 0)
    # near-telecentric: normalised coordinates span only about ±0.01, so the distortion terms' gradients are
    # tiny and OpenCV's ε test stops before the first step; iterate a fixed number of times instead
    crit = (cv2.TERM_CRITERIA_COUNT, 100, 0.0)
    obj = [v["obj"] for v in views]
    out = {}
    for side in "lr":
        pts = [v[side] for v in views]
        out[side] = _calibrate_camera((obj, pts, (w, h), k0.copy(), None), dict(flags=flags, criteria=crit), spread)
    # the relative pose of two near-telecentric views is poorly conditioned and OpenCV's stereoCalibrate
    # takes no extrinsic guess: try its refinement options and keep the lowest RMS (recorded)
    best = best_refined = None
    options = {"fixed intrinsics": cv2.CALIB_FIX_INTRINSIC,
               "refined intrinsics, focal fixed": cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_FIX_FOCAL_LENGTH}
    tries = {"fixed intrinsics": [("100 iterations", crit)],
             "refined intrinsics, focal fixed": [("until converged", (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-9))]}
    for name, fl in options.items():
        for c_name, c in tries[name]:
            try:
                # copies: OpenCV writes refined intrinsics into these arrays in place
                res = cv2.stereoCalibrate(obj, [v["l"] for v in views], [v["r"] for v in views], out["l"][0].copy(),
                                          out["l"][1].copy(), out["r"][0].copy(), out["r"][1].copy(), (w, h),
                                          flags=fl | VARIANTS[variant], criteria=c)
            except cv2.error:
                continue
            if np.isfinite(res[0]) and (best is None or res[0] < best[0][0]):
                best = (res, f"{name}, {c_name}")
            if "refined" in name and np.isfinite(res[0]) and (best_refined is None or res[0] < best_refined[0][0]):
                best_refined = (res, f"{name}, {c_name}")
    # and a two-stage recipe: the stereo-refined intrinsics of the best refining option, then a fixed-intrinsics solve
    if best_refined is not None:
        r0 = best_refined[0]
        try:
            res = cv2.stereoCalibrate(obj, [v["l"] for v in views], [v["r"] for v in views], r0[1].copy(), r0[2].copy(),
                                      r0[3].copy(), r0[4].copy(), (w, h), flags=cv2.CALIB_FIX_INTRINSIC | VARIANTS[variant],
                                      criteria=crit)
            if np.isfinite(res[0]) and (best is None or res[0] <= best[0][0]):
                best = (res, f"{best_refined[1]}, then fixed intrinsics")
        except cv2.error:
            pass
    if best is None:
        raise SlmlabError("OpenCV's stereoCalibrate failed on these views; add views (more stage positions, or the plate "
                          "held at tilts)")
    (rms, K1, d1, K2, d2, R, T, _, _), how = best
    return StereoPinhole(K1, d1, K2, d2, R, T, float(rms), variant, (out["l"][2], out["r"][2]), how)


#: OpenCV flags of a camera without distortion (the first stage of a known target's calibration)
NO_DISTORTION = cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST
#: a known target's calibration runs until converged (its first guess, a DLT, is far from the optimum)
TARGET_ITERATIONS = 3000


def _target_criteria(iterations: int) -> tuple:
    """OpenCV's stopping rule for a known target's fits: ``iterations`` Levenberg–Marquardt steps at most."""
    return (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, int(iterations), 1e-10)


def _normaliser(x: np.ndarray) -> np.ndarray:
    """Hartley's normalisation of points ``(n, k)``: the ``(k + 1) × (k + 1)`` matrix that moves their centroid to
    0 and scales their mean distance from it to ``√k``."""
    k = x.shape[1]
    c = x.mean(axis=0)
    s = np.sqrt(k) / np.mean(np.linalg.norm(x - c, axis=1))
    t = np.diag([s] * k + [1.0])
    t[:k, k] = -s * c
    return t


def dlt(obj: np.ndarray, img: np.ndarray) -> np.ndarray:
    """The 3 × 4 projection matrix ``P`` (``[img, 1] ~ P · [obj, 1]``) of one camera by the direct linear
    transform: linear least squares on Hartley-normalised coordinates (the right singular vector of the
    smallest singular value). ``obj`` ``(n, 3)`` [mm], not coplanar; ``img`` ``(n, 2)`` [px]; ``n >= 6``."""
    obj, img = np.asarray(obj, float), np.asarray(img, float)
    to, ti = _normaliser(obj), _normaliser(img)
    x = np.column_stack([obj, np.ones(len(obj))]) @ to.T
    u = (np.column_stack([img, np.ones(len(img))]) @ ti.T)[:, :2]
    a = np.zeros((2 * len(obj), 12))
    a[0::2, 0:4], a[0::2, 8:12] = x, -u[:, :1] * x
    a[1::2, 4:8], a[1::2, 8:12] = x, -u[:, 1:2] * x
    p = np.linalg.svd(a, full_matrices=False)[2][-1].reshape(3, 4)
    return np.linalg.inv(ti) @ p @ to


def dlt_intrinsics(p: np.ndarray, obj: np.ndarray) -> tuple[np.ndarray, float]:
    """The intrinsic guess ``K`` (positive focal lengths, no skew) of a projection matrix ``p`` by
    ``cv2.decomposeProjectionMatrix``, and the share of the points ``obj`` ``(n, 3)`` in front of that camera:
    near 0 where the image is a mirror image of ``obj`` (no pinhole camera sees one)."""
    p = p if np.linalg.det(p[:, :3]) > 0 else -p
    depth = (np.column_stack([obj, np.ones(len(obj))]) @ p.T)[:, 2]
    k = cv2.decomposeProjectionMatrix(p)[0]
    k = k @ np.diag(np.sign(np.diag(k)))
    k = k / k[2, 2]
    k[0, 1] = 0.0
    return k, float(np.mean(depth > 0))


def target_view(cal: CalibrationSet) -> tuple[dict, pd.DataFrame, np.ndarray]:
    """A known-target set as one view of one 3D target (module docstring): the view (``obj``: the dots' world
    positions less their mean [mm]; ``l``, ``r``: their image points [px]), the rows used and their world
    positions ``(n, 3)`` [mm]. Raises naming the reason where the dots do not determine a pinhole camera."""
    pts, world, mode = world_positions(cal)
    if mode == "moves":
        raise SlmlabError("the dots' world positions are not known (stage moves of a plate whose place is unknown); "
                          "a pinhole camera from one 3D view needs a known target or a Z stack of a plate", cal.path)
    if len(pts) < MIN_DOTS:
        raise SlmlabError(f"only {len(pts)} dots seen in both images with a known target position; the pinhole "
                          f"model needs at least {MIN_DOTS}", cal.path)
    sv = np.linalg.svd(world - world.mean(axis=0), compute_uv=False)
    if sv[2] <= 1e-4 * sv[0]:
        raise SlmlabError("the known target's dots lie in one plane (one pose of a flat target): one view of a "
                          "plane cannot tell a pinhole camera's focal length from its distance; image the target "
                          "at two or more stage Z positions, or use a target with steps", cal.path)
    view = {"sequence": "+".join(dict.fromkeys(pts["sequence"])), "position": 1,
            "obj": world - world.mean(axis=0), "l": pts[["wl1", "wl2"]].to_numpy(float),
            "r": pts[["wr1", "wr2"]].to_numpy(float)}
    return view, pts, world


def _mirrored(view: dict, path=None) -> bool:
    """Whether both images are mirror images of the target (DLT cheirality, :func:`dlt_intrinsics`)."""
    front = [dlt_intrinsics(dlt(view["obj"], view[side]), view["obj"])[1] for side in "lr"]
    if (front[0] > 0.5) != (front[1] > 0.5):
        raise SlmlabError("one image is a mirror image of the other (the left and right views disagree in "
                          "handedness); flip one camera's image coordinates", path)
    return front[0] < 0.5


def _centred(k: np.ndarray, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """``K`` with its principal point moved to the image centre, and the shift [px] that does it (add it to the
    image points; OpenCV refuses an initial principal point outside the image)."""
    shift = np.array([(size[0] - 1) / 2 - k[0, 2], (size[1] - 1) / 2 - k[1, 2]])
    k = np.array(k, float)
    k[:2, 2] += shift
    return k, shift


def _target_cameras(view: dict, size: tuple[int, int], fix: int, path=None,
                    iterations: int = TARGET_ITERATIONS, spread: bool = True) -> tuple[np.ndarray, bool, dict]:
    """Both cameras on one non-planar view, up to the standard distortion terms: the DLT's intrinsic guess
    refined by ``cv2.calibrateCamera`` without distortion, then with the standard terms (the variants' terms
    start from there: straight from the DLT the optimiser stalls). Returns the target points as given to
    OpenCV (mirrored where the images are), whether they are mirrored, and per camera ``(K, distortion, σ(f))``
    (σ NaN without ``spread``)."""
    mirrored = _mirrored(view, path)
    obj = view["obj"] * ([1.0, 1.0, -1.0] if mirrored else 1.0)
    cams = {}
    for side in "lr":
        cam = (dlt_intrinsics(dlt(obj, view[side]), obj)[0], None, np.nan)
        cam = _refine_camera(obj, view[side], size, cam, NO_DISTORTION | fix, iterations, spread=False)
        cams[side] = _refine_camera(obj, view[side], size, cam, fix, iterations, spread=spread)
    return obj, mirrored, cams


def _refine_camera(obj: np.ndarray, img: np.ndarray, size: tuple[int, int], cam: tuple, flags: int,
                   iterations: int = TARGET_ITERATIONS, *, spread: bool = True) -> tuple:
    """One camera ``(K, distortion, σ(f))`` refined by ``cv2.calibrateCameraExtended`` on one view, from ``cam``,
    its principal point moved to the image centre while OpenCV works (:func:`_centred`); ``spread``: σ(f)
    computed (:func:`_calibrate_camera`)."""
    k, shift = _centred(cam[0], size)
    args = ([obj.astype(np.float32)], [(img + shift).astype(np.float32)], size, k,
            None if cam[1] is None else cam[1].copy())
    kw = dict(flags=cv2.CALIB_USE_INTRINSIC_GUESS | flags, criteria=_target_criteria(iterations))
    k, d, std = _calibrate_camera(args, kw, spread)
    k = k.copy()
    k[:2, 2] -= shift
    return k, d, std


def _calibrate_camera(args: tuple, kw: dict, spread: bool) -> tuple:
    """``(K, distortion, σ(f))`` of one camera by ``cv2.calibrateCameraExtended``, or without ``spread`` (a fit
    whose σ nobody reads: held-out folds, a step the next one refines) by ``cv2.calibrateCamera``: the same fit,
    bit for bit, without the covariance (the zoo's camera fits: 12 % less time); σ(f) is then NaN."""
    if spread:
        _, k, d, _, _, std_in, _, _ = cv2.calibrateCameraExtended(*args, **kw)
        return k, d, float(std_in[0, 0])
    _, k, d, _, _ = cv2.calibrateCamera(*args, **kw)
    return k, d, float("nan")


def calibrate_target(view: dict, image_size: tuple[int, int], variant: str = "thin-prism", *,
                     fix_focal: bool = False, path=None, start=None,
                     iterations: int = TARGET_ITERATIONS, spread: bool = True) -> tuple[StereoPinhole, bool]:
    """A stereo pinhole pair from one view of a non-planar target (:func:`target_view`; module docstring):
    each camera by :func:`_target_cameras` (or from ``start``, its result) and the variant's terms, then
    ``cv2.stereoCalibrate`` with the intrinsics refined jointly or fixed, the lower RMS kept; every OpenCV fit
    stops after ``iterations`` steps; ``spread``: σ(f) computed, at the last camera step (with ``start`` and the
    ``standard`` variant, the σ ``start`` carries). Returns the pair (in the target's frame, mirrored where the
    images are) and whether the images are mirror images of it."""
    if variant not in VARIANTS:
        raise SlmlabError(f"unknown pinhole distortion variant {variant!r}; use one of {', '.join(VARIANTS)}")
    fix = cv2.CALIB_FIX_FOCAL_LENGTH if fix_focal else 0
    # σ(f) where it is reported: the last camera refinement's (the variant's terms refine the standard ones)
    obj, mirrored, cams = start or _target_cameras(view, image_size, fix, path, iterations,
                                                   spread=spread and not VARIANTS[variant])
    if VARIANTS[variant]:
        cams = {side: _refine_camera(obj, view[side], image_size, cams[side], VARIANTS[variant] | fix, iterations,
                                     spread=spread) for side in "lr"}
    (k1, s1), (k2, s2) = (_centred(cams[side][0], image_size) for side in "lr")
    img1, img2 = (view["l"] + s1).astype(np.float32), (view["r"] + s2).astype(np.float32)
    best = None
    for how, flags in (("refined intrinsics", cv2.CALIB_USE_INTRINSIC_GUESS | fix),
                       ("fixed intrinsics", cv2.CALIB_FIX_INTRINSIC)):
        res = cv2.stereoCalibrate([obj.astype(np.float32)], [img1], [img2], k1.copy(), cams["l"][1].copy(),
                                  k2.copy(), cams["r"][1].copy(), image_size, flags=flags | VARIANTS[variant],
                                  criteria=_target_criteria(iterations))
        if np.isfinite(res[0]) and (best is None or res[0] < best[0][0]):
            best = (res, how)
    if best is None:
        raise SlmlabError("OpenCV's stereoCalibrate failed on the known target; check the target's x_mm, y_mm, "
                          "z_mm and the stage positions", path)
    (rms, k1, d1, k2, d2, r, t, _, _), how = best
    k1, k2 = k1.copy(), k2.copy()
    k1[:2, 2] -= s1
    k2[:2, 2] -= s2
    return StereoPinhole(k1, d1, k2, d2, r, t, float(rms), variant, (cams["l"][2], cams["r"][2]), how), mirrored


def fit_stage_map(cal: CalibrationSet, stereo: StereoPinhole, kind: str = "affine"):
    """The map ``stage = A · camera + t`` fitted on the axis sequences' displacements (``affine``: any 3 × 3
    ``A``, absorbing the stage's skew and scale errors; ``rigid``: an orthogonal ``A``, a rotation or a
    reflection, whichever fits: :func:`orthogonal_map`). ``t`` puts the plate centre seen at
    the X sequence's first position (:func:`_origin_rows`) at its commanded stage position (an arbitrary but
    fixed origin)."""
    if kind not in STAGE_MAPS:
        raise SlmlabError(f"unknown stage map {kind!r}; use one of {', '.join(STAGE_MAPS)}")
    dps, das = [], []
    for seq in ("X", "Y", "Z"):
        df = cal.sequence(seq)
        df = df[df[["wl1", "wl2", "wr1", "wr2"]].notna().all(axis=1)]
        if df["position"].nunique() < 2:
            continue
        p = stereo.triangulate(df[["wl1", "wl2", "wr1", "wr2"]].to_numpy(float))
        dp, da, _ = displacements(df, p)
        dps.append(dp)
        das.append(da)
    if not dps:
        raise SlmlabError("the pinhole model needs X, Y or Z sequences (stage moves) to map the cameras to the stage")
    dp, da = np.vstack(dps), np.vstack(das)
    check_axes(da, "moves", cal.path)
    a = np.linalg.lstsq(dp, da, rcond=None)[0].T if kind == "affine" else orthogonal_map(dp, da)
    x1 = _origin_rows(cal)
    centre = stereo.triangulate(x1[["wl1", "wl2", "wr1", "wr2"]].to_numpy(float)).mean(axis=0)
    t = x1[["stage_x_mm", "stage_y_mm", "stage_z_mm"]].to_numpy(float)[0] - a @ centre
    return a, t


def orthogonal_map(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """The orthogonal 3 × 3 ``A`` with ``dst ≈ src · Aᵀ`` in least squares (``src, dst`` ``(n, 3)``): the
    orthogonal Procrustes solution ``(U Vᵀ)ᵀ`` of ``srcᵀ dst = U Σ Vᵀ``, a rotation or a reflection, whichever
    fits. A mirrored image makes the camera frame a mirror image of the stage's; a rotation forced on it
    (Kabsch's ``det = +1``) turns its least determined axis backwards."""
    u, _, vt = np.linalg.svd(np.asarray(src, float).T @ np.asarray(dst, float))
    return (u @ vt).T


def fit_world_map(p: np.ndarray, world: np.ndarray, kind: str = "affine") -> tuple[np.ndarray, np.ndarray]:
    """The map ``world = A · camera + t`` of a known-target set, fitted on its dots' triangulated camera-frame
    positions ``p`` and their world positions ``world`` ``(n, 3)`` [mm]: ``affine`` (12 parameters) or
    ``rigid`` (``A`` orthogonal, :func:`orthogonal_map`)."""
    if kind not in STAGE_MAPS:
        raise SlmlabError(f"unknown stage map {kind!r}; use one of {', '.join(STAGE_MAPS)}")
    if not np.isfinite(p).all():   # a pinhole pair that does not describe the views triangulates to nothing
        raise SlmlabError(f"the pinhole pair triangulates {int((~np.isfinite(p).all(axis=1)).sum())} of {len(p)} dots "
                          "to no point (its calibration does not describe these views)")
    if kind == "affine":
        sol = np.linalg.lstsq(np.column_stack([p, np.ones(len(p))]), world, rcond=None)[0]
        return sol[:3].T, sol[3]
    a = orthogonal_map(p - p.mean(axis=0), world - world.mean(axis=0))
    return a, world.mean(axis=0) - a @ p.mean(axis=0)


def _origin_rows(cal: CalibrationSet) -> pd.DataFrame:
    """The rows that fix the stage map's origin: the first position of the X sequence (else Y, else Z) with
    dots seen in both images (the plate may be out of view at a sequence's first positions)."""
    for seq in ("X", "Y", "Z"):
        df = cal.sequence(seq)
        df = df[df[["wl1", "wl2", "wr1", "wr2"]].notna().all(axis=1)]
        if not df.empty:
            return df[df["position"] == df["position"].min()]
    raise SlmlabError("no X, Y or Z position has a dot seen in both images; the pinhole model needs stage moves "
                      "of a plate in view", cal.path)


def _held_back_error(cal: CalibrationSet, variant: str, f_guess: float) -> float:
    """RMS displacement error [mm] on every 3rd stage position, the rest used to calibrate."""
    pts = cal.points
    held = pts["sequence"].isin(["X", "Y", "Z"]) & (pts["position"] % 3 == 0)
    train = CalibrationSet(pts[~held].reset_index(drop=True), cal.meta)
    test_pts = pts[held | (pts["position"] == 1)].reset_index(drop=True)
    stereo = calibrate_stereo(plate_views(train), train.image_size_px, variant, f_guess_px=f_guess, spread=False)
    a, t = fit_stage_map(train, stereo)
    errs = []
    for seq in ("X", "Y", "Z"):
        df = test_pts[(test_pts["sequence"] == seq) & test_pts[["wl1", "wl2", "wr1", "wr2"]].notna().all(axis=1)]
        if df["position"].nunique() < 2:
            continue
        p = stereo.triangulate(df[["wl1", "wl2", "wr1", "wr2"]].to_numpy(float)) @ a.T
        dp, da, _ = displacements(df, p)
        errs.append(dp - da)
    return float(np.sqrt(np.mean(np.vstack(errs) ** 2))) if errs else float("inf")


def _held_back_dots_errors(view: dict, pts: pd.DataFrame, world: np.ndarray, size, stage_map: str,
                           fix_focal: bool) -> dict:
    """Per variant, the RMS 3D error [mm] of a known target's every 3rd dot (at every stage position), the rest
    used to calibrate (:func:`calibrate_target`, :func:`fit_world_map`); ``inf`` where OpenCV fails."""
    _, code = np.unique(dot_labels(pts), return_inverse=True)
    held = code % 3 == 0
    train = {**view, **{k: view[k][~held] for k in ("obj", "l", "r")}}
    w = np.column_stack([view["l"], view["r"]])
    scores = {v: float("inf") for v in VARIANTS}
    try:
        start = _target_cameras(train, size, cv2.CALIB_FIX_FOCAL_LENGTH if fix_focal else 0, spread=False)
    except (cv2.error, SlmlabError):
        return scores
    for v in VARIANTS:
        try:
            stereo, _ = calibrate_target(train, size, v, fix_focal=fix_focal, start=start, spread=False)
            a, t = fit_world_map(stereo.triangulate(w[~held]), world[~held], stage_map)
        except (cv2.error, SlmlabError):   # a variant that triangulates to nothing scores inf, the others stand
            continue
        scores[v] = float(np.sqrt(np.mean((stereo.triangulate(w[held]) @ a.T + t - world[held]) ** 2)))
    return scores


def _z_stack_only(cal: CalibrationSet) -> bool:
    """Whether the set is a Z stack of a plate of known lattice and nothing else moves (its dots' world
    positions known: :func:`slmlab.models.frames.world_positions`), calibrated as one view of a 3D target."""
    try:
        return world_positions(cal)[2] == "zstack"
    except SlmlabError:
        return False


def _choose(scores: dict, fallback: str) -> str:
    """The variant with the smallest finite held-back error (``fallback`` where none is finite)."""
    finite = {k: v for k, v in scores.items() if np.isfinite(v)}
    return min(finite, key=finite.get) if finite else fallback


@register
class PinholeModel(Model):
    """The traditional pinhole stereo model, calibrated with OpenCV from the plate views of a set, or from a
    known target (module docstring)."""

    name = "pinhole"
    summary = ("traditional stereo pinhole model (OpenCV calibrateCamera + stereoCalibrate, triangulation; a map to "
               "the stage, or a known target's DLT and world)")
    accuracy_rank = 50
    units = {"K1": "px", "K2": "px", "d1": "- (OpenCV's distortion coefficients, dimensionless)",
             "d2": "- (OpenCV's distortion coefficients, dimensionless)", "T": "mm", "R": "-", "A": "-", "t": "mm",
             "rms_px": "px", "f_std_px": "px", "variant": "- (a name)", "stereo_option": "- (a name)"}

    def __init__(self, stereo: StereoPinhole, a: np.ndarray, t: np.ndarray, **kw):
        super().__init__(**kw)
        self.stereo, self.a, self.t = stereo, np.asarray(a, float), np.asarray(t, float)

    @classmethod
    def fit(cls, cal: CalibrationSet, *, variant: str | None = None, stage_map: str = "affine",
            views_from: tuple[str, ...] | None = None, fix_focal: bool = False, f_guess_px: float | None = None,
            iterations: int = TARGET_ITERATIONS, spread: bool = True, **_):
        """``variant`` ``None`` chooses by held-back positions (a known target: held-back dots);
        ``stage_map`` the map to the stage (or, for a known target, to the world: :func:`fit_world_map`);
        ``views_from`` the sequences used as target views (default: ``T`` if the set has tilted poses, else X,
        Y, Z; a known target uses all its sequences as one view); ``f_guess_px`` defaults to ``L / pixel`` of a
        CMO microscope with a 300 mm perspective distance and 3 µm pixels (a known target: from its DLT);
        ``iterations`` caps each of OpenCV's fits on a known target or a Z stack (one 3D view); without
        ``spread`` the focal lengths' σ is not computed (NaN: the same fit, faster; held-out folds)."""
        try:
            iterations = int(iterations) if float(iterations) == int(iterations) >= 1 else None
        except (TypeError, ValueError, OverflowError):
            iterations = None
        if iterations is None:
            raise SlmlabError("the pinhole option iterations must be a whole number of at least 1 (OpenCV's fits "
                              "stop after that many steps)")
        with one_thread():  # (calibrate pins threads too; this covers a direct call of fit)
            if cal.known_target or _z_stack_only(cal):
                return cls._fit_target(cal, variant=variant, stage_map=stage_map, fix_focal=fix_focal,
                                       iterations=iterations, spread=spread)
            return cls._fit(cal, variant=variant, stage_map=stage_map, views_from=views_from, fix_focal=fix_focal,
                            f_guess_px=f_guess_px, spread=spread)

    @classmethod
    def _fit(cls, cal, *, variant, stage_map, views_from, fix_focal, f_guess_px, spread):
        f_guess = f_guess_px or 1e5
        if views_from is None:
            views_from = ("T",) if not cal.sequence("T").empty else ("X", "Y", "Z")
        scores = {}
        if variant is None:
            if views_from != ("X", "Y", "Z"):
                variant = "standard"
            else:
                for v in VARIANTS:
                    try:
                        scores[v] = _held_back_error(cal, v, f_guess)
                    except (cv2.error, SlmlabError):
                        scores[v] = float("inf")
                variant = _choose(scores, "standard")
        stereo = calibrate_stereo(plate_views(cal, views_from), cal.image_size_px, variant, f_guess_px=f_guess,
                                  fix_focal=fix_focal, spread=spread)
        a, t = fit_stage_map(cal, stereo, stage_map)
        return cls(stereo, a, t, options={"variant": variant, "stage_map": stage_map, "views_from": list(views_from),
                                          "fix_focal": fix_focal, "f_guess_px": f_guess, "spread": spread},
                   calibration={**_report(stereo, scores), "held_back": "every 3rd stage position"})

    @classmethod
    def _fit_target(cls, cal, *, variant, stage_map, fix_focal, iterations, spread):
        view, pts, world = target_view(cal)
        scores = {}
        if variant is None:
            scores = _held_back_dots_errors(view, pts, world, cal.image_size_px, stage_map, fix_focal)
            variant = _choose(scores, "thin-prism")
        try:
            stereo, mirrored = calibrate_target(view, cal.image_size_px, variant, fix_focal=fix_focal, path=cal.path,
                                                iterations=iterations, spread=spread)
        except cv2.error as exc:
            raise SlmlabError(f"OpenCV could not calibrate a pinhole camera on the known target "
                              f"({str(exc).strip().splitlines()[-1]}); check x_mm, y_mm, z_mm", cal.path) from None
        a, t = fit_world_map(stereo.triangulate(np.column_stack([view["l"], view["r"]])), world, stage_map)
        sequences = list(dict.fromkeys(pts["sequence"]))
        return cls(stereo, a, t, options={"variant": variant, "stage_map": stage_map, "views_from": sequences,
                                          "fix_focal": fix_focal, "f_guess_px": None, "iterations": iterations,
                                          "spread": spread},
                   calibration={**_report(stereo, scores), "held_back": "every 3rd dot",
                                "world_from": f"{'known target' if cal.known_target else 'Z stack of a plate'}: "
                                              f"one view of {len(pts)} dots at "
                                              f"{pts.groupby(['sequence', 'position']).ngroups} stage position(s)",
                                "image_mirrored": mirrored})

    def describe(self) -> str:
        world = self.calibration.get("world_from", "stage moves").split(":")[0]
        return (f"pinhole ({self.options.get('variant', self.stereo.variant)} distortion, "
                f"{self.options.get('stage_map', 'affine')} map from {world})")

    def reconstruct(self, w: np.ndarray) -> np.ndarray:
        return self.stereo.triangulate(np.atleast_2d(w)) @ self.a.T + self.t

    def parameters_dict(self) -> dict:
        return {**self.stereo.as_dict(), "A": self.a.tolist(), "t": self.t.tolist()}

    @classmethod
    def from_parameters(cls, parameters, calibration, options):
        return cls(StereoPinhole.from_dict(parameters), parameters["A"], parameters["t"], calibration=calibration,
                   options=options)


def _report(stereo: StereoPinhole, scores: dict) -> dict:
    """What a pinhole calibration reports in the model file (``None`` where a number is not finite)."""
    return {"held_back_rms_mm": {k: (float(v) if np.isfinite(v) else None) for k, v in scores.items()},
            "stereo_rms_px": stereo.rms_px, "stereo_option": stereo.stereo_option,
            "focal_px": [float(stereo.K1[0, 0]), float(stereo.K2[0, 0])],
            "focal_std_px": _json_std(stereo.f_std_px),
            "focal_relative_std": _json_std(np.divide(stereo.f_std_px, [stereo.K1[0, 0], stereo.K2[0, 0]]))}


def views_table(views: list[dict]) -> pd.DataFrame:
    """How many points each view has (for reports)."""
    return pd.DataFrame([{"sequence": v["sequence"], "position": v["position"], "points": len(v["obj"])} for v in views])
