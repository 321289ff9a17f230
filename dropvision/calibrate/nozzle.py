"""The nozzle in the first frame: its outer walls (axis, tilt, outer width) and its tip plane.

- `find_nozzle`: the dark body touching the top edge (canonical orientation); its straight
  part is a run of rows of constant width of the dark run holding the nozzle (followed up from
  the body's lowest row): the one of the expected outer width when the metadata gives it, else
  the narrowest (a holder block above it is wider; `_straight_walls`); the outer walls'
  sub-pixel edges over those rows give the midline (axis column, tilt) and the outer width
  (cross-check of the pixel size, `outer_diameter_uncertainty_px`).  Walls shorter than 10 rows
  (a nozzle barely protruding from its holder) take the tilt from the holder's face instead,
  and with no straight walls at all the part of the body below the face is the nozzle
  (`_face_nozzle`: the axis is perpendicular to the face).
- `find_tip`: in a frame with the meniscus at rest, the vertical transmission profiles of the
  wall annulus columns (between the inner and outer radius) cross the edge level at the tip;
  when liquid hangs below the walls (annulus dark below the straight part) the tip is the row
  where the silhouette leaves the straight walls.
"""

from __future__ import annotations

import bisect
import functools
import math
from dataclasses import dataclass

import cv2
import numpy as np

from dropvision.calibrate.background import CalibrationError, NoNozzleError
from dropvision.frame.edges import DEFAULT_EDGE_THRESHOLD, first_rising_crossing, runs, subpixel_edges
from dropvision.frame.segmentation import fill_holes


@dataclass
class Nozzle:
    """Outer walls of the nozzle (full-frame coordinates).

    Attributes
    ----------
    rows : ndarray
        Rows of the straight part used for the fit.
    left_px, right_px : ndarray
        Sub-pixel outer wall edges on those rows.
    axis_a, axis_b : float
        Midline ``col = axis_a + axis_b * row``.
    outer_width_px : float
        Mean horizontal outer width (multiply by cos(tilt) for the diameter).
    straight_end_row : int
        Last row of the straight part.
    straight_start_row : int
        First row of the straight part (0: the walls reach the frame's top edge; more where a
        holder's face or a wider body lies above them).
    interior_level : float
        Median transmission inside the nozzle.
    """

    rows: np.ndarray
    left_px: np.ndarray
    right_px: np.ndarray
    axis_a: float
    axis_b: float
    outer_width_px: float
    straight_end_row: int
    interior_level: float
    #: Sub-pixel outer edges of every row of the top body (walls and the liquid hanging below).
    outline_rows: np.ndarray | None = None
    outline_left: np.ndarray | None = None
    outline_right: np.ndarray | None = None
    straight_start_row: int = 0

    @property
    def tilt_rad(self) -> float:
        return float(np.arctan(self.axis_b))

    @property
    def outer_diameter_px(self) -> float:
        return self.outer_width_px * float(np.cos(self.tilt_rad))

    def axis_col(self, row: float) -> float:
        return self.axis_a + self.axis_b * row


def components_with_stats(mask: np.ndarray):
    """``cv2.connectedComponentsWithStats(mask, connectivity=8)``, by the block-based algorithm (BBDT):
    the same labels and statistics (checked on real frames and random masks), some 3 times faster on a
    2048 x 1536 frame than the default one (whose statistics pass costs most of its time)."""
    return cv2.connectedComponentsWithStatsWithAlgorithm(mask, 8, cv2.CV_32S, cv2.CCL_BBDT)


