"""The dark bodies of a frame as liquid: attached liquid (nozzle body) and detached bodies.

- `find_nozzle_body` (`dropvision.segmentation`): the largest body touching the top of the region that
  spans the axis;
- `measure_attached`: its run edges cut at the tip plane, its volume below the tip plane, its
  bottom and its neck;
- `measure_body` / `describe_detached`: a detached body's volume, position on the axis, size,
  and whether it can be trusted (leaves the field of view or the measured band, overlaps dust);
- `class_image`: the per-pixel segmentation classes (`dropvision.segmentation.CLASS_*`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from dropvision.context import FrameContext
from dropvision.segmentation import (
    CLASS_ATTACHED,
    CLASS_BORDER,
    CLASS_DROP,
    CLASS_NOZZLE,
    CLASS_OUT_OF_FOCUS,
    CLASS_SATELLITE,
    CLASS_SPECK,
    CLASS_TAIL,
    CLASS_TOUCHING,
    DarkBody,
    Segmentation,
    find_nozzle_body,
)
from dropvision.edges import RowEdges, body_edges
from dropvision.nozzle import Protrusion, protruding_columns
from dropvision.outline import body_outline
from dropvision.volume import (
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
    volume_uncertainty_nl: float = float("nan")  # standard uncertainty (`volume.volume_uncertainty_px3`)
    off_path: bool = False  # beside the jet's path (`off_path_reason`): a speck, not liquid of this firing
    #: outer boundary, (row, col) pixel centres of the canonical frame (`dropvision.outline.body_outline`)
    outline: np.ndarray | None = field(default=None, repr=False, compare=False)

    def elongated(self, compact_ratio: float) -> bool:
        """Longer than ``compact_ratio`` equivalent-sphere diameters (a tail, a ligament)."""
        return self.length_um > compact_ratio * equivalent_diameter_um(self.volume_nl)


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
        of the first and none of the second.
    """

    volume_nl: float
    bottom_row: float
    neck_px: float
    leaves: bool
    edges: RowEdges
    volume_uncertainty_nl: float = float("nan")
    common_uncertainty_nl: float = float("nan")
    plane_uncertainty_nl: float = float("nan")


def out_of_focus_nozzle_px3(volume: BodyVolume, nozzle_blur_px: float) -> float:
    """Standard uncertainty (px^3) of attached liquid next to an out-of-focus nozzle.

    The walls' halo reaches ``3 sigma`` below the tip plane: the liquid's edges there are placed
    only to about half the walls' blur ``sigma``, over a band as wide as the top chord ``c``:
    ``pi c (3 sigma) (sigma / 2)``.  The halo is the static holder's and the liquid there fills the
    orifice in every frame: the error is the same from frame to frame, like the tip plane's
    (`measure_attached` counts it with the plane, which a grown volume cancels; on the synthetic
    out-of-focus holder the grown volume's median |error| / u went from 0.008 to 0.33 with it,
    every frame still within 2 u).
    """
    if not (np.isfinite(nozzle_blur_px) and nozzle_blur_px > 0):
        return 0.0
    return float(math.pi * volume.top_chord_px * 3.0 * nozzle_blur_px * 0.5 * nozzle_blur_px)


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
    # the background beside the liquid is read below the nozzle's halo (3 blur sigmas under its tip)
    halo_px = 3.0 * max(ctx.sigma_px if np.isfinite(ctx.sigma_px) else 0.0, 0.5)
    ed = body_edges(roi, ctx.inv_background, seg.labels, body.label, (body.x0, body.y0, body.x1, body.y1),
                    ctx.threshold, gain, row_min=max(0, int(math.floor(ctx.tip_roi)) - 1),
                    bright_row_min=int(math.ceil(ctx.tip_roi + halo_px)) if np.isfinite(ctx.tip_roi) else 0)
    # an out-of-focus holder: only what hangs below its face is liquid
    if np.isfinite(getattr(ctx, "face_a", float("nan"))):
        found = hanging_columns(roi, ctx, seg, body, gain)
        if found is None:
            return nothing_hangs(ed, 0.0)
        keep = (ed.right_px >= found.first - 0.5) & (ed.left_px <= found.last + 0.5)
        ed = RowEdges(ed.row[keep], np.maximum(ed.left_px[keep], found.first - 0.5),
                      np.minimum(ed.right_px[keep], found.last + 0.5), ed.touches)
        ed = edges_in_the_halo(roi, ctx, ed, found, gain)
        if not found.liquid:  # the face's blurred halo: no liquid, but as much could hide in it
            return nothing_hangs(ed, integrate(ed, ctx.tilt_rad, ctx.tip_roi, 0.0).volume_px3 * ctx.nl_per_px3)
    span = plane_span_chord_px(ed, ctx.tip_roi, ctx.axis_roi, ctx.tilt_rad)
    clip_to_tip_plane(ed, ctx.tip_roi, ctx.axis_roi, ctx.tilt_rad)
    bv = replace(integrate(ed, ctx.tilt_rad, ctx.tip_roi, ctx.sigma_px), plane_span_px=span)
    near = out_of_focus_nozzle_px3(bv, ctx.nozzle_blur_px) * ctx.nl_per_px3
    return AttachedLiquid(volume_nl=bv.volume_px3 * ctx.nl_per_px3, bottom_row=bv.bottom_row,
                          neck_px=neck_chord_px(ed, ctx.tip_roi), leaves=body.y1 >= roi.shape[0], edges=ed,
                          volume_uncertainty_nl=float(np.hypot(body_volume_uncertainty_nl(bv, ctx, plane=True), near)),
                          common_uncertainty_nl=_common_px3(bv, ctx, closed=False) * ctx.nl_per_px3,
                          plane_uncertainty_nl=float(np.hypot(plane_cut_uncertainty_px3(bv, _plane_sigma_px(ctx),
                                                                                         ctx.tilt_rad) * ctx.nl_per_px3,
                                                              near)))


