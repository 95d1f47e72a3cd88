"""Dot extraction from one image: find the dots of a calibration plate, refine their centres to sub-pixel
accuracy and number them on the plate's lattice (the command line's ``extract``; the paper's §3 input).

For one image (8, 12 or 16 bit, any format OpenCV reads, dark dots on a bright plate or bright dots on black):

1. candidates by a threshold sweep over the local contrast, and the plate's lattice fitted to them
   (:mod:`slmlab.images.dots`, :mod:`slmlab.images.lattice`); with the polarity unknown both are tried and the
   one whose lattice holds more dots is kept;
2. hot pixels cleaned, then every lattice node without a dot (over the whole plate where its size is given)
   searched locally before it is given up (:func:`slmlab.images.dots.search_missing`), one ring of lines at a
   time outwards from the lattice, each predicted by its model refitted to the dots found so far; the plate's
   markers read (those the reduced image joined to a dot too, at full resolution; on a two-level plate a
   blob in a hole whose shape blur hid) and the solid ones painted out with the background beside the dots;
3. sub-pixel centres (:mod:`slmlab.images.centres`); dots cut by the image edge or off the refitted lattice
   dropped;
4. the plate's ``[row, col]`` from its markers or its size (:mod:`slmlab.images.lattice`);
5. a **report** (:attr:`ImageDots.report`): one row per candidate blob and per node searched, with what
   became of it and why.

The result is an :class:`ImageDots`; a whole set of images is extracted by :mod:`slmlab.images.imageset`.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pandas as pd
from scipy.spatial import cKDTree

from ..errors import SlmlabError
from .centres import METHODS, dot_reach, light_pull_px, outline_cut, refine, saturated_dots, uneven_background
from .dots import (Candidates, Contrast, ContrastMesh, clean_hot_pixels, grey_image, read_image, search_missing,
                   sweep)
from .overlay import overlay_painted
from .markers import (distinct_markers, filled_holes, joined_markers, marker_outline, off_lattice_markers,
                      painted_out)
from .lattice import (AREA_RANGE, LatticeFit, PlateLattice, donut_indices, fit_lattice, inside_image,
                      lattice_residual_px, number_plate, origin_frame, plate_lattice, robust_model, similar_area)

__all__ = ["AUTO_EDGE_RATIO", "AUTO_FIT_RATIO", "AUTO_FIT_SLACK", "LIGHT_PULL_PX", "OFF_LATTICE_PX", "ImageDots",
           "empty_dots_table", "extract_image", "extract_image_methods", "Choice", "choose_method", "report_summary",
           "extract_stereo_pairs"]


#: ``method="auto"`` takes an edge estimator (``ellipse`` or ``edges``) only where its centres lie this much
#: more smoothly on the lattice than the moments' (real, textured dots: their texture pulls a centroid most, a
#: point of symmetry less, an edge fit least; PIV Challenge case E: edges' lattice residual 0.28 and 0.46 of
#: the moments'); otherwise the smoother of moments and symmetry, the more precise on uniform dots (symmetry
#: where noise limits). Where the centroid says the dots are textured, the edge fit is taken even where the
#: point of symmetry lies a little more smoothly: on the stereo-PIV rig's bright dots at the lowest contrast and
#: with its own camera, the edge fits were the nearer the truth (0.020 and 0.017 px RMS against 0.022 and 0.022).
#: On dots so found textured the model ``fit`` is tried too, and taken only below this times the best other's
#: (:func:`_textured_fit`; :data:`AUTO_FIT_RATIO` says why)
AUTO_EDGE_RATIO = 0.7
#: ``method="auto"`` takes the model ``fit``, on an image with saturation or streaks around the dots
#: (:func:`slmlab.images.centres.uneven_background`), where its centres lie this much more smoothly on the
#: lattice than the best other estimator's (on the first images of the rendered zoo's seed 1 it was 0.72-0.99 of
#: the others', and as accurate as they or more in every cell it was taken in, seeds 1 and 2; elsewhere it is not
#: tried: the others meet the targets there and are 5-20 times faster; started from the dots' profile it came to
#: 0.996 of the point of symmetry's on the stereo-DIC bench image, 2048 px, and took 0.35 s for 0.065). The lattice
#: residual does not see a smooth bias, and the fit is often the truer where it is not taken: on the rendered zoo,
#: seeds 1-3, in 71 % of the views it was not tried in (a median 0.88 of the chosen's RMS, which was at most
#: 0.041 px) and in 32 of the 33 where it was tried and not taken (0.78 of it where it lay 0.7-0.95 as smoothly).
#: On dots the others find textured (an edge fit chosen) it is tried too and taken only below :data:`AUTO_EDGE_RATIO`
#: of the best other's: window streaks across bright dots on a dark plate change the dots far more than the plate,
#: and where too faint there to be read between the dots (:mod:`slmlab.images.streaks`) they look like texture
#: (stereo-piv:7's streaks, before they were read along strips: the fit 0.56-0.57 of the edge fits', 0.012 px RMS
#: against 0.038), while on PIV Challenge case E's scratched dots the fit lies 0.83-0.86 of the edge fits' and its
#: centres, as smooth, agree less with the organisers' picks (0.228 px against 0.220). On an image whose dots'
#: patches hold a clipped region (:func:`slmlab.images.centres.saturated_dots` with ``regions``: a glare beside them,
#: a streak that clips the plate; not a lone pixel at full scale, which noise makes) the burden is turned: the fit is
#: taken unless its residual is above the best other's divided by this. What a glare does to the dots near it is
#: smooth over the plate, the lattice's cubic absorbs it and the residual does not see it
#: (``test_beside_a_saturating_glare_auto_takes_the_fit_the_lattice_cannot_judge``: the Greenough rig with everything
#: together, the point of symmetry 0.081 px from the lattice against the fit's 0.084, 0.13 px from the truth against
#: 0.074)
AUTO_FIT_RATIO = 0.95
#: ``method="auto"`` lets the model ``fit`` lose this many dots and still compete (its residual then taken on
#: the dots every competitor kept): it censors saturated pixels, and a dot whose whole surround is saturated
#: leaves it too few to place the dot, which it then drops; a glare that pulls a group of dots together does not
#: take them off the lattice for the others (greenough:5's bright region: the fit 0.030 px RMS with one dot
#: lost in 196, the others 1.2-1.4 px off on the three dots beside the glare)
AUTO_FIT_SLACK = 1
#: ``method="auto"`` does not choose the whole-dot estimators (``moments``, ``symmetry``) for bright dots that the
#: light's slope across them pulls this far [px] (:func:`slmlab.images.centres.light_pull_px`): the lattice residual
#: the rule compares cannot see a pull that is smooth across the plate. The 0.05 px the extraction is held to (on
#: stereo-piv:77's 150 px dots the estimate is the moments' pull: 0.49 px against 0.47 under a gradient)
LIGHT_PULL_PX = 0.05
#: a refined centre this far [px] from the refitted lattice may be dropped (if also five times the dots'
#: median distance from it): the least that tells a centre pulled by dust from the lattice's own scatter
OFF_LATTICE_PX = 0.25


@dataclass
class ImageDots:
    """Dots found in one image.

    Attributes
    ----------
    table
        one row per dot on the lattice: ``i1, i2`` (image-lattice coordinates, :class:`PlateLattice`),
        ``w1, w2`` [px], ``marker`` (a donut), ``level`` (0, or 1 on a two-level plate's second level), and,
        once anchored, ``row, col``; with an origin-anchored frame also ``xu, yu`` (plate-frame coordinates
        in plate units from the origin dot).
    found, rejected, spurious
        dots found (on the lattice, recovered ones included), candidate blobs rejected, and of those the ones
        off the lattice.
    note
        why the dots are not numbered (empty if they are).
    frame
        ``'plate'`` (``row, col`` are the plate's own indices), ``'origin'`` (``row = −yu``,
        ``col = −xu`` up to one shift for the whole set: :mod:`slmlab.images.imageset` numbers them), or ``None``
        (not anchored: ``note`` says why).
    how
        how the indices were anchored (for the notes).
    report
        one row per candidate blob and per lattice node searched: ``candidate`` (``-1`` for a searched node),
        ``w1, w2`` [px], ``area_px``, ``levels`` (sweep levels it was seen at), ``peak_sigma`` (its contrast
        in noise σ), ``status`` (``dot``, ``recovered``: found by the local search, ``rejected``,
        ``missing``: a node of the plate searched without a dot, ``empty``: a node beyond the plate) and
        ``reason``. :func:`report_summary` counts it.
    noise_blobs, hot_pixels
        blobs seen at one sweep level only (noise, not reported one by one) and hot pixels replaced.
    """

    table: pd.DataFrame
    found: int
    rejected: int
    spurious: int
    note: str = ""
    lattice: PlateLattice | None = field(default=None, repr=False)
    frame: str | None = None
    how: str = ""
    markers: list = field(default_factory=list)
    dark: bool = True
    report: pd.DataFrame = field(default_factory=lambda: pd.DataFrame(columns=_REPORT), repr=False)
    noise_blobs: int = 0
    hot_pixels: int = 0


_EMPTY = {"i1": int, "i2": int, "w1": float, "w2": float, "marker": bool, "level": int, "row": int, "col": int}
_REPORT = ["candidate", "w1", "w2", "area_px", "levels", "peak_sigma", "status", "reason"]


def empty_dots_table() -> pd.DataFrame:
    """An :class:`ImageDots` table without rows, with its columns and types."""
    return pd.DataFrame({k: pd.Series(dtype=t) for k, t in _EMPTY.items()})


# ------------------------------------------------------------------------------------------ locating
@dataclass
class _Located:
    """What detection, the lattice and the local search found in one image, before the centres are refined.

    ``ab``, ``xy``, ``area``, ``hole``, ``src``: the lattice's dots (its candidates, then the nodes the local
    search recovered): nodes, first centres [px], areas [px²], donut flags and candidate index (``-1``:
    recovered at a node where no candidate was); ``searched``: nodes searched, found flags, where [px] and
    significance [σ]; ``clean``: the image without its hot pixels (and its solid markers); ``reason``: why each
    candidate is off the lattice; ``markers``: the plate's markers."""

    dark: bool
    con: Contrast
    cand: Candidates
    fit: LatticeFit | None
    clean: np.ndarray | None = None
    hot: int = 0
    searched: tuple = ()
    ab: np.ndarray | None = None
    xy: np.ndarray | None = None
    area: np.ndarray | None = None
    hole: np.ndarray | None = None
    src: np.ndarray | None = None
    reason: np.ndarray | None = None
    markers: list = field(default_factory=list)


