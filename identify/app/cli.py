"""`identify` command line: fit, predict, design, paper.

    identify fit DATASET --out model.json      (a waveform template's dataset: identify.template_dataset)
    identify fit TABLE.csv --inputs A,B,... --outputs Y,N --out model.json   (a table: identify.tabular)
    identify fit DATASET --inputs V1,w1 --outputs drop_volume_nl --out model.json   (its shots.parquet)
    identify predict model.json --u1 U1 --u2 U2 [--samples 10000] [--seed S] [--json]
    identify predict model.json --table ROWS.csv --out PREDICTIONS.csv       (a table or template model)
    identify predict model.json --set V1=30 --set w1=20 [--json]               (one setting of a table or template model)
    identify design model.json --volume-nl V [--velocity-m-s W] [--json]
    identify design model.json --target head_volume_px3=V --target n_drops=1  (a table model)
    identify paper --u1 U1 --u2 U2 [--scheme-draw] [--samples N] [--seed S] [--json]
    identify report model.json --dataset DATASET --out DIR [--at U1,U2 ...] [--overwrite]
    identify tune model.json --volume-nl V [--velocity-m-s W] --rig simulated|folder|module:function --out DIR [--rerun F.rrd]
    identify tune model.json --target head_volume_px3=V --target n_drops=1 --rig module:function --out DIR  (a table model)

Bad input exits with status 2 and a one-line message on stderr.
"""

from __future__ import annotations

import argparse
import json
import math
import sys


from dvcore import schema
from dvcore.errors import UsageError, run_command
from dvcore.rerun_options import add_rerun_args
from dvcore.atomic import OutputError, check_output_file
from dvcore.atomic import check_outside_inputs

OUTPUT_UNITS = {"pinchoff_us": "us", "grown_volume_at_pinchoff_nl": "nl", "inflight_volume_nl": "nl",
                "jetting_velocity_m_s": "m/s"}


def _positive(name):
    def conv(text):
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name} must be a number, got {text!r}") from None
        if not math.isfinite(v) or v <= 0:
            raise argparse.ArgumentTypeError(f"{name} must be > 0, got {text!r}")
        return v
    return conv


def _level(text):
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--level must be a number, got {text!r}") from None
    if not 0 < v < 1:
        raise argparse.ArgumentTypeError(f"--level must be in (0, 1), got {text!r}")
    return v


def _probability(text):
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--min-probability must be a number, got {text!r}") from None
    if not 0 <= v <= 1:
        raise argparse.ArgumentTypeError(f"--min-probability must be in [0, 1], got {text!r}")
    return v


def _print_table(title: str, df) -> None:
    import pandas as pd  # the commands import the models; --help stays without pandas

    print(f"\n{title}")
    with pd.option_context("display.width", 160, "display.max_columns", 20, "display.float_format", "{:.4g}".format):
        print(df.to_string(index=False))


def _print_summary(summary: dict, header: str) -> None:
    print(header)
    for k, s in summary.items():
        if isinstance(s, dict):
            print(f"  {k:30s} mean {s['mean']:.4g}  std {s['std']:.3g}  parameters only 95% "
                  f"[{s['parameters_only_low']:.4g}, {s['parameters_only_high']:.4g}] {OUTPUT_UNITS.get(k, '')}")
        else:
            print(f"  {k:30s} {s:.4g} {OUTPUT_UNITS.get(k, '')}")


def _is_model_file(path) -> bool:
    """True when ``path`` is a model.json written by identify (replacing it loses nothing)."""
    from identify.model_file import model_schema

    return model_schema(path) is not None


