"""ARX models fitted on many short sequences, and their structure selection (Wang & Chiu, §4.2).

Model and conventions
---------------------
The ARX model with orders ``(na, nb, nk)`` is, exactly as MATLAB's ``arx``,

    A(q) y(t) = B(q) u(t - nk) + e(t),
    A(q) = 1 + a1 q^-1 + ... + a_na q^-na,
    B(q) = b1 + b2 q^-1 + ... + b_nb q^-(nb-1),

i.e. ``y(t) = -a1 y(t-1) - ... - a_na y(t-na) + b1 u(t-nk) + ... + b_nb u(t-nk-nb+1) + e(t)``.

**Delay convention.** ``nk`` is MATLAB's: the number of samples *before the first input
term*, so ``nk = 0`` means a direct feed-through ``b1 u(t)`` and ``nk = 1`` is an ordinary
strictly proper model whose first input term is ``b1 u(t-1)``. SIPPY (``system_identification(...,
'ARX', ..., ARX_orders=[na, nb, theta])``) and the textbooks that write
``B(q) = b1 q^-1 + ... + b_nb q^-nb`` count the delay ``theta`` (or ``d``) *after* one
built-in sample of delay: their first input term is ``u(t - theta - 1)``, so
``nk_MATLAB = theta_SIPPY + 1``; a MATLAB ``nk = 22`` model is SIPPY's ``theta = 21``.
``llsi`` (``llsi.arx(data, (na, nb, nk))``) uses MATLAB's convention.

Many sequences
--------------
Data are a list of sequences ``(u, y)`` (or objects with ``.u`` and ``.y``), possibly of
different lengths, each starting at the firing trigger. Regressors never cross a sequence
boundary: sequence ``j`` contributes only rows ``t`` of its own samples, and lagged values
are taken from the same sequence. Lags that reach before the sequence's first sample are
handled by the ``initial`` option:

``"zero"`` (default)
    pre-sample values are zero (u = 0, y = 0 before the trigger). This is *exact* for drop
    formation data: the nozzle is at rest before the firing trigger, so every sample
    t = 0, 1, ... of each sequence is a valid regression row.
``"exclude"``
    only rows whose regressors all lie inside the sequence are used
    (t >= max(na, nk + nb - 1)), MATLAB/llsi-style equation-error fitting with no
    assumption about the past.

Free-run simulation (:meth:`ArxModel.simulate`) always starts from rest (zero initial
conditions); one-step-ahead prediction (:meth:`ArxModel.predict_one_step`) uses the measured
past output with zeros before the first sample.

Structure selection
-------------------
:func:`select_structure` scores every (na, nb, nk) of a grid by K-fold cross-validation
*grouped by sequence* (whole sequences are held out), evaluating each model by free-run
**simulation** (not one-step prediction), as the paper's Table 2 does: the simulated
output must track the data from the trigger on, which is what the ECM is used for. See
its docstring for the metrics and the selection rule.

Output noise. Drop volumes carry *output* measurement noise. The ordinary equation-error
least squares (``focus="prediction"``, MATLAB's and llsi's ``arx``) is then biased, badly
so at a 10 µs sampling of a ~1 ms response (poles near z = 1). ``focus="simulation"``
(Steiglitz-McBride iterations, the model structure stays ARX) removes that bias and is the
default of :func:`select_structure`; :func:`fit_arx` defaults to the plain fit.

Numerics: least squares are solved in a nested, well-conditioned basis of backward
differences (Δ^i y(t-1), Δ^i u(t-nk), which spans exactly the same regressors as the lags) with
column scaling; parameters and covariance are mapped back to the lag coefficients
exactly. The grid search accumulates per-sequence Gram matrices of all candidate columns
once, so each (structure, fold) fit is a tiny solve.
"""

from __future__ import annotations

import itertools
import time
from dataclasses import dataclass, field
from math import comb

import numpy as np
import pandas as pd
import scipy.linalg
from scipy.signal import lfilter

__all__ = [
    "ArxModel",
    "StructureSelection",
    "fit_arx",
    "select_structure",
    "evaluate",
    "rmse",
    "fit_percent",
    "TABLE_COLUMNS",
]

INITIAL_MODES = ("zero", "exclude")
FOCUS_MODES = ("prediction", "simulation")

#: Columns of :attr:`StructureSelection.table`, in order.
TABLE_COLUMNS = (
    "na",
    "nb",
    "nk",
    "train_rmse_nl",
    "train_fit_percent",
    "val_rmse_nl",
    "val_fit_percent",
)

#: Largest condition number accepted for the column-scaled difference-basis regressors.
_MAX_CONDITION = 1e12


# ---------------------------------------------------------------------------------------
# Input handling
# ---------------------------------------------------------------------------------------


def _as_sequences(sequences, name: str = "sequences") -> list[tuple[np.ndarray, np.ndarray]]:
    """Validate and convert to a list of (u, y) float arrays."""
    if isinstance(sequences, tuple) and len(sequences) == 2 and np.ndim(sequences[0]) == 1 and np.ndim(sequences[1]) == 1:
        sequences = [sequences]  # a single (u, y) pair
    try:
        items = list(sequences)
    except TypeError:
        raise ValueError(f"{name} must be a list of (u, y) arrays or of objects with .u and .y") from None
    if not items:
        raise ValueError(f"{name} is empty: need at least one (u, y) sequence")
    out = []
    for j, s in enumerate(items):
        if hasattr(s, "u") and hasattr(s, "y"):
            u, y = s.u, s.y
        else:
            try:
                u, y = s
            except (TypeError, ValueError):
                raise ValueError(f"{name}[{j}] is neither a (u, y) pair nor an object with .u and .y") from None
        u = np.asarray(u, dtype=float)
        y = np.asarray(y, dtype=float)
        if u.ndim != 1 or y.ndim != 1:
            raise ValueError(f"{name}[{j}]: u and y must be 1-D arrays, got shapes {u.shape} and {y.shape}")
        if u.shape != y.shape:
            raise ValueError(f"{name}[{j}]: u has {u.size} samples but y has {y.size}")
        for arr, lab in ((u, "u"), (y, "y")):
            bad = ~np.isfinite(arr)
            if bad.any():
                raise ValueError(
                    f"{name}[{j}].{lab} contains {int(bad.sum())} NaN/inf value(s) "
                    f"(first at sample {int(np.argmax(bad))}); remove or interpolate them"
                )
        out.append((u, y))
    return out


