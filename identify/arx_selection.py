"""ARX structure selection: which (na, nb, nk) the data support (Wang & Chiu, §4.2, Table 2).

:func:`select_structure` scores every (na, nb, nk) of a grid by K-fold cross-validation
*grouped by sequence* (whole sequences are held out, :mod:`identify.kfold`, contiguous
layout), evaluating each model by free-run **simulation** (not one-step prediction), as the
paper's Table 2 does: the simulated output must track the data from the trigger on, which
is what the ECM is used for. See its docstring for the metrics and the selection rule.

The default grid is :data:`DEFAULT_GRID` (na 1-7, nb 1-4, nk 0-40 samples, MATLAB's delay
convention, see :mod:`identify.arx`); :func:`grid_for_dead_time` extends its delays past a
long dead time. The model itself, its least-squares fit and the Steiglitz-McBride prefilter
live in :mod:`identify.arx`.

Numerics: the grid search accumulates per-sequence Gram matrices of all candidate columns
(backward-difference basis) once, so each (structure, fold) fit is a tiny solve.
"""

from __future__ import annotations

import itertools
import time
from dataclasses import dataclass, field
from math import comb
from typing import NamedTuple

import numpy as np
import pandas as pd
from scipy.signal import lfilter

from identify.arx import (
    FOCUS_MODES,
    MAX_CONDITION,
    ArxModel,
    as_sequences,
    check_initial,
    check_lengths,
    first_row,
    fit_arx,
    param_transform,
    prefiltered,
    stabilise,
)
from identify.kfold import assign_folds

__all__ = [
    "ArxGrid",
    "DEFAULT_GRID",
    "grid_for_dead_time",
    "StructureSelection",
    "select_structure",
    "TABLE_COLUMNS",
]

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


class ArxGrid(NamedTuple):
    """Candidate ARX orders: ``na_range`` poles, ``nb_range`` input terms, ``nk_range``
    delays (samples before the first input term, MATLAB's convention)."""

    na_range: range
    nb_range: range
    nk_range: range


#: The one default ARX grid (Table 2 and beyond): na 1-7, nb 1-4, nk 0-40 samples.
#: :func:`select_structure` and ``identify fit`` (:func:`identify.hybrid_fit.fit_hybrid`,
#: through :func:`grid_for_dead_time`) use it.
DEFAULT_GRID = ArxGrid(na_range=range(1, 8), nb_range=range(1, 5), nk_range=range(0, 41))


def grid_for_dead_time(dead_time_samples: int, grid: ArxGrid = DEFAULT_GRID) -> ArxGrid:
    """The grid with its delays extended to at least 9 samples past a dead time.

    The delay is found from the data, not assumed: the grid keeps every delay from its
    first one; only when the dead time is long (``dead_time_samples + 9`` beyond the grid's
    last delay) are further delays added.

    Parameters
    ----------
    dead_time_samples : int
        Trigger-to-piston dead time in samples (e.g. 220 µs / 10 µs = 22).
    grid : ArxGrid
        Grid to extend (default :data:`DEFAULT_GRID`).

    Returns
    -------
    ArxGrid
        ``grid`` with ``nk_range = range(first nk, max(last nk + 1, dead_time_samples + 10))``.
    """
    nk = grid.nk_range
    return grid._replace(nk_range=range(nk.start, max(nk.stop, int(dead_time_samples) + 10)))


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