def cmd_fit(args) -> int:
    from pathlib import Path

    if args.inputs is not None or args.outputs is not None or Path(args.dataset).is_file():
        from identify.app.tabular_cli import cmd_fit_table

        return cmd_fit_table(args)  # a table of settings and end-point measurements
    from identify.dataset_checks import load_dataset
    from identify.hybrid_fit import fit_hybrid

    # model, report and recording: never onto or inside the dataset, whatever --overwrite says
    check_outside_inputs([args.dataset], args.out, args.report, getattr(args, "rerun", None))
    check_output_file(args.out, inputs=[args.dataset], overwrite=args.overwrite, is_ours=_is_model_file)
    if args.report is not None:  # refuse a report folder that is not ours before the fit
        from dvcore.atomic import check_output_dir

        check_output_dir(args.report, inputs=[args.dataset, args.out], overwrite=args.overwrite)
    from identify.template_dataset import is_template_dataset

    if is_template_dataset(args.dataset):  # a waveform template's parameters, not (u1, u2) (issue 31)
        return _fit_template(args)
    ds = load_dataset(args.dataset)
    rep = fit_hybrid(ds, folds=10 if args.folds is None else args.folds, seed=args.seed, arx=not args.no_arx, ecm_method=args.ecm_method,
                     adjuster_reference=args.adjuster_reference, progress=sys.stderr.isatty())
    m = rep.model
    if rep.arx_selection is not None:
        t = rep.arx_selection.table
        _print_table(f"ARX structure selection (selected na, nb, nk = {tuple(rep.arx_selection.selected)})",
                     t.head(args.max_rows) if len(t) > args.max_rows else t)
    c = m.ecm_coefficients
    print("\nECM coefficients (SI)")
    ci = m.to_dict()["ecm"]["coefficients_ci95"] or {}
    for k in ("A3", "A2", "A1", "A0", "B1", "B0"):
        e = ci.get(k)
        print(f"  {k} = {getattr(c, k):.5g}" + ("" if e is None else f" (+/- {e:.3g})"))
    for name, sel in (("pinch-off instant (us)", rep.pinchoff_selection), ("volume adjuster (nl)", rep.volume_selection),
                      ("velocity adjuster (m/s)", rep.velocity_selection)):
        _print_table(f"{name}: 10-fold CV, selected (n1, n2) = {sel.selected}", sel.table)
        _print_table(f"{name}: coefficients with 95 % intervals", sel.fit.to_pandas())
    for n in rep.notes:
        print(f"note: {n}")
    m.save(args.out)
    print(f"\nwrote {args.out}")
    if args.report is not None:
        from identify.app.report import write_report

        r = write_report(args.report, m, ds, fit_report=rep, inputs=[args.dataset, args.out],
                         overwrite=args.overwrite, seed=args.seed)
        print(f"wrote {r.index}")
    _with_recording(args, lambda rec, lg: lg.log_model_fit(rec, ds, m, rep.arx_selection))
    return 0


def _fit_template(args) -> int:
    """`identify fit DATASET` of a waveform template's dataset: the hybrid model on the template
    (`identify.template_dataset.fit_template_dataset`), its figures printed, model.json written."""
    from identify.template_dataset import fit_template_dataset, load_template_dataset

    refused = [flag for flag, given in (
        ("--folds", args.folds is not None), ("--ecm-method", args.ecm_method != "oe"),
        ("--adjuster-reference", args.adjuster_reference != "ecm"), ("--report", args.report is not None),
        ("--rerun", any(getattr(args, k, None) for k in ("rerun", "rerun_spawn", "rerun_connect")))) if given]
    if refused:
        raise UsageError(f"{args.dataset}: a dataset of a waveform template: {', '.join(refused)} not available for its "
                         "model (output-error ECM, laws linear in the parameters, no structure selection)")
    ds = load_template_dataset(args.dataset)
    m = fit_template_dataset(ds)
    tpl = m.template
    print(f"{ds.n_sequences} sequences of {args.dataset}; waveform template {tpl.describe()}")
    e = m.ecm
    print(f"\nECM ({e['level']}; drive in {tpl.drive_unit}): output-error rmse {e['rmse_nl']:.4g} nl over "
          f"{e['n_sequences']} sequences, {e['n_samples']} samples")
    c = m.ecm_coefficients
    for k in ("A3", "A2", "A1", "A0", "B1", "B0"):
        print(f"  {k} = {getattr(c, k):.5g}")
    for k, p in (e.get("parameters") or {}).items():
        lo, hi = p["ci95"]
        print(f"  {k} = {p['value']:.5g} (95 % [{lo:.4g}, {hi:.4g}])" if math.isfinite(lo) and math.isfinite(hi) and lo != hi
              else f"  {k} = {p['value']:.5g} (fixed)")
    units = tpl.units()
    print("\nlaws linear in " + ", ".join(f"{k} ({units[k]})" for k in m.inputs) + " (rmse over the training sequences)")
    for name, law, unit in (("pinch-off instant", m.pinchoff, "us"), ("volume adjuster", m.volume_adjuster, "nl"),
                            ("velocity adjuster", m.velocity_adjuster, "m/s")):
        print(f"  {name:18s} rmse {law.rmse:.4g} {unit} ({law.n} sequences)")
    for n in m.notes:
        print(f"note: {n}")
    m.save(args.out)
    print(f"\nwrote {args.out}")
    return 0