def _check_orders(na, nb, nk) -> tuple[int, int, int]:
    vals = []
    for lab, v, lo in (("na", na, 0), ("nb", nb, 1), ("nk", nk, 0)):
        if isinstance(v, bool) or not float(v).is_integer() or int(v) < lo:
            raise ValueError(f"ARX order {lab} must be an integer >= {lo}, got {v!r}")
        vals.append(int(v))
    return tuple(vals)


def _check_initial(initial: str) -> str:
    if initial not in INITIAL_MODES:
        raise ValueError(f"initial must be one of {INITIAL_MODES}, got {initial!r}")
    return initial


def _first_row(na: int, nb: int, nk: int, initial: str) -> int:
    """First regression row of a sequence (0 with pre-sample zeros)."""
    return 0 if initial == "zero" else max(na, nk + nb - 1)


def _check_lengths(seqs, na, nb, nk) -> None:
    need = max(na, nk + nb - 1) + 1
    for j, (u, _) in enumerate(seqs):
        if u.size < need:
            raise ValueError(
                f"sequence {j} has {u.size} samples, too short for ARX structure "
                f"(na={na}, nb={nb}, nk={nk}): at least max(na, nk+nb-1)+1 = {need} samples are needed"
            )


# ---------------------------------------------------------------------------------------
# Difference basis
# ---------------------------------------------------------------------------------------


def _diff_matrix(n: int) -> np.ndarray:
    """T with Δ^i x(t-m) = sum_j T[j, i] x(t-m-j), j <= i < n (T[j, i] = (-1)^j C(i, j))."""
    t = np.zeros((n, n))
    for i in range(n):
        for j in range(i + 1):
            t[j, i] = (-1) ** j * comb(i, j)
    return t


def _lag_basis_to_params(coef_y: np.ndarray, coef_u: np.ndarray, na: int, nb: int) -> np.ndarray:
    """Map difference-basis coefficients (+Δ^i y(t-1), Δ^i u(t-nk)) to theta = [a1..a_na, b1..b_nb]."""
    a = -(_diff_matrix(na) @ coef_y) if na else np.zeros(0)
    b = _diff_matrix(nb) @ coef_u
    return np.concatenate([a, b])


def _param_transform(na: int, nb: int) -> np.ndarray:
    """Linear map from difference-basis coefficients to theta (block diagonal)."""
    t = np.zeros((na + nb, na + nb))
    t[:na, :na] = -_diff_matrix(na)
    t[na:, na:] = _diff_matrix(nb)
    return t


def _diff_regressors(u: np.ndarray, y: np.ndarray, na: int, nb: int, nk: int, initial: str):
    """Difference-basis regressors D (rows x (na+nb)) and target of one sequence.

    Columns: Δ^i y(t-1) for i < na, then Δ^i u(t-nk) for i < nb, with zeros before the
    first sample (only used for rows whose lags reach there when ``initial == "zero"``).
    """
    pad = max(na, nk + nb - 1) + 1
    n = u.size
    up = np.concatenate([np.zeros(pad), u])
    yp = np.concatenate([np.zeros(pad), y])
    t0 = _first_row(na, nb, nk, initial)
    rows = np.arange(t0, n) + pad
    cols = []
    for i in range(na):
        cols.append(sum((-1) ** j * comb(i, j) * yp[rows - 1 - j] for j in range(i + 1)))
    for i in range(nb):
        cols.append(sum((-1) ** j * comb(i, j) * up[rows - nk - j] for j in range(i + 1)))
    return np.column_stack(cols) if cols else np.zeros((rows.size, 0)), yp[rows]


# ---------------------------------------------------------------------------------------
# Model
# ---------------------------------------------------------------------------------------


