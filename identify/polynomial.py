"""Polynomial surfaces z(u1, u2) of Eq. (7) for the pinch-off instant and the adjusters.

Reading of Eq. (7)
------------------
Eq. (7) lists ``p00 + p10 u1 + p01 u2 + p20 u1^2 + p11 u1 u2 + p02 u2^2 + ... +
p_{n1,0} u1^n1 + p_{n1-1,1} u1^(n1-1) u2 + ... + p_{1,n2-1} u1 u2^(n2-1) + p_{0,n2} u2^n2``
with ``i <= n1`` and ``j <= n2``. The last groups are the terms of total degree n1 (led by
``u1^n1``) and of total degree n2 (ending in ``u2^n2``), so the total degree never exceeds
``max(n1, n2)``. The term set is therefore

    { u1^i u2^j : 0 <= i <= n1, 0 <= j <= n2, i + j <= max(n1, n2) },

the convention of MATLAB's ``polyXY`` surface models (Curve Fitting Toolbox), which the
paper's tables (orders 1..2 x 1..3) use. Terms are ordered as in Eq. (7): by total degree,
then by decreasing power of u1. For (1, 1): [1, u1, u2]; (2, 3): [1, u1, u2, u1^2, u1 u2,
u2^2, u1^2 u2, u1 u2^2, u2^3].

Fitting is ordinary least squares on internally centred and scaled inputs (the term set is
closed under lowering a power, so the affine change of variables spans the same space); the
coefficients, their covariance and 95 % intervals (Student t, n - p degrees of freedom) are
reported in the paper's raw form (powers of u1 in µm/ms and u2 in µm).
"""

from __future__ import annotations

from dataclasses import dataclass
from math import comb
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import pandas as pd

from identify.kfold import grouped_kfold

#: Candidate orders of Tables 4-6.
DEFAULT_ORDERS = ((1, 1), (1, 2), (1, 3), (2, 1), (2, 2), (2, 3))


class PolynomialRankError(ValueError):
    """The (u1, u2) data cannot determine all coefficients of the requested polynomial."""


def poly_terms(n1: int, n2: int) -> list[tuple[int, int]]:
    """Exponents (i, j) of the terms of Eq. (7), in the paper's order."""
    if int(n1) != n1 or int(n2) != n2 or n1 < 0 or n2 < 0:
        raise ValueError(f"polynomial orders must be non-negative integers, got ({n1}, {n2})")
    m = max(n1, n2)
    out = []
    for d in range(m + 1):
        for i in range(d, -1, -1):
            j = d - i
            if i <= n1 and j <= n2:
                out.append((i, j))
    return out


def term_names(terms) -> list[str]:
    names = []
    for i, j in terms:
        parts = [p for p in ((f"u1^{i}" if i > 1 else "u1" if i == 1 else ""), (f"u2^{j}" if j > 1 else "u2" if j == 1 else "")) if p]
        names.append("*".join(parts) if parts else "1")
    return names


def _design(x1, x2, terms) -> np.ndarray:
    x1 = np.asarray(x1, dtype=float)[..., None]
    x2 = np.asarray(x2, dtype=float)[..., None]
    i = np.array([t[0] for t in terms])
    j = np.array([t[1] for t in terms])
    return x1**i * x2**j


def design_matrix(x1, x2, terms) -> np.ndarray:
    """Design matrix of Eq. (7) (one column per term of ``terms``) at (normalised) inputs."""
    return _design(x1, x2, terms)


def _scaled_to_raw(terms, centre, scale) -> np.ndarray:
    """Matrix T with raw = T @ scaled for the coefficient vectors."""
    index = {t: k for k, t in enumerate(terms)}
    p = len(terms)
    T = np.zeros((p, p))
    (c1, c2), (s1, s2) = centre, scale
    for col, (i, j) in enumerate(terms):
        for a in range(i + 1):
            fa = comb(i, a) * (-c1) ** (i - a) / s1**i
            for b in range(j + 1):
                fb = comb(j, b) * (-c2) ** (j - b) / s2**j
                T[index[(a, b)], col] += fa * fb
    return T


