"""dropvision.analysis.tracking: the line fit, the neighbour-outlier rule and the main drop of every frame,
each against values worked out by hand."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

import dropvision.quality as q
from dropvision.config import MeasureConfig
from dropvision.analysis.tracking import fit_line, neighbour_outliers, track_main_drop


# --- fit_line ----------------------------------------------------------------------------------
def test_fit_line_by_hand():
    """x 0..3, y 1, 3, 5, 8: mean x 1.5, mean y 4.25, Sxx 5, Sxy 11.5: slope 2.3, intercept 0.8;
    residuals 0.2, -0.1, -0.4, 0.3 (sum of squares 0.30): slope se sqrt(0.30 / 2 / 5)."""
    line = fit_line([0.0, 1.0, 2.0, 3.0, np.nan], [1.0, 3.0, 5.0, 8.0, 100.0])  # the NaN point is left out
    assert line.n == 4
    assert line.slope == pytest.approx(2.3, rel=1e-12)
    assert line.intercept == pytest.approx(0.8, rel=1e-12)
    assert line.slope_se == pytest.approx(math.sqrt(0.03), rel=1e-12)


def test_fit_line_too_few_points():
    two = fit_line([0.0, 2.0], [1.0, 5.0])
    assert two.slope == pytest.approx(2.0) and two.intercept == pytest.approx(1.0) and math.isnan(two.slope_se)
    assert math.isnan(fit_line([1.0], [1.0]).slope)
    assert math.isnan(fit_line([3.0, 3.0, 3.0], [1.0, 2.0, 3.0]).slope)  # x constant: no line


# --- neighbour_outliers ------------------------------------------------------------------------
def test_neighbour_outliers_by_hand():
    """y = 2x on x 0..9 with y(5) = 60 instead of 10: its neighbours predict it 10 (residual 50) and it
    spoils theirs (residual -25 at x 4 and 6); the other seven residuals are 0, so the scatter (lower
    quartile of |r|) is 0 and the floor decides: x 5 is the outlier, and once it is out nothing else is."""
    x = np.arange(10.0)
    y = 2.0 * x
    y[5] = 60.0
    assert np.flatnonzero(neighbour_outliers(x, y, sigmas=4.0, floor=1.0)).tolist() == [5]
    assert not neighbour_outliers(x, y, sigmas=4.0, floor=51.0).any()  # 50 off: under the floor
    # non-finite points are ignored; fewer than 4 distinct x: nothing judged
    y_nan = y.copy()
    y_nan[5] = np.nan
    assert not neighbour_outliers(x, y_nan, 4.0, 1.0).any()
    assert not neighbour_outliers(x[:3], np.array([0.0, 50.0, 0.0]), 4.0, 1.0).any()


# --- track_main_drop ---------------------------------------------------------------------------
@dataclass
class Body:
    volume_nl: float
    volume_uncertainty_nl: float
    z_um: float = 0.0
    x_um: float = 0.0
    length_um: float = 1.0
    diameter_um: float = 1.0
    top_row: float = 100.0
    leaves: bool = False
    out_of_band: bool = False
    on_dust: bool = False
    touching: bool = False
    long: bool = False
    top_chord_ratio: float = 1.0
    random_uncertainty_nl: float = float("nan")

    def elongated(self, compact_ratio: float) -> bool:
        return self.long


@dataclass
class Record:
    delay_us: float
    bodies: list
    neck_px: float = float("nan")
    attached_bottom_row: float = float("nan")


def _sequence():
    main = Body(10.0, 0.2, z_um=100.0, x_um=1.0, length_um=30.0, diameter_um=25.0, random_uncertainty_nl=0.12)
    touching = Body(1.0, 0.05, touching=True, random_uncertainty_nl=0.05)
    apart = Body(0.5, 0.03)
    return [
        Record(10.0, [], neck_px=1.0),  # attached, neck under ambiguous_gap_px 1.5: ambiguous
        Record(20.0, [], neck_px=5.0),  # attached, clear
        Record(30.0, []),  # detached delay, no body: no drop
        Record(40.0, [Body(9.0, 0.2, top_row=10.0, leaves=True)], attached_bottom_row=8.0),  # leaves, 2 px gap
        Record(50.0, [main, touching, apart]),  # compact main drop with two satellites
        Record(60.0, [Body(12.0, 0.3, long=True)]),  # still carries its tail
    ]


def test_track_main_drop_by_hand():
    attached = np.array([True, True, False, False, False, False])
    drop, found = track_main_drop(_sequence(), attached, MeasureConfig(), [[] for _ in range(6)])
    nan = np.nan
    # main drop: its own volume plus the touching satellite's (10 + 1), uncertainties added (0.2 + 0.05)
    np.testing.assert_array_equal(drop.drop_volume_nl, [nan, nan, nan, nan, 11.0, 12.0])
    np.testing.assert_allclose(drop.drop_volume_uncertainty_nl, [nan, nan, nan, nan, 0.25, 0.3], rtol=1e-12)
    # their random parts, the edges' own noise, independent: in quadrature (0.12, 0.05 -> 0.13)
    np.testing.assert_allclose(drop.drop_volume_random_uncertainty_nl, [nan, nan, nan, nan, 0.13, nan], rtol=1e-12)
    # detached: 0 where attached or no drop, every body of the frame (10 + 1 + 0.5) where trusted
    np.testing.assert_array_equal(drop.detached_volume_nl, [0.0, 0.0, 0.0, nan, 11.5, 12.0])
    np.testing.assert_allclose(drop.detached_volume_uncertainty_nl, [0.0, 0.0, 0.0, nan, 0.28, 0.3], rtol=1e-12)
    np.testing.assert_array_equal(drop.n_satellites, [0.0, 0.0, nan, nan, 2.0, 0.0])
    np.testing.assert_array_equal(drop.z_um, [nan, nan, nan, nan, 100.0, 0.0])
    np.testing.assert_array_equal(drop.length_um, [nan, nan, nan, nan, 30.0, 1.0])
    # the tail at 60 us keeps the compact-looking drop at 50 us out of flight too (a tail merges once)
    assert not drop.inflight.any()
    by_flag = {f.flag: f.frames for f in found}
    assert [f.flag for f in found] == [q.DROP_LEAVES, q.AMBIGUOUS, q.NO_DROP, q.TAIL]
    assert by_flag == {q.DROP_LEAVES: (3,), q.AMBIGUOUS: (0, 3), q.NO_DROP: (2,), q.TAIL: (4, 5)}
    assert all(f.note is None and not f.withheld for f in found)


def test_untrusted_tail_does_not_hold_earlier_frames():
    """A tail seen in a frame whose intensities are not trusted (or inconsistent with its neighbours)
    does not keep the earlier compact drop out of flight; the flags passed in are not changed."""
    attached = np.array([True, True, False, False, False, False])
    for prior in (q.BLURRED, q.NEIGHBOURS):
        flags = [[] for _ in range(5)] + [[prior]]
        drop, found = track_main_drop(_sequence(), attached, MeasureConfig(), flags)
        assert drop.inflight.tolist() == [False, False, False, False, True, False]
        assert dict((f.flag, f.frames) for f in found)[q.TAIL] == (5,)
        assert flags[5] == [prior] and flags[4] == []