def hanging_columns(roi: np.ndarray, ctx: FrameContext, seg: Segmentation, body: DarkBody,
                    gain: float) -> Protrusion | None:
    """What reaches below an out-of-focus holder's face (``ctx.face_a``, ``ctx.face_b``) at the axis, and
    whether it is liquid (`dropvision.nozzle.protruding_columns`; columns in region px), or None."""
    limit = ctx.mist_blur_factor * ctx.edge_blur_ref_px + ctx.mist_blur_offset_px
    x0, x1 = body.x0, body.x1
    y1 = min(roi.shape[0], body.y1 + int(math.ceil(3.0 * limit)) + 2)
    mask = seg.labels[:body.y1, x0:x1] == body.label
    t = roi[:y1, x0:x1].astype(np.float32) * ctx.inv_background[:y1, x0:x1]
    if gain != 1.0:
        t /= np.float32(gain)
    face = ctx.face_a + ctx.face_b * (np.arange(x0, x1) + ctx.c0) - ctx.r0
    found = protruding_columns(mask, t, face, ctx.axis_roi - x0, 0.5 * (ctx.threshold + ctx.liquid_level), limit,
                               judge_focus=not ctx.face_liquid_seen)
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
    blur = ctx.nozzle_blur_px if np.isfinite(ctx.nozzle_blur_px) and ctx.nozzle_blur_px > 0 else 0.0
    y_end = min(roi.shape[0], int(math.ceil(ctx.tip_roi + 3.0 * blur)) + 1)
    y_start = max(0, int(math.floor(ctx.tip_roi)))
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
        t = roi[y].astype(np.float32) * ctx.inv_background[y] / np.float32(gain)
        thr = 0.5 * float(np.median(t[side])) * (1.0 + ctx.liquid_level)
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
                          plane_uncertainty_nl=float(hidden_nl))


#: The tip plane is the median of the wall annulus's 50 % crossings, at least two columns a side
#: (`dropvision.nozzle.find_tip`): of at least 4 edges' independent errors the median keeps at most
#: ``sqrt(pi / 2) / sqrt(4)`` of one edge's.
TIP_MEDIAN_FACTOR = math.sqrt(math.pi / 2.0) / 2.0


