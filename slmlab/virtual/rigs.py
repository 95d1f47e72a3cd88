"""A zoo of virtual stereo rigs with truth, beside the CMO microscope (:mod:`slmlab.virtual.microscope` for the microscope).

Every rig is drawn from physics, not from a calibration model: two cameras, each a central projection
through its entrance pupil onto its own sensor, with its own lens distortion, a thin lens that sets its
focus and its defocus blur, and, for the stereo-PIV rig, exact refraction through a flat wall. They all
answer the protocol the simulator needs from :class:`slmlab.virtual.microscope.Microscope` (``project``,
``visible``, ``triangulate``, the stage and the plates, the dot finder's noise, ``as_dict``), so one set of
sessions, plates, stage and noise serves every rig.

The rigs
--------
``greenough``
    A Greenough stereo microscope: two objectives whose axes are inclined by ±2.5–4° from the vertical
    (a convergence of 5–8°), each with its own entrance pupil at the working distance (60–120 mm: true
    perspective, magnification changing by about 1/WD per mm of depth) and its image plane perpendicular
    to its *own* axis, so the object plane ``z = 0`` is seen with keystone. Object pixel 1.5–5 µm, a field of
    a few mm, object-side NA 0.015–0.035. Each view has its own radial and decentring distortion.
``stereo-dic``
    A stereo-DIC pair: two machine-vision cameras (2–4 Mpx) with 35–75 mm lenses at f/8–16, at ±10–20°
    from the normal of the specimen, 300–800 mm away (a field of 50–200 mm, a wide baseline), radial
    distortion ``k1, k2`` and a small tangential term.
``stereo-piv``
    A stereo-PIV pair at ±30–45° (in air) from the normal of the light sheet ``z = 0``, viewing it through a
    flat wall (5–20 mm of glass or acrylic, n = 1.49–1.52) into water (n = 1.333), the sheet 20–100 mm behind
    the wall. Rays are refracted exactly (Snell's law at both faces, per point: the transverse invariant
    ``n·sin θ`` is conserved across parallel interfaces and solved for by Newton's method to machine
    precision, :func:`refraction_invariant`). The sensors are tilted (Scheimpflug) so that the light sheet
    is in focus across the field: the sensor is the plane fitted through the thin-lens images of the
    sheet's *apparent* points (the Coddington sagittal and tangential images of a flat interface, averaged).
    What is left is the wall's astigmatism, which no sensor tilt removes.

Frames and units
----------------
rig frame
    ``x, y`` in the nominal object (focal, light-sheet) plane, ``z`` towards the cameras [mm]; camera 1
    ("l") sits at ``-x``, camera 2 ("r") at ``+x``.
camera frame
    ``x`` right, ``y`` down, ``z`` forward along the optical axis (OpenCV's); the image is read out
    upright (``w1`` along camera ``x``, ``w2`` along camera ``y``, origin at the top-left pixel) [px].
stage frame
    as on the microscope: the affine frame of the stage's actual axes, expressed in the rig frame.

Distortion (Brown–Conrady, on the ideal image plane before any sensor tilt, as OpenCV's tilted model) is
given in pixels at the image corner: with normalised coordinates scaled so that the corner is at radius 1,
``Δ = (k1 ρ² + k2 ρ⁴)·u + tangential(p1, p2)`` [px].

Focus and blur
--------------
Each camera is a thin lens of focal length ``f`` and entrance pupil ``D`` focused on its aim point (on
``z = 0``). A point's blur radius on the sensor is ``(D/2)·|s − s'|/s'`` along its chief ray, with ``s'``
the image distance of the point (of its apparent point behind the wall) and ``s`` that of the sensor; the
sagittal and tangential images of an oblique view through a wall differ, and the blur is the larger of
the defocus of their mean and half their difference. The dot finder's noise grows with blur: the
:class:`slmlab.virtual.microscope.CentroidNoise` of each rig reaches its ``at_dof_edge_px`` at a blur radius of
:data:`DOF_BLUR_PX`, which defines the rig's depth of field.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace
from typing import ClassVar

import numpy as np

from ..errors import SlmlabError
from .microscope import CentroidNoise, Plate, Stage
from .microscope import from_dict as microscope_from_dict

__all__ = ["DOF_BLUR_PX", "WATER_INDEX", "RANGES", "SENSORS", "ViewErrors", "Camera", "StereoRig", "GreenoughRig",
           "StereoDicRig", "StereoPivRig", "RIG_CLASSES", "RIGS", "make_rig", "random_rig", "rig_by_name", "rig_from_dict",
           "refraction_invariant", "look_at", "sized_plate", "with_plates"]

#: blur radius [px] at the edge of a rig's depth of field (where the dot finder's noise reaches at_dof_edge_px)
DOF_BLUR_PX = 5.0
#: refractive index of water
WATER_INDEX = 1.333

#: the ranges :func:`random_rig` draws every physical parameter from (uniform unless a tuple of choices)
RANGES = {
    "greenough": {"half_angle_deg": (2.5, 4.0), "working_distance_mm": (60.0, 120.0),
                  "object_pixel_mm": (0.0015, 0.005), "numerical_aperture": (0.015, 0.035),
                  "field_mm": (2.0, 8.0), "radial_px": (3.0, 1.0), "tangential_px": 1.0},
    "stereo-dic": {"half_angle_deg": (10.0, 20.0), "focal_mm": (35.0, 50.0, 60.0, 75.0),
                   "standoff_mm": (300.0, 800.0), "field_mm": (50.0, 200.0), "f_number": (8.0, 16.0),
                   "radial_px": (15.0, 3.0), "tangential_px": 1.5},
    "stereo-piv": {"half_angle_deg": (30.0, 45.0), "focal_mm": (50.0, 60.0, 85.0, 105.0),
                   "field_mm": (50.0, 200.0), "f_number": (5.6, 11.0), "wall_thickness_mm": (5.0, 20.0),
                   "glass_index": (1.49, 1.52), "water_depth_mm": (20.0, 100.0), "sheet_thickness_mm": (1.0, 3.0),
                   "radial_px": (10.0, 2.0), "tangential_px": 1.0},
}
#: sensors ``(width, height, pixel_mm)`` a rig may carry
SENSORS = {
    "greenough": ((1600, 1200, 0.0044), (2048, 1536, 0.00345), (1920, 1200, 0.00586), (2448, 2048, 0.00345)),
    "stereo-dic": ((1624, 1236, 0.0044), (1920, 1200, 0.00586), (2048, 1536, 0.00345), (2304, 1728, 0.0034)),
    "stereo-piv": ((1920, 1200, 0.00586), (2048, 1536, 0.0055), (2000, 2000, 0.0074)),
}


def look_at(centre: np.ndarray, target: np.ndarray, roll_deg: float = 0.0) -> np.ndarray:
    """3 × 3 rotation whose rows are a camera's ``x`` (right), ``y`` (down), ``z`` (forward) axes in the rig
    frame, for a camera at ``centre`` looking at ``target`` [mm], its ``y`` axis towards the rig's ``-y``,
    then rolled by ``roll_deg`` about its axis [degree]."""
    z = np.asarray(target, float) - np.asarray(centre, float)
    z /= np.linalg.norm(z)
    x = np.cross([0.0, -1.0, 0.0], z)
    x /= np.linalg.norm(x)
    r = np.vstack([x, np.cross(z, x), z])
    c, s = np.cos(np.radians(roll_deg)), np.sin(np.radians(roll_deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ r


def refraction_invariant(rho: np.ndarray, heights: np.ndarray, indices) -> np.ndarray:
    """The transverse invariant ``q = n·sin θ`` of the rays joining two points across parallel layers.

    A ray from one point to another, ``rho`` apart across the layers' normal and crossing layers of
    thicknesses ``heights`` (``(n, k)`` [mm], along the normal) and refractive indices ``indices`` (``k``),
    keeps ``q = n_i sin θ_i`` in every layer (Snell's law), and its lateral travel is
    ``Σ h_i q / sqrt(n_i² − q²) = rho``: monotone and convex in ``q``. Newton's method from the root's right
    (``q`` of the straight line through the lowest-index layer alone, where the sum is ≥ ``rho``) descends
    monotonically to the root; it stops when a step no longer decreases ``q`` (machine precision).
    Returns ``q`` ``(n,)``.
    """
    rho = np.asarray(rho, float)
    h = np.atleast_2d(np.asarray(heights, float))
    n2 = np.asarray(indices, float) ** 2
    k = int(np.argmin(n2))
    q = np.sqrt(n2[k]) * rho / np.hypot(rho, h[:, k])
    for _ in range(200):
        s = np.sqrt(n2 - q[:, None] ** 2)
        f = (h * q[:, None] / s).sum(axis=1) - rho
        fp = (h * n2 / s ** 3).sum(axis=1)
        new = np.maximum(q - f / fp, 0.0)
        done = ~(new < q)
        q = np.where(done, q, new)
        if done.all():
            break
    return q


@dataclass(frozen=True)
class ViewErrors:
    """How one view departs from the rig's nominal design.

    Attributes
    ----------
    radial_px
        ``(k1, k2)``: radial distortion at the image corner (``ρ = 1``) from the ``ρ²`` and ``ρ⁴`` terms [px].
    tangential_px
        ``(p1, p2)``: decentring (tangential) distortion at the corner [px].
    roll_deg
        camera rotation about its optical axis [degree].
    principal_offset_px
        where the optical axis meets the sensor, from the image centre [px].
    aim_offset_mm
        where the optical axis meets ``z = 0``, from the rig's origin ``(x, y)`` [mm].
    angle_error_deg
        departure of the axis's inclination from the nominal one [degree].
    distance_error
        relative departure of the working distance (and so of the magnification) from the nominal one [-].
    """

    radial_px: tuple[float, float] = (0.0, 0.0)
    tangential_px: tuple[float, float] = (0.0, 0.0)
    roll_deg: float = 0.0
    principal_offset_px: tuple[float, float] = (0.0, 0.0)
    aim_offset_mm: tuple[float, float] = (0.0, 0.0)
    angle_error_deg: float = 0.0
    distance_error: float = 0.0


class Camera:
    """One camera: entrance pupil at ``centre`` [mm, rig frame], orientation ``rotation`` (rows: camera axes),
    a thin lens (``focal_mm``, pupil diameter ``pupil_mm``), Brown–Conrady distortion (``radial_px``,
    ``tangential_px`` at the corner), and a sensor plane ``normal · X = offset_mm`` in the camera frame (the
    virtual sensor in front of the pupil, read out upright), with pixels ``pixel_mm`` and the optical axis
    at ``principal_px``. Derived, not stored in files: the rigs rebuild their cameras from their
    physical parameters."""

    def __init__(self, centre, rotation, *, focal_mm, pupil_mm, pixel_mm, size_px, principal_px, radial_px,
                 tangential_px, normal=(0.0, 0.0, 1.0), offset_mm=None, wavelength_um=0.55):
        self.centre = np.asarray(centre, float)
        self.rotation = np.asarray(rotation, float)
        self.focal_mm, self.pupil_mm, self.pixel_mm = float(focal_mm), float(pupil_mm), float(pixel_mm)
        self.size_px, self.principal_px = tuple(size_px), np.asarray(principal_px, float)
        self.radial_px, self.tangential_px = tuple(radial_px), tuple(tangential_px)
        self.wavelength_um = float(wavelength_um)
        n = np.asarray(normal, float)
        self.normal = n / np.linalg.norm(n)
        self.offset_mm = float(offset_mm)
        self.x0 = np.array([0.0, 0.0, self.offset_mm / self.normal[2]])  # where the axis meets the sensor
        e1 = np.array([1.0, 0.0, 0.0]) - self.normal[0] * self.normal
        self.e1 = e1 / np.linalg.norm(e1)
        self.e2 = np.cross(self.normal, self.e1)
        self.px_norm = self.pixel_mm / self.x0[2]  # one pixel in normalised image coordinates
        self.r_ref = 0.5 * np.hypot(*self.size_px) * self.px_norm

    def with_sensor(self, normal, offset_mm) -> "Camera":
        """The same camera with another sensor plane."""
        return Camera(self.centre, self.rotation, focal_mm=self.focal_mm, pupil_mm=self.pupil_mm,
                      pixel_mm=self.pixel_mm, size_px=self.size_px, principal_px=self.principal_px,
                      radial_px=self.radial_px, tangential_px=self.tangential_px, normal=normal,
                      offset_mm=offset_mm, wavelength_um=self.wavelength_um)

    def _shift(self, x, y):
        u, w = x / self.r_ref, y / self.r_ref
        r2 = u * u + w * w
        (k1, k2), (p1, p2) = self.radial_px, self.tangential_px
        radial = k1 * r2 + k2 * r2 * r2
        du = radial * u + 2 * p1 * u * w + p2 * (r2 + 2 * u * u)
        dw = radial * w + p1 * (r2 + 2 * w * w) + 2 * p2 * u * w
        return du * self.px_norm, dw * self.px_norm

    def to_pixels(self, d: np.ndarray) -> np.ndarray:
        """Image coordinates ``(n, 2)`` [px] of camera-frame ray directions ``d (n, 3)`` (``z > 0``)."""
        x, y = d[:, 0] / d[:, 2], d[:, 1] / d[:, 2]
        dx, dy = self._shift(x, y)
        ray = np.column_stack([x + dx, y + dy, np.ones_like(x)])
        s = ray * (self.offset_mm / (ray @ self.normal))[:, None] - self.x0
        return np.column_stack([s @ self.e1, s @ self.e2]) / self.pixel_mm + self.principal_px

    def from_pixels(self, w: np.ndarray, iterations: int = 30) -> np.ndarray:
        """Unit camera-frame directions ``(n, 3)`` of image points ``w (n, 2)`` [px] (distortion inverted by
        fixed-point iteration)."""
        uv = (np.asarray(w, float) - self.principal_px) * self.pixel_mm
        s = self.x0 + uv[:, :1] * self.e1 + uv[:, 1:] * self.e2
        xd, yd = s[:, 0] / s[:, 2], s[:, 1] / s[:, 2]
        x, y = xd.copy(), yd.copy()
        for _ in range(iterations):
            dx, dy = self._shift(x, y)
            x, y = xd - dx, yd - dy
        d = np.column_stack([x, y, np.ones_like(x)])
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    def defocus_px(self, d: np.ndarray, l_s: np.ndarray, l_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Blur radii [px] of points along camera-frame unit directions ``d`` whose (apparent) sagittal and
        tangential distances from the pupil are ``l_s``, ``l_m`` [mm]: the defocus of their mean image from
        the sensor, and half their astigmatic separation (thin lens, pupil diameter ``pupil_mm``)."""
        along = np.linalg.norm(d / d[:, 2:3], axis=1)  # length of the ray per unit of camera z
        sensor = along * self.offset_mm / ((d / d[:, 2:3]) @ self.normal)
        img = [l * self.focal_mm / (l * d[:, 2] - self.focal_mm) for l in (l_s, l_m)]
        mean = (img[0] + img[1]) / 2
        scale = self.pupil_mm / 2 / mean / self.pixel_mm
        return scale * np.abs(sensor - mean), scale * np.abs(img[0] - img[1]) / 2

    @property
    def diffraction_sigma_px(self) -> float:
        """σ of the diffraction Gaussian (0.21 λ / NA on the image side) [px]."""
        na = self.pupil_mm / (2 * self.x0[2])
        return 0.21 * self.wavelength_um * 1e-3 / na / self.pixel_mm


class StereoRig:
    """The protocol every rig answers (and the CMO :class:`~slmlab.virtual.microscope.Microscope` does too), with
    the methods they share. Subclasses are frozen dataclasses of physical parameters that build their two
    cameras (:meth:`_build_cameras`) and say how far the designs should reach in depth (:meth:`depth_mm`)."""

    kind: ClassVar[str] = ""

    def __post_init__(self):
        object.__setattr__(self, "_cache", {})
        object.__setattr__(self, "_cameras", self._build_cameras())

    # ------------------------------------------------------------------ to implement
    def _build_cameras(self) -> dict[str, Camera]:  # pragma: no cover - abstract
        raise NotImplementedError

    def depth_mm(self) -> float:  # pragma: no cover - abstract
        """Half the depth range the calibration designs span [mm]."""
        raise NotImplementedError

    # ------------------------------------------------------------------ rays
    def camera(self, side: str) -> Camera:
        """The camera of view ``side`` ('l' or 'r')."""
        return self._cameras[side]

    def chief_rays(self, points_mm: np.ndarray, camera: Camera):
        """Camera-frame unit directions ``(n, 3)`` of the chief rays from ``camera``'s pupil to rig-frame
        points, and the points' sagittal and tangential (apparent) distances along them [mm]."""
        v = np.atleast_2d(np.asarray(points_mm, float)) - camera.centre
        dist = np.linalg.norm(v, axis=1)
        return (v / dist[:, None]) @ camera.rotation.T, dist, dist

    def rays(self, w: np.ndarray, side: str) -> tuple[np.ndarray, np.ndarray]:
        """Rig-frame origins and unit directions ``(n, 3)`` of the rays in object space that image at
        ``w (n, 2)`` [px] in view ``side``."""
        cam = self.camera(side)
        d = cam.from_pixels(w) @ cam.rotation
        return np.broadcast_to(cam.centre, d.shape).copy(), d

    # ------------------------------------------------------------------ the protocol
    @property
    def image_size_px(self) -> tuple[int, int]:
        """``(width, height)`` [px]."""
        return tuple(int(v) for v in self.camera("l").size_px)

    def project_view(self, points_mm: np.ndarray, side: str) -> np.ndarray:
        """Image coordinates ``(n, 2)`` [px] in view ``side`` of rig-frame points ``(n, 3)`` [mm]."""
        cam = self.camera(side)
        d, _, _ = self.chief_rays(points_mm, cam)
        return cam.to_pixels(d)

    def project(self, points_mm: np.ndarray) -> np.ndarray:
        """Noise-free image coordinates ``(n, 4)`` = ``wl1, wl2, wr1, wr2`` [px] of rig-frame points [mm]."""
        return np.hstack([self.project_view(points_mm, "l"), self.project_view(points_mm, "r")])

    def visible(self, w: np.ndarray, dot_diameter_mm: float) -> np.ndarray:
        """``(n, 2)`` booleans: is the whole dot (at the field centre's scale) inside each image."""
        width, height = self.image_size_px
        margin = dot_diameter_mm * self.px_per_mm() / 2 + 2.0
        out = []
        for k in (0, 2):
            with np.errstate(invalid="ignore"):
                out.append((w[:, k] >= margin) & (w[:, k] <= width - 1 - margin)
                           & (w[:, k + 1] >= margin) & (w[:, k + 1] <= height - 1 - margin))
        return np.column_stack(out)

    def triangulate(self, w: np.ndarray, iterations: int = 20) -> np.ndarray:
        """Rig-frame points ``(n, 3)`` [mm] whose projections best match ``w (n, 4)`` [px] in least squares:
        the true model's inverse. Starts from the midpoint of the two object-space rays (exact but for the
        image noise), then Gauss–Newton on the four image coordinates with a central-difference Jacobian,
        vectorised over points, until the steps fall below 1e-13 of the working scale."""
        w = np.atleast_2d(np.asarray(w, float))
        (o1, d1), (o2, d2) = self.rays(w[:, 0:2], "l"), self.rays(w[:, 2:4], "r")
        b = np.einsum("ij,ij->i", d1, d2)
        r = o2 - o1
        e, f = np.einsum("ij,ij->i", d1, r), np.einsum("ij,ij->i", d2, r)
        den = 1.0 - b * b
        t1, t2 = (e - b * f) / den, (b * e - f) / den
        p = (o1 + t1[:, None] * d1 + o2 + t2[:, None] * d2) / 2
        h = 0.1 / self.px_per_mm()
        tol = 1e-13 * float(np.linalg.norm(self.camera("l").centre))
        for _ in range(iterations):
            res = w - self.project(p)
            jac = np.empty((len(p), 4, 3))
            for k in range(3):
                dp = np.zeros(3)
                dp[k] = h
                jac[:, :, k] = (self.project(p + dp) - self.project(p - dp)) / (2 * h)
            jtj = np.einsum("nik,nil->nkl", jac, jac)
            step = np.linalg.solve(jtj, np.einsum("nik,ni->nk", jac, res)[..., None])[..., 0]
            p = p + step
            if not np.nanmax(np.abs(step), initial=0.0) > tol:
                break
        return p

    def blur_components_px(self, points_mm: np.ndarray, side: str) -> tuple[np.ndarray, np.ndarray]:
        """Defocus blur radius and half the astigmatic separation [px] of rig-frame points in view ``side``."""
        cam = self.camera(side)
        return cam.defocus_px(*self.chief_rays(points_mm, cam))

    def blur_px(self, points_mm: np.ndarray, side: str) -> tuple[np.ndarray, float]:
        """Geometric blur radius ``(n,)`` [px] of rig-frame points in view ``side`` (the larger of defocus and
        astigmatism), and the diffraction Gaussian's σ [px]."""
        defocus, astig = self.blur_components_px(points_mm, side)
        return np.maximum(defocus, astig), self.camera(side).diffraction_sigma_px

    def centroid_sigma_px(self, points_mm: np.ndarray) -> np.ndarray:
        """The dot finder's per-coordinate noise ``(n,)`` [px] at rig-frame points: the rig's
        :class:`CentroidNoise` at each view's blur radius (reaching ``at_dof_edge_px`` at
        :data:`DOF_BLUR_PX`), RMS over the two views."""
        s = [self.noise.sigma_px(self.blur_px(points_mm, side)[0], DOF_BLUR_PX) for side in "lr"]
        return np.sqrt((s[0] ** 2 + s[1] ** 2) / 2)

    def field_centre_mm(self) -> np.ndarray:
        """The rig-frame point seen at the middle of both images, on the focal plane ``z = 0`` [mm]."""
        if "centre" not in self._cache:
            width, height = self.image_size_px
            mid = np.array([[(width - 1) / 2, (height - 1) / 2] * 2])
            p = self.triangulate(mid)[0]
            self._cache["centre"] = np.array([p[0], p[1], 0.0])
        return self._cache["centre"].copy()

    def px_per_mm(self) -> float:
        """The larger image scale at the field centre, over both views and both axes [px/mm]."""
        if "scale" not in self._cache:
            c = np.zeros((1, 3))
            h = 1e-4 * float(np.linalg.norm(self.camera("l").centre))
            w0 = self.project(c)
            jac = [(self.project(c + h * np.eye(3)[k]) - w0) / h for k in (0, 1)]
            self._cache["scale"] = float(max(np.hypot(j[0, 0::2], j[0, 1::2]).max() for j in jac))
        return self._cache["scale"]

    def depth_of_field_mm(self) -> float:
        """Half depth of field at the field centre, along ``z`` [mm]: where the defocus blur (mean of the
        views) reaches :data:`DOF_BLUR_PX`."""
        c, cam = self.field_centre_mm(), self.camera("l")
        # a quarter of the thin-lens estimate (blur NA·dz, object pixel 1/px_per_mm): blur is linear there
        dz = 0.25 * DOF_BLUR_PX / self.px_per_mm() * 2 * float(np.linalg.norm(cam.centre - c)) / cam.pupil_mm
        while True:
            pts = np.vstack([c + [0, 0, dz], c - [0, 0, dz]])
            blur = np.mean([self.blur_components_px(pts, s)[0] for s in "lr"])
            if np.isfinite(blur):  # (a point pushed out of the water: come closer)
                return DOF_BLUR_PX * dz / blur
            dz /= 2

    def field_mm(self) -> tuple[float, float]:
        """Width and height [mm] of the largest rectangle about the field centre (along ``x``, ``y``) that
        both views see whole at every depth within ``±depth_mm()``."""
        if "field" not in self._cache:
            self._cache["field"] = _common_field(self)
        return self._cache["field"]

    # ------------------------------------------------------------------ stage
    def stage_to_microscope(self, stage_mm: np.ndarray, origin_mm: np.ndarray) -> np.ndarray:
        """Rig-frame positions of stage-frame points ``(n, 3)`` [mm], stage zero at ``origin_mm``."""
        return np.asarray(origin_mm) + np.atleast_2d(stage_mm) @ self.stage.axes.T

    def microscope_to_stage(self, points_mm: np.ndarray, origin_mm: np.ndarray) -> np.ndarray:
        """Stage-frame coordinates of rig-frame points ``(n, 3)`` [mm]."""
        return np.linalg.solve(self.stage.axes, (np.atleast_2d(points_mm) - np.asarray(origin_mm)).T).T

    def as_dict(self) -> dict:
        """Every physical parameter as plain JSON-able values, with ``"rig": kind``."""
        return {"rig": self.kind, **_plain(asdict(self))}

    def replace(self, **changes):
        """A copy with some parameters replaced (``moving_plate=``, ``stage=``, ...)."""
        return replace(self, **changes)


def _common_field(rig: StereoRig) -> tuple[float, float]:
    """:meth:`StereoRig.field_mm` by bisection: the half-extents along ``x`` and ``y`` alone, then a common
    shrink factor until the whole rectangle's border is seen at ``z = -d, 0, +d``."""
    c, d = rig.field_centre_mm(), rig.depth_mm()
    t = np.linspace(-1.0, 1.0, 41)

    def seen(a, b):
        x = np.concatenate([t * a, t * a, -a + 0 * t, a + 0 * t])
        y = np.concatenate([-b + 0 * t, b + 0 * t, t * b, t * b])
        pts = np.vstack([np.column_stack([x, y, np.full_like(x, z)]) for z in (-d, 0.0, d)]) + [c[0], c[1], 0.0]
        with np.errstate(all="ignore"):
            return bool(rig.visible(rig.project(pts), 0.0).all())

    def largest(ok, hi):
        lo = 0.0
        for _ in range(40):
            mid = (lo + hi) / 2
            lo, hi = (mid, hi) if ok(mid) else (lo, mid)
        return lo

    big = 4.0 * max(rig.image_size_px) / rig.px_per_mm()
    a = largest(lambda v: seen(v, 0.0), big)
    b = largest(lambda v: seen(0.0, v), big)
    k = largest(lambda v: seen(v * a, v * b), 1.0)
    return 2 * k * a, 2 * k * b


def _plain(obj):
    if isinstance(obj, dict):
        return {k: _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if isinstance(obj, (np.floating, np.integer)):
        return obj.item()
    return obj


def _air_camera(sign: int, aim, angle_deg, distance_mm, errors: ViewErrors, *, focal_mm, image_distance_mm,
                pupil_mm, pixel_mm, size_px, wavelength_um) -> Camera:
    """A camera in air at ``distance_mm`` from its aim point ``(x, y, 0)``, its axis inclined by
    ``sign · angle_deg`` from ``+z`` in the ``x-z`` plane (``sign = -1``: on the ``-x`` side), the sensor
    perpendicular to the axis at ``image_distance_mm``."""
    a = np.radians(sign * angle_deg)
    aim = np.array([aim[0], aim[1], 0.0])
    centre = aim + distance_mm * np.array([np.sin(a), 0.0, np.cos(a)])
    width, height = size_px
    pp = ((width - 1) / 2 + errors.principal_offset_px[0], (height - 1) / 2 + errors.principal_offset_px[1])
    return Camera(centre, look_at(centre, aim, errors.roll_deg), focal_mm=focal_mm, pupil_mm=pupil_mm,
                  pixel_mm=pixel_mm, size_px=size_px, principal_px=pp, radial_px=errors.radial_px,
                  tangential_px=errors.tangential_px, offset_mm=image_distance_mm, wavelength_um=wavelength_um)


# --------------------------------------------------------------------------------------------- the rigs
@dataclass(frozen=True)
class GreenoughRig(StereoRig):
    """A Greenough stereo microscope with a camera on each of its two objectives (module docstring).

    Attributes
    ----------
    half_angle_deg
        inclination of each objective's axis from the vertical (the convergence is twice it) [degree].
    working_distance_mm
        distance from each objective's entrance pupil to the focus, along its axis [mm].
    object_pixel_mm
        object-side pixel size at the focus [mm/px].
    sensor_pixel_mm, image_size_px
        the cameras' pixel [mm] and size ``(width, height)`` [px].
    numerical_aperture
        object-side NA of each objective [-].
    wavelength_um
        mean wavelength of the illumination [µm].
    left, right
        the views' departures (:class:`ViewErrors`).
    stage, noise, grid_plate, moving_plate, preset
        as on :class:`slmlab.virtual.microscope.Microscope`.
    """

    kind: ClassVar[str] = "greenough"
    half_angle_deg: float = 3.0
    working_distance_mm: float = 90.0
    object_pixel_mm: float = 0.003
    sensor_pixel_mm: float = 0.00345
    image_size: tuple[int, int] = (2048, 1536)
    numerical_aperture: float = 0.025
    wavelength_um: float = 0.55
    left: ViewErrors = ViewErrors()
    right: ViewErrors = ViewErrors()
    stage: Stage = Stage()
    noise: CentroidNoise = CentroidNoise()
    grid_plate: Plate = Plate(27, 29, 0.2, 0.1)
    moving_plate: Plate = Plate(7, 7, 0.3, 0.15)
    preset: str = "greenough"

    def _build_cameras(self):
        m = self.sensor_pixel_mm / self.object_pixel_mm
        v = m * self.working_distance_mm  # the zoom's image distance: object pixel exact at the nominal WD
        cams = {}
        for side, sign, e in (("l", -1, self.left), ("r", 1, self.right)):
            wd = self.working_distance_mm * (1 + e.distance_error)
            cams[side] = _air_camera(sign, e.aim_offset_mm, self.half_angle_deg + e.angle_error_deg, wd, e,
                                     focal_mm=wd * v / (wd + v), image_distance_mm=v,
                                     pupil_mm=2 * self.numerical_aperture * wd, pixel_mm=self.sensor_pixel_mm,
                                     size_px=self.image_size, wavelength_um=self.wavelength_um)
        return cams

    def depth_mm(self) -> float:
        """The depth of field (half)."""
        return self.depth_of_field_mm()


@dataclass(frozen=True)
class StereoDicRig(StereoRig):
    """A stereo-DIC camera pair (module docstring).

    Attributes
    ----------
    half_angle_deg
        each camera's axis from the specimen's normal (the stereo angle is twice it) [degree].
    standoff_mm
        pupil to aim point along the axis [mm].
    focal_mm, f_number
        the lenses [mm, -].
    pixel_mm, image_size
        the sensors [mm, px].
    """

    kind: ClassVar[str] = "stereo-dic"
    half_angle_deg: float = 15.0
    standoff_mm: float = 600.0
    focal_mm: float = 50.0
    f_number: float = 11.0
    pixel_mm: float = 0.00345
    image_size: tuple[int, int] = (2048, 1536)
    wavelength_um: float = 0.55
    left: ViewErrors = ViewErrors()
    right: ViewErrors = ViewErrors()
    stage: Stage = Stage()
    noise: CentroidNoise = CentroidNoise()
    grid_plate: Plate = Plate(15, 19, 5.0, 2.5)
    moving_plate: Plate = Plate(9, 9, 3.0, 1.5)
    preset: str = "stereo-dic"

    def _build_cameras(self):
        cams = {}
        for side, sign, e in (("l", -1, self.left), ("r", 1, self.right)):
            s = self.standoff_mm * (1 + e.distance_error)
            cams[side] = _air_camera(sign, e.aim_offset_mm, self.half_angle_deg + e.angle_error_deg, s, e,
                                     focal_mm=self.focal_mm, image_distance_mm=self.focal_mm * s / (s - self.focal_mm),
                                     pupil_mm=self.focal_mm / self.f_number, pixel_mm=self.pixel_mm,
                                     size_px=self.image_size, wavelength_um=self.wavelength_um)
        return cams

    def depth_mm(self) -> float:
        """The depth of field (half), at most a tenth of the image's width at the focus (DIC measures
        surface shapes and out-of-plane motions of a few mm, not the whole depth of field)."""
        width = self.image_size[0] * self.pixel_mm * (self.standoff_mm - self.focal_mm) / self.focal_mm
        return min(self.depth_of_field_mm(), 0.1 * width)


@dataclass(frozen=True)
class StereoPivRig(StereoRig):
    """A stereo-PIV camera pair with Scheimpflug sensors, looking through a flat wall into water (module
    docstring).

    Attributes
    ----------
    half_angle_deg
        each camera's axis from the wall's normal, in air [degree].
    standoff_mm
        the *apparent* distance (thin-lens object distance) from the pupil to the aim point along the axis
        [mm]: the air path plus the water and wall paths as the lens sees them.
    focal_mm, f_number, pixel_mm, image_size, wavelength_um
        lenses and sensors (a 532 nm laser).
    wall_thickness_mm, glass_index
        the flat wall [mm, -].
    water_depth_mm, water_index
        distance from the light sheet ``z = 0`` to the wall's inner face [mm], and water's index.
    sheet_thickness_mm
        thickness of the light sheet [mm]: the designs span 1.5 times it on either side.
    """

    kind: ClassVar[str] = "stereo-piv"
    half_angle_deg: float = 35.0
    standoff_mm: float = 700.0
    focal_mm: float = 60.0
    f_number: float = 8.0
    pixel_mm: float = 0.0055
    image_size: tuple[int, int] = (2048, 1536)
    wavelength_um: float = 0.532
    wall_thickness_mm: float = 10.0
    glass_index: float = 1.49
    water_depth_mm: float = 50.0
    water_index: float = WATER_INDEX
    sheet_thickness_mm: float = 2.0
    left: ViewErrors = ViewErrors()
    right: ViewErrors = ViewErrors()
    stage: Stage = Stage()
    noise: CentroidNoise = CentroidNoise()
    grid_plate: Plate = Plate(15, 19, 5.0, 2.5)
    moving_plate: Plate = Plate(21, 21, 4.0, 2.0)
    preset: str = "stereo-piv"

    @property
    def indices(self) -> tuple[float, float, float]:
        """Refractive indices of air, the wall and water."""
        return (1.0, self.glass_index, self.water_index)

    def _layers(self, point_z: np.ndarray, camera_z: float) -> np.ndarray:
        """Thicknesses ``(n, 3)`` of air, wall and water [mm] between points and a camera's pupil."""
        wall_top = self.water_depth_mm + self.wall_thickness_mm
        return np.column_stack([np.full_like(point_z, camera_z - wall_top),
                                np.full_like(point_z, self.wall_thickness_mm), self.water_depth_mm - point_z])

    def chief_rays(self, points_mm, camera):
        """As :meth:`StereoRig.chief_rays`, refracted exactly through the wall: the air part of each ray
        from the transverse invariant (:func:`refraction_invariant`), the apparent distances by Coddington's
        equations for flat interfaces (sagittal ``Σ L_i / n_i``, tangential ``Σ L_i cos²θ_air /
        (n_i cos²θ_i)``, with ``L_i`` the path lengths). Points not in the water give NaN."""
        p = np.atleast_2d(np.asarray(points_mm, float))
        h = self._layers(p[:, 2], camera.centre[2])
        h[h[:, 2] <= 0] = np.nan
        dxy = p[:, :2] - camera.centre[:2]
        rho = np.hypot(dxy[:, 0], dxy[:, 1])
        q = refraction_invariant(rho, h, self.indices)
        u = np.divide(dxy, rho[:, None], out=np.zeros_like(dxy), where=rho[:, None] > 0)
        d = np.column_stack([q[:, None] * u, -np.sqrt(1 - q * q)])
        n = np.asarray(self.indices)
        cos2 = 1 - (q[:, None] / n) ** 2
        length = h / np.sqrt(cos2)
        l_s = (length / n).sum(axis=1)
        l_m = length[:, 0] + (1 - q * q) * (length[:, 1:] / (n[1:] * cos2[:, 1:])).sum(axis=1)
        return d @ camera.rotation.T, l_s, l_m

    def rays(self, w, side):
        """As :meth:`StereoRig.rays`, the rays refracted into the water: origins on the wall's inner face."""
        return self._refract_down(*super().rays(w, side))

    def _camera(self, sign: int, e: ViewErrors) -> Camera:
        """The camera of one side, aimed through the wall at its aim point, its sensor still untilted."""
        q = np.sin(np.radians(self.half_angle_deg + e.angle_error_deg))
        n = np.asarray(self.indices)
        h = np.array([self.wall_thickness_mm, self.water_depth_mm])
        lateral = float((h * q / np.sqrt(n[1:] ** 2 - q * q)).sum())
        length = h * n[1:] / np.sqrt(n[1:] ** 2 - q * q)
        media = float(((length / n[1:]).sum() + (1 - q * q) * (length / (n[1:] - q * q / n[1:])).sum()) / 2)
        s = self.standoff_mm * (1 + e.distance_error)
        air = s - media
        if air <= self.focal_mm:
            raise SlmlabError(f"stereo-PIV rig: standoff {s:g} mm leaves no air path in front of the wall; "
                              "give a larger standoff_mm")
        aim = np.array([e.aim_offset_mm[0], e.aim_offset_mm[1], 0.0])
        exit_ = aim + [sign * lateral, 0.0, self.water_depth_mm + self.wall_thickness_mm]
        centre = exit_ + air * np.array([sign * q, 0.0, np.sqrt(1 - q * q)])
        width, height = self.image_size
        pp = ((width - 1) / 2 + e.principal_offset_px[0], (height - 1) / 2 + e.principal_offset_px[1])
        return Camera(centre, look_at(centre, exit_, e.roll_deg), focal_mm=self.focal_mm,
                      pupil_mm=self.focal_mm / self.f_number, pixel_mm=self.pixel_mm, size_px=self.image_size,
                      principal_px=pp, radial_px=e.radial_px, tangential_px=e.tangential_px,
                      offset_mm=self.focal_mm * s / (s - self.focal_mm), wavelength_um=self.wavelength_um)

    def _scheimpflug(self, cam: Camera, iterations: int = 3) -> Camera:
        """Tilt the sensor so that the light sheet is in focus: the plane through the thin-lens images (mean
        of sagittal and tangential) of the sheet's points that the camera sees, refitted as the tilt moves
        the footprint."""
        g = np.linspace(0.0, 1.0, 9)
        width, height = cam.size_px
        grid = np.array([(a * (width - 1), b * (height - 1)) for a in g for b in g])
        for _ in range(iterations):
            d = cam.from_pixels(grid) @ cam.rotation
            o, dw = self._refract_down(np.broadcast_to(cam.centre, d.shape), d)
            pts = o + dw * (-o[:, 2] / dw[:, 2])[:, None]
            dc, l_s, l_m = self.chief_rays(pts, cam)
            lm = (l_s + l_m) / 2
            img = dc * (lm * cam.focal_mm / (lm * dc[:, 2] - cam.focal_mm))[:, None]
            mid = img.mean(axis=0)
            normal = np.linalg.svd(img - mid)[2][2]
            normal = normal if normal[2] > 0 else -normal
            cam = cam.with_sensor(normal, float(normal @ mid))
        return cam

    def _refract_down(self, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Water-side origins (on the wall's inner face) and unit directions of rays leaving ``o`` (in air)
        along rig-frame unit directions ``d`` (Snell's law: ``sin θ`` in air is the invariant)."""
        q = np.hypot(d[:, 0], d[:, 1])
        u = np.divide(d[:, :2], q[:, None], out=np.zeros_like(d[:, :2]), where=q[:, None] > 0)
        wall_top = self.water_depth_mm + self.wall_thickness_mm
        t_glass = q / np.sqrt(self.glass_index ** 2 - q * q)
        entry = (o[:, :2] + d[:, :2] * ((o[:, 2] - wall_top) / -d[:, 2])[:, None]
                 + u * (self.wall_thickness_mm * t_glass)[:, None])
        sw = q / self.water_index
        return (np.column_stack([entry, np.full(len(q), self.water_depth_mm)]),
                np.column_stack([u * sw[:, None], -np.sqrt(1 - sw * sw)]))

    def _build_cameras(self):
        return {side: self._scheimpflug(self._camera(sign, e))
                for side, sign, e in (("l", -1, self.left), ("r", 1, self.right))}

    def depth_mm(self) -> float:
        """1.5 light-sheet thicknesses (a calibration spans the sheet and some margin on either side)."""
        return 1.5 * self.sheet_thickness_mm


# --------------------------------------------------------------------------------------------- registry
RIG_CLASSES = {cls.kind: cls for cls in (GreenoughRig, StereoDicRig, StereoPivRig)}


def _nice(value: float) -> float:
    """The largest 'round' length (1, 1.2, 1.5, 2, 2.5, 3, 4, 5, 6, 8 × 10^k) not above ``value``."""
    e = 10.0 ** np.floor(np.log10(value))
    return float(f"{max(m * e for m in (1, 1.2, 1.5, 2, 2.5, 3, 4, 5, 6, 8) if m * e <= value * (1 + 1e-12)):.6g}")


def sized_plate(width_mm: float, height_mm: float, *, dots: int | None = None, pitch_mm: float | None = None,
                tolerance_um: float = 0.25, rotation_deg: float = 0.0, tilt_deg: float = 0.0) -> Plate:
    """A dot plate covering ``width_mm × height_mm``: ``dots`` across the smaller side at a round pitch (or
    the given ``pitch_mm``), dots half a pitch across, as many rows and columns as fit."""
    pitch = pitch_mm or _nice(min(width_mm, height_mm) / (dots - 1))
    rows, cols = (int(np.floor(v / pitch + 1e-9)) + 1 for v in (height_mm, width_mm))
    return Plate(rows, cols, pitch, pitch / 2, fabrication_tolerance_um=tolerance_um, rotation_deg=rotation_deg,
                 tilt_deg=tilt_deg)


def with_plates(rig, *, moving_dots: int, moving_share: float, tolerance_um: float, grid_rotation_deg: float = 0.15,
                moving_rotation_deg: float = -2.0, moving_tilt_deg: float = 0.05):
    """The rig with its plates sized for its common field (:meth:`StereoRig.field_mm`): the grid plate
    (pitch about 1/25 of the field) covering 90 % of it, the moving plate ``moving_dots`` square covering
    ``moving_share`` of the smaller side."""
    fw, fh = rig.field_mm()
    side = moving_share * min(fw, fh)
    grid = sized_plate(0.9 * fw, 0.9 * fh, pitch_mm=_nice(min(fw, fh) / 25), tolerance_um=tolerance_um,
                       rotation_deg=grid_rotation_deg)
    pitch = _nice(side / (moving_dots - 1))
    moving = Plate(moving_dots, moving_dots, pitch, pitch / 2, fabrication_tolerance_um=tolerance_um,
                   rotation_deg=moving_rotation_deg, tilt_deg=moving_tilt_deg)
    return replace(rig, grid_plate=grid, moving_plate=moving)


def _micro_stage(field_mm: float) -> Stage:
    return Stage(rotation_deg=-2.0, y_skew=0.004, y_tilt=0.010, z_tilt_x=0.006, z_tilt_y=-0.012, x_tilt=0.0003,
                 scale_error=(1.0e-4, -0.8e-4, 1.5e-4), straightness_um=(0.3, 0.3, 0.3), lead_error_um=0.3,
                 lead_mm=1.0, lead_phase_deg=(10.0, 130.0, 250.0), positioning_noise_um=0.3, travel_mm=field_mm)


def _macro_stage(field_mm: float) -> Stage:
    return Stage(rotation_deg=1.5, y_skew=-0.003, y_tilt=0.006, z_tilt_x=-0.004, z_tilt_y=0.005, x_tilt=0.0005,
                 scale_error=(1.5e-4, -1.0e-4, 2.0e-4), straightness_um=(2.0, 2.0, 2.0), lead_error_um=1.5,
                 lead_mm=2.0, lead_phase_deg=(40.0, 160.0, 280.0), positioning_noise_um=1.0, travel_mm=field_mm)


def _greenough() -> GreenoughRig:
    rig = GreenoughRig(
        left=ViewErrors((2.0, -0.5), (0.6, -0.3), -0.3, (12.0, -8.0), (0.02, -0.01), 0.05, 0.0015),
        right=ViewErrors((-1.2, 0.4), (-0.4, 0.5), 0.25, (-9.0, 14.0), (-0.015, 0.02), -0.04, -0.001),
        stage=_micro_stage(6.0), noise=CentroidNoise(0.02, 0.05))
    return with_plates(rig, moving_dots=7, moving_share=0.3, tolerance_um=0.25)


def _stereo_dic() -> StereoDicRig:
    rig = StereoDicRig(
        standoff_mm=750.0,
        left=ViewErrors((-8.0, 1.5), (0.8, -0.5), 0.6, (25.0, -18.0), (0.8, -0.5), 0.3, 0.006),
        right=ViewErrors((-6.0, -1.0), (-0.6, 0.9), -0.4, (-20.0, 15.0), (-0.6, 0.7), -0.25, -0.004),
        stage=_macro_stage(100.0), noise=CentroidNoise(0.03, 0.08))
    return with_plates(rig, moving_dots=9, moving_share=0.35, tolerance_um=2.0)


def _stereo_piv() -> StereoPivRig:
    rig = StereoPivRig(
        left=ViewErrors((-5.0, 1.0), (0.5, -0.4), 0.5, (20.0, -15.0), (0.6, -0.4), 0.3, 0.005),
        right=ViewErrors((-4.0, -0.8), (-0.4, 0.6), -0.35, (-18.0, 12.0), (-0.5, 0.6), -0.2, -0.004),
        stage=_macro_stage(100.0), noise=CentroidNoise(0.03, 0.08))
    return with_plates(rig, moving_dots=21, moving_share=0.7, tolerance_um=2.0)


#: the named rigs: name -> (builder, description)
RIGS = {
    "greenough": (_greenough, "Greenough stereo microscope: ±3° objectives at 90 mm, 3 µm object pixel, NA 0.025"),
    "stereo-dic": (_stereo_dic, "stereo-DIC pair: ±15°, 50 mm f/11 lenses at 750 mm, 3 Mpx, a 100 mm field"),
    "stereo-piv": (_stereo_piv, "stereo-PIV pair: ±35° in air, 60 mm f/8 Scheimpflug cameras through 10 mm of "
                                "acrylic, the light sheet 50 mm into water"),
}


def make_rig(name: str, **changes):
    """The rig of a named preset (:data:`RIGS`), optionally with parameters replaced."""
    if name not in RIGS:
        raise SlmlabError(f"unknown rig {name!r}; choose one of {', '.join(RIGS)}")
    rig = RIGS[name][0]()
    return replace(rig, **changes) if changes else rig


def rig_by_name(name: str):
    """A preset rig (:data:`RIGS`), or ``"KIND:SEED"``: a rig of that kind drawn at random (:func:`random_rig`)."""
    kind, sep, seed = name.partition(":")
    if not sep:
        return make_rig(name)
    if not seed.strip().isdigit():
        raise SlmlabError(f"rig {name!r}: give KIND:SEED with a whole-number seed, e.g. stereo-piv:7")
    return random_rig(kind, int(seed))


# --------------------------------------------------------------------------------------------- random rigs
def _uniform(rng: np.random.Generator, bounds) -> float:
    return float(rng.uniform(*bounds))


def _random_errors(rng, radial, tangential, *, roll_deg, principal_px, aim_mm, angle_deg, distance) -> ViewErrors:
    """One view's departures, each uniform within ± its bound (``radial``: the bounds of k1 and k2)."""
    u = lambda b, n=None: rng.uniform(-b, b, n)  # noqa: E731
    return ViewErrors(radial_px=(float(u(radial[0])), float(u(radial[1]))),
                      tangential_px=tuple(float(v) for v in u(tangential, 2)), roll_deg=float(u(roll_deg)),
                      principal_offset_px=tuple(float(v) for v in u(principal_px, 2)),
                      aim_offset_mm=tuple(float(v) for v in u(aim_mm, 2)), angle_error_deg=float(u(angle_deg)),
                      distance_error=float(u(distance)))


def _random_stage(rng, field_mm: float, micro: bool) -> Stage:
    """A stage with errors typical of a micrometre (``micro``) or a macro translation stage."""
    u = lambda b: float(rng.uniform(-b, b))  # noqa: E731
    k = 1.0 if micro else 0.5
    return Stage(rotation_deg=u(5.0), y_skew=u(0.01 * k), y_tilt=u(0.02 * k), z_tilt_x=u(0.02 * k),
                 z_tilt_y=u(0.02 * k), x_tilt=u(0.002), scale_error=tuple(u(2e-4) for _ in range(3)),
                 straightness_um=tuple(float(v) for v in rng.uniform(0, 0.5 if micro else 3.0, 3)),
                 lead_error_um=float(rng.uniform(0, 0.5 if micro else 2.0)),
                 lead_mm=float(rng.choice((0.5, 1.0)) if micro else rng.choice((1.0, 2.0, 5.0))),
                 lead_phase_deg=tuple(float(v) for v in rng.uniform(0, 360, 3)),
                 positioning_noise_um=float(rng.uniform(0.1, 0.5) if micro else rng.uniform(0.5, 2.0)),
                 travel_mm=field_mm)


def _random_noise(rng) -> CentroidNoise:
    focus = float(rng.uniform(0.015, 0.04))
    return CentroidNoise(focus, focus * float(rng.uniform(2.0, 3.0)))


def _draw_sensor(rng, kind: str, field_range, scale) -> tuple:
    """A sensor of ``kind`` and a distance-like parameter ``scale(sensor)`` that puts the field within
    ``field_range`` (rejection sampling)."""
    for _ in range(1000):
        sensor = SENSORS[kind][int(rng.integers(len(SENSORS[kind])))]
        out = scale(sensor)
        if out is not None:
            return sensor, out
    raise SlmlabError(f"cannot draw a {kind} rig within its ranges")  # pragma: no cover


def _random_greenough(rng) -> GreenoughRig:
    r = RANGES["greenough"]

    def pixel(sensor):
        px = _uniform(rng, r["object_pixel_mm"])
        return px if r["field_mm"][0] <= sensor[0] * px <= r["field_mm"][1] else None
    (w, h, sp), px = _draw_sensor(rng, "greenough", r["field_mm"], pixel)
    errors = [_random_errors(rng, r["radial_px"], r["tangential_px"], roll_deg=0.5, principal_px=20.0,
                             aim_mm=0.005 * w * px, angle_deg=0.1, distance=0.003) for _ in "lr"]
    rig = GreenoughRig(half_angle_deg=_uniform(rng, r["half_angle_deg"]),
                       working_distance_mm=_uniform(rng, r["working_distance_mm"]), object_pixel_mm=px,
                       sensor_pixel_mm=sp, image_size=(w, h), numerical_aperture=_uniform(rng, r["numerical_aperture"]),
                       left=errors[0], right=errors[1], stage=_random_stage(rng, w * px, True),
                       noise=_random_noise(rng), preset="random-greenough")
    return with_plates(rig, moving_dots=7, moving_share=0.3, tolerance_um=0.25,
                       moving_rotation_deg=float(rng.uniform(-3, 3)), moving_tilt_deg=float(rng.uniform(-0.1, 0.1)))


def _random_macro(rng, kind: str):
    """A stereo-DIC or stereo-PIV rig with every parameter drawn from :data:`RANGES`."""
    r = RANGES[kind]
    focal = float(rng.choice(r["focal_mm"]))

    def standoff(sensor):  # thin lens: magnification m = sensor width / field, s = f (1 + 1/m)
        s = focal * (1 + _uniform(rng, r["field_mm"]) / (sensor[0] * sensor[2]))
        lo, hi = r.get("standoff_mm", (250.0, 1500.0))
        return s if lo <= s <= hi else None
    (w, h, pixel), s = _draw_sensor(rng, kind, r["field_mm"], standoff)
    field = w * pixel * (s - focal) / focal
    errors = [_random_errors(rng, r["radial_px"], r["tangential_px"], roll_deg=1.0, principal_px=30.0,
                             aim_mm=0.01 * field, angle_deg=0.5, distance=0.01) for _ in "lr"]
    common = dict(half_angle_deg=_uniform(rng, r["half_angle_deg"]), standoff_mm=s, focal_mm=focal,
                  f_number=_uniform(rng, r["f_number"]), pixel_mm=pixel, image_size=(w, h), left=errors[0],
                  right=errors[1], stage=_random_stage(rng, field, False), noise=_random_noise(rng),
                  preset=f"random-{kind}")
    if kind == "stereo-dic":
        rig = StereoDicRig(**common)
        return with_plates(rig, moving_dots=9, moving_share=0.35, tolerance_um=2.0,
                           moving_rotation_deg=float(rng.uniform(-3, 3)), moving_tilt_deg=float(rng.uniform(-0.1, 0.1)))
    rig = StereoPivRig(**common, wall_thickness_mm=_uniform(rng, r["wall_thickness_mm"]),
                       glass_index=_uniform(rng, r["glass_index"]), water_depth_mm=_uniform(rng, r["water_depth_mm"]),
                       sheet_thickness_mm=_uniform(rng, r["sheet_thickness_mm"]))
    return with_plates(rig, moving_dots=21, moving_share=0.7, tolerance_um=2.0,
                       moving_rotation_deg=float(rng.uniform(-3, 3)), moving_tilt_deg=float(rng.uniform(-0.1, 0.1)))


def random_rig(kind: str, rng: np.random.Generator | int = 0):
    """A rig of ``kind`` ('greenough', 'stereo-dic', 'stereo-piv') with every physical parameter drawn within
    :data:`RANGES` (view errors, stage errors and the dot finder's noise within the bounds of the module's
    helpers), its plates sized for its field (for property tests)."""
    rng = np.random.default_rng(rng)
    if kind == "greenough":
        return _random_greenough(rng)
    if kind in ("stereo-dic", "stereo-piv"):
        return _random_macro(rng, kind)
    raise SlmlabError(f"unknown rig kind {kind!r}; choose one of {', '.join(RIG_CLASSES)}")


def rig_from_dict(d: dict):
    """Rebuild a rig from :meth:`StereoRig.as_dict` output, or the CMO microscope (no ``"rig"`` key) from
    :meth:`slmlab.virtual.microscope.Microscope.as_dict` output."""
    if "rig" not in d:
        return microscope_from_dict(d)
    if d["rig"] not in RIG_CLASSES:
        raise SlmlabError(f"unknown rig kind {d['rig']!r} in the simulator's parameters; this slmlab knows "
                          f"{', '.join(RIG_CLASSES)}")
    parts = {"stage": Stage, "noise": CentroidNoise, "grid_plate": Plate, "moving_plate": Plate,
             "left": ViewErrors, "right": ViewErrors}

    def build(cls, data):
        kwargs = {}
        for f in fields(cls):
            if f.name not in data:
                continue
            val = data[f.name]
            if f.name in parts:
                val = build(parts[f.name], val)
            elif isinstance(val, list):
                val = tuple(val)
            kwargs[f.name] = val
        return cls(**kwargs)
    return build(RIG_CLASSES[d["rig"]], d)