def _sequence_folds(n_seq: int, folds: int, seed: int) -> tuple[np.ndarray, int, str]:
    """Sequence folds (:func:`identify.kfold.assign_folds`, contiguous layout) and their description."""
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
    fold_of, k = assign_folds(n_seq, k, seed, layout="contiguous")
    return fold_of, k, scheme


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
    starts = {s: first_row(*s, initial) for s in structures}
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
            if np.any(np.linalg.cond(Hs) > MAX_CONDITION**2):
                results[s] = None
                continue
            coef = np.linalg.solve(Hs, (g / d)[..., None])[..., 0] / d
            if (na, nb) not in transforms:
                transforms[na, nb] = param_transform(na, nb)
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
            T = param_transform(na, nb)
            rows = mask & (np.arange(n_max)[None, :] >= first_row(na, nb, nk, initial))
            sse_out = np.empty((n_folds, n_seq))
            ok = True
            for f in range(n_folds):
                a_filt = stabilise(np.asarray(a_start, dtype=float))
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
                    if np.linalg.cond(Hs) > MAX_CONDITION**2:
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
                    a_filt = stabilise(a_new)
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
    na_range=DEFAULT_GRID.na_range,
    nb_range=DEFAULT_GRID.nb_range,
    nk_range=DEFAULT_GRID.nk_range,
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
        Input (µm) and output (nl for drop volumes) samples from the trigger.
    na_range, nb_range, nk_range : iterable of int (or a single int)
        Candidate orders; ``nk`` in samples (MATLAB's convention). Default
        :data:`DEFAULT_GRID`.
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
    initial = check_initial(initial)
    if focus not in FOCUS_MODES:
        raise ValueError(f"focus must be one of {FOCUS_MODES}, got {focus!r}")
    seqs = as_sequences(sequences)
    na_list = _range_list(na_range, "na_range", 0)
    nb_list = _range_list(nb_range, "nb_range", 1)
    nk_list = _range_list(nk_range, "nk_range", 0)
    if not (np.isfinite(tolerance) and tolerance >= 0):
        raise ValueError(f"tolerance must be a finite number >= 0, got {tolerance!r}")
    if not (np.isfinite(absolute_tolerance_nl) and absolute_tolerance_nl >= 0):
        raise ValueError(f"absolute_tolerance_nl must be a finite number >= 0, got {absolute_tolerance_nl!r}")
    check_lengths(seqs, na_list[-1], nb_list[-1], nk_list[-1])
    fold_of, n_folds, scheme = _sequence_folds(len(seqs), folds, seed)
    member = np.zeros((n_folds, len(seqs)))  # training membership
    for f in range(n_folds):
        member[f, fold_of != f] = 1.0
    grid = _Grid(seqs, na_list, nb_list, nk_list, member, initial)
    if focus == "prediction":
        table = grid.table(grid.least_squares(seqs, grid.structures))
        table["refined"] = False
        prefilter = None
        decided = table
    else:
        table, decided, prefilter = _simulation_focus_search(grid, tolerance, absolute_tolerance_nl, max_refine)
    best, selected, threshold = _decide(decided, tolerance, absolute_tolerance_nl)
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


_NO_STRUCTURE = "no ARX structure of the grid could be fitted (all rank-deficient or divergent)"


@dataclass(frozen=True)
class _Grid:
    """The candidate structures of one search and the fold membership they are scored with."""

    seqs: list
    na_list: list
    nb_list: list
    nk_list: list
    member: np.ndarray
    initial: str

    @property
    def structures(self):
        return list(itertools.product(self.na_list, self.nb_list, self.nk_list))

    def least_squares(self, fit_seqs, structures):
        """Cross-validated SSE of plain LS fits on ``fit_seqs``, scored by simulation on the raw data."""
        return _grid_sse(fit_seqs, self.seqs, structures, self.nk_list, self.na_list[-1], self.nb_list[-1],
                         self.initial, self.member)

    def table(self, res, structures=None):
        return _table(res, self.structures if structures is None else structures, self.member, self.seqs)


def _decide(table, tolerance, absolute_tolerance_nl):
    """(best, selected, threshold RMSE) of a table sorted by ``val_rmse_nl`` (the selection rule above)."""
    finite = table[np.isfinite(table.val_rmse_nl)]
    if finite.empty:
        raise ValueError(_NO_STRUCTURE)
    b = finite.iloc[0]
    best_rmse = float(b.val_rmse_nl)
    threshold = best_rmse + max(tolerance * best_rmse, absolute_tolerance_nl)
    ok = finite[finite.val_rmse_nl <= threshold].copy()
    ok["n_params"] = ok.na + ok.nb
    s = ok.sort_values(["n_params", "val_rmse_nl", "na"], kind="stable").iloc[0]
    return (int(b.na), int(b.nb), int(b.nk)), (int(s.na), int(s.nb), int(s.nk)), threshold


def _simulation_focus_search(grid: _Grid, tolerance, absolute_tolerance_nl, max_refine):
    """Stages 0-2 of ``focus="simulation"``: (whole table, refined rows the decision uses, prefilter A)."""
    seqs, initial = grid.seqs, grid.initial
    # stage 0: delay scan at the largest orders (plain LS) -> reference -> prefilter
    scan = [s for s in grid.structures if s[0] == grid.na_list[-1] and s[1] == grid.nb_list[-1]]
    ref_structure = _decide(grid.table(grid.least_squares(seqs, scan), scan), tolerance, absolute_tolerance_nl)[0]
    prefilter = fit_arx(seqs, *ref_structure, initial=initial, focus="simulation").a
    # stage 1: full grid, LS on data prefiltered by the common 1/A_ref (screening)
    table = grid.table(grid.least_squares(prefiltered(seqs, prefilter), grid.structures))
    # stage 2: per-structure, per-fold Steiglitz-McBride re-scoring, simplest first
    finite = table[np.isfinite(table.val_rmse_nl)]
    if finite.empty:
        raise ValueError(_NO_STRUCTURE)
    refined_res = _refine_simplest_first(grid, finite, prefilter, tolerance, absolute_tolerance_nl, max_refine)
    refined = grid.table(refined_res, list(refined_res))
    refined["refined"] = True
    rest = table.merge(refined[["na", "nb", "nk"]], on=["na", "nb", "nk"], how="left", indicator=True)
    rest = rest[rest["_merge"] == "left_only"].drop(columns="_merge")
    rest["refined"] = False
    # the decision uses refined rows only (stage-1 rows are screening scores)
    table = pd.concat([refined, rest], ignore_index=True)
    table = table.sort_values(["refined", "val_rmse_nl", "na", "nb", "nk"], ascending=[False, True, True, True, True],
                              kind="stable").reset_index(drop=True)
    return table, refined.sort_values(["val_rmse_nl", "na", "nb", "nk"], kind="stable"), prefilter


def _refine_simplest_first(grid: _Grid, finite, prefilter, tolerance, absolute_tolerance_nl, max_refine):
    """Stage 2: Steiglitz-McBride CV scores of the screening's candidates, by complexity level."""
    loose = float(finite.val_rmse_nl.iloc[0]) * (1.0 + 3.0 * tolerance) + absolute_tolerance_nl
    nk_set = set(grid.nk_list)

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
            refined_res.update(_sm_cv_sse(grid.seqs, todo, grid.member, grid.initial, prefilter))

    refine([(int(r.na), int(r.nb), int(r.nk)) for r in finite.iloc[:3].itertuples()])
    pairs = sorted(itertools.product(grid.na_list, grid.nb_list), key=lambda p: (p[0] + p[1], p[0]))
    level_found = None
    for na, nb in pairs:
        if level_found is not None and na + nb > level_found:
            break
        refine(candidates_of(na, nb))
        cur = grid.table(refined_res, list(refined_res))
        _, sel, _ = _decide(cur, tolerance, absolute_tolerance_nl)
        if sel[0] + sel[1] <= na + nb:
            level_found = na + nb
        if len(refined_res) >= max_refine:
            break
    return refined_res
