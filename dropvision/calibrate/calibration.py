"""Calibration of a strobe sequence from its own frames (`calibrate_frames`, `Calibration`).

The stages, each in its own module: the background (illumination) model and a clipped
backlight (`dropvision.calibrate.background`), the nozzle's walls and tip plane (`dropvision.calibrate.nozzle`), and
here the liquid's interior level (`interior_level`: median transmission inside liquid bodies,
their bright lens spot excluded; the edge threshold is half-way between it and 1,
`dropvision.frame.edges.edge_threshold`).  The edges' blur is measured afterwards
(`dropvision.calibrate.blur`), and `dropvision.calibrate.calibration_pass.calibrate_sequence` runs all of it on an open
sequence.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field, replace
from typing import ClassVar

import cv2
import numpy as np

from dropvision.calibrate.background import (BackgroundModel, CalibrationError, CalibrationWarning, NoNozzleError,
                                   clipped_edge_range_px, clipped_fraction, darkest_level, estimate_background,
                                   unclipped_level)
from dropvision.frame.edges import DEFAULT_EDGE_THRESHOLD, edge_threshold, first_pass_threshold
from dropvision.calibrate.nozzle import find_nozzle, find_tip, outer_diameter_uncertainty_px
from dropvision.frame.segmentation import fill_holes

#: The key of the fixed edge-position floor among ``Calibration.edge_position_terms_px`` (summary.json
#: ``calibration.edge_position_terms_px``; text of the output, not a decision made on a message).
EDGE_FLOOR_TERM = "edge floor"

__all__ = ["Calibration", "CalibrationError", "CalibrationWarning", "calibrate_frames", "interior_level"]


def quadrature_px(terms: dict) -> float:
    """Standard uncertainties (px) of independent parts, ``terms`` (name -> px), in quadrature."""
    return float(np.sqrt(sum(v * v for v in terms.values())))


def relative_uncertainty(uncertainty: float, value: float) -> float:
    """``uncertainty / value``; 0 for no uncertainty (a given value, taken as exact)."""
    u = float(uncertainty)
    return u / float(value) if u > 0 and value > 0 else 0.0


def interior_level(transmission: np.ndarray, region: np.ndarray, erode_px: int = 4,
                   threshold: float = DEFAULT_EDGE_THRESHOLD) -> float:
    """Median transmission inside dark bodies of ``region`` (bool), eroded, lens spot excluded
    (the mode instead when it is above 0.3: low contrast)."""
    t = np.asarray(transmission, np.float32)
    mask = (region & (t < threshold)).astype(np.uint8) * 255
    filled = fill_holes(mask)
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * erode_px + 1, 2 * erode_px + 1))
    inner = cv2.erode(filled, k) > 0
    vals = t[inner & (t < threshold)]
    if vals.size < 20:
        return float("nan")
    level = float(np.median(vals))
    if level > 0.3 and vals.size >= 200:
        # low contrast: the edge moves by (level error) / slope, and the slope is small, so the
        # halo of the lens spot must not pull the level up: the mode of the values instead
        hist, edges = np.histogram(vals, bins=60, range=(float(np.percentile(vals, 1)), float(np.percentile(vals, 99))))
        hist = np.convolve(hist, np.ones(5) / 5, mode="same")
        k = int(np.argmax(hist))
        half = 2.5 * (edges[1] - edges[0])
        centre = 0.5 * (edges[k] + edges[k + 1])
        near = vals[np.abs(vals - centre) <= half]
        level = float(np.mean(near)) if near.size else level
    return level


@dataclass(frozen=True)
class ClippedBackground:
    """A background clipped at the sensor maximum over more than ``clipped_limit`` of the frame.

    Attributes
    ----------
    fraction : float
        Fraction of the background model at the sensor maximum.
    level : float
        Grey level used wherever the background is clipped: the unclipped level read at the
        nozzle walls (`dropvision.calibrate.background.unclipped_level`), or the sensor maximum (a lower
        bound) when it could not be estimated (``level_known`` False).
    level_uncertainty : float
        Standard uncertainty of ``level`` (grey levels; NaN when unknown).
    max_value : int
        Sensor maximum (grey levels).
    level_known : bool
        The level was estimated (above the sensor maximum).
    edge_range_px : float
        With an unknown level: how far (px) the true edge may lie outside the measured one
        (`dropvision.calibrate.background.clipped_edge_range_px`); NaN when the level is known.
    """

    fraction: float
    level: float
    level_uncertainty: float
    max_value: int
    level_known: bool
    edge_range_px: float = float("nan")

    #: How the level is found (summary.json's ``calibration.clipped_background.method``).
    METHOD: ClassVar[str] = ("background grey level from the unclipped part of the top body's edge profile "
                             "(background.unclipped_level), used wherever the background model is at the "
                             "sensor maximum")

    def to_dict(self) -> dict:
        """summary.json's ``calibration.clipped_background`` (its keys and their order unchanged)."""
        out = {"fraction": self.fraction, "level": self.level, "level_uncertainty": self.level_uncertainty,
               "max_value": self.max_value, "method": self.METHOD, "level_known": self.level_known, "used": True}
        if not self.level_known:
            out["edge_range_px"] = self.edge_range_px
        return out


