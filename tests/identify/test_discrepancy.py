"""identify.discrepancy: the local model discrepancy and the drop scatter set apart from a smooth misfit
(issue 23), against independent references: the known noise of simulated data and the exact
squared misfit of a known law."""

import numpy as np
import pytest

from identify.discrepancy import LIKELIHOOD_RATIO_THRESHOLD, SCATTER_LIKELIHOOD_RATIO_THRESHOLD, \
    discrepancy_variance, fit_discrepancy, smooth_scatter_variance
from identify.polynomial import design_matrix, poly_terms

G1, G2 = np.meshgrid(np.linspace(50, 80, 5), np.linspace(20, 35, 5), indexing="ij")
U1, U2 = G1.ravel(), G2.ravel()
X1, X2 = (U1 - 65) / 15, (U2 - 27.5) / 7.5


def _bump(x1, x2):
    return np.exp(-((x1 - 0.5) ** 2 + (x2 + 0.5) ** 2) / 0.5)


@pytest.mark.slow
def test_no_structure_no_discrepancy():
    """Independent scatter alone: the likelihood ratio stays below the threshold in most draws,
    and then no local term is kept (variance exactly 0 everywhere)."""
    kept = 0
    for seed in range(10):
        e = np.random.default_rng(seed).standard_normal(U1.size)
        gp = fit_discrepancy(U1, U2, e, seed=0)
        assert gp is not None and gp["likelihood_ratio"] >= 0
        if gp["discrepancy_variance"] > 0:
            kept += 1
            assert gp["likelihood_ratio"] >= LIKELIHOOD_RATIO_THRESHOLD
        else:
            assert discrepancy_variance(gp, 65.0, 27.5)[0] == 0.0
    assert kept <= 4, kept  # without the likelihood-ratio gate most draws keep a small τ²


def test_local_discrepancy_where_the_misfit_is():
    """Cross-validation errors = a bump of height 4 + unit noise: the expected squared misfit is
    large at the bump (exact value there 16) and small far from it (exact 0)."""
    rng = np.random.default_rng(5)
    at_bump, far = [], []
    for seed in range(4):
        e = 4.0 * _bump(X1, X2) + rng.standard_normal(U1.size)
        gp = fit_discrepancy(U1, U2, e, seed=seed)
        assert gp["discrepancy_variance"] > 0
        v = discrepancy_variance(gp, [72.5, 53.0], [23.75, 33.0])
        at_bump.append(v[0])
        far.append(v[1])
    assert 4.0 < np.median(at_bump) < 30.0, at_bump
    assert np.median(far) < 1.0 and np.median(at_bump) > 5 * np.median(far), (at_bump, far)


@pytest.mark.slow
def test_smooth_scatter_sets_the_misfit_apart():
    """A linear polynomial fitted to linear + bump + noise (sd 1): its residual variance holds
    the bump; the REML scatter about polynomial + smooth departure is near the true 1."""
    X = design_matrix(X1, X2, poly_terms(1, 1))
    ratios_ols, ratios_reml = [], []
    for seed in range(5):
        rng = np.random.default_rng(100 + seed)
        y = 2 + X1 - X2 + 5.0 * _bump(X1, X2) + rng.standard_normal(U1.size)
        q, *_ = np.linalg.lstsq(X, y, rcond=None)
        r = y - X @ q
        s2, dof, lr = smooth_scatter_variance(U1, U2, r, X, seed=0)
        assert dof == U1.size - 3 and lr >= 0
        ratios_ols.append(float(r @ r) / dof)
        ratios_reml.append(s2)
    assert np.median(ratios_ols) > 1.4, ratios_ols  # 1.85 here: the bump counted as scatter
    assert 0.6 < np.median(ratios_reml) < 1.4 and np.median(ratios_reml) < np.median(ratios_ols) - 0.3, ratios_reml


def test_smooth_scatter_without_misfit_is_the_residual_variance():
    X = design_matrix(X1, X2, poly_terms(1, 1))
    y = 2 + X1 - X2 + np.random.default_rng(3).standard_normal(U1.size)
    r = y - X @ np.linalg.lstsq(X, y, rcond=None)[0]
    s2, dof, lr = smooth_scatter_variance(U1, U2, r, X, seed=0)
    if lr < SCATTER_LIKELIHOOD_RATIO_THRESHOLD:
        assert s2 == pytest.approx(float(r @ r) / dof, rel=1e-12)
    assert smooth_scatter_variance(U1[:6], U2[:6], r[:6], X[:6]) is None  # n - p < 4


# ---- bias of the chosen polynomial against a flexible one -------------------------------------

from identify.discrepancy import FLEXIBLE_ORDER, flexible_order, polynomial_bias  # noqa: E402
from identify.polynomial import fit_polynomial  # noqa: E402


