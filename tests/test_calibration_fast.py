"""The calibration's faster paths give the answers of the plain ones, to the bit (issue 30 item 4:
the per-shot cost of a 2048 x 1536 frame calibrated alone)."""

from __future__ import annotations

import cv2
import numpy as np

from dropvision.background import estimate_background
from dropvision.calibration_pass import transmission_noise
from dropvision.nozzle import components_with_stats


def _frame(seed: int = 0) -> np.ndarray:
    """A backlit frame: a vignetted background, a holder at the top, drops and specks, noise."""
    rng = np.random.default_rng(seed)
    h, w = 300, 220
    yy, xx = np.mgrid[0:h, 0:w]
    img = 200.0 - 60.0 * ((xx - 90) ** 2 + (yy - 140) ** 2) / (w * w)
    img[:60, 80:140] = 20.0  # the holder
    for cy, cx, r in ((150, 110, 14), (210, 112, 5), (250, 40, 2)):
        img[(yy - cy) ** 2 + (xx - cx) ** 2 <= r * r] = 25.0
    img += rng.normal(0.0, 2.0, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8)


def test_components_with_stats_are_opencv_s_default_ones():
    rng = np.random.default_rng(3)
    masks = [(_frame(k) < 100).astype(np.uint8) for k in range(3)]
    masks += [(rng.random((120, 170)) < p).astype(np.uint8) for p in (0.2, 0.45, 0.6)]
    for mask in masks:
        n, lab, stats, cent = cv2.connectedComponentsWithStats(mask, connectivity=8)
        n2, lab2, stats2, cent2 = components_with_stats(mask)
        assert n == n2 > 1
        np.testing.assert_array_equal(lab2, lab)
        np.testing.assert_array_equal(stats2, stats)
        np.testing.assert_allclose(cent2, cent)


def test_the_background_of_one_frame_is_that_of_the_frame_summed_twice():
    img = _frame(1)
    one = estimate_background([img])
    two = estimate_background([img, img])  # the sums' path: the mean is the frame itself
    assert one.n_frames == 1 and two.n_frames == 2
    np.testing.assert_array_equal(one.background, two.background)
    assert one.residual == two.residual > 0 and one.falloff == two.falloff > 0


def test_the_transmission_noise_is_the_plain_medians():
    rng = np.random.default_rng(5)
    t = np.clip(1.0 + rng.normal(0.0, 0.02, (200, 150)), 0, None).astype(np.float32)
    t[50:90, 40:70] = 0.1  # a body
    d = np.diff(t, axis=1)[(t[:, 1:] > 0.9) & (t[:, :-1] > 0.9)]
    plain = float(1.4826 * np.median(np.abs(d - np.median(d))) / np.sqrt(2.0))
    assert transmission_noise(t, 0.5) == plain
    assert abs(plain - 0.02) < 0.002
    assert transmission_noise(t[:3, :3], 0.5) == 0.5  # too few bright pairs: the default
