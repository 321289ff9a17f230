"""A printhead row: several nozzles under one flat nozzle plate in a frame (issue 32).

In a side view the orifices of a flat nozzle plate are not visible: a nozzle is where its liquid
leaves the plate, and a missing nozzle is a gap in the pitch.  The rule a person applies, and
`row_layout` applies to the first frame: the dark body at the top edge spans (nearly) the whole
width with a straight lower edge (a plate, not a nozzle or a holder block), and below it hang or
fly the bodies of two or more separate drop lines.  One drop line under a plate is a single
nozzle (`dropvision.measurement`'s path, unchanged).

Measurement (`measure_row`):

1. background (`dropvision.calibrate.background.estimate_background`), transmission, the plate's lower edge
   (a straight line fitted to the columns' sub-pixel 50 % crossings, columns where liquid hangs
   left out);
2. per frame, the dark bodies below the plate, each measured by the per-body code
   (`dropvision.frame.edges.body_edges`, `dropvision.frame.volume.integrate` with the blur correction, the
   volume uncertainty terms of `dropvision.frame.volume`); bodies on one line (same column within the
   drop size) form a drop line, its largest body the main drop, the others satellites;
3. trajectories: over a sequence, each drop line's main drop is followed from frame to frame and a
   straight line fitted to its positions over the delays (velocity, angle from the plate normal,
   the column where it meets the plate); in a single frame a line with two bodies points back
   along them, one with one body straight up;
4. nozzles: the columns where the trajectories meet the plate lie on a grid of the pitch (given
   as ``nozzle_pitch_um`` in sequence.json or ``--nozzle-pitch-um``, else the smallest spacing of
   the found nozzles refined by a least-squares fit); each drop line goes to the grid position
   its trajectory meets (not to the nearest column); grid positions between the first and the
   last found nozzle with no line are missing nozzles (at the row's ends only with the nozzle count
   given: `_end_gaps`).  Liquid hanging from the plate in a drop line's column (a meniscus or a
   ligament's root, smaller than the flying drop) is the nozzle's root, not a satellite: where it
   leaves the plate gives the nozzle's place directly, and the grid is fitted to those places.  In
   a single frame the angle of a drop is that of the line from its nozzle's place at the plate
   (else its grid position) to the drop;
5. states: ``missing``; ``weak`` (volume or velocity beyond ``WEAK_K`` robust standard
   deviations of the row: 1.4826 x the median absolute deviation, at least ``WEAK_FLOOR`` of
   the median, with the nozzle's own uncertainty in quadrature); ``deviated`` (|angle| beyond
   ``DEVIATED_MRAD``, the projected angle of IEC 62899-302-3 measured from the plate normal);
   ``satellites`` (satellites in at least half its frames); else ``ok``; the head's uniformity
   (CV of volume and velocity over the live nozzles, with the uncertainty the nozzles'
   uncertainties give it).

Outputs (`write_row_result`): nozzles.parquet, frames.parquet and bodies.parquet with a
``nozzle`` column (`dvcore.schema.NOZZLES`, ``ROW_FRAMES``, ``ROW_BODIES``), summary.json
(``ROW_SUMMARY``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from dvcore.robust import MAD_TO_SIGMA, robust_sigma

#: A plate spans at least this fraction of the frame's top row.
PLATE_MIN_WIDTH = 0.9
#: ... and its lower edge is a straight line for at least this fraction of the columns (within 3 px).
PLATE_MIN_STRAIGHT = 0.6
#: A drop line counts towards a row when its largest body has at least this fraction of the
#: area of the largest line's (`row_layout`).
MIN_LINE_AREA_RATIO = 0.2
#: Bodies smaller than this (px) are noise, mist or dust.
MIN_BODY_AREA_PX = 12
#: A nozzle's place from the liquid at the plate: the rows (px) below the plate's edge whose dark
#: pixels give the column where the liquid leaves it, from ROOT_SKIP_PX below the edge (past the
#: edge's own blur, which runs along the plate and would pull the place along a tilted edge).
ROOT_SKIP_PX = 1.5
ROOT_ROWS_PX = 3.0
ROOT_MARGIN_PX = 3
#: ... its standard error at least this (px): a bulge's outline placed to a tenth of a pixel.
ROOT_FLOOR_PX = 0.1
#: The liquid's interior level: its bodies eroded by this (px; a row's drops are small, a nozzle's
#: calibration erodes by 4).
ROW_LEVEL_ERODE_PX = 2
#: States: weak beyond WEAK_K robust SDs (at least WEAK_FLOOR of the median); deviated beyond DEVIATED_MRAD.
WEAK_K = 3.0
WEAK_FLOOR = 0.01
DEVIATED_MRAD = 10.0
STATES = ("ok", "missing", "weak", "deviated", "satellites")


@dataclass(frozen=True)
class Plate:
    """Lower edge of the nozzle plate: ``row = row0 + slope * col`` (canonical frame, px)."""

    row0: float
    slope: float
    rms_px: float
    n_cols: int

    def row_at(self, col):
        return self.row0 + self.slope * np.asarray(col, float)


def rough_transmission(image: np.ndarray) -> np.ndarray:
    """The frame over its bright level (95th percentile): enough to see what is dark."""
    img = np.asarray(image, np.float32)
    level = float(np.percentile(img[::4, ::4], 95))
    return img / max(level, 1e-6)


def find_plate(t: np.ndarray, threshold: float = 0.5) -> Plate | None:
    """The plate's lower edge, or None when the top edge is not a plate (dark over less than
    `PLATE_MIN_WIDTH` of the top row, or no straight lower edge)."""
    h, w = t.shape
    dark = t < threshold
    if dark[0].mean() < PLATE_MIN_WIDTH:
        return None
    bright = ~dark
    r = np.argmax(bright, axis=0)  # first bright row per column
    ok = bright[r, np.arange(w)] & (r > 0) & dark[0]
    cols = np.nonzero(ok)[0]
    if cols.size < 0.5 * w:
        return None
    r = r[cols]
    t0, t1 = t[r - 1, cols], t[r, cols]
    edge = (r - 1) + np.clip((threshold - t0) / np.maximum(t1 - t0, 1e-6), 0.0, 1.0)
    med = np.median(edge)
    keep = np.abs(edge - med) < 3.0
    for _ in range(3):
        if keep.sum() < 10:
            return None
        coef = np.polyfit(cols[keep], edge[keep], 1)
        res = edge - np.polyval(coef, cols)
        keep = np.abs(res) < max(3.0 * MAD_TO_SIGMA * np.median(np.abs(res[keep])), 0.3)
    straight = np.abs(res) < 3.0
    if straight.sum() < PLATE_MIN_STRAIGHT * w:
        return None
    return Plate(float(coef[1]), float(coef[0]), float(np.sqrt(np.mean(res[keep] ** 2))), int(keep.sum()))


def _components(t: np.ndarray, plate: Plate, threshold: float):
    """Labelled dark bodies below the plate: (n, labels, stats, centroids), the plate cut away."""
    h, w = t.shape
    below = np.arange(h)[:, None] > plate.row_at(np.arange(w))[None, :] + 0.5
    mask = ((t < threshold) & below).astype(np.uint8)
    return cv2.connectedComponentsWithStats(mask, connectivity=8)


def _line_groups(cols: np.ndarray, sizes: np.ndarray) -> list[np.ndarray]:
    """Indices of bodies grouped into lines: sorted by column, split where the gap is wider than
    1.5 drop sizes (the largest; at least 10 px): the bodies of one line lie within a fraction of
    a drop of its axis, two nozzles a pitch apart."""
    if cols.size == 0:
        return []
    order = np.argsort(cols)
    gap = max(1.5 * float(np.max(sizes)), 10.0)
    groups, cur = [], [order[0]]
    for a, b in zip(order[:-1], order[1:]):
        if cols[b] - cols[a] > gap:
            groups.append(np.array(cur))
            cur = []
        cur.append(b)
    groups.append(np.array(cur))
    return groups


def row_layout(image: np.ndarray) -> Plate | None:
    """The plate when ``image`` (canonical) shows a printhead row, else None (the rule of the module
    docstring: a plate spanning the top, two or more separate drop lines below it)."""
    t = rough_transmission(image)
    plate = find_plate(t)
    if plate is None:
        return None
    n, lab, stats, cen = _components(t, plate, 0.5)
    h, w = t.shape

    def liquid(k):  # not noise, not cut by the frame's border (a vignetted corner), not a sliver of the plate's edge
        x0, y0, bw, bh, area = stats[k]
        if area < MIN_BODY_AREA_PX or x0 == 0 or x0 + bw >= w or y0 + bh >= h:
            return False
        return bh >= 5 or y0 > plate.row_at(x0 + 0.5 * bw) + 1.5

    big = [k for k in range(1, n) if liquid(k)]
    if len(big) < 2:
        return None
    cols = cen[big, 0]
    sizes = np.maximum(stats[big, cv2.CC_STAT_WIDTH], stats[big, cv2.CC_STAT_HEIGHT]).astype(float)
    areas = stats[big, cv2.CC_STAT_AREA].astype(float)
    # drop lines of nozzles of one head carry drops of like size: a speck of dust beside one
    # nozzle's drops is no second nozzle (a line counts when its largest body has at least
    # MIN_LINE_AREA_RATIO of the largest line's)
    mains = np.array([areas[g].max() for g in _line_groups(cols, sizes)])
    return plate if int(np.sum(mains >= MIN_LINE_AREA_RATIO * mains.max())) >= 2 else None


#: A scan's frame names carry the nozzle's label: ``nozzle_03.png``, ``scan-nozzle7.tif``, ``noz12_...``.
SCAN_LABEL = r"(?:^|[^a-z])noz(?:zle)?[ _-]?(\d+)"


def scan_labels(meta) -> dict | None:
    """file -> nozzle label when every frame's name carries one (`SCAN_LABEL`) and there are two
    labels or more: a scanning drop watcher's folder (one nozzle per frame); else None."""
    import re

    out = {}
    for f in meta.frames:
        m = re.search(SCAN_LABEL, Path(f.file).stem, re.IGNORECASE)
        if m is None:
            return None
        out[f.file] = int(m.group(1))
    return out if len(set(out.values())) >= 2 else None


