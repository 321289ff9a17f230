"""Volumes of axisymmetric bodies from their silhouettes, by disc integration.

For every image row crossing a body, every dark run has sub-pixel edge positions
(`dropvision.frame.edges.body_edges`).  The run's chord ``c`` gives a slice of area ``pi (c/2)^2 cos(tilt)``: a horizontal chord of a
body of revolution whose axis is tilted by ``tilt`` from the image columns is ``1/cos(tilt)``
longer than the true diameter, and the horizontal slice of a locally cylindrical body is an
ellipse of area ``pi r^2 / cos(tilt)``; both together give ``pi (c/2)^2 cos(tilt)`` per unit
row height (exact for a cylinder; for a sphere the relative error is ``1 - cos(tilt)``,
3.4e-4 at 1.5 deg; see tests/frame/test_measure_frame.py::test_tilted_slices_cos_factor_vs_resampling
for the numerical check against resampling along the axis).

Coordinates: pixel centres are integers; a row ``i`` covers ``[i - 0.5, i + 0.5)``.

Also here, the shape measures read off the same edges: `clip_to_tip_plane` (the attached
liquid starts at the tilted tip plane), `neck_chord_px` and `top_chord_ratio`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from dropvision.frame.edges import RowEdges
from dvcore.robust import robust_sigma

#: Nanolitres per cubic micrometre.
NL_PER_UM3 = 1e-6


def slice_areas_px2(edges: RowEdges, tilt_rad: float = 0.0) -> np.ndarray:
    """Slice area per run, ``pi (c/2)^2 cos(tilt)`` (pixel units)."""
    c = np.maximum(edges.chord_px, 0.0)
    return np.pi * 0.25 * c * c * np.cos(tilt_rad)


def row_weights(rows: np.ndarray, top_px: float | None, plane_row_is_wall: bool = False) -> np.ndarray:
    """Weight of each row's slice for an integral starting at the plane ``y = top_px``.

    Rows wholly below the plane weigh 1.  The row containing the plane contributes the part of
    it below the plane; when that row's centre lies above the plane (its chord still belongs to
    the nozzle), or its chord is the nozzle's although its centre lies below (``plane_row_is_wall``,
    `plane_row_holds_wall`), the fraction is given to the next row instead.  Rows above weigh 0.
    """
    rows = np.asarray(rows, dtype=float)
    if top_px is None:
        return np.ones_like(rows)
    i0 = np.floor(top_px + 0.5)
    frac = i0 + 0.5 - top_px  # in (0, 1]
    w = np.where(rows >= i0 + 1, 1.0, 0.0)
    if i0 >= top_px and not plane_row_is_wall:
        w = np.where(rows == i0, frac, w)
    else:
        w = np.where(rows == i0 + 1, 1.0 + frac, w)
    return w


def plane_row_holds_wall(edges: RowEdges, top_px: float | None, wall_chord_px: float = float("nan")) -> bool:
    """Whether the row containing the plane ``y = top_px``, its centre below the plane, still shows
    the nozzle's walls rather than the liquid.

    With the plane close above a row's centre the row is half wall: the walls' face, blurred and
    placed to a fraction of a pixel, darkens it past the edge level or not, and its chord is the
    nozzle's outer width or the liquid's as the tip's estimate moves by hundredths of a pixel (on the
    synthetic sweep with the tip plane within 0.02 px of a row centre: +0.10 to +0.15 nl on a 0.24 nl
    meniscus, the whole walls' excess at half weight).  The row's chord is taken for the walls'
    when it lies nearer the walls' outer width ``wall_chord_px`` (the calibrated nozzle at its tip,
    in focus) than the chord of the row below (the liquid), the walls being the wider.  No walls'
    width (NaN: an out-of-focus holder, whose face line places its rows), no row below, or a plane
    row whose centre lies above the plane (`row_weights` gives it away already): False.
    """
    if top_px is None or edges.row.size == 0:
        return False
    rows, left, right = outline(edges)
    return _plane_row_is_walls(rows, right - left, top_px, wall_chord_px)


def _plane_row_is_walls(rows: np.ndarray, width: np.ndarray, top_px: float, wall_chord_px: float) -> bool:
    """`plane_row_holds_wall`'s rule on the rows' widths as the caller reads them (the chords, or
    `cut_at_plane`'s twice the high side's distance from the axis)."""
    i0 = math.floor(top_px + 0.5)
    if i0 < top_px or not np.isfinite(wall_chord_px):
        return False
    k0, k1 = np.flatnonzero(rows == i0), np.flatnonzero(rows == i0 + 1)
    if not (k0.size and k1.size and wall_chord_px > width[k1[0]]):
        return False
    return bool(width[k0[0]] - width[k1[0]] > 0.5 * (wall_chord_px - width[k1[0]]))


def plane_end_px3(edges: RowEdges, weights: np.ndarray, top_px: float | None, tilt_rad: float = 0.0) -> float:
    """Volume (px^3) to add to the first row below a plane for the slice's change across the piece it stands for.

    The first weighted row (centre ``s`` px below the plane) stands for the whole piece from the
    plane down to its lower boundary, ``s + 1/2`` long (`row_weights`), but its slice is the one at
    ``s``, not at the piece's middle ``(s + 1/2) / 2``.  Where the slice changes fast (a resting
    meniscus 3 px tall: its chord 42 px at the orifice, 35 and 26 px one and two rows down), the
    midpoint rule's error there is the piece's length times the slope of the slice area (the next
    row's less this row's) times ``s`` less the middle: on the synthetic meniscus with the plane
    0.25 px below a row centre, -0.010 nl of its 0.24 nl.  The slice is taken as linear through the
    two rows (one run each); 0 without a plane or such rows, where the line would give a negative
    slice at the plane, or where a tilted plane rises more than half a row across the first row
    (`clip_to_tip_plane` cuts those rows, and `plane_cut_uncertainty_px3` states their slab).
    """
    if top_px is None or edges.row.size == 0:
        return 0.0
    on = weights > 0
    if not np.any(on):
        return 0.0
    first = int(edges.row[on].min())
    this, nxt = edges.row == first, edges.row == first + 1
    if this.sum() != 1 or nxt.sum() != 1 or weights[nxt][0] != 1.0:
        return 0.0
    c0, c1 = float(edges.chord_px[this][0]), float(edges.chord_px[nxt][0])
    if abs(math.tan(tilt_rad)) * c0 > 0.5 or c0 <= 0 or c1 <= 0:
        return 0.0
    cos_t = math.cos(tilt_rad)
    a0, a1 = math.pi * 0.25 * c0 * c0 * cos_t, math.pi * 0.25 * c1 * c1 * cos_t
    s = first - top_px
    length = float(weights[this][0])  # s + 1/2
    if a0 + (a0 - a1) * s < 0:
        return 0.0
    return float(length * (a0 - a1) * (s - 0.5) * 0.5)


#: Sub-rows per row over which the band a tilted tip plane crosses is integrated (`cut_at_plane`).
PLANE_SUBROWS = 64


def _segment_fraction(v: np.ndarray) -> np.ndarray:
    """Share of a unit disc on the far side of the chord at ``v`` (1 for v <= -1, 0 for v >= 1)."""
    v = np.clip(v, -1.0, 1.0)
    return (np.arccos(v) - v * np.sqrt(1.0 - v * v)) / np.pi


def axis_edge_points(rows: np.ndarray, left: np.ndarray, right: np.ndarray, top_px: float, axis_col: float,
                     tilt_rad: float, reach_px) -> list[tuple[np.ndarray, np.ndarray, bool]]:
    """Each side's edges in axis coordinates: ``(s, r^2, high)`` per side (right, left), the depth
    ``s`` below the tip plane through (``top_px``, ``axis_col``) perpendicular to the tilted axis and
    the squared distance ``r^2`` from the axis, sorted by depth, ``high`` for the plane's high side
    (both sides without a tilt).  The low side's edges are kept only in rows ``reach_px + 1/2`` or
    more below the tip row (``reach_px``: how far the walls reach below it, per row or one value):
    above, the walls' remnant is its edge (`clip_to_tip_plane`).  Edges on the axis's other side
    (``r <= 0``) are left out."""
    tan, cos, sin = math.tan(tilt_rad), math.cos(tilt_rad), math.sin(tilt_rad)
    dy = np.asarray(rows, float) - top_px
    sides = []
    for x, sign in ((right, 1.0), (left, -1.0)):
        dx = np.asarray(x, float) - axis_col
        s = dy * cos + dx * sin
        r = sign * (dx * cos - dy * sin)
        high = abs(tan) < 1e-12 or (sign > 0) == (tan > 0)
        use = (r > 0) if high else (r > 0) & (dy >= np.asarray(reach_px, float) + 0.5)
        order = np.argsort(s[use], kind="stable")
        sides.append((s[use][order], r[use][order] ** 2, high))
    return sides


def cut_at_plane(edges: RowEdges, top_px: float, axis_col: float, tilt_rad: float,
                 wall_chord_px: float = float("nan")) -> tuple[np.ndarray, np.ndarray] | None:
    """Slice volumes (px^3 per run) and row weights of liquid below a tip plane that may be tilted.

    The plane through (``top_px``, ``axis_col``) is perpendicular to the axis, ``y = top - (x -
    axis) tan(tilt)``.  Near it the liquid is integrated as what it is, a body of revolution about
    the axis: discs perpendicular to the axis, ``pi r(s)^2`` at ``s`` px below the plane, from the
    plane down to the lower boundary ``y_J`` of the rows it and the walls cross, each disc counted
    for its share above that horizontal boundary (a disc segment, `_segment_fraction`); the rows
    below are whole (`slice_areas_px2`).  The radius ``r(s)`` is read off the edges: each edge's
    distance from the axis at its own ``s`` (for a 21 px orifice at 1.5 deg, the two edges of one
    row lie 1.1 px of ``s`` apart, a third of a resting meniscus), the plane's high side from the
    first row whose centre lies below the plane at the axis (only liquid lies below the plane
    there), the low side below the rows the walls reach (`clip_to_tip_plane`), its square linear
    between them and, above the first, on the line through the first two (`plane_end_px3`'s
    rule); a first row whose chord is the walls' (`plane_row_holds_wall`) is not read.  With no tilt
    this is `row_weights` with `plane_row_holds_wall` and `plane_end_px3`'s rule, to rounding.

    Returns None where fewer than two rows of liquid lie below the plane (no line to read).
    """
    if edges.row.size == 0 or not (np.isfinite(top_px) and np.isfinite(axis_col) and np.isfinite(tilt_rad)):
        return None
    tan, cos, sin = math.tan(tilt_rad), math.cos(tilt_rad), math.sin(tilt_rad)
    rows, left, right = outline(edges)
    chord = right - left
    liquid = (rows >= top_px) & (chord > 0)
    # the row holding the plane, read where the cut reads it (the high side's half-width, twice):
    # the walls' when nearer their width than the next row's (`plane_row_holds_wall`)
    if abs(tan) < 1e-12:
        width = chord
    else:
        width = 2.0 * np.abs((right if tan > 0 else left) - (axis_col + (rows - top_px) * tan))
    if _plane_row_is_walls(rows, width, top_px, wall_chord_px):
        liquid &= rows != math.floor(top_px + 0.5)
    idx = np.flatnonzero(liquid)
    if idx.size < 2 or rows[idx[1]] != rows[idx[0]] + 1:
        return None
    first = int(rows[idx[0]])
    # the top part ends below the rows the walls may reach under the tip row (`clip_to_tip_plane`)
    reach = abs(tan) * np.maximum(chord, wall_chord_px if np.isfinite(wall_chord_px) else 0.0)
    y_j = float(max(first, math.floor(top_px + float(np.max(reach[idx[:2]])) + 0.5)) + 0.5)
    near = liquid & (rows <= y_j + 1.5)
    sides = axis_edge_points(rows[near], left[near], right[near], top_px, axis_col, tilt_rad, reach[near])
    highs = [sd for sd in sides if sd[2] and sd[0].size >= 2]
    if not highs:
        return None
    s_end = (y_j - top_px) / cos + (math.sqrt(max(float(np.max(np.r_[sides[0][1], sides[1][1]])), 0.0))
                                    * abs(tan) if abs(tan) > 1e-12 else 0.0)
    n = max(int(math.ceil(s_end * PLANE_SUBROWS)), 1)
    ds = s_end / n
    sk = (np.arange(n) + 0.5) * ds
    # the radius: the mean of the sides that reach a depth (each side's r^2 linear between its edges)
    tot, cnt = np.zeros(n), np.zeros(n)
    for s_side, r2, _ in sides:
        if s_side.size == 0:
            continue
        on = (sk >= s_side[0]) & (sk <= s_side[-1])
        tot[on] += np.sqrt(np.interp(sk[on], s_side, r2))
        cnt[on] += 1
    # above the first edges: the line through the high side's first two (mean of both without a tilt)
    s1 = max(float(sd[0][0]) for sd in highs)
    s2 = min(float(sd[0][1]) for sd in highs)
    r2_at = [float(np.mean([np.interp(d, sd[0], sd[1]) for sd in highs])) for d in (s1, s2)]
    ak = np.where(cnt > 0, np.pi * (tot / np.maximum(cnt, 1)) ** 2, 0.0)
    up = sk < s1
    ak[up] = np.pi * (r2_at[0] + (r2_at[0] - r2_at[1]) / (s2 - s1) * (s1 - sk[up]))
    ak = np.maximum(ak, 0.0)  # discs perpendicular to the axis: no cos(tilt) factor
    # each disc's share above the horizontal y = y_J: y = top + s cos + n sin over the disc's n
    if abs(sin) > 1e-12:
        rk = np.sqrt(ak / np.pi)
        with np.errstate(divide="ignore", invalid="ignore"):
            v = np.where(rk > 0, (top_px + sk * cos - y_j) / (rk * abs(sin)), np.where(top_px + sk * cos < y_j, -1.0, 1.0))
        frac = _segment_fraction(v)
    else:
        frac = (sk * cos < y_j - top_px).astype(float)
    slab = ak * frac * ds
    run_w = np.where(edges.row - 0.5 >= y_j - 1e-9, 1.0, 0.0)
    vol = slice_areas_px2(edges, tilt_rad) * run_w
    # the top part on the rows its discs' centres lie in (the first row of liquid for those above it)
    disc_row = np.maximum(np.floor(top_px + sk * cos + 0.5).astype(int), first)
    slice_area = np.pi * 0.25 * chord * chord * cos
    run_chord = np.maximum(edges.chord_px, 0.0)
    for r in np.unique(disc_row):
        share = float(slab[disc_row == r].sum())
        if not np.any(liquid & (rows == r)):  # no liquid run there: the nearest row of liquid takes it
            r = int(rows[idx[np.argmin(np.abs(rows[idx] - r))]])
        on = np.flatnonzero(edges.row == r)
        on = on[np.argmax(run_chord[on])]  # the row's widest run (not a wall's remnant beside it)
        vol[on] += share
        k = np.flatnonzero(rows == r)[0]
        run_w[on] += share / float(slice_area[k]) if slice_area[k] > 0 else 0.0
    return vol, run_w


def _on_first_row(edges: RowEdges, weights: np.ndarray, px3: float) -> np.ndarray:
    """``px3`` placed on the first weighted row's run (zeros elsewhere; all zeros for 0)."""
    out = np.zeros(edges.row.size)
    if px3 != 0.0:
        on = weights > 0
        out[np.flatnonzero(on & (edges.row == edges.row[on].min()))[0]] = px3
    return out


