"""The short public calls of dropvision (re-exported lazily by ``import dropvision``)."""

from __future__ import annotations

import os

from dropvision.config import MeasureConfig
from dropvision.measurement import MeasureResult, measure_sequence
from dropvision.io.sequence import OVERRIDE_KEYS, sequence_from_arrays


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
        Frames in memory only: strobe delay of each frame after the trigger (µs). (A folder of
        one frame takes ``delay_us=``, a recording ``frame_rate_hz=``.)
    pixel_size_um : float, optional
        Pixel size in µm: required for frames in memory; for a folder it overrides
        sequence.json (summary.json says so: ``pixel_size_source``).
    config : MeasureConfig, optional
        Measurement knobs (defaults are the documented method).
    progress, csv, overwrite : bool
        Progress bar; also write frames.csv; write into an existing folder of someone else's.
    **metadata
        Keys of sequence.json: ``orientation``, ``nozzle_inner_diameter_um``,
        ``nozzle_outer_diameter_um``, ``nozzle_tip_row``, ``axis_col``, ``waveform``, ``ink``,
        ``bit_depth``; for frames in memory also ``name`` (see
        `dropvision.io.sequence.sequence_from_arrays`); for a folder also ``delay_us`` (a folder
        of one frame), ``frame_rate_hz``, ``first_frame_delay_us``, ``trigger_frame``. For a
        folder they override sequence.json, pass its validation, and are named in
        summary.json's ``*_source`` keys (`dropvision.io.sequence.open_sequence` ``overrides``);
        ``nozzle_outer_diameter_um`` without a pixel size gives the pixel size from the
        nozzle's measured outer width.

    Returns
    -------
    MeasureResult
        ``.frames`` (one row per frame: ``delay_us``, ``grown_volume_nl``, ``drop_volume_nl``,
        ``flow_velocity_m_s``, ``quality``, ...), ``.summary`` (``pinchoff_us``,
        ``inflight_volume_nl``, ``jetting_velocity_m_s``, ...), ``.per_delay()``.

    Raises
    ------
    dropvision.io.sequence.SequenceError
        Unusable input (the message names the file or the argument and the problem).
    dvcore.atomic.OutputError
        ``out`` would destroy something we did not write.
    """
    config = config or MeasureConfig()
    if isinstance(source, (str, os.PathLike)):
        if delays_us is not None:
            raise TypeError(f"measure({source!r}): delays_us applies to frames in memory; a folder of one frame "
                            "takes delay_us=, a recording frame_rate_hz=")
        overrides = {"pixel_size_um": pixel_size_um, **metadata}
        unknown = sorted(set(overrides) - set(OVERRIDE_KEYS))
        if unknown:
            raise TypeError(f"measure({source!r}): unknown metadata {', '.join(unknown)} (keys of sequence.json: "
                            f"{', '.join(OVERRIDE_KEYS)})")
        return measure_sequence(source, out, config, progress=progress, csv=csv, overwrite=overwrite,
                                overrides={k: v for k, v in overrides.items() if v is not None})
    if delays_us is None or pixel_size_um is None:
        raise TypeError("measure(frames): delays_us and pixel_size_um are required for frames in memory")
    seq = sequence_from_arrays(source, delays_us, pixel_size_um=pixel_size_um, **metadata)
    return measure_sequence(seq, out, config, progress=progress, csv=csv, overwrite=overwrite)
