"""Models of measured outputs on N named parameters from an end-point table (no time series).

A lab that sweeps its own waveform parameters (pulse voltages, lengths, delays) has a table: one
row per setting, the parameters in some columns and what was measured in others (a drop's head
volume, the number of drops). :func:`fit_table` builds, from such a table alone,

- for each **continuous output** (``head_volume_px3``): candidates from smooth surfaces (quadratic
  and cubic polynomials fitted with a Huber loss) to flexible ones (gradient-boosted trees with an
  absolute-error loss), chosen by K-fold cross-validation (smallest mean absolute error of the
  fitted scale); a positive output is fitted on its logarithm (multiplicative scatter). Gross
  outliers (a failed detection: axes of 0 or of 1,000 px) are treated robustly: the losses are
  robust (absolute error, Huber), and a value <= 0 of a positive output (log undefined) is left
  out of that output's fit by the rule :data:`POSITIVE_SHARE` states, counted in the notes; no row is
  ever removed by hand. Intervals at ``level`` (95 %):

  * one drop (prediction): split-conformal on the out-of-fold residuals, scaled locally
    (CV+, Barber et al. 2021, with normalised scores, Lei et al. 2018): a small model of the
    residuals' size ``s(x)`` (median absolute residual), cross-fitted so that the scores
    ``r / s(x)`` are honest; the interval is ``f(x) + [q_lo, q_hi] s(x)`` with ``q_lo``, ``q_hi``
    the empirical (level/2 and 1 - level/2, finite-sample corrected) quantiles of the scores. The
    quantiles are taken of the heavy-tailed real scatter itself (no normal law assumed), and the
    out-of-fold residuals come from models fitted on (K-1)/K of the rows: slightly conservative;
  * mean drop (confidence): the fit's own uncertainty, the delete-a-fold jackknife variance of
    the K fold models' predictions (``(K-1)/K sum (f_k - mean f_k)^2``), normal quantile. It holds
    no drop-to-drop scatter and no bias of the model form.

- for each **count output** (``n_drops``: non-negative integers with few distinct values): the
  probability of each count seen, as a continuation-ratio chain: ``P(n = k | n >= k)`` for the
  counts in increasing order, each a calibrated classifier (gradient-boosted trees with isotonic
  calibration by cross-validation, or a quadratic logistic regression: chosen by the K-fold Brier
  score) where both sides hold at least :data:`MIN_CLASS_ROWS` rows, else a constant (the
  smoothed rate). The largest count seen stands for "that many or more".

- the **training region**: each input's min..max seen, and the distance (in grid steps: each
  input divided by the median spacing of its distinct values) from a row to the nearest training
  row, at most the largest such distance between training rows (leave-one-out). A row outside
  is flagged with the reason (``outside_training_region``, ``outside_training_region_why``); its
  numbers are still given (trees extrapolate flat: unchecked there).

The model file (:data:`SCHEMA`, JSON) holds the training rows, the settings, the seeds, the
chosen candidates and the conformal quantiles; it holds no pickled object (loading a pickle runs
code). Loading it refits the chosen models deterministically from the stored rows (the cost: about
the final fits of :func:`fit_table` without its candidate search, a few seconds for 1,400 rows)
and checks that the refit reproduces the predictions saved with it
(:class:`RefitMismatchWarning` otherwise, e.g. another scikit-learn version).
"""

from __future__ import annotations

import hashlib
import json
import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from dvcore import schema
from identify.kfold import group_ids
from dvcore.errors import ParameterError

__all__ = [
    "SCHEMA", "TabularError", "RefitMismatchWarning", "TabularModel", "fit_table", "read_table",
    "REGRESSORS", "CLASSIFIERS", "output_kind",
]

#: Schema id of the model file (its keys: ``dvcore.schema.TABULAR_MODEL``).
SCHEMA = schema.TABULAR_MODEL.schema
#: A column of non-negative integers with at most this many distinct values is a count output.
MAX_COUNT_CLASSES = 12
#: A continuation step ``P(n = k | n >= k)`` is a classifier only where both sides hold this many
#: rows; else the smoothed rate ``(hits + 1/2) / (rows + 1)``.
MIN_CLASS_ROWS = 30
#: A continuous output is fitted on its logarithm when at least this share of its finite values
#: is > 0; its values <= 0 are then gross outliers (no logarithm), left out of its fit.
POSITIVE_SHARE = 0.9
#: Fewest rows with a measured value an output is fitted on.
MIN_ROWS = 20
#: Rows of the training table whose predictions are saved to check the refit at load.
CHECK_ROWS = 40
#: Largest relative difference between the saved and the refitted check predictions.
CHECK_RTOL = 1e-6


class TabularError(ValueError):
    """A table or a tabular model file that cannot be used (the message names the file)."""


class TabularParameterError(TabularError, ParameterError):
    """A bad parameter value of a table model's design or tuning: a `TabularError` said in Python
    terms (`dvcore.errors.ParameterError`; the command line writes the option's name)."""


class RefitMismatchWarning(UserWarning):
    """A model file refitted at load does not reproduce the predictions saved with it."""


