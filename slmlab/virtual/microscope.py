"""The virtual CMO stereo light microscope: optics, cameras and stage (paper §2; the physics of a CMO).

A physical model, not the paper's equations run backwards. Each optical sub-system sees the object
through an off-axis zone of the common main objective (CMO):

1. **Central projection** from a centre ``C_v = (c_v, 0, L)`` in the microscope frame onto the focal plane
   ``z = 0`` (the image planes are conjugate to it, not tilted). ``c_l = -L tan(γ/2)``, ``c_r = +L tan(γ/2)``
   for a convergence angle ``γ`` (about 13.8°). A point at height ``z`` above the focal plane lands at
   ``q = (c + (x - c) s, y s)`` with ``s = L / (L - z)``: magnification grows by ``1/L`` per mm of ``z``
   (true perspective) and the two views shift in opposite directions (disparity).
2. **Distortion of the main objective seen through an off-axis pupil**: decentring
   ``Δx = p1 (3x² + y²)``, ``Δy = 2 p1 x y`` plus a thin-prism term ``Δx = s1 (x² + y²)``, about the
   objective axis, with opposite sign in the two views (their pupils sit on opposite sides of it); plus the
   sub-system's own small radial distortion ``k1 r² (x, y)``. This bends columns quadratically and fans rows
   out linearly (paper Eq 3–6) and makes disparity a parabola in ``w1`` (paper Fig 7a).
3. **Camera**: magnification (pixels per mm of the focal plane; the two views differ slightly), an inverted
   image, a small rotation about the optical axis and an offset (principal point: where the objective axis
   lands in the image).

The stage is an affine frame (its three actual axis vectors, rotated about 3° from the image axes,
slightly skewed and tilted) with scale, straightness and periodic lead errors and positioning noise.

Frames and units
----------------
microscope frame
    ``x, y`` in the focal plane, origin on the objective axis, ``z`` up towards the objective [mm].
stage frame
    the affine frame of the stage's actual (linear) axes, origin at stage zero [mm]. World coordinates
    ``X_mm, Y_mm, Z_mm`` of ``truth.csv`` are in this frame: what a perfect stage would read.
image
    ``w1`` pixel column, ``w2`` pixel row, origin at the top-left pixel [px].
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields, replace

import numpy as np
import pandas as pd

__all__ = [
    "View",
    "Optics",
    "Stage",
    "Plate",
    "CentroidNoise",
    "Imaging",
    "Microscope",
    "rotation_z",
    "from_dict",
    "describe",
    "depth_response",
]


def rotation_z(angle_rad: float) -> np.ndarray:
    """3 × 3 rotation about the microscope z axis by ``angle_rad`` [rad]."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class View:
    """One optical sub-system of the CMO microscope with its camera.

    Attributes
    ----------
    decentring_per_mm
        ``p1`` of the decentred distortion ``Δx = p1 (3x² + y²)``, ``Δy = 2 p1 x y`` of the main objective as
        seen through this view's off-axis pupil, focal-plane coordinates [1/mm]. Opposite sign in the two
        views.
    thin_prism_per_mm
        ``s1`` of the thin-prism term ``Δx = s1 (x² + y²)`` of the same off-axis zone [1/mm].
    radial_k1_per_mm2
        the sub-system's own radial distortion ``Δq = k1 r² q`` [1/mm²].
    magnification_ratio
        this view's magnification relative to the nominal one [-] (the two views differ slightly).
    rotation_deg
        camera rotation about its optical axis [degree].
    principal_point_px
        image position ``(w1, w2)`` of the objective axis [px].
    """

    decentring_per_mm: float = 0.0
    thin_prism_per_mm: float = 0.0
    radial_k1_per_mm2: float = 0.0
    magnification_ratio: float = 1.0
    rotation_deg: float = 0.0
    principal_point_px: tuple[float, float] = (1024.0, 1024.0)