@dataclass
class ArxModel:
    """A fitted ARX model ``A(q) y(t) = B(q) u(t-nk) + e(t)`` (MATLAB conventions).

    Attributes
    ----------
    na, nb, nk : int
        Orders and delay (``nk`` = samples before the first input term, MATLAB).
    a : ndarray, shape (na+1,)
        ``[1, a1, ..., a_na]`` (MATLAB's ``A`` polynomial in q^-1).
    b : ndarray, shape (nb,)
        ``[b1, ..., b_nb]``, *without* the ``nk`` leading zeros that MATLAB's ``B`` carries
        (see :attr:`b_padded`).
    covariance : ndarray, shape (na+nb, na+nb)
        ``sigma2 (Phi^T Phi)^-1`` of theta = ``[a1..a_na, b1..b_nb]`` (MATLAB's order).
    sigma2 : float
        Residual (equation-error) variance, RSS / (n_samples - na - nb).
    n_samples : int
        Number of regression rows used in the fit (all sequences together).
    n_sequences : int
        Number of sequences fitted.
    initial : str
        ``"zero"`` (pre-sample zeros) or ``"exclude"``, see the module docstring.
    """

    na: int
    nb: int
    nk: int
    a: np.ndarray
    b: np.ndarray
    covariance: np.ndarray
    sigma2: float
    n_samples: int
    n_sequences: int = 1
    initial: str = "zero"

    def __post_init__(self) -> None:
        self.na, self.nb, self.nk = _check_orders(self.na, self.nb, self.nk)
        self.a = np.asarray(self.a, dtype=float)
        self.b = np.asarray(self.b, dtype=float)
        self.covariance = np.asarray(self.covariance, dtype=float)
        if self.a.shape != (self.na + 1,) or self.a[0] != 1.0:
            raise ValueError(f"ArxModel.a must be [1, a1, ..., a_na] of length {self.na + 1}, got {self.a!r}")
        if self.b.shape != (self.nb,):
            raise ValueError(f"ArxModel.b must have nb={self.nb} entries, got shape {self.b.shape}")
        p = self.na + self.nb
        if self.covariance.shape != (p, p):
            raise ValueError(f"ArxModel.covariance must be {p}x{p}, got shape {self.covariance.shape}")

    # -- parameters ------------------------------------------------------------------
    @property
    def theta(self) -> np.ndarray:
        """Parameter vector ``[a1, ..., a_na, b1, ..., b_nb]``."""
        return np.concatenate([self.a[1:], self.b])

    @property
    def parameter_names(self) -> list[str]:
        return [f"a{i}" for i in range(1, self.na + 1)] + [f"b{i}" for i in range(1, self.nb + 1)]

    @property
    def standard_errors(self) -> np.ndarray:
        """Standard errors of :attr:`theta`, sqrt(diag(covariance))."""
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))

    @property
    def b_padded(self) -> np.ndarray:
        """MATLAB's ``B``: ``nk`` zeros followed by b1..b_nb (coefficients of q^0, q^-1, ...)."""
        return np.concatenate([np.zeros(self.nk), self.b])

    def poles(self) -> np.ndarray:
        """Roots of A(z) (z-domain poles)."""
        return np.roots(self.a) if self.na else np.zeros(0)

    @property
    def is_stable(self) -> bool:
        return bool(np.all(np.abs(self.poles()) < 1.0))

    def parameters_table(self) -> pd.DataFrame:
        """Columns ``name, value, standard_error``."""
        return pd.DataFrame({"name": self.parameter_names, "value": self.theta, "standard_error": self.standard_errors})

    # -- use -------------------------------------------------------------------------
    def simulate(self, u) -> np.ndarray:
        """Free-run **simulation** from rest: ``A(q) y_sim = B(q) u(t-nk)``, zero initial conditions.

        Only the input is used; the output is never fed back. ``u`` may be 1-D or 2-D
        (sequences along the last axis, each simulated independently).
        """
        u = np.asarray(u, dtype=float)
        with np.errstate(over="ignore", invalid="ignore"):
            return lfilter(self.b_padded, self.a, u, axis=-1)

    def predict_one_step(self, u, y) -> np.ndarray:
        """**One-step-ahead prediction** ``y_hat(t|t-1) = (1 - A(q)) y(t) + B(q) u(t-nk)``.

        Uses the measured outputs ``y`` up to t-1 and zeros before the first sample.
        """
        u = np.asarray(u, dtype=float)
        y = np.asarray(y, dtype=float)
        if u.shape != y.shape:
            raise ValueError(f"predict_one_step: u has shape {u.shape} but y has {y.shape}")
        one_minus_a = np.concatenate([[0.0], -self.a[1:]])
        return lfilter(self.b_padded, [1.0], u, axis=-1) + lfilter(one_minus_a, [1.0], y, axis=-1)

    # -- serialisation ---------------------------------------------------------------
    def to_dict(self) -> dict:
        return {
            "na": self.na,
            "nb": self.nb,
            "nk": self.nk,
            "a": self.a.tolist(),
            "b": self.b.tolist(),
            "covariance": self.covariance.tolist(),
            "sigma2": float(self.sigma2),
            "n_samples": int(self.n_samples),
            "n_sequences": int(self.n_sequences),
            "initial": self.initial,
            "convention": "MATLAB: A(q)y(t)=B(q)u(t-nk)+e(t), first input term u(t-nk)",
        }

    @classmethod
    def from_dict(cls, d: dict) -> "ArxModel":
        keys = ("na", "nb", "nk", "a", "b", "covariance", "sigma2", "n_samples")
        missing = [k for k in keys if k not in d]
        if missing:
            raise ValueError(f"ArxModel.from_dict: missing key(s) {missing}")
        return cls(
            na=d["na"],
            nb=d["nb"],
            nk=d["nk"],
            a=np.asarray(d["a"], dtype=float),
            b=np.asarray(d["b"], dtype=float),
            covariance=np.asarray(d["covariance"], dtype=float),
            sigma2=float(d["sigma2"]),
            n_samples=int(d["n_samples"]),
            n_sequences=int(d.get("n_sequences", 1)),
            initial=d.get("initial", "zero"),
        )


# ---------------------------------------------------------------------------------------
# Fitting
# ---------------------------------------------------------------------------------------


def fit_arx(
    sequences,
    na: int,
    nb: int,
    nk: int,
    *,
    initial: str = "zero",
    focus: str = "prediction",
    max_iter: int = 20,
) -> ArxModel:
    """Least-squares ARX fit on one or many sequences (regressors never cross sequences).

    Parameters
    ----------
    sequences : list of (u, y) or of objects with ``.u``/``.y``
        1-D arrays of equal length per sequence; lengths may differ between sequences.
        A single ``(u, y)`` tuple is accepted too.
    na, nb, nk : int
        MATLAB orders: ``na >= 0`` poles, ``nb >= 1`` input terms, ``nk >= 0`` samples
        before the first input term.
    initial : {"zero", "exclude"}
        ``"zero"`` (default): values before each sequence's first sample are zero (the
        system is at rest before the trigger), every sample is a regression row.
        ``"exclude"``: only rows with all lags inside the sequence.
    focus : {"prediction", "simulation"}
        ``"prediction"`` (default, MATLAB ``arx``/llsi): one linear least-squares fit of the
        equation error. ``"simulation"``: Steiglitz-McBride iterations - refit on the
        data prefiltered by 1/Â(q) of the previous iterate (Â stabilised by reflecting
        roots into the unit circle), which converges towards the minimiser of the free-run
        simulation error and removes the bias that white *output* noise causes in the
        equation-error fit. The iterate with the smallest simulation error on the fitted
        data is returned (the plain fit included), so it is never worse than
        ``"prediction"`` on that criterion. Its covariance and ``sigma2`` are those of the
        last prefiltered regression (residual ≈ simulation error), an approximation.
    max_iter : int
        Maximum Steiglitz-McBride iterations (``focus="simulation"``).

    Returns
    -------
    ArxModel

    Raises
    ------
    ValueError
        NaN/inf in the data, a sequence shorter than ``max(na, nk+nb-1)+1`` samples, fewer
        rows than parameters, or rank-deficient regressors (e.g. zero or constant input).
    """
    na, nb, nk = _check_orders(na, nb, nk)
    initial = _check_initial(initial)
    if focus not in FOCUS_MODES:
        raise ValueError(f"focus must be one of {FOCUS_MODES}, got {focus!r}")
    seqs = _as_sequences(sequences)
    _check_lengths(seqs, na, nb, nk)
    model = _fit_ls(seqs, na, nb, nk, initial)
    if focus == "prediction" or na == 0:
        return model
    best, best_sse, stale = model, _sim_sse(model, seqs), 0
    a = model.a
    for _ in range(int(max_iter)):
        a_f = _stabilise(a)
        try:
            new = _fit_ls(_prefiltered(seqs, a_f), na, nb, nk, initial)
        except ValueError:
            break
        sse = _sim_sse(new, seqs)
        if sse < best_sse * (1.0 - 1e-9):
            best, best_sse, stale = new, sse, 0
        else:
            stale += 1
        step = np.max(np.abs(new.a - a))
        a = new.a
        if step < 1e-10 or stale >= 5:
            break
    return best