@dataclass(frozen=True)
class Calibration:
    """Everything the per-frame measurement needs (full-frame canonical coordinates).

    Frozen: `calibrate_frames` builds it from its stages' results, and the calibration pass
    (`dropvision.calibrate.calibration_pass.calibrate_sequence`) gives the new values of its own stages
    with `dataclasses.replace`; nothing assigns to a calibration once built.
    """

    shape: tuple[int, int]
    pixel_size_um: float
    pixel_size_source: str
    tip_row: float
    tip_source: str
    axis_col: float
    axis_source: str
    tilt_rad: float
    tilt_source: str
    liquid_level: float
    nozzle_level: float
    threshold: float
    nozzle_outer_diameter_px: float
    nozzle_outer_diameter_um_measured: float
    pixel_size_disagreement_percent: float
    background: BackgroundModel
    notes: tuple[str, ...] = ()
    #: Pixel size implied by ``nozzle_outer_diameter_um`` over the given one (NaN without it; 1 when the pixel
    #: size is the nozzle's own, ``pixel_size_from_nozzle``).
    pixel_size_ratio: float = float("nan")
    #: Standard uncertainty of that ratio from the measured outer diameter (see `outer_diameter_uncertainty_px`).
    pixel_size_ratio_uncertainty: float = float("nan")
    #: A clipped background (`ClippedBackground`); None when the background is not clipped.
    clipped: ClippedBackground | None = None
    #: Parts of the edge-position uncertainty common to a body (px; `dropvision.calibrate.calibration_pass.edge_position_terms_px`).
    edge_position_terms_px: dict = field(default_factory=dict)
    #: The nozzle walls are out of focus (the sharpest detached body is the in-focus reference).
    nozzle_out_of_focus: bool = False
    #: False when no nozzle was found (`_without_nozzle`): no tip plane, no attached liquid.
    nozzle_found: bool = True
    #: Width (px) of the meniscus at the tip plane in the first calibration frame and that frame's delay
    #: (µs): the orifice's inner diameter when the meniscus rests there (`dropvision.calibrate.calibration_pass.
    #: rest_meniscus_width_px`; NaN: not measured).
    rest_meniscus_width_px: float = float("nan")
    rest_meniscus_delay_us: float = float("nan")
    #: That width is the walls' outer width (to the two edges' blur): the liquid is pinned at the outer
    #: edge (a pendant drop on a needle, a wetted face), and the width says nothing of the inner diameter.
    rest_meniscus_at_outer_edge: bool = False
    #: The pixel size is the needle's (nozzle's) outer diameter over its outer width measured here
    #: (no pixel size given): nothing to check it against, and its uncertainty is stated.
    pixel_size_from_nozzle: bool = False
    #: Standard uncertainty of ``pixel_size_um`` (µm): 0 when given (taken as exact), else from the
    #: width's uncertainty (`dropvision.calibrate.nozzle.needle_width_terms_px`, ``nozzle_width_terms_px``).
    pixel_size_uncertainty_um: float = 0.0
    #: Parts (px, standard uncertainties) of the needle's outer width when the pixel size comes from it.
    nozzle_width_terms_px: dict = field(default_factory=dict)
    #: The tip row and the axis column were given (sequence.json or an option), not measured: nothing replaces them.
    tip_row_given: bool = False
    axis_col_given: bool = False
    #: The wall crossings the tip plane is the median of (`dropvision.calibrate.nozzle.find_tip`; 0: not
    #: from the walls' crossings).
    tip_crossings: int = 0
    #: The nozzle walls' own blur (Gaussian sigma, px) when they are out of focus (0: in focus): their
    #: outer width is read to about that on each side (`dropvision.analysis.plausibility.check_pixel_size`).
    nozzle_sigma_px: float = 0.0

    @property
    def pixel_size_relative_uncertainty(self) -> float:
        """``pixel_size_uncertainty_um / pixel_size_um`` (0 for a given pixel size)."""
        return relative_uncertainty(self.pixel_size_uncertainty_um, self.pixel_size_um)

    @property
    def edge_position_uncertainty_px(self) -> float:
        """Standard uncertainty (px) of an edge position common to a body: its parts in quadrature."""
        return quadrature_px(self.edge_position_terms_px)

    @property
    def volume_uncertainty_source(self) -> str:
        """The largest part of the edge-position uncertainty ("edge floor" when none is known)."""
        terms = self.edge_position_terms_px
        return max(terms, key=terms.get) if terms else EDGE_FLOOR_TERM

    @property
    def clipped_level(self) -> float:
        """Unclipped background level used where the background is clipped; NaN when not clipped or unknown."""
        if self.clipped is None:
            return float("nan")  # not clipped
        return float(self.clipped.level)

    @property
    def tilt_deg(self) -> float:
        return float(np.degrees(self.tilt_rad))

    def to_dict(self) -> dict:
        return {
            "pixel_size_um": self.pixel_size_um,
            "pixel_size_source": self.pixel_size_source,
            "tip_row": self.tip_row,
            "tip_row_source": self.tip_source,
            "axis_col": self.axis_col,
            "axis_col_source": self.axis_source,
            "tilt_deg": self.tilt_deg,
            "tilt_source": self.tilt_source,
            "coordinates": "canonical frame (nozzle at the top, drops travel down), pixel centres integers",
            "liquid_interior_transmission": self.liquid_level,
            "nozzle_interior_transmission": self.nozzle_level,
            "edge_threshold_transmission": self.threshold,
            "nozzle_outer_diameter_px": self.nozzle_outer_diameter_px,
            "nozzle_outer_diameter_um_measured": self.nozzle_outer_diameter_um_measured,
            "pixel_size_disagreement_percent": self.pixel_size_disagreement_percent,
            "pixel_size_ratio": self.pixel_size_ratio,
            "pixel_size_ratio_uncertainty": self.pixel_size_ratio_uncertainty,
            "pixel_size_from_nozzle": self.pixel_size_from_nozzle,
            "pixel_size_uncertainty_um": self.pixel_size_uncertainty_um,
            "nozzle_outer_diameter_uncertainty_px": (
                quadrature_px(self.nozzle_width_terms_px) if self.nozzle_width_terms_px else float("nan")),
            "nozzle_outer_diameter_terms_px": dict(self.nozzle_width_terms_px),
            "rest_meniscus_width_px": self.rest_meniscus_width_px,
            "background": {
                "method": "robust degree-4 polynomial fit to pixels away from dark bodies"
                + (", static dust attenuation folded in" if self.background.n_frames >= 3 else ""),
                "frames_used": self.background.n_frames,
                "dust_pixels": self.background.dust_pixels,
                "illumination_falloff": self.background.falloff,
                "residual": self.background.residual,
            },
            "clipped_background": None if self.clipped is None else self.clipped.to_dict(),
            "edge_position_uncertainty_px": self.edge_position_uncertainty_px,
            "edge_position_terms_px": dict(self.edge_position_terms_px),
            "volume_uncertainty_source": self.volume_uncertainty_source,
            "nozzle_out_of_focus": self.nozzle_out_of_focus,
            "notes": list(self.notes),
        }


