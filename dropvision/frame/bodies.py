"""The dark bodies of a frame as liquid: attached liquid (nozzle body) and detached bodies.

- `find_nozzle_body` (`dropvision.frame.segmentation`): the largest body touching the top of the region that
  spans the axis;
- `measure_attached`: its run edges cut at the tip plane, its volume below the tip plane, its
  bottom and its neck;
- `measure_body` / `describe_detached`: a detached body's volume, position on the axis, size,
  and whether it can be trusted (leaves the field of view or the measured band, overlaps dust).

The per-pixel class image the viewer shows is drawn from these bodies by
`dropvision.app.rerun_log.class_image`.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from dropvision.calibrate.frame_context import FrameContext
from dropvision.frame.segmentation import (
    DarkBody,
    Segmentation,
    find_nozzle_body,
)
from dropvision.frame.edges import RowEdges, body_edges, edge_shift_px
from dropvision.calibrate.nozzle import Protrusion, protruding_columns
from dropvision.frame.outline import body_outline
from dropvision.frame.volume import (
    asymmetry_uncertainty_px3,
    equivalent_diameter_um,
    BodyVolume,
    clip_to_tip_plane,
    integrate,
    neck_chord_px,
    top_chord_ratio,
    edge_definition_px,
    interpolation_error_px,
    plane_cut_uncertainty_px3,
    plane_span_chord_px,
    random_volume_uncertainty_px3,
    tilt_model_uncertainty_px3,
    volume_uncertainty_px3,
)


@dataclass
class DetachedBody:
    """A detached liquid body of one frame.

    Volumes in nl, lengths in µm, rows in region coordinates (px), ``bbox`` half-open
    ``(x0, y0, x1, y1)`` in region coordinates (px).
    """

    volume_nl: float
    z_um: float
    x_um: float
    length_um: float
    diameter_um: float
    top_row: float
    bottom_row: float
    leaves: bool
    out_of_band: bool
    on_dust: bool
    bbox: tuple[int, int, int, int]
    top_chord_ratio: float = float("nan")
    area_px: int = 0
    row_px: float = float("nan")  # volume centroid in the canonical frame (px)
    col_px: float = float("nan")
    min_transmission: float = float("nan")
    edge_blur_px: float = float("nan")
    reason: str = ""  # why it is not a drop or satellite (out-of-focus bodies)
    touching: bool = False  # split off the main drop at a waist: counted, its volume in the main drop's
    #: standard uncertainty (`body_volume_uncertainty_nl`, with its sides' departure from mirror images:
    #: `dropvision.frame.volume.asymmetry_uncertainty_px3`)
    volume_uncertainty_nl: float = float("nan")
    #: its part from the edges' own noise, independent from frame to frame (`body_random_uncertainty_nl`)
    random_uncertainty_nl: float = float("nan")
    off_path: bool = False  # beside the jet's path (`off_path_reason`): a speck, not liquid of this firing
    #: outer boundary, (row, col) pixel centres of the canonical frame (`dropvision.frame.outline.body_outline`)
    outline: np.ndarray | None = field(default=None, repr=False, compare=False)

    def elongated(self, compact_ratio: float) -> bool:
        """Longer than ``compact_ratio`` equivalent-sphere diameters (a tail, a ligament)."""
        return self.length_um > compact_ratio * equivalent_diameter_um(self.volume_nl)


class DetachedClass(enum.Enum):
    """The class of an in-focus detached body of one frame (`detached_class`); the value is its
    ``body_class`` in bodies.parquet where it has one of its own (a touching body is a ``satellite``)."""

    BORDER = "border"
    MAIN_DROP = "main_drop"
    TOUCHING = "touching"
    TAIL = "tail"
    SATELLITE = "satellite"


def detached_class(body: DetachedBody, index: int, compact_ratio: float) -> DetachedClass:
    """The one rule for the class of the ``index``-th in-focus detached body of a frame (largest
    first, `FrameRecord.bodies`), used by bodies.parquet (`dropvision.frame.body_classes.bodies_table`) and
    the viewer's class image (`class_image`): cut by the frame or the measured band, ``BORDER``;
    the first, ``MAIN_DROP``; split off the main drop at a waist, ``TOUCHING``; longer than
    ``compact_ratio`` equivalent-sphere diameters, ``TAIL``; else ``SATELLITE``."""
    if body.leaves or body.out_of_band:
        return DetachedClass.BORDER
    if index == 0:
        return DetachedClass.MAIN_DROP
    if body.touching:
        return DetachedClass.TOUCHING
    if body.elongated(compact_ratio):
        return DetachedClass.TAIL
    return DetachedClass.SATELLITE


@dataclass
class AttachedLiquid:
    """The liquid joined to the nozzle in one frame (`measure_attached`).

    Attributes
    ----------
    volume_nl : float
        Volume below the tip plane (nl).
    bottom_row : float
        Lowest row (region coordinates, px).
    neck_px : float
        Narrowest chord above its bulb (px), NaN if none (`volume.neck_chord_px`).
    leaves : bool
        It reaches the bottom of the frame (its volume is then unknown).
    edges : RowEdges
        Its run edges, cut at the tip plane.
    volume_uncertainty_nl : float
        Standard uncertainty of ``volume_nl``: the edges' common error, their noise and the tip
        plane's place in quadrature (`body_volume_uncertainty_nl`).
    common_uncertainty_nl, plane_uncertainty_nl : float
        Its parts from the edges' common error (blur correction included) and from the tip
        plane: a grown volume, a difference of two attached volumes, keeps only the difference
        of the first and, of the second, the difference of its position part.
    plane_position_uncertainty_nl : float
        The tip plane's part from its place alone, the slice there times the plane's uncertainty
        (`dropvision.frame.volume.plane_cut_uncertainty_px3` without a tilt): the same plane cuts
        every frame, but a frame whose liquid is wider there than the rest's moves by more.
    face_halo_nl : float
        The in-focus walls' halo below their face (`face_halo_px3`).
    halo_band_nl : float
        The part of ``common_uncertainty_nl`` from the band of edge levels
        (`dropvision.frame.volume.edge_definition_px`) when every row of the liquid lies within the
        nozzle's halo (3 blur sigmas below its tip), so that the band's bright end is the halo's
        level, not the background's (0 otherwise).  Every later frame's liquid holds the same rows
        under the same halo at the same level: a grown volume does not keep it
        (`dropvision.analysis.sequence_summary.grown_uncertainty`).
    """

    volume_nl: float
    bottom_row: float
    neck_px: float
    leaves: bool
    edges: RowEdges
    volume_uncertainty_nl: float = float("nan")
    common_uncertainty_nl: float = float("nan")
    plane_uncertainty_nl: float = float("nan")
    plane_position_uncertainty_nl: float = float("nan")
    face_halo_nl: float = 0.0
    halo_band_nl: float = 0.0


def out_of_focus_nozzle_px3(volume: BodyVolume, nozzle_blur_px: float) -> float:
    """Standard uncertainty (px^3) of attached liquid next to an out-of-focus nozzle.

    The walls' halo reaches ``3 sigma`` below the tip plane: the liquid's edges there are placed
    only to about half the walls' blur ``sigma``, over a band as wide as the top chord ``c``:
    ``pi c (3 sigma) (sigma / 2)``.  The halo is the static holder's and the liquid there fills the
    orifice in every frame: the error is the same from frame to frame, like the tip plane's
    (`measure_attached` counts it with the plane, which a grown volume cancels; on the synthetic
    out-of-focus holder the grown volume's median |error| / u went from 0.008 to 0.33 with it,
    every frame still within 2 u).  Not counted where the holder's face line is known: there the
    halo's rows are placed against their own background beside the liquid (`edges_in_the_halo`).
    """
    if not (np.isfinite(nozzle_blur_px) and nozzle_blur_px > 0):
        return 0.0
    return float(math.pi * volume.top_chord_px * 3.0 * nozzle_blur_px * 0.5 * nozzle_blur_px)


def face_halo_px3(volume: BodyVolume, walls_sigma_px: float) -> float:
    """How far (px^3) the in-focus walls' halo below their face can widen the attached liquid.

    The walls' face ends at the tip plane; its blur darkens the rows just below it beside the
    liquid, and the liquid's edges there move out by about half the walls' blur ``sigma``: over the
    plane's top chord ``c``, as a slab ``pi (c/2)^2 sigma / 2`` (the plane's own term at the walls'
    half-blur).  The resting meniscus fills the orifice and carries its share in every frame alike;
    what a frame spreads wider under the face than the rest (`dropvision.analysis.sequence_summary.
    grown_uncertainty` differences it against the first delay's) is not cancelled.  On the synthetic
    sweep, the attached volume's error rose by 0.018 nl (u70, top chord 38.2 -> 45.4 px, sigma 0.78 px:
    0.020 nl of this at its widest) and 0.027 nl (watcher-side, 38.3 -> 46.5 px, sigma 1.22 px:
    0.035 nl), and fell back as the chord did.  0 with out-of-focus walls (their own terms: `out_of_focus_nozzle_px3`)."""
    if not (np.isfinite(walls_sigma_px) and walls_sigma_px > 0):
        return 0.0
    c = volume.top_chord_px
    return float(math.pi * 0.25 * c * c * 0.5 * walls_sigma_px)


def measure_attached(roi: np.ndarray, ctx: FrameContext, seg: Segmentation, body: DarkBody, gain: float) -> AttachedLiquid:
    """Edges, volume below the tip plane, bottom and neck of the liquid joined to the nozzle.

    Parameters
    ----------
    roi : ndarray
        Raw frame, region of interest.
    ctx : FrameContext
    seg : Segmentation
    body : DarkBody
        The nozzle body (`find_nozzle_body`).
    gain : float
        Frame illumination relative to the background model.

    Returns
    -------
    AttachedLiquid
    """
    geo, photo = ctx.geometry, ctx.photometry
    # the background beside the liquid is read below the nozzle's halo (3 blur sigmas under its tip)
    halo_px = 3.0 * max(ctx.blur.correction_sigma_px if np.isfinite(ctx.blur.correction_sigma_px) else 0.0, 0.5)
    below_halo = int(math.ceil(geo.tip_roi + halo_px)) if np.isfinite(geo.tip_roi) else 0
    ed = body_edges(roi, photo.inv_background, seg.labels, body.label, body.bbox,
                    photo.threshold, gain, row_min=max(0, int(math.floor(geo.tip_roi)) - 1),
                    bright_row_min=below_halo)
    # no row below the halo: the band's bright end was read in it (`dropvision.frame.edges.subpixel_edges`)
    in_halo = bool(below_halo > 0 and ed.row.size and int(ed.row.max()) < below_halo)
    # an out-of-focus holder: only what hangs below its face is liquid
    if np.isfinite(geo.face_row0_px):
        found = hanging_columns(roi, ctx, seg, body, gain)
        if found is None:
            return nothing_hangs(ed, 0.0)
        keep = (ed.right_px >= found.first - 0.5) & (ed.left_px <= found.last + 0.5)
        ed = RowEdges(ed.row[keep], np.maximum(ed.left_px[keep], found.first - 0.5),
                      np.minimum(ed.right_px[keep], found.last + 0.5), ed.touches)
        ed = edges_in_the_halo(roi, ctx, ed, found, gain)
        if not found.liquid:  # the face's blurred halo: no liquid, but as much could hide in it
            return nothing_hangs(ed, integrate(ed, geo.tilt_rad, geo.tip_roi, 0.0).volume_px3 * geo.nl_per_px3)
    span = plane_span_chord_px(ed, geo.tip_roi, geo.axis_roi, geo.tilt_rad)
    clip_to_tip_plane(ed, geo.tip_roi, geo.axis_roi, geo.tilt_rad)
    walls_in_focus = not (np.isfinite(ctx.blur.nozzle_sigma_px) and ctx.blur.nozzle_sigma_px > 0)
    # the walls' width, against which the row holding the tip plane is judged (in-focus walls only)
    walls = geo.nozzle_outer_px if walls_in_focus and not np.isfinite(geo.face_row0_px) else float("nan")
    bv = replace(integrate(ed, geo.tilt_rad, geo.tip_roi, ctx.blur.correction_sigma_px, walls, axis_col=geo.axis_roi),
                 plane_span_px=span)
    # with the holder's face line known, the halo's rows were placed against their own background
    # (`edges_in_the_halo`): the halo no longer moves them, and their noise is in the random part
    near = (0.0 if np.isfinite(geo.face_row0_px)
            else out_of_focus_nozzle_px3(bv, ctx.blur.nozzle_sigma_px) * geo.nl_per_px3)
    halo = face_halo_px3(bv, ctx.blur.calibrated_sigma_px) * geo.nl_per_px3 if walls_in_focus else 0.0
    return AttachedLiquid(volume_nl=bv.volume_px3 * geo.nl_per_px3, bottom_row=bv.bottom_row,
                          neck_px=neck_chord_px(ed, geo.tip_roi), leaves=body.y1 >= roi.shape[0], edges=ed,
                          volume_uncertainty_nl=float(np.hypot(body_volume_uncertainty_nl(bv, ctx, plane=True), near)),
                          common_uncertainty_nl=_common_px3(bv, ctx, closed=False) * geo.nl_per_px3,
                          plane_uncertainty_nl=float(np.hypot(plane_cut_uncertainty_px3(bv, _plane_sigma_px(ctx),
                                                                                         geo.tilt_rad) * geo.nl_per_px3,
                                                              near)),
                          plane_position_uncertainty_nl=plane_cut_uncertainty_px3(bv, _plane_sigma_px(ctx))
                          * geo.nl_per_px3,
                          face_halo_nl=float(halo),
                          halo_band_nl=_definition_px3(bv, ctx) * geo.nl_per_px3 if in_halo else 0.0)


def hanging_columns(roi: np.ndarray, ctx: FrameContext, seg: Segmentation, body: DarkBody,
                    gain: float) -> Protrusion | None:
    """What reaches below an out-of-focus holder's face (``ctx.geometry.face_row0_px``, ``face_slope``) at the axis, and
    whether it is liquid (`dropvision.calibrate.nozzle.protruding_columns`; columns in region px), or None."""
    geo, photo = ctx.geometry, ctx.photometry
    limit = ctx.blur.mist_blur_factor * ctx.blur.reference_spread_px + ctx.config.mist_blur_offset_px
    x0, x1 = body.x0, body.x1
    y1 = min(roi.shape[0], body.y1 + int(math.ceil(3.0 * limit)) + 2)
    mask = seg.labels[:body.y1, x0:x1] == body.label
    t = roi[:y1, x0:x1].astype(np.float32) * photo.inv_background[:y1, x0:x1]
    if gain != 1.0:
        t /= np.float32(gain)
    face = geo.face_row0_px + geo.face_slope * (np.arange(x0, x1) + geo.col0_px) - geo.row0_px
    found = protruding_columns(mask, t, face, geo.axis_roi - x0, 0.5 * (photo.threshold + photo.liquid_level), limit,
                               judge_focus=not geo.face_liquid_seen)
    return None if found is None else replace(found, first=found.first + x0, last=found.last + x0)


def edges_in_the_halo(roi: np.ndarray, ctx: FrameContext, edges: RowEdges, found: Protrusion,
                      gain: float) -> RowEdges:
    """The liquid's edges in the rows within an out-of-focus face's halo (3 of its blur widths
    below the face), against the local background.

    There the halo darkens the background beside the liquid and the frame's 50 % line runs
    around both: the liquid's edge is half-way between its own level and the row's background
    beside it (the median of the 8 columns beyond each side of the protrusion), its outermost
    crossings within the protrusion's columns by linear interpolation (a lens spot inside is
    liquid).  A row without a pixel that dark holds no liquid.  Rows below the halo are unchanged.
    """
    blur = ctx.blur.nozzle_sigma_px if np.isfinite(ctx.blur.nozzle_sigma_px) and ctx.blur.nozzle_sigma_px > 0 else 0.0
    y_end = min(roi.shape[0], int(math.ceil(ctx.geometry.tip_roi + 3.0 * blur)) + 1)
    y_start = max(0, int(math.floor(ctx.geometry.tip_roi)))
    halo = (edges.row >= y_start) & (edges.row < y_end)
    if not halo.any():
        return edges
    ww = roi.shape[1]
    side = np.r_[np.arange(found.first - 9, found.first - 1), np.arange(found.last + 2, found.last + 10)]
    side = side[(side >= 0) & (side < ww)]
    if side.size == 0:
        return edges
    rows, lefts, rights = [], [], []
    for y in np.unique(edges.row[halo]):
        t = roi[y].astype(np.float32) * ctx.photometry.inv_background[y] / np.float32(gain)
        thr = 0.5 * float(np.median(t[side])) * (1.0 + ctx.photometry.liquid_level)
        dark = np.nonzero(t[found.first:found.last + 1] < thr)[0]
        if dark.size == 0:
            continue
        a, b = found.first + int(dark[0]), found.first + int(dark[-1])  # outermost: a lens spot inside is liquid
        left = a - 0.5 if a == 0 else a - 1 + (t[a - 1] - thr) / (t[a - 1] - t[a])
        right = b + 0.5 if b == ww - 1 else b + (thr - t[b]) / (t[b + 1] - t[b])
        rows.append(y)
        lefts.append(left)
        rights.append(right)
    keep = ~halo
    return RowEdges(np.r_[np.asarray(rows, int), edges.row[keep]].astype(edges.row.dtype),
                    np.r_[lefts, edges.left_px[keep]], np.r_[rights, edges.right_px[keep]], edges.touches)


def nothing_hangs(edges: RowEdges, hidden_nl: float) -> AttachedLiquid:
    """The attached liquid of a frame where nothing hangs below the face: 0 nl (not NaN), no bottom
    row (nothing to be joined to) and no neck; its uncertainty ``hidden_nl``, the volume of the
    face's halo below the face line (as much liquid could hide in it); ``edges`` kept for the viewer."""
    return AttachedLiquid(volume_nl=0.0, bottom_row=float("nan"), neck_px=float("nan"), leaves=False, edges=edges,
                          volume_uncertainty_nl=float(hidden_nl), common_uncertainty_nl=0.0,
                          plane_uncertainty_nl=float(hidden_nl), plane_position_uncertainty_nl=float(hidden_nl))