@dataclass
class BodyVolume:
    """Disc-integrated volume and centroid of one body (pixel units, region coordinates)."""

    volume_px3: float
    centroid_row: float
    centroid_col: float
    top_row: float
    bottom_row: float
    max_chord_px: float
    n_rows: int
    area_px2: float = 0.0  # silhouette area integrated (sum of chord x row weight): dV = pi area d
    blur_px3: float = 0.0  # blur correction added to volume_px3
    chord2_px2: float = 0.0  # sum of chord^2 x row weight (random edge noise: see volume_uncertainty_px3)
    top_chord_px: float = 0.0  # chord of the first integrated row (a cut at a plane: its area's share)
    dark_t: float = float("nan")  # the body's darkest level (`RowEdges.dark_t`): see edge_definition_px
    slope_t_per_px: float = float("nan")  # its edges' slope at the edge level (`RowEdges.slope_t_per_px`)
    bright_t: float = float("nan")  # the background next to its edges (`RowEdges.bright_t`)
    bright_noise_t: float = float("nan")  # those samples' own noise (`RowEdges.bright_noise_t`)
    # the chord across which a tilted tip plane runs (`plane_span_chord_px`; 0: the top chord)
    plane_span_px: float = 0.0
    # cut at the plane along the axis (`cut_at_plane`): no slab of rows the plane crosses is left unresolved
    cut_along_axis: bool = False