def calibrate_frames(first: np.ndarray, spread: list[np.ndarray], pixel_size_um: float, *,
                     nozzle_outer_diameter_um: float | None = None, nozzle_inner_diameter_um: float | None = None,
                     tip_row: float | None = None, axis_col: float | None = None, static_dust: bool = True,
                     pixel_size_tolerance: float = 0.02, edge_position_floor_px: float = 0.05,
                     max_value: int | None = None, clipped_limit: float = 0.01, allow_no_nozzle: bool = False,
                     pixel_size_from_nozzle: bool = False) -> Calibration:
    """Calibrate a sequence from its first (meniscus at rest) frame and frames spread over it.

    Its stages, each returning its own frozen result: the background (`lit_background`), the
    nozzle (`dropvision.calibrate.nozzle.find_nozzle`), the pixel size (`pixel_scale`), the tip plane
    and the axis (`tip_and_axis`) and the liquid's level (`liquid_interior_level`); the
    `Calibration` is assembled from them once.

    Parameters
    ----------
    first : ndarray
        The first frame in delay order.
    spread : list of ndarray
        Frames spread over the sequence (``first`` included), for the background.
    pixel_size_um : float
        From the metadata.
    nozzle_outer_diameter_um, nozzle_inner_diameter_um : float, optional
        Nozzle dimensions (cross-check of the pixel size; annulus columns).
    tip_row, axis_col : float, optional
        User-given values override the detection.
    pixel_size_tolerance : float
        Relative disagreement of the pixel size with the outer diameter beyond which a
        calibration note (and a `CalibrationWarning`) is given.
    edge_position_floor_px : float
        Systematic uncertainty of one wall edge (px), see `outer_diameter_uncertainty_px`.
    max_value : int, optional
        Sensor maximum; with it, a background clipped there over more than ``clipped_limit`` (a
        fraction) of the frame gets its unclipped level from the nozzle walls (`lit_background`).
    allow_no_nozzle : bool
        Where no nozzle is found but the first frame holds detached dark bodies, calibrate
        without it (`_without_nozzle`) instead of raising.
    static_dust : bool
        Fold static dust seen in three or more of ``spread`` into the background (`estimate_background`).
    pixel_size_from_nozzle : bool
        No pixel size was given: ``pixel_size_um`` is provisional and the pixel size is
        ``nozzle_outer_diameter_um`` over the outer width measured here, by the one rule of the
        needle's width (the narrowest straight walls of the top body, `dropvision.calibrate.nozzle.find_nozzle`
        without an expected width: the rule `dropvision.calibrate.inspection.nozzle_outer_width_px` applies);
        nothing is cross-checked against it.  Its uncertainty is set by
        `dropvision.calibrate.calibration_pass.calibrate_sequence` once the edge terms are known.
    """
    from_nozzle = bool(pixel_size_from_nozzle and nozzle_outer_diameter_um)
    # the width is the pixel size's source: no expected width steers the walls' choice (one rule)
    expected = nozzle_outer_diameter_um / pixel_size_um if nozzle_outer_diameter_um and not from_nozzle else None
    lit = lit_background(first, spread, expected, static_dust=static_dust, max_value=max_value,
                         clipped_limit=clipped_limit)
    bg = lit.background
    t_first = np.asarray(first, np.float32) / bg.background
    # first pass at 50 % (half-way to the darkest body in a low-contrast frame, where the nozzle
    # itself may sit near 50 %), refined with the measured nozzle level
    darkest = darkest_level(t_first)
    try:
        nozzle = find_nozzle(t_first, first_pass_threshold(darkest), expected)
    except CalibrationError as exc:
        if not (allow_no_nozzle and isinstance(exc, NoNozzleError)):
            raise
        return _without_nozzle(exc, t_first, spread, bg, pixel_size_um, first_pass_threshold(darkest), lit.notes,
                               lit.clipped)
    thr_n = edge_threshold(nozzle.interior_level)
    nozzle = find_nozzle(t_first, thr_n, expected)
    scale = pixel_scale(nozzle, pixel_size_um, nozzle_outer_diameter_um, from_nozzle=from_nozzle,
                        tolerance=pixel_size_tolerance, edge_position_floor_px=edge_position_floor_px)
    if scale.note is not None:
        warnings.warn(scale.note, CalibrationWarning, stacklevel=2)
    r_in = None if nozzle_inner_diameter_um is None else 0.5 * nozzle_inner_diameter_um / scale.pixel_size_um
    place = tip_and_axis(t_first, nozzle, thr_n, r_in, tip_row=tip_row, axis_col=axis_col)
    liquid, liquid_note = liquid_interior_level(spread, bg, place.tip_row, thr_n, nozzle.interior_level)
    notes = lit.notes + tuple(n for n in (scale.note, liquid_note) if n is not None)
    return Calibration(
        shape=t_first.shape, pixel_size_um=float(scale.pixel_size_um), pixel_size_source=scale.source,
        tip_row=float(place.tip_row), tip_source=place.tip_source, tip_row_given=tip_row is not None,
        axis_col=float(place.axis_col), axis_source=place.axis_source, axis_col_given=axis_col is not None,
        tilt_rad=float(place.tilt_rad), tilt_source=place.tilt_source,
        liquid_level=liquid, nozzle_level=nozzle.interior_level, threshold=edge_threshold(liquid),
        nozzle_outer_diameter_px=float(scale.outer_diameter_px),
        nozzle_outer_diameter_um_measured=float(scale.outer_diameter_um),
        pixel_size_disagreement_percent=scale.disagreement_percent, background=bg, notes=notes,
        pixel_size_ratio=scale.ratio, pixel_size_ratio_uncertainty=scale.ratio_uncertainty, clipped=lit.clipped,
        pixel_size_from_nozzle=from_nozzle, tip_crossings=int(place.tip_crossings))