@dataclass(frozen=True)
class Optics:
    """The common main objective, the two sub-systems and the cameras.

    Attributes
    ----------
    perspective_distance_mm
        ``L``, distance from the focal plane to the projection centres [mm]. Magnification changes by
        ``1/L`` per mm of depth.
    convergence_deg
        ``γ``, angle between the two views' chief rays at the focal point [degree].
    pixel_mm
        nominal object-side pixel size [mm/px] (the inverse of the nominal magnification).
    image_size_px
        ``(width, height)`` [px].
    depth_of_field_mm
        half depth of field [mm]: dots are sharp within ``|z| <= depth_of_field_mm``.
    inverted
        the microscope forms an inverted image (both image axes reversed).
    left, right
        the two views.
    """

    perspective_distance_mm: float = 300.0
    convergence_deg: float = 13.69
    pixel_mm: float = 0.003
    image_size_px: tuple[int, int] = (2048, 2048)
    depth_of_field_mm: float = 1.13
    inverted: bool = True
    left: View = field(default_factory=View)
    right: View = field(default_factory=View)

    @property
    def centre_x_mm(self) -> tuple[float, float]:
        """Lateral positions ``(c_l, c_r)`` of the two projection centres [mm]."""
        half_base = self.perspective_distance_mm * np.tan(np.radians(self.convergence_deg) / 2)
        return (-half_base, half_base)

    def view(self, side: str) -> View:
        return self.left if side == "l" else self.right


@dataclass(frozen=True)
class Stage:
    """A three-axis translation stage and its errors.

    The stage's actual axes, expressed in a frame rotated by ``rotation_deg`` about the microscope z axis,
    are ``ex = (1, 0, x_tilt)``, ``ey = (y_skew, 1, y_tilt)``, ``ez = (z_tilt_x, z_tilt_y, 1)`` (each
    normalised). To first order the paper's compensation coefficients (§5.3, Eq 21–22) are
    ``KYX = -y_skew``, ``KYZ = -y_tilt``, ``KZX = -z_tilt_x``, ``KZY = -z_tilt_y`` and ``θX = -rotation_deg``.

    Attributes
    ----------
    rotation_deg
        angle of the stage X axis from the microscope x axis, about z [degree].
    y_skew, y_tilt, z_tilt_x, z_tilt_y, x_tilt
        direction cosines of the axes' departures from orthogonality [-].
    scale_error
        relative scale error of each axis (X, Y, Z) [-].
    straightness_um
        bow of each axis: displacement perpendicular to it at ``travel_mm`` from zero [µm].
    lead_error_um, lead_mm, lead_phase_deg
        periodic error of the lead screws: amplitude [µm], period [mm], phase per axis [degree].
    positioning_noise_um
        standard deviation of the random positioning error per axis and move [µm].
    travel_mm
        reference travel for the straightness bow [mm].
    """

    rotation_deg: float = 0.0
    y_skew: float = 0.0
    y_tilt: float = 0.0
    z_tilt_x: float = 0.0
    z_tilt_y: float = 0.0
    x_tilt: float = 0.0
    scale_error: tuple[float, float, float] = (0.0, 0.0, 0.0)
    straightness_um: tuple[float, float, float] = (0.0, 0.0, 0.0)
    lead_error_um: float = 0.0
    lead_mm: float = 1.0
    lead_phase_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    positioning_noise_um: float = 0.0
    travel_mm: float = 4.0

    @property
    def axes(self) -> np.ndarray:
        """3 × 3 matrix whose columns are the stage's X, Y, Z unit axes in the microscope frame."""
        raw = np.array(
            [
                [1.0, self.y_skew, self.z_tilt_x],
                [0.0, 1.0, self.z_tilt_y],
                [self.x_tilt, self.y_tilt, 1.0],
            ]
        )
        raw /= np.linalg.norm(raw, axis=0)
        return rotation_z(np.radians(self.rotation_deg)) @ raw

    def actual(self, commanded_mm: np.ndarray, rng: np.random.Generator | None = None) -> np.ndarray:
        """Where the stage really is, in its own (affine) frame, for commanded positions ``(n, 3)`` [mm].

        Adds scale error, the periodic lead error along each axis, a quadratic straightness bow
        perpendicular to each axis, and (if ``rng`` is given) positioning noise.
        """
        s = np.atleast_2d(np.asarray(commanded_mm, dtype=float))
        out = s * (1.0 + np.asarray(self.scale_error))
        phase = np.radians(np.asarray(self.lead_phase_deg))
        out = out + 1e-3 * self.lead_error_um * np.sin(2 * np.pi * s / self.lead_mm + phase)
        bow = 1e-3 * np.asarray(self.straightness_um) * (s / self.travel_mm) ** 2
        # each axis bows along the next one (X bows in Y, Y in Z, Z in X)
        out = out + np.roll(bow, 1, axis=1)
        if rng is not None and self.positioning_noise_um > 0:
            out = out + rng.normal(0.0, 1e-3 * self.positioning_noise_um, size=out.shape)
        return out


