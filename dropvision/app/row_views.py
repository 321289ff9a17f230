"""Views of a printhead row (issue 32 item 5): the nozzle map in Rerun and on a report page.

`log_row` logs a measured row into a `dropvision.app.rerun_log.RerunLogger`'s stream:

``/nozzles/<quantity>/<state>``  :class:`rerun.Scalars` on the ``nozzle`` sequence timeline (time =
                                 nozzle number), one series per state, coloured by state
                                 (`STATE_COLOURS`): the nozzle map of volume_nl, velocity_m_s
                                 (a sequence of delays) and angle_mrad
``/row/frame``                   :class:`rerun.EncodedImage` of each frame (JPEG) at its ``delay``
                                 (duration) and ``frame`` (sequence) times
``/row/bodies``                  :class:`rerun.Points2D`, each body's centroid, radius from its area,
                                 coloured by the nozzle it came from (grey: not assigned)
``/row/plate``                   static :class:`rerun.LineStrips2D`, the plate's lower edge
``/row/axes``                    static :class:`rerun.LineStrips2D`, each live nozzle's axis (from its
                                 grid position along its angle), coloured by nozzle
``/row/nozzles``                 static :class:`rerun.TextDocument`, the nozzles table (markdown)
``/summary``                     static :class:`rerun.TextDocument`, summary.json

`write_row_report` writes a page (``index.html``, no scripts, no external resources) with the
nozzle map (``nozzle_map.png``), the frame with the axes and bodies (``row_frame.png``), the
head's pass/fail and the nozzles table, into a folder written atomically.

Coordinates: the canonical frame (drops travel down), pixel centres shifted by +0.5 px as in
`dropvision.app.rerun_log`.
"""

from __future__ import annotations

import html
import math
from pathlib import Path

import numpy as np

from dropvision.app.rerun_log import PIXEL_CENTRE_OFFSET

#: State -> RGB colour of the nozzle map.
STATE_COLOURS = {"ok": (46, 160, 67), "missing": (128, 128, 128), "weak": (230, 140, 0),
                 "deviated": (214, 39, 40), "satellites": (31, 119, 180)}
#: Quantities of the nozzle map: column -> label.
MAP_QUANTITIES = {"volume_nl": "volume (nl)", "velocity_m_s": "velocity (m/s)", "angle_mrad": "angle (mrad)"}
_UNASSIGNED = (160, 160, 160)


def nozzle_colour(i) -> tuple[int, int, int]:
    """A distinct colour per nozzle number (tab10 cycle); grey for None / NA."""
    palette = ((31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189),
               (140, 86, 75), (227, 119, 194), (188, 189, 34), (23, 190, 207), (127, 127, 127))
    try:
        return palette[int(i) % len(palette)]
    except (TypeError, ValueError):
        return _UNASSIGNED


def _axis_segments(nozzles, length_px: float) -> list[tuple[int, np.ndarray]]:
    """(nozzle, 2x2 (x, y) points) of each live nozzle's axis: from its grid position on the plate,
    ``length_px`` along its angle (+ towards increasing column)."""
    out = []
    for _, r in nozzles.iterrows():
        if r.state == "missing" or not np.isfinite(r.angle_mrad):
            continue
        a = r.angle_mrad * 1e-3
        x0, y0 = float(r.col_px), float(r.plate_row_px)
        out.append((int(r.nozzle), np.array([[x0, y0], [x0 + length_px * math.sin(a), y0 + length_px * math.cos(a)]])
                    + PIXEL_CENTRE_OFFSET))
    return out


def _markdown(nozzles) -> str:
    cols = [c for c in ("nozzle", "state", "volume_nl", "velocity_m_s", "angle_mrad", "pass", "reason", "pass_reason")
            if c in nozzles]
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for _, r in nozzles.iterrows():
        lines.append("| " + " | ".join(_fmt(r[c]) for c in cols) + " |")
    return "\n".join(lines)


def _fmt(v) -> str:
    if v is None:
        return ""
    if isinstance(v, (float, np.floating)):
        return "" if not np.isfinite(v) else f"{v:.4g}"
    s = str(v)
    return "" if s in ("<NA>", "nan") else s