def _plane_sigma_px(ctx: FrameContext) -> float:
    """How well the tip plane is placed (px): as an edge, the common error (`common_edge_sigma_px`)
    and the median of its crossings' own errors (`TIP_MEDIAN_FACTOR` x `edge_noise_total_px`), or
    to the walls' blur when they are out of focus."""
    nb = ctx.nozzle_blur_px if np.isfinite(ctx.nozzle_blur_px) else 0.0
    return float(math.sqrt(common_edge_sigma_px(ctx) ** 2 + (TIP_MEDIAN_FACTOR * edge_noise_total_px(ctx)) ** 2
                           + nb * nb))


def common_edge_sigma_px(ctx: FrameContext, volume: BodyVolume | None = None) -> float:
    """The sequence's measured edge-position error common to a body (px): the calibration's terms
    (background level, clipped background) without its fixed sub-pixel floor, which a volume
    replaces by the measured sub-pixel error of each edge (`edge_noise_total_px`).  Under a clipped
    background whose shape is seen (``ctx.clip_light``), the clipped term is the body's own
    (`clip_level_px`, at its centroid) where that is larger than the sequence's: the level's excess
    over the clip (the rise of the backlight from the clip's edge to the nozzle, which no fit of the
    frame's corners can undo) stays the least of it.  On the synthetic clipped pendant drop (the
    backlight 8 % above the nozzle's level at the drop) the median |error| / u over 8 noise draws
    went from 1.12 to 0.92, every draw within 2 u."""
    total = float(ctx.edge_position_sigma_px)
    floor = float(getattr(ctx, "edge_floor_px", 0.0))
    sq = total * total - floor * floor
    if volume is not None and getattr(ctx, "clip_light", None) is not None:
        seq = float(ctx.clip_term_px)
        sq += max(clip_level_px(volume, ctx), seq) ** 2 - seq * seq
    return math.sqrt(max(sq, 0.0))


def clip_level_px(volume: BodyVolume, ctx: FrameContext) -> float:
    """Edge-position error (px) of a body under a clipped background from the level used there: the
    backlight's relative offset at the body's centroid from the level read at the nozzle
    (`dropvision.calibration_pass.ClipIllumination.relative_error`), moving the 50 % crossing by
    ``dB/B / slope`` with the edge's slope ``(1 - T_liquid) / (sqrt(2 pi) sigma)``
    (`dropvision.calibration_pass.edge_position_terms_px`); 0 without a centroid."""
    if not (np.isfinite(volume.centroid_row) and np.isfinite(volume.centroid_col)):
        return 0.0
    rel = ctx.clip_light.relative_error(volume.centroid_row + ctx.r0, volume.centroid_col + ctx.c0)
    sig = max(float(ctx.sigma_px), 0.5) if np.isfinite(ctx.sigma_px) else 1.0
    depth = max(1.0 - float(ctx.liquid_level), 0.05)
    return float(rel * math.sqrt(2.0 * math.pi) * sig / depth)


def edge_noise_total_px(ctx: FrameContext) -> float:
    """Independent error of one edge (px): the noise over the edge's slope (``ctx.edge_noise_px``)
    and the sub-pixel interpolation's error at the calibrated blur
    (`dropvision.volume.interpolation_error_px`), in quadrature."""
    return float(math.hypot(ctx.edge_noise_px, interpolation_error_px(ctx.sigma_px)))


def sample_noise_t(ctx: FrameContext) -> float:
    """Standard deviation of one pixel's transmission as the edges see it: the frame's noise
    (``ctx.noise_t``), less where the frame is smoothed before its edges are placed (a Gaussian of
    ``ctx.smooth_px`` divides white noise by ``2 sqrt(pi) smooth_px``)."""
    noise = float(getattr(ctx, "noise_t", 0.0))
    smooth = float(getattr(ctx, "smooth_px", 0.0))
    if np.isfinite(smooth) and smooth > 0:
        noise /= max(2.0 * math.sqrt(math.pi) * smooth, 1.0)
    return noise


def _common_px3(volume: BodyVolume, ctx: FrameContext, closed: bool = True) -> float:
    """The edges' common error (px^3): the sequence's measured edge-position error
    (`common_edge_sigma_px`) and the body's own edge definition
    (`dropvision.volume.edge_definition_px`), with the blur correction's model error and the
    slices' tilt factor (`dropvision.volume.tilt_model_uncertainty_px3`)."""
    definition = edge_definition_px(volume, getattr(ctx, "liquid_level", float("nan")), sample_noise_t(ctx))
    edges = volume_uncertainty_px3(volume, common_edge_sigma_px(ctx, volume), ctx.tilt_rad, definition_px=definition)
    return float(math.hypot(edges, tilt_model_uncertainty_px3(volume, ctx.tilt_rad, closed)))