# ----------------------------------------------------------------------------- candidates
def _huber_poly(degree: int, seed: int):
    from sklearn.compose import TransformedTargetRegressor
    from sklearn.linear_model import HuberRegressor
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import PolynomialFeatures, StandardScaler

    # the target standardised too: the solver converges in a fraction of the iterations
    return TransformedTargetRegressor(make_pipeline(StandardScaler(), PolynomialFeatures(degree), StandardScaler(),
                                                    HuberRegressor(alpha=1e-4, max_iter=5000)),
                                      transformer=StandardScaler())


def _trees_l1(leaves: int, min_leaf: int, seed: int):
    from sklearn.ensemble import HistGradientBoostingRegressor

    return HistGradientBoostingRegressor(loss="absolute_error", learning_rate=0.1, max_iter=300,
                                         max_leaf_nodes=leaves, min_samples_leaf=min_leaf,
                                         early_stopping=False, random_state=seed)


#: Regression candidates, name -> factory(seed), from smooth to flexible.
REGRESSORS = {
    "quadratic_huber": lambda seed: _huber_poly(2, seed),
    "cubic_huber": lambda seed: _huber_poly(3, seed),
    "boosted_trees_l1": lambda seed: _trees_l1(15, 10, seed),
    "boosted_trees_l1_large": lambda seed: _trees_l1(31, 8, seed),
}


def _scale_model(n: int, seed: int):
    """The model of the residuals' size: median absolute residual on the inputs, shallow trees."""
    from sklearn.ensemble import HistGradientBoostingRegressor

    return HistGradientBoostingRegressor(loss="absolute_error", learning_rate=0.1, max_iter=50,
                                         max_leaf_nodes=7, min_samples_leaf=max(20, n // 20),
                                         early_stopping=False, random_state=seed)


def _calibrated_trees(min_leaf: int, seed: int, folds: int):
    from sklearn.calibration import CalibratedClassifierCV
    from sklearn.ensemble import HistGradientBoostingClassifier
    from sklearn.model_selection import StratifiedKFold

    base = HistGradientBoostingClassifier(min_samples_leaf=min_leaf, early_stopping=False, random_state=seed)
    return CalibratedClassifierCV(base, method="isotonic",
                                  cv=StratifiedKFold(folds, shuffle=True, random_state=seed))


def _quadratic_logistic(seed: int, folds: int):
    from sklearn.linear_model import LogisticRegression
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import PolynomialFeatures, StandardScaler

    return make_pipeline(StandardScaler(), PolynomialFeatures(2), StandardScaler(),
                         LogisticRegression(max_iter=5000))


#: Classifier candidates of one continuation step, name -> factory(seed, folds).
CLASSIFIERS = {
    "quadratic_logistic": _quadratic_logistic,
    "boosted_trees_isotonic": lambda seed, folds: _calibrated_trees(20, seed, folds),
    "boosted_trees_small_leaves_isotonic": lambda seed, folds: _calibrated_trees(10, seed, folds),
}


def _one_thread():
    """OpenMP limited to one thread while fitting and predicting: on a table of thousands of rows
    the threads of the tree ensembles cost more than they save (and spin on a busy machine)."""
    import sklearn.ensemble  # noqa: F401 - loads the OpenMP runtime first: a limit reaches only those loaded
    from threadpoolctl import threadpool_limits

    return threadpool_limits(limits=1, user_api="openmp")


def _fit_quietly(model, X, y, notes: list | None = None, what: str = ""):
    """Fit ``model``; a convergence warning of a candidate becomes a note (it is judged by CV)."""
    from sklearn.exceptions import ConvergenceWarning

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ConvergenceWarning)
        model.fit(X, y)
    for w in caught:
        if issubclass(w.category, ConvergenceWarning):
            if notes is not None and what and f"{what}: did not converge" not in notes:
                notes.append(f"{what}: did not converge")
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return model


# ----------------------------------------------------------------------------- reading
#: The table of a `dropvision campaign` dataset folder that :func:`read_table` reads: its shot
#: folders' rows, one per image, the labels as columns (`dvcore.schema.DATASET_SHOTS`).
SHOT_TABLE = "shots.parquet"


def read_table(path) -> pd.DataFrame:
    """Read a CSV or Parquet table, or the shot table of a campaign dataset folder.

    Parameters
    ----------
    path : str or Path
        ``*.csv`` (comma-separated, a header row) or ``*.parquet`` / ``*.pq``; or a dataset
        folder written by ``dropvision campaign`` over shot folders: its :data:`SHOT_TABLE`
        (one row per image: ``drop_volume_nl``, ``n_satellites``, ... and the shots' labels, e.g.
        ``V1``, ``w1``, as columns).

    Returns
    -------
    pandas.DataFrame

    Raises
    ------
    TabularError
        Not found, another format, unreadable or empty, a folder without a shot table (one line
        naming the file).
    """
    path = Path(path)
    if path.is_dir():
        if not (path / SHOT_TABLE).is_file():
            raise TabularError(f"{path}: a folder: a table is a .csv or .parquet file, or a campaign dataset folder "
                               f"holding {SHOT_TABLE} (dropvision campaign over shot folders); this one has none")
        path = path / SHOT_TABLE
    if not path.is_file():
        raise TabularError(f"{path}: table not found" if not path.exists() else f"{path}: not a file")
    suffix = path.suffix.lower()
    try:
        if suffix == ".csv":
            df = pd.read_csv(path)
        elif suffix in (".parquet", ".pq"):
            df = pd.read_parquet(path)
        else:
            raise TabularError(f"{path}: a table must be .csv or .parquet, got {suffix or 'no suffix'!r}")
    except TabularError:
        raise
    except (ValueError, OSError, UnicodeError, pd.errors.ParserError) as exc:
        raise TabularError(f"{path}: cannot read the table ({' '.join(str(exc).split())})") from None
    except Exception as exc:  # noqa: BLE001 - pyarrow's own errors: a corrupt file is the input's fault
        raise TabularError(f"{path}: cannot read the table ({type(exc).__name__}: {' '.join(str(exc).split())})") from None
    if len(df) == 0:
        raise TabularError(f"{path}: the table has no rows")
    if not isinstance(df.index, pd.RangeIndex):  # a Parquet file's stored index: kept as column(s)
        df = df.reset_index()
    return df.reset_index(drop=True)