@dataclass(frozen=True)
class LitBackground:
    """The background model of a sequence, a clipped backlight's level put in where it is clipped
    (`lit_background`).

    Attributes
    ----------
    background : BackgroundModel
    clipped : ClippedBackground or None
        None when the background is not clipped.
    notes : tuple of str
        The calibration's note on the clip (empty when not clipped).
    """

    background: BackgroundModel
    clipped: ClippedBackground | None = None
    notes: tuple[str, ...] = ()


def lit_background(first: np.ndarray, spread: list[np.ndarray], expected_width_px: float | None, *,
                   static_dust: bool = True, max_value: int | None = None,
                   clipped_limit: float = 0.01) -> LitBackground:
    """The background model of ``spread`` (`estimate_background`), and where it is clipped at the
    sensor maximum over more than ``clipped_limit`` of the frame, its unclipped level: read at the
    nozzle walls of ``first`` (`unclipped_level`; their expected width ``expected_width_px``), else the
    sensor maximum as a lower bound (the true edge then lies within `clipped_edge_range_px` outside the
    measured one)."""
    bg = estimate_background(spread, static_dust=static_dust)
    frac = clipped_fraction(bg.background, max_value)
    if not frac > clipped_limit:
        return LitBackground(bg)
    level, level_se = unclipped_level(first, find_nozzle(np.asarray(first, np.float32) / bg.background,
                                                         DEFAULT_EDGE_THRESHOLD,
                                                         expected_width_px), max_value)
    if bool(np.isfinite(level) and level > max_value):
        clipped = ClippedBackground(fraction=frac, level=level, level_uncertainty=level_se,
                                    max_value=int(max_value), level_known=True)
        bg = replace(bg, background=np.where(bg.background >= 0.99 * max_value, np.float32(level),
                                             bg.background).astype(np.float32))
        return LitBackground(bg, clipped, (
            f"background clipped at the sensor maximum over {100 * frac:.0f} % of the frame: its "
            f"level {level:.0f} (max {max_value}) estimated from the nozzle walls; edges are taken below the clip",))
    # the true level is at or above the clip: the sensor maximum is its lower bound, and the
    # true edge lies between our crossing and the first clipped pixel outside it
    bg = replace(bg, background=np.where(bg.background >= 0.99 * max_value, np.float32(max_value),
                                         bg.background).astype(np.float32))
    nz = find_nozzle(np.asarray(first, np.float32) / bg.background, DEFAULT_EDGE_THRESHOLD, expected_width_px)
    clipped = ClippedBackground(fraction=frac, level=float(max_value), level_uncertainty=float("nan"),
                                max_value=int(max_value), level_known=False,
                                edge_range_px=clipped_edge_range_px(first, nz, max_value))
    return LitBackground(bg, clipped, (
        f"background clipped over {100 * frac:.0f} % of the frame and its level could not be "
        f"estimated (the middle of the nozzle walls' edge is clipped too): the sensor maximum "
        f"{max_value} is taken as its level (a lower bound); the true edge lies within "
        f"{clipped.edge_range_px:.2f} px outside the measured one (in the uncertainty)",))


