"""Calibration of the confidence and prediction intervals of `identify predict` (issue 13).

For each seed: a synthetic campaign (`identify.synthetic_dataset.make_synthetic_dataset`, known truth,
``noise_percent`` noise) on a training grid of n x n controls over the paper's range
(u1 50..80 um/ms, u2 20..35 um) is fitted (`fit_hybrid(..., arx=False)`); at ``points``
held-out (u1, u2) drawn uniformly in the range (never on the grid) the model's intervals
(`HybridModel.interval_prediction`) are compared with

* the noise-free truth (``truth.json``): coverage of the confidence interval;
* one individual noisy drop per point, drawn with the dataset's own noise model (a second
  `make_synthetic_dataset` call at the held-out controls with another seed): coverage of
  the prediction interval.

    .venv/bin/python tools/interval_coverage.py [--seeds 10] [--points 20] [--grid 5] [--level 0.95]
        [--family linear|curved|exponential|saturating|curved_heavy_tailed|exponential_pinchoff_off_by_one|all]

Laws the model does not contain (issue 23, ``--family``, :data:`FAMILIES`): the project's linear
laws and Gaussian scatter hold the hybrid model exactly; the other families keep the same
physical ECM but add to the pinch-off law and both adjusters curvature in u1, an interaction
and smooth features no polynomial of Eq. (7) holds (:data:`LAWS`: ``curved`` (quadratic, x1 x2,
a sine), ``exponential`` (exponential growth in u1 times a linear u2 factor, a cosine in u2),
``saturating`` (tanh in u1, a local Gaussian bump)), some with heavier-tailed scatter (Student t
with 3 degrees of freedom, the same standard deviation) or with 12 % of the training sequences'
pinch-off detected one strobe delay (10 us) early or late. Printed per family and output: the
coverage of both intervals, the RMS standardised error of the mean (and of one drop), the held-out relative errors
of the point prediction (max |error|, RMS) and how often the model discrepancy dominates the
mean-drop interval.

``--measured``: image-measured campaigns instead (what `make demo` does): per seed, a training
grid of n x n controls (the paper's range; the grid jittered per seed by up to a quarter step so
that every seed has its own lack of fit) and ``points`` held-out controls are rendered as image
sequences (`dropvision.synth`, the demo's small frames: 192 x 640 px, delays 0..1600 us every
10 us; per seed its own imaging conditions, edge blur 0.6-1.4 px and image noise 0.5-1.5, so
that the systematic errors of the measurement differ between campaigns; render seed per
sequence), measured by `dropvision campaign`
(`run_campaign`) and the training campaign fitted; the confidence interval is compared with the
noise-free truth of the synthesizer's physics (`identify.physics.drop_history`; pinch-off: the
first strobe delay at or after the continuous instant, the quantity the images define), the
prediction interval with the held-out sequences' own measured values. Also printed: the
coverage without the systematic measurement term (``intervals.measurement``), to show what it
adds, and with its method part only (no pixel-size part: the synthetic pixel size is exact, so
this study cannot exercise that part).

    .venv/bin/python tools/interval_coverage.py --measured [--seeds 3] [--points 8] [--grid 4] [--workers 2]

Prints one row per output (pinch-off, in-flight volume, jetting velocity) and the binomial
95 % band of the coverage for the number of points.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from identify.synthetic_dataset import make_synthetic_dataset  # noqa: E402
from identify.physics import SynthPhysics  # noqa: E402
from identify.hybrid import INTERVAL_OUTPUTS  # noqa: E402
from identify.hybrid_fit import fit_hybrid  # noqa: E402

U1_RANGE, U2_RANGE = (50.0, 80.0), (20.0, 35.0)


def held_out_points(rng, n: int, grid) -> list[tuple[float, float]]:
    on_grid = {(round(a, 6), round(b, 6)) for a, b in grid}
    pts = []
    while len(pts) < n:
        p = (round(float(rng.uniform(*U1_RANGE)), 3), round(float(rng.uniform(*U2_RANGE)), 3))
        if p not in on_grid:
            pts.append(p)
    return pts


# ---- families of laws the model does not contain (issue 23) ------------------------------------


def _x(u1_um_per_ms, u2_um):
    """Controls scaled to [-1, 1] over the paper's range."""
    return (u1_um_per_ms - 65.0) / 15.0, (u2_um - 27.5) / 7.5


def _bump(x1, x2, c1, c2, width):
    return float(np.exp(-((x1 - c1) ** 2 + (x2 - c2) ** 2) / width))