#: The tip plane is the median of the wall annulus's 50 % crossings, at least two columns a side
#: (`dropvision.calibrate.nozzle.find_tip`): of at least 4 edges' independent errors the median keeps at most
#: ``sqrt(pi / 2) / sqrt(4)`` of one edge's (`tip_median_factor` with the crossings counted).
TIP_MEDIAN_FACTOR = math.sqrt(math.pi / 2.0) / 2.0


def tip_median_factor(crossings: int) -> float:
    """Share of one edge's independent error that the tip plane keeps: the mean of two sides'
    medians over ``crossings`` wall crossings in all, ``sqrt(pi / 2 / crossings)`` (a median's
    variance is pi/2 a mean's); `TIP_MEDIAN_FACTOR`, its value at 4 crossings, where fewer or none
    were counted (a tip found otherwise, or given).  On the synthetic low-contrast rig, 26
    crossings: 0.25 of an edge's, not 0.63."""
    return math.sqrt(math.pi / 2.0 / crossings) if crossings >= 4 else TIP_MEDIAN_FACTOR


#: An out-of-focus holder's face line is fitted to each column's lowest dark row, a whole row
#: (`dropvision.calibrate.nozzle.bottom_profile`): the face's 50 % crossing lies up to one row
#: below it, uniformly, a root-mean-square ``1 / sqrt(3)`` px.
FACE_ROW_RMS_PX = 1.0 / math.sqrt(3.0)