def scan_layout(seq) -> tuple[Plate, dict] | None:
    """(plate, labels) of a scan: frame names labelled by nozzle (`scan_labels`) and a plate
    spanning the top of the first frame; else None."""
    labels = scan_labels(seq.meta)
    if labels is None:
        return None
    fr = seq.read(0)
    if fr.error is not None:
        return None
    plate = find_plate(rough_transmission(fr.image))
    return None if plate is None else (plate, labels)


# ----------------------------------------------------------------------------- measurement
@dataclass
class Body:
    frame: int
    file: str
    delay_us: float
    row_px: float
    col_px: float
    volume_nl: float
    volume_uncertainty_nl: float
    area_px: int
    size_px: float
    attached: bool
    body_class: str = "unassigned"
    nozzle: int | None = None
    #: liquid hanging from the plate: the column where it leaves the plate (its dark pixels' weighted
    #: centroid in the first rows below the plate's edge)
    root_col_px: float = float("nan")


@dataclass
class Line:
    """A drop line of one frame: its flying bodies (main drop first) and the liquid still hanging
    from the plate in its column (``roots``: a meniscus bulge or a ligament's root)."""

    frame: int
    bodies: list
    nozzle: int | None = None
    roots: list = field(default_factory=list)

    @property
    def main(self) -> Body:
        return self.bodies[0]


@dataclass
class Track:
    """One nozzle's drop lines over the frames and its fitted trajectory."""

    lines: list
    plate_col: float = float("nan")
    angle_mrad: float = float("nan")
    angle_u_mrad: float = float("nan")
    velocity_m_s: float = float("nan")
    velocity_u_m_s: float = float("nan")
    nozzle: int | None = None
    notes: list = field(default_factory=list)
    #: liquid at the plate in frames where its drop flew out of its column (a crosstalk drop)
    extra_roots: list = field(default_factory=list)


def _frame_bodies(k, ref, img, inv_bg, plate, thr, sigma, level, noise_t, px) -> list[Body]:
    from dropvision.frame.edges import body_edges
    from dropvision.frame.volume import (NL_PER_UM3, asymmetry_uncertainty_px3, edge_definition_px, integrate,
                                   interpolation_error_px, random_volume_uncertainty_px3, volume_uncertainty_px3)

    t = img.astype(np.float32) * inv_bg
    h, w = t.shape
    n, lab, stats, cen = _components(t, plate, thr)
    out = []
    for j in range(1, n):
        x0, y0, bw, bh, area = stats[j]
        if area < MIN_BODY_AREA_PX:
            continue
        if x0 == 0 or y0 + bh >= h or x0 + bw >= w:
            continue  # cut by the frame's border: not measurable
        top = float(plate.row_at(x0 + 0.5 * bw))
        attached = y0 <= top + 1.5
        if attached and bh < 5:
            continue  # a sliver of the plate's edge (`row_layout`'s rule)
        ed = body_edges(img, inv_bg, lab, j, (x0, y0, x0 + bw, y0 + bh), thr)
        vol = integrate(ed, 0.0, top if attached else None, sigma)
        if vol.volume_px3 <= 0:
            continue
        definition = edge_definition_px(vol, level, noise_t)
        slope = ed.slope_t_per_px if np.isfinite(ed.slope_t_per_px) and ed.slope_t_per_px > 0 else 0.3
        u = math.hypot(volume_uncertainty_px3(vol, interpolation_error_px(sigma), definition_px=definition),
                       random_volume_uncertainty_px3(vol, noise_t / slope),
                       0.0 if attached else asymmetry_uncertainty_px3(ed))  # a free drop: one of revolution
        scale = px ** 3 * NL_PER_UM3
        root = float("nan")
        if attached:  # where the liquid leaves the plate: the first rows below the edge, weighted by darkness
            # (every pixel of those rows across the body and a margin: a threshold would cut one side's
            # blurred edge and not the other's)
            ca, cb = max(x0 - ROOT_MARGIN_PX, 0), min(x0 + bw + ROOT_MARGIN_PX, w)
            ra, rb = y0, min(y0 + int(math.ceil(ROOT_SKIP_PX + ROOT_ROWS_PX)) + 3, h)
            rr, cc = np.mgrid[ra:rb, ca:cb]
            below = rr - plate.row_at(cc)  # the plate edge's own blur left out: it runs along the plate
            near = (below >= ROOT_SKIP_PX) & (below <= ROOT_SKIP_PX + ROOT_ROWS_PX)
            wgt = np.where(near, np.clip(1.0 - t[ra:rb, ca:cb], 0.0, None), 0.0)
            if wgt.sum() > 0:
                root = float(np.sum(wgt * cc) / wgt.sum())
        out.append(Body(k, ref.file, float(ref.delay_us), float(vol.centroid_row), float(vol.centroid_col),
                        vol.volume_px3 * scale, u * scale, int(area), float(max(bw, bh)), bool(attached),
                        root_col_px=root))
    return out


def _lines(bodies: list[Body]) -> list[Line]:
    if not bodies:
        return []
    cols = np.array([b.col_px for b in bodies])
    sizes = np.array([b.size_px for b in bodies])
    lines = []
    for g in _line_groups(cols, sizes):
        bs = sorted((bodies[i] for i in g), key=lambda b: -b.volume_nl)
        flying = [b for b in bs if not b.attached]
        # liquid hanging from the plate behind a larger flying drop is the nozzle's root, not a
        # satellite; a line whose largest body is still attached (before break-off) keeps it as its main
        roots = [b for b in bs if b.attached] if not bs[0].attached else []
        if roots:
            bs = flying
        bs[0].body_class = "attached" if bs[0].attached else "main_drop"
        for b in bs[1:]:
            b.body_class = "attached" if b.attached else "satellite"
        for b in roots:
            b.body_class = "attached"
        lines.append(Line(bs[0].frame, bs, roots=roots))
    return lines


def _tracks(lines: list[Line]) -> list[Track]:
    """Drop lines of every frame joined into one track per nozzle: clusters of their main drops'
    columns (the same gap rule as within a frame)."""
    if not lines:
        return []
    cols = np.array([ln.main.col_px for ln in lines])
    sizes = np.array([ln.main.size_px for ln in lines])
    tracks = []
    for g in _line_groups(cols, sizes):
        by_frame: dict = {}
        for i in g:
            ln = lines[i]
            if ln.frame not in by_frame or ln.main.volume_nl > by_frame[ln.frame].main.volume_nl:
                by_frame[ln.frame] = ln
        tracks.append(Track(sorted(by_frame.values(), key=lambda ln: ln.main.delay_us)))
    return tracks