def _columns(df: pd.DataFrame, names, source, what: str, *, finite: bool) -> np.ndarray:
    """The columns ``names`` of ``df`` as a float array (rows x names)."""
    missing = [n for n in names if n not in df.columns]
    if missing:
        raise TabularError(f"{source}: no {what} column {missing[0]!r} (columns: {', '.join(map(str, df.columns[:20]))})")
    out = np.empty((len(df), len(names)))
    for j, n in enumerate(names):
        col = df[n]
        if col.dtype == bool or not (pd.api.types.is_numeric_dtype(col) or col.isna().all()):
            raise TabularError(f"{source}: {what} column {n!r} is not numeric (dtype {col.dtype})")
        out[:, j] = col.to_numpy(dtype=float, na_value=np.nan)
        if finite and not np.isfinite(out[:, j]).all():
            bad = np.flatnonzero(~np.isfinite(out[:, j]))
            raise TabularError(f"{source}: {what} column {n!r} is missing or not finite in {bad.size} row(s) "
                               f"(first: row {int(bad[0]) + 1} of the data)")
        if np.isinf(out[:, j]).any():
            raise TabularError(f"{source}: {what} column {n!r} holds infinite values")
    return out


def output_kind(values: np.ndarray) -> str:
    """``"count"`` for non-negative integers with at most :data:`MAX_COUNT_CLASSES` distinct
    values, else ``"continuous"`` (NaN ignored)."""
    v = values[np.isfinite(values)]
    if v.size and np.all(v >= 0) and np.all(v == np.round(v)) and np.unique(v).size <= MAX_COUNT_CLASSES:
        return "count"
    return "continuous"


# ----------------------------------------------------------------------------- region
@dataclass
class TrainingRegion:
    """Where the model has seen data: each input's range, and the nearest-row distance.

    Attributes
    ----------
    inputs : list of str
    low, high : numpy.ndarray
        Each input's smallest and largest training value.
    step : numpy.ndarray
        Each input's grid step: the median spacing of its distinct training values (1 for an
        input with one value: any other value is outside its range anyway).
    max_gap : float
        The largest distance, in steps, from a training row to its nearest other training row:
        a row farther than this from every training row is outside.
    """

    inputs: list
    low: np.ndarray
    high: np.ndarray
    step: np.ndarray
    max_gap: float

    @classmethod
    def of(cls, inputs, X: np.ndarray) -> "TrainingRegion":
        from scipy.spatial import cKDTree

        step = np.ones(X.shape[1])
        for j in range(X.shape[1]):
            u = np.unique(X[:, j])
            if u.size > 1:
                step[j] = float(np.median(np.diff(u)))
        Z = X / step
        gap = 0.0
        if len(Z) > 1:
            d, _ = cKDTree(Z).query(Z, k=2)
            gap = float(np.max(d[:, 1]))
        return cls(list(inputs), X.min(axis=0), X.max(axis=0), step, gap)

    def check(self, X: np.ndarray, X_train: np.ndarray) -> tuple[np.ndarray, list]:
        """Flags and reasons (``""`` inside) for the rows of ``X``."""
        from scipy.spatial import cKDTree

        why = [[] for _ in range(len(X))]
        for j, name in enumerate(self.inputs):
            for i in np.flatnonzero(X[:, j] < self.low[j]):
                why[i].append(f"{name}={X[i, j]:g} < {self.low[j]:g} (min seen)")
            for i in np.flatnonzero(X[:, j] > self.high[j]):
                why[i].append(f"{name}={X[i, j]:g} > {self.high[j]:g} (max seen)")
        d, _ = cKDTree(X_train / self.step).query(X / self.step, k=1)
        tol = 1e-9 * max(1.0, self.max_gap)
        for i in np.flatnonzero(d > self.max_gap + tol):
            why[i].append(f"{d[i]:.3g} grid steps from the nearest training row (at most {self.max_gap:.3g} "
                          "between training rows)")
        flags = np.array([bool(w) for w in why])
        return flags, ["; ".join(w) for w in why]

    def to_dict(self) -> dict:
        return {"low": self.low.tolist(), "high": self.high.tolist(), "step": self.step.tolist(),
                "max_gap_steps": self.max_gap}


# ----------------------------------------------------------------------------- continuous output
def _conformal_quantiles(scores: np.ndarray, level: float) -> tuple[float, float]:
    """Finite-sample lower/upper quantiles of the scores (split-conformal ranks)."""
    s = np.sort(scores)
    n = s.size
    alpha = 1.0 - level
    k_lo = math.floor((n + 1) * alpha / 2)
    k_hi = math.ceil((n + 1) * (1 - alpha / 2))
    lo = -math.inf if k_lo < 1 else float(s[k_lo - 1])
    hi = math.inf if k_hi > n else float(s[k_hi - 1])
    return lo, hi