def _point(text):
    parts = text.split(",")
    if len(parts) != 2:
        raise argparse.ArgumentTypeError(f"--at must be U1,U2 (two numbers), got {text!r}")
    return tuple(_positive("--at")(x.strip()) for x in parts)


def cmd_report(args) -> int:
    from identify.app.report import write_report
    from dvcore.atomic import check_output_dir
    from identify.dataset_checks import load_dataset

    _check_samples(args.samples)
    check_output_dir(args.out, inputs=[args.model, args.dataset], overwrite=args.overwrite)
    m = _load_model(args.model)
    ds = load_dataset(args.dataset)
    r = write_report(args.out, m, ds, at=args.at, samples=args.samples, seed=args.seed, level=args.level,
                     inputs=[args.model, args.dataset], overwrite=args.overwrite)
    print(f"wrote {r.index} ({len(r.figures)} figures)")
    return 0


def _with_recording(args, log) -> None:
    """Run ``log(rec, identify.app.rerun_log)`` when --rerun/--rerun-spawn/--rerun-connect was given."""
    from identify.app import rerun_log

    rec = rerun_log.recording_from_args(args)
    if rec is None:
        return
    try:
        log(rec, rerun_log)
    finally:
        rerun_log.close_recording(rec)


def _load_model(path):
    from identify.hybrid import HybridModel
    from identify.model_file import model_schema

    # anything else than a template model: HybridModel.from_json says what is wrong with it
    if model_schema(path) == schema.TEMPLATE_MODEL.schema:
        raise UsageError(f"{path}: a model on a waveform template ({schema.TEMPLATE_MODEL.schema}): this command "
                         "reads (u1, u2) models; predict it with `identify predict MODEL --set NAME=VALUE ...` or "
                         "`--table ROWS.csv --out FILE`")
    return HybridModel.from_json(path)


def _check_samples(n: int) -> None:
    """--samples in [1, what fits in memory] (`identify.montecarlo.check_samples`)."""
    from identify.montecarlo import SampleCountError, check_samples

    try:
        check_samples(n, "--samples")
    except SampleCountError as exc:
        raise UsageError(str(exc)) from None


def _check_finite(summary: dict, path) -> None:
    """A model whose values pass the checks but predict NaN/inf is refused, not printed."""
    for k, v in summary.items():
        values = v.values() if isinstance(v, dict) else (v,)
        if not all(math.isfinite(x) for x in values):
            raise UsageError(f"{path}: the model predicts a non-finite {k} at these (u1, u2): "
                             "a corrupt or hand-edited model file?")


def _predict_other_kind(args) -> int | None:
    """`identify predict` of a template model, a table model's --set or --table (their exit code);
    None: a hybrid model at --u1/--u2."""
    from identify.app.template_cli import cmd_predict_template, is_template_model

    if is_template_model(args.model):  # a waveform template's parameters (issue 31)
        return cmd_predict_template(args)
    if args.set:
        from identify.app.tabular_cli import cmd_predict_setting, is_table_model

        if not is_table_model(args.model):
            raise UsageError(f"{args.model}: --set is for a model on a waveform template or a table model; this "
                             "one takes --u1 and --u2")
        return cmd_predict_setting(args)
    if args.table is not None:
        from identify.app.tabular_cli import cmd_predict_table

        return cmd_predict_table(args)
    return None


def _prediction_summary(m, args, mc: dict, iv: dict, nominal: dict) -> tuple[dict, dict]:
    """`identify predict --json`'s entries (``dvcore.schema.PREDICTION``) from the Monte Carlo
    summary, the intervals and the nominal values, and the prediction's check (region, physics: an
    impossible output's values blanked)."""
    # Same keys as `identify paper`: nominal pinch-off and grown volume, Monte Carlo spreads of
    # the in-flight volume and jetting velocity (and of the first two under *_mc keys).
    summary = {
        "pinchoff_us": nominal["pinchoff_us"],
        "grown_volume_at_pinchoff_nl": nominal["grown_volume_at_pinchoff_nl"],
        "inflight_volume_nl": mc["inflight_volume_nl"],
        "jetting_velocity_m_s": mc["jetting_velocity_m_s"],
        "pinchoff_us_mc": mc["pinchoff_us"],
        "grown_volume_at_pinchoff_mc_nl": mc["grown_volume_at_pinchoff_nl"],
    }
    _check_finite(summary, args.model)
    # three intervals per measured output, named for what they cover (HybridModel.interval_prediction):
    # parameters_only_* (the parameter Monte Carlo band), mean_drop_* (confidence: the mean of many
    # drops), one_drop_* (prediction: one individual drop); *_dominant_term says which term widens them.
    for k in ("inflight_volume_nl", "jetting_velocity_m_s"):
        summary[k] = {**summary[k], **{f: iv[k][f] for f in INTERVAL_FIELDS}}
    summary["pinchoff_us_intervals"] = {f: iv["pinchoff_us"][f] for f in ("mean", "parameters_only_low",
                                                                          "parameters_only_high", *INTERVAL_FIELDS)}
    summary["level"] = args.level
    summary["interval_note"] = INTERVAL_NOTE
    summary["measurement"] = (m.intervals or {}).get("measurement")
    # outside the training region: flagged; a physically impossible output (negative volume,
    # pinch-off before the piston moves, velocity <= 0) is null with its reason, never a number
    check = m.check_prediction(args.u1, args.u2, {
        "pinchoff_us": nominal["pinchoff_us"], "grown_volume_at_pinchoff_nl": nominal["grown_volume_at_pinchoff_nl"],
        "inflight_volume_nl": summary["inflight_volume_nl"], "jetting_velocity_m_s": summary["jetting_velocity_m_s"]})
    for k in check["impossible"]:
        for key in _IMPOSSIBLE_ENTRIES[k]:
            summary[key] = _without_values(summary[key])
    summary.update(check)
    return summary, check


