"""`make demo`: the full loop on synthetic data with exact truth.

1. measure the shipped sample sequences (``sample_frames/``) and compare with their truth;
2. render a small calibration campaign (a grid of (u1, u2), like the paper's Table 1);
3. measure it into a training dataset (`dropvision campaign`);
4. fit the hybrid model (`identify fit`): ARX structure, ECM, pinch-off and adjusters;
5. predict one operating point with Monte Carlo and inverse-design a target volume;
6. write ``out/``: dataset, model.json, Rerun recordings and ``report/`` (`identify.app.report`:
   ``index.html`` with PNG figures like Figs. 6 and 7, surfaces, CV tables, residuals);
7. print a report: measured and predicted values against the synthetic truth.

Run ``python -m dropvision.app.demo --help`` for options (``--quick`` for a smaller grid).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from dropvision.app.campaign import run_campaign, synth_campaign
from dropvision.app.rerun_log import RerunLogger
from dropvision.config import MeasureConfig
from dropvision.measurement import measure_sequence
from identify.app.report import write_report
from identify.app.rerun_log import close_recording, log_model_fit, log_prediction, open_identify_recording
from dvcore.rerun_options import RerunOptions
from dvcore.atomic import OutputError, check_output_dir, claim_dir
from identify.dataset_checks import load_dataset
from dropvision.app.rigs import SimulatedPrinthead
from identify.design import design
from identify.hybrid import widening_reason
from identify.hybrid_fit import fit_hybrid
from identify.physics import SynthPhysics, drop_history
from identify.tuning import tune
from dvcore.jsonio import loads_strict

REPO = Path(__file__).resolve().parents[2]  # dropvision/app/demo.py -> repository root
SAMPLE_FRAMES = REPO / "sample_frames"


#: Frames of the demo's calibration campaign (`dropvision.synth.SynthConfig` keys); nominal ink.
CAMPAIGN_OVERRIDES = {"width_px": 192, "height_px": 640, "tip_row": 40.4, "axis_col": 95.6,
                      "delays_us": tuple(float(d) for d in range(0, 1601, 10)), "noise": 0.5}


def campaign_grid(quick: bool) -> tuple[list[float], list[float]]:
    """The demo campaign's u1 (µm/ms) and u2 (µm) values: 3 x 3 with ``quick``, else 4 x 4."""
    if quick:
        return [55.0, 65.0, 75.0], [20.0, 27.5, 35.0]
    return [50.0, 60.0, 70.0, 80.0], [20.0, 25.0, 30.0, 35.0]


def _rel_err(measured, truth) -> str:
    if measured is None or truth is None or not np.isfinite(measured) or not np.isfinite(truth) or truth == 0:
        return "   n/a"
    return f"{100.0 * (measured - truth) / truth:+6.2f} %"


def _fmt(x, spec=".3f") -> str:
    return "nan" if x is None or not np.isfinite(x) else format(x, spec)


def measure_samples(out: Path, rerun: bool) -> list[dict]:
    """Measure every sample sequence; return rows comparing summary and truth."""
    folders = sorted(p.parent for p in SAMPLE_FRAMES.glob("*/sequence.json"))
    if not folders:
        raise FileNotFoundError(f"{SAMPLE_FRAMES}: no sample sequences (folders with sequence.json)")
    rows = []
    for seq in folders:
        logger = None
        if rerun:
            logger = RerunLogger(path=out / f"measure-{seq.name}.rrd", recording_name=seq.name)
        try:
            t0 = time.perf_counter()
            res = measure_sequence(seq, out / "sample_measurements" / seq.name, MeasureConfig(), logger=logger,
                                   overwrite=True)
            dt = time.perf_counter() - t0
        finally:
            if logger is not None:
                logger.close()
        truth = loads_strict((seq / "truth.json").read_text())
        s = res.summary
        rows.append({"sequence": seq.name, "frames": len(res.frames), "seconds": dt, "summary": s, "truth": truth})
    return rows


