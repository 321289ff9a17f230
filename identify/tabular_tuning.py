"""Design and closed-loop tuning over the N parameters of a table model (:mod:`identify.tabular`).

Targets name the model's outputs: a continuous output ``head_volume_px3=712000`` is met when it
lies within ``tolerance_percent`` of the value; a count output ``n_drops=1`` asks for that count
(the "single drop" constraint: ``P(n_drops = 1)`` at least ``min_probability``).

**Where it searches.** Only settings inside the model's training region are ever proposed: the
candidates are the lattice of each input's distinct training values (an input with more than
:data:`LEVELS_PER_INPUT` distinct values: that many evenly spaced values over its range), each
kept only when :meth:`identify.tabular.TrainingRegion.check` finds it inside (within each input's
range, and no farther from a training row than any training row is from its nearest other one)
and, stricter, no farther from a training row than the median of those distances (the sparse
edges of the region, where the fit is least checked, are left out). A lab's sweep is such a
lattice; the settings it can dial are its values.

**What it chooses.** For each candidate the probability that one shot meets every target: per
continuous target, the normal probability that the drop falls in the window (fitted scale: the
logarithm of a positive output), centred on the fit, with the drop-to-drop scatter (the local
median absolute residual of the model, x 1.4826) and the fit's own uncertainty (the jackknife of
the fold models) in quadrature; per count target, the model's calibrated probability of that
count. Among the candidates whose count probability reaches ``min_probability`` (all of them when
none does) the most probable is proposed; ``feasible`` says the fit itself lies within the
tolerance there and the count constraint holds.

**Closed loop** (:func:`tune_table`). The model is the prior; each shot corrects it. Per
continuous target, the rig's offset from the model on the fitted scale (``log measured - log
fit``: a relative bias) is a Gaussian process over the inputs normalised to their training
ranges (mean 0, standard deviation ``prior_bias_percent`` and the fit's uncertainty in
quadrature, squared-exponential correlation ``lengthscale``), observed with the drop-to-drop
scatter (robustly: a shot beyond :data:`ROBUST_Z` standard deviations of what was expected counts
as that far, until a second such shot nearby confirms it); per count target, the model's
probability is the prior of a Beta update by the counts
seen at nearby shots (weight = the same correlation, prior weight :data:`COUNT_PRIOR_SHOTS`
shots). The next proposal maximises the corrected probability of meeting every target (the
bias's posterior variance adds to the window's spread, so a setting where the bias is known
beats one where it is guessed), nearest the last shot among equals. The loop stops when a shot
meets every target or the budget is spent.

Rigs: any ``function(settings: dict, shot: int) -> dict`` of measured outputs, loaded from
``module:function`` or ``path/to/file.py:function`` (:func:`load_table_rig`).
"""

from __future__ import annotations

import importlib
import importlib.util
import math
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd

from dvcore.robust import MAD_TO_SIGMA
from identify.tabular import TabularError, TabularModel, TabularParameterError

__all__ = ["Target", "parse_targets", "candidates", "TableDesign", "design_table", "TableTuningResult",
           "tune_table", "write_table_tuning", "read_table_tuning", "load_table_rig", "LEVELS_PER_INPUT",
           "MAX_CANDIDATES", "COUNT_PRIOR_SHOTS"]

#: An input with more distinct training values than this is searched at this many evenly spaced values.
LEVELS_PER_INPUT = 25
#: Most candidate settings searched (a random, seeded subset of a larger lattice).
MAX_CANDIDATES = 200_000
#: Weight, in shots, of the model's count probability against counts seen at nearby shots.
COUNT_PRIOR_SHOTS = 2.0
#: A shot's offset farther than this many standard deviations from the expected one is down-weighted
#: to count as this far (a robust, Huber-like update).
ROBUST_Z = 3.0
#: The columns of a tuning table that are not named after the model's inputs and outputs.
FIXED_COLUMNS = ("shot", "probability_on_target", "feasible", "outside_training_region", "within_tolerance")


@dataclass(frozen=True)
class Target:
    """One target: a continuous output's value, or a count output's count."""

    output: str
    value: float
    kind: str  # "continuous" or "count"

    @property
    def label(self) -> str:
        return f"{self.output}={self.value:g}"


