"""The short public calls of dropvision (re-exported lazily by ``import dropvision``)."""

from __future__ import annotations

import os

from dropvision.config import MeasureConfig
from dropvision.measurement import MeasureResult, measure_sequence
from dropvision.sequence import sequence_from_arrays


def measure(source, out=None, *, delays_us=None, pixel_size_um: float | None = None,
            config: MeasureConfig | None = None, progress: bool = False, csv: bool = False,
            overwrite: bool = False, **metadata) -> MeasureResult:
    """Measure drop formation in a strobe sequence: a folder, or frames in memory.

    Parameters
    ----------
    source : str or Path, or array_like
        A sequence folder (sequence.json + images, docs/FORMAT.md), or the frames themselves:
        an array of shape (n, rows, cols) (8- or 16-bit), or a list of 2-D frames.
    out : str or Path, optional
        Also write frames.parquet, per_delay.parquet and summary.json there (atomically; never
        over files we did not write unless ``overwrite``).
    delays_us : array_like of float, optional
        Frames in memory only: strobe delay of each frame after the trigger (µs).
    pixel_size_um : float, optional
        Frames in memory only: pixel size in µm.
    config : MeasureConfig, optional
        Measurement knobs (defaults are the documented method).
    progress, csv, overwrite : bool
        Progress bar; also write frames.csv; write into an existing folder of someone else's.
    **metadata
        Frames in memory only: ``orientation``, ``nozzle_inner_diameter_um``,
        ``nozzle_outer_diameter_um``, ``nozzle_tip_row``, ``axis_col``, ``waveform``, ``ink``,
        ``bit_depth``, ``name`` (see `dropvision.sequence.sequence_from_arrays`).

    Returns
    -------
    MeasureResult
        ``.frames`` (one row per frame: ``delay_us``, ``grown_volume_nl``, ``drop_volume_nl``,
        ``flow_velocity_m_s``, ``quality``, ...), ``.summary`` (``pinchoff_us``,
        ``inflight_volume_nl``, ``jetting_velocity_m_s``, ...), ``.per_delay()``.

    Raises
    ------
    dropvision.sequence.SequenceError
        Unusable input (the message names the file or the argument and the problem).
    identify.atomic.OutputError
        ``out`` would destroy something we did not write.
    """
    config = config or MeasureConfig()
    if isinstance(source, (str, os.PathLike)):
        given = [k for k, v in (("delays_us", delays_us), ("pixel_size_um", pixel_size_um)) if v is not None]
        if given or metadata:
            raise TypeError(f"measure({source!r}): {', '.join(given + list(metadata))} apply to frames in memory; "
                            "a folder takes its metadata from sequence.json")
        return measure_sequence(source, out, config, progress=progress, csv=csv, overwrite=overwrite)
    if delays_us is None or pixel_size_um is None:
        raise TypeError("measure(frames): delays_us and pixel_size_um are required for frames in memory")
    seq = sequence_from_arrays(source, delays_us, pixel_size_um=pixel_size_um, **metadata)
    return measure_sequence(seq, out, config, progress=progress, csv=csv, overwrite=overwrite)