def _plane_sigma_px(ctx: FrameContext) -> float:
    """How well the tip plane is placed (px): as an edge, the common error (`common_edge_sigma_px`)
    and the median of its crossings' own errors (`tip_median_factor` x `edge_noise_total_px`); with
    the walls out of focus, the plane placed on the holder's face line to its whole rows
    (`FACE_ROW_RMS_PX`), or to the walls' blur where no face line is known."""
    nb = ctx.blur.nozzle_sigma_px if np.isfinite(ctx.blur.nozzle_sigma_px) else 0.0
    if nb > 0 and np.isfinite(ctx.geometry.face_row0_px):
        nb = FACE_ROW_RMS_PX
    median = tip_median_factor(ctx.geometry.tip_crossings)
    return float(math.sqrt(common_edge_sigma_px(ctx) ** 2 + (median * edge_noise_total_px(ctx)) ** 2
                           + nb * nb))


def common_edge_sigma_px(ctx: FrameContext, volume: BodyVolume | None = None) -> float:
    """The sequence's measured edge-position error common to a body (px): the calibration's terms
    (background level, clipped background) without its fixed sub-pixel floor, which a volume
    replaces by the measured sub-pixel error of each edge (`edge_noise_total_px`).  Under a clipped
    background whose shape is seen (``ctx.blur.clip_light``), the clipped term is the body's own
    (`clip_level_px`, at its centroid) where that is larger than the sequence's: the level's excess
    over the clip (the rise of the backlight from the clip's edge to the nozzle, which no fit of the
    frame's corners can undo) stays the least of it.  On the synthetic clipped pendant drop (the
    backlight 8 % above the nozzle's level at the drop) the median |error| / u over 8 noise draws
    went from 1.12 to 0.92, every draw within 2 u."""
    total = float(ctx.blur.edge_position_sigma_px)
    floor = float(ctx.config.edge_position_floor_px)
    sq = total * total - floor * floor
    if volume is not None and ctx.blur.clip_light is not None:
        seq = float(ctx.blur.clip_term_px)
        sq += max(clip_level_px(volume, ctx), seq) ** 2 - seq * seq
    return math.sqrt(max(sq, 0.0))


