"""Reading and validating a training dataset folder (:func:`load_dataset`, :func:`validate`), and
what each fit can use of an irregular campaign (:func:`timeseries_runs`, :func:`summary_usable`);
the folder's files are described in :mod:`identify.dataset`."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from dvcore import schema
from dvcore.jsonio import load_json_hardened
from identify.dataset import MIN_RUN_SAMPLES, SUMMARY_COLUMNS, TIMESERIES_COLUMNS, Dataset, DatasetError, check_measurement_block
from identify.waveform import DEAD_TIME_US, HOLD_PRESET_US, U3_PRESET_UM_PER_MS

#: Summary columns that may hold NaN (not measured; the fits drop that sequence where needed).
_SUMMARY_NAN_OK = {"flow_velocity_at_max_stroke_m_s", "pinchoff_us", "grown_volume_at_pinchoff_nl",
                   "inflight_volume_nl", "jetting_velocity_m_s"}

def _check_columns(df: pd.DataFrame, spec: dict, fname: str) -> None:
    missing = [c for c in spec if c not in df.columns]
    if missing:
        raise DatasetError(f"{fname}: missing column(s) {', '.join(missing)}")
    for col, kind in spec.items():
        s = df[col]
        if kind == "f" and not (pd.api.types.is_numeric_dtype(s) and not pd.api.types.is_bool_dtype(s)):
            raise DatasetError(f"{fname}: column {col} must be numeric, got dtype {s.dtype}")
        if kind == "b" and not pd.api.types.is_bool_dtype(s):
            raise DatasetError(f"{fname}: column {col} must be boolean, got dtype {s.dtype}")
        if kind == "id" and s.isna().any():
            raise DatasetError(f"{fname}: column {col} has missing values")


def _finite(df: pd.DataFrame, col: str, fname: str, mask=None, *, nan_ok: bool = False) -> None:
    v = df[col].to_numpy(float)
    if mask is not None:
        v = v[np.asarray(mask)]
    bad = np.isinf(v) if nan_ok else ~np.isfinite(v)
    if bad.any():
        raise DatasetError(f"{fname}: column {col} has {int(bad.sum())} {'inf' if nan_ok else 'NaN/inf'} value(s)")


def _fmt_id(sid) -> str:
    return repr(sid.item() if hasattr(sid, "item") else sid)


def timeseries_runs(ds: Dataset) -> tuple[dict, list[str]]:
    """Time series usable for the ECM and ARX fits, and notes on what was dropped.

    Per sequence of the summary: its rows sorted by delay, repeated delays averaged (volume and
    flow velocity; attached only if every repeat is), attached rows with NaN volume taken as
    missing frames, then the contiguous run of attached samples from delay 0 (the fits need
    uniform sampling from the piston at rest). A run with fewer than :data:`MIN_RUN_SAMPLES`
    samples or ending before the dead time drops the sequence from the time-series fits.

    Returns
    -------
    runs : dict
        sequence_id -> DataFrame (columns of timeseries.parquet, attached rows only).
    notes : list of str
    """
    h = ds.sample_interval_us
    notes: list[str] = []
    runs: dict = {}
    ts = ds.timeseries
    ids_su = list(ds.summary["sequence_id"])
    only_ts = sorted(set(ts["sequence_id"].unique()) - set(ids_su), key=str)
    if only_ts:
        notes.append(f"{len(only_ts)} sequence(s) in timeseries.parquet but not in summary.parquet dropped "
                     f"(e.g. {', '.join(_fmt_id(x) for x in only_ts[:3])})")
    groups = {sid: g for sid, g in ts.groupby("sequence_id", sort=False)}
    for sid in ids_su:
        g = groups.get(sid)
        if g is None or len(g) == 0:
            notes.append(f"sequence {_fmt_id(sid)}: no time-series rows (failed sequence?): dropped from the "
                         "ECM/ARX fits; its summary values are used")
            continue
        g = g.sort_values("delay_us", kind="stable")
        d = g["delay_us"].to_numpy(float)
        if np.any(np.diff(d) == 0):
            n_rep = int(len(d) - np.unique(d).size)
            agg = {c: "first" for c in g.columns}
            agg.update({"grown_volume_nl": "mean", "flow_velocity_m_s": "mean", "attached": "all"})
            g = g.groupby("delay_us", sort=True, as_index=False).agg(agg)[list(g.columns)]
            notes.append(f"sequence {_fmt_id(sid)}: {n_rep} repeated delay(s) averaged")
        att = g["attached"].to_numpy(bool)
        vol = g["grown_volume_nl"].to_numpy(float)
        missing = att & ~np.isfinite(vol)
        if missing.any():
            notes.append(f"sequence {_fmt_id(sid)}: {int(missing.sum())} attached frame(s) without a volume "
                         "treated as missing")
        g = g[att & np.isfinite(vol)]
        k = np.round(g["delay_us"].to_numpy(float) / h).astype(np.int64)
        if k.size == 0 or k[0] != 0:
            first = "none" if k.size == 0 else f"{k[0] * h:g} us"
            notes.append(f"sequence {_fmt_id(sid)}: no attached frame at delay 0 (first: {first}): dropped from "
                         "the ECM/ARX fits; its summary values are used")
            continue
        n_run = int(np.argmax(np.diff(k) != 1)) + 1 if np.any(np.diff(k) != 1) else k.size
        if n_run < k.size:
            gap_at = (k[n_run - 1] + 1) * h
            lost = k.size - n_run
        else:
            gap_at, lost = None, 0
        if n_run < MIN_RUN_SAMPLES or k[n_run - 1] * h <= ds.dead_time_us:
            why = f"frames missing from {gap_at:g} us" if gap_at is not None else "too few frames"
            notes.append(f"sequence {_fmt_id(sid)}: only {n_run} contiguous sample(s) from delay 0 ({why}): "
                         "dropped from the ECM/ARX fits; its summary values are used")
            continue
        if lost:
            notes.append(f"sequence {_fmt_id(sid)}: frames missing from {gap_at:g} us: the ECM/ARX fits use the "
                         f"{n_run} contiguous samples up to {k[n_run - 1] * h:g} us ({lost} later attached "
                         "sample(s) unused)")
        runs[sid] = g.iloc[:n_run]
    return runs, notes


#: What each polynomial target needs from the summary (adjuster reference "ecm"; "measured" adds
#: the measured grown volume and flow velocity).
_TARGET_COLUMNS = {
    "pinchoff": ("pinchoff_us",),
    "volume_adjuster": ("pinchoff_us", "inflight_volume_nl"),
    "velocity_adjuster": ("jetting_velocity_m_s",),
}


def summary_usable(ds: Dataset, adjuster_reference: str = "ecm") -> tuple[dict, list[str]]:
    """Which summary rows each polynomial can use (finite values), and notes on the others.

    Returns
    -------
    masks : dict
        ``"pinchoff"``, ``"volume_adjuster"``, ``"velocity_adjuster"`` -> boolean array over the
        summary rows.
    notes : list of str
    """
    su = ds.summary
    need = {k: list(v) for k, v in _TARGET_COLUMNS.items()}
    if adjuster_reference == "measured":
        need["volume_adjuster"] = ["inflight_volume_nl", "grown_volume_at_pinchoff_nl"]
        need["velocity_adjuster"] = ["jetting_velocity_m_s", "flow_velocity_at_max_stroke_m_s"]
    masks, notes = {}, []
    ids = su["sequence_id"].to_numpy()
    for name, cols in need.items():
        ok = np.ones(len(su), bool)
        for c in cols:
            fin = np.isfinite(su[c].to_numpy(float))
            bad = ~fin & ok
            if bad.any():
                notes.append(f"{name}: {int(bad.sum())} sequence(s) without {c} dropped "
                             f"(e.g. {', '.join(_fmt_id(x) for x in ids[bad][:3])})")
            ok &= fin
        masks[name] = ok
    return masks, notes


def validate(ds: Dataset, *, min_controls: int = 3) -> Dataset:
    """Check a dataset's content; raise :class:`DatasetError` on the first problem.

    ``min_controls`` is the least number of distinct (u1, u2) pairs accepted (the linear
    polynomial of Eq. 7 has three coefficients).
    """
    base = ds.path if ds.path is not None else Path(".")
    f_ts, f_su, f_js = str(base / "timeseries.parquet"), str(base / "summary.parquet"), str(base / "dataset.json")
    if not np.isfinite(ds.nozzle_inner_diameter_um) or ds.nozzle_inner_diameter_um <= 0:
        raise DatasetError(f"{f_js}: nozzle_inner_diameter_um must be > 0, got {ds.nozzle_inner_diameter_um!r}")
    if not np.isfinite(ds.sample_interval_us) or ds.sample_interval_us <= 0:
        raise DatasetError(f"{f_js}: sample_interval_us must be > 0, got {ds.sample_interval_us!r}")
    if not np.isfinite(ds.dead_time_us) or ds.dead_time_us < 0:
        raise DatasetError(f"{f_js}: dead_time_us must be >= 0, got {ds.dead_time_us!r}")
    for name in ("u3_um_per_ms", "hold_us"):
        v = getattr(ds, name)
        if not np.isfinite(v) or v < 0 or (name == "u3_um_per_ms" and v == 0):
            raise DatasetError(f"{f_js}: {name} invalid: {v!r}")

    ts, su = ds.timeseries, ds.summary
    _check_columns(ts, TIMESERIES_COLUMNS, f_ts)
    _check_columns(su, SUMMARY_COLUMNS, f_su)
    if len(ts) == 0:
        raise DatasetError(f"{f_ts}: no rows")
    if ds.extra.get("measurement_uncertainty") is not None:
        check_measurement_block(ds.extra["measurement_uncertainty"], f_js)
    for col in ("u1_um_per_ms", "u2_um", "delay_us"):
        _finite(ts, col, f_ts)
    att = ts["attached"].to_numpy(bool)
    _finite(ts, "grown_volume_nl", f_ts, mask=att, nan_ok=True)  # NaN: a missing frame
    for col in SUMMARY_COLUMNS:
        if SUMMARY_COLUMNS[col] == "f":
            _finite(su, col, f_su, nan_ok=col in _SUMMARY_NAN_OK)
    for fname, df in ((f_ts, ts), (f_su, su)):
        for col in ("u1_um_per_ms", "u2_um"):
            if (df[col].to_numpy(float) <= 0).any():
                raise DatasetError(f"{fname}: column {col} must be > 0 (found {df[col].min()!r})")
    if (ts["delay_us"].to_numpy(float) < 0).any():
        raise DatasetError(f"{f_ts}: column delay_us must be >= 0")
    for col in ("inflight_volume_nl", "grown_volume_at_pinchoff_nl"):
        if (su[col].to_numpy(float) < 0).any():
            raise DatasetError(f"{f_su}: column {col} has negative volumes")
    if (su["pinchoff_us"].to_numpy(float) <= ds.dead_time_us).any():
        raise DatasetError(f"{f_su}: column pinchoff_us must exceed the dead time {ds.dead_time_us} us")
    if (su["jetting_velocity_m_s"].to_numpy(float) <= 0).any():
        raise DatasetError(f"{f_su}: column jetting_velocity_m_s must be > 0")
    gv = ts["grown_volume_nl"].to_numpy(float)[att]
    gv = gv[np.isfinite(gv)]
    # grown volumes are meniscus-subtracted, so slightly negative values from noise are fine;
    # a clearly negative volume signals a sign or unit error.
    scale = max(float(np.nanmax(np.abs(gv))) if gv.size else 0.0, 1e-12)
    if gv.size and gv.min() < -0.5 * scale:
        raise DatasetError(f"{f_ts}: column grown_volume_nl has strongly negative volumes (min {gv.min():.3g} nl)")

    if su["sequence_id"].duplicated().any():
        dup = su["sequence_id"][su["sequence_id"].duplicated()].iloc[0]
        raise DatasetError(f"{f_su}: sequence_id {dup!r} appears more than once")
    if len(su) < 2:
        raise DatasetError(f"{f_su}: only {len(su)} sequence; identification needs several sequences")

    h = ds.sample_interval_us
    su_idx = su.set_index("sequence_id")
    for sid, g in ts.groupby("sequence_id", sort=False):
        d = g["delay_us"].to_numpy(float)
        if np.unique(g["u1_um_per_ms"]).size != 1 or np.unique(g["u2_um"]).size != 1:
            raise DatasetError(f"{f_ts}: sequence {sid!r} has several (u1_um_per_ms, u2_um) values")
        if sid not in su_idx.index:
            continue  # in timeseries.parquet only: dropped by the fits with a note
        row = su_idx.loc[sid]
        if not np.isclose(g["u1_um_per_ms"].iloc[0], row["u1_um_per_ms"]) or not np.isclose(g["u2_um"].iloc[0], row["u2_um"]):
            raise DatasetError(f"{f_ts}: sequence {sid!r} (u1_um_per_ms, u2_um) differs from {f_su}")
        ds_sorted = np.sort(d)
        k = ds_sorted / h
        if not np.allclose(k, np.round(k), atol=1e-6):
            raise DatasetError(
                f"{f_ts}: sequence {sid!r} column delay_us is not on the {h} us sampling grid "
                "(non-uniform sampling)"
            )
        # gaps, repeated delays and short sequences are irregular, not wrong: see timeseries_runs
    n_ctrl = len(ds.distinct_controls())
    if n_ctrl < min_controls:
        raise DatasetError(
            f"{f_su}: only {n_ctrl} distinct (u1_um_per_ms, u2_um) pair(s); the polynomial models "
            f"need at least {min_controls}"
        )
    masks, _ = summary_usable(ds)
    ctrl = su[["u1_um_per_ms", "u2_um"]].to_numpy(float)
    for name, m in masks.items():
        n_use = len(np.unique(ctrl[m], axis=0)) if m.any() else 0
        if n_use < min_controls:
            cols = ", ".join(_TARGET_COLUMNS[name])
            raise DatasetError(
                f"{f_su}: only {n_use} distinct (u1_um_per_ms, u2_um) pair(s) with finite {cols}; the "
                f"{name} polynomial needs at least {min_controls}")
    runs, _ = timeseries_runs(ds)
    if not runs:
        raise DatasetError(
            f"{f_ts}: no sequence usable for the ECM: each needs at least {MIN_RUN_SAMPLES} contiguous "
            "attached samples from delay 0 past the dead time")
    _check_plausible(ds, f_ts, f_su, f_js)
    _check_ranges(ds, f_ts, f_su)
    return ds


#: Plausible range of (grown volume at pinch-off) / (nozzle cross-section x stroke u2): the
#: piston displaces the liquid that grows the drop, and its area is larger than the nozzle's
#: (the synthetic printhead: ~20; a 50 µm nozzle with the paper's ~18 nl drops at 25 µm: ~370).
#: Generous bounds, a factor 100 beyond either: volumes in pl labelled nl come out 1000 x too
#: large, in µl 1000 x too small.
VOLUME_PER_STROKE_RANGE = (1e-2, 1e4)


def _check_plausible(ds: Dataset, f_ts: str, f_su: str, f_js: str) -> None:
    """Refuse data that pass the format checks but cannot be what the columns say.

    - constant outputs: every sequence with the same in-flight volume, grown volume at
      pinch-off or jetting velocity (an export that filled a column with one value): the
      adjusters would be fitted to nothing;
    - swapped u1/u2 columns: the piston reaches its maximum stroke at dead time +
      1000 u2/u1 µs; the drop cannot pinch off while the piston is still pushing it out, so
      pinch-off before the maximum stroke in most sequences means u1 (µm/ms) and u2 (µm) are
      swapped (on the paper's grid u1 50-80, u2 20-35: pinch-off 1.7-2.8 stroke durations
      after the dead time; swapped: 0.2-0.9);
    - volume units: the grown volume at pinch-off against the nozzle cross-section x stroke
      (:data:`VOLUME_PER_STROKE_RANGE`), e.g. pl labelled nl.
    """
    su = ds.summary
    for col in ("inflight_volume_nl", "grown_volume_at_pinchoff_nl", "jetting_velocity_m_s"):
        v = su[col].to_numpy(float)
        v = v[np.isfinite(v)]
        if v.size >= 2 and np.all(v == v[0]):
            raise DatasetError(
                f"{f_su}: column {col} is constant ({v[0]:.6g} in all {v.size} sequences): nothing to "
                "identify; an export that filled the column with one value?")
    u1 = su["u1_um_per_ms"].to_numpy(float)
    u2 = su["u2_um"].to_numpy(float)
    stroke_us = 1000.0 * u2 / u1
    tp_all = su["pinchoff_us"].to_numpy(float)
    seen = np.isfinite(tp_all)
    early = (tp_all[seen] - ds.dead_time_us) < stroke_us[seen]
    if early.sum() > 0.5 * early.size:
        raise DatasetError(
            f"{f_su}: columns u1_um_per_ms and u2_um look swapped: in {int(early.sum())} of {early.size} "
            f"sequences pinch-off comes before the maximum stroke (dead time + 1000 u2/u1 us: median "
            f"{ds.dead_time_us + float(np.median(stroke_us)):.4g} us, pinch-off median "
            f"{float(np.median(tp_all[seen])):.4g} us); u1 (um/ms) median {float(np.median(u1)):.4g}, "
            f"u2 (um) median {float(np.median(u2)):.4g}")
    area_um2 = np.pi / 4.0 * ds.nozzle_inner_diameter_um**2
    per_stroke_nl = area_um2 * u2 * 1e-6  # um^3 -> nl
    lo, hi = VOLUME_PER_STROKE_RANGE
    for fname, col, values in (
        (f_su, "grown_volume_at_pinchoff_nl", su["grown_volume_at_pinchoff_nl"].to_numpy(float)),
        (f_su, "inflight_volume_nl", su["inflight_volume_nl"].to_numpy(float)),
    ):
        fin = np.isfinite(values)
        if not fin.any():
            continue
        ratio = float(np.median(values[fin] / per_stroke_nl[fin]))
        values = values[fin]
        if not lo <= ratio <= hi:
            unit = "pl labelled nl" if ratio > hi else "ul or m^3 labelled nl"
            raise DatasetError(
                f"{fname}: column {col} (median {float(np.median(values)):.4g} nl) is {ratio:.3g} x the "
                f"nozzle cross-section x stroke (nozzle_inner_diameter_um {ds.nozzle_inner_diameter_um:g} "
                f"of {f_js}), outside the plausible {lo:g}-{hi:g}: volumes in {unit}, or a wrong nozzle "
                "diameter?")
    gv = ds.timeseries["grown_volume_nl"].to_numpy(float)
    att = ds.timeseries["attached"].to_numpy(bool)
    top = float(np.nanmax(gv[att])) if np.isfinite(gv[att]).any() else 0.0
    top_ref = float(np.max(per_stroke_nl))
    if top > hi * top_ref:
        raise DatasetError(
            f"{f_ts}: column grown_volume_nl (max {top:.4g} nl) is {top / top_ref:.3g} x the nozzle "
            f"cross-section x largest stroke, above the plausible {hi:g}: volumes in pl labelled nl?")


#: Dataset columns bounded by an accepted physical range (``dvcore.schema.RANGES`` key), per file.
_RANGED_COLUMNS = (
    ("summary", "jetting_velocity_m_s", "jetting_velocity_m_s"),
    ("summary", "flow_velocity_at_max_stroke_m_s", "flow_velocity_m_s"),
    ("summary", "pinchoff_us", "pinchoff_us"),
    ("summary", "inflight_volume_nl", "volume_nl"),
    ("summary", "grown_volume_at_pinchoff_nl", "volume_nl"),
    ("timeseries", "flow_velocity_m_s", "flow_velocity_m_s"),
    ("timeseries", "grown_volume_nl", "volume_nl"),
)
#: The unit 1000 x smaller than the column's: what a value 1000 x too large was probably written in.
_SMALLER_UNIT = {"m/s": "mm/s", "µs": "ns", "nl": "pl"}


def _check_ranges(ds: Dataset, f_ts: str, f_su: str) -> None:
    """Refuse a column value outside its accepted physical range (``dvcore.schema.RANGES``): one
    line naming the file, the column, the value (and its sequence) and the likely unit mistake."""
    frames = {"summary": (ds.summary, f_su), "timeseries": (ds.timeseries, f_ts)}
    for which, col, key in _RANGED_COLUMNS:
        df, fname = frames[which]
        lo, hi, unit = schema.RANGES[key]
        v = df[col].to_numpy(float)
        bad = np.isfinite(v) & ((v < lo) | (v > hi))
        if not bad.any():
            continue
        i = int(np.flatnonzero(bad)[np.argmax(np.abs(v[bad]))])
        value = float(v[i])
        why = ""
        if abs(value) > hi and lo <= value / 1000.0 <= hi and unit in _SMALLER_UNIT:
            why = f": looks like {_SMALLER_UNIT[unit]} labelled {unit}"
        raise DatasetError(
            f"{fname}: column {col} has {value:.6g} {unit} (sequence {_fmt_id(df['sequence_id'].iloc[i])}; "
            f"{int(bad.sum())} value(s) outside the plausible {lo:g}..{hi:g} {unit} of a drop-on-demand "
            f"jet){why}")


#: The files of a dataset folder (`dvcore.schema.DATASET`; `dropvision campaign` writes them).
DATASET_FILES = ("timeseries.parquet", "summary.parquet", "dataset.json")


def open_dataset_folder(path) -> tuple[dict, dict]:
    """The files of a dataset folder (name -> path, :data:`DATASET_FILES`) and its dataset.json
    checked against `dvcore.schema.DATASET`: the start of reading either kind of dataset
    (:func:`load_dataset`, `identify.template_dataset.load_template_dataset`). DatasetError
    naming the folder or the file: no folder, a printhead row's output, a missing file, bad JSON."""
    path = Path(path)
    if not path.is_dir():
        raise DatasetError(f"{path}: dataset folder not found")
    files = {n: path / n for n in DATASET_FILES}
    if (path / "nozzles.parquet").is_file() and not files["timeseries.parquet"].is_file():  # issue 32
        raise DatasetError(f"{path}: a printhead row's output (nozzles.parquet, one row per nozzle), not a dataset: a "
                           "model is fitted to a campaign of single-nozzle sequences (dropvision campaign)")
    for n, f in files.items():
        if not f.is_file():
            raise DatasetError(f"{f}: missing file")
    meta = load_json_hardened(files["dataset.json"], DatasetError)
    try:
        schema.check_document(meta, schema.DATASET, files["dataset.json"])
    except schema.SchemaError as exc:
        raise DatasetError(str(exc)) from None
    return files, meta


