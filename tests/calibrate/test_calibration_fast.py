"""The calibration's faster paths give the answers of the plain ones, to the bit (issue 30 item 4:
the per-shot cost of a 2048 x 1536 frame calibrated alone)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from dropvision.calibrate.background import _block_means, background_residual, estimate_background, median_by_selection
from dropvision.calibrate.calibration_pass import attached_half_width_px, transmission_noise
from dropvision.calibrate.nozzle import (_ransac_draws, _sorted_median, _straight_stretch, _straight_walls, components_with_stats,
                               largest_top_body)
from dropvision.io.orientation import from_canonical, to_canonical
from dropvision.frame.segmentation import fill_holes, threshold_image


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


def _two_apart(t):
    """Differences of pixels two apart along the rows, both bright (`transmission_noise`'s pairs)."""
    return (t[:, 2:] - t[:, :-2])[(t[:, 2:] > 0.9) & (t[:, :-2] > 0.9)]


def test_the_transmission_noise_is_the_plain_medians():
    rng = np.random.default_rng(5)
    t = np.clip(1.0 + rng.normal(0.0, 0.02, (200, 150)), 0, None).astype(np.float32)
    t[50:90, 40:70] = 0.1  # a body
    d = _two_apart(t)
    plain = float(1.4826 * np.median(np.abs(d - np.median(d))) / np.sqrt(2.0))
    assert transmission_noise(t, 0.5) == plain
    assert abs(plain - 0.02) < 0.002
    assert transmission_noise(t[:3, :3], 0.5) == 0.5  # too few bright pairs: the default


def test_the_transmission_noise_of_8_bit_counts_in_2x2_cells():
    """An 8-bit frame whose noise is about one count, half of it shared by the 2x2 cells of a colour
    camera or a JPEG coder's chroma (true spread 1.16 counts with the rounding's): read on the raw
    counts, pixels two apart, within 5 % (1.02-1.03 of it over five seeds); neighbours' differences
    by their median absolute deviation (the rule before) give 0.90 of it (stuck at 1.048 counts)."""
    rng = np.random.default_rng(8)
    h, w = 400, 300
    cell = np.kron(rng.normal(0.0, 0.8, (h // 2, w // 2)), np.ones((2, 2)))
    own = rng.normal(0.0, 0.8, (h, w))
    background = 200.0 + 20.0 * np.linspace(0.0, 1.0, w)[None, :]  # a slow vignette
    image = np.clip(np.round(background + cell + own), 0, 255).astype(np.uint8)
    t = (image / background).astype(np.float32)
    truth = np.sqrt(0.8 ** 2 + 0.8 ** 2 + 1.0 / 12.0) / np.median(background)
    assert transmission_noise(t, 0.5, image) == pytest.approx(truth, rel=0.05)
    d = np.diff(t, axis=1)[(t[:, 1:] > 0.9) & (t[:, :-1] > 0.9)]
    before = float(1.4826 * np.median(np.abs(d - np.median(d))) / np.sqrt(2.0))
    assert before < 0.92 * truth


def test_the_median_by_selection_is_numpy_s_to_the_bit():
    rng = np.random.default_rng(7)
    cases = [rng.normal(0.0, 0.01, 300_001).astype(np.float32),  # odd count
             rng.normal(0.0, 0.01, 300_000).astype(np.float32),  # even count: the mean of the middle two
             rng.integers(0, 5, 250_000).astype(np.float32),  # many equal values about the middle
             np.abs(rng.standard_cauchy(200_000)),  # heavy tails (float64)
             np.r_[rng.normal(size=150_000), np.full(60_000, 1e9)],  # the middle far from the sample's bulk
             np.sort(rng.normal(size=200_000))]  # sorted: the strided sample is not random
    inf = rng.normal(size=200_000)
    inf[::1000] = np.inf
    cases.append(inf)
    for x in cases:
        plain = np.median(x)
        fast = median_by_selection(x.copy())
        assert fast.dtype == plain.dtype and fast == plain
    x = cases[1].copy()
    median_by_selection(x)
    np.testing.assert_array_equal(x, cases[1])  # not changed
    x[17] = np.nan
    assert np.isnan(median_by_selection(x)) and np.isnan(np.median(x))
    small = rng.normal(size=999)
    assert median_by_selection(small) == np.median(small)


def test_the_transmission_noise_of_a_large_region_is_the_plain_medians():
    rng = np.random.default_rng(6)
    t = np.clip(1.0 + rng.normal(0.0, 0.02, (700, 500)), 0, None).astype(np.float32)  # 300 000+ pairs
    t[100:300, 40:200] = 0.1
    d = _two_apart(t)
    assert d.size > 100_000
    plain = float(1.4826 * np.median(np.abs(d - np.median(d))) / np.sqrt(2.0))
    assert transmission_noise(t, 0.5) == plain


def _largest_top_body_plain(mask: np.ndarray, col: int | None):
    """The plain rule: every body labelled (OpenCV's default algorithm), the largest touching the top row."""
    n, lab, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    top = [k for k in range(1, n) if stats[k, cv2.CC_STAT_TOP] == 0
           and (col is None or stats[k, cv2.CC_STAT_LEFT] <= col < stats[k, cv2.CC_STAT_LEFT] + stats[k, cv2.CC_STAT_WIDTH])]
    if not top:
        return None
    k = max(top, key=lambda k: stats[k, cv2.CC_STAT_AREA])
    return fill_holes((lab == k).astype(np.uint8) * 255) > 0


def test_the_largest_top_body_by_flood_fill_is_the_labelled_one():
    rng = np.random.default_rng(11)
    masks = [(_frame(k) < 100).astype(np.uint8) for k in range(3)]
    masks += [(rng.random((120, 170)) < p).astype(np.uint8) for p in (0.2, 0.45, 0.6)]
    tie = np.zeros((40, 60), np.uint8)
    tie[:10, 5:15] = 1  # two top bodies of one area: the first in label order
    tie[:10, 30:40] = 1
    tie[4:6, 33:37] = 0  # a hole in the second, filled
    tie[4:6, 35:37] = 1  # (a hole of 4 px: 96 px filled, 100 with it)
    tie[9, 5:9] = 0  # 96 px: a tie of the pixel counts
    masks += [tie, np.zeros((30, 30), np.uint8), np.pad(np.ones((5, 5), np.uint8), 5)]  # none at the top
    many = np.zeros((20, 800), np.uint8)
    many[:3, ::3] = 1  # more than 250 top bodies
    many[:12, 400] = 1
    masks.append(many)
    checked = 0
    for mask in masks:
        for col in (None, 10, 35, 85, 110, 400):
            plain = _largest_top_body_plain(mask, col)
            fast = largest_top_body(mask.copy(), col)
            if plain is None:
                assert fast is None
                continue
            body, height = fast
            assert body.dtype == np.uint8 and height == int(np.nonzero(plain.any(axis=1))[0].max()) + 1
            np.testing.assert_array_equal(body > 0, plain[:height])
            assert not plain[height:].any()
            checked += 1
    assert checked >= 20


def test_the_ransac_draws_are_the_seeded_ones():
    for n in (20, 37, 500):
        rng = np.random.default_rng(0)
        plain = np.array([rng.choice(n, 2, replace=False) for _ in range(300)], dtype=np.intp)
        np.testing.assert_array_equal(_ransac_draws(n), plain)
        np.testing.assert_array_equal(_ransac_draws(n), plain)  # the cached copy, unchanged
    x = np.r_[np.arange(30.0), np.arange(30.0)]  # equal abscissae are left out, the order kept
    y = 2.0 * x + 1.0
    assert _straight_stretch(x, y, 0.5).all()


def test_the_rotations_by_opencv_are_numpy_s():
    rng = np.random.default_rng(2)
    turns = {"up": 2, "left": 1, "right": 3}
    for dtype in (np.uint8, np.uint16, np.float32, np.float64, np.int32, bool, np.int64):
        for shape in ((7, 5), (6, 9, 3), (4, 3, 1), (5, 4, 4), (5, 4, 5), (1, 8)):
            img = (rng.random(shape) * 200).astype(dtype)
            for orientation, k in turns.items():
                plain = np.ascontiguousarray(np.rot90(img, k))
                fast = to_canonical(img, orientation)
                assert fast.dtype == plain.dtype and fast.shape == plain.shape and fast.flags.c_contiguous
                np.testing.assert_array_equal(fast, plain)
                back = from_canonical(fast, orientation)
                assert back.shape == img.shape
                np.testing.assert_array_equal(back, img)
    view = rng.integers(0, 255, (9, 12), dtype=np.uint8)[::2, 1::3]  # not contiguous
    np.testing.assert_array_equal(to_canonical(view, "right"), np.rot90(view, 3))


def test_the_straight_walls_running_median_is_numpy_s():
    rng = np.random.default_rng(4)
    for _ in range(3000):
        m = int(rng.integers(1, 30))
        values = [rng.normal(100.0, 30.0, m), rng.integers(0, 40, m).astype(float), 0.5 * rng.integers(0, 9, m)]
        for v in values:
            assert _sorted_median(sorted(v.tolist())) == np.median(v)
    # the walls of a body: a holder 60 px wide above a nozzle 21 px wide, noisy, with a short wider stretch
    width = np.r_[np.full(30, 60.0), 21.0 + rng.integers(-1, 2, 40), np.full(4, 35.0), np.full(10, 90.0)]
    cand = np.ones(width.size, bool)
    assert _straight_walls(width, cand) == (30, 70)
    assert _straight_walls(width, cand, 60.0) == (0, 30)


@pytest.mark.slow
def test_the_block_means_are_numpy_s_to_the_bit():
    rng = np.random.default_rng(8)
    shapes = [(384, 512, 4), (512, 384, 4), (120, 160, 4), (16, 16, 2), (33, 250, 7), (17, 99, 3)]
    shapes += [(int(rng.integers(1, 200)), int(rng.integers(1, 200)), int(rng.integers(2, 9))) for _ in range(40)]
    for hb, wb, block in shapes:
        img = rng.normal(0.0, 0.05, (hb * block, wb * block)).astype(np.float32)
        img[rng.random(img.shape) < 0.2] = 0.0
        plain = img.reshape(hb, block, wb, block).mean(axis=(1, 3))
        fast = _block_means(img, hb, wb, block)
        assert fast.dtype == plain.dtype == np.float32
        np.testing.assert_array_equal(fast, plain)
        np.testing.assert_array_equal(np.signbit(fast), np.signbit(plain))
    img = _frame(2).astype(np.float32)
    valid = img > 100
    assert background_residual(img, valid, np.full_like(img, 200.0)) > 0


def test_the_threshold_image_is_the_plain_one():
    rng = np.random.default_rng(9)
    bg = (150.0 + 120.0 * rng.random((90, 70))).astype(np.float32)
    for dtype, thr in ((np.uint8, 0.5123), (np.uint16, 0.43), (np.uint8, 1.3), (np.float32, 0.5)):
        plain = np.ceil(np.asarray(bg, dtype=np.float64) * thr)
        if np.issubdtype(dtype, np.integer):
            plain = np.clip(plain, 0, np.iinfo(dtype).max)
        before = bg.copy()
        got = threshold_image(bg, thr, dtype)
        assert got.dtype == dtype
        np.testing.assert_array_equal(got, plain.astype(dtype))
        np.testing.assert_array_equal(bg, before)  # not changed


def _attached_half_width_plain(transmission, cal) -> float:
    """`attached_half_width_px` as it was: every body labelled."""
    mask = (transmission < cal.threshold).astype(np.uint8)
    _, lab = cv2.connectedComponents(mask, connectivity=8)
    axis = int(round(min(max(cal.axis_col, 0), transmission.shape[1] - 1)))
    top = np.unique(lab[0][lab[0] > 0])
    r = int(np.ceil(cal.tip_row)) + 2
    best = 0.0
    for k in top:
        _, cols = np.nonzero(lab[r:] == k)
        if cols.size and (np.any(np.abs(cols - cal.axis_col) < 2.0) or (lab[:r, axis] == k).any()):
            best = max(best, float(np.max(np.abs(cols - cal.axis_col))))
    return best


def test_the_attached_half_width_from_the_top_bodies_is_the_plain_one():
    from types import SimpleNamespace

    rng = np.random.default_rng(12)
    frames = [_frame(k).astype(np.float32) / 200.0 for k in range(3)]
    hanging = np.ones((120, 90), np.float32)
    hanging[:30, 30:60] = 0.1  # a nozzle, liquid hanging from it to one side, a second body at the top
    hanging[30:50, 35:70] = 0.2
    hanging[:8, 5:10] = 0.1
    hanging[60:70, 40:50] = 0.1  # a detached drop
    frames += [hanging, (rng.random((80, 260)) < 0.5).astype(np.float32)]
    many = np.ones((40, 800), np.float32)
    many[:3, ::3] = 0.0  # more than 250 bodies at the top: labelled
    many[:30, 400:420] = 0.0
    frames.append(many)
    checked = 0
    for t in frames:
        for axis, tip in ((45.0, 28.0), (110.0, 55.0), (410.0, 10.0), (3.0, 0.0)):
            cal = SimpleNamespace(threshold=0.5, axis_col=axis, tip_row=tip)
            plain = _attached_half_width_plain(t, cal)
            assert attached_half_width_px(t, cal) == plain
            checked += plain > 0
    assert checked >= 5


def test_background_residual_is_the_misfit_not_the_noise():
    """The background model's misfit (`background_residual`) is what changes slowly over the frame,
    the part that moves every edge of a body alike: a backlight the model misses by a smooth
    Gaussian field of sd 0.01 (correlated over ~30 px) is read within 10 % under pixel noise of sd
    0.02 (0.005 a 4 x 4 block), and noise alone reads under 0.2 of the blocks' spread (0.005),
    which it read before: the edges' random part holds the noise."""
    import cv2

    rng = np.random.default_rng(11)
    h, w = 600, 800
    bg = np.full((h, w), 200.0, np.float32)
    valid = np.ones((h, w), bool)
    field = cv2.GaussianBlur(rng.normal(0.0, 1.0, (h, w)).astype(np.float32), (0, 0), 30.0)
    misfit = 0.01 * field / field.std()
    noise = rng.normal(0.0, 0.02, (h, w))
    smooth_only = background_residual((bg * (1.0 + misfit)).astype(np.float32), valid, bg)
    both = background_residual((bg * (1.0 + misfit + noise)).astype(np.float32), valid, bg)
    assert smooth_only == pytest.approx(0.01, rel=0.15)
    assert both == pytest.approx(smooth_only, rel=0.1)
    only_noise = (bg * (1.0 + noise)).astype(np.float32)
    assert background_residual(only_noise, valid, bg) < 0.2 * 0.005
