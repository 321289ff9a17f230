"""Measurement configuration: the knobs of `dropvision.measurement.measure_sequence`."""

from __future__ import annotations

from dataclasses import dataclass

from identify.waveform import DEAD_TIME_US


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
        Smaller dark bodies (px) are noise.
    compact_ratio, tail_chord_ratio : float
        A detached main drop is "in flight" (tail merged or broken up) when its extent along
        the rows is at most ``compact_ratio`` equivalent-sphere diameters and its chord a
        quarter of its length below its top is at least ``tail_chord_ratio`` of its widest
        chord (0.87 for any spheroid; a joined tail is much thinner).
    blur_correction : bool
        Add the volume lost by the blurred 50 % silhouette (see `volume.blur_correction_px3`).
    max_blur_px : float
        A sequence or frame whose edge blur (Gaussian sigma, px) exceeds this is flagged.
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
        A detached body closer than this (px) to the attached liquid (or a neck thinner than
        this) makes the separation ambiguous (flagged).
    workers : int
        Decoding/measuring threads (cv2 releases the GIL).
    dead_time_us : float
        Default firing-trigger-to-piston delay (µs) when the waveform does not give one
        (`identify.waveform.DEAD_TIME_US`).
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
    dead_time_us: float = DEAD_TIME_US
