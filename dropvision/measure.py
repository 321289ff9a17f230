"""`dropvision measure SEQ_DIR --out OUT_DIR`: per-frame drop volumes, pinch-off, velocities.

Pipeline (one module per concept):

1. `dropvision.calibration`: background from a few frames spread over the sequence, nozzle,
   axis and tilt, tip plane, liquid interior level, effective blur.
2. `dropvision.segmentation`: dark mask in the region of interest (column band around the axis,
   from just above the tip down), lens spots filled, bodies labelled.
3. `dropvision.volume`: sub-pixel run edges, disc integration (tilt-corrected), blur correction.
4. `dropvision.tracking`: pinch-off, grown volume and flow velocity, in-flight drop, velocity.
5. `dropvision.quality`: why a value is NaN.

Frames are streamed (one decoded frame per worker at a time); only small per-frame records are
kept, so memory does not grow with the sequence length.  Output (`write_result`):
``frames.parquet`` (+ ``frames.csv``), ``per_delay.parquet``, ``summary.json``, written atomically.

Columns of ``frames`` (fixed): file, page, delay_us, repeat, attached, attached_volume_nl,
grown_volume_nl, drop_volume_nl, detached_volume_nl, drop_z_um, drop_x_um, n_satellites,
flow_velocity_m_s, quality, then extra columns: drop_length_um (main body's extent along the
image rows), drop_diameter_um (widest chord), inflight (bool: main drop compact, trusted),
neck_px (narrowest chord of the attached liquid), gain (frame illumination / background model),
blur_px (the frame's edge blur, Gaussian sigma, from its nozzle walls' steepness relative to the
calibration frame), wall_contrast (1 - the nozzle wall's transmission in the frame).
"""

from __future__ import annotations

import argparse
import math
import sys
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
from scipy.special import ndtr

from dropvision import quality as q
from dropvision.calibration import Calibration, CalibrationError, calibrate, edge_sigma_px, find_nozzle
from dropvision.segmentation import Body, dark_mask, segment, threshold_image
from dropvision.tracking import fit_line, flow_velocity_at, grown_and_flow, pinchoff_delay
from dropvision.volume import body_edges, integrate

SCHEMA_VERSION = "dropvision.measure/1"
#: Darkening (transmission units) every interior gap row must show beyond the ends' blurred
#: tails for a thread to join two bodies.  The ends' unresolved taper (meniscus cone, tail tip)
#: darkens the rows next to them by up to 0.09 more than a straight blurred edge.  In a seed
#: sweep (`tools/pinchoff_sweep.py`: 12 seeds x 16 waveforms at 192 x 640, 4 x 16 at
#: 640 x 1024) every just-detached gap (128) had an interior row within 0.035 of the tails'
#: prediction, and every last-attached thread (64) darkened all interior rows by >= 0.246.
#: At 1 px blur 0.05 is a thread about 0.2 px wide; a thinner one counts as broken.
INTERIOR_THREAD_MARGIN = 0.05
NL_PER_UM3 = 1e-6

FRAME_COLUMNS = [
    "file", "page", "delay_us", "repeat", "attached", "attached_volume_nl", "grown_volume_nl",
    "drop_volume_nl", "detached_volume_nl", "drop_z_um", "drop_x_um", "n_satellites",
    "flow_velocity_m_s", "quality", "drop_length_um", "drop_diameter_um", "inflight", "neck_px", "gain",
    "blur_px", "wall_contrast",
]
PER_DELAY_COLUMNS = [
    "attached_volume_nl", "grown_volume_nl", "drop_volume_nl", "detached_volume_nl", "drop_z_um",
    "drop_x_um", "n_satellites", "flow_velocity_m_s",
]


@dataclass(frozen=True)
class MeasureConfig:
    """Measurement knobs (defaults are the documented method; none is tuned to a data set).

    Attributes
    ----------
    calibration_frames : int
        Frames spread over the sequence used for the background (the first is always one).
    band_half_width : float
        Half width of the measured column band, in nozzle outer diameters.
    min_body_area_px : int
        Smaller dark bodies are noise.
    compact_ratio, tail_chord_ratio : float
        A detached main drop is "in flight" (tail merged or broken up) when its extent along
        the rows is at most ``compact_ratio`` equivalent-sphere diameters and its chord a
        quarter of its length below its top is at least ``tail_chord_ratio`` of its widest
        chord (0.87 for any spheroid; a joined tail is much thinner).
    blur_correction : bool
        Add the volume lost by the blurred 50 % silhouette (see `volume.blur_correction_px3`).
    max_blur_px : float
        A sequence or frame whose edge blur (Gaussian sigma) exceeds this is flagged.
    blur_change_tolerance : float
        A frame whose blur exceeds the calibrated blur by more than this fraction is flagged
        (the blur correction and the thread rule use the calibrated blur).
    contrast_change_tolerance : float
        A frame whose nozzle-wall contrast is below the calibration frame's by more than this
        fraction (a washed-out strobe, flare) is flagged.
    min_contrast : float
        Liquid interior transmission must be below 1 - min_contrast.
    saturation_limit : float
        Fraction of background samples at the sensor maximum above which a frame is flagged.
    gain_tolerance : float
        Relative frame illumination change beyond which thresholds follow the frame; beyond
        10x this the frame is flagged.
    ambiguous_gap_px : float
        A detached body closer than this to the attached liquid (or a neck thinner than this)
        makes the separation ambiguous (flagged).
    workers : int
        Decoding/measuring threads (cv2 releases the GIL).
    dead_time_us : float
        Default firing-trigger-to-piston delay when the waveform does not give one.
    """

    calibration_frames: int = 8
    band_half_width: float = 2.5
    min_body_area_px: int = 4
    compact_ratio: float = 2.0
    tail_chord_ratio: float = 0.6
    blur_correction: bool = True
    max_blur_px: float = 4.0
    blur_change_tolerance: float = 0.5
    contrast_change_tolerance: float = 0.15
    min_contrast: float = 0.3
    saturation_limit: float = 0.01
    gain_tolerance: float = 0.005
    ambiguous_gap_px: float = 1.5
    workers: int = 2
    dead_time_us: float = 220.0


