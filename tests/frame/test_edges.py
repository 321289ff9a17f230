"""The one edge level rule and the one crossing primitive (dropvision/frame/edges.py)."""

from __future__ import annotations

import numpy as np
import pytest

from dropvision.frame.edges import (DEFAULT_EDGE_THRESHOLD, crossing_fraction, edge_threshold, first_pass_threshold,
                              first_rising_crossing, runs, subpixel_edges)


def test_edge_threshold_half_way_to_the_interior():
    assert edge_threshold(0.0) == DEFAULT_EDGE_THRESHOLD == 0.5
    assert edge_threshold(0.4) == pytest.approx(0.7)


@pytest.mark.parametrize("darkest, expected", [(0.1, 0.5), (0.3, 0.5), (0.5, 0.75), (0.79, 0.895), (0.8, 0.5)])
def test_first_pass_threshold_low_contrast_only(darkest, expected):
    assert first_pass_threshold(darkest) == pytest.approx(expected)


def test_crossing_fraction_from_either_sample():
    # dark 0.2, bright 1.0, level 0.6: half-way
    assert crossing_fraction(0.2, 1.0, 0.6) == pytest.approx(0.5)
    assert crossing_fraction(0.2, 0.6, 0.5) == pytest.approx(0.75)
    assert crossing_fraction(0.2, 0.6, 0.5, from_bright=True) == pytest.approx(0.25)
    # clipped to the pixel pair
    assert crossing_fraction(0.7, 1.0, 0.6) == 0.0 and crossing_fraction(0.1, 0.4, 0.6) == 1.0


def test_crossing_fraction_flat_pair():
    t = np.array([0.8, 0.3, 0.6])
    np.testing.assert_array_equal(crossing_fraction(t, t, 0.6), [0.0, 1.0, 0.5])
    np.testing.assert_array_equal(crossing_fraction(t, t, 0.6, from_bright=True), [1.0, 0.0, 0.5])
    assert crossing_fraction(0.6, 0.6, 0.6) == 0.5


def test_crossing_fraction_keeps_float32():
    f = crossing_fraction(np.float32([0.2, 0.3]), np.float32([1.0, 0.9]), 0.6)
    assert f.dtype == np.float32


def test_subpixel_edges_of_a_linear_ramp():
    # one row: bright 1.0, then 0.6, 0.2 (dark), 0.2, then 0.6, 1.0; level 0.5 -> edges at 1.25 and 3.75
    image = np.array([[1.0, 0.6, 0.2, 0.2, 0.6, 1.0]], np.float32)
    mask = image < 0.5
    r, s, e = runs(mask)
    ed = subpixel_edges(image, np.ones_like(image), r, s, e, 0.5)
    assert ed.left_px[0] == pytest.approx(1.25) and ed.right_px[0] == pytest.approx(3.75)
    assert ed.chord_px[0] == pytest.approx(2.5) and not ed.touches


def test_first_rising_crossing():
    profile = np.array([1.0, 0.1, 0.1, 0.3, 0.7, 1.0])
    assert first_rising_crossing(profile, 0, 6, 0.5) == pytest.approx(3.5)
    assert first_rising_crossing(profile, 4, 6, 0.5) != first_rising_crossing(profile, 4, 6, 0.5)  # NaN: none