def _predict(tr: Track, delay: float, vr0: float) -> tuple[float, float]:
    """Where a track's main drop is at ``delay``: its straight line over the delays (two or more),
    else straight down at the row's typical speed ``vr0`` (px/µs)."""
    d = np.array([ln.main.delay_us for ln in tr.lines])
    r = np.array([ln.main.row_px for ln in tr.lines])
    c = np.array([ln.main.col_px for ln in tr.lines])
    if np.ptp(d) > 0:
        kr, r0 = np.polyfit(d, r, 1)
        kc, c0 = np.polyfit(d, c, 1)
        return float(r0 + kr * delay), float(c0 + kc * delay)
    return float(r[-1] + vr0 * (delay - d[-1])), float(c[-1])


def _link(lines: list[Line], first: list[Track]) -> list[Track]:
    """Tracks by trajectory: frame after frame (by delay), each drop line joins the track whose
    straight line predicts it best (within half the smallest spacing of the lines), so that a
    deviated drop flying past its neighbour's column stays with its own nozzle.  ``first``: the
    tracks by column, which give the row's typical downward speed for tracks of one point."""
    speeds = []
    for tr in first:
        d = np.array([ln.main.delay_us for ln in tr.lines])
        if np.ptp(d) > 0:
            speeds.append(np.polyfit(d, [ln.main.row_px for ln in tr.lines], 1)[0])
    if not speeds:
        return first
    vr0 = float(np.median(speeds))
    by_frame: dict = {}
    for ln in lines:
        by_frame.setdefault(ln.frame, []).append(ln)
    gaps = [np.min(np.diff(np.sort([ln.main.col_px for ln in lns]))) for lns in by_frame.values() if len(lns) > 1]
    gate = 0.5 * float(np.median(gaps)) if gaps else float("inf")
    tracks: list[Track] = []
    for f in sorted(by_frame, key=lambda f: (by_frame[f][0].main.delay_us, f)):
        lns = by_frame[f]
        delay = lns[0].main.delay_us
        pairs = []
        for ti, tr in enumerate(tracks):
            pr, pc = _predict(tr, delay, vr0)
            for li, ln in enumerate(lns):
                pairs.append((math.hypot(ln.main.row_px - pr, ln.main.col_px - pc), ti, li))
        used_t, used_l = set(), set()
        for dist, ti, li in sorted(pairs):
            if dist > gate or ti in used_t or li in used_l:
                continue
            tracks[ti].lines.append(lns[li])
            used_t.add(ti)
            used_l.add(li)
        tracks.extend(Track([ln]) for li, ln in enumerate(lns) if li not in used_l)
    return tracks


def _fit_trajectory(tr: Track, plate: Plate, px: float) -> None:
    """Velocity, angle and plate column of a track: straight lines row(t), col(t) fitted to its
    main drops (two delays or more), else the line through its bodies (one frame)."""
    mains = [ln.main for ln in tr.lines if not ln.main.attached]
    delays = np.array([b.delay_us for b in mains])
    if len(mains) >= 2 and np.ptp(delays) > 0:
        rows = np.array([b.row_px for b in mains])
        cols = np.array([b.col_px for b in mains])
        A = np.vstack([np.ones_like(delays), delays]).T
        (r0, vr), res_r, *_ = np.linalg.lstsq(A, rows, rcond=None)
        (c0, vc), res_c, *_ = np.linalg.lstsq(A, cols, rcond=None)
        n = len(mains)
        sxx = float(np.sum((delays - delays.mean()) ** 2))
        floor = 0.02  # px: centroid placement when the fit has no residual degrees of freedom
        sr = math.sqrt(float(res_r[0]) / (n - 2)) if n > 2 and res_r.size else floor
        sc = math.sqrt(float(res_c[0]) / (n - 2)) if n > 2 and res_c.size else floor
        sr, sc = max(sr, floor), max(sc, floor)
        se_vr, se_vc = sr / math.sqrt(sxx), sc / math.sqrt(sxx)
        speed = math.hypot(vr, vc)
        tr.velocity_m_s = speed * px
        tr.velocity_u_m_s = math.hypot(vr * se_vr, vc * se_vc) / speed * px
        tr.angle_mrad = math.atan2(vc, vr) * 1e3
        tr.angle_u_mrad = math.hypot(vr * se_vc, vc * se_vr) / speed**2 * 1e3
        # where the trajectory meets the plate: row(t) = plate row
        tp = (plate.row_at(c0) - r0) / vr if vr != 0 else float("nan")
        tr.plate_col = float(c0 + vc * tp)
        return
    ln = tr.lines[0]
    bs = [b for b in ln.bodies if not b.attached]
    if ln.main.attached or not bs:
        tr.plate_col = ln.main.col_px
    elif len(bs) >= 2:
        rows = np.array([b.row_px for b in bs])
        cols = np.array([b.col_px for b in bs])
        k = np.polyfit(rows, cols, 1)[0] if np.ptp(rows) > 2 * max(b.size_px for b in bs) else 0.0
        tr.plate_col = float(ln.main.col_px - k * (ln.main.row_px - plate.row_at(ln.main.col_px)))
    else:
        tr.plate_col = ln.main.col_px


def _grid(cols: np.ndarray, pitch_px: float | None) -> tuple[float, float, np.ndarray, np.ndarray, float]:
    """The nozzle grid ``col = c0 + pitch * k``: (c0, pitch, k per column, inliers, grid residual
    rms px).  With no pitch given: the smallest spacing, then a least-squares fit."""
    order = np.argsort(cols)
    c = cols[order]
    if c.size == 1:
        return float(c[0]), float(pitch_px or float("nan")), np.zeros(1, int), np.ones(1, bool), float("nan")
    if pitch_px is None:
        d = np.diff(c)
        # two columns closer than a fifth of the typical spacing are one nozzle's (two tracks of it)
        d = d[d > 0.2 * float(np.median(d))] if np.any(d > 0.2 * float(np.median(d))) else d
        p0 = float(np.min(d))
        near = d < 1.5 * p0
        p0 = float(np.median(d[near]))
    else:
        p0 = float(pitch_px)
    k = np.rint((c - c[0]) / p0).astype(int)
    p = p0
    if pitch_px is None and np.unique(k).size >= 3:
        # robust start (Siegel's repeated median of the pairwise spacings): one deviated nozzle among
        # four cannot pull the pitch, as a fit through it and the nearest two would
        p = float(np.median([np.median([(c[j] - c[i]) / (k[j] - k[i]) for j in range(c.size) if k[j] != k[i]])
                             for i in range(c.size)]))
    c0 = float(np.median(c - p * k))  # robust start: a deviated nozzle does not pull it
    res = c - (c0 + p * k)
    inl = np.abs(res) <= max(3.0 * MAD_TO_SIGMA * float(np.median(np.abs(res))), 1.0)
    for _ in range(3):
        if pitch_px is None and np.unique(k[inl]).size >= 2:
            p, c0 = np.polyfit(k[inl], c[inl], 1)
        else:
            c0 = float(np.mean(c[inl] - p * k[inl]))
        res = c - (c0 + p * k)
        s = MAD_TO_SIGMA * float(np.median(np.abs(res[inl])))
        inl = np.abs(res) <= max(3.0 * s, 1.0)
    dof = int(inl.sum()) - (2 if pitch_px is None else 1)
    rms = float(np.sqrt(np.sum(res[inl] ** 2) / dof)) if dof > 0 else float("nan")
    back = np.empty_like(order)
    back[order] = np.arange(order.size)
    return float(c0), float(p), k[back], inl[back], rms


def _robust_sd(x: np.ndarray) -> float:
    x = x[np.isfinite(x)]
    if x.size < 3:
        return float("nan")
    return robust_sigma(x)


def _cv(x: np.ndarray, u: np.ndarray) -> tuple[float, float]:
    """CV (sample SD / mean) of ``x`` and its standard uncertainty from the values' ``u``."""
    ok = np.isfinite(x)
    x, u = x[ok], np.where(np.isfinite(u[ok]), u[ok], 0.0)
    n = x.size
    if n < 2:
        return float("nan"), float("nan")
    m, s = float(x.mean()), float(x.std(ddof=1))
    cv = s / m
    grad = (x - m) / ((n - 1) * s * m) - cv / (n * m) if s > 0 else np.full(n, 1.0 / (math.sqrt(n) * m))
    return cv, float(np.sqrt(np.sum((grad * u) ** 2)))