def _folds(X: np.ndarray, folds: int, seed: int, name: str):
    """K-fold splits of the rows of ``X`` that never split a setting: the settings (rows of
    ``X``, :func:`identify.kfold.group_ids`) are shuffled into folds by scikit-learn's ``KFold``,
    and each row goes where its setting went. Where no setting repeats this is ``KFold`` over
    the rows itself (the same splits, so a saved model refits as before); where one does, its
    rows are all held out together (a repeat in the training folds would make the out-of-fold
    errors, and the intervals calibrated on them, optimistic)."""
    from sklearn.model_selection import KFold

    ids, n_settings = group_ids(X)
    if n_settings < folds:
        raise TabularError(f"{name}: only {n_settings} distinct setting(s) of the inputs (at least {folds} for "
                           f"{folds}-fold cross-validation)")
    rows = np.arange(ids.size)
    return [(rows[np.isin(ids, tr)], rows[np.isin(ids, te)])
            for tr, te in KFold(folds, shuffle=True, random_state=seed).split(np.zeros(n_settings))]


@dataclass
class _Continuous:
    """One continuous output fitted: the chosen model, its fold models and the scale model."""

    name: str
    log: bool
    candidate: str
    rows: np.ndarray  # indices of the training rows used (finite, and > 0 when log)
    final: object
    fold_models: list
    scale: object
    floor: float
    q_lo: float
    q_hi: float
    cv: dict = field(default_factory=dict)


def _fit_continuous(name, X, y_raw, *, candidates, folds, seed, level, notes, q=None) -> _Continuous:
    """Fit one continuous output (candidates by CV when ``q`` is None, else the stored choice)."""
    finite = np.isfinite(y_raw)
    pos = finite & (y_raw > 0)
    log = finite.any() and pos.sum() >= POSITIVE_SHARE * finite.sum()
    rows = np.flatnonzero(pos if log else finite)
    if log and (finite.sum() - pos.sum()) and q is None:
        notes.append(f"{name}: {int(finite.sum() - pos.sum())} row(s) <= 0 of a positive output left out of its fit "
                     f"(a failed measurement, no logarithm; rule identify.tabular.POSITIVE_SHARE)")
    if rows.size < max(MIN_ROWS, 2 * folds):
        raise TabularError(f"{name}: only {rows.size} row(s) with a measured value (at least "
                           f"{max(MIN_ROWS, 2 * folds)} for {folds}-fold cross-validation)")
    Xo, yo = X[rows], (np.log(y_raw[rows]) if log else y_raw[rows])
    splits = _folds(Xo, folds, seed, name)
    cv = {}
    best = oof_best = fold_best = None
    for cand in ([q["candidate"]] if q is not None else candidates):
        oof = np.empty(rows.size)
        fold_models = []
        for tr, te in splits:
            m = _fit_quietly(REGRESSORS[cand](seed), Xo[tr], yo[tr], notes, f"{name}: {cand}")
            oof[te] = m.predict(Xo[te])
            fold_models.append(m)
        r = yo - oof
        rel = np.abs(np.expm1(-r)) * 100 if log else np.abs(r) / max(np.median(np.abs(yo)), 1e-300) * 100
        cv[cand] = {"mean_abs_error": float(np.mean(np.abs(r))), "median_error_percent": float(np.median(rel)),
                    "p90_error_percent": float(np.percentile(rel, 90))}
        if best is None or cv[cand]["mean_abs_error"] < cv[best]["mean_abs_error"]:
            best, oof_best, fold_best = cand, oof, fold_models
    chosen = best
    r = yo - oof_best
    a = np.abs(r)
    floor = max(0.25 * float(np.median(a)), 1e-12)
    scale = _fit_quietly(_scale_model(rows.size, seed), Xo, a)
    if q is None:  # scores with a cross-fitted scale: honest quantiles
        s_oof = np.empty(rows.size)
        for tr, te in splits:
            s_oof[te] = np.maximum(_fit_quietly(_scale_model(tr.size, seed), Xo[tr], a[tr]).predict(Xo[te]), floor)
        scores = r / s_oof
        q_lo, q_hi = _conformal_quantiles(scores, level)
        if not (math.isfinite(q_lo) and math.isfinite(q_hi)):
            q_lo, q_hi = (q_lo if math.isfinite(q_lo) else float(scores.min()),
                          q_hi if math.isfinite(q_hi) else float(scores.max()))
            notes.append(f"{name}: {rows.size} rows are too few for a finite {100 * level:g} % conformal bound "
                         f"(at least {math.ceil(2 / (1 - level)) - 1}): the most extreme residual is used, the "
                         "one-drop interval may cover less")
    else:
        q_lo, q_hi = q["q_lo"], q["q_hi"]
    final = _fit_quietly(REGRESSORS[chosen](seed), Xo, yo, notes, f"{name}: {chosen}")
    return _Continuous(name, bool(log), chosen, rows, final, fold_best, scale, floor, q_lo, q_hi, cv)