def _detect(img: np.ndarray, con: Contrast, two_level: bool) -> _Located:
    """Sweep and lattice for one polarity's contrast."""
    cand = sweep(con, split=two_level)
    return _Located(con.dark, con, cand, fit_lattice(cand, img.shape, two_level=two_level))


#: a lattice whose pitch is below this many reduced pixels is looked for again in a less reduced image
#: (:func:`_detect_fine`): below about 10 a clean plate's dots merged at the sweep's lower levels and 95-98 % of
#: them were found, below 7 none (a 15 x 15 plate at a pitch of 20 px: all of it at 640 x 480, none at 2448 x 2048)
FINE_PITCH_REDUCED_PX = 10.0


def _held(loc: _Located) -> int:
    """How many candidates the lattice of ``loc`` holds (-1 without a lattice)."""
    return -1 if loc.fit is None else int(loc.fit.on.sum())


def _detect_fine(img: np.ndarray, dark: bool | None, two_level: bool) -> _Located:
    """:func:`_detect_any` at the default reduction, and again less reduced while the lattice's pitch is below
    :data:`FINE_PITCH_REDUCED_PX` reduced pixels (to a reduction that brings it there, kept where its lattice
    holds more candidates) or while no lattice is found (half the reduction, down to 2 where it was more). The
    reduction is set by the image's size
    (:func:`slmlab.images.dots.reduction`), not by its dots: a fine plate on a large sensor fell below what the
    sweep resolves (a clean 51 x 51 plate at a pitch of 21.6 px on a 1600 x 1200 sensor: 8 % of its dots found,
    and numbered wrongly)."""
    loc = _detect_any(img, dark, two_level)
    first = loc.con.scale
    while loc.con.scale > 1:
        r = loc.con.scale
        if loc.fit is None:   # not a full-resolution sweep of a large image without a plate (0.66 s at 2448 px)
            finer = r // 2
            if finer < 2 < first:
                break
        elif loc.fit.pitch < FINE_PITCH_REDUCED_PX * r:
            finer = max(1, int(loc.fit.pitch / FINE_PITCH_REDUCED_PX))
        else:
            break
        again = _detect_any(img, dark, two_level, finer)
        if loc.fit is not None and _held(again) <= _held(loc):
            break
        loc = again
    return loc