def _end_gaps(meta, nozzle_count, c0: float, pitch: float, kmin: int, n_noz: int, width_px: int, notes):
    """Missing nozzles at the row's ends: with the row's nozzle count given (``nozzle_count`` in
    sequence.json or ``--nozzle-count``) the found span short of it is made up at the end(s) where
    the grid still lies inside the frame (the row is in view); where both ends could hold them, or
    with no count, a note says the ends cannot be judged.  Returns (kmin, n_noz, end nozzle ids)."""
    from dropvision.io.sequence import SequenceError

    given = nozzle_count if nozzle_count is not None else meta.extra.get("nozzle_count")
    src = "command line --nozzle-count" if nozzle_count is not None else f"{meta.path / 'sequence.json'}"
    if given is None:
        notes.append("no nozzle_count given: a missing nozzle at either end of the row cannot be judged (a gap in the "
                     "pitch shows only between live nozzles)")
        return kmin, n_noz, []
    if isinstance(given, bool) or not isinstance(given, (int, float)) or given != int(given) or given < 1:
        raise SequenceError(f"{src}: nozzle_count must be a whole number >= 1, got {given!r}")
    count = int(given)
    if n_noz > count:
        raise SequenceError(f"{src}: nozzle_count is {count} but the drops lie on {n_noz} positions of the pitch grid")
    m = count - n_noz
    if m == 0:
        return kmin, n_noz, []
    kmax = kmin + n_noz - 1
    fits = [a for a in range(m + 1) if c0 + pitch * (kmin - a) >= 0 and c0 + pitch * (kmax + m - a) <= width_px - 1]
    if len(fits) != 1:
        notes.append(f"nozzle_count {count}: {m} nozzle(s) missing at the row's ends, but "
                     + ("either end could hold them in the frame" if fits else "the frame cannot hold the row")
                     + ": which end cannot be told; nozzles numbered from the first live one")
        return kmin, n_noz, []
    a = fits[0]
    notes.append(f"nozzle_count {count}: {a} missing at the left end, {m - a} at the right (the frame holds the row's "
                 "grid on that side only)")
    return kmin - a, count, list(range(a)) + list(range(count - (m - a), count))


def _adopt(f: Track, tr: Track) -> None:
    """``tr``'s liquid at the plate becomes flying track ``f``'s root (in frames where ``f``'s drop left its column)."""
    f.extra_roots.extend(ln.main for ln in tr.lines)
    for ln in tr.lines:
        if not np.isfinite(ln.main.root_col_px):
            ln.main.root_col_px = ln.main.col_px


def _adopt_lone_roots(tracks: list[Track]) -> list[Track]:
    """The tracks that are nozzles: liquid at the plate alone in its column joins the flying track
    it belongs to (`_adopt`)."""
    # liquid at the plate alone in its column (its drop flew into a neighbour's column, or left the
    # frame) is that nozzle's root when a drop's trajectory meets the plate there, not a nozzle of its own
    flying = [tr for tr in tracks if any(not ln.main.attached for ln in tr.lines)]
    fly_ids = {id(tr) for tr in flying}
    kept, alone = [], []
    for tr in tracks:
        if id(tr) in fly_ids or not flying:
            kept.append(tr)
            continue
        col = float(np.median([ln.main.col_px for ln in tr.lines]))
        near = min(flying, key=lambda f: abs(f.plate_col - col))
        if abs(near.plate_col - col) <= max(1.5 * max(ln.main.size_px for ln in tr.lines), 10.0):
            _adopt(near, tr)
        else:
            alone.append((col, tr))
    # ... and in one frame a drop with no liquid at the plate above it came from the nearest liquid with
    # no drop below it (crosstalk: the drop leaned past its column), when nearer to it than halfway to
    # any other nozzle's place
    orphans = [f for f in flying if not f.extra_roots and not any(ln.roots for ln in f.lines)]
    for col, tr in sorted(alone, key=lambda ct: ct[0]):
        others = [f.plate_col for f in kept if f not in orphans] + [c for c, t in alone if t is not tr]
        f = min(orphans, key=lambda f: abs(f.plate_col - col)) if orphans else None
        room = min((abs(c - col) for c in others), default=float("inf"))
        if f is not None and abs(f.plate_col - col) < 0.5 * room:
            _adopt(f, tr)
            f.plate_col = float(np.median([b.root_col_px for b in f.extra_roots]))
            orphans = [o for o in orphans if o is not f]
        else:
            kept.append(tr)
    return kept


def _given_pitch(meta, nozzle_pitch_um):
    """The pitch (µm) given on the command line or in sequence.json (None: not given); a bad one is an error."""
    given = nozzle_pitch_um if nozzle_pitch_um is not None else meta.extra.get("nozzle_pitch_um")
    if given is not None and not (isinstance(given, (int, float)) and np.isfinite(given) and given > 0):
        from dropvision.io.sequence import SequenceError
        raise SequenceError(f"{meta.path / 'sequence.json'}: nozzle_pitch_um must be a number > 0, got {given!r}")
    return given


def _one_track_per_position(tracks: list[Track], c0: float, pitch: float, kmin: int, notes: list) -> dict:
    """Nozzle -> track; two tracks on one grid position: the nearer keeps it (the other's bodies
    counted as that nozzle's, its drops not in its statistics)."""
    seen: dict = {}
    for tr in tracks:
        g = c0 + pitch * (tr.nozzle + kmin)
        if tr.nozzle in seen:
            i, other = tr.nozzle, seen[tr.nozzle]
            if abs(tr.plate_col - g) < abs(other.plate_col - g):
                other.nozzle, seen[i] = None, tr
                loser = other
            else:
                tr.nozzle, loser = None, tr
            # the farther's bodies come from that nozzle too (a satellite whose main drop left the frame)
            for ln in loser.lines:
                for b in ln.bodies + ln.roots:
                    b.nozzle = i
            notes.append(f"two drop lines meet the plate at nozzle {i}: the farther one's bodies counted as that "
                         "nozzle's, its drops not in its statistics")
        else:
            seen[tr.nozzle] = tr
    return seen


def _grid_se(kk: np.ndarray, inl: np.ndarray, grid_rms: float, pitch_given: bool, kmin: int):
    """The standard error (px) of each grid position, as a function of the nozzle id."""
    # the drops' scatter about the grid (their angles' spread times their distance from the plate)
    # through the fitted offset and, with no pitch given, the fitted pitch
    k_in = kk[inl].astype(float)
    # the residuals' rms has few degrees of freedom (one per nozzle less the fitted offset, and pitch):
    # the standard deviation of the Student-t distribution it implies, sqrt(dof / (dof - 2)) x its
    # value (dof at least 3), is the grid's standard uncertainty
    dof = max(int(k_in.size) - (1 if pitch_given else 2), 3)
    s_grid = (grid_rms if np.isfinite(grid_rms) else 0.5) * math.sqrt(dof / (dof - 2))
    sxx = float(np.sum((k_in - k_in.mean()) ** 2)) if k_in.size else 0.0

    def grid_se(i: int) -> float:
        if k_in.size == 0:
            return 0.5
        v = 1.0 / k_in.size + ((i + kmin - k_in.mean()) ** 2 / sxx if not pitch_given and sxx > 0 else 0.0)
        return s_grid * math.sqrt(v)

    return grid_se


def _row_nozzles(lines, plate: Plate, px: float, meta, nozzle_pitch_um, pitch_source, notes, nozzle_count=None,
                 width_px: int = 10**9):
    """A row's tracks (by trajectory) on the pitch grid: (track per nozzle, grid column per nozzle,
    its standard error (function), nozzle ids, pitch µm, pitch source, the nozzles' own places at
    the plate, the nozzles missing at the row's ends)."""
    tracks = _link(lines, _tracks(lines))
    for tr in tracks:
        _fit_trajectory(tr, plate, px)
    tracks = _adopt_lone_roots(tracks)
    given = _given_pitch(meta, nozzle_pitch_um)
    pitch_src = (pitch_source or "sequence.json") if given is not None else \
        "estimated from the found nozzles (smallest spacing, least-squares grid)"
    cols = np.array([tr.plate_col for tr in tracks])
    # the liquid at the plate gives a nozzle's place directly (independent of its drops' angles): the
    # grid is fitted to those places where two or more nozzles show them
    roots = [_root_col(tr) for tr in tracks]
    have = np.array([np.isfinite(r[0]) for r in roots], bool)
    if have.sum() >= 2:
        cols = np.where(have, [r[0] for r in roots], cols)
        pitch_src = pitch_src.replace("found nozzles", "liquid at the plate of the found nozzles")
    c0, pitch, kk, inl, grid_rms = _grid(cols, None if given is None else float(given) / px)
    kmin = int(kk.min()) if kk.size else 0
    n_noz = int(kk.max() - kmin + 1) if kk.size else 0
    kmin, n_noz, ends = _end_gaps(meta, nozzle_count, c0, pitch, kmin, n_noz, width_px, notes)
    for tr, k in zip(tracks, kk):
        tr.nozzle = int(k - kmin)
    seen = _one_track_per_position(tracks, c0, pitch, kmin, notes)
    grid_cols = c0 + pitch * (np.arange(n_noz) + kmin)
    grid_se = _grid_se(kk, inl, grid_rms, given is not None, kmin)
    own = {tr.nozzle: r for tr, r in zip(tracks, roots) if tr.nozzle is not None and np.isfinite(r[0])}
    return (seen, {i: float(grid_cols[i]) for i in range(n_noz)}, grid_se, list(range(n_noz)), float(pitch * px),
            pitch_src, own, ends)