def log_row(logger, nozzles, bodies, summary: dict, frames=()) -> None:
    """Log a measured row (`dropvision.analysis.nozzle_row.measure_row`'s tables and summary) and its frames
    (iterable of (index, delay_us, canonical image)) into ``logger`` (a RerunLogger)."""
    import rerun as rr

    from dropvision.app.rerun_log import TRANSMISSION_JPEG_QUALITY, delay_ns

    rec = logger.stream
    for q in MAP_QUANTITIES:
        for state, colour in STATE_COLOURS.items():
            rec.log(f"/nozzles/{q}/{state}", rr.SeriesPoints(names=state, colors=colour, marker_sizes=4.0),
                    static=True)
    for q in MAP_QUANTITIES:
        for state in STATE_COLOURS:
            sel = nozzles[(nozzles.state == state) & np.isfinite(nozzles[q].to_numpy(float))]
            if sel.empty:
                continue
            rec.send_columns(f"/nozzles/{q}/{state}",
                             indexes=[rr.TimeColumn("nozzle", sequence=sel.nozzle.to_numpy(np.int64))],
                             columns=rr.Scalars.columns(scalars=sel[q].to_numpy(float)))
    shape = None
    for index, delay_us, image in frames:
        rec.set_time("delay", duration=np.timedelta64(delay_ns(delay_us), "ns"))
        rec.set_time("frame", sequence=int(index))
        img = np.asarray(image)
        if img.dtype != np.uint8:
            img = np.round(img.astype(float) * 255.0 / max(float(img.max()), 1.0)).astype(np.uint8)
        shape = img.shape[:2]
        rec.log("/row/frame", rr.Image(img, color_model="L").compress(jpeg_quality=TRANSMISSION_JPEG_QUALITY))
        rec.log("/row/frame", rr.EncodedImage.from_fields(draw_order=-5.0))
        b = bodies[np.isclose(bodies.delay_us.to_numpy(float), float(delay_us))]
        if len(b):
            rec.log("/row/bodies", rr.Points2D(
                np.c_[b.col_px.to_numpy(float), b.row_px.to_numpy(float)] + PIXEL_CENTRE_OFFSET,
                radii=np.sqrt(b.area_px.to_numpy(float) / math.pi),
                colors=[nozzle_colour(n) for n in b.nozzle], show_labels=False,
                labels=[f"nozzle {n} {c} {v:.4g} nl" for n, c, v in zip(b.nozzle, b.body_class, b.volume_nl)]))
    length = 0.8 * (shape[0] if shape else 500.0)
    if shape is not None:
        x = np.array([0.0, shape[1] - 1.0])
        row0, slope = summary["plate_row_px"], math.tan(summary["plate_slope_mrad"] * 1e-3)
        y = row0 + slope * (x - (shape[1] - 1) / 2.0)
        rec.log("/row/plate", rr.LineStrips2D([np.c_[x, y] + PIXEL_CENTRE_OFFSET], colors=(0, 255, 255), show_labels=False),
                static=True)
    segs = _axis_segments(nozzles, length)
    if segs:
        rec.log("/row/axes", rr.LineStrips2D([s for _, s in segs], colors=[nozzle_colour(i) for i, _ in segs],
                                             labels=[f"nozzle {i}" for i, _ in segs], show_labels=False),
                static=True)
    rec.log("/row/nozzles", rr.TextDocument("## Nozzles\n\n" + _markdown(nozzles), media_type="text/markdown"),
            static=True)
    logger.log_summary(summary)


