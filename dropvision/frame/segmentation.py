"""Segmentation of backlit strobe frames into dark bodies.

A frame is compared with its illumination (background) estimate: a pixel is *dark* when its
transmission ``T = I / B`` is below the edge level (`dropvision.frame.edges.edge_threshold`, half-way
between the background and the liquid's interior level).  The comparison is done on the raw
integers against a precomputed integer threshold image, ``I < ceil(thr * B)``, which is
exactly ``T < thr`` and costs one ``cv2`` call.  Each dark body is then taken with its enclosed
bright lens spot filled (outer contours drawn filled), and labelled; bodies touching the top of
the region of interest are the nozzle (with any liquid still joined to it), the others are
detached liquid.
Static specks (opaque dust found during calibration) are removed from the dark mask before
labelling, so they can never become liquid.

`CLASS_*` are the class ids of the segmentation image shown by the Rerun viewer
(`dropvision.app.rerun_log.class_image` assigns them per frame, `dropvision.app.rerun_log` colours and
names them).  They follow the body classes of bodies.parquet (`dropvision.output.bodies_table`) as far as
one frame can tell: ``mist`` and ``dust`` are both `CLASS_OUT_OF_FOCUS` (dust is decided over
the sequence: an out-of-focus body at the same place in half the frames), and ``noise`` (a
detached body before the pinch-off, also a sequence-level decision) is drawn as the detached
class it would otherwise have.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

# --- segmentation classes (ids of the per-pixel class image handed to the Rerun logger) -------
CLASS_BACKGROUND = 0
CLASS_NOZZLE = 1
CLASS_ATTACHED = 2
CLASS_DROP = 3
CLASS_SATELLITE = 4
CLASS_SPECK = 5  # static opaque speck found during calibration (never a body)
CLASS_OUT_OF_FOCUS = 6  # out-of-focus detached body: mist, or dust when static over the sequence
CLASS_TOUCHING = 7  # satellite touching the main drop, split off it at the waist (not counted)
CLASS_TAIL = 8  # detached body longer than ``compact_ratio`` equivalent diameters (a free ligament)
CLASS_BORDER = 9  # detached body cut by the edge of the frame or of the measured band


@dataclass(frozen=True)
class DarkBody:
    """One dark body in region-of-interest coordinates.

    Attributes
    ----------
    label : int
        Value of this body in `Segmentation.labels`.
    x0, y0, x1, y1 : int
        Bounding box, half-open (``labels[y0:y1, x0:x1]``).
    area_px : int
        Number of pixels (lens spot filled).
    nozzle : bool
        Touches the top of the region of interest (nozzle and attached liquid).
    """

    label: int
    x0: int
    y0: int
    x1: int
    y1: int
    area_px: int
    nozzle: bool

    @property
    def bbox(self) -> tuple[int, int, int, int]:
        """``(x0, y0, x1, y1)``: the bounding box as the stages take it (half-open, region px)."""
        return (self.x0, self.y0, self.x1, self.y1)


@dataclass
class Segmentation:
    """Result of `segment`: filled label image of the region of interest and its bodies."""

    labels: np.ndarray  # uint16, 0 = background
    bodies: list[DarkBody]


def threshold_image(background: np.ndarray, threshold: float, dtype) -> np.ndarray:
    """Integer image ``ceil(threshold * background)`` so that ``I < it`` <=> ``I/B < threshold``.

    Parameters
    ----------
    background : ndarray
        Background (illumination) grey levels.
    threshold : float
        Edge level in transmission units (see `dropvision.frame.edges.edge_threshold`).
    dtype : numpy dtype
        Dtype of the frames (integers are clipped to its range).

    Returns
    -------
    ndarray of ``dtype``
        Grey-level threshold per pixel.
    """
    info = np.iinfo(dtype) if np.issubdtype(dtype, np.integer) else None
    t = np.array(background, dtype=np.float64)  # a copy of ours: the steps in place (the same values)
    np.multiply(t, threshold, out=t)
    np.ceil(t, out=t)
    if info is not None:
        np.clip(t, 0, info.max, out=t)
    return t.astype(dtype)


def dark_mask(image: np.ndarray, thr_image: np.ndarray, allowed: np.ndarray | None = None) -> np.ndarray:
    """uint8 mask (255 = dark) of ``image < thr_image``, restricted to ``allowed`` (uint8) if given."""
    mask = cv2.compare(image, thr_image, cv2.CMP_LT)
    if allowed is not None:
        mask = cv2.bitwise_and(mask, allowed)
    return mask


def segment(mask: np.ndarray, min_area_px: int = 4) -> Segmentation:
    """Label the dark bodies of ``mask`` with their holes (lens spots) filled.

    Parameters
    ----------
    mask : ndarray of uint8
        255 where dark.
    min_area_px : int
        Bodies with fewer filled pixels are ignored (noise).

    Returns
    -------
    Segmentation
    """
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    labels = np.zeros(mask.shape, np.uint16)
    bodies: list[DarkBody] = []
    for c in contours:
        x, y, w, h = cv2.boundingRect(c)
        if w * h < min_area_px:
            continue
        lab = len(bodies) + 1
        cv2.drawContours(labels, [c], 0, lab, thickness=cv2.FILLED)
        area = int(np.count_nonzero(labels[y:y + h, x:x + w] == lab))
        if area < min_area_px:
            labels[y:y + h, x:x + w][labels[y:y + h, x:x + w] == lab] = 0
            continue
        bodies.append(DarkBody(lab, x, y, x + w, y + h, area, y == 0))
    # keep labels consecutive after removals
    if bodies and bodies[-1].label != len(bodies):
        lut = np.zeros(bodies[-1].label + 1, np.uint16)
        new = []
        for i, b in enumerate(bodies, start=1):
            lut[b.label] = i
            new.append(DarkBody(i, b.x0, b.y0, b.x1, b.y1, b.area_px, b.nozzle))
        labels = lut[labels]
        bodies = new
    return Segmentation(labels, bodies)


def find_nozzle_body(bodies: list[DarkBody], axis_roi: float) -> DarkBody | None:
    """The largest body touching the top of the region whose columns span the axis.

    Parameters
    ----------
    bodies : list of DarkBody
    axis_roi : float
        Axis column (region coordinates, px).

    Returns
    -------
    DarkBody or None
    """
    found: DarkBody | None = None
    for b in bodies:
        if b.nozzle and b.x0 <= axis_roi < b.x1:
            if found is None or b.area_px > found.area_px:
                found = b
    return found


def fill_holes(mask: np.ndarray) -> np.ndarray:
    """uint8 mask with every enclosed hole filled (outer contours drawn filled)."""
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    out = np.zeros_like(mask)
    cv2.drawContours(out, contours, -1, 255, thickness=cv2.FILLED)
    return out