def _root_col(tr: Track) -> tuple[float, float]:
    """Where a track's liquid leaves the plate (its frames' roots, the largest of each): (column px,
    standard error px: their scatter over the frames, at least ROOT_FLOOR_PX); nan where none hangs."""
    c = np.array([max(ln.roots, key=lambda b: b.volume_nl).root_col_px for ln in tr.lines if ln.roots]
                 + [b.root_col_px for b in tr.extra_roots])
    c = c[np.isfinite(c)]
    if c.size == 0:
        return float("nan"), float("nan")
    sd = _robust_sd(c) if c.size >= 3 else float("nan")
    return float(np.median(c)), max(sd / math.sqrt(c.size) if np.isfinite(sd) else 0.0, ROOT_FLOOR_PX)


def _scan_nozzles(lines, scan: dict, plate: Plate, px: float):
    """A scan's tracks: one per label (its frames' largest drop lines); the stage brings every nozzle
    to one place, so each nozzle's column at the plate is the scan's common column (the median of
    the trajectories' plate columns; its standard error from their scatter)."""
    labels = sorted(set(scan.values()))
    by_label: dict = {}
    for ln in lines:
        d = by_label.setdefault(scan[ln.main.file], {})
        if ln.frame not in d or ln.main.volume_nl > d[ln.frame].main.volume_nl:
            d[ln.frame] = ln
    seen = {}
    for lab in labels:
        if lab in by_label:
            tr = Track(sorted(by_label[lab].values(), key=lambda ln: ln.main.delay_us), nozzle=lab)
            _fit_trajectory(tr, plate, px)
            seen[lab] = tr
    cols = np.array([tr.plate_col for tr in seen.values()])
    ref = float(np.median(cols)) if cols.size else float("nan")
    sd = _robust_sd(cols)
    se = sd / math.sqrt(cols.size) if np.isfinite(sd) else 0.5

    return (seen, {lab: ref for lab in labels}, lambda i: se, labels, float("nan"),
            "a scan: one nozzle per frame, brought to one place by the stage", {}, [])


@dataclass(frozen=True)
class _Photometry:
    """A row's photometric reference from its first frame: the inverse background, the first frame's
    transmission, the plate, the liquid's interior level, the edge threshold, the transmission's
    noise and the edge blur (px)."""

    inv_bg: np.ndarray
    t0: np.ndarray
    plate: Plate
    level: float
    thr: float
    noise_t: float
    sigma: float


def _reference_frames(seq) -> tuple[np.ndarray, list[np.ndarray]]:
    """The first readable frame's image and the background's frames: up to five spread evenly over
    the sequence (the unreadable ones left out).  Only these are held in memory: the frames are
    measured one at a time (`_measure_frames`)."""
    n = len(seq)
    first = None
    for k in range(n):
        fr = seq.read(k)
        if fr.error is None:
            first = (k, fr.image)
            break
    if first is None:
        from dropvision.io.sequence import SequenceError
        raise SequenceError(f"{seq.meta.path}: no readable frame of the printhead row")
    pick = []
    for i in np.unique(np.linspace(0, n - 1, min(5, n)).astype(int)):
        if i <= first[0]:
            if i == first[0]:
                pick.append(first[1])
            continue
        fr = seq.read(int(i))
        if fr.error is None:
            pick.append(fr.image)
    return first[1], pick


def _measure_frames(seq, ph: "_Photometry", px: float):
    """Every frame's bodies and drop lines, one frame in memory at a time: (bodies, lines, the
    unreadable frames' error rows, the number measured, their delays)."""
    bodies: list[Body] = []
    lines: list[Line] = []
    errors, delays, n_measured = [], set(), 0
    for k in range(len(seq)):
        fr = seq.read(k)
        if fr.error is not None:
            errors.append({"file": fr.ref.file, "page": fr.ref.page, "delay_us": fr.ref.delay_us, "reason": fr.error})
            continue
        bs = _frame_bodies(k, fr.ref, fr.image, ph.inv_bg, ph.plate, ph.thr, ph.sigma, ph.level, ph.noise_t, px)
        bodies.extend(bs)
        lines.extend(_lines(bs))
        delays.add(fr.ref.delay_us)
        n_measured += 1
    return bodies, lines, errors, n_measured, delays


def _edge_blur_px(img0, t0, inv_bg, lab, stats, thr: float, level: float) -> float:
    """Edge blur (px): the median edge-spread sigma of the first frame's six largest bodies (1.0 if none)."""
    from dropvision.calibrate.blur import esf_sigma_px
    from dropvision.frame.edges import body_edges
    from dropvision.frame.volume import outline

    sig = []
    for j in np.argsort(-stats[1:, cv2.CC_STAT_AREA])[:6] + 1:
        x0, y0, bw, bh, area = stats[j]
        if area < 50:
            continue
        ed = body_edges(img0, inv_bg, lab, j, (x0, y0, x0 + bw, y0 + bh), thr)
        rows, left, right = outline(ed)
        s = esf_sigma_px(t0, rows, left, right, level)
        if np.isfinite(s):
            sig.append(s)
    return float(np.median(sig)) if sig else 1.0


def _row_photometry(first: np.ndarray, pick: list[np.ndarray], plate_hint: Plate, scan) -> _Photometry:
    """Background from ``pick`` (`_reference_frames`), then the first frame's plate, liquid level,
    edge threshold, noise and edge blur."""
    from dropvision.calibrate.background import estimate_background
    from dropvision.calibrate.calibration import interior_level
    from dropvision.calibrate.calibration_pass import transmission_noise
    from dropvision.frame.edges import edge_threshold

    # a scan's drops sit at one place in every frame: no static dust looked for (it would be the liquid)
    bg = estimate_background(pick, static_dust=len(pick) >= 3 and scan is None).background
    inv_bg = (1.0 / np.maximum(bg, 1e-6)).astype(np.float32)
    t0 = first.astype(np.float32) * inv_bg
    plate = find_plate(t0) or plate_hint
    # the liquid's interior level (the calibration's estimator on the first frame's bodies: filled,
    # eroded by ROW_LEVEL_ERODE_PX, lens spot excluded; 0.1 where fewer than 20 pixels remain) and the
    # edge level
    nl, lab, stats, _ = _components(t0, plate, 0.5)
    level = interior_level(t0, lab > 0, erode_px=ROW_LEVEL_ERODE_PX)
    level = level if np.isfinite(level) else 0.1
    thr = edge_threshold(level)
    # noise of the transmission: the bright background's pixel-to-pixel scatter below the plate
    # (the calibration's estimator: bright neighbouring pairs only, not the liquid hanging there)
    below = max(0, int(plate.row_at(0)) + 2)
    noise_t = transmission_noise(t0[below:, :], 0.0, first[below:, :])
    # edge blur: the edge-spread functions of the first frame's large bodies
    sigma = _edge_blur_px(first, t0, inv_bg, lab, stats, thr, level)
    return _Photometry(inv_bg, t0, plate, level, thr, noise_t, sigma)