def _fit_ls(seqs, na: int, nb: int, nk: int, initial: str) -> ArxModel:
    """Equation-error least squares on validated sequences (see :func:`fit_arx`)."""
    blocks = [_diff_regressors(u, y, na, nb, nk, initial) for u, y in seqs]
    D = np.concatenate([b[0] for b in blocks])
    target = np.concatenate([b[1] for b in blocks])
    p = na + nb
    m = D.shape[0]
    if m <= p:
        raise ValueError(f"only {m} regression rows for {p} parameters (na={na}, nb={nb}, nk={nk}): need more data")
    scale = np.linalg.norm(D, axis=0)
    names = [f"Δ^{i} y(t-1)" for i in range(na)] + [f"Δ^{i} u(t-{nk})" for i in range(nb)]
    zero_cols = [names[i] for i in np.flatnonzero(scale == 0)]
    if zero_cols:
        raise ValueError(
            f"rank-deficient ARX regressors for (na={na}, nb={nb}, nk={nk}): regressor(s) {zero_cols} "
            "are identically zero over the regression rows (zero or constant input/output: "
            "the data are not persistently exciting for this structure)"
        )
    Ds = D / scale
    Q, R = scipy.linalg.qr(Ds, mode="economic")
    sv = scipy.linalg.svdvals(R)
    cond = sv[0] / sv[-1] if sv[-1] > 0 else np.inf
    if not cond < _MAX_CONDITION:
        raise ValueError(
            f"rank-deficient ARX regressors for (na={na}, nb={nb}, nk={nk}): condition number {cond:.3g} "
            "of the scaled regressors (the input is not persistently exciting for this structure, "
            "e.g. constant, or orders are redundant)"
        )
    coef_s = scipy.linalg.solve_triangular(R, Q.T @ target)
    coef = coef_s / scale
    resid = target - D @ coef
    rss = float(resid @ resid)
    sigma2 = rss / (m - p)
    r_inv = scipy.linalg.solve_triangular(R, np.eye(p))
    cov_d = (r_inv @ r_inv.T) / np.outer(scale, scale)
    T = _param_transform(na, nb)
    theta = T @ coef
    cov = sigma2 * (T @ cov_d @ T.T)
    return ArxModel(
        na=na,
        nb=nb,
        nk=nk,
        a=np.concatenate([[1.0], theta[:na]]),
        b=theta[na:],
        covariance=0.5 * (cov + cov.T),
        sigma2=sigma2,
        n_samples=m,
        n_sequences=len(seqs),
        initial=initial,
    )


# ---------------------------------------------------------------------------------------
# Metrics
# ---------------------------------------------------------------------------------------


def rmse(y, y_hat) -> float:
    """Root mean square error (units of y)."""
    e = np.asarray(y, dtype=float) - np.asarray(y_hat, dtype=float)
    return float(np.sqrt(np.mean(e**2)))


def fit_percent(y, y_hat) -> float:
    """MATLAB's normalised fit: 100 (1 - ||y - y_hat|| / ||y - mean(y)||) (%)."""
    y = np.asarray(y, dtype=float)
    den = np.linalg.norm(y - y.mean())
    if den == 0:
        raise ValueError("fit_percent: y is constant, the fit percent is undefined")
    return float(100.0 * (1.0 - np.linalg.norm(y - np.asarray(y_hat, dtype=float)) / den))


def evaluate(model: ArxModel, sequences, *, mode: str = "simulation") -> dict:
    """Pooled RMSE and fit percent of ``model`` on ``sequences``.

    ``mode="simulation"`` (free run from rest) or ``"prediction"`` (one step ahead).
    Returns ``{"mode", "rmse_nl", "fit_percent", "n_samples"}`` over all samples of all
    sequences pooled (the mean in the fit percent is the pooled mean).
    """
    if mode not in ("simulation", "prediction"):
        raise ValueError(f"mode must be 'simulation' or 'prediction', got {mode!r}")
    seqs = _as_sequences(sequences)
    ys, yh = [], []
    for u, y in seqs:
        ys.append(y)
        yh.append(model.simulate(u) if mode == "simulation" else model.predict_one_step(u, y))
    y = np.concatenate(ys)
    h = np.concatenate(yh)
    with np.errstate(over="ignore", invalid="ignore"):
        return {"mode": mode, "rmse_nl": rmse(y, h), "fit_percent": fit_percent(y, h), "n_samples": int(y.size)}


# ---------------------------------------------------------------------------------------
# Structure selection
# ---------------------------------------------------------------------------------------