def blur_correction_px3(edges: RowEdges, sigma_px: float, closed_top: bool = True) -> float:
    """Volume lost by the 50 % silhouette of a blurred body, ``pi sigma^2 * integral r dphi``.

    A Gaussian blur of ``sigma`` moves the 50 % contour of a smooth silhouette inwards by
    ``sigma^2 kappa / 2`` (kappa: its curvature); for a body of revolution this removes
    ``pi sigma^2 * integral r kappa dl = pi sigma^2 * integral r dphi`` (phi: the tangent angle of
    the meridian, from 0 at the top pole to pi at the bottom pole).  For a sphere of radius R
    this is ``2 pi sigma^2 R``, i.e. a relative volume loss of ``1.5 (sigma / R)^2``.  Both
    sides of the silhouette are used (mean); rows with several runs use the outermost edges.

    Parameters
    ----------
    edges : RowEdges
    sigma_px : float
        Effective blur (see `dropvision.calibrate.blur.edge_sigma_px`).
    closed_top : bool
        The body has a top pole (False for liquid joined to the nozzle: its silhouette starts
        at the tip plane).
    """
    return _blur_correction(edges, sigma_px, closed_top)[0]


def outline(edges: RowEdges) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The body's outline: per row (ascending), its outermost left and right edges (px)."""
    order = np.argsort(edges.row, kind="stable")
    uniq, first = np.unique(edges.row[order], return_index=True)
    if uniq.size == 0:
        return uniq, np.zeros(0), np.zeros(0)
    return (uniq, np.minimum.reduceat(edges.left_px[order], first),
            np.maximum.reduceat(edges.right_px[order], first))