def _angle_note(single: bool, scan, own: dict, seen: dict, pitch_src: str) -> str | None:
    """The note on how a single frame's angles are measured (None for a sequence of delays or a scan)."""
    if single and scan is None and own and len(own) == len(seen):
        return ("one delay: each nozzle's angle is measured from where its liquid leaves the plate (a meniscus "
                "or a ligament's root) to its drop, from the plate's normal")
    if single and scan is None:
        return ("one delay: each nozzle's angle is measured from the pitch grid fitted to the drops themselves, so "
                "a tilt common to the row" + ("" if "estimated" not in pitch_src else
                                              " (and, with the pitch estimated, a fan linear across it)")
                + " cannot be told from the grid's offset" + ("" if "estimated" not in pitch_src else " and pitch")
                + " in one frame: the angles are relative to the row's mean direction; their uncertainty "
                "includes the grid's (the row's angle spread over the nozzles, Student-t); a sequence of delays "
                "measures each trajectory on its own")
    return None


_MISSING = dict(volume_nl=np.nan, volume_uncertainty_nl=np.nan, velocity_m_s=np.nan, velocity_uncertainty_m_s=np.nan,
                angle_mrad=np.nan, angle_uncertainty_mrad=np.nan, satellites=0.0, satellite_volume_nl=np.nan,
                n_frames=0)


def _single_frame_angle(m: Body, i: int, plate: Plate, own: dict, grid_col: dict, grid_se, tilt: float):
    """A single frame's angle (mrad) of nozzle ``i``'s main drop ``m`` and its uncertainty: from the
    nozzle's own place at the plate, else from its grid position."""
    if i in own:  # from the nozzle's own place at the plate: an angle from the plate's normal
        c_i, se_i = own[i]
        dz = m.row_px - plate.row_at(c_i)
        ang = (math.atan2(m.col_px - c_i, dz) + tilt) * 1e3
    else:
        c_i, se_i = grid_col[i], grid_se(i)
        dz = m.row_px - plate.row_at(c_i)
        # from the grid fitted to the drops (no tilt to add), or to the others' liquid at the plate
        ang = (math.atan2(m.col_px - c_i, dz) + (tilt if own else 0.0)) * 1e3
    return ang, math.hypot(se_i, 0.05) / max(dz, 1.0) * 1e3


def _nozzle_stats(tr: Track, i: int, single: bool, plate: Plate, own: dict, grid_col: dict, grid_se) -> dict:
    """A live nozzle's volume, velocity, angle (each with its uncertainty), satellites and frame count;
    its bodies take its id."""
    for ln in tr.lines:
        for b in ln.bodies + ln.roots:
            b.nozzle = i
    for b in tr.extra_roots:
        b.nozzle = i
    mains = [ln.main for ln in tr.lines]
    vols = np.array([b.volume_nl for b in mains])
    us = np.array([b.volume_uncertainty_nl for b in mains])
    vol = float(vols.mean())
    u_vol = math.hypot(float(us.mean()), float(vols.std(ddof=1)) / math.sqrt(vols.size) if vols.size > 1 else 0.0)
    nsat = np.array([len(ln.bodies) - 1 for ln in tr.lines], float)
    sat_vol = [sum(b.volume_nl for b in ln.bodies[1:]) for ln in tr.lines if len(ln.bodies) > 1]
    # a trajectory's angle from the plate's normal: a plate tilted by atan(slope) in the image (the camera
    # rolled) turns its normal by as much
    tilt = math.atan(plate.slope)
    if single or not np.isfinite(tr.angle_mrad):
        ang, ang_u = _single_frame_angle(mains[0], i, plate, own, grid_col, grid_se, tilt)
    else:
        ang, ang_u = tr.angle_mrad + tilt * 1e3, tr.angle_u_mrad
    return dict(volume_nl=vol, volume_uncertainty_nl=u_vol,
                velocity_m_s=float("nan") if single else tr.velocity_m_s,
                velocity_uncertainty_m_s=float("nan") if single else tr.velocity_u_m_s,
                angle_mrad=float(ang), angle_uncertainty_mrad=float(ang_u),
                satellites=float(np.median(nsat)), satellite_volume_nl=float(np.mean(sat_vol)) if sat_vol else 0.0,
                n_frames=len(tr.lines))


def _nozzle_rows(ids, seen, grid_col, grid_se, own, ends, plate: Plate, single: bool, scan) -> list[dict]:
    """One row per nozzle of the grid: its place, and its statistics or why it is missing."""
    rows = []
    for i in ids:
        tr = seen.get(i)
        row = {"nozzle": i, "col_px": float(grid_col[i]), "plate_row_px": float(plate.row_at(grid_col[i]))}
        if tr is None:
            why = ("no drop where the others have one" + ("" if scan is not None else " (a gap in the pitch)")
                   if i not in ends else "no drop at the row's end (nozzle_count)")
            row.update(state="missing", reason=why, **_MISSING)
        else:
            row.update(_nozzle_stats(tr, i, single, plate, own, grid_col, grid_se))
        rows.append(row)
    return rows


def _line_and_body_tables(lines, bodies):
    """The row's frames table (one row per drop line, its main drop) and bodies table."""
    import pandas as pd

    from dvcore.schema import ROW_BODIES, ROW_FRAMES

    frame_rows, body_rows = [], []
    for ln in lines:
        m = ln.main
        frame_rows.append({"file": m.file, "delay_us": m.delay_us, "nozzle": m.nozzle, "volume_nl": m.volume_nl,
                           "volume_uncertainty_nl": m.volume_uncertainty_nl, "row_px": m.row_px, "col_px": m.col_px,
                           "attached": m.attached, "n_satellites": len(ln.bodies) - 1,
                           "satellite_volume_nl": float(sum(b.volume_nl for b in ln.bodies[1:]))})
    for b in bodies:
        body_rows.append({"file": b.file, "delay_us": b.delay_us, "nozzle": b.nozzle, "body_class": b.body_class,
                          "area_px": b.area_px, "volume_nl": b.volume_nl, "volume_uncertainty_nl": b.volume_uncertainty_nl,
                          "row_px": b.row_px, "col_px": b.col_px})
    ftab = pd.DataFrame(frame_rows, columns=ROW_FRAMES.column_names).astype({"nozzle": "Int64"})
    ftab = ftab.sort_values(["delay_us", "file", "col_px"], kind="stable").reset_index(drop=True)
    btab = pd.DataFrame(body_rows, columns=ROW_BODIES.column_names).astype({"nozzle": "Int64", "area_px": "int64"})
    return ftab, btab


def measure_row(seq, plate_hint: Plate, *, nozzle_pitch_um: float | None = None, pitch_source: str | None = None,
                scan: dict | None = None, nozzle_count: int | None = None):
    """Measure every nozzle of a row sequence: (nozzles, frames, bodies tables, summary dict).
    ``scan``: file -> nozzle label (`scan_labels`): one nozzle per frame."""
    import pandas as pd

    from dvcore.schema import NOZZLES

    meta = seq.meta
    px = float(meta.pixel_size_um)
    ph = _row_photometry(*_reference_frames(seq), plate_hint, scan)
    plate = ph.plate
    bodies, lines, errors, n_measured, delays = _measure_frames(seq, ph, px)
    notes = []
    if scan is not None:
        seen, grid_col, grid_se, ids, pitch_um, pitch_src, own, ends = _scan_nozzles(lines, scan, plate, px)
    else:
        seen, grid_col, grid_se, ids, pitch_um, pitch_src, own, ends = _row_nozzles(
            lines, plate, px, meta, nozzle_pitch_um, pitch_source, notes, nozzle_count, ph.t0.shape[1])
    single = len(delays) < 2
    note = _angle_note(single, scan, own, seen, pitch_src)
    if note is not None:
        notes.append(note)
    rows = _nozzle_rows(ids, seen, grid_col, grid_se, own, ends, plate, single, scan)
    # liquid at the plate belongs to the nozzle at its place (a crosstalk drop's line can pass a
    # neighbour's meniscus): the nearest nozzle's column
    if scan is None and grid_col:
        gc = np.array([grid_col[i] for i in ids])
        for b in bodies:
            if b.attached and b.body_class == "attached" and np.isfinite(b.root_col_px):
                b.nozzle = ids[int(np.argmin(np.abs(gc - b.root_col_px)))]
    _states(rows)
    nozzles = pd.DataFrame(rows)
    nozzles["pass"], nozzles["pass_reason"] = pd_na_bool(len(nozzles)), "no limits given"  # `judge_row`
    nozzles = nozzles[NOZZLES.column_names].astype({"nozzle": "int64", "n_frames": "int64"})
    ftab, btab = _line_and_body_tables(lines, bodies)
    summary = _row_summary(meta, scan, len(seq), n_measured, ids, nozzles, pitch_um, pitch_src, ph, errors, notes)
    return nozzles, ftab, btab, summary


