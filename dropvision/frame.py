"""The per-frame measurement: one decoded frame -> a small `FrameRecord`.

`measure_frame` runs the stages in order:

1. `measure_photometry`: illumination gain, saturation, the frame's own blur and contrast;
2. `segment_frame`: dark mask in the region of interest and its labelled bodies;
3. `dropvision.bodies.measure_attached`: the liquid joined to the nozzle;
4. `dropvision.pinchoff.thread_joined_labels`: bodies still joined to it by a thin thread;
5. `dropvision.bodies.measure_body` / `describe_detached`: the detached bodies.

`stream_frames` measures a sequence's frames in order with a few forked processes (Linux, a
long sequence, see `processes_usable`) or threads, decoding at most ``2 * workers`` frames (or
chunks of frames) at once, so memory does not grow with the sequence length.
"""

from __future__ import annotations

import sys
from collections import deque
from contextlib import contextmanager
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

import dropvision.quality as q
import dvcore.process as _process
from dropvision.bodies import (
    DetachedBody,
    body_volume_uncertainty_nl,
    describe_detached,
    find_nozzle_body,
    measure_attached,
    measure_body,
    off_path_reason,
)
from dropvision.classify import appearance, out_of_focus_reason
from dropvision.context import BlurReference, FrameContext
from dropvision.outline import body_outline, clip_rows, mask_centroid
from dropvision.pinchoff import thread_joined_labels
from dropvision.segmentation import DarkBody, Segmentation, dark_mask, segment, threshold_image
from dropvision.edges import RowEdges
from dropvision.volume import integrate, split_at_row, waist_row