@dataclass(frozen=True)
class PixelScale:
    """The pixel size of a calibration and the nozzle's outer width against it (`pixel_scale`).

    Attributes
    ----------
    pixel_size_um : float
        The given one, or the nozzle's outer diameter over its measured width (``from_nozzle``).
    source : str
        Where it comes from (summary.json ``pixel_size_source``).
    outer_diameter_px, outer_diameter_um : float
        The nozzle's outer width measured (px) and in µm at that pixel size.
    disagreement_percent, ratio, ratio_uncertainty : float
        A given pixel size checked against the outer diameter: the width's disagreement (%), the
        implied pixel size over the given one and its standard uncertainty (NaN: nothing to check).
    note : str or None
        The calibration's note when the disagreement is beyond the tolerance.
    """

    pixel_size_um: float
    source: str
    outer_diameter_px: float
    outer_diameter_um: float
    disagreement_percent: float = float("nan")
    ratio: float = float("nan")
    ratio_uncertainty: float = float("nan")
    note: str | None = None


def pixel_scale(nozzle, pixel_size_um: float, nozzle_outer_diameter_um: float | None, *, from_nozzle: bool,
                tolerance: float, edge_position_floor_px: float) -> PixelScale:
    """The pixel size (given, or the outer diameter over the measured width when ``from_nozzle``)
    and, for a given one, its check against the outer diameter: a note beyond ``tolerance``
    (relative); the ratio's uncertainty from `outer_diameter_uncertainty_px` with
    ``edge_position_floor_px``."""
    source = "sequence.json pixel_size_um"
    if from_nozzle:
        pixel_size_um = float(nozzle_outer_diameter_um) / nozzle.outer_diameter_px
        source = (f"nozzle outer diameter {nozzle_outer_diameter_um:g} um / {nozzle.outer_diameter_px:.2f} px "
                  f"(its straight outer walls, rows {int(nozzle.rows[0])}-{int(nozzle.rows[-1])} of the first frame)")
    d_px = nozzle.outer_diameter_px
    d_um = d_px * pixel_size_um
    if not (nozzle_outer_diameter_um and not from_nozzle):
        return PixelScale(pixel_size_um, source, d_px, d_um)
    # a given pixel size: checked against the diameter
    disagree = 100.0 * (d_um / nozzle_outer_diameter_um - 1.0)
    # implied pixel size (outer diameter / measured px) over the given one
    ratio = float(nozzle_outer_diameter_um / d_um)
    ratio_u = float(ratio * outer_diameter_uncertainty_px(nozzle, edge_position_floor_px) / d_px)
    note = None
    if abs(disagree) > 100 * tolerance:
        note = (f"pixel size {pixel_size_um} um disagrees by {disagree:+.1f} % with the nozzle's outer "
                f"width ({d_px:.1f} px for {nozzle_outer_diameter_um} um)")
    return PixelScale(pixel_size_um, source, d_px, d_um, disagree, ratio, ratio_u, note)


