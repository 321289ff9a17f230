"""Effective blur of the frame's edges (Gaussian sigma, px) from their edge-spread function.

`edge_sigma_px` pools the nozzle's straight outer walls, `esf_sigma_px` any body's outline.
"""

from __future__ import annotations

import numpy as np

from dropvision.calibrate.nozzle import Nozzle
from dropvision.calibrate.special import erf


def edge_sigma_px(transmission: np.ndarray, nozzle: Nozzle, half_window_px: int = 8,
                  clip_transmission: float = float("inf")) -> float:
    """Effective blur of straight edges (px): Gaussian sigma including the pixel box.

    The transmission samples across the nozzle's outer walls, placed at their distance from
    each row's sub-pixel 50 % edge, are pooled into one finely sampled edge-spread function and
    fitted by least squares with an error function ``(1 + erf(u / (sqrt(2) sigma))) / 2``
    (plus a shift).  This sigma (optics and pixel box together) is the smoothing that displaces
    a curved 50 % edge by ``sigma^2 * curvature / 2``.  Samples at or above
    ``clip_transmission`` (a clipped background) are left out of the fit.

    A wall's profile is a straight edge's only `WALL_END_CLEARANCE_SIGMAS` blur sigmas away from
    the walls' ends (`wall_rows_clear_of_ends`): nearer, the blur of a holder's face above them or
    of the tip's face below spreads into it and the fit reads a wider blur.  The walls are fitted
    once, then again on the rows that clear both ends by that many sigmas of the first fit (the
    rows farthest from them where none does).  A nozzle protruding 8.5 px below a holder block read
    1.22-1.42 px for the 1.02-1.12 px the same nozzle reads without the block (synthetic drop
    watcher, Gaussian blur 1.0 px): the blur correction of its 19.5 nl drop 26-64 % too large (now
    1.09-1.19 px).
    """
    args = (nozzle.interior_level, half_window_px, clip_transmission)
    sigma = esf_sigma_px(transmission, nozzle.rows, nozzle.left_px, nozzle.right_px, *args)
    if not np.isfinite(sigma):
        return sigma
    keep = wall_rows_clear_of_ends(nozzle, WALL_END_CLEARANCE_SIGMAS * sigma)
    if keep.all():
        return sigma
    return esf_sigma_px(transmission, nozzle.rows[keep], nozzle.left_px[keep], nozzle.right_px[keep], *args)


#: How far (in blur sigmas) a wall row used for the blur lies from the walls' ends: a perpendicular
#: edge that far away adds ``erfc(3 / sqrt(2)) / 2``, 0.1 % of the contrast, to the row's profile.
WALL_END_CLEARANCE_SIGMAS = 3.0


def wall_rows_clear_of_ends(nozzle: Nozzle, clearance_px: float) -> np.ndarray:
    """Which of ``nozzle.rows`` lie at least ``clearance_px`` from both ends of the straight walls:
    the face above them (half a row above ``nozzle.straight_start_row``; none where the walls reach
    the frame's top edge) and the tip below (half a row below ``nozzle.straight_end_row``).  Where
    no row does, the rows farthest from the nearer end.

    Returns
    -------
    ndarray of bool
        Per row of ``nozzle.rows``.
    """
    rows = np.asarray(nozzle.rows, float)
    if rows.size == 0:
        return np.zeros(0, bool)
    top = rows - (nozzle.straight_start_row - 0.5) if nozzle.straight_start_row > 0 else np.full(rows.size, np.inf)
    room = np.minimum(top, nozzle.straight_end_row + 0.5 - rows)
    keep = room >= clearance_px
    return keep if keep.any() else room >= room.max()


def esf_sigma_px(transmission: np.ndarray, rows, left_px, right_px, interior_level: float,
                 half_window_px: int = 8, clip_transmission: float = float("inf")) -> float:
    """Gaussian sigma (px) of an edge-spread function pooled from the rows of a body's outline.

    Each row's samples within ``half_window_px`` of its sub-pixel left and right edges are
    placed at their distance from the edge along its normal (the horizontal distance times the
    cosine of the outline's slope there; rows where the outline is flatter than 45 degrees are
    left out), scaled from ``interior_level`` (0) to the background (1), and fitted with
    ``(1 + erf(u / (sqrt(2) sigma))) / 2`` plus a shift (Gauss-Newton).  Straight walls
    (`edge_sigma_px`) have slope 0.

    Parameters
    ----------
    transmission : ndarray
        Frame over the background model.
    rows, left_px, right_px : array_like
        Row and sub-pixel edges of the outline (one entry per row).
    interior_level : float
        Transmission inside the body.
    half_window_px : int
        Samples taken either side of each edge (px).
    clip_transmission : float
        Samples at or above it (a clipped background) are left out.

    Returns
    -------
    float
        NaN without usable rows.
    """
    t = np.asarray(transmission, np.float64)
    h, w = t.shape
    lo = interior_level
    rows = np.asarray(rows, int)
    us, vs = [], []
    for edges, sign in ((np.asarray(left_px, float), -1.0), (np.asarray(right_px, float), 1.0)):
        slope = np.gradient(edges, rows) if rows.size >= 2 else np.zeros(rows.size)
        for y, xe, s in zip(rows, edges, slope):
            if not np.isfinite(xe) or abs(s) > 1.0:
                continue
            c = int(round(xe))
            c0, c1 = c - half_window_px, c + half_window_px + 1
            if c0 < 0 or c1 > w or not 0 <= y < h:
                continue
            x = np.arange(c0, c1)
            keep = t[y, c0:c1] < clip_transmission
            us.append(sign * (x[keep] - xe) / np.hypot(1.0, s))
            vs.append((t[y, c0:c1][keep] - lo) / (1.0 - lo))
    if not us:
        return float("nan")
    u = np.concatenate(us)
    v = np.concatenate(vs)

    sig, shift = 1.0, 0.0
    for _ in range(30):  # Gauss-Newton on (sigma, shift)
        z = (u - shift) / (np.sqrt(2.0) * sig)
        r = 0.5 * (1.0 + erf(z)) - v
        g = np.exp(-z * z) / np.sqrt(np.pi)  # d/dz of the model
        j = np.column_stack([g * (-z / sig), g * (-1.0 / (np.sqrt(2.0) * sig))])
        step, *_ = np.linalg.lstsq(j, -r, rcond=None)
        sig = float(np.clip(sig + step[0], 0.05, 20.0))
        shift = float(shift + step[1])
        if abs(step[0]) < 1e-6:
            break
    return sig