def print_sample_report(rows: list[dict]) -> None:
    print("\n== 1. sample_frames/: measured vs synthetic truth ==")
    keys = [
        ("pinchoff_us", "pinch-off (us)", ".0f"),
        ("grown_volume_at_pinchoff_nl", "grown volume at pinch-off (nl)", ".3f"),
        ("inflight_volume_nl", "in-flight volume (nl)", ".3f"),
        ("jetting_velocity_m_s", "jetting velocity (m/s)", ".4f"),
        ("flow_velocity_at_max_stroke_m_s", "flow velocity at max stroke (m/s)", ".3f"),
        ("satellites", "satellites", ".0f"),
    ]
    for r in rows:
        s, t = r["summary"], r["truth"]
        print(f"\n{r['sequence']}: {r['frames']} frames in {r['seconds']:.2f} s; errors: {len(s.get('errors') or [])}")
        print(f"  {'quantity':36s} {'measured':>10s} {'truth':>10s} {'error':>9s}")
        for key, label, spec in keys:
            m, tv = s.get(key), t.get(key)
            m = float("nan") if m is None else float(m)
            tv = float("nan") if tv is None else float(tv)
            print(f"  {label:36s} {_fmt(m, spec):>10s} {_fmt(tv, spec):>10s} {_rel_err(m, tv):>9s}")


