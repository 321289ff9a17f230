"""The edge: its threshold level, the sub-pixel crossing of it, and the edges of dark runs.

Every edge in a backlit frame is placed at one level: half-way between the background
(transmission 1) and the interior level of the dark body it bounds (`edge_threshold`).  Before
that interior level is measured (the first look at a frame during calibration), the level is
`first_pass_threshold` of the frame's darkest body.  Between a dark sample and its bright
neighbour the edge lies where the straight line between them crosses the threshold
(`crossing_fraction`); this one primitive places the run edges of every body
(`subpixel_edges`, `body_edges`), the nozzle tip along a column (`first_rising_crossing`) and
the ends of a pinch-off thread (`dropvision.analysis.pinchoff`).

Coordinates: pixel centres are integers; a row ``i`` covers ``[i - 0.5, i + 0.5)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from dvcore.robust import NOISE_LAG_PX, pair_noise_sigma

#: Edge level used when nothing is known of the interior (an opaque interior, level 0).
DEFAULT_EDGE_THRESHOLD = 0.5


def edge_threshold(interior_level: float) -> float:
    """Edge (50 %) transmission level half-way between the background (1) and a dark interior.

    Parameters
    ----------
    interior_level : float
        Transmission (background = 1) inside the liquid or the nozzle.

    Returns
    -------
    float
        ``(1 + interior_level) / 2``, in transmission units.
    """
    return 0.5 * (1.0 + interior_level)


def edge_shift_px(transmission_error: float, blur_sigma_px: float, liquid_level: float) -> float:
    """How far (px) an error in transmission moves an edge's 50 % crossing: over the edge's slope
    ``(1 - T_liquid) / (sqrt(2 pi) sigma)``, i.e. ``error * sqrt(2 pi) * sigma / depth``.

    The one rule of the slope (the background's misfit, a clipped level, the frame's noise and a
    body's backlight under a clip all move an edge so).  ``blur_sigma_px`` is taken as at least
    0.5 px (the pixel box; 1 px when unknown), the liquid's depth ``1 - liquid_level`` as at
    least 0.05.
    """
    sig = max(float(blur_sigma_px), 0.5) if np.isfinite(blur_sigma_px) else 1.0
    depth = max(1.0 - float(liquid_level), 0.05)
    return float(transmission_error * _SQRT_2PI * sig / depth)


_SQRT_2PI = math.sqrt(2.0 * math.pi)


def first_pass_threshold(darkest_transmission: float) -> float:
    """Edge level for a first look at a frame whose interior level is not measured yet.

    Half-way to the darkest body (`edge_threshold` of it) in a low-contrast frame, whose darkest
    body lies between 30 and 80 % transmission (liquid and nozzle half transparent: 50 % might
    miss them); `DEFAULT_EDGE_THRESHOLD` otherwise.

    Parameters
    ----------
    darkest_transmission : float
        Darkest transmission of the frame's bodies (`dropvision.calibrate.background.darkest_level`).

    Returns
    -------
    float
        Edge level (transmission).
    """
    if 0.3 < darkest_transmission < 0.8:
        return edge_threshold(darkest_transmission)
    return DEFAULT_EDGE_THRESHOLD


def crossing_fraction(t_dark, t_bright, threshold: float, from_bright: bool = False):
    """Where the straight line from a dark sample to its bright neighbour crosses ``threshold``.

    Parameters
    ----------
    t_dark, t_bright : float or ndarray
        Transmission of the dark sample and of its neighbour one pixel away.
    threshold : float
        Edge level (transmission, `edge_threshold`).
    from_bright : bool
        Measure the distance from the bright sample instead of the dark one.  It is computed
        directly, ``(t_bright - threshold) / (t_bright - t_dark)``, not as one minus the other
        (which would differ in the last bits of the samples' float32).

    Returns
    -------
    float or ndarray
        Distance from the dark (or bright) sample towards the other one, clipped to 0..1 px
        (float for scalars, the samples' dtype for arrays).  A flat pair has no crossing: the
        edge is put at the dark sample when both lie above the level (it is not dark), at the
        bright one when both lie below, half-way when both lie on it.
    """
    t_dark, t_bright = np.asarray(t_dark), np.asarray(t_bright)
    with np.errstate(divide="ignore", invalid="ignore"):
        if from_bright:
            f = np.clip((t_bright - threshold) / (t_bright - t_dark), 0.0, 1.0)
        else:
            f = np.clip((threshold - t_dark) / (t_bright - t_dark), 0.0, 1.0)
    if np.ndim(f) == 0:
        return float(f) if np.isfinite(f) else 0.5
    return np.where(np.isfinite(f), f, 0.5)


def first_rising_crossing(profile: np.ndarray, start: int, stop: int, threshold: float) -> float:
    """First crossing of ``threshold`` from a dark sample to the next bright one in ``profile[start:stop]``.

    Parameters
    ----------
    profile : ndarray
        Transmission along a line (a column, going down).
    start, stop : int
        Part of the profile searched.
    threshold : float
        Edge level (transmission).

    Returns
    -------
    float
        Sub-pixel index in ``profile`` (`crossing_fraction` past the last dark sample), NaN
        when the profile never rises through the level there.
    """
    seg = profile[start:stop]
    above = np.nonzero(seg >= threshold)[0]
    above = above[above > 0]
    for i in above:
        if seg[i - 1] < threshold:
            return start + i - 1 + float(crossing_fraction(seg[i - 1], seg[i], threshold))
    return np.nan


@dataclass
class RowEdges:
    """Sub-pixel edges of the dark runs of one body (all arrays have one entry per run).

    Attributes
    ----------
    row : ndarray of int
        Row of the run (region-of-interest coordinates).
    left_px, right_px : ndarray of float
        Sub-pixel edge positions (column coordinates, pixel centres integers).
    touches : bool
        A run reaches the side of the region (the edge could not be located).
    dark_t : float
        The body's darkest level: the 2nd percentile of the transmission of its run pixels (a
        lensing drop's dark rim; NaN when not measured).  With the liquid's calibrated interior
        level it bounds the band of edge levels (`dropvision.frame.volume.edge_definition_px`).
    slope_t_per_px : float
        Median slope of the transmission across the body's edges at the edge level (transmission
        per px, from the two samples either side of each crossing; NaN when not measured).
    bright_t : float
        The background next to the body: the 10th percentile of the transmission one edge width
        beyond its edges (`subpixel_edges`; 1 for a background model that holds there; NaN when
        not measured).
    bright_noise_t : float
        The spread (standard deviation) of those samples from row to row along each side of the
        outline (`_bright_level`): the noise a percentile of them carries, JPEG ringing included
        (NaN when not measured).
    """

    row: np.ndarray
    left_px: np.ndarray
    right_px: np.ndarray
    touches: bool
    dark_t: float = float("nan")
    slope_t_per_px: float = float("nan")
    bright_t: float = float("nan")
    bright_noise_t: float = float("nan")

    @property
    def chord_px(self) -> np.ndarray:
        return self.right_px - self.left_px

    @property
    def centre_px(self) -> np.ndarray:
        return 0.5 * (self.right_px + self.left_px)


def runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Horizontal runs of True in a 2-D boolean array.

    Returns
    -------
    rows, starts, stops : ndarray of int
        Run ``k`` covers ``mask[rows[k], starts[k]:stops[k]]``.
    """
    h, w = mask.shape
    padded = np.zeros((h, w + 2), np.int8)
    padded[:, 1:-1] = mask
    d = np.diff(padded, axis=1)
    # one pass: in each row the changes alternate, a start (+1) then its stop (-1)
    rr, cc = np.nonzero(d)
    up = d[rr, cc] == 1
    return rr[up], cc[up], cc[~up]


def subpixel_edges(
    image: np.ndarray,
    inv_background: np.ndarray,
    rows: np.ndarray,
    starts: np.ndarray,
    stops: np.ndarray,
    threshold: float,
    gain: float = 1.0,
    bright_row_min: int = 0,
) -> RowEdges:
    """Sub-pixel edges (`crossing_fraction`) at both ends of each run.

    Parameters
    ----------
    image : ndarray
        Raw image (region of interest).
    inv_background : ndarray of float32
        ``1 / background`` for the same region.
    rows, starts, stops : ndarray of int
        Runs as returned by `runs` (dark pixels ``starts..stops-1``).
    threshold : float
        Transmission level of the edge, ``(1 + interior_level) / 2``.
    gain : float
        Frame illumination relative to the background model (strobe flicker).
    bright_row_min : int
        The background beside the edges (``RowEdges.bright_t``) is read from this row down (all
        rows when none is that low): beside liquid hanging from a nozzle, the rows within the
        nozzle's blur below its tip show the nozzle's halo, not the background.

    Returns
    -------
    RowEdges
    """
    w = image.shape[1]
    touches = bool((starts == 0).any() or (stops == w).any())
    s = np.minimum(np.maximum(starts, 1), w - 1)  # integer clip (np.clip costs ~30 us a call here)
    e = np.minimum(np.maximum(stops, 1), w - 1)
    scale = 1.0 / gain
    t_out_l = image[rows, s - 1] * inv_background[rows, s - 1] * scale
    t_in_l = image[rows, s] * inv_background[rows, s] * scale
    t_in_r = image[rows, e - 1] * inv_background[rows, e - 1] * scale
    t_out_r = image[rows, e] * inv_background[rows, e] * scale
    left = (s - 1) + crossing_fraction(t_in_l, t_out_l, threshold, from_bright=True)
    right = (e - 1) + crossing_fraction(t_in_r, t_out_r, threshold)
    steps = np.concatenate([t_out_l - t_in_l, t_out_r - t_in_r])
    slope = float(np.partition(steps, steps.size // 2)[steps.size // 2]) if steps.size else float("nan")  # median
    b = rows >= bright_row_min
    if not b.any():
        b = np.ones(rows.size, bool)
    bright, bright_noise = _bright_level(image, inv_background, rows[b], s[b], e[b], threshold,
                                         ((t_out_l - t_in_l)[b], (t_out_r - t_in_r)[b]), scale)
    return RowEdges(np.asarray(rows), left.astype(float), right.astype(float), touches,
                    slope_t_per_px=slope, bright_t=bright, bright_noise_t=bright_noise)


def _bright_level(image, inv_background, rows, s, e, threshold: float, slopes: tuple,
                  scale: float) -> tuple[float, float]:
    """The background one edge width beyond a body's edges: the 10th percentile of its samples'
    transmission (NaN if none; `dropvision.frame.volume.edge_definition_px` adds back the 1.28 noise
    standard deviations by which noise alone puts it below the mean), and the noise of those
    samples.  A mean would dilute an out-of-focus mist droplet's shadow lying over a tenth of the
    outline.

    The samples' noise is read off themselves: the spread of the differences between samples two
    runs apart along each side of the outline, over sqrt(2) (`dvcore.robust.pair_noise_sigma`: on
    the raw counts, so that a noise of about one count is not read as a median absolute deviation
    of integers; two apart, `dvcore.robust.NOISE_LAG_PX`, so that a colour camera's or a JPEG
    coder's 2x2 cells do not hide it).  What changes from row to row is noise (the sensor's, and a
    JPEG coder's ringing beside a strong edge, which the frame's noise measured on flat background
    does not hold: 1.5-2x it on a quality-85 JPEG); a mist shadow or a halo lying over a stretch of
    the outline changes slowly along it and stays in the level.  NaN with fewer than 10
    differences.

    An edge's width along its row is its contrast over its slope there, ``2 (1 - threshold) /
    slope`` (about 2.5 Gaussian sigmas across a steep edge, more along the row where the edge is
    oblique); each sample lies that far (at least 2 px, at most 8 px) beyond the edge's bright
    sample.  A sample darker than the edge level is another body, not background: left out."""
    if rows.size == 0:
        return float("nan"), float("nan")
    w = image.shape[1]
    contrast = 2.0 * (1.0 - threshold)
    # integer clips by minimum/maximum (np.clip costs ~30 us a call here); both sides in one gather
    k = np.minimum(np.maximum(np.ceil(contrast / np.maximum(np.concatenate(slopes), 1e-6)), 2), 8).astype(np.intp)
    n = rows.size
    c = np.concatenate([s - 1, e])
    c[:n] -= k[:n]
    c[n:] += k[n:]
    c = np.minimum(np.maximum(c, 0), w - 1)
    rr = np.concatenate([rows, rows])
    raw = image[rr, c]
    per_count = inv_background[rr, c] * scale  # the transmission of one count of the raw value
    t = raw * per_count
    bright = t >= threshold
    # each sample and the one NOISE_LAG_PX runs before it on its side (the runs come in row order),
    # both background
    g = NOISE_LAG_PX
    i = np.r_[g:n, n + g:2 * n]
    pair = bright[i] & bright[i - g]
    noise = pair_noise_sigma(raw[i[pair]], raw[i[pair] - g],
                             float(np.median(per_count[bright])) if bright.any() else 1.0)
    t = t[bright]
    if t.size == 0:
        return float("nan"), noise
    k = t.size // 10  # the 10th percentile: a mist droplet's shadow over a part of the outline counts
    return float(np.partition(t, k)[k]), noise


def dark_level(image: np.ndarray, inv_background: np.ndarray, mask: np.ndarray, y0: int, x0: int,
               gain: float = 1.0, max_pixels: int = 3000) -> float:
    """The darkest level of a body: the 2nd percentile of its pixels' transmission (NaN if empty).

    ``mask`` covers ``image[y0:, x0:]`` from its top-left corner (a body's box).  A large body is
    sampled every few rows (about ``max_pixels`` pixels of its box: a percentile needs no more).
    """
    h, w = mask.shape
    step = max(1, -(-(h * w) // max_pixels))
    sub = mask[::step]
    t = image[y0:y0 + h:step, x0:x0 + w][sub].astype(np.float32)
    if t.size == 0:
        return float("nan")
    t *= inv_background[y0:y0 + h:step, x0:x0 + w][sub]
    k = t.size // 50
    return float(np.partition(t, k)[k]) / gain


def body_edges(
    image: np.ndarray,
    inv_background: np.ndarray,
    labels: np.ndarray,
    label: int,
    bbox: tuple[int, int, int, int],
    threshold: float,
    gain: float = 1.0,
    row_min: int = 0,
    bright_row_min: int = 0,
) -> RowEdges:
    """Sub-pixel run edges of one labelled body (region-of-interest coordinates).

    Parameters
    ----------
    image, inv_background : ndarray
        Region of interest and ``1 / background`` over it.
    labels : ndarray
        Label image of the region (`dropvision.frame.segmentation.segment`).
    label : int
        The body's label.
    bbox : (x0, y0, x1, y1)
        Its bounding box (half-open).
    threshold, gain : float
        See `subpixel_edges`.
    row_min : int
        Ignore rows above this one.
    bright_row_min : int
        See `subpixel_edges`.
    """
    x0, y0, x1, y1 = bbox
    y0 = max(y0, row_min)
    if y1 <= y0:
        e = np.zeros(0)
        return RowEdges(np.zeros(0, int), e, e, False)
    sub = labels[y0:y1, x0:x1] == label
    r, s, e = runs(sub)
    ed = subpixel_edges(image, inv_background, r + y0, s + x0, e + x0, threshold, gain, bright_row_min)
    ed.dark_t = dark_level(image, inv_background, sub, y0, x0, gain)
    return ed
