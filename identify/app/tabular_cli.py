"""`identify fit TABLE --inputs ... --outputs ...` and `identify predict MODEL --table ROWS --out FILE`.

The table mode of the two commands (:mod:`identify.tabular`): a CSV or Parquet table of
settings and end-point measurements instead of a dataset folder; :mod:`identify.app.cli`
dispatches here.
"""

from __future__ import annotations

import io
import math
import sys
from pathlib import Path

from dvcore.errors import UsageError

#: Columns every prediction table of ours holds (how an earlier one is recognised, to be replaced).
_OURS = ("outside_training_region", "outside_training_region_why")


def _names(text: str | None, flag: str) -> list[str]:
    if text is None:
        raise UsageError(f"a table needs {flag} NAME,NAME,... (its columns)")
    names = [s.strip() for s in text.split(",")]
    if not all(names):
        raise UsageError(f"{flag}: an empty column name in {text!r}")
    return names


def parse_settings(items) -> dict:
    """``["V1=30", "w1=20"]`` -> ``{"V1": 30.0, "w1": 20.0}`` (UsageError on a malformed or repeated one)."""
    out = {}
    for text in items:
        name, sep, value = text.partition("=")
        name = name.strip()
        if not sep or not name:
            raise UsageError(f"--set must be NAME=VALUE (a parameter and its value), got {text!r}")
        try:
            v = float(value)
        except ValueError:
            raise UsageError(f"--set {name}: the value must be a number, got {value.strip()!r}") from None
        if not math.isfinite(v):
            raise UsageError(f"--set {name}: the value must be finite, got {value.strip()!r}")
        if name in out:
            raise UsageError(f"--set {name} given twice")
        out[name] = v
    return out


def is_table_model(path) -> bool:
    """True when ``path`` is a model file of :mod:`identify.tabular` (replacing it loses nothing)."""
    from dvcore import schema
    from identify.model_file import model_schema

    return model_schema(path) == schema.TABULAR_MODEL.schema


def is_prediction_table(path) -> bool:
    """True when ``path`` is a prediction table written by `identify predict --table`."""
    path = Path(path)
    try:
        if path.suffix.lower() == ".csv":
            with open(path, encoding="utf-8") as fh:
                header = fh.readline().rstrip("\r\n").split(",")
        else:
            import pyarrow.parquet as pq

            header = pq.read_schema(path).names
        return all(c in header for c in _OURS)
    except Exception:  # noqa: BLE001 - anything unreadable is not ours
        return False


def cmd_fit_table(args) -> int:
    """Fit :class:`identify.tabular.TabularModel` on a table and write the model file."""
    from dvcore.atomic import check_output_file
    from dvcore.atomic import check_outside_inputs
    from identify.tabular import fit_table, read_table

    inputs, outputs = _names(args.inputs, "--inputs"), _names(args.outputs, "--outputs")
    if args.no_arx or args.ecm_method != "oe" or args.adjuster_reference != "ecm":
        raise UsageError("--no-arx, --ecm-method and --adjuster-reference are hybrid-model options, not a table's")
    check_outside_inputs([args.dataset], args.out, args.report)
    check_output_file(args.out, inputs=[args.dataset], overwrite=args.overwrite, is_ours=is_table_model)
    if args.report is not None:  # refuse a report folder that is not ours before the fit
        from dvcore.atomic import check_output_dir

        check_output_dir(args.report, inputs=[args.dataset, args.out], overwrite=args.overwrite)
    table = read_table(args.dataset)
    folds = 5 if args.folds is None else args.folds
    m = fit_table(table, inputs, outputs, folds=folds, seed=args.seed, source=str(args.dataset))
    import pandas as pd

    print(f"{len(table)} rows of {args.dataset}; inputs {', '.join(inputs)}; outputs "
          + ", ".join(f"{o} ({m.kinds[o]})" for o in outputs))
    with pd.option_context("display.width", 160, "display.max_columns", 20, "display.float_format", "{:.4g}".format):
        print(f"\n{folds}-fold cross-validation of the candidates (mean_abs_error: of the fitted scale, "
              "log for a positive output; brier: of the continuation step)")
        print(m.cv_table().to_string(index=False))
    for o, c in m.continuous.items():
        print(f"{o}: {c.candidate}{' on log ' + o if c.log else ''}, fitted on {c.rows.size} rows; one drop "
              f"{100 * m.level:g} %: fit + [{c.q_lo:.3g}, {c.q_hi:.3g}] x local scale of the residuals (conformal)")
    for o, c in m.counts.items():
        print(f"{o}: counts seen {c.classes} (the largest: that many or more)")
    r = m.region
    print("training region: " + ", ".join(f"{n} {lo:g}..{hi:g}" for n, lo, hi in zip(r.inputs, r.low, r.high))
          + f"; nearest-row distance at most {r.max_gap:.3g} grid steps")
    for n in m.notes:
        print(f"note: {n}")
    m.save(args.out)
    print(f"wrote {args.out}")
    if args.report is not None:
        from identify.app.tabular_report import write_table_report

        print(f"wrote {write_table_report(args.report, m, inputs=[args.dataset, args.out], overwrite=args.overwrite)}")
    if any(getattr(args, flag, None) for flag in ("rerun", "rerun_spawn", "rerun_connect")):
        from identify.app import rerun_log

        rec = rerun_log.recording_from_args(args)
        if rec is not None:
            try:
                rerun_log.log_jetting_window(rec, m)  # the report's maps, in the viewer
            finally:
                rerun_log.close_recording(rec)
    return 0