#: Extra terms added to the linear laws of `identify.physics.SynthPhysics` (pinch-off µs, volume
#: adjuster nl, velocity adjuster m/s) at scaled controls (x1, x2) in [-1, 1]: curvature in u1, an
#: interaction, and smooth features that no polynomial of Eq. (7) up to order (2, 3) holds. Their
#: sizes are those of the 1 % drop scatter (pinch-off ~11 us, in-flight volume ~0.18 nl, velocity
#: ~0.013 m/s), so that the misfit they leave is of the order of the parameter uncertainty. The
#: features are smooth on the scale of the training grid (periods of at least ~3.6 steps of the
#: 5 x 5 grid): a feature between the grid points (sin(2 pi x1) vanishes on every point of a
#: 5-point grid) is invisible to any interval built from the data.
LAWS = {
    "curved": (
        lambda x1, x2: 35.0 * x1**2 + 12.0 * x1 * x2 + 8.0 * np.sin(1.1 * np.pi * x1 + 0.7 * x2),
        lambda x1, x2: 0.20 * x1**2 + 0.08 * x1 * x2 + 0.06 * np.sin(1.0 * np.pi * x1 + 0.5 * np.pi * x2),
        lambda x1, x2: 0.030 * x1**2 + 0.012 * x1 * x2 + 0.010 * np.sin(1.1 * np.pi * x1 + 0.5 * np.pi * x2),
    ),
    "exponential": (
        lambda x1, x2: 25.0 * (np.exp(x1) - 1.0 - x1) * (1.0 + 0.4 * x2) + 10.0 * np.cos(0.9 * np.pi * x2),
        lambda x1, x2: 0.10 * (np.exp(1.2 * x1) - 1.0) * (1.0 + 0.5 * x2) + 0.08 * np.cos(0.9 * np.pi * x2),
        lambda x1, x2: 0.012 * (np.exp(1.5 * x1) - 1.0 - 1.5 * x1) + 0.008 * x1 * x2**2 + 0.010 * np.cos(np.pi * x1),
    ),
    "saturating": (
        lambda x1, x2: -30.0 * np.tanh(2.0 * x1) + 20.0 * _bump(x1, x2, 0.3, -0.4, 0.2),
        lambda x1, x2: 0.15 * np.tanh(2.0 * x1) * x2 + 0.12 * _bump(x1, x2, -0.3, 0.3, 0.15),
        lambda x1, x2: 0.020 * np.tanh(2.5 * x1) + 0.010 * x1 * x2 + 0.015 * _bump(x1, x2, 0.4, 0.2, 0.12),
    ),
}


def student_t3(rng, size=None):
    """Student t with 3 degrees of freedom scaled to unit variance (heavier tails than a normal)."""
    return rng.standard_t(3, size) / np.sqrt(3.0)


#: Misfit families: (laws of :data:`LAWS` or None for the linear ones, scatter, fraction of
#: sequences whose pinch-off is detected one strobe delay early or late).
FAMILIES = {
    "linear": (None, None, 0.0),
    "curved": ("curved", None, 0.0),
    "saturating": ("saturating", None, 0.0),
    "exponential": ("exponential", None, 0.0),
    "curved_heavy_tailed": ("curved", student_t3, 0.0),
    "exponential_pinchoff_off_by_one": ("exponential", None, 0.12),
}


@dataclass(frozen=True)
class CurvedPhysics(SynthPhysics):
    """`identify.physics.SynthPhysics` (same ECM) with the laws of :data:`LAWS` ``[laws]`` added."""

    laws: str = "curved"

    def pinchoff_instant_us(self, u1_um_per_ms: float, u2_um: float) -> float:
        return super().pinchoff_instant_us(u1_um_per_ms, u2_um) + float(LAWS[self.laws][0](*_x(u1_um_per_ms, u2_um)))

    def volume_adjuster_nl_at(self, u1_um_per_ms: float, u2_um: float) -> float:
        return super().volume_adjuster_nl_at(u1_um_per_ms, u2_um) + float(LAWS[self.laws][1](*_x(u1_um_per_ms, u2_um)))

    def velocity_adjuster_m_s_at(self, u1_um_per_ms: float, u2_um: float) -> float:
        return super().velocity_adjuster_m_s_at(u1_um_per_ms, u2_um) + float(LAWS[self.laws][2](*_x(u1_um_per_ms, u2_um)))


