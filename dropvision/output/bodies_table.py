"""bodies.parquet: what each dark body of a frame is, and why (the rules behind ``n_satellites``).

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
   `dropvision.frame.volume.waist_row`) is split off it at the waist and listed as a counted
   satellite (a drop of its own, as a person counts it); its volume stays in the frame's
   ``drop_volume_nl`` (the main drop's silhouette: they coalesce in flight).

``counted`` is True for satellites and tails of a frame whose ``n_satellites`` is known (the
frame's main drop and its companions are trusted); ``n_satellites`` of the frames table is the
number of counted bodies.

The edge spread and the out-of-focus test are `dropvision.frame.body_classes`'s.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from dropvision.frame.bodies import DetachedClass, detached_class
from dvcore import schema

if TYPE_CHECKING:  # pandas loads where a table is made, not at start-up
    import pandas as pd

__all__ = ["BODY_COLUMNS", "bodies_table"]

BODY_COLUMNS = schema.BODIES.column_names


def bodies_table(records, frames: pd.DataFrame, *, edge_blur_ref_px: float, compact_ratio: float) -> pd.DataFrame:
    """bodies.parquet: every body of every measured frame with its class and the reason.

    Parameters
    ----------
    records : list of dropvision.frame.measure_frame.FrameRecord
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