def _detect_any(img: np.ndarray, dark: bool | None, two_level: bool, scale: int | None = None) -> _Located:
    """:func:`_detect` for the given polarity, its streaks read on its dots' free side, or for both
    (``dark=None``), keeping the one whose lattice holds more candidates, their streaks read where both quartiles
    of a column agree (:class:`slmlab.images.dots.ContrastMesh`): read on one side, a column of dots passes for a
    streak of the other polarity, and the plate between the dots made a lattice that held more than the dots (240
    against 225 of a clean 17 × 17 plate cut by the image's edges). Detecting the polarity kept again on its free
    side would cost a third sweep and lattice (19 ms on an image of PIV Challenge case E, whose bright-dot contrast
    is streaky)."""
    mesh = ContrastMesh.of(img, scale)
    if dark is not None:
        return _detect(img, mesh.contrast(dark), two_level)
    runs = [_detect(img, mesh.contrast(d, sided=False), two_level) for d in (False, True)]
    return max(runs, key=lambda r: -1 if r.fit is None else int(r.fit.on.sum()))


def _dot_radius(loc: _Located) -> float:
    """The median radius of the lattice's candidates [px]."""
    return float(np.sqrt(np.median(loc.cand.area[loc.fit.on]) / np.pi))


def _locate(img: np.ndarray, rows: int | None, cols: int | None, dark: bool | None, two_level: bool,
            camera_hot: np.ndarray | None = None) -> _Located:
    """Steps 1-2 of the module docstring: candidates and lattice, a camera's text overlay painted over
    (:func:`slmlab.images.overlay.overlay_painted`), hot pixels (the camera's known ones
    ``camera_hot`` too, :func:`slmlab.images.dots.camera_hot_pixels`), the local search. ``img``: any 2-D array
    of grey levels (:func:`slmlab.images.dots.grey_image`)."""
    img = grey_image(img)
    loc = _detect_fine(img, dark, two_level)
    if loc.fit is None:
        return loc
    radius = _dot_radius(loc)
    loc.clean, loc.hot = clean_hot_pixels(overlay_painted(img, loc.con), radius, loc.cand.xy[loc.fit.on], camera_hot)
    changed = loc.hot or any(loc.con.overlay)   # the search reads the image cleaned and painted: taken if needed
    con = (lambda: loc.con.again(loc.clean)) if changed else (lambda: loc.con)
    grow, repeat = _search_box(loc.fit, rows, cols), rows is None or cols is None
    loc.searched = _recover(con, loc.cand, loc.fit, grow, img.shape, 0.5 * radius, repeat)
    loc.ab, loc.xy, loc.area, loc.hole, loc.src = _lattice_dots(loc.cand, loc.fit, loc.searched)
    _read_markers(loc)
    return loc


def _read_markers(loc: _Located) -> None:
    """Why each candidate off the lattice is off it, and the plate's markers (:func:`_candidate_reasons`, with
    on a two-level plate those joined to a dot too: :func:`slmlab.images.markers.joined_markers`, whose dots
    take the dots' median area, and where a triangle and a square were not both read so, those joined to a dot
    at the lower levels of the sweep only; where fewer than two were read, :func:`slmlab.images.markers.filled_holes`),
    into ``loc.reason`` and ``loc.markers``. On a two-level plate the solid ones read from their outlines
    (triangles, squares, blobs in holes) are painted out of ``loc.clean``
    (:func:`slmlab.images.markers.painted_out`) so that a marker beside a dot does not pull its centre."""
    con, cand, fit = loc.con, loc.cand, loc.fit
    two_level = fit.model.second is not None
    split = joined_markers(loc.clean, con, cand, fit) if two_level else []
    loc.reason, loc.markers = _candidate_reasons(loc.clean, con, cand, fit, [m for _, m, _ in split])
    if two_level and not {"triangle", "square"} <= {m.kind for m in loc.markers}:
        split += joined_markers(loc.clean, con, cand, fit, lower=True)   # a marker joined lower down only
        loc.reason, loc.markers = _candidate_reasons(loc.clean, con, cand, fit, [m for _, m, _ in split])
    loc.area = np.where(np.isin(loc.src, [k for k, _, _ in split]), float(np.median(cand.area[fit.on])), loc.area)
    if not two_level:
        return
    if len(loc.markers) < 2:
        loc.markers += filled_holes(con, cand, fit, (loc.ab, loc.xy), loc.clean.shape, loc.markers)
    marked = np.char.startswith(loc.reason.astype(str), "marker: ")
    read = [(outline, tuple(cand.xy[k])) for k in np.flatnonzero(marked & (loc.reason != "marker: frame"))
            if (outline := marker_outline(loc.clean, con, cand, k, cand.level[k])) is not None]
    outlines = [c for c, _ in read] + [c for _, _, c in split]
    if not outlines:
        return
    centre = np.array([xy for _, xy in read] + [m.centre for _, m, _ in split])
    r = np.clip(np.rint(con.to_reduced(centre)).astype(int), 0, np.array(con.z.shape[::-1]) - 1)
    background = list(con.background[r[:, 1], r[:, 0]].astype(loc.clean.dtype))
    loc.clean = painted_out(loc.clean, outlines, background, int(np.ceil(2 * con.scale)), fit.model.predict(loc.ab),
                            _dot_radius(loc))


def _search_box(fit: LatticeFit, rows: int | None, cols: int | None) -> int:
    """How many lines beyond the lattice's box to search: enough for the whole plate if its size is given,
    else one (repeated while lines are found)."""
    if rows is None or cols is None:
        return 1
    a0, a1, b0, b1 = fit.box
    return max(0, int(max(rows, cols) - min(a1 - a0, b1 - b0) - 1))