def _predict_continuous(c: _Continuous, X: np.ndarray, level: float) -> dict:
    from scipy.stats import norm

    f = c.final.predict(X)
    s = np.maximum(c.scale.predict(X), c.floor)
    fk = np.array([m.predict(X) for m in c.fold_models])
    K = fk.shape[0]
    sd = np.sqrt((K - 1) / K * np.sum((fk - fk.mean(axis=0)) ** 2, axis=0))
    z = norm.ppf(0.5 + level / 2)
    back = np.exp if c.log else (lambda v: v)
    return {f"{c.name}_mean": back(f),
            f"{c.name}_mean_drop_low": back(f - z * sd), f"{c.name}_mean_drop_high": back(f + z * sd),
            f"{c.name}_one_drop_low": back(f + c.q_lo * s), f"{c.name}_one_drop_high": back(f + c.q_hi * s)}


# ----------------------------------------------------------------------------- count output
@dataclass
class _Step:
    """``P(n = k | n >= k)``: a classifier, or a constant rate."""

    k: int
    candidate: str | None
    model: object
    rate: float
    cv: dict = field(default_factory=dict)

    def predict(self, X):
        if self.model is None:
            return np.full(len(X), self.rate)
        return self.model.predict_proba(X)[:, 1]


@dataclass
class _Count:
    name: str
    classes: list
    steps: list


def _stratified_folds(X: np.ndarray, hit: np.ndarray, folds: int, seed: int):
    """Stratified K-fold splits of the rows of ``X`` (classes ``hit``) that never split a setting:
    scikit-learn's ``StratifiedKFold`` where no setting repeats (the splits saved models were fitted
    with), ``StratifiedGroupKFold`` over the settings where one does (see :func:`_folds`)."""
    from sklearn.model_selection import StratifiedGroupKFold, StratifiedKFold

    ids, n_settings = group_ids(X)
    if n_settings == ids.size:
        return list(StratifiedKFold(folds, shuffle=True, random_state=seed).split(X, hit))
    return list(StratifiedGroupKFold(folds, shuffle=True, random_state=seed).split(X, hit, groups=ids))


def _fit_count(name, X, y_raw, *, folds, seed, notes, chosen=None, classifiers=None) -> _Count:
    ok = np.isfinite(y_raw)
    X, y = X[ok], y_raw[ok].astype(int)
    if y.size < max(MIN_ROWS, 2 * folds):
        raise TabularError(f"{name}: only {y.size} row(s) with a measured count (at least "
                           f"{max(MIN_ROWS, 2 * folds)} for {folds}-fold cross-validation)")
    classes = sorted(int(v) for v in np.unique(y))
    steps = []
    for j, k in enumerate(classes[:-1]):
        at = y >= k
        hit = (y[at] == k).astype(int)
        n_hit, n_miss = int(hit.sum()), int(at.sum() - hit.sum())
        rate = (n_hit + 0.5) / (at.sum() + 1.0)
        if min(n_hit, n_miss) < MIN_CLASS_ROWS:
            steps.append(_Step(k, None, None, float(rate)))
            continue
        Xs = X[at]
        cv = {}
        pick = chosen[j] if chosen is not None and j < len(chosen) else None
        if pick is None:
            splits = _stratified_folds(Xs, hit, folds, seed)
            for cand in classifiers or CLASSIFIERS:
                make = CLASSIFIERS[cand]
                p = np.empty(hit.size)
                for tr, te in splits:
                    p[te] = _fit_quietly(make(seed, folds), Xs[tr], hit[tr], notes,
                                         f"{name}: P(n={k} | n>={k}) {cand}").predict_proba(Xs[te])[:, 1]
                cv[cand] = {"brier": float(np.mean((p - hit) ** 2))}
            pick = min(cv, key=lambda c: cv[c]["brier"])
        model = _fit_quietly(CLASSIFIERS[pick](seed, folds), Xs, hit, notes, f"{name}: P(n={k} | n>={k}) {pick}")
        steps.append(_Step(k, pick, model, float(rate), cv))
    return _Count(name, classes, steps)


def _predict_count(c: _Count, X) -> dict:
    left = np.ones(len(X))
    out = {}
    for st in c.steps:
        h = np.clip(st.predict(X), 0.0, 1.0)
        out[f"{c.name}_p{st.k}"] = left * h
        left = left * (1.0 - h)
    out[f"{c.name}_p{c.classes[-1]}"] = left
    return out