def largest_top_body(mask: np.ndarray, col: int | None = None) -> tuple[np.ndarray, int] | None:
    """The largest 8-connected body of ``mask`` (uint8, 0 / 1) touching the top row (the first in
    `components_with_stats`' label order on a tie), holding column ``col`` within its bounding box
    where given: (its rows down to its lowest, 255 where it is, holes filled; that row count) or None.

    The bodies touching the top row are flood-filled from it (a cost of their own area, not the whole
    frame's), the same pixels and areas as `components_with_stats` gives; where two such bodies tie for
    the largest, or there are more than 250 of them, by `components_with_stats` itself (its label order).
    ``mask`` is not changed."""
    filled = top_bodies(mask)
    if filled is None:
        return _largest_top_body_ccl(mask, col)
    img, bodies = filled
    if col is not None:
        bodies = [b for b in bodies if b[2] <= col < b[2] + b[3]]
    if not bodies:
        return None
    best = max(b[0] for b in bodies)
    top = [b for b in bodies if b[0] == best]
    if len(top) > 1:  # a tie: the first in the label order decides
        return _largest_top_body_ccl(mask, col)
    _, value, _, _, height = top[0]
    return fill_holes(cv2.compare(img[:height], value, cv2.CMP_EQ)), int(height)


def top_bodies(mask: np.ndarray) -> tuple[np.ndarray, list[tuple[int, int, int, int, int]]] | None:
    """The 8-connected bodies of ``mask`` (uint8, 0 / 1) touching the top row, flood-filled from it:
    (a copy of ``mask`` with each such body's pixels set to its own value 2, 3, ..., and per body
    (pixel count, value, left column, width, height from the top row), in the order of their leftmost
    top-row pixel), or None with more than 250 of them (label them all instead)."""
    row0 = np.flatnonzero(np.diff(np.r_[0, mask[0] != 0].astype(np.int8)) > 0)  # the top row's dark runs' starts
    if row0.size > 250:
        return None
    img = mask.copy()
    bodies = []
    for x in row0:
        if img[0, x] != 1:
            continue  # filled from a run to its left (the same body)
        value = 2 + len(bodies)
        area, _, _, (left, _, width, height) = cv2.floodFill(img, None, (int(x), 0), value, 0, 0, 8)
        bodies.append((int(area), value, int(left), int(width), int(height)))
    return img, bodies


def _largest_top_body_ccl(mask: np.ndarray, col: int | None) -> tuple[np.ndarray, int] | None:
    """`largest_top_body` by `components_with_stats` (every body labelled)."""
    n, lab, stats, _ = components_with_stats(mask)
    top = [k for k in range(1, n) if stats[k, cv2.CC_STAT_TOP] == 0
           and (col is None or stats[k, cv2.CC_STAT_LEFT] <= col < stats[k, cv2.CC_STAT_LEFT] + stats[k, cv2.CC_STAT_WIDTH])]
    if not top:
        return None
    k = max(top, key=lambda k: stats[k, cv2.CC_STAT_AREA])
    height = int(stats[k, cv2.CC_STAT_TOP] + stats[k, cv2.CC_STAT_HEIGHT])
    return fill_holes(cv2.compare(lab[:height], int(k), cv2.CMP_EQ)), height


