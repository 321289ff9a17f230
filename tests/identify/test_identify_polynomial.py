"""identify.polynomial: Eq. (7) term set, least squares with intervals, CV order selection."""

import numpy as np
import pytest
from scipy import stats

from identify.polynomial import PolynomialRankError, fit_polynomial, poly_terms, sample_mvn, select_order


def _grid():
    u1 = np.arange(50.0, 80.0 + 1e-9, 5.0)
    u2 = np.arange(20.0, 35.0 + 1e-9, 1.25)
    U1, U2 = np.meshgrid(u1, u2, indexing="ij")
    return U1.ravel(), U2.ravel()


def test_term_set_eq7():
    assert poly_terms(1, 1) == [(0, 0), (1, 0), (0, 1)]
    assert poly_terms(2, 3) == [(0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2), (2, 1), (1, 2), (0, 3)]
    assert poly_terms(1, 3) == [(0, 0), (1, 0), (0, 1), (1, 1), (0, 2), (1, 2), (0, 3)]
    for n1, n2 in [(1, 2), (2, 2), (3, 1)]:
        assert all(i <= n1 and j <= n2 and i + j <= max(n1, n2) for i, j in poly_terms(n1, n2))


def test_fit_matches_textbook_ols_and_covers_truth():
    u1, u2 = _grid()
    rng = np.random.default_rng(3)
    truth = np.array([163.1, -1.40, 1.02])  # Eq. (15)
    z = truth[0] + truth[1] * u1 + truth[2] * u2 + 0.5 * rng.standard_normal(u1.size)
    fit = fit_polynomial(u1, u2, z, 1, 1)
    # independent reference: raw-design normal equations with a Student-t interval
    X = np.column_stack([np.ones_like(u1), u1, u2])
    beta, *_ = np.linalg.lstsq(X, z, rcond=None)
    r = z - X @ beta
    s2 = r @ r / (z.size - 3)
    cov = s2 * np.linalg.inv(X.T @ X)
    ci = stats.t.ppf(0.975, z.size - 3) * np.sqrt(np.diag(cov))
    np.testing.assert_allclose(fit.coefficients, beta, rtol=1e-9)
    np.testing.assert_allclose(fit.covariance, cov, rtol=1e-7, atol=1e-9 * np.abs(cov).max())
    np.testing.assert_allclose(fit.ci95, ci, rtol=1e-7)
    assert np.all(np.abs(fit.coefficients - truth) <= fit.ci95)
    np.testing.assert_allclose(fit.predict(u1, u2), fit.predict_raw(u1, u2), rtol=1e-10)


def test_interval_coverage_quadratic():
    """95 % intervals of a (2, 2) fit cover the true coefficients ~95 % of the time."""
    u1, u2 = _grid()
    truth = np.array([1.0, 0.05, -0.1, 2e-3, -1e-3, 4e-3])
    X = np.column_stack([u1**i * u2**j for i, j in poly_terms(2, 2)])
    rng = np.random.default_rng(0)
    hits = []
    for _ in range(200):
        z = X @ truth + 0.2 * rng.standard_normal(u1.size)
        fit = fit_polynomial(u1, u2, z, 2, 2)
        hits.append(np.abs(fit.coefficients - truth) <= fit.ci95)
    rate = np.mean(hits)
    assert 0.92 < rate < 0.98


def test_rank_deficiency():
    u1 = np.repeat([50.0, 60.0, 70.0], 2)
    u2 = np.tile([20.0, 30.0], 3)
    z = u1 + u2
    with pytest.raises(PolynomialRankError, match=r"3 distinct u2 values, the data have 3 and 2"):
        fit_polynomial(u1, u2, z, 1, 2)
    # collinear controls: u2 = u1 / 2 -> cannot separate u1 and u2
    v1 = np.array([50.0, 55.0, 60.0, 65.0, 70.0])
    with pytest.raises(PolynomialRankError, match="rank deficient"):
        fit_polynomial(v1, v1 / 2, v1, 1, 1)
    with pytest.raises(ValueError, match="NaN"):
        fit_polynomial(v1, v1, np.r_[v1[:-1], np.nan], 1, 1)
    with pytest.raises(PolynomialRankError, match="no candidate"):
        select_order(v1, v1 / 2, v1, orders=[(1, 1)], folds=5)


def test_cv_selects_true_order():
    u1, u2 = _grid()
    rng = np.random.default_rng(1)
    z_lin = 0.16 + 0.014 * u1 + 0.0037 * u2 + 0.01 * rng.standard_normal(u1.size)
    sel = select_order(u1, u2, z_lin)
    assert list(sel.table.columns) == ["n1", "n2", "n_terms", "train_rmse", "val_rmse", "selected"]
    assert sel.selected == (1, 1) and sel.table["selected"].sum() == 1
    z_q = 1050 - 14 * (u1 - 70) + 10.2 * (u2 - 25) + 0.3 * (u1 - 70) ** 2 + 0.5 * rng.standard_normal(u1.size)
    sel = select_order(u1, u2, z_q)
    assert sel.selected[0] == 2
    assert abs(sel.fit.coefficients[sel.fit.terms.index((2, 0))] - 0.3) <= sel.fit.ci95[sel.fit.terms.index((2, 0))]


def test_sample_mvn_singular():
    cov = np.array([[1.0, 1.0], [1.0, 1.0]])
    x = sample_mvn(np.array([1.0, 2.0]), cov, 20000, np.random.default_rng(0))
    np.testing.assert_allclose(x[:, 1] - x[:, 0], 1.0, atol=1e-12)
    assert np.std(x[:, 0]) == pytest.approx(1.0, rel=0.03)
