"""`identify predict TEMPLATE_MODEL --table ROWS --out FILE` and `identify predict TEMPLATE_MODEL --set V1=30 ...`.

The prediction of a model on a waveform template (:class:`identify.template_fit.TemplateModel`,
``identify.template-model/1``) from the command line: every row of a table of its parameters, or one
setting given as ``--set NAME=VALUE`` (repeatable, the form of ``--target``); each with the
``outside_training_region`` flag. :mod:`identify.app.cli` dispatches here.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from dvcore import schema
from dvcore.errors import UsageError

#: Units of the predicted outputs (the columns of `identify.template_fit.PREDICTION_COLUMNS`).
UNITS = {"pinchoff_us": "us", "grown_volume_at_pinchoff_nl": "nl", "inflight_volume_nl": "nl",
         "jetting_velocity_m_s": "m/s", "flow_velocity_at_velocity_instant_m_s": "m/s"}


def is_template_model(path) -> bool:
    """True when ``path`` is a model file of :mod:`identify.template_fit` (its schema id)."""
    from identify.model_file import model_schema

    return model_schema(path) == schema.TEMPLATE_MODEL.schema


def _refuse_other_options(args, what: str) -> None:
    given = [flag for flag, on in (("--u1/--u2", args.u1 is not None or args.u2 is not None),
                                   ("--level", abs(args.level - 0.95) > 1e-12),
                                   ("--rerun", any(getattr(args, k, None) for k in ("rerun", "rerun_spawn",
                                                                                   "rerun_connect")))) if on]
    if given:
        raise UsageError(f"{args.model}: {what}: {', '.join(given)} not available (its parameters come with --set "
                         "NAME=VALUE or --table ROWS.csv; it has no intervals)")


def _load(path):
    from identify.template_fit import TemplateModel

    try:
        return TemplateModel.from_json(path)
    except ValueError as exc:
        raise UsageError(" ".join(str(exc).split())) from None


def cmd_predict_template(args) -> int:
    """`identify predict` of a template model: ``--table`` + ``--out``, or ``--set`` (text or ``--json``)."""
    what = f"a model on a waveform template ({schema.TEMPLATE_MODEL.schema})"
    _refuse_other_options(args, what)
    if args.table is not None and args.set:
        raise UsageError("--set and --table exclude each other (one setting, or a table of them)")
    if args.table is not None:
        return _predict_table(args)
    if not args.set:
        m = _load(args.model)
        raise UsageError(f"{args.model}: {what}: give its parameters with --set NAME=VALUE (repeatable: "
                         f"{', '.join(m.inputs)}) or --table ROWS.csv --out FILE")
    if args.out is not None:
        raise UsageError("--out is for --table (a table of predictions); --set prints one (--json: as JSON)")
    from identify.app.tabular_cli import parse_settings

    settings = parse_settings(args.set)
    m = _load(args.model)
    import pandas as pd

    row = pd.DataFrame([settings])
    try:
        unknown = sorted(set(settings) - set(m.template.parameter_names))
        if unknown:
            raise ValueError(f"--set {unknown[0]}: not a parameter of the template {m.template.name} "
                             f"(declared: {', '.join(m.template.parameter_names)})")
        missing = [k for k in m.inputs if k not in settings]
        if missing:
            raise ValueError(f"--set {missing[0]}=VALUE missing (the model's parameters: {', '.join(m.inputs)}"
                             + (f"; fixed, may be left out: {', '.join(m.fixed)}" if m.fixed else "") + ")")
        pred = m.predict_table(row, source="--set").iloc[0]
    except ValueError as exc:
        raise UsageError(f"{args.model}: {' '.join(str(exc).replace('--set: row 1: ', '').split())}") from None
    values = {**m.fixed, **settings}
    values = {k: values[k] for k in m.template.parameter_names}
    out = {k: float(pred[k]) for k in UNITS}
    flag, why = bool(pred["outside_training_region"]), str(pred["outside_training_region_why"])
    if args.json:
        print(json.dumps({"schema": schema.TEMPLATE_SETTING_PREDICTION.schema, "settings": values, **out,
                          "outside_training_region": flag, "outside_training_region_why": why}))
        return 0
    units = m.template.units()
    print(f"waveform template {m.template.name}: " + ", ".join(f"{k} = {v:g} {units[k]}" for k, v in values.items()))
    for k, unit in UNITS.items():
        print(f"  {k:40s} {out[k]:.5g} {unit}")
    print(f"  {'outside_training_region':40s} {'yes: ' + why if flag else 'no'}")
    if flag:
        print(f"warning: outside the training region ({why}): the numbers are unchecked there", file=sys.stderr)
    return 0


def _predict_table(args) -> int:
    """Predict every row of ``--table`` and write ``--out`` (CSV or Parquet)."""
    from dvcore.atomic import check_output_file, check_outside_inputs
    from identify.app.tabular_cli import is_prediction_table, write_predictions
    from identify.tabular import TabularError, read_table

    if args.out is None:
        raise UsageError("--table needs --out FILE.csv (or .parquet): where the predictions go")
    out = Path(args.out)
    if out.suffix.lower() not in (".csv", ".parquet"):
        raise UsageError(f"{out}: the predictions are written as .csv or .parquet, got {out.suffix or 'no suffix'!r}")
    check_outside_inputs([args.model, args.table], out)
    check_output_file(out, inputs=[args.model, args.table], overwrite=args.overwrite, is_ours=is_prediction_table)
    m = _load(args.model)
    try:
        table = read_table(args.table)
    except TabularError as exc:
        raise UsageError(str(exc)) from None
    try:
        pred = m.predict_table(table, source=str(args.table))
    except ValueError as exc:
        raise UsageError(" ".join(str(exc).split())) from None
    return write_predictions(table, pred, out, args.table)