@dataclass
class MeasureResult:
    """Frame table and summary of one sequence."""

    frames: pd.DataFrame
    summary: dict

    def per_delay(self) -> pd.DataFrame:
        """Mean, std and count of the numeric columns per delay (columns ``<name>_mean`` ...)."""
        return per_delay(self.frames)

    def to_dict(self) -> dict:
        return {"frames": self.frames.to_dict(orient="list"), "summary": self.summary}


def per_delay(frames: pd.DataFrame) -> pd.DataFrame:
    """Per-delay statistics (mean, std, count of finite values) of the measured columns."""
    if frames.empty:
        return pd.DataFrame({"delay_us": []})
    g = frames.groupby("delay_us", sort=True)
    out = pd.DataFrame({"delay_us": g.size().index.to_numpy(float), "n_frames": g.size().to_numpy()})
    for col in PER_DELAY_COLUMNS:
        s = frames[col].astype(float)
        gg = s.groupby(frames["delay_us"])
        out[f"{col}_mean"] = gg.mean().to_numpy()
        out[f"{col}_std"] = gg.std(ddof=1).to_numpy()
        out[f"{col}_count"] = gg.count().to_numpy()
    out["attached_fraction"] = g["attached"].mean().to_numpy(float)
    return out


# ----------------------------------------------------------------------------- per frame
@dataclass
class FrameContext:
    """Precomputed per-sequence arrays for the per-frame measurement (region of interest)."""

    r0: int
    c0: int
    c1: int
    height: int
    width: int
    inv_background: np.ndarray
    background: np.ndarray
    thr_image: np.ndarray
    allowed: np.ndarray | None
    opaque: np.ndarray | None
    threshold: float
    liquid_level: float
    tip_roi: float
    axis_col: float
    tip_row: float
    tilt_rad: float
    sigma_px: float
    pixel_size_um: float
    max_value: int
    sample_rows: np.ndarray
    sample_cols: np.ndarray
    min_area_px: int
    gain_tolerance: float
    noise_t: float = 0.01
    # per-frame sharpness and contrast from windows across the nozzle walls (full-frame indices)
    wall_rows: np.ndarray | None = None
    wall_cols: np.ndarray | None = None
    wall_inv_background: np.ndarray | None = None
    blur_ref_px: float = float("nan")
    sharpness_ref: float = float("nan")
    max_frame_blur_px: float = float("inf")
    min_wall_contrast: float = 0.0

    @classmethod
    def build(cls, cal: Calibration, sigma_px: float, dtype, max_value: int, config: MeasureConfig) -> "FrameContext":
        h, w = cal.shape
        r0 = max(0, int(math.floor(cal.tip_row)) - 8)
        half = config.band_half_width * cal.nozzle_outer_diameter_px + abs(math.tan(cal.tilt_rad)) * (h - r0)
        half = max(half, 48.0)
        c0 = max(0, int(math.floor(cal.axis_col - half)))
        c1 = min(w, int(math.ceil(cal.axis_col + half)) + 1)
        bg = np.ascontiguousarray(cal.background.background[r0:, c0:c1])
        allowed = opaque = None
        if cal.background.opaque is not None:
            op = cal.background.opaque[r0:, c0:c1]
            if op.any():
                opaque = cv2.dilate(op.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
                allowed = np.where(op, 0, 255).astype(np.uint8)
        hh, ww = bg.shape
        rows = np.arange(0, hh, 4)
        sample_rows = np.concatenate([rows, rows, rows, rows])
        sample_cols = np.concatenate([np.full(rows.size, 1), np.full(rows.size, 3), np.full(rows.size, ww - 2),
                                      np.full(rows.size, ww - 4)]).clip(0, ww - 1)
        return cls(
            r0=r0, c0=c0, c1=c1, height=h, width=w,
            inv_background=(1.0 / bg).astype(np.float32), background=bg,
            thr_image=threshold_image(bg, cal.threshold, dtype), allowed=allowed, opaque=opaque,
            threshold=cal.threshold, liquid_level=cal.liquid_level, tip_roi=cal.tip_row - r0, axis_col=cal.axis_col, tip_row=cal.tip_row,
            tilt_rad=cal.tilt_rad, sigma_px=sigma_px if config.blur_correction else 0.0,
            pixel_size_um=cal.pixel_size_um, max_value=max_value,
            sample_rows=sample_rows, sample_cols=sample_cols, min_area_px=config.min_body_area_px,
            gain_tolerance=config.gain_tolerance,
        )

    def to_axis_um(self, row_roi: float, col_roi: float) -> tuple[float, float]:
        """(z along the axis from the tip plane, x across, + right) in µm of an ROI point."""
        dy = row_roi + self.r0 - self.tip_row
        dx = col_roi + self.c0 - self.axis_col
        s, c = math.sin(self.tilt_rad), math.cos(self.tilt_rad)
        return (dx * s + dy * c) * self.pixel_size_um, (dx * c - dy * s) * self.pixel_size_um


@dataclass
class DetachedBody:
    """A detached liquid body of one frame."""

    volume_nl: float
    z_um: float
    x_um: float
    length_um: float
    diameter_um: float
    top_row: float
    bottom_row: float
    leaves: bool
    out_of_band: bool
    on_dust: bool
    bbox: tuple[int, int, int, int]
    top_chord_ratio: float = float("nan")


@dataclass
class FrameRecord:
    """Everything kept from one frame (small)."""

    index: int
    file: str
    page: int | None
    delay_us: float
    repeat: int
    attached_volume_nl: float = float("nan")
    attached_bottom_row: float = float("nan")
    neck_px: float = float("nan")
    bodies: list[DetachedBody] = field(default_factory=list)
    flags: list[str] = field(default_factory=list)
    gain: float = 1.0
    blur_px: float = float("nan")
    wall_contrast: float = float("nan")
    error: str | None = None


def measure_frame(image: np.ndarray, ctx: FrameContext, ref=None, logger=None) -> FrameRecord:
    """Measure one decoded frame (canonical orientation) with a sequence's context."""
    rec = FrameRecord(
        index=getattr(ref, "index", 0), file=getattr(ref, "file", ""), page=getattr(ref, "page", None),
        delay_us=float(getattr(ref, "delay_us", 0.0)), repeat=getattr(ref, "repeat", 0),
    )
    roi = image[ctx.r0:, ctx.c0:ctx.c1]
    samples = roi[ctx.sample_rows, ctx.sample_cols]
    gain = q.frame_gain(samples, ctx.background[ctx.sample_rows, ctx.sample_cols])
    if not np.isfinite(gain):
        gain = 1.0
        rec.flags.append(q.ILLUMINATION)
    rec.gain = gain
    if q.saturation_fraction(samples, ctx.max_value) > 0.01:
        rec.flags.append(q.SATURATED)
    if ctx.wall_rows is not None:
        prof = image[ctx.wall_rows, ctx.wall_cols].astype(np.float32) * ctx.wall_inv_background / gain
        sharp = q.edge_sharpness(prof)
        rec.wall_contrast = q.wall_contrast(prof)
        rec.blur_px = ctx.blur_ref_px * ctx.sharpness_ref / sharp if sharp > 0 else float("inf")
        if rec.blur_px > ctx.max_frame_blur_px:
            rec.flags.append(q.BLURRED)
        if rec.wall_contrast < ctx.min_wall_contrast:
            rec.flags.append(q.LOW_CONTRAST)
    if abs(gain - 1.0) > 10 * ctx.gain_tolerance:
        rec.flags.append(q.ILLUMINATION)
    thr_img = ctx.thr_image
    if abs(gain - 1.0) > ctx.gain_tolerance:
        thr_img = threshold_image(ctx.background * gain, ctx.threshold, roi.dtype)
    mask = dark_mask(np.ascontiguousarray(roi), thr_img, ctx.allowed)
    seg = segment(mask, ctx.min_area_px)
    hh, ww = roi.shape
    cos_t = math.cos(ctx.tilt_rad)
    px = ctx.pixel_size_um
    px3_nl = px**3 * NL_PER_UM3
    all_edges = [] if logger is not None else None
    nozzle_body: Body | None = None
    axis_roi = ctx.axis_col - ctx.c0
    for b in seg.bodies:
        if b.nozzle and b.x0 <= axis_roi < b.x1:
            if nozzle_body is None or b.area_px > nozzle_body.area_px:
                nozzle_body = b
    if nozzle_body is None:
        rec.flags.append(q.NO_NOZZLE)
    else:
        b = nozzle_body
        ed = body_edges(roi, ctx.inv_background, seg.labels, b.label, (b.x0, b.y0, b.x1, b.y1), ctx.threshold,
                        gain, row_min=max(0, int(math.floor(ctx.tip_roi)) - 1))
        _clip_to_tip_plane(ed, ctx.tip_roi, axis_roi, ctx.tilt_rad)
        bv = integrate(ed, ctx.tilt_rad, ctx.tip_roi, ctx.sigma_px)
        if all_edges is not None:
            all_edges.append(ed)
        if b.y1 >= hh:
            rec.flags.append(q.ATTACHED_LEAVES)
        else:
            rec.attached_volume_nl = bv.volume_px3 * px3_nl
        rec.attached_bottom_row = bv.bottom_row
        below = ed.row > ctx.tip_roi + 2
        if np.any(below):
            rows = ed.row[below]
            chord = ed.chord_px[below]
            # narrowest chord between the tip and the widest row of the bulb below it (the neck)
            widest = rows[np.argmax(chord)]
            upper = rows <= widest
            k = np.argmin(np.where(upper, chord, np.inf))
            if widest - rows[k] >= 3 and chord[k] < 0.5 * chord.max():
                rec.neck_px = float(chord[k])
    threads = set()
    if nozzle_body is not None and np.isfinite(rec.attached_bottom_row):
        threads = _thread_joined(roi, ctx, seg, nozzle_body, rec.attached_bottom_row, gain)
    for b in seg.bodies:
        if b.nozzle:
            continue
        ed = body_edges(roi, ctx.inv_background, seg.labels, b.label, (b.x0, b.y0, b.x1, b.y1), ctx.threshold, gain)
        if all_edges is not None:
            all_edges.append(ed)
        bv = integrate(ed, ctx.tilt_rad, None, ctx.sigma_px)
        if bv.volume_px3 <= 0:
            continue
        if b.label in threads:  # still joined by a thread thinner than the blur: attached liquid
            if np.isfinite(rec.attached_volume_nl):
                rec.attached_volume_nl += bv.volume_px3 * px3_nl
            rec.attached_bottom_row = max(rec.attached_bottom_row, bv.bottom_row)
            continue
        z, x = ctx.to_axis_um(bv.centroid_row, bv.centroid_col)
        leaves = b.y1 >= hh or (b.x0 == 0 and ctx.c0 == 0) or (b.x1 >= ww and ctx.c1 >= ctx.width)
        out_band = (b.x0 == 0 and ctx.c0 > 0) or (b.x1 >= ww and ctx.c1 < ctx.width)
        on_dust = bool(ctx.opaque is not None and ctx.opaque[b.y0:b.y1, b.x0:b.x1][
            seg.labels[b.y0:b.y1, b.x0:b.x1] == b.label].any())
        rec.bodies.append(DetachedBody(
            top_chord_ratio=_top_chord_ratio(ed, bv),
            volume_nl=bv.volume_px3 * px3_nl, z_um=z, x_um=x,
            length_um=(bv.bottom_row - bv.top_row + 1) * px * cos_t, diameter_um=bv.max_chord_px * px * cos_t,
            top_row=bv.top_row, bottom_row=bv.bottom_row, leaves=bool(leaves), out_of_band=bool(out_band),
            on_dust=on_dust, bbox=(b.x0, b.y0, b.x1, b.y1),
        ))
    rec.bodies.sort(key=lambda d: -d.volume_nl)
    if logger is not None:
        _log_frame(logger, ref, image, ctx, seg, nozzle_body, rec, all_edges)
    return rec


def _thread_joined(roi, ctx: FrameContext, seg, nozzle_body, bottom_row: float, gain: float) -> set:
    """Labels of detached bodies still joined to the attached liquid by an unresolved thread.

    A liquid thread much thinner than the blur never reaches the 50 % level, but it leaves a
    faint dark line across the gap, and it crosses *every* row of the gap with about the same
    width, so its darkening does not fade anywhere in the gap.  The blurred ends alone darken
    the gap only by their tails, which decay away from each end.  Along the straight path from
    the attached liquid's bottom to a body's top (per row the darkest pixel within 2 px of the
    path), each gap row is compared with what the two ends alone would give there
    (`_end_tails_transmission`): each end is an edge at its sub-pixel 50 % crossing along the
    path, blurred by the calibrated blur.  The body is joined only when *every* gap row is darker
    than that by more than 4 noise standard deviations (and by at least 0.02): one gap row
    explained by the ends' tails alone breaks the thread.

    The straight-edge model misses the unresolved taper of a real end (the residual meniscus
    cone, a tail's tip), which darkens the row next to each end by up to ~0.09 more.  So in
    gaps of 3 rows or more only the rows not adjacent to an end are judged, each against
    ``max(INTERIOR_THREAD_MARGIN, 4 noise std)``.  A thread broken within a row of an end is
    therefore seen one frame later, once the gap has opened.
    """
    out = set()
    labels = seg.labels
    hh, ww = roi.shape
    yb = int(round(bottom_row))
    cols_b = np.nonzero(labels[yb] == nozzle_body.label)[0]
    if cols_b.size == 0:
        return out
    xb = 0.5 * (cols_b[0] + cols_b[-1])
    sig = ctx.sigma_px if ctx.sigma_px > 0 else 1.0
    margin = max(0.02, 4.0 * ctx.noise_t)
    interior_margin = max(INTERIOR_THREAD_MARGIN, 4.0 * ctx.noise_t)

    def darkest(y: int, xc: float) -> float:  # per row, within 2 px of the path
        c = int(round(xc))
        c0, c1 = max(0, c - 2), min(ww, c + 3)
        return float((roi[y, c0:c1].astype(np.float32) * ctx.inv_background[y, c0:c1]).min()) / gain

    for b in seg.bodies:
        if b.nozzle or b.y0 <= yb or b.y0 - yb > 100:
            continue
        cols_t = np.nonzero(labels[b.y0] == b.label)[0]
        xt = 0.5 * (cols_t[0] + cols_t[-1])
        if b.y0 - yb - 1 < 1:
            out.add(b.label)
            continue
        rows = np.arange(yb, b.y0 + 1)
        t_path = np.array([darkest(y, xb + (xt - xb) * (y - yb) / (b.y0 - yb)) for y in rows])
        # sub-pixel 50 % crossings of the two ends along the path (end row dark, next row not)
        e_top = yb + _crossing_fraction(t_path[0], t_path[1], ctx.threshold)
        e_bot = b.y0 - _crossing_fraction(t_path[-1], t_path[-2], ctx.threshold)
        expected = _end_tails_transmission(rows[1:-1], e_top, e_bot, sig, sig, ctx.liquid_level)
        excess = expected - t_path[1:-1]
        if excess.size >= 3:  # judge the rows not adjacent to an end (their taper is unmodelled)
            judged, limit = excess[1:-1], interior_margin
        else:
            judged, limit = excess, margin
        if float(judged.min()) > limit:
            out.add(b.label)
    return out


def _crossing_fraction(t_dark: float, t_next: float, threshold: float) -> float:
    """Where (0..1 px from the dark row) a linear profile crosses ``threshold``."""
    if not t_next > t_dark:
        return 0.5
    return float(np.clip((threshold - t_dark) / (t_next - t_dark), 0.0, 1.0))


def _end_tails_transmission(rows: np.ndarray, e_top: float, e_bot: float, sigma_top_px: float,
                            sigma_bot_px: float, liquid_level: float) -> np.ndarray:
    """Transmission along the axis between two blurred liquid ends (no liquid between them).

    Each end is an edge at its 50 % crossing (``e_top`` the upper body's bottom, ``e_bot`` the
    lower body's top) blurred by a Gaussian: its darkening at a distance ``d`` outside is
    ``(1 - L) (1 - Phi(d / sigma))``; the two tails add.
    """
    rows = np.asarray(rows, float)
    dark = ndtr((e_top - rows) / sigma_top_px) + ndtr((rows - e_bot) / sigma_bot_px)
    return 1.0 - (1.0 - liquid_level) * dark


def _clip_to_tip_plane(ed, tip_roi: float, axis_roi: float, tilt_rad: float) -> None:
    """Cut the attached liquid's runs at the tip plane (perpendicular to a tilted axis).

    The plane through (tip, axis) is ``y = tip - (x - axis) tan(tilt)``; near the tip of a tilted
    nozzle one wall ends below the tip row at the axis, and its part of a run is not liquid.
    """
    tan = math.tan(tilt_rad)
    if abs(tan) < 1e-9 or ed.row.size == 0:
        return
    near = ed.row < tip_roi + abs(tan) * (ed.right_px - ed.left_px) + 1.0
    if not np.any(near):
        return
    bound = axis_roi + (tip_roi - ed.row) / tan
    if tan > 0:
        ed.left_px = np.where(near, np.maximum(ed.left_px, bound), ed.left_px)
    else:
        ed.right_px = np.where(near, np.minimum(ed.right_px, bound), ed.right_px)
    ed.right_px = np.maximum(ed.right_px, ed.left_px)


def _top_chord_ratio(ed, bv, at: float = 0.25) -> float:
    """Chord a quarter of the body's length below its top over its widest chord.

    0.87 for any spheroid (whatever its aspect ratio); much smaller when a thin tail is still
    joined to the top of the drop.
    """
    if bv.max_chord_px <= 0 or not np.isfinite(bv.top_row):
        return float("nan")
    y = bv.top_row + at * (bv.bottom_row - bv.top_row)
    sel = np.abs(ed.row - y) <= 0.5
    if not np.any(sel):
        return float("nan")
    return float(ed.chord_px[sel].max() / bv.max_chord_px)


def _log_frame(logger, ref, image, ctx, seg, nozzle_body, rec, all_edges) -> None:
    """Hand the frame's stages to a Rerun logger (only called when logging is on)."""
    classes = np.zeros(len(seg.bodies) + 1, np.uint8)
    boxes = []
    main_bbox = rec.bodies[0].bbox if rec.bodies else None
    for b in seg.bodies:
        if b.nozzle:
            cls = 2 if b is nozzle_body else 1
        else:
            cls = 3 if (b.x0, b.y0, b.x1, b.y1) == main_bbox else 4
        classes[b.label] = cls
        boxes.append({"bbox": (b.x0, b.y0, b.x1, b.y1), "class_id": int(cls)})
    labels = classes[seg.labels]
    if ctx.opaque is not None:
        labels[ctx.opaque & (labels == 0)] = 5
    t_full = image.astype(np.float32)
    t_full[ctx.r0:, ctx.c0:ctx.c1] *= ctx.inv_background
    pts = []
    for ed in all_edges or []:
        pts.append(np.column_stack([ed.left_px, ed.row]))
        pts.append(np.column_stack([ed.right_px, ed.row]))
    edges = np.concatenate(pts) if pts else np.zeros((0, 2))
    t_roi = t_full[ctx.r0:, ctx.c0:ctx.c1]
    t_full = np.ones_like(t_full)
    t_full[ctx.r0:, ctx.c0:ctx.c1] = t_roi
    logger.log_frame(ref, image, t_full, labels, edges, boxes, None, roi_origin_xy=(ctx.c0, ctx.r0))


# ----------------------------------------------------------------------------- sequence
def _calibration_indices(delays: np.ndarray, n: int) -> list[int]:
    """Indices of up to ``n`` frames at distinct delays spread over the sequence (first included)."""
    if delays.size == 0:
        return []
    _, first_of = np.unique(delays, return_index=True)
    first_of = np.sort(first_of)
    pick = np.unique(np.round(np.linspace(0, first_of.size - 1, min(n, first_of.size))).astype(int))
    return [int(first_of[i]) for i in pick]


def _stream(seq, indices, ctx: FrameContext, workers: int, logger, errors: list, progress: bool,
            decoded: dict | None = None):
    """Yield FrameRecords in order; at most ``2 * workers`` frames decoded at once.

    ``decoded`` holds images already decoded by the calibration pass (a few, fixed number):
    they are used once and dropped instead of being decoded again.
    """
    decoded = {} if decoded is None else decoded

    def work(i):
        image = decoded.pop(i, None)
        if image is not None:
            return measure_frame(image, ctx, seq.meta.frames[i], logger)
        fr = seq.read(i)
        if fr.image is None:
            return FrameRecord(fr.ref.index, fr.ref.file, fr.ref.page, fr.ref.delay_us, fr.ref.repeat, error=fr.error)
        return measure_frame(fr.image, ctx, fr.ref, logger)

    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(indices), desc="measure", unit="frame", file=sys.stderr)
    try:
        if workers <= 1 or logger is not None:
            for i in indices:
                yield work(i)
                if bar is not None:
                    bar.update()
            return
        with ThreadPoolExecutor(max_workers=workers) as pool:
            pending: deque = deque()
            it = iter(indices)
            for i in it:
                pending.append(pool.submit(work, i))
                if len(pending) >= 2 * workers:
                    break
            while pending:
                rec = pending.popleft().result()
                nxt = next(it, None)
                if nxt is not None:
                    pending.append(pool.submit(work, nxt))
                yield rec
                if bar is not None:
                    bar.update()
    finally:
        if bar is not None:
            bar.close()


