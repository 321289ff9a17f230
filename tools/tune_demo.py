"""Closed-loop tuning against open-loop design on simulated printheads that differ from the model.

Fits the model the demo fits (its synthetic calibration campaign, nominal ink: rendered, measured,
`identify.hybrid_fit.fit_hybrid`; ``--quick``: the 3 x 3 grid of ``demo --quick``), caches it in
``OUT/model.json``, then for each plant (ink viscosity x 1.2; nozzle diameter x 0.97) and each
target volume runs `identify.tuning.tune` with the simulated printhead
(`dropvision.app.rigs.SimulatedPrinthead`) and prints every shot, the final error and the
open-loop error (shot 1 is `identify design`'s proposal; also against the plant's exact truth).
Writes ``OUT/<plant>_<target>/tuning.parquet`` and ``tuning.json``.

    python tools/tune_demo.py --out out/tune_demo [--quick] [--targets 18,20,22] [--shots 5]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from dropvision.app.campaign import run_campaign, synth_campaign
from dropvision.app.demo import CAMPAIGN_OVERRIDES, campaign_grid
from dropvision.app.rigs import SimulatedPrinthead
from dvcore.atomic import claim_dir
from identify.dataset_checks import load_dataset
from identify.hybrid import HybridModel
from identify.hybrid_fit import fit_hybrid
from identify.tuning import tune, write_tuning

PLANTS = {"viscosity_x1.2": {"viscosity_factor": 1.2}, "nozzle_diameter_x0.97": {"nozzle_diameter_factor": 0.97}}


def demo_model(out: Path, quick: bool, workers: int | None) -> Path:
    """The demo's model, fitted once and cached in ``out/model.json``."""
    path = out / "model.json"
    if path.is_file():
        return path
    u1, u2 = campaign_grid(quick)
    t0 = time.perf_counter()
    synth_campaign(out / "campaign", u1, u2, workers=workers, progress=False, overrides=CAMPAIGN_OVERRIDES,
                   overwrite=True)
    run_campaign(out / "campaign", out / "dataset", workers=workers, progress=False, overwrite=True)
    ds = load_dataset(out / "dataset")
    fit_hybrid(ds, folds=min(10, len(ds.summary))).model.save(path)
    print(f"fitted the demo model ({len(u1)} x {len(u2)} campaign) in {time.perf_counter() - t0:.0f} s -> {path}")
    return path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("out/tune_demo"))
    ap.add_argument("--quick", action="store_true", help="the 3 x 3 campaign of demo --quick")
    ap.add_argument("--targets", default="18,20,22", help="target in-flight volumes (nl), comma-separated")
    ap.add_argument("--velocity-m-s", type=float, default=None, help="also a velocity target")
    ap.add_argument("--shots", type=int, default=5)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=None)
    args = ap.parse_args(argv)
    claim_dir(args.out, overwrite=False, kind="tune-demo", is_ours=lambda p: (p / "model.json").is_file())
    path = demo_model(args.out, args.quick, args.workers)
    model = HybridModel.from_json(path)
    targets = [float(x) for x in args.targets.split(",")]
    rows = []
    for plant, factors in PLANTS.items():
        rig = SimulatedPrinthead(seed=args.seed, **factors)
        for target in targets:
            t0 = time.perf_counter()
            res = tune(model, rig, target, args.velocity_m_s, shots=args.shots, seed=args.seed, model_path=path)
            dt = time.perf_counter() - t0
            name = f"{plant}_{target:g}nl" + ("" if args.velocity_m_s is None else f"_{args.velocity_m_s:g}m_s")
            write_tuning(res, args.out / name, inputs=[path], overwrite=True)
            df = res.to_pandas()
            print(f"\n{plant}, target {target:g} nl"
                  + ("" if args.velocity_m_s is None else f" at {args.velocity_m_s:g} m/s")
                  + f" ({dt:.1f} s): {res.message}")
            cols = ["shot", "u1_um_per_ms", "u2_um", "corrected_volume_nl", "volume_one_drop_low_nl",
                    "volume_one_drop_high_nl", "measured_volume_nl", "rig_truth_inflight_volume_nl",
                    "volume_error_percent", "volume_bias_percent", "volume_bias_se_percent"]
            if args.velocity_m_s is not None:
                cols += ["measured_velocity_m_s", "velocity_error_percent", "velocity_bias_percent"]
            print(df[cols].to_string(index=False, float_format="{:.4g}".format))
            truth_err = 100 * (df.rig_truth_inflight_volume_nl / target - 1)
            rows.append({"plant": plant, "target_nl": target, "shots": len(df), "converged": res.converged,
                         "open_loop_velocity_pct": float(df.velocity_error_percent.iloc[0]),
                         "closed_loop_velocity_pct": float(df.velocity_error_percent.iloc[-1]),
                         "open_loop_measured_pct": res.open_loop_volume_error_percent,
                         "open_loop_truth_pct": float(truth_err.iloc[0]),
                         "closed_loop_measured_pct": res.final_volume_error_percent,
                         "closed_loop_truth_pct": float(truth_err.iloc[-1]), "seconds": dt})
    import pandas as pd

    table = pd.DataFrame(rows)
    if args.velocity_m_s is None:
        table = table.drop(columns=["open_loop_velocity_pct", "closed_loop_velocity_pct"])
    print("\nsummary (errors against the targets, %; shot 1 = open loop, `identify design`):")
    print(table.to_string(index=False, float_format="{:+.3f}".format))
    ok = bool(table.converged.all() and (np.abs(table.closed_loop_measured_pct) <= 0.5).all())
    print(f"\nall within tolerance in <= {args.shots} shots: {ok}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