def clip_level_px(volume: BodyVolume, ctx: FrameContext) -> float:
    """Edge-position error (px) of a body under a clipped background from the level used there: the
    backlight's relative offset at the body's centroid from the level read at the nozzle
    (`dropvision.calibrate.calibration_pass.ClipIllumination.relative_error`), moving the 50 % crossing by
    ``dB/B / slope`` with the edge's slope ``(1 - T_liquid) / (sqrt(2 pi) sigma)``
    (`dropvision.calibrate.calibration_pass.edge_position_terms_px`); 0 without a centroid."""
    geo, photo = ctx.geometry, ctx.photometry
    if not (np.isfinite(volume.centroid_row) and np.isfinite(volume.centroid_col)):
        return 0.0
    rel = ctx.blur.clip_light.relative_error(volume.centroid_row + geo.row0_px, volume.centroid_col + geo.col0_px)
    return edge_shift_px(rel, ctx.blur.correction_sigma_px, photo.liquid_level)


def edge_noise_total_px(ctx: FrameContext) -> float:
    """Independent error of one edge (px): the noise over the edge's slope (``ctx.blur.edge_noise_px``)
    and the sub-pixel interpolation's error at the calibrated blur
    (`dropvision.frame.volume.interpolation_error_px`), in quadrature."""
    return float(math.hypot(ctx.blur.edge_noise_px, interpolation_error_px(ctx.blur.correction_sigma_px)))