def _blur_correction(edges: RowEdges, sigma_px: float, closed_top: bool) -> tuple[float, float, float]:
    """`blur_correction_px3` with the correction's first moments: (volume, sum of volume x row,
    sum of volume x column), the lost volume of each row placed on that row's axis point."""
    if edges.row.size < 2 or not np.isfinite(sigma_px) or sigma_px <= 0:
        return 0.0, 0.0, 0.0
    uniq, left, right = outline(edges)
    if uniq.size < 2:
        return 0.0, 0.0, 0.0
    dy = np.diff(uniq).astype(float)
    w = np.zeros(uniq.size)
    r = 0.5 * (right - left)
    for x, sign in ((right, 1.0), (left, -1.0)):
        phi = np.arctan2(dy, sign * np.diff(x))  # tangent angle of each segment, in (0, pi)
        start = 0.0 if closed_top else phi[0]
        dphi = np.diff(np.concatenate(([start], phi, [np.pi])))
        w += r * dphi
    w *= np.pi * sigma_px**2 * 0.5
    return float(w.sum()), float(np.sum(w * uniq)), float(np.sum(w * 0.5 * (left + right)))


def integrate(
    edges: RowEdges,
    tilt_rad: float = 0.0,
    top_px: float | None = None,
    blur_sigma_px: float = 0.0,
    wall_chord_px: float = float("nan"),
    axis_col: float | None = None,
) -> BodyVolume:
    """Volume (pixel^3) and volume centroid of a body from its run edges.

    Parameters
    ----------
    edges : RowEdges
    tilt_rad : float
        Tilt of the jetting axis from the image columns.
    top_px : float, optional
        Integrate only below this plane (the nozzle tip), see `row_weights`.
    blur_sigma_px : float
        Effective blur; adds `blur_correction_px3` (0: no correction).
    wall_chord_px : float
        The nozzle walls' outer width at the plane (px; NaN: not known), for `plane_row_holds_wall`.
    axis_col : float, optional
        The axis' column at the plane: the plane is then perpendicular to the tilted axis through
        it, and the rows it crosses are cut as `cut_at_plane` does (the plane horizontal otherwise).
    """
    cut = cut_at_plane(edges, top_px, axis_col, tilt_rad, wall_chord_px) \
        if top_px is not None and axis_col is not None else None
    if cut is not None:
        a, wts = cut
    else:
        wts = row_weights(edges.row, top_px, plane_row_holds_wall(edges, top_px, wall_chord_px))
        a = slice_areas_px2(edges, tilt_rad) * wts
        a = a + _on_first_row(edges, wts, plane_end_px3(edges, wts, top_px, tilt_rad))
    area = float(np.sum(np.maximum(edges.chord_px, 0.0) * wts))
    chord2 = float(np.sum(np.maximum(edges.chord_px, 0.0) ** 2 * wts))
    vol = float(a.sum())
    c_vol = 0.0
    m_row = float((a * edges.row).sum())
    m_col = float((a * edges.centre_px).sum())
    if blur_sigma_px > 0 and vol > 0:
        sel = a > 0
        sub = RowEdges(edges.row[sel], edges.left_px[sel], edges.right_px[sel], edges.touches)
        c_vol, c_row, c_col = _blur_correction(sub, blur_sigma_px, top_px is None)
        cos_t = float(np.cos(tilt_rad))
        vol += c_vol * cos_t
        m_row += c_row * cos_t
        m_col += c_col * cos_t
    keep = a > 0
    if vol <= 0 or not np.any(keep):
        return BodyVolume(0.0, np.nan, np.nan, np.nan, np.nan, 0.0, 0)
    rows = edges.row[keep]
    return BodyVolume(
        vol,
        m_row / vol,  # the corrected volume's centroid: slices and the blur correction's moments
        m_col / vol,
        float(rows.min()),
        float(rows.max()),
        float(edges.chord_px[keep].max()),
        int(np.unique(rows).size),
        area,
        c_vol * float(np.cos(tilt_rad)),
        chord2,
        float(edges.chord_px[keep][rows == rows.min()].max()),
        edges.dark_t,
        edges.slope_t_per_px,
        edges.bright_t,
        edges.bright_noise_t,
        cut_along_axis=cut is not None,
    )