def family_dataset(out: Path, family: str, grid, noise_percent: float, seed: int, repeats: int = 1):
    """A synthetic campaign of ``family`` (:data:`FAMILIES`) at ``grid``, with truth.json."""
    laws, draw, off_fraction = FAMILIES[family]
    physics = None if laws is None else CurvedPhysics(laws=laws)
    ds = make_synthetic_dataset(out, grid=grid, noise_percent=noise_percent, seed=seed, physics=physics,
                                noise_draw=draw, repeats=repeats)
    if off_fraction > 0:  # pinch-off detected one strobe delay off in a few sequences
        rng = np.random.default_rng(40_000 + seed)
        n = len(ds.summary)
        hit = rng.choice(n, size=max(1, int(round(off_fraction * n))), replace=False)
        su = ds.summary.copy()
        su.loc[hit, "pinchoff_us"] += ds.sample_interval_us * rng.choice([-1.0, 1.0], size=hit.size)
        ds.summary = su
        su.to_parquet(Path(out) / "summary.parquet", index=False)
    return ds


def coverage(seeds, points: int = 20, grid_n: int = 5, level: float = 0.95, noise_percent: float = 1.0,
             samples: int = 2000, family: str = "linear", repeats: int = 1) -> pd.DataFrame:
    """One row per (seed, held-out point, output): inside_confidence, inside_prediction, z.

    ``family``: the laws and scatter of the campaigns (:data:`FAMILIES`; "linear": the project's
    own linear laws and Gaussian scatter). Also the relative error of the point prediction
    against the noise-free truth (``rel_error_%``) and the term that dominates each interval.
    """
    grid = [(float(a), float(b)) for a in np.linspace(*U1_RANGE, grid_n) for b in np.linspace(*U2_RANGE, grid_n)]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in seeds:
            ds = family_dataset(Path(tmp) / f"train{seed}", family, grid, noise_percent, seed, repeats)
            model = fit_hybrid(ds, arx=False, seed=0).model
            pts = held_out_points(np.random.default_rng(10_000 + seed), points, grid)
            ho_dir = Path(tmp) / f"held_out{seed}"
            drops = family_dataset(ho_dir, family, pts, noise_percent, 20_000 + seed).summary
            truth = json.loads((ho_dir / "truth.json").read_text())["per_control"]
            for i, (u1, u2) in enumerate(pts):
                iv = model.interval_prediction(u1, u2, samples=samples, seed=i, level=level)
                for k in INTERVAL_OUTPUTS:
                    e, t, y = iv[k], truth[i][k], float(drops[k].iloc[i])
                    rows.append({"family": family, "seed": seed, "u1": u1, "u2": u2, "output": k, "truth": t,
                                 "drop": y, "mean": e["mean"],
                                 "inside_confidence": e["mean_drop_low"] <= t <= e["mean_drop_high"],
                                 "inside_prediction": e["one_drop_low"] <= y <= e["one_drop_high"],
                                 "z_confidence": (e["mean"] - t) / e["mean_drop_std"],
                                 "z_prediction": (e["mean"] - y) / e["one_drop_std"],
                                 "rel_error_%": 100 * (e["mean"] - t) / t,
                                 "mean_drop_half_width_%": 100 * (e["mean_drop_high"] - e["mean"]) / abs(t),
                                 "mean_drop_dominant": e["mean_drop_dominant_term"]})
    return pd.DataFrame(rows)


#: Rendering of the measured mode: the demo's campaign frames (dropvision/app/demo.py).
MEASURED_OVERRIDES = {"width_px": 192, "height_px": 640, "tip_row": 40.4, "axis_col": 95.6,
                      "delays_us": tuple(float(d) for d in range(0, 1601, 10)), "noise": 0.5}


def _render(job) -> str:
    from dropvision.synth import SynthConfig, write_synthetic_sequence

    out, u1, u2, seed, imaging = job
    config = SynthConfig(u1_um_per_ms=u1, u2_um=u2, seed=seed, **{**MEASURED_OVERRIDES, **imaging})
    return str(write_synthetic_sequence(config, out, progress=False))


def _render_and_measure(root: Path, dataset: Path, points, seed0: int, workers: int, imaging: dict):
    """Render ``points`` as sequences below ``root`` and measure them into ``dataset``."""
    from concurrent.futures import ProcessPoolExecutor

    from dropvision.app.campaign import run_campaign
    from identify.dataset_checks import load_dataset

    root.mkdir(parents=True)
    jobs = [(str(root / f"p{i:03d}"), float(a), float(b), seed0 + i, imaging) for i, (a, b) in enumerate(points)]
    with ProcessPoolExecutor(max_workers=workers) as ex:
        list(ex.map(_render, jobs))
    res = run_campaign(root, dataset, workers=workers, progress=False)
    if res.failed:
        raise RuntimeError(f"sequences failed: {res.failed}")
    return load_dataset(dataset, min_controls=1)


