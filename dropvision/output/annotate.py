"""A measured frame drawn for a notebook (`annotate`, like trackpy's ``tp.annotate``) and the short
``repr`` of a result (`short_repr`).

`annotate` shows the frame as the camera stored it (orientation as stored, the holder, raw grey
levels), the outline of every body of bodies.parquet coloured by its class (`CLASS_COLOURS`), the
jetting axis from the nozzle tip, and a label with the volume of each liquid body. It works for a
`dropvision.measurement.MeasureResult` (a frame of a sequence) and a `dropvision.analysis.shots.ShotsResult`
(a shot). matplotlib is imported only when a frame is drawn.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np

from dropvision.io.orientation import canonical_to_original, swaps_axes

#: body_class -> matplotlib colour of its outline (the Rerun view's palette, `dropvision.app.rerun_log.CLASSES`)
CLASS_COLOURS = {
    "nozzle": "#969696", "attached": "#2878ff", "main_drop": "#e62828", "satellite": "#ffaa00",
    "tail": "#ff3caa", "border": "#b4e628", "mist": "#965aff", "dust": "#3cc850", "noise": "#00c8c8",
}
#: classes whose volume is written next to the body
_LABELLED = ("attached", "main_drop", "satellite", "tail", "border")


def _fmt(v, unit: str = "") -> str:
    try:
        v = float(v)
    except (TypeError, ValueError):
        return "n/a"
    if not math.isfinite(v):
        return "n/a"
    text = f"{v:.0f}" if abs(v) >= 1000 else f"{v:.3g}"  # 7785 nl, not 7.78e+03 nl
    return text + (f" {unit}" if unit else "")


def short_repr(result) -> str:
    """A few lines: what was measured, the headline figures, and where the tables are."""
    s, name = result.summary or {}, type(result).__name__
    if s.get("kind") == "shots":
        lines = [f"<{name}: {s.get('n_measured')} of {s.get('n_shots')} shot(s) measured; "
                 f"{len(s.get('errors') or [])} error(s)>",
                 f"  drop volume median {_fmt(s.get('drop_volume_median_nl'), 'nl')} "
                 f"(min {_fmt(s.get('drop_volume_min_nl'))}, max {_fmt(s.get('drop_volume_max_nl'))}), "
                 f"satellites median {_fmt(s.get('n_satellites_median'))}",
                 f"  quality {s.get('quality_counts')}",
                 "  .shots (a row per image), .frames, .bodies, .summary; .annotate(i) draws shot i"]
        return "\n".join(lines)
    seq = s.get("sequence", "frames in memory")
    frames = getattr(result, "frames", None)
    if s.get("n_frames") == 1 and frames is not None and len(frames):  # one frame: what it shows
        row = frames.iloc[0]
        what = (f"  main drop {_fmt(row.get('drop_volume_nl'), 'nl')}, {_fmt(row.get('n_satellites'))} satellite(s), "
                f"attached {_fmt(row.get('attached_volume_nl'), 'nl')}")
    else:
        what = (f"  pinch-off {_fmt(s.get('pinchoff_us'), 'us')}, in-flight volume "
                f"{_fmt(s.get('inflight_volume_nl'), 'nl')}, velocity {_fmt(s.get('jetting_velocity_m_s'), 'm/s')}")
    lines = [f"<{name}: {Path(seq).name if seq else '?'}, {s.get('n_measured')} of {s.get('n_frames')} "
             f"frame(s) measured>",
             what,
             f"  quality {s.get('quality_counts')}",
             "  .frames, .bodies, .summary, .per_delay(); .annotate(i) draws frame i"]
    if getattr(result, "nozzles", None) is not None:
        lines.insert(1, f"  printhead row: {len(result.nozzles)} nozzle row(s) in .nozzles")
    return "\n".join(lines)


def _frame_row(result, frame):
    """(frames-table row, index) of ``frame``: a position in ``result.frames`` or a file name."""
    frames = result.frames
    if isinstance(frame, (str, Path)):
        hits = np.flatnonzero(frames["file"].astype(str).to_numpy() == str(frame))
        if not hits.size:
            raise KeyError(f"annotate: no frame of file {str(frame)!r} (files: {', '.join(map(str, frames['file'][:5]))}"
                           f"{', ...' if len(frames) > 5 else ''})")
        frame = int(hits[0])
    if not isinstance(frame, (int, np.integer)) or isinstance(frame, bool):
        raise TypeError(f"annotate: frame is a position in .frames (0 to {len(frames) - 1}) or a file name, "
                        f"got {frame!r}")
    if not -len(frames) <= frame < len(frames):
        raise IndexError(f"annotate: frame {frame} out of range ({len(frames)} frame(s))")
    return frames.iloc[int(frame)], int(frame) % len(frames)


def frame_geometry(result, row) -> tuple[str, dict, Path | None]:
    """(orientation, calibration dict, folder holding the image) of a frames-table row."""
    s = result.summary
    if s.get("kind") == "shots":
        entry = next((e for e in s.get("shots", []) if e.get("file") == row["file"]), {})
        inputs = [Path(p) for p in s.get("inputs", [])]
        folder = inputs[0] if len(inputs) == 1 and inputs[0].is_dir() else None
        path = Path(row["file"]) if folder is None else folder / row["file"]
        return entry.get("orientation") or "down", entry.get("calibration") or {}, path
    seq = s.get("sequence")
    path = Path(seq) / row["file"] if seq and Path(seq).is_dir() else None  # "<in-memory>": frames in memory
    return s.get("orientation") or "down", s.get("calibration") or {}, path


def camera_image(path: Path, orientation: str, page=None) -> np.ndarray:
    """The grey image of ``path`` (a page of a TIFF stack) as the camera stored it."""
    from dropvision.io.orientation import from_canonical
    from dropvision.io.sequence import open_sequence

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the colour note was given when the frame was measured
        with open_sequence(path.parent, only_files=[path.name], overrides={"orientation": orientation},
                           require_pixel_size=False) as seq:
            pick = next((i for i, f in enumerate(seq.meta.frames)
                         if page is None or f.page is None or int(f.page) == int(page)), 0)
            fr = seq.read(pick)
    if fr.image is None:
        raise ValueError(f"{path}: {fr.error}")
    return from_canonical(fr.image, orientation)


def frame_bodies(result, row):
    """Positions in ``result.bodies`` of the bodies of a frames-table row."""
    b = result.bodies
    if b is None or not len(b):
        return np.zeros(0, int)
    same = b["file"].astype(str).to_numpy() == str(row["file"])
    if "repeat" in b and "repeat" in row:
        same &= b["repeat"].to_numpy() == int(row["repeat"])
    if "delay_us" in b and "delay_us" in row:
        same &= np.isclose(b["delay_us"].to_numpy(float), float(row["delay_us"]), rtol=0, atol=1e-9)
    if "page" in b and "page" in row and not _isna(row["page"]):
        same &= b["page"].astype("float").to_numpy() == float(row["page"])
    return np.flatnonzero(same)


def _isna(v) -> bool:
    import pandas as pd
    return v is None or bool(pd.isna(v))


def annotate(result, frame=0, image=None, *, ax=None, labels: bool = True):
    """Draw a measured frame as the camera took it, with its bodies, axis and volumes.

    Parameters
    ----------
    result : MeasureResult or ShotsResult
    frame : int or str
        Position in ``result.frames`` (a shot: the shot's row), or the image's file name.
    image : array_like, optional
        The frame as stored by the camera (2-D grey or colour); default: read from the folder the
        result was measured from (required for frames in memory).
    ax : matplotlib Axes, optional
        Where to draw; default a new figure.
    labels : bool
        Write the class and volume next to each liquid body.

    Returns
    -------
    matplotlib.axes.Axes
        The image, one outline (a closed ``Line2D`` labelled ``body <id>: <class>``) per body of
        ``result.bodies`` in that frame, the axis (``Line2D`` labelled ``axis``) and the texts.
    """
    import matplotlib.pyplot as plt

    row, pos = _frame_row(result, frame)
    orientation, calib, path = frame_geometry(result, row)
    if image is None:
        if path is None:
            raise ValueError("annotate: frames measured in memory: give the image (annotate(i, image=frames[i]))")
        image = camera_image(path, orientation, None if _isna(row.get("page")) else row.get("page"))
    image = np.asarray(image)
    cam_shape = image.shape[:2]
    canon_shape = (cam_shape[1], cam_shape[0]) if swaps_axes(orientation) else cam_shape
    if ax is None:
        _, ax = plt.subplots(figsize=(6, 6 * cam_shape[0] / max(cam_shape[1], 1)))
    top = float(np.iinfo(image.dtype).max) if np.issubdtype(image.dtype, np.integer) else None
    if image.ndim == 2:
        ax.imshow(image, cmap="gray", vmin=0, vmax=top, interpolation="nearest")
    else:
        ax.imshow(image if top is None else image / top, interpolation="nearest")
    outlines = getattr(result, "outlines_camera", None)
    idx = frame_bodies(result, row)
    bodies = result.bodies
    n_text = 0
    for i in idx:
        b = bodies.iloc[int(i)]
        cls = str(b["body_class"])
        colour = CLASS_COLOURS.get(cls, "white")
        pts = None if outlines is None or int(i) >= len(outlines) else np.asarray(outlines[int(i)])
        if pts is not None and len(pts):
            closed = np.vstack([pts, pts[:1]])
            ax.plot(closed[:, 1], closed[:, 0], "-", color=colour, lw=1.2, label=f"body {int(b['body_id'])}: {cls}")
        if labels and cls in _LABELLED and np.isfinite(float(b.get("row_camera_px", np.nan))):
            vol = b["volume_nl"]
            text = f"{cls.replace('_', ' ')} {_fmt(vol, 'nl')}" if cls != "border" else "border (cut)"
            whole = float(row.get("drop_volume_nl", np.nan)) if cls == "main_drop" else np.nan
            if np.isfinite(whole) and abs(whole - float(vol)) > 0.005 * abs(whole):
                # satellites split off at the waist keep their volume in the main drop's (frames, summary)
                text = f"main drop {_fmt(whole, 'nl')} (this part {_fmt(vol, 'nl')})"
            # the labels in a column at the top right (never on top of each other), a line to each body
            ax.annotate(text, (float(b["col_camera_px"]), float(b["row_camera_px"])),
                        xytext=(0.98, 0.96 - 0.07 * n_text), textcoords="axes fraction", ha="right", va="top",
                        color="white", fontsize=8,
                        bbox={"boxstyle": "round,pad=0.2", "fc": colour, "alpha": 0.8, "lw": 0},
                        arrowprops={"arrowstyle": "-", "color": colour, "lw": 0.8})
            n_text += 1
    tip, col = calib.get("tip_row"), calib.get("axis_col")
    tilt = math.radians(float(calib.get("tilt_deg") or 0.0))
    if col is not None and np.isfinite(float(col)):
        t0 = float(tip) if tip is not None and np.isfinite(float(tip)) else 0.0
        rows = np.array([t0, canon_shape[0] - 1.0])
        c, s = math.cos(tilt), math.sin(tilt)
        t = (rows - t0) / c
        r_cam, c_cam = canonical_to_original(t0 + t * c, float(col) + t * s, orientation, canon_shape)
        ax.plot(c_cam, r_cam, "--", color="yellow", lw=0.8, label="axis")
    ax.set_xlim(-0.5, cam_shape[1] - 0.5)
    ax.set_ylim(cam_shape[0] - 0.5, -0.5)
    title = f"{row['file']}" + (f"  delay {_fmt(row['delay_us'], 'us')}" if "delay_us" in row else "")
    ax.set_title(title, fontsize=9)
    ax.set_axis_off()
    return ax