_PREDICTED = (("pinchoff_us", "pinchoff_us_intervals"), ("inflight_volume_nl", "inflight_volume_nl"),
              ("jetting_velocity_m_s", "jetting_velocity_m_s"))


def _print_prediction(m, args, summary: dict, check: dict, iv: dict, nominal: dict) -> None:
    """The prediction as text: warnings on stderr, the table and its notes on stdout."""
    from identify.hybrid import describe_measurement, widening_reason

    for note in check["notes"]:
        print(f"warning: {note}", file=sys.stderr)
    pct = f"{100 * args.level:g} %"
    print(f"u1 = {args.u1} um/ms, u2 = {args.u2} um ({args.samples} Monte Carlo samples)")
    for k in ("pinchoff_us", "grown_volume_at_pinchoff_nl"):
        shown = "n/a (impossible, see the warning)" if k in check["impossible"] else (
            f"{nominal[k]:.4g} {OUTPUT_UNITS[k]} (nominal)")
        print(f"  {k:30s} {shown}")
    print(f"  {'quantity':30s} {'mean':>9s}   {'mean drop ' + pct + ' (confidence)':>30s}   "
          f"{'one drop ' + pct + ' (prediction)':>30s}   widest term (mean drop / one drop)")
    for k, key in _PREDICTED:
        e = summary[key]
        if k in check["impossible"]:
            print(f"  {k:30s} {'n/a':>9s}   (impossible, see the warning)")
            continue
        pred = f"[{e['one_drop_low']:.5g}, {e['one_drop_high']:.5g}]" if e["one_drop_available"] else "n/a"
        print(f"  {k:30s} {e['mean']:9.5g}   {'[%.5g, %.5g]' % (e['mean_drop_low'], e['mean_drop_high']):>30s}   "
              f"{pred:>30s} {OUTPUT_UNITS[k]:3s} {e['mean_drop_dominant_term']} / {e['one_drop_dominant_term']}")
    for k, key in _PREDICTED:
        why = None if k in check["impossible"] else widening_reason(k, summary[key])
        if why:
            print(f"note: {why}")
    print(f"note: {INTERVAL_NOTE}")
    print(f"note: {describe_measurement(m)}")
    if not iv["inflight_volume_nl"]["one_drop_available"]:
        print("note: this model file has no drop scatter (fitted before intervals existed): refit it for the "
              "prediction interval", file=sys.stderr)


def cmd_predict(args) -> int:
    other = _predict_other_kind(args)
    if other is not None:
        return other
    if args.u1 is None or args.u2 is None:
        raise UsageError("the following arguments are required: --u1, --u2 (or --table ROWS.csv --out FILE "
                         "with a table model, or --set NAME=VALUE ... with a template or table model)")
    _check_samples(args.samples)
    m = _load_model(args.model)
    want_band = any(getattr(args, k, None) for k in ("rerun", "rerun_spawn", "rerun_connect"))
    res = m.monte_carlo(args.u1, args.u2, samples=args.samples, seed=args.seed, band=want_band)
    _with_recording(args, lambda rec, lg: lg.log_prediction(rec, res, model=m))
    mc = res.summary()
    iv = m.interval_prediction(args.u1, args.u2, level=args.level, mc=res)
    nominal = m.nominal(args.u1, args.u2)  # raw values; checked below (region, physics)
    summary, check = _prediction_summary(m, args, mc, iv, nominal)
    if args.json:
        print(json.dumps({"schema": PREDICTION_SCHEMA, **summary}))
        return 0
    _print_prediction(m, args, summary, check, iv, nominal)
    return 0