def _row_summary(meta, scan, n: int, n_measured: int, ids, nozzles, pitch_um, pitch_src, ph: _Photometry,
                 errors, notes) -> dict:
    """summary.json of a row (`dvcore.schema.ROW_SUMMARY`, less the pass/fail and provenance keys)."""
    live = nozzles[nozzles.state != "missing"]
    vcv, vcv_u = _cv(live.volume_nl.to_numpy(float), live.volume_uncertainty_nl.to_numpy(float))
    ucv, ucv_u = _cv(live.velocity_m_s.to_numpy(float), live.velocity_uncertainty_m_s.to_numpy(float))
    counts = {s: int((nozzles.state == s).sum()) for s in STATES}
    plate = ph.plate
    return {
        "schema_version": "dropvision.row-summary/1", "kind": "printhead-row", "sequence": str(meta.path),
        "layout": "scan" if scan is not None else "row",
        "n_frames": n, "n_measured": n_measured, "n_nozzles": len(ids), "n_live": int(len(ids) - counts["missing"]),
        "state_counts": counts,
        "pitch_um": pitch_um, "pitch_source": pitch_src,
        "plate_row_px": float(plate.row_at((ph.t0.shape[1] - 1) / 2.0)),
        "plate_slope_mrad": float(math.atan(plate.slope) * 1e3),
        "volume_cv": vcv, "volume_cv_uncertainty": vcv_u, "velocity_cv": ucv, "velocity_cv_uncertainty": ucv_u,
        "limits": {"weak_k": WEAK_K, "weak_floor": WEAK_FLOOR, "deviated_mrad": DEVIATED_MRAD},
        "edge_blur_px": ph.sigma, "liquid_level": ph.level, "edge_threshold": ph.thr,
        "errors": errors, "notes": notes,
    }


def _states(rows: list[dict]) -> None:
    """``state`` and ``reason`` of each live nozzle (the module docstring's rules)."""
    live = [r for r in rows if "state" not in r]
    for key, unit in (("volume_nl", "nl"), ("velocity_m_s", "m/s")):
        x = np.array([r[key] for r in live], float)
        if np.isfinite(x).sum() < 3:
            continue
        med = float(np.nanmedian(x))
        sd = max(_robust_sd(x), WEAK_FLOOR * abs(med))
        ukey = key.replace("_nl", "_uncertainty_nl").replace("_m_s", "_uncertainty_m_s")
        for r in live:
            u = r[ukey] if np.isfinite(r[ukey]) else 0.0
            z = (r[key] - med) / math.hypot(sd, u)
            if np.isfinite(z) and abs(z) > WEAK_K:
                r.setdefault("_why", []).append(("weak", f"{key} {r[key]:.4g} {unit} is {z:+.1f} robust SDs "
                                                 f"({sd:.3g}) from the row's median {med:.4g}"))
    for r in live:
        if np.isfinite(r["angle_mrad"]) and abs(r["angle_mrad"]) > DEVIATED_MRAD:
            r.setdefault("_why", []).append(("deviated", f"|angle| {abs(r['angle_mrad']):.1f} mrad > {DEVIATED_MRAD:g} mrad"))
        if r["satellites"] >= 1:
            r.setdefault("_why", []).append(("satellites", f"median {r['satellites']:g} satellites per frame"))
        why = r.pop("_why", [])
        order = {s: i for i, s in enumerate(STATES)}
        why.sort(key=lambda w: order[w[0]])
        r["state"] = why[0][0] if why else "ok"
        r["reason"] = "; ".join(w[1] for w in why)


# ----------------------------------------------------------------------------- pass / fail
#: Pass/fail limits of a head (issue 32 item 3): option and sequence.json key -> unit.
LIMIT_KEYS = {"volume_tolerance_percent": "%", "velocity_tolerance_percent": "%", "angle_limit_mrad": "mrad"}
#: sequence.json key (and option --reference-nozzles) of a reference head's nozzles.parquet.
REFERENCE_KEY = "reference_nozzles"
#: The row's nozzle count (sequence.json ``nozzle_count`` or ``--nozzle-count``): end gaps (`_end_gaps`).
COUNT_KEY = "nozzle_count"


def row_limits(meta, given: dict | None = None) -> dict:
    """The pass/fail limits and the reference table of a row: each key of `LIMIT_KEYS` and
    `REFERENCE_KEY` from ``given`` (options; None values are not given), else sequence.json
    (``meta.extra``; a relative reference path is taken from the sequence folder).  Returns
    {key: value, "sources": {key: where}}; a value that is not a number > 0 is a SequenceError
    naming the file."""
    from dropvision.io.sequence import SequenceError

    given = {k: v for k, v in (given or {}).items() if v is not None}
    out, src = {}, {}
    extra = getattr(meta, "extra", None) or {}
    where = Path(meta.path) / "sequence.json"
    for key in LIMIT_KEYS:
        if key in given:
            v, s = given[key], "command line --" + key.replace("_", "-")
        elif key in extra:
            v, s = extra[key], "sequence.json"
        else:
            continue
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v) or v <= 0:
            raise SequenceError(f"{where if s == 'sequence.json' else s}: {key} must be a number > 0, got {v!r}")
        out[key], src[key] = float(v), s
    if REFERENCE_KEY in given:
        out[REFERENCE_KEY], src[REFERENCE_KEY] = Path(given[REFERENCE_KEY]), "command line --reference-nozzles"
    elif REFERENCE_KEY in extra:
        v = extra[REFERENCE_KEY]
        if not isinstance(v, str) or not v:
            raise SequenceError(f"{where}: {REFERENCE_KEY} must be the path of a nozzles.parquet, got {v!r}")
        p = Path(v)
        out[REFERENCE_KEY], src[REFERENCE_KEY] = (p if p.is_absolute() else Path(meta.path) / p), "sequence.json"
    if REFERENCE_KEY in out and not any(k in out for k in LIMIT_KEYS):
        raise SequenceError(f"{src[REFERENCE_KEY]}: a reference head's table ({out[REFERENCE_KEY]}) needs limits to "
                            "compare with: give --volume-tolerance-percent, --velocity-tolerance-percent or "
                            "--angle-limit-mrad (or their sequence.json keys)")
    out["sources"] = src
    return out


def read_reference(path) -> "pd.DataFrame":
    """A reference head's nozzles.parquet (`dvcore.schema.NOZZLES`), checked; a one-line
    SequenceError naming the file when it is not one."""
    import pandas as pd

    from dropvision.io.sequence import SequenceError
    from dvcore.schema import NOZZLES, SchemaError, check_table

    path = Path(path)
    if path.is_dir():
        path = path / "nozzles.parquet"
    if not path.is_file():
        raise SequenceError(f"{path}: no reference nozzles table there (--reference-nozzles wants a nozzles.parquet "
                            "of `dropvision measure` on a reference head)")
    try:
        ref = pd.read_parquet(path)
        check_table(ref, NOZZLES, path)
    except SchemaError as e:
        raise SequenceError(str(e)) from None
    except Exception as e:  # not a parquet file
        raise SequenceError(f"{path}: not a nozzles.parquet ({type(e).__name__}: {e})") from None
    if ref.nozzle.duplicated().any():
        raise SequenceError(f"{path}: nozzle numbers repeat in the reference table")
    return ref


def _aligned_reference(nozzles, reference, reference_path):
    """The reference table indexed by this row's nozzle numbers: (table, the shift of its numbers,
    the note on an alignment by position or None)."""
    from dropvision.io.sequence import SequenceError

    shift, aligned = 0, None
    mine, theirs = set(nozzles.nozzle.astype(int)), set(reference.nozzle.astype(int))
    if mine != theirs:
        # numbered from each head's first live nozzle: a reference whose first nozzle is missing is
        # numbered one less; its nozzles' columns on the pitch grid say which is which
        shift = _align_by_position(nozzles, reference)
        if shift is None:
            raise SequenceError(f"{reference_path}: the reference head's nozzles {_span(theirs)} are not this "
                                f"row's {_span(mine)} (a row's nozzles are numbered from its first live one, a "
                                "scan's by label) and their columns do not line up on one pitch grid: compare "
                                "heads with the same nozzles in the same place")
        aligned = (f"the reference head's nozzles matched by their place on the pitch grid: its nozzle j is "
                   f"this row's j {shift:+d}")
    return reference.set_index(reference.nozzle.astype(int) + shift), shift, aligned