# ----------------------------------------------------------------------------- the model
class TabularModel:
    """Models of a table's outputs on its input parameters (:func:`fit_table`).

    Attributes
    ----------
    inputs, outputs : list of str
    kinds : dict
        Output -> ``"continuous"`` or ``"count"``.
    region : TrainingRegion
    notes : list of str
        What the fit left out or noticed (rows <= 0, candidates that did not converge).
    """

    def __init__(self, inputs, outputs, data: pd.DataFrame, *, folds: int, seed: int, level: float,
                 continuous: dict, counts: dict, notes: list, source: str | None = None):
        self.inputs = list(inputs)
        self.outputs = list(outputs)
        self.data = data
        self.folds, self.seed, self.level = folds, seed, level
        self.continuous, self.counts = continuous, counts
        self.kinds = {o: ("count" if o in counts else "continuous") for o in self.outputs}
        self.notes = notes
        self.source = source
        self._X = data[self.inputs].to_numpy(float)
        self.region = TrainingRegion.of(self.inputs, self._X)

    # ------------------------------------------------------------------ predictions
    def predict(self, table, source="the table") -> pd.DataFrame:
        """Predictions for each row of ``table``.

        Parameters
        ----------
        table : pandas.DataFrame
            Must hold every input column (numeric, finite); other columns are ignored.
        source : str
            Named in errors.

        Returns
        -------
        pandas.DataFrame
            One row per input row, in order: per continuous output ``<o>_mean`` (the fitted
            typical value: the median drop, the exponential of the log fit for a positive
            output), ``<o>_mean_drop_low/high`` (confidence, at ``level``),
            ``<o>_one_drop_low/high`` (one drop, at ``level``); per count output
            ``<o>_p<k>`` (the probability of k, the largest k seen meaning k or more); then
            ``outside_training_region`` (bool) and ``outside_training_region_why`` ("" inside).
        """
        X = _columns(table, self.inputs, source, "input", finite=True)
        out = {}
        with _one_thread():
            for o in self.outputs:
                if o in self.continuous:
                    out.update(_predict_continuous(self.continuous[o], X, self.level))
                else:
                    out.update(_predict_count(self.counts[o], X))
        flags, why = self.region.check(X, self._X)
        out["outside_training_region"] = flags
        out["outside_training_region_why"] = why
        return pd.DataFrame(out, index=table.index if isinstance(table, pd.DataFrame) else None)

    def training_inputs(self) -> np.ndarray:
        """The training rows' inputs (rows x inputs, a copy)."""
        return self._X.copy()

    def fitted_scale(self, output: str, X: np.ndarray) -> dict:
        """A continuous output on its fitted scale (the logarithm of a positive output) at the rows
        of ``X`` (rows x inputs): ``fit``, ``scale`` (the local median absolute residual, floored)
        and ``fit_std`` (the jackknife standard deviation of the fold models); ``log``."""
        c = self.continuous[output]
        with _one_thread():
            f = c.final.predict(X)
            s = np.maximum(c.scale.predict(X), c.floor)
            fk = np.array([m.predict(X) for m in c.fold_models])
        K = fk.shape[0]
        sd = np.sqrt((K - 1) / K * np.sum((fk - fk.mean(axis=0)) ** 2, axis=0))
        return {"fit": f, "scale": s, "fit_std": sd, "log": c.log, "q_lo": c.q_lo, "q_hi": c.q_hi}

    def count_probabilities(self, output: str, X: np.ndarray) -> dict:
        """``{"<output>_p<k>": P(k)}`` of a count output at the rows of ``X`` (rows x inputs)."""
        with _one_thread():
            return _predict_count(self.counts[output], X)

    def cv_table(self) -> pd.DataFrame:
        """The cross-validation scores of every candidate (one row per output, step and candidate)."""
        rows = []
        for o, c in self.continuous.items():
            for cand, s in c.cv.items():
                rows.append({"output": o, "model": cand, "chosen": cand == c.candidate, **s})
        for o, c in self.counts.items():
            for st in c.steps:
                what = f"{o}: P(n={st.k} | n>={st.k})"
                if st.model is None:
                    rows.append({"output": what, "model": f"constant {st.rate:.4g}", "chosen": True})
                for cand, s in st.cv.items():
                    rows.append({"output": what, "model": cand, "chosen": cand == st.candidate, **s})
        return pd.DataFrame(rows)

    # ------------------------------------------------------------------ file
    def to_dict(self) -> dict:
        """The model file's content (:data:`SCHEMA`): training rows, settings, choices, checks."""
        from dvcore.versions import software_versions

        cols = self.inputs + self.outputs
        data = {c: [None if not np.isfinite(v) else float(v) for v in self.data[c].to_numpy(float)] for c in cols}
        check_rows = self.data.iloc[:CHECK_ROWS]
        pred = self.predict(check_rows)
        check = {c: pred[c].astype(float).tolist() for c in pred.columns if c != "outside_training_region_why"}
        return {
            "schema": SCHEMA,
            "inputs": self.inputs,
            "outputs": self.outputs,
            "kinds": self.kinds,
            "settings": {"folds": self.folds, "seed": self.seed, "level": self.level},
            "training_rows": len(self.data),
            "training_sha256": _data_hash(data),
            "training_source": self.source,
            "training_data": data,
            "continuous": {o: {"candidate": c.candidate, "log": c.log, "q_lo": c.q_lo, "q_hi": c.q_hi,
                               "rows_fitted": int(c.rows.size), "cv": c.cv}
                           for o, c in self.continuous.items()},
            "counts": {o: {"classes": c.classes,
                           "steps": [{"k": st.k, "model": st.candidate, "rate": st.rate, "cv": st.cv} for st in c.steps]}
                       for o, c in self.counts.items()},
            "training_region": self.region.to_dict(),
            "check": {"rows": len(check_rows), "predictions": check},
            "notes": self.notes,
            "versions": software_versions() | {"scikit-learn": _sklearn_version()},
        }

    def save(self, path) -> Path:
        """Write the model file atomically."""
        from dvcore.atomic import write_json

        return write_json(path, self.to_dict())

    @classmethod
    def from_json(cls, path) -> "TabularModel":
        """Read a model file and refit it from its stored rows (see the module docstring).

        Raises
        ------
        TabularError
            Unreadable, another schema, or a key of the wrong type or range (naming the key).
        """
        from dvcore.jsonio import load_json_hardened

        path = Path(path)
        if not path.is_file():
            raise TabularError(f"{path}: model file not found")
        return cls.from_dict(load_json_hardened(path, TabularError), source=str(path))

    @classmethod
    def from_dict(cls, d: dict, source="model") -> "TabularModel":
        """Validate ``d`` (:meth:`to_dict`'s form), refit, and check the refit."""
        def bad(key, problem):
            return TabularError(f"{source}: invalid tabular model file: {key} {problem}")

        if d.get("schema") != SCHEMA:
            raise bad("schema", f"is {d.get('schema')!r}, expected {SCHEMA!r}")
        try:
            schema.check_document(d, schema.TABULAR_MODEL, source)
        except schema.SchemaError as exc:
            raise TabularError(str(exc)) from None
        names = {}
        for key in ("inputs", "outputs"):
            v = d.get(key)
            if not isinstance(v, list) or not v or not all(isinstance(s, str) and s for s in v):
                raise bad(key, "must be a non-empty list of names")
            names[key] = v
        inputs, outputs = names["inputs"], names["outputs"]
        if len(set(inputs + outputs)) != len(inputs) + len(outputs):
            raise bad("inputs/outputs", "repeat a name")
        st = d.get("settings")
        if not isinstance(st, dict):
            raise bad("settings", "must be an object")
        folds, seed, level = st.get("folds"), st.get("seed"), st.get("level")
        if not _is_int(folds) or not 2 <= folds <= 50:
            raise bad("settings.folds", f"must be an integer in 2..50, got {folds!r}")
        if not _is_int(seed) or not 0 <= seed < 2 ** 32:
            raise bad("settings.seed", f"must be an integer in 0..2**32-1, got {seed!r}")
        if not _is_num(level) or not 0 < level < 1:
            raise bad("settings.level", f"must be a number in (0, 1), got {level!r}")
        data = d.get("training_data")
        if not isinstance(data, dict) or set(data) != set(inputs + outputs):
            raise bad("training_data", "must hold one list per input and output")
        n = d.get("training_rows")
        if not _is_int(n) or n < MIN_ROWS:
            raise bad("training_rows", f"must be an integer >= {MIN_ROWS}, got {n!r}")
        for c, v in data.items():
            if not isinstance(v, list) or len(v) != n:
                raise bad(f"training_data.{c}", f"must be a list of {n} values")
            if not all(x is None or _is_num(x) for x in v) or (c in inputs and None in v):
                raise bad(f"training_data.{c}", "must hold numbers (null only in outputs)")
        if d.get("training_sha256") != _data_hash(data):
            raise bad("training_data", "does not match training_sha256 (edited after it was written?)")
        frame = pd.DataFrame({c: np.array([np.nan if x is None else x for x in data[c]], float) for c in data})
        cont, counts = d.get("continuous"), d.get("counts")
        kinds = d.get("kinds")
        if not isinstance(cont, dict) or not isinstance(counts, dict) or not isinstance(kinds, dict):
            raise bad("continuous/counts/kinds", "must be objects")
        if set(cont) | set(counts) != set(outputs) or set(cont) & set(counts):
            raise bad("continuous/counts", "must name each output once")
        choices = {}
        for o, c in cont.items():
            if not isinstance(c, dict) or c.get("candidate") not in REGRESSORS:
                raise bad(f"continuous.{o}.candidate", f"must be one of {', '.join(REGRESSORS)}")
            for q in ("q_lo", "q_hi"):
                if not _is_num(c.get(q)):
                    raise bad(f"continuous.{o}.{q}", "must be a finite number")
            if c["q_lo"] > c["q_hi"]:
                raise bad(f"continuous.{o}", "q_lo must be <= q_hi")
            choices[o] = {"candidate": c["candidate"], "q_lo": float(c["q_lo"]), "q_hi": float(c["q_hi"])}
        for o, c in counts.items():
            steps = c.get("steps") if isinstance(c, dict) else None
            if not isinstance(steps, list) or not all(isinstance(s, dict) for s in steps):
                raise bad(f"counts.{o}.steps", "must be a list of objects")
            for s in steps:
                if s.get("model") is not None and s.get("model") not in CLASSIFIERS:
                    raise bad(f"counts.{o}.steps.model", f"must be null or one of {', '.join(CLASSIFIERS)}")
            choices[o] = [s.get("model") for s in steps]
        model = _build(inputs, outputs, frame, folds=folds, seed=seed, level=level, source=d.get("training_source"),
                       choices=choices)
        for o, c in counts.items():
            if len(model.counts[o].steps) != len(c["steps"]):
                raise bad(f"counts.{o}.steps", "do not match the stored counts")
        model.notes = [str(x) for x in d.get("notes", [])] if isinstance(d.get("notes"), list) else []
        saved = d.get("versions") if isinstance(d.get("versions"), dict) else {}
        _check_refit(model, d.get("check"), source, saved)
        return model