def sample_noise_t(ctx: FrameContext) -> float:
    """Standard deviation of one pixel's transmission as the edges see it: the frame's noise
    (``ctx.photometry.noise_transmission``), less where the frame is smoothed before its edges are placed (a Gaussian of
    ``ctx.photometry.smoothing_sigma_px`` divides white noise by ``2 sqrt(pi) sigma``)."""
    noise = float(ctx.photometry.noise_transmission)
    smooth = float(ctx.photometry.smoothing_sigma_px)
    if np.isfinite(smooth) and smooth > 0:
        noise /= max(2.0 * math.sqrt(math.pi) * smooth, 1.0)
    return noise


def _definition_px3(volume: BodyVolume, ctx: FrameContext) -> float:
    """The body's own band of edge levels (`dropvision.frame.volume.edge_definition_px`) as a
    volume (px^3): the part of `_common_px3` it adds in quadrature."""
    definition = edge_definition_px(volume, ctx.photometry.liquid_level, sample_noise_t(ctx))
    return volume_uncertainty_px3(volume, definition, ctx.geometry.tilt_rad, blur_fraction=0.0)


def _common_px3(volume: BodyVolume, ctx: FrameContext, closed: bool = True) -> float:
    """The edges' common error (px^3): the sequence's measured edge-position error
    (`common_edge_sigma_px`) and the body's own edge definition
    (`dropvision.frame.volume.edge_definition_px`), with the blur correction's model error and the
    slices' tilt factor (`dropvision.frame.volume.tilt_model_uncertainty_px3`)."""
    geo, photo = ctx.geometry, ctx.photometry
    definition = edge_definition_px(volume, photo.liquid_level, sample_noise_t(ctx))
    edges = volume_uncertainty_px3(volume, common_edge_sigma_px(ctx, volume), geo.tilt_rad, definition_px=definition)
    return float(math.hypot(edges, tilt_model_uncertainty_px3(volume, geo.tilt_rad, closed)))


