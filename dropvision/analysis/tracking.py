"""Tracking of the main drop over a sequence: per-frame drop values, in flight, jetting velocity.

Works on the per-frame records (`dropvision.frame.measure_frame.FrameRecord`) once the attached frames are
known (`dropvision.analysis.pinchoff.pinchoff_delay`):

- per frame, the main drop (largest detached body) and its satellites are trusted only when no
  body leaves the field of view or the measured band, overlaps dust, or lies too close to the
  attached liquid;
- in flight: a trusted main drop that is compact (axial length <= ``compact_ratio``
  equivalent-sphere diameters: the tail has merged or broken up) without a thin tail at its top,
  at a delay after the last one whose drop still carries its tail;
- jetting velocity: least-squares line of ``drop_z_um`` against ``delay_us`` over in-flight
  frames (slope in µm/µs = m/s, with its standard error); trajectory: line of ``drop_x_um``
  against ``drop_z_um``.
"""

from __future__ import annotations

import math

from dataclasses import dataclass

import numpy as np

import dropvision.quality as q
from dropvision.config import MeasureConfig
from dropvision.analysis.findings import Finding, frames_of
from dropvision.frame.measure_frame import FrameRecord


@dataclass(frozen=True)
class LineFit:
    """Least-squares line ``y = intercept + slope x`` with the slope's standard error."""

    slope: float
    intercept: float
    slope_se: float
    n: int


def fit_line(x, y) -> LineFit:
    """Ordinary least squares over the finite points.

    Parameters
    ----------
    x, y : array_like
        Points (any units; the slope is in y units per x unit).

    Returns
    -------
    LineFit
        NaN below 2 points or when ``x`` is constant; ``slope_se`` NaN below 3 points.
    """
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    ok = np.isfinite(x) & np.isfinite(y)
    x, y = x[ok], y[ok]
    n = x.size
    if n < 2 or np.ptp(x) == 0:
        return LineFit(np.nan, np.nan, np.nan, int(n))
    xm, ym = x.mean(), y.mean()
    sxx = np.sum((x - xm) ** 2)
    slope = float(np.sum((x - xm) * (y - ym)) / sxx)
    icpt = float(ym - slope * xm)
    if n < 3:
        return LineFit(slope, icpt, np.nan, n)
    res = y - (icpt + slope * x)
    se = float(np.sqrt(np.sum(res**2) / (n - 2) / sxx))
    return LineFit(slope, icpt, se, n)


@dataclass
class DropTrack:
    """Per-frame values of the main drop (one entry per frame, NaN where not trusted).

    Attributes
    ----------
    drop_volume_nl, detached_volume_nl : ndarray
        Main drop volume (its whole silhouette: a satellite touching it included) and all
        detached liquid (nl); detached 0 in attached frames and frames without a drop.
    z_um, x_um : ndarray
        Main drop volume centroid along and across the axis from the tip (µm).
    length_um, diameter_um : ndarray
        Main drop extent along the rows and widest chord (µm).
    n_satellites : ndarray
        Satellites, touching ones included (float, NaN where unknown; 0 in attached frames).
    drop_volume_uncertainty_nl, detached_volume_uncertainty_nl : ndarray
        Standard uncertainties of the two volumes (nl).
    drop_volume_random_uncertainty_nl : ndarray
        The main drop volume's part from its edges' own noise (nl; its touching bodies' in
        quadrature: `dropvision.frame.bodies.DetachedBody.random_uncertainty_nl`).
    inflight : ndarray of bool
        Main drop compact and trusted.
    """

    drop_volume_nl: np.ndarray
    detached_volume_nl: np.ndarray
    z_um: np.ndarray
    x_um: np.ndarray
    length_um: np.ndarray
    diameter_um: np.ndarray
    n_satellites: np.ndarray
    inflight: np.ndarray
    drop_volume_uncertainty_nl: np.ndarray | None = None
    detached_volume_uncertainty_nl: np.ndarray | None = None
    drop_volume_random_uncertainty_nl: np.ndarray | None = None


