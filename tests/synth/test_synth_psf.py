"""Non-Gaussian optics in the synthesizer (issue 29): an Airy pattern's diffraction rings and a
defocus disc (`dropvision.synth.render.psf_kernel`), pinned to their closed forms."""

import json

import numpy as np
import pytest
from scipy.special import j1

from dropvision.synth import SynthConfig, write_synthetic_sequence
from dropvision.synth.render import PSFS, psf_kernel


def _esf(kernel: np.ndarray) -> np.ndarray:
    """Edge-spread function of a kernel: its line-spread function (columns summed), accumulated."""
    return np.cumsum(kernel.sum(axis=0))


def test_kernels_are_normalised_and_symmetric():
    assert psf_kernel("gaussian", 0.0) is None
    for psf, r in (("airy", 3.0), ("disc", 2.5)):
        k = psf_kernel(psf, r)
        assert k.dtype == np.float32 and k.shape[0] == k.shape[1] and k.shape[0] % 2 == 1
        assert abs(float(k.sum()) - 1.0) < 1e-5
        np.testing.assert_allclose(k, k[::-1, :], atol=1e-7)
        np.testing.assert_allclose(k, k.T, atol=1e-7)
    with pytest.raises(ValueError, match="psf must be one of"):
        psf_kernel("lorentz", 2.0)
    with pytest.raises(ValueError, match="radius"):
        psf_kernel("airy", 0.0)


def test_airy_kernel_follows_the_closed_form():
    """(2 J1(v)/v)^2 with its first zero at the given radius: the centre over a sample half-way to
    the first ring, pixel-integrated with a fine subsampling, equals the closed form's ratio."""
    r0 = 6.0
    k = psf_kernel("airy", r0, subsample=1)
    c = k.shape[0] // 2
    v = 3.8317059702075125 * 3.0 / r0
    assert k[c, c + 3] / k[c, c] == pytest.approx((2 * j1(v) / v) ** 2, rel=1e-6)
    assert k[c, c + 6] / k[c, c] < 1e-6  # the first dark ring
    assert k[c, c + 8] > k[c, c + 6]  # the first bright ring beyond it


def test_non_gaussian_edges_ring_or_ramp_and_keep_the_half_level_at_the_edge():
    """A straight edge blurred by either kernel crosses 50 % where the edge is (both PSFs are
    symmetric); the Airy edge has long tails (its rings), the disc's is a ramp two radii wide."""
    airy = _esf(psf_kernel("airy", 3.0, subsample=7))
    n = airy.size
    # the ESF sampled at pixel boundaries: the edge lies between pixel n//2 and n//2+1 (half-way)
    mid = 0.5 * (airy[n // 2 - 1] + airy[n // 2])
    assert mid == pytest.approx(0.5, abs=1e-6)
    lsf = psf_kernel("airy", 3.0, subsample=7).sum(axis=0)
    assert lsf.min() >= 0  # an incoherent PSF is non-negative: its edge approaches 1 slowly (tails)
    assert airy[n // 2 + 3] < 0.985  # 3 px beyond the edge still 1.5 % short of the background
    disc = _esf(psf_kernel("disc", 4.0, subsample=9))
    m = disc.size
    assert 0.5 * (disc[m // 2 - 1] + disc[m // 2]) == pytest.approx(0.5, abs=1e-6)
    assert disc[m // 2 - 5] < 1e-6 and disc[m // 2 + 4] > 1 - 1e-6  # the ramp spans the disc's diameter


def test_config_validates_and_writes_the_psf(tmp_path):
    assert PSFS == ("gaussian", "airy", "disc")
    with pytest.raises(ValueError, match="SynthConfig.psf:"):
        SynthConfig(psf="lorentz")
    with pytest.raises(ValueError, match="psf_radius_px"):
        SynthConfig(psf="disc")
    cfg = SynthConfig(psf="airy", psf_radius_px=3.0, format="jpeg", jpeg_quality=80, width_px=96, height_px=200,
                      tip_row=12.4, delays_us=(900.0,))
    out = write_synthetic_sequence(cfg, tmp_path / "airy", progress=False)
    truth = json.loads((out / "truth.json").read_text())
    assert truth["realism"]["psf"] == "airy" and truth["realism"]["psf_radius_px"] == 3.0
    assert SynthConfig.from_dict(truth["parameters"]["config"]) == cfg


def test_psf_reaches_the_optics():
    from dropvision.synth.render import Optics

    base = dict(width_px=64, height_px=120, tip_row=10.4, delays_us=(0.0,), noise=0.0)
    assert SynthConfig(**base).optics().psf == "gaussian" and Optics().psf == "gaussian"
    a = SynthConfig(**base, psf="airy", psf_radius_px=3.0).optics()
    assert (a.psf, a.psf_radius_px) == ("airy", 3.0)