def calibrate_sequence(seq, config: MeasureConfig = MeasureConfig(), *,
                       decoded: dict | None = None) -> tuple[Calibration, float, FrameContext]:
    """Calibration pass over a few frames spread over an open sequence.

    ``decoded``, when given, receives the decoded calibration frames (index -> image) so that
    the measurement pass does not decode them again.

    Returns
    -------
    cal : Calibration
    sigma_px : float
        Effective edge blur.
    ctx : FrameContext
        What `measure_frame` needs.
    """
    from dropvision.io import SequenceError

    meta = seq.meta
    n = len(seq)
    delays = meta.delays_us
    cal_frames = {}
    for i in _calibration_indices(delays, config.calibration_frames):
        fr = seq.read(i)
        if fr.image is not None:
            cal_frames[i] = fr.image
    if not cal_frames:  # the spread frames were unreadable: take the first readable one
        for i in range(n):
            fr = seq.read(i)
            if fr.image is not None:
                cal_frames[i] = fr.image
                break
    if not cal_frames:
        raise SequenceError(f"{meta.path}: no readable frame")
    if decoded is not None:
        decoded.update(cal_frames)
    first_idx = min(cal_frames)
    images = [cal_frames[i] for i in sorted(cal_frames)]
    first = cal_frames[first_idx]
    try:
        cal = calibrate(
            first, images, meta.pixel_size_um,
            nozzle_outer_diameter_um=meta.nozzle_outer_diameter_um,
            nozzle_inner_diameter_um=meta.nozzle_inner_diameter_um,
            tip_row=meta.nozzle_tip_row, axis_col=meta.axis_col,
        )
    except CalibrationError as exc:
        raise SequenceError(f"{meta.path / meta.frames[first_idx].file}: {exc}") from exc
    t_first = np.asarray(first, np.float32) / cal.background.background
    nozzle = find_nozzle(t_first, 0.5 * (1.0 + cal.nozzle_level))
    sigma = edge_sigma_px(t_first, nozzle)
    max_value = 2 ** int(meta.bit_depth) - 1
    ctx = FrameContext.build(cal, sigma, first.dtype, max_value, config)
    # transmission noise: robust spread of the horizontal differences of bright background pixels
    tb = t_first[ctx.r0:, ctx.c0:ctx.c1]
    d = np.diff(tb, axis=1)[(tb[:, 1:] > 0.9) & (tb[:, :-1] > 0.9)]
    if d.size > 100:
        ctx.noise_t = float(1.4826 * np.median(np.abs(d - np.median(d))) / np.sqrt(2.0))
    # per-frame sharpness/contrast reference: the nozzle walls well above the tip plane
    dry = nozzle.rows <= cal.tip_row - 3
    wr, wc = q.wall_windows(nozzle.rows[dry], nozzle.left_px[dry], nozzle.right_px[dry], t_first.shape[1])
    if wr.shape[0] >= 4 and np.isfinite(sigma):
        prof = t_first[wr, wc]
        sharp, contrast = q.edge_sharpness(prof), q.wall_contrast(prof)
        if sharp > 0 and contrast > 0:
            ctx.wall_rows, ctx.wall_cols = wr, wc
            ctx.wall_inv_background = (1.0 / cal.background.background[wr, wc]).astype(np.float32)
            ctx.blur_ref_px, ctx.sharpness_ref = float(sigma), sharp
            ctx.max_frame_blur_px = min(config.max_blur_px, (1.0 + config.blur_change_tolerance) * sigma)
            ctx.min_wall_contrast = contrast * max(1.0 - config.contrast_change_tolerance,
                                                   config.min_contrast / max(1.0 - cal.liquid_level, 1e-6))
    return cal, sigma, ctx