def _recover(contrast, cand: Candidates, fit: LatticeFit, grow: int, shape, margin: float, repeat: bool):
    """Nodes of the box grown by ``grow`` lines without a candidate, searched (:func:`search_missing`) on the
    :class:`Contrast` that ``contrast()`` returns (computed only if a node is searched: the image less its hot
    pixels takes a new one), one ring of lines at a time from the box outwards, each predicted by the lattice's
    model refitted to the dots found so far (a model extrapolated over several lines can miss a dot by more
    than the search's reach); a find beyond the box stands only on a line that holds enough of them
    (:func:`_line_supported`, on all the nodes searched so far). With ``repeat``, the box keeps growing by one
    line while lines yield dots. Returns searched nodes, found mask, positions [px] and significance."""
    dots, radius = cand.xy[fit.on], float(np.sqrt(np.median(cand.area[fit.on]) / np.pi))
    done = set(map(tuple, fit.node[fit.on].tolist()))
    out, con, now, ring, found = [], None, fit, 0, np.zeros(0, bool)
    while True:
        nodes = fit.nodes(ring)
        p = now.model.predict(nodes)
        todo = np.array([n not in done for n in map(tuple, nodes.tolist())], bool) & inside_image(p, shape, margin)
        before = int(found.sum())
        if todo.any():
            con = contrast() if con is None else con
            out.append((nodes[todo], *search_missing(con, p[todo], now.tolerance(nodes[todo]), dots, radius,
                                                     now.spacing(nodes[todo]))))
            done |= set(map(tuple, nodes[todo].tolist()))
            searched, hit, where = (np.concatenate([o[i] for o in out]) for i in range(3))
            found = hit & _line_supported(*_plate_axes(fit, searched), hit)
            if found.sum() > before:
                now = replace(fit, model=_refitted(fit, dots, searched[found], where[found]))
        grew = found.sum() > before and ring <= 2 * max(fit.box[1] - fit.box[0], fit.box[3] - fit.box[2])
        if ring >= grow and not (repeat and grew):
            break
        ring += 1
    if not out:
        return np.empty((0, 2), int), np.empty(0, bool), np.empty((0, 2)), np.empty(0)
    nodes, _, where, sig = (np.concatenate(x) for x in zip(*out))
    return nodes, found, where, sig


def _refitted(fit: LatticeFit, dots: np.ndarray, nodes: np.ndarray, where: np.ndarray):
    """The lattice's model refitted to its dots ``dots`` [px] and the local search's finds ``nodes`` at
    ``where`` [px]."""
    ab = np.vstack([fit.node[fit.on], nodes]).astype(float)
    return robust_model(ab, np.vstack([dots, where]), fit.pitch, two_level=fit.model.second is not None)[0]


def _plate_axes(fit: LatticeFit, nodes: np.ndarray):
    """Searched ``nodes`` and the box of the lattice's dots along the plate's own rows and columns: the
    lattice's on a one-level plate; on a two-level plate its diagonals ``a ± b`` (the lattice's lines there
    cut the plate's corners, where they hold one or two of its dots)."""
    if fit.model.second is None:
        return nodes, fit.box
    e = np.column_stack([nodes.sum(axis=1), nodes[:, 0] - nodes[:, 1]])
    on = fit.node[fit.on]
    e_on = np.column_stack([on.sum(axis=1), on[:, 0] - on[:, 1]])
    return e, (e_on[:, 0].min(), e_on[:, 0].max(), e_on[:, 1].min(), e_on[:, 1].max())


def _line_supported(nodes: np.ndarray, box, ok: np.ndarray) -> np.ndarray:
    """Whether each searched node's finding stands: inside the lattice's box always; beyond it only if its
    line (the plate's row or column, :func:`_plate_axes`; beyond the box, nodes in the image) holds dots at
    ≥ 30 % of its searched nodes and at two
    at least (one if the image shows one node of it), as the lattice itself grows: a lone find on a line
    the image shows is a glyph or a hot spot, not the plate."""
    a0, a1, b0, b1 = box
    a, b = nodes[:, 0], nodes[:, 1]
    line = np.where(a < a0, a - a0, np.where(a > a1, a - a1, 0)) * 4 + np.where(a < a0, 0, np.where(a > a1, 1, 2))
    line = np.where((a >= a0) & (a <= a1), 10_000 + np.where(b < b0, b - b0, b - b1) * 4 + (b > b1), line)
    beyond = (a < a0) | (a > a1) | (b < b0) | (b > b1)
    keys, inv = np.unique(line, return_inverse=True)
    hits, total = np.bincount(inv, weights=ok, minlength=len(keys)), np.bincount(inv, minlength=len(keys))
    good_line = (hits >= np.minimum(2, total)) & (hits >= 0.3 * total)
    return ~beyond | good_line[inv]


def _lattice_dots(cand: Candidates, fit: LatticeFit, searched) -> tuple[np.ndarray, ...]:
    """The lattice's dots: its candidates, then the nodes the local search recovered. A recovered dot that
    a candidate left off the lattice sits on (its line was too sparse to grow into) takes that candidate's
    centroid, area and donut flag; the others take the dots' median area. Returns nodes ``(n, 2)``, first
    centres ``(n, 2)`` [px], areas [px²], donut flags and candidate indices (``-1``: none)."""
    nodes, ok, where, _ = searched
    where = where[ok]
    src = np.full(len(where), -1)
    off = np.flatnonzero(~fit.on)
    if len(off) and len(where):
        d, j = cKDTree(cand.xy[off]).query(where)
        near = d < 0.5 * np.sqrt(cand.area[off[j]] / np.pi)
        src[near] = off[j[near]]
    adopted = src >= 0
    xy = np.where(adopted[:, None], cand.xy[np.maximum(src, 0)], where)
    area = np.where(adopted, cand.area[np.maximum(src, 0)], np.median(cand.area[fit.on]))
    hole = adopted & cand.hole[np.maximum(src, 0)]
    return (np.vstack([fit.node[fit.on], nodes[ok]]), np.vstack([cand.xy[fit.on], xy]),
            np.r_[cand.area[fit.on], area], np.r_[cand.hole[fit.on], hole], np.r_[np.flatnonzero(fit.on), src])


def _refined(loc: _Located, method: str, two_level: bool):
    """The lattice's dots refined to sub-pixel centres (:func:`slmlab.images.centres.refine`, on the image
    cleaned of hot pixels); those cut by the image edge or off the lattice refitted on the refined centres of the
    whole dots (by more than half the capture radius, or than five times the dots' median distance from it and
    :data:`OFF_LATTICE_PX`) are dropped. Returns the dots' nodes ``(m, 2)``, centres ``(m, 2)`` [px], donut
    flags, candidate index of each (``-1``: recovered) and the dropped ones with why (candidates by index,
    recovered nodes by ``-1 - k``, their place among the recovered), and the lattice model refitted on the
    refined centres."""
    radii = np.sqrt(loc.area / np.pi)
    xy = refine(loc.clean, loc.xy, radii, dark=loc.dark, method=method)
    whole = ~outline_cut(loc.clean, xy, radii, loc.dark, loc.con.overlay)
    use = whole if whole.sum() >= 12 else np.ones(len(xy), bool)    # a dot cut by the edge does not shape it
    model, _ = robust_model(loc.ab[use].astype(float), xy[use], loc.fit.pitch, two_level=two_level)
    off = np.hypot(*(xy - model.predict(loc.ab)).T)
    # off the lattice: beyond half the capture radius, or five times the dots' median distance from it (at
    # least 0.25 px): a centre pulled by dust or a neighbour, not distortion, which the model absorbs
    limit = np.minimum(0.5 * loc.fit.tolerance(loc.ab), max(5 * float(np.nanmedian(off)), OFF_LATTICE_PX))
    good = (off < limit) & whole & np.isfinite(xy).all(axis=1)
    why = np.where(whole, np.char.mod("off the lattice after refinement (%.1f px)", off),
                   "touching border (the dot's outline is cut by the image edge)")
    dropped = {int(k): str(w) for k, w, g in zip(loc.src, why, good) if not g and k >= 0}
    n_on = int(loc.fit.on.sum())
    dropped.update({-1 - j: str(why[n_on + j]) for j in np.flatnonzero(~good[n_on:])})
    return loc.ab[good], xy[good], loc.hole[good], loc.src[good], dropped, model