@dataclass
class PolynomialFit:
    """Least-squares polynomial of Eq. (7) with coefficient statistics.

    Attributes
    ----------
    n1, n2 : int
        Orders for u1 and u2.
    terms : list of (i, j)
    coefficients : ndarray
        Raw coefficients p_ij (paper form), in the order of ``terms``.
    covariance : ndarray
        Covariance of the raw coefficients.
    ci95 : ndarray
        Half-width of the 95 % interval of each raw coefficient.
    centre, scale : tuple
        Internal input normalisation (u - centre) / scale.
    scaled_coefficients, scaled_covariance : ndarray
        The same model in the normalised basis (used for sampling and evaluation).
    residual_std, dof, n_samples, train_rmse : float/int
    name, unit : str
        What the polynomial models (e.g. "pinchoff", "us").
    """

    n1: int
    n2: int
    terms: list
    coefficients: np.ndarray
    covariance: np.ndarray
    ci95: np.ndarray
    centre: tuple
    scale: tuple
    scaled_coefficients: np.ndarray
    scaled_covariance: np.ndarray
    residual_std: float
    dof: int
    n_samples: int
    train_rmse: float
    name: str = "z"
    unit: str = ""

    def _xs(self, u1, u2):
        return (np.asarray(u1, float) - self.centre[0]) / self.scale[0], (np.asarray(u2, float) - self.centre[1]) / self.scale[1]

    def normalised(self, u1, u2):
        """Inputs in the internal normalisation (u - centre) / scale (see :func:`design_matrix`)."""
        return self._xs(u1, u2)

    def predict(self, u1, u2) -> np.ndarray:
        """Polynomial value at (u1, u2) (broadcasting)."""
        x1, x2 = self._xs(u1, u2)
        return _design(x1, x2, self.terms) @ self.scaled_coefficients

    def predict_std(self, u1, u2) -> np.ndarray:
        """Standard deviation of the fitted mean at (u1, u2) from the coefficient covariance."""
        x1, x2 = self._xs(u1, u2)
        X = _design(x1, x2, self.terms)
        return np.sqrt(np.einsum("...i,ij,...j->...", X, self.scaled_covariance, X))

    def predict_raw(self, u1, u2) -> np.ndarray:
        """Evaluation with the raw coefficients (as a reader of the paper would)."""
        return _design(u1, u2, self.terms) @ self.coefficients

    def sample(self, n: int, u1: float, u2: float, rng: np.random.Generator) -> np.ndarray:
        """Values at (u1, u2) for ``n`` coefficient vectors drawn from N(coef, cov)."""
        q = sample_mvn(self.scaled_coefficients, self.scaled_covariance, n, rng)
        x1, x2 = self._xs(u1, u2)
        return q @ _design(x1, x2, self.terms)

    def to_pandas(self) -> pd.DataFrame:
        """One row per term: term, i, j, coefficient, ci95, low, high."""
        import pandas as pd

        return pd.DataFrame({
            "term": term_names(self.terms),
            "i": [t[0] for t in self.terms],
            "j": [t[1] for t in self.terms],
            "coefficient": self.coefficients,
            "ci95": self.ci95,
            "low": self.coefficients - self.ci95,
            "high": self.coefficients + self.ci95,
        })

    def to_dict(self) -> dict:
        return {
            "name": self.name, "unit": self.unit, "n1": self.n1, "n2": self.n2,
            "terms": [list(t) for t in self.terms], "term_names": term_names(self.terms),
            "coefficients": self.coefficients.tolist(), "ci95": self.ci95.tolist(),
            "covariance": self.covariance.tolist(),
            "centre": list(self.centre), "scale": list(self.scale),
            "scaled_coefficients": self.scaled_coefficients.tolist(),
            "scaled_covariance": self.scaled_covariance.tolist(),
            "residual_std": self.residual_std, "dof": self.dof, "n_samples": self.n_samples,
            "train_rmse": self.train_rmse,
        }

    @classmethod
    def from_dict(cls, d: dict) -> "PolynomialFit":
        return cls(
            n1=int(d["n1"]), n2=int(d["n2"]), terms=[tuple(t) for t in d["terms"]],
            coefficients=np.asarray(d["coefficients"], float), covariance=np.asarray(d["covariance"], float),
            ci95=np.asarray(d["ci95"], float), centre=tuple(d["centre"]), scale=tuple(d["scale"]),
            scaled_coefficients=np.asarray(d["scaled_coefficients"], float),
            scaled_covariance=np.asarray(d["scaled_covariance"], float),
            residual_std=float(d["residual_std"]), dof=int(d["dof"]), n_samples=int(d["n_samples"]),
            train_rmse=float(d["train_rmse"]), name=d.get("name", "z"), unit=d.get("unit", ""),
        )