def body_volume_uncertainty_nl(volume: BodyVolume, ctx: FrameContext, plane: bool = False) -> float:
    """Standard uncertainty (nl) of a body's volume: the sequence's common edge-position error
    (`dropvision.volume.volume_uncertainty_px3`), the edges' own noise
    (`dropvision.volume.random_volume_uncertainty_px3`) and, for liquid cut at the tip plane
    (``plane``), the plane's place (as uncertain as an edge) in quadrature."""
    parts = [_common_px3(volume, ctx, closed=not plane), random_volume_uncertainty_px3(volume, edge_noise_total_px(ctx), ctx.tilt_rad)]
    if plane:
        parts.append(plane_cut_uncertainty_px3(volume, _plane_sigma_px(ctx), ctx.tilt_rad))
    return float(math.sqrt(sum(p * p for p in parts))) * ctx.nl_per_px3


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
    ed = body_edges(roi, ctx.inv_background, seg.labels, body.label, (body.x0, body.y0, body.x1, body.y1),
                    ctx.threshold, gain)
    return ed, integrate(ed, ctx.tilt_rad, None, ctx.sigma_px)


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
    hh, ww = seg.labels.shape
    b = body
    px = ctx.pixel_size_um
    cos_t = math.cos(ctx.tilt_rad)
    z, x = ctx.to_axis_um(volume.centroid_row, volume.centroid_col)
    leaves = b.y1 >= hh or (b.x0 == 0 and ctx.c0 == 0) or (b.x1 >= ww and ctx.c1 >= ctx.width)
    out_band = (b.x0 == 0 and ctx.c0 > 0) or (b.x1 >= ww and ctx.c1 < ctx.width)
    on_dust = False
    if ctx.opaque is not None:
        # an opaque speck inside the silhouette is filled over and changes no edge; one on its
        # boundary cuts a notch into it
        inside = (seg.labels[b.y0:b.y1, b.x0:b.x1] == b.label).astype(np.uint8)
        rim = inside > cv2.erode(inside, np.ones((3, 3), np.uint8), borderType=cv2.BORDER_CONSTANT, borderValue=0)
        on_dust = bool(ctx.opaque[b.y0:b.y1, b.x0:b.x1][rim].any())
    return DetachedBody(
        top_chord_ratio=top_chord_ratio(edges, volume),
        volume_nl=volume.volume_px3 * ctx.nl_per_px3, z_um=z, x_um=x,
        length_um=(volume.bottom_row - volume.top_row + 1) * px * cos_t,
        diameter_um=volume.max_chord_px * px * cos_t,
        top_row=volume.top_row, bottom_row=volume.bottom_row, leaves=bool(leaves), out_of_band=bool(out_band),
        on_dust=on_dust, bbox=(b.x0, b.y0, b.x1, b.y1), area_px=int(b.area_px),
        row_px=volume.centroid_row + ctx.r0, col_px=volume.centroid_col + ctx.c0,
        volume_uncertainty_nl=body_volume_uncertainty_nl(volume, ctx),
        outline=body_outline(seg.labels, b.label, (b.x0, b.y0, b.x1, b.y1), ctx.r0, ctx.c0),
    )


