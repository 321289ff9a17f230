"""The calibration pass of a sequence and what it leaves for the per-frame measurement.

`calibrate_sequence` decodes a few frames spread over an open sequence, calibrates them
(`dropvision.calibration.calibrate_frames`: background, nozzle, axis, tilt, tip plane, liquid level),
measures the edge blur, the transmission noise and the nozzle walls' reference sharpness and
contrast, and builds the `FrameContext`: the region of interest (a column band around the axis,
from just above the tip down) and the arrays every frame is measured with.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

import dropvision.quality as q
from dropvision.blur import edge_sigma_px, esf_sigma_px
from dropvision.calibration import Calibration, CalibrationError, calibrate_frames
from dropvision.nozzle import find_nozzle
from dropvision.config import MeasureConfig
from dropvision.sequence import SequenceError
from dropvision.classify import appearance, nozzle_edge_spread_px
from dropvision.edges import body_edges, edge_threshold
from dropvision.segmentation import dark_mask, find_nozzle_body, segment, threshold_image
from dropvision.volume import NL_PER_UM3, outline


@dataclass
class FrameContext:
    """Precomputed per-sequence arrays for the per-frame measurement (region of interest).

    ``r0``, ``c0:c1`` place the region of interest in the frame (px); ``*_roi`` positions are
    in region coordinates, the others in full-frame coordinates (px).  Transmission levels
    (``threshold``, ``liquid_level``, ``noise_t``) are relative to the background (= 1).
    """

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
    saturation_limit: float
    noise_t: float = 0.01
    # per-frame sharpness and contrast from windows across the nozzle walls (full-frame indices)
    wall_rows: np.ndarray | None = None
    wall_cols: np.ndarray | None = None
    wall_inv_background: np.ndarray | None = None
    blur_ref_px: float = float("nan")
    sharpness_ref: float = float("nan")
    max_frame_blur_px: float = float("inf")
    min_wall_contrast: float = 0.0
    # out-of-focus bodies (`dropvision.classify`): edge spread of the in-focus nozzle and the limit rule
    edge_blur_ref_px: float = float("nan")
    edge_blur_ref_source: str = "nozzle walls"
    # standard uncertainty of an edge position common to a body (px)
    edge_position_sigma_px: float = 0.05
    edge_noise_px: float = 0.0  # independent noise of one edge (px): noise / edge slope
    nozzle_blur_px: float = 0.0  # the walls' own blur (px) when they are out of focus, else 0
    # Gaussian smoothing of noisy frames before segmentation (px; 0 = none)
    smooth_px: float = 0.0
    # clipped background: its unclipped level (NaN: not clipped, or unknown) (`background.unclipped_level`)
    clipped_level: float = float("nan")
    mist_blur_factor: float = 1.2
    mist_blur_offset_px: float = 0.25
    compact_ratio: float = 2.0  # a compact body: at most this many equivalent diameters long

    @classmethod
    def build(cls, cal: Calibration, sigma_px: float, dtype, max_value: int, config: MeasureConfig,
              attached_half_width_px: float = 0.0) -> "FrameContext":
        """Region of interest and its arrays from a calibration.

        Parameters
        ----------
        cal : Calibration
        sigma_px : float
            Calibrated edge blur (Gaussian sigma, px); used only with ``config.blur_correction``.
        dtype : numpy dtype
            Dtype of the frames.
        max_value : int
            Sensor maximum grey level (saturation).
        config : MeasureConfig
        attached_half_width_px : float
            Widest reach (px) of the liquid hanging from the nozzle in the calibration frames from
            the axis (`attached_half_width_px`): the band holds it whole (a pendant drop many
            nozzle diameters wide), with a margin of a quarter nozzle diameter and 8 px.
        """
        h, w = cal.shape
        r0 = max(0, int(math.floor(cal.tip_row)) - 8)
        half = config.band_half_width * cal.nozzle_outer_diameter_px + abs(math.tan(cal.tilt_rad)) * (h - r0)
        half = max(half, 48.0, attached_half_width_px + 0.25 * cal.nozzle_outer_diameter_px + 8.0)
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
            threshold=cal.threshold, liquid_level=cal.liquid_level, tip_roi=cal.tip_row - r0, axis_col=cal.axis_col,
            tip_row=cal.tip_row, tilt_rad=cal.tilt_rad, sigma_px=sigma_px if config.blur_correction else 0.0,
            pixel_size_um=cal.pixel_size_um, max_value=max_value,
            sample_rows=sample_rows, sample_cols=sample_cols, min_area_px=config.min_body_area_px,
            gain_tolerance=config.gain_tolerance, saturation_limit=config.saturation_limit,
            mist_blur_factor=config.mist_blur_factor, mist_blur_offset_px=config.mist_blur_offset_px,
            compact_ratio=config.compact_ratio,
        )

    @property
    def nl_per_px3(self) -> float:
        """Volume of one cubic pixel (nl)."""
        return self.pixel_size_um**3 * NL_PER_UM3

    @property
    def axis_roi(self) -> float:
        """Axis column at the tip in region coordinates (px)."""
        return self.axis_col - self.c0

    def to_axis_um(self, row_roi: float, col_roi: float) -> tuple[float, float]:
        """Axis coordinates of a region point.

        Parameters
        ----------
        row_roi, col_roi : float
            Point in region coordinates (px).

        Returns
        -------
        z_um, x_um : float
            Along the axis from the tip plane (down +) and across it (right +), in µm.
        """
        dy = row_roi + self.r0 - self.tip_row
        dx = col_roi + self.c0 - self.axis_col
        s, c = math.sin(self.tilt_rad), math.cos(self.tilt_rad)
        return (dx * s + dy * c) * self.pixel_size_um, (dx * c - dy * s) * self.pixel_size_um


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


def calibrate_sequence(seq, config: MeasureConfig = MeasureConfig(), *,
                       decoded: dict | None = None) -> tuple[Calibration, float, FrameContext]:
    """Calibration pass over a few frames spread over an open sequence.

    Parameters
    ----------
    seq : dropvision.sequence.Sequence
        Open sequence (``meta``, ``len``, ``read``).
    config : MeasureConfig
    decoded : dict, optional
        Receives the decoded calibration frames (index -> image) so that the measurement pass
        does not decode them again.

    Returns
    -------
    cal : Calibration
    sigma_px : float
        Effective edge blur (Gaussian sigma, px).
    ctx : FrameContext
        What `dropvision.frame.measure_frame` needs.

    Raises
    ------
    dropvision.sequence.SequenceError
        No readable frame, or the calibration failed.
    """
    meta = seq.meta
    n = len(seq)
    cal_frames = {}
    for i in calibration_indices(meta.delays_us, config.calibration_frames):
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
        cal = calibrate_frames(
            first, images, meta.pixel_size_um,
            nozzle_outer_diameter_um=meta.nozzle_outer_diameter_um,
            nozzle_inner_diameter_um=meta.nozzle_inner_diameter_um,
            tip_row=meta.nozzle_tip_row, axis_col=meta.axis_col,
            pixel_size_tolerance=config.pixel_size_tolerance_fraction,
            edge_position_floor_px=config.edge_position_floor_px,
            max_value=2 ** int(meta.bit_depth) - 1, clipped_limit=config.saturation_limit,
        )
    except CalibrationError as exc:
        how = (meta.sources or {}).get("orientation")
        seen = (f"; orientation {meta.orientation} ({how}; --orientation or sequence.json orientation sets it)"
                if how and str(exc).startswith("no nozzle") else "")
        raise SequenceError(f"{meta.path / meta.frames[first_idx].file}: {exc}{seen}") from exc
    t_first = np.asarray(first, np.float32) / cal.background.background
    expected = meta.nozzle_outer_diameter_um / cal.pixel_size_um if meta.nozzle_outer_diameter_um else None
    nozzle = find_nozzle(t_first, edge_threshold(cal.nozzle_level), expected)
    max_value = 2 ** int(meta.bit_depth) - 1
    clip_t = 0.99 * max_value / cal.clipped_level if np.isfinite(cal.clipped_level) else float("inf")
    sigma = edge_sigma_px(t_first, nozzle, clip_transmission=clip_t)
    reach = max(attached_half_width_px(np.asarray(img, np.float32) / cal.background.background, cal) for img in images)
    ctx = FrameContext.build(cal, sigma, first.dtype, max_value, config, attached_half_width_px=reach)
    ctx.clipped_level = cal.clipped_level
    ctx.noise_t = transmission_noise(t_first[ctx.r0:, ctx.c0:ctx.c1], ctx.noise_t)
    if ctx.noise_t > config.smooth_noise_limit:  # noisy (low-contrast) frames: smooth before the edges
        ctx.smooth_px = float(config.smooth_px)
        if ctx.sigma_px > 0:  # the kernel is truncated (`smooth_roi`): its own standard deviation
            ctx.sigma_px = float(math.hypot(ctx.sigma_px, _kernel_sigma(ctx.smooth_px)))
    walls = wall_reference(nozzle, cal.tip_row, cal.background.background, t_first, sigma, cal.liquid_level, config)
    if walls is not None:
        ctx.wall_rows, ctx.wall_cols, ctx.wall_inv_background = walls.rows, walls.cols, walls.inv_background
        ctx.blur_ref_px, ctx.sharpness_ref = walls.blur_px, walls.sharpness
        ctx.max_frame_blur_px, ctx.min_wall_contrast = walls.max_frame_blur_px, walls.min_wall_contrast
    nozzle_ref = _nozzle_edge_spread(first, ctx)
    found = detached_appearances(images, ctx)
    ctx.edge_blur_ref_px, ctx.edge_blur_ref_source = nozzle_ref, "nozzle walls"
    body = body_blur_reference(found, nozzle_ref, sigma, config)
    if body is not None:
        # the nozzle (or the holder block around it) is out of focus: what is in focus is the
        # jet's plane, so the sharpest detached body is the reference for mist, and the blur
        # is its outline's edge-spread function; the walls no longer judge a frame's blur or contrast
        cal.nozzle_out_of_focus = True
        body_ref, sigma = body.edge_blur_ref_px, body.sigma_px
        ctx.nozzle_blur_px = body.nozzle_blur_px
        ctx.edge_blur_ref_px = body_ref
        ctx.mist_blur_factor = config.mist_blur_factor_bodies
        ctx.edge_blur_ref_source = "sharpest detached body (the nozzle walls are out of focus)"
        ctx.sigma_px = sigma if config.blur_correction else 0.0
        if ctx.smooth_px > 0 and ctx.sigma_px > 0:
            ctx.sigma_px = float(math.hypot(ctx.sigma_px, _kernel_sigma(ctx.smooth_px)))
        ctx.wall_rows = ctx.wall_cols = ctx.wall_inv_background = None
        ctx.max_frame_blur_px = float("inf")
        cal.notes.append(f"the nozzle walls are out of focus (edge spread {nozzle_ref:.2f} px against "
                         f"{body_ref:.2f} px of the sharpest detached body): in-focus and blur judged from the "
                         "detached bodies, no per-frame blur or contrast from the walls")
        _axis_along_columns(cal, ctx)
    cal.edge_position_terms_px = edge_position_terms_px(cal, sigma, config)
    ctx.edge_position_sigma_px = cal.edge_position_uncertainty_px
    sig = max(float(sigma), 0.5) if np.isfinite(sigma) else 1.0
    ctx.edge_noise_px = float(ctx.noise_t * math.sqrt(2.0 * math.pi) * sig / max(1.0 - cal.liquid_level, 0.05))
    return cal, sigma, ctx


@dataclass(frozen=True)
class BodyBlurReference:
    """The sharpest detached body as the blur reference, when the nozzle walls are out of focus.

    Attributes
    ----------
    edge_blur_ref_px : float
        Its edge spread (`dropvision.classify`): mist is judged against it.
    sigma_px : float
        Its edge blur (Gaussian sigma of its outline's edge-spread fit, else its edge spread):
        the calibration's blur from then on.
    nozzle_blur_px : float
        The walls' own blur: their edge-spread fit, else the body's scaled by the two spreads
        (three times the body's without a wall spread).
    """

    edge_blur_ref_px: float
    sigma_px: float
    nozzle_blur_px: float


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
        The walls' edge-spread fit (`dropvision.blur.edge_sigma_px`).
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
    return BodyBlurReference(edge_blur_ref_px=body_ref, sigma_px=sigma, nozzle_blur_px=nozzle_blur)


def edge_position_terms_px(cal: Calibration, sigma_px: float, config: MeasureConfig) -> dict[str, float]:
    """The parts (px, standard uncertainties) of an edge-position error common to a whole body.

    - ``edge floor``: ``config.edge_position_floor_px`` (threshold interpolation and blur model);
    - ``background level``: the background model's local misfit ``dB/B``
      (`dropvision.background.background_residual`) moves the 50 % crossing by
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
    sig = max(float(sigma_px), 0.5) if np.isfinite(sigma_px) else 1.0
    depth = max(1.0 - float(cal.liquid_level), 0.05)
    terms = {"edge floor": float(config.edge_position_floor_px),
             "background level": float(cal.background.residual) * math.sqrt(2.0 * math.pi) * sig / depth}
    clipped = cal.clipped or {}
    if clipped.get("used") and not clipped.get("level_known", True):
        terms["clipped background"] = 0.5 * float(clipped.get("edge_range_px", 1.0))
    elif clipped.get("used"):
        level = float(clipped["level"])
        rel = float(clipped.get("level_uncertainty", float("nan"))) / level
        span = 1.0 - float(clipped.get("max_value", level)) / level
        rel = math.hypot(rel if np.isfinite(rel) else 0.02, max(span, 0.0) / math.sqrt(3.0))
        terms["clipped background"] = rel * math.sqrt(2.0 * math.pi) * sig / depth
    return terms


#: Fields of `detached_appearances` (one record per body): the calibration frame it is in, its
#: area (px), darkest transmission, edge spread (`dropvision.classify.appearance`, px) and the
#: Gaussian sigma of its outline's edge-spread function (px).
APPEARANCE_DTYPE = np.dtype([("frame", int), ("area_px", int), ("min_transmission", float), ("edge_blur_px", float),
                             ("esf_sigma_px", float)])


def detached_appearances(images, ctx: FrameContext, min_area_px: int = 50) -> np.ndarray:
    """Detached dark bodies of the calibration frames that look like liquid, with their appearance.

    Bodies of at least ``min_area_px`` pixels, not touching the region's edges, as dark as half
    the liquid's depth (``1 - T_min >= (1 - T_liquid) / 2``), judged with the same estimator as
    every body (`dropvision.classify.appearance`).  Mist and dust are never sharper than the
    liquid in the jet's plane, so the smallest ``edge_blur_px`` is an in-focus body whenever the
    frames hold one.

    Parameters
    ----------
    images : sequence of ndarray
        Raw calibration frames (canonical orientation).
    ctx : FrameContext
    min_area_px : int
        Smaller bodies are not used (too few boundary pixels for a stable spread).

    Returns
    -------
    ndarray of `APPEARANCE_DTYPE`
    """
    out = []
    depth_min = 0.5 * (1.0 - ctx.liquid_level)
    for i, img in enumerate(images):
        roi = smooth_roi(img[ctx.r0:, ctx.c0:ctx.c1], ctx)
        seg = segment(dark_mask(np.ascontiguousarray(roi), ctx.thr_image, ctx.allowed), ctx.min_area_px)
        hh, ww = seg.labels.shape
        t = None
        for b in seg.bodies:
            if b.nozzle or b.area_px < min_area_px or b.x0 == 0 or b.x1 == ww or b.y1 == hh:
                continue
            app = appearance(roi, ctx.inv_background, seg.labels, b.label, (b.x0, b.y0, b.x1, b.y1), 1.0,
                             floor=ctx.liquid_level)
            if 1.0 - app.min_transmission >= depth_min and np.isfinite(app.edge_blur_px):
                # its outline's edge-spread function: the blur of the jet's plane
                ed = body_edges(roi, ctx.inv_background, seg.labels, b.label, (b.x0, b.y0, b.x1, b.y1),
                                ctx.threshold)
                if t is None:
                    t = roi.astype(np.float32) * ctx.inv_background
                sig = esf_sigma_px(t, *outline(ed), ctx.liquid_level)
                out.append((i, b.area_px, app.min_transmission, app.edge_blur_px, sig))
    return np.array(out, APPEARANCE_DTYPE)


def _axis_along_columns(cal: Calibration, ctx: FrameContext) -> None:
    """The jet's direction when the nozzle walls are out of focus: the image columns (tilt 0, stated).

    A blurred holder's face or walls do not give the jet's axis (a 3 deg tilt on a level jet
    was measured that way), and the line through a drop and its satellites is not the axis
    either (satellites drift off it by a few px: 1-4 deg from two bodies).  The volume's error
    from a tilt ``t`` left out is ``1 - cos t``: 0.14 % at 3 deg.  ``cal`` and ``ctx`` are
    updated in place.
    """
    cal.tilt_rad = ctx.tilt_rad = 0.0
    cal.tilt_source = "image columns (assumed: the nozzle walls are out of focus)"


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
    _, lab = cv2.connectedComponents(mask, connectivity=8)
    axis = int(round(min(max(cal.axis_col, 0), transmission.shape[1] - 1)))
    top = np.unique(lab[0][lab[0] > 0])
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


def _kernel_size(sigma_px: float) -> int:
    return 2 * int(math.ceil(2.0 * sigma_px)) + 1  # +-2 sigma


def _kernel_sigma(sigma_px: float) -> float:
    """Standard deviation (px) of the truncated Gaussian kernel `smooth_roi` applies."""
    k = cv2.getGaussianKernel(_kernel_size(sigma_px), sigma_px).ravel()
    x = np.arange(k.size) - k.size // 2
    return float(np.sqrt(np.sum(k * x * x)))


def smooth_roi(roi: np.ndarray, ctx: FrameContext) -> np.ndarray:
    """The region of interest, smoothed by ``ctx.smooth_px`` (Gaussian truncated at +-2 sigma)
    when the frames are noisy."""
    if ctx.smooth_px <= 0:
        return roi
    size = _kernel_size(ctx.smooth_px)
    return cv2.GaussianBlur(np.ascontiguousarray(roi), (size, size), ctx.smooth_px)


def _nozzle_edge_spread(first: np.ndarray, ctx: FrameContext) -> float:
    """Edge spread of the nozzle body in the first calibration frame (`dropvision.classify`)."""
    roi = smooth_roi(first[ctx.r0:, ctx.c0:ctx.c1], ctx)
    seg = segment(dark_mask(np.ascontiguousarray(roi), ctx.thr_image, ctx.allowed), ctx.min_area_px)
    body = find_nozzle_body(seg.bodies, ctx.axis_roi)
    return (float("nan") if body is None
            else nozzle_edge_spread_px(roi, ctx.inv_background, seg.labels, body, floor=ctx.liquid_level))


def transmission_noise(transmission: np.ndarray, default: float) -> float:
    """Robust spread (std) of the transmission noise of bright background pixels.

    Parameters
    ----------
    transmission : ndarray
        Frame over background (region of interest).
    default : float
        Returned when fewer than 100 neighbouring bright pairs exist.

    Returns
    -------
    float
        Noise standard deviation, in transmission units (MAD of horizontal differences).
    """
    d = np.diff(transmission, axis=1)[(transmission[:, 1:] > 0.9) & (transmission[:, :-1] > 0.9)]
    if d.size > 100:
        return float(1.4826 * np.median(np.abs(d - np.median(d))) / np.sqrt(2.0))
    return default


@dataclass(frozen=True)
class WallReference:
    """The nozzle walls well above the tip plane: the per-frame sharpness and contrast reference.

    Attributes
    ----------
    rows, cols : ndarray of int
        Pixel windows across the walls (`dropvision.quality.wall_windows`, full-frame).
    inv_background : ndarray of float32
        ``1 / background`` at those pixels.
    blur_px : float
        Calibrated edge blur the walls' sharpness corresponds to (px).
    sharpness : float
        Their edge sharpness in the calibration frame (`dropvision.quality.edge_sharpness`).
    max_frame_blur_px : float
        A frame blurrier than this is flagged.
    min_wall_contrast : float
        A frame whose walls' contrast is below this is flagged.
    """

    rows: np.ndarray
    cols: np.ndarray
    inv_background: np.ndarray
    blur_px: float
    sharpness: float
    max_frame_blur_px: float
    min_wall_contrast: float


def wall_reference(nozzle, tip_row: float, background: np.ndarray, t_first: np.ndarray, sigma_px: float,
                   liquid_level: float, config: MeasureConfig) -> WallReference | None:
    """Per-frame sharpness/contrast reference: the nozzle walls well above the tip plane.

    Parameters
    ----------
    nozzle : dropvision.nozzle.Nozzle
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
        blur_px=float(sigma_px), sharpness=sharp,
        max_frame_blur_px=min(config.max_blur_px, (1.0 + config.blur_change_tolerance) * sigma_px),
        min_wall_contrast=contrast * max(1.0 - config.contrast_change_tolerance,
                                         config.min_contrast / max(1.0 - liquid_level, 1e-6)))