#: The schema id of `identify predict --json` (its keys: ``dvcore.schema.PREDICTION``).
PREDICTION_SCHEMA = schema.PREDICTION.schema

#: The JSON entries that carry an output's value, blanked when that output is impossible.
_IMPOSSIBLE_ENTRIES = {
    "pinchoff_us": ("pinchoff_us", "pinchoff_us_mc", "pinchoff_us_intervals"),
    "grown_volume_at_pinchoff_nl": ("grown_volume_at_pinchoff_nl", "grown_volume_at_pinchoff_mc_nl"),
    "inflight_volume_nl": ("inflight_volume_nl",),
    "jetting_velocity_m_s": ("jetting_velocity_m_s",),
}


def _without_values(entry):
    """An output's entry with its values (numbers) null: its flags and names are kept."""
    if isinstance(entry, dict):
        return {k: (None if isinstance(v, float) and k != "level" else v) for k, v in entry.items()}
    return None


INTERVAL_FIELDS = ("level", "mean_drop_low", "mean_drop_high", "mean_drop_std", "one_drop_low",
                   "one_drop_high", "one_drop_std", "one_drop_available", "parameter_std", "model_std",
                   "model_std_source", "measurement_std", "drop_std", "mean_drop_dominant_term",
                   "one_drop_dominant_term", "variance_shares")
INTERVAL_NOTE = ("parameters only = the parameter Monte Carlo band alone (not an interval of the mean drop); "
                 "mean drop (confidence) = where the mean of many drops lies (parameter uncertainty of the ECM, pinch-off and "
                 "adjuster fits, plus model discrepancy seen in cross-validation, plus the systematic measurement "
                 "uncertainty of the training campaign: pixel size, edge bias, strobe grid); one drop (prediction) = where one "
                 "individual drop lies (confidence + drop-to-drop scatter of the training data)")


def cmd_design(args) -> int:
    from identify.app.tabular_cli import cmd_design_table, is_table_model
    from identify.design import design

    if is_table_model(args.model):
        return cmd_design_table(args)
    if args.target or args.min_probability is not None:
        raise UsageError("--target and --min-probability are for a table model (identify fit TABLE); this model "
                         "takes --volume-nl")
    if args.volume_nl is None:
        raise UsageError("--volume-nl is required (the target in-flight volume)")
    if args.tolerance_percent is None:
        args.tolerance_percent = 1.0
    _check_samples(args.samples)
    m = _load_model(args.model)
    r = design(m, args.volume_nl, args.velocity_m_s, tolerance_percent=args.tolerance_percent,
               samples=args.samples, seed=args.seed)
    if args.json:
        print(json.dumps(r.to_dict()))
    else:
        print(r.message)
        if r.spread:
            _print_summary(r.spread, "predicted spread:")
    return 0 if r.feasible else 1