def _judge_nozzle(r, limits: dict, ref, shift: int, med: dict) -> tuple[list[str], list[str], set]:
    """One nozzle against the limits (`judge_row`'s rules): (why it fails, notes, quantities not judged);
    ``ref``: the aligned reference table or None (the row's medians ``med`` and the plate normal)."""
    i = int(r.nozzle)
    fails, notes, not_judged = [], [], set()
    if r.state == "missing":
        return ["missing: no drop"], notes, not_judged

    def ref_value(col):
        return float(ref.at[i, col]) if i in ref.index else float("nan")

    for key, col, unit in (("volume_tolerance_percent", "volume_nl", "nl"),
                           ("velocity_tolerance_percent", "velocity_m_s", "m/s")):
        if key not in limits:
            continue
        tgt = ref_value(col) if ref is not None else med[col]
        what = f"reference nozzle {i - shift}" if ref is not None else "the row's median"
        if ref is not None and i not in ref.index:
            what = "the reference head, which has no nozzle at its place,"
        if not np.isfinite(r[col]):
            notes.append(f"{col} not measured: not judged")
            not_judged.add(col)
            continue
        if not np.isfinite(tgt) or tgt == 0:
            fails.append(f"{col}: {what} has no value to compare with")
            continue
        dev = 100.0 * (r[col] / tgt - 1.0)
        if abs(dev) > limits[key]:
            fails.append(f"{col} {r[col]:.4g} {unit} is {dev:+.2f} % from {what} {tgt:.4g} "
                         f"(limit {limits[key]:g} %)")
    if "angle_limit_mrad" in limits:
        a = float(r.angle_mrad)
        tgt = ref_value("angle_mrad") if ref is not None else 0.0
        lim = limits["angle_limit_mrad"]
        if not np.isfinite(a):
            notes.append("angle_mrad not measured: not judged")
            not_judged.add("angle_mrad")
        elif not np.isfinite(tgt):
            fails.append(f"angle_mrad: reference nozzle {i - shift} has no value to compare with"
                         if i in ref.index else "angle_mrad: the reference head has no nozzle at its place")
        elif abs(a - tgt) > lim:
            fails.append(f"angle {a:+.2f} mrad is {a - tgt:+.2f} mrad from "
                         f"{'reference nozzle ' + str(i - shift) if ref is not None else 'the plate normal'} "
                         f"(limit {lim:g} mrad)")
    return fails, notes, not_judged


def judge_row(nozzles, limits: dict, reference=None, reference_path=None) -> dict | None:
    """``pass`` and ``pass_reason`` of each nozzle (in place) against ``limits`` (`row_limits`), and
    the head's verdict for summary.json (None where no limit is given: ``pass`` is null).

    Rules: a missing nozzle fails; |volume - target| / target and |velocity - target| / target
    within the tolerances (per cent), the target being the reference nozzle's value (``reference``,
    matched by nozzle number) else the median of the row's live nozzles; |angle - reference angle|
    (no reference: |angle|) within the angle limit.  A quantity not measured (velocity of a single
    delay) is not judged, and the reason says so.  The head passes when every nozzle passes."""
    checks = [k for k in LIMIT_KEYS if k in limits]
    if not checks:
        nozzles["pass"] = pd_na_bool(len(nozzles))
        nozzles["pass_reason"] = "no limits given"
        return None
    ref, shift, aligned = None, 0, None
    if reference is not None:
        ref, shift, aligned = _aligned_reference(nozzles, reference, reference_path)
    live = nozzles.state != "missing"
    med = {}
    for c in ("volume_nl", "velocity_m_s"):
        x = nozzles.loc[live, c].to_numpy(float)
        med[c] = float(np.median(x[np.isfinite(x)])) if np.isfinite(x).any() else float("nan")
    passes, reasons, not_judged = [], [], set()
    for _, r in nozzles.iterrows():
        fails, notes, unjudged = _judge_nozzle(r, limits, ref, shift, med)
        not_judged |= unjudged
        passes.append(not fails)
        reasons.append("; ".join(fails + notes))
    nozzles["pass"] = np.array(passes, bool)
    nozzles["pass_reason"] = reasons
    failed = [int(i) for i, p in zip(nozzles.nozzle, passes) if not p]
    return {"pass": not failed, "failed_nozzles": failed,
            "limits": {k: limits[k] for k in checks}, "limit_sources": {k: limits["sources"][k] for k in checks},
            "reference": None if reference is None else str(reference_path),
            "not_judged": sorted(not_judged), **({"reference_alignment": aligned} if aligned else {})}


def _align_by_position(nozzles, reference) -> int | None:
    """The shift d (reference nozzle j is this row's j + d) that puts the two heads' nozzle columns
    on one pitch grid: every matched pair within a quarter pitch, the most pairs; None where no shift
    does (a scan's columns are all one place, or the heads do not sit alike in the frame)."""
    a = nozzles.set_index(nozzles.nozzle.astype(int)).col_px.astype(float)
    b = reference.set_index(reference.nozzle.astype(int)).col_px.astype(float)
    if len(a) < 2 or len(b) < 2:
        return None
    pitch = float(np.median(np.diff(np.sort(a.to_numpy()))))
    if not np.isfinite(pitch) or pitch <= 0:
        return None
    best = None
    for d in range(-int(b.index.max()) - len(a), int(a.index.max()) + len(b) + 1):
        common = [i for i in a.index if i - d in b.index]
        if len(common) < 2:
            continue
        dev = np.abs(np.array([a[i] - b[i - d] for i in common]))
        if np.all(dev < 0.25 * pitch) and (best is None or len(common) > best[0]):
            best = (len(common), d)
    return None if best is None else best[1]


def pd_na_bool(n: int):
    import pandas as pd

    return pd.array([pd.NA] * n, dtype="boolean")


def _span(ids) -> str:
    ids = sorted(ids)
    return f"{ids[0]}..{ids[-1]} ({len(ids)})" if ids else "none"


def measure_row_sequence(seq, out_dir, plate: Plate, *, inputs=(), overwrite: bool = False,
                         nozzle_pitch_um: float | None = None, extra_summary: dict | None = None,
                         scan: dict | None = None, csv: bool = False, limits: dict | None = None):
    """`measure_row` and its files written atomically into ``out_dir`` (None: nothing written);
    ``extra_summary`` joins summary.json; ``limits``: the options of `row_limits` (pass/fail,
    `judge_row`).  Returns (nozzles, frames, bodies, summary)."""
    from dvcore.atomic import atomic_dir
    from dvcore.versions import software_versions

    limits = dict(limits or {})
    nozzle_count = limits.pop(COUNT_KEY, None)  # the row's nozzle count travels with its options
    lim = row_limits(seq.meta, limits)  # before any work: a bad limit or reference is refused at once
    reference = read_reference(lim[REFERENCE_KEY]) if REFERENCE_KEY in lim else None
    nozzles, ftab, btab, summary = measure_row(seq, plate, nozzle_pitch_um=nozzle_pitch_um,
                                               pitch_source="command line --nozzle-pitch-um" if nozzle_pitch_um else None,
                                               scan=scan, nozzle_count=nozzle_count)
    summary["head_pass"] = judge_row(nozzles, lim, reference, lim.get(REFERENCE_KEY))
    summary.update(extra_summary or {})
    summary["software"] = software_versions()
    if out_dir is not None:
        with atomic_dir(out_dir, inputs=list(inputs), overwrite=overwrite, kind="measurement") as tmp:
            write_row_files(tmp, nozzles, ftab, btab, summary, csv=csv)
    return nozzles, ftab, btab, summary


def write_row_files(out, nozzles, ftab, btab, summary: dict, *, csv: bool = False) -> None:
    """A row's files into the folder ``out`` (in place: wrap in `dvcore.atomic.atomic_dir`), the
    tables checked against their schema first."""
    from dvcore.atomic import write_json
    from dvcore.schema import NOZZLES, ROW_BODIES, ROW_FRAMES, check_table

    out = Path(out)
    check_table(nozzles, NOZZLES, out / "nozzles.parquet")
    check_table(ftab, ROW_FRAMES, out / "frames.parquet")
    check_table(btab, ROW_BODIES, out / "bodies.parquet")
    out.mkdir(parents=True, exist_ok=True)
    nozzles.to_parquet(out / "nozzles.parquet", index=False)
    ftab.to_parquet(out / "frames.parquet", index=False)
    if csv:
        ftab.to_csv(out / "frames.csv", index=False)
    btab.to_parquet(out / "bodies.parquet", index=False)
    write_json(out / "summary.json", summary)