def parse_targets(model: TabularModel, specs) -> list[Target]:
    """Targets from ``["head_volume_px3=712000", "n_drops=1"]`` or ``{"n_drops": 1, ...}``.

    Raises
    ------
    TabularError
        No target, a malformed one, an output the model does not hold, a count it never saw, a
        non-positive value of an output fitted on its logarithm, an output named twice.
    """
    if isinstance(specs, (list, tuple)) and specs and all(isinstance(t, Target) for t in specs):
        return list(specs)
    items = list(specs.items()) if isinstance(specs, dict) else []
    if not isinstance(specs, dict):
        for s in specs or ():
            name, eq, value = str(s).partition("=")
            if not eq or not name.strip():
                raise TabularError(f"--target {s!r}: expected OUTPUT=VALUE (e.g. n_drops=1)")
            items.append((name.strip(), value.strip()))
    if not items:
        raise TabularError("give at least one --target OUTPUT=VALUE (outputs of the model: "
                           f"{', '.join(model.outputs)})")
    out, seen = [], set()
    for name, value in items:
        if name not in model.outputs:
            raise TabularError(f"--target {name}: not an output of the model (its outputs: {', '.join(model.outputs)})")
        if name in seen:
            raise TabularError(f"--target {name}: given twice")
        seen.add(name)
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise TabularError(f"--target {name}={value}: not a number") from None
        if not math.isfinite(v):
            raise TabularError(f"--target {name}={value}: not a finite number")
        if name in model.counts:
            classes = model.counts[name].classes
            if v != round(v) or int(v) not in classes:
                raise TabularError(f"--target {name}={value}: a count seen in training is needed ({classes}; "
                                   f"{classes[-1]} means {classes[-1]} or more)")
            out.append(Target(name, float(int(v)), "count"))
        else:
            if model.continuous[name].log and v <= 0:
                raise TabularError(f"--target {name}={value}: must be > 0 (the output is positive, fitted on its "
                                   "logarithm)")
            out.append(Target(name, v, "continuous"))
    return out


def candidates(model: TabularModel, *, seed: int = 0) -> np.ndarray:
    """The settings searched (rows x inputs): the lattice of the inputs' training values, inside
    the training region (see the module docstring)."""
    X = model.training_inputs()
    axes = []
    for j in range(X.shape[1]):
        u = np.unique(X[:, j])
        axes.append(u if u.size <= LEVELS_PER_INPUT else np.linspace(u[0], u[-1], LEVELS_PER_INPUT))
    sizes = [a.size for a in axes]
    total = int(np.prod(sizes, dtype=float))
    if total <= MAX_CANDIDATES:
        grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, len(axes))
    else:
        rng = np.random.default_rng(seed)
        grid = np.column_stack([a[rng.integers(0, a.size, MAX_CANDIDATES)] for a in axes])
    grid = np.unique(np.vstack([grid, X]), axis=0)  # the training settings are candidates too
    inside, _ = model.region.check(grid, X)
    grid = grid[~inside]
    # where the sweep is as dense as it typically is: no farther from a measured setting than the
    # median distance between a measured setting and its nearest other one (the region's edges,
    # up to the largest such distance, are sparse: a fit there is least checked)
    from scipy.spatial import cKDTree

    step = model.region.step
    tree = cKDTree(X / step)
    typical = float(np.median(tree.query(X / step, k=2)[0][:, 1])) if len(X) > 1 else 0.0
    d, _ = tree.query(grid / step, k=1)
    return grid[d <= typical * (1 + 1e-9) + 1e-12]


class _Surface:
    """The model's predictions at the candidates, on each continuous target's fitted scale."""

    def __init__(self, model: TabularModel, targets: list[Target], X: np.ndarray):
        self.X = X
        self.fit, self.drop_sd, self.fit_sd, self.p, self.log, self.q = {}, {}, {}, {}, {}, {}
        for t in targets:
            if t.kind == "continuous":
                parts = model.fitted_scale(t.output, X)
                self.fit[t.output] = parts["fit"]
                self.drop_sd[t.output] = MAD_TO_SIGMA * parts["scale"]
                self.fit_sd[t.output] = parts["fit_std"]
                self.log[t.output] = parts["log"]
                self.q[t.output] = (parts["q_lo"], parts["q_hi"])
            else:
                self.p[t.output] = model.count_probabilities(t.output, X)[f"{t.output}_p{int(t.value)}"]