def cmd_tune(args) -> int:
    from dvcore.atomic import check_output_dir
    from identify.app.tabular_cli import cmd_tune_table, is_table_model
    from identify.tuning import load_rig, tune, write_tuning

    if is_table_model(args.model):
        return cmd_tune_table(args)
    if args.target or args.tolerance_percent is not None or args.min_probability is not None:
        raise UsageError("--target, --tolerance-percent and --min-probability are for a table model "
                         "(identify fit TABLE); this model takes --volume-nl")
    if args.volume_nl is None:
        raise UsageError("--volume-nl is required (the target in-flight volume)")
    if args.prior_bias_percent is None:
        args.prior_bias_percent = 5.0
    _check_samples(args.samples)
    if args.shots < 1:
        raise UsageError(f"--shots must be >= 1, got {args.shots}")
    inputs = [args.model, args.rig_folder]  # the operator's shot folders are inputs too
    check_outside_inputs(inputs, args.out, getattr(args, "rerun", None))
    check_output_dir(args.out, inputs=inputs, overwrite=args.overwrite)  # refused before any shot
    m = _load_model(args.model)
    rig = load_rig(args.rig, viscosity_factor=args.viscosity_factor, nozzle_diameter_factor=args.nozzle_diameter_factor,
                   seed=args.seed, rig_folder=args.rig_folder, rig_timeout_s=args.rig_timeout_s)

    def show(so_far):
        write_tuning(so_far, args.out, inputs=inputs, overwrite=args.overwrite)  # every shot kept
        if args.json:
            return
        r = so_far.shots[-1]
        line = (f"shot {r['shot']}: u1 = {r['u1_um_per_ms']:.3f} um/ms, u2 = {r['u2_um']:.3f} um; volume predicted "
                f"{r['corrected_volume_nl']:.3f} nl [{r['volume_one_drop_low_nl']:.3f}, {r['volume_one_drop_high_nl']:.3f}], "
                f"measured {r['measured_volume_nl']:.3f} nl ({r['volume_error_percent']:+.2f} %)")
        if args.velocity_m_s is not None:
            line += f"; velocity measured {r['measured_velocity_m_s']:.3f} m/s ({r['velocity_error_percent']:+.2f} %)"
        line += f"; bias now {r['volume_bias_percent']:+.2f} +/- {r['volume_bias_se_percent']:.2f} %"
        print(line, flush=True)

    res = tune(m, rig, args.volume_nl, args.velocity_m_s, shots=args.shots,
               volume_tolerance_percent=args.volume_tolerance_percent,
               velocity_tolerance_percent=args.velocity_tolerance_percent, prior_bias_percent=args.prior_bias_percent,
               bias_lengthscale=args.bias_lengthscale, samples=args.samples, seed=args.seed, model_path=args.model,
               progress=show)
    write_tuning(res, args.out, inputs=inputs, overwrite=args.overwrite)
    _with_recording(args, lambda rec, lg: lg.log_tuning(rec, res, model=m))
    if args.json:
        from dvcore.atomic import to_json

        print(to_json({**res.to_dict(), "shots": res.shots}, indent=None), end="")  # NaN as null
    else:
        print(res.message)
        print(f"wrote {args.out}/tuning.parquet and tuning.json")
    return 0 if res.converged else 1


def cmd_paper(args) -> int:
    from identify.paper import EXPECTATION_SAMPLES, paper_expectation, paper_prediction

    if args.scheme_draw:
        samples = 10_000 if args.samples is None else args.samples
        _check_samples(samples)
        out = paper_prediction(args.u1, args.u2, samples=samples, seed=args.seed, simulation=args.simulation)
        what = (f"ONE draw of the paper's Monte Carlo scheme (10 values per coefficient, {out['samples']} "
                "combinations): its mean scatters by ~0.4 nl / 0.05 m/s from seed to seed; std/low/high: "
                "spread (min/max) within the draw")
    else:
        samples = EXPECTATION_SAMPLES if args.samples is None else args.samples
        _check_samples(samples)
        out = paper_expectation(args.u1, args.u2, samples=samples, seed=args.seed, simulation=args.simulation)
        what = (f"EXPECTATION of the paper's Monte Carlo model (converged: adjusters exact, ECM over {samples} "
                "independent draws; stable between seeds to ~0.002 nl); std/low/high: spread of one Monte "
                "Carlo model (2.5/97.5 %); --scheme-draw gives one draw of the paper's own sampling scheme")
    summary = {k: out[k] for k in OUTPUT_UNITS if k in out}
    if args.json:
        summary["estimate"] = out["estimate"]
        print(json.dumps(summary))
    else:
        _print_summary(
            summary,
            f"published colour-ink model (Eqs. 14-17) at u1 = {args.u1} um/ms, u2 = {args.u2} um, "
            f"{args.simulation} simulation",
        )
        print(f"estimate: {what}")
        if args.simulation == "sampled":
            print(
                "note: the published A2 gives a ~100 kHz mode with damping ratio 0.0012; sampled every 10 us "
                "as in the paper it aliases, and the flow velocity at maximum stroke read off 10 us samples "
                "reproduces Section 5.2 (17.74 nl, 1.12 m/s) within the scatter of the paper's own sampling scheme (10 values per coefficient: about 0.4 nl and 0.05 m/s between seeds; 40 seeds average 17.78 nl, 1.13 m/s). The exact continuous-time model "
                "(--simulation exact) gives the same volume but ~0.45 m/s: see identify/paper.py."
            )
    return 0


class _Parser(argparse.ArgumentParser):
    """Argument errors as one line on stderr, exit status 2."""

    def error(self, message):  # noqa: D401 - argparse API
        self.exit(2, f"{self.prog}: error: {message}\n")


