"""identify.montecarlo: batched exact ECM simulation against identify.ecm.simulate."""

import numpy as np
import pytest

from identify.dataset import default_physics
from identify.ecm import EcmCoefficients, simulate
from identify.montecarlo import (
    cubic_roots,
    coeff_array,
    ecm_response_at,
    modal_form,
    sample_ecm_coefficients,
    simulate_ensemble,
)
from identify.waveform import Waveform


def _coeffs(n, rel=0.05, seed=0):
    c0 = coeff_array(default_physics().ecm_parameters().coefficients())
    rng = np.random.default_rng(seed)
    return c0 * (1 + rel * rng.standard_normal((n, 6)))


@pytest.mark.parametrize("use_numba", [True, False])
def test_batch_matches_reference(use_numba):
    C = _coeffs(6)
    w = Waveform(70.0, 25.0)
    t = np.arange(0.0, 2000.0, 10.0)
    u = w.displacement_um(t - 220.0)
    vol, flow = simulate_ensemble(C, t, u, use_numba=use_numba)
    for i in range(C.shape[0]):
        v, f = simulate(EcmCoefficients(*C[i]), t, u)
        np.testing.assert_allclose(vol[i], v, rtol=0, atol=1e-9 * np.abs(v).max())
        np.testing.assert_allclose(flow[i], f, rtol=0, atol=1e-9 * np.abs(f).max())


def test_response_at_exact_instants():
    # corners on the 10 us grid: rise 500 us, hold 20 us -> FOH simulation is exact there
    C = _coeffs(4, seed=1)
    w = Waveform(50.0, 25.0)
    t = np.arange(0.0, 1600.0, 10.0)
    u = w.displacement_um(t - 220.0)
    for i in range(C.shape[0]):
        v, f = simulate(EcmCoefficients(*C[i]), t, u)
        k = np.array([30, 70, 72, 75, 120, 150])
        vol, flow = ecm_response_at(C[i], w, t[k] - 220.0)
        np.testing.assert_allclose(vol, v[k], rtol=1e-9)
        np.testing.assert_allclose(flow, f[k], rtol=1e-8, atol=1e-12)
    # batched rows with per-row instants equal the one-row calls
    tau = np.array([100.0, 333.3, 777.7, 1234.5])
    vb, fb = ecm_response_at(C, w, tau)
    for i in range(4):
        v1, f1 = ecm_response_at(C[i], w, tau[i])
        assert vb[i] == pytest.approx(v1[0], rel=1e-12)


def test_reference_point_of_team_notes():
    c = default_physics().ecm_parameters().coefficients()
    w = Waveform(70.0, 25.0)
    _, q = ecm_response_at(c, w, w.max_stroke_us)
    v_ms = q[0] * 1e-6 / (np.pi * (100e-6) ** 2)
    assert v_ms == pytest.approx(1.30, abs=0.01)
    t = np.arange(0, 1500, 10.0)
    v, _ = ecm_response_at(c, w, t - 220.0)
    assert v.max() == pytest.approx(18.5, abs=0.3)
    assert abs(t[np.argmax(v)] - 1000) < 100


def test_repeated_poles_fallback():
    # (s+1)^3 in 1/ms: triple pole -> companion/expm fallback
    tu = 1e-6
    lam = 1e3  # 1/s
    c = np.array([[1.0, 3 * lam, 3 * lam**2, lam**3, -1e-12 * lam, -1e-12 * lam**2]])
    m = modal_form(c)
    assert m.fallback[0]
    w = Waveform(50.0, 25.0)
    t = np.arange(0.0, 1600.0, 10.0)
    u = w.displacement_um(t - 220.0)
    v, f = simulate(EcmCoefficients(*c[0]), t, u)
    vb, fb = simulate_ensemble(c, t, u)
    np.testing.assert_allclose(vb[0], v, atol=1e-9 * np.abs(v).max())
    va, _ = ecm_response_at(c, w, t[100] - 220.0)
    assert va[0] == pytest.approx(v[100], rel=1e-9)
    assert tu  # units note: coefficients are SI


def test_cubic_roots_against_numpy():
    rng = np.random.default_rng(5)
    a = rng.uniform(0.1, 3.0, (200, 3))
    r = cubic_roots(a[:, 0], a[:, 1], a[:, 2])
    for i in range(200):
        ref = np.roots([1.0, *a[i]])
        dist = np.abs(r[i][:, None] - ref[None, :])
        assert dist.min(axis=1).max() < 1e-9 * np.abs(ref).max()
        assert dist.min(axis=0).max() < 1e-9 * np.abs(ref).max()


def test_coefficient_sampling_statistics():
    c0 = coeff_array(default_physics().ecm_parameters().coefficients())[0]
    rel_sd = np.array([0.01, 0.02, 0.0, 0.03, 0.01, 0.01])
    cov = np.diag((rel_sd * c0) ** 2)
    x = sample_ecm_coefficients(c0, cov, 20000, np.random.default_rng(0))
    np.testing.assert_allclose(x.mean(0), c0, rtol=1e-3)
    np.testing.assert_allclose(x.std(0) / np.abs(c0), rel_sd, atol=1e-3)


@pytest.mark.parametrize("use_numba", [True, False])
def test_three_real_poles(use_numba):
    p = np.poly([-1e3, -2e3, -5e3])  # 1/s: overdamped, three distinct real poles
    c = np.array([[*p, -1e-12 * 2e3, -1e-12 * 1e7]])
    m = modal_form(c)
    assert not m.fallback[0] and np.all(m.lam.imag == 0)
    w = Waveform(60.0, 30.0)
    t = np.arange(0.0, 2000.0, 10.0)
    u = w.displacement_um(t - 220.0)
    v, f = simulate(EcmCoefficients(*c[0]), t, u)
    vb, fb = simulate_ensemble(c, t, u, use_numba=use_numba)
    np.testing.assert_allclose(vb[0], v, atol=1e-9 * np.abs(v).max())
    np.testing.assert_allclose(fb[0], f, atol=1e-9 * np.abs(f).max())


def test_joint_pinchoff_volume_sampling():
    """Issue 13: pinch-off and volume adjuster drawn jointly; a zero cross-covariance gives the
    independent draws exactly, a negative one the variance of the sum it implies."""
    from identify.montecarlo import sample_pinchoff_volume
    from identify.polynomial import fit_polynomial

    rng = np.random.default_rng(0)
    u1, u2 = np.repeat(np.linspace(50, 80, 4), 4), np.tile(np.linspace(20, 35, 4), 4)
    p = fit_polynomial(u1, u2, 900 + rng.normal(0, 10, 16), 1, 1)
    v = fit_polynomial(u1, u2, 1 + rng.normal(0, 0.3, 16), 1, 1)
    zero = np.zeros((3, 3))
    tp, adj = sample_pinchoff_volume(p, v, zero, 500, 65.0, 27.0, np.random.default_rng(5))
    r = np.random.default_rng(5)
    assert np.array_equal(tp, p.sample(500, 65.0, 27.0, r))
    assert np.allclose(adj, v.sample(500, 65.0, 27.0, r), rtol=0, atol=1e-12)
    # fully anti-correlated (cross = -sqrt(Cp Cv) for equal designs): p / sd_p + v / sd_v ~ 0
    sp, sv = np.sqrt(p.scaled_covariance[0, 0]), np.sqrt(v.scaled_covariance[0, 0])
    cross = -(sv / sp) * p.scaled_covariance
    tp, adj = sample_pinchoff_volume(p, v, cross, 4000, 65.0, 27.0, np.random.default_rng(1))
    assert np.corrcoef(tp, adj)[0, 1] < -0.99
