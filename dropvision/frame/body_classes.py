"""How a dark body looks, and whether it is out of focus: the appearance estimator behind the mist
and dust classes of bodies.parquet (the class rules and the table: `dropvision.output.bodies_table`).

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

import cv2
import numpy as np

__all__ = ["Appearance", "appearance", "nozzle_edge_spread_px", "out_of_focus_reason"]

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
        Label image of the region (`dropvision.frame.segmentation.Segmentation.labels`).
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
    return appearance(roi, inv_background, labels, body.label, body.bbox, 1.0,
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