def measured_coverage(seeds, points: int = 8, grid_n: int = 4, level: float = 0.95, samples: int = 2000,
                      workers: int = 2) -> pd.DataFrame:
    """Like :func:`coverage`, on image-measured campaigns (see the module docstring)."""
    from identify.measurement_uncertainty import METHOD_UNCERTAINTY
    from identify.physics import SynthPhysics, drop_history

    physics = SynthPhysics()
    method_rel = {"pinchoff_us": 0.0, "inflight_volume_nl": METHOD_UNCERTAINTY["volume_rel"],
                  "jetting_velocity_m_s": METHOD_UNCERTAINTY["velocity_rel"]}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in seeds:
            rng = np.random.default_rng(30_000 + seed)
            # the imaging conditions of this campaign (the systematic errors differ between campaigns)
            imaging = {"blur_px": round(float(rng.uniform(0.6, 1.4)), 3),
                       "noise": round(float(rng.uniform(0.5, 1.5)), 3)}
            g1, g2 = np.linspace(*U1_RANGE, grid_n), np.linspace(*U2_RANGE, grid_n)
            j1, j2 = (rng.uniform(-0.25, 0.25, 2) * [(g1[1] - g1[0]), (g2[1] - g2[0])])
            grid = [(round(float(np.clip(a + j1, *U1_RANGE)), 3), round(float(np.clip(b + j2, *U2_RANGE)), 3))
                    for a in g1 for b in g2]
            ds = _render_and_measure(Path(tmp) / f"train{seed}", Path(tmp) / f"train{seed}_ds", grid,
                                     100_000 * (seed + 1), workers, imaging)
            model = fit_hybrid(ds, arx=False, seed=0, folds=min(10, len(ds.summary))).model
            pts = held_out_points(np.random.default_rng(10_000 + seed), points, grid)
            ho = _render_and_measure(Path(tmp) / f"held{seed}", Path(tmp) / f"held{seed}_ds", pts,
                                     100_000 * (seed + 1) + 50_000, workers, imaging).summary
            h = float(ds.sample_interval_us)
            for i, (u1, u2) in enumerate(pts):
                row = ho[np.isclose(ho["u1_um_per_ms"], u1) & np.isclose(ho["u2_um"], u2)]
                dh = drop_history(physics, u1, u2)
                truth = {"pinchoff_us": float(np.ceil(dh.pinchoff_instant_us / h - 1e-9) * h),
                         "inflight_volume_nl": dh.inflight_volume_nl, "jetting_velocity_m_s": dh.jetting_velocity_m_s}
                iv = model.interval_prediction(u1, u2, samples=samples, seed=i, level=level)
                for k in INTERVAL_OUTPUTS:
                    e, t = iv[k], truth[k]
                    y = float(row[k].iloc[0]) if len(row) else float("nan")
                    half = e["mean_drop_high"] - e["mean"]
                    s0 = float(np.sqrt(max(e["mean_drop_std"] ** 2 - e["measurement_std"] ** 2, 0.0)))
                    half0 = half * s0 / e["mean_drop_std"] if e["mean_drop_std"] > 0 else 0.0
                    s_m = float(np.hypot(s0, method_rel[k] * e["mean"])) if k != "pinchoff_us" else e["mean_drop_std"]
                    half_m = half * s_m / e["mean_drop_std"] if e["mean_drop_std"] > 0 else 0.0
                    rows.append({"seed": seed, **imaging, "u1": u1, "u2": u2, "output": k, "truth": t, "drop": y,
                                 "mean": e["mean"], "measurement_std": e["measurement_std"],
                                 "inside_confidence": e["mean_drop_low"] <= t <= e["mean_drop_high"],
                                 "inside_prediction": e["one_drop_low"] <= y <= e["one_drop_high"],
                                 "inside_confidence_without_measurement": abs(t - e["mean"]) <= half0,
                                 "inside_confidence_method_only": abs(t - e["mean"]) <= half_m,
                                 "z_confidence": (e["mean"] - t) / e["mean_drop_std"] if e["mean_drop_std"] > 0
                                 else float("inf") * np.sign(e["mean"] - t),
                                 "rel_error_%": 100 * (e["mean"] - t) / t})
    return pd.DataFrame(rows)


