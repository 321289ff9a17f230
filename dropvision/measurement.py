"""`measure_sequence`: per-frame drop volumes, pinch-off, velocities of a strobe sequence.

The orchestration: open -> calibrate -> stream frames -> assemble -> write.  One module per stage:

1. `dropvision.calibrate.calibration_pass`: calibration pass (`dropvision.calibrate.calibration`: background, nozzle,
   axis, tilt, tip plane, liquid level; edge blur) giving the per-frame `dropvision.calibrate.frame_context.FrameContext`.
2. `dropvision.frame.measure_frame`: the per-frame pipeline (`measure_frame`) and the frame stream:
   photometry and quality (`dropvision.quality`), dark mask and bodies
   (`dropvision.frame.segmentation`), attached and detached liquid (`dropvision.frame.bodies`), volumes by
   disc integration (`dropvision.frame.volume`), the thin-thread rule (`dropvision.analysis.pinchoff`).
3. `dropvision.analysis.sequence_summary`: the frames table and the summary (pinch-off, grown volume and flow
   velocity `dropvision.analysis.flow`, main drop and velocity `dropvision.analysis.tracking`), `per_delay`.
4. `dropvision.output.result_writer`: ``frames.parquet`` (+ ``frames.csv``), ``per_delay.parquet``,
   ``summary.json``, written atomically.

Frames are streamed (one decoded frame per worker at a time); only small per-frame records are
kept, so memory does not grow with the sequence length.  The knobs are `dropvision.config.MeasureConfig`;
the command line is `dropvision.app.measure_cli`.
"""

from __future__ import annotations

import contextlib
import dataclasses
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

import dropvision.quality as q
from dropvision.output.annotate import short_repr
from dropvision.config import MeasureConfig
from dropvision.output.bodies_table import bodies_table
from dropvision.calibrate.calibration_pass import calibrate_sequence
from dropvision.frame.measure_frame import FrameRecord, processes_usable, stream_frames
from dvcore.parallel import serial_native_pools
from dropvision.io.overrides import how_to_give
from dropvision.io.sequence import ArraySequence, Sequence, SequenceError, open_sequence, pixel_size_from_nozzle
from dropvision.output.result_writer import write_result
from dropvision.analysis.sequence_summary import assemble, per_delay
from dvcore.atomic import atomic_dir, check_output_dir, output_lock

if TYPE_CHECKING:  # pandas loads where a table is made, not at start-up
    import pandas as pd


@dataclass
class MeasureResult:
    """Frame table, body table and summary of one sequence (see `dropvision.analysis.sequence_summary`,
    `dropvision.output.bodies_table`)."""

    frames: pd.DataFrame
    summary: dict
    bodies: pd.DataFrame | None = None
    #: a printhead row's nozzles.parquet (`dropvision.analysis.nozzle_row`); None for one nozzle
    nozzles: pd.DataFrame | None = None
    #: outline of each row of ``bodies``: (N, 2) float arrays of (row, col) pixel centres of the
    #: canonical frame (nozzle at the top; `dropvision.frame.outline`); None where not traced (a printhead row)
    outlines: list | None = field(default=None, repr=False)
    #: the same outlines in the frame as the camera stored it (``summary["orientation"]`` undone)
    outlines_camera: list | None = field(default=None, repr=False)

    def __repr__(self) -> str:
        return short_repr(self)

    def annotate(self, frame=0, image=None, *, ax=None, labels: bool = True):
        """Draw a frame as the camera took it with the outline of every body coloured by class, the
        jetting axis and the volumes (`dropvision.output.annotate.annotate`); returns the matplotlib Axes."""
        from dropvision.output.annotate import annotate
        return annotate(self, frame, image, ax=ax, labels=labels)

    def per_delay(self) -> pd.DataFrame:
        """Mean, std and count of the numeric columns per delay (columns ``<name>_mean`` ...)."""
        return per_delay(self.frames)

    def to_dict(self) -> dict:
        """``{"frames": column -> list, "summary": dict}``."""
        return {"frames": self.frames.to_dict(orient="list"), "summary": self.summary}


def source_keys(meta) -> dict:
    """summary.json's orientation and ``*_source`` keys: where each value of the sequence's
    metadata came from (`dropvision.io.sequence.SequenceMeta.sources`)."""
    src = meta.sources or {}
    return {
        "orientation": meta.orientation,
        "orientation_source": src.get("orientation"),
        "pixel_size_source": src.get("pixel_size") or meta.pixel_size_source,
        "nozzle_outer_diameter_source": src.get("nozzle_outer_diameter"),
        "nozzle_inner_diameter_source": src.get("nozzle_inner_diameter"),
        "delay_source": src.get("delay"),
        "waveform_source": src.get("waveform"),
        "bit_depth_source": src.get("bit_depth"),
    }