def body_random_uncertainty_nl(volume: BodyVolume, ctx: FrameContext) -> float:
    """The part (nl) of `body_volume_uncertainty_nl` from the edges' own noise
    (`dropvision.frame.volume.random_volume_uncertainty_px3`): independent from frame to frame, the
    part a sequence's own scatter can show too narrow (`dropvision.analysis.sequence_summary.drop_scatter_ratio`)."""
    geo = ctx.geometry
    return float(random_volume_uncertainty_px3(volume, edge_noise_total_px(ctx), geo.tilt_rad)) * geo.nl_per_px3


def body_volume_uncertainty_nl(volume: BodyVolume, ctx: FrameContext, plane: bool = False) -> float:
    """Standard uncertainty (nl) of a body's volume: the sequence's common edge-position error
    (`dropvision.frame.volume.volume_uncertainty_px3`), the edges' own noise
    (`dropvision.frame.volume.random_volume_uncertainty_px3`) and, for liquid cut at the tip plane
    (``plane``), the plane's place (as uncertain as an edge) in quadrature."""
    geo = ctx.geometry
    parts = [_common_px3(volume, ctx, closed=not plane),
             random_volume_uncertainty_px3(volume, edge_noise_total_px(ctx), geo.tilt_rad)]
    if plane:
        parts.append(plane_cut_uncertainty_px3(volume, _plane_sigma_px(ctx), geo.tilt_rad))
    return float(math.sqrt(sum(p * p for p in parts))) * geo.nl_per_px3