def _add_fit(sub) -> None:
    """`identify fit`'s options."""
    f = sub.add_parser("fit", help="identify a hybrid model from a dataset folder, or models of a table's outputs")
    f.add_argument("dataset", help="a dataset folder (of (u1, u2) or of a waveform template), or a .csv/.parquet "
                   "table (with --inputs/--outputs; with them a campaign dataset folder is its shots.parquet)")
    f.add_argument("--inputs", default=None, metavar="A,B,...", help="a table's parameter columns")
    f.add_argument("--outputs", default=None, metavar="Y,N,...",
                   help="a table's measured columns (a count such as n_drops: probabilities of each count)")
    f.add_argument("--out", required=True, help="model.json to write (an existing file only if it is a model of ours)")
    f.add_argument("--overwrite", action="store_true", help="replace an existing --out file that is not a model")
    f.add_argument("--folds", type=int, default=None, help="cross-validation folds (default 10; a table: 5)")
    f.add_argument("--seed", type=int, default=0)
    f.add_argument("--no-arx", action="store_true", help="skip the ARX structure selection")
    f.add_argument("--ecm-method", default="oe", choices=["oe", "delta"])
    f.add_argument("--adjuster-reference", default="ecm", choices=["ecm", "measured"])
    f.add_argument("--max-rows", type=int, default=30, help="rows of the ARX table to print")
    f.add_argument("--report", default=None, metavar="DIR",
                   help="also write the report (figures and index.html, see `identify report`) into DIR")
    add_rerun_args(f)
    f.set_defaults(func=cmd_fit)


def _add_predict(sub) -> None:
    """`identify predict`'s options."""
    q = sub.add_parser("predict", help="predict drop volume/velocity with uncertainty")
    q.add_argument("model")
    q.add_argument("--u1", type=_positive("--u1"), default=None, help="stroke velocity (um/ms)")
    q.add_argument("--u2", type=_positive("--u2"), default=None, help="stroke (um)")
    q.add_argument("--table", default=None, metavar="ROWS.csv",
                   help="a table model: predict every row of this table (its input columns)")
    q.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                   help="a model on a waveform template or a table model: one setting, a parameter each time "
                        "(repeatable), e.g. --set V1=30 --set w1=20 (a template's fixed parameters may be left out)")
    q.add_argument("--out", default=None, metavar="FILE", help="with --table: the predictions (.csv or .parquet)")
    q.add_argument("--overwrite", action="store_true", help="with --table: replace an --out that is not ours")
    q.add_argument("--samples", type=int, default=10_000)
    q.add_argument("--seed", type=int, default=0)
    q.add_argument("--level", type=_level, default=0.95, help="level of both intervals (default 0.95)")
    q.add_argument("--json", action="store_true")
    add_rerun_args(q)
    q.set_defaults(func=cmd_predict)


def _add_design(sub) -> None:
    """`identify design`'s options."""
    d = sub.add_parser("design", help="find (u1, u2) for a target drop volume (and velocity)")
    d.add_argument("model")
    d.add_argument("--volume-nl", type=_positive("--volume-nl"), default=None,
                   help="target in-flight volume (a hybrid model; required there)")
    d.add_argument("--velocity-m-s", type=_positive("--velocity-m-s"), default=None)
    d.add_argument("--target", action="append", default=[], metavar="OUTPUT=VALUE",
                   help="a table model: a target (repeatable), e.g. head_volume_px3=712000 and n_drops=1 (a count: "
                        "P(that count) >= --min-probability)")
    d.add_argument("--tolerance-percent", type=_positive("--tolerance-percent"), default=None,
                   help="default 1 %% (a hybrid model), 2 %% (a table model)")
    d.add_argument("--min-probability", type=_probability, default=None,
                   help="a table model: least P(count) of a count target (default 0.9)")
    d.add_argument("--samples", type=int, default=2000)
    d.add_argument("--seed", type=int, default=0)
    d.add_argument("--json", action="store_true")
    d.set_defaults(func=cmd_design)


