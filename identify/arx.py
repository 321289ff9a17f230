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
Choosing (na, nb, nk) by grouped cross-validation lives in :mod:`identify.arx_selection`
(:func:`identify.arx_selection.select_structure`); the metrics live in :mod:`identify.metrics`.

Output noise. Drop volumes carry *output* measurement noise. The ordinary equation-error
least squares (``focus="prediction"``, MATLAB's and llsi's ``arx``) is then biased, badly
so at a 10 µs sampling of a ~1 ms response (poles near z = 1). ``focus="simulation"``
(Steiglitz-McBride iterations, the model structure stays ARX) removes that bias and is the
default of the structure selection; :func:`fit_arx` defaults to the plain fit.

Numerics: least squares are solved in a nested, well-conditioned basis of backward
differences (Δ^i y(t-1), Δ^i u(t-nk), which spans exactly the same regressors as the lags) with
column scaling; parameters and covariance are mapped back to the lag coefficients
exactly.
"""

from __future__ import annotations

from dataclasses import dataclass
from math import comb

import numpy as np
import scipy.linalg
from scipy.signal import lfilter

from identify.metrics import fit_percent, rmse

__all__ = [
    "ArxModel",
    "fit_arx",
    "evaluate",
    "INITIAL_MODES",
    "FOCUS_MODES",
    "MAX_CONDITION",
]

#: Pre-sample handling of the regressors (see the module docstring).
INITIAL_MODES = ("zero", "exclude")
#: Estimation criteria of :func:`fit_arx`.
FOCUS_MODES = ("prediction", "simulation")

#: Largest condition number accepted for the column-scaled difference-basis regressors.
MAX_CONDITION = 1e12


# ---------------------------------------------------------------------------------------
# Input handling
# ---------------------------------------------------------------------------------------


def as_sequences(sequences, name: str = "sequences") -> list[tuple[np.ndarray, np.ndarray]]:
    """Validate and convert ARX data to a list of (u, y) float arrays.

    Parameters
    ----------
    sequences : list of (u, y), list of objects with ``.u``/``.y``, or one (u, y) pair
        Input (e.g. piston displacement, µm) and output (e.g. grown volume, nl) samples,
        equal lengths per sequence.
    name : str
        Name used in error messages.

    Returns
    -------
    list of (ndarray, ndarray)
        Finite 1-D float arrays, units unchanged.

    Raises
    ------
    ValueError
        Empty data, wrong shapes, unequal lengths or NaN/inf values.
    """
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


def check_initial(initial: str) -> str:
    """Return ``initial`` if it is one of :data:`INITIAL_MODES`, else raise ``ValueError``."""
    if initial not in INITIAL_MODES:
        raise ValueError(f"initial must be one of {INITIAL_MODES}, got {initial!r}")
    return initial


def first_row(na: int, nb: int, nk: int, initial: str) -> int:
    """First regression row of a sequence (sample index; 0 with pre-sample zeros).

    Parameters
    ----------
    na, nb, nk : int
        ARX orders (MATLAB convention, see the module docstring).
    initial : {"zero", "exclude"}
        Pre-sample handling.

    Returns
    -------
    int
        0 for ``"zero"``, ``max(na, nk + nb - 1)`` for ``"exclude"`` (samples).
    """
    return 0 if initial == "zero" else max(na, nk + nb - 1)


def check_lengths(seqs, na, nb, nk) -> None:
    """Raise ``ValueError`` if a sequence has fewer than ``max(na, nk+nb-1)+1`` samples.

    Parameters
    ----------
    seqs : list of (u, y)
        Validated sequences (:func:`as_sequences`).
    na, nb, nk : int
        ARX orders and delay (samples).
    """
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


def param_transform(na: int, nb: int) -> np.ndarray:
    """Linear map from difference-basis coefficients to theta (block diagonal).

    Parameters
    ----------
    na, nb : int
        ARX orders.

    Returns
    -------
    ndarray, shape (na+nb, na+nb)
        ``T`` with ``theta = T @ coef`` for coefficients of the regressors
        Δ^i y(t-1) (i < na) and Δ^i u(t-nk) (i < nb); theta = [a1..a_na, b1..b_nb]
        (dimensionless / output unit per input unit).
    """
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
    t0 = first_row(na, nb, nk, initial)
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
    initial = check_initial(initial)
    if focus not in FOCUS_MODES:
        raise ValueError(f"focus must be one of {FOCUS_MODES}, got {focus!r}")
    seqs = as_sequences(sequences)
    check_lengths(seqs, na, nb, nk)
    model = _fit_ls(seqs, na, nb, nk, initial)
    if focus == "prediction" or na == 0:
        return model
    best, best_sse, stale = model, _sim_sse(model, seqs), 0
    a = model.a
    for _ in range(int(max_iter)):
        a_f = stabilise(a)
        try:
            new = _fit_ls(prefiltered(seqs, a_f), na, nb, nk, initial)
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
    if not cond < MAX_CONDITION:
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
    T = param_transform(na, nb)
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
# Evaluation
# ---------------------------------------------------------------------------------------


def evaluate(model: ArxModel, sequences, *, mode: str = "simulation") -> dict:
    """Pooled RMSE and fit percent of ``model`` on ``sequences``.

    Parameters
    ----------
    model : ArxModel
    sequences : list of (u, y) or objects with ``.u``/``.y``
        Input (µm) and output (nl for drop volumes) samples.
    mode : {"simulation", "prediction"}
        Free run from rest, or one step ahead.

    Returns
    -------
    dict
        ``{"mode", "rmse_nl", "fit_percent", "n_samples"}`` over all samples of all
        sequences pooled (RMSE in the output unit, nl; the mean in the fit percent is the
        pooled mean).
    """
    if mode not in ("simulation", "prediction"):
        raise ValueError(f"mode must be 'simulation' or 'prediction', got {mode!r}")
    seqs = as_sequences(sequences)
    ys, yh = [], []
    for u, y in seqs:
        ys.append(y)
        yh.append(model.simulate(u) if mode == "simulation" else model.predict_one_step(u, y))
    y = np.concatenate(ys)
    h = np.concatenate(yh)
    with np.errstate(over="ignore", invalid="ignore"):
        return {"mode": mode, "rmse_nl": rmse(y, h), "fit_percent": fit_percent(y, h), "n_samples": int(y.size)}



# ---------------------------------------------------------------------------------------
# Prefiltering (Steiglitz-McBride helpers, shared with identify.arx_selection)
# ---------------------------------------------------------------------------------------


def stabilise(a: np.ndarray) -> np.ndarray:
    """Stable version of a polynomial A(z): roots outside the unit circle reflected.

    Parameters
    ----------
    a : ndarray
        ``[1, a1, ..., a_na]`` (coefficients of q^0, q^-1, ...; dimensionless).

    Returns
    -------
    ndarray
        Same length; roots r with |r| >= 1 replaced by 1/conj(r) (those still on the unit
        circle shrunk by 0.999), so every root has |r| < 1. ``a`` itself when already stable.
    """
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


def prefiltered(seqs, a: np.ndarray):
    """Sequences filtered by 1/A(q) from rest (same filter on u and y keeps A y = B u).

    Parameters
    ----------
    seqs : list of (u, y)
        Validated sequences (units unchanged by the filter's unit DC scaling of A).
    a : ndarray
        ``[1, a1, ..., a_na]``, the prefilter denominator (dimensionless).

    Returns
    -------
    list of (ndarray, ndarray)
        ``(lfilter([1], a, u), lfilter([1], a, y))`` per sequence.
    """
    with np.errstate(over="ignore", invalid="ignore"):
        return [(lfilter([1.0], a, u), lfilter([1.0], a, y)) for u, y in seqs]