def measure_sequence(seq_dir, out_dir=None, config: MeasureConfig = MeasureConfig(), *, progress: bool = False,
                     logger=None, csv: bool = False, overwrite: bool = False, overrides: dict | None = None,
                     labels: dict | None = None, nozzle_pitch_um: float | None = None,
                     row_limits: dict | None = None) -> MeasureResult:
    """Measure a strobe sequence.

    Parameters
    ----------
    seq_dir : str or Path or Sequence
        Sequence folder (see docs/FORMAT.md), or an open `dropvision.io.sequence.Sequence` (e.g.
        frames in memory from `dropvision.io.sequence.sequence_from_arrays`).
    out_dir : str or Path, optional
        Write the result there (atomically): frames.parquet, bodies.parquet, per_delay.parquet, summary.json.
        It may not be the sequence folder, lie inside it or contain it; an existing folder is
        replaced only when it holds nothing but an earlier result of ours (see
        `dvcore.atomic.atomic_dir`). Checked before anything is measured.
    config : MeasureConfig
    progress : bool
        Progress bar on stderr.
    logger : object, optional
        Rerun logger (``log_calibration``, ``log_frame``, ``log_summary``); None costs nothing.
    csv : bool
        Also write frames.csv.
    overwrite : bool
        Write into an existing ``out_dir`` that holds files we did not write (they are kept).
    overrides, labels : dict, optional
        Values of sequence.json keys given outside the file (options), and how they were given;
        see `dropvision.io.sequence.open_sequence`. They are named in summary.json's ``*_source``
        keys.
    nozzle_pitch_um : float, optional
        A printhead row's nozzle pitch (overrides sequence.json's ``nozzle_pitch_um``).
    row_limits : dict, optional
        A printhead row's pass/fail limits and reference table (keys of
        `dropvision.analysis.nozzle_row.LIMIT_KEYS` and ``reference_nozzles``; override sequence.json's).

    Returns
    -------
    MeasureResult
        Volumes in nl, positions in µm, delays in µs, velocities in m/s.

    Raises
    ------
    dropvision.io.sequence.SequenceError
        Unusable sequence (missing metadata, other frame size, no readable frame, no nozzle).
    dvcore.atomic.OutputError
        ``out_dir`` overlaps the input or holds files we did not write.

    Notes
    -----
    A frame of several nozzles under one flat plate (`dropvision.analysis.nozzle_row.row_layout`) is a
    printhead row: measured per nozzle by `dropvision.analysis.nozzle_row.measure_row_sequence`
    (nozzles.parquet; the result carries ``nozzles``).
    """
    if isinstance(seq_dir, Sequence) and overrides:
        raise TypeError("measure_sequence: overrides apply to a sequence folder, not to an open Sequence")
    seq = seq_dir if isinstance(seq_dir, Sequence) else open_sequence(seq_dir, overrides=overrides, labels=labels)
    inputs = [] if isinstance(seq, ArraySequence) else [seq.meta.path]  # in memory: no folder
    if out_dir is None:
        return _measure(seq, None, inputs, config, progress, logger, csv, overwrite, nozzle_pitch_um, row_limits)
    with contextlib.ExitStack() as held:
        try:  # before any work: the output may destroy nothing, and no other run writes it
            check_output_dir(out_dir, inputs=inputs, overwrite=overwrite)
            held.enter_context(output_lock(out_dir))
        except BaseException:
            seq.close()
            raise
        return _measure(seq, out_dir, inputs, config, progress, logger, csv, overwrite, nozzle_pitch_um, row_limits)


def row_plate(seq: Sequence):
    """(plate, scan labels or None) of a printhead row when the first frame shows one, or of a
    scan (frames named by nozzle under a plate); else None."""
    from dropvision.analysis.nozzle_row import row_layout, scan_layout

    fr = seq.read(0)
    plate = None if fr.error is not None else row_layout(fr.image)
    return (plate, None) if plate is not None else scan_layout(seq)