def write_row_report(out_dir, nozzles, bodies, summary: dict, image=None, *, overwrite: bool = False) -> Path:
    """The row's report page in ``out_dir`` (atomically): index.html, nozzle_map.png and, with the
    first frame's canonical ``image``, row_frame.png.  Returns the page's path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from dvcore.atomic import atomic_dir

    out_dir = Path(out_dir)
    with atomic_dir(out_dir, overwrite=overwrite, kind="report") as tmp:
        fig, axes = plt.subplots(len(MAP_QUANTITIES), 1, figsize=(8, 7), sharex=True)
        for ax, (q, label) in zip(axes, MAP_QUANTITIES.items()):
            for state, colour in STATE_COLOURS.items():
                sel = nozzles[nozzles.state == state]
                if sel.empty:
                    continue
                u = q.replace("_nl", "_uncertainty_nl").replace("_m_s", "_uncertainty_m_s").replace(
                    "_mrad", "_uncertainty_mrad")
                y = sel[q].to_numpy(float)
                if state == "missing":  # where the others' values are: a cross on the axis
                    ax.plot(sel.nozzle, np.full(len(sel), np.nanmedian(nozzles[q]) if nozzles[q].notna().any() else 0.0),
                            "x", color=np.array(colour) / 255, label=state)
                    continue
                if not np.isfinite(y).any():
                    continue
                ax.errorbar(sel.nozzle, y, yerr=sel[u].to_numpy(float) if u in sel else None, fmt="o",
                            color=np.array(colour) / 255, label=state, capsize=3)
            if not nozzles[q].notna().any():
                ax.text(0.5, 0.5, "not measured (one delay)", transform=ax.transAxes, ha="center", va="center")
            ax.set_ylabel(label)
            ax.grid(alpha=0.3)
        axes[0].legend(fontsize=8, ncol=len(STATE_COLOURS))
        axes[-1].set_xlabel("nozzle")
        fig.suptitle("nozzle map")
        fig.tight_layout()
        fig.savefig(tmp / "nozzle_map.png", dpi=100)
        plt.close(fig)
        has_frame = image is not None
        if has_frame:
            img = np.asarray(image, float)
            fig, ax = plt.subplots(figsize=(10, 10 * img.shape[0] / img.shape[1] + 0.5))
            ax.imshow(img, cmap="gray", interpolation="nearest")
            for i, seg in _axis_segments(nozzles, 0.8 * img.shape[0]):
                ax.plot(seg[:, 0] - PIXEL_CENTRE_OFFSET, seg[:, 1] - PIXEL_CENTRE_OFFSET, "-", lw=1, color=np.array(nozzle_colour(i)) / 255)
            b = bodies[bodies.delay_us == bodies.delay_us.min()] if len(bodies) else bodies
            for _, r in b.iterrows():
                ax.add_patch(plt.Circle((r.col_px, r.row_px), math.sqrt(r.area_px / math.pi), fill=False, lw=1.5,
                                        color=np.array(nozzle_colour(r.nozzle)) / 255))
            ax.set_axis_off()
            fig.tight_layout()
            fig.savefig(tmp / "row_frame.png", dpi=100)
            plt.close(fig)
        (tmp / "index.html").write_text(_page(nozzles, summary, has_frame), encoding="utf-8")
    return out_dir / "index.html"


def _page(nozzles, summary: dict, has_frame: bool) -> str:
    e = html.escape
    hp = summary.get("head_pass")
    verdict = ("no limits given" if hp is None else
               "PASS" if hp["pass"] else f"FAIL (nozzles {', '.join(map(str, hp['failed_nozzles']))})")
    cols = [c for c in nozzles.columns]
    head = "".join(f"<th>{e(c)}</th>" for c in cols)
    body = "".join("<tr>" + "".join(f"<td>{e(_fmt(r[c]))}</td>" for c in cols) + "</tr>" for _, r in nozzles.iterrows())
    counts = ", ".join(f"{v} {k}" for k, v in summary.get("state_counts", {}).items() if v)
    facts = [("sequence", summary.get("sequence")), ("layout", summary.get("layout")),
             ("nozzles", f"{summary.get('n_nozzles')} ({counts})"), ("pitch (µm)", _fmt(summary.get("pitch_um"))),
             ("pitch source", summary.get("pitch_source")),
             ("volume CV", f"{_fmt(summary.get('volume_cv'))} ± {_fmt(summary.get('volume_cv_uncertainty'))}"),
             ("velocity CV", f"{_fmt(summary.get('velocity_cv'))} ± {_fmt(summary.get('velocity_cv_uncertainty'))}"),
             ("head", verdict)]
    if hp is not None:
        facts.append(("limits", ", ".join(f"{k} {v:g}" for k, v in hp["limits"].items())
                      + (f"; reference {hp['reference']}" if hp.get("reference") else "")))
    notes = "".join(f"<li>{e(str(n))}</li>" for n in summary.get("notes", []))
    return ("<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>printhead row</title>"
            "<style>body{font-family:sans-serif;margin:2em}table{border-collapse:collapse}"
            "td,th{border:1px solid #ccc;padding:2px 6px;font-size:90%}</style></head><body>\n"
            "<h1>Printhead row</h1>\n<table>"
            + "".join(f"<tr><th>{e(k)}</th><td>{e(str(v))}</td></tr>" for k, v in facts) + "</table>\n"
            "<h2>Nozzle map</h2>\n<img src=\"nozzle_map.png\" alt=\"nozzle map\">\n"
            + ("<h2>Frame</h2>\n<img src=\"row_frame.png\" alt=\"first frame, each nozzle's axis and bodies coloured "
               "by nozzle\" style=\"max-width:100%\">\n" if has_frame else "")
            + f"<h2>Nozzles</h2>\n<table id=\"nozzles\"><tr>{head}</tr>{body}</table>\n"
            + (f"<h2>Notes</h2><ul>{notes}</ul>\n" if notes else "") + "</body></html>\n")