# ------------------------------------------------------------------------------------------ the report
def _candidate_reasons(img: np.ndarray, con: Contrast, cand: Candidates, fit: LatticeFit,
                       split: list = ()) -> tuple[np.ndarray, list]:
    """Why each candidate the lattice left off was left off (an array of reasons; on-lattice ones empty),
    and the markers among them (:func:`slmlab.images.markers.off_lattice_markers`), with those ``split`` off a
    dot (each once: :func:`slmlab.images.markers.distinct_markers`)."""
    nodes = fit.nodes(grow=2)
    d, j = cKDTree(fit.model.predict(nodes)).query(cand.xy)
    near = d < fit.tolerance(nodes[j])
    ratio = cand.area / float(np.median(cand.area[fit.on]))
    taken = np.zeros(len(nodes), bool)
    a0, a1, b0, b1 = fit.box
    taken[((fit.node[fit.on, 0] - a0 + 2) * (b1 - b0 + 5) + fit.node[fit.on, 1] - b0 + 2)] = True
    inbox = (nodes[j, 0] >= a0) & (nodes[j, 0] <= a1) & (nodes[j, 1] >= b0) & (nodes[j, 1] <= b1)
    code = np.select([fit.on, cand.border, near & taken[j], near & ~similar_area(ratio, 1.0), near & ~inbox],
                     [0, 1, 2, 3, 4], 5)
    fixed = {1: "touching border", 2: "duplicate: another blob is nearer its node",
             4: "beyond the lattice (a line too sparse to be the plate's)"}
    reason = np.full(len(cand), "", dtype=object)
    for k in np.flatnonzero(code > 0):
        c = int(code[k])
        reason[k] = fixed.get(c) or (f"off the lattice ({d[k]:.1f} px from the nearest node)" if c == 5 else
                                     f"too {'small' if ratio[k] < AREA_RANGE[0] else 'large'} ({ratio[k]:.2g} of the "
                                     "dots' median area)")
    markers = off_lattice_markers(img, con, cand, fit, reason, ratio) + list(split)
    return reason, distinct_markers(markers, fit.pitch / 4)


def _report(cand: Candidates, reason: np.ndarray, searched, dropped: dict, expected: np.ndarray) -> pd.DataFrame:
    """The per-image report (:attr:`ImageDots.report`): the candidates, then the nodes searched
    (``expected``: the searched nodes inside the plate, where a dot was expected: ``missing`` if none was
    found, else ``empty``)."""
    status = np.where(reason == "", "dot", "rejected").astype(object)
    reason = reason.copy()
    for k, why in dropped.items():
        if k >= 0:
            status[k], reason[k] = "rejected", why
    reason[(status == "dot") & cand.hole] = "on the lattice, donut marker"
    reason[reason == ""] = "on the lattice"
    rep = pd.DataFrame({"candidate": np.arange(len(cand)), "w1": cand.xy[:, 0], "w2": cand.xy[:, 1],
                        "area_px": cand.area, "levels": cand.levels, "peak_sigma": cand.peak, "status": status,
                        "reason": reason})
    nodes, ok, where, sig = searched
    st = np.where(ok, "recovered", np.where(expected, "missing", "empty")).astype(object)
    why = [f"local search at node ({a}, {b}): " + (f"peak {s:.1f} σ" if o else f"no dot (best {s:.1f} σ)")
           for (a, b), o, s in zip(nodes, ok, sig)]
    for j, row in enumerate(np.flatnonzero(ok)):
        if -1 - j in dropped:
            st[row], why[row] = "rejected", why[row] + "; " + dropped[-1 - j]
    srch = pd.DataFrame({"candidate": -1, "w1": where[:, 0], "w2": where[:, 1], "area_px": np.nan, "levels": 0,
                         "peak_sigma": sig, "status": st, "reason": why})
    return pd.concat([rep, srch], ignore_index=True) if len(srch) else rep


def report_summary(report: pd.DataFrame) -> str:
    """One line of counts from :attr:`ImageDots.report`: dots on the lattice and recovered by the local
    search, nodes searched without a dot, and the rejected blobs by reason (numbers in reasons pooled)."""
    st = report["status"].value_counts()
    rej = report.loc[report["status"] == "rejected", "reason"].str.replace(r"\s*\(.*\)$|^local search.*; ", "",
                                                                         regex=True).value_counts()
    parts = [f"{int(st.get('dot', 0))} dots on the lattice", f"{int(st.get('recovered', 0))} recovered by the local search",
             f"{int(st.get('missing', 0))} plate nodes searched without a dot"]
    if len(rej):
        parts.append("rejected: " + ", ".join(f"{v} {k}" for k, v in rej.items()))
    return "; ".join(parts)