def _window(t: Target, log: bool, tol: float) -> tuple[float, float]:
    """The target window on the fitted scale."""
    if log:
        return math.log(t.value) + math.log1p(-tol), math.log(t.value) + math.log1p(tol)
    half = tol * abs(t.value)
    return t.value - half, t.value + half


def _probability(surface: _Surface, targets, tol, offsets=None, extra_var=None, count_p=None):
    """Per candidate: P(every target met by one shot), P(each count), the continuous centres."""
    from scipy.stats import norm

    n = len(surface.X)
    prob = np.ones(n)
    counts = {}
    for t in targets:
        if t.kind == "continuous":
            o = t.output
            mu = surface.fit[o] + (0.0 if offsets is None else offsets[o])
            var = surface.drop_sd[o] ** 2 + (surface.fit_sd[o] ** 2 if extra_var is None else extra_var[o])
            sd = np.sqrt(var)
            lo, hi = _window(t, surface.log[o], tol)
            prob *= norm.cdf((hi - mu) / sd) - norm.cdf((lo - mu) / sd)
        else:
            p = surface.p[t.output] if count_p is None else count_p[t.output]
            counts[t.output] = p
            prob *= p
    return prob, counts


def _choose(prob, counts, min_probability, X, near, span):
    ok = np.ones(len(prob), bool)
    for p in counts.values():
        ok &= p >= min_probability
    pool = np.flatnonzero(ok) if ok.any() else np.arange(len(prob))
    best = prob[pool].max()
    ties = pool[prob[pool] >= best - 1e-9]
    if near is not None and ties.size > 1:
        d = np.sum(((X[ties] - near) / span) ** 2, axis=1)
        return int(ties[np.argmin(d)]), bool(ok.any())
    return int(ties[0]), bool(ok.any())


@dataclass
class TableDesign:
    """Outcome of :func:`design_table`.

    ``settings``: input -> value proposed; ``predicted``: the model's columns there (as
    :meth:`identify.tabular.TabularModel.predict`); ``probability_on_target``: P(one shot meets
    every target); ``feasible``: the fit lies within the tolerance and each count constraint
    holds; ``outside_training_region``: always False (only candidates inside are searched).
    """

    feasible: bool
    settings: dict
    targets: dict
    tolerance_percent: float
    min_probability: float
    predicted: dict
    probability_on_target: float
    candidates: int
    message: str
    outside_training_region: bool = False

    def to_dict(self) -> dict:
        from dvcore.schema import TABULAR_DESIGN

        return {"schema": TABULAR_DESIGN.schema, "feasible": self.feasible, "settings": self.settings,
                "targets": self.targets, "tolerance_percent": self.tolerance_percent,
                "min_probability": self.min_probability, "predicted": self.predicted,
                "probability_on_target": self.probability_on_target, "candidates": self.candidates,
                "outside_training_region": self.outside_training_region, "message": self.message}


def _check_options(tolerance_percent, min_probability):
    if not (isinstance(tolerance_percent, (int, float)) and math.isfinite(tolerance_percent)
            and 0 < tolerance_percent < 100):
        raise TabularParameterError("tolerance_percent", f"must be a number in (0, 100), got {tolerance_percent!r}")
    if not (isinstance(min_probability, (int, float)) and 0 <= min_probability <= 1):
        raise TabularParameterError("min_probability", f"must be a number in [0, 1], got {min_probability!r}")


def _met(model, targets, pred_row: dict, tol: float) -> bool:
    """The fit itself within the tolerance (continuous targets)."""
    for t in targets:
        if t.kind == "continuous":
            v = pred_row[f"{t.output}_mean"]
            if not abs(v - t.value) <= tol * abs(t.value):
                return False
    return True


def _describe(targets, tol) -> str:
    return ", ".join(f"{t.output} = {t.value:g}" + (f" +/- {100 * tol:g} %" if t.kind == "continuous" else "")
                     for t in targets)