def _measure(seq: Sequence, out_dir, inputs: list, config: MeasureConfig, progress: bool, logger, csv: bool,
             overwrite: bool, nozzle_pitch_um: float | None = None, row_limits: dict | None = None) -> MeasureResult:
    """`measure_sequence` after its checks (the output folder locked)."""
    meta, n = seq.meta, len(seq)
    if n:
        forking = processes_usable(n, max(1, config.workers))
        with serial_native_pools(forking):  # the row check before a fork starts no native pool either
            row = row_plate(seq)
        if row is not None:  # several nozzles under one plate, or a scan of them (issue 32)
            from dropvision.analysis.nozzle_row import measure_row_sequence

            try:
                nozzles, frames, bodies, summary = measure_row_sequence(
                    seq, out_dir, row[0], inputs=inputs, overwrite=overwrite, nozzle_pitch_um=nozzle_pitch_um,
                    extra_summary=source_keys(meta), scan=row[1], csv=csv, limits=row_limits)
            finally:
                seq.close()
            return MeasureResult(frames, summary, bodies, nozzles)
    given = sorted(k for k, v in (row_limits or {}).items() if v is not None)
    if given:
        seq.close()
        raise SequenceError(f"{meta.path}: --{given[0].replace('_', '-')} applies to a printhead row (several nozzles "
                            "under one plate, or a scan of them); this sequence shows one nozzle")
    records, cal, sigma, ctx, meta, errors = _calibrated_records(seq, config, logger, progress)
    result = result_from_records(records, cal, sigma, ctx.blur.reference_spread_px, ctx.blur.reference, meta, config,
                                 errors)
    frames, summary = result.frames, result.summary
    if logger is not None:
        logger.log_table(frames)
        logger.log_summary(summary)
    if out_dir is not None:
        with atomic_dir(out_dir, inputs=inputs, overwrite=overwrite, kind="measurement") as tmp:
            write_result(result, tmp, csv=csv)
    return result


def _calibrated_records(seq: Sequence, config: MeasureConfig, logger=None, progress: bool = False):
    """The calibration pass and every frame of ``seq`` measured, ``seq`` closed: (records,
    calibration, blur sigma, frame context, metadata, errors)."""
    meta = seq.meta
    n = len(seq)
    if n == 0:
        seq.close()
        raise SequenceError(f"{meta.path}: no frames")
    errors: list[dict] = []
    decoded: dict = {}
    # frames measured in forked processes (decided again at the fork): OpenCV's pool is not started
    # meanwhile, so that this process still runs one thread when it forks (issue 29)
    try:
        with serial_native_pools(processes_usable(n, max(1, config.workers), logger)):
            records, cal, sigma, ctx = _measure_frames(seq, config, logger, progress, errors, decoded)
    finally:
        seq.close()
    if cal.pixel_size_from_nozzle:  # the calibration's width is the pixel size (the opening's was provisional)
        meta = dataclasses.replace(meta, pixel_size_um=cal.pixel_size_um, pixel_size_source=cal.pixel_size_source,
                                   sources={**(meta.sources or {}), "pixel_size": cal.pixel_size_source})
    return records, cal, sigma, ctx, meta, errors


@dataclass
class MeasuredParts:
    """What `result_from_records` takes of a measured sequence, without pandas and without the
    frame-sized arrays (`light_calibration`): what a forked worker sends back, the tables being made
    where pandas may load (`dropvision.analysis.shot_rig`: after the fork, in the calling process)."""

    records: list
    cal: object
    sigma_px: float  # the calibrated blur (`dropvision.calibrate.frame_context.BlurModel.calibrated_sigma_px`)
    reference_spread_px: float  # the in-focus reference's edge spread (summary ``edge_blur_ref_px``)
    blur_reference: object  # dropvision.calibrate.frame_context.BlurReference
    meta: object
    errors: list

    def result(self, config: MeasureConfig) -> MeasureResult:
        """The `MeasureResult` `measure_sequence` gives (`result_from_records`)."""
        return result_from_records(self.records, self.cal, self.sigma_px, self.reference_spread_px,
                                   self.blur_reference, self.meta, config, self.errors)


def light_calibration(cal):
    """A copy of a `dropvision.calibrate.calibration.Calibration` without its frame-sized arrays (background
    model, opaque specks): what its summary needs, and cheap to send between processes."""
    bg = dataclasses.replace(cal.background, background=np.zeros((0, 0), np.float32), opaque=None)
    return dataclasses.replace(cal, background=bg)


def measure_parts(seq: Sequence, config: MeasureConfig = MeasureConfig()) -> MeasuredParts:
    """`measure_sequence` of an open sequence, up to its tables: ``.result(config)`` gives them
    (the same `MeasureResult`). ``seq`` is closed."""
    records, cal, sigma, ctx, meta, errors = _calibrated_records(seq, config)
    return MeasuredParts(records, light_calibration(cal), float(sigma), float(ctx.blur.reference_spread_px),
                         ctx.blur.reference, meta, errors)