@dataclass
class StructureSelection:
    """Result of :func:`select_structure`.

    Attributes
    ----------
    table : DataFrame
        One row per structure, columns :data:`TABLE_COLUMNS` (RMSE in the output's unit,
        nl for drop volumes) plus ``refined`` (bool: re-scored by per-structure
        Steiglitz-McBride CV, see :func:`select_structure`); re-scored rows first, each
        group sorted by ``val_rmse_nl``. Models whose simulation diverged
        have ``inf`` RMSE and ``-inf`` fit.
    best : (na, nb, nk)
        Structure with the smallest validation RMSE.
    selected : (na, nb, nk)
        Simplest structure within ``tolerance`` of the best (see :func:`select_structure`).
    tolerance : dict
        ``{"relative", "absolute_nl", "threshold_rmse_nl"}``: a structure is acceptable if
        its validation RMSE <= threshold = best + max(relative * best, absolute_nl).
    folds : int
        Number of folds actually used.
    fold_scheme : str
        E.g. ``"10-fold grouped by sequence"`` or ``"leave-one-sequence-out (6 sequences < 10 folds)"``.
    fold_of_sequence : ndarray
        Fold index of each sequence.
    initial : str
    elapsed_s : float
        Wall time of the search.
    focus : str
        Estimation criterion (see :func:`select_structure`).
    n_refined : int
        Number of rows re-scored by per-structure Steiglitz-McBride CV (``refined`` column).
    prefilter_a : ndarray or None
        A(q) of the common screening prefilter 1/A(q) (``focus="simulation"``).
    model : ArxModel
        The selected structure fitted on all sequences.
    """

    table: pd.DataFrame
    best: tuple[int, int, int]
    selected: tuple[int, int, int]
    tolerance: dict
    folds: int
    fold_scheme: str
    fold_of_sequence: np.ndarray
    initial: str
    elapsed_s: float
    focus: str = "simulation"
    n_refined: int = 0
    prefilter_a: np.ndarray | None = field(default=None, repr=False)
    model: ArxModel | None = field(default=None, repr=False)

    def to_pandas(self) -> pd.DataFrame:
        """The structure table (a copy)."""
        return self.table.copy()

    def row(self, na: int, nb: int, nk: int) -> pd.Series:
        t = self.table
        hit = t[(t.na == na) & (t.nb == nb) & (t.nk == nk)]
        if hit.empty:
            raise KeyError(f"structure (na={na}, nb={nb}, nk={nk}) is not in the table")
        return hit.iloc[0]

    def to_dict(self) -> dict:
        return {
            "best": list(self.best),
            "selected": list(self.selected),
            "tolerance": dict(self.tolerance),
            "folds": self.folds,
            "fold_scheme": self.fold_scheme,
            "initial": self.initial,
            "focus": self.focus,
            "n_refined": self.n_refined,
            "elapsed_s": self.elapsed_s,
            "table": self.table.to_dict(orient="list"),
            "model": None if self.model is None else self.model.to_dict(),
        }


def _range_list(r, name: str, lo: int) -> list[int]:
    if isinstance(r, (int, np.integer)):
        r = [int(r)]
    vals = sorted({int(v) for v in r})
    if not vals:
        raise ValueError(f"{name} is empty")
    if vals[0] < lo:
        raise ValueError(f"{name} must contain integers >= {lo}, got {vals[0]}")
    return vals


def _assign_folds(n_seq: int, folds: int, seed: int) -> tuple[np.ndarray, int, str]:
    if isinstance(folds, bool) or int(folds) != folds or folds < 2:
        raise ValueError(f"folds must be an integer >= 2, got {folds!r}")
    folds = int(folds)
    if n_seq < 2:
        raise ValueError(f"cross-validation needs at least 2 sequences, got {n_seq}")
    if n_seq < folds:
        k = n_seq
        scheme = f"leave-one-sequence-out ({n_seq} sequences < {folds} folds)"
    else:
        k = folds
        scheme = f"{folds}-fold grouped by sequence"
    order = np.random.default_rng(seed).permutation(n_seq)
    fold_of = np.empty(n_seq, dtype=int)
    for f, idx in enumerate(np.array_split(order, k)):
        fold_of[idx] = f
    return fold_of, k, scheme


def _stabilise(a: np.ndarray) -> np.ndarray:
    """Reflect roots of A(z) outside the unit circle to 1/conj(root) (keeps |root| < 1)."""
    if a.size <= 1:
        return a
    r = np.roots(a)
    bad = np.abs(r) >= 1.0
    if not bad.any():
        return a
    r[bad] = 1.0 / np.conj(r[bad])
    r[np.abs(r) >= 1.0] *= 0.999
    return np.real(np.poly(r))


def _sim_sse(model: ArxModel, seqs) -> float:
    with np.errstate(over="ignore", invalid="ignore"):
        s = sum(float(np.sum((y - model.simulate(u)) ** 2)) for u, y in seqs)
    return s if np.isfinite(s) else np.inf


def _prefiltered(seqs, a: np.ndarray):
    """Sequences filtered by 1/A(q) from rest (same filter on u and y keeps A y = B u)."""
    with np.errstate(over="ignore", invalid="ignore"):
        return [(lfilter([1.0], a, u), lfilter([1.0], a, y)) for u, y in seqs]


