"""Measurement configuration: the knobs of `dropvision.measurement.measure_sequence`."""

from __future__ import annotations

from dataclasses import dataclass

from dvcore.waveform import DEAD_TIME_US


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
    mist_blur_factor, mist_blur_offset_px : float
        A detached body whose edge spread exceeds ``mist_blur_factor`` x the in-focus nozzle
        walls' plus ``mist_blur_offset_px`` is out of focus (mist, dust on the optics): listed in
        bodies.parquet, never a drop or a satellite (`dropvision.frame.body_classes`; chosen on synthetic
        frames: in-focus bodies 0.98-1.1x the walls', bodies blurred a further 3 px or more >= 1.2x).
    mist_blur_factor_bodies : float
        ``mist_blur_factor`` when the nozzle walls are out of focus and the reference is the
        sharpest detached body instead: a minimum over per-body estimates, biased low by their
        scatter (in-focus drops and satellites of one real JPEG frame: up to 1.33x apart; mist
        there 2.5x and more).
    smooth_noise_limit, smooth_px : float
        Frames whose background noise (transmission units) exceeds ``smooth_noise_limit`` are
        smoothed by a Gaussian of ``smooth_px`` before segmentation and edges (its blur is
        added to the calibrated blur for the volume correction): a 50 % edge moves by the noise
        over the edge slope, so noisy low-contrast frames need it to stay within 1 %.
    workers : int
        Decoding/measuring workers: forked processes on Linux for a sequence of at least
        `dropvision.frame.measure_frame.MIN_FRAMES_FOR_PROCESSES` frames measured from a top-level process
        running no other thread, native ones included (`dropvision.frame.measure_frame.processes_usable`: the
        command line runs one BLAS thread and holds OpenCV's pool off; in Python, set
        ``OPENBLAS_NUM_THREADS=1`` before NumPy is imported; the environment variable
        ``DROPVISION_NO_FORK=1`` keeps threads), threads otherwise. Same results either way.
    dead_time_us : float
        Default firing-trigger-to-piston delay (µs) when the waveform does not give one
        (`dvcore.waveform.DEAD_TIME_US`).

    Plausibility of the input (a lie in the metadata is flagged and noted, never silent):

    pixel_size_tolerance_fraction : float
        Beyond this relative difference between the given pixel size and the one implied by
        ``nozzle_outer_diameter_um`` every frame is flagged ``pixel_size_mismatch`` and the
        length-dependent summary values are NaN (0.02 = 2 %).
    pixel_size_note_sigmas : float
        Below that tolerance a note is still written when the ratio differs from 1 by more than
        this many standard uncertainties of the measured outer diameter (edge-fit scatter and
        a sub-pixel edge-position floor).
    edge_position_floor_px : float
        Systematic uncertainty of one sub-pixel wall edge (px) added in quadrature to the fit
        scatter of the nozzle's outer diameter (threshold and blur model; synthetic sequences show
        < 0.05 px).  Volumes do not use it: their edges' errors are measured terms
        (`dropvision.frame.bodies.common_edge_sigma_px`, `dropvision.frame.bodies.edge_noise_total_px`, the
        tip plane's `dropvision.frame.bodies._plane_sigma_px`); at 0.05 px it made the main drop's stated
        uncertainty 5-20x its true error on synthetic frames.
    min_pinchoff_frames : int
        Fewer measured frames never define a pinch-off.
    max_jetting_velocity_m_s, min_jetting_velocity_m_s : float
        Drop-on-demand jetting velocities outside this range (m/s) are implausible: delays in
        another unit or mislabelled.
    min_growth_at_max_stroke_fraction : float
        The grown volume at the waveform's maximum stroke must reach at least this fraction of
        the grown volume at pinch-off (the piston has pushed its stroke by then); less means
        the delays are stretched (e.g. given x10).
    track_outlier_sigmas : float
        A frame whose main-drop position (or attached volume) lies further than this many
        robust scatters from its neighbours' prediction is inconsistent.
    track_outlier_floor_um : float
        Smallest position residual (µm) ever called inconsistent (pixel quantisation).
    volume_outlier_floor_fraction : float
        Smallest volume residual ever called inconsistent, as a fraction of the sequence's
        largest attached volume (attached frames) or of the median drop volume (in flight).
    max_drop_to_nozzle_volumes : float
        A drop larger than this many nozzle volumes (pi r_in^2 x d_in: the nozzle bore one inner
        diameter long, the length scale of the meniscus) is implausible for the nozzle.
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
    mist_blur_factor: float = 1.2
    mist_blur_offset_px: float = 0.25
    mist_blur_factor_bodies: float = 1.5
    smooth_noise_limit: float = 0.025
    smooth_px: float = 1.0
    workers: int = 2
    dead_time_us: float = DEAD_TIME_US
    pixel_size_tolerance_fraction: float = 0.02
    pixel_size_note_sigmas: float = 4.0
    edge_position_floor_px: float = 0.05
    min_pinchoff_frames: int = 5
    max_jetting_velocity_m_s: float = 20.0
    min_jetting_velocity_m_s: float = 0.0
    min_growth_at_max_stroke_fraction: float = 0.1
    track_outlier_sigmas: float = 8.0
    track_outlier_floor_um: float = 10.0
    volume_outlier_floor_fraction: float = 0.03
    max_drop_to_nozzle_volumes: float = 1000.0