#: The quality codes `track_main_drop` gives, in the order a frame gets them.
TRACK_FLAGS = (q.DROP_LEAVES, q.OUT_OF_BAND, q.DUST_OVERLAP, q.AMBIGUOUS, q.NO_DROP, q.TAIL)
#: A frame with one of these does not hold earlier frames out of flight by its tail.
TAIL_IGNORED_FLAGS = q.UNTRUSTED_INTENSITY_FLAGS + (q.NEIGHBOURS,)


def track_main_drop(records: list[FrameRecord], attached: np.ndarray, config: MeasureConfig,
                    flags: list[list[str]]) -> tuple[DropTrack, list[Finding]]:
    """The main drop of every frame, in flight or not, and each frame's reasons (as findings).

    Parameters
    ----------
    records : list of FrameRecord
    attached : ndarray of bool
        Frames before the pinch-off without a detached drop.
    config : MeasureConfig
        ``ambiguous_gap_px``, ``compact_ratio``, ``tail_chord_ratio``.
    flags : list of list of str
        Per-frame quality flags so far (read, not changed).

    Returns
    -------
    DropTrack
    list of Finding
        One per quality code of `TRACK_FLAGS` given (``tail`` only keeps a frame out of flight).
    """
    m = len(records)
    drop_vol = np.full(m, np.nan)
    det_vol = np.full(m, np.nan)
    drop_z = np.full(m, np.nan)
    drop_x = np.full(m, np.nan)
    length = np.full(m, np.nan)
    diam = np.full(m, np.nan)
    nsat = np.full(m, np.nan)
    inflight = np.zeros(m, bool)
    drop_u = np.full(m, np.nan)
    drop_r = np.full(m, np.nan)
    det_u = np.full(m, np.nan)
    reasons: list[list[str]] = [[] for _ in range(m)]
    for k, r in enumerate(records):
        b = r.bodies[0] if r.bodies else None
        if attached[k]:
            det_vol[k] = det_u[k] = 0.0
            nsat[k] = 0
            if np.isfinite(r.neck_px) and r.neck_px < config.ambiguous_gap_px:
                reasons[k].append(q.AMBIGUOUS)
            continue
        if b is None:
            reasons[k].append(q.NO_DROP)
            det_vol[k] = det_u[k] = 0.0
            continue
        bad = main_drop_doubts(r, config)
        reasons[k].extend(bad)
        others = r.bodies[1:]
        sat_bad = any(o.leaves or o.out_of_band or o.on_dust for o in others)
        if not bad:
            # a satellite touching the main drop (one silhouette, split at its waist) is a drop of
            # its own, counted; its lobe stays in the main drop's volume (they coalesce in flight)
            drop_vol[k] = b.volume_nl + sum(o.volume_nl for o in others if o.touching)
            # one edge error for every body of the frame: the uncertainties add up
            drop_u[k] = b.volume_uncertainty_nl + sum(o.volume_uncertainty_nl for o in others if o.touching)
            # their edges' own noise is independent: in quadrature
            drop_r[k] = math.sqrt(b.random_uncertainty_nl ** 2
                                  + sum(o.random_uncertainty_nl ** 2 for o in others if o.touching))
            drop_z[k], drop_x[k] = b.z_um, b.x_um
            length[k], diam[k] = b.length_um, b.diameter_um
            if not sat_bad:
                det_vol[k] = sum(o.volume_nl for o in r.bodies)
                det_u[k] = sum(o.volume_uncertainty_nl for o in r.bodies)
                nsat[k] = len(others)
            inflight[k] = (not b.elongated(config.compact_ratio)
                           and not (b.top_chord_ratio < config.tail_chord_ratio))
            if not inflight[k]:
                reasons[k].append(q.TAIL)
    # a tail merges once: a compact-looking drop before a later delay whose tail is still joined
    # (a bulb on the tail can pass for a round top) is not yet in flight
    delays = np.array([r.delay_us for r in records], float)
    tail = np.array([q.TAIL in own and not any(f in fl for f in TAIL_IGNORED_FLAGS) for own, fl in zip(reasons, flags)],
                    bool)
    if tail.any():
        early = inflight & (delays < delays[tail].max())
        for k in np.nonzero(early)[0]:
            inflight[k] = False
            reasons[k].append(q.TAIL)
    found = [Finding(code, frames_of([code in own for own in reasons])) for code in TRACK_FLAGS
             if any(code in own for own in reasons)]
    return DropTrack(drop_vol, det_vol, drop_z, drop_x, length, diam, nsat, inflight, drop_u, det_u, drop_r), found