# ------------------------------------------------------------------------------------------ anchoring
def _anchor(table: pd.DataFrame, pl: PlateLattice, markers: list, rows, cols, *, anchor: str, marker_origin,
            two_level: bool, seen):
    """The plate's ``[row, col]`` of one image's lattice: from an L of donut markers, from a square and a
    triangle or a frame (an origin frame), or from the plate's size (:mod:`slmlab.images.lattice`). Returns
    the table (with ``row, col``, sorted, where anchored), the frame (``'plate'``, ``'origin'`` or ``None``),
    how it was anchored, why not, and the plate's window in ``i1, i2`` where its size numbered it. ``seen``:
    where the image shows a lattice site empty (:func:`_site_evidence`)."""
    frame, how, note, window = None, "", "", None
    holes = table["marker"].to_numpy(bool)
    donuts = int(holes.sum())
    sized = rows is not None and cols is not None
    # polygon markers give an origin, for a plate whose size is unknown; a donut L numbers any plate
    use_markers = anchor == "markers" or (anchor == "auto" and (donuts >= 3 or (markers and not sized)))
    if use_markers and donuts >= 3:
        ij, note = donut_indices(pl, holes, marker_origin)
        if ij is not None:
            table["row"], table["col"], frame, how = ij[0], ij[1], "plate", "an L of donut markers"
    elif use_markers:
        xy, msg = origin_frame(pl, markers)
        if xy is None:
            note = msg
        else:
            frame, how = "origin", msg
            if two_level:  # the origin's level is level 0
                table["level"] = (xy[0] % 2).astype(int)
            table["xu"], table["yu"] = xy[0].astype(int), xy[1].astype(int)
            table["row"], table["col"] = -table["yu"], -table["xu"]
    if frame is None and (sized or not note) and anchor != "markers":
        if not sized:
            note = ("no markers found and the plate's rows and cols are not given (a plate larger than the "
                    "field needs markers, or neighbouring images to track it from)")
        else:
            rc, inside, note, window = number_plate(pl, rows, cols, seen)
            if rc is not None:
                table["row"], table["col"], frame = rc[0], rc[1], "plate"
                how = "the plate's size" + (f" ({note})" if note else "")
                table = table[inside]
    if frame is None:
        table["row"] = pd.Series(dtype=int)
        table["col"] = pd.Series(dtype=int)
    else:
        table = table.iloc[np.lexsort((table["col"].to_numpy(), table["row"].to_numpy()))].reset_index(drop=True)
    return table, frame, how, note if frame is None else "", window


# ------------------------------------------------------------------------------------------ one image
def extract_image(img: np.ndarray, rows: int | None = None, cols: int | None = None, *, method: str = "moments",
                  dark: bool | None = True, dot_diameter_px: float | None = None, anchor: str = "auto",
                  marker_origin: tuple[int, int] = (2, 2), two_level: bool = False,
                  camera_hot: np.ndarray | None = None) -> ImageDots:
    """Find, refine and number the dots of a plate in one image (any bit depth; module docstring).

    Parameters
    ----------
    img
        grey-level image: any 2-D array of real numbers (``uint8`` and ``uint16`` as they are, others as ``float32``:
        :func:`slmlab.images.dots.grey_image`).
    rows, cols
        the plate's size, or ``None`` for a plate larger than the field (then markers anchor the indices).
    method
        the centre estimator, one of :data:`slmlab.images.centres.METHODS` (``'moments'``, the default,
        ``'ellipse'``, ``'edges'``, ``'fit'`` or ``'symmetry'``).
    dark
        dark dots on a bright plate (``True``), bright dots on a dark plate (``False``), or ``None``: decided
        from the image (both are tried; the one whose lattice holds more dots is kept).
    dot_diameter_px
        expected dot diameter [px] if known (the border margin of the plate-size numbering; else measured).
    anchor
        ``'auto'``: markers where the plate has them (a donut L, a square and a triangle, a frame around a
        dot), else the plate's size; ``'plate'``: from the plate's size and where the lattice leaves the image;
        ``'markers'``: from markers only.
    marker_origin
        ``(row, col)`` of the corner donut of an L of donuts.
    two_level
        a two-level plate (rows alternating between two depths, offset by half a pitch): indices in half
        pitches and a ``level`` per dot.
    camera_hot
        the camera's hot pixels (a boolean mask of the image's shape, :func:`slmlab.images.dots.camera_hot_pixels`
        of its images), cleaned wherever they are; without it only those outside the dots are.
    """
    return extract_image_methods(img, rows, cols, methods=(method,), dark=dark, dot_diameter_px=dot_diameter_px,
                                 anchor=anchor, marker_origin=marker_origin, two_level=two_level,
                                 camera_hot=camera_hot)[method]


def extract_image_methods(img: np.ndarray, rows: int | None = None, cols: int | None = None, *, methods=METHODS,
                          dark: bool | None = True, dot_diameter_px: float | None = None, anchor: str = "auto",
                          marker_origin: tuple[int, int] = (2, 2), two_level: bool = False,
                          camera_hot: np.ndarray | None = None) -> dict:
    """:func:`extract_image` (same parameters) by each centre estimator of ``methods``, as a dict from method to
    :class:`ImageDots`, the dots found once: detection, lattice, hot pixels and the local search do not
    depend on the estimator (its centres, what refinement drops and the numbering that follows do)."""
    _check_options(methods, anchor)
    loc = _locate(img, rows, cols, dark, two_level, camera_hot)
    if loc.fit is None:
        return {m: _no_lattice(loc) for m in methods}
    anchoring = dict(anchor=anchor, marker_origin=marker_origin, two_level=two_level)
    return {m: _finish(loc, m, rows, cols, anchoring, dot_diameter_px) for m in methods}


def _check_options(methods, anchor: str) -> None:
    """:class:`SlmlabError` for an unknown centre method or anchor."""
    bad = [m for m in methods if m not in METHODS]
    if bad:
        raise SlmlabError(f"unknown centre method {bad[0]!r}; use one of {', '.join(METHODS)}")
    if anchor not in ("auto", "plate", "markers"):
        raise SlmlabError(f"unknown anchor {anchor!r}; use 'auto', 'plate' or 'markers'")


def _no_lattice(loc: _Located) -> ImageDots:
    """The result of an image without a lattice: no dots, every candidate reported, and why."""
    none = (np.empty((0, 2), int), np.empty(0, bool), np.empty((0, 2)), np.empty(0))
    rep = _report(loc.cand, np.full(len(loc.cand), "no lattice found", object), none, {}, np.empty(0, bool))
    note = (f"no lattice: {len(loc.cand)} blob(s) found, none with six of its eight lattice neighbours (a plate "
            "of at least 3 × 3 dots is needed)")
    return ImageDots(empty_dots_table(), 0, len(loc.cand), 0, note, dark=loc.dark, report=rep,
                     noise_blobs=loc.cand.noise)


def _table(loc: _Located, method: str, two_level: bool):
    """The refined dots as a table (``i1, i2, w1, w2, marker, level`` and the candidate index ``_src``), their
    :class:`PlateLattice` and the dropped candidates with why."""
    ab, xy, hole, src, dropped, model = _refined(loc, method, two_level)
    pl = plate_lattice(model, ab, two_level=two_level)
    level = ((pl.i1 % 2) if two_level else np.zeros(len(ab), int)).astype(int)
    table = pd.DataFrame({"i1": pl.i1, "i2": pl.i2, "w1": xy[:, 0], "w2": xy[:, 1], "marker": hole, "level": level,
                          "_src": src})
    return table, pl, dropped