def design_table(model: TabularModel, targets, *, tolerance_percent: float = 2.0, min_probability: float = 0.9,
                 seed: int = 0) -> TableDesign:
    """Settings inside the training region most likely to meet ``targets`` in one shot.

    Parameters
    ----------
    model : TabularModel
    targets : list of str, dict or list of Target
        ``["head_volume_px3=712000", "n_drops=1"]`` (:func:`parse_targets`).
    tolerance_percent : float
        A continuous output within this of its target is met.
    min_probability : float
        A count target is a constraint: P(that count) at least this.
    seed : int
        Seed of the subset of a lattice larger than :data:`MAX_CANDIDATES`.
    """
    _check_options(tolerance_percent, min_probability)
    tg = parse_targets(model, targets)
    tol = tolerance_percent / 100.0
    X = candidates(model, seed=seed)
    surface = _Surface(model, tg, X)
    prob, counts = _probability(surface, tg, tol)
    i, constrained = _choose(prob, counts, min_probability, X, None, _span(model))
    settings = {n: float(v) for n, v in zip(model.inputs, X[i])}
    pred = model.predict(pd.DataFrame([settings])).iloc[0]
    predicted = {k: (bool(v) if isinstance(v, (bool, np.bool_)) else v if isinstance(v, str) else float(v))
                 for k, v in pred.items() if k != "outside_training_region_why"}
    met = _met(model, tg, predicted, tol)
    feasible = bool(met and constrained)
    where = ", ".join(f"{n} = {v:g}" for n, v in settings.items())
    got = "; ".join([f"{t.output} {predicted[t.output + '_mean']:.4g} (one drop "
                     f"[{predicted[t.output + '_one_drop_low']:.4g}, {predicted[t.output + '_one_drop_high']:.4g}])"
                     if t.kind == "continuous" else f"P({t.output} = {int(t.value)}) {counts[t.output][i]:.3f}"
                     for t in tg])
    if feasible:
        msg = f"{where} gives {got}; P(one shot meets every target) {prob[i]:.2f}"
    else:
        why = []
        if not met:
            why.append(f"no setting inside the training region has a fit within {tolerance_percent:g} %")
        if not constrained:
            why.append(f"no setting reaches P >= {min_probability:g} for the count target(s)")
        msg = (f"infeasible: {_describe(tg, tol)}: " + "; ".join(why) + f"; nearest: {where} gives {got}; "
               f"P(one shot meets every target) {prob[i]:.2f}")
    return TableDesign(feasible=feasible, settings=settings, targets={t.output: t.value for t in tg},
                       tolerance_percent=float(tolerance_percent), min_probability=float(min_probability),
                       predicted=predicted, probability_on_target=float(prob[i]), candidates=int(len(X)), message=msg)


def _span(model: TabularModel) -> np.ndarray:
    r = model.region
    return np.where(r.high > r.low, r.high - r.low, 1.0)


# ----------------------------------------------------------------------------- closed loop
def load_table_rig(spec: str) -> Callable:
    """The rig function of ``module:function`` (an importable module, or a ``.py`` file path).

    The current folder is searched too (as ``python -m`` would). Raises :class:`TabularError`
    (one line) when the module or the function cannot be found or is not callable.
    """
    mod, sep, attr = str(spec).rpartition(":")
    if not sep or not mod or not attr:
        raise TabularParameterError("spec", f"{spec}: a table model's rig is module:function (or path/to/file.py:function)",
                                    option="--rig")
    try:
        if mod.endswith(".py") or os.sep in mod or "/" in mod:
            path = Path(mod)
            if not path.is_file():
                raise TabularParameterError("spec", f"{spec}: {path}: no such file", option="--rig")
            name = f"_dropvision_rig_{abs(hash(str(path.resolve())))}"
            ms = importlib.util.spec_from_file_location(name, path)
            module = importlib.util.module_from_spec(ms)
            sys.modules[name] = module
            ms.loader.exec_module(module)
        else:
            added = os.getcwd() not in sys.path
            if added:
                sys.path.insert(0, os.getcwd())
            try:
                module = importlib.import_module(mod)
            finally:
                if added:
                    sys.path.remove(os.getcwd())
        fn = getattr(module, attr)
    except TabularError:
        raise
    except Exception as exc:  # noqa: BLE001 - whatever the user's module raises on import: one line
        raise TabularParameterError("spec", f"{spec}: cannot load the function ({type(exc).__name__}: {exc})",
                                    option="--rig") from None
    if not callable(fn):
        raise TabularParameterError("spec", f"{spec}: {attr} is not a function", option="--rig")
    return fn


