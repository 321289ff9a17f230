"""The dark mask is exactly ``I / B < threshold``, pixel by pixel, for every grey level.

`dropvision.frame.segmentation.threshold_image` compares integers against ``ceil(threshold * B)``
instead of dividing every frame by the background; the reference here is the division itself,
done in float64 over every grey level of the frame's dtype.  A threshold shifted by 0.01 (the
planted mutant ``threshold_plus_001`` of tools/mutants.py) moves a pixel's edge by a few
hundredths of a pixel only, too little for the volume tests, but it changes which grey levels
are dark and fails here.
"""

from __future__ import annotations

import numpy as np
import pytest

from dropvision.frame import segmentation as sg


@pytest.mark.parametrize("dtype, threshold", [(np.uint8, 0.56), (np.uint8, 0.5), (np.uint16, 0.531), (np.uint16, 0.6)])
def test_dark_mask_is_transmission_below_the_threshold(dtype, threshold):
    rng = np.random.default_rng(11)
    top = np.iinfo(dtype).max
    levels = np.arange(top + 1) if top < 1000 else np.unique(np.linspace(0, top, 4001).round())
    levels = levels.astype(dtype)
    # backgrounds as the calibration gives them (float32, not integers), one per row
    background = rng.uniform(0.3 * top, 0.95 * top, 37).astype(np.float32)
    image = np.broadcast_to(levels, (background.size, levels.size)).copy()
    b_img = np.broadcast_to(background[:, None], image.shape).copy()
    mask = sg.dark_mask(image, sg.threshold_image(b_img, threshold, dtype))
    expected = image.astype(np.float64) / b_img.astype(np.float64) < threshold
    assert mask.dtype == np.uint8 and set(np.unique(mask)) <= {0, 255}
    assert np.array_equal(mask == 255, expected), f"{np.count_nonzero((mask == 255) != expected)} pixels differ"
    # the mask's dark grey levels per row end where I / B reaches the threshold: not a level more
    first_bright = np.argmax(~expected, axis=1)
    assert np.all(image[np.arange(image.shape[0]), first_bright] >= threshold * background)