@dataclass(frozen=True)
class TipAndAxis:
    """The tip plane's row, the axis' column at it and its tilt, each with its source (`tip_and_axis`)."""

    tip_row: float
    tip_source: str
    axis_col: float
    axis_source: str
    tilt_rad: float
    tilt_source: str
    tip_crossings: int = 0  # the wall crossings the plane is the median of (`find_tip`; 0: none)


def tip_and_axis(t_first: np.ndarray, nozzle, threshold: float, inner_radius_px: float | None, *,
                 tip_row: float | None = None, axis_col: float | None = None) -> TipAndAxis:
    """The tip plane (`find_tip`) and the axis of the nozzle's outer walls' midline fit; a given
    ``tip_row`` or ``axis_col`` replaces what was found (the axis then taken at the given tip)."""
    tip, tip_src, crossings = find_tip(t_first, nozzle, threshold, inner_radius_px)
    axis = nozzle.axis_col(tip)
    axis_src = "nozzle outer walls midline fit"
    if tip_row is not None:
        tip, tip_src, crossings = float(tip_row), "user (sequence.json nozzle_tip_row)", 0
        axis = nozzle.axis_col(tip)
    if axis_col is not None:
        axis, axis_src = float(axis_col), "user (sequence.json axis_col)"
    return TipAndAxis(tip_row=tip, tip_source=tip_src, axis_col=axis, axis_source=axis_src,
                      tilt_rad=nozzle.tilt_rad, tilt_source="nozzle outer walls midline fit", tip_crossings=crossings)


