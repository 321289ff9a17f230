"""Cross-validated figures of `identify.tabular` on the real waveform sweep (issue 31 items 3, 4, 7).

    PYTHONPATH=$PWD python tools/waveform_sweep_cv.py [--csv ../shared/realdata/waveform-sweep/dev.csv]
        [--folds 5] [--repeats 1] [--json out.json]

Outer K-fold over the rows of ``dev.csv`` (split seed = repeat number): each outer fold is
predicted by a model fitted by :func:`identify.tabular.fit_table` on the other rows alone (its own
candidate choice, intervals and calibration by inner cross-validation), so no figure ever sees
a held-out row. Then a "w3 >= 22 held out" split: fitted on w3 < 22, predicted on w3 >= 22 (a
region the fit never saw), to test the extrapolation flag.

Figures, against the goals of the shared README (judged there on hidden rows):

- head volume: median and 90th percentile of |predicted mean / observed - 1| (goals <= 0.6 %,
  <= 4.5 %), coverage of the 95 % one-drop interval (goal 93-97 %), over rows with a measured
  volume (gross outliers included);
- satellites (n_drops >= 2, probability = sum of ``n_drops_p<k>`` for k >= 2): Brier score
  (goal <= 0.075) and, per decile of the predicted probability holding >= 50 rows, |observed
  frequency - mean predicted| (goal <= 5 points);
- the share of rows flagged outside the training region (in-region folds: should be ~0; the
  w3 >= 22 split: the unseen region flagged, or covered >= 90 %).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_CSV = ROOT.parent / "shared" / "realdata" / "waveform-sweep" / "dev.csv"
INPUTS = ["V3", "w1", "w2", "w3", "d1", "d2"]
VOLUME, COUNT = "head_volume_px3", "n_drops"


def scores(pred: pd.DataFrame, obs: pd.DataFrame) -> dict:
    """The figures of one set of predictions against the observed rows (same order)."""
    v = obs[VOLUME].to_numpy(float)
    ok = np.isfinite(v)
    err = np.abs(pred[f"{VOLUME}_mean"].to_numpy()[ok] / v[ok] - 1) * 100
    lo, hi = pred[f"{VOLUME}_one_drop_low"].to_numpy()[ok], pred[f"{VOLUME}_one_drop_high"].to_numpy()[ok]
    covered = (v[ok] >= lo) & (v[ok] <= hi)
    p_cols = [c for c in pred.columns if c.startswith(f"{COUNT}_p") and int(c[len(COUNT) + 2:]) >= 2]
    p = pred[p_cols].sum(axis=1).to_numpy()
    n = obs[COUNT].to_numpy(float)
    okn = np.isfinite(n)
    y = (n[okn] >= 2).astype(float)
    p = p[okn]
    deciles = []
    if p.size >= 10:
        edges = np.quantile(p, np.linspace(0, 1, 11))
        idx = np.clip(np.searchsorted(edges, p, side="right") - 1, 0, 9)
        for i in range(10):
            sel = idx == i
            if sel.sum() >= 50:
                deciles.append({"rows": int(sel.sum()), "predicted": float(p[sel].mean()),
                                "observed": float(y[sel].mean())})
    flagged = pred["outside_training_region"].to_numpy(bool)
    return {
        "rows": int(len(obs)), "volume_rows": int(ok.sum()),
        "median_error_percent": float(np.median(err)), "p90_error_percent": float(np.percentile(err, 90)),
        "one_drop_coverage_percent": float(covered.mean() * 100),
        "one_drop_median_width_percent": float(np.median((hi - lo) / v[ok]) * 100),
        "satellites_brier": float(np.mean((p - y) ** 2)),
        "satellites_rate": float(y.mean()),
        "worst_decile_points": float(max((abs(d["observed"] - d["predicted"]) * 100 for d in deciles), default=np.nan)),
        "deciles_checked": len(deciles),
        "flagged_percent": float(flagged.mean() * 100),
        "coverage_of_unflagged_percent": float(covered[~flagged[ok]].mean() * 100) if (~flagged[ok]).any() else np.nan,
    }


def main(argv=None) -> int:
    from identify.tabular import fit_table, read_table

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--csv", type=Path, default=DEFAULT_CSV)
    ap.add_argument("--folds", type=int, default=5, help="outer folds (the fit's own inner folds: 5)")
    ap.add_argument("--repeats", type=int, default=1, help="outer K-fold repeats (split seeds 0, 1, ...)")
    ap.add_argument("--seed", type=int, default=0, help="the fit's seed")
    ap.add_argument("--json", type=Path, default=None, help="also write the figures here")
    args = ap.parse_args(argv)
    from sklearn.model_selection import KFold

    table = read_table(args.csv)
    t0 = time.time()
    preds = []
    chosen = []
    for r in range(args.repeats):
        pred = [None] * len(table)
        parts = []
        for k, (tr, te) in enumerate(KFold(args.folds, shuffle=True, random_state=r).split(table)):
            m = fit_table(table.iloc[tr], INPUTS, [VOLUME, COUNT], seed=args.seed)
            chosen.append(m.continuous[VOLUME].candidate)
            p = m.predict(table.iloc[te])
            p.index = te
            parts.append(p)
            print(f"repeat {r} fold {k}: {m.continuous[VOLUME].candidate} ({time.time() - t0:.0f} s)", file=sys.stderr)
        pred = pd.concat(parts).sort_index()
        preds.append((pred, table.reset_index(drop=True)))
    allp = pd.concat([p for p, _ in preds], ignore_index=True)
    allo = pd.concat([o for _, o in preds], ignore_index=True)
    cv = scores(allp, allo)
    cv["repeats"], cv["folds"], cv["volume_models_chosen"] = args.repeats, args.folds, sorted(set(chosen))

    held = table["w3"] >= 22
    m = fit_table(table[~held], INPUTS, [VOLUME, COUNT], seed=args.seed)
    ext = scores(m.predict(table[held]), table[held])
    ext["train_rows"] = int((~held).sum())
    out = {"cv": cv, "w3_ge_22_held_out": ext, "seconds": round(time.time() - t0, 1)}
    print(json.dumps(out, indent=2))
    if args.json is not None:
        from dvcore.atomic import write_json

        write_json(args.json, out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