def read_dataset_tables(files: dict) -> dict:
    """timeseries.parquet and summary.parquet of :func:`open_dataset_folder`'s ``files`` (name ->
    DataFrame); DatasetError naming the file that cannot be read."""
    frames = {}
    for n in ("timeseries.parquet", "summary.parquet"):
        try:
            frames[n] = pd.read_parquet(files[n])
        except Exception as exc:  # noqa: BLE001 - pyarrow raises many types
            raise DatasetError(f"{files[n]}: cannot read parquet ({type(exc).__name__}: {exc})") from None
    return frames


def load_dataset(path, *, min_controls: int = 3) -> Dataset:
    """Read and validate a dataset folder.

    Raises
    ------
    DatasetError
        Missing folder/file, bad JSON, missing columns, wrong dtypes, inf, out-of-range
        values, delays off the sampling grid, a single sequence, too few distinct (u1, u2)
        pairs usable for a polynomial, no sequence usable for the ECM, implausible data.
    """
    path = Path(path)
    files, meta = open_dataset_folder(path)
    if meta.get("waveform") is not None:  # issue 31: its parameters, not (u1, u2), are the columns
        wf = meta["waveform"]
        name = wf.get("template") if isinstance(wf, dict) else wf
        raise DatasetError(f"{files['dataset.json']}: a dataset of the waveform template {name!r}, not of the paper's "
                           "(u1, u2): the hybrid model on a template reads it (identify.template_dataset; "
                           "`identify fit` of this folder)")
    frames = read_dataset_tables(files)

    def num(key, default=None, required=False):
        if key not in meta or meta[key] is None:
            if required:
                raise DatasetError(f"{files['dataset.json']}: missing key {key}")
            return default
        try:
            return float(meta[key])
        except (TypeError, ValueError):
            raise DatasetError(f"{files['dataset.json']}: {key} must be a number, got {meta[key]!r}") from None

    known = {"schema", "nozzle_inner_diameter_um", "sample_interval_us", "dead_time_us", "u3_um_per_ms", "hold_us", "ink", "nozzle"}
    ds = Dataset(
        timeseries=frames["timeseries.parquet"],
        summary=frames["summary.parquet"],
        nozzle_inner_diameter_um=num("nozzle_inner_diameter_um", required=True),
        sample_interval_us=num("sample_interval_us", required=True),
        dead_time_us=num("dead_time_us", DEAD_TIME_US),
        u3_um_per_ms=num("u3_um_per_ms", U3_PRESET_UM_PER_MS),
        hold_us=num("hold_us", HOLD_PRESET_US),
        ink=meta.get("ink"),
        nozzle=meta.get("nozzle"),
        path=path,
        extra={k: v for k, v in meta.items() if k not in known},
    )
    validate(ds, min_controls=min_controls)
    ds.hydraulics()  # validates ink/nozzle geometry if given
    return ds
