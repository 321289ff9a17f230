"""Optional Rerun (https://rerun.io) logging of a drop measurement.

Logging is opt-in and costs nothing when off: this module does not import :mod:`rerun` at import
time; the SDK is imported only when a :class:`RerunLogger` is created. The measurement receives
``logger=None`` when logging is off and skips every call.

Every logger owns an explicit :class:`rerun.RecordingStream` (never the global one), so several
loggers can coexist (one per sequence of a campaign) and a logger can be created inside a worker
process. Loggers themselves cannot be pickled: send the picklable :class:`RerunOptions` to the
worker and create the logger there (``RerunLogger(options)``).

Timelines
---------
``delay``  duration timeline, integer nanoseconds: ``round(delay_us * 1000)`` ns after the trigger.
``frame``  sequence timeline: ``FrameRef.index`` (processing order, 0..n-1).

Entity paths (``/frame/...`` in the Rerun 2-D image space of the canonical frame, see below)
---------------------------------------------------------------------------------------------
``/camera``                     :class:`rerun.EncodedImage`, JPEG of the frame as the camera stored it
                                (orientation as stored, 16-bit scaled to 8): the main view
``/frame``                      static :class:`rerun.AnnotationContext` (classes below) and static
                                :class:`rerun.Transform3D` placing the canonical frame (every
                                ``/frame/...`` entity) on ``/camera`` (`camera_transform`)
``/frame/transmission``         :class:`rerun.EncodedImage`, JPEG (quality
                                :data:`TRANSMISSION_JPEG_QUALITY`) of the uint8 image
                                ``round(255 * clip(T, 0, 1))``: what a person looks at
``/frame/raw``                  :class:`rerun.Image`, native dtype (uint8 / uint16), lossless;
                                only with ``RerunOptions(raw=True)`` / ``--rerun-raw``
``/frame/segmentation``         :class:`rerun.SegmentationImage` of the class ids (uint8)
``/frame/axis``                 static :class:`rerun.LineStrips2D`, nozzle axis
``/frame/tip_plane``            static :class:`rerun.LineStrips2D`, nozzle tip plane
``/frame/edges``                :class:`rerun.Points2D`, sub-pixel edge points
``/frame/bodies``               :class:`rerun.Boxes2D` with class ids, labels on hover
``/frame/labels``               :class:`rerun.Points2D` (radius 0), the visible labels of the
                                main drop, satellites and tails, beside their boxes, never
                                overlapping (:func:`body_labels`)
``/frame/track``                :class:`rerun.LineStrips2D`, main-drop centroid track so far
``/frame/drop``                 :class:`rerun.Points2D`, main-drop centroid in this frame
``/series/volume_nl/<name>``    :class:`rerun.Scalars` (grown, attached, drop, detached)
``/series/velocity_m_s/flow``   :class:`rerun.Scalars`
``/series/position_um/<name>``  :class:`rerun.Scalars` (drop_z, drop_x)
``/series/count/satellites``    :class:`rerun.Scalars`
``/log``                        :class:`rerun.TextLog`, one line per frame (file, quality)
``/calibration``                static :class:`rerun.TextDocument` (markdown)
``/summary``                    static :class:`rerun.TextDocument` (markdown of summary.json)
``/table``                      static :class:`rerun.TextDocument`: the values of a single frame
                                (no time series of one point; ``log_calibration(n_frames=1)``)
``/camera/image``, ``/camera/bodies``, ``/shots/<column>``, ``/shots/table``
                                a folder of shots (`RerunLogger.log_shots`, ``shot`` timeline):
                                each shot as stored with its bodies' outlines, one bar per shot

Pixel convention: dropvision uses integer pixel centres (pixel ``(r, c)`` spans
``[c - 0.5, c + 0.5] x [r - 0.5, r + 0.5]``); Rerun draws pixel ``(r, c)`` over
``[c, c + 1] x [r, r + 1]``. Points (edges, axis, tip plane, track) are therefore shifted by
:data:`PIXEL_CENTRE_OFFSET` = +0.5 px. Body boxes ``(x0, y0, x1, y1)`` use the slice convention
(first pixel, one past the last pixel), which maps onto Rerun's space without a shift.

Tilt convention (calibration ``tilt_deg``): the axis direction in image ``(x, y)`` (y down) is
``(sin t, cos t)``; positive tilt means drops drift to +x (right) as they fall. ``drop_x_um`` is
measured along ``(cos t, -sin t)`` (+ to the right).
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, is_dataclass
from dataclasses import fields as dataclass_fields
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from dvcore.rerun_options import DEFAULT_APPLICATION_ID, RerunOptions, options_from_args
from identify.app.rerun_stream import close_stream, delay_ns, open_stream

if TYPE_CHECKING:  # pragma: no cover - typing only
    import rerun as rr
    import rerun.blueprint as rrb

    from dropvision.frame.bodies import DetachedBody
    from dropvision.frame.segmentation import DarkBody, Segmentation

__all__ = [
    "CLASS_BACKGROUND",
    "CLASS_NOZZLE",
    "CLASS_ATTACHED",
    "CLASS_DROP",
    "CLASS_SATELLITE",
    "CLASS_SPECK",
    "CLASS_OUT_OF_FOCUS",
    "CLASS_TOUCHING",
    "CLASS_TAIL",
    "CLASS_BORDER",
    "CLASSES",
    "LABELLED_CLASSES",
    "body_labels",
    "class_image",
    "PIXEL_CENTRE_OFFSET",
    "ROW_SERIES",
    "RerunLogger",
    "TRANSMISSION_JPEG_QUALITY",
    "logger_from_args",
    "measurement_blueprint",
]

def pd_to_float(values: Any) -> np.ndarray:
    """Float array from a column that may be a nullable pandas dtype (NA -> NaN)."""
    to_numpy = getattr(values, "to_numpy", None)
    if to_numpy is not None:
        try:
            return to_numpy(dtype=float, na_value=np.nan)
        except TypeError:
            return to_numpy(dtype=float)
    return np.asarray(values, dtype=float)


# --- segmentation classes --------------------------------------------------------------------

from dropvision.frame.bodies import DetachedClass, detached_class  # noqa: E402
from dropvision.frame.segmentation import (  # noqa: E402  (one set of class ids, defined with the segmentation)
    CLASS_ATTACHED,
    CLASS_BACKGROUND,
    CLASS_BORDER,
    CLASS_DROP,
    CLASS_NOZZLE,
    CLASS_OUT_OF_FOCUS,
    CLASS_SATELLITE,
    CLASS_SPECK,
    CLASS_TAIL,
    CLASS_TOUCHING,
)

#: class id -> (label, RGBA colour) as logged in the annotation context at ``/frame``.
CLASSES: dict[int, tuple[str, tuple[int, int, int, int]]] = {
    CLASS_BACKGROUND: ("background", (0, 0, 0, 0)),
    CLASS_NOZZLE: ("nozzle", (150, 150, 150, 255)),
    CLASS_ATTACHED: ("attached liquid", (40, 120, 255, 255)),
    CLASS_DROP: ("main drop", (230, 40, 40, 255)),
    CLASS_SATELLITE: ("satellite", (255, 170, 0, 255)),
    CLASS_SPECK: ("static speck", (60, 200, 80, 255)),
    # per frame, mist and dust look alike; dust is decided over the sequence (bodies.parquet)
    CLASS_OUT_OF_FOCUS: ("out of focus (mist, or dust if static: bodies.parquet)", (150, 90, 255, 255)),
    CLASS_TOUCHING: ("touching satellite (split at the waist, not counted)", (255, 110, 0, 255)),
    CLASS_TAIL: ("tail (free ligament)", (255, 60, 170, 255)),
    CLASS_BORDER: ("cut by the border (volume unknown)", (180, 230, 40, 255)),
}

#: Classes whose bodies get a visible label beside their box (the others: on hover), and its
#: short name.  Labels sit in a column right of these boxes, pushed apart vertically so that
#: none overlap (`body_labels`).
LABELLED_CLASSES: dict[int, str] = {
    CLASS_DROP: "main drop",
    CLASS_SATELLITE: "satellite",
    CLASS_TOUCHING: "touching satellite",
    CLASS_TAIL: "tail",
}

#: vertical spacing of the body labels, as a fraction of the image height (a 704-row frame fills
#: the view's height at ~1.3 screen px per image px: ~13 image px per line of text)
LABEL_SPACING = 0.022

#: Accepted spellings of a body's class when given as a string.
_CLASS_NAMES: dict[str, int] = {
    "background": CLASS_BACKGROUND,
    "nozzle": CLASS_NOZZLE,
    "attached": CLASS_ATTACHED,
    "attached liquid": CLASS_ATTACHED,
    "attached_liquid": CLASS_ATTACHED,
    "drop": CLASS_DROP,
    "main": CLASS_DROP,
    "main drop": CLASS_DROP,
    "main_drop": CLASS_DROP,
    "satellite": CLASS_SATELLITE,
    "speck": CLASS_SPECK,
    "static speck": CLASS_SPECK,
    "static_speck": CLASS_SPECK,
    "out of focus": CLASS_OUT_OF_FOCUS,
    "out_of_focus": CLASS_OUT_OF_FOCUS,
    "mist": CLASS_OUT_OF_FOCUS,
    "dust": CLASS_OUT_OF_FOCUS,
    "touching": CLASS_TOUCHING,
    "touching satellite": CLASS_TOUCHING,
    "touching_satellite": CLASS_TOUCHING,
    "tail": CLASS_TAIL,
    "border": CLASS_BORDER,
    "cut": CLASS_BORDER,
}

#: JPEG quality of the logged transmission image. One frame of a 704 x 224 sequence is ~8 kB
#: instead of 158 kB (raw) + 158 kB (transmission) uncompressed; the raw frame is logged only on
#: request (``--rerun-raw``).
TRANSMISSION_JPEG_QUALITY = 90

#: Rerun draws pixel (r, c) over [c, c+1] x [r, r+1]; dropvision pixel centres are integers.
PIXEL_CENTRE_OFFSET = 0.5

#: frame-table column -> (entity path, series name shown in the legend)
ROW_SERIES: dict[str, tuple[str, str]] = {
    "grown_volume_nl": ("/series/volume_nl/grown", "grown volume [nl]"),
    "attached_volume_nl": ("/series/volume_nl/attached", "attached volume [nl]"),
    "drop_volume_nl": ("/series/volume_nl/drop", "main drop volume [nl]"),
    "detached_volume_nl": ("/series/volume_nl/detached", "detached volume [nl]"),
    "flow_velocity_m_s": ("/series/velocity_m_s/flow", "flow velocity [m/s]"),
    "drop_z_um": ("/series/position_um/drop_z", "drop z (along axis) [um]"),
    "drop_x_um": ("/series/position_um/drop_x", "drop x (across axis) [um]"),
    "n_satellites": ("/series/count/satellites", "satellites"),
}

_SERIES_COLOURS: dict[str, tuple[int, int, int]] = {
    "grown_volume_nl": (40, 120, 255),
    "attached_volume_nl": (120, 180, 255),
    "drop_volume_nl": (230, 40, 40),
    "detached_volume_nl": (255, 120, 120),
    "flow_velocity_m_s": (40, 170, 90),
    "drop_z_um": (230, 40, 40),
    "drop_x_um": (255, 170, 0),
    "n_satellites": (255, 170, 0),
}


# --- blueprint -------------------------------------------------------------------------------


#: the overlays of the frame views, in canonical coordinates under ``/frame`` (its static transform
#: places them on the camera's frame)
FRAME_OVERLAYS = ("/frame/segmentation", "/frame/axis", "/frame/tip_plane", "/frame/edges",
                  "/frame/bodies", "/frame/labels", "/frame/track", "/frame/drop")


def frame_views(raw: bool = False) -> list:
    """The frame views: the frame as the camera stored it (``/camera``) with the overlays drawn on it
    (``/frame``'s transform maps the canonical frame onto the camera's), then the normalised
    transmission in the canonical frame (nozzle at the top) with the same overlays, then the raw
    canonical frame when ``raw``."""
    import rerun.blueprint as rrb

    views = [rrb.Spatial2DView(name="camera frame (as stored)", origin="/",
                               contents=["/camera", "/frame", *FRAME_OVERLAYS]),
             rrb.Spatial2DView(name="normalised (transmission, nozzle at the top)", origin="/frame",
                               contents=["/frame", "/frame/transmission", *FRAME_OVERLAYS])]
    if raw:
        views.append(rrb.Spatial2DView(name="raw frame (nozzle at the top)", origin="/frame",
                                       contents=["/frame", "/frame/raw", *FRAME_OVERLAYS]))
    return views


def measurement_blueprint(raw: bool = False, *, single: bool = False) -> rrb.Blueprint:
    """Default layout: frame views (camera | normalised | raw tabs) left, time series stacked right.

    ``Horizontal(Tabs(camera frame, normalised[, raw]), Vertical(TimeSeriesView volume, velocity,
    position, TextDocumentView summary))``, with the ``delay`` timeline selected in the time panel,
    collapsed to its scrubber; the selection and blueprint panels collapsed (the frame gets the
    room). The raw tab exists only when ``raw``. ``single`` (one frame, a pendant drop): no time
    series of one point; the frame's values as a table (``/table``) beside the summary.
    """
    import rerun.blueprint as rrb

    views = frame_views(raw)
    texts = rrb.Tabs(
        rrb.TextDocumentView(name="summary", origin="/summary"),
        rrb.TextDocumentView(name="calibration", origin="/calibration"),
        rrb.TextLogView(name="frames", origin="/log"),
    )
    if single:
        right = rrb.Vertical(rrb.TextDocumentView(name="the frame's values", origin="/table"), texts,
                             row_shares=[3, 2])
    else:
        right = rrb.Vertical(
            rrb.TimeSeriesView(name="volume [nl]", origin="/series/volume_nl"),
            rrb.TimeSeriesView(name="flow velocity [m/s]", origin="/series/velocity_m_s"),
            rrb.TimeSeriesView(name="drop position [um]", origin="/series/position_um"),
            texts,
            row_shares=[3, 2, 2, 2],
        )
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Tabs(*views),
            right,
            column_shares=[3, 2],
        ),
        rrb.TimePanel(timeline="delay", state="collapsed"),  # the scrubber only
        rrb.SelectionPanel(state="collapsed"),
        rrb.BlueprintPanel(state="collapsed"),
        collapse_panels=False,
    )


def camera_transform(orientation: str, canonical_shape) -> tuple[float, tuple[float, float]]:
    """(rotation in degrees about the view's z axis, translation (x, y)) taking Rerun's pixel space of
    the canonical frame (``/frame``) onto the frame as the camera stored it (``/camera``): the quarter
    turns of `dropvision.io.orientation` (pixel ``(r, c)`` spans ``[c, c + 1] x [r, r + 1]``)."""
    hc, wc = float(canonical_shape[0]), float(canonical_shape[1])
    return {"down": (0.0, (0.0, 0.0)), "up": (180.0, (wc, hc)), "left": (90.0, (hc, 0.0)),
            "right": (-90.0, (0.0, wc))}[orientation]


def camera_preview(image: np.ndarray) -> np.ndarray:
    """8-bit grey of a stored frame for the camera view: 8-bit as it is; 16-bit scaled so that its
    99.9th percentile is white (a 12-bit camera's frame is not drawn black)."""
    image = np.asarray(image)
    if image.dtype == np.uint8:
        return np.ascontiguousarray(image)
    top = float(np.percentile(image, 99.9)) or 1.0
    return np.round(np.clip(image.astype(np.float32) * (255.0 / top), 0, 255)).astype(np.uint8)


#: shots.parquet columns drawn as one bar per shot (`RerunLogger.log_shots`)
SHOT_BARS: dict[str, str] = {"drop_volume_nl": "main drop volume [nl]", "n_satellites": "satellites",
                             "drop_z_um": "main drop from the tip [um]"}
#: shots.parquet columns of the shots' table (``/shots/table``), those present
SHOT_TABLE_COLUMNS = ("file", "delay_us", "drop_volume_nl", "drop_volume_uncertainty_nl", "n_satellites",
                      "drop_z_um", "attached_volume_nl", "quality")


def shots_blueprint() -> rrb.Blueprint:
    """A folder of shots: the shot as the camera stored it with its bodies' outlines (``/camera``, the
    ``shot`` timeline picks the shot), one bar per shot for each of `SHOT_BARS`, and the shots' table."""
    import rerun.blueprint as rrb

    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial2DView(name="shot (as stored) and its bodies", origin="/camera"),
            rrb.Vertical(*[rrb.BarChartView(name=name, origin=f"/shots/{col}") for col, name in SHOT_BARS.items()],
                         rrb.Tabs(rrb.TextDocumentView(name="shots", origin="/shots/table"),
                                  rrb.TextDocumentView(name="summary", origin="/summary")),
                         row_shares=[2] * len(SHOT_BARS) + [3]),
            column_shares=[3, 2],
        ),
        rrb.TimePanel(timeline="shot", state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.BlueprintPanel(state="collapsed"),
        collapse_panels=False,
    )


# --- duck-typed accessors --------------------------------------------------------------------


def _get(obj: Any, names: Iterable[str], default: Any = None) -> Any:
    """First present attribute or mapping key of ``obj`` among ``names``."""
    keyed = isinstance(obj, Mapping) or (hasattr(obj, "keys") and hasattr(obj, "__getitem__"))
    for name in names:
        if keyed:  # dict, pandas Series, ...
            if name in obj.keys():
                return obj[name]
        elif hasattr(obj, name):
            return getattr(obj, name)
    return default


def _finite(value: Any) -> float | None:
    """``float(value)`` if it is a finite number (bools count as 0/1), else None."""
    if value is None or isinstance(value, str):
        return None
    try:
        out = float(value)
    except (TypeError, ValueError):
        return None
    return out if math.isfinite(out) else None


def _class_id(body: Any, index: int) -> int:
    raw = _get(body, ("class_id", "cls", "klass", "kind", "class"))
    if raw is None:
        raise ValueError(f"log_frame: bodies[{index}] has no class (class_id / cls / kind / class)")
    if isinstance(raw, str):
        key = raw.strip().lower()
        if key not in _CLASS_NAMES:
            raise ValueError(f"log_frame: bodies[{index}] has unknown class {raw!r}; "
                             f"expected one of {sorted(_CLASS_NAMES)} or an id 0..{max(CLASSES)}")
        return _CLASS_NAMES[key]
    cid = int(raw)
    if cid not in CLASSES:
        raise ValueError(f"log_frame: bodies[{index}] has class id {cid}, expected 0..{max(CLASSES)}")
    return cid


def _markdown_table(items: Iterable[tuple[str, Any]], header: tuple[str, str] = ("key", "value")) -> str:
    lines = [f"| {header[0]} | {header[1]} |", "|---|---|"]
    for key, value in items:
        if isinstance(value, (float, np.floating)):
            text = f"{value:.6g}"
        elif isinstance(value, (list, tuple)):
            text = "; ".join(str(v) for v in value)
        else:
            text = str(value)
        lines.append(f"| {key} | {text.replace('|', '/')} |")
    return "\n".join(lines)


def _flatten(mapping: Mapping[str, Any], prefix: str = "") -> list[tuple[str, Any]]:
    out: list[tuple[str, Any]] = []
    for key, value in mapping.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            out.extend(_flatten(value, name + "."))
        else:
            out.append((name, value))
    return out


@dataclass(frozen=True)
class _Box:
    """A body normalised to full-frame coordinates (half-open box)."""

    x0: float
    y0: float
    x1: float
    y1: float
    class_id: int
    volume_nl: float | None
    centroid_xy: tuple[float, float] | None


def _full_labels(labels, shape, ox: int, oy: int) -> np.ndarray:
    """`log_frame`'s class image checked and, given in a region of interest at ``(ox, oy)``, placed
    in a frame of ``shape`` (padded with background)."""
    labels = np.asarray(labels)
    if (ox, oy) != (0, 0) and labels.ndim == 2 and shape is not None:
        if ox < 0 or oy < 0 or oy + labels.shape[0] > shape[0] or ox + labels.shape[1] > shape[1]:
            raise ValueError(f"log_frame: labels {labels.shape} at roi_origin_xy {(ox, oy)} "
                             f"do not fit in the image shape {shape}")
        full = np.zeros(shape, dtype=labels.dtype)
        full[oy:oy + labels.shape[0], ox:ox + labels.shape[1]] = labels
        labels = full
    if labels.ndim != 2 or (shape is not None and labels.shape != shape):
        raise ValueError(f"log_frame: labels shape {labels.shape} must be 2-D and equal "
                         f"the image shape {shape}")
    if labels.dtype.kind not in "iub":
        raise ValueError(f"log_frame: labels must be an integer array, got {labels.dtype}")
    if labels.size and (labels.min() < 0 or labels.max() > max(CLASSES)):
        raise ValueError(f"log_frame: labels must hold class ids 0..{max(CLASSES)}, got "
                         f"range {labels.min()}..{labels.max()}")
    return labels


def _frame_log_text(index, delay_us, file, quality) -> tuple[str, str]:
    """A frame's line of the text log and its level (WARN for a quality other than ok)."""
    text = f"frame {int(index)} delay {float(delay_us):g} us {file}".rstrip()
    level = "INFO"
    if isinstance(quality, str) and quality and quality.lower() != "ok":
        text += f": {quality}"
        level = "WARN"
    elif _finite(quality) is not None and not isinstance(quality, (bool, np.bool_)):
        text += f": quality {float(quality):g}"
    return text, level


def _body_boxes(bodies: list[Any], ox: int = 0, oy: int = 0) -> list[_Box]:
    out = []
    for i, body in enumerate(bodies):
        bbox = _get(body, ("bbox",))
        if bbox is None:
            corners = [_get(body, (k,)) for k in ("x0", "y0", "x1", "y1")]
            bbox = None if any(v is None for v in corners) else corners
        if bbox is None or len(bbox) != 4:
            raise ValueError(f"log_frame: bodies[{i}] needs bbox = (x0, y0, x1, y1) or x0, y0, x1, y1; "
                             f"got {body!r}")
        x0, y0, x1, y1 = (float(v) for v in bbox)
        if not (x0 <= x1 and y0 <= y1):
            raise ValueError(f"log_frame: bodies[{i}] bbox {tuple(bbox)!r} has x1 < x0 or y1 < y0")
        centroid = _get(body, ("centroid_xy",))
        if centroid is not None:
            centroid = (float(centroid[0]) + ox, float(centroid[1]) + oy)
        out.append(_Box(x0 + ox, y0 + oy, x1 + ox, y1 + oy, _class_id(body, i),
                        _finite(_get(body, ("volume_nl",))), centroid))
    return out


def body_labels(boxes: Iterable[Any], spacing: float) -> list[tuple[tuple[float, float], int, str]]:
    """Where to write the visible body labels so that none covers a labelled box or another label.

    One label per box of a class in :data:`LABELLED_CLASSES`, in a column right of all these
    boxes, at its box's mid-height; a label closer than ``spacing`` (image px, about one line of
    text) to the one above is pushed down (greedy, top to bottom).  The viewer centres a point's
    label on the point, so the point sits half the text's estimated width right of the column.

    Returns
    -------
    list of ((x, y), class_id, text)
        Rerun image coordinates of the label centres.
    """
    items = sorted((b for b in boxes if b.class_id in LABELLED_CLASSES), key=lambda b: (b.y0 + b.y1, b.x0))
    if not items:
        return []
    column = max(b.x1 for b in items) + 0.5 * spacing
    out: list[tuple[tuple[float, float], int, str]] = []
    last = -math.inf
    for b in items:
        y = max((b.y0 + b.y1) / 2.0, last + spacing)
        last = y
        text = LABELLED_CLASSES[b.class_id] + ("" if b.volume_nl is None else f" {b.volume_nl:.3g} nl")
        out.append(((column + 0.5 * _CHAR_WIDTH * spacing * (len(text) + 2), y), b.class_id, text))
    return out


#: width of a character of a label in lines of text (the viewer's font at its default size)
_CHAR_WIDTH = 0.42


# --- logger ----------------------------------------------------------------------------------



# --- the class image of a measured frame ------------------------------------------------------


def _parts_by_box(bodies: Sequence[DetachedBody], rejected: Sequence[DetachedBody],
                  compact_ratio: float) -> dict[tuple[int, int, int, int], list[tuple[DetachedBody, int]]]:
    """The detached bodies (with their class id) by bounding box: the parts of one silhouette share one."""
    parts: dict[tuple[int, int, int, int], list[tuple[DetachedBody, int]]] = {}
    ids = {DetachedClass.BORDER: CLASS_BORDER, DetachedClass.MAIN_DROP: CLASS_DROP,
           DetachedClass.TOUCHING: CLASS_TOUCHING, DetachedClass.TAIL: CLASS_TAIL,
           DetachedClass.SATELLITE: CLASS_SATELLITE}
    for j, d in enumerate(bodies):
        cls = ids[detached_class(d, j, compact_ratio)]
        parts.setdefault(tuple(int(v) for v in d.bbox), []).append((d, cls))
    for d in rejected:
        parts.setdefault(tuple(int(v) for v in d.bbox), []).append((d, CLASS_OUT_OF_FOCUS))
    return parts


def _split_silhouette(seg: Segmentation, b, found: list, labels: np.ndarray) -> list[dict]:
    """One silhouette, several parts (a satellite touching the main drop, split at the waist): each
    touching part's pixels on its side of the main drop's rows take its class (in ``labels``, in
    place); one box per part around its own pixels."""
    mine = seg.labels[b.y0:b.y1, b.x0:b.x1] == b.label
    sub = labels[b.y0:b.y1, b.x0:b.x1]
    rows = np.arange(b.y0, b.y1)[:, None]
    whole = next((d for d, _ in found if not d.touching), None)
    for d, cls in found:
        if d is whole or whole is None:
            continue
        side = rows > whole.bottom_row if d.bottom_row > whole.bottom_row else rows < whole.top_row
        sub[mine & side] = cls
    boxes = []
    for d, cls in found:
        rr, cc = np.nonzero(mine & (sub == cls))
        box = b.bbox if rr.size == 0 else (b.x0 + int(cc.min()), b.y0 + int(rr.min()),
                                            b.x0 + int(cc.max()) + 1, b.y0 + int(rr.max()) + 1)
        boxes.append({"bbox": box, "class_id": int(cls), "volume_nl": float(d.volume_nl)})
    return boxes


def class_image(seg: Segmentation, nozzle_body: DarkBody | None, bodies: Sequence[DetachedBody] = (),
                rejected: Sequence[DetachedBody] = (), opaque: np.ndarray | None = None, *,
                compact_ratio: float = 2.0) -> tuple[np.ndarray, list[dict]]:
    """Per-pixel segmentation classes and per-body boxes of one frame (for the Rerun viewer).

    The classes follow the rules of bodies.parquet (`dropvision.output.bodies_table`) as far as one frame
    can tell (`dropvision.frame.segmentation` says what each ``CLASS_*`` is). A view of the measured
    bodies, not a measurement: it lives with the viewer (moved from `dropvision.frame.bodies`).

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
    parts = _parts_by_box(bodies, rejected, compact_ratio)
    classes = np.zeros(len(seg.bodies) + 1, np.uint8)
    for b in seg.bodies:
        found = parts.get(b.bbox)
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
        bbox = b.bbox
        found = parts.get(bbox) if not b.nozzle else None
        if not found:
            boxes.append({"bbox": bbox, "class_id": int(classes[b.label])})
        elif len(found) == 1:
            d, cls = found[0]
            boxes.append({"bbox": bbox, "class_id": int(cls), "volume_nl": float(d.volume_nl)})
        else:
            boxes.extend(_split_silhouette(seg, b, found, labels))
    if opaque is not None:
        labels[opaque & (labels == 0)] = CLASS_SPECK
    return labels, boxes


@dataclass
class _Calibration:
    tip_row: float | None  # None: no nozzle found (no tip plane)
    axis_col: float | None  # None: no jetting axis either
    tilt_rad: float
    pixel_size_um: float | None


class RerunLogger:
    """Logs one measured sequence to Rerun (file and/or live viewer).

    The measurement calls :meth:`log_calibration` once, :meth:`log_frame` per frame (delay
    order), :meth:`log_summary` once, then :meth:`close`. Also usable as a context manager.

    Parameters
    ----------
    options : RerunOptions, optional
        Sinks and ids; must have ``options.enabled``. Alternatively give the keywords below
        (not both): ``RerunLogger(path="seq.rrd", app_id="dropvision")``.
    path, spawn, connect_url, app_id, recording_id, recording_name
        As the :class:`RerunOptions` fields (``app_id`` = ``application_id``).
    raw : bool
        Also log the raw frame at ``/frame/raw`` (lossless, full size); as ``RerunOptions.raw``.
    blueprint : rerun.blueprint.BlueprintLike, optional
        Layout saved with the recording; default :func:`measurement_blueprint`.
    """

    def __init__(self, options: RerunOptions | None = None, *, path: str | Path | None = None,
                 spawn: bool = False, connect_url: str | None = None,
                 app_id: str = DEFAULT_APPLICATION_ID, recording_id: str | None = None,
                 recording_name: str | None = None, raw: bool = False,
                 blueprint: rrb.BlueprintLike | None = None) -> None:
        if options is None:
            options = RerunOptions(path=None if path is None else Path(path), spawn=spawn,
                                   connect_url=connect_url, application_id=app_id,
                                   recording_id=recording_id, recording_name=recording_name, raw=raw)
        elif (path, spawn, connect_url, app_id, recording_id, recording_name, raw) != (
                None, False, None, DEFAULT_APPLICATION_ID, None, None, False):
            raise TypeError("RerunLogger: give either options or the keyword fields, not both")
        import rerun as rr

        self._rr = rr
        self.options = options
        self.stream: rr.RecordingStream = open_stream(
            options, blueprint if blueprint is not None else measurement_blueprint(raw=options.raw))
        self._calibration: _Calibration | None = None
        self._shape: tuple[int, int] | None = None
        self._lines_logged = False
        self._track_px: list[tuple[float, float]] = []
        self._closed = False
        self._orientation = "down"  # of the stored frames (log_calibration): /frame placed on /camera
        self._transform_logged = False
        self._single = False  # one frame (log_calibration n_frames=1): a table, no time series
        self._own_blueprint = blueprint is None
        self._log_static_layout()

    # pickling a live stream makes no sense: give the worker the options instead
    def __reduce__(self) -> Any:
        raise TypeError("RerunLogger cannot be pickled; pass RerunOptions to the worker and "
                        "create RerunLogger(options) there")

    def __enter__(self) -> RerunLogger:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _log_static_layout(self) -> None:
        rr = self._rr
        rec = self.stream
        rec.log("/frame", rr.AnnotationContext(
            [(cid, label, colour) for cid, (label, colour) in CLASSES.items()]), static=True)
        for column, (path, name) in ROW_SERIES.items():
            rec.log(path, rr.SeriesLines(names=name, colors=_SERIES_COLOURS[column]), static=True)
            rec.log(path, rr.SeriesPoints(names=name, colors=_SERIES_COLOURS[column],
                                          marker_sizes=2.0), static=True)

    # -- calibration ---------------------------------------------------------------------------

    def log_calibration(self, calib: Any, *, shape: tuple[int, int] | None = None, orientation: str | None = None,
                        n_frames: int | None = None) -> None:
        """Log the nozzle axis and tip plane (static) and a calibration table.

        Parameters
        ----------
        calib : object or mapping
            With ``tip_row``, ``axis_col`` (canonical full-frame pixel coords, integer pixel
            centres; NaN where a frame has no nozzle: that line is not drawn), optional ``tilt_deg`` or ``tilt_rad`` (default 0, see module docstring),
            ``pixel_size_um`` and ``shape``; ``to_dict()`` (if present) fills the table.
        shape : (rows, cols), optional
            Image shape for the line extents; default ``calib.shape``, else the first frame's.
        orientation : str, optional
            How the camera stored the frames (`dropvision.io.orientation`; default ``calib.orientation``,
            else ``"down"``): ``/frame`` (canonical) is placed on ``/camera`` (as stored) by a static
            transform (`camera_transform`).
        n_frames : int, optional
            Frames of the sequence: one (a single frame, a pendant drop) gets the frame's values as
            a table and no time series of one point (`measurement_blueprint` ``single``).
        """
        self._check_open()
        orientation = orientation or _get(calib, ("orientation",))
        if isinstance(orientation, str) and orientation in ("down", "up", "left", "right"):
            self._orientation = orientation
            self._transform_logged = False
        if n_frames is not None and int(n_frames) == 1 and not self._single:
            self._single = True
            if self._own_blueprint:
                self.stream.send_blueprint(measurement_blueprint(raw=self.options.raw, single=True),
                                           make_active=True, make_default=True)
        tip_row = _finite(_get(calib, ("tip_row", "nozzle_tip_row")))  # None: no nozzle, no tip plane
        axis_col = _finite(_get(calib, ("axis_col",)))
        tilt_deg = _get(calib, ("tilt_deg",))
        if tilt_deg is None:
            tilt_rad = _get(calib, ("tilt_rad",), 0.0)
            tilt_deg = None if _finite(tilt_rad) is None else math.degrees(float(tilt_rad))
        tilt_deg = _finite(tilt_deg)
        if tilt_deg is None or abs(tilt_deg) >= 45.0:
            raise ValueError(f"log_calibration: tilt_deg must be finite and |tilt| < 45, "
                             f"got {_get(calib, ('tilt_deg',))!r}")
        self._calibration = _Calibration(tip_row, axis_col, math.radians(tilt_deg),
                                         _finite(_get(calib, ("pixel_size_um",))))
        if shape is None:
            shape = _get(calib, ("shape",))
        if shape is not None:
            if len(shape) != 2:
                raise ValueError(f"log_calibration: shape must be (rows, cols), got {shape!r}")
            self._shape = (int(shape[0]), int(shape[1]))
        self._lines_logged = False
        if self._shape is not None:
            self._log_calibration_lines()
        items: list[tuple[str, Any]] = [("tip_row [px]", tip_row), ("axis_col [px]", axis_col),
                                        ("tilt [deg]", tilt_deg)]
        if callable(getattr(calib, "to_dict", None)):
            fields_ = dict(calib.to_dict())
        elif isinstance(calib, Mapping):
            fields_ = dict(calib)
        elif is_dataclass(calib) and not isinstance(calib, type):
            fields_ = {f.name: getattr(calib, f.name) for f in dataclass_fields(calib)}
        else:
            fields_ = {k: getattr(calib, k) for k in ("pixel_size_um",) if hasattr(calib, k)}
        items.extend((k, v) for k, v in _flatten(fields_)
                     if k not in ("tip_row", "nozzle_tip_row", "axis_col", "tilt_deg", "tilt_rad")
                     and (isinstance(v, (str, list, tuple)) or np.ndim(v) == 0)
                     and not is_dataclass(v) and len(str(v)) <= 200)
        self.stream.log("/calibration", self._rr.TextDocument(
            "## Calibration\n\n" + _markdown_table(items), media_type="text/markdown"), static=True)

    def _log_camera_transform(self) -> None:
        """The static transform of ``/frame`` (canonical) onto ``/camera`` (as stored), once the
        canonical shape is known."""
        if self._transform_logged or self._shape is None:
            return
        rr = self._rr
        degrees, (tx, ty) = camera_transform(self._orientation, self._shape)
        self.stream.log("/frame", rr.Transform3D(translation=[tx, ty, 0.0],
                                                 rotation=rr.RotationAxisAngle(axis=[0.0, 0.0, 1.0],
                                                                               degrees=degrees)), static=True)
        self._transform_logged = True

    def _log_calibration_lines(self) -> None:
        self._log_camera_transform()
        cal, shape = self._calibration, self._shape
        if cal is None or shape is None or self._lines_logged:
            return
        rows, cols = shape
        t = math.tan(cal.tilt_rad)
        rr = self._rr
        if cal.axis_col is not None:  # through the tip, or (no nozzle) vertical through the drops' line
            ys = np.array([-0.5, rows - 0.5])
            axis = np.column_stack([cal.axis_col + (ys - (cal.tip_row or 0.0)) * t, ys])
            self.stream.log("/frame/axis", rr.LineStrips2D([axis + PIXEL_CENTRE_OFFSET],
                            colors=(255, 255, 0), radii=-1.0, labels="axis", show_labels=False), static=True)
        if cal.tip_row is not None:
            xs = np.array([-0.5, cols - 0.5])
            tip = np.column_stack([xs, cal.tip_row - (xs - (cal.axis_col or 0.0)) * t])
            self.stream.log("/frame/tip_plane", rr.LineStrips2D([tip + PIXEL_CENTRE_OFFSET], colors=(0, 255, 255),
                            radii=-1.0, labels="tip plane", show_labels=False), static=True)
        self._lines_logged = True

    # -- per frame ------------------------------------------------------------------------------

    def log_frame(self, ref: Any, image: np.ndarray | None, transmission: np.ndarray | None,
                  labels: np.ndarray | None, edges: np.ndarray | None, bodies: Iterable[Any] | None,
                  row: Mapping[str, Any] | None, *, roi_origin_xy: tuple[int, int] = (0, 0)) -> None:
        """Log one frame at its ``delay`` (ns) and ``frame`` (index) times.

        Parameters
        ----------
        ref : FrameRef-like
            ``index`` (int), ``delay_us`` (float), optional ``file``; attributes or mapping keys.
        image : 2-D array or None
            Raw canonical frame (uint8/uint16): gives the image shape; logged unchanged at
            ``/frame/raw`` only when the options ask for it (``raw=True``).
        transmission : 2-D float array or None
            Illumination-normalised frame (1 = background); logged as the JPEG of the uint8
            image ``255*clip(T,0,1)`` (:data:`TRANSMISSION_JPEG_QUALITY`).
        labels : 2-D integer array or None
            Class id per pixel (``CLASS_*`` constants, 0 = background): the image's shape, or a
            region of interest placed at ``roi_origin_xy`` (padded with background).
        edges : (N, 2) array or None
            Sub-pixel edge points as ``(x, y)`` = (column, row), integer pixel centres.
        bodies : iterable or None
            Objects/mappings with ``bbox`` = ``(x0, y0, x1, y1)`` or attributes/keys ``x0, y0,
            x1, y1`` (half-open: ``labels[y0:y1, x0:x1]``), a class (``class_id``/``cls``/
            ``kind``/``class``: id or name), optional ``volume_nl`` (box label) and
            ``centroid_xy`` (track point when the table has no ``drop_z_um``).
        row : mapping, pandas Series or None
            Frame-table values (column names of ``MeasureResult.frames``); finite values of the
            columns in :data:`ROW_SERIES` become scalar series; ``quality`` goes to ``/log``.
        roi_origin_xy : (int, int)
            Full-frame ``(x, y)`` of the region of interest's top-left pixel, added to
            ``labels`` placement, ``edges`` and ``bodies`` given in ROI coordinates.
        """
        self._check_open()
        rr, rec = self._rr, self.stream
        index = _get(ref, ("index",))
        delay_us = _get(ref, ("delay_us",))
        if index is None or delay_us is None:
            raise ValueError(f"log_frame: ref needs index and delay_us, got {ref!r}")
        rec.set_time("frame", sequence=int(index))
        rec.set_time("delay", duration=np.timedelta64(delay_ns(delay_us), "ns"))

        shape = None if image is None else self._log_frame_image(image)
        if transmission is not None:
            shape = self._log_frame_transmission(transmission, shape)
        ox, oy = (int(v) for v in roi_origin_xy)
        if labels is not None:
            labels = _full_labels(labels, shape, ox, oy)
            shape = shape or labels.shape
            rec.log("/frame/segmentation", rr.SegmentationImage(labels.astype(np.uint8), opacity=0.45))
        if shape is not None and self._shape is None:
            self._shape = (int(shape[0]), int(shape[1]))
            self._log_calibration_lines()
        self._log_camera_transform()

        if edges is not None:
            pts = np.asarray(edges, dtype=float)
            if pts.size == 0:
                pts = pts.reshape(0, 2)
            if pts.ndim != 2 or pts.shape[1] != 2:
                raise ValueError(f"log_frame: edges must be an (N, 2) array of (x, y), got shape {pts.shape}")
            rec.log("/frame/edges", rr.Points2D(pts + (ox + PIXEL_CENTRE_OFFSET, oy + PIXEL_CENTRE_OFFSET),
                                                radii=-1.5, colors=(255, 0, 255)))
        boxes = None if bodies is None else _body_boxes(list(bodies), ox, oy)
        if boxes is not None:
            self._log_bodies(boxes, shape or self._shape)
        if row is None:
            row = {}
        self._log_frame_row(row, boxes)
        text, level = _frame_log_text(index, delay_us, _get(ref, ("file",), ""), row.get("quality"))
        rec.log("/log", rr.TextLog(text, level=level))

    def _log_frame_image(self, image: np.ndarray) -> tuple:
        """The raw frame (only with ``raw=True``) and the frame as the camera stored it; its shape."""
        rr, rec = self._rr, self.stream
        image = np.asarray(image)
        if image.ndim != 2:
            raise ValueError(f"log_frame: image must be 2-D, got shape {image.shape}")
        if self.options.raw:
            rec.log("/frame/raw", rr.Image(image))
        # the frame as the camera stored it: the main view, the overlays placed on it by /frame's transform
        from dropvision.io.orientation import from_canonical
        rec.log("/camera", rr.Image(camera_preview(from_canonical(image, self._orientation)),
                                    color_model="L").compress(jpeg_quality=TRANSMISSION_JPEG_QUALITY))
        rec.log("/camera", rr.EncodedImage.from_fields(draw_order=-10.0))
        return image.shape

    def _log_frame_transmission(self, transmission: np.ndarray, shape) -> tuple:
        """The transmission as an 8-bit JPEG (`log_frame`); the frame's shape."""
        rr, rec = self._rr, self.stream
        transmission = np.asarray(transmission)
        if transmission.ndim != 2 or (shape is not None and transmission.shape != shape):
            raise ValueError(f"log_frame: transmission shape {transmission.shape} must be 2-D "
                             f"and equal the image shape {shape}")
        shape = shape or transmission.shape
        if transmission.dtype != np.uint8:
            transmission = np.round(np.clip(np.nan_to_num(transmission, nan=0.0), 0.0, 1.0)
                                    * 255.0).astype(np.uint8)
        rec.log("/frame/transmission", rr.Image(transmission, color_model="L").compress(
            jpeg_quality=TRANSMISSION_JPEG_QUALITY))
        rec.log("/frame/transmission", rr.EncodedImage.from_fields(draw_order=-5.0))
        return shape

    def _log_frame_row(self, row: Mapping[str, Any], boxes) -> None:
        """The frame's main drop (its point and the track so far) and its frame-table series."""
        rr, rec = self._rr, self.stream
        point = self._drop_point_px(row, boxes)
        if point is not None:
            self._track_px.append(point)
            rec.log("/frame/drop", rr.Points2D([point], radii=-4.0, class_ids=CLASS_DROP, show_labels=False))
        else:
            rec.log("/frame/drop", rr.Clear(recursive=False))
        if len(self._track_px) >= 2:
            rec.log("/frame/track", rr.LineStrips2D([self._track_px], radii=-1.0,
                                                    colors=CLASSES[CLASS_DROP][1]))
        for column, (path, _name) in ROW_SERIES.items():
            value = _finite(row.get(column))
            if value is not None and not self._single:  # one frame: its values go to /table (log_table)
                rec.log(path, rr.Scalars(value))

    def log_measured_frame(self, ref: Any, image: np.ndarray, transmission: np.ndarray, seg: Segmentation,
                           nozzle_body: DarkBody | None, bodies: Sequence[DetachedBody],
                           rejected: Sequence[DetachedBody], opaque: np.ndarray | None, edges: np.ndarray, *,
                           compact_ratio: float, roi_origin_xy: tuple[int, int]) -> None:
        """:meth:`log_frame` of a measured frame: its segmentation and bodies drawn as the class
        image and body boxes of :func:`class_image` (region coordinates, placed at
        ``roi_origin_xy``); no frame-table row."""
        labels, boxes = class_image(seg, nozzle_body, bodies, rejected, opaque, compact_ratio=compact_ratio)
        self.log_frame(ref, image, transmission, labels, edges, boxes, None, roi_origin_xy=roi_origin_xy)

    def _log_bodies(self, boxes: list[_Box], shape: tuple[int, int] | None) -> None:
        """Boxes of every body (class colour, label on hover) and, beside the boxes of the
        classes in :data:`LABELLED_CLASSES`, one visible label each (`body_labels`)."""
        rr = self._rr
        if not boxes:
            self.stream.log("/frame/bodies", rr.Clear(recursive=False))
            self.stream.log("/frame/labels", rr.Clear(recursive=False))
            return
        texts = [CLASSES[b.class_id][0] + ("" if b.volume_nl is None else f" {b.volume_nl:.3g} nl")
                 for b in boxes]
        self.stream.log("/frame/bodies", rr.Boxes2D(
            mins=[(b.x0, b.y0) for b in boxes], sizes=[(b.x1 - b.x0, b.y1 - b.y0) for b in boxes],
            class_ids=[b.class_id for b in boxes], labels=texts, show_labels=False))
        rows = shape[0] if shape is not None else max(b.y1 for b in boxes)
        placed = body_labels(boxes, LABEL_SPACING * rows)
        if not placed:
            self.stream.log("/frame/labels", rr.Clear(recursive=False))
            return
        self.stream.log("/frame/labels", rr.Points2D(
            [p for p, _, _ in placed], radii=0.0, class_ids=[c for _, c, _ in placed],
            labels=[t for _, _, t in placed], show_labels=True))

    def _drop_point_px(self, row: Mapping[str, Any], boxes: list[_Box] | None) -> tuple[float, float] | None:
        """Main-drop centroid in Rerun pixel space: from the table (needs calibration), else bodies."""
        cal = self._calibration
        z_um, x_um = _finite(row.get("drop_z_um")), _finite(row.get("drop_x_um"))
        if cal is not None and cal.pixel_size_um and z_um is not None and None not in (cal.tip_row, cal.axis_col):
            x_um = x_um or 0.0
            s, c = math.sin(cal.tilt_rad), math.cos(cal.tilt_rad)
            x = cal.axis_col + (z_um * s + x_um * c) / cal.pixel_size_um
            y = cal.tip_row + (z_um * c - x_um * s) / cal.pixel_size_um
            return (x + PIXEL_CENTRE_OFFSET, y + PIXEL_CENTRE_OFFSET)
        drops = [b for b in boxes or () if b.class_id == CLASS_DROP]
        if not drops:
            return None
        best = max(drops, key=lambda b: (b.x1 - b.x0) * (b.y1 - b.y0))
        if best.centroid_xy is not None:
            return (best.centroid_xy[0] + PIXEL_CENTRE_OFFSET, best.centroid_xy[1] + PIXEL_CENTRE_OFFSET)
        return ((best.x0 + best.x1) / 2.0, (best.y0 + best.y1) / 2.0)  # half-open box centre

    # -- per sequence ---------------------------------------------------------------------------

    def log_table(self, frames: Any) -> None:
        """Log the scalar series of the final frame table (``MeasureResult.frames``).

        Sequence-level quantities (grown volume relative to the initial meniscus, flow velocity,
        pinch-off-dependent drop values) are only known once every frame is measured; they are
        logged here at each row's ``delay`` (and ``frame`` = row position) from the table, the
        source of truth, so that the plots show exactly what ``frames.parquet`` holds.
        """
        self._check_open()
        rr, rec = self._rr, self.stream
        delays = np.asarray(frames["delay_us"], dtype=float)
        if self._single or len(delays) == 1:  # no time series of one point: the frame's values as a table
            row = frames.iloc[0] if hasattr(frames, "iloc") else {k: v[0] for k, v in frames.items()}
            items = [(k, row[k]) for k in (frames.columns if hasattr(frames, "columns") else frames)
                     if np.ndim(row[k]) == 0]
            rec.log("/table", rr.TextDocument("## The frame's values\n\n" + _markdown_table(items, ("column", "value")),
                                              media_type="text/markdown"), static=True)
            return
        for column, (path, _name) in ROW_SERIES.items():
            if column not in frames:
                continue
            values = np.asarray(pd_to_float(frames[column]), dtype=float)
            ok = np.isfinite(values) & np.isfinite(delays)
            if not ok.any():
                continue
            rec.send_columns(
                path,
                indexes=[rr.TimeColumn("delay", duration=np.array([delay_ns(d) for d in delays[ok]], dtype="timedelta64[ns]")),
                         rr.TimeColumn("frame", sequence=np.flatnonzero(ok))],
                columns=rr.Scalars.columns(scalars=values[ok]),
            )

    def log_shots(self, result: Any, *, images: bool = True) -> None:
        """Log a folder of shots (`dropvision.analysis.shots.ShotsResult`): per shot (``shot`` timeline, its
        position in ``result.frames``) the frame as the camera stored it (``/camera``, read again
        from the folder) with every body's outline in its class colour and the liquid's volumes
        (``/camera/bodies``); static, one bar per shot for each column of `SHOT_BARS`
        (``/shots/<column>``), the shots' table (``/shots/table``) and the summary; the layout
        `shots_blueprint` (no time series: shots have no time between them)."""
        self._check_open()
        from dropvision.output.annotate import camera_image, frame_bodies, frame_geometry

        rr, rec = self._rr, self.stream
        if self._own_blueprint:
            rec.send_blueprint(shots_blueprint(), make_active=True, make_default=True)
        rec.log("/camera", rr.AnnotationContext(
            [(cid, label, colour) for cid, (label, colour) in CLASSES.items()]), static=True)
        frames, bodies = result.frames, result.bodies
        outlines = getattr(result, "outlines_camera", None) or []
        for i in range(len(frames) if images else 0):
            row = frames.iloc[i]
            rec.set_time("shot", sequence=i)
            orientation, _calib, path = frame_geometry(result, row)
            try:
                image = camera_image(path, orientation) if path is not None else None
            except Exception as exc:  # noqa: BLE001 - a shot that cannot be read again: said, not fatal
                rec.log("/log", rr.TextLog(f"shot {i} {row['file']}: not shown ({exc})", level="WARN"))
                image = None
            if image is not None:
                rec.log("/camera/image", rr.Image(camera_preview(image), color_model="L").compress(
                    jpeg_quality=TRANSMISSION_JPEG_QUALITY))
            strips, ids, texts = [], [], []
            for j in frame_bodies(result, row):
                pts = np.asarray(outlines[j]) if j < len(outlines) else np.zeros((0, 2))
                if len(pts) < 2:
                    continue
                b = bodies.iloc[int(j)]
                xy = np.vstack([pts, pts[:1]])[:, ::-1] + PIXEL_CENTRE_OFFSET  # (row, col) -> (x, y), closed
                strips.append(xy)
                ids.append(_CLASS_NAMES.get(str(b["body_class"]), CLASS_OUT_OF_FOCUS))
                vol = _finite(b.get("volume_nl"))
                texts.append(f"{b['body_class']}" + ("" if vol is None else f" {vol:.3g} nl"))
            if strips:
                rec.log("/camera/bodies", rr.LineStrips2D(strips, class_ids=ids, labels=texts, radii=-1.5,
                                                          show_labels=False))
            else:
                rec.log("/camera/bodies", rr.Clear(recursive=False))
            rec.log("/log", rr.TextLog(f"shot {i} {row['file']}: quality {row.get('quality')}", level="INFO"))
        table = result.shots
        for col in SHOT_BARS:
            if col in table:
                rec.log(f"/shots/{col}", rr.BarChart(np.nan_to_num(pd_to_float(table[col]), nan=0.0)), static=True)
        cols = [c for c in SHOT_TABLE_COLUMNS if c in table]
        lines = ["| shot | " + " | ".join(cols) + " |", "|---" * (len(cols) + 1) + "|"]
        for i, (_, r) in enumerate(table.iterrows()):
            cells = [(f"{float(r[c]):.4g}" if isinstance(r[c], (float, np.floating)) else str(r[c])) for c in cols]
            lines.append(f"| {i} | " + " | ".join(x.replace("|", "/") for x in cells) + " |")
        rec.log("/shots/table", rr.TextDocument("## Shots\n\n" + "\n".join(lines), media_type="text/markdown"),
                static=True)
        self.log_summary({k: v for k, v in result.summary.items() if k not in ("shots", "config", "software")})

    def log_summary(self, summary: Mapping[str, Any]) -> None:
        """Log the sequence summary (``summary.json`` content) as a static markdown table."""
        self._check_open()
        if not isinstance(summary, Mapping):
            raise ValueError(f"log_summary: summary must be a mapping, got {type(summary).__name__}")
        self.stream.log("/summary", self._rr.TextDocument(
            "## Summary\n\n" + _markdown_table(_flatten(summary)), media_type="text/markdown"),
            static=True)

    def close(self) -> None:
        """Flush and finalise the sinks (the .rrd footer is written); idempotent."""
        if self._closed:
            return
        self._closed = True
        close_stream(self.stream)  # never blocks on an unreachable viewer

    def _check_open(self) -> None:
        if self._closed:
            raise RuntimeError("RerunLogger is closed")


# --- command line ----------------------------------------------------------------------------


def logger_from_args(args: argparse.Namespace, app_id: str = DEFAULT_APPLICATION_ID, *,
                     recording_name: str | None = None) -> RerunLogger | None:
    """A :class:`RerunLogger` from parsed :func:`add_rerun_args` flags, or None when off.

    When None is returned nothing from rerun has been imported or initialised.
    """
    options = options_from_args(args, app_id, recording_name=recording_name)
    if options is not None:
        options = options.start_viewer()  # a viewer that cannot start: warned, work goes on
    return None if options is None or not options.enabled else RerunLogger(options)
