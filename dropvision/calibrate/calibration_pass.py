"""The calibration pass of a sequence: from a few frames to the `FrameContext` of its measurement.

`calibrate_sequence` decodes a few frames spread over an open sequence (`calibration_frames`),
calibrates them (`calibrate_first`: `dropvision.calibrate.calibration.calibrate_frames`, background,
nozzle, axis, tilt, tip plane, liquid level), and then runs the stages below, each taking arrays (or
the groups built so far) and returning a small frozen result; the context's groups
(`dropvision.calibrate.frame_context.Geometry`, `PhotometricReference`, `BlurModel`) are built from them,
and the `FrameContext` once, at the end.  The `Calibration` is frozen: a stage's values enter it by
`dataclasses.replace` where the stage ends (`InFocusAxis.applied_to`; the uncertainties, the notes and
the resting meniscus at the end).

- `nozzle_walls`: the nozzle's walls in the first frame, their blur, and how far the attached
  liquid reaches sideways;
- `noise_smoothing`: the transmission noise, and whether noisy frames are smoothed first;
- `wall_reference`: the nozzle walls' sharpness and contrast, against which a frame's blur and
  contrast are judged;
- `body_blur_reference` / `focus_reference`: whether the nozzle walls are out of focus, and then
  the sharpest detached body as the blur reference (`detached_appearances` finds the bodies);
- `in_focus_axis`: with the walls out of focus, the jet's axis, the tip plane and the liquid's
  level from what is in focus;
- `calibration_uncertainty`: the edge-position uncertainty common to a body
  (`edge_position_terms_px`) and a pixel size from the needle's width with its uncertainty;
- `FocusReference.blur_model`: the one `BlurModel`, from the in-focus reference and those uncertainties;
- `liquid_seen_hanging`, `rest_meniscus_width_px`: liquid hanging from an out-of-focus face, and
  the resting meniscus' width, both measured with the finished context.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import cv2
import numpy as np

import dropvision.quality as q
from dvcore.robust import MAD_TO_SIGMA, NOISE_LAG_PX, pair_noise_sigma
from dropvision.calibrate.background import NoNozzleError, median_by_selection
from dropvision.calibrate.blur import edge_sigma_px, esf_sigma_px
from dropvision.frame.bodies import hanging_columns, measure_attached
from dropvision.calibrate.calibration import (EDGE_FLOOR_TERM, Calibration, CalibrationError, calibrate_frames,
                                              interior_level, quadrature_px, relative_uncertainty)
from dropvision.frame.body_classes import appearance, nozzle_edge_spread_px, out_of_focus_reason
from dropvision.config import MeasureConfig
from dropvision.io.overrides import how_to_give
from dropvision.calibrate.frame_context import (BlurModel, BlurReference, FrameContext, Geometry, PhotometricReference,
                                                WallReference, smooth_roi, smoothing_kernel_sigma_px)
from dropvision.frame.edges import body_edges, edge_shift_px, edge_threshold
from dropvision.calibrate.nozzle import (bottom_profile, find_nozzle, fit_face_line, largest_top_body, needle_width_terms_px,
                               top_bodies)
from dropvision.frame.segmentation import dark_mask, find_nozzle_body, segment
from dropvision.io.sequence import SequenceError, pixel_size_from_nozzle
from dropvision.frame.volume import axis_edge_points, outline


#: The frames' transmission noise taken when the first calibration frame has too few bright pixels to measure it.
DEFAULT_NOISE_TRANSMISSION = 0.01
#: The name of the edge-position term of a clipped background (`edge_position_terms_px`; summary.json
#: ``calibration.edge_position_terms_px``): a body's own term replaces it under a seen backlight.
CLIPPED_BACKGROUND_TERM = "clipped background"


def calibration_indices(delays_us: np.ndarray, n: int) -> list[int]:
    """Indices of up to ``n`` frames at distinct delays spread over the sequence (first included).

    Parameters
    ----------
    delays_us : ndarray
        Delay of every frame (µs), in frame order.
    n : int
        Most frames to pick.

    Returns
    -------
    list of int
    """
    if delays_us.size == 0:
        return []
    _, first_of = np.unique(delays_us, return_index=True)
    first_of = np.sort(first_of)
    pick = np.unique(np.round(np.linspace(0, first_of.size - 1, min(n, first_of.size))).astype(int))
    return [int(first_of[i]) for i in pick]


def calibrate_sequence(seq, config: MeasureConfig = MeasureConfig(), *, decoded: dict | None = None,
                       static_dust: bool = True) -> tuple[Calibration, float, FrameContext]:
    """Calibration pass over a few frames spread over an open sequence (its stages: the module's text).

    Parameters
    ----------
    seq : dropvision.io.sequence.Sequence
        Open sequence (``meta``, ``len``, ``read``).
    config : MeasureConfig
    decoded : dict, optional
        Receives the decoded calibration frames (index -> image) so that the measurement pass
        does not decode them again.
    static_dust : bool
        Look for static dust in the calibration frames (`dropvision.calibrate.background.estimate_background`);
        False for the frames of several shots, whose drops may sit at one place in all of them.

    Returns
    -------
    cal : Calibration
    sigma_px : float
        The calibrated edge blur (Gaussian sigma, px; ``ctx.blur.calibrated_sigma_px``).
    ctx : FrameContext
        What `dropvision.frame.measure_frame` needs, built once at the end of the pass.

    Raises
    ------
    dropvision.io.sequence.SequenceError
        No readable frame, or the calibration failed.
    """
    meta = seq.meta
    frames = calibration_frames(seq, config.calibration_frames)
    if decoded is not None:
        decoded.update(frames.decoded)
    cal = calibrate_first(frames, meta, config, static_dust=static_dust)
    first, images = frames.first, frames.images
    t_first = np.asarray(first, np.float32) / cal.background.background
    max_value = 2 ** int(meta.bit_depth) - 1
    walls = nozzle_walls(cal, t_first, images, meta.nozzle_outer_diameter_um, max_value)
    # the walls as the reference: the region, the frames' noise and smoothing, the walls' sharpness
    geometry = Geometry.from_calibration(cal, config, attached_half_width_px=walls.attached_half_width_px)
    noise = noise_smoothing(geometry.crop(t_first), walls.sigma_px if config.blur_correction else 0.0, config,
                            default_noise_transmission=DEFAULT_NOISE_TRANSMISSION, image_roi=geometry.crop(first))
    photometry = PhotometricReference.from_calibration(
        cal, geometry, first.dtype, max_value, noise_transmission=noise.noise_transmission,
        smoothing_sigma_px=noise.smoothing_sigma_px,
        walls=None if walls.nozzle is None else wall_reference(walls.nozzle, cal.tip_row, cal.background.background,
                                                               t_first, walls.sigma_px, cal.liquid_level, config))
    found = detached_appearances(images, geometry, photometry, config)
    if walls.nozzle is None and not found.size:
        raise SequenceError(f"{frames.first_path(meta)}: no nozzle: no dark body touches the top edge "
                            "of the frame, and no detached drop to measure without it")
    # the in-focus reference: the walls, or the sharpest detached body when they are out of focus
    spread_px = _nozzle_edge_spread(first, geometry, photometry, config) if walls.nozzle is not None else float("nan")
    focus = focus_reference(found, spread_px, walls.sigma_px, noise.correction_sigma_px, noise.smoothing_sigma_px,
                            config)
    face = None
    if focus.nozzle_out_of_focus:
        # the walls no longer judge a frame's blur or contrast, nor give the jet's axis
        if walls.nozzle is not None:
            cal = replace(cal, nozzle_out_of_focus=True, notes=cal.notes + (focus.note,),
                          tilt_rad=AXIS_ALONG_COLUMNS_TILT_RAD, tilt_source=AXIS_ALONG_COLUMNS_SOURCE,
                          nozzle_sigma_px=float(focus.nozzle_sigma_px))
        axis = in_focus_axis(cal, images, t_first, geometry, photometry, config, focus)
        cal, face = axis.applied_to(cal), axis.face
        # the region of interest and its photometric reference (without the walls) anew
        geometry = Geometry.from_calibration(cal, config, attached_half_width_px=walls.attached_half_width_px,
                                             face=face)
        photometry = PhotometricReference.from_calibration(
            cal, geometry, first.dtype, max_value, noise_transmission=photometry.noise_transmission,
            smoothing_sigma_px=photometry.smoothing_sigma_px)
    unc = calibration_uncertainty(cal, walls.nozzle, focus.calibrated_sigma_px, config)
    ctx = FrameContext(geometry, photometry, focus.blur_model(unc, cal, photometry, first, max_value), config)
    notes = ()
    if face is not None and liquid_seen_hanging(images, ctx):
        ctx = replace(ctx, geometry=replace(geometry, face_liquid_seen=True))
        notes = (FACE_LIQUID_SEEN_NOTE,)
    rest = {}
    if walls.nozzle is not None and not focus.nozzle_out_of_focus:
        width = rest_meniscus_width_px(first, ctx)
        # as wide as the walls at the plane: pinned at their outer edge (a pendant drop, a wetted face),
        # not at the orifice's inner edge; its two edges placed to about the blur each
        outside = bool(np.isfinite(width) and width >= cal.nozzle_outer_diameter_px
                       - 2.0 * max(float(ctx.blur.correction_sigma_px), 0.5))
        rest = dict(rest_meniscus_width_px=width, rest_meniscus_delay_us=float(meta.delays_us[frames.first_index]),
                    rest_meniscus_at_outer_edge=outside)
    cal = replace(cal, **unc.calibration_fields(), notes=cal.notes + notes, **rest)
    return cal, focus.calibrated_sigma_px, ctx


@dataclass(frozen=True)
class CalibrationFrames:
    """The frames a sequence is calibrated from (`calibration_frames`).

    Attributes
    ----------
    decoded : dict
        Frame index -> decoded image (canonical orientation).
    """

    decoded: dict

    @property
    def first_index(self) -> int:
        """The first frame's index in the sequence (the meniscus at rest)."""
        return min(self.decoded)

    @property
    def first(self) -> np.ndarray:
        return self.decoded[self.first_index]

    @property
    def images(self) -> list[np.ndarray]:
        """The frames in index order (the first included)."""
        return [self.decoded[i] for i in sorted(self.decoded)]

    def first_path(self, meta):
        """The first frame's file (the errors name it)."""
        return meta.path / meta.frames[self.first_index].file


def calibration_frames(seq, n: int) -> CalibrationFrames:
    """Up to ``n`` readable frames spread over ``seq`` (`calibration_indices`), else its first readable one.

    Raises
    ------
    dropvision.io.sequence.SequenceError
        No readable frame.
    """
    meta = seq.meta
    cal_frames = {}
    for i in calibration_indices(meta.delays_us, n):
        fr = seq.read(i)
        if fr.image is not None:
            cal_frames[i] = fr.image
    if not cal_frames:  # the spread frames were unreadable: take the first readable one
        for i in range(len(seq)):
            fr = seq.read(i)
            if fr.image is not None:
                cal_frames[i] = fr.image
                break
    if not cal_frames:
        raise SequenceError(f"{meta.path}: no readable frame")
    return CalibrationFrames(cal_frames)


def calibrate_first(frames: CalibrationFrames, meta, config: MeasureConfig, *, static_dust: bool = True) -> Calibration:
    """`dropvision.calibrate.calibration.calibrate_frames` of the calibration frames with what ``meta``
    states; its `CalibrationError` as a `dropvision.io.sequence.SequenceError` naming the first frame
    (and, for no nozzle, how the orientation was found and how to give it)."""
    try:
        return calibrate_frames(
            frames.first, frames.images, meta.pixel_size_um,
            nozzle_outer_diameter_um=meta.nozzle_outer_diameter_um,
            nozzle_inner_diameter_um=meta.nozzle_inner_diameter_um,
            tip_row=meta.nozzle_tip_row, axis_col=meta.axis_col, static_dust=static_dust,
            pixel_size_tolerance=config.pixel_size_tolerance_fraction,
            edge_position_floor_px=config.edge_position_floor_px,
            max_value=2 ** int(meta.bit_depth) - 1, clipped_limit=config.saturation_limit,
            # without a nozzle, its detached drops are measured where the frame's orientation is known (stated
            # or detected): an undetected one is refused, naming what each edge shows
            allow_no_nozzle=meta.nozzle_tip_row is None and not getattr(meta, "orientation_assumed", False),
            pixel_size_from_nozzle=pixel_size_from_nozzle(meta),
        )
    except CalibrationError as exc:
        how = (meta.sources or {}).get("orientation")
        give = how_to_give("orientation", {"_caller": (meta.sources or {}).get("caller")})  # the caller's words
        seen = (f"; orientation {meta.orientation} ({how}; {give} or sequence.json orientation sets it)"
                if how and isinstance(exc, NoNozzleError) else "")
        raise SequenceError(f"{frames.first_path(meta)}: {exc}{seen}") from exc


@dataclass(frozen=True)
class NozzleWalls:
    """The nozzle's outer walls in the first calibration frame (`nozzle_walls`).

    Attributes
    ----------
    nozzle : dropvision.calibrate.nozzle.Nozzle or None
        None when the calibration found no nozzle.
    sigma_px : float
        The walls' edge blur (Gaussian sigma of their edge-spread fit, px; NaN without a nozzle).
    attached_half_width_px : float
        Widest reach of the liquid hanging from the nozzle from the axis over the calibration
        frames (`attached_half_width_px`; 0 without a nozzle).
    """

    nozzle: object = None
    sigma_px: float = float("nan")
    attached_half_width_px: float = 0.0


def nozzle_walls(cal: Calibration, t_first: np.ndarray, images, nozzle_outer_diameter_um: float | None,
                 max_value: int) -> NozzleWalls:
    """The walls of ``cal``'s nozzle in the first frame (``t_first``: over the background), their
    blur (`dropvision.calibrate.blur.edge_sigma_px`, below a clipped background's clip) and how far
    the attached liquid reaches sideways in ``images``."""
    if not cal.nozzle_found:
        return NozzleWalls()
    expected = (nozzle_outer_diameter_um / cal.pixel_size_um
                if nozzle_outer_diameter_um and not cal.pixel_size_from_nozzle else None)
    nozzle = find_nozzle(t_first, edge_threshold(cal.nozzle_level), expected)
    clip_t = 0.99 * max_value / cal.clipped_level if np.isfinite(cal.clipped_level) else float("inf")
    sigma = edge_sigma_px(t_first, nozzle, clip_transmission=clip_t)
    reach = max(attached_half_width_px(np.asarray(img, np.float32) / cal.background.background, cal)
                for img in images)
    return NozzleWalls(nozzle, sigma, reach)


#: The calibration's note when liquid hangs in focus from an out-of-focus face (`liquid_seen_hanging`).
FACE_LIQUID_SEEN_NOTE = ("liquid hangs from the out-of-focus face in focus in a calibration frame: a dark bump "
                         "at the axis below the face is taken as its meniscus in every frame")


@dataclass(frozen=True)
class CalibrationUncertainty:
    """The uncertainties the calibration pass adds to a calibration (`calibration_uncertainty`).

    Attributes
    ----------
    edge_position_terms_px : dict
        `edge_position_terms_px`.
    nozzle_width_terms_px : dict
        With the pixel size from the needle's width: the width's parts
        (`dropvision.calibrate.nozzle.needle_width_terms_px`), else empty.
    pixel_size : dict
        With the pixel size from the needle's width: its uncertainty, ratio 1 with the width's relative
        uncertainty, and its source with them (`Calibration` fields), else empty.
    """

    edge_position_terms_px: dict
    nozzle_width_terms_px: dict
    pixel_size: dict

    @property
    def edge_position_uncertainty_px(self) -> float:
        """The edge-position terms in quadrature (`Calibration.edge_position_uncertainty_px`)."""
        return quadrature_px(self.edge_position_terms_px)

    def calibration_fields(self) -> dict:
        """The `Calibration` fields it gives."""
        return dict(edge_position_terms_px=self.edge_position_terms_px,
                    nozzle_width_terms_px=self.nozzle_width_terms_px, **self.pixel_size)


def calibration_uncertainty(cal: Calibration, nozzle, sigma_px: float, config: MeasureConfig) -> CalibrationUncertainty:
    """The edge-position uncertainty common to a body (`edge_position_terms_px`) and, when the pixel
    size is the needle's (``cal.pixel_size_from_nozzle``, a ``nozzle`` found), the needle width's
    parts and the pixel size's uncertainty from them."""
    terms = edge_position_terms_px(cal, sigma_px, config)
    if not (cal.pixel_size_from_nozzle and nozzle is not None):
        return CalibrationUncertainty(terms, {}, {})
    width_terms = needle_width_terms_px(nozzle, quadrature_px(terms), sigma_px)
    u_width = math.sqrt(sum(v * v for v in width_terms.values()))
    u_um = float(cal.pixel_size_um * u_width / cal.nozzle_outer_diameter_px)
    source = cal.pixel_size_source + (f" = {cal.pixel_size_um:.5g} +- {u_um:.2g} um (width "
                                      f"+-{u_width:.2f} px: " + ", ".join(f"{k} {v:.2f}" for k, v in
                                                                         width_terms.items()) + ")")
    # the pixel size is the nozzle's by construction: ratio 1 with the width's uncertainty (what a campaign's
    # intervals take as the pixel size's part, identify.measurement_uncertainty)
    return CalibrationUncertainty(terms, width_terms, dict(
        pixel_size_uncertainty_um=u_um, pixel_size_ratio=1.0,
        pixel_size_ratio_uncertainty=relative_uncertainty(u_um, cal.pixel_size_um), pixel_size_source=source))


@dataclass(frozen=True)
class BodyBlurReference:
    """The sharpest detached body as the blur reference, when the nozzle walls are out of focus.

    Attributes
    ----------
    reference_spread_px : float
        Its edge spread (`dropvision.frame.body_classes`): mist is judged against it.
    calibrated_sigma_px : float
        Its edge blur (Gaussian sigma of its outline's edge-spread fit, else its edge spread):
        the calibration's blur from then on.
    nozzle_sigma_px : float
        The walls' own blur (Gaussian sigma): their edge-spread fit, else the body's scaled by the
        two spreads (three times the body's without a wall spread).
    """

    reference_spread_px: float
    calibrated_sigma_px: float
    nozzle_sigma_px: float


def body_blur_reference(found: np.ndarray, nozzle_edge_spread_px: float, walls_sigma_px: float,
                        config: MeasureConfig) -> BodyBlurReference | None:
    """Whether the nozzle walls are out of focus, and then the sharpest detached body's blur reference.

    Parameters
    ----------
    found : ndarray of APPEARANCE_DTYPE
        Detached bodies of the calibration frames (`detached_appearances`).
    nozzle_edge_spread_px : float
        Edge spread of the nozzle walls in the first frame (NaN: not measured).
    walls_sigma_px : float
        The walls' edge-spread fit (`dropvision.calibrate.blur.edge_sigma_px`).
    config : MeasureConfig
        ``mist_blur_factor`` and ``mist_blur_offset_px``: the walls are out of focus when their
        spread is beyond ``mist_blur_factor x`` the sharpest body's ``+ mist_blur_offset_px``.

    Returns
    -------
    BodyBlurReference or None
        None when the walls are in focus (or no detached body was found): they stay the reference.
    """
    body_ref = float(found["edge_blur_px"].min()) if found.size else float("nan")
    limit = config.mist_blur_factor * body_ref + config.mist_blur_offset_px
    if not (np.isfinite(body_ref) and not nozzle_edge_spread_px <= limit):
        return None
    sharpest = found[int(np.argmin(found["edge_blur_px"]))]
    sigma = float(sharpest["esf_sigma_px"]) if np.isfinite(sharpest["esf_sigma_px"]) else float(body_ref)
    nozzle_blur = float(walls_sigma_px if np.isfinite(walls_sigma_px) else
                        sigma * nozzle_edge_spread_px / body_ref if np.isfinite(nozzle_edge_spread_px) else 3.0 * sigma)
    return BodyBlurReference(reference_spread_px=body_ref, calibrated_sigma_px=sigma, nozzle_sigma_px=nozzle_blur)


def smoothed_sigma_px(sigma_px: float, smooth_px: float) -> float:
    """The edge blur (px) after the smoothing of noisy frames: the kernel's own standard deviation
    (it is truncated, `dropvision.calibrate.frame_context.smooth_roi`) added in quadrature; unchanged without
    smoothing or without a blur correction (``sigma_px`` 0)."""
    if smooth_px > 0 and sigma_px > 0:
        return float(math.hypot(sigma_px, smoothing_kernel_sigma_px(smooth_px)))
    return sigma_px


@dataclass(frozen=True)
class NoiseSmoothing:
    """The frames' transmission noise and whether they are smoothed before their edges are found.

    Attributes
    ----------
    noise_transmission : float
        Robust standard deviation of the transmission noise (`transmission_noise`).
    smoothing_sigma_px : float
        Gaussian smoothing (sigma, px) of each region before segmentation (0: none).
    correction_sigma_px : float
        The edge blur the volumes are corrected for (px), the smoothing included (`smoothed_sigma_px`).
    """

    noise_transmission: float
    smoothing_sigma_px: float
    correction_sigma_px: float


def noise_smoothing(transmission_roi: np.ndarray, sigma_px: float, config: MeasureConfig, *,
                    default_noise_transmission: float, image_roi: np.ndarray | None = None) -> NoiseSmoothing:
    """Noise of the first calibration frame, and the smoothing noisy (low-contrast) frames get.

    Parameters
    ----------
    transmission_roi : ndarray
        First calibration frame over the background, region of interest.
    sigma_px : float
        Edge blur of the volume correction (px; 0 without it).
    config : MeasureConfig
        Frames noisier than ``smooth_noise_limit`` are smoothed by ``smooth_px``.
    default_noise_transmission : float
        The noise taken when the frame has too few bright pixels to measure it.
    image_roi : ndarray, optional
        The first calibration frame's raw values over the region (`transmission_noise`).

    Returns
    -------
    NoiseSmoothing
    """
    noise = transmission_noise(transmission_roi, default_noise_transmission, image_roi)
    if noise > config.smooth_noise_limit:
        smooth_px = float(config.smooth_px)
        return NoiseSmoothing(noise_transmission=noise, smoothing_sigma_px=smooth_px,
                              correction_sigma_px=smoothed_sigma_px(sigma_px, smooth_px))
    return NoiseSmoothing(noise_transmission=noise, smoothing_sigma_px=0.0, correction_sigma_px=sigma_px)


@dataclass(frozen=True)
class FocusReference:
    """What a body's edge spread and the volumes' blur correction are referred to: the nozzle
    walls, or the sharpest detached body when the walls are out of focus.

    Attributes
    ----------
    reference_spread_px : float
        Edge spread mist is judged against (`dropvision.frame.body_classes`).
    blur_reference : BlurReference
        Where it comes from (its text is written in the summary).
    mist_blur_factor : float
        The limit's factor on it (``config.mist_blur_factor`` or ``mist_blur_factor_bodies``).
    calibrated_sigma_px : float
        Calibrated edge blur (Gaussian sigma, px): the walls' fit, or the body's.
    correction_sigma_px : float
        The blur the volumes are corrected for (px; 0 without correction; smoothing included).
    nozzle_sigma_px : float
        The walls' own blur (Gaussian sigma) when they are out of focus (px), else 0.
    nozzle_out_of_focus : bool
    note : str or None
        The summary's note when the walls are out of focus.
    """

    reference_spread_px: float
    blur_reference: BlurReference
    mist_blur_factor: float
    calibrated_sigma_px: float
    correction_sigma_px: float
    nozzle_sigma_px: float
    nozzle_out_of_focus: bool
    note: str | None = None

    def blur_model(self, unc: "CalibrationUncertainty", cal: Calibration, photometry: PhotometricReference,
                   first: np.ndarray, max_value: int) -> BlurModel:
        """The sequence's `BlurModel`: this reference with the uncertainties ``unc`` of ``cal``
        (`calibration_uncertainty`), the edge noise of ``photometry``'s transmission noise, and a
        clipped backlight's shape under the clip (`illumination_under_clip` of the first frame)."""
        sigma = self.calibrated_sigma_px
        clip_light = illumination_under_clip(first, cal, max_value)
        return BlurModel(calibrated_sigma_px=sigma, correction_sigma_px=self.correction_sigma_px,
                         reference=self.blur_reference, reference_spread_px=self.reference_spread_px,
                         mist_blur_factor=self.mist_blur_factor, nozzle_sigma_px=self.nozzle_sigma_px,
                         edge_position_sigma_px=unc.edge_position_uncertainty_px,
                         edge_noise_px=edge_shift_px(photometry.noise_transmission, sigma, cal.liquid_level),
                         clip_light=clip_light,
                         clip_term_px=(0.0 if clip_light is None else
                                       float(unc.edge_position_terms_px.get(CLIPPED_BACKGROUND_TERM, 0.0))))


def focus_reference(found: np.ndarray, nozzle_edge_spread_px: float, walls_sigma_px: float,
                    correction_sigma_px: float, smooth_px: float, config: MeasureConfig) -> FocusReference:
    """The blur references: the nozzle walls, or the sharpest detached body when they are out of focus.

    When the nozzle (or the holder block around it) is out of focus, what is in focus is the
    jet's plane: the sharpest detached body is the reference for mist, and the blur is its
    outline's edge-spread function (`body_blur_reference`).

    Parameters
    ----------
    found : ndarray of APPEARANCE_DTYPE
        Detached bodies of the calibration frames (`detached_appearances`).
    nozzle_edge_spread_px : float
        Edge spread of the nozzle walls in the first frame (NaN: not measured).
    walls_sigma_px : float
        The walls' edge-spread fit (`dropvision.calibrate.blur.edge_sigma_px`).
    correction_sigma_px : float
        The blur correction so far (`noise_smoothing`): kept when the walls are in focus.
    smooth_px : float
        Smoothing of noisy frames (px; 0: none).
    config : MeasureConfig

    Returns
    -------
    FocusReference
    """
    body = body_blur_reference(found, nozzle_edge_spread_px, walls_sigma_px, config)
    if body is None:
        return FocusReference(reference_spread_px=nozzle_edge_spread_px, blur_reference=BlurReference.NOZZLE_WALLS,
                              mist_blur_factor=config.mist_blur_factor, calibrated_sigma_px=walls_sigma_px,
                              correction_sigma_px=correction_sigma_px, nozzle_sigma_px=0.0, nozzle_out_of_focus=False)
    note = (f"the nozzle walls are out of focus (edge spread {nozzle_edge_spread_px:.2f} px against "
            f"{body.reference_spread_px:.2f} px of the sharpest detached body): in-focus and blur judged from the "
            "detached bodies, no per-frame blur or contrast from the walls")
    return FocusReference(
        reference_spread_px=body.reference_spread_px,
        blur_reference=BlurReference.SHARPEST_BODY,
        mist_blur_factor=config.mist_blur_factor_bodies, calibrated_sigma_px=body.calibrated_sigma_px,
        correction_sigma_px=smoothed_sigma_px(body.calibrated_sigma_px if config.blur_correction else 0.0, smooth_px),
        nozzle_sigma_px=body.nozzle_sigma_px, nozzle_out_of_focus=True, note=note)


def edge_position_terms_px(cal: Calibration, sigma_px: float, config: MeasureConfig) -> dict[str, float]:
    """The parts (px, standard uncertainties) of an edge-position error common to a whole body.

    - ``edge floor``: ``config.edge_position_floor_px`` (threshold interpolation and blur model);
    - ``background level``: the background model's local misfit ``dB/B``
      (`dropvision.calibrate.background.background_residual`) moves the 50 % crossing by
      ``dB/B / slope``, the edge's slope being ``(1 - T_liquid) / (sqrt(2 pi) sigma)``;
    - ``clipped background``: against a background clipped at an unknown level the true edge
      lies up to ``edge_range_px`` outside the measured one: half of it; with an estimated level,
      its standard uncertainty ``level_uncertainty / level`` moves the crossing like a
      background error, and so does the backlight's variation under the clip, which no pixel
      shows (the level is read at the nozzle and used everywhere): of the scale of the level's
      excess over the clip, ``1 - max / level``, taken as uniform within that span (over
      sqrt(3)).

    Parameters
    ----------
    cal : Calibration
    sigma_px : float
        Edge blur (Gaussian sigma, px; at least 0.5 px is used: the pixel box).
    config : MeasureConfig

    Returns
    -------
    dict
        Term name -> px.
    """
    terms = {EDGE_FLOOR_TERM: float(config.edge_position_floor_px),
             "background level": edge_shift_px(float(cal.background.residual), sigma_px, cal.liquid_level)}
    clipped = cal.clipped
    if clipped is not None and not clipped.level_known:
        terms[CLIPPED_BACKGROUND_TERM] = 0.5 * float(clipped.edge_range_px)
    elif clipped is not None:
        level = float(clipped.level)
        rel = float(clipped.level_uncertainty) / level
        span = 1.0 - float(clipped.max_value) / level
        rel = math.hypot(rel if np.isfinite(rel) else 0.02, max(span, 0.0) / math.sqrt(3.0))
        terms[CLIPPED_BACKGROUND_TERM] = edge_shift_px(rel, sigma_px, cal.liquid_level)
    return terms


@dataclass(frozen=True)
class ClipIllumination:
    """The backlight under a clipped background, extrapolated from the part of it that is seen.

    The level used wherever the background is clipped is read at the nozzle (`dropvision.calibrate.background.
    unclipped_level`) and used everywhere; the backlight under the clip is not flat (vignetting,
    fall-off).  The background below the clip (its unclipped pixels away from dark bodies) is fitted
    by smooth polynomials in the frame's coordinates (normalised to [-1, 1]) of degree 2 and 3; their
    values relative to their mean at the nozzle's walls (where the level was read) say how far a
    body's own background lies from the level used: `level_offsets`.

    Attributes
    ----------
    coef2, coef3 : tuple of float
        Coefficients of the two fits (terms ``u^i v^j``, ``i + j <= degree``, in `_poly_terms` order).
    shape : (int, int)
        Frame rows, columns (canonical orientation).
    ref2, ref3 : float
        The fits' mean over the nozzle's walls.
    level_rel_se : float
        The level's own relative standard error (``level_uncertainty / level``).
    """

    coef2: tuple
    coef3: tuple
    shape: tuple
    ref2: float
    ref3: float
    level_rel_se: float

    def _value(self, coef, row, col) -> float:
        h, w = self.shape
        u = (float(col) - 0.5 * (w - 1)) / (0.5 * (w - 1))
        v = (float(row) - 0.5 * (h - 1)) / (0.5 * (h - 1))
        deg = 2 if len(coef) == 6 else 3
        return float(sum(c * u ** i * v ** j for c, (i, j) in zip(coef, _poly_terms(deg))))

    def level_offsets(self, row: float, col: float) -> tuple[float, float]:
        """Relative offset of the backlight at (row, col) (full frame, px) from the level used, by
        the degree-2 and degree-3 fits."""
        return (self._value(self.coef2, row, col) / self.ref2 - 1.0,
                self._value(self.coef3, row, col) / self.ref3 - 1.0)

    def relative_error(self, row: float, col: float) -> float:
        """Standard uncertainty (relative) of the level at a body at (row, col): the degree-2 fit's
        offset there (the level used is the nozzle's: off by that much), the two fits' disagreement
        (the extrapolation's own error) and the level's standard error, in quadrature."""
        d2, d3 = self.level_offsets(row, col)
        return float(math.sqrt(d2 * d2 + (d3 - d2) ** 2 + self.level_rel_se ** 2))


def _poly_terms(degree: int) -> list[tuple[int, int]]:
    return [(i, j) for i in range(degree + 1) for j in range(degree + 1 - i)]


def illumination_under_clip(image: np.ndarray, cal: Calibration, max_value: int,
                            min_pixels: int = 500) -> ClipIllumination | None:
    """The backlight under a clipped background (`ClipIllumination`), from the frame's unclipped background.

    Only for a clipped background whose level was estimated (``cal.clipped`` with its level known) and a
    nozzle found; the background pixels between 30 % and 97 % of the sensor maximum, away from dark
    bodies (`dropvision.calibrate.background.dark_bodies_mask`), at least ``min_pixels`` of them (at most ~20000
    used).  None otherwise (a background clipped everywhere shows nothing of its
    shape: the level's excess over the clip stays the term, `edge_position_terms_px`).
    """
    from dropvision.calibrate.background import dark_bodies_mask

    clipped = cal.clipped
    if not (clipped is not None and clipped.level_known and cal.nozzle_found
            and np.isfinite(cal.tip_row) and np.isfinite(cal.axis_col)):
        return None
    img = np.asarray(image, np.float32)
    h, w = img.shape
    seen = ~dark_bodies_mask(img, 6) & (img > 0.3 * max_value) & (img < 0.97 * max_value)
    rows, cols = np.nonzero(seen)
    if rows.size < min_pixels:
        return None
    step = max(1, rows.size // 20000)  # every step-th seen pixel: at most ~20000
    rows, cols = rows[::step], cols[::step]
    u = (cols - 0.5 * (w - 1)) / (0.5 * (w - 1))
    v = (rows - 0.5 * (h - 1)) / (0.5 * (h - 1))
    y = img[rows, cols].astype(np.float64)
    half = 0.5 * float(cal.nozzle_outer_diameter_px) if np.isfinite(cal.nozzle_outer_diameter_px) else 10.0
    wall_r = np.linspace(0.0, max(float(cal.tip_row), 0.0), 12)
    wall_c = np.array([cal.axis_col - half - 3.0, cal.axis_col + half + 3.0])
    fits, refs = [], []
    for deg in (2, 3):
        terms = _poly_terms(deg)
        coef, *_ = np.linalg.lstsq(np.stack([u ** i * v ** j for i, j in terms], axis=1), y, rcond=None)
        fits.append(tuple(float(c) for c in coef))
        wu = (wall_c[None, :] - 0.5 * (w - 1)) / (0.5 * (w - 1))
        wv = (wall_r[:, None] - 0.5 * (h - 1)) / (0.5 * (h - 1))
        refs.append(float(np.mean(sum(c * wu ** i * wv ** j for c, (i, j) in zip(coef, terms)))))
    if not (refs[0] > 0 and refs[1] > 0):
        return None
    level = float(clipped.level)
    rel_se = float(clipped.level_uncertainty) / level
    return ClipIllumination(coef2=fits[0], coef3=fits[1], shape=(h, w), ref2=refs[0], ref3=refs[1],
                            level_rel_se=rel_se if np.isfinite(rel_se) else 0.0)


#: Fields of `detached_appearances` (one record per body): the calibration frame it is in, its
#: area (px), darkest transmission, edge spread (`dropvision.frame.body_classes.appearance`, px) and the
#: Gaussian sigma of its outline's edge-spread function (px).
APPEARANCE_DTYPE = np.dtype([("frame", int), ("area_px", int), ("min_transmission", float), ("edge_blur_px", float),
                             ("esf_sigma_px", float)])


def detached_appearances(images, geometry: Geometry, photometry: PhotometricReference, config: MeasureConfig,
                         min_area_px: int = 50) -> np.ndarray:
    """Detached dark bodies of the calibration frames that look like liquid, with their appearance.

    Bodies of at least ``min_area_px`` pixels, not touching the region's edges, as dark as half
    the liquid's depth (``1 - T_min >= (1 - T_liquid) / 2``), judged with the same estimator as
    every body (`dropvision.frame.body_classes.appearance`).  Mist and dust are never sharper than the
    liquid in the jet's plane, so the smallest ``edge_blur_px`` is an in-focus body whenever the
    frames hold one.

    Parameters
    ----------
    images : sequence of ndarray
        Raw calibration frames (canonical orientation).
    geometry, photometry : Geometry, PhotometricReference
        The region of interest and its reference (the blur is not needed).
    config : MeasureConfig
    min_area_px : int
        Smaller bodies are not used (too few boundary pixels for a stable spread).

    Returns
    -------
    ndarray of `APPEARANCE_DTYPE`
    """
    photo = photometry
    out = []
    depth_min = 0.5 * (1.0 - photo.liquid_level)
    for i, img in enumerate(images):
        roi, seg = _segmented_region(img, geometry, photo, config)
        hh, ww = seg.labels.shape
        t = None
        for b in seg.bodies:
            if b.nozzle or b.area_px < min_area_px or b.x0 == 0 or b.x1 == ww or b.y1 == hh:
                continue
            app = appearance(roi, photo.inv_background, seg.labels, b.label, b.bbox, 1.0,
                             floor=photo.liquid_level)
            if 1.0 - app.min_transmission >= depth_min and np.isfinite(app.edge_blur_px):
                # its outline's edge-spread function: the blur of the jet's plane
                ed = body_edges(roi, photo.inv_background, seg.labels, b.label, b.bbox,
                                photo.threshold)
                if t is None:
                    t = roi.astype(np.float32) * photo.inv_background
                sig = esf_sigma_px(t, *outline(ed), photo.liquid_level)
                out.append((i, b.area_px, app.min_transmission, app.edge_blur_px, sig))
    return np.array(out, APPEARANCE_DTYPE)


#: The jet's direction when the nozzle walls are out of focus: the image columns (tilt 0, stated).
#: A blurred holder's face or walls do not give the jet's axis (a 3 deg tilt on a level jet was
#: measured that way), and the line through a drop and its satellites is not the axis either
#: (satellites drift off it by a few px: 1-4 deg from two bodies).  The volume's error from a
#: tilt ``t`` left out is ``1 - cos t``: 0.14 % at 3 deg.
AXIS_ALONG_COLUMNS_TILT_RAD = 0.0
AXIS_ALONG_COLUMNS_SOURCE = "image columns (assumed: the nozzle walls are out of focus)"


def in_focus_drops(images, geometry: Geometry, photometry: PhotometricReference, config: MeasureConfig,
                   reference_spread_px: float, mist_blur_factor: float,
                   min_area_px: int = 50) -> tuple[float, int, float]:
    """The jet's axis column (full frame, px) from the line of the detached in-focus drops, and the
    liquid's interior level from those bodies.

    In each calibration frame the detached bodies in focus (edge spread within the mist limit of
    the in-focus reference, ``reference_spread_px`` with ``mist_blur_factor`` (`FocusReference`),
    `dropvision.frame.body_classes.out_of_focus_reason`) and as dark as half the
    liquid's depth, away from the region's edges; the largest is the main drop, its area
    centroid's column on the axis of a body of revolution.  The axis is the median over the
    frames; the level the median of `dropvision.calibrate.calibration.interior_level` over their bodies
    (mist, a holder's fragments or a vignetted corner are no liquid).

    Returns
    -------
    (column, number of frames it comes from, level); (NaN, 0, NaN) without any such body.
    """
    geo, photo = geometry, photometry
    cols, levels = [], []
    depth_min = 0.5 * (1.0 - photo.liquid_level)
    for img in images:
        roi, seg = _segmented_region(img, geo, photo, config)
        hh, ww = seg.labels.shape
        liquid = []
        for b in sorted(seg.bodies, key=lambda b: -b.area_px):
            if b.nozzle or b.area_px < min_area_px or b.x0 == 0 or b.x1 == ww or b.y1 == hh:
                continue
            app = appearance(roi, photo.inv_background, seg.labels, b.label, b.bbox, 1.0,
                             floor=photo.liquid_level)
            if (1.0 - app.min_transmission >= depth_min
                    and out_of_focus_reason(app, reference_spread_px, mist_blur_factor,
                                            config.mist_blur_offset_px) is None):
                liquid.append(b)
        if not liquid:
            continue
        best = liquid[0]
        _, cc = np.nonzero(seg.labels[best.y0:best.y1, best.x0:best.x1] == best.label)
        cols.append(float(np.mean(cc)) + best.x0 + geo.col0_px)
        region = np.isin(seg.labels, [b.label for b in liquid])
        if photo.opaque is not None:
            region &= ~photo.opaque
        lv = interior_level(roi.astype(np.float32) * photo.inv_background, region, threshold=photo.threshold)
        if np.isfinite(lv):
            levels.append(lv)
    if not cols:
        return float("nan"), 0, float("nan")
    return float(np.median(cols)), len(cols), (float(np.median(levels)) if levels else float("nan"))


def holder_face(transmission: np.ndarray, threshold: float, axis_col: float) -> tuple[float, float] | None:
    """The face line of the top body holding the axis column (full frame): ``row = a + b * col``.

    The largest dark body touching the top edge whose columns hold ``axis_col``, its holes filled;
    its lower outline's straight line (`dropvision.calibrate.nozzle.fit_face_line`).  None without one.
    """
    mask = (np.asarray(transmission) < threshold).astype(np.uint8)
    top = largest_top_body(mask, int(round(axis_col)) if np.isfinite(axis_col) else -1)
    if top is None:
        return None
    cols, bottom = bottom_profile(top[0] > 0)  # its rows down to its lowest: the same lower outline
    return fit_face_line(cols, bottom)


@dataclass(frozen=True)
class InFocusAxis:
    """The jet's axis, the tip plane and the liquid's level from what is in focus, when the nozzle
    walls are not (`in_focus_axis`): each as the calibration had it where nothing replaces it.

    Attributes
    ----------
    axis_col, tip_row : float
        Full frame (px).
    axis_source, tip_source : str
    liquid_level, threshold : float
        The liquid's interior transmission and the edge threshold from it.
    face : (float, float) or None
        The out-of-focus holder's face line ``row = a + b * col`` (`holder_face`); None without one.
    notes : tuple of str
        The calibration's notes on what was replaced, and why.
    """

    axis_col: float
    axis_source: str
    tip_row: float
    tip_source: str
    liquid_level: float
    threshold: float
    face: tuple[float, float] | None
    notes: tuple[str, ...]

    def applied_to(self, cal: Calibration) -> Calibration:
        """``cal`` with these values, its notes followed by these."""
        return replace(cal, axis_col=self.axis_col, axis_source=self.axis_source, tip_row=self.tip_row,
                       tip_source=self.tip_source, liquid_level=self.liquid_level, threshold=self.threshold,
                       notes=cal.notes + self.notes,
                       tip_crossings=cal.tip_crossings if self.tip_row == cal.tip_row else 0)


def in_focus_axis(cal: Calibration, images, t_first: np.ndarray, geometry: Geometry,
                  photometry: PhotometricReference, config: MeasureConfig, focus: FocusReference) -> InFocusAxis:
    """With the nozzle walls out of focus, the jet's axis and the tip plane from what is in focus.

    A blurred holder's midline is not the jet's axis (it is no nozzle, and the capillary sits
    anywhere in it), and where its straight walls end is not the orifice: the axis is the line of
    the detached in-focus drops (`in_focus_drops`, which also gives the liquid's level: the liquid
    below the walls' end is a blurred holder), the tip plane the holder's face (the 50 % line of
    its lower edge, `holder_face`) at that column, and the attached liquid only what hangs
    below that face (`dropvision.calibrate.nozzle.protruding_columns`, with ``Geometry.face_row0_px``/``face_slope``).
    A given axis column or tip row is kept.
    """
    axis, n_frames, level = in_focus_drops(images, geometry, photometry, config, focus.reference_spread_px,
                                           focus.mist_blur_factor)
    notes = []
    axis_col, axis_src = cal.axis_col, cal.axis_source
    if np.isfinite(axis):
        notes.append(f"the jet's axis is the line of the detached in-focus drops (column {axis:.1f}, "
                     f"{n_frames} calibration frame(s))" + (
                         f", not the out-of-focus nozzle's midline ({cal.axis_col:.1f}, "
                         f"{axis - cal.axis_col:+.1f} px)" if np.isfinite(cal.axis_col) else ""))
        if np.isfinite(cal.axis_col) and abs(axis - cal.axis_col) > 0.25 * cal.nozzle_outer_diameter_px:
            notes.append(f"the drops fly {abs(axis - cal.axis_col):.0f} px beside the middle of the out-of-focus "
                         f"body taken for the nozzle: its width ({cal.nozzle_outer_diameter_px:.0f} px, "
                         "nozzle_outer_diameter_px) is a holder's, not the nozzle's")
        if not cal.axis_col_given:
            axis_col, axis_src = axis, "line of the detached in-focus drops " + (
                "(the nozzle is out of focus)" if cal.nozzle_found else "(no nozzle found)")
    liquid, threshold = cal.liquid_level, cal.threshold
    if np.isfinite(level) and abs(level - cal.liquid_level) > 0.01:
        notes.append(f"liquid interior level {level:.3f} from the detached in-focus drops ("
                     + ("the liquid below the out-of-focus walls' end, a blurred holder, gave "
                        if cal.nozzle_found else "every detached body gave ") + f"{cal.liquid_level:.3f})")
        liquid, threshold = level, edge_threshold(level)
    face = holder_face(t_first, threshold, axis_col) if cal.nozzle_found else None
    tip_row, tip_src = cal.tip_row, cal.tip_source
    if face is not None and not cal.tip_row_given:
        tip = face[0] + face[1] * axis_col
        if abs(tip - cal.tip_row) > 0.5:
            notes.append(f"tip plane at the out-of-focus holder's face, row {tip:.1f} at the axis (where its "
                         f"walls' silhouette ends: row {cal.tip_row:.1f})")
        tip_row, tip_src = float(tip), "the out-of-focus holder's face (straight fit of its 50 % line)"
    return InFocusAxis(axis_col=axis_col, axis_source=axis_src, tip_row=tip_row, tip_source=tip_src,
                       liquid_level=liquid, threshold=threshold, face=face, notes=tuple(notes))


def rest_meniscus_width_px(image: np.ndarray, ctx: FrameContext, rows: int = 4) -> float:
    """Width (px, across the axis) of the liquid at the tip plane in one frame: the orifice's inner
    diameter when the meniscus rests there, pinned at its inner edge.

    The attached liquid's outline in the rows wholly below the tip plane (at most ``rows``); a cap's
    squared chord is nearly linear in the depth, so the squared chords are fitted by a line and
    read at the plane.  With the axis tilted, each edge is read at its own depth along the axis and
    its distance from it (the discs of `dropvision.frame.volume.cut_at_plane`), the plane's low side
    only below the rows the walls reach under the tip row: the rows' horizontal chords there hold
    the walls' clipped remnant (on the synthetic tilted nozzle at some tip phases: 50.8 and 61.2 px
    for a 42.3 px orifice, and a correct pixel size called wrong).  NaN with fewer than 2 such rows
    (a meniscus flat at, or inside, the orifice) or none at all.
    """
    geo, photo = ctx.geometry, ctx.photometry
    roi = ctx.region(image)
    seg = segment(dark_mask(np.ascontiguousarray(roi), photo.thr_image, photo.allowed), ctx.config.min_body_area_px)
    body = find_nozzle_body(seg.bodies, geo.axis_roi)
    if body is None:
        return float("nan")
    att = measure_attached(roi, ctx, seg, body, 1.0)
    r, left, right = outline(att.edges)
    below = r > geo.tip_roi + 0.5
    r, left, right = r[below][:rows], left[below][:rows], right[below][:rows]
    if r.size < 2:
        return float("nan")
    tan = math.tan(geo.tilt_rad)
    if abs(tan) < 1e-12:
        sq = float(np.polyval(np.polyfit(r.astype(float), (right - left) ** 2, 1), geo.tip_roi))
        return float(np.sqrt(sq)) if sq > 0 else float("nan")
    reach = abs(tan) * (geo.nozzle_outer_px if np.isfinite(geo.nozzle_outer_px) else float(np.max(right - left)))
    sides = axis_edge_points(r, left, right, geo.tip_roi, geo.axis_roi, geo.tilt_rad, reach)
    depth, r2 = np.concatenate([sd[0] for sd in sides]), np.concatenate([sd[1] for sd in sides])
    if np.unique(np.round(depth, 6)).size < 2:
        return float("nan")
    sq = float(np.polyval(np.polyfit(depth, r2, 1), 0.0))
    return float(2.0 * np.sqrt(sq)) if sq > 0 else float("nan")


def liquid_seen_hanging(images, ctx: FrameContext) -> bool:
    """Whether a calibration frame shows liquid hanging in focus below an out-of-focus face
    (`dropvision.frame.bodies.hanging_columns`)."""
    geo, photo = ctx.geometry, ctx.photometry
    for img in images:
        roi = ctx.region(img)
        seg = segment(dark_mask(np.ascontiguousarray(roi), photo.thr_image, photo.allowed), ctx.config.min_body_area_px)
        body = find_nozzle_body(seg.bodies, geo.axis_roi)
        if body is not None:
            found = hanging_columns(roi, ctx, seg, body, 1.0)
            if found is not None and found.liquid:
                return True
    return False


def attached_half_width_px(transmission: np.ndarray, cal: Calibration) -> float:
    """How far (px) the liquid hanging from the nozzle reaches sideways from the axis in one frame.

    The dark body touching the top edge that holds the axis column, in its rows from 2 px below
    the tip plane down (a holder block above the tip does not count); 0 when there is none.

    Parameters
    ----------
    transmission : ndarray
        Frame over the background model (canonical orientation).
    cal : Calibration

    Returns
    -------
    float
        Largest horizontal distance (px) of its pixels from the axis.
    """
    mask = (transmission < cal.threshold).astype(np.uint8)
    filled = top_bodies(mask)  # the bodies touching the top edge only (speed: the same bodies as labelling all)
    if filled is None:
        _, lab = cv2.connectedComponents(mask, connectivity=8)
        top = np.unique(lab[0][lab[0] > 0])
    else:
        lab, top = filled[0], [b[1] for b in filled[1]]
    axis = int(round(min(max(cal.axis_col, 0), transmission.shape[1] - 1)))
    r = int(math.ceil(cal.tip_row)) + 2
    below = lab[r:]
    best = 0.0
    for k in top:
        _, cols = np.nonzero(below == k)
        if cols.size == 0:
            continue
        holds_axis = bool(np.any(np.abs(cols - cal.axis_col) < 2.0)) or bool((lab[:r, axis] == k).any())
        if holds_axis:
            best = max(best, float(np.max(np.abs(cols - cal.axis_col))))
    return best


def _segmented_region(image: np.ndarray, geometry: Geometry, photometry: PhotometricReference, config: MeasureConfig):
    """(region, segmentation) of a raw frame: its region of interest smoothed as the frames are
    (`FrameContext.region`) and its dark bodies (`dropvision.frame.segmentation.segment`)."""
    roi = smooth_roi(geometry.crop(image), photometry.smoothing_sigma_px)
    mask = dark_mask(np.ascontiguousarray(roi), photometry.thr_image, photometry.allowed)
    return roi, segment(mask, config.min_body_area_px)


def _nozzle_edge_spread(first: np.ndarray, geometry: Geometry, photometry: PhotometricReference,
                        config: MeasureConfig) -> float:
    """Edge spread of the nozzle body in the first calibration frame (`dropvision.frame.body_classes`)."""
    photo = photometry
    roi, seg = _segmented_region(first, geometry, photo, config)
    body = find_nozzle_body(seg.bodies, geometry.axis_roi)
    return (float("nan") if body is None
            else nozzle_edge_spread_px(roi, photo.inv_background, seg.labels, body, floor=photo.liquid_level))


def transmission_noise(transmission: np.ndarray, default: float, image: np.ndarray | None = None) -> float:
    """Robust spread (std) of the transmission noise of bright background pixels.

    Pixels `dvcore.robust.NOISE_LAG_PX` apart along a row, both bright, share their expectation:
    their differences' spread over sqrt(2) is one pixel's noise (neighbours would miss the part a
    colour camera's or a JPEG coder's 2x2 cells share).  With the raw ``image`` of integer counts,
    the spread is read on the counts (`dvcore.robust.quantized_sigma`: a noise of about one count
    is not a median absolute deviation of integers, which sticks at 1.05 counts from 0.7 to 1.3)
    and scaled by the transmission of one count.

    Parameters
    ----------
    transmission : ndarray
        Frame over background (region of interest).
    default : float
        Returned when 100 bright pairs or fewer exist.
    image : ndarray, optional
        The frame's raw values over the same region (``transmission`` is ``image`` over the
        background).

    Returns
    -------
    float
        Noise standard deviation, in transmission units.
    """
    g = NOISE_LAG_PX
    bright = transmission > 0.9
    pair = bright[:, g:] & bright[:, :-g]
    if np.count_nonzero(pair) <= 100:
        return default
    if image is not None and np.issubdtype(image.dtype, np.integer):
        counts = image.astype(np.float32)[:, :-g][pair]
        per_count = float(median_by_selection(transmission[:, :-g][pair] / np.maximum(counts, 1.0)))
        return pair_noise_sigma(image[:, g:][pair], image[:, :-g][pair], per_count)
    d = (transmission[:, g:] - transmission[:, :-g])[pair]  # np.median's values, by selection (speed only)
    return float(MAD_TO_SIGMA * median_by_selection(np.abs(d - median_by_selection(d))) / np.sqrt(2.0))


def wall_reference(nozzle, tip_row: float, background: np.ndarray, t_first: np.ndarray, sigma_px: float,
                   liquid_level: float, config: MeasureConfig) -> WallReference | None:
    """Per-frame sharpness/contrast reference: the nozzle walls well above the tip plane.

    Parameters
    ----------
    nozzle : dropvision.calibrate.nozzle.Nozzle
        Outer walls found in the first calibration frame.
    tip_row : float
        Tip plane row; walls 3 rows and more above it are used (dry).
    background : ndarray
        Background model (grey levels, full frame).
    t_first : ndarray
        First calibration frame over the background (transmission).
    sigma_px : float
        Calibrated edge blur (px).
    liquid_level : float
        Liquid interior transmission (scales the contrast floor).
    config : MeasureConfig

    Returns
    -------
    WallReference or None
        None when fewer than 4 wall windows, no finite blur, or walls without sharpness or
        contrast: the frames' blur and contrast are then not judged from the walls.
    """
    dry = nozzle.rows <= tip_row - 3
    wr, wc = q.wall_windows(nozzle.rows[dry], nozzle.left_px[dry], nozzle.right_px[dry], t_first.shape[1])
    if not (wr.shape[0] >= 4 and np.isfinite(sigma_px)):
        return None
    prof = t_first[wr, wc]
    sharp, contrast = q.edge_sharpness(prof), q.wall_contrast(prof)
    if not (sharp > 0 and contrast > 0):
        return None
    return WallReference(
        rows=wr, cols=wc, inv_background=(1.0 / background[wr, wc]).astype(np.float32),
        blur_sigma_px=float(sigma_px), sharpness=sharp,
        max_frame_blur_px=min(config.max_blur_px, (1.0 + config.blur_change_tolerance) * sigma_px),
        min_wall_contrast=contrast * max(1.0 - config.contrast_change_tolerance,
                                         config.min_contrast / max(1.0 - liquid_level, 1e-6)))
