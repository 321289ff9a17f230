"""The per-frame measurement: one decoded frame -> a small `FrameRecord`.

`measure_frame` runs the stages in order:

1. `measure_photometry`: illumination gain, saturation, the frame's own blur and contrast;
2. `segment_frame`: dark mask in the region of interest and its labelled bodies;
3. `dropvision.frame.bodies.measure_attached`: the liquid joined to the nozzle;
4. `dropvision.analysis.pinchoff.thread_joined_labels`: bodies still joined to it by a thin thread;
5. `dropvision.frame.bodies.measure_body` / `describe_detached`: the detached bodies.

`stream_frames` measures a sequence's frames in order through the engine `dvcore.parallel`
(a few forked processes on Linux for a long sequence, see `processes_usable`, or threads),
decoding at most ``2 * workers`` frames (or chunks of frames) at once, so memory does not grow
with the sequence length.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field

import numpy as np

import dropvision.quality as q
import dvcore.parallel as _parallel
from dropvision.frame.bodies import (
    DetachedBody,
    body_volume_uncertainty_nl,
    describe_detached,
    find_nozzle_body,
    measure_attached,
    measure_body,
    off_path_reason,
)
from dropvision.frame.body_classes import appearance, out_of_focus_reason
from dropvision.calibrate.frame_context import BlurReference, FrameContext
from dropvision.frame.outline import body_outline, clip_rows, mask_centroid
from dropvision.analysis.pinchoff import thread_joined_labels
from dropvision.frame.segmentation import DarkBody, Segmentation, dark_mask, segment, threshold_image
from dropvision.frame.edges import RowEdges
from dropvision.frame.volume import integrate, split_at_row, waist_row


@dataclass
class FrameRecord:
    """Everything kept from one frame (small).

    Volumes in nl, rows in region coordinates (px), ``neck_px`` and ``blur_px`` in px; ``bodies``
    are the in-focus detached bodies, largest first (the first is the main drop); ``rejected``
    the out-of-focus ones (`dropvision.frame.body_classes`).
    """

    index: int
    file: str
    page: int | None
    delay_us: float
    repeat: int
    attached_volume_nl: float = float("nan")
    attached_volume_uncertainty_nl: float = float("nan")
    attached_common_uncertainty_nl: float = float("nan")  # edges' common error: see AttachedLiquid
    attached_plane_uncertainty_nl: float = float("nan")
    attached_plane_position_uncertainty_nl: float = float("nan")  # see AttachedLiquid
    attached_face_halo_nl: float = 0.0  # see AttachedLiquid.face_halo_nl
    attached_halo_band_nl: float = 0.0  # see AttachedLiquid.halo_band_nl
    attached_bottom_row: float = float("nan")
    neck_px: float = float("nan")
    bodies: list[DetachedBody] = field(default_factory=list)
    rejected: list[DetachedBody] = field(default_factory=list)  # out of focus (mist, dust): never liquid
    attached_body: dict | None = None  # area of the attached body (bodies.parquet; appearance not computed)
    attached_outline: np.ndarray | None = field(default=None, repr=False)  # its outline (`dropvision.frame.outline`)
    flags: list[str] = field(default_factory=list)
    gain: float = 1.0
    blur_px: float = float("nan")
    wall_contrast: float = float("nan")
    error: str | None = None


def measure_frame(image: np.ndarray, ctx: FrameContext, ref=None, logger=None) -> FrameRecord:
    """Measure one decoded frame (canonical orientation) with a sequence's context.

    Parameters
    ----------
    image : ndarray
        The full frame (raw grey levels).
    ctx : FrameContext
        From `dropvision.calibrate.calibration_pass.calibrate_sequence`.
    ref : frame reference, optional
        ``index``, ``file``, ``page``, ``delay_us`` (µs), ``repeat`` copied into the record.
    logger : object, optional
        Rerun logger (``log_frame``); None costs nothing.

    Returns
    -------
    FrameRecord
    """
    rec = FrameRecord(
        index=getattr(ref, "index", 0), file=getattr(ref, "file", ""), page=getattr(ref, "page", None),
        delay_us=float(getattr(ref, "delay_us", 0.0)), repeat=getattr(ref, "repeat", 0),
    )
    photo = measure_photometry(image, ctx)
    rec.gain, rec.blur_px, rec.wall_contrast = photo.gain, photo.blur_px, photo.wall_contrast
    rec.flags.extend(photo.flags)
    roi = ctx.region(image)
    seg = segment_frame(roi, ctx, rec.gain)
    edges: list[RowEdges] = []
    # no tip plane: the calibration found no nozzle (`dropvision.calibrate.calibration`), nothing is attached
    nozzle_body = find_nozzle_body(seg.bodies, ctx.geometry.axis_roi) if np.isfinite(ctx.geometry.tip_roi) else None
    threads: set[int] = set()
    sources: dict[int, tuple[DarkBody, RowEdges]] = {}
    if nozzle_body is None:
        rec.flags.append(q.NO_NOZZLE)
    else:
        att = measure_attached(roi, ctx, seg, nozzle_body, rec.gain)
        # its appearance is not needed for any decision: not computed per frame (speed)
        box, row0_px, col0_px = nozzle_body.bbox, ctx.geometry.row0_px, ctx.geometry.col0_px
        row_px, col_px = mask_centroid(seg.labels, nozzle_body.label, box, row0_px, col0_px)
        rec.attached_body = {"area_px": int(nozzle_body.area_px), "min_transmission": float("nan"),
                             "edge_blur_px": float("nan"), "row_px": row_px, "col_px": col_px}
        rec.attached_outline = body_outline(seg.labels, nozzle_body.label, box, row0_px, col0_px)
        edges.append(att.edges)
        if att.leaves:
            rec.flags.append(q.ATTACHED_LEAVES)
        else:
            rec.attached_volume_nl = att.volume_nl
            rec.attached_volume_uncertainty_nl = att.volume_uncertainty_nl
            rec.attached_common_uncertainty_nl = att.common_uncertainty_nl
            rec.attached_plane_uncertainty_nl = att.plane_uncertainty_nl
            rec.attached_plane_position_uncertainty_nl = att.plane_position_uncertainty_nl
            rec.attached_face_halo_nl = att.face_halo_nl
            rec.attached_halo_band_nl = att.halo_band_nl
        rec.attached_bottom_row = att.bottom_row
        rec.neck_px = att.neck_px
        if np.isfinite(rec.attached_bottom_row):
            threads = thread_joined_labels(roi, ctx, seg, nozzle_body, rec.attached_bottom_row, rec.gain)
    for b in seg.bodies:
        if b.nozzle:
            continue
        ed, bv = measure_body(roi, ctx, seg, b, rec.gain)
        edges.append(ed)
        if bv.volume_px3 <= 0:
            continue
        if b.label in threads:  # still joined by a thread thinner than the blur: attached liquid
            if np.isfinite(rec.attached_volume_nl):
                rec.attached_volume_nl += bv.volume_px3 * ctx.geometry.nl_per_px3
                u = body_volume_uncertainty_nl(bv, ctx)  # the same edge error: added, not in quadrature
                rec.attached_volume_uncertainty_nl += u
                rec.attached_common_uncertainty_nl += u
            rec.attached_bottom_row = max(rec.attached_bottom_row, bv.bottom_row)
            continue
        app = appearance(roi, ctx.photometry.inv_background, seg.labels, b.label, b.bbox, rec.gain,
                         floor=ctx.photometry.liquid_level)
        body = describe_detached(ctx, seg, b, ed, bv)
        body.min_transmission, body.edge_blur_px = app.min_transmission, app.edge_blur_px
        why = out_of_focus_reason(app, ctx.blur.reference_spread_px, ctx.blur.mist_blur_factor,
                                  ctx.config.mist_blur_offset_px,
                                  "nozzle walls'" if ctx.blur.reference is BlurReference.NOZZLE_WALLS
                                  else "the sharpest body's")
        if why is None:
            rec.bodies.append(body)
            sources[id(body)] = (b, ed)
        else:
            body.reason = why
            rec.rejected.append(body)
    rec.bodies.sort(key=lambda d: -d.volume_nl)
    for body in rec.bodies[1:]:
        why = off_path_reason(rec.bodies[0], body, ctx.blur.reference is BlurReference.NOZZLE_WALLS)
        if why is not None:
            body.reason, body.off_path = why, True
            rec.rejected.append(body)
    rec.bodies = [b for b in rec.bodies if not b.off_path]
    if rec.bodies:
        _split_touching(ctx, seg, rec, *sources[id(rec.bodies[0])])
    if logger is not None:
        _log_frame(logger, ref, image, ctx, seg, nozzle_body, rec, edges)
    return rec


def _split_touching(ctx: FrameContext, seg: Segmentation, rec: FrameRecord, body: DarkBody, edges: RowEdges) -> None:
    """A satellite touching the main drop (one silhouette with a short waist) is split off it.

    The main drop is then the larger lobe; the smaller one, when compact (at most
    ``ctx.config.compact_ratio`` equivalent diameters long: a tail with a bulb is not split off), is
    listed as a touching satellite (counted in ``n_satellites``: a drop of its own; its volume
    stays in the main drop's ``drop_volume_nl`` and the detached volume). `dropvision.frame.volume.waist_row` says
    what a waist is.
    """
    row = waist_row(edges)
    if row is None:
        return
    main = rec.bodies[0]
    parts = []
    for part in split_at_row(edges, row):
        vol = integrate(part, ctx.geometry.tilt_rad, None, ctx.blur.correction_sigma_px)
        if vol.volume_px3 <= 0:
            return
        d = describe_detached(ctx, seg, body, part, vol)
        d.min_transmission, d.edge_blur_px = main.min_transmission, main.edge_blur_px
        # each lobe's outline: the silhouette's between the lobe's rows (cut at the waist)
        d.outline = clip_rows(d.outline, ctx.geometry.row0_px + d.top_row - 0.5, ctx.geometry.row0_px + d.bottom_row + 0.5)
        parts.append(d)
    parts.sort(key=lambda d: -d.volume_nl)
    if parts[1].elongated(ctx.config.compact_ratio):  # a tail (with a bulb), not a satellite
        return
    parts[1].touching = True
    parts[1].reason = f"touches the main drop (one silhouette, split at its waist, row {row + ctx.geometry.row0_px})"
    rec.bodies[0] = parts[0]
    rec.bodies.append(parts[1])
    rec.bodies[1:] = sorted(rec.bodies[1:], key=lambda d: -d.volume_nl)


@dataclass(frozen=True)
class Photometry:
    """A frame's illumination, blur and wall contrast (`measure_photometry`).

    Attributes
    ----------
    gain : float
        Frame illumination over the background model (1 where unknown or clipped).
    blur_px : float
        Edge blur (Gaussian sigma, px) from the nozzle walls' steepness relative to the
        calibration frame; NaN where not judged (no wall reference) or unmeasurable (the walls
        show no edge: flagged blurred).
    wall_contrast : float
        1 - the walls' transmission (NaN without a wall reference).
    flags : tuple of str
        Quality codes (`dvcore.schema.Quality`): illumination, saturated or clipped, blurred,
        low contrast.
    """

    gain: float
    blur_px: float = float("nan")
    wall_contrast: float = float("nan")
    flags: tuple[str, ...] = ()


def measure_photometry(image: np.ndarray, ctx: FrameContext) -> Photometry:
    """Illumination gain, saturation, edge blur and wall contrast of a frame.

    Flags: illumination unknown or off by more than 10 ``ctx.config.gain_tolerance``, more than
    ``ctx.config.saturation_limit`` of the background samples saturated, blur or contrast off the
    calibration frame's (an unmeasurable blur, walls without any edge, is NaN and flagged blurred),
    less than half of the frame bright background (`dropvision.quality.background_fraction`: no
    backlit drop image at all).

    Parameters
    ----------
    image : ndarray
        The full frame (raw grey levels).
    ctx : FrameContext

    Returns
    -------
    Photometry
    """
    flags: list[str] = []
    blur_px = wall_contrast = float("nan")
    ph = ctx.photometry
    samples = ctx.geometry.crop(image)[ph.sample_rows, ph.sample_cols]
    clipped = bool(np.isfinite(ph.clipped_level))
    # a clipped background shows no strobe variation: the strobe is taken as steady (gain 1)
    gain = 1.0 if clipped else q.frame_gain(samples, ph.background[ph.sample_rows, ph.sample_cols])
    if not np.isfinite(gain):
        gain = 1.0
        flags.append(q.ILLUMINATION)
    if q.saturation_fraction(samples, ph.max_value) > ctx.config.saturation_limit:
        flags.append(q.CLIPPED if clipped else q.SATURATED)
    walls = ph.walls
    if walls is not None:
        prof = image[walls.rows, walls.cols].astype(np.float32) * walls.inv_background / gain
        sharp = q.edge_sharpness(prof)
        wall_contrast = q.wall_contrast(prof)
        if sharp > 0:
            blur_px = walls.blur_sigma_px * walls.sharpness / sharp
            if blur_px > walls.max_frame_blur_px:
                flags.append(q.BLURRED)
        else:
            # the walls show no edge at all (a black or uniform frame): the blur is unmeasurable,
            # NaN (the frames table holds no infinities) and the frame flagged as blurred
            flags.append(q.BLURRED)
        if wall_contrast < walls.min_wall_contrast:
            flags.append(q.LOW_CONTRAST)
    if abs(gain - 1.0) > 10 * ctx.config.gain_tolerance:
        flags.append(q.ILLUMINATION)
    if q.background_fraction(image) < q.MIN_BACKGROUND_FRACTION:  # a photograph, a texture: no drop image
        flags.append(q.NOT_DROP_IMAGE)
    return Photometry(gain=gain, blur_px=blur_px, wall_contrast=wall_contrast, flags=tuple(flags))


def segment_frame(roi: np.ndarray, ctx: FrameContext, gain: float) -> Segmentation:
    """Dark bodies of the region of interest (thresholds follow the frame's illumination).

    Parameters
    ----------
    roi : ndarray
        Raw frame, region of interest.
    ctx : FrameContext
    gain : float
        Frame illumination relative to the background model; beyond ``ctx.config.gain_tolerance`` the
        threshold image is recomputed for it.

    Returns
    -------
    Segmentation
    """
    thr_img = ctx.photometry.thr_image
    if abs(gain - 1.0) > ctx.config.gain_tolerance:
        thr_img = threshold_image(ctx.photometry.background * gain, ctx.photometry.threshold, roi.dtype)
    mask = dark_mask(np.ascontiguousarray(roi), thr_img, ctx.photometry.allowed)
    return segment(mask, ctx.config.min_body_area_px)


def _log_frame(logger, ref, image: np.ndarray, ctx: FrameContext, seg: Segmentation, nozzle_body: DarkBody | None,
               rec: FrameRecord, all_edges: list[RowEdges]) -> None:
    """Hand the frame's stages to a Rerun logger (only called when logging is on).

    The class image and body boxes follow bodies.parquet's rules as far as one frame can tell
    (`dropvision.app.rerun_log.class_image`): mist and dust both as out of focus (``rec.rejected``).
    """
    g = ctx.geometry
    t_full = image.astype(np.float32)
    g.crop(t_full)[...] *= ctx.photometry.inv_background
    pts = []
    for ed in all_edges:
        pts.append(np.column_stack([ed.left_px, ed.row]))
        pts.append(np.column_stack([ed.right_px, ed.row]))
    edges = np.concatenate(pts) if pts else np.zeros((0, 2))
    t_roi = g.crop(t_full)
    t_full = np.ones_like(t_full)
    g.crop(t_full)[...] = t_roi
    logger.log_measured_frame(ref, image, t_full, seg, nozzle_body, rec.bodies, rec.rejected, ctx.photometry.opaque,
                              edges, compact_ratio=ctx.config.compact_ratio, roi_origin_xy=(g.col0_px, g.row0_px))


#: Fewest frames for which `stream_frames` forks worker processes (below, threads: forking two
#: processes costs some 10-20 ms, a frame ~3 ms of decoding and measuring).
MIN_FRAMES_FOR_PROCESSES = 32
#: Most frames in one chunk sent to a forked worker (chunks are ~1/4 of a worker's share, at most
#: this: few messages, and little work in flight when the caller stops).
MAX_CHUNK_FRAMES = 32


def _measure_index(seq, ctx: FrameContext, decoded: dict, i: int, logger=None) -> FrameRecord:
    """Decode frame ``i`` of ``seq`` (or take it from ``decoded``) and measure it."""
    image = decoded.pop(i, None)
    if image is not None:
        return measure_frame(image, ctx, seq.meta.frames[i], logger)
    fr = seq.read(i)
    if fr.image is None:
        return FrameRecord(fr.ref.index, fr.ref.file, fr.ref.page, fr.ref.delay_us, fr.ref.repeat, error=fr.error)
    return measure_frame(fr.image, ctx, fr.ref, logger)


def _give_warnings(seq, caught) -> None:
    """Issue in this process the warnings a forked worker recorded; the colour -> grey note only
    if it is the sequence's first (as `dropvision.io.sequence.Sequence.read` does)."""
    import warnings

    from dropvision.io.sequence_meta import RGBConvertedWarning

    for category, message in caught:
        first = getattr(seq, "first_colour_note", None)
        if issubclass(category, RGBConvertedWarning) and first is not None and not first():
            continue
        warnings.warn(message, category, stacklevel=3)


def processes_usable(n_frames: int, workers: int, logger=None, *,
                     min_frames: int = MIN_FRAMES_FOR_PROCESSES) -> bool:
    """Whether `stream_frames` measures in forked processes: no Rerun logger (it lives in this
    process) and the engine's rules (`dvcore.parallel.processes_usable`: Linux, two workers,
    ``min_frames`` frames, a top-level process running one thread at the operating system's
    level, :data:`dvcore.parallel.NO_FORK_ENV` unset). The command line keeps one thread up to the fork
    (OpenBLAS on one thread, OpenCV's pool never started: :func:`dvcore.parallel.serial_native_pools`). The
    per-frame work holds the GIL for much of its time, so two threads measure hardly faster
    than one; two processes nearly twice as fast."""
    return logger is None and _parallel.processes_usable(n_frames, workers, min_items=min_frames)


def _progress_bar(n: int, progress: bool):
    if not progress:
        return None
    from tqdm import tqdm  # optional progress bar: imported only when asked for

    return tqdm(total=n, desc="measure", unit="frame", file=sys.stderr)


def stream_frames(seq, indices, ctx: FrameContext, workers: int, logger=None, progress: bool = False,
                  decoded: dict | None = None, *, processes: bool | None = None):
    """Measure frames of an open sequence, yielding their `FrameRecord` in order.

    The engine `dvcore.parallel.map_in_order` runs them: in ``workers`` forked processes
    (contiguous chunks of frames) where its rules allow it (:func:`processes_usable`), otherwise
    on ``workers`` threads, at most ``2 * workers`` frames (or chunks) decoded at once; with a
    logger, here, one after the other. The records are the same either way; a forked worker's
    warnings are given here, in order (the colour note once per sequence).

    Parameters
    ----------
    seq : dropvision.io.sequence.Sequence
        Open sequence (``meta``, ``read``; ``after_fork`` runs in each forked worker).
    indices : sequence of int
        Frames to measure.
    ctx : FrameContext
    workers : int
        Processes or threads.
    logger : object, optional
        Rerun logger.
    progress : bool
        Progress bar on stderr (started after the workers are forked).
    decoded : dict, optional
        Images already decoded by the calibration pass (index -> image, a few): used once and
        dropped instead of being decoded again.
    processes : bool, optional
        As for `dvcore.parallel.map_in_order` (True: fork whatever the rules say; tests only).

    Yields
    ------
    FrameRecord
        With ``error`` set (and nothing measured) for an unreadable frame.
    """
    decoded = {} if decoded is None else decoded
    if logger is not None:  # the Rerun logger lives in this process: one frame after the other
        workers, processes = 1, False

    def measure(i):
        return _measure_index(seq, ctx, decoded, i, logger)

    yield from _parallel.map_in_order(
        measure, indices, workers, processes=processes, min_items=MIN_FRAMES_FOR_PROCESSES,
        min_chunk=4, max_chunk=MAX_CHUNK_FRAMES, after_fork=getattr(seq, "after_fork", None),
        relay=lambda caught: _give_warnings(seq, caught), progress=lambda n: _progress_bar(n, progress),
        label=str(seq.meta.path), unit="frame")