def cmd_predict_table(args) -> int:
    """Predict every row of ``--table`` and write ``--out`` (CSV or Parquet)."""
    from dvcore.atomic import check_output_file
    from dvcore.atomic import check_outside_inputs
    from identify.tabular import RefitMismatchWarning, TabularModel, read_table

    import warnings

    if args.out is None:
        raise UsageError("--table needs --out FILE.csv (or .parquet): where the predictions go")
    out = Path(args.out)
    if out.suffix.lower() not in (".csv", ".parquet"):
        raise UsageError(f"{out}: the predictions are written as .csv or .parquet, got {out.suffix or 'no suffix'!r}")
    if args.u1 is not None or args.u2 is not None:
        raise UsageError("--u1/--u2 and --table exclude each other (a table model takes its inputs from the table)")
    check_outside_inputs([args.model, args.table], out)
    check_output_file(out, inputs=[args.model, args.table], overwrite=args.overwrite, is_ours=is_prediction_table)
    table = read_table(args.table)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", RefitMismatchWarning)
        m = TabularModel.from_json(args.model)
    for w in caught:
        print(f"warning: {w.message}", file=sys.stderr)
    if abs(args.level - m.level) > 1e-12:
        raise UsageError(f"{args.model}: its intervals are at {100 * m.level:g} % (fixed when fitted), "
                         f"not --level {args.level:g}")
    pred = m.predict(table, source=str(args.table))
    return write_predictions(table, pred, out, args.table)


def write_predictions(table, pred, out: Path, table_path) -> int:
    """The rows of ``table`` with their predictions ``pred`` beside them, written to ``out`` (CSV or
    Parquet by the suffix; refused where ``table`` already holds a prediction column); the count
    outside the training region printed (a warning on stderr when any). Returns the exit status 0."""
    import pandas as pd

    from dvcore.atomic import write_bytes

    clash = [c for c in pred.columns if c in table.columns]
    if clash:
        raise UsageError(f"{table_path}: already has a column {clash[0]!r} of the predictions (a prediction table?)")
    result = pd.concat([table.reset_index(drop=True), pred.reset_index(drop=True)], axis=1)
    if out.suffix.lower() == ".csv":
        write_bytes(out, result.to_csv(index=False).encode("utf-8"))
    else:
        buf = io.BytesIO()
        result.to_parquet(buf, index=False)
        write_bytes(out, buf.getvalue())
    n_out = int(pred["outside_training_region"].sum())
    print(f"wrote {out}: {len(pred)} rows, {n_out} outside the training region")
    if n_out:
        print(f"warning: {n_out} row(s) outside the training region (column outside_training_region_why): "
              "their numbers are unchecked there", file=sys.stderr)
    return 0


def cmd_predict_setting(args) -> int:
    """`identify predict model.json --set NAME=VALUE ...` with a table model: one setting, printed
    (``--json``: ``dvcore.schema.TABULAR_SETTING_PREDICTION``)."""
    import json

    import pandas as pd

    from dvcore import schema

    if args.table is not None or args.out is not None:
        raise UsageError("--set and --table/--out exclude each other (one setting, or a table of them)")
    if args.u1 is not None or args.u2 is not None:
        raise UsageError("--u1/--u2 and --set exclude each other (a table model takes its inputs by name)")
    settings = parse_settings(args.set)
    m = _load(args.model)
    if abs(args.level - m.level) > 1e-12:
        raise UsageError(f"{args.model}: its intervals are at {100 * m.level:g} % (fixed when fitted), "
                         f"not --level {args.level:g}")
    unknown = sorted(set(settings) - set(m.inputs))
    missing = [k for k in m.inputs if k not in settings]
    if unknown or missing:
        raise UsageError(f"{args.model}: " + (f"--set {unknown[0]}: not an input of the model" if unknown
                                              else f"--set {missing[0]}=VALUE missing")
                         + f" (its inputs: {', '.join(m.inputs)})")
    pred = m.predict(pd.DataFrame([{k: settings[k] for k in m.inputs}]), source="--set").iloc[0]
    flag, why = bool(pred["outside_training_region"]), str(pred["outside_training_region_why"])
    values = {c: float(pred[c]) for c in pred.index if c not in _OURS}
    if args.json:
        print(json.dumps({"schema": schema.TABULAR_SETTING_PREDICTION.schema,
                          "settings": {k: settings[k] for k in m.inputs}, "predicted": values,
                          "outside_training_region": flag, "outside_training_region_why": why}))
        return 0
    print(", ".join(f"{k} = {settings[k]:g}" for k in m.inputs))
    for c, v in values.items():
        print(f"  {c:40s} {v:.5g}")
    print(f"  {'outside_training_region':40s} {'yes: ' + why if flag else 'no'}")
    if flag:
        print(f"warning: outside the training region ({why}): the numbers are unchecked there", file=sys.stderr)
    return 0


