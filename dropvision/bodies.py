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
from dataclasses import dataclass

import cv2
import numpy as np

from dropvision.context import FrameContext
from dropvision.segmentation import (
    CLASS_ATTACHED,
    CLASS_DROP,
    CLASS_NOZZLE,
    CLASS_SATELLITE,
    CLASS_SPECK,
    Body,
    Segmentation,
    find_nozzle_body,
)
from dropvision.volume import (
    BodyVolume,
    RowEdges,
    body_edges,
    clip_to_tip_plane,
    integrate,
    neck_chord_px,
    top_chord_ratio,
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
    touching: bool = False  # split off the main drop at a waist: not a separate silhouette


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
    """

    volume_nl: float
    bottom_row: float
    neck_px: float
    leaves: bool
    edges: RowEdges


def measure_attached(roi: np.ndarray, ctx: FrameContext, seg: Segmentation, body: Body, gain: float) -> AttachedLiquid:
    """Edges, volume below the tip plane, bottom and neck of the liquid joined to the nozzle.

    Parameters
    ----------
    roi : ndarray
        Raw frame, region of interest.
    ctx : FrameContext
    seg : Segmentation
    body : Body
        The nozzle body (`find_nozzle_body`).
    gain : float
        Frame illumination relative to the background model.

    Returns
    -------
    AttachedLiquid
    """
    ed = body_edges(roi, ctx.inv_background, seg.labels, body.label, (body.x0, body.y0, body.x1, body.y1),
                    ctx.threshold, gain, row_min=max(0, int(math.floor(ctx.tip_roi)) - 1))
    clip_to_tip_plane(ed, ctx.tip_roi, ctx.axis_roi, ctx.tilt_rad)
    bv = integrate(ed, ctx.tilt_rad, ctx.tip_roi, ctx.sigma_px)
    return AttachedLiquid(volume_nl=bv.volume_px3 * ctx.nl_per_px3, bottom_row=bv.bottom_row,
                          neck_px=neck_chord_px(ed, ctx.tip_roi), leaves=body.y1 >= roi.shape[0], edges=ed)


def measure_body(roi: np.ndarray, ctx: FrameContext, seg: Segmentation, body: Body,
                 gain: float) -> tuple[RowEdges, BodyVolume]:
    """Run edges and disc-integrated volume (px^3, blur corrected) of a detached body.

    Parameters
    ----------
    roi : ndarray
        Raw frame, region of interest.
    ctx : FrameContext
    seg : Segmentation
    body : Body
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


def describe_detached(ctx: FrameContext, seg: Segmentation, body: Body, edges: RowEdges,
                      volume: BodyVolume) -> DetachedBody:
    """A detached body in physical units, with what makes it untrusted.

    Parameters
    ----------
    ctx : FrameContext
    seg : Segmentation
    body : Body
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
    )


def class_image(seg: Segmentation, nozzle_body: Body | None, main_bbox: tuple[int, int, int, int] | None,
                opaque: np.ndarray | None) -> tuple[np.ndarray, list[dict]]:
    """Per-pixel segmentation classes and per-body boxes of one frame (for the Rerun viewer).

    Parameters
    ----------
    seg : Segmentation
    nozzle_body : Body or None
        The body holding the attached liquid (`CLASS_ATTACHED`; other top bodies `CLASS_NOZZLE`).
    main_bbox : tuple or None
        Bounding box of the main drop (`CLASS_DROP`; other detached bodies `CLASS_SATELLITE`).
    opaque : ndarray of bool, optional
        Static specks (`CLASS_SPECK` where no body is).

    Returns
    -------
    labels : ndarray of uint8
        Class id per region pixel.
    boxes : list of dict
        ``{"bbox": (x0, y0, x1, y1), "class_id": int}`` per body (region coordinates, px).
    """
    classes = np.zeros(len(seg.bodies) + 1, np.uint8)
    boxes = []
    for b in seg.bodies:
        if b.nozzle:
            cls = CLASS_ATTACHED if b is nozzle_body else CLASS_NOZZLE
        else:
            cls = CLASS_DROP if (b.x0, b.y0, b.x1, b.y1) == main_bbox else CLASS_SATELLITE
        classes[b.label] = cls
        boxes.append({"bbox": (b.x0, b.y0, b.x1, b.y1), "class_id": int(cls)})
    labels = classes[seg.labels]
    if opaque is not None:
        labels[opaque & (labels == 0)] = CLASS_SPECK
    return labels, boxes
