"""Confidence and prediction intervals of the hybrid model are calibrated (issue 13, item 1).

A fast version of tools/interval_coverage.py: 2 seeds x 20 held-out points (5x5 training
grid, 1 % noise), 3 outputs -> 120 interval checks per kind at nominal 95 %. Binomial sd of a
coverage over 120 independent checks is 2.0 points of %, so 3 sd gives 89-100 %; the points
of one seed share one fit (correlated), so the band asserted is wider, 85-100 %, per kind.
Too wide intervals (coverage 100 %, e.g. the pinch-off jitter counted twice) are caught by
the RMS of (mean - truth) / confidence_std, which must be near 1 (0.6-1.5).
"""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))

from interval_coverage import coverage, table  # noqa: E402


@pytest.fixture(scope="module")
def cov():
    return coverage(seeds=(0, 1), points=20, grid_n=5, samples=1000)


def test_interval_coverage_in_band(cov):
    assert cov["u1"].size == 120
    conf = 100 * cov["inside_confidence"].mean()
    pred = 100 * cov["inside_prediction"].mean()
    assert 85.0 <= conf <= 100.0, conf
    assert 85.0 <= pred <= 100.0, pred
    for _, row in table(cov).iterrows():
        assert row["confidence_coverage_%"] >= 75.0 and row["prediction_coverage_%"] >= 75.0, row
    rms = float(np.sqrt(np.mean(cov["z_confidence"] ** 2)))
    assert 0.6 <= rms <= 1.5, rms


def test_held_out_points_are_not_training_controls(cov):
    grid = {(a, b) for a in np.linspace(50, 80, 5) for b in np.linspace(20, 35, 5)}
    assert not any((r.u1, r.u2) in grid for r in cov.itertuples())
