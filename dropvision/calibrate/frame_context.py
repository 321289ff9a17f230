"""What the calibration pass leaves for the per-frame measurement: the `FrameContext`.

A frozen result in three groups, with the `dropvision.config.MeasureConfig` beside them:
`Geometry` (the region of interest, a column band around the axis from just above the tip down,
and the axis), `PhotometricReference` (the arrays every frame is measured with, the noise, the smoothing of
noisy frames (`smooth_roi`) and the references frames are judged against) and `BlurModel` (the
edge blur and the in-focus reference).  The pass that builds it is `dropvision.calibrate.calibration_pass`.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import cv2
import numpy as np

from dropvision.calibrate.calibration import Calibration
from dropvision.config import MeasureConfig
from dropvision.frame.segmentation import threshold_image
from dropvision.frame.volume import NL_PER_UM3


class BlurReference(enum.Enum):
    """What a body's edge spread is judged against (`dropvision.frame.body_classes`): the in-focus nozzle
    walls, or the sharpest detached body when the walls are out of focus.  The value is the text
    summary.json's ``calibration.edge_blur_ref_source`` holds; decisions use the member, never the text."""

    NOZZLE_WALLS = "nozzle walls"
    SHARPEST_BODY = "sharpest detached body (the nozzle walls are out of focus)"


@dataclass(frozen=True)
class Geometry:
    """Where a sequence's frames are measured: the region of interest and the jet's axis.

    The region is a column band around the axis from just above the tip plane down
    (``row0_px``, ``col0_px:col1_px`` in the full frame, px); ``*_roi`` positions are in region
    coordinates, the others in full-frame coordinates (px, canonical orientation).

    Attributes
    ----------
    row0_px, col0_px, col1_px : int
        First row, first and end (exclusive) column of the region in the frame (px).
    frame_height_px, frame_width_px : int
        The frame's size (px).
    tip_row, axis_col : float
        Tip plane's row and the axis' column at it (px; NaN without a nozzle).
    tilt_rad : float
        The axis' tilt from the columns (rad).
    pixel_size_um : float
    face_row0_px, face_slope : float
        The face of an out-of-focus holder, ``row = face_row0_px + face_slope * col`` (full frame,
        px; NaN: the nozzle is in focus): the attached liquid is only what hangs below it
        (`dropvision.calibrate.nozzle.protruding_columns`).
    face_liquid_seen : bool
        Liquid was seen hanging from that face in focus in a calibration frame: a dark bump there is liquid.
    nozzle_outer_px : float
        The nozzle's outer width at its tip (px; NaN without a nozzle).
    tip_crossings : int
        The wall crossings the tip plane is the median of (``Calibration.tip_crossings``; 0: not so placed).
    """

    row0_px: int
    col0_px: int
    col1_px: int
    frame_height_px: int
    frame_width_px: int
    tip_row: float
    axis_col: float
    tilt_rad: float
    pixel_size_um: float
    face_row0_px: float = float("nan")
    face_slope: float = 0.0
    face_liquid_seen: bool = False
    nozzle_outer_px: float = float("nan")
    tip_crossings: int = 0

    @classmethod
    def from_calibration(cls, cal: Calibration, config: MeasureConfig, attached_half_width_px: float = 0.0,
                         face: tuple[float, float] | None = None, face_liquid_seen: bool = False) -> "Geometry":
        """The region of interest of a calibration.

        Parameters
        ----------
        cal : Calibration
        config : MeasureConfig
            ``band_half_width`` (in nozzle outer diameters).
        attached_half_width_px : float
            Widest reach (px) of the liquid hanging from the nozzle in the calibration frames from
            the axis (`dropvision.calibrate.calibration_pass.attached_half_width_px`): the band holds it whole (a
            pendant drop many nozzle diameters wide), with a margin of a quarter nozzle diameter and 8 px.
        face : (float, float), optional
            An out-of-focus holder's face line (``face_row0_px``, ``face_slope``).
        face_liquid_seen : bool
        """
        h, w = cal.shape
        # no nozzle found (no tip plane, no outer width): the whole frame
        row0 = max(0, int(math.floor(cal.tip_row)) - 8) if math.isfinite(cal.tip_row) else 0
        half = config.band_half_width * cal.nozzle_outer_diameter_px + abs(math.tan(cal.tilt_rad)) * (h - row0)
        half = max(half, 48.0, attached_half_width_px + 0.25 * cal.nozzle_outer_diameter_px + 8.0)
        if not (math.isfinite(half) and math.isfinite(cal.axis_col)):
            col0, col1 = 0, w
        else:
            col0 = max(0, int(math.floor(cal.axis_col - half)))
            col1 = min(w, int(math.ceil(cal.axis_col + half)) + 1)
        face_row0, face_slope = face if face is not None else (float("nan"), 0.0)
        return cls(row0_px=row0, col0_px=col0, col1_px=col1, frame_height_px=h, frame_width_px=w,
                   tip_row=cal.tip_row, axis_col=cal.axis_col, tilt_rad=cal.tilt_rad, pixel_size_um=cal.pixel_size_um,
                   face_row0_px=face_row0, face_slope=face_slope, face_liquid_seen=face_liquid_seen,
                   nozzle_outer_px=float(cal.nozzle_outer_diameter_px), tip_crossings=int(cal.tip_crossings))

    def crop(self, image: np.ndarray) -> np.ndarray:
        """The region of interest of a full frame (a view)."""
        return image[self.row0_px:, self.col0_px:self.col1_px]

    @property
    def tip_roi(self) -> float:
        """Tip plane's row in region coordinates (px)."""
        return self.tip_row - self.row0_px

    @property
    def axis_roi(self) -> float:
        """Axis column at the tip in region coordinates (px)."""
        return self.axis_col - self.col0_px

    @property
    def nl_per_px3(self) -> float:
        """Volume of one cubic pixel (nl)."""
        return self.pixel_size_um**3 * NL_PER_UM3

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
        dy = row_roi + self.row0_px - self.tip_row
        dx = col_roi + self.col0_px - self.axis_col
        s, c = math.sin(self.tilt_rad), math.cos(self.tilt_rad)
        across = dx * c - (dy * s if s else 0.0)  # no tip plane (no nozzle): along the axis unknown, across known
        return (dx * s + dy * c) * self.pixel_size_um, across * self.pixel_size_um