def _site_evidence(loc: _Located, table: pd.DataFrame, margin_px: float):
    """``empty(points (n, 2) [px]) -> (n,)``: where this image shows that a lattice site holds no dot of the
    plate (empty background, not a dot hidden): at least ``margin_px`` inside it, not saturated, on a
    background like the found dots' (within their range and three robust spreads; a saturated glare is not),
    clear of a camera's text strip (:func:`slmlab.images.overlay.overlay_rows`), and no noisier than 1.5 times
    theirs (window streaks or texture there may hide a dot from the sweep and the local search), and no candidate blob of any kind within a third of a
    pitch (a dot the lattice left off, too faint or pulled by a glare, is hidden, not absent). An empty
    plate line is evidence of the plate's edge only at such sites."""
    con, shape = loc.con, loc.clean.shape
    top = float(np.max(loc.clean))
    blobs = cKDTree(loc.cand.xy) if len(loc.cand) else None

    def reduced(p):
        r = np.rint(con.to_reduced(p)).astype(int)
        return np.clip(r[:, 1], 0, con.z.shape[0] - 1), np.clip(r[:, 0], 0, con.z.shape[1] - 1)
    ry, rx = reduced(np.column_stack([table["w1"].to_numpy(), table["w2"].to_numpy()]))
    bg, spread = con.background[ry, rx], float(np.median(con.spread[ry, rx]))
    pad = 3 * 1.4826 * float(np.median(np.abs(bg - np.median(bg)))) + 3 * spread
    lo, hi = float(bg.min()) - pad, float(bg.max()) + pad

    def empty(p: np.ndarray) -> np.ndarray:
        ok = inside_image(p, shape, margin_px, con.overlay)
        y, x = reduced(p)
        level = -con.signed[y, x] if con.dark else con.signed[y, x]
        if blobs is not None and len(p):
            ok = ok & (blobs.query(p)[0] > loc.fit.pitch / 3)
        return (ok & (con.background[y, x] >= lo) & (con.background[y, x] <= hi) & (level < 0.98 * top)
                & (con.spread[y, x] <= 1.5 * spread))
    return empty


def _finish(loc: _Located, method: str, rows, cols, anchoring: dict, dot_diameter_px,
            tabled=None) -> ImageDots:
    """Steps 3-5 of the module docstring on located dots: centres, numbering, report (``tabled``: this
    method's :func:`_table`, if already made)."""
    table, pl, dropped = tabled if tabled is not None else _table(loc, method, anchoring["two_level"])
    reason, markers = loc.reason.copy(), list(loc.markers)
    radius = dot_diameter_px / 2 if dot_diameter_px else _dot_radius(loc)
    src_all = table["_src"].to_numpy()
    table, frame, how, note, window = _anchor(table, pl, markers, rows, cols, seen=_site_evidence(loc, table, radius + 1),
                                              **anchoring)
    outside = np.setdiff1d(src_all, table["_src"].to_numpy())
    dropped.update({int(k): "outside the plate (beyond its rows × cols)" for k in outside if k >= 0})
    nodes = loc.searched[0]
    if window is None:       # no plate window: the nodes beyond the lattice's box held no dot to expect
        a0, a1, b0, b1 = loc.fit.box
        expected = (nodes[:, 0] >= a0) & (nodes[:, 0] <= a1) & (nodes[:, 1] >= b0) & (nodes[:, 1] <= b1)
    else:
        i = nodes @ pl.m.T
        expected = (i[:, 0] >= window[0]) & (i[:, 0] <= window[1]) & (i[:, 1] >= window[2]) & (i[:, 1] <= window[3])
    rep = _report(loc.cand, reason, loc.searched, dropped, expected)
    spurious = sum(why.startswith("off the lattice (") for why in rep["reason"].to_numpy())
    rejected = int(np.count_nonzero(rep["status"].to_numpy() == "rejected"))
    return ImageDots(table.drop(columns="_src"), len(src_all), rejected, spurious, note, pl, frame, how, markers,
                     loc.dark, rep, loc.cand.noise, loc.hot)


class Choice(NamedTuple):
    """:func:`choose_method`'s answer: the ``method``, the lattice ``residuals`` [px] of each estimator tried, the
    image's ``dots`` by the method (:func:`extract_image`'s result, from the same search) and the ``runner_up``:
    the rule's choice without the model fit (what an image on which the fit loses dots takes instead)."""

    method: str
    residuals: dict
    dots: ImageDots
    runner_up: str


def choose_method(img: np.ndarray, rows=None, cols=None, **kw) -> Choice:
    """The centre estimator for a plate's images (``method="auto"``): the dots of one image found once and
    refined by every estimator; among those that keep the most dots (an estimator pulled off the lattice by a
    glare or a streak loses dots; the fit may lose :data:`AUTO_FIT_SLACK`), compared by
    :func:`slmlab.images.lattice.lattice_residual_px` on the dots all of them kept: the model ``fit``, tried on
    an image with saturation or streaks around the dots (:func:`slmlab.images.centres.uneven_background`), if it
    is below :data:`AUTO_FIT_RATIO` times the best other's residual (where the dots' patches hold a clipped region,
    unless it is above the best other's divided by it); bright dots the light's slope pulls by more than
    :data:`LIGHT_PULL_PX` are left to the fit and the edge estimators (all are still reported); else an edge estimator (the smoother of
    ``ellipse`` and ``edges``) only if it is below :data:`AUTO_EDGE_RATIO` times the moments' residual or the
    moments lost dots (textured dots; then the model fit is tried too, :func:`_textured_fit`), else the smoother
    of ``moments`` and ``symmetry``. ``kw``: :func:`extract_image`'s keywords. Returns a :class:`Choice`."""
    anchoring = {k: kw[k] for k in ("anchor", "marker_origin", "two_level") if k in kw}
    anchoring = {"anchor": "auto", "marker_origin": (2, 2), "two_level": False, **anchoring}
    _check_options(METHODS, anchoring["anchor"])
    loc = _locate(img, rows, cols, kw.get("dark", True), anchoring["two_level"], kw.get("camera_hot"))
    if loc.fit is None:
        return Choice("moments", {m: float("nan") for m in METHODS}, _no_lattice(loc), "moments")
    radii = np.sqrt(loc.area / np.pi)
    reach = dot_reach(loc.clean, loc.xy, radii, loc.dark)
    uneven = uneven_background(loc.clean, loc.xy, radii, loc.dark, reach)
    clipped = bool(saturated_dots(loc.clean, loc.xy, reach, regions=True).any())   # a glare, a clipped streak
    tabled = {m: _table(loc, m, anchoring["two_level"]) for m in METHODS if uneven or m != "fit"}
    kept, res = _kept_and_residuals({m: t[0] for m, t in tabled.items()})
    if light_pull_px(loc.clean, loc.xy, radii, loc.dark, reach) > LIGHT_PULL_PX:   # the light pulls whole dots
        kept = {m: k for m, k in kept.items() if m not in ("moments", "symmetry")}
    method = _best_method(kept, res, 1 / AUTO_FIT_RATIO if clipped else AUTO_FIT_RATIO)
    runner_up = _best_method({m: k for m, k in kept.items() if m != "fit"}, res)
    if _textured(method, res) and "fit" not in tabled:  # textured: something pulls the dots off symmetry
        tabled["fit"] = _table(loc, "fit", anchoring["two_level"])
        taken, res = _textured_fit({m: t[0] for m, t in tabled.items()}, res)
        method = "fit" if taken else method
    dots = _finish(loc, method, rows, cols, anchoring, kw.get("dot_diameter_px"), tabled[method])
    return Choice(method, res, dots, runner_up)