def _add_tune(sub) -> None:
    """`identify tune`'s options."""
    t = sub.add_parser("tune", help="closed loop: propose (u1, u2), fire a rig, measure, correct, until on target")
    t.add_argument("model")
    t.add_argument("--volume-nl", type=_positive("--volume-nl"), default=None,
                   help="target in-flight volume (nl; a hybrid model, required there)")
    t.add_argument("--target", action="append", default=[], metavar="OUTPUT=VALUE",
                   help="a table model: a target (repeatable), e.g. head_volume_px3=712000 and n_drops=1")
    t.add_argument("--tolerance-percent", type=_positive("--tolerance-percent"), default=None,
                   help="a table model: a continuous target within this is met (default 2 %%)")
    t.add_argument("--min-probability", type=_probability, default=None,
                   help="a table model: least P(count) of a count target (default 0.9)")
    t.add_argument("--velocity-m-s", type=_positive("--velocity-m-s"), default=None, help="target jetting velocity")
    t.add_argument("--rig", required=True,
                   help="simulated (a synthetic printhead, measured from rendered frames), folder (waits for "
                        "the operator's sequence folders in --rig-folder) or module:function (your own hardware)")
    t.add_argument("--out", required=True, help="folder for tuning.parquet and tuning.json")
    t.add_argument("--shots", type=int, default=5, help="shot budget (default 5)")
    t.add_argument("--volume-tolerance-percent", type=_positive("--volume-tolerance-percent"), default=0.5)
    t.add_argument("--velocity-tolerance-percent", type=_positive("--velocity-tolerance-percent"), default=1.0)
    t.add_argument("--prior-bias-percent", type=_positive("--prior-bias-percent"), default=None,
                   help="prior standard deviation of the rig's bias beyond the model's interval (default 5 %%; "
                        "a table model: 2 %%)")
    t.add_argument("--bias-lengthscale", type=_positive("--bias-lengthscale"), default=0.25,
                   help="correlation length of the rig's bias over (u1, u2), in training-region spans (default 0.25)")
    t.add_argument("--viscosity-factor", type=_positive("--viscosity-factor"), default=1.0,
                   help="simulated rig: ink viscosity x this")
    t.add_argument("--nozzle-diameter-factor", type=_positive("--nozzle-diameter-factor"), default=1.0,
                   help="simulated rig: nozzle diameters x this")
    t.add_argument("--rig-folder", default=None, help="folder rig: where shot_01/, shot_02/ ... appear")
    t.add_argument("--rig-timeout-s", type=_positive("--rig-timeout-s"), default=3600.0,
                   help="folder rig: wait this long for a shot's sequence.json")
    t.add_argument("--samples", type=int, default=2000, help="Monte Carlo samples of each proposal's interval")
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--overwrite", action="store_true",
                   help="write into an existing --out that holds other files (those are kept)")
    t.add_argument("--json", action="store_true")
    add_rerun_args(t)
    t.set_defaults(func=cmd_tune)


def _add_paper(sub) -> None:
    """`identify paper`'s options."""
    r = sub.add_parser("paper", help="published colour-ink model of the paper")
    r.add_argument("--u1", type=_positive("--u1"), required=True)
    r.add_argument("--u2", type=_positive("--u2"), required=True)
    r.add_argument("--samples", type=int, default=None,
                   help="draws (default: 20000 independent for the expectation, 10000 = 10^4 for --scheme-draw)")
    r.add_argument("--scheme-draw", action="store_true",
                   help="one draw of the paper's own sampling scheme (seed-dependent) instead of the expectation")
    r.add_argument("--seed", type=int, default=0)
    r.add_argument("--simulation", choices=["sampled", "exact"], default="sampled",
                   help="sampled: the paper's 10 us simulation (reproduces Section 5.2, default); "
                        "exact: the continuous-time model")
    r.add_argument("--json", action="store_true")
    r.set_defaults(func=cmd_paper)


def _add_report(sub) -> None:
    """`identify report`'s options."""
    g = sub.add_parser("report", help="figures and an HTML page of a model and its training dataset")
    g.add_argument("model")
    g.add_argument("--dataset", required=True, help="the training dataset folder")
    g.add_argument("--out", required=True, help="report folder to write (index.html and PNG figures)")
    g.add_argument("--at", type=_point, action="append", default=None, metavar="U1,U2",
                   help="point of the interval figure (repeatable; default: the centre of the training grid)")
    g.add_argument("--samples", type=int, default=10_000)
    g.add_argument("--seed", type=int, default=0)
    g.add_argument("--level", type=_level, default=0.95, help="level of both intervals (default 0.95)")
    g.add_argument("--overwrite", action="store_true",
                   help="write into an existing --out that holds other files (those are kept)")
    g.set_defaults(func=cmd_report)


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="identify", description="Hybrid drop-formation models (Wang & Chiu)")
    sub = p.add_subparsers(dest="command", required=True, parser_class=_Parser)
    for add in (_add_fit, _add_predict, _add_design, _add_tune, _add_paper, _add_report):
        add(sub)
    return p


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    # one error boundary: input/environment failures exit 2 with one line, bugs exit 1
    return run_command("identify", args, expected=(OutputError,))

if __name__ == "__main__":
    sys.exit(main())