@dataclass
class FrameRecord:
    """Everything kept from one frame (small).

    Volumes in nl, rows in region coordinates (px), ``neck_px`` and ``blur_px`` in px; ``bodies``
    are the in-focus detached bodies, largest first (the first is the main drop); ``rejected``
    the out-of-focus ones (`dropvision.classify`).
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
    attached_bottom_row: float = float("nan")
    neck_px: float = float("nan")
    bodies: list[DetachedBody] = field(default_factory=list)
    rejected: list[DetachedBody] = field(default_factory=list)  # out of focus (mist, dust): never liquid
    attached_body: dict | None = None  # area of the attached body (bodies.parquet; appearance not computed)
    attached_outline: np.ndarray | None = field(default=None, repr=False)  # its outline (`dropvision.outline`)
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
        From `dropvision.calibration_pass.calibrate_sequence`.
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
    # no tip plane: the calibration found no nozzle (`dropvision.calibration`), nothing is attached
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
    stays in the main drop's ``drop_volume_nl`` and the detached volume). `dropvision.volume.waist_row` says
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
#: Set to 1 to keep `stream_frames` on threads (no forked processes).
NO_FORK_ENV = "DROPVISION_NO_FORK"

# what a forked worker measures: (sequence, context, calibration frames), set just before the
# pool forks its processes (they inherit it: nothing is pickled on the way in)
_FORK_STATE: tuple | None = None


def _measure_index(seq, ctx: FrameContext, decoded: dict, i: int, logger=None) -> FrameRecord:
    """Decode frame ``i`` of ``seq`` (or take it from ``decoded``) and measure it."""
    image = decoded.pop(i, None)
    if image is not None:
        return measure_frame(image, ctx, seq.meta.frames[i], logger)
    fr = seq.read(i)
    if fr.image is None:
        return FrameRecord(fr.ref.index, fr.ref.file, fr.ref.page, fr.ref.delay_us, fr.ref.repeat, error=fr.error)
    return measure_frame(fr.image, ctx, fr.ref, logger)


def _forked_worker_init(parent_pid: int) -> None:
    """In a forked worker: die with the parent (``kill -9`` of it leaves no worker behind),
    leave Ctrl-C to the parent (it ends the workers), and give the sequence a lock and open
    multi-frame files of its own (the parent's lock may have been held at the fork, and an
    inherited file's offset is shared with the parent)."""
    import signal

    from dvcore.process import die_with_parent

    die_with_parent(parent_pid)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    reset = getattr(_FORK_STATE[0], "after_fork", None)
    if reset is not None:
        reset()


def _measure_chunk(indices) -> tuple[list, list]:
    """In a forked worker: the records of ``indices`` and the warnings they raised (category,
    message), for the parent to give in order (a child's own would be lost or printed)."""
    import warnings

    seq, ctx, decoded = _FORK_STATE
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        recs = [_measure_index(seq, ctx, decoded, i) for i in indices]
    return recs, [(w.category, str(w.message)) for w in caught]


def _give_warnings(seq, caught) -> None:
    """Issue in this process the warnings a forked worker recorded; the colour -> grey note only
    if it is the sequence's first (as `dropvision.sequence.Sequence.read` does)."""
    import warnings

    from dropvision.sequence_meta import RGBConvertedWarning

    for category, message in caught:
        first = getattr(seq, "first_colour_note", None)
        if issubclass(category, RGBConvertedWarning) and first is not None and not first():
            continue
        warnings.warn(message, category, stacklevel=3)


def processes_usable(n_frames: int, workers: int, logger=None, *,
                     min_frames: int = MIN_FRAMES_FOR_PROCESSES) -> bool:
    """Whether `stream_frames` measures in forked processes: on Linux, with at least two workers
    and :data:`MIN_FRAMES_FOR_PROCESSES` frames, no Rerun logger (it lives in this process), only
    from a top-level process (not inside a pool's or a campaign's worker: no nested pools), unless
    :data:`NO_FORK_ENV` is set, and only while this process runs **one thread at the operating
    system's level** (`dvcore.process.os_thread_count`). Any other thread -- a notebook's, a
    viewer's, or a native pool's (OpenBLAS started with NumPy, OpenCV's after its first parallel
    call) -- may hold a lock at the instant of the fork, and the child that needs it waits for
    ever (issue 29: a worker blocked in ``pthread_mutex_lock`` inside ``cv2.findContours`` after
    the calibration had used OpenCV's pool). With one thread there is no such lock; the command
    line keeps it so (OpenBLAS on one thread, OpenCV's pool never started: :func:`serial_native_pools`).
    The per-frame work holds the GIL for much of its time, so two threads measure hardly faster
    than one; two processes nearly twice as fast. ``min_frames``: another least count, for work
    whose items cost more than a frame (a shot of `dropvision.shots`: its own decoding and
    assembly)."""
    import multiprocessing
    import os
    import threading

    from dvcore.process import os_thread_count

    return (sys.platform == "linux" and workers >= 2 and n_frames >= min_frames
            and logger is None and not os.environ.get(NO_FORK_ENV)
            and multiprocessing.parent_process() is None and threading.active_count() == 1
            and os_thread_count() == 1)


@contextmanager
def serial_native_pools(active: bool = True):
    """While ``active``: OpenCV runs its functions on the calling thread, so that its thread pool
    is never started and the process stays single-threaded up to the fork of the frame workers
    (:func:`processes_usable`). Its thread count is given back afterwards (setting it starts no
    thread). `dropvision.measurement.measure_sequence` wraps a measurement that will fork in it."""
    if not active:
        yield
        return
    import cv2

    before = cv2.getNumThreads()
    cv2.setNumThreads(0)
    try:
        yield
    finally:
        cv2.setNumThreads(before)


class WorkerProcessDied(RuntimeWarning):
    """A forked worker process of `stream_frames` died (killed, out of memory, a crash in a
    decoder); the frames it had not returned are measured again with threads."""


class WorkerProcessStalled(WorkerProcessDied):
    """The forked workers of `stream_frames` used no CPU for :data:`STALL_S` seconds while a
    result was awaited (a worker blocked for ever, e.g. on a lock held at the fork); they are
    killed and the frames not yet returned are measured with threads."""


#: Seconds without CPU progress of every worker process, while their result is awaited, after
#: which `stream_frames` takes them for stalled (:class:`WorkerProcessStalled`). A busy worker
#: uses CPU even on a loaded machine; one blocked on a lock uses none. The environment variable
#: :data:`STALL_ENV` sets another value.
STALL_S = 10.0
STALL_ENV = _process.STALL_ENV


class _Watchdog:
    """A future's result, waited for with a bound (`dvcore.process.wait_working`): while it is
    awaited, the worker processes ``pids`` must use CPU at least once every ``stall_s`` seconds,
    or `dvcore.process.WorkersStalled` is raised: never an endless wait."""

    def __init__(self, pids, stall_s: float, poll_s: float = 0.2):
        self.pids, self.stall_s, self.poll_s = list(pids), stall_s, poll_s

    def result(self, future):
        from dvcore.process import wait_working

        wait_working([future], lambda: self.pids, self.stall_s, poll_s=self.poll_s)
        return future.result()


def _stall_s() -> float:
    return _process.stall_s(STALL_S)


def _progress_bar(n: int, progress: bool):
    if not progress:
        return None
    from tqdm import tqdm  # optional progress bar: imported only when asked for

    return tqdm(total=n, desc="measure", unit="frame", file=sys.stderr)


def _in_order(pool, fn, items, depth: int, result=None):
    """``fn(item)`` for every item, run on ``pool``, yielded in the items' order, with at most
    ``depth`` submitted and not yet yielded (memory stays bounded, whatever the length);
    ``result(future)`` waits for each (default ``future.result()``; the forked workers' watchdog
    bounds the wait)."""
    result = result or (lambda f: f.result())
    pending: deque = deque()
    it = iter(items)
    for item in it:
        pending.append(pool.submit(fn, item))
        if len(pending) >= depth:
            break
    while pending:
        value = result(pending.popleft())
        for item in it:  # one more, if any
            pending.append(pool.submit(fn, item))
            break
        yield value


def _stream_forked(seq, indices, ctx: FrameContext, workers: int, decoded: dict, progress: bool = False):
    """`stream_frames` in ``workers`` forked processes: contiguous chunks of frames (at most
    :data:`MAX_CHUNK_FRAMES`), at most ``2 * workers`` chunks in flight, records in order; the
    workers' warnings given here, in order. The processes are forked before the progress bar
    starts its monitor thread. If the caller stops early or is interrupted, the workers are
    terminated at once; if a worker dies, or the workers use no CPU for :data:`STALL_S` seconds
    while a result is awaited (`_Watchdog`), they are ended and the frames not yet returned are
    measured with threads (a :class:`WorkerProcessDied` or :class:`WorkerProcessStalled` warning
    says so) instead of losing the sequence or waiting for ever. Every wait on a worker is bounded."""
    import multiprocessing
    import os
    import warnings
    from concurrent.futures import ProcessPoolExecutor
    from concurrent.futures.process import BrokenProcessPool

    from dvcore.process import WorkersStalled, close_pool, end_pool, pool_pids

    global _FORK_STATE
    indices = list(indices)
    size = min(MAX_CHUNK_FRAMES, max(4, -(-len(indices) // (4 * workers))))
    chunks = [indices[a:a + size] for a in range(0, len(indices), size)]
    done, bar, finished, stalled = 0, None, False, False
    _FORK_STATE = (seq, ctx, dict(decoded))
    decoded.clear()
    pool = ProcessPoolExecutor(max_workers=min(workers, len(chunks)), initializer=_forked_worker_init,
                               initargs=(os.getpid(),), mp_context=multiprocessing.get_context("fork"))
    try:
        with warnings.catch_warnings():  # Python >= 3.12 warns of every fork once native threads exist
            warnings.simplefilter("ignore", DeprecationWarning)
            first = pool.submit(int)  # the first submit forks every worker: now, before the bar's thread
        watchdog = _Watchdog(pool_pids(pool), _stall_s())
        watchdog.result(first)
        bar = _progress_bar(len(indices), progress)
        for recs, caught in _in_order(pool, _measure_chunk, chunks, 2 * workers, watchdog.result):
            _give_warnings(seq, caught)
            for rec in recs:
                yield rec
                done += 1
                if bar is not None:
                    bar.update()
        finished = True
    except (BrokenProcessPool, WorkersStalled) as exc:
        stalled = isinstance(exc, WorkersStalled)
        end_pool(pool, kill=True)  # before measuring on: a stalled worker holds no CPU, but memory
        rest = indices[done:]
        what = "the worker processes stalled" if stalled else "a worker process died"
        warnings.warn(f"{seq.meta.path}: {what} ({exc}); measuring the remaining {len(rest)} frame(s) with threads",
                      WorkerProcessStalled if stalled else WorkerProcessDied, stacklevel=3)
        bar = bar if bar is not None else _progress_bar(len(indices), progress)
        with ThreadPoolExecutor(max_workers=workers) as tpool:
            for rec in _in_order(tpool, lambda i: _measure_index(seq, ctx, {}, i), rest, 2 * workers):
                yield rec
                if bar is not None:
                    bar.update()
    finally:
        if finished:
            close_pool(pool)
        else:  # stopped early, interrupted, an error, a dead or stalled worker: no waiting for chunks in flight
            end_pool(pool)
        _FORK_STATE = None
        if bar is not None:
            bar.close()


def stream_frames(seq, indices, ctx: FrameContext, workers: int, logger=None, progress: bool = False,
                  decoded: dict | None = None):
    """Measure frames of an open sequence, yielding their `FrameRecord` in order.

    Where :func:`processes_usable` says so, ``workers`` forked processes measure contiguous
    chunks of frames; otherwise ``workers`` threads, at most ``2 * workers`` frames decoded at
    once (one thread when logging). The records are the same either way.

    Parameters
    ----------
    seq : dropvision.sequence.Sequence
        Open sequence (``meta``, ``read``).
    indices : sequence of int
        Frames to measure.
    ctx : FrameContext
    workers : int
        Processes or threads.
    logger : object, optional
        Rerun logger.
    progress : bool
        Progress bar on stderr.
    decoded : dict, optional
        Images already decoded by the calibration pass (index -> image, a few): used once and
        dropped instead of being decoded again.

    Yields
    ------
    FrameRecord
        With ``error`` set (and nothing measured) for an unreadable frame.
    """
    decoded = {} if decoded is None else decoded
    if processes_usable(len(indices), workers, logger):  # before any progress bar starts its thread
        yield from _stream_forked(seq, indices, ctx, workers, decoded, progress)
        return
    bar = _progress_bar(len(indices), progress)
    try:
        if workers <= 1 or logger is not None:
            for i in indices:
                yield _measure_index(seq, ctx, decoded, i, logger)
                if bar is not None:
                    bar.update()
            return
        with ThreadPoolExecutor(max_workers=workers) as pool:
            for rec in _in_order(pool, lambda i: _measure_index(seq, ctx, decoded, i), indices, 2 * workers):
                yield rec
                if bar is not None:
                    bar.update()
    finally:
        if bar is not None:
            bar.close()


#: The forked-worker machinery under public names, for other work measured alike
#: (`dropvision.shot_rig`: the shots of a folder).
in_order, Watchdog, give_warnings = _in_order, _Watchdog, _give_warnings


def stall_seconds() -> float:
    """Seconds without CPU progress after which forked workers are taken for stalled (:data:`STALL_S`,
    or the environment variable :data:`STALL_ENV`)."""
    return _stall_s()