def _measured(model, targets, answer, where: str) -> dict:
    """The rig's answer checked: every target output present; numbers."""
    if not isinstance(answer, dict):
        raise TabularError(f"{where}: the rig returned {type(answer).__name__}; expected a dict of measured outputs "
                           f"({', '.join(t.output for t in targets)})")
    out = {}
    for t in targets:
        if t.output not in answer:
            raise TabularError(f"{where}: the rig's answer has no {t.output}")
    for k, v in answer.items():
        if v is None:
            v = float("nan")
        if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, float, np.integer, np.floating)):
            if k in model.outputs:
                raise TabularError(f"{where}: {k} = {v!r} is not a number")
            continue  # another value of the rig's own: not written
        v = float(v)
        if k in model.counts and math.isfinite(v) and (v < 0 or v != round(v)):
            raise TabularError(f"{where}: {k} = {v!r} is not a count (a non-negative integer)")
        out[k] = v
    for t in targets:
        if t.kind == "count" and not math.isfinite(out[t.output]):
            raise TabularError(f"{where}: no {t.output} measured (got NaN)")
    return out


@dataclass
class TableTuningResult:
    """A tuning run of a table model: one record per shot (the columns of
    `dvcore.schema.TABULAR_TUNING`) and what it was run for."""

    shots: list
    inputs: list
    targets: dict
    tolerance_percent: float
    min_probability: float
    converged: bool
    message: str
    meta: dict = field(default_factory=dict)

    def to_pandas(self) -> pd.DataFrame:
        df = pd.DataFrame(self.shots)
        df["shot"] = df["shot"].astype("int64")
        for c in ("feasible", "outside_training_region", "within_tolerance"):
            df[c] = df[c].astype(bool)
        return df

    def to_dict(self) -> dict:
        from dvcore.schema import TABULAR_TUNING_RUN

        return {"schema": TABULAR_TUNING_RUN.schema, "inputs": list(self.inputs), "targets": dict(self.targets),
                "tolerance_percent": self.tolerance_percent, "min_probability": self.min_probability,
                "converged": self.converged, "shots_fired": len(self.shots), "message": self.message, **self.meta}


def _gp(obs: list, prior_sd: float, lengthscale: float, at: np.ndarray):
    """Posterior mean and variance of a zero-mean GP offset at ``at`` from ``obs``.

    ``obs``: ``(x, r, sd, sd_gross, sign)`` per shot: ``sd_gross`` (> ``sd``) for a shot that was
    a gross deviation (``sign`` its direction, 0: none). A gross deviation counts with
    ``sd_gross`` alone; once another gross deviation of the same sign confirms it nearby
    (correlation >= 1/2) both count with ``sd``: one failed detection teaches nothing, two in the
    same place are the rig.
    """
    ok = [o for o in obs if math.isfinite(o[1])]
    p2 = prior_sd**2
    if not ok:
        return np.zeros(len(at)), np.full(len(at), p2)
    x = np.array([o[0] for o in ok])
    r = np.array([o[1] for o in ok])
    s = np.array([o[2] for o in ok])
    gross = np.array([o[3] for o in ok])
    sign = np.array([o[4] for o in ok])
    d2 = np.sum((x[:, None, :] - x[None, :, :]) ** 2, axis=-1)
    corr = np.exp(-0.5 * d2 / lengthscale**2)
    for i in np.flatnonzero(sign != 0):
        confirmed = np.any((sign == sign[i]) & (corr[i] >= 0.5) & (np.arange(len(ok)) != i))
        if not confirmed:
            s[i] = gross[i]
    cov = p2 * corr + np.diag(s**2)
    k = p2 * np.exp(-0.5 * np.sum((at[:, None, :] - x[None, :, :]) ** 2, axis=-1) / lengthscale**2)
    w = np.linalg.solve(cov, k.T)
    return r @ w, np.maximum(p2 - np.sum(k * w.T, axis=1), 0.0)