def _grid_sse(fit_seqs, score_seqs, structures, nk_list, na_max, nb_max, initial, member):
    """Per-(structure, fold, sequence) simulation SSE of LS fits on the training folds.

    Fits use ``fit_seqs`` (possibly prefiltered); the simulation is scored on
    ``score_seqs`` (the raw data). Returns {structure: (n_folds, n_seq) array or None}.
    """
    n_seq = len(score_seqs)
    n_folds = member.shape[0]
    lengths = np.array([u.size for u, _ in score_seqs])
    n_max = int(lengths.max())
    pad = max(na_max, nk_list[-1] + nb_max - 1) + 1

    def padded(pairs):
        U = np.zeros((n_seq, pad + n_max))
        Y = np.zeros((n_seq, pad + n_max))
        for j, (u, y) in enumerate(pairs):
            U[j, pad : pad + u.size] = u
            Y[j, pad : pad + y.size] = y
        return U, Y

    U, Y = padded(fit_seqs)
    U_raw, Y_raw = padded(score_seqs)
    mask = np.arange(n_max)[None, :] < lengths[:, None]

    def lagged(X, lag):  # X(t - lag) for rows t = 0..n_max-1
        return X[:, pad - lag : pad - lag + n_max]

    def diff_col(X, lag, i):
        return sum((-1) ** j * comb(i, j) * lagged(X, lag + j) for j in range(i + 1))

    cols = [lagged(Y, 0)]  # target
    y_col, u_col = {}, {}
    for i in range(na_max):
        y_col[i] = len(cols)
        cols.append(diff_col(Y, 1, i))
    for nk in nk_list:
        for i in range(nb_max):
            u_col[nk, i] = len(cols)
            cols.append(diff_col(U, nk, i))
    Z = np.stack(cols, axis=-1) * mask[..., None]  # rows beyond each sequence are zero
    Y_obs = Y_raw[:, pad:]
    starts = {s: _first_row(*s, initial) for s in structures}
    G = np.einsum("jtp,jtq->jpq", Z, Z)  # per-sequence Gram over rows t >= current start
    current = 0
    results, transforms = {}, {}
    for start in sorted(set(starts.values())):
        if start > current:
            blk = Z[:, current:start]
            G = G - np.einsum("jtp,jtq->jpq", blk, blk)
            current = start
        Gf = np.tensordot(member, G, axes=(1, 0))  # (n_folds, n_cols, n_cols) training Grams
        for s in (s for s in structures if starts[s] == start):
            na, nb, nk = s
            idx = np.array([y_col[i] for i in range(na)] + [u_col[nk, i] for i in range(nb)])
            H = Gf[:, idx[:, None], idx[None, :]]
            g = Gf[:, idx, 0]
            d = np.sqrt(np.einsum("fii->fi", H))
            if np.any(d == 0):
                results[s] = None
                continue
            Hs = H / (d[:, :, None] * d[:, None, :])
            if np.any(np.linalg.cond(Hs) > _MAX_CONDITION**2):
                results[s] = None
                continue
            coef = np.linalg.solve(Hs, (g / d)[..., None])[..., 0] / d
            if (na, nb) not in transforms:
                transforms[na, nb] = _param_transform(na, nb)
            theta = coef @ transforms[na, nb].T  # (n_folds, p)
            sse = np.empty((n_folds, n_seq))
            with np.errstate(over="ignore", invalid="ignore"):
                for f in range(n_folds):
                    a_poly = np.concatenate([[1.0], theta[f, :na]])
                    # delay by slicing the padded input, not by nk leading zeros (nk-times cheaper)
                    e = (Y_obs - lfilter(theta[f, na:], a_poly, lagged(U_raw, nk), axis=-1)) * mask
                    sse[f] = np.einsum("jt,jt->j", e, e)
            results[s] = sse
    return results


def _table(results, structures, member, score_seqs) -> pd.DataFrame:
    lengths = np.array([u.size for u, _ in score_seqs])
    sy = np.array([y.sum() for _, y in score_seqs])
    syy = np.array([y @ y for _, y in score_seqs])
    train_n = member @ lengths
    train_sst = member @ syy - (member @ sy) ** 2 / train_n
    total_sst = syy.sum() - sy.sum() ** 2 / lengths.sum()
    val_member = 1.0 - member
    rows = []
    for s in structures:
        sse = results[s]
        if sse is None or not np.all(np.isfinite(sse)):
            rows.append((*s, np.inf, -np.inf, np.inf, -np.inf))
            continue
        tr_sse = np.einsum("fj,fj->f", member, sse)
        va_sse = float(np.einsum("fj,fj->", val_member, sse))
        rows.append(
            (
                *s,
                float(np.mean(np.sqrt(tr_sse / train_n))),
                float(np.mean(100.0 * (1.0 - np.sqrt(tr_sse / train_sst)))),
                float(np.sqrt(va_sse / lengths.sum())),
                float(100.0 * (1.0 - np.sqrt(va_sse / total_sst))),
            )
        )
    table = pd.DataFrame(rows, columns=list(TABLE_COLUMNS))
    return table.sort_values(["val_rmse_nl", "na", "nb", "nk"], kind="stable").reset_index(drop=True)


def _sm_cv_sse(seqs, structures, member, initial, a_start, max_iter: int = 12):
    """Per-fold Steiglitz-McBride fits of each structure; simulation SSE per (fold, sequence).

    Each fold starts from the prefilter ``a_start``, refits the LS on training data filtered
    by 1/Â and keeps the iterate with the smallest *training* simulation error.
    """
    n_seq = len(seqs)
    n_folds = member.shape[0]
    lengths = np.array([u.size for u, _ in seqs])
    n_max = int(lengths.max())
    pad = max(max(na, nk + nb - 1) for na, nb, nk in structures) + 1
    U = np.zeros((n_seq, pad + n_max))
    Y = np.zeros((n_seq, pad + n_max))
    for j, (u, y) in enumerate(seqs):
        U[j, pad : pad + u.size] = u
        Y[j, pad : pad + y.size] = y
    mask = np.arange(n_max)[None, :] < lengths[:, None]
    Y_obs = Y[:, pad:]

    def lagged(X, lag):
        return X[:, pad - lag : pad - lag + n_max]

    def diff_col(X, lag, i):
        return sum((-1) ** j * comb(i, j) * lagged(X, lag + j) for j in range(i + 1))

    results = {}
    with np.errstate(over="ignore", invalid="ignore"):
        for s in structures:
            na, nb, nk = s
            T = _param_transform(na, nb)
            rows = mask & (np.arange(n_max)[None, :] >= _first_row(na, nb, nk, initial))
            sse_out = np.empty((n_folds, n_seq))
            ok = True
            for f in range(n_folds):
                a_filt = _stabilise(np.asarray(a_start, dtype=float))
                best_tr, best_sse, stale = np.inf, None, 0
                for _ in range(max_iter):
                    Uf = lfilter([1.0], a_filt, U, axis=-1)
                    Yf = lfilter([1.0], a_filt, Y, axis=-1)
                    cols = [lagged(Yf, 0)] + [diff_col(Yf, 1, i) for i in range(na)]
                    cols += [diff_col(Uf, nk, i) for i in range(nb)]
                    Zs = np.stack(cols, axis=-1) * (rows * member[f][:, None])[..., None]
                    Gm = np.einsum("jtp,jtq->pq", Zs, Zs)
                    H, g = Gm[1:, 1:], Gm[1:, 0]
                    d = np.sqrt(np.diag(H))
                    if not np.all(np.isfinite(d)) or np.any(d == 0):
                        break
                    Hs = H / np.outer(d, d)
                    if np.linalg.cond(Hs) > _MAX_CONDITION**2:
                        break
                    theta = T @ (np.linalg.solve(Hs, g / d) / d)
                    a_new = np.concatenate([[1.0], theta[:na]])
                    e = (Y_obs - lfilter(theta[na:], a_new, lagged(U, nk), axis=-1)) * mask
                    sse = np.einsum("jt,jt->j", e, e)
                    tr = float(member[f] @ sse)
                    if np.isfinite(tr) and tr < best_tr * (1.0 - 1e-9):
                        best_tr, best_sse, stale = tr, sse, 0
                    else:
                        stale += 1
                    step = np.max(np.abs(a_new - a_filt)) if a_new.size == a_filt.size else np.inf
                    a_filt = _stabilise(a_new)
                    if step < 1e-10 or stale >= 3:
                        break
                if best_sse is None:
                    ok = False
                    break
                sse_out[f] = best_sse
            results[s] = sse_out if ok else None
    return results