def volume_uncertainty_px3(volume: BodyVolume, edge_sigma_px: float, tilt_rad: float = 0.0,
                           blur_fraction: float = 0.25, definition_px: float = 0.0) -> float:
    """Standard uncertainty (px^3) of a disc-integrated volume from errors common to its edges.

    An error ``d`` common to every edge of the silhouette (threshold level, background model,
    a clipped background) changes each slice ``pi c^2 / 4`` by ``pi c d / 2`` per edge, so the
    volume by ``pi d * sum(c)``: ``pi d`` times the silhouette's area (for a sphere of radius
    ``R``, ``3 d / R`` relative).  The edge's definition on this body (``definition_px``,
    `edge_definition_px`) is such an error too, in quadrature with ``edge_sigma_px``.  The blur
    correction's model error, ``blur_fraction`` of the correction, is added in quadrature.
    `random_volume_uncertainty_px3` gives the part of independent per-edge noise,
    `plane_cut_uncertainty_px3` that of a cut at the tip plane.

    Parameters
    ----------
    volume : BodyVolume
        From `integrate` (``area_px2``, ``blur_px3``).
    edge_sigma_px : float
        Standard uncertainty of an edge's position, common to the body (px).
    tilt_rad : float
        Tilt of the axis (the slices are ``cos(tilt)`` thinner).
    blur_fraction : float
        Relative uncertainty of the blur correction.
    definition_px : float
        Standard uncertainty of where the body's edge lies, from the band of edge levels
        (`edge_definition_px`, px; 0: none).

    Returns
    -------
    float
    """
    if volume.volume_px3 <= 0:
        return float("nan")
    edge_sigma_px = math.hypot(edge_sigma_px, definition_px if np.isfinite(definition_px) else 0.0)
    edge = math.pi * volume.area_px2 * edge_sigma_px * math.cos(tilt_rad)
    return float(math.hypot(edge, blur_fraction * volume.blur_px3))


def edge_definition_px(volume: BodyVolume, liquid_level: float, noise_t: float = 0.0) -> float:
    """Standard uncertainty (px) of where a body's edge lies: the band of edge levels its own profile allows.

    Every edge is placed half-way between the background (1, the background model) and the
    liquid's dark level (the calibration's interior level, `dropvision.frame.edges.edge_threshold`).
    Both ends of that contrast are claims the body's own profile can contradict:

    - the dark end: a drop is a lens, not uniformly dark; its own darkest level (its rim: the 2nd
      percentile of its pixels, `dropvision.frame.edges.dark_level`, less the 2.05 noise standard
      deviations by which the 2nd percentile of noise lies below its mean) claims it as well as
      the calibrated interior median (its bright spot left out);
    - the bright end: the background next to its edges (`dropvision.frame.edges.RowEdges.bright_t`,
      one edge width out: the 10th percentile of its samples plus the 1.28 noise standard
      deviations by which the 10th percentile of noise lies below its mean; the noise is the
      larger of the frame's and the samples' own, `dropvision.frame.edges.RowEdges.bright_noise_t`, which
      holds a JPEG coder's ringing beside the edge) is not the model's 1 where mist, flare or a
      diffraction halo lie over it.

    Real optics justify any edge level between half-way to the calibrated levels and half-way
    between the body's own: ``(1 + T_liquid) / 2`` and ``(bright + dark) / 2``.  Across that band
    the edge moves by ``D``, the band's width over the edge's slope
    (`dropvision.frame.edges.RowEdges.slope_t_per_px`).  With the true edge anywhere in the band (a
    rectangular distribution) and the volume measured at the band's end, the error's standard
    deviation about the measured edge is ``sqrt((D/2)^2 + D^2/12) = D / sqrt(3)``: the term,
    common to the body's edges.  The same rule wherever the frame comes from: on a body as dark
    as the calibrated liquid over a background the model holds, it is zero.

    Parameters
    ----------
    volume : BodyVolume
        From `integrate` (``dark_t``, ``bright_t``, ``slope_t_per_px``).
    liquid_level : float
        The liquid's calibrated interior transmission.
    noise_t : float
        Standard deviation of a pixel's transmission noise.

    Returns
    -------
    float
        px (0 where nothing is measured: no slope, no dark level).
    """
    noise = max(float(noise_t), 0.0) if np.isfinite(noise_t) else 0.0
    dark = min(volume.dark_t + 2.05 * noise, liquid_level) if np.isfinite(liquid_level) else float("nan")
    own = float(volume.bright_noise_t) if np.isfinite(volume.bright_noise_t) else 0.0
    bright = volume.bright_t + 1.2816 * max(noise, own) if np.isfinite(volume.bright_t) else 1.0
    slope = volume.slope_t_per_px
    if not (np.isfinite(dark) and np.isfinite(slope) and slope > 0):
        return 0.0
    band_t = abs(0.5 * (bright + dark) - 0.5 * (1.0 + float(liquid_level)))
    return float(band_t / slope / math.sqrt(3.0))


