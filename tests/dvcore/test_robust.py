"""The robust spreads of `dvcore.robust` against known noise."""

import numpy as np
import pytest

from dvcore.robust import pair_noise_sigma, quantized_sigma, robust_sigma


@pytest.mark.parametrize("sigma", [0.5, 0.7, 1.0, 1.3, 1.6, 2.0, 3.0, 8.0])
def test_quantized_sigma_follows_the_noise_of_rounded_values(sigma):
    """Rounded Gaussian values (an 8-bit frame's counts): the spread of their differences read by
    `quantized_sigma` is within 8 % of the true one (the rounding's 1/12 count^2 included), over
    200 draws of 400; the median absolute deviation of the same integers sticks at 1.048 counts
    from 0.7 to 1.3 and is off by more than 15 % at some of these spreads (the test's reason)."""
    rng = np.random.default_rng(11)
    want = np.sqrt(sigma ** 2 + 1.0 / 12.0)
    got, mad = [], []
    for _ in range(200):
        x = np.round(rng.normal(0.0, sigma, 400) + rng.uniform())
        d = np.diff(x)
        got.append(quantized_sigma(d) / np.sqrt(2.0))
        mad.append(robust_sigma(d) / np.sqrt(2.0))
    assert np.mean(got) == pytest.approx(want, rel=0.08)
    if sigma in (0.7, 1.3):
        assert abs(np.mean(mad) / want - 1.0) > 0.15


def test_quantized_sigma_by_hand():
    # 0, 1, 1, 2: the quartiles of the cells [-0.5, 0.5), [0.5, 1.5) x 2, [1.5, 2.5) at 0.5 and 1.5
    assert quantized_sigma([0, 1, 1, 2]) == pytest.approx(1.0 / 1.349)
    assert quantized_sigma([3, 3, 3, 3]) == pytest.approx(0.5 / 1.349)  # one cell: its width's half
    assert quantized_sigma(np.array([0.2, 0.9, 1.1, 2.4])) == quantized_sigma([0, 1, 1, 2])  # rounded


def test_pair_noise_sigma_reads_counts_on_their_lattice_and_floats_plainly():
    rng = np.random.default_rng(4)
    a = np.round(100 + rng.normal(0.0, 1.0, 5000)).astype(np.uint8)
    b = np.round(100 + rng.normal(0.0, 1.0, 5000)).astype(np.uint8)
    # unsigned counts: no wrap-around in the differences; one count is 0.004 of transmission
    assert pair_noise_sigma(a, b, 0.004) == pytest.approx(0.004 * np.sqrt(1 + 1 / 12), rel=0.05)
    fa, fb = rng.normal(0.0, 0.02, 5000), rng.normal(0.0, 0.02, 5000)
    assert pair_noise_sigma(fa, fb) == robust_sigma(fa - fb) / np.sqrt(2.0)
    assert np.isnan(pair_noise_sigma(a[:9], b[:9]))
