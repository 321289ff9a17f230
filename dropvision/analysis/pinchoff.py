"""Pinch-off: when the drop separates from the liquid still attached to the nozzle.

Two rules, one per frame and one per sequence:

- `thread_joined_labels` (per frame): a dark body below the attached liquid is still part of
  it when an unresolved liquid thread (thinner than the blur) joins them;
- `pinchoff_delay` (per sequence): the first delay at which at least half of the frames show
  a detached drop; frames before it are ``attached``.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from dropvision.calibrate.frame_context import FrameContext
from dropvision.frame.edges import crossing_fraction
from dropvision.frame.segmentation import DarkBody, Segmentation
from dropvision.calibrate.special import ndtr

if TYPE_CHECKING:  # pandas loads where a table is made, not at start-up
    import pandas as pd

#: Darkening (transmission units) every interior gap row must show beyond the ends' blurred
#: tails for a thread to join two bodies.  The ends' unresolved taper (meniscus cone, tail tip)
#: darkens the rows next to them by up to 0.09 more than a straight blurred edge.  In a seed
#: sweep (`tools/pinchoff_sweep.py`: 12 seeds x 16 waveforms at 192 x 640, 4 x 16 at
#: 640 x 1024) every just-detached gap (128) had an interior row within 0.035 of the tails'
#: prediction, and every last-attached thread (64) darkened all interior rows by >= 0.246.
#: At 1 px blur 0.05 is a thread about 0.2 px wide; a thinner one counts as broken.
INTERIOR_THREAD_MARGIN = 0.05


def thread_joined_labels(roi: np.ndarray, ctx: FrameContext, seg: Segmentation, nozzle_body: DarkBody,
                         bottom_row: float, gain: float) -> set[int]:
    """Labels of detached bodies still joined to the attached liquid by an unresolved thread.

    A liquid thread much thinner than the blur never reaches the 50 % level, but it leaves a
    faint dark line across the gap, and it crosses *every* row of the gap with about the same
    width, so its darkening does not fade anywhere in the gap.  The blurred ends alone darken
    the gap only by their tails, which decay away from each end.  Along the straight path from
    the attached liquid's bottom to a body's top (per row the darkest pixel within 2 px of the
    path), each gap row is compared with what the two ends alone would give there
    (`end_tails_transmission`): each end is an edge at its sub-pixel 50 % crossing along the
    path, blurred by the calibrated blur.  The body is joined only when *every* gap row is darker
    than that by more than 4 noise standard deviations (and by at least 0.02): one gap row
    explained by the ends' tails alone breaks the thread.

    The straight-edge model misses the unresolved taper of a real end (the residual meniscus
    cone, a tail's tip), which darkens the row next to each end by up to ~0.09 more.  So in
    gaps of 3 rows or more only the rows not adjacent to an end are judged, each against
    ``max(INTERIOR_THREAD_MARGIN, 4 noise std)``.  A thread broken within a row of an end is
    therefore seen one frame later, once the gap has opened.

    Parameters
    ----------
    roi : ndarray
        Raw frame, region of interest.
    ctx : FrameContext
        Calibrated blur (px), threshold, liquid level and noise (transmission units).
    seg : Segmentation
        The frame's bodies.
    nozzle_body : DarkBody
        The nozzle with the attached liquid.
    bottom_row : float
        Bottom row of the attached liquid (region coordinates, px).
    gain : float
        Frame illumination relative to the background model.

    Returns
    -------
    set of int
        Labels (in ``seg.labels``) of the joined bodies.
    """
    photo = ctx.photometry
    out: set[int] = set()
    labels = seg.labels
    yb = int(round(bottom_row))
    cols_b = np.nonzero(labels[yb] == nozzle_body.label)[0]
    if cols_b.size == 0:
        return out
    xb = 0.5 * (cols_b[0] + cols_b[-1])
    sig = ctx.blur.correction_sigma_px if ctx.blur.correction_sigma_px > 0 else 1.0
    margin = max(0.02, 4.0 * photo.noise_transmission)
    interior_margin = max(INTERIOR_THREAD_MARGIN, 4.0 * photo.noise_transmission)

    near, far = int(math.ceil(4.0 * sig)) + 3, int(math.ceil(4.0 * sig)) + 8
    side_offsets = np.concatenate([np.arange(-far, -near + 1), np.arange(near, far + 1)])

    for b in seg.bodies:
        if b.nozzle or b.y0 <= yb or b.y0 - yb > 100:
            continue
        cols_t = np.nonzero(labels[b.y0] == b.label)[0]
        xt = 0.5 * (cols_t[0] + cols_t[-1])
        if b.y0 - yb - 1 < 1:
            out.add(b.label)
            continue
        rows = np.arange(yb, b.y0 + 1)
        # the path's column per row, rounded half to even like Python's round
        path_cols = np.round(xb + (xt - xb) * (rows - yb) / (b.y0 - yb)).astype(np.intp)
        # per row the darkest pixel within 2 px of the path
        t_path = _window_min(roi, photo.inv_background, rows, path_cols, _DARKEST_OFFSETS) / gain
        # sub-pixel 50 % crossings of the two ends along the path (end row dark, next row not)
        # (a path that does not rise from an end has no crossing there: the row's middle)
        e_top = yb + (crossing_fraction(t_path[0], t_path[1], photo.threshold) if t_path[1] > t_path[0] else 0.5)
        e_bot = b.y0 - (crossing_fraction(t_path[-1], t_path[-2], photo.threshold) if t_path[-2] > t_path[-1] else 0.5)
        expected = end_tails_transmission(rows[1:-1], e_top, e_bot, sig, sig, photo.liquid_level)
        excess = expected - t_path[1:-1]
        # a thread darkens the path, not the rows beside it: a darker surround (a blurred holder's
        # halo the background model misses) darkens both and is no thread
        # per row the mean of the median of the free pixels on each side of the path
        t_side = _sides_median_mean(roi, photo.inv_background, labels, rows[1:-1], path_cols[1:-1],
                                    side_offsets, gain)
        local = np.where(np.isfinite(t_side), t_side - t_path[1:-1], np.inf)
        if excess.size >= 3:  # judge the rows not adjacent to an end (their taper is unmodelled)
            judged, local, limit = excess[1:-1], local[1:-1], interior_margin
        else:
            judged, limit = excess, margin
        if float(judged.min()) > limit and float(local.min()) > limit:
            out.add(b.label)
    return out


#: Columns of the path's darkest-pixel window, relative to the path (within 2 px)
_DARKEST_OFFSETS = np.arange(-2, 3)


def _gather(roi: np.ndarray, inv_background: np.ndarray, rows: np.ndarray, cols: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Transmission (float32, ``roi * inv_background``) at ``rows[:, None]``, ``cols``; inside the frame."""
    inside = (cols >= 0) & (cols < roi.shape[1])
    cc = np.minimum(np.maximum(cols, 0), roi.shape[1] - 1)
    rr = np.broadcast_to(rows[:, None], cc.shape)
    return roi[rr, cc].astype(np.float32) * inv_background[rr, cc], inside, cc


def _window_min(roi: np.ndarray, inv_background: np.ndarray, rows: np.ndarray, cols: np.ndarray,
                offsets: np.ndarray) -> np.ndarray:
    """Per row the smallest transmission within ``cols + offsets`` (inside the frame), float64."""
    t, inside, _ = _gather(roi, inv_background, rows, cols[:, None] + offsets)
    return np.where(inside, t, np.float32(np.inf)).min(axis=1).astype(np.float64)


def _sides_median_mean(roi: np.ndarray, inv_background: np.ndarray, labels: np.ndarray, rows: np.ndarray,
                       cols: np.ndarray, offsets: np.ndarray, gain: float) -> np.ndarray:
    """Per row the mean over the two sides of the path of the median free-pixel transmission / gain.

    ``offsets`` holds the left side's columns, then as many of the right side's.  A side with no
    free pixel (label 0) inside the frame is left out; NaN where both are.  The medians are taken
    as `numpy.median` takes them (float32, the two middle values' mean in float32), so the
    figures are those of the per-row ``np.median`` of the free pixels, bit for bit.
    """
    t, inside, cc = _gather(roi, inv_background, rows, cols[:, None] + offsets)
    free = inside & (labels[np.broadcast_to(rows[:, None], cc.shape), cc] == 0)
    half = offsets.size // 2
    meds = np.full((rows.size, 2), np.nan)
    for k, side in enumerate((slice(0, half), slice(half, None))):
        ok = free[:, side]
        n = ok.sum(axis=1)
        srt = np.sort(np.where(ok, t[:, side], np.float32(np.inf)), axis=1)
        has = n > 0
        i_hi = np.maximum(n // 2, 0)
        i_lo = np.maximum(n // 2 - 1, 0)
        hi = np.take_along_axis(srt, i_hi[:, None], axis=1)[:, 0]
        lo = np.take_along_axis(srt, i_lo[:, None], axis=1)[:, 0]
        med = np.where(n % 2 == 1, hi, (lo + hi) / np.float32(2.0))
        meds[has, k] = med[has].astype(np.float64) / gain
    both = np.isfinite(meds).all(axis=1)
    out = np.where(np.isnan(meds[:, 0]), meds[:, 1], meds[:, 0])
    out[both] = (meds[both, 0] + meds[both, 1]) / 2.0
    return out


def end_tails_transmission(rows: np.ndarray, e_top: float, e_bot: float, sigma_top_px: float,
                           sigma_bot_px: float, liquid_level: float) -> np.ndarray:
    """Transmission along the axis between two blurred liquid ends (no liquid between them).

    Each end is an edge at its 50 % crossing (``e_top`` the upper body's bottom, ``e_bot`` the
    lower body's top) blurred by a Gaussian: its darkening at a distance ``d`` outside is
    ``(1 - L) (1 - Phi(d / sigma))``; the two tails add.

    Parameters
    ----------
    rows : array_like
        Rows to evaluate (px).
    e_top, e_bot : float
        Rows of the two ends' 50 % crossings (px).
    sigma_top_px, sigma_bot_px : float
        Their Gaussian blur (px).
    liquid_level : float
        Liquid interior transmission ``L``.

    Returns
    -------
    ndarray
        Transmission (background = 1) at ``rows``.
    """
    rows = np.asarray(rows, float)
    dark = ndtr((e_top - rows) / sigma_top_px) + ndtr((rows - e_bot) / sigma_bot_px)
    return 1.0 - (1.0 - liquid_level) * dark


def pinchoff_delay(delay_us: np.ndarray, detached: np.ndarray) -> float:
    """First delay at which at least half of the frames show a detached drop.

    Parameters
    ----------
    delay_us : ndarray
        Delay of every frame (µs).
    detached : ndarray of bool
        The frame shows a detached main drop.

    Returns
    -------
    float
        Pinch-off delay (µs); NaN if no delay qualifies.
    """
    import pandas as pd
    df = pd.DataFrame({"d": delay_us, "x": detached.astype(float)})
    frac = df.groupby("d")["x"].mean()
    hit = frac.index[frac.to_numpy() >= 0.5]
    return float(hit[0]) if len(hit) else float("nan")


def isolated_detached(delay_us: np.ndarray, detached: np.ndarray) -> np.ndarray:
    """Frames at a delay whose majority shows a detached drop while the neighbouring delays do not.

    The drop separates once: a detached delay between attached ones (or a first delay detached
    with the next attached) is a frame from another sequence or a mislabelled delay.  The last
    delay is never isolated (a sequence may end at the pinch-off).

    Parameters
    ----------
    delay_us : ndarray
        Delay of every frame (µs).
    detached : ndarray of bool
        The frame shows a detached body.

    Returns
    -------
    ndarray of bool
        Per frame.
    """
    import pandas as pd
    delay_us = np.asarray(delay_us, float)
    if delay_us.size == 0:
        return np.zeros(0, bool)
    frac = pd.Series(np.asarray(detached, float)).groupby(delay_us).mean()
    maj = frac.to_numpy() >= 0.5
    iso = np.zeros(maj.size, bool)
    for i in range(maj.size - 1):
        if maj[i] and not maj[i + 1] and (i == 0 or not maj[i - 1]):
            iso[i] = True
    bad = set(frac.index[iso].to_numpy(float))
    return np.array([d in bad for d in delay_us], bool)


def pinchoff_bracket_problem(delay_us: np.ndarray, pinch_us: float, min_frames: int) -> str | None:
    """Why a pinch-off delay is not defined by the sequence, or None when it is.

    The pinch-off lies between the last attached and the first detached delay; it is defined
    only when these are consecutive delays at the sequence's own step (the smallest difference
    between its delays) and the sequence has at least ``min_frames`` frames.

    Parameters
    ----------
    delay_us : ndarray
        Delay of every frame used (µs).
    pinch_us : float
        First delay at which the drop is detached (`pinchoff_delay`).
    min_frames : int
        Fewest frames.

    Returns
    -------
    str or None
        A short sentence.
    """
    d = np.unique(np.asarray(delay_us, float))
    if not np.isfinite(pinch_us):
        return None
    if np.asarray(delay_us).size < min_frames:
        return f"pinch-off undefined: {np.asarray(delay_us).size} frames (fewer than {min_frames})"
    before = d[d < pinch_us]
    if before.size == 0:
        return f"pinch-off undefined: the first delay ({pinch_us:g} us) already shows a detached drop"
    step = float(np.min(np.diff(d)))
    gap = pinch_us - float(before.max())
    if gap > step * (1.0 + 1e-6):
        return (f"pinch-off undefined: {gap:g} us between the last attached ({before.max():g} us) and the first "
                f"detached delay, more than the sequence's step {step:g} us")
    return None
