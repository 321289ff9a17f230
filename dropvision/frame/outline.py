"""Body outlines: the boundary of each measured body, in the canonical frame and in the camera's.

`body_outline` traces a body's silhouette (the labelled dark mask of `dropvision.frame.segmentation`) into
an (N, 2) array of (row, col) pixel centres of its outer boundary, in the full canonical frame
(nozzle at the top). `to_camera` / `from_camera` map such points between the canonical frame and
the frame as the camera stored it (`dropvision.io.orientation`: quarter turns only, so the round trip is
exact). `mask_centroid` is the centroid of a silhouette (the attached body's position).
"""

from __future__ import annotations

import cv2
import numpy as np

from dropvision.io.orientation import canonical_to_original, original_to_canonical, swaps_axes

#: an outline with no point (a body without a silhouette)
EMPTY = np.zeros((0, 2), np.float32)


def _mask(labels: np.ndarray, label: int, bbox) -> np.ndarray:
    x0, y0, x1, y1 = (int(v) for v in bbox)
    return np.ascontiguousarray(labels[y0:y1, x0:x1] == label).astype(np.uint8)


def body_outline(labels: np.ndarray, label: int, bbox, r0: int = 0, c0: int = 0) -> np.ndarray:
    """Outer boundary of body ``label`` of a labelled region, as (row, col) pixel centres of the
    full canonical frame (float32, (N, 2), closed implicitly: the last point joins the first).

    ``bbox`` is the body's half-open ``(x0, y0, x1, y1)`` in region coordinates; ``(r0, c0)`` the
    region's top-left corner in the frame. The longest outer contour when the silhouette has
    several pieces (it has one by construction)."""
    m = _mask(labels, label, bbox)
    if not m.any():
        return EMPTY.copy()
    contours, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    c = max(contours, key=len)[:, 0, :].astype(np.float32)  # (x, y) within the box
    x0, y0 = int(bbox[0]), int(bbox[1])
    return np.column_stack([c[:, 1] + (y0 + r0), c[:, 0] + (x0 + c0)]).astype(np.float32)


def mask_centroid(labels: np.ndarray, label: int, bbox, r0: int = 0, c0: int = 0) -> tuple[float, float]:
    """(row, col) centroid of body ``label``'s pixels in the full canonical frame (NaN when empty)."""
    m = _mask(labels, label, bbox)
    rows, cols = np.nonzero(m)
    if rows.size == 0:
        return float("nan"), float("nan")
    return float(rows.mean() + int(bbox[1]) + r0), float(cols.mean() + int(bbox[0]) + c0)


def camera_shape(canonical_shape, orientation: str) -> tuple[int, int]:
    """(rows, cols) of the stored (camera) frame of a canonical frame of ``canonical_shape``."""
    h, w = int(canonical_shape[0]), int(canonical_shape[1])
    return (w, h) if swaps_axes(orientation) else (h, w)


def to_camera(points, orientation: str, canonical_shape) -> np.ndarray:
    """(row, col) points of the canonical frame -> the same points in the frame as stored."""
    p = np.asarray(points, np.float64).reshape(-1, 2)
    r, c = canonical_to_original(p[:, 0], p[:, 1], orientation, canonical_shape)
    return np.column_stack([r, c]).astype(np.float32 if np.asarray(points).dtype == np.float32 else np.float64)


def from_camera(points, orientation: str, camera_shape_) -> np.ndarray:
    """Inverse of `to_camera`, given the STORED frame's shape."""
    p = np.asarray(points, np.float64).reshape(-1, 2)
    r, c = original_to_canonical(p[:, 0], p[:, 1], orientation, camera_shape_)
    return np.column_stack([r, c]).astype(np.float32 if np.asarray(points).dtype == np.float32 else np.float64)


def clip_rows(outline: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """The part of a closed outline between rows ``lo`` and ``hi`` (inclusive), as one run of points:
    the outline of one lobe of a silhouette split at a waist row (its closing segment is the cut)."""
    if outline is None or not len(outline):
        return outline
    keep = (outline[:, 0] >= lo) & (outline[:, 0] <= hi)
    if keep.all() or not keep.any():
        return outline[keep]
    start = int(np.argmin(keep))  # a point outside the band: the kept points are then one run
    rolled, kept = np.roll(outline, -start, axis=0), np.roll(keep, -start)
    return rolled[kept]
