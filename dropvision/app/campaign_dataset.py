"""The campaign's dataset: each measured sequence's share of it and the dataset files.

`shard_part` reads one finished shard (``shards/<id>/frames.parquet`` and ``summary.json``,
checked against their schema) into its :class:`ShardPart`: its ``timeseries.parquet`` rows
(per strobe delay, averaged over the attached frames) and its ``summary.parquet`` row;
`assemble_dataset` writes ``timeseries.parquet``, ``summary.parquet`` and ``dataset.json`` from
the parts, refusing sequences that disagree on the nozzle, the ink or the printhead drive; the
shot folders' rows (:class:`ShotsPart`, their shard's shots.parquet) go into ``shots.parquet``.

A sequence's drive is the paper's trapezoid (its ``u1_um_per_ms``, ``u2_um`` columns) or another
waveform template of `identify.waveform` (sequence.json ``waveform`` in the template form: its
parameters take the place of u1/u2, one column each, and dataset.json records the template,
``waveform``, and the parameters' units, ``waveform_parameters``; issue 31). One dataset is one
template: sequences of different templates (or constants) are refused.
The campaign driver is `dropvision.app.campaign.run_campaign`.
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from dvcore import schema
from dvcore.atomic import write_bytes, write_json
from dvcore.jsonio import load_json_hardened
from dvcore.versions import software_versions
from identify.waveform import DEAD_TIME_US, HOLD_PRESET_US, U3_PRESET_UM_PER_MS, template_from_dict

__all__ = ["DATASET_SCHEMA", "TIMESERIES_COLUMNS", "SUMMARY_COLUMNS", "ShardPart", "ShotsPart", "shard_part",
           "assemble_dataset", "sequence_controls"]

DATASET_SCHEMA = schema.DATASET.schema
TIMESERIES_COLUMNS = schema.TIMESERIES.column_names
SUMMARY_COLUMNS = schema.DATASET_SUMMARY.column_names
#: The trapezoid's parameters (columns 2 and 3 of both tables; another template's take their place).
_CONTROLS = ("u1_um_per_ms", "u2_um")
_TS_REST = [c for c in TIMESERIES_COLUMNS if c not in ("sequence_id", *_CONTROLS)]
_SU_REST = [c for c in SUMMARY_COLUMNS if c not in ("sequence_id", *_CONTROLS)]
#: What a sequence of the paper's flat waveform form is called where templates are compared.
_TRAPEZOID = "the paper's trapezoid (u1_um_per_ms, u2_um)"


def sequence_controls(wf) -> tuple[dict | None, dict | None, str | None]:
    """The drive of a sequence (its validated sequence.json ``waveform``) as the dataset holds it.

    Returns
    -------
    (template, controls, error)
        ``template``: ``{"template": name, <constants>}`` of a waveform template other than the
        paper's trapezoid (`dropvision.io.overrides.validate_waveform` gives the trapezoid in the flat
        form), else None; ``controls``: the parameter columns, name -> value (``u1_um_per_ms``,
        ``u2_um`` for the trapezoid); ``error``: why the sequence cannot enter the dataset (then
        the others are None).
    """
    wf = wf or {}
    if "template" in wf:
        params = wf.get("parameters")
        if not isinstance(params, dict) or not params:
            return None, None, (f"sequence.json waveform template {wf['template']!r} has no parameters: a sequence "
                                "needs them (only a shot folder's labels may give them)")
        template = {k: v for k, v in wf.items() if k not in ("parameters", "dead_time_us")}
        return template, {k: float(v) for k, v in params.items()}, None
    if "u1_um_per_ms" not in wf or "u2_um" not in wf:
        return None, None, "sequence.json has no waveform u1_um_per_ms/u2_um"
    return None, {"u1_um_per_ms": float(wf["u1_um_per_ms"]), "u2_um": float(wf["u2_um"])}, None


def _timeseries_rows(seq_id: str, controls: dict, frames: pd.DataFrame) -> pd.DataFrame:
    frames = frames.copy()
    frames["_grown_attached"] = frames["grown_volume_nl"].where(frames["attached"])
    frames["_flow_attached"] = frames["flow_velocity_m_s"].where(frames["attached"])
    g = frames.groupby("delay_us", sort=True)
    out = pd.DataFrame(
        {
            "delay_us": g.size().index.to_numpy(dtype=float),
            "grown_volume_nl": g["_grown_attached"].mean().to_numpy(dtype=float),
            "flow_velocity_m_s": g["_flow_attached"].mean().to_numpy(dtype=float),
            "attached": g["attached"].all().to_numpy(dtype=bool),
        }
    )
    for i, (name, value) in enumerate(controls.items()):
        out.insert(i, name, float(value))
    out.insert(0, "sequence_id", seq_id)
    return out[["sequence_id", *controls, *_TS_REST]]


def _same(a, b, tol: float) -> bool:
    if isinstance(a, (int, float)) and isinstance(b, (int, float)):
        return math.isclose(a, b, rel_tol=tol, abs_tol=tol)
    return a == b


def _common(values, what: str, tol: float = 1e-9, why: str = "one dataset is one nozzle and one ink"):
    """The one value the sequences share (None when none gives it).

    ``values``: (sequence id, value) pairs. Sequences that differ are refused, naming the
    sequences of each value: one dataset is one nozzle and one ink (per-sequence calibration,
    the pixel size, is not compared here: see `assemble_dataset`).
    """
    pairs = [(sid, v) for sid, v in values if v is not None]
    if not pairs:
        return None
    groups: list[tuple[object, list[str]]] = []
    for sid, v in pairs:
        for value, names in groups:
            if _same(value, v, tol):
                names.append(sid)
                break
        else:
            groups.append((v, [sid]))
    if len(groups) > 1:
        def named(names):
            return ", ".join(names[:3]) + (f" and {len(names) - 3} more" if len(names) > 3 else "")

        shown = "; ".join(f"{value!r} in {named(names)}" for value, names in groups[:4])
        raise ValueError(f"sequences disagree on {what}: {shown}; {why}")
    return groups[0][0]


@dataclass(frozen=True)
class ShardPart:
    """One ok shard's share of the dataset (`shard_part`): its timeseries rows, its summary
    row and its metadata. ``input_hash`` ties it to the shard it was read from; ``template``:
    its waveform template (`sequence_controls`; None: the paper's trapezoid)."""

    input_hash: str | None
    timeseries: pd.DataFrame
    row: dict
    meta: tuple
    template: dict | None = None


@dataclass(frozen=True)
class ShotsPart:
    """One ok shot folder's share of the dataset: its shots.parquet rows, the ``shot_folder``
    column first (`dvcore.schema.DATASET_SHOTS`). ``input_hash`` ties it to its shard."""

    input_hash: str | None
    table: pd.DataFrame


def _shots_part(dataset_dir, seq_id: str, entry: dict) -> ShotsPart:
    path = Path(dataset_dir) / "shards" / entry["shard"] / "shots.parquet"
    table = pd.read_parquet(path)
    schema.check_table(table, schema.SHOTS, path)
    if "shot_folder" in table.columns:  # a label of that name
        table = table.rename(columns={"shot_folder": "label_shot_folder"})
    table.insert(0, "shot_folder", seq_id)
    return ShotsPart(entry.get("input_hash"), table)


def shard_part(dataset_dir, seq_id: str, entry: dict) -> ShardPart | ShotsPart | None:
    """Read one ok shard into its :class:`ShardPart` (a shot folder, ``entry["kind"]`` "shots": its
    :class:`ShotsPart`); None (and ``entry`` marked failed) when its sequence.json has no waveform
    u1/u2 nor a waveform template with its parameters (`sequence_controls`). Raises when the
    shard's files are unreadable or break the schema.

    The campaign driver calls it as each sequence finishes, while the workers measure the
    others, so that the dataset's final assembly only concatenates (see `run_campaign`)."""
    if entry.get("kind") == "shots":
        return _shots_part(dataset_dir, seq_id, entry)
    meta = entry.get("meta") or {}
    wf = meta.get("waveform") or {}
    template, controls, error = sequence_controls(wf)
    if error is not None:
        entry["status"], entry["error"] = "failed", error
        return None
    shard = Path(dataset_dir) / "shards" / entry["shard"]
    frames = pd.read_parquet(shard / "frames.parquet")
    schema.check_table(frames, schema.FRAMES, shard / "frames.parquet")
    summary = schema.check_document(load_json_hardened(shard / "summary.json", schema.SchemaError), schema.SUMMARY,
                                    shard / "summary.json")
    jv = summary.get("jetting_velocity_m_s")
    return ShardPart(
        input_hash=entry.get("input_hash"),
        timeseries=_timeseries_rows(seq_id, controls, frames),
        row={
            "sequence_id": seq_id,
            **controls,
            "pinchoff_us": summary.get("pinchoff_us"),
            "grown_volume_at_pinchoff_nl": summary.get("grown_volume_at_pinchoff_nl"),
            "inflight_volume_nl": summary.get("inflight_volume_nl"),
            "jetting_velocity_m_s": jv,
            "flow_velocity_at_max_stroke_m_s": summary.get("flow_velocity_at_max_stroke_m_s"),
            "inflight_volume_std_nl": summary.get("inflight_volume_std_nl"),
            "jetting_velocity_se_m_s": summary.get("jetting_velocity_se_m_s"),
            "satellites": summary.get("satellites"),
            "n_frames": len(frames),
            "n_errors": len(summary.get("errors") or []),
            "pixel_size_ratio": (summary.get("calibration") or {}).get("pixel_size_ratio"),
            "pixel_size_ratio_uncertainty": (summary.get("calibration") or {}).get("pixel_size_ratio_uncertainty"),
            "inflight_frames": summary.get("inflight_frames"),
        },
        meta=(seq_id, meta, wf),
        template=template,
    )


def assemble_dataset(dataset_dir, entries: dict[str, dict], parts: dict[str, ShardPart] | None = None) -> None:
    """Write timeseries.parquet, summary.parquet and dataset.json from the ok shards, and
    shots.parquet from the ok shot folders (where the campaign holds any, or an earlier run wrote
    one: then rewritten, empty when none is left).

    ``parts``: sequence id -> its :class:`ShardPart` (:class:`ShotsPart`) read earlier (as the
    sequence finished); a part is used only while it matches the entry's input hash, any other
    ok shard is read here. The dataset is the same either way (rows in sequence-id order)."""
    dataset_dir = Path(dataset_dir)
    parts = parts or {}
    ts_parts, rows, metas, templates, shot_tables = [], [], [], [], {}
    for seq_id, entry in sorted(entries.items()):
        if entry.get("status") != "ok":
            continue
        part = parts.get(seq_id)
        if part is None or part.input_hash != entry.get("input_hash"):
            part = shard_part(dataset_dir, seq_id, entry)
            if part is None:
                continue
        if isinstance(part, ShotsPart):
            shot_tables[seq_id] = part.table
            continue
        ts_parts.append(part.timeseries)
        rows.append(part.row)
        metas.append(part.meta)
        templates.append((seq_id, part.template or _TRAPEZOID))
    waveform_why = "one dataset is one printhead drive (the model has one dead time, instroke and hold)"
    # one template (and its constants) for every sequence: its parameters are the columns
    template = _common(templates, "waveform template", why="one dataset is one printhead drive (one waveform "
                       "template, its parameters the dataset's columns)")
    template = None if template in (None, _TRAPEZOID) else template
    units = template_from_dict(template).units() if template is not None else None
    controls = list(units) if units is not None else list(_CONTROLS)
    timeseries = (
        pd.concat(ts_parts, ignore_index=True) if ts_parts else pd.DataFrame(columns=TIMESERIES_COLUMNS)
    )
    summary_df = pd.DataFrame(rows, columns=["sequence_id", *controls, *_SU_REST])
    for col in summary_df.columns[1:]:
        summary_df[col] = pd.to_numeric(summary_df[col], errors="coerce").astype(float)
    delays = timeseries.groupby("sequence_id")["delay_us"].apply(lambda d: np.diff(np.sort(d.to_numpy())))
    steps = np.concatenate(delays.to_list()) if len(delays) else np.array([])
    steps = steps[steps > 0]
    # the dataset is in physical units: each sequence carries its own scale (a refocused camera
    # changes the pixel size, not the nozzle or the ink), so pixel sizes are listed, not compared
    pixel_sizes = {sid: m.get("pixel_size_um") for sid, m, _ in metas if m.get("pixel_size_um") is not None}
    distinct = sorted(set(pixel_sizes.values()))
    dataset = {
        "schema": DATASET_SCHEMA,
        "nozzle_inner_diameter_um": _common([(s, m.get("nozzle_inner_diameter_um")) for s, m, _ in metas],
                                            "nozzle_inner_diameter_um"),
        "ink": _common([(s, m.get("ink")) for s, m, _ in metas], "ink"),
        "nozzle": _common([(s, m.get("nozzle")) for s, m, _ in metas], "nozzle geometry"),
        "pixel_size_um": distinct[0] if len(distinct) == 1 else None,
        "pixel_size_um_by_sequence": pixel_sizes if len(distinct) > 1 else None,
        "sample_interval_us": float(np.median(steps)) if steps.size else None,
        "dead_time_us": _common([(s, w.get("dead_time_us", DEAD_TIME_US)) for s, _, w in metas],
                                "waveform dead_time_us", why=waveform_why),
        "u3_um_per_ms": _common([(s, w.get("u3_um_per_ms", U3_PRESET_UM_PER_MS)) for s, _, w in metas],
                                "waveform u3_um_per_ms", why=waveform_why),
        "hold_us": _common([(s, w.get("hold_us", HOLD_PRESET_US)) for s, _, w in metas], "waveform hold_us",
                           why=waveform_why),
        "waveform": template,
        "waveform_parameters": units,
        "n_sequences": len(rows),
        "sequences": [r["sequence_id"] for r in rows],
        "failed": {k: e.get("error") for k, e in entries.items() if e.get("status") != "ok"},
        "created_by": "dropvision campaign",
        "versions": software_versions(),
    }
    if template is None:  # the paper's trapezoid: as before
        del dataset["waveform"], dataset["waveform_parameters"]
    else:  # a template has no instroke nor hold of its own (its constants are in "waveform")
        del dataset["u3_um_per_ms"], dataset["hold_us"]
    has_shots = any(e.get("kind") == "shots" for e in entries.values())
    if has_shots or (dataset_dir / schema.DATASET_SHOTS.file).is_file():
        shots = _shots_table(list(shot_tables.values()))
        if has_shots:
            dataset["shot_folders"] = list(shot_tables)
            dataset["n_shots"] = len(shots)
        schema.check_table(shots, schema.DATASET_SHOTS, dataset_dir / schema.DATASET_SHOTS.file)
        write_bytes(dataset_dir / schema.DATASET_SHOTS.file, parquet_bytes(shots))
    write_bytes(dataset_dir / "timeseries.parquet", parquet_bytes(timeseries))
    write_bytes(dataset_dir / "summary.parquet", parquet_bytes(summary_df))
    write_json(dataset_dir / "dataset.json", dataset)


def _shots_table(tables: list[pd.DataFrame]) -> pd.DataFrame:
    """The shot folders' rows in one table: the declared columns, then every label column (in the
    order first met), NaN where a folder lacks it."""
    declared = schema.DATASET_SHOTS.column_names
    if not tables:
        dtypes = {"float": float, "bool": bool, "int": "Int64"}
        empty = pd.DataFrame({c.name: pd.Series(dtype=dtypes.get(c.dtype, object))
                              for c in schema.DATASET_SHOTS.columns})
        return empty[declared]
    labels: list[str] = []
    for t in tables:
        labels += [c for c in t.columns if c not in declared and c not in labels]
    out = pd.concat([t.reindex(columns=declared + labels) for t in tables], ignore_index=True)
    for c in labels:
        out[c] = pd.to_numeric(out[c], errors="coerce").astype(float)
    out["n_satellites"] = out["n_satellites"].astype("Int64")
    out["inflight"] = out["inflight"].astype(bool)
    return out


def parquet_bytes(df: pd.DataFrame) -> bytes:
    """A table as Parquet bytes (no index), for an atomic `dvcore.atomic.write_bytes`."""
    buf = io.BytesIO()
    df.to_parquet(buf, index=False)
    return buf.getvalue()