def _sorted_median(values: list[float]) -> float:
    """``np.median`` of a sorted list of finite floats (the middle one, or the mean of the middle two)."""
    m = len(values)
    return values[m // 2] if m % 2 else (values[m // 2 - 1] + values[m // 2]) / 2.0


def _straight_walls(width: np.ndarray, cand: np.ndarray, expected_px: float | None = None) -> tuple[int, int]:
    """(start, stop) of the nozzle's straight part: a run of rows of constant width.

    Runs of consecutive candidate rows whose widths (5-row running median) stay within 1.5 px of
    the run's median are the straight parts of the top body (a holder block above the nozzle, the nozzle, a needle).
    With the nozzle's expected outer width (px), the longest run within a factor 1.5 of it is the
    nozzle; none: (0, 0).  Without it, runs of at least 6 rows are preferred to shorter ones (at
    least 3) and the narrowest is the nozzle (a holder is wider; the liquid hanging below is not
    of constant width), the longest on a tie.
    """
    # a 5-row running median: edge noise (low contrast) must not break a straight wall
    width = np.asarray(width, float)
    if width.size >= 5:
        pad = np.pad(width, 2, mode="edge")
        width = np.median(np.lib.stride_tricks.sliding_window_view(pad, 5), axis=1)
    runs_ = []
    i, n = 0, width.size
    values = width.tolist()
    while i < n:
        if not cand[i]:
            i += 1
            continue
        j = i + 1
        grown = [values[i]]  # width[i:j] sorted: its median as np.median gives it (the middle one, or the
        while j < n and cand[j] and abs(width[j] - _sorted_median(grown)) <= 1.5:  # mean of the middle two)
            bisect.insort(grown, values[j])
            j += 1
        if width[i] >= 4 and j - i >= 3:
            runs_.append((i, j))
        i = j
    if not runs_:
        return (0, 0)
    med = {r: float(np.median(width[r[0]:r[1]])) for r in runs_}
    if expected_px:
        near = [r for r in runs_ if 1 / 1.5 < med[r] / expected_px < 1.5]
        return max(near, key=lambda r: r[1] - r[0]) if near else (0, 0)
    if any(r[1] - r[0] >= 6 for r in runs_):
        runs_ = [r for r in runs_ if r[1] - r[0] >= 6]
    return min(runs_, key=lambda r: (med[r], -(r[1] - r[0])))


@functools.lru_cache(maxsize=64)
def _ransac_draws(n: int) -> np.ndarray:
    """`_straight_stretch`'s 300 pairs of indices into ``n`` points: seeded draws, the same every time
    (drawn once per ``n``: a face is fitted several times in a calibration), in order; read only."""
    rng = np.random.default_rng(0)
    out = np.array([rng.choice(n, 2, replace=False) for _ in range(300)], dtype=np.intp).reshape(-1, 2)
    out.flags.writeable = False
    return out


def _straight_stretch(x: np.ndarray, y: np.ndarray, band_px: float, min_points: int = 10) -> np.ndarray | None:
    """The points of the longest straight stretch of ``y(x)``: RANSAC over 300 pairs of points
    (seeded: the same answer every time), inliers within ``band_px`` of the line through the pair.
    A boolean mask, or None when no line holds ``min_points``."""
    pairs = _ransac_draws(int(x.size))
    pairs = pairs[x[pairs[:, 0]] != x[pairs[:, 1]]]
    if not len(pairs):
        return None
    best, best_count = None, -1
    for a in range(0, len(pairs), 50):  # 50 lines at once (the same arithmetic, element by element)
        i, j = pairs[a:a + 50, 0], pairs[a:a + 50, 1]
        slope = (y[j] - y[i]) / (x[j] - x[i])
        inl = np.abs(y[None, :] - (y[i][:, None] + slope[:, None] * (x[None, :] - x[i][:, None]))) <= band_px
        counts = inl.sum(axis=1)
        k = int(np.argmax(counts))  # the first of the most inliers, as one line after the other
        if counts[k] > best_count:
            best, best_count = inl[k], int(counts[k])
    return None if best is None or best_count < min_points else best


def _face_nozzle(t: np.ndarray, body: np.ndarray, threshold: float) -> tuple[int, int, float] | None:
    """A nozzle barely protruding from a holder block or plate: (first row, stop row, axis slope).

    The lowest dark row of the top body in each column is its bottom profile; its longest
    straight stretch (RANSAC) is the holder's face, and the columns reaching more than 1.5 px below the face
    (the group nearest the middle of the face) are the nozzle (and its meniscus).  Returns the rows
    from the face down to the bottom of that group and the axis slope (col per row,
    perpendicular to the face), or None when nothing protrudes.
    """
    cols, bottom = bottom_profile(body)  # the lowest dark row of each column
    if cols.size < 20:
        return None
    # the face is the longest straight stretch of the bottom profile (a wedge or a rounded corner
    # beside it is not): RANSAC over pairs of columns, inliers within 1 px, refitted
    x = cols.astype(float)
    best = _straight_stretch(x, bottom, 1.0)
    if best is None:
        return None
    q = np.polyfit(x[best], bottom[best], 1)
    res = bottom - np.polyval(q, x)
    below = res >= 1.5
    if not below.any():
        return None
    # groups of adjacent protruding columns; the nozzle is the one nearest the middle of the face
    # (a wedge or corner protrudes at its ends)
    edges_ = np.flatnonzero(np.diff(np.r_[0, below.astype(int), 0]))
    groups = list(zip(edges_[::2], edges_[1::2] - 1))
    face_mid = 0.5 * (x[best].min() + x[best].max())
    lo, hi = min(groups, key=lambda g: abs(0.5 * (x[g[0]] + x[g[1]]) - face_mid))
    face_row = float(max(np.polyval(q, cols[lo]), np.polyval(q, cols[hi])))  # the face's lower end over the nozzle
    r0 = int(np.ceil(face_row + 1.0))
    r1 = int(bottom[lo:hi + 1].max()) + 1
    if r1 - r0 < 4:  # fewer rows give no usable wall lines
        return None
    return r0, r1, float(-q[0])


def _axis_runs(rr: np.ndarray, s: np.ndarray, e: np.ndarray, y1: int) -> tuple[np.ndarray, np.ndarray]:
    """Per row, the dark run holding the nozzle: followed from the lowest row upwards.

    In the lowest row with a run at least 3 px wide the widest run is taken; in each row above,
    the run overlapping (8-connected) the one below it most. Rows above the first row without
    such a run get -1.
    """
    start = np.full(y1, -1)
    stop = np.full(y1, -1)
    order = np.argsort(rr, kind="stable")
    rr, s, e = rr[order], s[order], e[order]
    bounds = np.searchsorted(rr, np.arange(y1 + 1))
    prev = None
    for r in range(y1 - 1, -1, -1):
        i0, i1 = bounds[r], bounds[r + 1]
        if i0 == i1:
            if prev is None:
                continue
            break
        if prev is None:
            k = i0 + int(np.argmax(e[i0:i1] - s[i0:i1]))
            if e[k] - s[k] < 3:  # a noise pixel hanging below the body
                continue
        else:  # 8-connected: a run touching the one below diagonally still continues it
            overlap = np.minimum(e[i0:i1], prev[1] + 1) - np.maximum(s[i0:i1], prev[0] - 1)
            if overlap.max() <= 0:
                break
            k = i0 + int(np.argmax(overlap))
        start[r], stop[r] = s[k], e[k]
        prev = (s[k], e[k])
    return start, stop


def find_nozzle(transmission: np.ndarray, threshold: float = DEFAULT_EDGE_THRESHOLD,
                expected_width_px: float | None = None) -> Nozzle:
    """Locate the nozzle (dark body at the top edge) and fit its outer walls.

    Parameters
    ----------
    transmission : ndarray of float
        Background-normalised frame (canonical orientation).
    threshold : float
        Edge level (50 % between background and the nozzle's interior).
    expected_width_px : float, optional
        The nozzle's outer diameter in pixels when the metadata gives it: picks the nozzle among
        the straight parts of the top body (a holder block is wider).
    """
    t = np.asarray(transmission, np.float32)
    h, w = t.shape
    mask = (t < threshold).astype(np.uint8)
    top = largest_top_body(mask)
    if top is None:
        raise NoNozzleError("no nozzle: no dark body touches the top edge of the frame")
    body, y1 = top[0] > 0, top[1]  # the body's rows 0 .. y1 - 1 (its lowest row y1 - 1)
    rr, s, e = runs(body[:y1])
    # outer silhouette per row: first start .. last stop
    first = np.full(y1, -1)
    last = np.full(y1, -1)
    np.maximum.at(last, rr, e)
    first_vals = np.full(y1, w + 1)
    np.minimum.at(first_vals, rr, s)
    first = np.where(first_vals <= w, first_vals, -1)
    # the run holding the nozzle in each row, followed up from the body's lowest row (a holder
    # block beside the nozzle is another run, or makes this one much wider)
    a_start, a_stop = _axis_runs(rr, s, e, y1)
    width = np.where(a_start >= 0, a_stop - a_start, 0)
    cand = (width > 2) & (width < 0.9 * w) & (a_start > 0) & (a_stop < w)
    if cand.sum() < 3:
        raise NoNozzleError(f"no nozzle: the dark body at the top edge (rows 0-{y1 - 1}, up to "
                               f"{int(np.max(last - np.maximum(first, 0)))} px wide) has no straight walls")
    a, b = _straight_walls(width, cand, expected_width_px)
    face_slope = None
    if b - a < 3:  # no walls of the expected width: a nozzle barely protruding from a holder or plate
        face = _face_nozzle(t, body[:y1], threshold)
        if face is None:
            raise NoNozzleError(
                f"no nozzle: the dark body at the top edge (rows 0-{y1 - 1}, up to {int(width.max())} px wide) "
                "has fewer than 3 rows of constant width"
                + (f" near the expected {expected_width_px:.0f} px" if expected_width_px else "")
                + " and nothing protrudes below its lower face; give nozzle_tip_row and axis_col in sequence.json")
        a, b, face_slope = face
    # sub-pixel edges of the outer walls, away from the tip (blur) and from a holder's face
    if b - a >= 12:
        rows = np.arange(a + 2 if a > 0 else a, b - 4)  # 2 rows off a holder's face above the walls
    else:
        rows = np.arange(a, max(a + 1, b - 1) if face_slope is not None else max(a + 3, b - 2))
    ones = np.broadcast_to(np.float32(1.0), t.shape)  # no background here (t is one): read, never written
    edges = subpixel_edges(t, ones, rows, a_start[rows], a_stop[rows], threshold)
    left, right = edges.left_px, edges.right_px
    mid = 0.5 * (left + right)
    coef = np.polyfit(rows.astype(float), mid, 1) if rows.size >= 2 else np.array([0.0, mid[0]])
    if face_slope is None and rows.size < 10:  # walls too short for their midline's slope
        face_slope = _face_nozzle(t, body[:y1], threshold)
        face_slope = None if face_slope is None else face_slope[2]
    if face_slope is not None and rows.size < 10:  # the axis is perpendicular to the holder's face
        coef = np.array([face_slope, float(np.mean(mid) - face_slope * np.mean(rows))])
    inner = cv2.erode(body[: b].astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    vals_in = t[: b][inner & (t[: b] < threshold)]
    level = float(np.median(vals_in)) if vals_in.size else 0.0
    orows = np.nonzero((first > 0) & (last < w) & (last > first))[0]
    outline = subpixel_edges(t, ones, orows, first[orows], last[orows], threshold)
    return Nozzle(rows, left, right, float(coef[1]), float(coef[0]), float(np.mean(right - left)), int(b - 1), level,
                  orows, outline.left_px, outline.right_px, straight_start_row=int(a))


def find_tip(
    transmission: np.ndarray,
    nozzle: Nozzle,
    threshold: float,
    inner_radius_px: float | None = None,
) -> tuple[float, str, int]:
    """Sub-pixel row of the nozzle tip plane at the axis, how it was found, and of how many crossings.

    Parameters
    ----------
    transmission : ndarray
        A frame with the meniscus at rest (normalised).
    nozzle : Nozzle
    threshold : float
        50 % level between background and the nozzle's interior.
    inner_radius_px : float, optional
        Nozzle inner radius (pixels), to place the annulus columns on the wall.

    Returns
    -------
    tip_row : float
    source : str
        ``"wall annulus 50 % crossing"`` or ``"silhouette leaves the straight walls"``.
    crossings : int
        With the wall annulus: twice the fewer columns of a side whose crossings the side's
        median is taken over (the plane is the mean of the two medians: of independent edge
        errors it keeps ``sqrt(pi / 2 / crossings)`` of one edge's); 0 otherwise.
    """
    t = np.asarray(transmission, np.float32)
    h, w = t.shape
    r_out = 0.5 * nozzle.outer_diameter_px
    tan = nozzle.axis_b
    end = nozzle.straight_end_row
    lo = r_out * 0.6 if inner_radius_px is None else inner_radius_px + 1.5
    hi = r_out - 2.5
    tips, counts = {}, {}
    if hi > lo:
        offsets = np.linspace(lo, hi, max(2, int(hi - lo) + 1))
        for side in (-1, 1):
            vals = []
            for d in offsets:
                col = nozzle.axis_col(end) + side * d
                c = int(round(col))
                if not 0 <= c < w:
                    continue
                y = first_rising_crossing(t[:, c], max(0, end - 12), min(h, end + 12), threshold)
                if np.isfinite(y):
                    vals.append(y + (c - nozzle.axis_col(y)) * tan)
            if len(vals) >= 2:
                tips[side] = float(np.median(vals))
                counts[side] = len(vals)
    if len(tips) == 2 and abs(tips[-1] - tips[1]) < 1.0 and abs(0.5 * (tips[-1] + tips[1]) - end) < 4:
        return 0.5 * (tips[-1] + tips[1]), "wall annulus 50 % crossing", 2 * min(counts.values())
    # silhouette departure from the straight wall lines: the deviation of the outer edges from
    # the fitted wall lines, extrapolated linearly back to zero from its first rows above 0.3 px
    rows = np.arange(end + 1, min(h, end + 60))
    mask = (t < threshold)
    fl = np.polyfit(nozzle.rows.astype(float), nozzle.left_px, 1)
    fr = np.polyfit(nozzle.rows.astype(float), nozzle.right_px, 1)
    ys, devs = [], []
    for y in rows:
        cl = np.polyval(fl, y)
        cr = np.polyval(fr, y)
        row = mask[y]
        c0 = int(max(0, np.floor(cl - r_out)))
        c1 = int(min(w, np.ceil(cr + r_out)))
        if not np.any(row[c0:c1]):
            return float(y - 0.5), "silhouette leaves the straight walls (ends)", 0
        rr, s, e = runs(row[None, c0:c1])
        ed = subpixel_edges(t[y:y + 1, c0:c1], np.ones((1, c1 - c0), np.float32), np.zeros_like(s), s, e, threshold)
        dev = max(abs(ed.left_px.min() + c0 - cl), abs(ed.right_px.max() + c0 - cr))
        ys.append(y)
        devs.append(dev)
        if dev > 3.0:
            break
    ys = np.array(ys, float)
    devs = np.array(devs, float)
    sel = devs > 0.3
    if sel.sum() >= 2:
        k = np.nonzero(sel)[0]
        k = k[: max(2, min(len(k), 4))]
        slope, icpt = np.polyfit(ys[k], devs[k], 1)
        if slope > 0:
            y0 = -icpt / slope
            return float(np.clip(y0, end - 1.0, ys[k[0]])), "silhouette leaves the straight walls", 0
    if sel.any():
        return float(ys[np.argmax(sel)] - 0.5), "silhouette leaves the straight walls", 0
    return float(end + 0.5), "end of the straight walls", 0


def outer_diameter_uncertainty_px(nozzle: Nozzle, edge_position_floor_px: float) -> float:
    """Standard uncertainty (px) of the nozzle's measured outer diameter.

    Two parts in quadrature: the statistical error of the mean width (standard deviation of
    the per-row widths over the straight rows / sqrt(rows)), and a systematic floor of
    ``edge_position_floor_px`` on each of the two walls (threshold and blur model bias, which
    does not average out over rows).

    Parameters
    ----------
    nozzle : Nozzle
        Fitted outer walls.
    edge_position_floor_px : float
        Systematic uncertainty of one edge (px).

    Returns
    -------
    float
        Uncertainty of ``nozzle.outer_diameter_px`` (px).
    """
    w = np.asarray(nozzle.right_px, float) - np.asarray(nozzle.left_px, float)
    w = w[np.isfinite(w)]
    stat = float(np.std(w, ddof=1) / np.sqrt(w.size)) if w.size >= 2 else float("nan")
    return float(np.hypot(stat, np.sqrt(2.0) * edge_position_floor_px) * np.cos(nozzle.tilt_rad))


def needle_width_terms_px(nozzle: Nozzle, edge_position_px: float, sigma_px: float) -> dict[str, float]:
    """The parts (px, standard uncertainties) of the needle's outer width when the pixel size comes from it.

    The width is the mean distance between the straight outer walls' 50 % edges (`find_nozzle`); a
    symmetric blur moves both edges by nothing, a meniscus is below the rows used.  What is left:

    - ``rows``: the per-row widths' scatter over the square root of the independent rows they hold
      (neighbouring rows share the blur: one independent row per ``max(1, 2 sigma)`` rows);
    - ``taper``: the walls' width changes along the rows used (a tapered needle, perspective): the
      width's trend over them, taken as uniform over its span (over sqrt(12));
    - ``edges``: an edge-position error common to the frame (``edge_position_px``: threshold, background
      level, a clipped background) moves both walls outward or inward together: twice it.

    Parameters
    ----------
    nozzle : Nozzle
        Fitted outer walls.
    edge_position_px : float
        Standard uncertainty of an edge position common to the frame (px).
    sigma_px : float
        Edge blur (Gaussian sigma, px; NaN: 1 px).

    Returns
    -------
    dict
        ``rows``, ``taper``, ``edges`` (px, of the diameter: the tilt's cosine applied).
    """
    w = np.asarray(nozzle.right_px, float) - np.asarray(nozzle.left_px, float)
    rows = np.asarray(nozzle.rows, float)
    ok = np.isfinite(w)
    w, rows = w[ok], rows[ok]
    sig = float(sigma_px) if np.isfinite(sigma_px) else 1.0
    cos = float(np.cos(nozzle.tilt_rad))
    if w.size >= 3:
        slope, icpt = np.polyfit(rows, w, 1)
        resid = w - (icpt + slope * rows)
        n_eff = max(1.0, w.size / max(1.0, 2.0 * sig))
        stat = float(np.std(resid, ddof=2) / np.sqrt(n_eff))
        taper = float(abs(slope) * (rows.max() - rows.min()) / np.sqrt(12.0))
    else:
        stat, taper = float(np.std(w)) if w.size else float("nan"), 0.0
    return {"rows": stat * cos, "taper": taper * cos, "edges": 2.0 * float(edge_position_px) * cos}


# ----------------------------------------------------------------------------- an out-of-focus holder's face
#: A column of the top body reaching this far (px) below the face line protrudes from it (the same
#: margin as `_face_nozzle`'s: a 50 % line of a straight face scatters by less).
FACE_PROTRUSION_PX = 1.5
SQRT_2PI = math.sqrt(2.0 * math.pi)


def bottom_profile(body: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(columns, lowest row) of a boolean body mask: its lower outline, one row per column it holds."""
    body = np.asarray(body, bool)
    cols = np.nonzero(body.any(axis=0))[0]
    h = body.shape[0]
    bottom = h - 1 - np.argmax(body[::-1, cols], axis=0)
    return cols, bottom.astype(float)


def fit_face_line(cols: np.ndarray, bottom: np.ndarray, band_px: float = 2.0) -> tuple[float, float] | None:
    """The face of a holder block or nozzle plate: the straight line its lower outline follows.

    A face is flat: its 50 % line is the longest straight stretch of the bottom profile (RANSAC
    over pairs of columns, inliers within ``band_px``, refitted by least squares); liquid hanging
    from it, a chamfer or a rounded corner at its ends are outliers.  The columns within 10 px
    of the body's ends (its rounded corners) are not used.

    Returns
    -------
    (a, b) or None
        ``row = a + b * col``; None with fewer than 20 columns or no line holding 10 of them.
    """
    cols = np.asarray(cols, float)
    bottom = np.asarray(bottom, float)
    keep = (cols > cols.min() + 10) & (cols < cols.max() - 10) if cols.size else np.zeros(0, bool)
    x, y = cols[keep], bottom[keep]
    if x.size < 20:
        return None
    best = _straight_stretch(x, y, band_px)
    if best is None:
        return None
    b, a = np.polyfit(x[best], y[best], 1)
    return float(a), float(b)


@dataclass(frozen=True)
class Protrusion:
    """What reaches below an out-of-focus face at the jet's axis (`protruding_columns`).

    ``first``, ``last``: its columns (inclusive); ``liquid``: dark and in focus (what hangs from the
    orifice), else the face's own blurred halo (a ragged 50 % line, a capillary's blurred face);
    ``reason`` says which test it failed.
    """

    first: int
    last: int
    liquid: bool
    reason: str = ""


def protruding_columns(body: np.ndarray, transmission: np.ndarray, face_rows: np.ndarray, axis_col: float,
                       dark_limit: float, focus_limit_px: float, margin_px: float = FACE_PROTRUSION_PX, *,
                       judge_focus: bool = True) -> Protrusion | None:
    """What reaches below an out-of-focus face at the jet's axis, and whether it is liquid.

    The columns of the body whose lowest row lies more than ``margin_px`` below the face line
    form groups; the group holding the jet's axis column is what may hang from the orifice.  It
    is liquid when it looks like liquid in the jet's plane (a person's two looks):

    - dark: its darkest pixels below the face (2nd percentile) at most ``dark_limit`` (the halo
      of a blurred holder beyond its own ragged 50 % line is grey);
    - in focus: the lower edge of its deeper half (columns reaching at least half its depth
      below the face) as sharp as the drops': per column, the step from its darkest pixel below
      the face to the transmission 3 blur widths below its edge, over ``sqrt(2 pi)`` x the
      gradient at the edge (the edge spread of `dropvision.frame.body_classes.appearance`, with the local
      step: liquid inside a halo has less contrast), median over the columns, at most
      ``focus_limit_px`` (the mist limit).

    Parameters
    ----------
    body : ndarray of bool
        The top body (region rows from 0, its columns).
    transmission : ndarray
        The same pixels over the background, with at least ``3 * focus_limit_px + 2`` rows below the body.
    face_rows : ndarray of float
        The face line's row at every column.
    axis_col : float
        The jet's axis column (same columns).
    dark_limit : float
        Transmission liquid is darker than (half-way between the edge level and the liquid's).
    focus_limit_px : float
        Largest edge spread of a body in focus (px).
    margin_px : float
        Protrusion below the face line from which a column counts.
    judge_focus : bool
        False where liquid was already seen hanging there in focus (another frame of the
        sequence): a dark protrusion is then its meniscus, however small (a bump of a few px
        inside the halo has no edge of its own to judge).

    Returns
    -------
    Protrusion or None (nothing reaches below the face at the axis).
    """
    cols, bottom = bottom_profile(body)
    c = int(round(axis_col))
    if cols.size == 0 or not 0 <= c < body.shape[1]:
        return None
    depth = np.full(body.shape[1], -np.inf)
    depth[cols] = bottom - face_rows[cols]
    prot = depth > margin_px
    if not prot[c]:
        return None
    lo, hi = c, c
    while lo > 0 and prot[lo - 1]:
        lo -= 1
    while hi < prot.size - 1 and prot[hi + 1]:
        hi += 1
    t = np.asarray(transmission, np.float32)
    rows = np.arange(body.shape[0])[:, None]
    below = body[:, lo:hi + 1] & (rows > face_rows[None, lo:hi + 1])
    vals = t[:body.shape[0], lo:hi + 1][below]
    p2 = float(np.percentile(vals, 2)) if vals.size else 1.0
    if p2 > dark_limit:
        return Protrusion(lo, hi, False, f"not dark: transmission {p2:.2f} > {dark_limit:.2f} below the face")
    if not judge_focus:
        return Protrusion(lo, hi, True)
    span = np.arange(lo, hi + 1)
    core = span[depth[span] >= 0.5 * depth[span].max()]
    off = int(math.ceil(3.0 * focus_limit_px))
    spreads = []
    bottom_of = np.full(body.shape[1], -1)
    bottom_of[cols] = bottom.astype(int)
    for j in core:
        b = bottom_of[j]
        f = int(math.ceil(face_rows[j]))
        if b + off >= t.shape[0] or b < 1:
            continue
        g = 0.5 * float(t[b + 1, j] - t[b - 1, j])
        step = float(t[b + off, j] - t[f:b + 1, j].min())
        spreads.append(step / (SQRT_2PI * g) if g > 0 else np.inf)
    spread = float(np.median(spreads)) if spreads else np.inf
    if spread > focus_limit_px:
        return Protrusion(lo, hi, False, f"out of focus: edge spread {spread:.2f} px > {focus_limit_px:.2f} px")
    return Protrusion(lo, hi, True)