def measure_sequence(seq_dir, out_dir=None, config: MeasureConfig = MeasureConfig(), *, progress: bool = False,
                     logger=None, csv: bool = False, overwrite: bool = False) -> MeasureResult:
    """Measure a strobe sequence folder.

    Parameters
    ----------
    seq_dir : str or Path
        Sequence folder (see docs/FORMAT.md).
    out_dir : str or Path, optional
        Write the result there (atomically): frames.parquet, per_delay.parquet, summary.json.
        It may not be the sequence folder, lie inside it or contain it; an existing folder is
        replaced only when it holds nothing but an earlier result of ours (see
        `identify.atomic.atomic_dir`). Checked before anything is measured.
    config : MeasureConfig
    progress : bool
        Progress bar on stderr.
    logger : object, optional
        Rerun logger (``log_calibration``, ``log_frame``, ``log_summary``); None costs nothing.
    csv : bool
        Also write frames.csv.
    overwrite : bool
        Write into an existing ``out_dir`` that holds files we did not write (they are kept).

    Returns
    -------
    MeasureResult

    Raises
    ------
    dropvision.io.SequenceError
        Unusable sequence (missing metadata, other frame size, no readable frame, no nozzle).
    identify.atomic.OutputError
        ``out_dir`` overlaps the input or holds files we did not write.
    """
    from identify.atomic import atomic_dir, check_output_dir
    from dropvision.io import SequenceError, open_sequence

    seq = open_sequence(seq_dir)
    if out_dir is not None:  # before any work: the output may destroy nothing
        check_output_dir(out_dir, inputs=[seq.meta.path], overwrite=overwrite)
    meta = seq.meta
    n = len(seq)
    if n == 0:
        raise SequenceError(f"{meta.path}: no frames")
    errors: list[dict] = []
    decoded: dict = {}
    cal, sigma, ctx = calibrate_sequence(seq, config, decoded=decoded)
    if logger is not None:
        logger.log_calibration(cal, shape=cal.shape)
    seq_flags = []
    if np.isfinite(sigma) and sigma > config.max_blur_px:
        seq_flags.append(q.BLURRED)
    if 1.0 - cal.liquid_level < config.min_contrast:
        seq_flags.append(q.LOW_CONTRAST)
    # --- measurement pass (streamed) -----------------------------------------------------
    records: list[FrameRecord] = []
    for rec in _stream(seq, range(n), ctx, max(1, config.workers), logger, errors, progress, decoded):
        if rec.error is not None:
            errors.append({"file": rec.file, "page": rec.page, "delay_us": rec.delay_us, "reason": rec.error})
            continue
        rec.flags = seq_flags + rec.flags
        records.append(rec)
    seq.close()
    frames, summary = assemble(records, cal, sigma, meta, config, errors)
    result = MeasureResult(frames, summary)
    if logger is not None:
        logger.log_table(frames)
        logger.log_summary(summary)
    if out_dir is not None:
        with atomic_dir(out_dir, inputs=[meta.path], overwrite=overwrite, kind="measurement") as tmp:
            write_result(result, tmp, csv=csv)
    return result


