"""A campaign dataset of a waveform template (issue 31): read it, fit the hybrid model on it.

`dropvision campaign` writes a dataset of sequences driven by a waveform template other than the
paper's trapezoid (sequence.json ``waveform`` in the template form, e.g. ``three_pulse``) with the
template's parameters in place of ``u1_um_per_ms``, ``u2_um`` (one float column each, in
``summary.parquet`` and ``timeseries.parquet``) and the template in dataset.json (``waveform``:
``{template, <constants>}``; ``waveform_parameters``: name -> unit); `dvcore.schema.DATASET`.

:func:`is_template_dataset` tells such a folder from a (u1, u2) one (which
:func:`identify.dataset_checks.load_dataset` reads, unchanged); :func:`load_template_dataset`
reads and checks it (:class:`identify.dataset.DatasetError` naming the file and the column);
:func:`fit_template_dataset` fits :class:`identify.template_fit.TemplateModel` on it (the ECM
physical where dataset.json has the ink and nozzle geometry of Eq. 2). ``identify fit DATASET``
runs these for such a folder.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from dvcore.jsonio import load_json_hardened
from identify.dataset import Dataset, DatasetError
from identify.dataset_checks import open_dataset_folder, read_dataset_tables
from identify.template_fit import OUTPUTS, TemplateModel, fit_template_model
from identify.waveform import DEAD_TIME_US, WaveformTemplate, template_from_dict

__all__ = ["TemplateDataset", "is_template_dataset", "load_template_dataset", "fit_template_dataset"]

_TS_COLUMNS = ("sequence_id", "delay_us", "grown_volume_nl", "attached")


@dataclass
class TemplateDataset:
    """A campaign dataset of a waveform template: the training table (one row per sequence: its
    parameters and :data:`identify.template_fit.OUTPUTS`), the time series, and what dataset.json
    says of the drive and the nozzle."""

    template: WaveformTemplate
    summary: pd.DataFrame
    timeseries: pd.DataFrame
    nozzle_inner_diameter_um: float
    sample_interval_us: float
    dead_time_us: float
    ink: dict | None
    nozzle: dict | None
    path: Path

    @property
    def n_sequences(self) -> int:
        return len(self.summary)

    def hydraulics(self):
        """The known elements of Eq. (2) from the ink and nozzle geometry, or None
        (`identify.dataset.Dataset.hydraulics`, the same rule)."""
        return Dataset(pd.DataFrame(), pd.DataFrame(), self.nozzle_inner_diameter_um, self.sample_interval_us,
                       ink=self.ink, nozzle=self.nozzle, path=self.path).hydraulics()


def _meta(path: Path) -> dict | None:
    """dataset.json of ``path`` (None where there is none or it is not an object)."""
    f = path / "dataset.json"
    if not f.is_file():
        return None
    doc = load_json_hardened(f, DatasetError)
    return doc if isinstance(doc, dict) else None


def is_template_dataset(path) -> bool:
    """Whether ``path`` is a dataset folder whose dataset.json names a waveform template
    (``waveform``; a (u1, u2) dataset has none). An unreadable dataset.json raises
    :class:`DatasetError` naming it."""
    path = Path(path)
    if not path.is_dir():
        return False
    meta = _meta(path)
    return meta is not None and meta.get("waveform") is not None


def _number(meta: dict, key: str, fname: str, default=None) -> float:
    v = meta.get(key)
    if v is None:
        if default is None:
            raise DatasetError(f"{fname}: missing key {key}")
        return float(default)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
        raise DatasetError(f"{fname}: {key} must be a finite number, got {v!r}")
    return float(v)


def load_template_dataset(path) -> TemplateDataset:
    """Read and check a dataset folder of a waveform template.

    Raises
    ------
    DatasetError
        A missing file, a dataset.json without a valid ``waveform`` template or with
        ``waveform_parameters`` that differ from the template's, a missing parameter or output
        column, a parameter that is not a finite number, non-positive nozzle diameter or strobe
        interval (the message names the file and the column).
    """
    path = Path(path)
    files, meta = open_dataset_folder(path)
    fjs = str(files["dataset.json"])
    try:
        template = template_from_dict(meta.get("waveform"))
    except ValueError as exc:
        raise DatasetError(f"{fjs}: waveform: {exc}") from None
    names = list(template.parameter_names)
    declared = meta.get("waveform_parameters")
    if declared is not None and (not isinstance(declared, dict) or list(declared) != names
                                 or any(declared[k] != u for k, u in template.units().items())):
        raise DatasetError(f"{fjs}: waveform_parameters {declared!r} differ from the {template.describe()}")
    nozzle_d = _number(meta, "nozzle_inner_diameter_um", fjs)
    h = _number(meta, "sample_interval_us", fjs)
    dead = _number(meta, "dead_time_us", fjs, DEAD_TIME_US)
    if nozzle_d <= 0 or h <= 0 or dead < 0:
        raise DatasetError(f"{fjs}: nozzle_inner_diameter_um and sample_interval_us must be > 0, dead_time_us >= 0 "
                           f"(got {nozzle_d:g}, {h:g}, {dead:g})")
    frames = read_dataset_tables(files)
    su, ts = frames["summary.parquet"], frames["timeseries.parquet"]
    for fname, df, need in ((files["summary.parquet"], su, ("sequence_id", *names, *OUTPUTS)),
                            (files["timeseries.parquet"], ts, _TS_COLUMNS)):
        missing = [c for c in need if c not in df.columns]
        if missing:
            raise DatasetError(f"{fname}: missing column(s) {', '.join(missing)} (a dataset of the "
                               f"{template.describe()})")
        if not len(df):
            raise DatasetError(f"{fname}: no rows")
    for c in (*names, *OUTPUTS):
        if not pd.api.types.is_numeric_dtype(su[c]) or pd.api.types.is_bool_dtype(su[c]):
            raise DatasetError(f"{files['summary.parquet']}: column {c} must be numeric, got dtype {su[c].dtype}")
    for c in names:
        v = su[c].to_numpy(float)
        if not np.all(np.isfinite(v)):
            raise DatasetError(f"{files['summary.parquet']}: column {c} ({template.units()[c]}) has "
                               f"{int((~np.isfinite(v)).sum())} NaN/inf value(s): every sequence has its parameters")
    for i, row in su.iterrows():  # every sequence's parameters within the template's ranges and shape
        try:
            template.check({c: float(row[c]) for c in names}, f"sequence {row['sequence_id']}")
        except ValueError as exc:
            raise DatasetError(f"{files['summary.parquet']}: {exc}") from None
    if not pd.api.types.is_bool_dtype(ts["attached"]):
        raise DatasetError(f"{files['timeseries.parquet']}: column attached must be boolean, got {ts['attached'].dtype}")
    return TemplateDataset(template, su.reset_index(drop=True), ts[list(_TS_COLUMNS)].reset_index(drop=True), nozzle_d,
                           h, dead, meta.get("ink"), meta.get("nozzle"), path)


def fit_template_dataset(ds: TemplateDataset | str | Path, *, la: float | None = None) -> TemplateModel:
    """:func:`identify.template_fit.fit_template_model` on a template dataset (a folder or
    :class:`TemplateDataset`); the ECM physical (Ra, CN, Kc; La fixed at ``la``) where dataset.json
    has the ink and nozzle geometry, else at the coefficient level. Sequences without a measured
    output are left out of that output's law (the note says how many)."""
    ds = ds if isinstance(ds, TemplateDataset) else load_template_dataset(ds)
    su = ds.summary
    names = list(ds.template.parameter_names)
    ok = np.all(np.isfinite(su[list(OUTPUTS)].to_numpy(float)), axis=1)
    notes = []
    if not ok.all():
        notes.append(f"{int((~ok).sum())} sequence(s) without a measured pinch-off, in-flight volume or jetting "
                     f"velocity left out of the laws (e.g. {', '.join(map(str, su['sequence_id'][~ok][:3]))})")
    try:
        model = fit_template_model(ds.template, su.loc[ok, ["sequence_id", *names, *OUTPUTS]].reset_index(drop=True),
                                   ds.timeseries, dead_time_us=ds.dead_time_us,
                                   nozzle_inner_diameter_um=ds.nozzle_inner_diameter_um,
                                   hydraulics=ds.hydraulics(), la=la)
    except ValueError as exc:
        raise DatasetError(f"{ds.path}: {exc}") from None
    model.notes = notes + list(model.notes)
    return model