@dataclass(frozen=True)
class Plate:
    """A calibration plate of round dots (paper §3, Fig 3a).

    Dot ``[i, j]`` (row ``i = 1..rows``, column ``j = 1..cols``) is indexed as it appears in the image:
    ``[1, 1]`` top left. Plate coordinates are centred on the plate [mm].

    Attributes
    ----------
    rows, cols
        number of dot rows and columns.
    pitch_mm
        dot spacing [mm].
    dot_diameter_mm
        dot diameter [mm].
    fabrication_tolerance_um
        dot positions are off by a uniform error within ± this [µm].
    rotation_deg
        in-plane rotation of the plate relative to the microscope x axis when mounted [degree].
    tilt_deg
        tilt of the plate about the microscope x axis [degree].
    """

    rows: int
    cols: int
    pitch_mm: float
    dot_diameter_mm: float
    fabrication_tolerance_um: float = 0.25
    rotation_deg: float = 0.0
    tilt_deg: float = 0.0

    def nominal_points(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Row index, column index and plate-frame coordinates ``(n, 3)`` of every dot [mm]."""
        i, j = np.meshgrid(np.arange(1, self.rows + 1), np.arange(1, self.cols + 1), indexing="ij")
        i, j = i.ravel(), j.ravel()
        # the image is inverted: [1, 1] at the top left of the image is at +x, +y on the plate
        x = ((self.cols - 1) / 2 - (j - 1)) * self.pitch_mm
        y = ((self.rows - 1) / 2 - (i - 1)) * self.pitch_mm
        return i, j, np.column_stack([x, y, np.zeros_like(x)])

    def orientation(self) -> np.ndarray:
        """3 × 3 rotation from plate frame to microscope frame."""
        t = np.radians(self.tilt_deg)
        tilt = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(t), -np.sin(t)], [0.0, np.sin(t), np.cos(t)]])
        return rotation_z(np.radians(self.rotation_deg)) @ tilt

    def as_meta(self) -> dict:
        return {"rows": self.rows, "cols": self.cols, "pitch_mm": self.pitch_mm,
                "dot_diameter_mm": self.dot_diameter_mm}


@dataclass(frozen=True)
class CentroidNoise:
    """Noise of a dot finder's centres, growing with defocus (0.01–0.1 px on real images).

    ``σ(z) = in_focus_px · sqrt(1 + (z / z_r)²)`` with ``z_r`` chosen so that ``σ = at_dof_edge_px`` at the
    edge of the depth of field.

    Attributes
    ----------
    in_focus_px
        per-coordinate standard deviation in focus [px].
    at_dof_edge_px
        per-coordinate standard deviation at ``|z| = depth_of_field_mm`` [px].
    """

    in_focus_px: float = 0.02
    at_dof_edge_px: float = 0.05

    def sigma_px(self, z_mm: np.ndarray, depth_of_field_mm: float) -> np.ndarray:
        """Per-coordinate standard deviation for dots at heights ``z_mm`` above the focal plane [px]."""
        if self.in_focus_px == 0:
            return np.zeros_like(np.asarray(z_mm, dtype=float))
        ratio = max(self.at_dof_edge_px / self.in_focus_px, 1.0)
        z_r = depth_of_field_mm / np.sqrt(ratio**2 - 1) if ratio > 1 else np.inf
        return self.in_focus_px * np.sqrt(1.0 + (np.asarray(z_mm) / z_r) ** 2)


@dataclass(frozen=True)
class Imaging:
    """How the cameras turn light into 8-bit images: defocus blur, vignetting, shot and read noise, quantisation.

    Attributes
    ----------
    numerical_aperture
        object-side NA of each sub-system [-]: the geometric defocus blur radius is ``|z|·NA`` [mm], and
        diffraction adds a Gaussian of σ = 0.21 λ / NA.
    wavelength_um
        mean wavelength of the illumination [µm].
    full_well_e
        electrons at 255 DN [e-].
    read_noise_e
        read noise [e-].
    background_dn
        grey level of the plate's bright background at the image centre [DN].
    dot_dn
        grey level inside a sharp dot [DN] (dark dots on a bright plate).
    vignetting
        relative fall-off of the illumination at the image corners [-].
    """

    numerical_aperture: float = 0.02
    wavelength_um: float = 0.55
    full_well_e: float = 10000.0
    read_noise_e: float = 8.0
    background_dn: float = 200.0
    dot_dn: float = 40.0
    vignetting: float = 0.25

    def blur_px(self, z_mm: np.ndarray, pixel_mm: float) -> tuple[np.ndarray, float]:
        """Geometric defocus radius [px] at heights ``z_mm`` and the diffraction Gaussian's σ [px]."""
        radius = np.abs(np.asarray(z_mm, dtype=float)) * self.numerical_aperture / pixel_mm
        sigma = 0.21 * self.wavelength_um * 1e-3 / self.numerical_aperture / pixel_mm
        return radius, sigma


@dataclass(frozen=True)
class Microscope:
    """The virtual CMO stereo microscope: optics, stage, plates and the dot finder's noise.

    Attributes
    ----------
    optics, stage, noise, imaging
        see :class:`Optics`, :class:`Stage`, :class:`CentroidNoise`, :class:`Imaging`.
    grid_plate
        the large plate of the ``grid`` sequence (paper §3: 27 × 29, pitch 0.2 mm).
    moving_plate
        the plate of the axis sequences (paper §4–§6: 7 × 7, pitch 0.3 mm).
    preset
        name of the preset it was made from (informative).
    """

    optics: Optics = field(default_factory=Optics)
    stage: Stage = field(default_factory=Stage)
    noise: CentroidNoise = field(default_factory=CentroidNoise)
    grid_plate: Plate = field(default_factory=lambda: Plate(27, 29, 0.2, 0.1))
    moving_plate: Plate = field(default_factory=lambda: Plate(7, 7, 0.3, 0.15))
    imaging: Imaging = field(default_factory=Imaging)
    preset: str = "custom"

    # ------------------------------------------------------------------ projection
    def project_view(self, points_mm: np.ndarray, side: str) -> np.ndarray:
        """Image coordinates ``(n, 2)`` [px] in view ``side`` ('l' or 'r') of microscope-frame points [mm]."""
        p = np.atleast_2d(np.asarray(points_mm, dtype=float))
        o = self.optics
        v = o.view(side)
        c = o.centre_x_mm[0 if side == "l" else 1]
        L = o.perspective_distance_mm
        s_minus_1 = p[:, 2] / (L - p[:, 2])  # s = L / (L - z); written so that L -> inf stays exact
        qx = p[:, 0] + (p[:, 0] - c) * s_minus_1
        qy = p[:, 1] * (1.0 + s_minus_1)
        # main objective seen through the off-axis pupil (decentring + thin prism), and radial distortion
        r2 = qx * qx + qy * qy
        dx = v.decentring_per_mm * (3 * qx * qx + qy * qy) + v.thin_prism_per_mm * r2 + v.radial_k1_per_mm2 * r2 * qx
        dy = 2 * v.decentring_per_mm * qx * qy + v.radial_k1_per_mm2 * r2 * qy
        m = v.magnification_ratio / o.pixel_mm * (-1.0 if o.inverted else 1.0)
        u1, u2 = m * (qx + dx), m * (qy + dy)
        a = np.radians(v.rotation_deg)
        ca, sa = np.cos(a), np.sin(a)
        w1 = ca * u1 - sa * u2 + v.principal_point_px[0]
        w2 = sa * u1 + ca * u2 + v.principal_point_px[1]
        return np.column_stack([w1, w2])

    def project(self, points_mm: np.ndarray) -> np.ndarray:
        """Noise-free image coordinates ``(n, 4)`` = ``wl1, wl2, wr1, wr2`` [px] of microscope-frame points."""
        return np.hstack([self.project_view(points_mm, "l"), self.project_view(points_mm, "r")])

    @property
    def image_size_px(self) -> tuple[int, int]:
        """``(width, height)`` of both images [px]."""
        return self.optics.image_size_px

    def field_centre_mm(self) -> np.ndarray:
        """The microscope-frame point seen at the middle of both images, in the focal plane [mm] (the two
        views' principal points averaged; the weak-perspective inverse of the undistorted projection)."""
        o = self.optics
        width, height = o.image_size_px
        m = 1.0 / o.pixel_mm * (-1.0 if o.inverted else 1.0)
        pp = (np.asarray(o.left.principal_point_px) + np.asarray(o.right.principal_point_px)) / 2
        return np.array([((width - 1) / 2 - pp[0]) / m, ((height - 1) / 2 - pp[1]) / m, 0.0])

    def centroid_sigma_px(self, points_mm: np.ndarray) -> np.ndarray:
        """The dot finder's per-coordinate noise [px] at microscope-frame points ``(n, 3)`` [mm]: it grows with
        defocus, the height above the focal plane (:class:`CentroidNoise`)."""
        return self.noise.sigma_px(np.atleast_2d(points_mm)[:, 2], self.optics.depth_of_field_mm)

    def visible(self, w: np.ndarray, dot_diameter_mm: float) -> np.ndarray:
        """``(n, 2)`` booleans: is the whole dot inside the image, in the left and the right view."""
        width, height = self.optics.image_size_px
        margin = dot_diameter_mm / self.optics.pixel_mm / 2 + 2.0
        out = []
        for k in (0, 2):
            out.append((w[:, k] >= margin) & (w[:, k] <= width - 1 - margin)
                       & (w[:, k + 1] >= margin) & (w[:, k + 1] <= height - 1 - margin))
        return np.column_stack(out)

    def triangulate(self, w: np.ndarray, iterations: int = 8) -> np.ndarray:
        """Microscope-frame points ``(n, 3)`` [mm] whose projections best match ``w`` ``(n, 4)`` [px].

        The true model's least-squares triangulation (Gauss-Newton on the four image coordinates, with a
        numerical Jacobian, vectorised over points). Applied to noisy centres it gives the noise floor that
        no calibrated model can beat.
        """
        w = np.atleast_2d(np.asarray(w, dtype=float))
        o = self.optics
        m = 1.0 / o.pixel_mm * (-1.0 if o.inverted else 1.0)
        ppl, ppr = np.asarray(o.left.principal_point_px), np.asarray(o.right.principal_point_px)
        tan_half = np.tan(np.radians(o.convergence_deg) / 2)
        # start: weak-perspective inverse of the undistorted projection
        x0 = ((w[:, 0] - ppl[0]) + (w[:, 2] - ppr[0])) / (2 * m)
        y0 = ((w[:, 1] - ppl[1]) + (w[:, 3] - ppr[1])) / (2 * m)
        z0 = ((w[:, 2] - ppr[0]) - (w[:, 0] - ppl[0])) / (2 * m) / tan_half * -1.0
        p = np.column_stack([x0, y0, z0])
        h = 1e-6
        for _ in range(iterations):
            f = self.project(p)
            r = w - f
            jac = np.empty((len(p), 4, 3))
            for k in range(3):
                dp = p.copy()
                dp[:, k] += h
                jac[:, :, k] = (self.project(dp) - f) / h
            jtj = np.einsum("nik,nil->nkl", jac, jac)
            jtr = np.einsum("nik,ni->nk", jac, r)
            p = p + np.linalg.solve(jtj, jtr[..., None])[..., 0]
        return p

    # ------------------------------------------------------------------ stage
    def stage_to_microscope(self, stage_mm: np.ndarray, origin_mm: np.ndarray) -> np.ndarray:
        """Microscope-frame positions of stage-frame points ``(n, 3)`` [mm], stage zero at ``origin_mm``."""
        return np.asarray(origin_mm) + np.atleast_2d(stage_mm) @ self.stage.axes.T

    def microscope_to_stage(self, points_mm: np.ndarray, origin_mm: np.ndarray) -> np.ndarray:
        """Stage-frame coordinates of microscope-frame points ``(n, 3)`` [mm]."""
        return np.linalg.solve(self.stage.axes, (np.atleast_2d(points_mm) - np.asarray(origin_mm)).T).T

    def as_dict(self) -> dict:
        """All parameters as plain JSON-able values (nested dicts, units in the names)."""
        return _plain(asdict(self))

    def replace(self, **changes) -> "Microscope":
        """A copy with some top-level parts replaced (``optics=``, ``stage=``, ...)."""
        return replace(self, **changes)


def _plain(obj):
    if isinstance(obj, dict):
        return {k: _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if isinstance(obj, (np.floating, np.integer)):
        return obj.item()
    return obj


def from_dict(d: dict) -> Microscope:
    """Rebuild a :class:`Microscope` from :meth:`Microscope.as_dict` output."""
    def build(cls, data):
        kwargs = {}
        for f in fields(cls):
            if f.name not in data:
                continue
            val = data[f.name]
            sub = {"optics": Optics, "stage": Stage, "noise": CentroidNoise, "grid_plate": Plate,
                   "moving_plate": Plate, "imaging": Imaging, "left": View, "right": View}.get(f.name)
            if sub is not None:
                val = build(sub, val)
            elif isinstance(val, list):
                val = tuple(val)
            kwargs[f.name] = val
        return cls(**kwargs)
    return build(Microscope, d)


def describe(microscope: Microscope) -> pd.DataFrame:
    """What the microscope's parameters imply, with units: the quantities the paper estimates (θX, EX, EZ,
    K terms to first order), the perspective and the noise floor (``σX ≈ pixel·σc/√2``, ``σZ ≈ EZ·√2·σc`` for
    centre noise ``σc``)."""
    o, st, nz = microscope.optics, microscope.stage, microscope.noise
    t = np.tan(np.radians(o.convergence_deg) / 2)
    rows = [
        ("object pixel", 1e3 * o.pixel_mm, "µm/px", "optics.pixel_mm"),
        ("image size", f"{o.image_size_px[0]} × {o.image_size_px[1]}", "px", "optics.image_size_px"),
        ("convergence γ", o.convergence_deg, "degree", "optics.convergence_deg"),
        ("perspective distance L", o.perspective_distance_mm, "mm", "optics.perspective_distance_mm"),
        ("magnification change with depth", 100.0 / o.perspective_distance_mm, "%/mm", "1/L"),
        ("disparity per mm of depth", 2 * t / o.pixel_mm, "px/mm", "2 tan(γ/2) / pixel"),
        ("EZ (nominal)", o.pixel_mm / (2 * t), "mm/px", "pixel / (2 tan(γ/2))"),
        ("EX, EY (nominal)", -o.pixel_mm if o.inverted else o.pixel_mm, "mm/px", "inverted image"),
        ("θX (nominal)", -st.rotation_deg, "degree", "-stage.rotation_deg"),
        ("KYX ≈ -y_skew", -st.y_skew, "-", "stage.y_skew"),
        ("KYZ ≈ -y_tilt", -st.y_tilt, "-", "stage.y_tilt"),
        ("KZX ≈ -z_tilt_x", -st.z_tilt_x, "-", "stage.z_tilt_x"),
        ("KZY ≈ -z_tilt_y", -st.z_tilt_y, "-", "stage.z_tilt_y"),
        ("depth of field", f"±{o.depth_of_field_mm:g}", "mm", "optics.depth_of_field_mm"),
        ("centroid noise in focus", nz.in_focus_px, "px", "noise.in_focus_px"),
        ("noise floor σX in focus", 1e3 * o.pixel_mm * nz.in_focus_px / np.sqrt(2), "µm", "pixel·σc/√2"),
        ("noise floor σZ in focus", 1e3 * o.pixel_mm / (2 * t) * np.sqrt(2) * nz.in_focus_px, "µm", "EZ·√2·σc"),
        ("stage positioning noise", st.positioning_noise_um, "µm", "stage.positioning_noise_um"),
    ]
    return pd.DataFrame(rows, columns=["quantity", "value", "unit", "from"])


def depth_response(microscope: Microscope, z_mm: np.ndarray, *, x_mm: float = 0.0, y_mm: float = 0.0,
                   baseline_mm: float = 1.0) -> pd.DataFrame:
    """Disparity and magnification of each view against depth, measured by projecting points.

    For each height ``z`` a point at ``(x, y, z)`` and one ``baseline_mm`` further along x are projected.

    Returns
    -------
    DataFrame
        ``z_mm``, ``disparity_px`` (``w1_r − w1_l`` of the first point), ``magnification_l_px_per_mm``,
        ``magnification_r_px_per_mm`` (image length of the baseline divided by its length).
    """
    z = np.asarray(z_mm, dtype=float)
    a = np.column_stack([np.full_like(z, x_mm), np.full_like(z, y_mm), z])
    b = a + [baseline_mm, 0.0, 0.0]
    wa, wb = microscope.project(a), microscope.project(b)
    return pd.DataFrame({
        "z_mm": z,
        "disparity_px": wa[:, 2] - wa[:, 0],
        "magnification_l_px_per_mm": np.hypot(*(wb[:, 0:2] - wa[:, 0:2]).T) / baseline_mm,
        "magnification_r_px_per_mm": np.hypot(*(wb[:, 2:4] - wa[:, 2:4]).T) / baseline_mm,
    })
