"""The live journal of `dropvision watch`: ``OUT/live/frames.jsonl``, one JSON line per frame.

Each frame measured live appends its provisional row (`live_row`: the frame's own measurement,
before the sequence-level analysis; columns `dvcore.schema.LIVE_FRAMES`) in one ``write`` of one
whole line (`Journal`), so a kill leaves whole rows; `read_journal` drops a cut last line, and
`journal_table` reads the rows as a table.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import dropvision.quality as q
from dropvision.frame.measure_frame import FrameRecord
from dvcore import schema
from dvcore.jsonio import loads_strict

__all__ = ["JOURNAL", "Journal", "live_row", "read_journal", "journal_table"]

#: The journal of live rows, relative to OUT (JSON lines, one per measured frame; `dvcore.schema.LIVE_FRAMES`).
JOURNAL = schema.LIVE_FRAMES.file


def read_journal(out_dir) -> list[dict]:
    """Rows of ``OUT/live/frames.jsonl`` (whole lines only; a cut last line is left out).

    Parameters
    ----------
    out_dir : str or Path
        The watch's output folder.

    Returns
    -------
    list of dict
        One per frame measured live, in the order they were measured.
    """
    path = Path(out_dir) / JOURNAL
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        return []
    rows = []
    for line in data.split(b"\n")[:-1]:  # the part after the last newline is cut: left out
        try:
            row = loads_strict(line)
        except ValueError:
            continue
        if isinstance(row, dict) and isinstance(row.get("file"), str):
            rows.append(row)
    return rows


def journal_table(out_dir):
    """The journal as a table: `read_journal`'s rows with the columns and types of
    `dvcore.schema.LIVE_FRAMES` (null numbers as NaN, ``page`` nullable integer).

    Parameters
    ----------
    out_dir : str or Path
        The watch's output folder.

    Returns
    -------
    pandas.DataFrame
    """
    import pandas as pd

    table = pd.DataFrame(read_journal(out_dir), columns=schema.LIVE_FRAMES.column_names)
    for col in schema.LIVE_FRAMES.columns:
        if col.dtype == "int":
            table[col.name] = table[col.name].astype("Int64")
        elif col.dtype == "float":
            table[col.name] = pd.to_numeric(table[col.name]).astype(float)
    return table


def live_row(rec: FrameRecord, cal_frames: int) -> dict:
    """A frame's provisional row: its own measurement, before the sequence-level analysis
    (volumes nl, positions µm along (z) and across (x) the axis, delays µs)."""
    main = rec.bodies[0] if rec.bodies else None
    return {
        "file": rec.file, "page": rec.page, "delay_us": rec.delay_us, "repeat": rec.repeat,
        "attached_volume_nl": rec.attached_volume_nl,
        "attached_volume_uncertainty_nl": rec.attached_volume_uncertainty_nl,
        "n_detached": len(rec.bodies),
        "drop_volume_nl": main.volume_nl if main else math.nan,
        "drop_z_um": main.z_um if main else math.nan,
        "drop_x_um": main.x_um if main else math.nan,
        # a frame that could not be read says so in its quality too, never "ok" beside its error
        "quality": q.join([*rec.flags, q.UNREADABLE] if rec.error is not None else rec.flags),
        "blur_px": rec.blur_px, "gain": rec.gain, "error": rec.error,
        "calibration_frames": cal_frames,
    }


class Journal:
    """Append-only JSON lines: one ``os.write`` of one whole line per row."""

    def __init__(self, path: Path):
        self.path = path
        self._fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o666)  # the umask applies

    def append(self, row: dict) -> None:
        from dvcore.atomic import to_json

        line = to_json(row, indent=None).encode("utf-8")  # ends with "\n"
        view = memoryview(line)
        try:
            while view:  # a regular file takes it in one write; a short write is continued
                view = view[os.write(self._fd, view):]
        except OSError as exc:  # a full disk: named by the journal, not by the input
            raise OSError(exc.errno, exc.strerror or str(exc), str(self.path)) from None

    def close(self) -> None:
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1