def sample_mvn(mean: np.ndarray, cov: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Draws of N(mean, cov), shape (n, p); a positive semi-definite (even singular) cov is fine."""
    mean = np.asarray(mean, float)
    cov = 0.5 * (np.asarray(cov, float) + np.asarray(cov, float).T)
    w, V = np.linalg.eigh(cov)
    root = V * np.sqrt(np.clip(w, 0.0, None))
    return mean + rng.standard_normal((n, mean.size)) @ root.T


def _check_inputs(u1, u2, z, what):
    u1, u2, z = (np.asarray(a, dtype=float).ravel() for a in (u1, u2, z))
    if not (u1.size == u2.size == z.size):
        raise ValueError(f"{what}: u1, u2 and z must have the same length")
    bad = ~(np.isfinite(u1) & np.isfinite(u2) & np.isfinite(z))
    if bad.any():
        raise ValueError(f"{what}: {int(bad.sum())} NaN/inf value(s) in u1, u2 or z")
    return u1, u2, z


def fit_polynomial(u1, u2, z, n1: int, n2: int, *, name: str = "z", unit: str = "", confidence: float = 0.95) -> PolynomialFit:
    """Least-squares fit of Eq. (7) of orders (n1, n2).

    Raises
    ------
    PolynomialRankError
        When the (u1, u2) points cannot determine every coefficient (too few distinct
        values of u1 or u2, or fewer points than coefficients + 1).
    """
    u1, u2, z = _check_inputs(u1, u2, z, name)
    terms = poly_terms(n1, n2)
    p = len(terms)
    n = z.size
    n_u1, n_u2 = np.unique(u1).size, np.unique(u2).size
    if n_u1 <= n1 or n_u2 <= n2:
        raise PolynomialRankError(
            f"{name} polynomial (n1={n1}, n2={n2}) needs at least {n1 + 1} distinct u1 and {n2 + 1} "
            f"distinct u2 values, the data have {n_u1} and {n_u2}"
        )
    centre = (float(np.mean(u1)), float(np.mean(u2)))
    scale = (float(np.std(u1)) or 1.0, float(np.std(u2)) or 1.0)
    X = _design((u1 - centre[0]) / scale[0], (u2 - centre[1]) / scale[1], terms)
    U, s, Vt = np.linalg.svd(X, full_matrices=False)
    rank = int(np.sum(s > s[0] * 1e-10)) if s.size else 0
    if rank < p:
        raise PolynomialRankError(
            f"{name} polynomial (n1={n1}, n2={n2}): the (u1, u2) grid is rank deficient "
            f"(design rank {rank} < {p} coefficients); use lower orders or more distinct controls"
        )
    if n <= p:
        raise PolynomialRankError(
            f"{name} polynomial (n1={n1}, n2={n2}): {n} data points for {p} coefficients; "
            "need more points than coefficients for intervals"
        )
    q = Vt.T @ ((U.T @ z) / s)
    resid = z - X @ q
    dof = n - p
    s2 = float(resid @ resid) / dof
    xtx_inv = (Vt.T / s**2) @ Vt
    cov_q = s2 * xtx_inv
    T = _scaled_to_raw(terms, centre, scale)
    coef = T @ q
    cov = T @ cov_q @ T.T
    from scipy import special  # not scipy.stats (~0.5 s to import): the same values

    tq = special.stdtrit(dof, 0.5 + confidence / 2)
    ci = tq * np.sqrt(np.clip(np.diag(cov), 0, None))
    return PolynomialFit(
        n1=n1, n2=n2, terms=terms, coefficients=coef, covariance=cov, ci95=ci, centre=centre, scale=scale,
        scaled_coefficients=q, scaled_covariance=cov_q, residual_std=float(np.sqrt(s2)), dof=dof,
        n_samples=n, train_rmse=float(np.sqrt(np.mean(resid**2))), name=name, unit=unit,
    )


@dataclass
class OrderSelection:
    """Result of :func:`select_order`: the CV table (Tables 4-6) and the chosen fit.

    ``table`` columns: n1, n2, n_terms, train_rmse, val_rmse, selected (bool). RMSEs are
    averaged over the folds; ``val_rmse`` is NaN when a fold could not be fitted.
    """

    table: pd.DataFrame
    selected: tuple[int, int]
    fit: PolynomialFit
    name: str = "z"

    def to_pandas(self) -> pd.DataFrame:
        return self.table.copy()


def select_order(
    u1, u2, z, orders=DEFAULT_ORDERS, *, folds: int = 10, seed: int = 0, tolerance: float = 0.05,
    name: str = "z", unit: str = "",
) -> OrderSelection:
    """10-fold cross-validation over candidate orders, then a fit of the chosen order on all data.

    Folds keep repeated measurements of one (u1, u2) together, so validation points are
    always unseen controls (:func:`identify.kfold.grouped_kfold`, round-robin layout). The
    chosen order is the one with the fewest terms whose mean validation RMSE is within
    ``tolerance`` (relative) of the best (the paper's "comparable RMSE with a simpler
    structure").

    Raises
    ------
    PolynomialRankError
        If no candidate order can be fitted on the data.
    """
    u1, u2, z = _check_inputs(u1, u2, z, name)
    splits = grouped_kfold(np.column_stack([u1, u2]), folds, seed, layout="round_robin")
    rows = []
    for n1, n2 in orders:
        tr, va = [], []
        ok = True
        for f_idx in splits:
            train = np.setdiff1d(np.arange(z.size), f_idx)
            try:
                fit = fit_polynomial(u1[train], u2[train], z[train], n1, n2, name=name)
            except PolynomialRankError:
                ok = False
                break
            tr.append(fit.train_rmse)
            va.append(np.mean((fit.predict(u1[f_idx], u2[f_idx]) - z[f_idx]) ** 2))
        rows.append({
            "n1": n1, "n2": n2, "n_terms": len(poly_terms(n1, n2)),
            "train_rmse": float(np.mean(tr)) if ok else np.nan,
            "val_rmse": float(np.sqrt(np.mean(va))) if ok else np.nan,
        })
    import pandas as pd  # only here: predicting needs no pandas

    table = pd.DataFrame(rows)
    valid = table.dropna(subset=["val_rmse"])
    if valid.empty:
        raise PolynomialRankError(
            f"{name}: no candidate polynomial order can be fitted in cross-validation; "
            "the (u1, u2) grid has too few distinct controls"
        )
    best = valid["val_rmse"].min()
    ok_rows = valid[valid["val_rmse"] <= best * (1 + tolerance) + 1e-300]
    choice = ok_rows.sort_values(["n_terms", "val_rmse"]).iloc[0]
    sel = (int(choice["n1"]), int(choice["n2"]))
    table["selected"] = (table["n1"] == sel[0]) & (table["n2"] == sel[1])
    fit = fit_polynomial(u1, u2, z, *sel, name=name, unit=unit)
    return OrderSelection(table=table, selected=sel, fit=fit, name=name)
