"""Beyond the paper: a direct polynomial mapping from image coordinates to the stage frame.

The paper's chain is linear after its corrections, so what a CMO microscope does beyond them (perspective: a
disparity ``∝ z/(L − z)`` and a magnification that changes with depth; the disparity curvature the paper's
procedure misses; residual camera rotation) is left in its residuals. This model maps
``(v1, v2, D) = ((w1_l + w1_r)/2, (w2_l + w2_r)/2, u·(w_r − w_l))`` to stage coordinates with a polynomial of
total degree ``k`` (one degree per coordinate). ``u`` is the direction in which each dot's disparity changes
from position to position (in the Z sequence, if there is one), that is, with depth: ``(1, 0)`` for a CMO
microscope (§4: after alignment the disparity is along ``w1``), ``(0, 1)`` for the PIV Challenge rig, whose
second camera looks down obliquely. The variables are normalised to ``[−1, 1]`` over
the calibration set.

Two ways to calibrate, chosen from the set (``mode="auto"``):

``"moves"``
    the set has stage moves in X or Y (the paper's X, Y, Z sequences, or a free set ``V``). The targets are
    the commanded stage positions, with **one unknown offset per dot and sequence** (eliminated by centring),
    so no absolute plate position is needed.
``"zstack"``
    only a Z sequence, as in a lab with a Z stage alone. X and Y come from the plate: dot ``[row, col]`` of
    a ``rows × cols`` plate of pitch ``p`` sits at ``x = ((cols + 1)/2 − col)·p``, ``y = ((rows + 1)/2 − row)·p``
    (:meth:`slmlab.virtual.microscope.Plate.nominal_points`; ``[1, 1]`` at ``+x, +y``) plus the commanded X, Y; Z is
    the commanded stage Z. The frame is the plate's axes and the Z stage's direction.

In both, a stage's own errors at each position (positioning noise, lead and straightness errors: the same
for every dot of that position) are a **random effect per position**. Their variance and the centroid noise's
are estimated from the residuals (within and between positions), and X and Y are fitted by generalised least
squares (quasi-demeaning by position): the polynomial's shape comes from the many dots within each position,
and only its large-scale part from the (noisy) stage moves. Z keeps ordinary least squares (see
:func:`_theta`). Rows are weighted by how one point's scatter grows with defocus.

**Length reference.** A stage's scale error is invisible in its own commanded moves. Whenever the set has
a static ``grid`` pair, its dots are reconstructed and fitted to the plate's nominal lattice, and the metric
of the stage frame's X-Y block follows (:func:`plate_length_reference`): the stage's X and Y scale errors
relative to the plate, and the cosine between its X and Y axes, are reported. With
``length_reference="plate"`` the X and Y scales are then taken from the plate. That is not the default: the
plate lies in no plane of the stage frame, and the cosines between the stage's Z axis and its X and Y axes,
which no plate in one pose can measure, enter as their product with the plate's slope in the commanded
frame: second order, but on the ``paper`` preset (tilts of about 0.013) about 4e-4 in Y, more than its
stage's scale errors; the reported ``sigma`` includes the term. Z has no such reference (a plate is flat); for axes whose scale is the stage's, a
user can declare its uncertainty from the stage's datasheet as ``stage_scale_sigma`` (relative, 1σ).

* The degree is chosen on held-out positions (every third position of each sequence), never on test data,
  by their held-out error net of the stage's own positioning noise, with the one-standard-error rule (the
  lowest degree within one standard error of the best), and below the number of positions per sequence.
  Where the dots' world positions are known its degree in the depth variable ``D`` is below the number of
  distinct depths, and where a position holds more than one depth (a two-level plate, a stepped target) at most
  :data:`DEPTH_DEGREE` (quadratic, as the Soloff model's Z).
* Outliers (mismatched or misindexed dots) are down-weighted by iteratively reweighted least squares (Huber
  weights, then rejection beyond 10 robust sigmas); the rejected rows are reported.
* Per-point uncertainty ``sX, sY, sZ`` [mm] (1σ): the centroid noise as a function of depth (it grows with
  defocus), estimated from the scatter within positions; the coefficients' covariance (which
  carries the stage's random errors through the generalised least squares); and the scale uncertainty of
  each axis (the plate's for X and Y with ``length_reference="plate"``, the declared ``stage_scale_sigma``
  otherwise) times the distance from the frame's reference.
"""

from __future__ import annotations

import hashlib
import json
from itertools import combinations_with_replacement

import numpy as np
import pandas as pd
from scipy import sparse

from ..errors import SlmlabError
from ..io import CalibrationSet, IMAGE_COLUMNS
from ..linefit import point_keys
from .base import Model, register
from .folds import row_folds, thin_dots
from .frames import distinct_levels, levels, plate_xy, world_positions

__all__ = ["features", "fit_direct", "fit_frame", "check_options", "DirectModel", "LEGACY_FRAME", "DEGREE_ROWS",
           "DEPTH_DEGREE"]

#: the normalisation of model files written before the frame was fitted: centre, scale, disparity direction
LEGACY_FRAME = {"centre": [1024.0, 1024.0, 0.0], "scale": [1024.0, 1024.0, 100.0], "direction": [1.0, 0.0]}
RCOND = 1e-13  # relative eigenvalue cutoff of the least-squares fits' normal matrices
DEGREE_ROWS = 6000  # sets with more rows choose their degree on every k-th dot (at most this many rows)
#: where a stage position holds more than one depth (a target with depth of its own: a two-level plate, a stepped
#: target), the highest power of the depth variable ``D`` (and below the number of distinct depths):
#: the depths of a position share its stage error, and a cubic through the four depths of a two-level plate at two
#: positions follows those errors as a staircase, as optics; the optics bend smoothly in depth, as the Soloff model's
#: polynomials (quadratic in Z) say. On ``stereo-piv:3`` two-level-2z the direct model with a cubic was chosen at
#: 1.39x the best plain polynomial in X and Y; quadratic, it is 0.85x (and the default, which takes the cubic
#: polynomial there, 1.00x); on a stepped target in one pose (``stereo-dic:2``, five depths) the default took the
#: Soloff model in X at 1.05x, and now takes the direct model at 0.88x. With one depth per position (a Z stack, a
#: board stack) the cap is the number of depths, interior planes held out from five on: held to a quadratic, the
#: stage's error per position of a 13-plane stack (``greenough:3``) was estimated at 4 µm in Y, and the direct
#: model's Y was 3.7 µm off
DEPTH_DEGREE = 2
#: the stage's error per position (:func:`_solve`) has settled when an iteration moves it by less than this share
SETTLED = 0.01
#: the coordinates fitted with the stage's error per position as a random effect (X, Y; Z by ordinary least
#: squares: :func:`_theta`)
XY = np.array([True, True, False])