def measure_body(roi: np.ndarray, ctx: FrameContext, seg: Segmentation, body: DarkBody,
                 gain: float) -> tuple[RowEdges, BodyVolume]:
    """Run edges and disc-integrated volume (px^3, blur corrected) of a detached body.

    Parameters
    ----------
    roi : ndarray
        Raw frame, region of interest.
    ctx : FrameContext
    seg : Segmentation
    body : DarkBody
    gain : float
        Frame illumination relative to the background model.

    Returns
    -------
    edges : RowEdges
    volume : BodyVolume
    """
    ed = body_edges(roi, ctx.photometry.inv_background, seg.labels, body.label, body.bbox,
                    ctx.photometry.threshold, gain)
    return ed, integrate(ed, ctx.geometry.tilt_rad, None, ctx.blur.correction_sigma_px)


def off_path_reason(main: DetachedBody, body: DetachedBody, through_tip: bool = True) -> str | None:
    """Why an in-focus body beside the jet's path is not a satellite of the main drop, or None.

    Satellites and tail pieces fly on the main drop's path: the line from the tip (x = 0 on the
    tip plane) through the main drop's centroid, or, when the nozzle is out of focus and its
    axis not trusted (``through_tip`` False), the line through the main drop along the axis's
    direction.  A body whose centre is further from that line
    than the main drop's half-width (at least 10 µm) at its height lies off the path the drop
    swept: a speck or dust on the optics that a single frame cannot tell from liquid by its look.
    """
    size = max(main.diameter_um, main.length_um, 20.0)
    if not (np.isfinite(main.z_um) and np.isfinite(body.z_um)):
        return None
    x_path = main.x_um * body.z_um / main.z_um if through_tip and main.z_um > size else main.x_um
    off = abs(body.x_um - x_path)
    if off > 0.5 * max(main.diameter_um, 20.0):
        line = "the line from the tip through the main drop" if through_tip else "the main drop's line"
        return (f"{off:.0f} um beside the jet's path ({line}), more than "
                f"the drop's half-width {0.5 * max(main.diameter_um, 20.0):.0f} um: a speck, not a satellite")
    return None


