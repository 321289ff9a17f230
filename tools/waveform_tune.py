"""Closed-loop tuning of the real sweep's six parameters against twins of the dispenser.

Fits (or loads: ``--model``) the table model on ../shared/realdata/waveform-sweep/dev.csv as
`identify fit dev.csv --inputs V3,w1,w2,w3,d1,d2 --outputs head_volume_px3,n_drops` does, then for
each twin seed (tools/waveform_twin.py: another dispenser per seed) and each target (the head
volumes at the 25th, 50th and 75th percentiles of the single-drop rows, with n_drops = 1) runs
`identify.tabular_tuning.tune_table` (2 % tolerance, 5 shots) and prints the shots to target
(``--holdout``: per seed, the model fitted on a random half of the rows and the twin built from
the other half, so that the model never sees the twin's rows):
per target, the success rate, median and max shots (over the runs that succeeded), and the
open-loop success (shot 1 = `identify design`).

    python tools/waveform_tune.py [--model model.json] [--seeds 10] [--shots 5]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))
from waveform_twin import DEV, INPUTS, Twin  # noqa: E402


def main(argv=None) -> int:
    from identify.tabular import TabularModel, fit_table
    from identify.tabular_tuning import tune_table

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, default=None, help="a model.json fitted on dev.csv (default: fit it)")
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--shots", type=int, default=5)
    ap.add_argument("--tolerance-percent", type=float, default=2.0)
    ap.add_argument("--holdout", action="store_true",
                    help="per seed: the model fitted on a random half of the rows, the twin built from the other "
                         "half (the model never sees the twin's rows; each has half the data)")
    args = ap.parse_args(argv)
    dev = pd.read_csv(DEV)
    model = None
    if not args.holdout:
        model = (TabularModel.from_json(args.model) if args.model is not None
                 else fit_table(dev, INPUTS, ["head_volume_px3", "n_drops"], source=str(DEV)))
    single = dev.loc[dev.n_drops == 1, "head_volume_px3"]
    targets = {f"p{int(q * 100)}": float(single.quantile(q)) for q in (0.25, 0.5, 0.75)}
    rows = []
    for seed in range(args.seeds):
        if args.holdout:
            half = np.random.default_rng(10_000 + seed).permutation(len(dev)) < len(dev) // 2
            model = fit_table(dev[half].reset_index(drop=True), INPUTS, ["head_volume_px3", "n_drops"])
            twin = Twin(dev[~half].reset_index(drop=True), seed=seed)
        else:
            twin = Twin(dev, seed=seed)
        for name, v in targets.items():
            t0 = time.perf_counter()
            res = tune_table(model, twin, {"head_volume_px3": v, "n_drops": 1}, shots=args.shots,
                             tolerance_percent=args.tolerance_percent, seed=seed)
            df = res.to_pandas()
            rows.append({"seed": seed, "target": name, "volume_px3": v, "converged": res.converged, "shots": len(df),
                         "open_loop_met": bool(df.within_tolerance.iloc[0]),
                         "last_error_percent": float(df.head_volume_px3_error_percent.iloc[-1]),
                         "last_n_drops": float(df.n_drops.iloc[-1]), "seconds": time.perf_counter() - t0})
            r = rows[-1]
            print(f"seed {seed} {name} ({v:.4g} px3): {'met in ' + str(r['shots']) if r['converged'] else 'NOT met'}; "
                  f"errors {', '.join(f'{e:+.2f}' for e in df.head_volume_px3_error_percent)} %, "
                  f"n_drops {', '.join(f'{n:g}' for n in df.n_drops)}", flush=True)
    t = pd.DataFrame(rows)
    print("\nper target (over the seeds): success rate, median and max shots of the successes, open-loop success")
    for name, g in t.groupby("target", sort=False):
        ok = g[g.converged]
        print(f"  {name} ({targets[name]:.4g} px3): {len(ok)}/{len(g)} met in <= {args.shots} shots; shots median "
              f"{ok.shots.median() if len(ok) else float('nan'):g}, max {ok.shots.max() if len(ok) else float('nan')}; "
              f"open loop {int(g.open_loop_met.sum())}/{len(g)}")
    return 0 if t.converged.all() else 1


if __name__ == "__main__":
    sys.exit(main())