def class_image(seg: Segmentation, nozzle_body: DarkBody | None, bodies: Sequence[DetachedBody] = (),
                rejected: Sequence[DetachedBody] = (), opaque: np.ndarray | None = None, *,
                compact_ratio: float = 2.0) -> tuple[np.ndarray, list[dict]]:
    """Per-pixel segmentation classes and per-body boxes of one frame (for the Rerun viewer).

    The classes follow the rules of bodies.parquet (`dropvision.classify`) as far as one frame
    can tell (`dropvision.segmentation` says what each ``CLASS_*`` is).

    Parameters
    ----------
    seg : Segmentation
    nozzle_body : DarkBody or None
        The body holding the attached liquid (`CLASS_ATTACHED`; other top bodies `CLASS_NOZZLE`).
    bodies : sequence of DetachedBody
        The frame's in-focus detached bodies, largest first (`FrameRecord.bodies`), matched to
        the segmentation by their ``bbox``: cut by the frame or band (``leaves`` /
        ``out_of_band``) `CLASS_BORDER`; the first `CLASS_DROP`; one with ``touching`` (split
        off the main drop at a waist, same silhouette) `CLASS_TOUCHING` on its side of the
        main drop's rows; longer than ``compact_ratio`` equivalent-sphere diameters `CLASS_TAIL`;
        the others `CLASS_SATELLITE`.
    rejected : sequence of DetachedBody
        The out-of-focus bodies (`FrameRecord.rejected`): `CLASS_OUT_OF_FOCUS`.
    opaque : ndarray of bool, optional
        Static specks (`CLASS_SPECK` where no body is).
    compact_ratio : float
        ``MeasureConfig.compact_ratio``.

    Returns
    -------
    labels : ndarray of uint8
        Class id per region pixel.  A detached body in neither list (joined to the attached
        liquid by a thread thinner than the blur) is `CLASS_ATTACHED`.
    boxes : list of dict
        ``{"bbox": (x0, y0, x1, y1), "class_id": int}`` per body (region coordinates, px,
        half-open), with ``"volume_nl"`` for detached bodies; a split silhouette gives one box
        per part, each around its own pixels.
    """
    parts: dict[tuple[int, int, int, int], list[tuple[DetachedBody, int]]] = {}
    for j, d in enumerate(bodies):
        if d.leaves or d.out_of_band:
            cls = CLASS_BORDER
        elif j == 0:
            cls = CLASS_DROP
        elif d.touching:
            cls = CLASS_TOUCHING
        elif d.elongated(compact_ratio):
            cls = CLASS_TAIL
        else:
            cls = CLASS_SATELLITE
        parts.setdefault(tuple(int(v) for v in d.bbox), []).append((d, cls))
    for d in rejected:
        parts.setdefault(tuple(int(v) for v in d.bbox), []).append((d, CLASS_OUT_OF_FOCUS))
    classes = np.zeros(len(seg.bodies) + 1, np.uint8)
    for b in seg.bodies:
        found = parts.get((b.x0, b.y0, b.x1, b.y1))
        if b.nozzle:
            classes[b.label] = CLASS_ATTACHED if b is nozzle_body else CLASS_NOZZLE
        elif found:
            whole = [cls for d, cls in found if not d.touching]
            classes[b.label] = whole[0] if whole else found[0][1]
        else:
            classes[b.label] = CLASS_ATTACHED
    labels = classes[seg.labels]
    boxes = []
    for b in seg.bodies:
        bbox = (b.x0, b.y0, b.x1, b.y1)
        found = parts.get(bbox) if not b.nozzle else None
        if not found:
            boxes.append({"bbox": bbox, "class_id": int(classes[b.label])})
            continue
        if len(found) == 1:
            d, cls = found[0]
            boxes.append({"bbox": bbox, "class_id": int(cls), "volume_nl": float(d.volume_nl)})
            continue
        # one silhouette, several parts (a satellite touching the main drop, split at the waist)
        mine = seg.labels[b.y0:b.y1, b.x0:b.x1] == b.label
        sub = labels[b.y0:b.y1, b.x0:b.x1]
        rows = np.arange(b.y0, b.y1)[:, None]
        whole = next((d for d, _ in found if not d.touching), None)
        for d, cls in found:
            if d is whole or whole is None:
                continue
            side = rows > whole.bottom_row if d.bottom_row > whole.bottom_row else rows < whole.top_row
            sub[mine & side] = cls
        for d, cls in found:
            rr, cc = np.nonzero(mine & (sub == cls))
            box = bbox if rr.size == 0 else (b.x0 + int(cc.min()), b.y0 + int(rr.min()),
                                              b.x0 + int(cc.max()) + 1, b.y0 + int(rr.max()) + 1)
            boxes.append({"bbox": box, "class_id": int(cls), "volume_nl": float(d.volume_nl)})
    if opaque is not None:
        labels[opaque & (labels == 0)] = CLASS_SPECK
    return labels, boxes