def _measure_frames(seq, config: MeasureConfig, logger, progress: bool, errors: list, decoded: dict):
    """The calibration pass and every frame of ``seq`` measured: (records, calibration, blur
    sigma, frame context); unreadable frames go to ``errors``."""
    meta = seq.meta
    cal, sigma, ctx = calibrate_sequence(seq, config, decoded=decoded)
    check_scale_in_focus(cal, meta)
    if logger is not None:
        logger.log_calibration(cal, shape=cal.shape, orientation=meta.orientation, n_frames=len(seq))
    seq_flags = calibration_flags(cal, sigma, config)
    records: list[FrameRecord] = []
    for rec in stream_frames(seq, range(len(seq)), ctx, max(1, config.workers), logger, progress, decoded):
        if rec.error is not None:
            errors.append({"file": rec.file, "page": rec.page, "delay_us": rec.delay_us, "reason": rec.error})
            continue
        rec.flags = seq_flags + rec.flags
        records.append(rec)
    return records, cal, sigma, ctx


def check_scale_in_focus(cal, meta) -> None:
    """Refuse a pixel size taken from the nozzle's outer width when the calibration found its walls
    out of focus (the width is a blurred holder's, not the nozzle's): `dropvision.io.sequence.SequenceError`."""
    if cal.nozzle_out_of_focus and pixel_size_from_nozzle(meta):
        # the diameter came from an option or an argument: the message names what that caller gives
        labels = {"_caller": (meta.sources or {}).get("caller")}
        raise SequenceError(f"{meta.path}: the pixel size was to come from the nozzle's outer width "
                            f"({meta.pixel_size_source}), but the nozzle walls are out of focus (the drops are "
                            f"sharper): give the pixel size ({how_to_give('pixel_size_um', labels)} or sequence.json pixel_size_um)")


def calibration_flags(cal, sigma_px: float, config: MeasureConfig) -> list[str]:
    """Quality codes every frame of a calibration gets: blurred beyond ``config.max_blur_px``, the
    liquid's contrast below ``config.min_contrast``."""
    flags = []
    if np.isfinite(sigma_px) and sigma_px > config.max_blur_px:
        flags.append(q.BLURRED)
    if 1.0 - cal.liquid_level < config.min_contrast:
        flags.append(q.LOW_CONTRAST)
    return flags


def result_from_records(records: list[FrameRecord], cal, sigma_px: float, reference_spread_px: float,
                        blur_reference, meta, config: MeasureConfig, errors: list) -> MeasureResult:
    """The frames table, bodies table and summary of measured records (`dropvision.analysis.sequence_summary.assemble`,
    the sources of ``meta``, the in-focus reference: its edge spread ``reference_spread_px`` and its
    `dropvision.calibrate.frame_context.BlurReference`): what `measure_sequence` returns."""
    frames, summary = assemble(records, cal, sigma_px, meta, config, errors)
    summary.update(source_keys(meta))
    summary["calibration"]["pixel_size_source"] = summary["pixel_size_source"]
    bodies = bodies_table(records, frames, edge_blur_ref_px=reference_spread_px, compact_ratio=config.compact_ratio)
    summary["calibration"]["edge_blur_ref_px"] = float(reference_spread_px)
    summary["calibration"]["edge_blur_ref_source"] = blur_reference.value
    outlines, outlines_camera = body_outlines(records, bodies, meta.orientation, cal.shape)
    return MeasureResult(frames, summary, bodies, outlines=outlines, outlines_camera=outlines_camera)


def body_outlines(records, bodies, orientation: str, canonical_shape) -> tuple[list, list]:
    """The outline of every row of ``bodies`` (`dropvision.output.bodies_table.bodies_table`'s order: the attached
    body, the in-focus detached bodies, the rejected ones, frame by frame) in the canonical frame and
    in the camera's (`dropvision.frame.outline`); fills ``bodies``' ``row_camera_px`` / ``col_camera_px``."""
    from dropvision.frame.outline import EMPTY, to_camera

    canonical = []
    for r in records:
        if r.attached_body is not None:
            canonical.append(EMPTY if r.attached_outline is None else r.attached_outline)
        canonical += [EMPTY if b.outline is None else b.outline for b in (*r.bodies, *r.rejected)]
    if len(canonical) != len(bodies):  # the tables' rule changed without this one: no outlines rather than wrong ones
        canonical = [EMPTY] * len(bodies)
    camera = [to_camera(o, orientation, canonical_shape) for o in canonical]
    if len(bodies):
        centre = to_camera(bodies[["row_px", "col_px"]].to_numpy(float), orientation, canonical_shape)
        bodies["row_camera_px"], bodies["col_camera_px"] = centre[:, 0], centre[:, 1]
    return canonical, camera