def interpolation_error_px(sigma_px: float) -> float:
    """Standard deviation (px) of a sub-pixel edge placed by linear interpolation between two samples.

    A pixel integrates the light over its square and the optics blur the silhouette by a Gaussian
    of ``sigma_px``: across an edge, the samples follow that box-and-Gaussian profile, not the
    straight line `dropvision.frame.edges.crossing_fraction` draws between two of them.  Where the 50 %
    crossing lands depends on where the edge lies between the pixel centres (its phase): zero at a
    centre and half-way between (by symmetry), most at a quarter pixel.  Along a curved outline the
    phase changes from row to row, so the error is independent from edge to edge: this is its RMS
    over a uniform phase (computed here from the profile; 0 for a sharp edge, whose box-integrated
    profile is straight; 0.010 px at ``sigma`` 1 px, 0.03 px at 0.5 px).
    """
    s = float(sigma_px) if np.isfinite(sigma_px) else 0.0
    return _interpolation_error_px(round(max(s, 0.0), 2))


@lru_cache(maxsize=256)
def _interpolation_error_px(sigma_px: float) -> float:
    if sigma_px < 0.02:
        return 0.0
    erf = np.frompyfunc(math.erf, 1, 1)  # scipy.special would cost the command ~0.25 s of imports

    phase = (np.arange(64) + 0.5) / 64  # the edge's place past a sample (px)
    x = np.arange(-12, 13)[None, :] - phase[:, None]
    sub = (np.arange(16) + 0.5) / 16 - 0.5  # the pixel's square
    t = 0.5 * (1.0 + erf((x[..., None] + sub) / (math.sqrt(2.0) * sigma_px)).astype(float)).mean(axis=-1)
    i = np.argmax(t >= 0.5, axis=1)
    k = np.arange(phase.size)
    t0, t1 = t[k, i - 1], t[k, i]
    pos = x[k, i - 1] + (0.5 - t0) / (t1 - t0)
    return float(np.sqrt(np.mean(pos * pos)))


#: How many robust sigmas of the midpoints' scatter about the body's axis a row's midpoint must
#: lie off it to count in `asymmetry_px3`, and how many consecutive rows must (noise alone puts 4
#: sigmas three rows running once in about 4 x 10^12 rows).
ASYMMETRY_SIGMAS = 4.0
ASYMMETRY_MIN_ROWS = 3


def asymmetry_px3(edges: RowEdges) -> float:
    """Volume (px^3) of the stretches where a body's two sides are not mirror images about its axis.

    The disc integration takes the body as one of revolution: each row's two edges lie as far
    either side of its axis.  A stretch of rows whose midpoint leaves the axis (the least-squares
    line through the rows' midpoints, fitted twice more on the rows within 3 robust sigmas of it: a
    tilted drop keeps its line; a spheroid tilted 4 deg reads 0) by more than `ASYMMETRY_SIGMAS`
    robust sigmas of the midpoints' own scatter, in at least `ASYMMETRY_MIN_ROWS` consecutive rows,
    has one side pushed out or in by twice that offset ``d``: something lying over that edge (an
    out-of-focus mist droplet's shadow, a speck) or a body that is not one of revolution there.
    Either way the slices there are uncertain by what the departure adds, ``pi c |2 d| / 2`` a
    row.  On the synthetic drop watcher's single frames: 0.052 and 0.074 nl on the two of thirty
    whose 19.5 nl drop had a mist droplet's shadow over its edge (errors 0.082 and 0.090 nl against
    0.039 and 0.036 nl stated), 0 on 27 of the others and 0.008 nl on one.

    Returns
    -------
    float
        px^3 (0 for fewer than 10 rows).
    """
    rows, left, right = outline(edges)
    if rows.size < 10:
        return 0.0
    y = rows.astype(float)
    mid = 0.5 * (left + right)
    use = np.ones(y.size, bool)
    for _ in range(3):  # the line through the midpoints, twice more through those within 3 sigmas of it
        yu, mu = y[use], mid[use]
        ym, mm = float(np.mean(yu)), float(np.mean(mu))
        syy = float(np.dot(yu - ym, yu - ym))
        slope = float(np.dot(yu - ym, mu - mm)) / syy if syy > 0 else 0.0
        d = mid - (mm + slope * (y - ym))
        scale = max(robust_sigma(d), 1e-3)
        use = np.abs(d) <= 3.0 * scale
        if use.sum() < 3:
            return 0.0
    off = np.abs(d) > ASYMMETRY_SIGMAS * scale
    if np.count_nonzero(off) < ASYMMETRY_MIN_ROWS:
        return 0.0
    idx = np.flatnonzero(off)  # runs of consecutive rows off the axis
    run = np.cumsum(np.r_[True, (np.diff(idx) != 1) | (np.diff(rows[idx]) != 1)]) - 1
    keep = idx[np.bincount(run)[run] >= ASYMMETRY_MIN_ROWS]
    return float(np.pi * np.sum((right - left)[keep] * np.abs(d[keep])))


def asymmetry_uncertainty_px3(edges: RowEdges) -> float:
    """Standard uncertainty (px^3) of a detached body's volume from its sides' departure from mirror
    images (`asymmetry_px3`): the true slices anywhere between with and without it, the measured ones
    at one end, over sqrt(3), as for the band of edge levels (`edge_definition_px`)."""
    return asymmetry_px3(edges) / math.sqrt(3.0)


