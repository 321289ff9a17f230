"""What the calibration pass leaves for the per-frame measurement: the `FrameContext`.

The region of interest (a column band around the axis, from just above the tip down), the arrays
every frame is measured with and the references frames are judged against, and the smoothing of
noisy frames (`smooth_roi`).  The pass that fills it is `dropvision.calibration_pass`.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import cv2
import numpy as np

from dropvision.calibration import Calibration
from dropvision.config import MeasureConfig
from dropvision.segmentation import threshold_image
from dropvision.volume import NL_PER_UM3


class BlurReference(enum.Enum):
    """What a body's edge spread is judged against (`dropvision.classify`): the in-focus nozzle
    walls, or the sharpest detached body when the walls are out of focus.  The value is the text
    summary.json's ``calibration.edge_blur_ref_source`` holds; decisions use the member, never the text."""

    NOZZLE_WALLS = "nozzle walls"
    SHARPEST_BODY = "sharpest detached body (the nozzle walls are out of focus)"


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
    blur_reference: BlurReference = BlurReference.NOZZLE_WALLS
    # standard uncertainty of an edge position common to a body (px)
    edge_position_sigma_px: float = 0.05
    edge_noise_px: float = 0.0  # independent noise of one edge (px): noise / edge slope
    # the fixed sub-pixel floor within edge_position_sigma_px (`MeasureConfig.edge_position_floor_px`):
    # the nozzle's diameter keeps it; a body's volume uses measured terms instead (`dropvision.bodies`)
    edge_floor_px: float = 0.0
    nozzle_blur_px: float = 0.0  # the walls' own blur (px) when they are out of focus, else 0
    # Gaussian smoothing of noisy frames before segmentation (px; 0 = none)
    smooth_px: float = 0.0
    # clipped background: its unclipped level (NaN: not clipped, or unknown) (`background.unclipped_level`)
    clipped_level: float = float("nan")
    mist_blur_factor: float = 1.2
    mist_blur_offset_px: float = 0.25
    compact_ratio: float = 2.0  # a compact body: at most this many equivalent diameters long
    # the face of an out-of-focus holder (full frame, row = face_a + face_b * col; NaN: the nozzle is in
    # focus): the attached liquid is only what hangs below it (`dropvision.nozzle.protruding_columns`)
    face_a: float = float("nan")
    face_b: float = 0.0
    # liquid was seen hanging from it in focus in a calibration frame: a dark bump there is liquid
    face_liquid_seen: bool = False
    # a clipped background whose shape is seen below the clip (`dropvision.calibration_pass.ClipIllumination`):
    # each body's level error from where it lies replaces the sequence's "clipped background" term
    # (``clip_term_px``, px, within edge_position_sigma_px)
    clip_light: object = None
    clip_term_px: float = 0.0

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
        # no nozzle found (no tip plane, no outer width): the whole frame
        r0 = max(0, int(math.floor(cal.tip_row)) - 8) if math.isfinite(cal.tip_row) else 0
        half = config.band_half_width * cal.nozzle_outer_diameter_px + abs(math.tan(cal.tilt_rad)) * (h - r0)
        half = max(half, 48.0, attached_half_width_px + 0.25 * cal.nozzle_outer_diameter_px + 8.0)
        if not (math.isfinite(half) and math.isfinite(cal.axis_col)):
            c0, c1 = 0, w
        else:
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
            compact_ratio=config.compact_ratio, edge_floor_px=config.edge_position_floor_px,
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
        across = dx * c - (dy * s if s else 0.0)  # no tip plane (no nozzle): along the axis unknown, across known
        return (dx * s + dy * c) * self.pixel_size_um, across * self.pixel_size_um


def _kernel_size(sigma_px: float) -> int:
    return 2 * int(math.ceil(2.0 * sigma_px)) + 1  # +-2 sigma


def smoothing_kernel_sigma_px(sigma_px: float) -> float:
    """Standard deviation (px) of the truncated Gaussian kernel `smooth_roi` applies for ``sigma_px``."""
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