def assemble(records: list[FrameRecord], cal: Calibration, sigma_px: float, meta, config: MeasureConfig,
             errors: list[dict]) -> tuple[pd.DataFrame, dict]:
    """Sequence-level analysis of the per-frame records -> (frames table, summary dict)."""
    from identify.versions import software_versions

    m = len(records)
    delay = np.array([r.delay_us for r in records], float)
    flags = [list(r.flags) for r in records]
    att_vol = np.array([r.attached_volume_nl for r in records], float)
    main = [r.bodies[0] if r.bodies else None for r in records]
    has_det = np.array([b is not None for b in main], bool)
    pinch = pinchoff_delay(delay, has_det) if m else float("nan")
    attached = ~has_det & ((delay < pinch) if np.isfinite(pinch) else True)
    grown, flow, meniscus, grown_by_delay = grown_and_flow(delay, att_vol, attached, meta.nozzle_inner_diameter_um)
    # The grown volume is relative to the initial meniscus (Section 4.1.1): that needs a frame
    # taken before the piston moves (delay <= dead time). Without one, no grown volume or flow.
    wf0 = meta.waveform or {}
    dead_time = float(wf0.get("dead_time_us", config.dead_time_us))
    meniscus_at_rest = bool(m) and float(np.min(delay)) <= dead_time
    if not meniscus_at_rest:
        grown[:] = np.nan
        flow[:] = np.nan
        grown_by_delay = grown_by_delay.iloc[0:0]
        meniscus = float("nan")
        for k in range(m):
            if attached[k]:
                flags[k].append(q.NO_REST_MENISCUS)
    drop_vol = np.full(m, np.nan)
    det_vol = np.full(m, np.nan)
    drop_z = np.full(m, np.nan)
    drop_x = np.full(m, np.nan)
    length = np.full(m, np.nan)
    diam = np.full(m, np.nan)
    nsat = np.full(m, np.nan)
    inflight = np.zeros(m, bool)
    for k, r in enumerate(records):
        b = main[k]
        if attached[k]:
            det_vol[k] = 0.0
            nsat[k] = 0
            if np.isfinite(r.neck_px) and r.neck_px < config.ambiguous_gap_px:
                flags[k].append(q.AMBIGUOUS)
            continue
        if b is None:
            flags[k].append(q.NO_DROP)
            det_vol[k] = 0.0
            continue
        bad = []
        if b.leaves:
            bad.append(q.DROP_LEAVES)
        if b.out_of_band:
            bad.append(q.OUT_OF_BAND)
        if b.on_dust:
            bad.append(q.DUST_OVERLAP)
        if np.isfinite(r.attached_bottom_row) and b.top_row - r.attached_bottom_row < config.ambiguous_gap_px + 1:
            bad.append(q.AMBIGUOUS)
        flags[k].extend(bad)
        others = r.bodies[1:]
        sat_bad = any(o.leaves or o.out_of_band or o.on_dust for o in others)
        if not bad:
            drop_vol[k] = b.volume_nl
            drop_z[k], drop_x[k] = b.z_um, b.x_um
            length[k], diam[k] = b.length_um, b.diameter_um
            if not sat_bad:
                det_vol[k] = sum(o.volume_nl for o in r.bodies)
                nsat[k] = len(others)
            d_eq = (6.0 * b.volume_nl / NL_PER_UM3 / np.pi) ** (1.0 / 3.0)
            inflight[k] = b.length_um <= config.compact_ratio * d_eq and not (b.top_chord_ratio < config.tail_chord_ratio)
            if not inflight[k]:
                flags[k].append(q.TAIL)
    ok_seq = [q.BLURRED, q.LOW_CONTRAST, q.SATURATED, q.ILLUMINATION]
    for k in range(m):
        if any(f in ok_seq for f in flags[k]):
            # untrusted intensities: no number from this frame
            att_vol[k] = grown[k] = drop_vol[k] = det_vol[k] = drop_z[k] = drop_x[k] = np.nan
            flow[k] = np.nan
            inflight[k] = False
    inflight_only_flags = {q.TAIL}
    frames = pd.DataFrame({
        "file": [r.file for r in records],
        "page": pd.array([r.page for r in records], dtype="Int64"),
        "delay_us": delay,
        "repeat": np.array([r.repeat for r in records], int),
        "attached": attached.astype(bool),
        "attached_volume_nl": att_vol,
        "grown_volume_nl": grown,
        "drop_volume_nl": drop_vol,
        "detached_volume_nl": det_vol,
        "drop_z_um": drop_z,
        "drop_x_um": drop_x,
        "n_satellites": pd.array([None if not np.isfinite(v) else int(v) for v in nsat], dtype="Int64"),
        "flow_velocity_m_s": flow,
        "quality": [q.join([f for f in fl if f not in inflight_only_flags]) for fl in flags],
        "drop_length_um": length,
        "drop_diameter_um": diam,
        "inflight": inflight,
        "neck_px": np.array([r.neck_px for r in records], float),
        "blur_px": np.array([r.blur_px for r in records], float),
        "wall_contrast": np.array([r.wall_contrast for r in records], float),
        "gain": np.array([r.gain for r in records], float),
    }, columns=FRAME_COLUMNS)
    # --- summary -------------------------------------------------------------------------
    last_att = delay[attached & (delay < pinch)] if np.isfinite(pinch) else delay[attached]
    g_pinch = float("nan")
    if np.isfinite(pinch) and last_att.size:
        at_last = grown[(delay == last_att.max()) & attached]
        at_last = at_last[np.isfinite(at_last)]
        g_pinch = float(np.mean(at_last)) if at_last.size else float("nan")
    inf_vol = drop_vol[inflight]
    line = fit_line(delay[inflight], drop_z[inflight])
    traj = fit_line(drop_z[inflight], drop_x[inflight])
    sats = nsat[inflight & np.isfinite(nsat)]
    wf = meta.waveform or {}
    t_ms = float("nan")
    fv_ms = float("nan")
    if "u1_um_per_ms" in wf and "u2_um" in wf:
        dead = float(wf.get("dead_time_us", config.dead_time_us))
        t_ms = dead + 1000.0 * float(wf["u2_um"]) / float(wf["u1_um_per_ms"])
        if meta.nozzle_inner_diameter_um:
            fv_ms = flow_velocity_at(grown_by_delay, t_ms, meta.nozzle_inner_diameter_um)
    calib = cal.to_dict()
    calib["edge_blur_sigma_px"] = sigma_px
    calib["orientation"] = meta.orientation
    summary = {
        "schema_version": SCHEMA_VERSION,
        "sequence": str(meta.path),
        "n_frames": int(len(meta.frames)),
        "n_measured": int(m),
        "pinchoff_us": pinch,
        "grown_volume_at_pinchoff_nl": g_pinch,
        "initial_meniscus_volume_nl": meniscus,
        "initial_meniscus_source": (f"attached volume of the first frame(s), delay {float(np.min(delay)):g} us <= dead time "
                                    f"{dead_time:g} us" if meniscus_at_rest else q.NO_REST_MENISCUS),
        "inflight_volume_nl": float(np.mean(inf_vol)) if inf_vol.size else float("nan"),
        "inflight_volume_std_nl": float(np.std(inf_vol, ddof=1)) if inf_vol.size >= 2 else float("nan"),
        "inflight_frames": int(inf_vol.size),
        "jetting_velocity_m_s": line.slope,
        "jetting_velocity_se_m_s": line.slope_se,
        "trajectory_angle_mrad": float(1000.0 * np.arctan(traj.slope)) if np.isfinite(traj.slope) else float("nan"),
        "satellites": int(np.median(sats)) if sats.size else None,
        "max_stroke_us": t_ms,
        "flow_velocity_at_max_stroke_m_s": fv_ms,
        "calibration": calib,
        "errors": errors,
        "quality_counts": frames["quality"].value_counts().to_dict(),
        "software": software_versions(),
        "config": asdict(config),
    }
    return frames, summary


def write_result(result: MeasureResult, out_dir, *, csv: bool = False, extra_summary: dict | None = None) -> None:
    """Write frames.parquet (+ frames.csv), per_delay.parquet and summary.json into ``out_dir``."""
    from identify.atomic import write_json

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    result.frames.to_parquet(out / "frames.parquet", index=False)
    if csv:
        result.frames.to_csv(out / "frames.csv", index=False)
    result.per_delay().to_parquet(out / "per_delay.parquet", index=False)
    summary = dict(result.summary)
    if extra_summary:
        summary.update(extra_summary)
    write_json(out / "summary.json", summary)