@dataclass(frozen=True)
class WallReference:
    """The nozzle walls well above the tip plane: the per-frame sharpness and contrast reference.

    Attributes
    ----------
    rows, cols : ndarray of int
        Pixel windows across the walls (`dropvision.quality.wall_windows`, full-frame).
    inv_background : ndarray of float32
        ``1 / background`` at those pixels.
    blur_sigma_px : float
        Calibrated blur (Gaussian sigma, px) the walls' sharpness corresponds to.
    sharpness : float
        Their edge sharpness in the calibration frame (`dropvision.quality.edge_sharpness`).
    max_frame_blur_px : float
        A frame blurrier than this (Gaussian sigma, px) is flagged.
    min_wall_contrast : float
        A frame whose walls' contrast is below this is flagged.
    """

    rows: np.ndarray
    cols: np.ndarray
    inv_background: np.ndarray
    blur_sigma_px: float
    sharpness: float
    max_frame_blur_px: float
    min_wall_contrast: float


@dataclass(frozen=True)
class PhotometricReference:
    """The photometric reference of a sequence's frames over the region of interest.

    Transmission levels (``threshold``, ``liquid_level``, ``noise_transmission``) are relative
    to the background (= 1).

    Attributes
    ----------
    background, inv_background : ndarray of float32
        The background model over the region (grey levels) and its inverse.
    thr_image : ndarray
        The grey level of the edge threshold over the region (`dropvision.frame.segmentation.threshold_image`).
    allowed, opaque : ndarray or None
        Where static specks are not (mask for segmentation) and where they are (dilated); None without specks.
    threshold, liquid_level : float
        Edge threshold and the liquid's interior transmission.
    max_value : int
        Sensor maximum (grey levels).
    sample_rows, sample_cols : ndarray of int
        Background samples along the region's sides (region coordinates) for a frame's gain.
    noise_transmission : float
        Robust standard deviation of a bright pixel's transmission (`dropvision.calibrate.calibration_pass.transmission_noise`).
    smoothing_sigma_px : float
        Gaussian smoothing (sigma, px) of each region before segmentation (0: none; `smooth_roi`).
    clipped_level : float
        A clipped background's unclipped level (grey levels; NaN: not clipped, or unknown).
    walls : WallReference or None
        The nozzle walls as the per-frame sharpness and contrast reference (None: not judged from them).
    """

    background: np.ndarray
    inv_background: np.ndarray
    thr_image: np.ndarray
    allowed: np.ndarray | None
    opaque: np.ndarray | None
    threshold: float
    liquid_level: float
    max_value: int
    sample_rows: np.ndarray
    sample_cols: np.ndarray
    noise_transmission: float = 0.01
    smoothing_sigma_px: float = 0.0
    clipped_level: float = float("nan")
    walls: WallReference | None = None

    @classmethod
    def from_calibration(cls, cal: Calibration, geometry: Geometry, dtype, max_value: int, *,
                         noise_transmission: float = 0.01, smoothing_sigma_px: float = 0.0,
                         walls: WallReference | None = None) -> "PhotometricReference":
        """The arrays of a calibration over the region of ``geometry``, with the frames' noise, smoothing
        and wall reference as measured by the calibration pass."""
        bg = np.ascontiguousarray(geometry.crop(cal.background.background))
        allowed = opaque = None
        if cal.background.opaque is not None:
            op = geometry.crop(cal.background.opaque)
            if op.any():
                opaque = cv2.dilate(op.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
                allowed = np.where(op, 0, 255).astype(np.uint8)
        hh, ww = bg.shape
        rows = np.arange(0, hh, 4)
        sample_rows = np.concatenate([rows, rows, rows, rows])
        sample_cols = np.concatenate([np.full(rows.size, 1), np.full(rows.size, 3), np.full(rows.size, ww - 2),
                                      np.full(rows.size, ww - 4)]).clip(0, ww - 1)
        return cls(background=bg, inv_background=(1.0 / bg).astype(np.float32),
                   thr_image=threshold_image(bg, cal.threshold, dtype), allowed=allowed, opaque=opaque,
                   threshold=cal.threshold, liquid_level=cal.liquid_level, max_value=max_value,
                   sample_rows=sample_rows, sample_cols=sample_cols, noise_transmission=noise_transmission,
                   smoothing_sigma_px=smoothing_sigma_px, clipped_level=cal.clipped_level, walls=walls)


@dataclass(frozen=True)
class BlurModel:
    """The blur of a sequence's edges (the glossary in docs/ARCHITECTURE.md names each term).

    Attributes
    ----------
    calibrated_sigma_px : float
        The edge blur (Gaussian sigma, px) measured in the calibration: the nozzle walls' edge-spread
        fit, or the sharpest detached body's when the walls are out of focus.
    correction_sigma_px : float
        The blur the volumes are corrected for (px): ``calibrated_sigma_px`` with the smoothing of
        noisy frames added in quadrature; 0 without ``MeasureConfig.blur_correction``.
    reference : BlurReference
        What a body's edge spread is judged against.
    reference_spread_px : float
        That reference's edge spread (px; summary.json ``edge_blur_ref_px``): mist is judged against it.
    mist_blur_factor : float
        The mist limit's factor on it (``MeasureConfig.mist_blur_factor``, or
        ``mist_blur_factor_bodies`` with a body reference).
    nozzle_sigma_px : float
        The nozzle walls' own blur (Gaussian sigma, px) when they are out of focus, else 0.
    edge_position_sigma_px : float
        Standard uncertainty of an edge position common to a body (px).
    edge_noise_px : float
        Independent noise of one edge (px): the transmission noise over the edge's slope.
    clip_light : ClipIllumination or None
        The backlight under a clipped background, where its shape is seen below the clip
        (`dropvision.calibrate.calibration_pass.ClipIllumination`): each body's level error from where it lies
        replaces the sequence's "clipped background" term (``clip_term_px``, px, within
        ``edge_position_sigma_px``).
    clip_term_px : float
    """

    calibrated_sigma_px: float
    correction_sigma_px: float
    reference: BlurReference = BlurReference.NOZZLE_WALLS
    reference_spread_px: float = float("nan")
    mist_blur_factor: float = 1.2
    nozzle_sigma_px: float = 0.0
    edge_position_sigma_px: float = 0.05
    edge_noise_px: float = 0.0
    clip_light: object = None
    clip_term_px: float = 0.0


@dataclass(frozen=True)
class FrameContext:
    """What the per-frame measurement (`dropvision.frame.measure_frame`) needs of a sequence: the
    calibration pass's result (`dropvision.calibrate.calibration_pass.calibrate_sequence`) in three groups,
    and the configuration beside them.

    Attributes
    ----------
    geometry : Geometry
        The region of interest and the jet's axis.
    photometry : PhotometricReference
        The background, thresholds, noise and the walls' sharpness and contrast reference.
    blur : BlurModel
        Edge blur, the in-focus reference and the edge-position uncertainties.
    config : MeasureConfig
        The knobs (``min_body_area_px``, ``gain_tolerance``, ``saturation_limit``, ``compact_ratio``,
        ``mist_blur_offset_px``, ``edge_position_floor_px`` ...), read where they apply.
    """

    geometry: Geometry
    photometry: PhotometricReference
    blur: BlurModel
    config: MeasureConfig

    def region(self, image: np.ndarray) -> np.ndarray:
        """The region of interest of a full frame, smoothed as the frames are (`smooth_roi`)."""
        return smooth_roi(self.geometry.crop(image), self.photometry.smoothing_sigma_px)


def _kernel_size(sigma_px: float) -> int:
    return 2 * int(math.ceil(2.0 * sigma_px)) + 1  # +-2 sigma


def smoothing_kernel_sigma_px(sigma_px: float) -> float:
    """Standard deviation (px) of the truncated Gaussian kernel `smooth_roi` applies for ``sigma_px``."""
    k = cv2.getGaussianKernel(_kernel_size(sigma_px), sigma_px).ravel()
    x = np.arange(k.size) - k.size // 2
    return float(np.sqrt(np.sum(k * x * x)))


def smooth_roi(roi: np.ndarray, smoothing_sigma_px: float) -> np.ndarray:
    """The region of interest, smoothed by a Gaussian of ``smoothing_sigma_px`` (truncated at +-2
    sigma) when the frames are noisy (``PhotometricReference.smoothing_sigma_px`` > 0)."""
    if smoothing_sigma_px <= 0:
        return roi
    size = _kernel_size(smoothing_sigma_px)
    return cv2.GaussianBlur(np.ascontiguousarray(roi), (size, size), smoothing_sigma_px)