def table(df: pd.DataFrame) -> pd.DataFrame:
    """Per output (and per family when the rows have one): coverage of both intervals at the level,
    RMS of the standardised error of the mean, and the held-out relative errors of the point
    prediction against the noise-free truth (max |error|, RMS) where the rows carry them."""
    if "family" in df and df["family"].nunique() > 1:
        return pd.concat([table(g).assign(family=f) for f, g in df.groupby("family", sort=False)], ignore_index=True)
    g = df.groupby("output", sort=False)
    out = pd.DataFrame({
        "seeds": g["seed"].nunique(), "n_points": g.size(),
        "confidence_coverage_%": 100 * g["inside_confidence"].mean(),
        "prediction_coverage_%": 100 * g["inside_prediction"].mean(),
        "rms_z_confidence": g["z_confidence"].apply(lambda z: float(np.sqrt(np.mean(z**2)))),
    })
    if "z_prediction" in df:
        out["rms_z_prediction"] = g["z_prediction"].apply(lambda z: float(np.sqrt(np.mean(z**2))))
    if "mean_drop_half_width_%" in df:
        out["max_abs_error_%"] = g["rel_error_%"].apply(lambda z: float(np.max(np.abs(z))))
        out["rms_error_%"] = g["rel_error_%"].apply(lambda z: float(np.sqrt(np.mean(z**2))))
        out["median_mean_drop_half_width_%"] = g["mean_drop_half_width_%"].median()
        out["discrepancy_dominant_%"] = 100 * g["mean_drop_dominant"].apply(lambda d: float(np.mean(d == "model_discrepancy")))
    if "inside_confidence_without_measurement" in df:
        out["confidence_without_measurement_%"] = 100 * g["inside_confidence_without_measurement"].mean()
        out["confidence_method_term_only_%"] = 100 * g["inside_confidence_method_only"].mean()
        out["mean_error_%"] = g["rel_error_%"].mean()
        out["rms_error_%"] = g["rel_error_%"].apply(lambda z: float(np.sqrt(np.mean(z**2))))
    out = out.reset_index()
    if "family" in df:
        out.insert(0, "family", df["family"].iloc[0])
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--points", type=int, default=20, help="held-out points per seed")
    ap.add_argument("--grid", type=int, default=5, help="training grid n x n")
    ap.add_argument("--level", type=float, default=0.95)
    ap.add_argument("--noise-percent", type=float, default=1.0)
    ap.add_argument("--measured", action="store_true",
                    help="image-measured campaigns (rendered, measured, fitted); defaults 3 seeds, 8 points, 4x4")
    ap.add_argument("--workers", type=int, default=2, help="processes for rendering and measuring (--measured)")
    ap.add_argument("--family", default="linear",
                    help="laws and scatter of the campaigns: " + ", ".join(FAMILIES) + "; several comma-separated, "
                         "or 'all'")
    ap.add_argument("--csv", type=Path, default=None, help="write the per-point rows here")
    args = ap.parse_args(argv)
    families = list(FAMILIES) if args.family == "all" else args.family.split(",")
    unknown = [f for f in families if f not in FAMILIES]
    if unknown:
        ap.error(f"--family: unknown {', '.join(unknown)} (known: {', '.join(FAMILIES)})")
    if args.measured:
        seeds = args.seeds if "--seeds" in (argv or sys.argv) else 3
        pts = args.points if "--points" in (argv or sys.argv) else 8
        grid = args.grid if "--grid" in (argv or sys.argv) else 4
        df = measured_coverage(range(seeds), pts, grid, args.level, workers=args.workers)
        what = (f"image-measured campaigns (demo frames), {seeds} seeds x {pts} held-out points, "
                f"{grid}x{grid} jittered training grid")
    else:
        seeds, pts, grid = args.seeds, args.points, args.grid
        df = pd.concat([coverage(range(seeds), pts, grid, args.level, args.noise_percent, family=f)
                        for f in families], ignore_index=True)
        what = (f"make_synthetic_dataset, {seeds} seeds x {pts} held-out points, {grid}x{grid} training grid, "
                f"noise {args.noise_percent:g} %, families {', '.join(families)}")
    if args.csv:
        df.to_csv(args.csv, index=False)
    t = table(df)
    n = int(t["n_points"].iloc[0])
    sd = 100 * np.sqrt(args.level * (1 - args.level) / n)
    print(f"nominal {100 * args.level:g} % intervals: {what}")
    with pd.option_context("display.width", 250, "display.max_columns", 30, "display.float_format", "{:.2f}".format):
        print(t.to_string(index=False))
    print(f"binomial sd of a coverage over {n} points at {100 * args.level:g} %: {sd:.2f} points of % "
          f"(95 % band {100 * args.level - 1.96 * sd:.1f}-{min(100.0, 100 * args.level + 1.96 * sd):.1f} %)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
