"""Writing a measurement: frames.parquet (+ frames.csv), bodies.parquet, per_delay.parquet, summary.json.

The frames table is checked against its schema before anything is written
(`dropvision.analysis.sequence_summary.check_frames_table`): a missing, undeclared or mistyped column, or an
infinite value, is an error naming it, never a silently empty column nor a file its readers refuse.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from dropvision.analysis.sequence_summary import check_frames_table, per_delay
from dvcore.atomic import write_json

if TYPE_CHECKING:  # pragma: no cover - typing only
    from dropvision.measurement import MeasureResult


def write_result(result: "MeasureResult", out_dir, *, csv: bool = False, extra_summary: dict | None = None) -> None:
    """Write a measurement's files into a folder.

    Parameters
    ----------
    result : MeasureResult
        Frames table and summary.
    out_dir : str or Path
        Created if missing; the files are written in place (wrap in `dvcore.atomic.atomic_dir`
        for an atomic result, as `dropvision.measurement.measure_sequence` does).
    csv : bool
        Also write frames.csv.
    extra_summary : dict, optional
        Entries added to (or replacing those of) summary.json.

    Raises
    ------
    dvcore.schema.SchemaError
        The frames table does not follow its schema (nothing is written).
    """
    out = Path(out_dir)
    if result.summary.get("kind") == "printhead-row":  # issue 32: its own tables
        from dropvision.analysis.nozzle_row import write_row_files

        write_row_files(out, result.nozzles, result.frames, result.bodies, {**result.summary, **(extra_summary or {})},
                        csv=csv)
        return
    check_frames_table(result.frames, out / "frames.parquet")
    out.mkdir(parents=True, exist_ok=True)
    result.frames.to_parquet(out / "frames.parquet", index=False)
    if csv:
        result.frames.to_csv(out / "frames.csv", index=False)
    if result.bodies is not None:
        result.bodies.to_parquet(out / "bodies.parquet", index=False)
    per_delay(result.frames).to_parquet(out / "per_delay.parquet", index=False)
    summary = dict(result.summary)
    if extra_summary:
        summary.update(extra_summary)
    write_json(out / "summary.json", summary)


def check_shots_result(result, out_dir, *, extra_summary: dict | None = None) -> dict:
    """Check a shot folder's tables and summary.json (``summary`` and ``extra_summary``) against
    their schemas, naming the files as they will lie in ``out_dir``; returns the summary to write.

    Raises
    ------
    dvcore.schema.SchemaError
        A table or summary.json does not follow its declaration.
    """
    from dvcore import schema

    out = Path(out_dir)
    summary = {**result.summary, **(extra_summary or {})}
    check_frames_table(result.frames, out / "frames.parquet")
    schema.check_table(result.shots, schema.SHOTS, out / "shots.parquet")
    schema.check_document(summary, schema.SHOTS_SUMMARY, out / "summary.json")
    return summary


def write_shots_result(result, out_dir, summary: dict, *, csv: bool = False) -> None:
    """Write a shot folder's files (`dropvision.analysis.shots.ShotsResult`) into ``out_dir`` (in place: wrap
    in `dvcore.atomic.atomic_dir`): shots.parquet, frames.parquet (+ frames.csv), bodies.parquet
    when there are bodies, and ``summary`` (from `check_shots_result`) as summary.json."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    result.shots.to_parquet(out / "shots.parquet", index=False)
    result.frames.to_parquet(out / "frames.parquet", index=False)
    if csv:
        result.frames.to_csv(out / "frames.csv", index=False)
    if result.bodies is not None:
        result.bodies.to_parquet(out / "bodies.parquet", index=False)
    write_json(out / "summary.json", summary)