def main_drop_doubts(record: FrameRecord, config: MeasureConfig) -> list[str]:
    """Why a frame's main drop (its largest detached body) is not trusted, in `TRACK_FLAGS` order:
    it leaves the field of view, leaves the measured band, overlaps dust, or its top lies within
    ``config.ambiguous_gap_px`` + 1 px of the attached liquid's bottom (empty: trusted)."""
    b = record.bodies[0]
    bad = []
    if b.leaves:
        bad.append(q.DROP_LEAVES)
    if b.out_of_band:
        bad.append(q.OUT_OF_BAND)
    if b.on_dust:
        bad.append(q.DUST_OVERLAP)
    if np.isfinite(record.attached_bottom_row) and b.top_row - record.attached_bottom_row < config.ambiguous_gap_px + 1:
        bad.append(q.AMBIGUOUS)
    return bad


def neighbour_outliers(x, y, sigmas: float, floor: float) -> np.ndarray:
    """Points that disagree with their neighbours in ``x`` far beyond the series' own scatter.

    Every point is predicted from the means of the nearest distinct ``x`` on each side (linear
    interpolation; one-sided linear extrapolation from the two nearest at the ends).  The
    scatter is the robust spread (1.4826 MAD) of these residuals; a point whose residual
    exceeds ``max(sigmas * scatter, floor)`` is an outlier.  The worst outlier is removed and the
    residuals recomputed until none is left, so that one outlier does not make its neighbours
    look wrong.

    Parameters
    ----------
    x, y : array_like
        Points (e.g. delay in µs and drop position in µm); non-finite ones are ignored.
    sigmas : float
        Threshold in robust scatters.
    floor : float
        Smallest residual called an outlier (y units).

    Returns
    -------
    ndarray of bool
        Outliers, per point.
    """
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    use = np.isfinite(x) & np.isfinite(y)
    out = np.zeros(x.size, bool)
    while True:
        idx = np.nonzero(use & ~out)[0]
        ux = np.unique(x[idx])
        if ux.size < 4:
            return out
        means = np.array([y[idx][x[idx] == u].mean() for u in ux])
        res = np.full(x.size, np.nan)
        for k in idx:
            i = int(np.searchsorted(ux, x[k]))
            lo = [j for j in (i - 1, i - 2) if j >= 0]
            hi = [j for j in (i + 1, i + 2) if j < ux.size]
            if lo and hi:
                a, b = lo[0], hi[0]
            elif len(hi) == 2:
                a, b = hi
            elif len(lo) == 2:
                a, b = lo[1], lo[0]
            else:
                continue
            pred = means[a] + (means[b] - means[a]) * (x[k] - ux[a]) / (ux[b] - ux[a])
            res[k] = y[k] - pred
        r = res[np.isfinite(res)]
        if r.size < 4:
            return out
        # lower quartile of |r| (0.3186 sigma for Gaussian residuals): an outlier also spoils its
        # neighbours' predictions, so up to ~3/4 of the residuals may be off
        scatter = float(np.quantile(np.abs(r), 0.25)) / 0.3186
        limit = max(sigmas * scatter, floor)
        worst = int(np.nanargmax(np.abs(res)))
        if not abs(res[worst]) > limit:
            return out
        out[worst] = True