def tilt_model_uncertainty_px3(volume: BodyVolume, tilt_rad: float, closed: bool = True) -> float:
    """Standard uncertainty (px^3) of the slices' ``cos(tilt)`` factor (`slice_areas_px2`).

    The factor is exact for a locally cylindrical body.  For a spheroid of semi-axes ``a`` (along
    its axis) and ``b`` (across) whose axis is tilted by ``t`` in the image plane, every
    horizontal slice is an ellipse whose depth over its chord is ``sqrt(cos^2 t + (b/a)^2 sin^2 t)``,
    not ``cos t``: the measured volume is too small by ``D = V (sqrt(cos^2 t + (b/a)^2 sin^2 t) /
    cos t - 1)`` (``1 - cos t`` for a sphere; more for an oblate, oscillating drop; 0 for a long
    body).  ``b/a`` is the body's own widest chord over its extent along the rows.  A body lies
    between the cylinder (the measured value) and its spheroid (``D`` away): ``D`` itself is
    taken as the standard uncertainty (a spheroid's error is all of it).  0 on an untilted axis.
    Liquid cut at the tip plane (``closed`` False) goes on into the nozzle: its extent along the rows
    is not its length, and it is taken as no flatter than a sphere (``b/a`` at most 1).
    """
    if volume.volume_px3 <= 0 or not np.isfinite(tilt_rad) or tilt_rad == 0.0:
        return 0.0
    length = volume.bottom_row - volume.top_row + 1.0
    aspect = volume.max_chord_px / length if np.isfinite(length) and length > 0 else 1.0
    if not closed:
        aspect = min(aspect, 1.0)
    c, s = math.cos(tilt_rad), math.sin(tilt_rad)
    return float(volume.volume_px3 * (math.sqrt(c * c + (aspect * s) ** 2) / c - 1.0))


def random_volume_uncertainty_px3(volume: BodyVolume, edge_noise_px: float, tilt_rad: float = 0.0) -> float:
    """Standard uncertainty (px^3) of a volume from independent noise ``edge_noise_px`` on every edge.

    Each slice changes by ``pi c (d_left + d_right) / 2``: in quadrature over the rows,
    ``pi d sqrt(sum(c^2) / 2)``.
    """
    if volume.volume_px3 <= 0:
        return float("nan")
    return float(math.pi * edge_noise_px * math.sqrt(0.5 * volume.chord2_px2) * math.cos(tilt_rad))


def plane_cut_uncertainty_px3(volume: BodyVolume, plane_sigma_px: float, tilt_rad: float = 0.0) -> float:
    """Standard uncertainty (px^3) of a volume cut at a plane placed to ``plane_sigma_px``: the
    slice there, ``pi (c/2)^2`` per px (``c`` the top chord).  A tilted plane rises by
    ``C tan(tilt)`` across the body it cuts, which the rows resolve only to a row: the slab it
    crosses, ``pi (C/2)^2 C |tan(tilt)|``, is cut by horizontal rows (`row_weights`) and a clipped
    chord (`clip_to_tip_plane`), not by the plane; its uniform spread over ``sqrt(12)`` adds in
    quadrature.  ``C`` is the chord the plane runs across before the clip
    (``volume.plane_span_px``, `plane_span_chord_px`), not the clipped top chord, which shortens as
    the tilt grows (on the synthetic tilted nozzle: 0.026 nl stated against 0.043 nl of error at
    3 deg, 0.041 nl against 0.017 nl at 1.5 deg, with the clipped chord).  A volume cut along the
    axis (``volume.cut_along_axis``, `cut_at_plane`) resolves that slab: no such term."""
    c = volume.top_chord_px
    span = max(float(volume.plane_span_px), c) if np.isfinite(volume.plane_span_px) else c
    tilt = 0.0 if volume.cut_along_axis else \
        math.pi * 0.25 * span * span * span * abs(math.tan(tilt_rad)) / math.sqrt(12.0)
    return float(math.hypot(math.pi * 0.25 * c * c * plane_sigma_px, tilt))


def plane_span_chord_px(edges: RowEdges, tip_row: float, axis_col: float, tilt_rad: float) -> float:
    """The widest chord (px) of the liquid a tilted tip plane crosses, before `clip_to_tip_plane` cuts
    it, read on the side where the plane is above the tip row (its rows below the tip hold liquid
    only; on the other side the nozzle's outer wall reaches below the tip row until the clip cuts
    it): twice the distance of that side's edge from the axis, in the rows whose centres lie below
    the tip row down to ``tip + |tan(tilt)| chord + 1`` (the rows the clip looks at).  0 without a
    tilt or such a row."""
    tan = math.tan(tilt_rad) if np.isfinite(tilt_rad) else 0.0
    if edges.row.size == 0 or not np.isfinite(tip_row) or abs(tan) < 1e-9:
        return 0.0
    chord = edges.right_px - edges.left_px
    near = (edges.row > tip_row) & (edges.row < tip_row + abs(tan) * chord + 1.0)
    if not np.any(near):
        return 0.0
    # the axis at each row (it leans with the tilt), and the edge on the plane's high side
    axis = axis_col + (edges.row[near] - tip_row) * tan
    half = edges.right_px[near] - axis if tan > 0 else axis - edges.left_px[near]
    return float(2.0 * max(float(half.max()), 0.0))


def equivalent_diameter_um(volume_nl: float) -> float:
    """Diameter (µm) of the sphere of ``volume_nl``."""
    return (6.0 * volume_nl / NL_PER_UM3 / math.pi) ** (1.0 / 3.0) if volume_nl > 0 else 0.0


# ----------------------------------------------------------------------------- shape from edges
def clip_to_tip_plane(edges: RowEdges, tip_row: float, axis_col: float, tilt_rad: float) -> None:
    """Cut the attached liquid's runs at the tip plane (perpendicular to a tilted axis), in place.

    The plane through (tip, axis) is ``y = tip - (x - axis) tan(tilt)``; near the tip of a tilted
    nozzle one wall ends below the tip row at the axis, and its part of a run is not liquid.

    Parameters
    ----------
    edges : RowEdges
        Run edges of the nozzle body (region coordinates, px); modified in place.
    tip_row, axis_col : float
        Tip row and axis column at the tip (region coordinates, px).
    tilt_rad : float
        Tilt of the jetting axis from the image columns (rad).
    """
    tan = math.tan(tilt_rad)
    if abs(tan) < 1e-9 or edges.row.size == 0:
        return
    near = edges.row < tip_row + abs(tan) * (edges.right_px - edges.left_px) + 1.0
    if not np.any(near):
        return
    bound = axis_col + (tip_row - edges.row) / tan
    if tan > 0:
        edges.left_px = np.where(near, np.maximum(edges.left_px, bound), edges.left_px)
    else:
        edges.right_px = np.where(near, np.minimum(edges.right_px, bound), edges.right_px)
    edges.right_px = np.maximum(edges.right_px, edges.left_px)


