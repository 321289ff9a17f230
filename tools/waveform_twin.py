"""A twin of the MicroDrop dispenser of ../shared/realdata/waveform-sweep, built from its rows.

Not the model, and not fitted the way the model is: a surface of the log head volume over the six
parameters normalised to their ranges (:func:`_surface`, extremely randomised trees), fitted on
a bootstrap resample of the rows chosen by the seed (each seed is another plausible dispenser).
A shot at a setting returns

- ``head_volume_px3``: the surface there times ``exp(r)``, ``r`` an out-of-fold residual (5-fold:
  the same surface fitted without the row) of one of the :data:`NEIGHBOURS` training rows nearest
  the setting, drawn (their own scatter, gross outliers included: a real shot can fail the same
  way);
- ``n_drops``: the count of one of those rows, drawn (NaN volume when it is 0).

Use as a rig: ``identify tune model.json ... --rig tools/waveform_twin.py:fire`` (seed from the
environment variable ``DV_TWIN_SEED``, default 0; table from ``DV_TWIN_TABLE``, default dev.csv).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pandas as pd

INPUTS = ["V3", "w1", "w2", "w3", "d1", "d2"]
DEV = Path(__file__).resolve().parents[2] / "shared" / "realdata" / "waveform-sweep" / "dev.csv"
#: Training rows a shot draws its residual and its drop count from.
NEIGHBOURS = 6
#: Trees of the twin's surface.
TREES = 200


def _surface(Z, y, seed):
    """The twin's surface: extremely randomised trees (an average of many random partitions: a
    piecewise-smooth interpolant, another learner than the model's boosted trees). A thin-plate
    RBF over the six normalised parameters was tried first: out-of-fold median |error| 4 % (the
    trees: 0.72 %), too far from the data to be its twin."""
    from sklearn.ensemble import ExtraTreesRegressor

    return ExtraTreesRegressor(TREES, min_samples_leaf=1, random_state=seed, n_jobs=1).fit(Z, y)


class Twin:
    """``twin(settings: dict, shot: int) -> {"head_volume_px3": ..., "n_drops": ...}``."""

    def __init__(self, table: pd.DataFrame | None = None, seed: int = 0, inputs=INPUTS):
        from scipy.spatial import cKDTree

        df = pd.read_csv(DEV) if table is None else table
        self.inputs = list(inputs)
        X = df[self.inputs].to_numpy(float)
        self.low = X.min(axis=0)
        self.span = np.where(X.max(axis=0) > self.low, X.max(axis=0) - self.low, 1.0)
        Z = (X - self.low) / self.span
        v = df["head_volume_px3"].to_numpy(float)
        ok = np.isfinite(v) & (v > 0)
        y = np.where(ok, np.log(np.where(ok, v, 1.0)), np.nan)
        rng = np.random.default_rng(seed)
        boot = rng.choice(np.flatnonzero(ok), ok.sum(), replace=True)
        self.surface = _surface(Z[boot], y[boot], seed)
        # the scatter: out-of-fold residuals (5-fold: the same surface fitted without the row; an
        # in-sample residual of an interpolant is ~0)
        self.residuals = np.full(len(y), np.nan)
        folds = rng.integers(0, 5, len(y))
        for k in range(5):
            tr, te = ok & (folds != k), ok & (folds == k)
            self.residuals[te] = y[te] - _surface(Z[tr], y[tr], seed).predict(Z[te])
        self.counts = df["n_drops"].to_numpy(float)
        self.tree = cKDTree(Z)
        self.rng = np.random.default_rng(seed + 1_000_003)

    def truth(self, settings: dict) -> float:
        """The twin's smooth head volume (no scatter) at ``settings``."""
        z = (np.array([float(settings[n]) for n in self.inputs]) - self.low) / self.span
        return float(np.exp(self.surface.predict(z[None, :])[0]))

    def __call__(self, settings: dict, shot: int) -> dict:
        z = (np.array([float(settings[n]) for n in self.inputs]) - self.low) / self.span
        _, near = self.tree.query(z, k=NEIGHBOURS)
        n = float(self.counts[self.rng.choice(near)])
        res = self.residuals[near]
        res = res[np.isfinite(res)]
        r = float(self.rng.choice(res)) if res.size else 0.0
        vol = float(np.exp(self.surface.predict(z[None, :])[0] + r)) if n > 0 else float("nan")
        return {"head_volume_px3": vol, "n_drops": n, "truth_head_volume_px3": self.truth(settings)}


_TWIN: Twin | None = None


def fire(settings: dict, shot: int) -> dict:
    """The rig function: one twin per process (``DV_TWIN_SEED``, ``DV_TWIN_TABLE``)."""
    global _TWIN
    if _TWIN is None:
        table = os.environ.get("DV_TWIN_TABLE")
        _TWIN = Twin(None if not table else pd.read_csv(table), seed=int(os.environ.get("DV_TWIN_SEED", "0")))
    return _TWIN(settings, shot)