def _exponents(degree: int, nvar: int = 3) -> list[tuple[int, ...]]:
    out = []
    for d in range(1, degree + 1):
        for combo in combinations_with_replacement(range(nvar), d):
            out.append(tuple(combo.count(k) for k in range(nvar)))
    return out


def _raw_variables(w: np.ndarray, direction, nvar: int = 3) -> np.ndarray:
    """``(v1, v2, D)`` [px], and with ``nvar = 4`` also ``D⊥``: the disparity's component across ``u``."""
    w = np.asarray(w, float)
    u = np.asarray(direction, float)
    d1, d2 = w[:, 2] - w[:, 0], w[:, 3] - w[:, 1]
    cols = [(w[:, 0] + w[:, 2]) / 2, (w[:, 1] + w[:, 3]) / 2, u[0] * d1 + u[1] * d2]
    if nvar == 4:
        cols.append(-u[1] * d1 + u[0] * d2)
    return np.column_stack(cols)


def _nvar(frame: dict) -> int:
    return int(frame.get("variables", 3))


def _variables(w: np.ndarray, frame: dict) -> np.ndarray:
    v = _raw_variables(w, frame["direction"], _nvar(frame))
    return (v - np.asarray(frame["centre"])) / np.asarray(frame["scale"])


def fit_frame(w: np.ndarray, key: np.ndarray | None = None, use: np.ndarray | None = None, *,
              variables: int = 3, depth: np.ndarray | None = None) -> dict:
    """The normalisation of a calibration set's image coordinates ``(n, 4)`` [px]: the disparity direction
    ``u``, and the centre and half-range [px] of ``(v1, v2, D)``, so that the set spans ``[−1, 1]`` in each.

    ``u`` is the principal direction of how each dot's disparity vector changes from position to position
    (``key``: one label per dot and sequence; only the rows ``use``, typically the Z sequence's, if any),
    with its largest component positive: the direction depth moves the disparity in. Across the field the disparity also varies, and for
    an oblique camera far more than with depth, so the spread of the disparities themselves would mislead."""
    w = np.asarray(w, float)
    if depth is not None:  # known depths (a known target): the direction of the disparity's regression on depth
        d = w[:, 2:4] - w[:, 0:2]
        u = (d - d.mean(axis=0)).T @ (np.asarray(depth, float) - np.mean(depth))
    else:
        sub = w if use is None or not np.any(use) else w[use]
        d = sub[:, 2:4] - sub[:, 0:2]
        if key is None:
            d = d - d.mean(axis=0)
        else:
            _, inv = np.unique(key if use is None or not np.any(use) else key[use], return_inverse=True)
            d = d - _means(d, inv.ravel(), inv.max() + 1, np.ones(len(d)))[inv.ravel()]
        _, vec = np.linalg.eigh(d.T @ d)
        u = vec[:, -1]
    u = u / max(np.linalg.norm(u), 1e-300)
    u = u if u[np.argmax(np.abs(u))] > 0 else -u
    v = _raw_variables(w, u, variables)
    lo, hi = v.min(axis=0), v.max(axis=0)
    return {"centre": ((lo + hi) / 2).tolist(), "scale": np.maximum((hi - lo) / 2, 1e-6).tolist(),
            "direction": u.tolist(), "variables": int(variables)}


def features(w: np.ndarray, degree: int, frame: dict | None = None) -> np.ndarray:
    """Monomials of the normalised ``(v1, v2, D)`` up to total ``degree`` (no constant) ``(n, m)``.

    Built from power tables (``v**k`` by repeated multiplication, then two products per monomial) into a
    preallocated array: no ``pow`` calls, no temporary per monomial."""
    return _features_v(_variables(w, frame or LEGACY_FRAME), degree)


def _features_v(v: np.ndarray, degree: int) -> np.ndarray:
    """:func:`features` of normalised variables ``(n, 3)`` or ``(n, 4)``."""
    n, nvar = v.shape
    powers = np.empty((nvar, degree + 1, n))
    powers[:, 0] = 1.0
    for k in range(1, degree + 1):
        np.multiply(powers[:, k - 1], v.T, out=powers[:, k])
    return _features_t(powers, degree).T


def _features_t(powers: np.ndarray, degree: int) -> np.ndarray:
    """Monomial-major features ``(m, n)``, each row written contiguously, from power tables."""
    nvar = powers.shape[0]
    exps = _exponents(degree, nvar)
    out = np.empty((len(exps), powers.shape[2]))
    for row, e in enumerate(exps):
        np.multiply(powers[0, e[0]], powers[1, e[1]], out=out[row])
        for k in range(2, nvar):
            if e[k]:
                out[row] *= powers[k, e[k]]
    return out


# --------------------------------------------------------------------------------------------- rows


def _rows(cal: CalibrationSet, mode: str):
    pts, target, mode = world_positions(cal, mode)
    codes = {s: k for k, s in enumerate(sorted(pts["sequence"].unique()))}
    seq_code = pts["sequence"].map(codes).to_numpy()
    positions = seq_code * 1_000_000 + pts["position"].to_numpy()
    if mode == "moves":
        groups = point_keys(pts["row"], pts["col"]) * max(16, len(codes)) + seq_code   # a dot per sequence
    else:  # one group: the world position is known up to one common constant
        groups = np.zeros(len(pts), np.int64)
    return pts, groups, positions, target, mode


def _mean_by(inv: np.ndarray, n: int, wts: np.ndarray):
    """The weighted means ``(n, m)`` per group ``inv`` of the rows of any ``x (rows, m)``, as a function of
    ``x``: one sparse product (the same products summed in the same order as a ``bincount`` per column, so the
    same bits, in one pass), its matrix built once for every ``x`` that shares the groups and weights."""
    sw = np.maximum(np.bincount(inv, wts, n), 1e-300)[:, None]
    groups = sparse.csc_matrix((wts, inv, np.arange(len(inv) + 1)), shape=(n, len(inv)))  # one row per column
    return lambda x: (groups @ x) / sw


def _means(x: np.ndarray, inv: np.ndarray, n: int, wts: np.ndarray) -> np.ndarray:
    """Weighted means ``(n, m)`` of the rows of ``x`` per group ``inv`` (:func:`_mean_by`)."""
    return _mean_by(inv, n, wts)(x)


def _per_row(means: np.ndarray, inv: np.ndarray) -> np.ndarray:
    """Group means ``(n, m)`` for each row of groups ``inv``; one group's mean row broadcasts as it is."""
    return means if len(means) == 1 else means[inv]


