"""What each dark body of a frame is, and why: the rules behind ``n_satellites`` and bodies.parquet.

A backlit frame shows more dark bodies than the liquid of this firing: out-of-focus mist
droplets and dust on the optics (soft, low contrast), bodies cut by the frame or the measured
band, liquid before the pinch-off that cannot be a drop of this firing.  Every body gets one
class, tried in this order (thresholds in `dropvision.config.MeasureConfig`):

1. ``attached``: the body touching the top of the region that spans the axis (nozzle and the
   liquid joined to it; its volume is the attached volume below the tip plane).
2. ``mist``: edge spread (`appearance`) above ``mist_blur_factor`` x the in-focus nozzle
   walls' + ``mist_blur_offset_px``: out of focus, so not in the plane of the jet (mist drifting
   in front of or behind it, dust on a window).  ``dust`` instead when an out-of-focus body sits
   at the same place (within 3 px) in at least half of the frames: static.
3. ``border``: touches the edge of the frame or of the measured band: cut, its volume unknown.
4. In a frame still attached (before the pinch-off): ``noise`` (a detached in-focus body before
   the drop separates is not liquid of this firing).
5. ``main_drop``: the largest remaining body; ``tail``: another body longer than
   ``compact_ratio`` equivalent-sphere diameters (a free ligament); ``satellite``: the others.
   A satellite touching the main drop (one silhouette with a short waist,
   `dropvision.volume.waist_row`) is split off it at the waist and listed as a counted
   satellite (a drop of its own, as a person counts it); its volume stays in the frame's
   ``drop_volume_nl`` (the main drop's silhouette: they coalesce in flight).

``counted`` is True for satellites and tails of a frame whose ``n_satellites`` is known (the
frame's main drop and its companions are trusted); ``n_satellites`` of the frames table is the
number of counted bodies.

The edge spread of a body is ``(1 - max(T_min, T_liquid)) / (sqrt(2 pi) g)``, with ``T_min`` its
darkest transmission (2nd percentile), ``T_liquid`` the liquid's interior level, and ``g`` the median gradient magnitude (px^-1) at its boundary pixels: the Gaussian
sigma of a step edge from ``T_min`` to 1, biased high by pixel sampling in the same way for the
nozzle walls (so only the ratio is used).  On synthetic frames in-focus drops, satellites and
the nozzle walls give 0.95-1.1x the walls' value at blur 0.8-1.8 px; bodies blurred by a further
3-8 px give 1.4x and more.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import cv2
import numpy as np

from dvcore import schema

if TYPE_CHECKING:  # pandas loads where a table is made, not at start-up
    import pandas as pd

__all__ = ["Appearance", "appearance", "nozzle_edge_spread_px", "out_of_focus_reason", "bodies_table",
           "BODY_COLUMNS"]

BODY_COLUMNS = schema.BODIES.column_names
_SQRT_2PI = math.sqrt(2.0 * math.pi)
_KERNEL3 = np.ones((3, 3), np.uint8)


@dataclass(frozen=True)
class Appearance:
    """How a body looks: darkest transmission and edge spread (px)."""

    min_transmission: float
    edge_blur_px: float


def appearance(roi: np.ndarray, inv_background: np.ndarray, labels: np.ndarray, label: int,
               bbox: tuple[int, int, int, int], gain: float, *, floor: float = 0.0, skip_top_rows: int = 0,
               pad: int = 3) -> Appearance:
    """Darkest transmission and edge spread of one labelled body.

    Parameters
    ----------
    roi : ndarray
        Raw frame, region of interest.
    inv_background : ndarray
        1 / background over the region.
    labels : ndarray
        Label image of the region (`dropvision.segmentation.Segmentation.labels`).
    label : int
        The body's label.
    bbox : (x0, y0, x1, y1)
        Its bounding box, half-open (region px).
    gain : float
        Frame illumination relative to the background model.
    floor : float
        The step's depth is taken to at most ``1 - floor`` (the liquid's interior level): dust
        or noise darker than the liquid inside a body does not make its edges look softer.
    skip_top_rows : int
        Boundary pixels in the region's first rows are left out (a body cut by the top of the
        region has no edge there).
    pad : int
        Pixels around the box used for the gradients.

    Returns
    -------
    Appearance
        ``edge_blur_px`` NaN when the body has no usable boundary.
    """
    x0, y0, x1, y1 = bbox
    h, w = labels.shape
    ya, yb, xa, xb = max(y0 - pad, 0), min(y1 + pad, h), max(x0 - pad, 0), min(x1 + pad, w)
    t = roi[ya:yb, xa:xb].astype(np.float32) * inv_background[ya:yb, xa:xb]
    if gain != 1.0:
        t /= np.float32(gain)
    inside = labels[ya:yb, xa:xb] == label
    if not inside.any():
        return Appearance(float("nan"), float("nan"))
    vals = t[inside]
    t_min = float(np.partition(vals, vals.size // 50)[vals.size // 50])  # 2nd percentile
    gx = cv2.Sobel(t, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(t, cv2.CV_32F, 0, 1, ksize=3)
    grad = cv2.magnitude(gx, gy) / 8.0
    boundary = inside & ~(cv2.erode(inside.astype(np.uint8), _KERNEL3, borderType=cv2.BORDER_REPLICATE) > 0)
    if skip_top_rows > ya:
        boundary[: skip_top_rows - ya] = False
    g = grad[boundary]
    if g.size < 3:
        return Appearance(t_min, float("nan"))
    g_med = float(np.partition(g, g.size // 2)[g.size // 2])  # median (upper for even sizes)
    depth = 1.0 - max(t_min, floor)
    spread = depth / (_SQRT_2PI * g_med) if g_med > 0 and depth > 0 else float("inf")
    return Appearance(t_min, spread)


def nozzle_edge_spread_px(roi: np.ndarray, inv_background: np.ndarray, labels: np.ndarray, body,
                          floor: float = 0.0) -> float:
    """Edge spread of the in-focus nozzle body (its walls and meniscus), the reference for mist."""
    return appearance(roi, inv_background, labels, body.label, (body.x0, body.y0, body.x1, body.y1), 1.0,
                      floor=floor, skip_top_rows=2).edge_blur_px


def out_of_focus_reason(app: Appearance, ref_px: float, factor: float, offset_px: float,
                        ref_name: str = "nozzle walls'") -> str | None:
    """Why a body is out of focus (its edge spread against the in-focus reference), or None.

    Parameters
    ----------
    app : Appearance
    ref_px : float
        Edge spread of the in-focus reference (`nozzle_edge_spread_px`, or the sharpest detached
        body when the nozzle is out of focus); NaN: never.
    factor, offset_px : float
        ``MeasureConfig.mist_blur_factor`` (``mist_blur_factor_bodies`` with a body reference)
        and ``mist_blur_offset_px``.
    ref_name : str
        Names the reference in the reason.
    """
    if not (np.isfinite(ref_px) and ref_px > 0):
        return None
    limit = factor * ref_px + offset_px
    if app.edge_blur_px > limit:
        return (f"edge spread {app.edge_blur_px:.2f} px > {factor:g} x {ref_name} {ref_px:.2f} px + "
                f"{offset_px:g} px: out of focus")
    return None


def bodies_table(records, frames: pd.DataFrame, *, edge_blur_ref_px: float, compact_ratio: float) -> pd.DataFrame:
    """bodies.parquet: every body of every measured frame with its class and the reason.

    Parameters
    ----------
    records : list of dropvision.frame.FrameRecord
        The measured frames, in the order of ``frames``.
    frames : DataFrame
        The frames table of the same records (``attached``, ``n_satellites``, ``drop_volume_nl``).
    edge_blur_ref_px : float
        The nozzle walls' edge spread (px).
    compact_ratio : float
        A body longer than this many equivalent-sphere diameters is a ``tail``.

    Returns
    -------
    DataFrame
        Columns `BODY_COLUMNS` (`dvcore.schema.BODIES`).
    """
    import pandas as pd

    from dropvision.bodies import DetachedClass, detached_class

    rows: list[dict] = []
    # static out-of-focus bodies (same place in >= half the frames) are dust, not mist
    soft = [(k, b) for k, r in enumerate(records) for b in r.rejected]
    static: set[tuple[int, int]] = set()
    if soft and len(records) >= 2:
        pos = np.array([(b.row_px, b.col_px) for _, b in soft])
        frame_of = np.array([k for k, _ in soft])
        for i in range(len(soft)):
            near = np.hypot(pos[:, 0] - pos[i, 0], pos[:, 1] - pos[i, 1]) <= 3.0
            if np.unique(frame_of[near]).size >= 0.5 * len(records):
                static.add((int(frame_of[i]), id(soft[i][1])))
    attached = frames["attached"].to_numpy(bool)
    nsat = frames["n_satellites"]
    for k, r in enumerate(records):
        base = {"file": r.file, "page": r.page, "delay_us": r.delay_us, "repeat": r.repeat}
        known = not pd.isna(nsat.iloc[k])
        n = 0
        if r.attached_body is not None:
            rows.append({**base, "body_id": n, "body_class": "attached", "counted": False,
                         "reason": "touches the top of the region and spans the axis: nozzle and attached liquid",
                         **r.attached_body, "volume_nl": r.attached_volume_nl})
            n += 1
        for j, b in enumerate(r.bodies):
            kind = detached_class(b, j, compact_ratio)
            cls, counted = "satellite", False
            if kind is DetachedClass.BORDER:
                cls, why = "border", "touches the edge of the frame or of the measured band: cut"
            elif attached[k]:
                cls, why = "noise", "detached body in a frame before the pinch-off: not liquid of this firing"
            elif kind is DetachedClass.MAIN_DROP:
                cls, why = "main_drop", "largest in-focus detached body"
            elif kind is DetachedClass.TOUCHING:
                why = b.reason + ": a drop of its own, counted; its volume stays in the main drop's"
                counted = known
            elif kind is DetachedClass.TAIL:
                cls, why = "tail", f"in focus, detached, longer than {compact_ratio:g} equivalent diameters"
                counted = known
            else:
                why = "in focus, detached, smaller than the main drop"
                counted = known
            rows.append({**base, "body_id": n, "body_class": cls, "reason": why, "counted": counted,
                         **_body_values(b, edge_blur_ref_px)})
            n += 1
        for b in r.rejected:
            cls = "dust" if (k, id(b)) in static else ("noise" if b.off_path else "mist")
            why = b.reason + ("; static over the frames: dust" if cls == "dust" else "")
            rows.append({**base, "body_id": n, "body_class": cls, "reason": why, "counted": False,
                         **_body_values(b, edge_blur_ref_px)})
            n += 1
    df = pd.DataFrame(rows, columns=list(BODY_COLUMNS))
    df["page"] = pd.array(df["page"], dtype="Int64")
    df["body_id"] = df["body_id"].astype(int)
    df["area_px"] = df["area_px"].astype(int)
    df["counted"] = df["counted"].astype(bool)
    for c in ("delay_us", "volume_nl", "row_px", "col_px", "z_um", "x_um", "min_transmission", "edge_blur_px"):
        df[c] = df[c].astype(float)
    df["edge_blur_ref_px"] = float(edge_blur_ref_px)
    df["repeat"] = df["repeat"].astype(int)
    return df


def _body_values(b, ref: float) -> dict:
    return {"area_px": b.area_px, "volume_nl": b.volume_nl, "row_px": b.row_px, "col_px": b.col_px,
            "z_um": b.z_um, "x_um": b.x_um, "min_transmission": b.min_transmission,
            "edge_blur_px": b.edge_blur_px, "edge_blur_ref_px": ref}