def _is_demo_output(folder: Path) -> bool:
    """An output folder of the demo of an older version (before ownership markers)."""
    return (folder / "model.json").is_file() and (folder / "dataset" / "manifest.json").is_file()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m dropvision.app.demo", description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("out"), help="output folder (default out/)")
    parser.add_argument("--quick", action="store_true", help="3 x 3 grid instead of 4 x 4")
    parser.add_argument("--workers", type=int, default=None, help="worker processes (default: all cores)")
    parser.add_argument("--no-rerun", action="store_true", help="skip the Rerun recordings")
    parser.add_argument("--overwrite", action="store_true",
                        help="write into an existing --out that holds other files (those are kept)")
    args = parser.parse_args(argv)

    out = args.out
    try:
        claim_dir(out, overwrite=args.overwrite, kind="demo", is_ours=_is_demo_output)
        check_output_dir(out / "report", overwrite=args.overwrite)  # refused now, not after the run
    except OutputError as exc:
        print(f"dropvision demo: error: {exc}", file=sys.stderr)
        return 2
    # Everything below is written inside our own claimed folder: earlier results there are ours.
    t_start = time.perf_counter()
    progress = sys.stderr.isatty()

    rows = measure_samples(out, rerun=not args.no_rerun)
    print_sample_report(rows)

    # 2-3. campaign -> dataset
    u1_grid, u2_grid = campaign_grid(args.quick)
    overrides = CAMPAIGN_OVERRIDES
    print(f"\n== 2. rendering a {len(u1_grid)} x {len(u2_grid)} synthetic campaign (u1 {u1_grid}, u2 {u2_grid}) ==")
    t0 = time.perf_counter()
    synth_campaign(out / "campaign", u1_grid, u2_grid, workers=args.workers, progress=progress, overrides=overrides,
                   overwrite=True)
    print(f"rendered in {time.perf_counter() - t0:.1f} s -> {out / 'campaign'}")
    print("\n== 3. measuring the campaign into a training dataset ==")
    t0 = time.perf_counter()
    res = run_campaign(out / "campaign", out / "dataset", workers=args.workers, progress=progress, overwrite=True)
    print(f"{len(res.measured)} measured, {len(res.skipped)} unchanged, {len(res.failed)} failed "
          f"in {time.perf_counter() - t0:.1f} s -> {out / 'dataset'}")
    for sid, err in res.failed.items():
        print(f"  failed {sid}: {err}")

    # 4. identification
    print("\n== 4. identifying the hybrid model ==")
    ds = load_dataset(out / "dataset")
    rep = fit_hybrid(ds, folds=min(10, len(ds.summary)), progress=progress)
    model = rep.model
    model.save(out / "model.json")
    if rep.arx_selection is not None:
        na, nb, nk = rep.arx_selection.selected
        print(f"ARX structure selected (na, nb, nk): ({na}, {nb}, {nk}); nk in MATLAB's convention, = {nk - 1} "
              f"samples in SIPPY's/the paper's (dead time 220 us = 22 samples of 10 us; identify/arx.py explains the +1)")
        print(rep.arx_selection.table.head(8).to_string(index=False, float_format="{:.4g}".format))
    physics = SynthPhysics()
    true_ratios = physics.ecm_parameters().coefficients().ratios()
    fit_ratios = model.ecm_coefficients.ratios()
    names = ["A2/A3", "A1/A3", "A0/A3", "B1/A3", "B0/A3"]
    print("ECM coefficient ratios, identified vs truth: " + ", ".join(
        f"{n} {_rel_err(f, t).strip()}" for n, f, t in zip(names, fit_ratios, true_ratios)))
    for n in rep.notes:
        print(f"note: {n}")

    def truth_fn(a, b):
        h = drop_history(physics, a, b)
        return {"inflight_volume_nl": h.inflight_volume_nl, "jetting_velocity_m_s": h.jetting_velocity_m_s,
                "pinchoff_us": h.pinchoff_instant_us, "grown_volume_at_pinchoff_nl": h.grown_volume_at_pinchoff_instant_nl}

    # 5. prediction and inverse design
    u1, u2 = (65.0, 27.5) if args.quick else (70.0, 25.0)
    mc = model.monte_carlo(u1, u2, samples=10_000, seed=0, band=True)
    summ = mc.summary()
    truth = truth_fn(u1, u2)
    print(f"\n== 5. prediction at u1 = {u1:g} um/ms, u2 = {u2:g} um (10,000 Monte Carlo samples) ==")
    meas = ds.summary[np.isclose(ds.summary.u1_um_per_ms, u1) & np.isclose(ds.summary.u2_um, u2)]
    iv = model.interval_prediction(u1, u2, mc=mc)
    print(f"  {'quantity':28s} {'predicted':>9s} {'mean drop 95 % (conf.)':>24s} {'one drop 95 % (pred.)':>26s} "
          f"{'measured':>9s} {'truth':>9s} {'pred. error':>11s}")
    for key in ("inflight_volume_nl", "jetting_velocity_m_s"):
        s, e = summ[key], iv[key]
        m = float(meas[key].mean()) if len(meas) else float("nan")
        print(f"  {key:28s} {s['mean']:9.3f} {'[%7.3f, %7.3f]' % (e['mean_drop_low'], e['mean_drop_high']):>24s} "
              f"{'[%7.3f, %7.3f]' % (e['one_drop_low'], e['one_drop_high']):>26s} {_fmt(m):>9s} "
              f"{truth[key]:9.3f} {_rel_err(s['mean'], truth[key]):>11s}")
    print("  mean drop (confidence): where the mean of many drops lies (parameters + model discrepancy + the "
          "campaign's measurement uncertainty); one drop (prediction): where one drop lies (+ drop-to-drop scatter)")
    for key in ("inflight_volume_nl", "jetting_velocity_m_s"):
        why = widening_reason(key, iv[key])
        if why:
            print(f"  {why}")
    target = round(float(np.mean(ds.summary.inflight_volume_nl)), 1)
    d = design(model, target, samples=2000)
    print(f"\ninverse design for an in-flight volume of {target} nl: u1 = {d.u1_um_per_ms:.2f} um/ms, u2 = {d.u2_um:.2f} um "
          f"({'feasible' if d.feasible else 'infeasible'}: {d.message})")
    td = truth_fn(d.u1_um_per_ms, d.u2_um)
    print(f"  synthetic truth there: in-flight volume {td['inflight_volume_nl']:.3f} nl "
          f"({_rel_err(td['inflight_volume_nl'], target).strip()} from the target), "
          f"jetting velocity {td['jetting_velocity_m_s']:.3f} m/s")
    # the lab loop: the same target on a printhead whose ink is 1.2x as viscous as the model's
    run = tune(model, SimulatedPrinthead(physics=physics, viscosity_factor=1.2, seed=0), target, shots=5, seed=0)
    print(f"\nclosed-loop tuning to {target} nl on a printhead with 1.2x the ink viscosity (identify tune):")
    for s in run.shots:
        print(f"  shot {s['shot']}: u1 = {s['u1_um_per_ms']:.2f} um/ms, u2 = {s['u2_um']:.2f} um -> measured "
              f"{s['measured_volume_nl']:.3f} nl ({s['volume_error_percent']:+.2f} %), rig bias "
              f"{s['volume_bias_percent']:+.2f} +- {s['volume_bias_se_percent']:.2f} %")
    print(f"  {run.message}")

    # 6. the report (figures and index.html) and the identification recording
    report = write_report(out / "report", model, ds, fit_report=rep, at=[(u1, u2)], mc={(u1, u2): mc},
                          truth_fn=truth_fn, samples=10_000, seed=0, overwrite=args.overwrite,
                          title="dropvision demo: identified hybrid model")
    if not args.no_rerun:
        rec = open_identify_recording(RerunOptions(path=out / "identify.rrd", application_id="dropvision-identify"))
        try:
            log_model_fit(rec, ds, model, rep.arx_selection)
            log_prediction(rec, mc)
        finally:
            close_recording(rec)
    print(f"\n== 6. outputs in {out}/ ==")
    for p in [out / "dataset", out / "model.json", report.index, *report.figures, *sorted(out.glob("*.rrd"))]:
        print(f"  {p}")
    print(f"\ndemo finished in {time.perf_counter() - t_start:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