def test_polynomial_bias_is_the_exact_misfit_of_a_law_the_flexible_one_holds():
    z = 3.0 + 2.0 * X1 + 1.5 * X1**2 - 0.7 * X1 * X2  # in the flexible (2, 3) polynomial, not in (1, 1)
    chosen = fit_polynomial(U1, U2, z, 1, 1)
    flexible = fit_polynomial(U1, U2, z, *flexible_order(chosen))
    assert flexible_order(chosen) == FLEXIBLE_ORDER
    u1, u2 = np.array([52.0, 63.3, 77.1]), np.array([21.0, 30.2, 34.0])
    x1, x2 = (u1 - 65) / 15, (u2 - 27.5) / 7.5
    truth = 3.0 + 2.0 * x1 + 1.5 * x1**2 - 0.7 * x1 * x2
    b, var = polynomial_bias(chosen, flexible, u1, u2)
    np.testing.assert_allclose(b, truth - chosen.predict(u1, u2), atol=1e-9)
    np.testing.assert_allclose(var, 0.0, atol=1e-12)  # the flexible fit is exact: no scatter


def test_polynomial_bias_variance_matches_the_spread_of_b_without_bias():
    """On a law both hold (linear) with unit scatter, b is pure noise: its mean square over many
    draws is its stated variance (nested least squares), and max(0, b² - var) is small."""
    u1, u2 = np.array([55.0, 71.3]), np.array([33.0, 24.1])
    b_all, v_all = [], []
    for seed in range(400):
        z = 1.0 + X1 - 0.5 * X2 + np.random.default_rng(seed).standard_normal(U1.size)
        chosen = fit_polynomial(U1, U2, z, 1, 1)
        b, v = polynomial_bias(chosen, fit_polynomial(U1, U2, z, 2, 3), u1, u2)
        b_all.append(b)
        v_all.append(v)
    b_all, v_all = np.array(b_all), np.array(v_all)
    np.testing.assert_allclose(np.mean(b_all**2, axis=0), np.mean(v_all, axis=0), rtol=0.2)
    assert np.all(np.mean(np.maximum(0.0, b_all**2 - v_all), axis=0) < 0.5 * np.mean(v_all, axis=0))


# ---- the cross-validation misfit carried back to the full fit -------------------------------------

from identify.discrepancy import cv_misfit_variance  # noqa: E402


def _loo(u1, u2, y, n1, n2):
    """Leave-one-out errors of a polynomial and the fold's leverage at the left-out control."""
    X = design_matrix(u1, u2, poly_terms(n1, n2))
    e, h_f = np.empty(y.size), np.empty(y.size)
    for i in range(y.size):
        keep = np.arange(y.size) != i
        beta, *_ = np.linalg.lstsq(X[keep], y[keep], rcond=None)
        e[i] = X[i] @ beta - y[i]
        h_f[i] = X[i] @ np.linalg.solve(X[keep].T @ X[keep], X[i])
    beta, *_ = np.linalg.lstsq(X, y, rcond=None)
    return e, h_f, y - X @ beta


def test_cv_misfit_is_the_full_fits_misfit_for_leave_one_out():
    """Noise-free curved law, a plane fitted: the leave-one-out errors carried back by (1 + h_f)
    are the full fit's residuals exactly, while the raw errors overstate the misfit."""
    a, b = np.meshgrid(np.linspace(-1, 1, 5), np.linspace(-1, 1, 5))
    u1, u2 = a.ravel(), b.ravel()
    y = 0.3 * u1**2 + 0.2 * np.sin(2.0 * u2) * u1
    e, h_f, r = _loo(u1, u2, y, 1, 1)
    assert cv_misfit_variance(e, 0.0, np.zeros_like(e), h_f) == pytest.approx(np.mean(r**2), rel=1e-10)
    assert np.mean(e**2) > 1.3 * np.mean(r**2)  # what the uncorrected estimate would read


def test_cv_misfit_of_pure_scatter_is_near_zero():
    """No misfit, scatter s² = 1: E[e²] = s² (1 + h_f) and the fold's parameter variance is s² h_f,
    so the estimate (pooled over 300 campaigns) is 0 within its sampling error."""
    rng = np.random.default_rng(3)
    a, b = np.meshgrid(np.linspace(-1, 1, 5), np.linspace(-1, 1, 5))
    u1, u2 = a.ravel(), b.ravel()
    es, vs, hs = [], [], []
    for _ in range(300):
        e, h_f, _ = _loo(u1, u2, 1.0 + 0.5 * u1 - u2 + rng.standard_normal(u1.size), 2, 1)
        es.append(e), vs.append(h_f), hs.append(h_f)
    e, v, h = map(np.concatenate, (es, vs, hs))
    raw = np.mean((e**2 - 1.0 - v) / (1 + h) ** 2)
    assert abs(raw) < 0.05
    assert cv_misfit_variance(e, 1.0, v, h) == pytest.approx(max(0.0, raw))