def _textured(method: str, res: dict) -> bool:
    """Whether the dots look textured to :func:`choose_method`'s rule, having taken ``method`` on the estimators'
    lattice residuals ``res`` [px]: an edge estimator taken, or a whole-dot one taken although an edge estimator,
    which lost a dot, is below :data:`AUTO_EDGE_RATIO` times its residual (window streaks across a PIV rig's bright
    dots too faint on its dark plate to be read there: on stereo-piv:38's two-level plate under everything together, the moments,
    0.142 px, kept one dot more than the edge fits, 0.075; the model fit, 0.040, was not tried)."""
    edge = min(res.get("ellipse", np.inf), res.get("edges", np.inf))
    whole = method in ("moments", "symmetry") and edge < AUTO_EDGE_RATIO * res[method]
    return method in ("ellipse", "edges") or whole


def _textured_fit(tables: dict, res: dict) -> tuple[bool, dict]:
    """Whether the model fit is taken on dots :func:`_best_method` found textured (an edge estimator chosen on
    ``res``, the others' residuals [px]), from every estimator's table of dots (the fit's among them): only where
    the rule, with the fit, takes it and its residual is below :data:`AUTO_EDGE_RATIO` times the best finite one
    of the others that keep the most dots (a more flexible model replaces a simpler one only where clearly
    smoother, as an edge fit replaces the centroid). Returns that and the residuals to report: the comparison's
    if taken, else ``res`` and the fit's."""
    kept, with_fit = _kept_and_residuals(tables)
    most = max(kept.values())
    others = [with_fit[m] for m in kept if m != "fit" and kept[m] == most and np.isfinite(with_fit[m])]
    taken = (_best_method(kept, with_fit) == "fit" and bool(others)
             and with_fit["fit"] < AUTO_EDGE_RATIO * min(others))
    return taken, with_fit if taken else {**res, "fit": with_fit["fit"]}


def _kept_and_residuals(tables: dict) -> tuple[dict, dict]:
    """Each estimator's kept dots, as :func:`_best_method` counts them, and lattice residual [px]
    (:func:`slmlab.images.lattice.lattice_residual_px`), from its table of dots. The model ``fit`` may lose
    :data:`AUTO_FIT_SLACK` dots and still count as keeping the most; the residuals of those that keep the most
    are then taken on the dots all of them kept, so that a lost dot does not make an estimator look smoother."""
    kept = {m: len(t) for m, t in tables.items()}
    most = max(kept.values())
    if "fit" in kept and most - AUTO_FIT_SLACK <= kept["fit"] < most:
        kept["fit"] = most
    keys = {m: set(zip(t["i1"], t["i2"])) for m, t in tables.items()}
    common = set.intersection(*(keys[m] for m in kept if kept[m] == most))
    res = {}
    for m, t in tables.items():
        on = [k in common for k in zip(t["i1"], t["i2"])] if kept[m] == most else slice(None)
        res[m] = lattice_residual_px(t[on])
    return kept, res


def _best_method(kept_dots: dict, res: dict, fit_ratio: float = AUTO_FIT_RATIO) -> str:
    """:func:`choose_method`'s rule on each estimator's kept dots and lattice residual [px]; the model fit is
    taken below ``fit_ratio`` times the best other's residual (:data:`AUTO_FIT_RATIO`, or its inverse where the
    dots' patches hold a clipped region)."""
    most = max(kept_dots.values())
    kept = [m for m in kept_dots if kept_dots[m] == most]      # an estimator whose centres leave the lattice
    score = {m: res[m] if np.isfinite(res[m]) else np.inf for m in kept}
    others = [score[m] for m in kept if m != "fit"]
    if "fit" in kept and np.isfinite(score["fit"]) and (not others or score["fit"] < fit_ratio * min(others)):
        return "fit"
    kept = [m for m in kept if m != "fit"]
    if not kept:
        return "fit"
    whole = min((m for m in ("moments", "symmetry") if m in kept), key=score.get, default=None)
    edge = min((m for m in ("ellipse", "edges") if m in kept), key=score.get, default=None)
    if whole is None or edge is None:
        return whole or edge
    # textured dots (or streaks across them) pull a centroid off the lattice, or make it rougher than the outline
    textured = "moments" not in kept or score[edge] < AUTO_EDGE_RATIO * score["moments"]
    return edge if textured else whole


def extract_stereo_pairs(pairs: list[tuple[Path, Path]], rows: int, cols: int, *, anchor: str = "markers") -> pd.DataFrame:
    """Extract real stereo pairs (left, right image paths): dots found and indexed per image, and common.

    Returns a DataFrame ``pair, left, right, common, note``; the per-pair tables are in the ``.attrs``.
    """
    out, tables = [], {}
    for left, right in pairs:
        views = [extract_image(read_image(p), rows, cols, anchor=anchor) for p in (left, right)]
        m = views[0].table.merge(views[1].table, on=["row", "col"], suffixes=("_l", "_r"))
        tables[Path(left).stem] = m
        out.append((Path(left).stem, len(views[0].table), len(views[1].table), len(m),
                    "; ".join(v.note for v in views if v.note)))
    df = pd.DataFrame(out, columns=["pair", "left", "right", "common", "note"])
    df.attrs["tables"] = tables
    return df