def _is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_num(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _data_hash(data: dict) -> str:
    return hashlib.sha256(json.dumps(data, sort_keys=True, allow_nan=False).encode()).hexdigest()


def _sklearn_version() -> str:
    import sklearn

    return sklearn.__version__


def _check_refit(model: TabularModel, check, source, saved_versions: dict) -> None:
    if not isinstance(check, dict) or not isinstance(check.get("predictions"), dict):
        raise TabularError(f"{source}: invalid tabular model file: check must hold the saved predictions")
    rows = check.get("rows")
    if not _is_int(rows) or not 0 < rows <= min(CHECK_ROWS, len(model.data)):
        raise TabularError(f"{source}: invalid tabular model file: check.rows {rows!r}")
    now = model.predict(model.data.iloc[:rows])
    worst, where = 0.0, None
    for c in now.columns:
        if c == "outside_training_region_why":
            continue
        saved = check["predictions"].get(c)
        if not isinstance(saved, list) or len(saved) != rows or not all(_is_num(v) for v in saved):
            raise TabularError(f"{source}: invalid tabular model file: check.predictions.{c} must be {rows} numbers")
        a, b = now[c].to_numpy(float), np.array(saved, float)
        dev = float(np.max(np.abs(a - b) / np.maximum(np.abs(b), 1e-12)))
        if dev > worst:
            worst, where = dev, c
    if worst > CHECK_RTOL:
        from dvcore import __version__

        then = f"scikit-learn {saved_versions.get('scikit-learn', '?')}, dropvision {saved_versions.get('dropvision', '?')}"
        warnings.warn(f"{source}: the model refitted from its stored rows differs from the saved predictions by up "
                      f"to {worst:.2g} (relative, {where}): fitted with {then}, refitted with scikit-learn "
                      f"{_sklearn_version()}, dropvision {__version__} (another version fits differently; refit "
                      "the model to save predictions of this one)", RefitMismatchWarning, stacklevel=3)


def _build(inputs, outputs, frame, *, folds, seed, level, source, choices=None, candidates=None,
           classifiers=None) -> TabularModel:
    X = frame[inputs].to_numpy(float)
    notes: list = []
    continuous, counts = {}, {}
    with _one_thread():
        for o in outputs:
            y = frame[o].to_numpy(float)
            is_count = isinstance(choices[o], list) if choices is not None else output_kind(y) == "count"
            if is_count:
                counts[o] = _fit_count(o, X, y, folds=folds, seed=seed, notes=notes,
                                       chosen=None if choices is None else choices[o], classifiers=classifiers)
            else:
                continuous[o] = _fit_continuous(o, X, y, candidates=candidates or list(REGRESSORS), folds=folds,
                                                seed=seed, level=level, notes=notes,
                                                q=None if choices is None else choices[o])
    return TabularModel(inputs, outputs, frame, folds=folds, seed=seed, level=level, continuous=continuous,
                        counts=counts, notes=notes, source=source)


def fit_table(table: pd.DataFrame, inputs, outputs, *, folds: int = 5, seed: int = 0, level: float = 0.95,
              candidates=None, classifiers=None, source=None) -> TabularModel:
    """Fit models of ``outputs`` on ``inputs`` from the rows of ``table``.

    Parameters
    ----------
    table : pandas.DataFrame
        One row per setting. Inputs must be numeric and finite in every row; an output may be
        missing (NaN: nothing measured) in some rows, which are left out of that output's fit.
    inputs, outputs : sequence of str
        Column names (distinct).
    folds : int
        K of the K-fold cross-validation (candidates, intervals, calibration).
    seed : int
        Seed of the fold splits and the tree ensembles (the fit is deterministic given it).
    level : float
        Level of the intervals (0.95).
    candidates : sequence of str, optional
        Regression candidates to choose among (names of :data:`REGRESSORS`; default all).
    classifiers : sequence of str, optional
        Classifier candidates of each continuation step (names of :data:`CLASSIFIERS`; default all).
    source : str, optional
        The table's file, named in errors and saved in the model file.

    Returns
    -------
    TabularModel

    Raises
    ------
    TabularError
        A missing or non-numeric column, an input that is not finite, a name used twice, too
        few rows, an unknown candidate.
    """
    src = source or "the table"
    inputs, outputs = list(inputs), list(outputs)
    if not inputs or not outputs:
        raise TabularError(f"{src}: give at least one input and one output column")
    both = inputs + outputs
    dup = sorted({c for c in both if both.count(c) > 1})
    if dup:
        raise TabularError(f"{src}: column {dup[0]!r} named twice in the inputs and outputs")
    if not (isinstance(folds, int) and 2 <= folds <= 50):
        raise TabularError(f"{src}: folds must be an integer in 2..50, got {folds!r}")
    if not 0 < level < 1:
        raise TabularError(f"{src}: level must be in (0, 1), got {level!r}")
    for given, known in ((candidates, REGRESSORS), (classifiers, CLASSIFIERS)):
        for c in given or ():
            if c not in known:
                raise TabularError(f"unknown candidate {c!r} (known: {', '.join(known)})")
    X = _columns(table, inputs, src, "input", finite=True)
    Y = _columns(table, outputs, src, "output", finite=False)
    if len(table) < max(MIN_ROWS, 2 * folds):
        raise TabularError(f"{src}: {len(table)} rows; at least {max(MIN_ROWS, 2 * folds)} are needed")
    frame = pd.DataFrame(np.column_stack([X, Y]), columns=both)
    return _build(inputs, outputs, frame, folds=folds, seed=seed, level=level,
                  source=None if source is None else str(source), candidates=candidates, classifiers=classifiers)