def select_structure(
    sequences,
    na_range=range(1, 8),
    nb_range=range(1, 5),
    nk_range=range(0, 41),
    folds: int = 10,
    tolerance: float = 0.05,
    *,
    absolute_tolerance_nl: float = 0.0,
    seed: int = 0,
    initial: str = "zero",
    focus: str = "simulation",
    max_refine: int = 60,
) -> StructureSelection:
    """Cross-validated ARX structure search over an (na, nb, nk) grid (paper Table 2).

    Every structure of the full grid is fitted by least squares on the training sequences
    of each fold and scored by free-run **simulation** (from rest, input only) on the
    training and the held-out sequences (the paper's Table 2 evaluates models this way).

    Folds are grouped by sequence: sequences are shuffled with ``seed`` and split into
    ``folds`` groups of nearly equal size; each group is held out once. With fewer
    sequences than ``folds``, leave-one-sequence-out is used (``fold_scheme`` says so).

    Estimation (``focus``):

    * ``"prediction"``: plain equation-error least squares for every structure and fold
      (MATLAB ``arx``), one stage. With *output* measurement noise and fast sampling
      (poles near z = 1) this is strongly biased: the equation error A(q) v(t) is
      high-pass noise correlated with the lagged outputs, so the simulated RMSE stays far
      above the noise floor and the minimum wanders (ECM data, 0.1 % noise: best
      (7, 4, 18), RMSE 1.35x the noise).
    * ``"simulation"`` (default), three stages:

      0. delay scan: plain LS at (max na, max nb) for every nk; the best one refined by
         :func:`fit_arx` (``focus="simulation"``) on all sequences gives a prefilter 1/A_ref;
      1. screening: the full grid, LS on data prefiltered by the common 1/A_ref
         (one Steiglitz-McBride step; a fixed weighting that sees all sequences, as a
         hand-chosen low-pass would), scored by simulation on the raw data;
      2. re-scoring (``refined`` column True): per structure and fold, Steiglitz-McBride
         iterations on the training sequences (start 1/A_ref, keep the iterate with the
         lowest training simulation error), scored on the held-out sequences. Structures
         are visited simplest first ((na+nb, na) order); for each (na, nb) whose screening
         RMSE is within (1 + 3 tolerance) of the screening best, the two best screening
         delays and the delays within +-2 of the best one; the three screening-best
         structures are always re-scored. The walk stops after the complexity level at
         which an acceptable structure appears (or ``max_refine`` structures).

      ``best``/``selected`` are decided on the re-scored rows only; the screening rows
      stay in the table (``refined`` False) for reference.

    Metrics (output units, "nl" for drop volumes):

    * ``val_rmse_nl``, ``val_fit_percent``: pooled over all held-out predictions (each
      sequence is simulated once, by the model of the fold that held it out);
      fit = 100 (1 - ||y - y_sim|| / ||y - mean(y)||) with the pooled mean.
    * ``train_rmse_nl``, ``train_fit_percent``: pooled over the training sequences of a fold,
      averaged over the folds.

    Selection rule: ``best`` minimises ``val_rmse_nl``. A structure is *acceptable* when
    its validation RMSE <= best + max(tolerance * best, absolute_tolerance_nl). Among the
    acceptable ones, ``selected`` is the simplest: fewest parameters ``na + nb``, then,
    among structures with as many parameters, the smallest validation RMSE (which also
    picks the delay ``nk``; e.g. (3, 2) and (2, 3) cost the same, the data decide). Near the noise floor σ a relative tolerance r accepts structures whose own
    simulation error is below about σ sqrt((1+r)^2 - 1) (0.32 σ for the default
    r = 0.05): extra parameters that only fit sampling zeros or noise are dropped, a
    missing pole, input term or a wrong delay whose error is comparable to the noise is
    not. Structure details smaller than that are not identifiable from the data by any
    rule. ``absolute_tolerance_nl`` lets a known noise floor count as "comparable".

    Parameters
    ----------
    sequences : list of (u, y) or objects with ``.u``/``.y``
    na_range, nb_range, nk_range : iterable of int (or a single int)
    folds : int
        Number of folds (default 10, as in the paper).
    tolerance : float
        Relative tolerance on the validation RMSE (default 0.05).
    absolute_tolerance_nl : float
        Absolute tolerance (output units), default 0.
    seed : int
        Seed of the fold shuffle.
    initial : {"zero", "exclude"}
        Pre-sample handling of the fits, see :func:`fit_arx`.
    focus : {"simulation", "prediction"}
        Estimation criterion, see above.
    max_refine : int
        Maximum number of structures re-scored in stage 2.

    Returns
    -------
    StructureSelection
    """
    t_start = time.perf_counter()
    initial = _check_initial(initial)
    if focus not in FOCUS_MODES:
        raise ValueError(f"focus must be one of {FOCUS_MODES}, got {focus!r}")
    seqs = _as_sequences(sequences)
    na_list = _range_list(na_range, "na_range", 0)
    nb_list = _range_list(nb_range, "nb_range", 1)
    nk_list = _range_list(nk_range, "nk_range", 0)
    if not (np.isfinite(tolerance) and tolerance >= 0):
        raise ValueError(f"tolerance must be a finite number >= 0, got {tolerance!r}")
    if not (np.isfinite(absolute_tolerance_nl) and absolute_tolerance_nl >= 0):
        raise ValueError(f"absolute_tolerance_nl must be a finite number >= 0, got {absolute_tolerance_nl!r}")
    na_max, nb_max = na_list[-1], nb_list[-1]
    _check_lengths(seqs, na_max, nb_max, nk_list[-1])
    fold_of, n_folds, scheme = _assign_folds(len(seqs), folds, seed)
    member = np.zeros((n_folds, len(seqs)))  # training membership
    for f in range(n_folds):
        member[f, fold_of != f] = 1.0
    structures = list(itertools.product(na_list, nb_list, nk_list))

    def select(table):
        finite = table[np.isfinite(table.val_rmse_nl)]
        if finite.empty:
            raise ValueError("no ARX structure of the grid could be fitted (all rank-deficient or divergent)")
        b = finite.iloc[0]
        best_rmse = float(b.val_rmse_nl)
        threshold = best_rmse + max(tolerance * best_rmse, absolute_tolerance_nl)
        ok = finite[finite.val_rmse_nl <= threshold].copy()
        ok["n_params"] = ok.na + ok.nb
        s = ok.sort_values(["n_params", "val_rmse_nl", "na"], kind="stable").iloc[0]
        return (int(b.na), int(b.nb), int(b.nk)), (int(s.na), int(s.nb), int(s.nk)), threshold

    if focus == "prediction":
        res = _grid_sse(seqs, seqs, structures, nk_list, na_max, nb_max, initial, member)
        table = _table(res, structures, member, seqs)
        prefilter = None
    else:
        # stage 0: delay scan at the largest orders (plain LS) -> reference -> prefilter
        scan = [s for s in structures if s[0] == na_max and s[1] == nb_max]
        res = _grid_sse(seqs, seqs, scan, nk_list, na_max, nb_max, initial, member)
        ref_structure = select(_table(res, scan, member, seqs))[0]
        prefilter = fit_arx(seqs, *ref_structure, initial=initial, focus="simulation").a
        # stage 1: full grid, LS on data prefiltered by the common 1/A_ref (screening)
        res = _grid_sse(_prefiltered(seqs, prefilter), seqs, structures, nk_list, na_max, nb_max, initial, member)
        table = _table(res, structures, member, seqs)
        # stage 2: per-structure, per-fold Steiglitz-McBride re-scoring, simplest first
        finite = table[np.isfinite(table.val_rmse_nl)]
        if finite.empty:
            raise ValueError("no ARX structure of the grid could be fitted (all rank-deficient or divergent)")
        loose = float(finite.val_rmse_nl.iloc[0]) * (1.0 + 3.0 * tolerance) + absolute_tolerance_nl
        nk_set = set(nk_list)

        def candidates_of(na, nb):
            rows = finite[(finite.na == na) & (finite.nb == nb)]
            if rows.empty or float(rows.val_rmse_nl.iloc[0]) > loose:
                return []
            top = [int(k) for k in rows.nk.iloc[:2]]
            extra = [top[0] + d for d in (-2, -1, 1, 2)]
            return [(na, nb, k) for k in dict.fromkeys(top + extra) if k in nk_set]

        refined_res = {}

        def refine(structs):
            todo = [s for s in structs if s not in refined_res]
            if todo:
                refined_res.update(_sm_cv_sse(seqs, todo, member, initial, prefilter))

        refine([(int(r.na), int(r.nb), int(r.nk)) for r in finite.iloc[:3].itertuples()])
        pairs = sorted(itertools.product(na_list, nb_list), key=lambda p: (p[0] + p[1], p[0]))
        level_found = None
        for na, nb in pairs:
            if level_found is not None and na + nb > level_found:
                break
            refine(candidates_of(na, nb))
            cur = _table(refined_res, list(refined_res), member, seqs)
            cur["refined"] = True
            _, sel, _ = select(cur)
            if sel[0] + sel[1] <= na + nb:
                level_found = na + nb
            if len(refined_res) >= max_refine:
                break
        refined = _table(refined_res, list(refined_res), member, seqs)
        refined["refined"] = True
        rest = table.merge(refined[["na", "nb", "nk"]], on=["na", "nb", "nk"], how="left", indicator=True)
        rest = rest[rest["_merge"] == "left_only"].drop(columns="_merge")
        rest["refined"] = False
        # the decision uses refined rows only (stage-1 rows are screening scores)
        table = pd.concat([refined, rest], ignore_index=True)
        table = table.sort_values(["refined", "val_rmse_nl", "na", "nb", "nk"], ascending=[False, True, True, True, True], kind="stable").reset_index(drop=True)
        best, selected, threshold = select(refined.sort_values(["val_rmse_nl", "na", "nb", "nk"], kind="stable"))
    if focus == "prediction":
        table["refined"] = False
        best, selected, threshold = select(table)
    model = fit_arx(seqs, *selected, initial=initial, focus=focus)
    return StructureSelection(
        table=table,
        best=best,
        selected=selected,
        tolerance={"relative": float(tolerance), "absolute_nl": float(absolute_tolerance_nl), "threshold_rmse_nl": threshold},
        folds=n_folds,
        fold_scheme=scheme,
        fold_of_sequence=fold_of,
        initial=initial,
        elapsed_s=time.perf_counter() - t_start,
        focus=focus,
        n_refined=int(table["refined"].sum()),
        prefilter_a=None if prefilter is None else np.asarray(prefilter),
        model=model,
    )