def _design(pc, pm, theta, pinv, cols, sq) -> np.ndarray:
    """One coordinate's design matrix of :func:`_solve`, column-major (the memory order its Gram matrix has
    always been computed in, so the same bits): the monomials ``cols`` of the centred features ``pc``
    (column-major) less ``θ_t`` times their position means ``pm`` (skipped where every ``θ_t`` is 0, as in
    Z), each row scaled by its weight's root ``sq``."""
    pck = pc if cols.all() else pc[:, cols]
    a = np.empty(pck.shape, order="F")
    if theta.any():
        shift = np.take(theta * pm.T[cols], pinv, axis=1)  # (columns, rows): θ_t · mean, per row
        np.subtract(pck, shift.T, out=a)
        a *= sq[:, None]
    else:
        np.multiply(pck, sq[:, None], out=a)
    return a


# --------------------------------------------------------------------------------------------- solver
def _least_squares(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Minimum-norm least squares through the eigen-decomposition of the normal matrix ``AᵀA`` (a few
    times faster than an SVD of the tall ``A``). Directions with eigenvalues below ``RCOND`` of the largest
    are dropped: monomials the data cannot tell apart (``x⁴`` on 4 lattice columns). Returns the solution
    and ``V`` with ``(AᵀA)⁺ = V Vᵀ``."""
    lam, vec = np.linalg.eigh(a.T @ a)
    keep = lam > RCOND * lam[-1]
    v = vec[:, keep] / np.sqrt(lam[keep])
    return v @ (v.T @ (a.T @ b)), v


def _theta(s_e2, s_u2, n_t) -> np.ndarray:
    """Quasi-demeaning factors ``(positions, 3)``. Z keeps ``θ = 0`` (ordinary least squares): its depth
    dependence is known only between positions (a plate is flat), while within a position the disparity's
    noise would pull ``∂Z/∂D`` towards zero (errors in the variables) once the between part is down-weighted."""
    theta = 1 - np.sqrt(s_e2[None, :] / (s_e2[None, :] + n_t[:, None] * s_u2[None, :]))
    theta[:, ~XY] = 0.0
    return theta


def _robust_weights(r: np.ndarray, wts: np.ndarray, it: int) -> np.ndarray:
    """:func:`_solve`'s row weights for iteration ``it`` from the rows' normalised residuals ``r``: Huber at 3
    robust sigmas (of the rows weighted now, ``wts``) for the first three, then rejection beyond 10."""
    scale = 1.4826 * np.median(r[wts > 0]) + 1e-12
    if it < 3:
        return np.minimum(1.0, 3.0 * scale / np.maximum(r, 1e-15))      # Huber
    return (r < 10.0 * scale).astype(float)                             # reject beyond 10 robust sigmas


def _solve(phi, target, groups, positions, *, mask=None, iterations: int = 8, variance=None, clusters=None,
           precision=None):
    """Generalised least squares with per-group offsets (centred out) and a random effect per position.

    Each coordinate ``k``: rows are centred per group (dot), then quasi-demeaned per position,
    ``y − θ_t·ȳ_t`` with ``θ_t = 1 − sqrt(σe² / (σe² + n_t σu²))`` (X and Y; see :func:`_theta` for Z)
    (``σe``: the scatter of one row, ``σu``: the
    stage's error per position, both from the previous iteration's residuals, or fixed by ``variance =
    (σe², σu²)``, each ``(3,)`` [mm²]: estimate them once with a rich polynomial, else a model's misfit would
    pass for stage error). An estimate of ``σu`` in X or Y still rising when the iterations end (by more than
    :data:`SETTLED` at the last one, and above the first) is feeding on itself: down-weighting the positions'
    means lets the fit's means drift from them, which raises ``σu``, which down-weights them further. Its first
    estimate (ordinary least squares, every row at full weight) replaces it; ``σe``, from the scatter within
    positions, which the drift hardly touches, stays (Z's ``θ`` is 0: its estimate does not feed back). Where
    the positions' means carry how X or Y changes with depth (a Z stack of a flat plate) the drift is a shear:
    on 13 planes of a random Greenough rig (``greenough:3``) ``σu`` in Y went 0.23, 0.40, 0.56 ... 3.5 µm, and
    the direct model's Y was 0.7 % of depth off (1.8 µm RMS inside the volume, against 0.15 µm for the Soloff
    model; 0.20 µm with the first estimate). Robust weights: Huber first, then rejection beyond 10 robust
    sigmas (inliers keep full weight, gross outliers get none). ``clusters``: labels of rows whose errors are
    shared (a plate's dots, whose fabrication errors are in every plane of a Z stack): the coefficients'
    covariance is then the cluster-robust sandwich, else ``σe²·(AᵀA)⁻¹``. ``precision``: relative weights ``(n, 3)`` of the rows
    per coordinate (mean 1), the inverse of how the scatter of one point grows with defocus; ``σe`` is then
    the scatter at unit weight."""
    labels, inv = np.unique(groups, return_inverse=True)
    plabels, pinv = np.unique(positions, return_inverse=True)
    inv, pinv = inv.ravel(), pinv.ravel()
    n_g, n_p, m = len(labels), len(plabels), phi.shape[1]
    mask = np.ones((m, 3), bool) if mask is None else mask
    wts = np.ones(len(phi))
    hw = np.ones((len(phi), 3)) if precision is None else np.asarray(precision, float)
    s_e2, s_u2 = (np.ones(3), np.zeros(3)) if variance is None else (np.asarray(variance[0]), np.asarray(variance[1]))
    n_t = np.bincount(pinv, minlength=n_p).astype(float)
    theta = _theta(s_e2, s_u2, n_t)
    per_group = np.bincount(inv, minlength=n_g)
    dof_dots = np.mean(per_group[inv] / np.maximum(per_group[inv] - 1, 1)) if n_g > 1 else 1.0
    for it in range(iterations):
        by_group, by_position = _mean_by(inv, n_g, wts), _mean_by(pinv, n_p, wts)
        pc, sc = phi - _per_row(by_group(phi), inv), target - _per_row(by_group(target), inv)
        pm, sm = by_position(pc), by_position(sc)
        pc_columns = np.asfortranarray(pc)  # the designs are built and multiplied column by column
        coef = np.zeros((m, 3))
        designs = []
        for k in range(3):
            sq = np.sqrt(wts * hw[:, k])
            th = theta[pinv, k]
            a = _design(pc_columns, pm, theta[:, k], pinv, mask[:, k], sq)
            b = (sc[:, k] - th * sm[pinv, k]) * sq
            coef[mask[:, k], k], vk = _least_squares(a, b)
            designs.append((a, vk, b))
        res = sc - pc @ coef
        n_t = np.bincount(pinv, wts, n_p)
        rm = by_position(res)
        within = res - rm[pinv]
        if variance is None:
            dof_pos = np.mean(n_t[pinv] / np.maximum(n_t[pinv] - 1, 1))
            dof_par = wts.sum() / max(wts.sum() - m - n_g - n_p, 1.0)
            s_e2 = np.maximum(np.sum(wts[:, None] * hw * within ** 2, 0) / wts.sum() * dof_dots * dof_pos * dof_par,
                              1e-24)
            live = n_t > 0.5
            s_u2, previous = np.maximum(np.mean(rm[live] ** 2, 0) - s_e2 * np.mean(1 / n_t[live]), 0.0), s_u2
            first = s_u2 if it == 0 else first
            rising = (np.sqrt(s_u2) - np.sqrt(previous) > SETTLED * np.sqrt(s_u2)) & (s_u2 > first) & XY
            theta = _theta(s_e2, s_u2, n_t)
        new = _robust_weights(np.linalg.norm(within * np.sqrt(hw / s_e2), axis=1), wts, it)
        if it >= 4 and np.allclose(new, wts, atol=1e-4) and (variance is not None or not rising.any()):
            break
        if variance is not None and np.array_equal(new, wts) and (it >= 3 or (new == 1.0).all()):
            break  # a fixed point (θ fixed, the same weights): every further iteration repeats this one, bit for bit
        wts = new
    if variance is None:  # an estimate still rising at the last iteration feeds on itself: the first one stays
        s_u2 = np.where(rising, first, s_u2)
    offsets = _means(target - phi @ coef, inv, n_g, wts)
    return {"coef": coef, "weights": wts, "feature_mean": wts @ phi / wts.sum(), "labels": labels, "inv": inv,
            "offsets": offsets, "within": within, "pinv": pinv, "sigma_e_mm": np.sqrt(s_e2),
            "sigma_u_mm": np.sqrt(s_u2), "cov": _coefficient_cov(designs, coef, mask, s_e2, clusters)}


def _coefficient_cov(designs, coef: np.ndarray, mask: np.ndarray, s_e2: np.ndarray, clusters) -> np.ndarray:
    """The coefficients' covariance ``(3, m, m)`` of :func:`_solve`'s fit: ``σe²·(AᵀA)⁻¹`` per coordinate, or
    the cluster-robust sandwich where ``clusters`` labels rows whose errors are shared. ``designs``: per
    coordinate ``(A, V, b)`` with ``(AᵀA)⁺ = V Vᵀ``."""
    m = coef.shape[0]
    cov = np.zeros((3, m, m))
    if clusters is not None:
        _, cinv = np.unique(clusters, return_inverse=True)
        cinv = cinv.ravel()
        n_c = cinv.max() + 1
    for k in range(3):
        idx = np.flatnonzero(mask[:, k])
        a, vk, b = designs[k]
        bread = vk @ vk.T
        if clusters is None:
            cov[k][np.ix_(idx, idx)] = s_e2[k] * bread
        else:
            score = a * (b - a @ coef[idx, k])[:, None]
            sums = np.stack([np.bincount(cinv, score[:, j], n_c) for j in range(score.shape[1])], axis=1)
            cov[k][np.ix_(idx, idx)] = bread @ (sums.T @ sums) @ bread * n_c / max(n_c - 1, 1)
    return cov


def _held_out_error(phi, target, groups, positions, folds, variance, precision, mask=None) -> np.ndarray:
    """RMS [mm] per coordinate on the test rows of each ``(train, test)`` fold of a fit on its training rows,
    net of the stage's own error at each held-out position (its variance ``σu²`` estimated by the fit), pooled
    over the folds."""
    sq, count = np.zeros(3), 0
    for train, test in folds:
        f = _solve(phi[train], target[train], groups[train], positions[train], variance=variance,
                   precision=precision[train], mask=mask)
        idx = np.minimum(np.searchsorted(f["labels"], groups[test]), len(f["labels"]) - 1)  # labels are sorted
        ok = f["labels"][idx] == groups[test]
        if not ok.any():
            continue
        e = phi[test][ok] @ f["coef"] + f["offsets"][idx[ok]] - target[test][ok]
        n = np.linalg.norm(e / f["sigma_e_mm"], axis=1)
        inlier = n <= np.median(n) + 5 * 1.4826 * np.median(np.abs(n - np.median(n)))  # robust to outliers
        e, pos = e[inlier], positions[test][ok][inlier]
        _, pinv = np.unique(pos, return_inverse=True)
        pinv = pinv.ravel()
        pm = _means(e, pinv, pinv.max() + 1, np.ones(len(e)))
        n_t = np.bincount(pinv)
        within = np.mean((e - pm[pinv]) ** 2, axis=0)
        between = np.mean(pm ** 2, axis=0) - f["sigma_u_mm"] ** 2 - f["sigma_e_mm"] ** 2 * np.mean(1 / n_t)
        sq += len(e) * (within + np.maximum(between, 0.0))
        count += len(e)
    return np.sqrt(sq / max(count, 1))


def _noise_variance(noise_poly: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """One point's variance ``(n, 3)`` [mm²] at normalised depths ``depth`` (n,): ``a + b·Dn + c·Dn²`` per
    coordinate (:func:`_noise_vs_depth`)."""
    return (np.asarray(noise_poly) @ np.stack([np.ones_like(depth), depth, depth ** 2])).T


def _precision(noise_poly: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """Relative weights ``(n, 3)`` (mean 1, within a factor 10 either way) of rows at normalised depth
    ``depth``: the inverse of their variance under ``noise_poly``."""
    var = _noise_variance(noise_poly, depth)
    scale = np.mean(np.abs(var), 0)
    if not (np.isfinite(scale).all() and (scale > 0).all()):  # no scatter left to measure: equal weights
        return np.ones_like(var)
    var = np.clip(var, 0.1 * scale, 10 * scale)
    p = 1.0 / var
    return p / p.mean(axis=0)


def _noise_vs_depth(vn_depth, within, wts, dof) -> np.ndarray:
    """Per coordinate, the variance [mm²] of one row as ``a + b·Dn + c·Dn²`` of the normalised depth variable
    (the centroid noise grows with defocus), fitted to the squared within-position residuals. ``(3, 3)``."""
    good = wts > 0.5
    a = np.column_stack([np.ones(good.sum()), vn_depth[good], vn_depth[good] ** 2])
    out = np.zeros((3, 3))
    for k in range(3):
        out[k] = np.linalg.lstsq(a, dof * within[good, k] ** 2, rcond=None)[0]
    return out


def plate_length_reference(cal: CalibrationSet, frame: dict, degree: int, coef, const) -> dict:
    """The stage's X and Y scale against the static grid plate's pitch (module docstring).

    The grid pair's dots inside the calibrated region are reconstructed in the commanded stage frame and
    fitted by ``t + a·x + b·y`` (``x, y`` the plate's nominal coordinates; ``a, b`` [mm per mm], 3-vectors).
    The plate's lattice is square and of known pitch: ``aᵀGa = bᵀGb = 1``, ``aᵀGb = 0``, where ``G`` is the
    Euclidean metric of the commanded frame. Its X-Y block (``Gxx, Gxy, Gyy``) follows from these three
    equations, taking the Z terms as Euclidean (their cross terms are second order): ``√Gxx`` and ``√Gyy`` are
    the real lengths of a commanded millimetre along X and Y, and ``Gxy/√(Gxx·Gyy)`` the cosine between the
    stage's X and Y axes. Returns ``factor`` (``√Gxx, √Gyy``), their 1σ ``sigma``, ``xy_cosine`` and the
    number of ``dots`` used (factors 1 if there is no grid pair)."""
    none = {"factor": [1.0, 1.0], "sigma": [0.0, 0.0], "xy_cosine": None, "dots": 0}
    grid = cal.sequence("grid").dropna(subset=IMAGE_COLUMNS)
    if len(grid) < 20:
        return none
    w = grid[IMAGE_COLUMNS].to_numpy(float)
    inside = (np.abs(_variables(w, frame)) <= 1.0).all(axis=1)
    if inside.sum() < 20:
        return none
    p = features(w[inside], degree, frame) @ coef + const
    g = plate_xy(grid["row"].to_numpy()[inside], grid["col"].to_numpy()[inside], cal.plate("grid"))
    design = np.column_stack([np.ones(len(g)), g])
    sol, *_ = np.linalg.lstsq(design, p, rcond=None)
    a, b = sol[1], sol[2]
    lhs = np.array([[a[0] ** 2, 2 * a[0] * a[1], a[1] ** 2],
                    [b[0] ** 2, 2 * b[0] * b[1], b[1] ** 2],
                    [a[0] * b[0], a[0] * b[1] + a[1] * b[0], a[1] * b[1]]])
    try:
        gxx, gxy, gyy = np.linalg.solve(lhs, [1 - a[2] ** 2, 1 - b[2] ** 2, -a[2] * b[2]])
    except np.linalg.LinAlgError:
        return none
    if not (np.isfinite([gxx, gxy, gyy]).all() and gxx > 0 and gyy > 0):  # no metric: the grid cannot measure
        return none
    resid = p - design @ sol
    s2 = np.sum(resid[:, :2] ** 2) / max(2 * (len(g) - 3), 1)
    sgg = np.sum((g - g.mean(axis=0)) ** 2) / 2
    cosine = gxy / np.sqrt(gxx * gyy)
    # 1σ: the fit's, and the neglected Z cross terms: the plate's slope in the commanded frame (a₃, b₃) times
    # the cosine between the stage's Z axis and its X or Y axis, which nothing here measures. That cosine is the
    # sum of two tilts (the X or Y axis out of the plate's plane, the Z axis off its normal); each is taken as
    # large as the largest tilt the data show (the X-Y cosine, a₃, b₃). With tilts of 1e-2 the term is 1e-4,
    # as large as the scale errors measured: the plate's reference is then no better than the stage's.
    tilt = max(abs(cosine), abs(a[2]), abs(b[2]))
    sigma = np.hypot(np.sqrt(s2 / sgg), np.abs([a[2], b[2]]) * 2 * tilt)
    return {"factor": [float(np.sqrt(gxx)), float(np.sqrt(gyy))], "sigma": [float(v) for v in sigma],
            "xy_cosine": float(cosine), "dots": int(inside.sum())}


def _depth_cap(target: np.ndarray, positions: np.ndarray, mode: str, max_degree: int) -> int:
    """One more than the highest power of the depth variable ``D`` allowed: the number of distinct depths where
    the dots' world positions ``target`` are known, at most :data:`DEPTH_DEGREE` + 1 where a stage position (of
    ``positions``, one label per row) holds more than one depth (a target with depth of its own, in any
    sequence); no cap on stage moves."""
    if mode not in ("target", "zstack"):
        return max_degree + 1
    depths = distinct_levels(target)
    several = pd.Series(levels(target)).groupby(np.asarray(positions)).nunique().max() > 1
    return min(depths, DEPTH_DEGREE + 1) if several else depths


def _monomial_mask(degrees, nvar: int, depth_cap: int) -> np.ndarray:
    """``(m, 3)`` which monomials each coordinate uses: total degree within its own, and degree in the depth
    variable ``D`` below ``depth_cap`` (:func:`_depth_cap`)."""
    return np.array([[sum(e) <= dk and e[2] < depth_cap for dk in degrees] for e in _exponents(max(degrees), nvar)])


def _choose_degrees(w, frame, target, groups, positions, folds, variance, precision, depth_cap, max_degree, sampled,
                    one_se: bool = True):
    """Held-out RMS [mm] per degree and coordinate on ``folds`` (``(train, test)`` row masks), and the degree
    per coordinate: by the one-standard-error rule (the lowest degree within one standard error of the best)
    where the held-out rows lie on the calibration's own axes (``one_se``), else the best."""
    nvar = _nvar(frame)
    cv = {}
    n_train = min(tr.sum() for tr, _ in folds)
    for d in range(1, max_degree + 1):
        phi = features(w, d, frame)
        if d > 1 and (phi.shape[1] + 1 >= n_train or d >= sampled):
            break
        mask = _monomial_mask([d] * 3, nvar, depth_cap)
        cv[d] = _held_out_error(phi, target, groups, positions, folds, variance, precision, mask)
    # Held-out positions on the calibration's own axes cannot see the rest of the volume, where a needlessly
    # high degree extrapolates badly: hence the rule. Crossed folds (new depths and new dots) do see it.
    se = 1 / np.sqrt(2 * sum(te.sum() for _, te in folds)) if one_se else 0.0
    degrees = [min(d for d in cv if cv[d][k] <= min(v[k] for v in cv.values()) * (1 + se)) for k in range(3)]
    return degrees, cv


def fit_direct(cal: CalibrationSet, degree: int | None = None, max_degree: int = 5, *, mode: str = "auto",
               length_reference: str = "stage", variables="auto"):
    """Fit the direct model; ``degree=None`` chooses it per coordinate on held-out positions;
    ``variables``: 3 (``v1, v2, D``), 4 (and ``D⊥``), or ``"auto"`` (4 where the held-out errors say the fourth
    carries information). Returns a dict with ``coef``, ``const``, ``frame``, ``degrees``, ``cv`` (held-out
    RMS per degree), ``weights``, ``sigma_mm`` (scatter of one point), ``stage_error_mm`` (per position),
    ``noise_poly``, ``cov``, ``suspects``, ``mode`` and ``variables_cv``."""
    if variables not in (3, 4, "auto"):
        raise SlmlabError(f"variables must be 3, 4 or 'auto', not {variables!r}")
    pts, groups, positions, target, mode = _rows(cal, mode)
    w = pts[IMAGE_COLUMNS].to_numpy(float)
    dots = point_keys(pts["row"], pts["col"]) * max(16, int(positions.max()) // 1_000_000 + 1) + positions // 1_000_000
    known_depth = target[:, 2] if mode == "target" else None
    in_z = (pts["sequence"] == "Z").to_numpy()
    frames = {3: fit_frame(w, dots, in_z, depth=known_depth)}
    depth_cap = _depth_cap(target, positions, mode, max_degree)
    variance, precision = _variance_components(w, frames[3], target, groups, positions, max_degree, depth_cap)
    if variables != 3:
        frames[4] = fit_frame(w, dots, in_z, depth=known_depth, variables=4)
        if variables == 4:
            frames = {4: frames[4]}
    if degree is None:
        folds = _degree_folds(pts, mode)
        if len(pts) > DEGREE_ROWS:  # the degree is chosen on every k-th dot: a ranking, not the fit, needs them
            keep = thin_dots(pts, DEGREE_ROWS)
            folds = [(tr & keep, te & keep) for tr, te in folds]
        frame, degrees, cv, variables_cv = _choose_variables_and_degrees(
            cal, w, frames, target, groups, positions, folds, variance, precision, depth_cap, max_degree, mode)
    else:
        degrees = [int(d) for d in np.broadcast_to(np.asarray(degree, int), (3,))]
        frame, cv, variables_cv = (frames[4] if variables == 4 else frames[3]), {}, {}
    phi = features(w, max(degrees), frame)
    mask = _monomial_mask(degrees, _nvar(frame), depth_cap)
    dots_only = point_keys(pts["row"], pts["col"]) if mode != "moves" else None
    fit = _solve(phi, target, groups, positions, mask=mask, variance=variance, clusters=dots_only,
                 precision=precision)
    coef, wts = fit["coef"], fit["weights"]
    if mode == "moves":  # the first moving sequence's first position: plate centre at its commanded position
        first = pts["position"].to_numpy() == pts.groupby("sequence")["position"].transform("min").to_numpy()
        const = np.mean(target[first] - phi[first] @ coef, axis=0)
    else:
        const = np.sum(wts[:, None] * (target - phi @ coef), 0) / wts.sum()
    scale = {"factor": [1.0, 1.0], "sigma": [0.0, 0.0], "xy_cosine": None, "dots": 0}
    if mode == "moves":  # measured (and reported) whenever there is a grid pair; applied on request
        scale = plate_length_reference(cal, frame, max(degrees), coef, const)
        if length_reference == "plate":
            coef[:, :2] *= scale["factor"]
            const[:2] *= scale["factor"]
    sigma, noise_poly = _point_scatter(pts, fit, mode, _variables(w, frame)[:, 2])
    good = wts > 0.1
    suspects = pts[~good][["sequence", "position", "row", "col"]].assign(weight=wts[~good])
    return {"coef": coef, "const": const, "frame": frame, "degree": max(degrees), "degrees": degrees, "cv": cv,
            "weights": wts, "sigma_mm": sigma, "stage_error_mm": fit["sigma_u_mm"],
            "noise_poly": noise_poly, "cov": fit["cov"], "feature_mean": fit["feature_mean"], "suspects": suspects,
            "mode": mode, "length_reference": scale, "variables_cv": variables_cv}


#: the last few variance components computed, by a digest of their inputs: the default fits the same rows in
#: the same frame once per plain-polynomial degree (and again per held-out fold), and each estimate is two
#: rich-polynomial solves (the same inputs give the same bits, so the cache changes no result)
_VARIANCE_CACHE: dict[bytes, tuple] = {}
_VARIANCE_CACHE_SIZE = 16


def _variance_components(w, frame, target, groups, positions, max_degree: int, depth_cap: int):
    """The variance components (one row's scatter, the stage's error per position) from a rich polynomial,
    and how one point's scatter grows with defocus (the rows' relative precision). Returns ``(variance,
    precision)`` for :func:`_solve` (copies: the caller may keep or change them)."""
    digest = hashlib.blake2b(json.dumps([frame, max_degree, depth_cap], sort_keys=True, default=str).encode())
    for a in (w, target, groups, positions):
        a = np.ascontiguousarray(a)
        digest.update(f"{a.dtype}{a.shape}".encode())
        digest.update(a.tobytes())
    key = digest.digest()
    if key not in _VARIANCE_CACHE:
        if len(_VARIANCE_CACHE) >= _VARIANCE_CACHE_SIZE:
            _VARIANCE_CACHE.pop(next(iter(_VARIANCE_CACHE)))  # the oldest
        _VARIANCE_CACHE[key] = _estimate_variance(w, frame, target, groups, positions, max_degree, depth_cap)
    (s_e2, s_u2), precision = _VARIANCE_CACHE[key]
    return (s_e2.copy(), s_u2.copy()), precision.copy()


def _estimate_variance(w, frame, target, groups, positions, max_degree: int, depth_cap: int):
    """:func:`_variance_components`, computed."""
    rich = max(d for d in range(1, max_degree + 1) if d == 1 or len(_exponents(d)) * 4 < len(w))
    phi_rich = features(w, rich, frame)
    rich_mask = _monomial_mask([rich] * 3, 3, depth_cap)
    depth = _variables(w, frame)[:, 2]
    pre = _solve(phi_rich, target, groups, positions, mask=rich_mask)
    precision = _precision(_noise_vs_depth(depth, pre["within"], pre["weights"], 1.0), depth)
    pre = _solve(phi_rich, target, groups, positions, precision=precision, mask=rich_mask)
    return (pre["sigma_e_mm"] ** 2, pre["sigma_u_mm"] ** 2), precision


def _degree_folds(pts, mode: str) -> list:
    """The held-out folds the degree is chosen on: every third position of each sequence for stage moves;
    crossed folds of positions and dots where the dots' world positions are known."""
    if mode == "moves":
        held = (pts["position"].to_numpy() % 3 == 0)
        return [(~held, held)]
    return row_folds(pts, mode, diagonal=True)


def _choose_variables_and_degrees(cal, w, frames, target, groups, positions, folds, variance, precision,
                                  depth_cap, max_degree, mode):
    """The variables (3 or 4, where the fourth lowers the held-out error by 5 %) and the degree per
    coordinate (:func:`_choose_degrees`). Returns ``(frame, degrees, cv, variables_cv)``."""
    trains = [tr for tr, _ in folds]
    if (not folds or any(not tr.any() or not te.any() for tr, te in folds)
            or (mode == "moves" and (min(len(np.unique(positions[tr])) for tr in trains) < 2))):
        raise SlmlabError("too few stage positions to choose the degree (at least 3 per sequence); give "
                          "degree=... or image more positions", cal.path)
    # a polynomial of degree d along a sequence needs more than d of its positions to be pinned down
    n_pos = pd.Series(positions).groupby(positions // 1_000_000).nunique()
    # (on stage moves; where the dots' world positions are known the depth variable's own cap says it)
    sampled = (min(pd.Series(positions[tr]).groupby(positions[tr] // 1_000_000).nunique().min() for tr in trains)
               if n_pos.min() >= 3 and mode == "moves" else max_degree + 1)
    chosen, variables_cv = {}, {}
    for nv, fr in frames.items():
        chosen[nv] = _choose_degrees(w, fr, target, groups, positions, folds, variance, precision, depth_cap,
                                     max_degree, sampled, one_se=mode == "moves")
        variables_cv[nv] = [float(min(v[k] for v in chosen[nv][1].values())) for k in range(3)]
    nv = 3
    if 4 in chosen and 3 in chosen:
        tiny = 1e-12  # mm: held-out errors of zero (noise-free data) compare as equal
        ratio = np.exp(np.mean(np.log(np.maximum(variables_cv[4], tiny) / np.maximum(variables_cv[3], tiny))))
        nv = 4 if ratio < 0.95 else 3
    elif 4 in chosen:
        nv = 4
    degrees, cv = chosen[nv]
    return frames[nv], degrees, {d: [float(x) for x in v] for d, v in cv.items()}, variables_cv


def _point_scatter(pts, fit: dict, mode: str, depth) -> tuple[np.ndarray, np.ndarray]:
    """One point's scatter ``sigma`` (3,) [mm] and its growth with defocus ``noise_poly`` (3, 3), from the
    final fit's within-position residuals (net of the plate's fabrication errors where the dots' world
    positions are known)."""
    wts, within, sigma = fit["weights"], fit["within"], fit["sigma_e_mm"]
    n_pt = np.bincount(fit["pinv"], wts)[fit["pinv"]]
    dof = np.mean(n_pt / np.maximum(n_pt - 1, 1))
    if mode == "moves":
        n_pg = np.bincount(fit["inv"])[fit["inv"]]
        dof *= np.mean(n_pg / np.maximum(n_pg - 1, 1))
    else:  # the plate's fabrication errors are in the X, Y targets, the same in every plane: a per-dot
        # effect (in the coefficients' covariance through the clusters). One point's scatter is measured
        # across planes.
        _, dinv = np.unique(point_keys(pts["row"], pts["col"]), return_inverse=True)
        dinv = dinv.ravel()
        n_d = np.bincount(dinv, wts)
        fab = _means(within, dinv, len(n_d), wts)
        within = within - fab[dinv]
        dof *= np.mean(n_d[dinv] / np.maximum(n_d[dinv] - 1, 1))
        sigma = np.sqrt(np.sum(wts[:, None] * within ** 2, 0) / wts.sum() * dof)
    return sigma, _noise_vs_depth(depth, within, wts, dof)


def check_options(*, degree=None, length_reference: str = "stage", stage_scale_sigma: float = 0.0,
                  variables="auto") -> None:
    """Raise :class:`SlmlabError` on an option of the direct model a user got wrong (one line, the remedy)."""
    if length_reference not in ("plate", "stage"):
        raise SlmlabError(f"unknown length reference {length_reference!r}; use 'plate' or 'stage'")
    if degree is not None and not all(isinstance(d, (int, np.integer)) and 1 <= d <= 5
                                      for d in np.atleast_1d(degree).tolist()):
        raise SlmlabError(f"degree must be a whole number 1 to 5, or three of them (X, Y, Z), not {degree!r}")
    if not (isinstance(stage_scale_sigma, (int, float)) and 0 <= stage_scale_sigma < 0.1):
        raise SlmlabError(f"stage_scale_sigma is a relative 1-sigma scale uncertainty (e.g. 1e-4), "
                          f"not {stage_scale_sigma!r}")
    if variables not in (3, 4, "auto"):
        raise SlmlabError(f"variables must be 3, 4 or 'auto', not {variables!r}")


@register
class DirectModel(Model):
    """Direct polynomial mapping ``(v1, v2, D) → stage`` fitted on displacements (beyond the paper)."""

    name = "direct"
    summary = ("direct polynomial mapping (v1, v2, D) -> stage frame, stage errors as random effects, degree by "
               "held-out dots and positions; calibrates from a Z stack alone")
    accuracy_rank = 5
    units = {"coef": "mm per normalised monomial", "const": "mm", "centroid_noise_px": "px", "sigma_mm": "mm",
             "frame": "px (centre, scale); unit vector (direction)", "noise_poly": "mm^2 per power of Dn",
             "cov": "mm^2 per normalised monomial^2", "feature_mean": "normalised monomial", "scale_sigma": "relative, per axis", "reference_mm": "mm"}

    def __init__(self, degree, coef, const, cov=None, sigma_mm=(0.0, 0.0, 0.0), centroid_noise_px=0.02, *,
                 frame=None, noise_poly=None, scale_sigma=(0.0, 0.0, 0.0), reference_mm=None, feature_mean=None, **kw):
        super().__init__(**kw)
        self.degree, self.coef, self.const = int(degree), np.asarray(coef, float), np.asarray(const, float)
        self.frame = dict(frame or LEGACY_FRAME)
        cov = None if cov is None else np.asarray(cov, float)
        if cov is not None and cov.ndim == 2:  # files before per-coordinate covariances: one, scaled by σ²
            cov = np.stack([cov] * 3)
        self.cov = cov
        self.sigma_mm = np.broadcast_to(np.asarray(sigma_mm, float), (3,)).copy()
        self.centroid_noise_px = float(centroid_noise_px)
        if noise_poly is None:
            noise_poly = np.column_stack([self.sigma_mm ** 2, np.zeros(3), np.zeros(3)])
        self.noise_poly = np.asarray(noise_poly, float)
        self.scale_sigma = np.broadcast_to(np.asarray(scale_sigma, float), (3,)).copy()
        self.feature_mean = np.zeros(len(self.coef)) if feature_mean is None else np.asarray(feature_mean, float)
        self.reference_mm = self.const.copy() if reference_mm is None else np.asarray(reference_mm, float)

    @classmethod
    def fit(cls, cal, *, degree: int | None = None, centroid_noise_px: float = 0.02, mode: str = "auto",
            stage_scale_sigma: float = 0.0, length_reference: str = "stage", variables="auto", **_):
        """Fit on a calibration set. ``mode``: ``"auto"``, ``"moves"``, ``"zstack"`` or ``"target"``
        (:func:`world_positions`); ``length_reference``: ``"plate"`` or ``"stage"`` (module docstring);
        ``stage_scale_sigma``: the stage's scale uncertainty (relative, 1σ, from its datasheet), added to the
        per-point uncertainty of the axes whose scale is the stage's; ``variables``: 3, 4 or ``"auto"``
        (:func:`fit_direct`)."""
        check_options(degree=degree, length_reference=length_reference, stage_scale_sigma=stage_scale_sigma,
                      variables=variables)
        f = fit_direct(cal, degree, mode=mode, length_reference=length_reference, variables=variables)
        ref = f["length_reference"]
        if f["mode"] in ("zstack", "target"):  # X, Y from the plate's lattice or the target
            scale_sigma = [0.0, 0.0, stage_scale_sigma]
        elif length_reference == "plate" and ref["dots"]:
            scale_sigma = [*ref["sigma"], stage_scale_sigma]
        else:
            scale_sigma = [stage_scale_sigma] * 3
        return cls(f["degree"], f["coef"], f["const"], f["cov"], f["sigma_mm"], centroid_noise_px,
                   frame=f["frame"], noise_poly=f["noise_poly"], scale_sigma=scale_sigma,
                   reference_mm=f["const"], feature_mean=f["feature_mean"],
                   options={"degree_chosen_by": "held-out positions" if degree is None else "user",
                            "mode": f["mode"], "length_reference": length_reference,
                            "stage_scale_sigma": float(stage_scale_sigma), "variables": _nvar(f["frame"]),
                            "variables_chosen_by": "held-out positions" if variables == "auto" else "user"},
                   calibration={"held_out_rms_mm_by_degree": {str(k): v for k, v in f["cv"].items()},
                                "degree_per_coordinate": f["degrees"],
                                "frame": ("stage axes" if f["mode"] == "moves" else
                                          "the target's frame plus the stage's moves" if f["mode"] == "target" else
                                          "plate axes (x = ((cols+1)/2 - col) pitch, y = ((rows+1)/2 - row) "
                                          "pitch) and the Z stage's direction"),
                                "held_out_rms_mm_by_variables": {str(k): v for k, v in f["variables_cv"].items()},
                                "xy_scale_from": ("the plate's lattice" if f["mode"] == "zstack" else
                                                  "the target" if f["mode"] == "target" else
                                                  f"grid plate ({ref['dots']} dots)"
                                                  if length_reference == "plate" and ref["dots"] else
                                                  "the stage's commanded moves"),
                                "stage_xy_scale_error_vs_plate": [float(v - 1) for v in ref["factor"]],
                                "stage_xy_scale_error_sigma": ref["sigma"],
                                "stage_xy_axes_cosine": ref["xy_cosine"],
                                "residual_sigma_mm": [float(v) for v in f["sigma_mm"]],
                                "stage_error_per_position_mm": [float(v) for v in f["stage_error_mm"]],
                                "down_weighted_rows": f["suspects"].to_dict(orient="records")})

    def describe(self) -> str:
        deg = self.calibration.get("degree_per_coordinate", [self.degree] * 3)
        return f"direct, {_nvar(self.frame)} variables, degrees {'/'.join(str(int(v)) for v in deg)}"

    def fixed_options(self) -> dict:
        out = {"variables": _nvar(self.frame), "mode": self.options.get("mode", "auto")}
        if "degree_per_coordinate" in self.calibration:
            out["degree"] = [int(v) for v in self.calibration["degree_per_coordinate"]]
        return out

    def reconstruct(self, w: np.ndarray) -> np.ndarray:
        w = np.atleast_2d(np.asarray(w, float))
        out = np.empty((len(w), 3))
        ct = np.ascontiguousarray(self.coef.T)  # (3, m): with monomial-major features, one fast BLAS product
        for a in range(0, len(w), 1 << 15):
            f = features(w[a:a + (1 << 15)], self.degree, self.frame).T  # (m, n), contiguous
            out[a:a + (1 << 15)] = (ct @ f).T + self.const
        return out

    def calibration_sigma(self, w: np.ndarray) -> np.ndarray:
        """1σ ``(n, 3)`` [mm] of the calibration alone at noise-free image coordinates: the coefficients'
        covariance along the point's (centred) monomials. Two independent calibrations differ at a point by
        about ``√2`` times this (notebook 09's cross-validation diffs)."""
        w = np.atleast_2d(np.asarray(w, float))
        if self.cov is None:
            return np.zeros((len(w), 3))
        c = features(w, self.degree, self.frame) - self.feature_mean  # the covariance is of centred features
        return np.sqrt(np.stack([np.einsum("ni,ij,nj->n", c, self.cov[k], c) for k in range(3)], axis=1))

    def uncertainty(self, w: np.ndarray) -> np.ndarray:
        """1σ ``(n, 3)`` [mm] per point, from three independent parts:

        * the scatter of one point, as a quadratic in the normalised depth ``Dn`` (the centroid noise grows
          with defocus), measured within positions on the calibration set (floored at a quarter of its mean);
        * the calibration's uncertainty (:meth:`calibration_sigma`);
        * each axis's scale uncertainty times the distance from the frame's reference.
        """
        w = np.atleast_2d(np.asarray(w, float))
        noise = _noise_variance(self.noise_poly, _variables(w, self.frame)[:, 2])
        var = np.maximum(noise, 0.25 * self.sigma_mm[None, :] ** 2) + self.calibration_sigma(w) ** 2
        if self.scale_sigma.any():
            var += (self.scale_sigma * (self.reconstruct(w) - self.reference_mm)) ** 2
        return np.sqrt(var)

    def parameters_dict(self) -> dict:
        return {"degree": self.degree, "coef": self.coef.tolist(), "const": self.const.tolist(),
                "frame": self.frame, "cov": None if self.cov is None else self.cov.tolist(),
                "sigma_mm": self.sigma_mm.tolist(), "noise_poly": self.noise_poly.tolist(),
                "scale_sigma": self.scale_sigma.tolist(),
                "feature_mean": self.feature_mean.tolist(), "reference_mm": self.reference_mm.tolist(),
                "centroid_noise_px": self.centroid_noise_px}

    @classmethod
    def from_parameters(cls, p, calibration, options):
        return cls(p["degree"], p["coef"], p["const"], p.get("cov"), p.get("sigma_mm", 0.0),
                   p.get("centroid_noise_px", 0.02), frame=p.get("frame"), noise_poly=p.get("noise_poly"),
                   scale_sigma=p.get("scale_sigma", 0.0), reference_mm=p.get("reference_mm"),
                   feature_mean=p.get("feature_mean"), calibration=calibration, options=options)