def describe_detached(ctx: FrameContext, seg: Segmentation, body: DarkBody, edges: RowEdges,
                      volume: BodyVolume) -> DetachedBody:
    """A detached body in physical units, with what makes it untrusted.

    Parameters
    ----------
    ctx : FrameContext
    seg : Segmentation
    body : DarkBody
    edges : RowEdges
    volume : BodyVolume
        From `measure_body`.

    Returns
    -------
    DetachedBody
        ``leaves``: touches the bottom of the frame or its side; ``out_of_band``: touches the side
        of the measured band inside the frame; ``on_dust``: opaque dust on its boundary (a speck
        wholly inside the silhouette changes no edge).
    """
    geo, photo = ctx.geometry, ctx.photometry
    hh, ww = seg.labels.shape
    b = body
    px = geo.pixel_size_um
    cos_t = math.cos(geo.tilt_rad)
    z, x = geo.to_axis_um(volume.centroid_row, volume.centroid_col)
    leaves = b.y1 >= hh or (b.x0 == 0 and geo.col0_px == 0) or (b.x1 >= ww and geo.col1_px >= geo.frame_width_px)
    out_band = (b.x0 == 0 and geo.col0_px > 0) or (b.x1 >= ww and geo.col1_px < geo.frame_width_px)
    on_dust = False
    if photo.opaque is not None:
        # an opaque speck inside the silhouette is filled over and changes no edge; one on its
        # boundary cuts a notch into it
        inside = (seg.labels[b.y0:b.y1, b.x0:b.x1] == b.label).astype(np.uint8)
        rim = inside > cv2.erode(inside, np.ones((3, 3), np.uint8), borderType=cv2.BORDER_CONSTANT, borderValue=0)
        on_dust = bool(photo.opaque[b.y0:b.y1, b.x0:b.x1][rim].any())
    return DetachedBody(
        top_chord_ratio=top_chord_ratio(edges, volume),
        volume_nl=volume.volume_px3 * geo.nl_per_px3, z_um=z, x_um=x,
        length_um=(volume.bottom_row - volume.top_row + 1) * px * cos_t,
        diameter_um=volume.max_chord_px * px * cos_t,
        top_row=volume.top_row, bottom_row=volume.bottom_row, leaves=bool(leaves), out_of_band=bool(out_band),
        on_dust=on_dust, bbox=b.bbox, area_px=int(b.area_px),
        row_px=volume.centroid_row + geo.row0_px, col_px=volume.centroid_col + geo.col0_px,
        volume_uncertainty_nl=float(np.hypot(body_volume_uncertainty_nl(volume, ctx),
                                             asymmetry_uncertainty_px3(edges) * geo.nl_per_px3)),
        random_uncertainty_nl=body_random_uncertainty_nl(volume, ctx),
        outline=body_outline(seg.labels, b.label, b.bbox, ctx.geometry.row0_px, ctx.geometry.col0_px),
    )