def neck_chord_px(edges: RowEdges, tip_row: float) -> float:
    """Narrowest chord of the attached liquid between the tip and the widest row of its bulb.

    Parameters
    ----------
    edges : RowEdges
        Run edges of the attached liquid (region coordinates, px).
    tip_row : float
        Tip plane row (region coordinates, px); rows within 2 px below it are the meniscus.

    Returns
    -------
    float
        The neck's chord (px); NaN when there is no neck (the narrowest chord is less than 3
        rows above the widest one, or not narrower than half of it).
    """
    below = edges.row > tip_row + 2
    if not np.any(below):
        return float("nan")
    rows = edges.row[below]
    chord = edges.chord_px[below]
    widest = rows[np.argmax(chord)]
    upper = rows <= widest
    k = np.argmin(np.where(upper, chord, np.inf))
    if widest - rows[k] >= 3 and chord[k] < 0.5 * chord.max():
        return float(chord[k])
    return float("nan")


def top_chord_ratio(edges: RowEdges, volume: BodyVolume, at: float = 0.25) -> float:
    """Chord a quarter of the body's length below its top over its widest chord.

    0.87 for any spheroid (whatever its aspect ratio); much smaller when a thin tail is still
    joined to the top of the drop.

    Parameters
    ----------
    edges : RowEdges
        Run edges of the body (px).
    volume : BodyVolume
        Its integrated volume (`integrate`): top, bottom row and widest chord (px).
    at : float
        Where to take the chord, as a fraction of the length from the top.

    Returns
    -------
    float
        Dimensionless ratio; NaN for an empty body or no run at that row.
    """
    if volume.max_chord_px <= 0 or not np.isfinite(volume.top_row):
        return float("nan")
    y = volume.top_row + at * (volume.bottom_row - volume.top_row)
    sel = np.abs(edges.row - y) <= 0.5
    if not np.any(sel):
        return float("nan")
    return float(edges.chord_px[sel].max() / volume.max_chord_px)


def waist_row(edges: RowEdges, ratio: float = 0.6, max_neck_rows: int = 3, min_lobe_rows: int = 3) -> int | None:
    """Row of a short waist joining two lobes (a satellite touching the drop), or None.

    The widest chord per row is scanned for its narrowest interior row whose chord is below
    ``ratio`` x the widest chord of *both* lobes (above and below), where the narrow part is at
    most ``max_neck_rows`` rows long (a thin tail is long and is not a waist) and each lobe has
    at least ``min_lobe_rows`` rows.

    Parameters
    ----------
    edges : RowEdges
        Run edges of one body (px).
    ratio : float
        Neck chord over the smaller lobe's widest chord.
    max_neck_rows : int
        Longest narrow part that is still a waist (rows).
    min_lobe_rows : int
        Fewest rows of each lobe.

    Returns
    -------
    int or None
        The waist row (region coordinates), or None.
    """
    if edges.row.size == 0:
        return None
    rows = np.unique(edges.row)
    width = np.zeros(rows.size)
    np.maximum.at(width, np.searchsorted(rows, edges.row), edges.chord_px)
    n = rows.size
    if n < 2 * min_lobe_rows + 1 or np.any(np.diff(rows) != 1):
        return None
    above_max = np.maximum.accumulate(width)  # max of width[:i + 1]
    below_max = np.maximum.accumulate(width[::-1])[::-1]  # max of width[i:]
    idx = np.arange(min_lobe_rows, n - min_lobe_rows)
    lobes = np.minimum(above_max[idx - 1], below_max[idx + 1])
    best = None
    for i in idx[width[idx] < ratio * lobes]:  # usually none: the loop is over waist candidates only
        above, below = above_max[i - 1], below_max[i + 1]
        narrow = width < ratio * min(above, below)
        j0 = i
        while j0 > 0 and narrow[j0 - 1]:
            j0 -= 1
        j1 = i
        while j1 < n - 1 and narrow[j1 + 1]:
            j1 += 1
        if j1 - j0 + 1 > max_neck_rows or j0 < min_lobe_rows or n - 1 - j1 < min_lobe_rows:
            continue
        if best is None or width[i] < width[best]:
            best = i
    return None if best is None else int(rows[best])


def split_at_row(edges: RowEdges, row: int) -> tuple[RowEdges, RowEdges]:
    """The runs above ``row`` (and half of it) and below it: two bodies joined at a waist.

    The waist row's runs are given to both parts with their chord divided by sqrt(2) (same
    centre): half the slice area each, so the two volumes add up to the whole.
    """
    up = edges.row < row
    down = edges.row > row
    at = edges.row == row
    half = edges.chord_px[at] / (2.0 * math.sqrt(2.0))
    half_l = edges.centre_px[at] - half
    half_r = edges.centre_px[at] + half

    def part(sel):
        return RowEdges(np.concatenate([edges.row[sel], edges.row[at]]),
                        np.concatenate([edges.left_px[sel], half_l]),
                        np.concatenate([edges.right_px[sel], half_r]), edges.touches,
                        edges.dark_t, edges.slope_t_per_px, edges.bright_t, edges.bright_noise_t)

    return part(up), part(down)