def liquid_interior_level(spread: list[np.ndarray], bg: BackgroundModel, tip_row: float, threshold: float,
                          nozzle_level: float) -> tuple[float, str | None]:
    """The liquid's interior level: the median of `interior_level` over ``spread``, below the tip
    plane (3 rows down) and off opaque specks; the nozzle's level ``nozzle_level`` with a note when
    no liquid body is large enough.  Returns (level, note or None)."""
    region = np.zeros(bg.background.shape, bool)
    region[int(np.ceil(tip_row)) + 3:, :] = True
    if bg.opaque is not None:
        region &= ~bg.opaque
    levels = []
    for img in spread:
        lv = interior_level(np.asarray(img, np.float32) / bg.background, region, threshold=threshold)
        if np.isfinite(lv):
            levels.append(lv)
    if levels:
        return float(np.median(levels)), None
    return nozzle_level, "no liquid body large enough to measure its interior level: nozzle level used"


#: Tilt and its source when no nozzle is found: the image columns (stated, as for an out-of-focus nozzle).
NO_NOZZLE_TILT_SOURCE = "image columns (assumed: no nozzle found)"


def _without_nozzle(exc: CalibrationError, t_first: np.ndarray, spread: list[np.ndarray], bg: BackgroundModel,
                    pixel_size_um: float, threshold: float, notes: tuple[str, ...],
                    clipped: ClippedBackground | None) -> Calibration:
    """A calibration without a nozzle, for a frame whose detached drops can still be measured.

    Only when the first frame holds a dark body touching no edge of the frame of at least 50 px
    (else ``exc`` is raised: nothing to measure).  No tip plane (NaN: no position along the axis),
    no axis yet (the calibration pass takes the line of the detached drops), no outer width; the
    liquid's interior level from those bodies.  Each drop's volume is its own (discs about its
    own axis); what needs the nozzle (attached volume, its cross-checks) is not given.
    """
    h, w = t_first.shape
    n, lab, st, _ = cv2.connectedComponentsWithStats((t_first < threshold).astype(np.uint8), connectivity=8)
    x0, y0, bw, bh, area = st[:, 0], st[:, 1], st[:, 2], st[:, 3], st[:, 4]
    inside = (x0 > 0) & (y0 > 0) & (x0 + bw < w) & (y0 + bh < h) & (area >= 50)
    inside[0] = False
    if not inside.any():
        raise exc
    levels = []
    for img in spread:
        t = np.asarray(img, np.float32) / bg.background
        _, lab_i, st_i, _ = cv2.connectedComponentsWithStats((t < threshold).astype(np.uint8), connectivity=8)
        keep = ((st_i[:, 0] > 0) & (st_i[:, 1] > 0) & (st_i[:, 0] + st_i[:, 2] < w) & (st_i[:, 1] + st_i[:, 3] < h)
                & (st_i[:, 4] >= 50))
        keep[0] = False
        region = keep[lab_i]
        if bg.opaque is not None:
            region &= ~bg.opaque
        lv = interior_level(t, region, threshold=threshold)
        if np.isfinite(lv):
            levels.append(lv)
    liquid = float(np.median(levels)) if levels else float(np.percentile(t_first[inside[lab]], 2))
    notes = notes + (f"{exc}: no nozzle found; the detached drops are measured each about its own axis, the jet's "
                     "axis is their line, and what needs the nozzle (attached volume, tip plane, distance along the "
                     "axis, pixel-size cross-checks) is not given",)
    nan = float("nan")
    return Calibration(
        shape=(h, w), pixel_size_um=float(pixel_size_um), pixel_size_source="sequence.json pixel_size_um",
        tip_row=nan, tip_source="none (no nozzle found)", axis_col=nan, axis_source="none (no nozzle found)",
        tilt_rad=0.0, tilt_source=NO_NOZZLE_TILT_SOURCE, liquid_level=liquid, nozzle_level=nan,
        threshold=edge_threshold(liquid), nozzle_outer_diameter_px=nan, nozzle_outer_diameter_um_measured=nan,
        pixel_size_disagreement_percent=nan, background=bg, notes=notes, clipped=clipped, nozzle_found=False)