def _load(path):
    import warnings

    from identify.tabular import RefitMismatchWarning, TabularModel

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", RefitMismatchWarning)
        m = TabularModel.from_json(path)
    for w in caught:
        print(f"warning: {w.message}", file=sys.stderr)
    return m


def _no_hybrid_options(args) -> None:
    if args.volume_nl is not None or args.velocity_m_s is not None:
        raise UsageError(f"{args.model}: a table model takes --target OUTPUT=VALUE, not --volume-nl/--velocity-m-s "
                         "(its outputs are named in the model)")
    if not args.target:
        raise UsageError(f"{args.model}: a table model needs --target OUTPUT=VALUE (e.g. --target n_drops=1)")


def cmd_design_table(args) -> int:
    """`identify design model.json --target O=V ...` with a table model."""
    import json

    from identify.tabular_tuning import design_table

    _no_hybrid_options(args)
    m = _load(args.model)
    r = design_table(m, args.target, tolerance_percent=2.0 if args.tolerance_percent is None else args.tolerance_percent,
                     min_probability=0.9 if args.min_probability is None else args.min_probability, seed=args.seed)
    if args.json:
        print(json.dumps(r.to_dict()))
    else:
        print(r.message)
        print(f"searched {r.candidates} settings inside the training region")
    return 0 if r.feasible else 1


def cmd_tune_table(args) -> int:
    """`identify tune model.json --target O=V ... --rig module:function --out DIR` with a table model."""
    from dvcore.atomic import check_output_dir, check_outside_inputs
    from identify.tabular_tuning import load_table_rig, tune_table, write_table_tuning

    _no_hybrid_options(args)
    for flag, v, default in (("--viscosity-factor", args.viscosity_factor, 1.0),
                             ("--nozzle-diameter-factor", args.nozzle_diameter_factor, 1.0),
                             ("--rig-folder", args.rig_folder, None)):
        if v != default:
            raise UsageError(f"{flag} is an option of the simulated and folder rigs of a hybrid model, not a table's")
    for flag in ("rerun", "rerun_spawn", "rerun_connect"):
        if getattr(args, flag, None):
            raise UsageError(f"--{flag.replace('_', '-')} is not available for a table model (yet)")
    if args.shots < 1:
        raise UsageError(f"--shots must be >= 1, got {args.shots}")
    inputs = [args.model]
    check_outside_inputs(inputs, args.out)
    check_output_dir(args.out, inputs=inputs, overwrite=args.overwrite)  # refused before any shot
    m = _load(args.model)
    rig = load_table_rig(args.rig)

    def show(so_far):
        write_table_tuning(so_far, args.out, inputs=inputs, overwrite=args.overwrite)  # every shot kept
        if args.json:
            return
        r = so_far.shots[-1]
        where = ", ".join(f"{n} = {r[n]:g}" for n in m.inputs)
        got = []
        for o in so_far.targets:
            if f"{o}_error_percent" in r:
                got.append(f"{o} predicted {r[o + '_corrected']:.4g} [{r[o + '_one_drop_low']:.4g}, "
                           f"{r[o + '_one_drop_high']:.4g}], measured {r[o]:.4g} ({r[o + '_error_percent']:+.2f} %)")
            else:
                got.append(f"{o} measured {r[o]:g}")
        print(f"shot {r['shot']}: {where}; " + "; ".join(got) + f"; P(on target) {r['probability_on_target']:.2f}",
              flush=True)

    res = tune_table(m, rig, args.target, shots=args.shots,
                     tolerance_percent=2.0 if args.tolerance_percent is None else args.tolerance_percent,
                     min_probability=0.9 if args.min_probability is None else args.min_probability,
                     prior_bias_percent=2.0 if args.prior_bias_percent is None else args.prior_bias_percent,
                     lengthscale=args.bias_lengthscale, seed=args.seed, rig_name=args.rig, model_path=args.model,
                     progress=show)
    write_table_tuning(res, args.out, inputs=inputs, overwrite=args.overwrite)
    if args.json:
        from dvcore.atomic import to_json

        print(to_json({**res.to_dict(), "shots": res.shots}, indent=None), end="")
    else:
        print(res.message)
        print(f"wrote {args.out}/tuning.parquet and tuning.json")
    return 0 if res.converged else 1
