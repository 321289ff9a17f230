"""Hand cases of the run-level edge functions of `dropvision.frame.edges`: `runs`, `subpixel_edges`
(the frame's illumination gain, the ``touches`` flag) and `body_edges` (bounding box offsets,
``row_min``).  Each was let through by the other tests when planted (tools/mutants.py:
``flicker_gain_inverted``, ``right_side_never_touches``, ``row_min_ignored``): every test
frame there has a gain of 1, no run at the region's right side, and the attached liquid's
rows above the tip plane carry no weight in the volume.
"""

from __future__ import annotations

import numpy as np
import pytest

from dropvision.frame import edges as edg

# one row of transmission: dark run at columns 3..7; the edge level 0.55 is crossed half-way
# between columns 2 and 3 (0.8 -> 0.3) and between 7 and 8 (0.3 -> 0.8)
PROFILE = np.array([1.0, 1.0, 0.8, 0.3, 0.1, 0.1, 0.1, 0.3, 0.8, 1.0, 1.0])
LEVEL = 0.55


def _row_image(profile, background=200.0, gain=1.0):
    b = np.full((1, profile.size), background, np.float32)
    return (gain * profile * b).astype(np.float32), (1.0 / b).astype(np.float32)


def test_runs_hand_case():
    mask = np.array([[0, 1, 1, 0, 1], [1, 1, 1, 1, 1], [0, 0, 0, 0, 0]], bool)
    rows, starts, stops = edg.runs(mask)
    assert rows.tolist() == [0, 0, 1] and starts.tolist() == [1, 4, 0] and stops.tolist() == [3, 5, 5]


@pytest.mark.parametrize("gain", [1.0, 1.25, 0.8])
def test_subpixel_edges_divide_by_the_frame_gain(gain):
    """A frame lit ``gain`` times the background model has the same transmission once divided
    by the gain: the edges stay at 2.5 and 7.5 px."""
    img, inv_b = _row_image(PROFILE, gain=gain)
    ed = edg.subpixel_edges(img, inv_b, np.array([0]), np.array([3]), np.array([8]), LEVEL, gain)
    assert ed.left_px.tolist() == pytest.approx([2.5], abs=1e-6)
    assert ed.right_px.tolist() == pytest.approx([7.5], abs=1e-6)
    assert ed.chord_px.tolist() == pytest.approx([5.0], abs=1e-6) and not ed.touches
    if gain != 1.0:  # the same frame read as if lit like the background: the edges move
        plain = edg.subpixel_edges(img, inv_b, np.array([0]), np.array([3]), np.array([8]), LEVEL)
        assert abs(plain.chord_px[0] - 5.0) > 0.05


@pytest.mark.parametrize("start, stop, touches", [(3, 8, False), (0, 8, True), (3, 11, True), (0, 11, True)])
def test_subpixel_edges_touches_either_side(start, stop, touches):
    img, inv_b = _row_image(PROFILE)
    ed = edg.subpixel_edges(img, inv_b, np.array([0]), np.array([start]), np.array([stop]), LEVEL)
    assert ed.touches is touches


def test_body_edges_offsets_and_row_min():
    """A label image of a region starting at row 10, column 20 of the frame's region: edges in
    region coordinates, only the body's own label, rows from ``row_min`` on."""
    h, w = 9, 11
    img = np.tile(_row_image(PROFILE)[0], (h, 1))
    inv_b = np.full((h, w), 1.0 / 200.0, np.float32)
    labels = np.zeros((h, w), np.uint16)
    labels[2:7, 3:8] = 1
    labels[7:9, 0:2] = 2  # another body inside the bounding box below
    bbox = (0, 2, w, 9)
    ed = edg.body_edges(img, inv_b, labels, 1, bbox, LEVEL)
    assert ed.row.tolist() == [2, 3, 4, 5, 6]
    assert ed.left_px == pytest.approx([2.5] * 5, abs=1e-6) and ed.right_px == pytest.approx([7.5] * 5, abs=1e-6)
    cut = edg.body_edges(img, inv_b, labels, 1, bbox, LEVEL, row_min=4)
    assert cut.row.tolist() == [4, 5, 6]
    assert edg.body_edges(img, inv_b, labels, 1, bbox, LEVEL, row_min=9).row.size == 0
    # a bounding box starting at column 3: the columns are still the region's
    sub = edg.body_edges(img, inv_b, labels, 1, (3, 2, 8, 7), LEVEL)
    assert sub.left_px == pytest.approx([2.5] * 5, abs=1e-6) and sub.right_px == pytest.approx([7.5] * 5, abs=1e-6)
