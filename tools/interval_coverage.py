"""Calibration of the confidence and prediction intervals of `identify predict` (issue 13).

For each seed: a synthetic campaign (`identify.dataset.make_synthetic_dataset`, known truth,
``noise_percent`` noise) on a training grid of n x n controls over the paper's range
(u1 50..80 um/ms, u2 20..35 um) is fitted (`fit_hybrid(..., arx=False)`); at ``points``
held-out (u1, u2) drawn uniformly in the range (never on the grid) the model's intervals
(`HybridModel.interval_prediction`) are compared with

* the noise-free truth (``truth.json``): coverage of the confidence interval;
* one individual noisy drop per point, drawn with the dataset's own noise model (a second
  `make_synthetic_dataset` call at the held-out controls with another seed): coverage of
  the prediction interval.

    .venv/bin/python tools/interval_coverage.py [--seeds 10] [--points 20] [--grid 5] [--level 0.95]

Prints one row per output (pinch-off, in-flight volume, jetting velocity) and the binomial
95 % band of the coverage for the number of points.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from identify.dataset import make_synthetic_dataset  # noqa: E402
from identify.hybrid import INTERVAL_OUTPUTS, fit_hybrid  # noqa: E402

U1_RANGE, U2_RANGE = (50.0, 80.0), (20.0, 35.0)


def held_out_points(rng, n: int, grid) -> list[tuple[float, float]]:
    on_grid = {(round(a, 6), round(b, 6)) for a, b in grid}
    pts = []
    while len(pts) < n:
        p = (round(float(rng.uniform(*U1_RANGE)), 3), round(float(rng.uniform(*U2_RANGE)), 3))
        if p not in on_grid:
            pts.append(p)
    return pts


def coverage(seeds, points: int = 20, grid_n: int = 5, level: float = 0.95, noise_percent: float = 1.0,
             samples: int = 2000) -> pd.DataFrame:
    """One row per (seed, held-out point, output): inside_confidence, inside_prediction, z."""
    grid = [(float(a), float(b)) for a in np.linspace(*U1_RANGE, grid_n) for b in np.linspace(*U2_RANGE, grid_n)]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in seeds:
            ds = make_synthetic_dataset(Path(tmp) / f"train{seed}", grid=grid, noise_percent=noise_percent, seed=seed)
            model = fit_hybrid(ds, arx=False, seed=0).model
            pts = held_out_points(np.random.default_rng(10_000 + seed), points, grid)
            ho_dir = Path(tmp) / f"held_out{seed}"
            drops = make_synthetic_dataset(ho_dir, grid=pts, noise_percent=noise_percent, seed=20_000 + seed).summary
            truth = json.loads((ho_dir / "truth.json").read_text())["per_control"]
            for i, (u1, u2) in enumerate(pts):
                iv = model.interval_prediction(u1, u2, samples=samples, seed=i, level=level)
                for k in INTERVAL_OUTPUTS:
                    e, t, y = iv[k], truth[i][k], float(drops[k].iloc[i])
                    rows.append({"seed": seed, "u1": u1, "u2": u2, "output": k, "truth": t, "drop": y,
                                 "mean": e["mean"],
                                 "inside_confidence": e["confidence_low"] <= t <= e["confidence_high"],
                                 "inside_prediction": e["prediction_low"] <= y <= e["prediction_high"],
                                 "z_confidence": (e["mean"] - t) / e["confidence_std"]})
    return pd.DataFrame(rows)


def table(df: pd.DataFrame) -> pd.DataFrame:
    g = df.groupby("output", sort=False)
    return pd.DataFrame({
        "seeds": g["seed"].nunique(), "n_points": g.size(),
        "confidence_coverage_%": 100 * g["inside_confidence"].mean(),
        "prediction_coverage_%": 100 * g["inside_prediction"].mean(),
        "rms_z_confidence": g["z_confidence"].apply(lambda z: float(np.sqrt(np.mean(z**2)))),
    }).reset_index()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--points", type=int, default=20, help="held-out points per seed")
    ap.add_argument("--grid", type=int, default=5, help="training grid n x n")
    ap.add_argument("--level", type=float, default=0.95)
    ap.add_argument("--noise-percent", type=float, default=1.0)
    args = ap.parse_args(argv)
    df = coverage(range(args.seeds), args.points, args.grid, args.level, args.noise_percent)
    t = table(df)
    n = int(t["n_points"].iloc[0])
    sd = 100 * np.sqrt(args.level * (1 - args.level) / n)
    print(f"nominal {100 * args.level:g} % intervals, {args.seeds} seeds x {args.points} held-out points, "
          f"{args.grid}x{args.grid} training grid, noise {args.noise_percent:g} %")
    with pd.option_context("display.width", 160, "display.float_format", "{:.2f}".format):
        print(t.to_string(index=False))
    print(f"binomial sd of a coverage over {n} points at {100 * args.level:g} %: {sd:.2f} points of % "
          f"(95 % band {100 * args.level - 1.96 * sd:.1f}-{min(100.0, 100 * args.level + 1.96 * sd):.1f} %)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