def _check_tune_options(model: TabularModel, tolerance_percent, min_probability, prior_bias_percent, lengthscale,
                        shots) -> None:
    """`tune_table`'s options and the model's input names checked (TabularError naming the bad one)."""
    _check_options(tolerance_percent, min_probability)
    for name, option, v in (("prior_bias_percent", None, prior_bias_percent),
                            ("lengthscale", "--bias-lengthscale", lengthscale)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise TabularParameterError(name, f"must be a positive number, got {v!r}", option=option)
    if isinstance(shots, bool) or int(shots) != shots or shots < 1:
        raise TabularParameterError("shots", f"must be an integer >= 1, got {shots!r}")
    clash = [n for n in model.inputs if n in FIXED_COLUMNS]
    if clash:
        raise TabularError(f"the model's input {clash[0]!r} has the name of a tuning column; rename it in the table")


def _tuning_result(model: TabularModel, tg, records: list, *, converged: bool, final: bool, what: str, shots: int,
                   tolerance_percent: float, min_probability: float, meta: dict) -> TableTuningResult:
    """The run so far, with its one-line message (met, in progress, or not met)."""
    last = records[-1]
    got = ", ".join(f"{t.output} {last[t.output]:.4g}" + (f" ({last[t.output + '_error_percent']:+.2f} %)"
                                                            if t.kind == "continuous" else "") for t in tg)
    where = ", ".join(f"{n} = {last[n]:g}" for n in model.inputs)
    if converged:
        msg = f"target {what} met in {len(records)} shot(s): {where} measured {got}"
    elif not final:
        msg = f"in progress: {len(records)} of at most {int(shots)} shot(s) fired; last: {where} measured {got}"
    else:
        msg = f"target {what} not met in {len(records)} shot(s); last: {where} measured {got}"
    return TableTuningResult(shots=list(records), inputs=list(model.inputs), targets={t.output: t.value for t in tg},
                             tolerance_percent=float(tolerance_percent), min_probability=float(min_probability),
                             converged=converged, message=msg, meta=dict(meta))


def _belief(tg, surface: _Surface, obs: dict, prior_sd: dict, lengthscale: float, Z: np.ndarray):
    """The rig's offset from the model learnt from the shots so far: per continuous output its mean
    and variance over the candidates (`_gp`), per count output the probability of the target count."""
    offsets, var, count_p = {}, {}, {}
    for t in tg:
        if t.kind == "continuous":
            m, v = _gp(obs[t.output], prior_sd[t.output], lengthscale, Z)
            offsets[t.output], var[t.output] = m, v
        else:
            p = surface.p[t.output].copy()
            if obs[t.output]:
                xs = np.array([x for x, _, _ in obs[t.output]])
                hits = np.array([h for _, h, _ in obs[t.output]])
                w = np.exp(-0.5 * np.sum((Z[:, None, :] - xs[None, :, :]) ** 2, axis=-1) / lengthscale**2)
                p = (COUNT_PRIOR_SHOTS * p + w @ hits) / (COUNT_PRIOR_SHOTS + w.sum(axis=1))
            count_p[t.output] = p
    return offsets, var, count_p


def _fire(rig: Callable, name: str, settings: dict, k: int):
    """The rig's answer to shot ``k`` (its failure one TabularError naming the rig and the shot)."""
    try:
        return rig(dict(settings), k)
    except (TabularError, OSError):
        raise
    except Exception as exc:  # noqa: BLE001 - the lab's own code failed: one line naming the rig and shot
        raise TabularError(f"rig {name}: shot {k}: the rig failed ({type(exc).__name__}: {exc})") from exc


def _continuous_record(t, i: int, value: float, surface: _Surface, offsets, var, obs: dict, prior_sd: dict,
                       lengthscale: float, Z: np.ndarray, tolerance_percent: float, tol: float):
    """A continuous target's columns of the shot at candidate ``i`` measuring ``value`` (the shot
    joins ``obs``): (columns, within tolerance, the corrected prediction within tolerance)."""
    o = t.output
    log = surface.log[o]
    q_lo, q_hi = surface.q[o]
    f = float(surface.fit[o][i])
    back = math.exp if log else (lambda z: z)
    mu, sd = f + float(offsets[o][i]), math.sqrt(float(surface.drop_sd[o][i] ** 2 + var[o][i]))
    z = (math.log(value) if value > 0 else float("nan")) if log else value
    # a robust update: a shot farther than ROBUST_Z standard deviations from what was
    # expected counts as that far (the heavy tails of real scatter: a failed detection
    # must not teach the loop a bias) until a second one nearby confirms it (_gp)
    r_obs = z - f if math.isfinite(z) else float("nan")
    s_obs = float(surface.drop_sd[o][i])
    expect_sd = math.sqrt(s_obs**2 + float(var[o][i]))
    innovation = r_obs - float(offsets[o][i])
    s_gross, sign = s_obs, 0
    if math.isfinite(innovation) and abs(innovation) > ROBUST_Z * expect_sd:
        s_gross = math.sqrt((abs(innovation) / ROBUST_Z) ** 2 - float(var[o][i]))
        sign = 1 if innovation > 0 else -1
    obs[o].append((Z[i], r_obs, s_obs, s_gross, sign))
    after, after_var = _gp(obs[o], prior_sd[o], lengthscale, Z[i:i + 1])
    err = 100.0 * (value / t.value - 1.0) if math.isfinite(value) else float("nan")
    within = math.isfinite(err) and abs(err) <= tolerance_percent
    fit_ok = abs(back(mu) / t.value - 1.0) <= tol
    bias = math.expm1 if log else (lambda b: b / abs(t.value))
    cols = {
        f"{o}_target": t.value,
        f"{o}_predicted": back(f),
        f"{o}_corrected": back(mu),
        f"{o}_one_drop_low": back(mu + q_lo / MAD_TO_SIGMA * sd),
        f"{o}_one_drop_high": back(mu + q_hi / MAD_TO_SIGMA * sd),
        o: value,
        f"{o}_error_percent": err,
        f"{o}_bias_percent": 100.0 * bias(float(after[0])),
        f"{o}_bias_se_percent": 100.0 * math.sqrt(float(after_var[0])) * (1.0 if log else 1.0 / abs(t.value)),
    }
    return cols, within, fit_ok


def _count_record(model: TabularModel, t, i: int, value, surface: _Surface, count_p: dict, obs: dict, Z: np.ndarray):
    """A count target's columns of the shot at candidate ``i`` (the shot joins ``obs``): (columns, hit)."""
    o = t.output
    kk = int(t.value)
    hit = float(value == kk or (kk == model.counts[o].classes[-1] and value >= kk))
    obs[o].append((Z[i], hit, 0.0))
    return {f"{o}_target": t.value, f"{o}_p{kk}_predicted": float(surface.p[o][i]),
            f"{o}_p{kk}_corrected": float(count_p[o][i]), o: value}, bool(hit)


def tune_table(model: TabularModel, rig: Callable, targets, *, shots: int = 5, tolerance_percent: float = 2.0,
               min_probability: float = 0.9, prior_bias_percent: float = 2.0, lengthscale: float = 0.25,
               seed: int = 0, rig_name: str | None = None, model_path=None,
               progress: Callable[["TableTuningResult"], None] | None = None) -> TableTuningResult:
    """Tune the model's inputs on a rig until one shot meets every target (module docstring).

    Parameters
    ----------
    model : TabularModel
    rig : callable
        ``rig(settings: dict, shot: int) -> dict`` of measured outputs (each target output).
    targets : list of str or dict
        :func:`parse_targets`.
    shots : int
        Shot budget (>= 1).
    tolerance_percent, min_probability : float
        As :func:`design_table`.
    prior_bias_percent : float
        Prior standard deviation (%) of the rig's offset from the model, beyond the fit's own
        uncertainty.
    lengthscale : float
        Correlation length of the offset over the inputs, in units of their training ranges.
    seed : int
        Seed of the candidate subset (a lattice larger than :data:`MAX_CANDIDATES`).
    rig_name : str, optional
        Written in ``meta`` (e.g. the ``module:function``).
    model_path : path, optional
        The model file: its name and SHA-256 go into ``meta``.
    progress : callable, optional
        Called after every shot with the run so far (message "in progress: ...").

    Raises
    ------
    TabularError
        Bad targets or options; a rig answer without a target output.
    """
    from dvcore.versions import software_versions
    from identify.tuning import file_sha256

    _check_tune_options(model, tolerance_percent, min_probability, prior_bias_percent, lengthscale, shots)
    tg = parse_targets(model, targets)
    tol = tolerance_percent / 100.0
    X = candidates(model, seed=seed)
    train = model.training_inputs()
    span, low = _span(model), model.region.low
    Z = (X - low) / span
    surface = _Surface(model, tg, X)
    prior_sd = {t.output: math.hypot(float(np.median(surface.fit_sd[t.output])), prior_bias_percent / 100.0)
                for t in tg if t.kind == "continuous"}
    obs = {t.output: [] for t in tg}
    records: list = []
    name = rig_name or getattr(rig, "__name__", type(rig).__name__)
    meta = {"seed": int(seed), "shot_budget": int(shots), "prior_bias_percent": float(prior_bias_percent),
            "bias_lengthscale": float(lengthscale), "candidates": int(len(X)), "rig": str(name),
            "model_file": None if model_path is None else str(model_path),
            "model_sha256": None if model_path is None else file_sha256(model_path),
            "versions": software_versions()}
    common = dict(what=_describe(tg, tol), shots=shots, tolerance_percent=tolerance_percent,
                  min_probability=min_probability, meta=meta)
    for k in range(1, int(shots) + 1):
        offsets, var, count_p = _belief(tg, surface, obs, prior_sd, lengthscale, Z)
        prob, counts = _probability(surface, tg, tol, offsets, var, count_p)
        near = None if not records else np.array([records[-1][n] for n in model.inputs])
        i, constrained = _choose(prob, counts, min_probability, X, near, span)
        settings = {n: float(v) for n, v in zip(model.inputs, X[i])}
        outside, _ = model.region.check(X[i:i + 1], train)
        measured = _measured(model, tg, _fire(rig, name, settings, k), f"rig {name}: shot {k}")
        rec: dict = {"shot": k, **settings}
        within = True
        fit_ok = True
        for t in tg:
            if t.kind == "continuous":
                cols, ok, fit = _continuous_record(t, i, measured[t.output], surface, offsets, var, obs, prior_sd,
                                                   lengthscale, Z, tolerance_percent, tol)
                within, fit_ok = within and ok, fit_ok and fit
            else:
                cols, hit = _count_record(model, t, i, measured[t.output], surface, count_p, obs, Z)
                within = within and hit
            rec.update(cols)
        for key, v in measured.items():  # the other outputs of the model the rig measured, then its own values
            if key not in rec:
                rec[key if key in model.outputs else f"rig_{key}"] = v
        rec.update({"probability_on_target": float(prob[i]), "feasible": bool(fit_ok and constrained),
                    "outside_training_region": bool(outside[0]), "within_tolerance": bool(within)})
        records.append(rec)
        if progress is not None:
            progress(_tuning_result(model, tg, records, converged=bool(within), final=bool(within), **common))
        if within:
            break
    return _tuning_result(model, tg, records, converged=bool(within), final=True, **common)


def write_table_tuning(result: TableTuningResult, out_dir, *, inputs=(), overwrite: bool = False) -> Path:
    """Write ``out_dir/tuning.parquet`` (one row per shot) and ``tuning.json`` atomically
    (`dvcore.atomic.atomic_dir`: an earlier result of ours is replaced, nothing half-written)."""
    from dvcore.atomic import atomic_dir, write_json
    from identify.tuning import TUNING_FILES

    with atomic_dir(out_dir, inputs=inputs, overwrite=overwrite, kind="tuning") as tmp:
        result.to_pandas().to_parquet(tmp / TUNING_FILES[0], index=False)
        write_json(tmp / TUNING_FILES[1], result.to_dict())
    return Path(out_dir)


def read_table_tuning(folder) -> TableTuningResult:
    """Read a table tuning run folder back, checked against `dvcore.schema.TABULAR_TUNING` and
    `TABULAR_TUNING_RUN` (a :class:`dvcore.schema.SchemaError` names the file)."""
    from dvcore.schema import TABULAR_TUNING_RUN, SchemaError
    from identify.tuning import read_run_folder

    df, doc, table = read_run_folder(folder, TABULAR_TUNING_RUN)
    need = list(FIXED_COLUMNS) + list(doc["inputs"]) + list(doc["targets"])
    missing = [c for c in need if c not in df.columns]
    if missing:
        raise SchemaError(f"{table}: missing column {missing[0]!r}")
    keys = {"schema", "inputs", "targets", "tolerance_percent", "min_probability", "converged", "message",
            "shots_fired"}
    return TableTuningResult(shots=df.to_dict(orient="records"), inputs=doc["inputs"], targets=doc["targets"],
                             tolerance_percent=doc["tolerance_percent"], min_probability=doc["min_probability"],
                             converged=bool(doc["converged"]), message=doc["message"],
                             meta={k: v for k, v in doc.items() if k not in keys})
